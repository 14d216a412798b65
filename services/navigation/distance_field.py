"""Distance to the nearest occupied cell, everywhere on a grid, and its smooth lookup.

One field serves three users: the scan matcher (a scan fits the map where its points lie
on occupied cells: Hector/Cartographer-style matching against a smooth field), the
particle filter's likelihood-field sensor model (Thrun et al., Probabilistic Robotics
6.4, the model AMCL uses) and the costmap's inflation. The exact Euclidean distance
transform is scipy's; lookups interpolate it bilinearly, so the matcher sees a field that
is continuous in the pose.
"""

from __future__ import annotations

import numpy as np
from quadmanip.services.navigation.grid import GridGeometry
from scipy import ndimage

__all__ = ["DistanceField"]


class DistanceField:
    """Metres from each cell centre to the nearest occupied cell centre, capped at
    ``max_distance``. Points off the grid read ``max_distance``."""

    def __init__(self, occupied: np.ndarray, geometry: GridGeometry, max_distance: float = 2.0):
        if occupied.shape != geometry.shape:
            raise ValueError(f"mask shape {occupied.shape} != grid shape {geometry.shape}")
        self.geometry = geometry
        self.max_distance = float(max_distance)
        if occupied.any():
            d = ndimage.distance_transform_edt(~occupied) * geometry.resolution
        else:
            d = np.full(geometry.shape, self.max_distance)
        self.distance_grid = np.minimum(d, self.max_distance)

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated distance (m) at points (N, 2)."""
        rc = self.geometry.to_fractional(xy)
        return ndimage.map_coordinates(
            self.distance_grid, rc.T, order=1, mode="constant", cval=self.max_distance
        )

    def distance_and_gradient(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance at points (N, 2) and its gradient d/d(x, y) (N, 2), by central
        differences of the interpolated field over half a cell."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        h = 0.5 * self.geometry.resolution
        offsets = np.array([[0, 0], [h, 0], [-h, 0], [0, h], [0, -h]])
        vals = self.distance((xy[None, :, :] + offsets[:, None, :]).reshape(-1, 2)).reshape(5, -1)
        grad = np.stack([(vals[1] - vals[2]) / (2 * h), (vals[3] - vals[4]) / (2 * h)], axis=1)
        return vals[0], grad
