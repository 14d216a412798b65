"""Self-righting: side detection, the sequence's bookkeeping, and falls in physics.

The physics trials (quadmanip/testbench/self_righting_trials.py) stand the robot up with
the locomotion controller, topple it with a push through the sim's test-only disturbance
channel, damp the legs until it rests, right it from its measured state and stand it up
again; they are judged on ground truth. The 10-per-side sweep of the issue's acceptance is
``run_trials`` in that module (``python -m quadmanip.testbench.self_righting_trials``).
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.common.joint_layout import LEG_JOINTS, LEG_SLICE, N_LEG_JOINTS, leg_slice
from quadmanip.common.rotations import (
    quat_from_axis_angle,
    quat_from_euler_xyz,
    quat_from_yaw,
    quat_mul,
    quat_to_mat,
)
from quadmanip.services.locomotion.self_righting import (
    RecoveryParams,
    SelfRighting,
    gravity_in_base,
    lying_side,
    side_roll,
    tilt_angle,
)
from quadmanip.testbench.self_righting_trials import PushSpec, run_trial

pytestmark = pytest.mark.unit

P = RecoveryParams()
Q_LYING = rd.lying_joint_positions()[LEG_SLICE]


def g_of(roll_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """gravity_base (world z in the base frame) of a base rolled, then pitched about its
    new y axis, as given (degrees)."""
    return gravity_in_base(quat_from_euler_xyz([roll_deg, pitch_deg, 0.0], degrees=True))


# ------------------------------------------------------------------ side detection
def test_gravity_in_base_is_world_z_in_the_base_frame():
    # Heading 0.5 rad, then rolled onto its left side.
    q = quat_mul(quat_from_yaw(0.5), quat_from_axis_angle([1.0, 0.0, 0.0], -math.pi / 2))
    r = quat_to_mat(q)
    assert gravity_in_base(q) == pytest.approx(r[2, :])
    # Left side down: the base's +y axis (its left) points down in the world.
    assert r[:, 1] == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    assert gravity_in_base(q) == pytest.approx([0.0, -1.0, 0.0], abs=1e-12)


@pytest.mark.parametrize(
    ("roll", "pitch", "side"),
    [
        (0.0, 0.0, "upright"),
        (15.0, 0.0, "upright"),
        (-10.0, 12.0, "upright"),
        (0.0, -18.0, "upright"),
        (-25.0, 0.0, "left"),
        (-45.0, 0.0, "left"),  # propped on its legs
        (-90.0, 0.0, "left"),  # flat on the left side
        (-130.0, 0.0, "left"),  # leaning back on the arm
        (-120.0, 15.0, "left"),
        (45.0, 0.0, "right"),
        (90.0, 0.0, "right"),
        (130.0, -10.0, "right"),
        (145.0, 0.0, "right"),  # the most a push left it rolled, with margin
        (160.0, 0.0, "back"),
        (-160.0, 0.0, "back"),
        (180.0, 0.0, "back"),
        (0.0, 170.0, "back"),  # flipped over its nose
        (-30.0, 85.0, "left"),  # nose down, leaning left
        (30.0, -85.0, "right"),  # tail down, leaning right
    ],
)
def test_lying_side_from_scripted_gravity(roll, pitch, side):
    assert lying_side(g_of(roll, pitch), P) == side


def test_lying_side_accepts_an_accelerometer_scale_reading_and_rejects_garbage():
    assert lying_side(9.81 * g_of(-100.0), P) == "left"
    assert lying_side(np.array([0.0, 0.3, 9.7]), P) == "upright"
    for bad in (np.zeros(3), np.array([0.0, np.nan, 1.0]), np.array([np.inf, 0.0, 0.0])):
        with pytest.raises(ValueError):
            lying_side(bad, P)


def test_lying_side_thresholds_come_from_the_params():
    strict = RecoveryParams(
        done_tilt=math.radians(8.0), upright_tilt=math.radians(12.0), back_tilt=math.radians(60.0)
    )
    assert lying_side(g_of(15.0), P) == "upright"
    assert lying_side(g_of(15.0), strict) == "right"
    assert lying_side(g_of(-130.0), P) == "left"
    assert lying_side(g_of(-130.0), strict) == "back"


def test_params_are_checked():
    with pytest.raises(ValueError, match="durations"):
        RecoveryParams(t_push=0.0)
    with pytest.raises(ValueError, match="tilts"):
        RecoveryParams(done_tilt=0.5, upright_tilt=0.4)
    with pytest.raises(ValueError, match="tilts"):
        RecoveryParams(rolled_tilt=1.2)
    with pytest.raises(ValueError, match="max_attempts"):
        RecoveryParams(max_attempts=0)


def test_side_roll_and_tilt():
    assert side_roll(g_of(-90.0), "left") == pytest.approx(math.pi / 2)
    assert side_roll(g_of(-130.0), "left") == pytest.approx(math.radians(130.0))
    assert side_roll(g_of(130.0), "right") == pytest.approx(math.radians(130.0))
    assert side_roll(g_of(20.0), "left") == pytest.approx(math.radians(-20.0))
    assert tilt_angle(g_of(0.0, 30.0)) == pytest.approx(math.radians(30.0))
    assert tilt_angle(g_of(180.0)) == pytest.approx(math.pi)


def test_params_are_toml_friendly():
    for f in fields(RecoveryParams):
        assert isinstance(getattr(P, f.name), (int, float, str, tuple)), f.name
    assert 0.0 < P.done_tilt < P.rolled_tilt < P.relapse_tilt
    assert P.done_tilt < P.upright_tilt


# ------------------------------------------------------------------ the sequence, no physics
def drive(sr: SelfRighting, gravity, t_end: float, q0=None, dt: float = 0.002):
    """Feed the sequence perfect tracking (q = last q_des) and gravity(t); log commands."""
    q = np.array(Q_LYING if q0 is None else q0, dtype=float)
    out = []
    t = 0.0
    while t <= t_end and not (sr.done or sr.failed):
        q_des, dq_des, kp, kd = sr.command(t, q, np.zeros(N_LEG_JOINTS), gravity(t))
        out.append((t, sr.phase, q.copy(), q_des, dq_des, kp, kd))
        q = q_des.copy()
        t += dt
    return out


def test_times_out():
    sr = SelfRighting(RecoveryParams(timeout=1.0), "left", Q_LYING, Q_LYING)
    drive(sr, lambda t: g_of(-100.0), 2.0)
    assert sr.failed and "timeout" in sr.reason


def test_rejects_a_start_that_is_not_a_side_and_bad_arrays():
    with pytest.raises(ValueError, match="side"):
        SelfRighting(P, "back", Q_LYING, Q_LYING)
    with pytest.raises(ValueError, match="12"):
        SelfRighting(P, "left", np.zeros(16), Q_LYING)
    with pytest.raises(ValueError, match="finite"):
        SelfRighting(P, "left", np.full(12, np.nan), Q_LYING)


def test_commands_respect_joint_ranges_and_torque_limits():
    info = rd.robot_info()
    lo = np.array([info.joint_ranges[j][0] for j in LEG_JOINTS])
    hi = np.array([info.joint_ranges[j][1] for j in LEG_JOINTS])
    tau = info.torque_limits[:N_LEG_JOINTS]
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        sr = SelfRighting(P, side, rng.uniform(lo, hi), Q_LYING)
        t = 0.0
        while t < P.timeout and not sr.failed:
            q = rng.uniform(lo - 0.1, hi + 0.1)  # measured, even a little past the ranges
            roll = rng.uniform(60.0, 140.0) * (-1 if side == "left" else 1)
            q_des, dq_des, kp, kd = sr.command(t, q, rng.normal(size=12), g_of(roll))
            assert np.all(q_des >= lo) and np.all(q_des <= hi)
            assert np.all(np.abs(kp * (q_des - q)) <= tau + 1e-9)
            assert np.all(kp >= 0.0) and np.all(kd > 0.0) and np.all(np.isfinite(dq_des))
            t += 0.01
        assert sr.failed


def test_left_and_right_sequences_mirror_each_other():
    def swapped(q: np.ndarray) -> np.ndarray:  # FL <-> FR, RL <-> RR
        return np.concatenate([q[leg_slice(i)] for i in (1, 0, 3, 2)])

    def mirrored(q: np.ndarray) -> np.ndarray:
        m = swapped(q)
        m[0::3] *= -1.0  # abduction axes are +x on both sides
        return m

    q0 = Q_LYING + np.random.default_rng(1).normal(scale=0.1, size=12)
    left = SelfRighting(P, "left", q0, Q_LYING)
    right = SelfRighting(P, "right", mirrored(q0), Q_LYING)
    assert left.ground_legs == (0, 2) and right.ground_legs == (1, 3)
    assert left.lever_leg == 2 and right.lever_leg == 3
    for k in range(1500):
        t = 0.002 * k
        roll = 120.0 - 30.0 * t
        ql, _, kpl, _ = left.command(t, q0, np.zeros(12), g_of(-roll))
        qr, _, kpr, _ = right.command(t, mirrored(q0), np.zeros(12), g_of(roll))
        assert left.phase == right.phase
        assert qr == pytest.approx(mirrored(ql), abs=1e-9)
        assert kpr == pytest.approx(swapped(kpl))


def test_the_rear_floor_side_leg_goes_behind_the_back_and_presses_into_the_floor():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    assert sr.ground_legs == (0, 2) and sr.lever_leg == 2  # FL, RL; RL levers
    log = drive(sr, lambda t: g_of(-115.0), 2.0)
    phases = [row[1] for row in log]
    for ph in ("tuck", "turn", "sweep", "push", "hold"):
        assert ph in phases
    last, kp = log[-1][3], log[-1][5]
    level = math.radians(115.0 - 90.0)  # abduction that puts a leg's plane parallel to the floor
    abad, hip, knee = last[leg_slice(2)]
    assert hip > 2.5  # the leg points up and back
    assert abad == pytest.approx(level - P.dig_angle)  # its plane tilted into the floor
    assert knee > -1.0  # stretched
    assert kp[leg_slice(2)] == pytest.approx([P.kp_push] * 3)
    abad, hip, knee = last[leg_slice(0)]  # FL stays folded, its plane off the floor
    assert abad == pytest.approx(level - P.clear_angle)
    assert hip == pytest.approx(Q_LYING[1]) and knee == pytest.approx(P.tuck_knee)
    for leg in (1, 3):  # the upper legs wait folded, to land on
        assert last[leg_slice(leg)] == pytest.approx(Q_LYING[leg_slice(leg)])


def test_propped_on_its_legs_it_is_lowered_onto_its_side_first():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    log = drive(sr, lambda t: g_of(-45.0) if t < 1.0 else g_of(-125.0), 3.0)
    phases = list(dict.fromkeys(row[1] for row in log))
    assert phases[:5] == ["tuck", "lower", "turn", "sweep", "push"]
    lowered = [row[3] for row in log if row[1] == "lower"][-1]
    for leg in (0, 2):  # abduction back to zero, folded: the propping legs give way
        assert lowered[leg_slice(leg)][0] == pytest.approx(0.0, abs=1e-3)
        assert lowered[leg_slice(leg)][2] == pytest.approx(P.tuck_knee, abs=1e-3)
    assert sr.attempts == 1


def test_done_once_rolled_level_and_folded():
    sr = SelfRighting(P, "right", Q_LYING, Q_LYING)
    log = drive(sr, lambda t: g_of(110.0) if t < 1.2 else g_of(3.0, -2.0), 6.0)
    assert sr.done and not sr.failed
    phases = list(dict.fromkeys(row[1] for row in log))
    assert phases[-4:] == ["unlever", "fold", "settle", "done"]
    assert log[-1][3] == pytest.approx(Q_LYING)
    t_done = log[-1][0]
    assert t_done == pytest.approx(1.2 + P.t_unlever + P.t_fold, abs=0.02)


def test_not_done_while_the_legs_are_still_moving():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    t, t_settled = 0.0, P.t_unlever + P.t_fold + P.t_settle
    while t < t_settled - 0.05:
        sr.command(t, Q_LYING, np.full(12, 2.0), g_of(0.0))  # level, legs swinging
        t += 0.002
    assert not sr.done and not sr.failed
    while t < t_settled + 0.05:
        sr.command(t, Q_LYING, np.full(12, 2.0), g_of(0.0))
        t += 0.002
    assert sr.failed and "not at rest" in sr.reason


def test_gives_up_after_the_attempts_when_it_does_not_roll():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    log = drive(sr, lambda t: g_of(-100.0), P.timeout)
    assert sr.failed and sr.attempts == P.max_attempts
    assert "left side" in sr.reason
    assert [row[1] for row in log].count("tuck") > 1  # it tried again
    # Failed: limp, as in damping.
    q_des, _, kp, kd = sr.command(log[-1][0] + 0.01, Q_LYING, np.zeros(12), g_of(-100.0))
    assert np.all(kp == 0.0) and np.all(kd > 0.0)


def test_fails_when_it_ends_on_its_back():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    drive(sr, lambda t: g_of(-100.0) if t < 0.6 else g_of(-175.0), 4.0)
    assert sr.failed and "back" in sr.reason


def test_starts_over_from_the_other_side_if_it_rolls_there():
    sr = SelfRighting(P, "left", Q_LYING, Q_LYING)
    drive(sr, lambda t: g_of(-100.0) if t < 1.0 else g_of(110.0), 3.5)
    assert sr.side == "right" and sr.attempts == 2 and sr.ground_legs == (1, 3)


# ------------------------------------------------------------------ physics
@pytest.mark.parametrize(("side", "seed"), [("left", 0), ("right", 1)])
def test_pushed_over_rights_itself_and_stands(side, seed):
    r = run_trial(side, seed)
    assert r["fell_to"] == side, r
    assert 100.0 < abs(r["rest_roll_deg"]) < 140.0  # really on its side
    assert r["success"], r
    assert r["t_standing"] < 10.0


def test_rights_itself_when_propped_on_its_legs_after_a_small_push():
    # A smaller impulse leaves the robot leaning ~45 deg on its folded-under legs.
    r = run_trial("left", 3, push=PushSpec("left", 100.0, 0.25))
    assert r["fell_to"] == "left" and abs(r["rest_roll_deg"]) < 60.0, r
    assert r["success"], r
