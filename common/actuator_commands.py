"""The safety rules every actuator layer applies to commands, the sim's and a hardware
adapter's alike (docs/architecture.md, "Hardware adapter contract").

Plain numpy, no MuJoCo, no transport: the simulator's actuator layer
(:mod:`quadmanip.sim.actuators`) and a hardware adapter (:mod:`quadmanip.hardware`) both
use these, so the robot behaves the same when its commands stop, go bad or an emergency
stop is pressed, whichever side of the contract it runs on.

* :func:`check_leg_command` and :func:`check_arm_trajectory`: commands with the wrong
  size, non-finite numbers, negative gains or unordered time stamps are refused with a
  reason; they never reach a motor.
* :class:`LegWatchdog`: the legs are *active* while the last valid leg command is younger
  than the timeout, *damping* otherwise (also before the first command: a robot whose
  controller is not running does not hold itself up), and *estop* while an emergency stop
  is latched. The e-stop damps at once and holds until it is reset explicitly; valid
  commands arriving meanwhile do not release it.
* Arm trajectories: time-stamped knots interpolated with cubic Hermite splines
  (:func:`hermite`) and feed-forward torques linearly (:func:`lerp`). A new trajectory
  replaces the queued ones from its first stamp on (:func:`queue_segment`), the old one
  running until then (:func:`active_segment`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from quadmanip.common.joint_layout import N_ARM_JOINTS, N_LEG_JOINTS

__all__ = [
    "ArmSegment",
    "LegMode",
    "LegWatchdog",
    "active_segment",
    "check_arm_trajectory",
    "check_leg_command",
    "hermite",
    "lerp",
    "queue_segment",
]

LEG_FIELDS = ("q_des", "dq_des", "kp", "kd", "tau_ff")


class LegMode(StrEnum):
    """What the leg motors are doing (RobotStatus.leg_mode)."""

    DAMPING = "damping"
    ACTIVE = "active"
    ESTOP = "estop"


def check_leg_command(
    q_des: object, dq_des: object, kp: object, kd: object, tau_ff: object
) -> tuple[np.ndarray | None, str]:
    """A private (5, 12) copy of a valid leg command and "", or None and the reason."""
    arrays = (q_des, dq_des, kp, kd, tau_ff)
    for name, a in zip(LEG_FIELDS, arrays, strict=True):
        if np.shape(a) != (N_LEG_JOINTS,):
            return None, f"{name} shape {np.shape(a)} != ({N_LEG_JOINTS},)"
    try:
        cmd = np.array(arrays, dtype=float)
    except (TypeError, ValueError):
        return None, "not numbers"
    if not np.isfinite(cmd).all():
        return None, "non-finite value"
    if (cmd[2:4] < 0).any():
        return None, "negative gain"
    return cmd, ""


@dataclass(frozen=True)
class ArmSegment:
    """One accepted arm trajectory (``tau_ff`` None: no feed-forward)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau_ff: np.ndarray | None = None

    def sample(self, now: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Desired position, velocity and feed-forward torque at ``now``."""
        q, dq = hermite(self.t, self.q, self.dq, now)
        ff = lerp(self.t, self.tau_ff, now) if self.tau_ff is not None else np.zeros_like(q)
        return q, dq, ff


def check_arm_trajectory(
    t: object,
    q: object,
    dq: object,
    kp: object,
    kd: object,
    tau_ff: object | None = None,
) -> tuple[ArmSegment | None, str]:
    """An :class:`ArmSegment` (private copies) of a valid trajectory and "", or None and
    the reason. ``tau_ff`` (N, 4): feed-forward torque per knot (N m), None for zeros."""
    try:
        t = np.asarray(t, dtype=float)
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        kp = np.asarray(kp, dtype=float)
        kd = np.asarray(kd, dtype=float)
        ff = np.zeros_like(q) if tau_ff is None else np.asarray(tau_ff, dtype=float)
    except (TypeError, ValueError):
        return None, "not numbers"
    if t.ndim != 1 or len(t) < 1:
        return None, f"t shape {t.shape} is not (N>=1,)"
    n = len(t)
    if q.shape != (n, N_ARM_JOINTS) or dq.shape != (n, N_ARM_JOINTS):
        return None, f"q/dq shapes {q.shape}/{dq.shape} != ({n}, {N_ARM_JOINTS})"
    if kp.shape != (N_ARM_JOINTS,) or kd.shape != (N_ARM_JOINTS,):
        return None, f"kp/kd shapes {kp.shape}/{kd.shape} != ({N_ARM_JOINTS},)"
    if ff.shape != (n, N_ARM_JOINTS):
        return None, f"tau_ff shape {ff.shape} != ({n}, {N_ARM_JOINTS})"
    if not all(np.all(np.isfinite(a)) for a in (t, q, dq, kp, kd, ff)):
        return None, "non-finite value"
    if np.any(kp < 0) or np.any(kd < 0):
        return None, "negative gain"
    if n > 1 and np.any(np.diff(t) <= 0):
        return None, "time stamps not strictly increasing"
    seg = ArmSegment(
        t.copy(), q.copy(), dq.copy(), kp.copy(), kd.copy(), ff.copy() if ff.any() else None
    )
    return seg, ""


def queue_segment(segments: list[ArmSegment], seg: ArmSegment) -> list[ArmSegment]:
    """The queue with ``seg`` replacing everything from its first stamp on."""
    return [s for s in segments if s.t[0] < seg.t[0]] + [seg]


def active_segment(segments: list[ArmSegment], now: float) -> ArmSegment | None:
    """The segment that runs at ``now`` (None before the first one starts); drops the
    segments a later one has taken over from (in place)."""
    while len(segments) > 1 and segments[1].t[0] <= now:
        segments.pop(0)
    if segments and segments[0].t[0] <= now:
        return segments[0]
    return None


class LegWatchdog:
    """Leg mode from command age and the emergency stop (see the module doc).

    ``update(now)`` returns the mode and counts *timeouts*: transitions from active to
    damping because commands stopped (the counter every status report carries).
    """

    def __init__(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"leg command timeout must be > 0, got {timeout}")
        self.timeout = float(timeout)
        self.last_command = -np.inf
        self.has_command = False
        self.estop_reason: str | None = None
        self.timeouts = 0
        self.mode = LegMode.DAMPING

    def command(self, now: float) -> None:
        """A valid leg command was accepted at ``now``."""
        self.last_command = float(now)
        self.has_command = True

    def engage_estop(self, reason: str) -> None:
        """Latch the emergency stop: damping from now on, until :meth:`reset_estop`."""
        self.estop_reason = reason or "emergency stop"

    def reset_estop(self) -> None:
        """Release the emergency stop; the legs stay damped until a fresh command."""
        if self.estop_reason is not None:
            self.estop_reason = None
            self.has_command = False

    def mode_at(self, now: float) -> LegMode:
        """The mode at ``now`` (no side effects)."""
        if self.estop_reason is not None:
            return LegMode.ESTOP
        if not self.has_command or now - self.last_command > self.timeout + 1e-9:
            return LegMode.DAMPING
        return LegMode.ACTIVE

    def update(self, now: float) -> LegMode:
        """The mode at ``now``; counts an active → damping transition as a timeout."""
        mode = self.mode_at(now)
        if mode is LegMode.DAMPING and self.mode is LegMode.ACTIVE:
            self.timeouts += 1
        self.mode = mode
        return mode


def hermite(
    t: np.ndarray, q: np.ndarray, dq: np.ndarray, now: float
) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite interpolation of knots (t[N], q[N,k], dq[N,k]) at ``now``.

    Exact at the knots (position and velocity), C1 between them. Before the first knot
    it returns the first point, after the last the last point with zero velocity.
    """
    n = len(t)
    if now <= t[0]:
        return q[0].copy(), (dq[0].copy() if n == 1 or now == t[0] else np.zeros_like(q[0]))
    if now >= t[-1]:
        return q[-1].copy(), (dq[-1].copy() if now == t[-1] else np.zeros_like(q[-1]))
    i = int(np.searchsorted(t, now, side="right") - 1)
    h = t[i + 1] - t[i]
    s = (now - t[i]) / h
    s2, s3 = s * s, s * s * s
    h00 = 2 * s3 - 3 * s2 + 1
    h10 = s3 - 2 * s2 + s
    h01 = -2 * s3 + 3 * s2
    h11 = s3 - s2
    pos = h00 * q[i] + h10 * h * dq[i] + h01 * q[i + 1] + h11 * h * dq[i + 1]
    d00 = (6 * s2 - 6 * s) / h
    d10 = 3 * s2 - 4 * s + 1
    d01 = (-6 * s2 + 6 * s) / h
    d11 = 3 * s2 - 2 * s
    vel = d00 * q[i] + d10 * dq[i] + d01 * q[i + 1] + d11 * dq[i + 1]
    return pos, vel


def lerp(t: np.ndarray, y: np.ndarray, now: float) -> np.ndarray:
    """Piecewise-linear interpolation of knot rows ``y[N, k]`` at ``now``; the first row
    before the first knot, the last one after the last."""
    if now <= t[0]:
        return y[0].copy()
    if now >= t[-1]:
        return y[-1].copy()
    i = int(np.searchsorted(t, now, side="right") - 1)
    s = (now - t[i]) / (t[i + 1] - t[i])
    return (1.0 - s) * y[i] + s * y[i + 1]
