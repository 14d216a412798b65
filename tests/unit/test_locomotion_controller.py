"""The controller in closed loop with MuJoCo physics, in-process (no Zenoh).

The plant is the sim's own engine (actuator layer at 1 kHz, IMU model) with the robot on a
flat floor, started in the description's `lying` keyframe. The controller sees only the
LowState; ground truth is read by the test to judge. The same acceptance runs over Zenoh,
with the sim and locomotion as separate processes, are in
tests/integration/test_locomotion_acceptance.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import mujoco
import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import quat_from_yaw, quat_mul
from quadmanip.services.locomotion.controller import (
    CommandError,
    LocomotionController,
    load_locomotion_config,
)
from quadmanip.testbench.locomotion_plant import SimPlant, controller_step

pytestmark = pytest.mark.unit

FOOT_SITES = [f"{leg}_foot" for leg in ("FL", "FR", "RL", "RR")]


class Run:
    """Controller + plant; `until(t, before_tick)` advances to sim time t."""

    def __init__(self, plant: SimPlant | None = None, **overrides: object) -> None:
        self.ctl = LocomotionController(load_locomotion_config(**overrides))
        self.plant = plant or SimPlant()
        self.ls = self.plant.lowstate
        self.fell = False
        self._feet = [self.plant.model.site(s).id for s in FOOT_SITES]

    def until(self, t: float, before_tick: Callable[[float], None] | None = None) -> None:
        while self.plant.time < t - 1e-9:
            if before_tick is not None:
                before_tick(self.ls.stamp)
            self.ls = self.plant.step(controller_step(self.ctl, self.ls))
            if self.ctl.phase in ("balance", "walk", "stopping") and self.plant.fallen():
                self.fell = True

    def stand(self) -> None:
        self.ctl.set_mode("stand")
        self.until(2.5)
        assert self.ctl.phase == "balance"

    def base_minus_feet(self) -> np.ndarray:
        """True base position relative to the centre of the feet (world frame)."""
        d = self.plant.data
        return self.plant.true_position() - d.site_xpos[self._feet].mean(axis=0)

    def walk(self, v: tuple[float, float, float], t_end: float, settle: float = 1.0) -> float:
        """Walk with a 50 Hz command stream; returns the RMSE after `settle` seconds."""
        t0 = self.plant.time
        errs: list[np.ndarray] = []

        def cmd(t: float) -> None:
            k = round(t / 0.002)
            if k % 10 == 0:
                self.ctl.set_velocity(*v, now=t)
            if t - t0 >= settle:
                errs.append(self.plant.true_velocity_body() - np.asarray(v))

        self.until(t_end, cmd)
        e = np.array(errs)
        self.lin_rmse = float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1))))
        self.yaw_rmse = float(np.sqrt(np.mean(e[:, 2] ** 2)))
        return self.lin_rmse


def test_stands_up_from_lying_and_holds_still():
    run = Run()
    assert run.plant.true_position()[2] < 0.15  # starts lying
    run.stand()
    p0 = run.plant.true_position()
    run.until(5.0)
    p1 = run.plant.true_position()
    assert p1[2] == pytest.approx(0.30, abs=0.01)
    assert np.linalg.norm(p1[:2] - p0[:2]) < 0.02
    rpy = run.ctl.last_rpy
    assert abs(rpy[0]) < 0.02 and abs(rpy[1]) < 0.02
    # The MPC's forces carry the weight measured by the plant's own model.
    mass = float(run.plant.model.body_subtreemass[run.plant.model.body("base").id])
    assert run.ctl.debug.foot_forces[:, 2].sum() == pytest.approx(mass * 9.81, rel=0.05)


@pytest.mark.parametrize("heading_deg", [90.0, 180.0])
def test_stands_level_whatever_its_heading(heading_deg: float):
    """The MPC's angular reference is in the world frame and the plan's in Euler rates: a
    mix-up of the two rolled a robot standing at 90° over within 10 s (a grasp trial in
    front of a table, on CI). Standing at any heading keeps the trunk level."""
    plant = SimPlant()
    q = plant.data.qpos
    q[3:7] = quat_mul(quat_from_yaw(math.radians(heading_deg)), q[3:7].copy())
    mujoco.mj_forward(plant.model, plant.data)
    plant.lowstate = plant.engine.low_state()
    run = Run(plant)
    run.stand()
    worst = 0.0

    def tilt(_t: float) -> None:
        nonlocal worst
        r = run.plant.data.xmat[run.plant.model.body("base").id].reshape(3, 3)
        worst = max(worst, math.degrees(math.acos(min(1.0, r[2, 2]))))

    run.until(6.0, tilt)
    assert worst < 1.5, f"trunk tilted {worst:.1f}° standing at {heading_deg}°"
    assert not run.fell


def test_trots_forward_at_half_a_metre_per_second():
    run = Run()
    run.stand()
    rmse = run.walk((0.5, 0.0, 0.0), 6.0)
    assert not run.fell
    assert rmse <= 0.1
    assert run.yaw_rmse <= 0.15
    assert run.plant.true_position()[0] > 1.2  # 3.5 s of walking at ~0.5 m/s


def test_turns_in_place_at_one_radian_per_second():
    run = Run()
    run.stand()
    yaw0 = run.plant.true_yaw()
    run.walk((0.0, 0.0, 1.0), 5.5)
    assert not run.fell
    assert run.yaw_rmse <= 0.15
    assert run.lin_rmse <= 0.1
    turned = (run.plant.true_yaw() - yaw0) % (2 * math.pi)
    assert turned > 2.0  # 3 s at ~1 rad/s (mod 2π)


def test_stops_and_stands_within_half_a_second_of_the_last_command():
    run = Run()
    run.stand()
    run.walk((0.4, 0.0, 0.0), 4.5)
    t_last = run.plant.time
    run.until(t_last + 0.5)
    v = run.plant.true_velocity_body()
    assert np.linalg.norm(v[:2]) < 0.1
    assert run.ctl.phase == "balance" and bool(np.all(run.ctl.debug.contact))
    # Afterwards it only re-centres the body over its feet (at most pose_speed, 0.1 m/s).
    p_stop = run.plant.true_position()
    run.until(t_last + 1.5)
    assert np.linalg.norm(run.plant.true_position()[:2] - p_stop[:2]) < 0.05


@pytest.mark.parametrize("v", [(0.05, 0.03, 0.0), (0.0, -0.06, 0.1)])
def test_a_slow_trot_that_stops_leaves_the_trunk_where_it_stopped(v):
    """The precise approach creeps and stops: standing, the trunk stays where the trot
    stopped instead of moving over the feet's centre (that moved it ~5 mm here, 5-18 mm
    in the full stack, after the approach had said it was there)."""
    run = Run()
    run.stand()
    run.walk(v, run.plant.time + 2.0, settle=0.5)

    def zero(t: float) -> None:
        if round(t / 0.002) % 10 == 0:
            run.ctl.set_velocity(0.0, 0.0, 0.0, now=t)

    t0 = run.plant.time
    while run.ctl.phase != "balance" and run.plant.time < t0 + 2.0:
        run.until(run.plant.time + 0.01, zero)
    assert run.ctl.phase == "balance"
    p_stop = run.plant.true_position()
    run.until(run.plant.time + 1.5, zero)
    assert np.linalg.norm(run.plant.true_position()[:2] - p_stop[:2]) < 0.003
    assert not run.fell


def test_a_small_velocity_while_standing_moves_the_trunk_without_a_step():
    """The precise approach's last centimetres: commands within the trot's deadband move
    the standing trunk over its feet (no trot, no foot moves), so 1.5 cm forward-left and
    1 degree of turn land within millimetres, and the move stops at ``nudge_reach``."""
    run = Run()
    run.stand()
    d = run.plant.data
    feet0 = d.site_xpos[run._feet][:, :2].copy()
    p0 = run.plant.true_position()[:2].copy()
    yaw0 = run.ctl.last_rpy[2]
    v = (0.015, 0.0075, 0.0175)  # for 1 s: 1.5 cm forward, 0.75 cm left, 1 degree left

    def nudge(t: float) -> None:
        if round(t / 0.002) % 10 == 0:
            run.ctl.set_velocity(*(v if t < t0 + 1.0 else (0.0, 0.0, 0.0)), now=t)

    t0 = run.plant.time
    run.until(t0 + 2.5, nudge)
    assert run.ctl.phase == "balance"  # it never trotted
    assert np.abs(d.site_xpos[run._feet][:, :2] - feet0).max() < 0.003
    c, s = math.cos(yaw0), math.sin(yaw0)
    moved = run.plant.true_position()[:2] - p0
    assert c * moved[0] + s * moved[1] == pytest.approx(0.015, abs=0.003)
    assert -s * moved[0] + c * moved[1] == pytest.approx(0.0075, abs=0.003)
    assert math.degrees(run.ctl.last_rpy[2] - yaw0) == pytest.approx(1.0, abs=0.3)
    # held on: the trunk stops at the reach, still standing on the same feet
    v = (0.02, 0.0, 0.0)
    t0 = run.plant.time
    run.until(t0 + 4.0, lambda t: run.ctl.set_velocity(*v, now=t))
    reach = float(np.linalg.norm(run.base_minus_feet()[:2]))
    assert reach == pytest.approx(run.ctl.cfg.nudge_reach, abs=0.01)
    assert run.ctl.phase == "balance" and not run.fell
    # a command above the nudge speed trots as before
    run.until(run.plant.time + 0.3, lambda t: run.ctl.set_velocity(0.05, 0.0, 0.0, now=t))
    assert run.ctl.phase == "walk"


def test_crouch_and_com_shift_follow_body_pose_commands():
    run = Run()
    run.stand()
    ref = run.base_minus_feet()
    run.ctl.set_body_pose(-0.08, 0.0, 0.0, 0.0, 0.0, 0.0)
    run.until(4.5)
    assert run.plant.true_position()[2] == pytest.approx(0.30 - 0.08, abs=0.01)
    for dx, dy in ((0.05, 0.0), (-0.05, 0.0), (0.0, 0.05), (0.0, -0.05)):
        run.ctl.set_body_pose(0.0, dx, dy, 0.0, 0.0, 0.0)
        run.until(run.plant.time + 2.0)
        shift = run.base_minus_feet() - ref
        assert shift[0] == pytest.approx(dx, abs=0.01)
        assert shift[1] == pytest.approx(dy, abs=0.01)
    run.ctl.set_body_pose(0.0, 0.0, 0.0, 0.15, -0.1, 0.1)
    run.until(run.plant.time + 1.5)
    assert run.ctl.last_rpy[0] == pytest.approx(0.15, abs=0.02)
    assert run.ctl.last_rpy[1] == pytest.approx(-0.1, abs=0.02)
    assert not run.fell


def test_recovers_from_a_30_newton_lateral_push_while_trotting_in_place():
    run = Run()
    run.stand()
    run.ctl.set_mode("walk")
    run.until(3.5)
    run.plant.push(np.array([0.0, 30.0, 0.0]), 0.2)
    peak = 0.0

    def watch(_t: float) -> None:
        nonlocal peak
        peak = max(peak, abs(run.plant.true_velocity_body()[1]))

    run.until(5.5, watch)
    assert peak > 0.1  # the push really moved the robot
    assert not run.fell
    assert np.linalg.norm(run.plant.true_velocity_body()[:2]) < 0.15


def test_rejects_invalid_commands_with_a_reason():
    run = Run()
    ctl = run.ctl
    with pytest.raises(CommandError, match="unknown mode"):
        ctl.set_mode("dance")
    with pytest.raises(CommandError, match="standing"):
        ctl.set_mode("walk")  # lying in damping: cannot walk
    with pytest.raises(CommandError, match="need mode"):
        ctl.set_velocity(0.2, 0.0, 0.0, now=0.0)
    run.stand()
    with pytest.raises(CommandError, match="non-finite"):
        ctl.set_velocity(float("nan"), 0.0, 0.0, now=2.5)
    with pytest.raises(CommandError, match="outside limits"):
        ctl.set_velocity(2.0, 0.0, 0.0, now=2.5)
    with pytest.raises(CommandError, match="z_offset"):
        ctl.set_body_pose(-0.5, 0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(CommandError, match="non-finite"):
        ctl.set_body_pose(0.0, float("inf"), 0.0, 0.0, 0.0, 0.0)
    assert ctl.phase == "balance" and ctl.mode == "stand"
    assert np.all(ctl.cmd_vel == 0.0)


def heavy_gripper_plant(extra_mass: float) -> SimPlant:
    """Robot whose gripper carries `extra_mass` kg: the model of a held object (no weld)."""
    spec = rd.robot_spec()
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], friction=[1, 0.005, 1e-4]
    )
    model = spec.compile()
    tcp_body = model.site_bodyid[model.site(rd.GRIPPER_TCP_SITE).id]
    model.body_mass[tcp_body] += extra_mass
    mujoco.mj_setConst(model, mujoco.MjData(model))
    return SimPlant(model=model)


def test_arm_reaching_forward_with_half_a_kilo_stands_and_walks():
    run = Run(plant=heavy_gripper_plant(0.5), held_mass=0.5)
    eng = run.plant.engine
    # Arm forward: the sim's actuator layer tracks this trajectory from t = 0.5 s.
    from quadmanip.common import messages as m

    q_reach = np.array([0.9, 0.5, -1.3, 0.0])
    q0 = run.plant.lowstate.joints.q[12:16]
    eng.apply_arm_trajectory(
        m.ArmTrajectory(
            stamp=0.0,
            t=np.array([0.5, 2.0]),
            q=np.stack([q0, q_reach]),
            dq=np.zeros((2, 4)),
            kp=np.full(4, 60.0),
            kd=np.full(4, 2.0),
        )  # fmt: skip
    )
    run.stand()
    run.until(3.0)
    assert np.abs(run.plant.lowstate.joints.q[12:16] - q_reach).max() < 0.1
    x0 = run.plant.true_position()[0]
    run.walk((0.4, 0.0, 0.0), 9.0)
    assert not run.fell
    assert run.plant.true_position()[0] - x0 >= 2.0
    assert run.lin_rmse <= 0.15


def test_sit_down_and_damp():
    run = Run()
    run.stand()
    run.ctl.set_mode("sit")
    run.until(4.5)
    assert run.plant.true_position()[2] < 0.16  # folded legs, trunk low
    q = run.plant.lowstate.joints.q[:12]
    assert q[2::3] == pytest.approx([-2.7] * 4, abs=0.15)  # knees folded
    run.ctl.set_mode("damp")
    out = controller_step(run.ctl, run.plant.lowstate)
    assert np.all(out.kp == 0.0) and np.all(out.tau_ff == 0.0) and np.all(out.kd > 0.0)
    run.until(5.5)
    assert run.plant.true_position()[2] < 0.16


def test_node_helpers_held_mass_and_quaternion():
    from quadmanip.common import messages as m
    from quadmanip.common.rotations import mat_to_quat, quat_to_mat
    from quadmanip.services.locomotion.controller import NodeOptions
    from quadmanip.services.locomotion.node import held_mass

    opt = NodeOptions(held_object_mass=0.5, grip_effort_threshold=2.0, grip_min_gap=0.005)
    z = np.zeros(16)
    squeezing = m.JointState(stamp=0.0, q=z, dq=z, tau=z, gripper_gap=0.03, gripper_effort=8.0)
    empty = m.JointState(stamp=0.0, q=z, dq=z, tau=z, gripper_gap=0.001, gripper_effort=8.0)
    open_ = m.JointState(stamp=0.0, q=z, dq=z, tau=z, gripper_gap=0.05, gripper_effort=0.0)
    # no word from manipulation: the gripper state decides
    assert held_mass(None, squeezing, opt) == 0.5
    assert held_mass(None, empty, opt) == 0.0  # closed on nothing
    assert held_mass(None, open_, opt) == 0.0
    # manipulation's payload wins over the guess, both ways
    assert held_mass(m.Payload(stamp=1.0, mass=0.097), squeezing, opt) == 0.097
    assert held_mass(m.Payload(stamp=1.0, mass=0.0), squeezing, opt) == 0.0
    with pytest.raises(m.MessageError):
        m.Payload(stamp=1.0, mass=-0.1)
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        assert mat_to_quat(quat_to_mat(q)) == pytest.approx(q, abs=1e-9)


def test_the_trunk_reaches_a_body_offset_in_the_time_manipulation_waits_for_it():
    """Manipulation waits for a trunk move a time that grows with its length
    (primitive.body_settle_time): by then the trunk stands within 4 mm (its drift
    tolerance, PrimitiveConfig.drift_tol) of each offset, from a few millimetres (a place's
    sideways shift) to an 8 cm crouch."""
    from quadmanip.services.manipulation.config import load_manipulation_config
    from quadmanip.services.manipulation.primitive import BodyPoseRequest, body_settle_time

    cfg = load_manipulation_config()
    run = Run()
    run.stand()
    ref = run.base_minus_feet()
    z0 = run.plant.true_position()[2]
    old = BodyPoseRequest()
    waits = []
    for z, y in ((0.0, 0.006), (0.03, 0.006), (0.015, -0.034), (-0.08, 0.0), (0.0, 0.0)):
        new = BodyPoseRequest(y_offset=y, z_offset=z)
        wait = body_settle_time(cfg.grasp, old, new)
        waits.append(wait)
        run.ctl.set_body_pose(z, 0.0, y, 0.0, 0.0, 0.0)
        run.until(run.plant.time + wait)
        shift = run.base_minus_feet() - ref
        dz = run.plant.true_position()[2] - z0
        assert abs(shift[1] - y) < cfg.primitive.drift_tol, (z, y, wait, shift)
        assert abs(dz - z) < cfg.primitive.drift_tol, (z, y, wait, dz)
        old = new
    assert not run.fell
    assert min(waits) < 0.5 * cfg.grasp.body_settle_time  # a short move is not waited long
