"""The bus between real processes over a real local router (issue 2, item 3).

A ``relay`` service (tests/integration/helpers/relay.py, run by ``run_service`` in its
own process) echoes every registered message type; the test process publishes one
example of each and checks that exactly the same message comes back. Malformed bytes on
the relay's keys are counted and logged while it keeps relaying, and the relay's test
action runs goal → accept/reject → feedback → result/cancel across processes.
"""

from __future__ import annotations

import json
import queue
import signal
import time

import pytest
import qm_examples
import qm_keys
import zenoh
from quadmanip.common.actions import ActionClient
from quadmanip.common.messages import Clock, Heartbeat
from quadmanip.common.schema import message_types

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

RELAY = str(qm_examples.__file__).replace("qm_examples.py", "relay.py")


@pytest.fixture
def relay(zenoh_router, spawn, bus_factory):
    """(router endpoint, relay child, test-process bus) with the relay up and wired."""
    child = spawn(RELAY, endpoint=zenoh_router)
    assert child.wait_for(r'"ready": true', 30), child.output()
    bus = bus_factory(zenoh_router, table=qm_keys.TABLE)
    return zenoh_router, child, bus


def _roundtrip_all(bus, timeout: float) -> dict[str, object]:
    """Publish one example per type until each has come back once (or timeout)."""
    examples = {t: qm_examples.example(t) for t in message_types()}
    received: dict[str, queue.Queue] = {t.SCHEMA: queue.Queue() for t in examples}
    pubs = {}
    for t in examples:
        s = qm_examples.slug(t)
        bus.subscribe(f"test/out/{s}", received[t.SCHEMA].put)
        pubs[t] = bus.publisher(f"test/in/{s}")
    got: dict[str, object] = {}
    deadline = time.monotonic() + timeout
    while len(got) < len(examples) and time.monotonic() < deadline:
        for t, msg in examples.items():
            if t.SCHEMA not in got:
                pubs[t].publish(msg)
        time.sleep(0.2)  # subscriptions propagate; re-send the missing ones
        for t in examples:
            try:
                got.setdefault(t.SCHEMA, received[t.SCHEMA].get_nowait())
            except queue.Empty:
                pass
    return {"examples": {t.SCHEMA: m for t, m in examples.items()}, "got": got}


def test_every_message_type_is_delivered_unchanged_across_processes(relay):
    _, child, bus = relay
    out = _roundtrip_all(bus, timeout=15.0)
    examples, got = out["examples"], out["got"]
    assert len(examples) >= 20  # the contract's message set is all there
    missing = sorted(set(examples) - set(got))
    assert not missing, f"never came back: {missing}\n{child.output()[-2000:]}"
    for name, msg in examples.items():
        assert got[name] == msg, name
        assert type(got[name]) is type(msg)
    assert bus.stats.decode_errors == 0


def test_malformed_bytes_are_counted_and_the_subscriber_keeps_working(relay):
    _, child, bus = relay
    back: queue.Queue = queue.Queue()
    bus.subscribe("test/out/clock", back.put)
    pub = bus.publisher("test/in/clock")
    # The relay's subscriber must be reachable before we start counting.
    deadline = time.monotonic() + 10
    while back.empty() and time.monotonic() < deadline:
        pub.publish(Clock(stamp=1.0))
        time.sleep(0.1)
    assert not back.empty(), child.output()
    key = bus.key("test/in/clock")
    bad = [
        b"",  # empty
        b"\xff\x00garbage",  # not msgpack
        b"\x94\xa8qm.Clock\x01\x00",  # truncated array
        bus_encoded_wrong_type(),  # a valid message of another type
        b"\x94\xa8qm.Clock\x63\x00\x81\xa5stamp\xcb\x7f\xf8\x00\x00\x00\x00\x00\x00",  # v99, NaN
    ]
    for data in bad:
        bus.session.put(key, data)
    m = child.wait_for(r'"errors": \{[^}]*"qm/dog1/test/in/clock": 5\b', 10)
    assert m, child.output()[-3000:]
    # ... and the relay still relays good messages, in order, after the bad ones.
    while not back.empty():
        back.get_nowait()
    pub.publish(Clock(stamp=42.0))
    assert back.get(timeout=5).stamp == 42.0
    # The malformed input was logged (throttled: fewer lines than errors) with its reason.
    warn = [ln for ln in child.lines if "dropped malformed message" in ln]
    assert 1 <= len(warn) < len(bad), child.output()
    assert "key=qm/dog1/test/in/clock" in warn[0]


def bus_encoded_wrong_type() -> bytes:
    from quadmanip.common.schema import encode

    return encode(Heartbeat(stamp=1.0, service="x", seq=1, state="ok"))


def test_action_goal_feedback_result_reject_and_cancel_across_processes(relay):
    _, child, bus = relay
    client = bus.action_client("relay", "count")
    feedback: list = []
    h = client.send_goal(Clock(stamp=4.0), feedback_cb=feedback.append, timeout=5.0)
    assert h.accepted, h.reason
    res = h.result(timeout=10)
    assert res is not None and res.status == "succeeded"
    assert res.result == Clock(stamp=4.0)
    assert [round(f.progress, 2) for f in h.feedback] == [0.25, 0.5, 0.75, 1.0]
    assert feedback == h.feedback

    rejected = client.send_goal(Clock(stamp=-1.0))
    assert not rejected.accepted and "must be >= 0" in rejected.reason
    with pytest.raises(TypeError, match="takes Clock"):  # the key table's row, at the client
        client.send_goal(Heartbeat(stamp=0.0, service="x", seq=0, state=""))
    # A client built on another table (another build of the stack): the server refuses too.
    stray = ActionClient(bus, "relay", "count", Heartbeat)
    wrong = stray.send_goal(Heartbeat(stamp=0.0, service="x", seq=0, state=""))
    assert not wrong.accepted and "wrong goal type" in wrong.reason
    stray.undeclare()

    failed = client.send_goal(Clock(stamp=13.0))
    assert failed.accepted
    res = failed.result(timeout=5)
    assert res.status == "failed" and "unlucky" in res.reason

    long = client.send_goal(Clock(stamp=200.0))
    assert long.accepted
    busy = client.send_goal(Clock(stamp=1.0))
    assert not busy.accepted and "busy" in busy.reason
    time.sleep(0.2)
    assert long.cancel()
    res = long.result(timeout=5)
    assert res.status == "canceled"
    assert 0 < len(long.feedback) < 200

    nobody = bus.action_client("nobody", "nothing").send_goal(Clock(stamp=1.0), timeout=0.5)
    assert not nobody.accepted and "no action server" in nobody.reason


def test_service_runtime_heartbeat_and_clean_sigterm_stop(relay):
    _, child, bus = relay
    beats: queue.Queue = queue.Queue()
    bus.subscribe("relay/heartbeat", lambda m: beats.put((time.monotonic(), m)))
    # Robot time comes from sim/clock (configs/bus.toml robot_clock): heartbeats carry it.
    clock = bus.publisher("sim/clock")
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        clock.publish(Clock(stamp=42.5))
        (t1, first) = beats.get(timeout=5)
        if first.stamp == 42.5:
            break
    (t2, second) = beats.get(timeout=3)
    assert first.service == "relay" and first.state == "running"
    assert first.stamp == 42.5 and second.stamp == 42.5
    assert second.seq == first.seq + 1
    assert 0.5 < t2 - t1 < 1.5  # 1 Hz
    t0 = time.monotonic()
    child.signal(signal.SIGTERM)
    code = child.wait(5)
    elapsed = time.monotonic() - t0
    assert code == 0, child.output()[-2000:]
    assert elapsed < 2.0, elapsed
    stopped = [json.loads(ln) if ln.startswith("{") else ln for ln in child.lines]
    assert any("stopped code=0" in str(ln) for ln in stopped), child.output()[-1000:]


def test_raw_zenoh_put_without_session_reaches_nothing_typed(relay):
    """Sanity of the isolation the tests rely on: a session on another router port does
    not see this router's traffic (multicast scouting is off)."""
    endpoint, _, bus = relay
    got: queue.Queue = queue.Queue()
    bus.subscribe("test/isolation", got.put)
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", "[]")
    cfg.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    other = zenoh.open(cfg)
    try:
        from quadmanip.common.schema import encode

        for _ in range(5):
            other.put(bus.key("test/isolation"), encode(Clock(stamp=1.0)))
            time.sleep(0.05)
        with pytest.raises(queue.Empty):
            got.get(timeout=0.5)
    finally:
        other.close()


FORGETFUL = """
import time
from quadmanip.common import keys
from quadmanip.common.bus import Bus, BusConfig
from quadmanip.common.messages import Clock
table = keys.TABLE.extended((keys.row("test", "forget", Clock, "event", "out", "check"),))
bus = Bus(BusConfig(connect=({ep!r},), listen=("tcp/127.0.0.1:0",)), table=table)
bus.subscribe("test/forget", print)
bus.watch_liveliness(print)
bus.declare_alive("forgetful")
time.sleep(0.3)
print("leaving without close", flush=True)
raise SystemExit(5)
"""


def test_a_process_that_forgets_to_close_its_bus_still_exits(zenoh_router, spawn):
    """zenoh-python runs callbacks on a non-daemon thread, so an unclosed session used
    to hang interpreter exit forever; the bus closes forgotten sessions first."""
    child = spawn("-c", FORGETFUL.format(ep=zenoh_router), endpoint=zenoh_router)
    assert child.wait_for("leaving without close", 30), child.output()
    t0 = time.monotonic()
    assert child.wait(5) == 5, child.output()
    assert time.monotonic() - t0 < 3.0


STUCK = """
import ctypes, signal, sys
from quadmanip.common import keys
from quadmanip.common.service import Service, run_service

class Stuck(Service):
    name = "stuck"
    key_table = keys.TABLE.extended(services=("stuck",))

    def setup(self):
        # A long C call that never returns to Python, not even on a signal (like a C
        # library that retries on EINTR): the main thread cannot run any Python handler.
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
        print("setup entered", flush=True)
        ctypes.CDLL(None).sleep(30)

sys.exit(run_service(Stuck, []))
"""


def test_a_service_stuck_in_c_code_still_exits_within_2s_of_sigterm(zenoh_router, spawn):
    child = spawn("-c", STUCK, endpoint=zenoh_router)
    assert child.wait_for("setup entered", 30), child.output()
    time.sleep(0.2)
    t0 = time.monotonic()
    child.signal(signal.SIGTERM)
    code = child.wait(5)
    elapsed = time.monotonic() - t0
    assert code == 1, child.output()  # forced: the stop overran, and says so
    assert elapsed < 2.0, elapsed
    assert "stop overran its budget" in child.output()
