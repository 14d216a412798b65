"""Transport-free execution of manipulation primitives (grasp, place, drawer, posture).

A primitive is a generator-based state machine: it receives an :class:`Observation` every
control tick (robot time, arm joints, gripper gap and effort) and answers with a list of
commands (:class:`ArmCommand`, :class:`GripperCmd`, :class:`BodyPoseRequest`). The node
turns those into bus messages; the tests feed them straight into the sim's actuator layer.
Nothing here imports a transport, so every primitive is testable in-process.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
from quadmanip.services.manipulation.config import GraspConfig, ManipulationConfig
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
from quadmanip.services.manipulation.trajectory import (
    JointTrajectory,
    MotionLimits,
    TrajectoryError,
    hold,
    plan_cartesian_line,
    plan_joint_path,
)

__all__ = [
    "ArmCommand",
    "PostureMove",
    "BodyPoseRequest",
    "Command",
    "GripperCmd",
    "Observation",
    "Primitive",
    "PrimitiveFailed",
    "Status",
]


@dataclass(frozen=True)
class Observation:
    """What the manipulation service measures each tick (joint encoders and gripper)."""

    t: float
    q_arm: np.ndarray
    dq_arm: np.ndarray
    gripper_gap: float
    gripper_effort: float
    # Base pose (x, y, z, yaw) from locomotion's odometry, None where there is none (the
    # in-process harness, whose legs are held rigidly).
    base: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class ArmCommand:
    """Send this trajectory to the arm (it replaces the running one from its first stamp)."""

    traj: JointTrajectory


@dataclass(frozen=True)
class GripperCmd:
    """Finger gap (m) with a squeeze force limit (N)."""

    gap: float
    max_force: float


@dataclass(frozen=True)
class BodyPoseRequest:
    """Body offsets from the nominal standing pose (m), sent to locomotion (moveCOM), and
    the trunk's pitch (rad about the body y axis, locomotion's sign: negative lifts the
    nose). Only a posture pitches the trunk (``PostureSpec.body_pitch``); every other
    primitive levels it first, since grasps, places and drawers are planned for a level
    trunk."""

    x_offset: float = 0.0
    y_offset: float = 0.0
    z_offset: float = 0.0
    pitch: float = 0.0


Command = ArmCommand | GripperCmd | BodyPoseRequest


def body_settle_time(cfg: GraspConfig, old: BodyPoseRequest, new: BodyPoseRequest) -> float:
    """Seconds the trunk is given to go from offsets ``old`` to ``new``: longer for a
    longer way (GraspConfig.body_settle_min/per_m), at most ``body_settle_time``, which a
    pitch change always gets."""
    if new.pitch != old.pitch:
        return cfg.body_settle_time
    way = max(
        abs(new.x_offset - old.x_offset),
        abs(new.y_offset - old.y_offset),
        abs(new.z_offset - old.z_offset),
    )
    return min(cfg.body_settle_time, cfg.body_settle_min + cfg.body_settle_per_m * way)


class Status(StrEnum):
    """Lifecycle of a primitive."""

    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELED = "canceled"


class PrimitiveFailed(Exception):
    """Raised inside a primitive to end it with a failure ``reason``."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


Script = Generator[list[Command], Observation, None]


@dataclass
class _Progress:
    value: float = 0.0
    text: str = ""
    log: list[tuple[float, str]] = field(default_factory=list)


class Primitive:
    """Base class: subclasses implement :meth:`script` as a generator of command lists."""

    name = "primitive"
    # planned for a level trunk: a pitch a posture left is levelled before the script
    plans_level = True

    def __init__(
        self,
        geom: ArmGeometry,
        cfg: ManipulationConfig,
        monitor: GraspMonitor | None = None,
        body: BodyPoseRequest | None = None,
    ) -> None:
        self.geom = geom
        self.cfg = cfg
        self.limits = MotionLimits.build(geom, cfg.motion.v_max, cfg.motion.a_max)
        # shared across primitives so that place() knows what grasp() holds
        self.monitor = monitor if monitor is not None else GraspMonitor(cfg.gripper)
        self.status = Status.RUNNING
        self.note = ""  # what it was planned as, for the log (see Outcome.plan)
        self.reason = ""
        self.progress = _Progress()
        # body offset currently requested from locomotion (shared like the monitor)
        self.body = body if body is not None else BodyPoseRequest()
        self.t_start: float | None = None
        self.t_end: float | None = None
        self._gen: Script | None = None
        self._last_obs: Observation | None = None
        self._base0: tuple[float, float, float, float] | None = None
        self._body0 = self.body

    # -------------------------------------------------------------------- driving
    def script(self) -> Script:  # pragma: no cover - abstract
        """The primitive's behaviour; yields command lists, receives observations."""
        raise NotImplementedError
        yield []

    def _leveled_script(self) -> Script:
        """:meth:`script`, after levelling a trunk a posture left pitched."""
        if self.body.pitch != 0.0 and self.plans_level:
            b = self.body
            self.stage("levelling the trunk", None)
            yield from self.move_body(b.x_offset, b.y_offset, b.z_offset)
            self._body0 = self.body
        yield from self.script()

    def step(self, obs: Observation) -> list[Command]:
        """Advances the state machine by one observation; returns commands to send."""
        if self.status is not Status.RUNNING:
            return []
        self._last_obs = obs
        if self._base0 is None and obs.base is not None:
            self._base0 = obs.base
            self._body0 = self.body
        self.monitor.update(obs.t, obs.gripper_gap, obs.gripper_effort)
        try:
            if self._gen is None:
                self.t_start = obs.t
                self._gen = self._leveled_script()
                cmds = next(self._gen)
            else:
                cmds = self._gen.send(obs)
        except StopIteration:
            self.status = Status.SUCCEEDED
            self.t_end = obs.t
            self._note(obs.t, "succeeded", 1.0)
            return []
        except PrimitiveFailed as exc:
            self.status = Status.FAILED
            self.reason = exc.reason
            self.t_end = obs.t
            self._note(obs.t, f"failed: {exc.reason}")
            return [ArmCommand(hold(obs.q_arm, obs.t))]
        except TrajectoryError as exc:
            self.status = Status.FAILED
            self.reason = f"trajectory_{exc.reason}: {exc.detail}"
            self.t_end = obs.t
            self._note(obs.t, f"failed: {self.reason}")
            return [ArmCommand(hold(obs.q_arm, obs.t))]
        return cmds

    def cancel(self, obs: Observation) -> list[Command]:
        """Stops now: the arm holds where it is (a one-knot trajectory)."""
        if self.status is Status.RUNNING:
            self.status = Status.CANCELED
            self.reason = "canceled"
            self.t_end = obs.t
            if self._gen is not None:
                self._gen.close()
        return [ArmCommand(hold(obs.q_arm, obs.t))]

    @property
    def done(self) -> bool:
        """True once succeeded, failed or canceled."""
        return self.status is not Status.RUNNING

    def _note(self, t: float, text: str, value: float | None = None) -> None:
        if value is not None:
            self.progress.value = value
        self.progress.text = text
        self.progress.log.append((t, text))

    # ------------------------------------------------------------- script helpers
    def stage(self, text: str, value: float | None) -> None:
        """Reports progress (0..1) and a human-readable stage name."""
        t = self._last_obs.t if self._last_obs is not None else 0.0
        self._note(t, text, value)

    @staticmethod
    def together(*scripts: Script) -> Script:
        """Runs ``scripts`` side by side (each gets every observation, their commands go
        out together) until the last has ended: e.g. the fingers opening while the arm
        moves, which drive different actuators."""
        live, cmds = [], []
        for s in scripts:
            try:
                cmds += next(s)
                live.append(s)
            except StopIteration:
                pass
        while live:
            obs = yield cmds
            cmds, still = [], []
            for s in live:
                try:
                    cmds += s.send(obs)
                    still.append(s)
                except StopIteration:
                    pass
            live = still

    def run_trajectory(self, traj: JointTrajectory) -> Script:
        """Sends a trajectory and waits until the arm reached its end (or fails: stuck)."""
        obs = yield [ArmCommand(traj)]
        g, still = self.cfg.grasp, self.cfg.primitive.arm_still_speed
        q_end = traj.q_end
        while True:
            if obs.t >= traj.end_time:
                err = float(np.max(np.abs(obs.q_arm - q_end)))
                speed = np.abs(obs.dq_arm)
                if err <= g.arm_tolerance and float(np.max(speed)) < still:
                    return
                if obs.t > traj.end_time + g.arm_timeout:
                    # say whether the arm is held off its goal or cannot come to rest
                    j = int(np.argmax(speed))
                    k = int(np.argmax(np.abs(obs.q_arm - q_end)))
                    why = (
                        f"joint {j + 1} still moving at {speed[j]:.2f} rad/s"
                        if speed[j] >= still
                        else f"joint {k + 1} held off its goal"
                    )
                    raise PrimitiveFailed(
                        f"arm_blocked: {err:.3f} rad from the trajectory end after timeout, {why}"
                    )
            obs = yield []

    def body_drift(self) -> np.ndarray:
        """Unplanned body motion since the primitive started: ``(dx, dy, dz)`` in the
        start body frame, odometry minus the body-pose offsets this primitive requested.

        Under real locomotion the trunk does not stay put while the arm works: the balance
        controller keeps the whole-robot COM over the feet, so reaching 8 cm forward backs
        the trunk off 1-2 cm. Targets fixed in the world (a drawer handle) are corrected by
        this. Zero without odometry.
        """
        obs = self._last_obs
        if obs is None or obs.base is None or self._base0 is None:
            return np.zeros(3)
        x0, y0, z0, yaw0 = self._base0
        x, y, z, _ = obs.base
        c, s = math.cos(yaw0), math.sin(yaw0)
        dx, dy = x - x0, y - y0
        b, b0 = self.body, self._body0
        return np.array(
            [
                c * dx + s * dy - (b.x_offset - b0.x_offset),
                -s * dx + c * dy - (b.y_offset - b0.y_offset),
                z - z0 - (b.z_offset - b0.z_offset),
            ]
        )

    def follow_drift(self, target: Any, label: str, tries: int = 3) -> Script:
        """Re-aims the tool at ``target`` (an ``ArmTarget`` fixed in the world, e.g. a
        drawer handle or a grasp point, planned for the body as requested) after the trunk's
        unplanned drift: a crouch that stopped 1 cm short, the trunk backing off as the arm
        reaches. Lateral drift cannot be fixed by this arm (it has no y); it stays."""
        from quadmanip.services.manipulation.arm_kinematics import ArmTarget, fk_tcp

        pc = self.cfg.primitive
        for _ in range(tries):
            yield from self.wait(pc.drift_settle_time)
            d = self.body_drift()
            obs = self._last_obs
            assert obs is not None
            here = fk_tcp(self.geom, obs.q_arm)
            want = ArmTarget(target.x - d[0], target.z - d[2], here.pitch, here.roll)
            if math.hypot(want.x - here.x, want.z - here.z) < pc.drift_tol:
                return
            self.stage(f"{label}: follow body drift {d[0]:+.3f} / {d[2]:+.3f} m", None)
            yield from self.line_to(want)

    def move_joints(self, q_goal: np.ndarray) -> Script:
        """Joint-space move from the measured joints to ``q_goal`` (limits enforced)."""
        obs = self._last_obs
        assert obs is not None
        traj = plan_joint_path([obs.q_arm, q_goal], obs.t, self.limits, dt=self.cfg.motion.dt)
        yield from self.run_trajectory(traj)

    def line_to(self, goal: Any, speed: float | None = None) -> Script:
        """Straight-line tool move from the measured joints to ``goal`` (an ``ArmTarget``),
        at ``speed`` m/s or the configured linear speed (faster with empty fingers)."""
        obs = self._last_obs
        assert obs is not None
        m = self.cfg.motion
        speed = speed or (m.linear_speed if self.monitor.holding else m.empty_linear_speed)
        traj = plan_cartesian_line(
            self.geom,
            obs.q_arm,
            goal,
            obs.t,
            self.limits,
            linear_speed=speed,
            angular_speed=m.angular_speed,
            dt=m.dt,
        )
        yield from self.run_trajectory(traj)

    def require_holding(self, where: str) -> None:
        """Fails the primitive with ``object_lost`` unless the gripper still holds."""
        if not self.monitor.holding:
            raise PrimitiveFailed(f"object_lost {where} ({self.monitor.state.value})")

    def holding_on(self, script: Script, where: str) -> Script:
        """Runs ``script`` and fails it with ``object_lost`` as soon as the gripper no
        longer holds (not only at its end)."""
        try:
            cmds = next(script)
        except StopIteration:
            return
        while True:
            obs = yield cmds
            self.require_holding(where)
            try:
                cmds = script.send(obs)
            except StopIteration:
                return

    def wait(self, duration: float) -> Script:
        """Idles for ``duration`` seconds of robot time."""
        assert self._last_obs is not None
        t_end = self._last_obs.t + duration
        while True:
            obs = yield []
            if obs.t >= t_end:
                return

    def move_body(
        self,
        x: float = 0.0,
        y: float = 0.0,
        z: float = 0.0,
        during: Script | None = None,
        settle: bool = True,
    ) -> Script:
        """Requests a body offset (moveCOM) with a level trunk and gives locomotion time
        to reach it. ``during`` (a gripper move) runs while the trunk moves: the settle
        time counts from the request, so a gripper that opens meanwhile costs no time.
        Without ``settle`` the request is sent and not waited for (a primitive's last
        step, the trunk back to its stance with nothing in the fingers)."""
        new = BodyPoseRequest(x_offset=x, y_offset=y, z_offset=z)
        t_end = -math.inf
        if new != self.body:
            assert self._last_obs is not None
            t_end = self._last_obs.t + body_settle_time(self.cfg.grasp, self.body, new)
            self.body = new
            yield [new]
        if during is not None:
            yield from during
        assert self._last_obs is not None
        if settle and self._last_obs.t < t_end:
            yield from self.wait(t_end - self._last_obs.t)

    def open_gripper(self, gap: float | None = None, settle: float = 0.1) -> Script:
        """Opens to ``gap`` (default: fully), waits until the fingers got there (they move
        at the gripper's rated speed, 0.15 m/s of gap: 0.8 s from closed to fully open) or
        stopped against something, then ``settle`` seconds more."""
        assert self._last_obs is not None
        cfg = self.cfg.gripper
        t0 = self._last_obs.t
        full, force = self.monitor.command_open(t0)
        g = full if gap is None else float(min(max(gap, 0.0), full))
        obs = yield [GripperCmd(g, force)]
        last, still_since = (obs.t, obs.gripper_gap), None
        while abs(obs.gripper_gap - g) > cfg.open_tolerance and obs.t - t0 < cfg.close_timeout:
            obs = yield []
            dt = obs.t - last[0]
            if dt > 0:
                moving = abs(obs.gripper_gap - last[1]) / dt >= cfg.settle_speed
                still_since = None if moving else (still_since or obs.t)
                last = (obs.t, obs.gripper_gap)
            if still_since is not None and obs.t - still_since >= cfg.settle_time:
                break  # blocked short of the gap (e.g. by the drawer bar)
        yield from self.wait(settle)

    def close_gripper(self, max_force: float | None = None) -> Script:
        """Force-limited close; returns when the monitor decided holding or empty."""
        assert self._last_obs is not None
        gap, force = self.monitor.command_close(self._last_obs.t, max_force)
        obs = yield [GripperCmd(gap, force)]
        while self.monitor.state is GripState.CLOSING:
            obs = yield []
        del obs


class PostureMove(Primitive):
    """Joint-space move to a named posture (limits enforced by the planner)."""

    name = "move_to_posture"
    plans_level = False  # it sets the trunk pitch itself

    def __init__(
        self,
        geom: ArmGeometry,
        cfg: ManipulationConfig,
        q_goal: np.ndarray,
        held_across: bool = False,
        body_pitch: float = 0.0,
        **kw: Any,
    ) -> None:
        super().__init__(geom, cfg, **kw)
        self.q_goal = np.asarray(q_goal, dtype=float)
        self.held_across = held_across  # see PostureSpec.held_across
        self.body_pitch = float(body_pitch)  # see PostureSpec.body_pitch
        if self.monitor.holding:  # gentler with an object in the gripper
            s = cfg.motion.holding_speed_scale
            v, a = np.asarray(cfg.motion.v_max), np.asarray(cfg.motion.a_max)
            self.limits = MotionLimits.build(geom, tuple(s * v), tuple(s * s * a))

    def goal_for(self, roll_now: float) -> np.ndarray:
        """The posture's joints; holding with ``held_across``, the wrist a quarter turn
        from the posture's roll (the turn nearest ``roll_now``, within the wrist range)."""
        q = self.q_goal.copy()
        if not (self.held_across and self.monitor.holding):
            return q
        lo, hi = self.geom.q_min[3], self.geom.q_max[3]
        turns = [r for r in (q[3] + math.pi / 2, q[3] - math.pi / 2) if lo <= r <= hi]
        if turns:
            q[3] = min(turns, key=lambda r: abs(r - roll_now))
        return q

    def script(self):  # noqa: ANN201 - generator type from Primitive
        """One synchronised quintic move; the trunk pitches to the posture's
        ``body_pitch`` meanwhile (given ``body_settle_time`` from the request when it
        changes). The pitch is sent with every posture move, changed or not: after a
        restart of this service the executive does not know what locomotion holds, and a
        posture is what the task moves to first."""
        self.stage("moving", 0.1)
        obs = yield []
        b = self.body
        changed = b.pitch != self.body_pitch
        self.body = BodyPoseRequest(b.x_offset, b.y_offset, b.z_offset, self.body_pitch)
        obs = yield [self.body]
        settled = obs.t + (self.cfg.grasp.body_settle_time if changed else 0.0)
        yield from self.move_joints(self.goal_for(float(obs.q_arm[3])))
        if self._last_obs is not None and self._last_obs.t < settled:
            yield from self.wait(settled - self._last_obs.t)
