"""Actuator layer math: PD+ff torque, clamps, timeout damping, arm spline, rejection.

Uses a small fixed-base model with the robot's joint names (each joint on its own body),
so the numbers here depend only on the actuator layer, not on the robot description.
"""

import mujoco
import numpy as np
import pytest
from quadmanip.common.robot_description import (
    ARM_JOINTS,
    GRIPPER_JOINTS,
    LEG_JOINTS,
    robot_spec,
)
from quadmanip.sim.actuators import (
    ActuatorConfig,
    ActuatorLayer,
    LegMode,
    hermite,
    torque_speed_clamp,
)

pytestmark = pytest.mark.unit

TAU_LEG = 33.5
TAU_ARM = 10.0
F_GRIP = 40.0


def _model() -> mujoco.MjModel:
    """Fixed-base stand-in: one hinge per robot joint, the robot's tendon-driven gripper
    (two slides synchronised by an equality, with the description's drive inertia, one
    motor on the gap tendon) and the description's ``velocity_limits`` numeric."""
    bodies, motors = [], []
    for i, name in enumerate(LEG_JOINTS + ARM_JOINTS):
        bodies.append(
            f'<body name="b_{name}" pos="{i} 0 0"><joint name="{name}" axis="0 1 0" '
            f'damping="0"/><geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="1"/>'
            "</body>"
        )
        lim = TAU_LEG if name in LEG_JOINTS else TAU_ARM
        motors.append(f'<motor joint="{name}" ctrlrange="{-lim} {lim}" ctrllimited="true"/>')
    armature = robot_spec().joint(GRIPPER_JOINTS[0]).armature  # the drive's inertia
    for k, name in enumerate(GRIPPER_JOINTS):
        bodies.append(
            f'<body name="b_{name}" pos="20 {k} 0"><joint name="{name}" type="slide" '
            f'axis="0 1 0" range="0 0.05" limited="true" damping="2" armature="{armature}"/>'
            '<geom type="box" size="0.01 0.01 0.01" mass="0.05"/></body>'
        )
    motors.append(f'<motor name="gripper" tendon="gap" ctrlrange="{-F_GRIP} {F_GRIP}"/>')
    speeds = " ".join(["30"] * 12 + ["6"] * 4 + ["0.15"])
    xml = (
        '<mujoco><option gravity="0 0 0" timestep="0.001"/><worldbody>'
        + "".join(bodies)
        + '</worldbody><tendon><fixed name="gap"><joint joint="gripper_left" coef="1"/>'
        '<joint joint="gripper_right" coef="1"/></fixed></tendon>'
        '<equality><joint joint1="gripper_right" joint2="gripper_left"/></equality>'
        "<actuator>"
        + "".join(motors)
        + f'</actuator><custom><numeric name="velocity_limits" data="{speeds}"/></custom>'
        "</mujoco>"
    )
    return mujoco.MjModel.from_xml_string(xml)


@pytest.fixture
def layer():
    m = _model()
    d = mujoco.MjData(m)
    cfg = ActuatorConfig(torque_speed_corner=0.5, leg_damping_kd=2.0)
    return m, d, ActuatorLayer(m, cfg, LEG_JOINTS, ARM_JOINTS, GRIPPER_JOINTS)


def _leg_cmd(q=0.0, dq=0.0, kp=0.0, kd=0.0, ff=0.0):
    return tuple(np.full(12, v, dtype=float) for v in (q, dq, kp, kd, ff))


def test_limits_come_from_the_model(layer):
    _, _, act = layer
    assert np.allclose(act.legs.tau_max, TAU_LEG)
    assert np.allclose(act.arm.tau_max, TAU_ARM)
    assert np.allclose(act.gripper.tau_max, F_GRIP)
    assert np.allclose(act.legs.max_speed, 30.0)
    assert np.allclose(act.arm.max_speed, 6.0)


def test_pd_feedforward_law_and_clamp(layer):
    m, d, act = layer
    rng = np.random.default_rng(1)
    q = rng.uniform(-0.5, 0.5, 12)
    dq = rng.uniform(-2, 2, 12)
    d.qpos[act.legs.qpos] = q
    d.qvel[act.legs.dof] = dq
    q_des, dq_des = rng.uniform(-0.5, 0.5, 12), rng.uniform(-1, 1, 12)
    kp, kd, ff = np.full(12, 20.0), np.full(12, 0.5), rng.uniform(-3, 3, 12)
    assert act.set_leg_command(d.time, q_des, dq_des, kp, kd, ff)
    act.apply(d)
    expected = kp * (q_des - q) + kd * (dq_des - dq) + ff
    assert np.all(np.abs(expected) < TAU_LEG)  # small enough to be unclamped
    np.testing.assert_allclose(d.ctrl[act.legs.act], expected, rtol=0, atol=1e-12)
    # A huge gain saturates at exactly the model's limit, with the right sign.
    assert act.set_leg_command(d.time, q + 1.0, dq, np.full(12, 1e4), kd, np.zeros(12))
    act.apply(d)
    np.testing.assert_allclose(d.ctrl[act.legs.act], TAU_LEG)


def test_torque_speed_envelope():
    tau_max = np.array([10.0])
    # Below the corner speed: full torque both ways.
    assert torque_speed_clamp(np.array([50.0]), np.array([10.0]), tau_max, 30, 0.5)[0] == 10
    # Halfway between corner (15) and no-load (30): half torque in the direction of motion.
    assert torque_speed_clamp(np.array([50.0]), np.array([22.5]), tau_max, 30, 0.5)[0] == 5
    # Braking torque (against the motion) keeps the full limit.
    assert torque_speed_clamp(np.array([-50.0]), np.array([22.5]), tau_max, 30, 0.5)[0] == -10
    # At and beyond no-load speed no driving torque is left.
    assert torque_speed_clamp(np.array([50.0]), np.array([31.0]), tau_max, 30, 0.5)[0] == 0


def test_starts_in_damping_and_times_out_after_50ms(layer):
    m, d, act = layer
    dq = np.linspace(-3, 3, 12)
    d.qvel[act.legs.dof] = dq
    act.apply(d)
    assert act.leg_mode is LegMode.DAMPING
    assert act.leg_timeouts == 0  # damping before any command is not a timeout
    np.testing.assert_allclose(d.ctrl[act.legs.act], -2.0 * dq)
    assert act.set_leg_command(d.time, *_leg_cmd(ff=1.5))
    step = m.opt.timestep
    n_active = 0
    while True:
        d.qvel[act.legs.dof] = dq  # keep the velocity so the damping torque is visible
        act.apply(d)
        if act.leg_mode is not LegMode.ACTIVE:
            break
        np.testing.assert_allclose(d.ctrl[act.legs.act], 1.5)
        n_active += 1
        d.time += step
    # Active for 50 ms (inclusive of the command's own step), then damping.
    assert n_active == 51
    assert d.time == pytest.approx(0.051, abs=1e-9)
    np.testing.assert_allclose(d.ctrl[act.legs.act], -2.0 * dq)
    assert act.leg_timeouts == 1
    act.apply(d)
    assert act.leg_timeouts == 1  # counted once per timeout, not per step
    # A fresh command brings it back.
    assert act.set_leg_command(d.time, *_leg_cmd(ff=-1.0))
    act.apply(d)
    assert act.leg_mode is LegMode.ACTIVE


@pytest.mark.parametrize(
    "bad",
    [
        {"q": np.full(11, 0.0)},
        {"kp": np.full(13, 1.0)},
        {"ff": np.r_[np.zeros(11), np.nan]},
        {"dq": np.r_[np.inf, np.zeros(11)]},
        {"kd": np.r_[-1.0, np.zeros(11)]},
        {"q": np.zeros((3, 4))},
    ],
)
def test_bad_leg_commands_never_reach_physics(layer, bad):
    _, d, act = layer
    good = dict(zip(("q", "dq", "kp", "kd", "ff"), _leg_cmd(kp=10.0, ff=0.5), strict=True))
    assert act.set_leg_command(d.time, *good.values())
    act.apply(d)
    before = d.ctrl.copy()
    cmd = {**good, **bad}
    assert not act.set_leg_command(d.time, *cmd.values())
    assert act.rejected == 1
    act.apply(d)
    np.testing.assert_array_equal(d.ctrl, before)
    assert np.all(np.isfinite(d.ctrl))


def test_bad_arm_and_gripper_commands_rejected(layer):
    _, d, act = layer
    t = np.array([0.0, 1.0])
    q = np.zeros((2, 4))
    k = np.ones(4)
    assert not act.set_arm_trajectory(0, t, np.zeros((2, 3)), q, k, k)
    assert not act.set_arm_trajectory(0, t, q, q, np.ones(5), k)
    assert not act.set_arm_trajectory(0, np.array([0.0, np.nan]), q, q, k, k)
    assert not act.set_arm_trajectory(0, np.array([1.0, 0.5]), q, q, k, k)
    assert not act.set_arm_trajectory(0, t, q, q, k, k, np.zeros((3, 4)))  # tau_ff per knot
    assert not act.set_arm_trajectory(0, t, q, q, k, k, np.full((2, 4), np.inf))
    assert not act.set_gripper_command(0, float("nan"), 10.0)
    assert not act.set_gripper_command(0, 0.02, -1.0)
    assert act.rejected == 8
    act.apply(d)
    assert np.all(np.isfinite(d.ctrl))


def test_hermite_exact_at_knots_and_smooth_between():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.1, 0.5, 6))
    q = rng.normal(size=(6, 4))
    dq = rng.normal(size=(6, 4))
    for i in range(6):
        p, v = hermite(t, q, dq, t[i])
        np.testing.assert_allclose(p, q[i], atol=1e-12)
        np.testing.assert_allclose(v, dq[i], atol=1e-12)
    # C1: velocity equals the numerical derivative of position, and is continuous at knots.
    ts = np.linspace(t[0], t[-1], 4001)
    pos = np.array([hermite(t, q, dq, x)[0] for x in ts])
    vel = np.array([hermite(t, q, dq, x)[1] for x in ts])
    num = np.gradient(pos, ts, axis=0)
    assert np.max(np.abs(num[2:-2] - vel[2:-2])) < 1e-2 * max(1.0, np.abs(vel).max())
    assert np.max(np.abs(np.diff(vel, axis=0))) < 0.05 * np.abs(vel).max()
    # A cubic is reproduced exactly (Hermite is exact for cubics).
    f = lambda x: 0.3 * x**3 - x**2 + 2 * x - 1  # noqa: E731
    df = lambda x: 0.9 * x**2 - 2 * x + 2  # noqa: E731
    tk = np.array([0.0, 0.7, 1.5])
    qk = np.repeat(f(tk)[:, None], 4, axis=1)
    dqk = np.repeat(df(tk)[:, None], 4, axis=1)
    for x in np.linspace(0, 1.5, 17):
        np.testing.assert_allclose(hermite(tk, qk, dqk, x)[0], f(x), atol=1e-12)
    # After the end: hold the last point with zero velocity.
    p, v = hermite(t, q, dq, t[-1] + 1.0)
    np.testing.assert_allclose(p, q[-1])
    np.testing.assert_allclose(v, 0.0)


def test_arm_trajectory_drives_pd_and_replacement_starts_at_its_first_stamp(layer):
    m, d, act = layer
    kp, kd = np.full(4, 8.0), np.full(4, 0.3)
    t = np.array([0.0, 1.0])
    q = np.array([[0.0] * 4, [1.0] * 4])
    dq = np.zeros((2, 4))
    assert act.set_arm_trajectory(d.time, t, q, dq, kp, kd)
    d.time = 0.5
    act.apply(d)
    q_mid, dq_mid = hermite(t, q, dq, 0.5)
    np.testing.assert_allclose(q_mid, 0.5)
    np.testing.assert_allclose(d.ctrl[act.arm.act], kp * q_mid + kd * dq_mid)
    # A second trajectory starting at t=0.8 does not act before 0.8 ...
    q2 = np.array([[-1.0] * 4, [-1.0] * 4])
    assert act.set_arm_trajectory(d.time, np.array([0.8, 2.0]), q2, dq, kp * 0.75, kd)
    d.time = 0.7
    act.apply(d)
    q7, dq7 = hermite(t, q, dq, 0.7)
    np.testing.assert_allclose(d.ctrl[act.arm.act], np.clip(kp * q7 + kd * dq7, -10, 10))
    # ... and replaces the first one from 0.8 on.
    d.time = 0.9
    act.apply(d)
    np.testing.assert_allclose(d.ctrl[act.arm.act], 0.75 * kp * -1.0)
    # After its end it holds the last point.
    d.time = 5.0
    act.apply(d)
    np.testing.assert_allclose(d.ctrl[act.arm.act], 0.75 * kp * -1.0)


def test_arm_feed_forward_is_interpolated_added_to_the_pd_and_clamped(layer):
    m, d, act = layer
    kp, kd = np.full(4, 8.0), np.full(4, 0.3)
    t = np.array([0.0, 1.0, 2.0])
    q = np.array([[0.0] * 4, [1.0] * 4, [1.0] * 4])
    dq = np.zeros((3, 4))
    ff = np.array([[1.0, -1.0, 0.0, 2.0], [3.0, -3.0, 4.0, 2.0], [30.0, -30.0, 4.0, 2.0]])
    assert act.set_arm_trajectory(d.time, t, q, dq, kp, kd, ff)
    for now, ff_now in ((0.25, [1.5, -1.5, 1.0, 2.0]), (1.0, ff[1]), (1.5, [16.5, -16.5, 4, 2])):
        d.time = now
        act.apply(d)
        q_d, dq_d = hermite(t, q, dq, now)
        want = np.clip(kp * q_d + kd * dq_d + np.asarray(ff_now), -TAU_ARM, TAU_ARM)
        np.testing.assert_allclose(d.ctrl[act.arm.act], want)  # linear in time, then clamped
    d.time = 9.0  # after the end: the last knot's feed-forward is held
    act.apply(d)
    np.testing.assert_allclose(d.ctrl[act.arm.act], np.clip(kp * 1.0 + ff[2], -TAU_ARM, TAU_ARM))
    # without tau_ff (a 1.0 sender) there is no feed-forward
    assert act.set_arm_trajectory(d.time, np.array([10.0]), q[:1], dq[:1], kp, kd)
    d.time = 10.0
    act.apply(d)
    np.testing.assert_allclose(d.ctrl[act.arm.act], 0.0)


def test_arm_follows_trajectory_in_physics(layer):
    m, d, act = layer
    t = np.linspace(0.0, 1.0, 5)
    q = np.outer(np.sin(np.pi * t), [0.4, -0.3, 0.2, 0.5])
    dq = np.outer(np.pi * np.cos(np.pi * t), [0.4, -0.3, 0.2, 0.5])
    assert act.set_arm_trajectory(0.0, t, q, dq, np.full(4, 200.0), np.full(4, 5.0))
    err = []
    while d.time < 1.2:
        act.apply(d)
        mujoco.mj_step(m, d)
        qd, _ = hermite(t, q, dq, d.time)
        err.append(np.abs(d.qpos[act.arm.qpos] - qd).max())
    assert max(err) < 0.05  # tracks the spline within 3 degrees
    assert err[-1] < 0.01


def test_gripper_force_clamped_to_max_force(layer):
    m, d, act = layer
    assert act.gripper_gap_range() == (0.0, 0.1)
    step = m.opt.timestep
    # Fingers held far from the target (blocked): once the ramped setpoint has moved past
    # them the force saturates at max_force, not at the motor limit, and stays there.
    d.qpos[act.gripper.qpos] = 0.04
    assert act.set_gripper_command(d.time, 0.0, 7.5)
    for _ in range(20):
        act.apply(d)
        d.time += step
    np.testing.assert_allclose(d.ctrl[act.gripper.act], -7.5)
    # Anti-windup: the setpoint waits just past the blocked fingers instead of running on
    # to the commanded gap.
    assert act.gripper_setpoint == pytest.approx(0.08, abs=2e-3)
    # At the target: proportional control on the gap (sum of the two fingers).
    d.qpos[act.gripper.qpos] = 0.0201
    assert act.set_gripper_command(d.time, 0.04, 30.0)
    for _ in range(30):
        act.apply(d)
        d.time += step
    assert act.gripper_setpoint == pytest.approx(0.04, abs=1e-12)
    np.testing.assert_allclose(
        d.ctrl[act.gripper.act], act.config.gripper_kp * (0.04 - 0.0402), atol=1e-9
    )
    # In physics the fingers settle at the commanded gap, symmetrically.
    assert act.set_gripper_command(d.time, 0.06, 30.0)
    for _ in range(1500):
        act.apply(d)
        mujoco.mj_step(m, d)
    assert act.gripper_gap(d) == pytest.approx(0.06, abs=5e-4)
    q = d.qpos[act.gripper.qpos]
    assert q[0] == pytest.approx(q[1], abs=1e-3)


# Finger-speed tolerance: the ramped setpoint moves at exactly the rated gap speed and the
# torque-speed envelope stops the motor pushing past it; being explicit, it can overshoot
# by one step's speed change (~1.5 % when a squeezed object vanishes). The two fingers are
# kept in step by a soft equality, so one may run a few percent ahead of the other. 2 % on
# the gap rate, 7 % on a single finger.
SPEED_TOL = 0.02
FINGER_TOL = 0.07


def _gripper_model(with_object: bool) -> mujoco.MjModel:
    """A fixed palm with the robot's gripper (two pads facing each other, slides synchronised
    by an equality, one motor on the gap tendon, the description's finger damping and
    armature and its 0.15 m/s rated gap speed) and, optionally, a free 30 mm box floating
    between the pads (no gravity)."""
    robot = robot_spec()
    joint = robot.joint(GRIPPER_JOINTS[0])
    fingers = "".join(
        f'<body name="{name}"><joint name="{name}" type="slide" axis="0 {sign} 0" '
        f'range="0 0.06" damping="{joint.damping[0]}" armature="{joint.armature}"/>'
        f'<geom type="box" size="0.02 0.003 0.011" pos="0 {sign * 0.003} 0" mass="0.04" '
        'friction="1 0.005 0.0001" condim="4" solref="0.004 1"/></body>'
        for name, sign in zip(GRIPPER_JOINTS, (1, -1), strict=True)
    )
    obj = (
        '<body name="obj" pos="0 0 0"><freejoint/><geom type="box" size="0.02 0.015 0.02" '
        'mass="0.1" solref="0.004 1"/></body>'
        if with_object
        else ""
    )
    bodies, motors = [], []
    for i, name in enumerate(LEG_JOINTS + ARM_JOINTS):
        bodies.append(
            f'<body pos="{i + 1} 0 0"><joint name="{name}" axis="0 1 0"/>'
            '<geom type="sphere" size="0.02" mass="1" contype="0" conaffinity="0"/></body>'
        )
        motors.append(f'<motor joint="{name}" ctrlrange="-10 10"/>')
    speeds = " ".join(["30"] * 12 + ["6"] * 4 + ["0.15"])
    xml = (
        '<mujoco><option gravity="0 0 0" timestep="0.001" integrator="implicitfast" '
        'cone="elliptic" impratio="10"/><worldbody><body name="palm">'
        + fingers
        + "</body>"
        + obj
        + "".join(bodies)
        + '</worldbody><tendon><fixed name="gap"><joint joint="gripper_left" coef="1"/>'
        '<joint joint="gripper_right" coef="1"/></fixed></tendon>'
        '<equality><joint joint1="gripper_right" joint2="gripper_left" solref="0.005 1"/>'
        "</equality><actuator>"
        + "".join(motors)
        + '<motor name="gripper" tendon="gap" ctrlrange="-40 40"/></actuator>'
        f'<custom><numeric name="velocity_limits" data="{speeds}"/></custom></mujoco>'
    )
    return mujoco.MjModel.from_xml_string(xml)


@pytest.mark.parametrize("with_object", [False, True])
def test_fingers_never_exceed_the_rated_gap_speed(with_object):
    """Open -> closed at the full 40 N: the fingers move at the description's rated speed
    (0.15 m/s of gap, 0.075 m/s per pad), never faster, and a blocked close still
    squeezes the object at the commanded force."""
    m = _gripper_model(with_object)
    d = mujoco.MjData(m)
    act = ActuatorLayer(m, ActuatorConfig(), LEG_JOINTS, ARM_JOINTS, GRIPPER_JOINTS)
    v_lim = 0.15
    assert act.gripper_speed == pytest.approx(v_lim)  # read from the model's numeric
    d.qpos[act.gripper.qpos] = 0.05  # open: gap 0.1 m
    mujoco.mj_forward(m, d)
    gaps, v_gap, v_fingers = [], [], []

    def run(seconds: float) -> None:
        for _ in range(round(seconds / m.opt.timestep)):
            act.apply(d)
            mujoco.mj_step(m, d)
            gaps.append(act.gripper_gap(d))
            v_fingers.append(np.abs(d.qvel[act.gripper.dof]).max())
            v_gap.append(abs(d.qvel[act.gripper.dof].sum()))

    assert act.set_gripper_command(d.time, 0.0, 40.0)
    run(1.0)
    rate = np.abs(np.diff(gaps)) / m.opt.timestep  # the gap's measured rate of change
    assert max(v_gap) <= v_lim * (1 + SPEED_TOL)
    assert rate.max() <= v_lim * (1 + SPEED_TOL)
    assert max(v_fingers) <= 0.5 * v_lim * (1 + FINGER_TOL)  # each pad moves half the gap
    # It really moves at the rated speed (not slower): 0.1 m -> the object / closed in
    # about gap / 0.15 m/s.
    t_half = np.argmax(np.asarray(gaps) < 0.07) * m.opt.timestep
    assert t_half == pytest.approx(0.03 / v_lim, abs=0.01)
    if with_object:
        # Blocked at the object's 30 mm, squeezing at the full commanded force.
        assert act.gripper_gap(d) == pytest.approx(0.03, abs=1.5e-3)
        assert act.tau[act.gripper.act] == pytest.approx(-40.0)
    else:
        assert act.gripper_gap(d) < 1e-3
    # Opening again follows the ramp too (the setpoint did not wind up past the object).
    gaps.clear(), v_gap.clear(), v_fingers.clear()
    assert act.set_gripper_command(d.time, 0.1, 40.0)
    run(0.8)
    rate = np.abs(np.diff(gaps)) / m.opt.timestep
    assert max(v_gap) <= v_lim * (1 + SPEED_TOL)
    assert rate.max() <= v_lim * (1 + SPEED_TOL)
    assert max(v_fingers) <= 0.5 * v_lim * (1 + FINGER_TOL)
    assert act.gripper_gap(d) == pytest.approx(0.1, abs=1e-3)


def test_fingers_freed_while_squeezing_stay_within_the_rated_speed():
    """The object vanishes from a 40 N squeeze (it slipped out): the motor is at its current
    limit, yet the fingers close no faster than the rated speed (the back-EMF line)."""
    m = _gripper_model(True)
    d = mujoco.MjData(m)
    act = ActuatorLayer(m, ActuatorConfig(), LEG_JOINTS, ARM_JOINTS, GRIPPER_JOINTS)
    d.qpos[act.gripper.qpos] = 0.02  # 40 mm, closing on the 30 mm box
    mujoco.mj_forward(m, d)
    assert act.set_gripper_command(d.time, 0.0, 40.0)
    for _ in range(300):
        act.apply(d)
        mujoco.mj_step(m, d)
    assert act.tau[act.gripper.act] == pytest.approx(-40.0, abs=0.5)  # squeezing
    free = next(j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE)
    obj = m.jnt_qposadr[free]
    d.qpos[obj : obj + 3] = (0.0, 0.0, 1.0)  # test disturbance: the object is gone
    v_gap = []
    for _ in range(400):
        act.apply(d)
        mujoco.mj_step(m, d)
        v_gap.append(abs(d.qvel[act.gripper.dof].sum()))
    assert max(v_gap) <= 0.15 * (1 + SPEED_TOL)
    assert act.gripper_gap(d) < 1e-3  # and they did close
