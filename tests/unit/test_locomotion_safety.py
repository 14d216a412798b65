"""The safety checker and the deadline monitor with scripted states (no physics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.services.locomotion.deadline import DeadlineMonitor, DeadlineParams
from quadmanip.services.locomotion.safety import SafetyChecker, SafetyLimits

LO, HI, TAU = rd.leg_joint_limits()
Q_OK = (LO + HI) / 2.0
Z = np.zeros(12)


def checker(**kw) -> SafetyChecker:
    return SafetyChecker(SafetyLimits(**kw), LO, HI, TAU)


def test_leg_limits_come_from_the_description():
    assert LO.shape == HI.shape == TAU.shape == (12,)
    assert np.all(LO < HI)
    assert set(TAU.tolist()) == {30.0, 40.0}  # hip/thigh 30 N m, knee 40 N m (ctrlrange)


@pytest.mark.parametrize("axis", ["roll", "pitch"])
def test_tilt_trips_just_past_the_limit(axis):
    c = checker(max_roll=0.6, max_pitch=0.6)
    ang = {"roll": 0.0, "pitch": 0.0}
    ang[axis] = 0.59
    assert c.check(0.0, ang["roll"], ang["pitch"], Q_OK, Z, 0.28) is None
    ang[axis] = -0.61
    reason = c.check(0.002, ang["roll"], ang["pitch"], Q_OK, Z, 0.28)
    assert reason is not None and reason.startswith(axis) and "34°" in reason


def test_low_trunk_trips_only_after_its_time_and_resets_when_it_rises():
    c = checker(min_height=0.12, low_height_time=0.3)
    assert c.check(0.0, 0, 0, Q_OK, Z, 0.10) is None
    assert c.check(0.29, 0, 0, Q_OK, Z, 0.10) is None
    assert c.check(0.30, 0, 0, Q_OK, Z, 0.13) is None  # back up: timer reset
    assert c.check(0.50, 0, 0, Q_OK, Z, 0.11) is None
    assert c.check(0.79, 0, 0, Q_OK, Z, 0.11) is None
    assert "trunk 0.11 m" in c.check(0.80, 0, 0, Q_OK, Z, 0.11)


def test_height_none_is_not_checked():
    c = checker(min_height=0.12, low_height_time=0.0)
    assert c.check(1.0, 0, 0, Q_OK, Z, None) is None
    assert c.check(1.0, 0, 0, Q_OK, Z, 0.05) is not None


def test_joint_out_of_range_by_more_than_the_margin():
    c = checker(joint_margin=0.1)
    q = Q_OK.copy()
    q[2] = LO[2] - 0.09
    assert c.check(0.0, 0, 0, q, Z, 0.28) is None
    q[2] = LO[2] - 0.11
    assert "leg joint 2" in c.check(0.0, 0, 0, q, Z, 0.28)
    q = Q_OK.copy()
    q[7] = HI[7] + 0.2
    assert "leg joint 7" in c.check(0.0, 0, 0, q, Z, 0.28)


def test_torque_saturation_must_be_uninterrupted():
    c = checker(torque_fraction=0.98, saturation_time=0.5)
    tau = Z.copy()
    tau[5] = -TAU[5]  # at the limit
    dt = 0.002
    for k in range(200):  # 0.4 s saturated
        assert c.check(k * dt, 0, 0, Q_OK, tau, 0.28) is None
    assert c.check(0.402, 0, 0, Q_OK, Z, 0.28) is None  # a break
    t0 = 0.404
    for k in range(250):  # 0.498 s
        assert c.check(t0 + k * dt, 0, 0, Q_OK, tau, 0.28) is None
    assert "leg joint 5 torque saturated" in c.check(t0 + 0.5, 0, 0, Q_OK, tau, 0.28)
    c.reset()
    assert c.check(2.0, 0, 0, Q_OK, tau, 0.28) is None


def test_bad_limits_are_refused():
    with pytest.raises(ValueError):
        SafetyLimits(max_roll=0.0)
    with pytest.raises(ValueError):
        SafetyLimits(torque_fraction=1.5)


# ----------------------------------------------------------------------------- deadline
DT = 0.002


def run(mon: DeadlineMonitor, t0: float, seconds: float, answer_s: float = 0.0005,
        skip_every: int = 0, tick0: int | None = None,
        pace: float | None = None) -> tuple[list, float, int]:  # fmt: skip
    """Feed the monitor 500 Hz ticks; every ``skip_every``-th tick is never answered.
    ``pace``: the robot's robot seconds per wall second, told to the monitor through the
    states' arrival times (None: no arrival times)."""
    changes = []
    n = round(seconds / DT)
    tick = round(t0 / DT) if tick0 is None else tick0
    t = t0
    for k in range(n):
        tick += 1
        t = t0 + (k + 1) * DT
        if skip_every and k % skip_every == 0:
            continue
        arrived = None if pace is None else 1000.0 + t / pace
        mon.tick(t, tick, answer_s, 0.001 if k % 15 == 0 else None, arrived)
        ch = mon.evaluate(t)
        if ch is not None:
            changes.append((round(t, 3), *ch))
    return changes, t, tick


def test_a_loop_that_keeps_up_stays_ok():
    mon = DeadlineMonitor(DeadlineParams())
    changes, *_ = run(mon, 0.0, 5.0)
    assert changes == [] and mon.state == "ok" and mon.speed_scale == 1.0
    assert mon.missed_ticks == 0 and mon.late_answers == 0


def test_ticks_skipped_in_a_burst_are_not_missed_deadlines():
    mon = DeadlineMonitor(DeadlineParams(answer_budget=0.003))
    changes, *_ = run(mon, 0.0, 3.0, answer_s=0.0008, skip_every=5)  # on time, 20 % skipped
    assert changes == [] and mon.missed_ticks == 0
    assert mon.coalesced_ticks == pytest.approx(300, abs=3)


def test_missed_ticks_degrade_then_clean_windows_recover():
    p = DeadlineParams(window=1.0, recover_time=3.0, degraded_speed_scale=0.5,
                       max_late_fraction=1.0)  # fmt: skip
    mon = DeadlineMonitor(p)
    # 10 % of ticks skipped because the answers were late (4 ms > 3 ms budget).
    changes, t, tick = run(mon, 0.0, 2.0, answer_s=0.004, skip_every=10)
    assert changes and changes[0][1] == "degraded"
    assert "ticks missed" in changes[0][2]
    assert mon.speed_scale == 0.5 and mon.degraded_episodes == 1
    assert mon.missed_ticks == pytest.approx(100, abs=2)
    changes, t, tick = run(mon, t, 5.0, tick0=tick)
    assert [c[1] for c in changes] == ["ok"]
    # Back to ok only after recover_time of clean windows (first clean window ends ~1 s in).
    assert changes[0][0] - 2.0 >= 3.0
    assert mon.speed_scale == 1.0


def test_too_late_to_walk_holds_for_the_whole_degraded_episode():
    p = DeadlineParams(answer_budget=0.003, no_walk_late=0.008, recover_time=2.0)
    mon = DeadlineMonitor(p)
    changes, t, tick = run(mon, 0.0, 1.0, answer_s=0.005)  # late, but a trot is possible
    assert mon.state == "degraded" and mon.speed_scale == p.degraded_speed_scale
    _, t, tick = run(mon, t, 0.5, answer_s=0.012, tick0=tick)  # too late to trot
    assert mon.speed_scale == 0.0
    _, t, tick = run(mon, t, 1.0, answer_s=0.005, tick0=tick)  # better, still degraded
    assert mon.state == "degraded" and mon.speed_scale == 0.0  # no flapping back
    changes, t, tick = run(mon, t, 4.0, tick0=tick)
    assert changes[-1][1] == "ok" and mon.speed_scale == 1.0


def test_late_answers_degrade_only_when_the_robot_does_not_wait():
    p = DeadlineParams(answer_budget=0.003)
    mon = DeadlineMonitor(p)
    mon.robot_status(0.0, 0, waits=True)  # lockstep: no deadline
    changes, t, tick = run(mon, 0.0, 3.0, answer_s=0.005)
    assert changes == [] and mon.late_answers > 1000
    mon.robot_status(0.0, 0, waits=False)
    changes, *_ = run(mon, t, 2.0, answer_s=0.005, tick0=tick)
    assert changes[0][1] == "degraded" and "later than 3.0 ms" in changes[0][2]


def test_budgets_are_in_robot_time_for_a_robot_slower_than_real_time():
    # 4 ms answers: late for a real-time robot's 2 ms ticks, on time for a simulated robot
    # running at half speed (its ticks are 4 ms apart on the wall clock).
    slow = DeadlineMonitor(DeadlineParams(answer_budget=0.003))
    changes, *_ = run(slow, 0.0, 3.0, answer_s=0.004, pace=0.5)
    assert changes == [] and slow.pace == pytest.approx(0.5, rel=1e-6)
    assert slow.late_answers == 0
    realtime = DeadlineMonitor(DeadlineParams(answer_budget=0.003))
    changes, *_ = run(realtime, 0.0, 3.0, answer_s=0.004, pace=1.0)
    assert changes[0][1] == "degraded" and "later than 3.0 ms" in changes[0][2]
    # Answers too late even at half speed still degrade, with the wall budget in the reason.
    slow2 = DeadlineMonitor(DeadlineParams(answer_budget=0.003))
    changes, *_ = run(slow2, 0.0, 3.0, answer_s=0.007, pace=0.5)
    assert changes[0][1] == "degraded" and "later than 6.0 ms" in changes[-1][2] + changes[0][2]
    # A robot faster than real time (a lockstep sim racing ahead) never shortens them.
    fast = DeadlineMonitor(DeadlineParams(answer_budget=0.003))
    run(fast, 0.0, 1.0, answer_s=0.002, pace=3.0)
    assert fast.pace == 1.0 and fast.state == "ok"


def test_robot_side_reports_degrade():
    mon = DeadlineMonitor(DeadlineParams(max_cmd_age_ticks=2.0))
    mon.robot_status(3.5, 0)
    changes, t, tick = run(mon, 0.0, 1.5)
    assert "3.5 ticks old" in changes[0][2]
    mon2 = DeadlineMonitor(DeadlineParams())
    mon2.robot_status(0.0, 1)  # one timeout at start-up is history, not a new one
    run(mon2, 0.0, 1.5)
    assert mon2.state == "ok"
    mon2.robot_status(0.0, 2)
    changes, *_ = run(mon2, 1.5, 1.5)
    assert changes[0][1] == "degraded" and "1 leg-command timeouts" in changes[0][2]
    assert mon2.leg_timeouts == 2


def test_deadline_params_are_checked():
    with pytest.raises(ValueError):
        DeadlineParams(degraded_speed_scale=0.0)
    with pytest.raises(ValueError):
        DeadlineParams(window=0.0)
    assert math.isclose(DeadlineParams().answer_budget, 0.003)


# ----------------------------------------------------------------------------- controller
# The controller's latch and reset, driven with scripted measurements (no physics).
from quadmanip.common.joint_layout import LEG_SLICE, N_JOINTS  # noqa: E402
from quadmanip.services.locomotion.controller import (  # noqa: E402
    CommandError,
    LocomotionController,
    load_locomotion_config,
)

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def _quat_roll(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


def _balancing() -> tuple[LocomotionController, np.ndarray, float]:
    """A controller in its balance phase (stand-up run on scripted, stand-pose joints)."""
    ctl = LocomotionController(load_locomotion_config())
    q = np.zeros(N_JOINTS)
    q[LEG_SLICE] = ctl.q_stand
    ctl.set_mode("stand")
    t = 0.0
    while ctl.phase != "balance":
        t += 0.002
        ctl.step(t, q, np.zeros(N_JOINTS), LEVEL, np.zeros(3), np.array([0, 0, 9.81]))
    return ctl, q, t


def _tick(ctl: LocomotionController, q: np.ndarray, t: float, quat: np.ndarray) -> None:
    ctl.step(t, q, np.zeros(N_JOINTS), quat, np.zeros(3), np.array([0, 0, 9.81]))


def test_a_fall_latches_safe_mode_until_recover():
    ctl, q, t = _balancing()
    _tick(ctl, q, t + 0.002, _quat_roll(0.5))
    assert ctl.phase == "balance"  # 29°: within the limit
    out = ctl.step(t + 0.004, q, np.ones(N_JOINTS), _quat_roll(0.7), np.zeros(3), np.zeros(3))
    assert ctl.phase == "safe" and ctl.trips == 1 and ctl.trip_reason.startswith("roll 40°")
    np.testing.assert_allclose(out.kp, 0.0)  # legs damped
    assert np.all(out.kd > 0)
    for mode in ("stand", "walk", "sit"):
        with pytest.raises(CommandError, match="recover"):
            ctl.set_mode(mode)
    with pytest.raises(CommandError):
        ctl.set_velocity(0.1, 0.0, 0.0, now=t)
    ctl.set_mode("damp")  # accepted, stays latched
    _tick(ctl, q, t + 0.006, LEVEL)
    assert ctl.phase == "safe" and ctl.trip_reason  # level again: still latched
    ctl.set_mode("recover")
    assert ctl.phase == "standing_up" and ctl.trip_reason == ""


def test_recover_on_a_side_rights_itself_and_on_the_back_asks_for_help():
    ctl, q, t = _balancing()
    _tick(ctl, q, t + 0.002, _quat_roll(-1.5))  # lying on its left side (+y down)
    assert ctl.phase == "safe" and ctl.lying_side() == "left"
    ctl.set_mode("recover")
    assert ctl.phase == "righting"
    out = ctl.step(t + 0.004, q, np.zeros(N_JOINTS), _quat_roll(-1.5), np.zeros(3), np.zeros(3))
    assert np.all(out.kp > 0)  # the sequence drives the joints
    with pytest.raises(CommandError, match="righting"):
        ctl.set_mode("stand")
    ctl.set_mode("damp")
    _tick(ctl, q, t + 0.006, _quat_roll(math.pi))  # upside down
    assert ctl.lying_side() == "back"
    ctl.set_mode("recover")
    assert ctl.phase == "safe" and "needs help" in ctl.trip_reason


def test_stand_from_lying_on_a_side_is_refused():
    ctl = LocomotionController(load_locomotion_config())
    q = np.zeros(N_JOINTS)
    ctl.step(0.002, q, np.zeros(N_JOINTS), _quat_roll(1.5), np.zeros(3), np.zeros(3))
    with pytest.raises(CommandError, match="lies on its right"):
        ctl.set_mode("stand")


def test_degraded_limits_speed_and_stands_on_joint_stiffness():
    ctl, q, t = _balancing()
    ctl.degraded, ctl.speed_scale = True, 0.5
    with pytest.raises(CommandError, match="degraded"):
        ctl.set_velocity(0.5, 0.0, 0.0, now=t)
    out = ctl.step(t + 0.002, q, np.zeros(N_JOINTS), LEVEL, np.zeros(3), np.array([0, 0, 9.81]))
    assert np.all(out.kp == ctl.cfg.deadline.degraded_kp)
    np.testing.assert_allclose(out.q_des, q[LEG_SLICE])  # held where it stood
    # The feed-forward carries a static share of the weight: knees push (non-zero torque).
    assert np.all(np.abs(out.tau_ff[2::3]) > 0.5)
    ctl.set_velocity(0.3, 0.0, 0.0, now=t)  # within half the limit: accepted
    ctl.degraded, ctl.speed_scale = False, 1.0
    out = ctl.step(t + 0.004, q, np.zeros(N_JOINTS), LEVEL, np.zeros(3), np.array([0, 0, 9.81]))
    assert np.all(out.kp == 0.0)
