"""The behavior node's view of which services run (services/behavior/service_watch.py).

The watch is fed what the node sees on the bus (liveliness tokens, heartbeats) with wall
times given by the test, the way a SIGKILL and the launcher's restart look from outside:
the token vanishes at once, comes back when the new process starts, and its heartbeat
says ``starting`` until its setup is done, then ``running`` with ``seq`` from 0 again.
"""

from __future__ import annotations

import math

import pytest
from quadmanip.services.behavior.service_watch import ServiceWatch, stand_command

pytestmark = pytest.mark.unit

SERVICES = ("locomotion", "manipulation", "navigation", "perception")


def _started(t: float = 0.0, timeout: float = 15.0) -> ServiceWatch:
    watch = ServiceWatch(SERVICES, heartbeat_timeout=timeout)
    for s in SERVICES:
        watch.liveliness(s, True, t)
        watch.heartbeat(s, 0, "running", t)
    return watch


def test_a_service_runs_once_its_token_is_there_and_its_heartbeat_says_running() -> None:
    watch = ServiceWatch(SERVICES)
    assert watch.not_running() == set(SERVICES) and watch.away() == set()  # never seen
    watch.liveliness("perception", True, 1.0)
    watch.heartbeat("perception", 0, "starting", 1.2)  # setup (a model loading) not done
    assert not watch.running("perception")
    watch.heartbeat("perception", 1, "running", 2.2)
    assert watch.running("perception") and watch.running_since("perception") == 2.2
    assert watch.outages() == dict.fromkeys(SERVICES, 0)  # a first start is no outage
    assert [(t.service, t.what) for t in watch.drain()] == [("perception", "back")]
    assert watch.drain() == []


def test_a_killed_service_is_gone_at_once_and_back_when_its_new_process_runs() -> None:
    watch = _started()
    for seq in range(1, 5):
        watch.heartbeat("navigation", seq, "running", float(seq))
    watch.drain()
    watch.liveliness("navigation", False, 4.5)  # SIGKILL: the token vanishes with it
    assert not watch.running("navigation") and watch.away() == {"navigation"}
    assert watch.outages()["navigation"] == 1
    assert watch.running_since("navigation") == -math.inf
    gone = watch.drain()
    assert [(t.service, t.what) for t in gone] == [("navigation", "went_away")]
    assert "token vanished" in gone[0].why
    # restarted by the launcher: token first, then heartbeats from 0, running after setup
    watch.liveliness("navigation", True, 6.0)
    watch.heartbeat("navigation", 0, "starting", 6.1)
    assert not watch.running("navigation")
    watch.heartbeat("navigation", 1, "running", 7.1)
    assert watch.running("navigation") and watch.running_since("navigation") == 7.1
    assert watch.outages()["navigation"] == 1  # one outage, not two
    assert watch.away() == set()
    # the others were never touched
    assert all(watch.running(s) for s in SERVICES)


def test_a_heartbeat_before_the_new_token_is_not_taken_for_the_new_life() -> None:
    watch = _started()
    watch.liveliness("manipulation", False, 1.0)
    watch.heartbeat("manipulation", 0, "running", 2.0)  # raced its own token
    assert not watch.running("manipulation")
    watch.liveliness("manipulation", True, 2.1)
    assert not watch.running("manipulation")  # token alone: setup may not be done
    watch.heartbeat("manipulation", 1, "running", 3.0)
    assert watch.running("manipulation") and watch.outages()["manipulation"] == 1


def test_a_heartbeat_counting_from_zero_again_is_a_restart_even_without_a_token_blink() -> None:
    watch = _started()
    for seq in range(1, 30):
        watch.heartbeat("locomotion", seq, "running", float(seq))
    watch.heartbeat("locomotion", 0, "starting", 30.0)  # a new process behind the same token
    assert not watch.running("locomotion") and watch.outages()["locomotion"] == 1
    watch.heartbeat("locomotion", 1, "running", 31.0)
    assert watch.running("locomotion") and watch.running_since("locomotion") == 31.0
    assert watch.outages()["locomotion"] == 1


def test_a_silent_service_is_gone_after_the_heartbeat_timeout() -> None:
    watch = _started(timeout=5.0)
    watch.tick(4.9)
    assert watch.away() == set()
    watch.tick(5.1)
    assert watch.away() == set(SERVICES)  # all silent since t=0
    assert watch.outages() == dict.fromkeys(SERVICES, 1)
    watch.tick(60.0)
    assert watch.outages() == dict.fromkeys(SERVICES, 1)  # one outage per silence
    watch.heartbeat("perception", 7, "running", 61.0)  # it speaks again
    assert watch.running("perception") and watch.outages()["perception"] == 1
    # with no timeout only the tokens count
    quiet = _started(timeout=0.0)
    quiet.tick(1e6)
    assert quiet.away() == set()


def test_a_service_that_says_it_failed_is_not_running() -> None:
    watch = _started()
    watch.heartbeat("perception", 1, "failed", 1.0)
    assert not watch.running("perception") and watch.outages()["perception"] == 1
    watch.heartbeat("perception", 2, "degraded", 2.0)  # degraded still serves
    assert watch.running("perception")


def test_services_not_watched_are_ignored() -> None:
    watch = _started()
    watch.liveliness("viz", False, 1.0)
    watch.heartbeat("sim", 3, "running", 1.0)
    assert watch.outages() == dict.fromkeys(SERVICES, 0)
    assert not watch.running("viz") and watch.running_since("viz") == -math.inf


@pytest.mark.parametrize(
    ("state", "phase", "upright", "mode"),
    [
        ("ok", "damp", True, "stand"),  # a new locomotion starts damped: the robot lies
        ("ok", "sit", True, "stand"),
        ("ok", "damp", False, "recover"),  # on a side: stand is refused, recover rights it
        ("tripped", "safe", True, "recover"),  # latched safe mode: the explicit reset
        ("tripped", "safe", False, "recover"),
        ("tripped", "righting", False, None),  # getting up already
        ("ok", "standing_up", True, None),
        ("ok", "balance", True, None),
        ("degraded", "walk", True, None),
    ],
)
def test_what_to_ask_locomotion_to_get_the_robot_standing(
    state: str, phase: str, upright: bool, mode: str | None
) -> None:
    assert stand_command(state, phase, upright) == mode
