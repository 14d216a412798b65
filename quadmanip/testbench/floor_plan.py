"""The house's true floor plan at the LiDAR's height, and a LiDAR simulated on it.

GROUND TRUTH, for the navigation benchmark's scoring (map F1) and for the navigation
algorithms' unit tests (synthetic scans). No service imports this.

The plan is rasterised from the compiled empty house (the same MJCF the simulator runs):
a cell is occupied when it overlaps the footprint of a box geom that reaches into the
horizontal band the 2D LiDAR scans (its height standing, from the robot description,
+/- ``band``). The LiDAR model marches each ray over that raster.
"""

from __future__ import annotations

import math
from functools import lru_cache

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.services.navigation.grid import GridGeometry, Pose2
from quadmanip.services.navigation.scan import lidar_height_above_base

__all__ = ["FloorPlan", "lidar_height", "simulate_scan", "true_floor_plan"]


def lidar_height() -> float:
    """Height of the LiDAR above the floor with the robot standing in its home pose."""
    model = rd.load_mujoco_model()
    base_z = float(rd.home_qpos(model)[rd.free_joint_qpos_index(model) + 2])
    return base_z + lidar_height_above_base()


class FloorPlan:
    """A boolean occupancy raster (``mask[row, col]``) on ``geometry``."""

    def __init__(self, mask: np.ndarray, geometry: GridGeometry) -> None:
        self.mask = mask
        self.geometry = geometry

    def occupied(self, xy: np.ndarray) -> np.ndarray:
        """Whether points (N, 2) fall on occupied cells (outside the raster: occupied)."""
        r, c = self.geometry.to_cell(xy)
        inside = self.geometry.inside(r, c)
        out = np.ones(len(r), dtype=bool)
        out[inside] = self.mask[r[inside], c[inside]]
        return out


@lru_cache(maxsize=4)
def true_floor_plan(
    resolution: float = 0.05, height: float | None = None, band: float = 0.005
) -> FloorPlan:
    """The empty house's occupied cells in the LiDAR's band (world frame = the map frame
    of a map started at the world origin)."""
    from quadmanip.sim.world.builder import build_world  # the simulator's world: tooling only

    h = lidar_height() if height is None else height
    world = build_world(None, robot=False)
    m = world.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    boxes = []
    for g in range(m.ngeom):
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
            continue
        R = d.geom_xmat[g].reshape(3, 3)
        half = m.geom_size[g]
        z_half = float(np.abs(R[2]) @ half)
        zc = float(d.geom_xpos[g][2])
        if zc + z_half < h - band or zc - z_half > h + band:
            continue
        boxes.append((d.geom_xpos[g][:2].copy(), R[:2, :2].copy(), half[:2].copy()))
    lo = np.min([c - np.abs(R) @ hs for c, R, hs in boxes], axis=0) - 0.5
    hi = np.max([c + np.abs(R) @ hs for c, R, hs in boxes], axis=0) + 0.5
    lo = np.floor(lo / resolution) * resolution
    geo = GridGeometry.covering(
        (float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])), resolution
    )
    rows, cols = np.mgrid[0 : geo.height, 0 : geo.width]
    centres = geo.cell_center(rows.ravel(), cols.ravel())
    mask = np.zeros(geo.height * geo.width, dtype=bool)
    # a cell is occupied when the box overlaps it (a return on the box's face lands in the
    # cell it enters, whose centre may lie just outside the box)
    grow = 0.5 * resolution - 1e-6
    for c, R, hs in boxes:
        local = (centres - c) @ R  # into the box's frame (R's columns are its axes)
        mask |= (np.abs(local[:, 0]) <= hs[0] + grow) & (np.abs(local[:, 1]) <= hs[1] + grow)
    return FloorPlan(mask.reshape(geo.shape), geo)


def simulate_scan(
    plan: FloorPlan,
    lidar_pose: Pose2,
    rays: int = 360,
    range_min: float = 0.1,
    range_max: float = 12.0,
    noise: float = 0.01,
    rng: np.random.Generator | None = None,
    dropout: float = 0.0,
) -> np.ndarray:
    """Ranges (m) of a 360-degree scan from ``lidar_pose`` (angle_min = -pi, counter-
    clockwise, ``rays`` beams), 0 for no return, like the simulator's LaserScan. Rays march
    over the raster in quarter-cell steps; ``dropout`` is the fraction of returns lost."""
    rng = rng or np.random.default_rng(0)
    step = plan.geometry.resolution / 4.0
    angles = lidar_pose[2] - math.pi + np.arange(rays) * (2 * math.pi / rays)
    s = np.arange(range_min, range_max + step, step)
    xs = lidar_pose[0] + np.cos(angles)[:, None] * s[None, :]
    ys = lidar_pose[1] + np.sin(angles)[:, None] * s[None, :]
    hit = plan.occupied(np.stack([xs.ravel(), ys.ravel()], axis=1)).reshape(rays, len(s))
    first = np.argmax(hit, axis=1)
    ranges = np.where(hit.any(axis=1), s[first], 0.0)
    valid = ranges > 0
    ranges[valid] += rng.normal(0.0, noise, int(valid.sum()))
    ranges[(ranges < range_min) | (ranges > range_max)] = 0.0
    if dropout > 0:
        ranges[rng.random(rays) < dropout] = 0.0
    return ranges
