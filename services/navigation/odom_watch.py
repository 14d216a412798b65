"""Odometry that starts again in a new frame: the jump a restart of locomotion makes.

A new locomotion process counts its odometry from its own origin, so the odom pose jumps
by metres in one step while the robot lies still (its legs damped). Taken for motion, that
jump moves every particle of the localiser and the robot is lost; navigation instead
rebases the localiser on the new frame (:meth:`.amcl.Amcl.rebase`). A jump is an odometry
step farther (or turned more) than the robot can move in the time between the two poses,
with a floor for the noise of one step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from quadmanip.services.navigation.grid import Pose2, wrap

__all__ = ["OdomJumpConfig", "odometry_jumped"]


@dataclass(frozen=True)
class OdomJumpConfig:
    """Thresholds of :func:`odometry_jumped`."""

    distance: float = 0.3  # m: a step this long is a jump at any speed
    angle: float = 0.5  # rad: a turn this large is a jump at any speed
    speed: float = 1.0  # m/s: faster than the robot walks
    turn_rate: float = 2.0  # rad/s: faster than it turns
    max_gap: float = 0.5  # s: a longer gap between the two poses counts as this long


def odometry_jumped(
    before: Pose2, t_before: float, after: Pose2, t_after: float, cfg: OdomJumpConfig
) -> bool:
    """Whether odometry went from ``before`` (robot time ``t_before``) to ``after``
    (``t_after``) by a jump rather than by motion. The gap is capped at ``max_gap``: while
    locomotion is away the robot lies still, however long that takes."""
    dt = min(max(t_after - t_before, 0.0), cfg.max_gap)
    moved = math.hypot(after[0] - before[0], after[1] - before[1])
    turned = abs(wrap(after[2] - before[2]))
    return moved > cfg.distance + cfg.speed * dt or turned > cfg.angle + cfg.turn_rate * dt
