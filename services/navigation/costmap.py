"""A layered 2D costmap for planning and control (paper Section 5.2's move_base costmap,
in the layering of ROS navigation / Nav2: static, obstacle, inflation).

- static layer: the SLAM map's occupied cells (value >= ``occupied_threshold``); unknown
  cells (-1) count as lethal when ``unknown_is_lethal`` (the planner must not route through
  space nobody has seen); plus the places file's keepout areas (``with_keepouts``).
- obstacle layer: the current LiDAR's returns. Each update marks the returns within
  ``obstacle_range`` and clears the cells every beam passed through, so a chair that went
  away disappears once a beam sees through its place; an optional persistence forgets
  cells nobody has re-observed for a while.
- object layer: discs at the objects perception has seen on the floor, below the LiDAR's
  plane (:meth:`Costmap.set_objects`, chosen by :mod:`.object_layer`).
- inflation: the exact Euclidean distance transform of the lethal cells (scipy) gives each
  cell's clearance; cells closer than ``robot_radius`` (the inscribed radius: the robot's
  centre may not go there) are 253, and a cost that decays exponentially out to
  ``inflation_radius`` keeps paths off the walls. An obstacle update rebuilds only the
  window it touched (padded by the largest distance any cell reads), so a rebuild takes a
  few milliseconds on a house-sized map.

Cost values follow Nav2: 0 free ... 252 inflated, 253 inscribed, 254 lethal, 255 unknown.
Clearances are distances from a cell's centre to the nearest lethal cell's edge (the EDT's
centre-to-centre distance less half a cell).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.grid import GridGeometry, Pose2
from scipy import ndimage

__all__ = [
    "FREE",
    "INFLATED_MAX",
    "INSCRIBED",
    "LETHAL",
    "UNKNOWN",
    "Costmap",
    "CostmapConfig",
    "area_mask",
    "with_keepouts",
]

FREE = 0
INFLATED_MAX = 252
INSCRIBED = 253
LETHAL = 254
UNKNOWN = 255


@dataclass(frozen=True)
class CostmapConfig:
    """Costmap parameters. The footprint defaults come from the robot description: trunk
    0.419 x 0.2505 m, feet 0.155 m (+ 0.02 m sole) out from the centre line. The robot
    radius is the circle the trunk sweeps turning in place (half its diagonal, 0.24 m)
    plus a margin: with only the feet's half width (0.19 m) the planner let the robot stand
    beside the sofa, and its in-place turn there knocked it over in a mapping run."""

    occupied_threshold: int = 65
    unknown_is_lethal: bool = True
    robot_radius: float = 0.28  # m: see the class docstring
    inflation_radius: float = 0.7  # m: cost falls to 0 beyond this clearance
    cost_scaling: float = 5.0  # 1/m: cost = 252 exp(-k (d - robot_radius))
    clearance_max: float = 1.0  # m: clearances read at most this (and the rebuild pad)
    obstacle_range: float = 4.0  # m: returns nearer than this mark obstacles
    raytrace_range: float = 8.0  # m: beams clear the cells they pass up to this range
    obstacle_persistence: float = 0.0  # s: forget unseen obstacle cells (0: never)
    footprint_length: float = 0.419  # m: trunk
    footprint_width: float = 0.2505  # m: trunk
    footprint_margin: float = 0.06  # m: feet stick out ~0.05 m sideways, plus slack


def area_mask(
    geometry: GridGeometry, areas: Sequence[tuple[float, float, float, float]]
) -> np.ndarray:
    """The grid's cells that an area (x_min, y_min, x_max, y_max, map frame) overlaps."""
    out = np.zeros(geometry.shape, dtype=bool)
    res = geometry.resolution
    for x0, y0, x1, y1 in areas:
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"area {(x0, y0, x1, y1)}: want x_min < x_max, y_min < y_max")
        c0 = max(int(math.floor((x0 - geometry.origin_x) / res)), 0)
        c1 = min(int(math.ceil((x1 - geometry.origin_x) / res)), geometry.width)
        r0 = max(int(math.floor((y0 - geometry.origin_y) / res)), 0)
        r1 = min(int(math.ceil((y1 - geometry.origin_y) / res)), geometry.height)
        if c1 > c0 and r1 > r0:
            out[r0:r1, c0:c1] = True
    return out


def with_keepouts(
    occupancy: np.ndarray,
    geometry: GridGeometry,
    areas: Sequence[tuple[float, float, float, float]],
) -> np.ndarray:
    """A copy of the map's ``occupancy`` (int8, 0..100, -1 unknown) with every cell that
    an area (x_min, y_min, x_max, y_max, map frame) overlaps occupied (100): the static
    layer of places the LiDAR sees only in part, such as a table whose top lies above
    the scan (the places file's ``keepout``; paper-4: every walk from the kitchen
    table's far side to the boxes was planned between its legs, under the top)."""
    out = np.array(occupancy, copy=True)
    out[area_mask(geometry, areas)] = 100
    return out


class Costmap:
    """Static + obstacle layers and their inflation on one grid (the map frame)."""

    def __init__(
        self,
        config: CostmapConfig,
        static_occupancy: np.ndarray,
        geometry: GridGeometry,
    ) -> None:
        occ = np.asarray(static_occupancy)
        if occ.shape != geometry.shape:
            raise ValueError(f"occupancy shape {occ.shape} != grid shape {geometry.shape}")
        if config.robot_radius <= 0 or config.inflation_radius < config.robot_radius:
            raise ValueError("need 0 < robot_radius <= inflation_radius")
        self.config = config
        self.geometry = geometry
        self.static_lethal = occ >= config.occupied_threshold
        self.unknown = occ < 0
        self.obstacles = np.zeros(geometry.shape, dtype=bool)
        self.objects = np.zeros(geometry.shape, dtype=bool)
        self._seen = np.full(geometry.shape, -np.inf)
        self._cap = max(config.clearance_max, config.inflation_radius)
        self._pad = int(math.ceil(self._cap / geometry.resolution)) + 2
        self.distance = np.zeros(geometry.shape, dtype=np.float32)
        self.cost = np.zeros(geometry.shape, dtype=np.uint8)
        self.version = 0
        """Incremented whenever ``cost`` changes (planners cache their graphs on it)."""
        self.last_rebuild_ms = 0.0
        self._rebuild(None)

    # ------------------------------------------------------------------ layers

    @property
    def occupied(self) -> np.ndarray:
        """Cells something stands in: static + obstacle + object layers."""
        return self.static_lethal | self.obstacles | self.objects

    @property
    def lethal(self) -> np.ndarray:
        """Cells the robot's body may not overlap: the occupied ones (+ unknown)."""
        return self._lethal_with(self.objects)

    def _lethal_with(self, objects: np.ndarray) -> np.ndarray:
        """:attr:`lethal` with ``objects`` as the object layer."""
        m = self.static_lethal | self.obstacles | objects
        if self.config.unknown_is_lethal:
            m = m | self.unknown
        return m

    def lethal_except_near(self, xy: tuple[float, float], radius: float) -> np.ndarray:
        """:attr:`lethal` without the object layer's cells within ``radius`` of ``xy``
        (the object an approach goes to is no obstacle to it)."""
        return self._lethal_with(self.objects_except_near(xy, radius))

    def objects_except_near(self, xy: tuple[float, float], radius: float) -> np.ndarray:
        """The object layer without its cells within ``radius`` of ``xy``."""
        objects = self.objects.copy()
        disc = self._disc(xy, radius)
        if disc is not None:
            win, near = disc
            objects[win] &= ~near
        return objects

    def _disc(
        self, xy: tuple[float, float], radius: float
    ) -> tuple[tuple[slice, slice], np.ndarray] | None:
        """The grid window around the disc of ``radius`` about ``xy`` and the mask of its
        cells whose centres lie in the disc; None when the disc misses the grid."""
        geo = self.geometry
        rows, cols = geo.to_cell(np.array([[xy[0] - radius, xy[1] - radius],
                                           [xy[0] + radius, xy[1] + radius]]))  # fmt: skip
        r0, c0 = max(int(rows[0]), 0), max(int(cols[0]), 0)
        r1, c1 = min(int(rows[1]), geo.height - 1), min(int(cols[1]), geo.width - 1)
        if r0 > r1 or c0 > c1:
            return None
        rr, cc = np.mgrid[r0 : r1 + 1, c0 : c1 + 1]
        centres = geo.cell_center(rr.ravel(), cc.ravel()) - (xy[0], xy[1])
        near = (np.hypot(centres[:, 0], centres[:, 1]) <= radius).reshape(rr.shape)
        return (slice(r0, r1 + 1), slice(c0, c1 + 1)), near

    def update_obstacles(
        self,
        points_map: np.ndarray,
        sensor_pose: Pose2,
        stamp: float | None = None,
        clear_to: np.ndarray | None = None,
    ) -> None:
        """Fold one scan into the obstacle layer: clear every cell a beam passed through
        (sensor to one cell short of its return, or to ``clear_to`` for beams without a
        return, both up to ``raytrace_range``), then mark the returns within
        ``obstacle_range``. ``stamp`` (s) drives the optional persistence."""
        cfg, geo = self.config, self.geometry
        pts = np.asarray(points_map, dtype=float).reshape(-1, 2)
        s = np.array(sensor_pose[:2], dtype=float)
        before = self.obstacles.copy()
        ends = pts if clear_to is None else np.vstack([pts, np.asarray(clear_to).reshape(-1, 2)])
        stop_short = np.r_[np.full(len(pts), geo.resolution), np.zeros(len(ends) - len(pts))]
        self._raytrace_clear(s, ends, stop_short)
        if len(pts):
            r = np.hypot(*(pts - s).T)
            mark = pts[r <= cfg.obstacle_range]
            rows, cols = geo.to_cell(mark)
            ok = geo.inside(rows, cols)
            self.obstacles[rows[ok], cols[ok]] = True
            if stamp is not None:
                self._seen[rows[ok], cols[ok]] = stamp
        if stamp is not None and cfg.obstacle_persistence > 0:
            self.obstacles &= self._seen >= stamp - cfg.obstacle_persistence
        changed = before != self.obstacles
        if changed.any():
            rr, cc = np.nonzero(changed)
            self._rebuild((int(rr.min()), int(rr.max()) + 1, int(cc.min()), int(cc.max()) + 1))

    def set_objects(self, discs: Sequence[tuple[float, float, float]]) -> bool:
        """Replace the object layer by ``discs`` (x, y, radius; map frame): the cells whose
        centres lie within a disc. Rebuilds only the window that changed; True if any did."""
        geo = self.geometry
        new = np.zeros(geo.shape, dtype=bool)
        for x, y, r in discs:
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(r) and r > 0.0):
                raise ValueError(f"object disc {(x, y, r)}: want finite x, y and r > 0")
            rows, cols = geo.to_cell(np.array([[x - r, y - r], [x + r, y + r]]))
            r0, c0 = max(int(rows[0]), 0), max(int(cols[0]), 0)
            r1, c1 = min(int(rows[1]) + 1, geo.height), min(int(cols[1]) + 1, geo.width)
            if r1 <= r0 or c1 <= c0:
                continue
            rr, cc = np.mgrid[r0:r1, c0:c1]
            centres = geo.cell_center(rr.ravel(), cc.ravel())
            inside = np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= r
            new[rr.ravel()[inside], cc.ravel()[inside]] = True
        changed = new != self.objects
        if not changed.any():
            return False
        self.objects = new
        rr, cc = np.nonzero(changed)
        self._rebuild((int(rr.min()), int(rr.max()) + 1, int(cc.min()), int(cc.max()) + 1))
        return True

    def forget_unseen_near(self, xy: tuple[float, float], radius: float, before: float) -> int:
        """Clear the obstacle cells within ``radius`` of ``xy`` last marked before the
        stamp ``before`` (those marked without a stamp count as never seen); returns how
        many. For marks the LiDAR cannot confirm from where the robot stands (Nav2's
        clear-costmap recovery, here limited to a goal's surroundings)."""
        disc = self._disc(xy, radius)
        if disc is None:
            return 0
        win, near = disc
        stale = near & self.obstacles[win] & (self._seen[win] < before)
        n = int(stale.sum())
        if n:
            self.obstacles[win] &= ~stale
            self._rebuild((win[0].start, win[0].stop, win[1].start, win[1].stop))
        return n

    def obstacle_age_near(self, xy: tuple[float, float], radius: float, now: float) -> float | None:
        """Seconds since the freshest obstacle-layer mark within ``radius`` of ``xy`` was
        made (inf when marked without a stamp), or None when there is none."""
        disc = self._disc(xy, radius)
        if disc is None:
            return None
        win, near = disc
        marked = near & self.obstacles[win]
        if not marked.any():
            return None
        return float(now - self._seen[win][marked].max())

    def clear_obstacles(self) -> None:
        """Forget the obstacle layer (e.g. after relocalisation)."""
        if self.obstacles.any():
            self.obstacles[:] = False
            self._rebuild(None)

    def _raytrace_clear(self, s: np.ndarray, ends: np.ndarray, stop_short: np.ndarray) -> None:
        if not len(ends):
            return
        geo = self.geometry
        d = ends - s
        r = np.hypot(d[:, 0], d[:, 1])
        ok = r > 1e-6
        d, r, short = d[ok], r[ok], stop_short[ok]
        reach = np.minimum(r - short, self.config.raytrace_range)
        step = 0.5 * geo.resolution
        n = np.maximum(np.floor(reach / step).astype(np.int64) + 1, 0)
        n[reach <= 0] = 0
        total = int(n.sum())
        if total == 0:
            return
        beam = np.repeat(np.arange(len(n)), n)
        k = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
        t = k * step / r[beam]
        xy = s + d[beam] * t[:, None]
        rows, cols = geo.to_cell(xy)
        inside = geo.inside(rows, cols)
        self.obstacles[rows[inside], cols[inside]] = False

    # --------------------------------------------------------------- inflation

    def _rebuild(self, window: tuple[int, int, int, int] | None) -> None:
        """Recompute distance and cost in the changed window padded by the largest
        distance read; the EDT runs over that, padded once more (its nearest obstacles)."""

        t0 = time.perf_counter()
        h, w = self.geometry.shape
        if window is None:
            tgt = (0, h, 0, w)
        else:
            r0, r1, c0, c1 = window
            p = self._pad
            tgt = (max(r0 - p, 0), min(r1 + p, h), max(c0 - p, 0), min(c1 + p, w))
        p = self._pad
        src = (max(tgt[0] - p, 0), min(tgt[1] + p, h), max(tgt[2] - p, 0), min(tgt[3] + p, w))
        lethal = self.lethal[src[0] : src[1], src[2] : src[3]]
        res = self.geometry.resolution
        if lethal.any():
            edt = ndimage.distance_transform_edt(~lethal) * res
            d = np.where(lethal, 0.0, np.maximum(edt - 0.5 * res, 0.0))
        else:
            d = np.full(lethal.shape, self._cap)
        d = np.minimum(d, self._cap)
        sl = (slice(tgt[0] - src[0], tgt[1] - src[0]), slice(tgt[2] - src[2], tgt[3] - src[2]))
        d = d[sl]
        t = (slice(tgt[0], tgt[1]), slice(tgt[2], tgt[3]))
        self.distance[t] = d
        hard = self.occupied[t]
        self.cost[t] = self._cost_of(d, hard, self.unknown[t])
        self.version += 1
        self.last_rebuild_ms = (time.perf_counter() - t0) * 1e3

    def _cost_of(self, d: np.ndarray, hard: np.ndarray, unknown: np.ndarray) -> np.ndarray:
        """Costs from clearances: occupied (map or LiDAR) 254, unknown 255, else by d."""
        cfg = self.config
        decay = INFLATED_MAX * np.exp(-cfg.cost_scaling * (d - cfg.robot_radius))
        c = np.where(d <= cfg.inflation_radius, np.clip(np.rint(decay), 1, INFLATED_MAX), 0)
        c = np.where(d <= cfg.robot_radius, INSCRIBED, c)
        c = np.where(unknown, UNKNOWN, c)
        c = np.where(hard, LETHAL, c)
        return c.astype(np.uint8)

    # ------------------------------------------------------------------ queries

    def cost_at(self, xy: np.ndarray) -> np.ndarray:
        """Cost (uint8) of the cells holding points (N, 2); off the map reads LETHAL."""
        rows, cols = self.geometry.to_cell(xy)
        inside = self.geometry.inside(rows, cols)
        out = np.full(len(rows), LETHAL, dtype=np.uint8)
        out[inside] = self.cost[rows[inside], cols[inside]]
        return out

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m) from points (N, 2) to the nearest lethal cell, bilinearly
        interpolated, capped at ``max(clearance_max, inflation_radius)``; 0 off the map."""
        rc = self.geometry.to_fractional(xy)
        return ndimage.map_coordinates(
            self.distance, rc.T, order=1, mode="constant", cval=0.0
        ).astype(float)

    def is_traversable(self, xy: np.ndarray) -> np.ndarray:
        """Whether the robot's centre may stand at points (N, 2): below the inscribed
        cost, and not unknown when unknown space is lethal."""
        c = self.cost_at(xy)
        ok = c < INSCRIBED
        if not self.config.unknown_is_lethal:
            ok |= c == UNKNOWN
        return ok

    def footprint_free(
        self, pose: Pose2, margin: float | None = None, lethal: np.ndarray | None = None
    ) -> bool:
        """Whether the oriented trunk rectangle (+ ``margin``, default the footprint
        margin, + half a cell for the cells' extent) at ``pose`` overlaps no lethal cell
        (of ``lethal``, a mask of the grid's shape, when given). Tighter than the inscribed
        circle for in-place turns and the final approach beside furniture."""
        cfg, geo = self.config, self.geometry
        pad = cfg.footprint_margin if margin is None else margin
        hx = 0.5 * cfg.footprint_length + pad + 0.5 * geo.resolution
        hy = 0.5 * cfg.footprint_width + pad + 0.5 * geo.resolution
        rad = math.hypot(hx, hy)
        x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2])
        if lethal is None and self.clearance(np.array([[x, y]]))[0] > rad + geo.resolution:
            return True
        mask = self.lethal if lethal is None else lethal
        (r0, r1), (c0, c1) = (
            geo.to_cell(np.array([[x - rad, y - rad], [x + rad, y + rad]]))[i] for i in (0, 1)
        )
        if r0 < 0 or c0 < 0 or r1 >= geo.height or c1 >= geo.width:
            return False  # the footprint reaches off the map
        rr, cc = np.nonzero(mask[r0 : r1 + 1, c0 : c1 + 1])
        if not len(rr):
            return True
        centres = geo.cell_center(rr + r0, cc + c0) - (x, y)
        c, s = math.cos(yaw), math.sin(yaw)
        lx = c * centres[:, 0] + s * centres[:, 1]
        ly = -s * centres[:, 0] + c * centres[:, 1]
        return not bool(np.any((np.abs(lx) <= hx) & (np.abs(ly) <= hy)))
