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
"""

from __future__ import annotations

import threading

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.rotations import mat_to_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.locomotion.controller import (
    CommandError,
    LocomotionConfig,
    LocomotionController,
    NodeOptions,
)


class LocomotionNode(Service):
    """Answers each LowState with a LegCommand; takes mode/velocity/pose commands."""

    name = "locomotion"
    config_type = LocomotionConfig
    config_name = "locomotion"
    inputs = (
        Input("sim/lowstate", doc="500 Hz encoders + IMU"),
        Input("locomotion/cmd_vel", doc="body velocity (base frame)"),
        Input("locomotion/body_pose", doc="body pose offsets (standing)"),
        Input("locomotion/mode", doc="stand/sit/damp/walk"),
        Input("locomotion/payload", doc="mass held in the gripper"),
    )
    outputs = (
        Output("sim/leg_command"),
        Output("locomotion/odometry"),
        Output("locomotion/debug"),
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
        self.subscribe("sim/lowstate", self._on_lowstate)
        self.log.info("locomotion ready", profile=cfg.profile, mpc_every=self.ctl.mpc_every)

    # ------------------------------------------------------------------ commands
    def _reject(self, what: str, exc: Exception) -> None:
        self.rejected += 1
        self.log.warning("command rejected", command=what, reason=str(exc), total=self.rejected)

    def _on_mode(self, msg: m.LocomotionMode) -> None:
        with self.lock:
            try:
                self.ctl.set_mode(msg.mode)
                self.log.info("mode", mode=msg.mode)
            except CommandError as exc:
                self._reject("mode", exc)

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
        with self.lock:
            if self._last_cmd is not None and ls.tick < self._last_cmd.tick - 1:
                # Ticks went backwards: the sim (or hardware adapter) restarted. Start over
                # in damping, like a robot whose controller was just switched on.
                self.log.warning("lowstate tick went back; restarting the controller",
                                 tick=ls.tick, last=self._last_cmd.tick)  # fmt: skip
                self.ctl = LocomotionController(self.config)
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
            out = self.ctl.step(
                ls.stamp,
                ls.joints.q,
                ls.joints.dq,
                ls.imu.orientation,
                ls.imu.angular_velocity,
                ls.imu.linear_acceleration,
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
            self._last_cmd = cmd
            self.ticks += 1
            if self.ctl.phase != self._last_phase:
                self.log.info("phase", old=self._last_phase, new=self.ctl.phase, t=ls.stamp)
                self._last_phase = self.ctl.phase
            if self.ctl.phase in ("balance", "walk", "stopping"):
                if self.ticks % max(1, self.config.node.odometry_every) == 0:
                    self.pub_odom.publish(self._odometry(ls.stamp))
                if self.ctl.mpc_tick != self._last_mpc_tick:
                    self._last_mpc_tick = self.ctl.mpc_tick
                    self.pub_debug.publish(self._debug(ls.stamp))

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
