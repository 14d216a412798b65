"""Planar frames of the task: map, odom and the robot's level body frame.

The task reasons in the ``map`` frame (the places file, navigation's pose, perception's
tracks); navigation's ``approach`` takes odom targets, and manipulation's goals are in the
*level* body frame (the base's position and heading, z up), which is what perception's
grasp estimates are in too. ``MapPose.map_to_odom`` (x, y, yaw) takes an odometry pose into
the map: ``p_map = T(map_to_odom) p_odom``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "BasePose",
    "Point3",
    "Pose2",
    "base_from_odom",
    "carried_over",
    "compose",
    "invert",
    "map_from_odom",
    "odom_from_base",
    "odom_from_map",
    "transform_point",
    "wrap",
]

Pose2 = tuple[float, float, float]
"""x, y (m), yaw (rad)."""
Point3 = tuple[float, float, float]


@dataclass(frozen=True)
class BasePose:
    """The base in the odom frame: position (m) and heading (rad), from odometry."""

    x: float
    y: float
    z: float
    yaw: float


def wrap(a: float) -> float:
    """An angle in [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def compose(a: Pose2, b: Pose2) -> Pose2:
    """The pose ``b`` (given in frame ``a``) in ``a``'s parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def invert(a: Pose2) -> Pose2:
    """The inverse transform of ``a``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap(-a[2]))


def transform_point(pose: Pose2, p: Point3) -> Point3:
    """Point ``p`` of frame ``pose`` in the parent frame (z unchanged: frames are level)."""
    x, y, _ = compose(pose, (p[0], p[1], 0.0))
    return (x, y, p[2])


def odom_from_map(map_to_odom: Pose2, p: Point3) -> Point3:
    """A map point in the odom frame."""
    return transform_point(invert(map_to_odom), p)


def map_from_odom(map_to_odom: Pose2, p: Point3) -> Point3:
    """An odom point in the map frame."""
    return transform_point(map_to_odom, p)


def base_from_odom(base: BasePose, p: Point3) -> Point3:
    """An odom point in the level body frame of ``base`` (z relative to the base)."""
    x, y, _ = transform_point(invert((base.x, base.y, base.yaw)), (p[0], p[1], 0.0))
    return (x, y, p[2] - base.z)


def odom_from_base(base: BasePose, p: Point3) -> Point3:
    """A point of the level body frame of ``base`` in the odom frame."""
    x, y, _ = transform_point((base.x, base.y, base.yaw), (p[0], p[1], 0.0))
    return (x, y, p[2] + base.z)


def carried_over(
    position: Point3, yaw: float, then: BasePose, now: BasePose
) -> tuple[Point3, float]:
    """A grasp (position and yaw in the level body frame of ``then``) expressed in the
    level body frame of ``now``: the robot stepped in between (odometry, not ground truth;
    over a step of a few decimetres its drift is millimetres)."""
    return base_from_odom(now, odom_from_base(then, position)), wrap(yaw + then.yaw - now.yaw)
