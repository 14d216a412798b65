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
not near the walk's goal (what it walks up to) nor what the robot handles or holds where
a walk begins (:func:`handled`; the node passes those tracks as ``exempt``): an object the
walk passes is an obstacle all the way. Tested against the robot's pose at every scan,
the disc of a standing cracker box vanished as the robot came within 0.6 m of it, the
path was planned through it again and the trunk knocked it over (paper-1, 2026-12-06;
seed-118 lost its cracker box so). Standing or in an approach every track is a disc (an
approach's stance check leaves its own target out): until 2026-12-07 those within 0.6 m
of the robot were none, and a stance's way past a cracker box standing 0.58 m from the
robot was taken as clear (paper-4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from quadmanip.common.rotations import wrap_angle

__all__ = ["Disc", "ObjectLayerConfig", "floor_obstacles", "handled"]

Disc = tuple[float, float, float]  # x, y, radius (m, map frame)


@dataclass(frozen=True)
class ObjectLayerConfig:
    """Which of perception's tracks the costmap holds, and how large."""

    enabled: bool = True
    max_height: float = 0.3  # m: centroids lower than this lie on the floor (tables: 0.4 m)
    margin: float = 0.05  # m: added to half the object's larger horizontal extent
    min_radius: float = 0.05  # m
    max_radius: float = 0.2  # m: a larger extent is clipped (a track that merged two views)
    # what the robot handles or holds where a walk begins (:func:`handled`): a track this
    # near and within near_bearing of its heading (the object it probed, failed to grasp or
    # holds lies ahead, in the gripper's reach: 0.35-0.51 m, a few degrees off), or one
    # this near the trunk whatever the bearing. A neighbour is not: paper-4 (2026-12-07), a
    # cracker box 0.53 m away, 46 deg to the side of the padlock just grasped, was left
    # out of the walk that turned away from it
    near_robot: float = 0.6  # m
    near_bearing: float = 0.5  # rad
    near_trunk: float = 0.3  # m
    near_goal: float = 0.5  # m: ... or what a walk goes up to (walks end 0.6-1.0 m short)
    zone_margin: float = 0.3  # m: around the floor zones


def floor_obstacles(
    centroids: np.ndarray,
    extents: np.ndarray,
    confirmed: np.ndarray,
    zones: Sequence[tuple[float, float, float, float]],
    goal_xy: tuple[float, float] | None,
    cfg: ObjectLayerConfig,
    exempt: np.ndarray | None = None,
) -> list[Disc]:
    """Discs (map frame) for the tracks with map-frame ``centroids`` (N, 3) and
    ``extents`` (N, 3) that count as floor obstacles (the module docstring says which);
    ``zones`` are (x_min, y_min, x_max, y_max) areas; ``exempt`` (N,) marks tracks that
    are none (what the robot handles or holds, :func:`handled`)."""
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
        if goal_xy is not None and math.hypot(x - goal_xy[0], y - goal_xy[1]) < cfg.near_goal:
            continue
        r = 0.5 * float(max(ext[0], ext[1])) + cfg.margin
        out.append((float(x), float(y), min(max(r, cfg.min_radius), cfg.max_radius)))
    return out


def handled(xy: np.ndarray, pose: tuple[float, float, float], cfg: ObjectLayerConfig) -> np.ndarray:
    """Which of the tracks at map-frame ``xy`` (N, 2) a robot at ``pose`` (x, y, yaw)
    handles or holds (the config's ``near_robot``, ``near_bearing``, ``near_trunk``)."""
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    dx, dy = p[:, 0] - pose[0], p[:, 1] - pose[1]
    dist = np.hypot(dx, dy)
    off = np.abs(wrap_angle(np.arctan2(dy, dx) - pose[2]))
    return (dist < cfg.near_trunk) | ((dist < cfg.near_robot) & (off <= cfg.near_bearing))
