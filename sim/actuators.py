"""The actuator layer: what a real quadruped SDK does between the bus and the motors.

Every physics step it turns the latest per-joint commands into motor torques and writes
them to ``data.ctrl`` of the model's motor actuators. Nothing else in the simulator moves
the robot (docs/architecture.md, "Honest simulation").

* Legs: ``tau = kp (q_des - q) + kd (dq_des - dq) + tau_ff`` (the low-level command of
  Unitree-style SDKs). If no valid leg command arrives for ``leg_timeout`` seconds of sim
  time the legs fall back to damping, ``tau = -kd_damp dq``, the safety mode real robots
  use when their controller dies. The layer starts in damping: a robot whose controller
  is not running does not hold itself up.
* Arm: time-stamped joint trajectories (t[N], q[N,4], dq[N,4], kp, kd, tau_ff[N,4]),
  positions interpolated with cubic Hermite splines and feed-forward torques linearly at
  every physics step, so the arm is smooth whatever rate its owner publishes at:
  ``tau = kp (q(t) - q) + kd (dq(t) - dq) + tau_ff(t)`` (the owner sends e.g. the arm's
  gravity torque as tau_ff). After the last knot the last point is held. A new trajectory
  replaces the old one from its first time stamp on (the old one keeps running until
  then). Before any trajectory the arm servos hold the pose they started in.
* Gripper: stiff position control on the finger gap, with the finger force clamped to
  the commanded ``max_force`` (a real parallel gripper's current limit): fingers blocked
  by an object squeeze it with ``max_force`` per finger. Like a real gripper's motion
  controller, the loop does not jump to a new gap: its setpoint moves toward the
  commanded gap at the description's rated gap speed (``velocity_limits``, 0.15 m/s), so
  the fingers close at that speed and touch objects gently. The setpoint never leads the
  measured gap by more than it takes to saturate the force (anti-windup): a blocked
  finger squeezes at ``max_force``, and one whose object is pulled away, or that is told
  to reverse, follows the ramp instead of leaping at the full force. The finger force
  also obeys the torque-speed envelope below (the rated gap speed is the drive's no-load
  speed), so the motor cannot push the fingers past it even in contact transients (an
  object slipping out of a squeeze); the drive's reflected inertia (the finger joints'
  armature in the description) keeps one step's speed change small enough for that
  explicit limit to hold within 1 %. Contacts can still drag the fingers a little faster
  for a few milliseconds (pads rubbing on the floor as the arm moves: up to 7 % in the
  grasp benchmark), as they would backdrive a real drive.
* Every torque is clamped to the actuator's limit from the model (``ctrlrange`` times
  gear) and to a linear torque-speed envelope: above a corner speed the torque available
  in the direction of motion falls linearly to zero at the joint's no-load speed, while
  braking torque stays available (a DC motor driven by a voltage-limited amplifier).
* Commands with the wrong size, non-finite numbers or negative gains are rejected,
  counted and logged; they never reach physics.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common.actuator_commands import (
    ArmSegment,
    LegMode,
    LegWatchdog,
    active_segment,
    check_arm_trajectory,
    check_leg_command,
    hermite,
    lerp,
    queue_segment,
)
from quadmanip.common.joint_layout import GRIPPER_ACTUATOR
from quadmanip.common.joint_layout import N_ARM_JOINTS as N_ARM
from quadmanip.common.joint_layout import N_LEG_JOINTS as N_LEG
from quadmanip.common.log import get_logger

log = get_logger("sim.actuators")


@dataclass(frozen=True)
class ActuatorConfig:
    """Parameters of the actuator layer (section ``[actuators]`` of configs/sim.toml)."""

    # Leg commands older than this (sim time, s) put the legs in damping mode.
    leg_timeout: float = 0.05
    # Damping gain on the legs in damping mode (N m s / rad).
    leg_damping_kd: float = 2.0
    # No-load joint speeds (rad/s) for the torque-speed envelope, used when the robot
    # description has no ``velocity_limits`` numeric; <= 0 disables the envelope.
    leg_max_speed: float = 30.0
    arm_max_speed: float = 6.0
    # Fraction of the no-load speed up to which full torque is available.
    torque_speed_corner: float = 0.5
    # Arm servo gains used before the first trajectory (holding the initial pose).
    arm_hold_kp: float = 60.0
    arm_hold_kd: float = 2.0
    # Gripper position loop on the finger gap (N/m, N s/m) and default force limit (N).
    # Stiff, like a real parallel gripper's drive: blocked by an object, the fingers
    # squeeze at the commanded max_force (the current limit), not at kp times a few mm.
    # The gap's inertia is the description's fingers with the drive's reflected rotor
    # inertia (armature 0.5 kg per finger: 0.27 kg on the gap): 20000 N/m with 150 N s/m
    # is damped at zeta ~0.9 and far from the 1 ms step's stability limit.
    gripper_kp: float = 20000.0
    gripper_kd: float = 150.0
    gripper_default_force: float = 20.0


@dataclass(frozen=True)
class JointMap:
    """Addresses of one group of joints in qpos/qvel and of their motor actuators."""

    names: tuple[str, ...]
    qpos: np.ndarray  # int, index into data.qpos
    dof: np.ndarray  # int, index into data.qvel / qfrc_*
    act: np.ndarray  # int, index into data.ctrl
    gear: np.ndarray  # float, actuator gear (torque = gear * ctrl)
    tau_max: np.ndarray  # float, torque limit (N m or N) in joint space

    max_speed: np.ndarray  # float, no-load speed (rad/s or m/s); inf = no envelope

    @staticmethod
    def build(
        model: mujoco.MjModel, names: tuple[str, ...] | list[str], default_speed: float
    ) -> JointMap:
        """Find each named joint and the motor actuator that drives it directly."""
        names = tuple(names)
        qpos, dof, act = [], [], []
        for name in names:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise KeyError(f"joint {name!r} not in the model")
            qpos.append(int(model.jnt_qposadr[jid]))
            dof.append(int(model.jnt_dofadr[jid]))
            aid = _actuator_for_joint(model, jid)
            if aid < 0:
                raise KeyError(f"no motor actuator drives joint {name!r}")
            act.append(aid)
        return JointMap._with_actuators(model, names, qpos, dof, act, default_speed)

    @staticmethod
    def _with_actuators(
        model: mujoco.MjModel,
        names: tuple[str, ...],
        qpos: list[int],
        dof: list[int],
        act: list[int],
        default_speed: float,
    ) -> JointMap:
        gear = [float(model.actuator_gear[a, 0]) for a in act]
        speeds = actuator_speed_limits(model)
        if speeds is not None:
            max_speed = [float(speeds[a]) for a in act]
        else:
            max_speed = [default_speed if default_speed > 0 else np.inf] * len(act)
        return JointMap(
            names=names,
            qpos=np.asarray(qpos, dtype=np.intp),
            dof=np.asarray(dof, dtype=np.intp),
            act=np.asarray(act, dtype=np.intp),
            gear=np.asarray(gear, dtype=float),
            tau_max=np.asarray(
                [_torque_limit(model, a, g) for a, g in zip(act, gear, strict=True)], dtype=float
            ),
            max_speed=np.asarray(max_speed, dtype=float),
        )


def actuator_speed_limits(model: mujoco.MjModel) -> np.ndarray | None:
    """Per-actuator no-load speeds from the description's ``velocity_limits`` numeric."""
    nid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, "velocity_limits")
    if nid < 0:
        return None
    adr, size = int(model.numeric_adr[nid]), int(model.numeric_size[nid])
    if size != model.nu:
        log.warning("velocity_limits size differs from the number of actuators", size=size)
        return None
    return np.asarray(model.numeric_data[adr : adr + size], dtype=float)


def _gripper_map(model: mujoco.MjModel, joints: tuple[str, ...], actuator: str) -> JointMap:
    """The gripper: its finger joints (the gap is their sum) and its single actuator."""
    aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
    if aid < 0:
        raise KeyError(f"actuator {actuator!r} not in the model")
    qpos, dof = [], []
    for name in joints:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise KeyError(f"joint {name!r} not in the model")
        qpos.append(int(model.jnt_qposadr[jid]))
        dof.append(int(model.jnt_dofadr[jid]))
    jm = JointMap._with_actuators(model, joints, [aid], [aid], [aid], np.inf)
    return JointMap(
        names=joints,
        qpos=np.asarray(qpos, dtype=np.intp),
        dof=np.asarray(dof, dtype=np.intp),
        act=jm.act,
        gear=jm.gear,
        tau_max=jm.tau_max,
        max_speed=jm.max_speed,
    )


def _actuator_for_joint(model: mujoco.MjModel, jid: int) -> int:
    for aid in range(model.nu):
        if (
            model.actuator_trntype[aid] == mujoco.mjtTrn.mjTRN_JOINT
            and model.actuator_trnid[aid, 0] == jid
        ):
            return aid
    return -1


def _torque_limit(model: mujoco.MjModel, aid: int, gear: float) -> float:
    """Joint-space torque limit of an actuator: ctrlrange * gear, else forcerange."""
    limits = []
    if model.actuator_ctrllimited[aid]:
        lo, hi = model.actuator_ctrlrange[aid]
        limits.append(min(abs(lo), abs(hi)) * abs(gear))
    if model.actuator_forcelimited[aid]:
        lo, hi = model.actuator_forcerange[aid]
        limits.append(min(abs(lo), abs(hi)) * abs(gear))
    return min(limits) if limits else float("inf")


def torque_speed_clamp(
    tau: np.ndarray,
    dq: np.ndarray,
    tau_max: np.ndarray,
    max_speed: np.ndarray | float,
    corner: float,
) -> np.ndarray:
    """Clamp torques to ``|tau| <= tau_max`` and to a linear torque-speed envelope.

    Torque pushing in the direction of motion is limited to ``tau_max`` up to
    ``corner * max_speed`` and then falls linearly to zero at ``max_speed``; braking
    torque (opposite to the motion) keeps the full limit.
    """
    tau = np.clip(tau, -tau_max, tau_max)
    max_speed = np.asarray(max_speed, dtype=float)
    with np.errstate(invalid="ignore"):
        scale = np.clip((max_speed - np.abs(dq)) / ((1.0 - corner) * max_speed), 0.0, 1.0)
    scale = np.where(np.isfinite(max_speed) & (max_speed > 0), scale, 1.0)
    driving = tau * dq > 0.0
    lim = tau_max * scale
    return np.where(driving, np.clip(tau, -lim, lim), tau)


__all__ = [
    "ActuatorConfig",
    "ActuatorLayer",
    "ArmSegment",
    "JointMap",
    "LegMode",
    "hermite",
    "lerp",
    "torque_speed_clamp",
]


class ActuatorLayer:
    """Per-joint PD + feed-forward motor layer with timeout damping (see module doc)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        config: ActuatorConfig,
        leg_joints: tuple[str, ...] | list[str],
        arm_joints: tuple[str, ...] | list[str],
        gripper_joints: tuple[str, ...] | list[str],
        gripper_actuator: str = GRIPPER_ACTUATOR,
    ) -> None:
        if len(leg_joints) != N_LEG or len(arm_joints) != N_ARM:
            raise ValueError(f"expected {N_LEG} leg joints and {N_ARM} arm joints")
        self.model = model
        self.config = config
        self.legs = JointMap.build(model, leg_joints, config.leg_max_speed)
        self.arm = JointMap.build(model, arm_joints, config.arm_max_speed)
        self.gripper = _gripper_map(model, tuple(gripper_joints), gripper_actuator)
        self.rejected = 0
        self.reject_reasons: dict[str, int] = {}
        # Legs: start in damping, no command yet; the watchdog (shared with hardware
        # adapters) decides active / damping / e-stop and counts the timeouts.
        self._leg_cmd: tuple[np.ndarray, ...] | None = None
        self.watchdog = LegWatchdog(config.leg_timeout)
        self.leg_mode = LegMode.DAMPING
        # Arm: hold the pose found at the first step.
        self._arm_segments: list[ArmSegment] = []
        self._arm_hold: np.ndarray | None = None
        # Gripper: hold the opening found at the first step. ``_grip_gap`` is the commanded
        # gap, ``_grip_ref`` the ramped setpoint of the position loop, ``_grip_t`` the sim
        # time it was last advanced.
        self._grip_gap: float | None = None
        self._grip_ref: float | None = None
        self._grip_t = 0.0
        self._grip_force = float(config.gripper_default_force)
        self.tau = np.zeros(model.nu)
        # Legs + arm as one 16-vector (wire order) for the per-step loop.
        self._j_qpos = np.concatenate([self.legs.qpos, self.arm.qpos])
        self._j_dof = np.concatenate([self.legs.dof, self.arm.dof])
        self._j_act = np.concatenate([self.legs.act, self.arm.act])
        self._j_gear = np.concatenate([self.legs.gear, self.arm.gear])
        self._j_tau_max = np.concatenate([self.legs.tau_max, self.arm.tau_max])
        self._j_max_speed = np.concatenate([self.legs.max_speed, self.arm.max_speed])
        self._j_corner = np.where(
            np.isfinite(self._j_max_speed) & (self._j_max_speed > 0),
            config.torque_speed_corner * self._j_max_speed,
            np.inf,
        )
        self._tau16 = np.zeros(N_LEG + N_ARM)
        self._grip_act = int(self.gripper.act[0])
        self._grip_gear = float(self.gripper.gear[0])
        self._grip_tau_max = float(self.gripper.tau_max[0])
        # Rated gap speed (m/s) from the description; inf (no numeric) = no ramp.
        speed = float(self.gripper.max_speed[0])
        self._grip_speed = speed if np.isfinite(speed) and speed > 0 else np.inf
        self._grip_corner = config.torque_speed_corner * self._grip_speed

    # ----------------------------------------------------------------- commands
    def _reject(self, what: str, reason: str) -> bool:
        self.rejected += 1
        key = f"{what}: {reason}"
        self.reject_reasons[key] = self.reject_reasons.get(key, 0) + 1
        log.throttled(
            f"reject-{what}",
            1.0,
            logging.WARNING,
            "command rejected",
            command=what,
            reason=reason,
            total=self.rejected,
        )
        return False

    def set_leg_command(
        self,
        now: float,
        q_des: np.ndarray,
        dq_des: np.ndarray,
        kp: np.ndarray,
        kd: np.ndarray,
        tau_ff: np.ndarray,
    ) -> bool:
        """Accept a leg command received at sim time ``now``; False if rejected."""
        cmd, reason = check_leg_command(q_des, dq_des, kp, kd, tau_ff)
        if cmd is None:
            return self._reject("leg", reason)
        self._leg_cmd = tuple(cmd)
        self.watchdog.command(now)
        return True

    @property
    def leg_timeouts(self) -> int:
        """Times the legs fell back to damping because commands stopped."""
        return self.watchdog.timeouts

    def engage_estop(self, reason: str) -> None:
        """Emergency stop: legs and arm damp at once, latched until :meth:`reset_estop`."""
        if self.watchdog.estop_reason is None:
            log.warning("emergency stop: damping", reason=reason)
        self.watchdog.engage_estop(reason)

    def reset_estop(self) -> None:
        """Release the emergency stop (the legs wait for a fresh command; the arm holds
        where it is until a new trajectory)."""
        if self.watchdog.estop_reason is not None:
            log.info("emergency stop reset")
            self._arm_segments = []
            self._arm_hold = None
        self.watchdog.reset_estop()

    def set_arm_trajectory(
        self,
        now: float,
        t: np.ndarray,
        q: np.ndarray,
        dq: np.ndarray,
        kp: np.ndarray,
        kd: np.ndarray,
        tau_ff: np.ndarray | None = None,
    ) -> bool:
        """Accept an arm trajectory; it takes over from its first time stamp on.
        ``tau_ff`` (N, 4): feed-forward torque per knot (N m), None for zeros."""
        seg, reason = check_arm_trajectory(t, q, dq, kp, kd, tau_ff)
        if seg is None:
            return self._reject("arm", reason)
        self._arm_segments = queue_segment(self._arm_segments, seg)
        return True

    def set_gripper_command(self, now: float, gap: float, max_force: float) -> bool:
        """Accept a gripper command: finger gap (m) and force limit (N)."""
        try:
            gap, max_force = float(gap), float(max_force)
        except (TypeError, ValueError):
            return self._reject("gripper", "not a number")
        if not (np.isfinite(gap) and np.isfinite(max_force)):
            return self._reject("gripper", "non-finite value")
        if max_force < 0:
            return self._reject("gripper", "negative force")
        lo, hi = self.gripper_gap_range()
        self._grip_gap = float(np.clip(gap, lo, hi))
        self._grip_force = max_force
        return True

    # ------------------------------------------------------------------ gripper
    @property
    def gripper_speed(self) -> float:
        """Rated finger-gap speed (m/s) the setpoint ramps at (inf: no ramp)."""
        return self._grip_speed

    @property
    def gripper_setpoint(self) -> float | None:
        """The position loop's current (ramped) gap setpoint, None before the first step."""
        return self._grip_ref

    def gripper_gap(self, data: mujoco.MjData) -> float:
        """Finger gap (m): the sum of the finger slide positions (0 = closed)."""
        return float(np.sum(data.qpos[self.gripper.qpos]))

    def gripper_gap_range(self) -> tuple[float, float]:
        """Gap range allowed by the finger joint limits."""
        jr = [
            self.model.jnt_range[mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, n)]
            for n in self.gripper.names
        ]
        return float(sum(max(r[0], 0.0) for r in jr)), float(sum(r[1] for r in jr))

    # -------------------------------------------------------------------- apply
    def leg_mode_at(self, now: float) -> LegMode:
        """Active while the last valid leg command is younger than the timeout (and no
        emergency stop is latched)."""
        return self.watchdog.mode_at(now)

    def apply(self, data: mujoco.MjData) -> None:
        """Compute and write the motor torques for the current physics step.

        Legs and arm are handled as one 16-vector (one gather, one clamp, one scatter):
        this runs at 1 kHz in Python, so it is kept to a handful of numpy calls.
        """
        now = float(data.time)
        cfg = self.config
        q = data.qpos[self._j_qpos]
        dq = data.qvel[self._j_dof]
        # Legs.
        mode = self.watchdog.update(now)
        if mode is not self.leg_mode:
            if mode is LegMode.DAMPING and self.leg_mode is LegMode.ACTIVE:
                log.warning("leg commands timed out: damping", t=round(now, 4),
                            timeouts=self.leg_timeouts)  # fmt: skip
            else:
                log.info("leg mode", old=self.leg_mode.value, new=mode.value, t=round(now, 4))
            self.leg_mode = mode
        tau = self._tau16
        if mode is LegMode.ACTIVE:
            q_des, dq_des, kp, kd, ff = self._leg_cmd  # type: ignore[misc]
            tau[:N_LEG] = kp * (q_des - q[:N_LEG]) + kd * (dq_des - dq[:N_LEG]) + ff
        else:
            tau[:N_LEG] = -cfg.leg_damping_kd * dq[:N_LEG]
        # Arm.
        qa, dqa = q[N_LEG:], dq[N_LEG:]
        seg = active_segment(self._arm_segments, now)
        if mode is LegMode.ESTOP:  # the arm damps too
            self._arm_segments = []
            self._arm_hold = None
            tau[N_LEG:] = -cfg.arm_hold_kd * dqa
        elif seg is not None:
            qd, dqd = hermite(seg.t, seg.q, seg.dq, now)
            tau[N_LEG:] = seg.kp * (qd - qa) + seg.kd * (dqd - dqa)
            if seg.tau_ff is not None:
                tau[N_LEG:] += lerp(seg.t, seg.tau_ff, now)
        else:  # no trajectory has started yet: the servos hold their start pose
            if self._arm_hold is None:
                self._arm_hold = qa.copy()
            tau[N_LEG:] = cfg.arm_hold_kp * (self._arm_hold - qa) - cfg.arm_hold_kd * dqa
        np.clip(tau, -self._j_tau_max, self._j_tau_max, out=tau)
        if np.any(np.abs(dq) > self._j_corner):  # torque-speed envelope only matters here
            tau[:] = torque_speed_clamp(
                tau, dq, self._j_tau_max, self._j_max_speed, cfg.torque_speed_corner
            )
        # Gripper: one actuator pulls the gap tendon (both fingers, synchronised by the
        # gripper's linkage); position loop on the gap, force clamped to max_force.
        gap = float(data.qpos[self.gripper.qpos].sum())
        gap_dot = float(data.qvel[self.gripper.dof].sum())
        if self._grip_gap is None:
            self._grip_gap = gap
        fmax = min(self._grip_force, self._grip_tau_max)
        ref = self._grip_ref
        if ref is None or now < self._grip_t:  # first step, or the sim was reset
            ref, self._grip_t = gap, now
        # The setpoint ramps toward the commanded gap at the rated speed...
        if np.isfinite(self._grip_speed):
            step = self._grip_speed * (now - self._grip_t)
            ref += min(max(self._grip_gap - ref, -step), step)
        else:
            ref = self._grip_gap
        self._grip_t = now
        # ...and leads the fingers by at most what saturates the force (anti-windup): at a
        # standstill the full force (blocked fingers squeeze at fmax), at the rated speed
        # only the tracking lag (1.1 mm). Freed fingers follow the ramp; fingers dragged
        # faster than that (pads rubbing on the floor) overtake the setpoint and are braked.
        v_ratio = abs(gap_dot) / self._grip_speed
        lead = (cfg.gripper_kd * self._grip_speed + fmax * max(0.0, 1.0 - v_ratio)) / cfg.gripper_kp
        ref = min(max(ref, gap - lead), gap + lead)
        self._grip_ref = ref
        f = cfg.gripper_kp * (ref - gap) - cfg.gripper_kd * gap_dot
        f = min(max(f, -fmax), fmax)
        # The drive's torque-speed line: force in the direction of motion falls to zero at
        # the no-load (rated) speed, so the motor cannot push the fingers past it whatever
        # contacts do (an object slipping out of the grip). Explicit, so it relies on the
        # drive's reflected inertia (the finger joints' armature) to keep the speed change
        # of one step small.
        if f * gap_dot > 0.0 and abs(gap_dot) > self._grip_corner:
            lim = self._grip_tau_max * max(
                0.0, (self._grip_speed - abs(gap_dot)) / (self._grip_speed - self._grip_corner)
            )
            f = min(max(f, -lim), lim)
        # Write ctrl (ctrl = tau / gear).
        data.ctrl[self._j_act] = tau / self._j_gear
        data.ctrl[self._grip_act] = f / self._grip_gear
        self.tau[self._j_act] = tau
        self.tau[self._grip_act] = f
