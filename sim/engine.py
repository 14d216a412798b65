"""The simulation engine: physics, actuator layer, sensors and ground truth; no transport.

``SimEngine(world, config)`` owns one MuJoCo model/data pair built by
:func:`quadmanip.sim.world.build_world`. Time is counted in control ticks (500 Hz by
default) of ``substeps`` physics steps (1 kHz): :meth:`SimEngine.step_tick` takes the leg
command that answers the last state, advances one tick and returns what the robot's
devices and the judge produce at the new tick. Sensors run on a schedule in sim time
(every ``control_rate / rate`` ticks), so a run is deterministic whatever the wall clock
does; the node decides how fast ticks happen (realtime or lockstep).

Physics is advanced with ``mj_step1``/``mj_step2`` so that the actuator layer computes
its torques from the state at the start of each step, with kinematics and sensors
current for that state (as a motor driver samples its encoder, then sets current).

The honesty invariant (docs/architecture.md, "Honest simulation"): after load, the robot and
the objects move only by actuator torques, contacts and gravity. The engine's
:class:`~quadmanip.sim.honesty.HonestyGuard` (``self.honesty``) checks the model once at
construction (no mocap body, active equality, gravity compensation, foreign actuator or
tendon on the robot or an object; the finger coupling excepted) and, before every physics
step, that ``xfrc_applied`` holds exactly what the test-only disturbance channel wrote,
``qfrc_applied`` is zero and no such equality was switched on. Each new violation is
logged once at ERROR; :meth:`SimEngine.honesty_violations` lists them all for the judge.

Objects never sleep (MuJoCo island sleeping freezes a tree whose speed stays under
``sleep_tolerance`` for 10 steps, which would hold an object creeping off a rim in place;
see :func:`configure_sleep`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import mujoco
import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.common.log import get_logger
from quadmanip.common.robot_description import (
    ARM_JOINTS,
    BASE_BODY,
    CAMERAS,
    GRIPPER_ACTUATOR,
    GRIPPER_JOINTS,
    LEG_JOINTS,
)
from quadmanip.common.scheduling import SchedulingConfig
from quadmanip.sim.actuators import ActuatorConfig, ActuatorLayer, LegMode
from quadmanip.sim.disturbance import DisturbanceChannel
from quadmanip.sim.honesty import HonestyGuard
from quadmanip.sim.judge import Judge, JudgeConfig
from quadmanip.sim.sensors import Imu, Lidar, RgbdRenderer, SensorsConfig

log = get_logger("sim.engine")


@dataclass(frozen=True)
class PhysicsConfig:
    """``[physics]``: the control rate (the physics timestep is the robot description's
    ``<option timestep>``, its only source)."""

    control_rate: float = 500.0  # Hz: LowState / LegCommand rate
    # MuJoCo's island sleeping: unactuated bodies at rest (drawers) stop being simulated
    # until something awake touches them, a force is applied to them or they move. The
    # robot (actuated) and the objects (see configure_sleep) never sleep.
    sleep: bool = True


@dataclass(frozen=True)
class GroundTruthConfig:
    """``[ground_truth]``: rates of the judge-only publications (0 disables one)."""

    poses_rate: float = 50.0
    contacts_rate: float = 10.0
    judge_rate: float = 1.0


@dataclass(frozen=True)
class NodeConfig:
    """``[node]``: how the Zenoh node paces the engine."""

    mode: Literal["realtime", "lockstep"] = "realtime"
    realtime_factor: float = 1.0  # cap in realtime mode
    heartbeat_rate: float = 1.0  # Hz (wall time)
    lockstep_log_period: float = 1.0  # s of waiting between "waiting for controller" lines
    # s (wall) between re-sends of the last LowState while lockstep waits for its answer,
    # so a controller started late still gets the tick it must answer
    lockstep_republish_period: float = 0.2
    rtf_log_period: float = 5.0  # s (wall) between logs of the achieved real-time factor
    clock_rate: float = 100.0  # Hz of sim/clock (sim time); LowState stamps every tick
    status_rate: float = 2.0  # Hz (wall) of sim/status: leg-command age, timeouts, RTF


@dataclass(frozen=True)
class SimConfig:
    """Everything in configs/sim.toml."""

    scenario: str = "paper-1"
    seed: int = 0
    allow_test_disturbance: bool = False
    physics: PhysicsConfig = PhysicsConfig()
    actuators: ActuatorConfig = ActuatorConfig()
    sensors: SensorsConfig = SensorsConfig()
    ground_truth: GroundTruthConfig = GroundTruthConfig()
    judge: JudgeConfig = JudgeConfig()
    node: NodeConfig = NodeConfig()
    # The physics loop's priority; the node applies it in realtime mode only (lockstep has
    # no deadline, and a real-time lockstep loop would starve everything else).
    scheduling: SchedulingConfig = SchedulingConfig(policy="fifo", priority=70, fallback_nice=-5)


@dataclass
class TickOutput:
    """What the devices and the judge produce at one control tick (None = not due)."""

    tick: int
    stamp: float
    lowstate: msg.LowState
    leg_mode: LegMode
    images: list[msg.RgbdImage] = field(default_factory=list)
    scan: msg.LaserScan | None = None
    gt_poses: msg.GroundTruthPoses | None = None
    gt_drawers: msg.GroundTruthPoses | None = None
    gt_contacts: msg.GroundTruthContacts | None = None
    judge: msg.JudgeReport | None = None


def standing_data(world: Any) -> mujoco.MjData:
    """The scenario's initial state but with the robot in the ``home`` standing pose at its
    start position: an initial condition for tests and benchmarks (set before the first
    step, like loading a scenario), not something done during a run."""
    m = world.model
    d = world.initial_data()
    rm = rd.load_mujoco_model()
    home = rd.home_qpos(rm)
    d.qpos[rd.joint_qpos_indices(m)] = home[rd.joint_qpos_indices(rm)]
    adr = rd.free_joint_qpos_index(m)
    d.qpos[adr + 2] = home[rd.free_joint_qpos_index(rm) + 2]
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    return d


def _every(control_rate: float, rate: float, what: str) -> int:
    """Decimation in ticks for a sensor rate (0 = never)."""
    if rate <= 0:
        return 0
    n = round(control_rate / rate)
    if n < 1 or abs(control_rate / n - rate) > 1e-6 * rate:
        log.warning("rate rounded", what=what, asked=rate, got=control_rate / max(n, 1))
    return max(n, 1)


def _robot_bodies(model: mujoco.MjModel, base: int) -> np.ndarray:
    return np.flatnonzero(model.body_rootid == model.body_rootid[base])


def configure_sleep(model: mujoco.MjModel, enabled: bool, never: Iterable[int] = ()) -> None:
    """Switch MuJoCo's island sleeping on or off and keep the trees of the ``never`` bodies
    (the objects) always awake.

    A sleeping tree is frozen until something awake touches it, and a tree falls asleep
    after 10 steps under ``sleep_tolerance`` (1 mm/s): an object released at rest with its
    centre of mass just past a rim falls asleep before it tips and stays balanced there for
    ever (tests/unit/test_honesty.py: a cracker box 1 mm past a table edge has dropped 5 cm
    after 0.69 s without sleeping, and is still on the edge after 3 s with it). So objects
    never sleep; passive house parts (drawers) still may, but an island holding an object
    cannot.
    """
    if enabled:
        model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    else:
        model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    for b in never:
        tree = int(model.body_treeid[b])
        if tree >= 0:
            model.tree_sleep_policy[tree] = int(mujoco.mjtSleepPolicy.mjSLEEP_NEVER)


class SimEngine:
    """Physics + actuator layer + sensors + ground truth for one scenario (no Zenoh)."""

    def __init__(
        self,
        world: Any,
        config: SimConfig,
        *,
        data: mujoco.MjData | None = None,
        cameras: bool = True,
        lidar: bool = True,
        ground_truth: bool = True,
    ) -> None:
        self.world = world
        self.config = config
        self.model: mujoco.MjModel = world.model
        # The scenario's initial state (a test may pass its own initial data, e.g. standing).
        self.data: mujoco.MjData = data if data is not None else world.initial_data()
        m = self.model
        pc = config.physics
        timestep = float(m.opt.timestep)  # from the robot description's <option>
        self.substeps = round(1.0 / (pc.control_rate * timestep))
        if self.substeps < 1 or abs(self.substeps * timestep * pc.control_rate - 1) > 1e-9:
            raise ValueError("control period must be a whole number of physics steps")
        self.control_dt = self.substeps * timestep
        self.rng = np.random.default_rng(config.seed + config.sensors.seed)

        self.base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, BASE_BODY)
        if self.base < 0:
            raise KeyError("the model has no body 'base'")
        self.robot_bodies = _robot_bodies(m, self.base)
        self.actuators = ActuatorLayer(
            m, config.actuators, LEG_JOINTS, ARM_JOINTS, GRIPPER_JOINTS, GRIPPER_ACTUATOR
        )
        self.imu = Imu(m, config.sensors.imu, self.rng)
        self.disturbance = DisturbanceChannel(m, config.allow_test_disturbance)
        self._joint_qpos = np.concatenate([self.actuators.legs.qpos, self.actuators.arm.qpos])
        self._joint_dof = np.concatenate([self.actuators.legs.dof, self.actuators.arm.dof])
        self._joint_act = np.concatenate([self.actuators.legs.act, self.actuators.arm.act])

        sc = config.sensors
        cr = pc.control_rate
        self.camera_cfg = dict(zip(CAMERAS, (sc.front_camera, sc.gripper_camera), strict=True))
        self._cam_every = {n: _every(cr, c.rate, n) for n, c in self.camera_cfg.items()}
        self._lidar_every = _every(cr, sc.lidar.rate, "lidar") if lidar else 0
        # Stagger the expensive sensors inside their period (front camera at phase 0, the
        # gripper camera half a period later, LiDAR a quarter) so no single tick carries
        # all the rendering: the longest pause of the control loop is one frame, not two.
        self._cam_phase = {
            n: (i * every) // max(len(self._cam_every), 1)
            for i, (n, every) in enumerate(self._cam_every.items())
        }
        self._lidar_phase = self._lidar_every // 4
        gt = config.ground_truth
        self._poses_every = _every(cr, gt.poses_rate, "gt poses") if ground_truth else 0
        self._contacts_every = _every(cr, gt.contacts_rate, "gt contacts") if ground_truth else 0
        self._judge_every = _every(cr, gt.judge_rate, "judge") if ground_truth else 0
        self.renderer: RgbdRenderer | None = None
        self._want_cameras = cameras
        self.lidar = Lidar(m, sc.lidar, self.rng) if lidar else None

        self.object_names: list[str] = list(getattr(world, "object_names", ()) or ())
        body_ids = getattr(world, "object_body_ids", {}) or {}
        self._object_bodies = np.array([body_ids[n] for n in self.object_names], dtype=int)
        # The judge tracks rest and contacts every tick (history: "at rest for 1 s").
        self.judge: Judge | None = (
            Judge(world, config.judge) if ground_truth and hasattr(world, "regions") else None
        )
        self._judge_track_every = max(_every(pc.control_rate, config.judge.track_rate, "judge"), 1)
        handles = getattr(world, "drawer_handles", {}) or {}
        self._drawer_names = list(handles)
        self._drawer_bodies = np.array([m.body(b).id for b in handles.values()], dtype=int)

        self.tick = 0
        self.start_time = float(self.data.time)
        configure_sleep(m, pc.sleep, never=self._object_bodies)
        self.honesty = HonestyGuard(
            m,
            self.data,
            self.robot_bodies,
            self._object_bodies,
            self.disturbance,
            time_origin=self.start_time,
        )
        self._contacts: msg.GroundTruthContacts | None = None
        mujoco.mj_forward(m, self.data)
        self._contacts = self._capture_contacts(stamp=0.0)
        # Invariant between steps: mj_step1 has run on the current state.
        mujoco.mj_step1(m, self.data)

    # ------------------------------------------------------------------ helpers
    def ensure_renderer(self) -> RgbdRenderer | None:
        """Create the GL renderer lazily, in the thread that steps the engine."""
        if self.renderer is None and self._want_cameras:
            self.renderer = RgbdRenderer(
                self.model, self.camera_cfg, render=self.config.sensors.render
            )
        return self.renderer

    @property
    def time(self) -> float:
        """Sim time (s) since the scenario was loaded."""
        return float(self.data.time) - self.start_time

    # ----------------------------------------------------------------- commands
    def apply_leg_command(self, cmd: msg.LegCommand) -> bool:
        return self.actuators.set_leg_command(
            float(self.data.time), cmd.q_des, cmd.dq_des, cmd.kp, cmd.kd, cmd.tau_ff
        )

    def apply_arm_trajectory(self, traj: msg.ArmTrajectory) -> bool:
        # Trajectory stamps are robot time (= sim time since load); the layer uses data.time.
        return self.actuators.set_arm_trajectory(
            float(self.data.time),
            np.asarray(traj.t) + self.start_time,
            traj.q,
            traj.dq,
            traj.kp,
            traj.kd,
            traj.tau_ff,
        )

    def apply_gripper_command(self, cmd: msg.GripperCommand) -> bool:
        return self.actuators.set_gripper_command(float(self.data.time), cmd.gap, cmd.max_force)

    def apply_disturbance(self, d: msg.Disturbance) -> bool:
        return self.disturbance.request(
            float(self.data.time), d.force, d.torque, d.duration, d.body
        )

    # ------------------------------------------------------------------ physics
    def physics_step(self, capture_contacts: bool = False) -> None:
        """One physics step (1 ms): honesty check, disturbance, actuator torques, integrate.

        ``capture_contacts`` records the contacts and their forces right after the solver
        ran (before the next collision pass replaces them): the step's ground truth.
        """
        m, d = self.model, self.data
        self.honesty.check(d)  # what this step is about to integrate; logs new violations
        self.disturbance.apply(d)
        self.actuators.apply(d)
        mujoco.mj_step2(m, d)
        if capture_contacts:
            self._contacts = self._capture_contacts()
        mujoco.mj_step1(m, d)

    def step_tick(
        self, leg_cmd: msg.LegCommand | None = None, *, sensors: bool = True
    ) -> TickOutput:
        """Apply ``leg_cmd`` (if any), advance one control tick, observe the new state.

        ``sensors=False`` returns only the LowState; call :meth:`add_sensors` on the result
        (before the next step) for the cameras, LiDAR and ground truth due at this tick.
        The node uses this to publish the state first, so the controller computes its
        answer while the sim renders.
        """
        if leg_cmd is not None:
            self.apply_leg_command(leg_cmd)
        capture = self._contacts_every > 0 and (self.tick + 1) % self._contacts_every == 0
        for i in range(self.substeps):
            self.physics_step(capture_contacts=capture and i == self.substeps - 1)
        self.tick += 1
        if self.judge is not None and self.tick % self._judge_track_every == 0:
            self.judge.track(self.data)
        return self.observe(sensors=sensors)

    # ------------------------------------------------------------- observation
    def _due(self, every: int, phase: int = 0) -> bool:
        return every > 0 and self.tick % every == phase

    def low_state(self) -> msg.LowState:
        """Encoders + IMU at the current state (LowState of this tick)."""
        d = self.data
        stamp = self.time
        act = self.actuators
        tau = act.tau[self._joint_act]
        f_fingers = act.tau[act.gripper.act]
        joints = msg.JointState(
            stamp=stamp,
            q=d.qpos[self._joint_qpos],
            dq=d.qvel[self._joint_dof],
            tau=tau,
            gripper_gap=act.gripper_gap(d),
            # Squeezing force of the fingers (N): their actuators push toward closing (<0).
            gripper_effort=float(-np.mean(f_fingers)),
        )
        r = self.imu.read(d)
        imu = msg.Imu(
            stamp=stamp,
            orientation=r.orientation,
            angular_velocity=r.angular_velocity,
            linear_acceleration=r.linear_acceleration,
        )
        return msg.LowState(stamp=stamp, tick=self.tick, joints=joints, imu=imu)

    def render(self, camera: str) -> msg.RgbdImage:
        renderer = self.ensure_renderer()
        if renderer is None:
            raise RuntimeError("cameras are disabled")
        f = renderer.render(self.data, camera)
        return msg.RgbdImage(
            stamp=self.time,
            camera=camera,
            rgb=f.rgb,
            depth=f.depth,
            K=f.K,
            position=f.position,
            orientation=f.orientation,
        )

    def scan(self) -> msg.LaserScan:
        if self.lidar is None:
            raise RuntimeError("lidar is disabled")
        s = self.lidar.read(self.data)
        return msg.LaserScan(
            stamp=self.time,
            angle_min=s.angle_min,
            angle_increment=s.angle_increment,
            range_min=s.range_min,
            range_max=s.range_max,
            ranges=s.ranges,
        )

    def gt_poses(self) -> msg.GroundTruthPoses:
        """GROUND TRUTH: world poses of the robot base and every object."""
        d = self.data
        ids = np.concatenate([[self.base], self._object_bodies]).astype(int)
        return msg.GroundTruthPoses(
            stamp=self.time,
            names=["base", *self.object_names],
            positions=d.xpos[ids],
            orientations=d.xquat[ids],
        )

    def gt_drawers(self) -> msg.GroundTruthPoses | None:
        """GROUND TRUTH: world poses of the drawer handles (names ``left``/``right``/``top``;
        None for a world without drawers). How far a drawer is open is its handle's travel."""
        if not self._drawer_names:
            return None
        d = self.data
        return msg.GroundTruthPoses(
            stamp=self.time,
            names=list(self._drawer_names),
            positions=d.xpos[self._drawer_bodies],
            orientations=d.xquat[self._drawer_bodies],
        )

    def gt_contacts(self) -> msg.GroundTruthContacts:
        """GROUND TRUTH: the contacts of the last captured step (see ``physics_step``)."""
        assert self._contacts is not None
        return self._contacts

    def _capture_contacts(self, stamp: float | None = None) -> msg.GroundTruthContacts:
        """Contacts with world point and the force on body1 (world frame), read right
        after the constraint solver so forces and contacts belong to the same step."""
        m, d = self.model, self.data
        b1, b2, pos, frc = [], [], [], []
        f6 = np.zeros(6)
        for i in range(d.ncon):
            c = d.contact[i]
            if c.efc_address < 0:
                continue
            g1, g2 = int(c.geom[0]), int(c.geom[1])
            body1, body2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            mujoco.mj_contactForce(m, d, i, f6)
            # mj_contactForce is the force geom1 exerts on geom2 in the contact frame.
            f_world = -(c.frame.reshape(3, 3).T @ f6[:3])
            b1.append(m.body(body1).name or f"body{body1}")
            b2.append(m.body(body2).name or f"body{body2}")
            pos.append(c.pos.copy())
            frc.append(f_world)
        return msg.GroundTruthContacts(
            stamp=self.time - m.opt.timestep if stamp is None else stamp,
            body1=b1,
            body2=b2,
            positions=np.reshape(pos, (-1, 3)),
            forces=np.reshape(frc, (-1, 3)),
        )

    def judge_report(self) -> msg.JudgeReport | None:
        """The judge's verdict from ground truth (None for a world without regions)."""
        if self.judge is None:
            return None
        return self.judge.report(
            self.data,
            trial_start=self.start_time,
            violations=self.honesty_violations(),
            leg_timeouts=self.actuators.leg_timeouts,
        )

    def observe(self, sensors: bool = True) -> TickOutput:
        """The state of this tick plus every sensor/ground-truth output due at it."""
        out = TickOutput(
            tick=self.tick,
            stamp=self.time,
            lowstate=self.low_state(),
            leg_mode=self.actuators.leg_mode_at(float(self.data.time)),
        )
        return self.add_sensors(out) if sensors else out

    def add_sensors(self, out: TickOutput) -> TickOutput:
        """Fill ``out`` (this tick's) with the sensor and ground-truth outputs due now."""
        if out.tick != self.tick:
            raise ValueError("add_sensors must be called at the tick it observes")
        if self._want_cameras:
            for name, every in self._cam_every.items():
                if self._due(every, self._cam_phase[name]):
                    out.images.append(self.render(name))
        if self._due(self._lidar_every, self._lidar_phase):
            out.scan = self.scan()
        if self._due(self._poses_every):
            out.gt_poses = self.gt_poses()
            out.gt_drawers = self.gt_drawers()
        if self._due(self._contacts_every):
            out.gt_contacts = self.gt_contacts()
        if self._due(self._judge_every):
            out.judge = self.judge_report()
        return out

    # ------------------------------------------------------------------ honesty
    def honesty_violations(self) -> list[str]:
        """Everything the honesty guard found, structural and at run time, deduplicated
        with counts and first times (empty for an honest run): the judge's evidence that
        only physics moved the robot and the objects."""
        return self.honesty.violations()

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
