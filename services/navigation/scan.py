"""A LaserScan's returns as points: in the LiDAR's frame, then in the base frame.

The LiDAR's mount on the base (the ``lidar`` site of the robot description) is read once
from the description; navigation treats the scan as planar in the base's horizontal
plane (the trunk's roll and pitch stay within a few degrees while walking)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.grid import Pose2, transform_points

__all__ = [
    "ScanPoints",
    "lidar_height_above_base",
    "lidar_mount",
    "nearest_return",
    "scan_points",
]


def lidar_height_above_base() -> float:
    """Height (m) of the LiDAR above the base origin, from the robot description."""
    import mujoco
    from quadmanip.common import robot_description as rd

    model = rd.load_mujoco_model()
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, rd.LIDAR_SITE)
    return float(model.site_pos[sid][2])


def lidar_mount() -> Pose2:
    """(x, y, yaw) of the LiDAR in the base frame, from the robot description."""
    import mujoco
    from quadmanip.common import robot_description as rd

    model = rd.load_mujoco_model()
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, rd.LIDAR_SITE)
    if sid < 0:
        raise ValueError(f"the robot description has no {rd.LIDAR_SITE!r} site")
    # the site's pose relative to its body (the base); its yaw about z
    q = model.site_quat[sid]
    yaw = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
    p = model.site_pos[sid]
    return (float(p[0]), float(p[1]), float(yaw))


@dataclass(frozen=True)
class ScanPoints:
    """The valid returns of one scan: points (N, 2) in the base frame, their ranges and
    beam angles (LiDAR frame), the LiDAR's pose in the base frame and the scan's stamp."""

    stamp: float
    points: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    sensor: Pose2
    range_max: float


def scan_points(
    stamp: float,
    ranges: np.ndarray,
    angle_min: float,
    angle_increment: float,
    range_min: float,
    range_max: float,
    mount: Pose2 = (0.0, 0.0, 0.0),
    attitude: np.ndarray | None = None,
    height: float = 0.0,
    min_hit_height: float = 0.05,
) -> ScanPoints:
    """The returns (ranges within [range_min, range_max], finite) as base-frame points.

    With the trunk's ``attitude`` (3x3 rotation, base to a gravity-aligned frame) and the
    LiDAR's ``height`` above the floor, returns that hit lower than ``min_hit_height`` are
    dropped: when the trunk pitches or rolls a few degrees the tilted scan plane reaches
    the floor a few metres out, and those returns are not obstacles.
    """
    r = np.asarray(ranges, dtype=float)
    a = angle_min + angle_increment * np.arange(len(r))
    ok = np.isfinite(r) & (r >= max(range_min, 1e-6)) & (r <= range_max)
    if attitude is not None and height > 0.0:
        R = np.asarray(attitude, dtype=float)
        # beam direction in the base frame (the mount's yaw), its vertical component
        ab = a + mount[2]
        rise = R[2, 0] * np.cos(ab) + R[2, 1] * np.sin(ab)
        ok &= height + np.where(np.isfinite(r), r, 0.0) * rise >= min_hit_height
    r, a = r[ok], a[ok]
    local = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    return ScanPoints(float(stamp), transform_points(mount, local), r, a, mount, float(range_max))


def nearest_return(points: np.ndarray) -> tuple[float, float] | None:
    """(distance m, bearing rad) from the base of the nearest return (base-frame points,
    N x 2), or None without returns: said when a walk ends blocked, so a log shows what
    was in the way (paper-4, 2026-12-05: six walks ended "no progress" with nothing in
    the log to say why)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if pts.shape[0] == 0:
        return None
    d = np.hypot(pts[:, 0], pts[:, 1])
    i = int(np.argmin(d))
    return float(d[i]), float(np.arctan2(pts[i, 1], pts[i, 0]))
