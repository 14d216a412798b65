"""Grid geometry shared by every navigation layer: cells of ``resolution`` metres, row 0
at the lowest y (ROS's OccupancyGrid convention), the map's lower-left corner at
``(origin_x, origin_y)``. The map frame is axis-aligned with the grid (no origin yaw)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.common.rotations import wrap_angle as wrap

__all__ = ["GridGeometry", "Pose2", "compose", "invert", "transform_points", "wrap"]

Pose2 = tuple[float, float, float]
"""A planar pose (x, y, yaw)."""


def compose(a: Pose2, b: Pose2) -> Pose2:
    """a ⊕ b: the pose b (given in a's frame) in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], float(wrap(a[2] + b[2])))


def invert(a: Pose2) -> Pose2:
    """The inverse transform of a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], float(wrap(-a[2])))


def transform_points(pose: Pose2, pts: np.ndarray) -> np.ndarray:
    """Points (N, 2) given in the frame ``pose`` expressed in its parent frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    out = np.empty_like(pts)
    out[:, 0] = pose[0] + c * pts[:, 0] - s * pts[:, 1]
    out[:, 1] = pose[1] + s * pts[:, 0] + c * pts[:, 1]
    return out


@dataclass(frozen=True)
class GridGeometry:
    """Where a grid of ``height`` rows x ``width`` columns lies in its frame."""

    resolution: float
    origin_x: float
    origin_y: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (self.resolution > 0 and self.width > 0 and self.height > 0):
            raise ValueError(f"bad grid geometry {self}")

    @classmethod
    def covering(
        cls, lo: tuple[float, float], hi: tuple[float, float], resolution: float
    ) -> GridGeometry:
        """The grid that covers the rectangle lo..hi."""
        w = int(math.ceil((hi[0] - lo[0]) / resolution - 1e-9))
        h = int(math.ceil((hi[1] - lo[1]) / resolution - 1e-9))
        return cls(resolution, float(lo[0]), float(lo[1]), max(w, 1), max(h, 1))

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols), the shape of a grid array."""
        return (self.height, self.width)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) in metres."""
        return (
            self.origin_x,
            self.origin_y,
            self.origin_x + self.width * self.resolution,
            self.origin_y + self.height * self.resolution,
        )

    def to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) int arrays of the cells holding points (N, 2); may lie outside."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        cols = np.floor((xy[:, 0] - self.origin_x) / self.resolution).astype(np.int64)
        rows = np.floor((xy[:, 1] - self.origin_y) / self.resolution).astype(np.int64)
        return rows, cols

    def to_fractional(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) continuous (row, col) coordinates with cell centres at integers, for
        interpolation (``scipy.ndimage.map_coordinates``)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        out = np.empty_like(xy)
        out[:, 0] = (xy[:, 1] - self.origin_y) / self.resolution - 0.5
        out[:, 1] = (xy[:, 0] - self.origin_x) / self.resolution - 0.5
        return out

    def inside(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Mask of the cells that lie in the grid."""
        return (rows >= 0) & (rows < self.height) & (cols >= 0) & (cols < self.width)

    def contains(self, x: float, y: float) -> bool:
        """Whether the point (x, y) lies on the grid."""
        x0, y0, x1, y1 = self.extent
        return x0 <= x < x1 and y0 <= y < y1

    def cell_center(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 2) centres of cells."""
        rows = np.asarray(rows, dtype=float).reshape(-1)
        cols = np.asarray(cols, dtype=float).reshape(-1)
        return np.stack(
            [
                self.origin_x + (cols + 0.5) * self.resolution,
                self.origin_y + (rows + 0.5) * self.resolution,
            ],
            axis=1,
        )
