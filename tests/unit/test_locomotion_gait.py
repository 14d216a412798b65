"""Gait schedule (Fig. 16), COM reference (eqs. 10-12, Algorithm 7) and swing (Algorithm 8)."""

from __future__ import annotations

import numpy as np
import pytest
from quadmanip.common.rotations import quat_mul, yaw_from_quat
from quadmanip.services.locomotion.com_reference import (
    ComReference,
    FsmParams,
    fsm_plan,
    integrate_quat,
    omega_matrix,
)
from quadmanip.services.locomotion.gait import GaitParams, TrotGait
from quadmanip.services.locomotion.swing_leg import SwingParams, swing_profile, touchdown_target

pytestmark = pytest.mark.unit


# --------------------------------------------------------------------------- gait
def test_four_phase_trot_matches_table_3():
    g = TrotGait(GaitParams(t_swing=0.3, t_stance=0.1))
    assert g.period == pytest.approx(0.8)
    ts = np.arange(0.0, 0.8, 0.001)
    contacts = np.array([g.contact(t) for t in ts])
    phases = [g.phase_info(t)[2] for t in ts]
    # swing_FLRR, stance, swing_FRRL, stance with the Table 3 durations.
    assert phases[0] == 0 and phases[350] == 1 and phases[450] == 2 and phases[750] == 3
    assert np.array_equal(contacts[100], [False, True, True, False])
    assert np.array_equal(contacts[500], [True, False, False, True])
    assert np.all(contacts[350]) and np.all(contacts[750])
    # Each leg is down T_sw + 2 T_st = 0.5 s of each 0.8 s cycle; diagonals move together.
    assert contacts.mean(axis=0) == pytest.approx([0.5 / 0.8] * 4, abs=0.002)
    assert np.array_equal(contacts[:, 0], contacts[:, 3])
    assert np.array_equal(contacts[:, 1], contacts[:, 2])
    assert g.stance_duration() == pytest.approx(0.5)


def test_schedule_and_swing_progress():
    g = TrotGait(GaitParams(t_swing=0.2, t_stance=0.05))
    sched = g.schedule(0.0, 6, 0.03)
    assert sched.shape == (6, 4)
    assert not sched[0, 0] and sched[0, 1]
    _, progress, _ = g.phase_info(0.1)
    assert progress[0] == pytest.approx(0.5) and progress[1] == -1.0
    assert g.in_all_stance(0.22) and not g.in_all_stance(0.1)


# ------------------------------------------------------------------ eqs. 10-12
def test_corrected_omega_is_the_quaternion_derivative():
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w = rng.normal(size=3)
        expected = 0.5 * quat_mul(q, np.concatenate([[0.0], w]))
        assert 0.5 * omega_matrix(w) @ q == pytest.approx(expected)


def test_yaw_integration_eq_12():
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for _ in range(500):
        q = integrate_quat(q, np.array([0.0, 0.0, 1.0]), 0.002)
    assert yaw_from_quat(q) == pytest.approx(1.0, abs=1e-3)
    assert np.linalg.norm(q) == pytest.approx(1.0)


def test_target_position_eq_10_and_lead_limit():
    ref = ComReference(FsmParams(max_lead=0.15))
    ref.reset(np.zeros(3), 0.0)
    for _ in range(50):  # 0.1 s at 0.5 m/s with the robot keeping up
        ref.advance(np.array([0.5, 0.0]), 0.0, 0.3, 0.002, ref.p_target.copy(), 0.0)
    assert ref.p_target[0] == pytest.approx(0.05)
    for _ in range(500):  # the robot is held at the origin: the target stops 15 cm ahead
        ref.advance(np.array([0.5, 0.0]), 0.0, 0.3, 0.002, np.zeros(3), 0.0)
    assert np.linalg.norm(ref.p_target[:2]) == pytest.approx(0.15)


def test_fsm_reaches_target_without_exceeding_limits():
    """Algorithm 7 drives the planned pose to the desired one and stops there."""
    pose, vel = np.array([0.0]), np.array([0.0])
    lim, acc = np.array([0.5]), np.array([2.0])
    poses = []
    for _ in range(100):
        pp, pv = fsm_plan(pose, vel, np.array([0.3]), lim, np.array([0.003]),
                          np.array([0.05]), acc, 1, 0.03)  # fmt: skip
        assert abs(pv[0, 0]) <= lim[0] + 1e-9
        pose, vel = pp[0], pv[0]
        poses.append(pose[0])
    assert poses[-1] == pytest.approx(0.3)
    assert vel[0] == 0.0
    assert max(poses) <= 0.3 + 0.02  # no large overshoot


def test_fsm_turns_back_with_feed_back_vel():
    pp, pv = fsm_plan(np.array([0.0]), np.array([-0.4]), np.array([0.2]), np.array([0.5]),
                      np.array([0.003]), np.array([0.05]), np.array([2.0]), 1, 0.03)  # fmt: skip
    assert pv[0, 0] == pytest.approx(0.05)


# ----------------------------------------------------------------- Algorithm 8
def test_swing_profile_shape():
    start = np.array([0.1, 0.15, 0.02])
    target = np.array([0.25, 0.15, 0.02])
    p0, v0 = swing_profile(start, target, 0.0, 0.2, 0.08)
    pm, _ = swing_profile(start, target, 0.5, 0.2, 0.08)
    p1, v1 = swing_profile(start, target, 1.0, 0.2, 0.08)
    assert p0 == pytest.approx(start)
    assert p1 == pytest.approx(target)
    assert pm[2] == pytest.approx(0.02 + 0.08)
    assert pm[0] == pytest.approx(0.175)
    assert v0[:2] == pytest.approx([0.0, 0.0]) and v1[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
    # Finite-difference velocity matches.
    pa, va = swing_profile(start, target, 0.3, 0.2, 0.08)
    pb, _ = swing_profile(start, target, 0.3 + 1e-6 / 0.2, 0.2, 0.08)
    assert (pb - pa) / 1e-6 == pytest.approx(va, rel=1e-4)


def test_raibert_placement_with_velocity_and_yaw_rate():
    hips = np.array([[0.2, 0.15, 0.3], [0.2, -0.15, 0.3], [-0.2, 0.15, 0.3], [-0.2, -0.15, 0.3]])
    offs = hips.copy()
    offs[:, 2] = 0.0
    params = SwingParams(feedback_gain=0.15, max_step=0.3)
    v = np.array([0.5, 0.0, 0.0])
    tgt = touchdown_target(hips, v, v, 0.0, offs, 0.5, np.zeros(4), params, 0.02)
    assert tgt[:, 0] - hips[:, 0] == pytest.approx([0.125] * 4)  # v * T_stance / 2
    assert tgt[:, 2] == pytest.approx([0.02] * 4)
    # Pushed sideways (v_y = 0.3 with no command): feet step out by k * 0.3.
    tgt = touchdown_target(hips, np.array([0.0, 0.3, 0.0]), np.zeros(3), 0.0, offs, 0.5,
                           np.zeros(4), params, 0.02)  # fmt: skip
    assert tgt[:, 1] - hips[:, 1] == pytest.approx([0.045] * 4)
    # Turning left: front feet step left, rear feet right (ω × r_hip).
    tgt = touchdown_target(hips, np.zeros(3), np.zeros(3), 1.0, offs, 0.5, np.zeros(4),
                           params, 0.02)  # fmt: skip
    dy = tgt[:, 1] - hips[:, 1]
    assert dy[0] > 0 and dy[1] > 0 and dy[2] < 0 and dy[3] < 0
