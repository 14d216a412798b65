"""The last centimetres, standing: small velocities that shift the trunk over its feet.

Locomotion treats a velocity command within the trot's deadband, sent while the robot
stands, as a nudge: the standing trunk moves at that velocity over its feet, without a
step, up to a few centimetres (locomotion's ``nudge_speed``, ``nudge_reach``,
``nudge_turn``). A trot cannot make such small moves: a stop and go of 0.4 s at 3 cm/s
moved the trunk 5-16 mm, often not the way it was told (measured in-process), so the
approach and the final alignment of ``navigate_to`` finish by nudges once the robot
stands near its goal. This module is their shared rule: proportional on the pose error,
each linear component below the nudge speed, and a patience after which the robot must
step again (the trunk has reached the end of its reach).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NudgeConfig", "StandingNudge"]


@dataclass(frozen=True)
class NudgeConfig:
    """When and how a standing robot is nudged onto its goal."""

    range: float = 0.03  # m: a standing robot this near its goal shifts its trunk
    turn: float = 0.03  # rad: ... and this near its heading
    speed: float = 0.018  # m/s per axis: below locomotion's nudge_speed (no step)
    wz: float = 0.045  # rad/s: below locomotion's nudge_wz
    gain: float = 1.5  # 1/s on the pose error
    patience: float = 3.0  # s of nudging without arriving: then step again


class StandingNudge:
    """The nudge toward a goal, while the robot stands near it."""

    def __init__(self, config: NudgeConfig | None = None):
        self.config = config or NudgeConfig()
        self.reset()

    def reset(self) -> None:
        """A new goal: the full patience again."""
        self._nudged = 0.0  # s nudging since the robot last stepped

    def command(
        self, error: np.ndarray | tuple[float, float, float], standing: bool | None, dt: float
    ) -> tuple[float, float, float] | None:
        """(vx, vy, wz) for the base-frame pose ``error`` (ex, ey, eyaw), or None where the
        robot must step: not standing (None: unknown), too far, or out of patience."""
        cfg = self.config
        e = np.asarray(error, dtype=float)
        if not standing:
            if standing is False:
                self._nudged = 0.0  # a step re-centres the trunk over its feet
            return None
        if np.hypot(e[0], e[1]) > cfg.range or abs(e[2]) > cfg.turn:
            return None
        if self._nudged > cfg.patience:
            return None
        self._nudged += dt
        v = cfg.gain * e
        over = max(abs(v[0]) / cfg.speed, abs(v[1]) / cfg.speed, 1.0)  # keep the direction
        wz = float(np.clip(v[2], -cfg.wz, cfg.wz))
        return float(v[0] / over), float(v[1] / over), wz
