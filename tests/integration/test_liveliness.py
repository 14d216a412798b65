"""Liveliness: a service process killed with SIGKILL is seen as gone within 1 s (issue 2).

The ``relay`` helper runs through ``run_service``, which declares the liveliness token
``qm/<robot>/relay/alive``. SIGKILL gives the process no chance to undeclare anything;
the kernel closes its TCP links, the router notices the closed transport and withdraws
the token, and watchers get a DELETE.
"""

from __future__ import annotations

import queue
import signal
import time

import pytest
import qm_examples

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

RELAY = str(qm_examples.__file__).replace("qm_examples.py", "relay.py")


def _events(bus):
    q: queue.Queue = queue.Queue()
    bus.watch_liveliness(lambda service, alive: q.put((time.monotonic(), service, alive)))
    return q


def _wait(q: queue.Queue, service: str, alive: bool, timeout: float) -> float | None:
    deadline = time.monotonic() + timeout
    while (remaining := deadline - time.monotonic()) > 0:
        try:
            t, s, a = q.get(timeout=remaining)
        except queue.Empty:
            return None
        if s == service and a == alive:
            return t
    return None


def _seen_by_query(bus, service: str, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if service in bus.alive_services(timeout=1.0):
            return True
    return False


@pytest.mark.parametrize("mode", ["peer", "client"])
def test_sigkilled_service_is_seen_gone_within_1s(zenoh_router, spawn, bus_factory, mode):
    watcher = bus_factory(zenoh_router, mode=mode)
    events = _events(watcher)
    child = spawn(RELAY, "--mode", mode, endpoint=zenoh_router)
    assert _wait(events, "relay", True, 30) is not None, child.output()
    # a one-shot query from a session that just opened came back empty on CI although the
    # token had been seen (see the action notes in common/bus.py): ask again
    assert _seen_by_query(watcher, "relay", 10.0), "liveliness query never listed relay"
    t_kill = time.monotonic()
    child.signal(signal.SIGKILL)
    t_gone = _wait(events, "relay", False, 3.0)
    assert t_gone is not None, "token never withdrawn"
    assert t_gone - t_kill < 1.0, f"seen gone after {t_gone - t_kill:.3f}s"
    print(f"{mode}: SIGKILLed service seen gone after {1000 * (t_gone - t_kill):.1f} ms")
    assert "relay" not in watcher.alive_services(timeout=0.5)


def test_watcher_started_late_sees_existing_tokens_and_clean_stop(zenoh_router, spawn, bus_factory):
    child = spawn(RELAY, endpoint=zenoh_router)
    assert child.wait_for(r'"ready": true', 30), child.output()
    watcher = bus_factory(zenoh_router)
    events = _events(watcher)  # history: the already-declared token is reported
    assert _wait(events, "relay", True, 5) is not None
    child.signal(signal.SIGTERM)
    assert _wait(events, "relay", False, 2.0) is not None
    assert child.wait(2.0) == 0, child.output()[-1500:]
