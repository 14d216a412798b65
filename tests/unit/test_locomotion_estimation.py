"""Leg kinematics (pinocchio vs MuJoCo), whole-body inertia, and the Kalman state estimator."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import quat_to_mat, rpy_from_mat
from quadmanip.services.locomotion.leg_kinematics import FOOT_SITES, LegKinematics
from quadmanip.services.locomotion.state_estimator import EstimatorParams, StateEstimator

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def kin() -> LegKinematics:
    return LegKinematics()


@pytest.fixture(scope="module")
def mj() -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = rd.load_mujoco_model()
    return m, mujoco.MjData(m)


def _mujoco_at(mj, q16: np.ndarray) -> mujoco.MjData:
    m, d = mj
    mujoco.mj_resetData(m, d)
    d.qpos[2] = 0.0
    d.qpos[rd.joint_qpos_indices(m)] = q16
    mujoco.mj_forward(m, d)
    return d


def test_feet_and_jacobians_match_mujoco(kin, mj):
    m, _ = mj
    rng = np.random.default_rng(3)
    for _ in range(5):
        q16 = rd.home_joint_positions(m) + rng.normal(scale=0.3, size=16)
        d = _mujoco_at(mj, q16)
        kin.update(q16)
        dofs = rd.joint_dof_indices(m)
        for i, site in enumerate(FOOT_SITES):
            sid = m.site(site).id
            assert kin.foot_pos[i] == pytest.approx(d.site_xpos[sid], abs=1e-9)
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jacp, None, sid)
            assert kin.foot_jac[i] == pytest.approx(jacp[:, dofs[3 * i : 3 * i + 3]], abs=1e-9)


def test_stance_torque_sign_is_minus_j_transpose_f(kin, mj):
    """Virtual work: a foot pushed up by the ground needs motor torques τ = −Jᵀ f."""
    m, _ = mj
    q16 = rd.home_joint_positions(m)
    kin.update(q16)
    f = np.zeros((4, 3))
    f[:, 2] = 40.0
    tau = kin.leg_torques(f)
    # Equilibrium of the leg: for any small joint motion the motors' work and the ground
    # force's work on the foot cancel, τ·δq + f·δp = 0 (checked by finite differences).
    dq = np.random.default_rng(0).normal(scale=1e-4, size=12)
    q2 = q16.copy()
    q2[:12] += dq
    p0 = kin.foot_pos.copy()
    kin.update(q2)
    dp = kin.foot_pos - p0
    assert tau @ dq + np.sum(f * dp) == pytest.approx(0.0, abs=1e-6)


def test_whole_body_inertia_matches_mujoco(kin, mj):
    m, _ = mj
    q16 = rd.home_joint_positions(m)
    d = _mujoco_at(mj, q16)
    kin.update(q16)
    bi = kin.body_inertia()
    base = m.body("base").id
    assert bi.mass == pytest.approx(float(m.body_subtreemass[base]), rel=1e-9)
    assert bi.com == pytest.approx(d.subtree_com[base] - d.xpos[base], abs=1e-9)
    assert np.all(np.linalg.eigvalsh(bi.inertia) > 0)
    # A 0.5 kg object in the gripper moves the COM towards the gripper.
    held = kin.body_inertia(held_mass=0.5)
    tcp = d.site_xpos[m.site(rd.GRIPPER_TCP_SITE).id] - d.xpos[base]
    assert held.mass == pytest.approx(bi.mass + 0.5)
    expected = (bi.mass * bi.com + 0.5 * tcp) / (bi.mass + 0.5)
    assert held.com == pytest.approx(expected, abs=1e-9)


def test_arm_reaching_forward_moves_com_forward(kin, mj):
    m, _ = mj
    q_stowed = rd.home_joint_positions(m)
    kin.update(q_stowed)
    com_stowed = kin.body_inertia().com
    q_reach = q_stowed.copy()
    q_reach[12:16] = [0.8, 0.6, -1.4, 0.0]
    kin.update(q_reach)
    assert kin.body_inertia().com[0] > com_stowed[0] + 0.005


# ------------------------------------------------------------------ estimator
def _feet_world() -> np.ndarray:
    return np.array(
        [[0.2, 0.15, 0.02], [0.2, -0.15, 0.02], [-0.2, 0.15, 0.02], [-0.2, -0.15, 0.02]]
    )


def test_estimator_tracks_constant_velocity_walk():
    """Base moving at 0.4 m/s over fixed stance feet; IMU with a small accelerometer bias."""
    est = StateEstimator(EstimatorParams())
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    v = np.array([0.4, -0.1, 0.0])
    feet = _feet_world()
    p = np.array([0.0, 0.0, 0.3])
    est.reset(quat, feet - p)
    est.x[3:6] = 0.0  # starts not knowing the velocity
    dt = 0.002
    for _ in range(1000):
        p = p + v * dt
        rel = feet - p
        foot_vel = np.tile(-v, (4, 1))
        est.update(dt, quat, np.zeros(3), np.array([0.02, -0.02, 9.81]), rel, foot_vel, np.ones(4))
    assert est.velocity == pytest.approx(v, abs=0.01)
    assert est.position[:2] == pytest.approx(p[:2], abs=0.02)
    assert est.position[2] == pytest.approx(0.3, abs=0.005)


def test_estimator_ignores_swing_feet():
    est = StateEstimator(EstimatorParams())
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    feet = _feet_world()
    p = np.array([0.0, 0.0, 0.3])
    est.reset(quat, feet - p)
    stance = np.array([1.0, 0.0, 0.0, 1.0])
    for _ in range(300):
        rel = feet - p
        vel = np.zeros((4, 3))
        # Swing feet report wild motion; the stance feet say the base is still.
        rel[[1, 2]] += np.array([0.0, 0.0, 0.05])
        vel[[1, 2]] = [1.0, 0.0, 0.5]
        est.update(0.002, quat, np.zeros(3), np.array([0.0, 0.0, 9.81]), rel, vel, stance)
    assert np.abs(est.velocity).max() < 0.01
    assert est.position == pytest.approx(p, abs=0.003)


def test_rotation_helpers_roundtrip():
    rng = np.random.default_rng(5)
    for _ in range(5):
        rpy = rng.uniform(-0.5, 0.5, size=3)
        cr, sr = np.cos(rpy[0]), np.sin(rpy[0])
        cp, sp = np.cos(rpy[1]), np.sin(rpy[1])
        cy, sy = np.cos(rpy[2]), np.sin(rpy[2])
        r = (
            np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
            @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
            @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        )
        assert rpy_from_mat(r) == pytest.approx(rpy)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, r.reshape(9))
        assert quat_to_mat(q) == pytest.approx(r)
