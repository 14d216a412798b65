"""The scheduling of control loops (common/scheduling.py): SCHED_FIFO where permitted, the
nice fallback and the plain fallback, each checked in a process that really lacks the
permission (a child that drops root, or lowers its own limits)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest
from quadmanip.common.scheduling import (
    SchedulingConfig,
    ThreadScheduler,
    apply_scheduling,
    thread_policy,
)

CHILD = r"""
import json, os, resource, sys
# Import first: an ordinary user may not read this interpreter's files.
from quadmanip.common.scheduling import SchedulingConfig, apply_scheduling
# No real-time or nice allowance (lowering a limit is always permitted), then, if root,
# become an ordinary user: no capabilities left.
resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
resource.setrlimit(resource.RLIMIT_NICE, (0, 0))
if os.geteuid() == 0:
    os.setgroups([]); os.setgid(65534); os.setuid(65534)
res = apply_scheduling(SchedulingConfig(policy="fifo", priority=80, fallback_nice=-10))
print(json.dumps({"applied": res.applied, "nice": res.nice, "reasons": res.reasons,
                  "now": os.getpriority(os.PRIO_PROCESS, 0), "summary": res.summary()}))
"""


def _run_unprivileged() -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_unprivileged_without_nice_limit_keeps_normal_priority_and_says_why():
    res = _run_unprivileged()
    assert res["applied"] == "normal"
    assert res["now"] == os.getpriority(os.PRIO_PROCESS, 0)  # unchanged (inherited)
    assert any("SCHED_FIFO 80 not permitted" in r for r in res["reasons"])
    assert any("nice -10 not permitted" in r for r in res["reasons"])
    assert "no real-time priority" in res["summary"]


def test_fifo_refused_falls_back_to_nice(monkeypatch):
    """SCHED_FIFO refused (as for a user with nice allowance but no rtprio): nice instead,
    applied for real where permitted, else the plain fallback."""

    def refuse(tids: list[int], priority: int) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr("quadmanip.common.scheduling._set_fifo", refuse)

    def body(tid: int) -> tuple:
        res = apply_scheduling(SchedulingConfig(policy="fifo", fallback_nice=-3), [tid])
        return res, thread_policy(tid)

    res, policy = _in_thread(body)
    assert any("SCHED_FIFO 80 not permitted" in r for r in res.reasons)
    if res.applied == "nice":
        assert policy == ("normal", -3) and res.nice == -3
    else:
        assert res.applied == "normal" and any("nice -3 not permitted" in r for r in res.reasons)


def _fifo_permitted() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        return True
    except (PermissionError, AttributeError):
        return False


def _in_thread(fn):
    """Run fn(tid) in a fresh thread (so the test process itself stays normal)."""
    box: dict = {}

    def body() -> None:
        try:
            box["value"] = fn(threading.get_native_id())
        except BaseException as exc:  # noqa: BLE001 - re-raised below
            box["error"] = exc

    t = threading.Thread(target=body)
    t.start()
    t.join()
    if "error" in box:
        raise box["error"]
    return box["value"]


@pytest.mark.skipif(not _fifo_permitted(), reason="SCHED_FIFO not permitted here")
def test_fifo_applies_to_the_given_threads():
    def body(tid: int) -> tuple:
        res = apply_scheduling(SchedulingConfig(policy="fifo", priority=7), [tid])
        return res.applied, res.threads, thread_policy(tid)

    applied, threads, policy = _in_thread(body)
    assert applied == "fifo" and threads == 1
    assert policy == ("fifo", 7)
    assert thread_policy(threading.get_native_id())[0] == "normal"  # others untouched


def test_normal_policy_changes_nothing():
    before = thread_policy(threading.get_native_id())
    res = apply_scheduling(SchedulingConfig(policy="normal"))
    assert res.applied == "normal" and res.threads == 0
    assert thread_policy(threading.get_native_id()) == before


def test_thread_scheduler_reaches_threads_started_later(monkeypatch):
    seen: list[list[int]] = []
    monkeypatch.setattr(
        "quadmanip.common.scheduling.apply_scheduling",
        lambda cfg, tids: seen.append(list(tids)) or _ok(len(tids)),
    )
    sched = ThreadScheduler(SchedulingConfig(policy="fifo"))
    assert sched.apply() is not None
    first = set(seen[0])
    assert sched.apply() is None  # nothing new
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert sched.apply() is not None
        assert t.native_id in seen[-1] and not first & set(seen[-1])
    finally:
        stop.set()
        t.join()


def _ok(n: int):
    from quadmanip.common.scheduling import SchedulingResult

    return SchedulingResult("fifo", priority=80, threads=n)


def test_thread_scheduler_stops_retrying_when_not_permitted(monkeypatch):
    from quadmanip.common.scheduling import SchedulingResult

    calls = []
    monkeypatch.setattr(
        "quadmanip.common.scheduling.apply_scheduling",
        lambda cfg, tids: calls.append(tids) or SchedulingResult("normal", reasons=["EPERM"]),
    )
    sched = ThreadScheduler(SchedulingConfig(policy="fifo"))
    assert sched.apply().applied == "normal"
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert sched.apply() is None and len(calls) == 1
    finally:
        stop.set()
        t.join()


@pytest.mark.parametrize(
    "kwargs",
    [{"policy": "rr"}, {"priority": 0}, {"priority": 100}, {"fallback_nice": -21}, {"cpus": (-1,)}],
)
def test_bad_config_is_refused(kwargs):
    with pytest.raises(ValueError):
        SchedulingConfig(**kwargs)
