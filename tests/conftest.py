"""Shared pytest fixtures: a real Zenoh router in a subprocess, child processes, buses.

Integration tests run real processes over a real local Zenoh router on a free loopback
TCP port, so parallel test runs (and other stacks on the machine) never see each other:
multicast scouting is off everywhere and each router has its own port.

* ``zenoh_router`` — starts ``python -m quadmanip.common.router`` on a free port, yields
  its endpoint (``tcp/127.0.0.1:PORT``), stops it afterwards.
* ``router_factory`` — for tests that kill and restart routers: ``router_factory(port)``
  returns a :class:`RouterProcess` (``.endpoint``, ``.kill()``, ``.stop()``).
* ``spawn`` — ``spawn("-m", "module", "args"..., endpoint=ep)`` or
  ``spawn(script_path, ..., endpoint=ep)`` starts a Python child with
  ``QM_ZENOH_CONNECT=ep``; its output lines are collected (``wait_for``); every child is
  killed at teardown, so a failing test never leaves orphans.
* ``bus_factory`` — ``bus_factory(endpoint, mode="peer")`` opens a :class:`Bus` in the test
  process and closes it at teardown.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
HELPERS = REPO / "tests" / "integration" / "helpers"
if str(HELPERS) not in sys.path:
    sys.path.insert(0, str(HELPERS))

LOOPBACK = "127.0.0.1"


def free_port() -> int:
    """A TCP port on the loopback interface that is free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def port_open(port: int, host: str = LOOPBACK) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False


def child_env(endpoint: str | None = None, **extra: str) -> dict[str, str]:
    """Environment for a child process on the test bus (loopback only, line-buffered)."""
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("QM_LOG_LEVEL", "INFO")
    if endpoint is not None:
        env["QM_ZENOH_CONNECT"] = endpoint
        env["QM_ZENOH_LISTEN"] = f"tcp/{LOOPBACK}:0"
    env.update(extra)
    return env


class ChildProcess:
    """A child process whose stdout+stderr lines are collected by a reader thread."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        self.argv = argv
        self.proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            cwd=str(REPO),
            start_new_session=True,  # our signals only; the group can be killed as a whole
        )
        self.lines: list[str] = []
        self._queue: queue.Queue[str] = queue.Queue()
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    def output(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_for(self, pattern: str, timeout: float, start: int = 0) -> re.Match[str] | None:
        """Wait until an output line (from index ``start``) matches the regex ``pattern``."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout
        i = start
        with self._cond:
            while True:
                while i < len(self.lines):
                    m = rx.search(self.lines[i])
                    if m:
                        return m
                    i += 1
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(min(remaining, 0.1))

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)

    def kill(self) -> None:
        """SIGKILL the whole process group (no orphans even if the child forked)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            pass

    def wait(self, timeout: float) -> int | None:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None


class RouterProcess(ChildProcess):
    """``python -m quadmanip.common.router`` on one loopback port."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.endpoint = f"tcp/{LOOPBACK}:{port}"
        super().__init__(
            [sys.executable, "-m", "quadmanip.common.router", "--listen", self.endpoint],
            child_env(),
        )

    def wait_ready(self, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"router exited {self.proc.returncode}:\n{self.output()}")
            if port_open(self.port):
                return
            time.sleep(0.05)
        raise TimeoutError(f"router on {self.endpoint} not ready in {timeout}s:\n{self.output()}")

    def stop(self, timeout: float = 5.0) -> int | None:
        self.signal(signal.SIGTERM)
        code = self.wait(timeout)
        if code is None:
            self.kill()
        return code


@pytest.fixture
def router_factory() -> Iterator[Callable[..., RouterProcess]]:
    """Start routers on given (or free) ports; all are killed at teardown."""
    routers: list[RouterProcess] = []

    def start(port: int | None = None, wait: bool = True) -> RouterProcess:
        r = RouterProcess(port if port is not None else free_port())
        routers.append(r)
        if wait:
            r.wait_ready()
        return r

    yield start
    for r in routers:
        r.kill()


@pytest.fixture
def zenoh_router(router_factory: Callable[..., RouterProcess]) -> str:
    """A fresh router on a free loopback port; yields its endpoint string."""
    return router_factory().endpoint


@pytest.fixture
def spawn() -> Iterator[Callable[..., ChildProcess]]:
    """Start Python children on the test bus; all are killed at teardown.

    ``spawn("-m", "quadmanip.x", "--flag", endpoint=ep)`` runs a module;
    ``spawn(path_to_script, "arg", endpoint=ep)`` a script (helpers live in
    ``tests/integration/helpers``). Extra environment variables via ``env={...}``.
    """
    children: list[ChildProcess] = []

    def start(
        *args: str, endpoint: str | None = None, env: dict[str, str] | None = None
    ) -> ChildProcess:
        child = ChildProcess([sys.executable, *map(str, args)], child_env(endpoint, **(env or {})))
        children.append(child)
        return child

    yield start
    for c in children:
        c.kill()


@pytest.fixture
def bus_factory() -> Iterator[Callable[..., object]]:
    """Open :class:`quadmanip.common.bus.Bus` objects in the test process; closed at teardown."""
    from quadmanip.common.bus import Bus, BusConfig

    buses: list[Bus] = []

    def open_bus(
        endpoint: str, mode: str = "peer", robot: str = "dog1", table: object = None
    ) -> Bus:
        cfg = BusConfig(
            mode=mode,  # type: ignore[arg-type]
            connect=(endpoint,),
            listen=(f"tcp/{LOOPBACK}:0",) if mode == "peer" else (),
            env_override=False,
        )
        bus = Bus(cfg, robot=robot, table=table)  # type: ignore[arg-type]
        buses.append(bus)
        return bus

    yield open_bus
    for b in buses:
        b.close()


@pytest.fixture
def up_calls(monkeypatch: pytest.MonkeyPatch) -> dict:
    """``launcher.up`` replaced by a recorder: the keyword arguments of its last call (the
    CLI tests check what ``quadmanip up`` passes on without starting anything)."""
    from quadmanip import launcher

    seen: dict = {}

    def fake_up(**kwargs: object) -> int:
        seen.update(kwargs)
        return 0

    monkeypatch.setattr(launcher, "up", fake_up)
    return seen
