"""The sim node over a real router, in its own process (issue 3, "Over Zenoh").

A client in the test process counts what arrives, by sim time: LowState at 500 Hz
(within 5 %), RGB-D from both cameras and LiDAR scans at 10 Hz, in ``lockstep`` (answered
by the trivial responder process of ``quadmanip.testbench.bench_sim``) and in ``realtime``. The
test-only disturbance channel is refused when the config does not enable it.
"""

from __future__ import annotations

import signal
import threading
import time

import pytest
from quadmanip.common import messages as msg

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

SIM_SECONDS = 2.0  # of sim time counted per mode


class Collector:
    """Counts messages per topic with their sim stamps (thread-safe)."""

    def __init__(self, bus) -> None:
        self.lock = threading.Lock()
        self.stamps: dict[str, list[float]] = {}
        self.ticks: list[int] = []
        self.last: dict[str, object] = {}
        topics = (
            "sim/lowstate",
            "sim/camera/front",
            "sim/camera/gripper",
            "sim/scan",
            "sim/gt/base",
        )
        for topic in topics:
            self.stamps[topic] = []
            bus.subscribe(topic, self._cb(topic))

    def _cb(self, topic):
        def cb(m) -> None:
            with self.lock:
                self.stamps[topic].append(m.stamp)
                self.last[topic] = m
                if topic == "sim/lowstate":
                    self.ticks.append(m.tick)

        return cb

    def sim_time(self) -> float:
        with self.lock:
            s = self.stamps["sim/lowstate"]
            return s[-1] if s else -1.0

    def wait_sim(self, t: float, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.sim_time() >= t:
                return True
            time.sleep(0.05)
        return False

    def rate(self, topic: str, t0: float, t1: float) -> float:
        with self.lock:
            n = sum(1 for s in self.stamps[topic] if t0 <= s < t1)
        return n / (t1 - t0)


def _start_sim(spawn, endpoint, *args):
    node = spawn("-m", "quadmanip.sim.node", "--scenario", "paper-1", *args, endpoint=endpoint)
    assert node.wait_for(r"INFO sim running", 60), node.output()[-3000:]
    return node


def _check_rates(col: Collector, t0: float) -> None:
    t1 = t0 + SIM_SECONDS
    assert col.rate("sim/lowstate", t0, t1) == pytest.approx(500.0, rel=0.05)
    for topic in ("sim/camera/front", "sim/camera/gripper", "sim/scan"):
        assert col.rate(topic, t0, t1) == pytest.approx(10.0, abs=0.6), topic
    img = col.last["sim/camera/front"]
    assert img.rgb.shape == (240, 320, 3) and img.depth.shape == (240, 320)
    assert col.last["sim/scan"].ranges.shape == (360,)


def test_lockstep_rates_with_responder(zenoh_router, spawn, bus_factory):
    bus = bus_factory(zenoh_router)
    col = Collector(bus)
    responder = spawn("-m", "quadmanip.testbench.bench_sim", "responder", endpoint=zenoh_router)
    assert responder.wait_for("responder ready", 30), responder.output()
    node = _start_sim(spawn, zenoh_router, "--lockstep")
    assert col.wait_sim(0.5, 60), node.output()[-3000:]
    t0 = col.sim_time()
    assert col.wait_sim(t0 + SIM_SECONDS + 0.2, 90), node.output()[-3000:]
    _check_rates(col, t0)
    # Lockstep: every tick published, in order, 2 ms apart in sim time (a tick can repeat
    # only if the sim republished it while waiting for a slow answer).
    with col.lock:
        ticks = [k for k in col.ticks if k > 0]
        stamps = sorted(set(col.stamps["sim/lowstate"]))
    assert all(b - a in (0, 1) for a, b in zip(ticks, ticks[1:], strict=False))
    assert sorted(set(ticks)) == list(range(ticks[0], ticks[-1] + 1))
    assert max(abs(b - a - 0.002) for a, b in zip(stamps, stamps[1:], strict=False)) < 1e-9
    # The responder holds the pose: the legs are active, the robot does not fall.
    assert "new=active" in node.output()
    node.signal(signal.SIGTERM)
    assert node.wait(5) == 0, node.output()[-2000:]


def test_realtime_rates_and_disturbance_refused(zenoh_router, spawn, bus_factory):
    bus = bus_factory(zenoh_router)
    col = Collector(bus)
    node = _start_sim(spawn, zenoh_router, "--realtime")
    assert col.wait_sim(0.5, 60), node.output()[-3000:]
    w0, t0 = time.monotonic(), col.sim_time()
    # Test-only push: 400 N up on the base for 0.5 s would throw the 16 kg robot up; the
    # node refuses it because allow_test_disturbance is false.
    pub = bus.publisher("sim/test/disturbance")
    push = msg.Disturbance(stamp=t0, force=[0, 0, 400.0], torque=[0, 0, 0], duration=0.5)
    for _ in range(5):
        pub.publish(push)
        time.sleep(0.05)
    assert col.wait_sim(t0 + SIM_SECONDS + 0.2, 60), node.output()[-3000:]
    wall = time.monotonic() - w0
    _check_rates(col, t0)
    # Realtime: capped at 1x (the machine may be slower, never faster).
    assert (col.sim_time() - t0) / wall < 1.1
    assert node.wait_for("test disturbance ignored", 5), node.output()[-3000:]
    base = col.last["sim/gt/base"]
    assert base.names == ("base",) and base.positions[0][2] < 0.35
    node.signal(signal.SIGTERM)
    assert node.wait(5) == 0, node.output()[-2000:]
