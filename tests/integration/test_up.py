"""`quadmanip up`: router + registered services over TCP on loopback, restarts, clean stop."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import psutil
import pytest
from quadmanip import services_registry
from quadmanip.common.bus import Bus, BusConfig
from quadmanip.launcher import free_endpoint, load_launch_config, wait_for_port

pytestmark = pytest.mark.integration

START_TIMEOUT_S = 60.0  # a cold MuJoCo import on a loaded 2-core machine is slow


class UpProcess:
    """`quadmanip up` as a child of the test, its output collected line by line."""

    def __init__(self, *args: str, cwd: str | None = None) -> None:
        self.endpoint = free_endpoint()
        env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
        env.pop("QM_ZENOH_CONNECT", None)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "quadmanip.cli", "up", "--listen", self.endpoint, *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            cwd=cwd,  # services that write files (viz recordings) write them there
        )
        self.lines: list[str] = []
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    @property
    def output(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_for(self, text: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self._cond:
            while not any(text in line for line in self.lines):
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    return any(text in line for line in self.lines)
                self._cond.wait(min(left, 0.1))
        return True

    def descendants(self) -> list[psutil.Process]:
        return psutil.Process(self.proc.pid).children(recursive=True)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


def _gone(procs: list[psutil.Process], timeout: float) -> list[psutil.Process]:
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    return [p for p in alive if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


@pytest.fixture
def stack(tmp_path):
    ups: list[UpProcess] = []

    def start(*args: str) -> UpProcess:
        up = UpProcess(*args, cwd=str(tmp_path))
        ups.append(up)
        assert up.wait_for("running; Ctrl-C", START_TIMEOUT_S), up.output
        return up

    yield start
    for up in ups:
        leftovers = up.descendants() if up.proc.poll() is None else []
        up.kill()
        for p in leftovers:
            p.kill()


def _expected_children() -> set[str]:
    """The router and every service of configs/launch.toml's list that is registered and
    importable (profiles such as unitree-sim start others)."""
    listed = set(load_launch_config().services)
    ready = {n for n, p in services_registry.available().items() if p is None}
    return {"router", *(listed & ready)}


def _wait_alive(endpoint: str, services: set[str], timeout: float) -> set[str]:
    """Services whose liveliness token is visible through the router (what a peer sees)."""
    alive: set[str] = set()
    with Bus(BusConfig(mode="client", connect=(endpoint,))) as bus:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not services <= alive:
            alive = bus.alive_services(timeout=1.0)
            time.sleep(0.2)
    return alive


def test_up_starts_everything_and_stops_on_sigterm_within_3s(stack):
    up = stack()
    services = _expected_children() - {"router"}
    # Every registered service really runs: its liveliness token reaches us via the router.
    alive = _wait_alive(up.endpoint, services, START_TIMEOUT_S)
    assert services <= alive, up.output
    children = up.descendants()
    started = {
        line.split("started ", 1)[1].split(" ")[0] for line in up.lines if "started " in line
    }
    assert started == _expected_children(), up.output
    assert len(children) >= len(started)
    assert all(p.is_running() for p in children), up.output

    t0 = time.monotonic()
    up.proc.send_signal(signal.SIGTERM)
    rc = up.proc.wait(timeout=10)
    elapsed = time.monotonic() - t0
    assert rc == 0, up.output
    assert elapsed <= 3.0, f"took {elapsed:.2f} s\n{up.output}"
    assert _gone(children, 1.0) == [], up.output
    assert "stopped cleanly" in up.output


def _started(up: UpProcess, name: str, after: int = 0) -> int | None:
    """The pid of the last ``started NAME (pid N)`` line from line ``after`` on, if any."""
    pids = [
        int(line.split(f"started {name} (pid ", 1)[1].split(")")[0])
        for line in up.lines[after:]
        if f"started {name} (pid " in line
    ]
    return pids[-1] if pids else None


def _wait_restarted(up: UpProcess, name: str, old_pid: int, timeout: float) -> int:
    """Wait for the launcher to start ``name`` again after ``old_pid`` died; its new pid."""
    assert up.wait_for(f"{name} (pid {old_pid}) killed by SIGKILL; restarting in", 30), up.output
    n = next(i for i, line in enumerate(up.lines) if f"{name} (pid {old_pid}) killed" in line)
    deadline = time.monotonic() + timeout
    while (new_pid := _started(up, name, after=n)) is None and time.monotonic() < deadline:
        if up.proc.poll() is not None:
            break  # the launcher gave up: the assertion below shows its output
        time.sleep(0.1)
    assert new_pid is not None and new_pid != old_pid, up.output
    return new_pid


def test_a_killed_service_is_restarted_and_the_stack_keeps_running(stack):
    # One cheap service (no physics, no renderer) keeps this fast on a small machine.
    up = stack("--services", "manipulation")
    assert _wait_alive(up.endpoint, {"manipulation"}, START_TIMEOUT_S) >= {"manipulation"}
    old_pid = _started(up, "manipulation")
    assert old_pid is not None, up.output
    os.killpg(old_pid, signal.SIGKILL)  # the whole group, as an OOM kill or a crash would

    new_pid = _wait_restarted(up, "manipulation", old_pid, START_TIMEOUT_S)
    assert f"started manipulation (pid {new_pid}) again (restart 1)" in up.output
    assert "restart 1 of 5 within 60 s" in up.output
    assert up.proc.poll() is None, up.output  # the launcher kept running
    new = psutil.Process(new_pid)
    assert new.is_running() and new.status() != psutil.STATUS_ZOMBIE
    assert new.pid in {p.pid for p in up.descendants()}
    # The new process really serves: its liveliness token reaches a peer via the router.
    assert "manipulation" in _wait_alive(up.endpoint, {"manipulation"}, START_TIMEOUT_S)
    assert psutil.pid_exists(new_pid) and up.proc.poll() is None, up.output

    children = up.descendants()
    up.proc.send_signal(signal.SIGTERM)
    assert up.proc.wait(timeout=30) == 0, up.output
    assert "stopped cleanly" in up.output
    assert _gone(children, 3.0) == [], up.output


def test_a_killed_router_is_restarted(stack):
    up = stack("--services", "")  # the router alone
    old_pid = _started(up, "router")
    assert old_pid is not None, up.output
    os.killpg(old_pid, signal.SIGKILL)
    new_pid = _wait_restarted(up, "router", old_pid, START_TIMEOUT_S)
    # The new router serves the same endpoint: a client session opens through it.
    assert wait_for_port(up.endpoint, START_TIMEOUT_S, lambda: up.proc.poll() is None), up.output
    with Bus(BusConfig(mode="client", connect=(up.endpoint,))) as bus:
        assert bus.alive_services(timeout=1.0) == set()  # no services in this stack
    assert psutil.pid_exists(new_pid) and up.proc.poll() is None, up.output
    up.proc.send_signal(signal.SIGTERM)
    assert up.proc.wait(timeout=30) == 0, up.output


def test_child_killed_externally_with_restart_no_makes_up_exit_nonzero_naming_it(stack):
    up = stack("--restart", "no")
    time.sleep(0.5)
    # The last child started: a service if one is registered, otherwise the router.
    victim_line = [line for line in up.lines if "started " in line][-1]
    name = victim_line.split("started ", 1)[1].split(" ")[0]
    pid = int(victim_line.split("(pid ", 1)[1].split(")")[0])
    others = [p for p in up.descendants() if p.pid != pid]
    os.kill(pid, signal.SIGKILL)
    rc = up.proc.wait(timeout=10)
    assert rc != 0, up.output
    assert f"error: {name} (pid {pid}) killed by SIGKILL" in up.output, up.output
    assert _gone(others, 1.0) == [], up.output


def test_launcher_killed_hard_leaves_no_orphans(stack):
    up = stack()
    children = up.descendants()
    assert children
    up.proc.kill()  # SIGKILL: no chance to clean up; PR_SET_PDEATHSIG must do it
    up.proc.wait(5)
    assert _gone(children, 3.0) == []


def test_up_rejects_an_unknown_service():
    result = subprocess.run(
        [sys.executable, "-m", "quadmanip.cli", "up", "--services", "no_such_service"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert "no_such_service" in result.stdout


def test_demo_runs_the_stack_and_saves_camera_frames(tmp_path):
    out = tmp_path / "demo"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "quadmanip.cli",
            "demo",
            # The whole stack in lockstep runs at about 0.2 of real time on 2 cores (the sim's
            # software rendering, perception and viz share them): 20 s was too short to
            # reach the trot, 3 s of robot time in.
            "--duration",
            "35",
            "--out",
            str(out),
            "--frames-every",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")),
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "demo: stopped cleanly" in result.stdout
    running = _expected_children() - {"router"}
    if not running:
        assert "round trip through the router" in result.stdout
        return
    for name in running:
        assert f"qm/dog1/{name}/heartbeat" in result.stdout
    if "sim" in running:
        import cv2

        rgb = sorted(out.glob("front_*_rgb.png"))
        depth = sorted(out.glob("front_*_depth.png"))
        assert rgb and depth, sorted(p.name for p in out.iterdir())
        image = cv2.imread(str(rgb[-1]))
        assert image is not None and image.ndim == 3 and min(image.shape[:2]) >= 32
        assert image.std() > 5.0  # a rendered room, not a blank frame
    if "viz" in running:
        assert list(out.glob("*.rrd")), "the viz recording belongs in the demo's --out folder"
    if {"sim", "locomotion"} <= running:
        # The operator script makes the robot stand up and trot; the demo checks it moved.
        assert "demo: the robot stood up and walked" in result.stdout, result.stdout[-3000:]
