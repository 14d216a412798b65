"""Issue 12 over the real processes: health, the safety trip, recovery, the robot side's
status. The harness is the robustness benchmark's own (quadmanip/testbench/
bench_robustness.py: router + ``sim`` + ``locomotion`` child processes); ground truth only
scores.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from quadmanip.testbench import bench_robustness as rb
from quadmanip.testbench.self_righting_trials import toppling_push

pytestmark = pytest.mark.integration

LOCKSTEP_SIM = [
    "--lockstep", "--scenario", "empty", "--set", "allow_test_disturbance=true",
    "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
    "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
    "--set", "ground_truth.poses_rate=500",
]  # fmt: skip


def test_push_trips_safe_mode_refuses_commands_and_recover_gets_it_up():
    """A toppling push → tripped within 0.3 s of the tilt limit, legs damped, the reason
    published; stand/walk refused until `recover`; then it rights itself and stands."""
    log = io.StringIO()
    with rb.RobotStack(LOCKSTEP_SIM, ["--set", "node.start_mode=stand"], log) as st:
        st.wait_standing()
        h = st.last_health()
        assert h is not None and h.state == "ok" and h.phase == "balance" and h.upright
        assert h.scheduling  # says how the loop runs
        limits = rb.load_locomotion_config().safety
        trial = rb._fall_trial(st, "left", np.random.default_rng(3), limits)
        assert trial["safe"], (trial, log.getvalue()[-3000:])
        # Within 0.3 s of the tilt limit (negative: another check tripped even earlier).
        assert trial["fall_detect_s"] is not None and trial["fall_detect_s"] <= 0.3
        assert trial["t_cross"] is not None and trial["t_cross"] < 1.5
        assert trial["righted"], (trial, log.getvalue()[-3000:])
        assert trial["right_s"] <= rb.RIGHT_WITHIN_S
        # After the trip, commands are refused until the recover: count them in the health.
        with st.lock:
            trips = [x for x in st.health if x.state == "tripped" and x.phase == "safe"]
        assert trips and trips[0].trips == 1
        assert any(x.reason.startswith("recovering") for x in st.health)


def test_tripped_robot_refuses_stand_until_recover():
    log = io.StringIO()
    with rb.RobotStack(LOCKSTEP_SIM, ["--set", "node.start_mode=stand"], log) as st:
        st.wait_standing()
        st.pub_push.publish(toppling_push("right", np.random.default_rng(5), stamp=st.now()))
        deadline = time.monotonic() + 60
        while (h := st.last_health()) is None or h.state != "tripped":
            assert time.monotonic() < deadline, log.getvalue()[-3000:]
            time.sleep(0.02)
        st.wait_sim(st.now() + 1.5)
        before = st.last_health()
        assert before is not None and before.phase == "safe" and not before.upright
        st.mode("stand")
        st.wait_sim(st.now() + 0.5)
        after = st.last_health()
        assert after is not None and after.phase == "safe" and after.state == "tripped"
        assert after.rejected_commands == before.rejected_commands + 1
        assert "send mode 'recover'" in log.getvalue()


def test_robot_status_reports_fresh_commands_in_lockstep():
    log = io.StringIO()
    with rb.RobotStack(LOCKSTEP_SIM, ["--set", "node.start_mode=stand"], log) as st:
        st.wait_standing()
        st.wait_sim(st.now() + 2.0)
        with st.lock:
            status = list(st.status)
        assert status, "no sim/status"
        last = status[-1]
        assert last.mode == "lockstep" and last.leg_mode == "active"
        assert last.cmd_age_max == 0 and last.stale_ticks == 0 and last.leg_timeouts == 0
        assert last.ticks > 0
