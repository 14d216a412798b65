"""The objects perception has seen on the floor, as obstacles for the planner.

The LiDAR's plane lies 0.375 m above the floor: the household objects the robot tidies are
below it, and the map and the obstacle layer do not hold them. A cracker box standing in
the living room's path to the doorway was found lying (0.06 m tall on a 0.16 x 0.21 m
face, wider than the gripper opens) in two runs of seed-103 and never tidied: the planner
had sent the robot's walks to the kitchen right over it (seed-110 lost one 0.13 m from
there, never grasped). Nav2 adds such
obstacles from a depth camera's point cloud; here perception already keeps them (its
object memory, ``perception/objects``), so the costmap takes a disc per confirmed floor
object instead.

Which tracks become discs (:func:`floor_obstacles`): confirmed, centroid lower than
``max_height`` (a table's objects lie under no path), inside one of the floor zones where
objects are searched (false detections elsewhere, e.g. in a doorway, would close it), and
not near the robot or the walk's goal (the object it handles, holds or walks up to).
During a walk "near the robot" means near where the walk started (the node passes those
tracks as ``exempt`` and no ``robot_xy``): an object the walk passes is an obstacle all
the way. Tested against the robot's pose at every scan, the disc of a standing cracker
box vanished as the robot came within 0.6 m of it, the path was planned through it again
and the trunk knocked it over (paper-1, 2026-12-06; seed-118 lost its cracker box so).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Disc", "ObjectLayerConfig", "floor_obstacles"]

Disc = tuple[float, float, float]  # x, y, radius (m, map frame)


@dataclass(frozen=True)
class ObjectLayerConfig:
    """Which of perception's tracks the costmap holds, and how large."""

    enabled: bool = True
    max_height: float = 0.3  # m: centroids lower than this lie on the floor (tables: 0.4 m)
    margin: float = 0.05  # m: added to half the object's larger horizontal extent
    min_radius: float = 0.05  # m
    max_radius: float = 0.2  # m: a larger extent is clipped (a track that merged two views)
    near_robot: float = 0.6  # m: tracks this near the robot are what it handles or holds
    near_goal: float = 0.5  # m: ... or what a walk goes up to (walks end 0.6-1.0 m short)
    zone_margin: float = 0.3  # m: around the floor zones


def floor_obstacles(
    centroids: np.ndarray,
    extents: np.ndarray,
    confirmed: np.ndarray,
    zones: Sequence[tuple[float, float, float, float]],
    robot_xy: tuple[float, float] | None,
    goal_xy: tuple[float, float] | None,
    cfg: ObjectLayerConfig,
    exempt: np.ndarray | None = None,
) -> list[Disc]:
    """Discs (map frame) for the tracks with map-frame ``centroids`` (N, 3) and
    ``extents`` (N, 3) that count as floor obstacles (the module docstring says which);
    ``zones`` are (x_min, y_min, x_max, y_max) areas; ``exempt`` (N,) marks tracks that
    are none, and without ``robot_xy`` no track is left out for lying near the robot."""
    if not cfg.enabled:
        return []
    c = np.asarray(centroids, dtype=float).reshape(-1, 3)
    e = np.asarray(extents, dtype=float).reshape(-1, 3)
    ok = np.asarray(confirmed, dtype=bool).reshape(-1)
    if exempt is not None:
        ok = ok & ~np.asarray(exempt, dtype=bool).reshape(-1)
    if not (len(c) == len(e) == len(ok)):
        raise ValueError(f"centroids {len(c)}, extents {len(e)}, confirmed {len(ok)} differ")
    out: list[Disc] = []
    m = cfg.zone_margin
    for (x, y, z), ext, conf in zip(c, e, ok, strict=True):
        if not conf or not (math.isfinite(x) and math.isfinite(y)) or z >= cfg.max_height:
            continue
        if not any(x0 - m <= x <= x1 + m and y0 - m <= y <= y1 + m for x0, y0, x1, y1 in zones):
            continue
        if robot_xy is not None and math.hypot(x - robot_xy[0], y - robot_xy[1]) < cfg.near_robot:
            continue
        if goal_xy is not None and math.hypot(x - goal_xy[0], y - goal_xy[1]) < cfg.near_goal:
            continue
        r = 0.5 * float(max(ext[0], ext[1])) + cfg.margin
        out.append((float(x), float(y), min(max(r, cfg.min_radius), cfg.max_radius)))
    return out
