"""The safety checker: trips a latched safe mode when the robot is falling or overloaded.

Like legged_control's SafetyChecker and the protection layer of commercial quadrupeds, it
watches what the robot measures (IMU orientation, joint encoders and motor torques, the
trunk height from leg kinematics) and trips on:

* roll or pitch beyond ``max_roll`` / ``max_pitch`` (a fall: checked every tick, so a
  tip-over is caught at the tick the limit is crossed);
* the trunk lower than ``min_height`` above the feet for ``low_height_time`` (legs
  buckling under it);
* a joint beyond its range (the description's) by more than ``joint_margin``;
* a motor at ``torque_fraction`` of its limit for ``saturation_time`` without a break
  (a leg pushing against something it cannot move, or a controller that went unstable).

The checker only decides; the controller latches the trip (legs damped, the reason kept)
until an explicit ``recover`` command. Limits: ``[safety]`` of configs/locomotion.toml.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SafetyLimits:
    """When the safety checker trips ([safety] table)."""

    max_roll: float = 0.6  # rad (34°): well past any commanded roll (limits.roll 0.3)
    max_pitch: float = 0.6  # rad
    min_height: float = 0.12  # m, trunk above the lowest foot (deepest crouch: 0.16)
    low_height_time: float = 0.3  # s below min_height before tripping
    joint_margin: float = 0.1  # rad beyond the description's joint range
    torque_fraction: float = 0.98  # of the motor's torque limit counts as saturated
    saturation_time: float = 0.5  # s of uninterrupted saturation before tripping

    def __post_init__(self) -> None:
        if not (0.0 < self.max_roll < math.pi and 0.0 < self.max_pitch < math.pi):
            raise ValueError("safety max_roll and max_pitch must be in (0, pi) rad")
        if self.min_height < 0.0 or self.low_height_time < 0.0 or self.saturation_time < 0.0:
            raise ValueError("safety heights and times must be >= 0")
        if not 0.0 < self.torque_fraction <= 1.0:
            raise ValueError("safety torque_fraction must be in (0, 1]")


class SafetyChecker:
    """Per-tick checks of measured state against :class:`SafetyLimits` (module doc)."""

    def __init__(
        self, limits: SafetyLimits, q_lower: np.ndarray, q_upper: np.ndarray, tau_max: np.ndarray
    ) -> None:
        self.limits = limits
        self.q_lower = np.asarray(q_lower, float) - limits.joint_margin
        self.q_upper = np.asarray(q_upper, float) + limits.joint_margin
        self.tau_sat = np.asarray(tau_max, float) * limits.torque_fraction
        self.reset()

    def reset(self) -> None:
        """Forget the timers (after a recover, or when a phase stops checking)."""
        self._low_since: float | None = None
        self._sat_since = np.full(len(self.tau_sat), np.nan)

    def check_tilt(self, roll: float, pitch: float) -> str | None:
        """Reason to trip for this orientation (None: fine)."""
        lim = self.limits
        if abs(roll) > lim.max_roll:
            return f"roll {math.degrees(roll):.0f}° beyond ±{math.degrees(lim.max_roll):.0f}°"
        if abs(pitch) > lim.max_pitch:
            return f"pitch {math.degrees(pitch):.0f}° beyond ±{math.degrees(lim.max_pitch):.0f}°"
        return None

    def check_height(self, t: float, height: float) -> str | None:
        """Trunk height above the feet (m); trips after ``low_height_time`` below the limit."""
        lim = self.limits
        if height >= lim.min_height:
            self._low_since = None
            return None
        if self._low_since is None:
            self._low_since = t
        if t - self._low_since >= lim.low_height_time:
            return (
                f"trunk {height:.2f} m above the feet, below {lim.min_height:.2f} m "
                f"for {t - self._low_since:.2f} s"
            )
        return None

    def check_joints(self, t: float, q12: np.ndarray, tau12: np.ndarray) -> str | None:
        """Joint ranges and torque saturation of the 12 leg joints."""
        q12 = np.asarray(q12, float)
        out = (q12 < self.q_lower) | (q12 > self.q_upper)
        if np.any(out):
            j = int(np.flatnonzero(out)[0])
            return f"leg joint {j} at {q12[j]:.2f} rad, beyond its range by > margin"
        sat = np.abs(np.asarray(tau12, float)) >= self.tau_sat
        self._sat_since = np.where(sat, np.where(np.isnan(self._sat_since), t, self._sat_since),
                                   np.nan)  # fmt: skip
        held = np.where(sat, t - self._sat_since, 0.0)
        if np.any(held >= self.limits.saturation_time):
            j = int(np.argmax(held))
            return f"leg joint {j} torque saturated for {held[j]:.2f} s"
        return None

    def check(
        self,
        t: float,
        roll: float,
        pitch: float,
        q12: np.ndarray,
        tau12: np.ndarray,
        height: float | None = None,
    ) -> str | None:
        """All checks for one tick; ``height`` None skips the height check (phases where
        the feet are not under the trunk, e.g. standing up)."""
        reason = self.check_tilt(roll, pitch)
        if reason is None and height is not None:
            reason = self.check_height(t, height)
        if reason is None:
            reason = self.check_joints(t, q12, tau12)
        return reason
