"""Arm kinematics (eqs. 1-9) against pinocchio's FK of the robot description."""

import math

import numpy as np
import pinocchio as pin
import pytest
from quadmanip.paths import CONFIG_DIR
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    IkError,
    IkFailure,
    fk,
    fk_tcp,
    solve_ik,
    solve_ik_or_raise,
    solve_ik_pose,
    target_from_base_pose,
)

pytestmark = pytest.mark.unit

MJCF = CONFIG_DIR / "robot" / "quadmanip_dog.xml"


@pytest.fixture(scope="module")
def geom() -> ArmGeometry:
    return ArmGeometry.from_description()


@pytest.fixture(scope="module")
def pin_model():
    model = pin.buildModelFromMJCF(str(MJCF))
    return model, model.createData()


def _pin_tcp_in_arm_base(model, data, q_arm):
    q = pin.neutral(model)
    for i, name in enumerate(("arm_j1", "arm_j2", "arm_j3", "arm_j4")):
        q[model.joints[model.getJointId(name)].idx_q] = q_arm[i]
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    base = data.oMf[model.getFrameId("arm_base")]
    tcp = data.oMf[model.getFrameId("gripper_tcp")]
    return (base.inverse() * tcp).homogeneous


def test_dimensions_are_table_2(geom):
    # Table 2 of the paper: d1..d5 = 0.06, 0.25, 0.06, 0.21, 0.1 m (read from the MJCF)
    assert (geom.d1, geom.d2, geom.d3, geom.d4, geom.d5) == pytest.approx(
        (0.06, 0.25, 0.06, 0.21, 0.1), abs=1e-12
    )
    assert geom.d7 == pytest.approx(math.hypot(0.06, 0.21))


def test_fk_matches_pinocchio(geom, pin_model):
    model, data = pin_model
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = rng.uniform(geom.q_min, geom.q_max)
        ours = fk(geom, q)
        ref = _pin_tcp_in_arm_base(model, data, q)
        assert np.max(np.abs(ours[:3, 3] - ref[:3, 3])) < 1e-9
        assert np.max(np.abs(ours[:3, :3] - ref[:3, :3])) < 1e-9
        closed = fk_tcp(geom, q)
        assert closed.x == pytest.approx(ref[0, 3], abs=1e-12)
        assert closed.z == pytest.approx(ref[2, 3], abs=1e-12)
        assert abs(ref[1, 3]) < 1e-12  # every reachable pose lies in the arm plane


def test_fk_ik_round_trip(geom):
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(5000):
        q = rng.uniform(geom.q_min, geom.q_max)
        t_ref = fk(geom, q)
        sol = solve_ik(geom, fk_tcp(geom, q), roll_symmetric=False)
        assert sol.ok, sol.detail
        t = fk(geom, sol.q)
        worst = max(worst, np.max(np.abs(t - t_ref)))
    assert worst <= 1e-9


def test_ik_prefers_reference_elbow(geom):
    rng = np.random.default_rng(3)
    n_same = 0
    for _ in range(500):
        q = rng.uniform(geom.q_min, geom.q_max)
        sol = solve_ik(geom, fk_tcp(geom, q), q_ref=q, roll_symmetric=False)
        assert sol.ok
        n_same += np.allclose(sol.q, q, atol=1e-9)
    # with the true configuration as reference the same branch comes back every time
    assert n_same == 500


def test_ik_pose_full_matrix(geom, pin_model):
    model, data = pin_model
    q = np.array([0.4, 0.9, 0.2, -1.1])
    pose = _pin_tcp_in_arm_base(model, data, q)
    sol = solve_ik_pose(geom, pose, q_ref=q)
    assert sol.ok
    assert np.allclose(sol.q, q, atol=1e-9)


def test_rejections_have_reasons(geom):
    reach = geom.d2 + geom.d7
    cases = {
        IkFailure.TOO_FAR: ArmTarget(reach + geom.d5 + 0.05, geom.d1, 0.0, 0.0),
        # wrist exactly at the shoulder: closer than |d2 - d7|
        IkFailure.TOO_CLOSE: ArmTarget(geom.d5, geom.d1, 0.0, 0.0),
        IkFailure.NON_FINITE: ArmTarget(float("nan"), 0.1, 0.0, 0.0),
    }
    for reason, target in cases.items():
        sol = solve_ik(geom, target)
        assert not sol.ok and sol.reason is reason and sol.q is None and sol.detail
    # a roll beyond the wrist range (and its half-turn twin) when symmetry is not allowed
    sol = solve_ik(geom, ArmTarget(0.3, 0.0, 1.0, 3.05), roll_symmetric=False)
    assert sol.reason is IkFailure.ROLL_OUT_OF_RANGE
    # ... accepted through the gripper's half-turn symmetry
    sol = solve_ik(geom, ArmTarget(0.3, 0.0, 1.0, 3.05))
    assert sol.ok and sol.q[3] == pytest.approx(3.05 - math.pi)
    # in reach, but only with the wrist bent beyond its +-2 rad range (tool pointing back)
    sol = solve_ik(geom, ArmTarget(0.35, 0.1, math.pi, 0.0))
    assert sol.reason is IkFailure.JOINT_LIMIT and "arm_j" in sol.detail
    with pytest.raises(IkError) as err:
        solve_ik_or_raise(geom, cases[IkFailure.TOO_FAR])
    assert err.value.reason is IkFailure.TOO_FAR


def test_out_of_plane_target_reports_lateral_shift(geom):
    pose = fk(geom, (0.3, 0.8, 0.4, 0.0))
    pose[1, 3] = 0.07
    sol = solve_ik_pose(geom, pose)
    assert sol.reason is IkFailure.OUT_OF_PLANE
    assert sol.lateral_shift == pytest.approx(0.07)
    # body frame -> arm_base frame: y is the shift Algorithm 6's moveCOM must make
    p_base = np.array(geom.arm_base_pos) + np.array([0.3, -0.05, -0.2])
    target, shift = target_from_base_pose(geom, p_base, math.pi / 2, 0.0)
    assert shift == pytest.approx(-0.05)
    assert (target.x, target.z) == pytest.approx((0.3, -0.2))


def test_floor_is_reachable_from_standing(geom):
    """A 5 cm object on the floor 30 cm ahead of the trunk centre, home height 0.30 m."""
    base_height = 0.30
    p_base = np.array([0.30, 0.0, 0.025 - base_height])
    target, shift = target_from_base_pose(geom, p_base, math.pi / 2, 0.0)
    sol = solve_ik(geom, target)
    assert sol.ok and shift == 0.0
    assert fk(geom, sol.q)[2, 3] == pytest.approx(target.z, abs=1e-9)


def test_carry_while_holding_turns_the_fingers_to_close_along_the_body_x(geom, pin_model):
    """PostureSpec.held_across: carried, an object pinched across its narrow side lies
    across the body (a spoon's handle no longer reaches back into the front legs); the
    tool centre stays where the posture puts it."""
    from quadmanip.services.manipulation.config import load_manipulation_config
    from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
    from quadmanip.services.manipulation.postures import resolve_postures
    from quadmanip.services.manipulation.primitive import PostureMove

    cfg = load_manipulation_config()
    model, data = pin_model
    for name in ("carry", "carry_high"):
        assert cfg.postures[name].held_across
        q = resolve_postures(geom, cfg)[name]
        monitor = GraspMonitor(cfg.gripper)
        move = PostureMove(geom, cfg, q, held_across=True, monitor=monitor)
        empty = _pin_tcp_in_arm_base(model, data, move.goal_for(0.0))
        assert abs(empty[1, 1]) == pytest.approx(1.0, abs=1e-9)  # fingers slide along y
        monitor.state = GripState.HOLDING
        for roll_now in (-1.0, 0.0, 1.0):
            q_held = move.goal_for(roll_now)
            assert geom.q_min[3] <= q_held[3] <= geom.q_max[3]
            if roll_now:  # the quarter turn nearer the wrist's roll now
                assert q_held[3] == pytest.approx(q[3] + math.copysign(math.pi / 2, roll_now))
            held = _pin_tcp_in_arm_base(model, data, q_held)
            assert abs(held[0, 1]) == pytest.approx(1.0, abs=1e-9)  # ... now along x
            np.testing.assert_allclose(held[:3, 3], empty[:3, 3], atol=1e-12)
