"""Joint and Cartesian trajectories respect limits; postures load; bad input is rejected."""

import math

import numpy as np
import pytest
from quadmanip.common.config import ConfigError
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry, ArmTarget, fk_tcp, solve_ik
from quadmanip.services.manipulation.config import load_manipulation_config
from quadmanip.services.manipulation.postures import REQUIRED_POSTURES, resolve_postures
from quadmanip.services.manipulation.trajectory import (
    JointTrajectory,
    MotionLimits,
    TrajectoryError,
    hold,
    plan_cartesian_line,
    plan_joint_path,
    start_within_limits,
    validate,
)
from quadmanip.sim.actuators import hermite

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def geom():
    return ArmGeometry.from_description()


@pytest.fixture(scope="module")
def cfg():
    return load_manipulation_config()


@pytest.fixture(scope="module")
def limits(geom, cfg):
    return MotionLimits.build(geom, cfg.motion.v_max, cfg.motion.a_max)


def _dense(traj, dt=0.001):
    """What the actuator layer tracks: Hermite interpolation of the knots."""
    ts = np.arange(traj.t[0], traj.t[-1], dt)
    out = [hermite(traj.t, traj.q, traj.dq, t) for t in ts]
    return ts, np.array([o[0] for o in out]), np.array([o[1] for o in out])


def test_joint_path_is_time_optimal_quintic_within_limits(geom, limits, cfg):
    q0 = np.array(cfg.postures["stow"].q)
    q1 = np.array([0.5, 0.3, 0.7, 1.0])
    traj = plan_joint_path([q0, q1], 10.0, limits)
    assert traj.t[0] == 10.0 and np.allclose(traj.q[0], q0) and np.allclose(traj.q[-1], q1)
    assert np.all(traj.dq[0] == 0) and np.allclose(traj.dq[-1], 0, atol=1e-12)
    # duration = max over joints of the quintic bounds 15/8 D/v and sqrt(10/sqrt3 D/a)
    d = np.abs(q1 - q0)
    expect = max(
        np.max(15 / 8 * d / limits.v_max), np.max(np.sqrt(10 / math.sqrt(3) * d / limits.a_max))
    )
    assert traj.end_time - traj.start_time == pytest.approx(expect, rel=1e-9)
    ts, q, dq = _dense(traj)
    assert np.all(np.abs(dq) <= limits.v_max * 1.001)
    acc = np.diff(dq, axis=0) / np.diff(ts)[:, None]
    assert np.all(np.abs(acc) <= limits.a_max * 1.05)
    # synchronised: every joint follows the same normalised profile
    s = (q - q0) / (q1 - q0)
    assert np.allclose(s, s[:, :1], atol=1e-6)


def test_cartesian_line_is_straight(geom, limits, cfg):
    q0 = resolve_postures(geom, cfg)["probe_floor"]
    start = fk_tcp(geom, q0)
    goal = ArmTarget(start.x, start.z - 0.12, start.pitch, start.roll)
    traj = plan_cartesian_line(geom, q0, goal, 0.0, limits, linear_speed=0.15)
    ts, q, _ = _dense(traj, dt=0.002)
    pts = np.array([[fk_tcp(geom, qi).x, fk_tcp(geom, qi).z, fk_tcp(geom, qi).pitch] for qi in q])
    # x and pitch stay put within 1 mm / 5 mrad while z drops 12 cm
    assert np.max(np.abs(pts[:, 0] - start.x)) < 1e-3
    assert np.max(np.abs(pts[:, 2] - start.pitch)) < 5e-3
    end = fk_tcp(geom, traj.q[-1])
    assert end.z == pytest.approx(goal.z, abs=1e-9)
    # 12 cm at 0.15 m/s peak speed -> quintic duration 15/8 * 0.12 / 0.15 = 1.5 s
    assert traj.end_time == pytest.approx(1.5, rel=0.05)
    validate(traj, limits)


def test_cartesian_line_through_unreachable_region_is_rejected(geom, limits, cfg):
    # tool straight down 32 cm ahead, 5 cm above the arm base; 50 cm farther is out of reach
    q0 = np.asarray(solve_ik(geom, ArmTarget(0.32, 0.05, math.pi / 2, 0.0)).q)
    start = fk_tcp(geom, q0)
    with pytest.raises(TrajectoryError) as err:
        plan_cartesian_line(
            geom, q0, ArmTarget(start.x + 0.5, start.z, start.pitch, 0.0), 0.0, limits
        )
    assert err.value.reason.startswith("unreachable_too_far")


def test_limits_and_non_finite_rejected(limits):
    q = np.zeros((3, 4))
    fast = JointTrajectory(
        t=np.array([0.0, 0.1, 0.2]), q=q, dq=np.array([[0, 0, 0, 0], [5.0, 0, 0, 0], [0, 0, 0, 0]])
    )
    with pytest.raises(TrajectoryError, match="velocity_limit"):
        validate(fast, limits)
    jerk = JointTrajectory(
        t=np.array([0.0, 0.01, 0.02]),
        q=q,
        dq=np.array([[0, 0, 0, 0], [1.0, 0, 0, 0], [0, 0, 0, 0]]),
    )
    with pytest.raises(TrajectoryError, match="acceleration_limit"):
        validate(jerk, limits)
    nan = JointTrajectory(t=np.array([0.0]), q=np.full((1, 4), np.nan), dq=np.zeros((1, 4)))
    with pytest.raises(TrajectoryError, match="non_finite"):
        validate(nan, limits)
    with pytest.raises(TrajectoryError, match="joint_limit"):
        plan_joint_path([[0, 0, 0, 0], [3.0, 0, 0, 0]], 0.0, limits)
    with pytest.raises(TrajectoryError, match="non_finite"):
        plan_joint_path([[0, 0, 0, 0], [np.inf, 0, 0, 0]], 0.0, limits)
    h = hold([0.1, 0.2, 0.3, 0.4], 5.0)
    validate(h, limits)
    assert h.t.tolist() == [5.0] and np.all(h.dq == 0)


def test_a_start_pushed_just_past_a_limit_moves_back_inside(geom, limits, cfg):
    # paper-3: the elbow read 2.012 rad (limit 2.000) after a blocked place; every move
    # from there was refused and the held object could not be put down
    j = 2
    postures = resolve_postures(geom, cfg)
    q0 = np.array(postures["probe_table"])
    q0[j] = limits.q_max[j] + 0.012
    q1 = np.array(postures["carry_high"])
    traj = plan_joint_path([q0, q1], 0.0, limits)
    assert traj.q[0][j] == pytest.approx(limits.q_max[j]) and np.allclose(traj.q[-1], q1)
    assert q0[j] == pytest.approx(limits.q_max[j] + 0.012)  # the caller's array untouched
    start = fk_tcp(geom, start_within_limits(q0, limits))
    goal = ArmTarget(start.x, start.z - 0.05, start.pitch, start.roll)  # down: j3 bends less
    line = plan_cartesian_line(geom, q0, goal, 0.0, limits)
    assert np.all(line.q[:, j] <= limits.q_max[j] + 1e-9)
    # a start far outside is no measurement error: refused
    q0[j] = limits.q_max[j] + 0.3
    with pytest.raises(TrajectoryError, match="joint_limit"):
        plan_joint_path([q0, q1], 0.0, limits)


def test_postures_from_config(geom, cfg):
    postures = resolve_postures(geom, cfg)
    assert set(REQUIRED_POSTURES) <= set(postures)
    fl = fk_tcp(geom, postures["probe_floor"])
    # camera looking down (Fig. 5a), 10 deg forward of vertical so the open fingers do not
    # hide the probing area (configs/manipulation.toml)
    assert fl.pitch == pytest.approx(1.4, abs=1e-9)
    assert fk_tcp(geom, postures["probe_table"]).z > fl.z + 0.15  # higher, over a table (5b)
    assert np.allclose(postures["stow"], [-math.pi / 2, math.pi / 2, 0, 0], atol=1e-5)


def test_posture_pitches_are_ones_locomotion_accepts(cfg):
    """A body pitch beyond locomotion's limit would be refused there (a log line) and the
    posture would look from a level trunk; only the tall-box probe lifts the nose."""
    from quadmanip.services.locomotion.controller import load_locomotion_config

    limit = load_locomotion_config().limits.pitch
    pitched = {n for n, p in cfg.postures.items() if p.body_pitch != 0.0}
    assert pitched == {"probe_tall"}
    assert all(abs(p.body_pitch) <= limit for p in cfg.postures.values())
    tall, side = cfg.postures["probe_tall"], cfg.postures["probe_horizontal"]
    assert tall.tcp == side.tcp and tall.body_pitch < 0.0  # the same arm, nose up


def test_unknown_config_key_is_an_error(tmp_path):
    bad = tmp_path / "m.toml"
    bad.write_text("[motion]\nv_maxx = [1.0, 1.0, 1.0, 1.0]\n")
    with pytest.raises(ConfigError, match="v_maxx"):
        load_manipulation_config(str(bad))
