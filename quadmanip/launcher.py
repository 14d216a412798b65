"""`quadmanip up`: a Zenoh router plus the configured services as child processes.

Why a launcher of our own instead of a process manager: a developer wants one command that
starts the stack on a laptop, interleaves the logs (each line prefixed with the child's name),
and tears everything down on Ctrl-C without leaving a stray process holding a Zenoh port.

Guarantees:
- every child runs in its own process group, so the terminal's Ctrl-C reaches only the
  launcher, which stops the services first (they close their sessions while the router is
  still up) and the router last: SIGTERM, then SIGKILL to the whole group after
  ``stop_grace_s``; exit within ``stop_grace_s + 0.5`` s of SIGTERM;
- children get ``PR_SET_PDEATHSIG`` (via ``QM_PARENT_PID``, see ``quadmanip.cli``), so even a
  SIGKILLed launcher leaves no orphans on Linux; restarts are spawned from the same (main)
  thread as the first start, so they get the same guarantee;
- a child that dies on its own is handled by its restart policy (``[restart]`` of
  ``configs/launch.toml``, like compose's ``restart:``), the router included (services
  reconnect to a restarted router on their own):

  * ``on-failure`` (default): a child that exits non-zero or is killed by a signal (SIGKILL
    included) is restarted with the same argv and environment after a backoff that doubles
    with each restart in the window (``backoff_s`` .. ``backoff_max_s``); what is left of its
    old process group is SIGKILLed first. A child that exits 0 is left stopped and the rest
    keep running (the launcher exits 0 once every child has exited 0). A child that would
    restart more than ``max_restarts`` times within ``window_s`` makes the launcher give up:
    it names the child, stops the rest and exits ``EXIT_CHILD_DIED``;
  * ``no``: any exit of a child is reported by name, the rest are stopped, and the exit code
    is non-zero (``EXIT_CHILD_DIED``).

  The decision is :class:`RestartTracker`, a pure class (no processes, no clock of its own).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, TextIO, cast

from quadmanip import services_registry
from quadmanip.common.bus import Bus, BusConfig
from quadmanip.common.config import load_config

EXIT_OK = 0
EXIT_CHILD_DIED = 1
EXIT_USAGE = 2

RestartMode = Literal["no", "on-failure"]
RESTART_MODES: tuple[str, ...] = ("no", "on-failure")


@dataclass(frozen=True)
class RestartPolicy:
    """How one child is restarted when it dies on its own (compose's ``restart:``).

    ``policy``: ``"on-failure"`` restarts a child that exits non-zero or by a signal;
    ``"no"`` never restarts (any exit stops the launcher). ``max_restarts`` restarts are
    allowed within any ``window_s`` seconds; one more and the launcher gives up. Before the
    n-th restart of a window the launcher waits ``backoff_s * 2**(n-1)``, at most
    ``backoff_max_s``, so a crash loop does not spin a core.
    """

    policy: RestartMode = "on-failure"
    max_restarts: int = 5
    window_s: float = 60.0
    backoff_s: float = 0.5
    backoff_max_s: float = 5.0

    def __post_init__(self) -> None:
        if self.policy not in RESTART_MODES:
            raise ValueError(f"restart policy must be one of {RESTART_MODES}, got {self.policy!r}")
        if self.max_restarts < 0:
            raise ValueError("max_restarts must be >= 0")
        if self.window_s <= 0.0:
            raise ValueError("window_s must be positive")
        if not 0.0 <= self.backoff_s <= self.backoff_max_s:
            raise ValueError("want 0 <= backoff_s <= backoff_max_s")

    def backoff(self, attempt: int) -> float:
        """Seconds to wait before restart number ``attempt`` (1-based) within the window."""
        if attempt < 1:
            raise ValueError("attempt is 1-based")
        # Cap the exponent: 2**attempt for a large attempt would overflow a float.
        return min(self.backoff_max_s, self.backoff_s * 2.0 ** min(attempt - 1, 60))


@dataclass(frozen=True)
class RestartOverride:
    """``[restart.services.NAME]``: the keys it sets replace ``[restart]``'s for that child."""

    policy: RestartMode | None = None
    max_restarts: int | None = None
    window_s: float | None = None
    backoff_s: float | None = None
    backoff_max_s: float | None = None


@dataclass(frozen=True)
class RestartConfig(RestartPolicy):
    """``[restart]`` of ``configs/launch.toml``: the policy of every child, plus overrides.

    ``services`` is keyed by child name (a service, or ``"router"``).
    """

    services: dict[str, RestartOverride] = field(default_factory=dict)

    def for_child(self, name: str) -> RestartPolicy:
        """The effective policy of child ``name`` (its override merged over the base)."""
        base = {f.name: getattr(self, f.name) for f in dataclasses.fields(RestartPolicy)}
        override = self.services.get(name)
        if override is not None:
            base.update(
                {
                    f.name: getattr(override, f.name)
                    for f in dataclasses.fields(override)
                    if getattr(override, f.name) is not None
                }
            )
        return RestartPolicy(**base)

    def with_policy(self, policy: RestartMode) -> RestartConfig:
        """This config with ``policy`` for every child (``up --restart``): a command-line
        choice beats the file, per-service overrides included; their limits stay."""
        services = {name: dataclasses.replace(o, policy=None) for name, o in self.services.items()}
        return dataclasses.replace(self, policy=policy, services=services)


RestartAction = Literal["restart", "leave", "give-up"]


@dataclass(frozen=True)
class RestartDecision:
    """What to do about one exit: ``restart`` after ``delay_s`` (``attempt`` is its number
    within the window), ``leave`` the child stopped, or ``give-up`` (stop everything)."""

    action: RestartAction
    reason: str
    delay_s: float = 0.0
    attempt: int = 0


class RestartTracker:
    """The restart decisions for one child: a sliding window of its recent restarts.

    Pure on purpose (no processes, the time is an argument), so the policy is unit-tested
    without spawning anything; the launcher only acts on the decisions.
    """

    def __init__(self, policy: RestartPolicy) -> None:
        self.policy = policy
        self._recent: deque[float] = deque()  # times of the restarts within the window
        self.total = 0  # restarts over the launcher's lifetime (for the log)

    def recent(self, now: float) -> int:
        """Restarts within the last ``window_s`` before ``now``."""
        while self._recent and now - self._recent[0] >= self.policy.window_s:
            self._recent.popleft()
        return len(self._recent)

    def on_exit(self, returncode: int, now: float) -> RestartDecision:
        """Decide about a child that exited with Popen's ``returncode`` at time ``now``."""
        p = self.policy
        if p.policy == "no":
            return RestartDecision("give-up", "not restarted (restart policy 'no')")
        if returncode == 0:
            # Like compose's on-failure: a clean exit is the child's own decision to stop.
            return RestartDecision("leave", "not restarted (a clean exit; restart on-failure)")
        count = self.recent(now)
        if count >= p.max_restarts:
            return RestartDecision(
                "give-up",
                f"giving up: {count} restarts within {p.window_s:g} s already "
                f"(max_restarts {p.max_restarts})",
            )
        self._recent.append(now)
        self.total += 1
        attempt = count + 1
        delay = p.backoff(attempt)
        return RestartDecision(
            "restart",
            f"restarting in {delay:g} s (restart {attempt} of {p.max_restarts} "
            f"within {p.window_s:g} s; {self.total} in all)",
            delay_s=delay,
            attempt=attempt,
        )


@dataclass(frozen=True)
class LaunchProfile:
    """One ``[profiles.NAME]`` table of ``configs/launch.toml`` (``quadmanip up --profile``).

    ``services`` replaces the base list (in start order); ``service_args`` is merged over
    the base ``[service_args]``, one service's argument list replacing that service's.
    """

    services: tuple[str, ...] = ()
    service_args: dict[str, list[str]] = field(default_factory=dict)


@dataclass(frozen=True)
class LaunchConfig:
    """Contents of ``configs/launch.toml``."""

    router: bool = True
    listen: str = "tcp/127.0.0.1:7447"
    services: tuple[str, ...] = ()
    stop_grace_s: float = 2.0
    router_wait_s: float = 10.0
    service_args: dict[str, list[str]] = field(default_factory=dict)
    profiles: dict[str, LaunchProfile] = field(default_factory=dict)
    restart: RestartConfig = field(default_factory=RestartConfig)

    def __post_init__(self) -> None:
        if not 0.0 < self.stop_grace_s <= 10.0:
            raise ValueError("stop_grace_s must be in (0, 10]")
        if self.router_wait_s <= 0.0:
            raise ValueError("router_wait_s must be positive")
        parse_endpoint(self.listen)


def load_launch_config(name_or_path: str = "launch") -> LaunchConfig:
    """Load the launch configuration (strict: unknown keys are errors)."""
    return load_config(LaunchConfig, name_or_path)


def apply_profile(config: LaunchConfig, profile: str | None) -> LaunchConfig:
    """``config`` with profile ``profile`` applied (``None``: unchanged).

    Raises ValueError naming the known profiles if ``profile`` is not in ``config.profiles``.
    """
    if profile is None:
        return config
    try:
        chosen = config.profiles[profile]
    except KeyError:
        known = ", ".join(sorted(config.profiles)) or "none defined"
        raise ValueError(f"unknown profile {profile!r} (known profiles: {known})") from None
    return dataclasses.replace(
        config,
        services=tuple(chosen.services),
        service_args={**config.service_args, **chosen.service_args},
    )


def parse_endpoint(endpoint: str) -> tuple[str, str, int]:
    """Split a Zenoh endpoint ``tcp/host:port`` into (protocol, host, port)."""
    proto, sep, rest = endpoint.partition("/")
    host, colon, port = rest.rpartition(":")
    if not sep or not colon or not host or not port.isdigit():
        raise ValueError(f"bad endpoint {endpoint!r}: want e.g. 'tcp/127.0.0.1:7447'")
    return proto, host.strip("[]"), int(port)


def connect_endpoint(listen: str) -> str:
    """The endpoint local children should connect to when the router listens on ``listen``.

    A wildcard listen address (0.0.0.0, ::) is not connectable; use loopback instead.
    """
    proto, host, port = parse_endpoint(listen)
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def free_endpoint(host: str = "127.0.0.1") -> str:
    """A TCP endpoint on a port that is free right now (for tests and throwaway stacks)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        port = s.getsockname()[1]
    return f"tcp/{host}:{port}"


def wait_for_port(endpoint: str, timeout_s: float, alive: Callable[[], bool]) -> bool:
    """Poll until something accepts TCP connections on ``endpoint`` (or ``alive()`` is False)."""
    _, host, port = parse_endpoint(endpoint)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not alive():
            return False
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return True
        except OSError:
            time.sleep(0.05)
    return False


def cli_command(*args: str) -> list[str]:
    """Command line that runs ``quadmanip <args>`` with this interpreter (no PATH lookup)."""
    return [sys.executable, "-m", "quadmanip.cli", *args]


def describe_exit(code: int) -> str:
    """Human wording for a Popen return code (negative = killed by a signal)."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with code {code}"


@dataclass
class Child:
    """One child process of the launcher."""

    name: str
    argv: list[str]
    env: dict[str, str]
    proc: subprocess.Popen[bytes] | None = None
    reader: threading.Thread | None = None
    tracker: RestartTracker | None = None
    restart_at: float | None = None  # monotonic time of a scheduled restart
    done: bool = False  # exited 0 under on-failure: left stopped on purpose

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


class Launcher:
    """Starts children in order, multiplexes their output, and stops them all.

    Spawn and stop from one thread only (the main thread): ``PR_SET_PDEATHSIG`` fires when
    the *thread* that forked a child exits.
    """

    def __init__(
        self,
        *,
        listen: str | None,
        services: Sequence[str],
        service_args: dict[str, list[str]] | None = None,
        robot: str | None = None,
        stop_grace_s: float = 2.0,
        router_wait_s: float = 10.0,
        out: TextIO | None = None,
        connect: str | None = None,
        restart: RestartConfig | None = None,
    ) -> None:
        self.listen = listen
        self.connect = connect_endpoint(listen) if listen else connect
        self.services = list(services)
        self.service_args = dict(service_args or {})
        self.robot = robot
        self.stop_grace_s = stop_grace_s
        self.router_wait_s = router_wait_s
        self.out = out if out is not None else sys.stdout
        # Used by run() only: start()/dead_child()/stop() callers (demo, testbench) supervise
        # themselves and see a dead child as before.
        self.restart = restart if restart is not None else RestartConfig()
        self.children: list[Child] = []
        self._write_lock = threading.Lock()
        self._stopping = False
        width = max([len(n) for n in [*self.services, "router", "up"]])
        self._width = width

    # ----------------------------------------------------------------- output
    def log(self, text: str, name: str = "up") -> None:
        """Write one prefixed line to the launcher's output."""
        with self._write_lock:
            try:
                self.out.write(f"{name:>{self._width}} | {text}\n")
                self.out.flush()
            except (ValueError, OSError):
                pass  # output closed (e.g. broken pipe): keep supervising anyway

    def _pump(self, child: Child) -> None:
        assert child.proc is not None and child.proc.stdout is not None
        for raw in iter(child.proc.stdout.readline, b""):
            self.log(raw.decode("utf-8", errors="replace").rstrip("\r\n"), child.name)
        child.proc.stdout.close()

    # ------------------------------------------------------------------ start
    def _base_env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        env["QM_PARENT_PID"] = str(os.getpid())
        if self.connect:
            env["QM_ZENOH_CONNECT"] = self.connect
        return env

    def _spawn(self, child: Child) -> None:
        """Start ``child`` (first start or restart: same argv and env) and pump its output."""
        restart = child.proc is not None
        child.proc = subprocess.Popen(
            child.argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=child.env,
            process_group=0,
        )
        child.reader = threading.Thread(
            target=self._pump, args=(child,), name=f"out-{child.name}", daemon=True
        )
        child.reader.start()
        if not restart:
            self.children.append(child)
        again = (
            ""
            if not restart or child.tracker is None
            else f" again (restart {child.tracker.total})"
        )
        self.log(f"started {child.name} (pid {child.pid}){again}: {' '.join(child.argv[3:])}")

    def service_argv(self, name: str) -> list[str]:
        """The command line of service ``name`` as the launcher runs it."""
        args = ["service", name]
        if self.robot:
            args += ["--robot", self.robot]
        if self.connect:
            args += ["--connect", self.connect]
        args += list(self.service_args.get(name, []))
        return cli_command(*args)

    def start(self) -> None:
        """Start the router (if any), wait for its port, then the services in order.

        Raises RuntimeError (after stopping what started) if the router never comes up.
        """
        env = self._base_env()
        if self.listen:
            router = Child("router", cli_command("router", "--listen", self.listen), env)
            self._spawn(router)
            if not wait_for_port(self.connect or self.listen, self.router_wait_s, router.running):
                why = (
                    describe_exit(router.proc.returncode)
                    if router.proc and router.proc.poll() is not None
                    else f"not listening on {self.listen} after {self.router_wait_s:.0f} s"
                )
                self.stop()
                raise RuntimeError(f"router failed to start: {why}")
            self.log(f"router listening on {self.listen}")
        for name in self.services:
            self._spawn(Child(name, self.service_argv(name), env))

    # ---------------------------------------------------------------- monitor
    def dead_child(self) -> Child | None:
        """The first child that exited while we were not stopping, if any.

        For callers that supervise without restarts (demo, testbench); ``run`` uses
        :meth:`supervise`.
        """
        if self._stopping:
            return None
        for child in self.children:
            if child.proc is not None and child.proc.poll() is not None:
                return child
        return None

    def supervise(self, now: float) -> tuple[int, str] | None:
        """One pass of ``run``'s loop: apply the restart policy to children that exited.

        Starts children whose backoff is over, schedules restarts for new failures.
        Returns ``(exit code, why)`` when the launcher must stop, else None. Call it from
        the thread that spawned the children (``PR_SET_PDEATHSIG``).
        """
        if self._stopping:
            return None
        for child in self.children:
            if child.restart_at is not None:
                if now >= child.restart_at:
                    child.restart_at = None
                    try:
                        self._spawn(child)
                    except OSError as exc:  # e.g. out of processes or file descriptors
                        self.log(f"error: cannot restart {child.name}: {exc}; stopping the rest")
                        return EXIT_CHILD_DIED, f"{child.name} could not be restarted"
                continue
            if child.done or child.proc is None or child.proc.poll() is None:
                continue
            if child.tracker is None:
                child.tracker = RestartTracker(self.restart.for_child(child.name))
            code = child.proc.returncode
            decision = child.tracker.on_exit(code, now)
            what = f"{child.name} (pid {child.pid}) {describe_exit(code)}"
            if decision.action == "restart":
                # Grandchildren of the dead child may still hold its pipe or a port.
                self._signal_group(child, signal.SIGKILL)
                child.restart_at = now + decision.delay_s
                self.log(f"{what}; {decision.reason}")
            elif decision.action == "leave":
                child.done = True
                self.log(f"{what}; {decision.reason}")
            else:
                self.log(f"error: {what}; {decision.reason}; stopping the rest")
                n = child.tracker.total
                after = f" after {n} restart{'s' if n != 1 else ''}" if n else ""
                return EXIT_CHILD_DIED, f"{child.name} died{after}"
        if self.children and all(c.done for c in self.children):
            return EXIT_OK, "every child exited cleanly"
        return None

    # ------------------------------------------------------------------- stop
    @staticmethod
    def _signal_group(child: Child, sig: signal.Signals) -> None:
        if child.proc is None:
            return
        try:
            os.killpg(child.proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def _wait_all(self, children: Sequence[Child], deadline: float) -> None:
        for child in children:
            if child.proc is None:
                continue
            try:
                child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass

    def stop(self) -> None:
        """Stop every child: services first, router last; SIGKILL after the grace period."""
        self._stopping = True
        t0 = time.monotonic()
        services = [c for c in self.children if c.name != "router"]
        routers = [c for c in self.children if c.name == "router"]
        for child in services:
            if child.running():
                self._signal_group(child, signal.SIGTERM)
        # Services get most of the grace period while the router still serves their close.
        self._wait_all(services, t0 + 0.75 * self.stop_grace_s)
        for child in routers:
            if child.running():
                self._signal_group(child, signal.SIGTERM)
        self._wait_all(self.children, t0 + self.stop_grace_s)
        for child in self.children:
            if child.running():
                self.log(f"{child.name} did not stop in {self.stop_grace_s:.1f} s: SIGKILL")
            # Sweep the whole group, also grandchildren of a child that already exited.
            self._signal_group(child, signal.SIGKILL)
        self._wait_all(self.children, time.monotonic() + 0.5)
        for child in self.children:
            if child.reader is not None:
                child.reader.join(timeout=0.2)

    # -------------------------------------------------------------------- run
    def run(self, stop_event: threading.Event) -> int:
        """Start everything, supervise (restarting children as their policy says) until
        ``stop_event`` or a give-up, then stop all."""
        try:
            self.start()
        except RuntimeError as exc:
            self.log(f"error: {exc}")
            return EXIT_CHILD_DIED
        if not self.services:
            self.log("no services to start; running the router only")
        self.log("running; Ctrl-C or SIGTERM stops everything")
        outcome: tuple[int, str] | None = None
        while outcome is None and not stop_event.wait(0.05):
            outcome = self.supervise(time.monotonic())
        code, why = outcome if outcome is not None else (EXIT_OK, "")
        self.log("stopping")
        self.stop()
        if code != EXIT_OK:
            self.log(f"stopped; exit {code} because {why}")
        else:
            self.log(f"stopped cleanly{'' if not why else f' ({why})'}")
        return code


def install_stop_signals(stop_event: threading.Event) -> None:
    """SIGTERM, SIGINT and SIGHUP set ``stop_event`` (main thread only)."""

    def handler(signum: int, _frame: object) -> None:
        stop_event.set()

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, handler)


def resolve_services(
    requested: str | None, config: LaunchConfig
) -> tuple[list[str], list[str], str | None]:
    """Which services to start: ``--services`` (strict) or the config (tolerant).

    Returns (names, notes, error). Names from the command line must be registered and importable;
    names from ``launch.toml`` that are not registered yet are skipped with a note, so the
    default config can name the whole planned stack while only part of it exists.
    """
    registry = services_registry.available()
    if requested is not None:
        names = [n.strip() for n in requested.split(",") if n.strip()]
        for name in names:
            problem = registry.get(name, None) if name in registry else "not registered"
            if problem:
                known = ", ".join(registry) or "none registered yet"
                return [], [], f"cannot start {name!r}: {problem} (registered: {known})"
        return names, [], None
    names, skipped = [], []
    for name in config.services:
        if name not in registry:
            skipped.append(name)
        elif registry[name]:
            return [], [], f"cannot start {name!r}: {registry[name]}"
        else:
            names.append(name)
    notes = [f"not registered yet, skipped: {', '.join(skipped)}"] if skipped else []
    return names, notes, None


def up(
    *,
    services: str | None = None,
    router: bool | None = None,
    listen: str | None = None,
    connect: str | None = None,
    robot: str | None = None,
    config: str = "launch",
    profile: str | None = None,
    restart: str | None = None,
    out: TextIO | None = None,
) -> int:
    """Entry point of ``quadmanip up`` (flags override ``configs/launch.toml``).

    ``profile`` names a ``[profiles.NAME]`` table of the config: its services replace the
    configured list and its service_args are merged over the base ones. ``restart``
    (``"no"`` or ``"on-failure"``) replaces the restart policy of every child.
    """
    out = out if out is not None else sys.stdout
    try:
        cfg = apply_profile(load_launch_config(config), profile)
        if listen is not None:
            parse_endpoint(listen)
        if connect is not None:
            parse_endpoint(connect)
        if restart is not None:
            if restart not in RESTART_MODES:
                raise ValueError(f"--restart must be one of {', '.join(RESTART_MODES)}")
            mode = cast(RestartMode, restart)  # checked just above
            cfg = dataclasses.replace(cfg, restart=cfg.restart.with_policy(mode))
    except ValueError as exc:
        out.write(f"up | error: {exc}\n")
        return EXIT_USAGE
    names, notes, error = resolve_services(services, cfg)
    if error:
        out.write(f"up | error: {error}\n")
        return EXIT_USAGE
    # Handlers before the first child exists: a SIGTERM from now on stops the children.
    stop_event = threading.Event()
    install_stop_signals(stop_event)
    use_router = cfg.router if router is None else router
    if not use_router and names and not (connect or os.environ.get("QM_ZENOH_CONNECT")):
        out.write("up | note: --no-router without --connect: services use their bus defaults\n")
    launcher = Launcher(
        listen=(listen or cfg.listen) if use_router else None,
        connect=connect,
        services=names,
        service_args=cfg.service_args,
        robot=robot,
        stop_grace_s=cfg.stop_grace_s,
        router_wait_s=cfg.router_wait_s,
        out=out,
        restart=cfg.restart,
    )
    for note in notes:
        launcher.log(note)
    return launcher.run(stop_event)


def observer_bus(endpoint: str) -> Bus:
    """A program's own peer session on a private stack's router (``endpoint``), to watch
    and drive that stack (tidyup, the test harness); it ignores ``QM_ZENOH_*``."""
    return Bus(
        BusConfig(mode="peer", connect=(endpoint,), listen=("tcp/127.0.0.1:0",), env_override=False)
    )
