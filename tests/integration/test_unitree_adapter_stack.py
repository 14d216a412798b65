"""The Unitree adapter over real processes (issue 16): a router, the simulated DDS robot
(``unitree-sim-robot``), the adapter (``unitree-adapter``) and locomotion, DDS on the
loopback interface in a private domain. This process listens on ``rt/lowcmd`` as a
second DDS participant to see what the adapter sends the robot; ground truth only
scores the stand.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("unitree_sdk2py", reason="the unitree extra is not installed")

from quadmanip.common import messages as m  # noqa: E402
from quadmanip.common.bus import Bus, BusConfig  # noqa: E402
from quadmanip.common.config import load_config  # noqa: E402
from quadmanip.hardware.unitree import dds  # noqa: E402
from quadmanip.hardware.unitree.joint_map import LEG_MAP  # noqa: E402
from quadmanip.hardware.unitree.lowlevel import (  # noqa: E402
    CMD_MOTOR0,
    CMD_MOTOR_STRIDE,
    decode_lowcmd,
    lowcmd_crc_ok,
)
from quadmanip.hardware.unitree.node import UnitreeAdapterConfig  # noqa: E402
from quadmanip.launcher import free_endpoint  # noqa: E402
from quadmanip.testbench.unitree_sim_robot import SMALL_MACHINE_RTF  # noqa: E402

# The simulated robot runs at the pace a 2-core machine holds for it, the adapter and
# locomotion (SMALL_MACHINE_RTF); locomotion's deadlines follow the robot's pace.
pytestmark = [pytest.mark.integration]

ADAPTER = load_config(UnitreeAdapterConfig, "unitree_adapter")
ROBOT_TIMEOUT = 0.1  # the simulated robot's own motor timeout (its --motor-timeout)
# One private DDS domain per test process (the SDK joins one domain per process); the
# stacks of the tests below run one after the other on it.
DOMAIN = random.randint(150, 230)


class Stack:
    """Router + simulated robot + adapter + locomotion, and a DDS ear on rt/lowcmd."""

    def __init__(self, domain: int) -> None:
        self.ep = free_endpoint()
        self.domain = str(domain)
        self.logs = tempfile.TemporaryDirectory(prefix="qm-unitree-")
        # QM_PARENT_PID: the services die with this process (no real-time orphans left
        # running after a killed test run).
        self.env = {**os.environ, "QM_ZENOH_CONNECT": self.ep, "QM_PARENT_PID": str(os.getpid())}
        self.procs: dict[str, subprocess.Popen] = {}
        self.lock = threading.Lock()
        # (wall, 1.0 if the adapter's damping command else 0.0, mean kd)
        self.lowcmd: list[tuple[float, float, float]] = []
        self.gt: list[tuple[float, float]] = []
        self.status: list[m.RobotStatus] = []

    def start(self, name: str, *args: str) -> None:
        fh = open(Path(self.logs.name) / f"{name}.log", "w")  # noqa: SIM115
        self.procs[name] = subprocess.Popen(
            [sys.executable, "-m", *args], env=self.env, stdout=fh, stderr=subprocess.STDOUT
        )

    def log(self, name: str) -> str:
        return (Path(self.logs.name) / f"{name}.log").read_text()

    def logs_tail(self) -> str:
        return "\n".join(f"--- {n}\n{self.log(n)[-1500:]}" for n in self.procs)

    def _on_lowcmd(self, data: bytes) -> None:
        v = decode_lowcmd(data)
        if not lowcmd_crc_ok(v):
            return
        slots = [CMD_MOTOR0 + CMD_MOTOR_STRIDE * int(s) for s in LEG_MAP.motor]
        kd = np.array([v[i + 5] for i in slots], dtype=np.float32)
        damping = all(v[i + 4] == 0.0 and v[i + 3] == 0.0 for i in slots) and bool(
            np.all(kd == np.float32(ADAPTER.safety.damping_kd))
        )
        with self.lock:
            self.lowcmd.append((time.monotonic(), 1.0 if damping else 0.0, float(kd.mean())))

    def __enter__(self) -> Stack:
        from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_

        self.start("router", "quadmanip.common.router", "--listen", self.ep)
        time.sleep(0.8)
        self.start("robot", "quadmanip.cli", "service", "unitree-sim-robot", "--domain",
                   self.domain, "--scenario", "paper-1", "--realtime-factor", str(SMALL_MACHINE_RTF),
                   "--motor-timeout", str(ROBOT_TIMEOUT))  # fmt: skip
        self.start("adapter", "quadmanip.cli", "service", "unitree-adapter", "--domain",
                   self.domain)  # fmt: skip
        self.start("locomotion", "quadmanip.cli", "service", "locomotion")
        dds.init_dds(int(self.domain), "lo")
        self.ear = dds.raw_subscriber(ADAPTER.dds.lowcmd_topic, LowCmd_, self._on_lowcmd)
        time.sleep(0.5)
        cfg = BusConfig(
            mode="peer", connect=(self.ep,), listen=("tcp/127.0.0.1:0",), env_override=False
        )
        self.bus = Bus(cfg)
        self.bus.subscribe(
            "sim/gt/base", lambda g: self.gt.append((time.monotonic(), g.positions[0][2]))
        )
        self.bus.subscribe("sim/status", self.status.append)
        self.clock = self.bus.latest("sim/clock")
        self.mode = self.bus.publisher("locomotion/mode")
        self.estop = self.bus.publisher("sim/estop")
        return self

    def __exit__(self, *exc: object) -> None:
        self.ear.close()
        self.bus.close()
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        for p in self.procs.values():
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        self.logs.cleanup()

    def now(self) -> float:
        c = self.clock.get()
        return c.stamp if c is not None else 0.0

    def stand(self, timeout: float = 90.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            self.mode.publish(m.LocomotionMode(stamp=self.now(), mode="stand"))
            time.sleep(0.5)
            with self.lock:
                recent = [z for t, z in self.gt if t > time.monotonic() - 1.0]
            if len(recent) > 5 and min(recent) > 0.26:
                return
            assert time.monotonic() < deadline, self.logs_tail()

    def last_status(self) -> m.RobotStatus | None:
        return self.status[-1] if self.status else None


@pytest.fixture
def stack():
    with Stack(DOMAIN) as st:
        st.stand()
        yield st


def test_stands_over_the_adapter_with_crc_checked_commands(stack):
    """The robot stands at the controller's height on LowCmds the adapter sealed (CRCs
    checked here and by the robot), with none refused."""
    with stack.lock:
        z = [z for t, z in stack.gt if t > time.monotonic() - 1.0]
        active = [c for c in stack.lowcmd if c[1] == 0.0]
    assert 0.26 < float(np.median(z)) < 0.34
    assert len(active) > 100
    assert "bad CRC" not in stack.log("robot") and "bad CRC" not in stack.log("adapter")
    s = stack.last_status()
    assert s is not None and s.mode == "hardware" and s.leg_mode == "active"


def test_estop_damps_at_once_latches_and_releases(stack):
    t0 = time.monotonic()
    stack.estop.publish(m.EmergencyStop(stamp=stack.now(), engage=True, reason="test"))
    time.sleep(1.0)  # locomotion keeps sending commands all along
    with stack.lock:
        after = [c for c in stack.lowcmd if c[0] > t0]
    first_damp = next(c for c in after if c[1] == 1.0)
    # From this process's publish: the Zenoh hop through the router is in it (the adapter
    # writes the damping command in the e-stop's callback).
    assert first_damp[0] - t0 < 0.25, f"e-stop took {(first_damp[0] - t0) * 1e3:.0f} ms"
    assert first_damp[2] == pytest.approx(ADAPTER.safety.damping_kd)
    # Latched: nothing active after the first damping command.
    assert all(c[1] == 1.0 for c in after if c[0] > first_damp[0])
    assert any(s.leg_mode == "estop" for s in stack.status[-4:])
    # Release: commands flow again.
    stack.estop.publish(m.EmergencyStop(stamp=stack.now(), engage=False))
    t1 = time.monotonic()
    deadline = t1 + 5
    while True:
        with stack.lock:
            if any(c[1] == 0.0 for c in stack.lowcmd if c[0] > t1):
                break
        assert time.monotonic() < deadline, stack.logs_tail()
        time.sleep(0.05)


def test_killing_locomotion_damps_within_the_timeout_then_killing_the_adapter(stack):
    """SIGKILL locomotion: the adapter's next commands damp, within its 50 ms timeout of
    the last active one. Then SIGKILL the adapter: the robot damps on its own timeout."""
    stack.procs["locomotion"].send_signal(signal.SIGKILL)
    t_kill = time.monotonic()
    time.sleep(1.0)
    with stack.lock:
        after = [c for c in stack.lowcmd if c[0] > t_kill - 0.1]
    last_active = max(c[0] for c in after if c[1] == 0.0)
    first_damp = min(c[0] for c in after if c[1] == 1.0 and c[0] > last_active)
    gap = first_damp - last_active
    # 50 ms of commands stopping, plus at most one robot state (the adapter checks on each:
    # 2 ms of robot time, 8 ms of wall time at rtf 0.25) and scheduling slack.
    assert gap <= ADAPTER.safety.timeout + 0.002 / SMALL_MACHINE_RTF + 0.005, (
        f"damped {gap * 1e3:.1f} ms after the last command"
    )
    assert "leg commands stopped" in stack.log("adapter")
    # The adapter goes on sending damping while the robot's states arrive.
    with stack.lock:
        assert sum(1 for c in stack.lowcmd if c[0] > first_damp + 0.2 and c[1] == 1.0) > 50
    # Now the adapter dies: the robot's own motor timeout damps it (logged by its
    # actuator layer with the robot time).
    assert "timed out" not in stack.log("robot")
    stack.procs["adapter"].send_signal(signal.SIGKILL)
    deadline = time.monotonic() + 5
    while "leg commands timed out: damping" not in stack.log("robot"):
        assert time.monotonic() < deadline, stack.logs_tail()
        time.sleep(0.05)
