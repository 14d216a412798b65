"""The bus, logging and service runtime inside one process (no router, no children).

A single Zenoh session delivers its own publications to its own subscribers, which is
enough to test decoding, error counting, latest-only delivery, actions, liveliness and
the bounded close without starting processes (those are in tests/integration).
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time

import pytest
from quadmanip.common import keys
from quadmanip.common.actions import ActionCanceled, GoalHandle
from quadmanip.common.bus import Bus, BusConfig, safe_close, zenoh_config
from quadmanip.common.log import _LineFormatter, get_logger
from quadmanip.common.messages import Clock, Heartbeat, LegCommand
from quadmanip.common.schema import encode
from quadmanip.common.service import Input, Output, Service, _parse_set, run_service

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

LOCAL = BusConfig(mode="peer", connect=(), listen=("tcp/127.0.0.1:0",), env_override=False)
UNIT = keys.TABLE.extended(
    (
        keys.row("x", "clock", Clock, "control", "out", "unit"),
        keys.row("x", "c", Clock, "control", "out", "unit"),
        keys.row("x", "a", Clock, "control", "out", "unit"),
        keys.row("x", "sensor", Clock, "sensor", "out", "unit"),
        keys.row("x", "state", LegCommand, "sensor", "out", "unit"),
        keys.row("probe", "in", Clock, "control", "in", "unit"),
        keys.row("probe", "out", Clock, "event", "out", "unit"),
    ),
    tuple(keys.action_row("arm", a, Clock, "unit") for a in ("count", "once", "late", "nobody")),
)
"""The product's key table plus this file's own keys."""


@pytest.fixture
def bus():
    b = Bus(LOCAL, robot="unit", table=UNIT)
    yield b
    b.close()


def _drain(q: queue.Queue, timeout: float) -> list:
    out = []
    deadline = time.monotonic() + timeout
    while (remaining := deadline - time.monotonic()) > 0:
        try:
            out.append(q.get(timeout=remaining))
        except queue.Empty:
            break
    return out


def test_keys_and_zenoh_config_translation():
    b = Bus(LOCAL, robot="dog7")
    try:
        assert b.key("sim/lowstate") == "qm/dog7/sim/lowstate"
        assert b.key("/sim/lowstate/") == "qm/dog7/sim/lowstate"
        assert b.key("qm/other/sim/clock") == "qm/other/sim/clock"
        assert b.service_of("qm/dog7/locomotion/alive") == "locomotion"
    finally:
        assert b.close()
    zc = zenoh_config(BusConfig(mode="client", connect=("tcp/10.1.2.3:7447",)))
    assert json.loads(zc.get_json("mode")) == "client"
    assert json.loads(zc.get_json("connect/endpoints")) == ["tcp/10.1.2.3:7447"]
    assert json.loads(zc.get_json("scouting/multicast/enabled")) is False
    assert json.loads(zc.get_json("transport/link/tx/lease")) == 3000
    retry = json.loads(zc.get_json("connect/retry"))
    assert retry["period_max_ms"] == 500


def test_publisher_refuses_other_types(bus):
    pub = bus.publisher("x/clock")
    assert (pub.msg_type, pub.kind) == (Clock, "control")  # from the table's row
    assert bus.publisher("x/state").kind == "sensor"
    with pytest.raises(TypeError, match="sends Clock"):
        pub.publish(Heartbeat(stamp=0.0, service="s", seq=0, state=""))


def test_the_bus_refuses_what_the_key_table_lacks(bus):
    for refused in (
        lambda: bus.publisher("x/y"),
        lambda: bus.subscribe("x/y", print),
        lambda: bus.latest("qm/unit/x/y"),
        lambda: bus.action_server("arm", "jump", lambda h: None),
        lambda: bus.action_client("arm", "jump"),
    ):
        with pytest.raises(keys.UnknownKey, match="not in the key table"):
            refused()
    with pytest.raises(keys.UnknownKey, match="several message types"):
        bus.subscribe("x/*", print)  # Clock and LegCommand rows
    assert bus.subscribe("*/heartbeat", print).msg_type is Heartbeat
    with pytest.raises(TypeError, match="takes Clock"):
        bus.action_client("arm", "count").send_goal(Heartbeat(stamp=0, service="", seq=0, state=""))
    with pytest.raises(keys.UnknownKey):
        Bus(LOCAL).publisher("x/clock")  # the product table has no test keys


def test_malformed_payloads_are_counted_logged_throttled_and_stream_continues(bus, caplog):
    got: queue.Queue = queue.Queue()
    sub = bus.subscribe("x/clock", got.put)
    key = bus.key("x/clock")
    bad = [b"", b"\xc1", b"\x94", encode(Heartbeat(stamp=0.0, service="s", seq=1, state=""))]
    with caplog.at_level(logging.WARNING, logger="quadmanip.bus"):
        for data in bad * 5:
            bus.session.put(key, data)
        bus.publisher("x/clock").publish(Clock(stamp=3.0))
        msgs = _drain(got, 1.0)
    assert [m.stamp for m in msgs] == [3.0]
    assert sub.error_count == 20 and sub.received_count == 21
    assert bus.stats.key(key).decode_errors == 20
    assert "expected qm.Clock, got qm.Heartbeat" in bus.stats.key(key).last_error
    logged = [r for r in caplog.records if r.getMessage() == "dropped malformed message"]
    assert 1 <= len(logged) <= 2  # 1 per second per key, not 20


def test_callback_exceptions_are_counted_and_do_not_stop_the_subscriber(bus):
    seen: list[float] = []

    def cb(m: Clock) -> None:
        seen.append(m.stamp)
        if m.stamp < 2:
            raise RuntimeError("boom")

    sub = bus.subscribe("x/c", cb)
    pub = bus.publisher("x/c")
    for s in (0.0, 1.0, 2.0):
        pub.publish(Clock(stamp=s))
    deadline = time.monotonic() + 2
    while len(seen) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert seen == [0.0, 1.0, 2.0]
    assert sub.callback_error_count == 2


def test_latest_only_subscriber_never_queues_behind_a_slow_consumer(bus):
    calls: list[tuple[float, float]] = []

    def slow(m: Clock) -> None:
        calls.append((time.monotonic(), m.stamp))
        time.sleep(0.1)

    sub = bus.subscribe("x/sensor", slow, latest_only=True)
    pub = bus.publisher("x/sensor")
    for i in range(100):
        pub.publish(Clock(stamp=float(i)))
        time.sleep(0.003)
    t_end = time.monotonic()
    time.sleep(0.5)
    assert calls and calls[-1][1] == 99.0  # the newest sample is always delivered
    assert len(calls) < 20  # ~0.3 s of publishing / 0.1 s per call, not 100
    assert sub.dropped_count + len(calls) == 100
    # No backlog: the last call starts at most one callback duration after the last sample.
    assert calls[-1][0] - t_end < 0.25


def test_latest_cache_returns_newest_valid_message(bus):
    cache = bus.latest("x/state")
    assert cache.get() is None and cache.age is None
    pub = bus.publisher("x/state")
    import numpy as np

    z = np.zeros(12)

    def cmd(tick: int) -> LegCommand:
        return LegCommand(stamp=tick * 0.002, tick=tick, q_des=z, dq_des=z, kp=z, kd=z, tau_ff=z)

    for t in range(5):
        pub.publish(cmd(t))
    msg = cache.wait_new(1.0) if cache.get() is None else cache.get()
    deadline = time.monotonic() + 1
    while (msg is None or msg.tick != 4) and time.monotonic() < deadline:
        time.sleep(0.01)
        msg = cache.get()
    assert msg.tick == 4
    bus.session.put(cache.key, b"\x00\x01")
    time.sleep(0.1)
    assert cache.get().tick == 4  # a malformed sample does not replace the good one
    assert cache.error_count == 1
    threading.Timer(0.05, lambda: pub.publish(cmd(9))).start()
    assert cache.wait_new(1.0).tick == 9


def test_action_roundtrip_reject_preempt_and_lost_result_recovery(bus):
    started = threading.Event()

    def execute(h: GoalHandle) -> Clock:
        started.set()
        n = int(h.goal.stamp)
        for i in range(n):
            if h.cancel_requested:
                raise ActionCanceled("preempted")
            h.feedback((i + 1) / n)
            time.sleep(0.02)
        return Clock(stamp=float(n))

    bus.action_server("arm", "count", execute, policy="preempt")
    client = bus.action_client("arm", "count")
    h = client.send_goal(Clock(stamp=3.0))
    assert h.accepted
    res = h.result(timeout=3)
    assert (res.status, res.result) == ("succeeded", Clock(stamp=3.0))
    assert [f.progress for f in h.feedback] == pytest.approx([1 / 3, 2 / 3, 1.0])

    first = client.send_goal(Clock(stamp=500.0))
    assert first.accepted and started.wait(2)
    second = client.send_goal(Clock(stamp=2.0))  # preempts the first
    assert second.accepted
    assert first.result(timeout=3).status == "canceled"
    assert second.result(timeout=3).status == "succeeded"

    dup = client.send_goal(Clock(stamp=1.0), goal_id=second.goal_id)
    assert not dup.accepted and "duplicate" in dup.reason

    # A result publication that never arrives is recovered from the status queryable.
    client._subs[1].undeclare()
    lost = client.send_goal(Clock(stamp=1.0))
    res = lost.result(timeout=3, poll_s=0.2)
    assert res is not None and res.status == "succeeded"


def test_a_resent_goal_is_accepted_again_and_runs_once(bus):
    runs: list[str] = []

    def execute(h: GoalHandle) -> Clock:
        runs.append(h.goal_id)
        time.sleep(0.2)
        return h.goal

    bus.action_server("arm", "once", execute)  # policy "reject": busy otherwise
    client = bus.action_client("arm", "once")
    first = client.send_goal(Clock(stamp=2.0), goal_id="g-1")
    again = client.send_goal(Clock(stamp=2.0), goal_id="g-1")  # a retry after a lost reply
    assert first.accepted and again.accepted, (first.reason, again.reason)
    assert again.result(timeout=3).result == Clock(stamp=2.0)
    time.sleep(0.3)
    assert runs == ["g-1"]
    # after it finished too; another goal under that id is still refused
    assert client.send_goal(Clock(stamp=2.0), goal_id="g-1").accepted
    other = client.send_goal(Clock(stamp=5.0), goal_id="g-1")
    assert not other.accepted and "duplicate" in other.reason
    assert runs == ["g-1"]


def test_a_goal_waits_its_timeout_for_a_server_that_appears_late(bus):
    client = bus.action_client("arm", "late")
    threading.Timer(0.4, lambda: bus.action_server("arm", "late", lambda h: h.goal)).start()
    t0 = time.monotonic()
    h = client.send_goal(Clock(stamp=1.0), timeout=5.0)
    assert h.accepted, h.reason
    assert 0.3 < time.monotonic() - t0 < 5.0
    nobody = bus.action_client("arm", "nobody").send_goal(Clock(stamp=1.0), timeout=0.3)
    assert not nobody.accepted and "no action server" in nobody.reason


def test_liveliness_token_appears_and_disappears(bus):
    events: queue.Queue = queue.Queue()
    bus.watch_liveliness(lambda s, a: events.put((s, a)))
    token = bus.declare_alive("probe")
    assert ("probe", True) in _drain(events, 0.5)
    assert "probe" in bus.alive_services(timeout=0.5)
    token.undeclare()
    assert ("probe", False) in _drain(events, 0.5)


def test_safe_close_abandons_a_hanging_close_within_its_budget():
    class Hanging:
        def close(self) -> None:
            time.sleep(5)

    t0 = time.monotonic()
    assert safe_close(Hanging(), timeout_s=0.3) is False  # type: ignore[arg-type]
    assert time.monotonic() - t0 < 0.5
    b = Bus(LOCAL, table=UNIT)
    b.subscribe("x/a", lambda m: time.sleep(1))
    b.publisher("x/a").publish(Clock(stamp=0.0))
    t0 = time.monotonic()
    b.close()
    assert time.monotonic() - t0 < 2.0
    assert b.close() is True  # idempotent


def test_log_lines_are_one_line_with_service_and_fields(monkeypatch):
    rec = logging.LogRecord("quadmanip.x", logging.WARNING, __file__, 1, "hello world", None, None)
    rec.fields = {"key": "qm/dog1/a", "n": 3, "text": "two words"}  # type: ignore[attr-defined]
    rec.service = "locomotion"  # type: ignore[attr-defined]
    line = _LineFormatter(as_json=False).format(rec)
    assert line.endswith('WARNING locomotion hello world key=qm/dog1/a n=3 text="two words"')
    assert "\n" not in line
    obj = json.loads(_LineFormatter(as_json=True).format(rec))
    assert obj["service"] == "locomotion" and obj["n"] == 3 and obj["message"] == "hello world"
    log = get_logger("unit")
    assert log.throttled("k", 10.0, logging.INFO, "first") is True
    assert log.throttled("k", 10.0, logging.INFO, "second") is False


class Probe(Service):
    """A service for runtime tests."""

    name = "probe"
    key_table = UNIT
    inputs = (Input("probe/in"),)
    outputs = (Output("probe/out"),)
    loop_period = 0.01

    def setup(self) -> None:
        self.steps = 0
        self.pub = self.publisher("probe/out")
        self.subscribe("probe/in", self.pub.publish)
        with pytest.raises(KeyError, match="not declared"):
            self.publisher("probe/undeclared")

    def step(self) -> None:
        self.steps += 1
        if self.steps == 3:
            raise ValueError("one bad step")
        if self.steps >= 20:
            self.stop_event.set()


def test_run_service_lifecycle_declared_io_and_step_errors(capsys):
    assert run_service(Probe, ["--describe"]) == 0
    desc = json.loads(capsys.readouterr().out)
    assert desc["inputs"][0] == {
        "topic": "probe/in",
        "type": "qm.Clock/1.0",
        "latest_only": False,
        "doc": "",
    }
    assert desc["outputs"][0]["kind"] == "event"
    assert desc["heartbeat"] == "probe/heartbeat" and desc["liveliness"] == "probe/alive"
    t0 = time.monotonic()
    assert run_service(Probe, [], bus_config=LOCAL, install_signals=False) == 0
    assert time.monotonic() - t0 < 3.0
    assert run_service(Probe, ["--set", "nope=1"], bus_config=LOCAL, install_signals=False) == 2

    class Stray(Probe):
        outputs = (Output("probe/elsewhere"),)

    with pytest.raises(ValueError, match="probe/elsewhere"):
        Stray.check_declarations()
    assert run_service(Stray, ["--describe"]) == 2


def test_set_values_parse_as_toml():
    assert _parse_set(["a=1", "b.c=2.5", "d=true", "e=word", 'f="q"', "g=[1, 2]"]) == {
        "a": 1,
        "b.c": 2.5,
        "d": True,
        "e": "word",
        "f": "q",
        "g": [1, 2],
    }


def test_follow_clock_stamps_with_robot_time(bus):
    assert bus.clock() > 1e9  # wall time until told otherwise
    cache = bus.follow_clock("x/clock")
    assert bus.clock() == 0.0
    pub = bus.publisher("x/clock")
    pub.publish(Clock(stamp=12.25))
    deadline = time.monotonic() + 1.0
    while cache.get() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert bus.clock() == 12.25
