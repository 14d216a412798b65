"""The arm and gripper behind a small driver interface (as lerobot puts motors behind a
bus class): the adapter composes a leg backend with one of these.

Quadruped SDKs have no arm standard, so an integrator writes one :class:`ArmDriver` for
their arm's servo bus. The shared part lives in :class:`StreamingArmDriver`: it keeps the
arm trajectories of ``sim/arm_trajectory`` (the same rules as the sim's actuator layer,
common/actuator_commands) and, every control tick, streams the interpolated setpoint to
the servos through :meth:`StreamingArmDriver.send`, which a driver implements with its
bus. Before the first trajectory the servos hold where they were; the e-stop damps them.

:class:`SimulatedArmDriver` is a kinematic servo model for tests (no physics): each joint
moves toward its setpoint at its rated speed, the gripper gap at its rated gap speed.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np
from quadmanip.common.actuator_commands import (
    ArmSegment,
    active_segment,
    check_arm_trajectory,
    queue_segment,
)
from quadmanip.common.joint_layout import N_ARM_JOINTS

__all__ = [
    "ArmDriver",
    "ArmReading",
    "ArmSetpoint",
    "SimulatedArmDriver",
    "StreamingArmDriver",
]


@dataclass(frozen=True)
class ArmReading:
    """The arm's measured state (wire order of ``ARM_JOINTS``) and the gripper's."""

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    gripper_gap: float
    gripper_effort: float


@dataclass(frozen=True)
class ArmSetpoint:
    """What the servos get this tick: PD targets + feed-forward, and the gripper's."""

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray
    gripper_gap: float
    gripper_force: float
    damping: bool = False


class ArmDriver(abc.ABC):
    """What the adapter needs from an arm (all times are robot time, s)."""

    @abc.abstractmethod
    def read(self) -> ArmReading | None:
        """The newest reading, None before the first one."""

    @abc.abstractmethod
    def set_trajectory(self, now: float, seg_args: dict) -> str:
        """Queue a trajectory (the fields of ArmTrajectory); "" or the refusal reason."""

    @abc.abstractmethod
    def set_gripper(self, gap: float, max_force: float) -> str:
        """Command the finger gap (m) and force limit (N); "" or the refusal reason."""

    @abc.abstractmethod
    def update(self, now: float) -> None:
        """Send this control tick's setpoint."""

    @abc.abstractmethod
    def engage_estop(self) -> None:
        """Damp the arm at once (latched until :meth:`reset_estop`)."""

    @abc.abstractmethod
    def reset_estop(self) -> None:
        """Release the e-stop: hold where the arm is."""

    def close(self) -> None:  # noqa: B027 (optional hook)
        """Release the bus."""


class StreamingArmDriver(ArmDriver):
    """Trajectory keeping and setpoint streaming; subclasses implement :meth:`send` and
    :meth:`read`. ``hold_kp``/``hold_kd``: gains while holding (the sim's arm_hold_*)."""

    def __init__(
        self,
        hold_kp: float = 60.0,
        hold_kd: float = 2.0,
        damping_kd: float = 2.0,
        gap_range: tuple[float, float] = (0.0, 0.12),
        default_force: float = 20.0,
    ) -> None:
        self.hold_kp, self.hold_kd, self.damping_kd = hold_kp, hold_kd, damping_kd
        self.gap_range = gap_range
        self._segments: list[ArmSegment] = []
        self._hold: np.ndarray | None = None
        self._gap: float | None = None
        self._force = float(default_force)
        self.estop = False
        self.rejected = 0
        self.last_reject = ""

    def _refuse(self, reason: str) -> str:
        self.rejected += 1
        self.last_reject = reason
        return reason

    def set_trajectory(self, now: float, seg_args: dict) -> str:
        seg, reason = check_arm_trajectory(**seg_args)
        if seg is None:
            return self._refuse(reason)
        if self.estop:
            return self._refuse("emergency stop engaged")
        self._segments = queue_segment(self._segments, seg)
        return ""

    def set_gripper(self, gap: float, max_force: float) -> str:
        try:
            gap, max_force = float(gap), float(max_force)
        except (TypeError, ValueError):
            return self._refuse("not a number")
        if not (np.isfinite(gap) and np.isfinite(max_force)):
            return self._refuse("non-finite value")
        if max_force < 0:
            return self._refuse("negative force")
        self._gap = float(np.clip(gap, *self.gap_range))
        self._force = max_force
        return ""

    def engage_estop(self) -> None:
        self.estop = True
        self._segments = []

    def reset_estop(self) -> None:
        self.estop = False
        self._hold = None

    def setpoint(self, now: float) -> ArmSetpoint | None:
        """This tick's setpoint (None until the first reading)."""
        r = self.read()
        if r is None:
            return None
        gap = r.gripper_gap if self._gap is None else self._gap
        z = np.zeros(N_ARM_JOINTS)
        if self.estop:
            kd = np.full(N_ARM_JOINTS, self.damping_kd)
            return ArmSetpoint(r.q.copy(), z, z.copy(), kd, z.copy(), gap, self._force, True)
        seg = active_segment(self._segments, now)
        if seg is not None:
            self._hold = None
            q, dq, ff = seg.sample(now)
            return ArmSetpoint(q, dq, seg.kp.copy(), seg.kd.copy(), ff, gap, self._force)
        if self._hold is None:
            self._hold = r.q.copy()
        kp = np.full(N_ARM_JOINTS, self.hold_kp)
        kd = np.full(N_ARM_JOINTS, self.hold_kd)
        return ArmSetpoint(self._hold.copy(), z, kp, kd, z.copy(), gap, self._force)

    def update(self, now: float) -> None:
        sp = self.setpoint(now)
        if sp is not None:
            self.send(now, sp)

    @abc.abstractmethod
    def send(self, now: float, sp: ArmSetpoint) -> None:
        """Put ``sp`` on the servo bus."""


class SimulatedArmDriver(StreamingArmDriver):
    """Kinematic servos for tests: joints slew toward the setpoint at ``max_speed``
    (rad/s), the gripper gap at ``gap_speed`` (m/s); damping stops them where they are."""

    def __init__(
        self,
        q0: np.ndarray,
        gap0: float = 0.0,
        max_speed: float = 6.0,
        gap_speed: float = 0.15,
        **kwargs: float,
    ) -> None:
        super().__init__(**kwargs)
        self.q = np.asarray(q0, dtype=float).copy()
        self.dq = np.zeros(N_ARM_JOINTS)
        self.gap = float(gap0)
        self.max_speed, self.gap_speed = max_speed, gap_speed
        self._t: float | None = None
        self.last: ArmSetpoint | None = None

    def read(self) -> ArmReading:
        return ArmReading(self.q.copy(), self.dq.copy(), np.zeros(N_ARM_JOINTS), self.gap, 0.0)

    def send(self, now: float, sp: ArmSetpoint) -> None:
        dt = 0.0 if self._t is None else max(0.0, now - self._t)
        self._t = now
        self.last = sp
        if sp.damping:
            self.dq = np.zeros(N_ARM_JOINTS)
            return
        step = np.clip(sp.q - self.q, -self.max_speed * dt, self.max_speed * dt)
        self.q = self.q + step
        self.dq = step / dt if dt > 0 else np.zeros(N_ARM_JOINTS)
        g = self.gap_speed * dt
        self.gap += float(np.clip(sp.gripper_gap - self.gap, -g, g))
