"""The locomotion service process: `LocomotionController` wired to Zenoh.

Every `sim/lowstate` (500 Hz; encoders + IMU) is answered at once with a `sim/leg_command`
that echoes its tick (the sim's lockstep mode waits for it). Commands arrive on
`locomotion/cmd_vel`, `locomotion/body_pose` and `locomotion/mode`; invalid ones are
rejected with a logged reason and counted. Outputs: `locomotion/odometry` (every tick) and
`locomotion/debug` (every MPC step). The held-object mass in the MPC (a point mass at the
tool centre) is the one manipulation announces on `locomotion/payload` - the object's
catalogue mass. Without any payload message (manipulation not running, teleoperation) the
gripper state in the LowState decides: fingers squeezing on something count as holding
`held_object_mass`. A wrong guess is not harmless: assuming 0.5 kg for a 0.1 kg screwdriver
held 0.5 m ahead made the standing balance rock front/back and throw the trunk up 14 cm.

The control loop (issue 12): the Zenoh callback only hands the newest LowState to one
control thread, which answers it; LowStates that arrived while it was busy are skipped
rather than answered late one after another. The process runs at real-time priority where
permitted (``[scheduling]``). The deadline monitor (deadline.py) measures late answers,
ticks missed because of them, MPC overruns and, from ``sim/status``, the age of the
commands the robot applied and its leg timeouts; when the loop cannot keep up it degrades
on purpose (lower speed limits or no walking, a joint-level stance). ``locomotion/health`` says ok, degraded or
tripped (the safety checker's latched safe mode) with the reason, at ``health_rate`` and
at once on every change.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.rotations import mat_to_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.locomotion.controller import (
    MPC_PHASES,
    CommandError,
    LocomotionConfig,
    LocomotionController,
    NodeOptions,
)
from quadmanip.services.locomotion.deadline import DeadlineMonitor


class LocomotionNode(Service):
    """Answers each LowState with a LegCommand; takes mode/velocity/pose commands."""

    name = "locomotion"
    config_type = LocomotionConfig
    config_name = "locomotion"
    inputs = (
        Input("sim/lowstate", doc="500 Hz encoders + IMU"),
        Input("locomotion/cmd_vel", doc="body velocity (base frame)"),
        Input("locomotion/body_pose", doc="body pose offsets (standing)"),
        Input("locomotion/mode", doc="stand/sit/damp/walk/recover"),
        Input("locomotion/payload", doc="mass held in the gripper"),
        Input("sim/status", doc="command age and leg timeouts at the robot"),
    )
    outputs = (
        Output("sim/leg_command"),
        Output("locomotion/odometry"),
        Output("locomotion/debug"),
        Output("locomotion/health"),
    )

    def setup(self) -> None:
        cfg: LocomotionConfig = self.config
        self.ctl = LocomotionController(cfg)
        self.lock = threading.Lock()
        self.rejected = 0
        self.ticks = 0
        self.pub_cmd = self.publisher("sim/leg_command")
        self.pub_odom = self.publisher("locomotion/odometry")
        self.pub_debug = self.publisher("locomotion/debug")
        self.pub_health = self.publisher("locomotion/health")
        self.deadline = DeadlineMonitor(cfg.deadline)
        self._health_key: tuple[str, str, str] = ("", "", "")
        self._health_wall = 0.0
        self._pending: tuple[m.LowState, float] | None = None
        self._wake = threading.Condition()
        self._last_stamp = 0.0
        self._last_mpc_tick = -1
        self._last_phase = self.ctl.phase
        self._last_cmd: m.LegCommand | None = None
        if cfg.node.start_mode != "damp":
            self.ctl.set_mode(cfg.node.start_mode)
        self.subscribe("locomotion/mode", self._on_mode)
        self._payload: m.Payload | None = None
        self.subscribe("locomotion/payload", self._on_payload)
        self.subscribe("locomotion/cmd_vel", self._on_cmd_vel)
        self.subscribe("locomotion/body_pose", self._on_body_pose)
        self.subscribe("sim/status", self._on_robot_status)
        self._control = threading.Thread(target=self._control_loop, name="control", daemon=True)
        self._control.start()
        self.subscribe("sim/lowstate", self._on_lowstate)
        self.log.info("locomotion ready", profile=cfg.profile, mpc_every=self.ctl.mpc_every)

    # ------------------------------------------------------------------ commands
    def _reject(self, what: str, exc: Exception) -> None:
        self.rejected += 1
        # once a second per command: a client that keeps commanding a damped
        # robot at 20 Hz buried the trip's own log line (the count says how many)
        self.log.throttled(
            f"reject-{what}",
            1.0,
            logging.WARNING,
            "command rejected",
            command=what,
            reason=str(exc),
            total=self.rejected,
        )

    def _on_mode(self, msg: m.LocomotionMode) -> None:
        with self.lock:
            try:
                before = (self.ctl.mode, self.ctl.phase)
                self.ctl.set_mode(msg.mode)
                if (self.ctl.mode, self.ctl.phase) != before:  # a repeated request is quiet
                    self.log.info("mode", mode=msg.mode, phase=self.ctl.phase)
                if msg.mode == "recover" and self.ctl.phase == "safe":
                    self.log.warning("cannot recover", reason=self.ctl.trip_reason)
            except CommandError as exc:
                self._reject("mode", exc)
            self._publish_health(self._last_stamp, force=True)

    def _on_robot_status(self, msg: m.RobotStatus) -> None:
        with self.lock:
            self.deadline.robot_status(
                msg.cmd_age_p50, msg.leg_timeouts, waits=msg.mode == "lockstep"
            )

    def _on_payload(self, msg: m.Payload) -> None:
        if self._payload is None or abs(msg.mass - self._payload.mass) > 1e-9:
            self.log.info("payload", mass=round(float(msg.mass), 3), object=msg.object_name)
        self._payload = msg

    def _on_cmd_vel(self, msg: m.BodyVelocityCommand) -> None:
        with self.lock:
            try:
                # Time of arrival in robot time: the last LowState stamp.
                self.ctl.set_velocity(msg.vx, msg.vy, msg.wz, now=self._last_stamp)
            except CommandError as exc:
                self._reject("cmd_vel", exc)

    def _on_body_pose(self, msg: m.BodyPoseCommand) -> None:
        with self.lock:
            try:
                self.ctl.set_body_pose(
                    msg.z_offset, msg.x_offset, msg.y_offset, msg.roll, msg.pitch, msg.yaw
                )
            except CommandError as exc:
                self._reject("body_pose", exc)

    # ------------------------------------------------------------------ control loop
    def _on_lowstate(self, ls: m.LowState) -> None:
        """Zenoh callback: hand the newest LowState to the control thread. The time kept
        is the arrival of the oldest LowState not yet answered: the answer's lateness is
        measured from there, so skipping a stale state hides no delay."""
        with self._wake:
            first = self._pending[1] if self._pending is not None else time.perf_counter()
            self._pending = (ls, first)
            self._wake.notify()

    def _control_loop(self) -> None:
        while not self.stop_event.is_set():
            with self._wake:
                while self._pending is None and not self.stop_event.is_set():
                    self._wake.wait(0.1)
                item, self._pending = self._pending, None
            if item is None:
                continue
            try:
                self._answer(*item)
            except Exception as exc:  # noqa: BLE001 - the loop must outlive one bad tick
                # No answer for this tick: the robot side damps the legs if this repeats.
                self.step_errors += 1
                self.log.throttled("control", 1.0, logging.ERROR, "control tick raised",
                                   error=repr(exc), errors=self.step_errors, exc_info=True)  # fmt: skip

    def _answer(self, ls: m.LowState, arrived: float) -> None:
        with self.lock:
            if self._last_cmd is not None and ls.tick < self._last_cmd.tick - 1:
                # Ticks went backwards: the sim (or hardware adapter) restarted. Start over
                # in damping, like a robot whose controller was just switched on.
                self.log.warning("lowstate tick went back; restarting the controller",
                                 tick=ls.tick, last=self._last_cmd.tick)  # fmt: skip
                self.ctl = LocomotionController(self.config)
                self.deadline.restart()
                self._last_cmd = None
                self._last_phase = self.ctl.phase
            if self._last_cmd is not None and ls.tick <= self._last_cmd.tick:
                # A LowState seen before (the lockstep sim republishes while it waits):
                # answer again with the same command instead of stepping the controller.
                if ls.tick == self._last_cmd.tick:
                    self.pub_cmd.publish(self._last_cmd)
                return
            self._last_stamp = float(ls.stamp)
            self.ctl.held_mass = held_mass(self._payload, ls.joints, self.config.node)
            mpc_before = self.ctl.mpc_tick
            out = self.ctl.step(
                ls.stamp,
                ls.joints.q,
                ls.joints.dq,
                ls.imu.orientation,
                ls.imu.angular_velocity,
                ls.imu.linear_acceleration,
                ls.joints.tau,
            )
            cmd = m.LegCommand(
                stamp=ls.stamp,
                tick=ls.tick,
                q_des=out.q_des,
                dq_des=out.dq_des,
                kp=out.kp,
                kd=out.kd,
                tau_ff=out.tau_ff,
            )
            self.pub_cmd.publish(cmd)
            answer_s = time.perf_counter() - arrived
            self._last_cmd = cmd
            self.ticks += 1
            ran_mpc = self.ctl.mpc_tick != mpc_before
            self.deadline.tick(
                float(ls.stamp), int(ls.tick), answer_s,
                self.ctl.debug.mpc_step_s if ran_mpc else None, arrived,
            )  # fmt: skip
            self._after_tick(ls.stamp)
            if self.ctl.phase in MPC_PHASES:
                if self.ticks % max(1, self.config.node.odometry_every) == 0:
                    self.pub_odom.publish(self._odometry(ls.stamp))
                if self.ctl.mpc_tick != self._last_mpc_tick:
                    self._last_mpc_tick = self.ctl.mpc_tick
                    self.pub_debug.publish(self._debug(ls.stamp))

    def _after_tick(self, stamp: float) -> None:
        """Phase changes, trips and the deadline state: log them, publish health."""
        ctl = self.ctl
        if ctl.phase != self._last_phase:
            if ctl.phase == "safe":
                self.log.warning("safety trip: safe mode (legs damped) until 'recover'",
                                 reason=ctl.trip_reason, t=round(stamp, 3))  # fmt: skip
            self.log.info("phase", old=self._last_phase, new=ctl.phase, t=round(stamp, 3))
            self._last_phase = ctl.phase
        change = self.deadline.evaluate(float(stamp))
        if change is not None:
            state, reason = change
            if state == "degraded":
                self.log.warning("degraded: slower on purpose", reason=reason,
                                 speed_scale=self.deadline.speed_scale)  # fmt: skip
            else:
                self.log.info("deadline ok again: full speed limits", t=round(stamp, 3))
        ctl.degraded = self.deadline.state == "degraded"
        ctl.speed_scale = self.deadline.speed_scale
        self._publish_health(stamp)

    def _health_state(self) -> tuple[str, str]:
        ctl, dl = self.ctl, self.deadline
        if ctl.phase == "safe":
            return "tripped", ctl.trip_reason or "tripped"
        if ctl.phase == "righting":
            return "tripped", f"recovering: righting itself from its {ctl.lying_side()}"
        if dl.state == "degraded":
            return "degraded", dl.reason
        return "ok", ""

    def health(self, stamp: float) -> m.LocomotionHealth:
        """The health message for now (state, reason and counters)."""
        ctl, dl = self.ctl, self.deadline
        state, reason = self._health_state()
        res = self.scheduling_result
        return m.LocomotionHealth(
            stamp=float(stamp),
            state=state,
            reason=reason[:256],
            phase=ctl.phase,
            upright=ctl.lying_side() == "upright",
            scheduling=(res.summary() if res is not None else "not applied")[:128],
            max_speed=float(ctl.velocity_bound()[0]),
            missed_ticks=dl.missed_ticks,
            late_answers=dl.late_answers,
            mpc_overruns=dl.mpc_overruns,
            answer_ms_p99=dl.answer_p99 * 1e3,
            leg_timeouts=dl.leg_timeouts,
            cmd_age_ticks=dl.cmd_age_ticks,
            degraded_episodes=dl.degraded_episodes,
            trips=ctl.trips,
            rejected_commands=self.rejected,
        )

    def _publish_health(self, stamp: float, force: bool = False) -> None:
        """At ``health_rate`` (wall), and at once when state, reason or phase change."""
        state, reason = self._health_state()
        key = (state, reason, self.ctl.phase)
        now = time.monotonic()
        period = 1.0 / max(self.config.node.health_rate, 1e-6)
        if force or key != self._health_key or now - self._health_wall >= period:
            self.pub_health.publish(self.health(stamp))
            self._health_key, self._health_wall = key, now

    def _odometry(self, stamp: float) -> m.Odometry:
        est = self.ctl.est
        r = est.R
        q = mat_to_quat(r)
        return m.Odometry(
            stamp=stamp,
            position=est.position,
            orientation=q,
            linear_velocity=r.T @ est.velocity,
            angular_velocity=est.omega_body,
        )

    def _debug(self, stamp: float) -> m.LocomotionDebug:
        d = self.ctl.debug
        pred = d.predicted[:, 3:6] if d.predicted.size else np.zeros((0, 3))
        return m.LocomotionDebug(
            stamp=stamp,
            gait_phase=d.gait_phase,
            contact=d.contact,
            foot_forces=d.foot_forces,
            mpc_solve_ms=d.mpc_solver_s * 1e3,
            mpc_predicted_positions=pred,
        )


def held_mass(payload: m.Payload | None, js: m.JointState, opt: NodeOptions) -> float:
    """Mass in the gripper for the MPC: manipulation's last payload message; without one,
    fingers squeezing on something count as holding ``opt.held_object_mass``."""
    if payload is not None:
        return float(payload.mass)
    holding = js.gripper_effort > opt.grip_effort_threshold and js.gripper_gap > opt.grip_min_gap
    return opt.held_object_mass if holding else 0.0


def main(argv: list[str]) -> int:
    """Entry point of `quadmanip service locomotion`."""
    return run_service(LocomotionNode, argv)
