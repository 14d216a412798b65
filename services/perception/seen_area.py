"""Where the cameras have seen the floor and the table tops: a 2-D grid of seen cells.

The task searches each zone from viewpoints (``services/behavior/coverage.py``), yet the
front camera sees most of a room from its first views: in the tidy-up trials of
2026-12-05/06 the robot walked the rest of the viewpoints after the last object was
placed for 18-144 s (median 46 s) of each trial, finding nothing. Perception knows what
its cameras have seen. Each frame it remembers (the detector ran on it in a search or
probing posture) counts a view of the cells of its depth returns (every ``stride``-th
pixel) within range of the camera that lie on the floor (below ``floor_max_z``) or on a
table top (within ``table_z``, seen from ``table_look_down`` above); a cell shown by
``min_views`` frames counts seen, and the task skips a viewpoint whose view the grid shows
seen. The range is where the detector finds the small objects reliably, not the depth
camera's reach: a cell counts only where an object in it would have been found.

The grid lies in the map frame (the node marks frames only while navigation publishes
the map->odom correction: a later correction moves nothing already marked) and grows as
cells are marked (no map size is assumed); cell (row, col) covers ``origin + resolution
* (col, row)`` to ``+ resolution``. Plain numpy, no transport.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.services.perception.point_cloud import lift_box

__all__ = ["FLOOR", "TABLE", "SeenArea", "SeenConfig"]

FLOOR, TABLE = 0, 1  # the two levels a cell is seen at (the node turns them into SeenGrid's bits)


@dataclass(frozen=True)
class SeenConfig:
    """What counts as seen, and how often the grid is published."""

    resolution: float = 0.1  # m per cell
    stride: int = 6  # every stride-th depth pixel, both ways
    front_range: float = 2.0  # m from the front camera: objects found reliably within it
    gripper_range: float = 1.5  # m from the gripper camera
    near: float = 0.2  # m: returns nearer the camera are the robot's own fingers
    self_radius: float = 0.35  # m about the base (horizontal): the robot's own trunk
    floor_max_z: float = 0.05  # m: returns lower than this lie on the floor
    table_z: tuple[float, float] = (0.3, 0.6)  # m: returns within lie on a table top
    # m: a table-top return counts only from a camera at least this much above it. The
    # front camera (0.33 m up) sees a 0.40 m table's underside (0.385 m, within table_z)
    # and marked up to a fifth of the kitchen table from one stance; the tops were
    # "seen" with no view of them, and paper-3 (2026-12-06) never found a padlock there.
    table_look_down: float = 0.15
    # frames that must show a cell before it counts seen: the memory confirms a track
    # after 3 detections, so a cell glimpsed once while walking past is not enough
    min_views: int = 3
    period: float = 1.0  # s between publications

    def __post_init__(self) -> None:
        if not (0.01 <= self.resolution <= 1.0):
            raise ValueError(f"SeenConfig.resolution must be in [0.01, 1] m: {self.resolution}")
        if self.stride < 1:
            raise ValueError(f"SeenConfig.stride must be >= 1: {self.stride}")
        if not 1 <= self.min_views <= 255:
            raise ValueError(f"SeenConfig.min_views must be in [1, 255]: {self.min_views}")
        if not self.table_z[0] < self.table_z[1]:
            raise ValueError(f"SeenConfig.table_z must be (low, high): {self.table_z}")
        if not self.table_look_down >= 0.0:
            raise ValueError(f"SeenConfig.table_look_down must be >= 0 m: {self.table_look_down}")


class SeenArea:
    """The grid of seen cells (``FLOOR`` and ``TABLE`` bits) in one planar frame."""

    def __init__(self, config: SeenConfig | None = None) -> None:
        self.config = config or SeenConfig()
        self.views = np.zeros((2, 0, 0), np.uint8)  # frames that showed each cell: floor, table
        self.last = np.zeros((2, 0, 0), np.float32)  # the stamp of each cell's latest view
        self.row0 = 0  # cell index (floor(y / resolution)) of row 0
        self.col0 = 0  # ... of column 0

    @property
    def origin(self) -> tuple[float, float]:
        """(x, y) of the corner of cell (0, 0)."""
        r = self.config.resolution
        return self.col0 * r, self.row0 * r

    def seen(self, level: int) -> np.ndarray:
        """Cells of ``level`` (``FLOOR``, ``TABLE``) shown by ``min_views`` frames."""
        return self.views[level] >= self.config.min_views

    def seen_at(self, level: int) -> np.ndarray:
        """The stamp of each cell's latest view at ``level`` (0: never)."""
        return self.last[level]

    def mark(self, points: np.ndarray, stamp: float = 0.0, camera_z: float = math.inf) -> int:
        """Count one frame's view (at ``stamp``) of the cells of ``points`` (N, 3; the
        grid's frame, z up from the floor) that lie on the floor or a table top (a camera
        at height ``camera_z`` sees a table's top only from ``table_look_down`` above it);
        returns how many cells this frame made seen (``min_views`` reached)."""
        cfg = self.config
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        z = p[:, 2]
        on_top = (z >= cfg.table_z[0]) & (z <= cfg.table_z[1])
        levels = (z < cfg.floor_max_z, on_top & (z <= camera_z - cfg.table_look_down))
        keep = levels[0] | levels[1]
        if not keep.any():
            return 0
        col = np.floor(p[:, 0] / cfg.resolution).astype(np.int64)
        row = np.floor(p[:, 1] / cfg.resolution).astype(np.int64)
        self._grow(int(row[keep].min()), int(row[keep].max()), int(col[keep].min()),
                   int(col[keep].max()))  # fmt: skip
        made = 0
        for k, on in enumerate(levels):
            if not on.any():
                continue
            # each cell once per frame
            cells = np.unique(np.stack([row[on] - self.row0, col[on] - self.col0]), axis=1)
            v = self.views[k][cells[0], cells[1]]
            made += int(np.count_nonzero(v == cfg.min_views - 1))
            self.views[k][cells[0], cells[1]] = np.minimum(v.astype(np.int32) + 1, 255)
            self.last[k][cells[0], cells[1]] = stamp
        return made

    def mark_frame(
        self,
        depth: np.ndarray,
        K: np.ndarray,
        position: np.ndarray,
        orientation: np.ndarray,
        reach: float,
        to_grid: np.ndarray,
        base_xy: np.ndarray,
        stamp: float = 0.0,
    ) -> int:
        """Mark what a depth image shows within ``reach`` (m along the optical axis): the
        camera pose (position, quaternion [w, x, y, z]) and the base's ``base_xy`` in odom,
        ``to_grid`` the planar transform (3x3) from odom into the grid's frame (map->odom's
        matrix). The robot's own fingers and trunk are not marked."""
        cfg = self.config
        h, w = np.asarray(depth).shape
        cloud = lift_box(depth, (0, 0, w, h), K, position, orientation, cfg.stride, reach)
        p = cloud.points
        own = np.linalg.norm(p - np.asarray(position, float), axis=1) < cfg.near
        own |= np.hypot(p[:, 0] - base_xy[0], p[:, 1] - base_xy[1]) < cfg.self_radius
        pts = p[~own]
        m = np.asarray(to_grid, dtype=float)
        pts[:, :2] = pts[:, :2] @ m[:2, :2].T + m[:2, 2]
        return self.mark(pts, stamp, float(np.asarray(position, float)[2]))

    def _grow(self, r_lo: int, r_hi: int, c_lo: int, c_hi: int) -> None:
        """Make the grid hold rows r_lo..r_hi and columns c_lo..c_hi (cell indices),
        with room to spare so a walk does not reallocate it every frame."""
        _, h, w = self.views.shape
        if h and w and r_lo >= self.row0 and c_lo >= self.col0:
            if r_hi < self.row0 + h and c_hi < self.col0 + w:
                return
        pad = max(int(math.ceil(1.0 / self.config.resolution)), 1)  # 1 m
        if h and w:
            r_lo, c_lo = min(r_lo, self.row0), min(c_lo, self.col0)
            r_hi, c_hi = max(r_hi, self.row0 + h - 1), max(c_hi, self.col0 + w - 1)
        nr0, nc0 = r_lo - pad, c_lo - pad
        shape = (2, r_hi - r_lo + 1 + 2 * pad, c_hi - c_lo + 1 + 2 * pad)
        views, last = np.zeros(shape, np.uint8), np.zeros(shape, np.float32)
        if h and w:
            r, c = self.row0 - nr0, self.col0 - nc0
            views[:, r : r + h, c : c + w] = self.views
            last[:, r : r + h, c : c + w] = self.last
        self.views, self.last, self.row0, self.col0 = views, last, nr0, nc0
