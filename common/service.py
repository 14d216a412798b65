"""The service runtime: what every quadmanip process (sim, locomotion, ...) is made of.

A service is a subclass of :class:`Service` that declares its name, its config dataclass
and its inputs and outputs, and fills in :meth:`Service.setup` (declare subscribers and
publishers), optionally :meth:`Service.step` (called every ``loop_period``) or a whole
:meth:`Service.run`, and :meth:`Service.teardown`. Its node module exposes::

    def main(argv: list[str]) -> int:
        return run_service(LocomotionNode, argv)

:func:`run_service` does the rest, identically for every service: command-line flags
(``--config``, ``--set key=value``, ``--connect``, ``--robot``, ``--describe``), logging
with the service name, the bus session, a liveliness token ``<name>/alive``, a
:class:`~quadmanip.common.messages.Heartbeat` on ``<name>/heartbeat`` at 1 Hz carrying the
service state, and the lifecycle: ``starting`` → ``running`` → ``stopping`` on SIGTERM or
SIGINT. The stop is bounded: after the signal the process exits within ``STOP_BUDGET_S``
(2 s) whatever the service code does (signals are read from a wakeup fd by a dedicated
thread, and a watchdog ends a stuck process with exit code 1; a second signal ends it at once).

Inputs, outputs and actions are declared by naming rows of the key table
(:mod:`quadmanip.common.keys`), which alone gives each topic's message type and QoS kind
and each action's goal type. :meth:`Service.check_declarations` refuses a declaration that
is not in the table (``run_service`` calls it before anything starts), and
:meth:`Service.subscribe`, :meth:`Service.publisher` and :meth:`Service.action_server`
refuse what is not declared, so the declaration (``--describe`` prints it as JSON) is
always the true wiring diagram of the node.

Example (a test service whose topics come from an extended table)::

    @dataclass(frozen=True)
    class EchoConfig:
        gain: float = 1.0

    class Echo(Service):
        name = "echo"
        config_type = EchoConfig
        key_table = keys.TABLE.extended(
            (keys.row("echo", "clock", Clock, "event", "out", "echoed clock"),)
        )
        inputs = (Input("sim/clock"),)
        outputs = (Output("echo/clock"),)

        def setup(self) -> None:
            self.pub = self.publisher("echo/clock")
            self.subscribe("sim/clock", self.pub.publish)
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import logging
import os
import select
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Literal

from quadmanip.common import keys
from quadmanip.common.actions import ActionServer, GoalHandle
from quadmanip.common.bus import (
    Bus,
    BusConfig,
    LatestCache,
    TypedPublisher,
    TypedSubscriber,
    apply_env,
)
from quadmanip.common.config import (
    ConfigError,
    config_path,
    expand_overrides,
    from_dict,
    load_config,
)
from quadmanip.common.log import StructuredLogger, configure_logging, get_logger
from quadmanip.common.messages import Heartbeat
from quadmanip.common.scheduling import SchedulingConfig, SchedulingResult, ThreadScheduler
from quadmanip.common.schema import Message

__all__ = [
    "HEARTBEAT_PERIOD_S",
    "STOP_BUDGET_S",
    "Input",
    "Output",
    "Service",
    "run_service",
]

STOP_BUDGET_S = 2.0
"""Seconds from SIGTERM/SIGINT to process exit, guaranteed by a watchdog."""
HEARTBEAT_PERIOD_S = 1.0

State = Literal["starting", "running", "degraded", "stopping", "stopped", "failed"]


@dataclasses.dataclass(frozen=True)
class Input:
    """A declared subscription: a topic of the key table (or a wildcard over rows of one
    message type, such as ``*/heartbeat``), and whether only the newest sample matters."""

    topic: str
    latest_only: bool = False
    doc: str = ""


@dataclasses.dataclass(frozen=True)
class Output:
    """A declared publication: a topic of the key table (type and kind come from its row)."""

    topic: str
    doc: str = ""


@dataclasses.dataclass(frozen=True)
class _NoConfig:
    """Config of a service that has no parameters."""


class Service:
    """Base class of a service process; see the module docstring for the pattern."""

    name: ClassVar[str] = ""
    config_type: ClassVar[type] = _NoConfig
    # configs/<config_name>.toml; None → the service name; the file is optional only for
    # a config dataclass whose fields all have defaults.
    config_name: ClassVar[str | None] = None
    inputs: ClassVar[Sequence[Input]] = ()
    outputs: ClassVar[Sequence[Output]] = ()
    actions: ClassVar[Sequence[str]] = ()  # actions served: "<name>/action/<action>" rows
    # The table the declarations name rows of; only tests and benchmarks extend it.
    key_table: ClassVar[keys.KeyTable] = keys.TABLE
    # If set, the default run() calls step() at this period (seconds, wall clock).
    loop_period: ClassVar[float | None] = None

    def __init__(self, bus: Bus, config: Any, args: argparse.Namespace | None = None) -> None:
        self.bus = bus
        self.config = config
        self.args = args
        self.log: StructuredLogger = get_logger(self.name or type(self).__name__)
        self.stop_event = threading.Event()
        self._state: State = "starting"
        self.step_errors = 0
        # What the runtime achieved of scheduling() (None: not applied, or not asked for).
        self.scheduling_result: SchedulingResult | None = None

    # --- declarations ------------------------------------------------------------
    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Override to add service-specific command-line flags."""

    @classmethod
    def check_declarations(cls) -> None:
        """Raise ``ValueError`` naming every declared input, output or action that is not a
        row of :attr:`key_table` (``run_service`` calls this before anything starts)."""
        problems = []
        try:
            cls.key_table.topic(f"{cls.name}/heartbeat")
        except KeyError as exc:
            problems.append(f"heartbeat: {exc}")
        for inp in cls.inputs:
            try:
                cls.key_table.message_type(inp.topic)
            except KeyError as exc:
                problems.append(f"input: {exc}")
        for out in cls.outputs:
            try:
                cls.key_table.topic(out.topic)
            except KeyError as exc:
                problems.append(f"output: {exc}")
            if "*" in out.topic:
                problems.append(f"output {out.topic!r}: a publication names one topic")
        for action in cls.actions:
            try:
                cls.key_table.action(cls.name, action)
            except KeyError as exc:
                problems.append(f"action: {exc}")
        if problems:
            raise ValueError(f"service {cls.name!r} declares what the key table lacks: {problems}")

    @classmethod
    def describe(cls) -> dict[str, Any]:
        """Inputs, outputs and actions as plain data (``--describe``), types and kinds as
        the key table gives them."""
        table = cls.key_table

        def schema(t: type[Message]) -> str:
            version = getattr(t, "VERSION", "?")
            if isinstance(version, tuple):
                version = ".".join(map(str, version))
            return f"{getattr(t, 'SCHEMA', t.__name__)}/{version}"

        return {
            "service": cls.name,
            "config": cls.config_type.__name__,
            "inputs": [
                {
                    "topic": i.topic,
                    "type": schema(table.message_type(i.topic)),
                    "latest_only": i.latest_only,
                    "doc": i.doc,
                }
                for i in cls.inputs
            ],
            "outputs": [
                {
                    "topic": o.topic,
                    "type": schema(table.topic(o.topic).msg_type),
                    "kind": table.topic(o.topic).kind,
                    "doc": o.doc,
                }
                for o in cls.outputs
            ],
            "actions": [
                {
                    "action": table.action(cls.name, a).name,
                    "goal": schema(table.action(cls.name, a).goal_type),
                }
                for a in cls.actions
            ],
            "heartbeat": f"{cls.name}/heartbeat",
            "liveliness": f"{cls.name}/alive",
        }

    # --- wiring helpers (only declared topics) -----------------------------------
    def _declared(self, items: Sequence[Any], topic: str, what: str) -> Any:
        for item in items:
            if item.topic == topic:
                return item
        known = ", ".join(i.topic for i in items) or "none"
        raise KeyError(f"{self.name}: {what} {topic!r} is not declared (declared: {known})")

    def publisher(self, topic: str) -> TypedPublisher[Any]:
        """A publisher for a declared output (type and QoS from the key table)."""
        self._declared(self.outputs, topic, "output")
        return self.bus.publisher(topic)

    def subscribe(
        self, topic: str, callback: Callable[[Any], Any], *, latest_only: bool | None = None
    ) -> TypedSubscriber[Any]:
        """Subscribe to a declared input (type from the key table, delivery from the
        declaration)."""
        inp = self._declared(self.inputs, topic, "input")
        lo = inp.latest_only if latest_only is None else latest_only
        return self.bus.subscribe(topic, callback, latest_only=lo)

    def latest(self, topic: str) -> LatestCache[Any]:
        """A latest-only cache of a declared input."""
        self._declared(self.inputs, topic, "input")
        return self.bus.latest(topic)

    def action_server(
        self,
        action: str,
        execute: Callable[[GoalHandle], Message | None],
        *,
        accept: Callable[[Message], tuple[bool, str]] | None = None,
        policy: Literal["reject", "preempt", "parallel"] = "reject",
    ) -> ActionServer:
        """Serve a declared action ``<name>/action/<action>`` (goal type from the table)."""
        if action not in self.actions:
            known = ", ".join(self.actions) or "none"
            raise KeyError(f"{self.name}: action {action!r} is not declared (declared: {known})")
        return self.bus.action_server(self.name, action, execute, accept=accept, policy=policy)

    # --- scheduling ----------------------------------------------------------------
    def scheduling(self) -> SchedulingConfig | None:
        """The scheduling policy of this process's threads (common/scheduling.py): the
        config's ``scheduling`` table if it has one. Override to decide at run time (the
        sim asks for real-time priority only in realtime mode)."""
        cfg = getattr(self.config, "scheduling", None)
        return cfg if isinstance(cfg, SchedulingConfig) else None

    # --- lifecycle (override these) ------------------------------------------------
    def setup(self) -> None:
        """Declare publishers, subscribers and action servers; load models."""

    def step(self) -> None:
        """One iteration of the periodic loop (when ``loop_period`` is set)."""

    def run(self) -> None:
        """Run until :attr:`stop_event` is set. Default: call :meth:`step` periodically
        (drift-free schedule) or just wait; an exception in step is logged (throttled),
        counted, and the loop goes on."""
        period = self.loop_period
        if period is None:
            while not self.stop_event.wait(0.5):
                pass
            return
        next_t = time.monotonic()
        while not self.stop_event.is_set():
            try:
                self.step()
            except Exception as exc:  # noqa: BLE001 - keep the service alive, say why
                self.step_errors += 1
                self.log.throttled(
                    "step",
                    1.0,
                    logging.ERROR,
                    "step raised",
                    error=repr(exc),
                    errors=self.step_errors,
                    exc_info=True,
                )
            next_t += period
            delay = next_t - time.monotonic()
            if delay < -period:  # fell far behind: skip missed ticks instead of bursting
                next_t = time.monotonic()
                delay = 0.0
            if delay > 0 and self.stop_event.wait(delay):
                break

    def teardown(self) -> None:
        """Release resources (the bus is closed afterwards by the runtime)."""

    # --- state -----------------------------------------------------------------
    @property
    def state(self) -> str:
        return self._state

    def set_state(self, state: str) -> None:
        """Set the state reported in heartbeats (e.g. ``degraded`` with a reason in logs)."""
        self._state = state  # type: ignore[assignment]

    @property
    def stopping(self) -> bool:
        return self.stop_event.is_set()


# --------------------------------------------------------------------------- runtime


def _parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``key=value`` pairs, value parsed as a TOML value (bare words become strings)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects key=value, got {item!r}")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out[key.strip()] = value
    return out


def _load_service_config(cls: type[Service], name: str | None, overrides: dict[str, Any]) -> Any:
    """``--config`` if given, else ``configs/<config_name or name>.toml`` if it exists, else
    the dataclass defaults; ``--set`` overrides apply in every case."""
    if name is not None:
        return load_config(cls.config_type, name, overrides)
    path = config_path(cls.config_name or cls.name)
    if path.is_file():
        return load_config(cls.config_type, path, overrides)
    return from_dict(cls.config_type, expand_overrides(overrides), source=f"{cls.name} defaults")


class _Heartbeat:
    def __init__(self, service: Service, period: float) -> None:
        self._svc = service
        self._period = period
        self._stop = threading.Event()
        self._pub = service.bus.publisher(f"{service.name}/heartbeat")
        self._seq = 0
        self.scheduler: ThreadScheduler | None = None
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def beat(self) -> None:
        try:
            self._pub.publish(
                Heartbeat(
                    stamp=self._svc.bus.clock(),
                    service=self._svc.name,
                    seq=self._seq,
                    state=self._svc.state[:64],
                )
            )
            self._seq += 1
        except Exception as exc:  # noqa: BLE001 - a closing session must not crash us
            self._svc.log.throttled(
                "heartbeat", 5.0, logging.WARNING, "heartbeat failed", error=repr(exc)
            )

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.beat()
            if self.scheduler is not None:
                self.scheduler.apply()  # threads Zenoh started since the last beat
            self._stop.wait(self._period)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(0.2)


def _apply_scheduling(svc: Service, heartbeat: _Heartbeat, log: StructuredLogger) -> None:
    """Give the service's threads its scheduling policy after setup (its Zenoh threads
    exist by then); the heartbeat covers threads started later. Logged either way: a
    control loop without real-time priority must say so."""
    cfg = svc.scheduling()
    if cfg is None or (cfg.policy == "normal" and not cfg.cpus):
        return
    if cfg.policy != "normal":
        # A deadline loop must not stop for a full garbage collection: move everything
        # built during setup (models, imports) out of the collector's view, so a
        # collection only scans what the loop itself allocates.
        gc.collect()
        gc.freeze()
    sched = ThreadScheduler(cfg)
    res = sched.apply()
    svc.scheduling_result = sched.result
    heartbeat.scheduler = sched
    if res is None:
        return
    if res.realtime:
        log.info("scheduling", applied=res.summary())
    else:
        log.warning("no real-time priority", applied=res.summary(), why="; ".join(res.reasons))


def _exit_soon(code: int, delay: float = 0.5) -> None:
    time.sleep(delay)
    logging.shutdown()
    os._exit(code)


def build_parser(cls: type[Service]) -> argparse.ArgumentParser:
    """The command-line parser every service shares (plus its own ``add_arguments``)."""
    p = argparse.ArgumentParser(
        prog=f"quadmanip service {cls.name}",
        description=(cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else None,
    )
    p.add_argument(
        "--config", help=f"config name or path (default configs/{cls.config_name or cls.name}.toml)"
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value (dotted key, TOML value); repeatable",
    )
    p.add_argument("--bus-config", default="bus", help="bus config name or path")
    p.add_argument("--connect", help="comma-separated Zenoh endpoints (like QM_ZENOH_CONNECT)")
    p.add_argument("--mode", choices=("peer", "client"), help="Zenoh session mode")
    p.add_argument(
        "--robot", default=os.environ.get("QM_ROBOT", keys.DEFAULT_ROBOT), help="robot name"
    )
    p.add_argument("--log-level", help="DEBUG, INFO, WARNING (default QM_LOG_LEVEL or INFO)")
    p.add_argument(
        "--describe", action="store_true", help="print the declared inputs/outputs as JSON and exit"
    )
    cls.add_arguments(p)
    return p


def run_service(
    cls: type[Service],
    argv: Sequence[str] | None = None,
    *,
    bus_config: BusConfig | None = None,
    install_signals: bool = True,
) -> int:
    """Run service ``cls`` as this process's main job; returns the exit code.

    0: stopped on request; 1: failed (exception in setup/run, or a stop that overran the
    budget); 2: bad command line or config.
    """
    if not cls.name:
        raise TypeError(f"{cls.__name__}.name is empty")
    parser = build_parser(cls)
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    configure_logging(cls.name, level=args.log_level)
    log = get_logger(f"{cls.name}.runtime")
    try:
        cls.check_declarations()
    except ValueError as exc:
        log.error("declaration does not match the key table", error=str(exc))
        return 2
    if args.describe:
        print(json.dumps(cls.describe(), indent=2))
        return 0
    try:
        config = _load_service_config(cls, args.config, _parse_set(args.set))
        if bus_config is None:
            bus_config = apply_env(load_config(BusConfig, args.bus_config))
        changes: dict[str, Any] = {}
        if args.connect:
            changes["connect"] = tuple(e.strip() for e in args.connect.split(",") if e.strip())
        if args.mode:
            changes["mode"] = args.mode
        if changes:
            bus_config = dataclasses.replace(bus_config, **changes)
    except (ConfigError, ValueError) as exc:
        log.error("bad configuration", error=str(exc))
        return 2

    stop_event = threading.Event()
    stop_requested_at: list[float] = []

    def _watchdog() -> None:
        time.sleep(STOP_BUDGET_S - 0.1)
        log.error("stop overran its budget; exiting hard", budget_s=STOP_BUDGET_S)
        logging.shutdown()
        os._exit(1)

    stop_lock = threading.Lock()

    def _request_stop(signum: int) -> None:
        with stop_lock:
            if stop_requested_at:  # second signal: the user means it
                os._exit(1)
            stop_requested_at.append(time.monotonic())
        log.info("stop requested", signal=signal.Signals(signum).name)
        threading.Thread(target=_watchdog, name="stop-watchdog", daemon=True).start()
        stop_event.set()
        svc_ref = holder.get("svc")
        if svc_ref is not None:
            svc_ref.stop_event.set()

    def _ignore(_signum: int, _frame: object) -> None:
        """The Python-level handler: a no-op, the wakeup-fd thread does the work."""

    def _signal_loop(fd: int) -> None:
        while True:
            try:
                select.select([fd], [], [])
                data = os.read(fd, 64)
            except OSError:
                return
            for signum in data:
                _request_stop(signum)

    # Python runs signal handlers only in the main thread, between bytecodes: a main
    # thread stuck in a long C call (a model compile) would delay the stop, watchdog
    # included. The C-level handler, though, writes each signal number to the wakeup fd
    # from whichever thread the kernel picked, without the GIL; a dedicated thread reads
    # it and requests the stop, so the bounded stop holds whatever the main thread does.
    holder: dict[str, Service] = {}
    previous: dict[int, Any] = {}
    previous_wakeup: int | None = None
    wake_r = wake_w = -1
    if install_signals and threading.current_thread() is threading.main_thread():
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_w, False)
        previous_wakeup = signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, _ignore)
        threading.Thread(target=_signal_loop, args=(wake_r,), name="signals", daemon=True).start()

    code = 0
    bus: Bus | None = None
    heartbeat: _Heartbeat | None = None
    svc: Service | None = None
    try:
        bus = Bus(bus_config, robot=args.robot, table=cls.key_table)
        # Follow robot time unless this service is the clock's source (the sim stamps with
        # its own engine time).
        if bus_config.robot_clock and all(o.topic != bus_config.robot_clock for o in cls.outputs):
            bus.follow_clock(bus_config.robot_clock)
        svc = cls(bus, config, args)
        holder["svc"] = svc
        if stop_event.is_set():
            svc.stop_event.set()
        bus.declare_alive(cls.name)
        heartbeat = _Heartbeat(svc, HEARTBEAT_PERIOD_S)
        heartbeat.start()
        log.info(
            "starting", robot=args.robot, mode=bus_config.mode, connect=",".join(bus_config.connect)
        )
        svc.setup()
        _apply_scheduling(svc, heartbeat, log)
        if not svc.stop_event.is_set():
            if svc.state == "starting":
                svc.set_state("running")
            heartbeat.beat()
            log.info("running")
            svc.run()
    except Exception as exc:  # noqa: BLE001 - report, then stop cleanly
        code = 1
        log.error("service failed", error=repr(exc), exc_info=True)
        if svc is not None:
            svc.set_state("failed")
            if heartbeat is not None:
                heartbeat.beat()
    finally:
        if svc is not None:
            svc.stop_event.set()
            if code == 0:
                svc.set_state("stopping")
            try:
                svc.teardown()
            except Exception as exc:  # noqa: BLE001
                code = 1
                log.error("teardown failed", error=repr(exc), exc_info=True)
        if heartbeat is not None:
            heartbeat.stop()
        if bus is not None:
            t0 = stop_requested_at[0] if stop_requested_at else time.monotonic()
            budget = max(0.2, STOP_BUDGET_S - 0.3 - (time.monotonic() - t0))
            if not bus.close(timeout=min(budget, bus.config.close_timeout_s)) and install_signals:
                # A hung zenoh close also hangs interpreter exit (its callback thread is
                # not a daemon): make sure this process still ends, with its exit code.
                log.warning("bus close did not finish in time; forcing exit", code=code)
                threading.Thread(target=_exit_soon, args=(code,), daemon=True).start()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if previous_wakeup is not None:
            signal.set_wakeup_fd(previous_wakeup)
        elapsed = (time.monotonic() - stop_requested_at[0]) if stop_requested_at else None
        log.info("stopped", code=code, **({"stop_s": round(elapsed, 3)} if elapsed else {}))
    return code
