"""The safety layer of a hardware adapter's legs: the sim's rules (common/actuator_commands)
plus the clamps a real motor needs before a command leaves the computer.

Per control tick the adapter asks :meth:`LegSafety.targets` what the 12 leg motors should
get, given the measured joint state:

* *active* (a valid command younger than ``timeout``): the command with ``q_des`` clamped
  into the joint range, gains clamped to ``kp_max``/``kd_max``, and the feed-forward torque
  reduced where the PD law evaluated at the measured state would exceed the motor's torque
  limit (the motor driver runs the PD itself at a higher rate; this bounds what we ask);
* *damping* (commands stopped for ``timeout``, or never came): ``kp = 0``,
  ``kd = damping_kd``, zero torque: the legs fold slowly instead of holding or collapsing;
* *estop* (latched by :meth:`engage_estop` until :meth:`reset_estop`): damping too.

Commands with the wrong shape, non-finite values or negative gains are refused with a
reason and counted; they never reach a motor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from quadmanip.common.actuator_commands import LegMode, LegWatchdog, check_leg_command
from quadmanip.common.joint_layout import N_LEG_JOINTS

__all__ = ["LegSafety", "LegSafetyConfig", "MotorTargets"]


@dataclass(frozen=True)
class LegSafetyConfig:
    """``[safety]`` of an adapter's config."""

    timeout: float = 0.05  # s without a valid leg command -> damping (the sim's leg_timeout)
    damping_kd: float = 2.0  # N m s/rad in damping and e-stop (the sim's leg_damping_kd)
    kp_max: float = 200.0  # N m/rad: above any gain locomotion uses (stand-up 100)
    kd_max: float = 10.0  # N m s/rad

    def __post_init__(self) -> None:
        if not self.timeout > 0:
            raise ValueError("safety.timeout must be > 0")
        if self.damping_kd < 0 or self.kp_max <= 0 or self.kd_max <= 0:
            raise ValueError("safety gains must be positive")


@dataclass(frozen=True)
class MotorTargets:
    """What the 12 leg motors get this tick (our wire order) and why."""

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray
    mode: LegMode


class LegSafety:
    """See the module doc. ``lower``/``upper``/``tau_max``: the 12 leg joints' limits in
    wire order (``robot_description.leg_joint_limits()``)."""

    def __init__(
        self,
        config: LegSafetyConfig,
        lower: np.ndarray,
        upper: np.ndarray,
        tau_max: np.ndarray,
    ) -> None:
        shapes = {np.shape(a) for a in (lower, upper, tau_max)}
        if shapes != {(N_LEG_JOINTS,)}:
            raise ValueError(f"limits must be ({N_LEG_JOINTS},) arrays, got {shapes}")
        if np.any(np.asarray(lower) >= np.asarray(upper)) or np.any(np.asarray(tau_max) <= 0):
            raise ValueError("joint limits must have lower < upper and tau_max > 0")
        self.config = config
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.tau_max = np.asarray(tau_max, dtype=float)
        self.watchdog = LegWatchdog(config.timeout)
        self._cmd: np.ndarray | None = None
        self.rejected = 0
        self.last_reject = ""
        self.clamped = 0
        """Ticks on which a clamp changed the command."""

    @property
    def mode(self) -> LegMode:
        return self.watchdog.mode

    @property
    def timeouts(self) -> int:
        return self.watchdog.timeouts

    def command(
        self,
        now: float,
        q_des: object,
        dq_des: object,
        kp: object,
        kd: object,
        tau_ff: object,
    ) -> str:
        """Take a leg command at ``now`` (monotonic s): "" if accepted, else the reason."""
        cmd, reason = check_leg_command(q_des, dq_des, kp, kd, tau_ff)
        if cmd is None:
            self.rejected += 1
            self.last_reject = reason
            return reason
        self._cmd = cmd
        self.watchdog.command(now)
        return ""

    def engage_estop(self, reason: str) -> None:
        """Damping at once, latched."""
        self.watchdog.engage_estop(reason)

    def reset_estop(self) -> None:
        """Release the e-stop; damping until a fresh command arrives."""
        self.watchdog.reset_estop()
        self._cmd = None

    @property
    def estop_reason(self) -> str | None:
        return self.watchdog.estop_reason

    def damping(self, q: np.ndarray, mode: LegMode = LegMode.DAMPING) -> MotorTargets:
        """The damping targets (positions are only echoed: kp is 0)."""
        z = np.zeros(N_LEG_JOINTS)
        kd = np.full(N_LEG_JOINTS, self.config.damping_kd)
        return MotorTargets(np.asarray(q, dtype=float).copy(), z, z.copy(), kd, z.copy(), mode)

    def targets(self, now: float, q: np.ndarray, dq: np.ndarray) -> MotorTargets:
        """The motors' targets at ``now`` given the measured ``q``, ``dq`` (wire order)."""
        mode = self.watchdog.update(now)
        if mode is not LegMode.ACTIVE or self._cmd is None:
            return self.damping(q, mode if mode is not LegMode.ACTIVE else LegMode.DAMPING)
        q_des, dq_des, kp, kd, ff = self._cmd
        c = self.config
        q_c = np.clip(q_des, self.lower, self.upper)
        kp_c = np.minimum(kp, c.kp_max)
        kd_c = np.minimum(kd, c.kd_max)
        ff_c = np.clip(ff, -self.tau_max, self.tau_max)
        pd = kp_c * (q_c - q) + kd_c * (dq_des - dq)
        total = pd + ff_c
        over = np.abs(total) > self.tau_max
        if over.any():  # lower the feed-forward so that PD + ff stays within the limit
            ff_c = np.where(over, np.clip(total, -self.tau_max, self.tau_max) - pd, ff_c)
        if (
            over.any()
            or not np.array_equal(q_c, q_des)
            or not np.array_equal(kp_c, kp)
            or not np.array_equal(kd_c, kd)
            or not np.array_equal(ff_c, ff)
        ):
            self.clamped += 1
        return MotorTargets(q_c, dq_des.copy(), kp_c, kd_c, ff_c, mode)
