"""The locomotion controller: modes, estimator, gait, MPC and legs, with no transport.

`LocomotionController.step()` is called at the leg-command rate (500 Hz) with what a real
robot measures (joint encoders and the IMU) and returns the 12 per-joint commands
(q_des, dq_des, kp, kd, tau_ff) for the actuator layer. Every `mpc_every` ticks
(T_pred = 0.03 s) it solves the convex MPC. The node (`node.py`) wires it to Zenoh; tests and
the benchmark drive it in-process with the simulator as the plant.

Modes: ``damp`` (passive damping), ``sit`` (fold the legs), ``stand`` (stand up if needed,
then balance on four feet with the MPC, following body pose commands) and ``walk`` (trot
with body velocity commands). A walk command that stops arriving for `cmd_timeout` brings
the robot to a stop and back to four-feet standing.

Safety (safety.py) is checked every tick: a fall, buckling legs, a joint out of range or a
saturated motor latches the ``safe`` phase (legs damped, ``trip_reason`` kept) and every
command but ``damp`` and ``recover`` is refused. ``recover`` is the explicit reset: lying
on a side, the robot rights itself (self_righting.py, phase ``righting``) and stands up;
upright, it stands up; on its back it stays safe and says it needs help.
``degraded`` (set by the node while its deadline monitor says the loop cannot keep up)
comes with ``speed_scale`` < 1, which shrinks the velocity limits (faster commands are
refused, a running one is clipped; at 0 the robot stops and stands), and it stiffens the standing legs at the joint level: a PD on the joints runs in the actuator
layer at its own rate, so it holds the stance even when the MPC's forces arrive late
(without it, standing under a load that delayed answers by 20 ms toppled the robot).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.joint_layout import LEG_SLICE, N_JOINTS, N_LEG_JOINTS, N_LEGS, leg_slice
from quadmanip.common.rotations import quat_to_mat, rpy_from_mat
from quadmanip.common.scheduling import SchedulingConfig
from quadmanip.services.locomotion.com_reference import ComReference, FsmParams
from quadmanip.services.locomotion.convex_mpc import GRAVITY, ConvexMpc, MpcParams, MpcWeights
from quadmanip.services.locomotion.deadline import DeadlineParams
from quadmanip.services.locomotion.gait import GaitParams, TrotGait
from quadmanip.services.locomotion.leg_kinematics import LegKinematics
from quadmanip.services.locomotion.safety import SafetyChecker, SafetyLimits
from quadmanip.services.locomotion.self_righting import RecoveryParams, SelfRighting, lying_side
from quadmanip.services.locomotion.state_estimator import EstimatorParams, StateEstimator
from quadmanip.services.locomotion.swing_leg import SwingParams, swing_profile, touchdown_target

MODES = ("damp", "sit", "stand", "walk", "recover")
# Phases whose body is carried by the MPC on its feet (tilt, height and joints checked).
MPC_PHASES = ("balance", "walk", "stopping")


@dataclass(frozen=True)
class Limits:
    """Accepted command ranges."""

    vx: float = 0.9
    vy: float = 0.4
    wz: float = 1.6
    z_crouch: float = 0.12  # how far the body may go down (m)
    z_raise: float = 0.03  # how far up (m)
    shift: float = 0.06  # COM shift in x and y (m)
    roll: float = 0.3
    pitch: float = 0.3
    yaw: float = 0.3


@dataclass(frozen=True)
class LegGains:
    """Joint-space gains for standing up / sitting and damping, and stance damping."""

    kp_posture: float = 60.0
    kd_posture: float = 2.0
    kd_damp: float = 2.0
    kd_stance: float = 0.5
    kd_swing: float = 0.5


@dataclass(frozen=True)
class NodeOptions:
    """Settings of the Zenoh node only ([node] table)."""

    start_mode: str = "damp"  # mode at start: damp (wait for a command) or stand
    held_object_mass: float = 0.15  # kg assumed while squeezing, without locomotion/payload
    grip_effort_threshold: float = 2.0  # N of squeeze that means "holding"
    grip_min_gap: float = 0.005  # m, below this the fingers closed on nothing
    odometry_every: int = 1  # ticks between odometry messages
    health_rate: float = 10.0  # Hz (wall) of locomotion/health; changes go out at once


@dataclass(frozen=True)
class Profile:
    """A named parameter set: MPC weights, gait timing and Algorithm 7's PLANNED_ACC."""

    weights: MpcWeights = field(default_factory=MpcWeights)
    gait: GaitParams = field(default_factory=GaitParams)
    planned_acc: float = 2.0


def default_profiles() -> dict[str, Profile]:
    """`paper` = Table 3 as printed; `tuned` = what walks best here (docs/locomotion.md)."""
    tuned = Profile(
        weights=MpcWeights(
            q_theta=(50.0, 50.0, 10.0),
            q_p=(10.0, 10.0, 50.0),
            q_omega=(1.0, 1.0, 0.3),
            q_v=(5.0, 5.0, 1.0),
            r_u=4e-5,
        ),
        gait=GaitParams(t_swing=0.2, t_stance=0.05, foot_height=0.08),
        planned_acc=10.0,
    )
    return {"paper": Profile(), "tuned": tuned}


@dataclass(frozen=True)
class LocomotionConfig:
    """Everything the controller needs (configs/locomotion.toml)."""

    control_dt: float = 0.002
    stand_height: float = 0.30  # base height when standing (m)
    stand_up_time: float = 1.2
    sit_time: float = 1.2
    cmd_timeout: float = 0.15
    pose_speed: float = 0.1  # m/s, body pose moves while standing
    stand_integral_gain: float = 4.0  # 1/s, integral action on the standing pose
    stand_integral_limit: float = 0.03  # m
    # Where a trot stops, the trunk stays (up to this far from the feet's centre, m) instead
    # of moving over the feet's centre: that move shifted the trunk 5-18 mm after every
    # stop and kept the precise approach from ending within 1 cm.
    stop_keep_max: float = 0.03
    # Standing nudges: a velocity command at or below these speeds while standing moves the
    # trunk over its feet (no step), up to ``nudge_reach`` from the feet's centre and
    # ``nudge_turn`` from the stance's yaw. A trot cannot make such small moves: a stop and
    # go of 0.4 s at 3 cm/s moved the trunk 5-16 mm, often not the way it was told, which
    # kept the precise approach from its last centimetre.
    nudge_speed: float = 0.02  # m/s per axis (the trot's own deadband)
    nudge_wz: float = 0.05  # rad/s
    nudge_reach: float = 0.04  # m
    nudge_turn: float = 0.035  # rad (2 degrees)
    held_mass: float = 0.0
    profile: str = "tuned"
    profiles: dict[str, Profile] = field(default_factory=default_profiles)
    mpc: MpcParams = field(default_factory=MpcParams)
    swing: SwingParams = field(default_factory=SwingParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    fsm: FsmParams = field(default_factory=FsmParams)
    limits: Limits = field(default_factory=Limits)
    gains: LegGains = field(default_factory=LegGains)
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    deadline: DeadlineParams = field(default_factory=DeadlineParams)
    recovery: RecoveryParams = field(default_factory=RecoveryParams)
    node: NodeOptions = field(default_factory=NodeOptions)
    # The control loop answers LowState: real-time priority where permitted (issue 12).
    scheduling: SchedulingConfig = field(
        default_factory=lambda: SchedulingConfig(policy="fifo", priority=80, fallback_nice=-10)
    )

    def __post_init__(self) -> None:
        if self.profile not in self.profiles:
            raise ValueError(f"unknown profile {self.profile!r} (have {sorted(self.profiles)})")
        if self.node.start_mode not in ("damp", "stand"):
            raise ValueError(f"node.start_mode must be damp or stand, not {self.node.start_mode!r}")
        if self.control_dt <= 0.0 or self.cmd_timeout <= 0.0:
            raise ValueError("control_dt and cmd_timeout must be > 0")


def load_locomotion_config(name: str = "locomotion", **overrides: object) -> LocomotionConfig:
    """Load configs/<name>.toml (overrides as dotted keys, e.g. profile="paper")."""
    from quadmanip.common.config import load_config

    return load_config(LocomotionConfig, name, overrides or None)


@dataclass
class LegOutput:
    """Per-joint command for the 12 leg joints."""

    q_des: np.ndarray
    dq_des: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau_ff: np.ndarray


@dataclass
class DebugInfo:
    """What the controller did on the last tick (for the debug stream and benchmarks)."""

    mode: str = "damp"
    gait_phase: np.ndarray = field(default_factory=lambda: np.zeros(4))
    contact: np.ndarray = field(default_factory=lambda: np.ones(4, dtype=bool))
    foot_forces: np.ndarray = field(default_factory=lambda: np.zeros((4, 3)))
    predicted: np.ndarray = field(default_factory=lambda: np.zeros((0, 12)))
    mpc_step_s: float = 0.0
    mpc_step_cpu_s: float = 0.0  # CPU time of the step (unaffected by other processes)
    mpc_solver_s: float = 0.0
    mpc_solved: bool = False
    mpc_status: str = ""


class CommandError(ValueError):
    """A command that is rejected (non-finite, out of range, unknown mode)."""


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for a (3,) and b (n, 3)."""
    out = np.empty_like(b)
    out[:, 0] = a[1] * b[:, 2] - a[2] * b[:, 1]
    out[:, 1] = a[2] * b[:, 0] - a[0] * b[:, 2]
    out[:, 2] = a[0] * b[:, 1] - a[1] * b[:, 0]
    return out


class LocomotionController:
    """Modes + estimator + gait + MPC + swing legs (see module doc)."""

    def __init__(self, config: LocomotionConfig, mjcf: str | None = None) -> None:
        self.cfg = config
        if config.profile not in config.profiles:
            raise ValueError(f"unknown profile {config.profile!r}")
        prof = config.profiles[config.profile]
        mpc_params = replace(config.mpc, weights=prof.weights)
        self.mpc = ConvexMpc(mpc_params)
        self.mpc_every = max(1, round(mpc_params.dt / config.control_dt))
        self.gait = TrotGait(prof.gait)
        self.kin = LegKinematics(mjcf)
        self.est = StateEstimator(config.estimator)
        self.ref = ComReference(replace(config.fsm, planned_acc=prof.planned_acc))
        self.mode = "damp"
        self.phase = "damp"  # internal: damp, sit, standing_up, balance, walk, stopping
        self.held_mass = float(config.held_mass)
        self.debug = DebugInfo()
        # Nominal stance: feet under the hips, pushed out by the abduction offset.
        self.nominal_feet = self.kin.straight_leg_feet.copy()
        self.nominal_feet[:, 2] = -config.stand_height + config.estimator.foot_radius
        self.q_stand = self._leg_ik(self.nominal_feet)
        # Sit = the description's `lying` keyframe (the pose the robot rests in).
        description = rd.load_mujoco_model(mjcf) if mjcf is not None else None
        self.q_sit = rd.lying_joint_positions(description)[LEG_SLICE].copy()
        self.safety = SafetyChecker(config.safety, *rd.leg_joint_limits(description))
        self.trip_reason = ""  # why the safe phase latched ("" when not tripped)
        self.trips = 0
        self.degraded = False  # the node's deadline monitor: the loop cannot keep up
        self.speed_scale = 1.0  # ... and the share of the velocity limits it can track
        self._q_hold: np.ndarray | None = None  # degraded stance: joint-level hold target
        self.gravity_b = np.array([0.0, 0.0, 1.0])  # world z in the base frame (IMU)
        self._righting: SelfRighting | None = None
        self._righting_side = "left"
        self._righting_t0 = 0.0
        # Commands.
        self.cmd_vel = np.zeros(3)
        self.cmd_vel_time = -math.inf
        self.body_pose = np.zeros(6)  # z, x, y, roll, pitch, yaw offsets
        # Internal state.
        self._t = 0.0
        self._tick = 0
        self._interp_from: np.ndarray | None = None
        self._interp_t0 = 0.0
        self._gait_t0 = 0.0
        self._forces_world = np.zeros((4, 3))
        self._contact_prev = np.ones(4, dtype=bool)
        self._liftoff = np.zeros((4, 3))
        self._td_target = np.zeros((4, 3))
        self._stand_yaw = 0.0
        self._stand_offset = np.zeros(2)  # trunk - feet centre kept from a stop (world xy)
        self._stand_turn = 0.0  # rad: the stance's yaw nudged this far (nudge_turn at most)
        self._nudge = np.zeros(3)  # the standing nudge velocity (base frame)
        self._nudge_time = -math.inf
        self._stop_requested = False
        self._auto_walk = True
        self.mpc_tick = 0
        self._pose_int = np.zeros(3)
        self._inertia = self.kin.body_inertia(self.held_mass)
        self.last_rpy = np.zeros(3)

    # ------------------------------------------------------------------ helpers
    def _leg_ik(self, feet_body: np.ndarray, iters: int = 30) -> np.ndarray:
        """Joint angles that put the feet at feet_body (base frame), by damped Newton steps."""
        q = np.zeros(N_JOINTS)
        q[LEG_SLICE] = np.tile([0.0, 0.7, -1.4], N_LEGS)
        for _ in range(iters):
            self.kin.update(q)
            err = feet_body - self.kin.foot_pos
            if np.max(np.abs(err)) < 1e-6:
                break
            for i in range(N_LEGS):
                j = self.kin.foot_jac[i]
                step = np.linalg.solve(j.T @ j + 1e-6 * np.eye(3), j.T @ err[i])
                q[leg_slice(i)] += step
        return q[LEG_SLICE].copy()

    # ------------------------------------------------------------------ commands
    def set_mode(self, mode: str) -> None:
        """Request a mode: damp, sit, stand or walk."""
        if mode not in MODES:
            raise CommandError(f"unknown mode {mode!r}; expected one of {MODES}")
        if mode == "recover":
            self._recover()
            return
        if self.phase == "safe":
            if mode == "damp":
                return
            raise CommandError(f"tripped ({self.trip_reason}): send mode 'recover' first")
        if self.phase == "righting" and mode != "damp":
            raise CommandError("righting itself: wait for it to stand, or send 'damp'")
        if mode == "stand" and self.phase in ("damp", "sit"):
            side = self.lying_side()
            if side != "upright":
                raise CommandError(f"the robot lies on its {side}: send mode 'recover'")
        if mode == self.mode:
            return
        if mode == "walk" and self.phase not in ("balance", "walk", "stopping"):
            raise CommandError("walk needs the robot standing first (mode 'stand')")
        self.mode = mode
        if mode == "walk":
            # Explicit walk: trot (in place without velocity commands) until told to stand.
            self._auto_walk = False
            if self.phase != "walk":
                self._start_walk()
            return
        if mode == "damp":
            self.phase = "damp"
        elif mode == "sit":
            self._start_interp("sit")
        elif mode == "stand":
            if self.phase in ("walk", "stopping"):
                self._stop_requested = True
                self.phase = "stopping"
            elif self.phase not in ("balance",):
                self._start_interp("standing_up")

    def set_velocity(self, vx: float, vy: float, wz: float, now: float) -> None:
        """Body velocity command (base frame); starts walking from standing."""
        v = np.array([vx, vy, wz], dtype=float)
        if not np.all(np.isfinite(v)):
            raise CommandError(f"non-finite velocity command {v.tolist()}")
        bound = self.velocity_bound()
        if np.any(np.abs(v) > bound + 1e-9):
            why = " (degraded: the loop cannot keep up)" if self.degraded else ""
            raise CommandError(f"velocity {v.tolist()} outside limits ±{bound.tolist()}{why}")
        if self.phase not in ("balance", "walk", "stopping") and self.mode != "walk":
            raise CommandError(f"velocity commands need mode stand or walk (now {self.mode})")
        if self.phase == "balance" and self.mode != "walk" and self._is_nudge(v):
            self._nudge = v
            self._nudge_time = float(now)
            return
        self.cmd_vel = v
        self.cmd_vel_time = float(now)
        if np.any(np.abs(v) > 1e-6):
            if self.phase == "balance":
                self._auto_walk = True
                self._start_walk()
            elif self.phase in ("walk", "stopping"):
                # Keep trotting: the gait clock runs on (no jump in the swing phase).
                self.phase = "walk"
                self._stop_requested = False
            self.mode = "walk"

    def _is_nudge(self, v: np.ndarray) -> bool:
        """A command small enough to move the standing trunk instead of trotting."""
        cfg = self.cfg
        small = abs(v[0]) <= cfg.nudge_speed and abs(v[1]) <= cfg.nudge_speed
        return bool(small and abs(v[2]) <= cfg.nudge_wz)

    def _apply_nudge(self, dt: float) -> None:
        """Move the standing goal by the fresh nudge: the trunk's offset over its feet
        (within ``nudge_reach``) and the stance's yaw (within ``nudge_turn``)."""
        cfg = self.cfg
        if self._t - self._nudge_time > cfg.cmd_timeout:
            return
        c, s = math.cos(self._stand_yaw), math.sin(self._stand_yaw)
        vx, vy, wz = self._nudge
        off = self._stand_offset + dt * np.array([c * vx - s * vy, s * vx + c * vy])
        n = float(np.hypot(*off))
        self._stand_offset = off if n <= cfg.nudge_reach else off * (cfg.nudge_reach / n)
        turn = float(np.clip(self._stand_turn + wz * dt, -cfg.nudge_turn, cfg.nudge_turn))
        self._stand_yaw += turn - self._stand_turn
        self._stand_turn = turn

    def set_body_pose(
        self, z: float, x: float, y: float, roll: float, pitch: float, yaw: float
    ) -> None:
        """Body pose offsets from the nominal stand (used while standing)."""
        p = np.array([z, x, y, roll, pitch, yaw], dtype=float)
        if not np.all(np.isfinite(p)):
            raise CommandError(f"non-finite body pose command {p.tolist()}")
        lim = self.cfg.limits
        checks = [
            (-lim.z_crouch <= z <= lim.z_raise, "z_offset"),
            (abs(x) <= lim.shift, "x_offset"),
            (abs(y) <= lim.shift, "y_offset"),
            (abs(roll) <= lim.roll, "roll"),
            (abs(pitch) <= lim.pitch, "pitch"),
            (abs(yaw) <= lim.yaw, "yaw"),
        ]
        for ok, name in checks:
            if not ok:
                raise CommandError(f"body pose {name} out of range: {p.tolist()}")
        self.body_pose = p

    def velocity_bound(self) -> np.ndarray:
        """|vx|, |vy|, |wz| accepted now: the limits, scaled down while degraded."""
        lim = self.cfg.limits
        return np.array([lim.vx, lim.vy, lim.wz]) * self.speed_scale

    def lying_side(self) -> str:
        """upright, left, right or back, from the last IMU orientation."""
        return lying_side(self.gravity_b, self.cfg.recovery)

    # ------------------------------------------------------------------ safety
    def trip(self, reason: str) -> None:
        """Latch the safe phase (legs damped) with ``reason`` until a ``recover``."""
        if self.phase == "safe":
            return
        self.phase = "safe"
        self.mode = "damp"
        self.trip_reason = reason
        self.trips += 1
        self._righting = None
        self.cmd_vel = np.zeros(3)

    def _recover(self) -> None:
        """The explicit reset: right itself if on a side, then stand up (module doc)."""
        if self.phase not in ("safe", "damp", "sit"):
            return  # already up (or getting up): nothing to reset
        side = self.lying_side()
        if side == "back":
            self.phase, self.mode = "safe", "damp"
            self.trip_reason = "lying on its back: needs help (turn it over, then 'recover')"
            return
        self.trip_reason = ""
        self.safety.reset()
        self.mode = "stand"
        if side == "upright":
            self._start_interp("standing_up")
            return
        self.phase = "righting"
        self._righting = None  # built at the next tick from the measured joints
        self._righting_side = side
        self._righting_t0 = self._t

    def _check_safety(self, q16: np.ndarray, tau16: np.ndarray | None, r: np.ndarray) -> None:
        if self.phase in ("damp", "safe", "righting"):
            return
        rpy = rpy_from_mat(r)
        height = None
        if self.phase in MPC_PHASES:  # the lowest foot below the trunk, along world z
            height = float(np.max(-(r @ self.kin.foot_pos.T)[2]))
        tau = np.zeros(N_LEG_JOINTS) if tau16 is None else np.asarray(tau16, float)[LEG_SLICE]
        reason = self.safety.check(self._t, float(rpy[0]), float(rpy[1]), q16[LEG_SLICE], tau,
                                   height)  # fmt: skip
        if reason is not None:
            self.trip(reason)

    def _righting_tick(self, q16: np.ndarray, dq16: np.ndarray) -> LegOutput:
        if self._righting is None:
            self._righting = SelfRighting(
                self.cfg.recovery, self._righting_side, q16[LEG_SLICE].copy(), self.q_sit
            )
        rt = self._righting
        q_des, dq_des, kp, kd = rt.command(
            self._t - self._righting_t0, q16[LEG_SLICE], dq16[LEG_SLICE], self.gravity_b
        )
        if rt.failed:
            self.trip(f"self-righting failed: {rt.reason}")
            return self._damp(q16)
        if rt.done:
            self._righting = None
            self._start_interp("standing_up")
        return LegOutput(q_des, dq_des, kp, kd, np.zeros(N_LEG_JOINTS))

    # ------------------------------------------------------------------ transitions
    def _start_interp(self, phase: str) -> None:
        self.phase = phase
        self._interp_from = None  # taken from the measured pose at the next tick
        self._interp_t0 = self._t

    def _start_walk(self) -> None:
        self.phase = "walk"
        self._pose_int = np.zeros(3)
        self._gait_t0 = self._t
        self._stop_requested = False

    def _enter_balance(self, quat: np.ndarray) -> None:
        self.phase = "balance"
        self.est.reset(quat, self.kin.foot_pos)
        rpy = rpy_from_mat(quat_to_mat(quat))
        self.ref.reset(self.est.position, float(rpy[2]))
        self._stand_yaw = float(rpy[2])
        self._stand_offset = np.zeros(2)
        self._stand_turn = 0.0
        self.body_pose = np.zeros(6)
        if self.mode == "walk":
            self.mode = "stand"

    # ------------------------------------------------------------------ main loop
    def step(
        self,
        t: float,
        q16: np.ndarray,
        dq16: np.ndarray,
        quat: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        tau16: np.ndarray | None = None,
    ) -> LegOutput:
        """One control tick: measurements in (``tau16``: the motors' torques, for the
        saturation check), per-joint leg command out."""
        self._t = float(t)
        self._tick += 1
        q16 = np.asarray(q16, dtype=float)
        dq16 = np.asarray(dq16, dtype=float)
        self.kin.update(q16)
        self.debug.mode = self.mode
        r_imu = quat_to_mat(np.asarray(quat, dtype=float))
        self.gravity_b = r_imu[2, :].copy()
        self._check_safety(q16, tau16, r_imu)
        if self.phase in ("damp", "safe"):
            return self._damp(q16)
        if self.phase == "righting":
            return self._righting_tick(q16, dq16)
        if self.phase in ("sit", "standing_up"):
            out = self._posture(q16)
            if self.phase == "standing_up" and self._t - self._interp_t0 >= self.cfg.stand_up_time:
                self._enter_balance(np.asarray(quat, dtype=float))
            return out
        return self._mpc_tick(q16, dq16, np.asarray(quat, float), gyro, accel)

    def _damp(self, q16: np.ndarray) -> LegOutput:
        z = np.zeros(N_LEG_JOINTS)
        return LegOutput(
            q16[LEG_SLICE].copy(),
            z,
            z.copy(),
            np.full(N_LEG_JOINTS, self.cfg.gains.kd_damp),
            z.copy(),
        )

    def _posture(self, q16: np.ndarray) -> LegOutput:
        """Joint-space interpolation to the stand or sit pose (smoothstep in time)."""
        if self._interp_from is None:
            self._interp_from = q16[LEG_SLICE].copy()
        dur = self.cfg.stand_up_time if self.phase == "standing_up" else self.cfg.sit_time
        goal = self.q_stand if self.phase == "standing_up" else self.q_sit
        s = float(np.clip((self._t - self._interp_t0) / dur, 0.0, 1.0))
        a = s * s * (3.0 - 2.0 * s)
        da = 6.0 * s * (1.0 - s) / dur if s < 1.0 else 0.0
        q_des = self._interp_from + (goal - self._interp_from) * a
        dq_des = (goal - self._interp_from) * da
        g = self.cfg.gains
        return LegOutput(
            q_des,
            dq_des,
            np.full(N_LEG_JOINTS, g.kp_posture),
            np.full(N_LEG_JOINTS, g.kd_posture),
            np.zeros(N_LEG_JOINTS),
        )

    def _mpc_tick(
        self,
        q16: np.ndarray,
        dq16: np.ndarray,
        quat: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
    ) -> LegOutput:
        cfg = self.cfg
        dt = cfg.control_dt
        walking = self.phase in ("walk", "stopping")
        t_g = self._t - self._gait_t0
        if walking:
            contact, progress, _ = self.gait.phase_info(t_g)
        else:
            contact, progress = np.ones(4, dtype=bool), np.full(4, -1.0)
        # Velocity command timeout → stop; a degraded loop clips what is running.
        bound = self.velocity_bound()
        cmd = np.clip(self.cmd_vel, -bound, bound)
        if walking and not np.any(bound > 0.0):
            self._stop_requested = True  # too late to trot at all: stop and stand
        if walking and self._t - self.cmd_vel_time > cfg.cmd_timeout:
            cmd[:] = 0.0
            self._stop_requested = self._stop_requested or self._auto_walk
        if walking and self._auto_walk and np.all(np.abs(self.cmd_vel) < 1e-6):
            self._stop_requested = True
        # Estimator.
        foot_vel = self.kin.foot_velocities(dq16[LEG_SLICE])
        # Stance feet roll: their centres move by ω_calf × r·up, which is not base motion.
        up_b = self.gravity_b  # world z in the base frame (from this tick's IMU, in step())
        roll = self.kin.rolling_velocities(
            dq16[LEG_SLICE], np.asarray(gyro, float), up_b, cfg.estimator.foot_radius
        )
        self.est.update(
            dt, quat, gyro, accel, self.kin.foot_pos, foot_vel - roll, contact.astype(float)
        )
        r = self.est.R
        rpy = rpy_from_mat(r)
        self.last_rpy = rpy
        pos = self.est.position
        vel = self.est.velocity
        omega_w = r @ self.est.omega_body
        # Stop: once slow, in a four-feet phase.
        if walking and self._stop_requested:
            slow = np.linalg.norm(vel[:2]) < 0.15 and abs(omega_w[2]) < 0.3
            if slow and bool(np.all(contact)):
                self.phase = "balance"
                self.mode = "stand"
                self._stop_requested = False
                self.cmd_vel = np.zeros(3)
                self._stand_yaw = float(rpy[2])
                self._stand_turn = 0.0
                feet = np.mean(self.est.x[6:18].reshape(4, 3)[:, :2], axis=0)
                off = pos[:2] - feet
                n = float(np.hypot(*off))
                keep = cfg.stop_keep_max
                self._stand_offset = off if n <= keep else off * (keep / n)
                self.ref.reset(pos, float(rpy[2]))
                walking = False
                contact, progress = np.ones(4, dtype=bool), np.full(4, -1.0)
        # Reference target (eqs. 10–12).
        height = cfg.stand_height + (self.body_pose[0] if not walking else 0.0)
        if walking:
            self.ref.advance(cmd[:2], cmd[2], height, dt, pos, float(rpy[2]))
            rp_des = np.zeros(2)
        else:
            # Standing: COM shift/rotation relative to the feet's centre.
            if self.phase == "balance":
                self._apply_nudge(dt)
            feet_xy = np.mean(self.est.x[6:18].reshape(4, 3)[:, :2], axis=0)
            yaw0 = self._stand_yaw
            c, s = math.cos(yaw0), math.sin(yaw0)
            off = np.array([c * self.body_pose[1] - s * self.body_pose[2],
                            s * self.body_pose[1] + c * self.body_pose[2]])  # fmt: skip
            off = off + self._stand_offset
            goal = np.array([feet_xy[0] + off[0], feet_xy[1] + off[1], height])
            # Integral action on the standing pose: removes the steady-state offset that the
            # single-rigid-body model leaves (leg masses, joint friction), so body pose
            # commands land within millimetres.
            # It integrates only near the goal, so the transient of a new command winds
            # nothing up.
            ki, lim = cfg.stand_integral_gain, cfg.stand_integral_limit
            err = goal - pos
            near = (np.abs(err) < 0.02) & (np.abs(vel) < 0.02)
            self._pose_int = np.clip(self._pose_int + ki * err * dt * near, -lim, lim)
            self.ref.p_target = goal + self._pose_int
            yt = yaw0 + self.body_pose[5]
            self.ref.q_target = np.array([math.cos(yt / 2), 0.0, 0.0, math.sin(yt / 2)])
            # Algorithm 7's VEL_LIMIT for body pose moves while standing.
            self.ref.v_target_world = np.full(3, cfg.pose_speed)
            self.ref.yaw_rate_target = 0.0
            rp_des = self.body_pose[3:5]
        # Feet in the world (odom) frame.
        feet_w = (r @ self.kin.foot_pos.T).T + pos
        # Swing bookkeeping: lift-off points and touchdown targets.
        lifted = self._contact_prev & ~contact
        self._liftoff[lifted] = feet_w[lifted]
        self._contact_prev = contact.copy()
        # MPC every mpc_every ticks.
        if self._tick % self.mpc_every == 0 or not self.debug.mpc_solved:
            self._run_mpc(rpy, pos, omega_w, vel, rp_des, feet_w, walking, t_g, cmd)
        # Swing targets.
        v_cmd_w = r[:, :2] @ cmd[:2] if walking else np.zeros(2)
        v_cmd_w3 = np.array([v_cmd_w[0], v_cmd_w[1], 0.0])
        hips_w = (r @ self.nominal_feet.T).T + pos
        hip_off_w = (r @ self.nominal_feet.T).T
        t_left = np.where(progress >= 0, (1.0 - progress) * self.gait.params.t_swing, 0.0)
        self._td_target = touchdown_target(
            hips_w, vel, v_cmd_w3, cmd[2] if walking else 0.0, hip_off_w,
            self.gait.stance_duration(), t_left, cfg.swing, cfg.estimator.foot_radius,
        )  # fmt: skip
        # Leg torques.
        g = cfg.gains
        f_body = (r.T @ self._forces_world.T).T
        tau_st = self.kin.leg_torques(f_body)
        kp_c = np.asarray(cfg.swing.kp_cartesian)
        kd_c = np.asarray(cfg.swing.kd_cartesian)
        w_b = self.est.omega_body
        # Desired foot velocities relative to the base (base frame), all legs at once:
        # stance feet stay put in the world, so they move by −(v + ω × r) relative to the base.
        v_b = r.T @ vel
        v_rel = -v_b[None, :] - _cross(w_b, self.kin.foot_pos)
        swing_force = np.zeros((4, 3))
        for i in np.flatnonzero(~contact):
            p_des_w, v_des_w = swing_profile(
                self._liftoff[i], self._td_target[i], progress[i], self.gait.params.t_swing,
                self.gait.params.foot_height,
            )  # fmt: skip
            p_des_b = r.T @ (p_des_w - pos)
            v_rel[i] = r.T @ (v_des_w - vel) - _cross(w_b, p_des_b[None, :])[0]
            swing_force[i] = kp_c * (p_des_b - self.kin.foot_pos[i]) + kd_c * (
                v_rel[i] - foot_vel[i]
            )
        tau_sw = self.kin.cartesian_torques(swing_force)
        st = np.repeat(contact, 3)
        tau = np.where(st, tau_st, tau_sw)
        kd = np.where(st, g.kd_stance, g.kd_swing)
        # Joint velocities that realise those foot velocities (J is 3×3 per leg).
        dq_des = np.linalg.solve(
            self.kin.foot_jac + 1e-9 * np.eye(3)[None], v_rel[:, :, None]
        ).reshape(N_LEG_JOINTS)
        q_des = q16[LEG_SLICE].copy()
        self.debug.gait_phase = np.where(progress >= 0, progress, 0.0)
        self.debug.contact = contact.copy()
        self.debug.foot_forces = self._forces_world.copy()
        kp = np.zeros(N_LEG_JOINTS)
        if self.degraded and not walking:
            q_des, kp, kd = self._degraded_stance(q16[LEG_SLICE], kd)
            # The MPC's forces answer a state that is stale by now: carry the weight with
            # a static share per foot instead, and let the joint PD do the balancing.
            share = np.zeros((4, 3))
            share[:, 2] = self._inertia.mass * GRAVITY / 4.0
            tau = self.kin.leg_torques((r.T @ share.T).T)
        else:
            self._q_hold = None
        return LegOutput(q_des, dq_des, kp, kd, tau)

    def _degraded_stance(
        self, q12: np.ndarray, kd: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint-level stiffness for a late loop (module doc): hold the joints where they
        were when the loop fell behind (following the measured joints would let the
        stance sag away under gravity)."""
        d = self.cfg.deadline
        if self._q_hold is None:
            self._q_hold = q12.copy()
        kp = np.full(N_LEG_JOINTS, d.degraded_kp)
        return self._q_hold.copy(), kp, np.maximum(kd, d.degraded_kd)

    def _run_mpc(
        self,
        rpy: np.ndarray,
        pos: np.ndarray,
        omega_w: np.ndarray,
        vel: np.ndarray,
        rp_des: np.ndarray,
        feet_w: np.ndarray,
        walking: bool,
        t_g: float,
        cmd: np.ndarray,
    ) -> None:
        """Build the MPC problem around the COM and solve it (stores the first forces)."""
        t0 = time.perf_counter()
        c0 = time.thread_time()
        p = self.mpc.params
        n = p.horizon
        self.mpc_tick += 1
        self._inertia = self.kin.body_inertia(self.held_mass)
        bi = self._inertia
        r = self.est.R
        com_off_w = r @ bi.com
        com = pos + com_off_w
        com_vel = vel + _cross(omega_w, com_off_w[None, :])[0]
        x_ref = self.ref.plan(rpy, pos, omega_w, vel, rp_des, n, p.dt)
        x_ref[:, 3:6] += com_off_w  # base reference → COM reference
        x0 = np.concatenate([rpy, com, omega_w, com_vel])
        if walking:
            contacts = self.gait.schedule(t_g, n, p.dt)
        else:
            contacts = np.ones((n, 4), dtype=bool)
        # Foot positions over the horizon: stance feet stay; a swinging foot lands on its target.
        feet = np.broadcast_to(feet_w, (n, 4, 3)).copy()
        for i in range(4):
            if not contacts[0, i] or not self.debug.contact[i]:
                feet[:, i, :] = self._td_target[i]
        foot_rel = feet - x_ref[:, None, 3:6]
        sol = self.mpc.solve(x0, x_ref, foot_rel, contacts, bi.mass, bi.inertia)
        self.debug.mpc_solved = sol.status == "solved"
        self.debug.mpc_status = sol.status
        if sol.status == "solved" or sol.status == "no_contact":
            self._forces_world = sol.first.copy()
        self.debug.predicted = sol.predicted
        self.debug.mpc_solver_s = sol.solver_time_s
        self.debug.mpc_step_s = time.perf_counter() - t0
        self.debug.mpc_step_cpu_s = time.thread_time() - c0
