"""The quadmanip bus: typed publish/subscribe, actions and liveliness over Zenoh.

Every service talks to every other only through a :class:`Bus`. Keys follow
``qm/<robot>/<service>/<topic>``; methods take the relative ``<service>/<topic>`` part
(``"sim/lowstate"``) and add the prefix (a key that already starts with ``qm/`` is used
as is). Payloads are the msgpack encoding of :mod:`quadmanip.common.messages`.

The key table (:mod:`quadmanip.common.keys`) is the only wiring contract: a topic's
message type and kind (QoS) come from its row, so ``bus.publisher("sim/lowstate")`` needs
nothing else. A topic or action that is not in the table, or a message of another type,
is refused with :class:`~quadmanip.common.keys.UnknownKey` or ``TypeError``. Tests and
benchmarks with keys of their own pass ``Bus(table=keys.TABLE.extended(...))``.

Quality of service, by traffic kind (the ``kind`` column of the key table):

* ``"control"`` (leg/arm/gripper commands, velocity commands): reliable, congestion
  control BLOCK (a command is never silently dropped), priority REAL_TIME, express (not
  batched: lowest latency).
* ``"sensor"`` (state, images, scans): congestion control DROP (a stale frame is worth
  nothing), priority DATA, batched. Receivers should use ``latest_only=True`` or
  :meth:`Bus.latest` so a slow consumer never builds a queue.
* ``"event"`` (heartbeats, action feedback/results), and the key table's ``"gt"`` (ground
  truth) and ``"action"``: reliable, BLOCK, priority DATA_HIGH, batched.

Receiving is strict and robust: each sample is decoded with ``decode(data, expected=cls)``;
a :class:`~quadmanip.common.schema.MessageError` (or an exception in the user callback) is
counted per subscriber and in :attr:`Bus.stats`, logged at most once per second per key,
and the subscriber keeps running.

Sessions: ``mode`` peer (default: connects to the router, then links directly to other
peers it learns of by gossip), client (everything through the router; opening waits
until the router is reachable) or router.
Multicast scouting is off by default so two stacks on one network never merge by accident.
``QM_ZENOH_CONNECT`` (comma-separated endpoints), ``QM_ZENOH_LISTEN`` and ``QM_ZENOH_MODE``
override the file config (compose sets the first). The session retries its connect
endpoints forever (every ``reconnect_period_ms``), so a restarted router is rejoined
without restarting the service.

Shutdown: zenoh-python can hang in ``Session.close()`` (callbacks still running while
the session is torn down, reconnecting links). :meth:`Bus.close` therefore stops its own
worker threads, undeclares every entity, then closes the session, all in a daemon thread
it waits on for at most ``close_timeout_s`` (2 s); on timeout it logs and lets the
process exit anyway.

Actions (goal → accepted or rejected → feedback → result, cancelable) are in
:mod:`quadmanip.common.actions`; :meth:`Bus.action_server` and :meth:`Bus.action_client`
create them.
"""

from __future__ import annotations

import atexit
import dataclasses
import logging
import os
import threading
import time
import weakref
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, Generic, Literal, TypeVar

import zenoh
from quadmanip.common import keys
from quadmanip.common.config import load_config
from quadmanip.common.log import get_logger
from quadmanip.common.schema import Message, MessageError, decode, encode

if TYPE_CHECKING:
    from quadmanip.common.actions import ActionClient, ActionServer, GoalHandle

__all__ = [
    "Bus",
    "BusConfig",
    "LatestCache",
    "LivelinessWatcher",
    "TypedPublisher",
    "TypedSubscriber",
    "apply_env",
    "load_bus_config",
    "open_session",
    "safe_close",
    "zenoh_config",
]

log = get_logger("bus")
M = TypeVar("M", bound=Message)
Kind = Literal["control", "sensor", "event", "gt", "action"]

ENV_CONNECT = "QM_ZENOH_CONNECT"
ENV_LISTEN = "QM_ZENOH_LISTEN"
ENV_MODE = "QM_ZENOH_MODE"


# --------------------------------------------------------------------------- config


@dataclasses.dataclass(frozen=True)
class BusConfig:
    """How a process joins the bus (``configs/bus.toml``, overridable by environment)."""

    mode: Literal["peer", "client", "router"] = "peer"
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    # Where a peer (or router) accepts links; ignored by clients. An ephemeral port on all
    # IPv4 interfaces, so peers on other machines can link directly (Zenoh's own default,
    # tcp/[::]:0, fails in containers without IPv6). Empty: Zenoh's default.
    listen: tuple[str, ...] = ("tcp/0.0.0.0:0",)
    multicast_scouting: bool = False
    gossip: bool = True
    # A link silent for lease_ms is declared dead (SIGKILL closes the socket at once, so
    # this only matters for a vanished host or cable); keep_alive messages per lease.
    lease_ms: int = 3000
    keep_alive: int = 4
    reconnect_period_ms: int = 500
    close_timeout_s: float = 2.0
    error_log_period_s: float = 1.0
    # Whether QM_ZENOH_* environment variables may override this config.
    env_override: bool = True
    # Topic whose Clock stamps are robot time (the sim publishes sim time there; a hardware
    # adapter publishes wall time on the same key). Services stamp heartbeats with it.
    # Empty: stamp with wall time.
    robot_clock: str = "sim/clock"

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"mode must be peer, client or router, not {self.mode!r}")
        if self.mode == "client" and not self.connect:
            raise ValueError("a client needs at least one connect endpoint")
        if self.lease_ms < 100 or self.keep_alive < 1:
            raise ValueError("lease_ms must be >= 100 and keep_alive >= 1")
        if not 0.0 < self.close_timeout_s <= 10.0:
            raise ValueError("close_timeout_s must be in (0, 10]")


def _split_env(value: str) -> tuple[str, ...]:
    return tuple(p.strip() for p in value.split(",") if p.strip())


def apply_env(config: BusConfig, environ: dict[str, str] | None = None) -> BusConfig:
    """Apply ``QM_ZENOH_CONNECT`` / ``QM_ZENOH_LISTEN`` / ``QM_ZENOH_MODE`` overrides."""
    env = os.environ if environ is None else environ
    if not config.env_override:
        return config
    changes: dict[str, Any] = {}
    if env.get(ENV_CONNECT, "").strip():
        changes["connect"] = _split_env(env[ENV_CONNECT])
    if env.get(ENV_LISTEN, "").strip():
        changes["listen"] = _split_env(env[ENV_LISTEN])
    if env.get(ENV_MODE, "").strip():
        changes["mode"] = env[ENV_MODE].strip()
    return dataclasses.replace(config, **changes) if changes else config


def load_bus_config(
    name_or_path: str = "bus", overrides: dict[str, Any] | None = None
) -> BusConfig:
    """``configs/bus.toml`` (or another file) with the environment overrides applied."""
    return apply_env(load_config(BusConfig, name_or_path, overrides))


def zenoh_config(config: BusConfig) -> zenoh.Config:
    """Translate a :class:`BusConfig` to a ``zenoh.Config``."""
    zc = zenoh.Config()

    def put(key: str, value: Any) -> None:
        import json

        zc.insert_json5(key, json.dumps(value))

    put("mode", config.mode)
    put("connect/endpoints", list(config.connect))
    if config.listen and config.mode != "client":
        put("listen/endpoints", list(config.listen))
    put("scouting/multicast/enabled", config.multicast_scouting)
    put("scouting/gossip/enabled", config.gossip)
    put("transport/link/tx/lease", config.lease_ms)
    put("transport/link/tx/keep_alive", config.keep_alive)
    # Never give up on the router: retry forever at a fixed, short period, and do not
    # fail the process if the router is not up yet (start order must not matter).
    period = config.reconnect_period_ms
    put("connect/timeout_ms", -1)
    put("connect/exit_on_failure", False)
    put(
        "connect/retry",
        {"period_init_ms": period, "period_max_ms": period, "period_increase_factor": 1.0},
    )
    put(
        "listen/retry",
        {"period_init_ms": period, "period_max_ms": period, "period_increase_factor": 1.0},
    )
    if config.mode == "router":
        put("listen/timeout_ms", 0)
        put("listen/exit_on_failure", True)
    return zc


def open_session(config: BusConfig) -> zenoh.Session:
    """Open a Zenoh session for ``config`` (environment overrides are NOT applied here)."""
    return zenoh.open(zenoh_config(config))


def safe_close(
    session: zenoh.Session, timeout_s: float = 2.0, undeclare: Iterable[Any] = ()
) -> bool:
    """Undeclare ``undeclare`` then close ``session`` in a daemon thread, waiting ``timeout_s``.

    Returns True when the close finished in time. A hung close is abandoned (the thread is
    a daemon, so it does not keep the process alive).
    """
    items = list(undeclare)

    def _do() -> None:
        for item in items:
            try:
                item.undeclare()
            except Exception:  # noqa: BLE001 - best effort during shutdown
                pass
        try:
            session.close()
        except Exception:  # noqa: BLE001
            pass

    t = threading.Thread(target=_do, name="zenoh-close", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        log.warning("zenoh session close timed out; abandoning it", timeout_s=timeout_s)
        return False
    return True


# --------------------------------------------------------------------------- stats


@dataclasses.dataclass
class KeyStats:
    """Counters for one key on this bus."""

    published: int = 0
    received: int = 0
    decode_errors: int = 0
    callback_errors: int = 0
    dropped: int = 0  # latest-only: samples overwritten before the worker took them
    last_error: str = ""


class BusStats:
    """Thread-safe per-key counters; ``bus.stats.snapshot()`` returns plain dicts."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._keys: dict[str, KeyStats] = {}

    def _get(self, key: str) -> KeyStats:
        ks = self._keys.get(key)
        if ks is None:
            ks = self._keys[key] = KeyStats()
        return ks

    def add(self, key: str, field: str, n: int = 1, error: str | None = None) -> None:
        with self._lock:
            ks = self._get(key)
            setattr(ks, field, getattr(ks, field) + n)
            if error is not None:
                ks.last_error = error

    def key(self, key: str) -> KeyStats:
        with self._lock:
            return dataclasses.replace(self._get(key))

    @property
    def decode_errors(self) -> int:
        with self._lock:
            return sum(k.decode_errors for k in self._keys.values())

    def snapshot(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return {k: dataclasses.asdict(v) for k, v in self._keys.items()}


# --------------------------------------------------------------------------- pub/sub


_QOS: dict[str, dict[str, Any]] = {
    "control": {
        "congestion_control": zenoh.CongestionControl.BLOCK,
        "priority": zenoh.Priority.REAL_TIME,
        "express": True,
    },
    "sensor": {
        "congestion_control": zenoh.CongestionControl.DROP,
        "priority": zenoh.Priority.DATA,
        "express": False,
    },
    "event": {
        "congestion_control": zenoh.CongestionControl.BLOCK,
        "priority": zenoh.Priority.DATA_HIGH,
        "express": False,
    },
}


# Kind names of the key table (quadmanip.common.keys) that map onto the QoS above.
_QOS["gt"] = _QOS["event"]
_QOS["action"] = _QOS["event"]


class TypedPublisher(Generic[M]):
    """Publishes messages of one type on one key; see :meth:`Bus.publisher`."""

    def __init__(self, bus: Bus, key: str, msg_type: type[M], kind: Kind) -> None:
        if kind not in _QOS:
            raise ValueError(f"kind must be one of {sorted(_QOS)}, not {kind!r}")
        self.key = key
        self.msg_type = msg_type
        self.kind = kind
        self._bus = bus
        qos = dict(_QOS[kind])
        if kind != "sensor":
            qos["reliability"] = zenoh.Reliability.RELIABLE
        self._pub = bus.session.declare_publisher(key, **qos)
        self.count = 0

    def publish(self, msg: M) -> None:
        """Encode and send ``msg`` (must be an instance of the declared type)."""
        if not isinstance(msg, self.msg_type):
            raise TypeError(
                f"publisher on {self.key} sends {self.msg_type.__name__}, got {type(msg).__name__}"
            )
        self._pub.put(encode(msg))
        self.count += 1
        self._bus.stats.add(self.key, "published")

    put = publish

    def undeclare(self) -> None:
        try:
            self._pub.undeclare()
        except Exception:  # noqa: BLE001
            pass


def _decode_counted(bus: Bus, owner: Any, key: str, data: bytes) -> Any:
    """Decode ``data`` as ``owner.msg_type``. A ``MessageError`` is counted (on ``owner`` and
    in the bus stats), logged at most once per period per key, and gives None: a malformed
    payload never reaches a callback and never stops the stream."""
    try:
        return decode(data, expected=owner.msg_type)
    except MessageError as exc:
        owner.error_count += 1
        bus.stats.add(owner.key, "decode_errors", error=str(exc))
        log.throttled(
            f"decode:{owner.key}",
            bus.config.error_log_period_s,
            logging.WARNING,
            "dropped malformed message",
            key=key,
            expected=owner.msg_type.__name__,
            error=str(exc),
            errors=owner.error_count,
        )
        return None


class TypedSubscriber(Generic[M]):
    """Decodes samples on one key expression into ``msg_type``; see :meth:`Bus.subscribe`.

    ``latest_only``: the Zenoh callback only stores the newest raw payload; a worker thread
    decodes it and runs the user callback. Samples that arrive while the callback runs
    replace each other (counted as ``dropped_count``), so a slow consumer never queues.
    """

    def __init__(
        self,
        bus: Bus,
        key: str,
        msg_type: type[M],
        callback: Callable[[M], Any],
        latest_only: bool = False,
    ) -> None:
        self.key = key
        self.msg_type = msg_type
        self.latest_only = latest_only
        self.received_count = 0
        self.error_count = 0
        self.callback_error_count = 0
        self.dropped_count = 0
        self._bus = bus
        self._callback = callback
        self._stop = threading.Event()
        self._slot: tuple[str, bytes] | None = None
        self._slot_lock = threading.Lock()
        self._wake = threading.Event()
        self._worker: threading.Thread | None = None
        if latest_only:
            self._worker = threading.Thread(target=self._work, name=f"latest:{key}", daemon=True)
            self._worker.start()
            handler = self._on_sample_latest
        else:
            handler = self._on_sample
        self._sub = bus.session.declare_subscriber(key, handler)

    # Zenoh callbacks -------------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self._stop.is_set():
            return
        self._deliver(str(sample.key_expr), sample.payload.to_bytes())

    def _on_sample_latest(self, sample: zenoh.Sample) -> None:
        if self._stop.is_set():
            return
        item = (str(sample.key_expr), sample.payload.to_bytes())
        with self._slot_lock:
            if self._slot is not None:
                self.dropped_count += 1
                self._bus.stats.add(self.key, "dropped")
            self._slot = item
        self._wake.set()

    def _work(self) -> None:
        while not self._stop.is_set():
            if not self._wake.wait(0.2):
                continue
            with self._slot_lock:
                item, self._slot = self._slot, None
                self._wake.clear()
            if item is not None:
                self._deliver(*item)

    def _deliver(self, key: str, data: bytes) -> None:
        self.received_count += 1
        self._bus.stats.add(self.key, "received")
        msg = _decode_counted(self._bus, self, key, data)
        if msg is None:
            return
        try:
            self._callback(msg)
        except Exception as exc:  # noqa: BLE001 - a callback bug must not kill the stream
            self.callback_error_count += 1
            self._bus.stats.add(self.key, "callback_errors", error=repr(exc))
            log.throttled(
                f"callback:{self.key}",
                self._bus.config.error_log_period_s,
                logging.ERROR,
                "subscriber callback raised",
                key=key,
                error=repr(exc),
                exc_info=True,
            )

    def undeclare(self) -> None:
        self._stop.set()
        self._wake.set()
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001
            pass


class LatestCache(Generic[M]):
    """Keeps only the newest sample on a key; decodes lazily in :meth:`get`.

    The Zenoh callback stores raw bytes only, so a 10 Hz image stream costs nothing until
    someone reads it, and reading always gives the newest message.
    """

    def __init__(self, bus: Bus, key: str, msg_type: type[M]) -> None:
        self.key = key
        self.msg_type = msg_type
        self.error_count = 0
        self.received_count = 0
        self._bus = bus
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._raw: bytes | None = None
        self._seq = 0
        self._decoded_seq = 0
        self._msg: M | None = None
        self._received_at: float | None = None
        self._sub = bus.session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        with self._cond:
            self._raw = data
            self._seq += 1
            self.received_count += 1
            self._received_at = time.monotonic()
            self._cond.notify_all()
        self._bus.stats.add(self.key, "received")

    def get(self) -> M | None:
        """The newest valid message, or None if none arrived yet."""
        with self._lock:
            if self._seq != self._decoded_seq and self._raw is not None:
                raw, self._decoded_seq = self._raw, self._seq
                msg = _decode_counted(self._bus, self, self.key, raw)
                if msg is not None:
                    self._msg = msg
            return self._msg

    @property
    def age(self) -> float | None:
        """Seconds (monotonic) since the last sample arrived; None if never."""
        with self._lock:
            return None if self._received_at is None else time.monotonic() - self._received_at

    def wait_new(self, timeout: float) -> M | None:
        """Wait for a sample newer than the current one; returns it (None on timeout)."""
        with self._cond:
            seq = self._seq
            if not self._cond.wait_for(lambda: self._seq != seq, timeout):
                return None
        return self.get()

    def undeclare(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001
            pass


class LivelinessWatcher:
    """Calls ``callback(service, alive)`` when a service's token appears or disappears."""

    def __init__(self, bus: Bus, key: str, callback: Callable[[str, bool], Any]) -> None:
        self.key = key
        self._bus = bus
        self._callback = callback
        self._lock = threading.Lock()
        self.alive: set[str] = set()
        self._sub = bus.session.liveliness().declare_subscriber(key, self._on_sample, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        service = self._bus.service_of(str(sample.key_expr))
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            if alive:
                self.alive.add(service)
            else:
                self.alive.discard(service)
        try:
            self._callback(service, alive)
        except Exception as exc:  # noqa: BLE001
            log.error("liveliness callback raised", key=str(sample.key_expr), error=repr(exc))

    def undeclare(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001
            pass


# --------------------------------------------------------------------------- the bus


_open_buses: weakref.WeakSet[Bus] = weakref.WeakSet()


def _close_open_buses() -> None:
    """Close buses the program forgot to close: zenoh-python runs Python callbacks on a
    non-daemon thread, so an open session with a callback subscriber makes the interpreter
    wait forever at exit (eclipse-zenoh 1.x, zenoh-python issue 434)."""
    for bus in list(_open_buses):
        bus.close()


# Interpreter exit joins non-daemon threads *before* atexit handlers run, so a plain
# atexit hook would come too late; threading's own pre-join hook (used by
# concurrent.futures for the same reason) runs first. atexit stays as the fallback.
_register_pre_join = getattr(threading, "_register_atexit", None)
if callable(_register_pre_join):
    _register_pre_join(_close_open_buses)
else:  # pragma: no cover - other Python implementations
    atexit.register(_close_open_buses)


class Bus:
    """One Zenoh session of one process, with typed helpers; use as a context manager.

    ``Bus(config)`` uses the config as given; ``Bus()`` loads ``configs/bus.toml`` and the
    ``QM_ZENOH_*`` environment overrides. ``table`` is the key table it enforces (the
    product's :data:`~quadmanip.common.keys.TABLE` unless a test or benchmark extends it). ``clock`` stamps messages the bus creates itself
    (heartbeats, action envelopes): pass the robot clock (sim time) when you have one.
    """

    def __init__(
        self,
        config: BusConfig | None = None,
        robot: str = keys.DEFAULT_ROBOT,
        *,
        clock: Callable[[], float] | None = None,
        table: keys.KeyTable | None = None,
    ) -> None:
        self.config = config if config is not None else load_bus_config()
        self.table = table if table is not None else keys.TABLE
        self.robot = keys.validate_robot_name(robot)
        self.prefix = f"{keys.PREFIX}/{robot}/"
        self.clock: Callable[[], float] = clock or time.time
        self.stats = BusStats()
        self._entities: list[Any] = []
        self._lock = threading.Lock()
        self._closed = False
        self.session: zenoh.Session = open_session(self.config)
        _open_buses.add(self)
        log.debug(
            "bus open",
            mode=self.config.mode,
            connect=",".join(self.config.connect),
            zid=str(self.session.zid()),
        )

    # keys ------------------------------------------------------------------------
    def key(self, topic: str) -> str:
        """``"sim/lowstate"`` → ``"qm/dog1/sim/lowstate"`` (absolute ``qm/...`` kept)."""
        topic = topic.strip("/")
        return topic if topic.startswith("qm/") else self.prefix + topic

    def service_of(self, key: str) -> str:
        """The ``<service>`` part of a full key of this robot."""
        rest = key[len(self.prefix) :] if key.startswith(self.prefix) else key
        return rest.split("/", 1)[0]

    def _track(self, entity: Any) -> Any:
        with self._lock:
            if self._closed:
                raise RuntimeError("bus is closed")
            self._entities.append(entity)
        return entity

    # pub/sub ---------------------------------------------------------------------
    def _name(self, topic: str) -> str:
        """The table name of a relative or absolute (``qm/<robot>/...``) topic."""
        topic = topic.strip("/")
        return keys.parse_key(topic)[1] if topic.startswith(f"{keys.PREFIX}/") else topic

    def publisher(self, topic: str) -> TypedPublisher[Any]:
        """A publisher on ``topic``; message type and QoS kind come from its key-table row."""
        row = self.table.topic(self._name(topic))
        return self._track(TypedPublisher(self, self.key(topic), row.msg_type, row.kind))

    def subscribe(
        self,
        topic: str,
        callback: Callable[[Any], Any],
        *,
        latest_only: bool = False,
    ) -> TypedSubscriber[Any]:
        """Subscribe with a callback; ``topic`` may hold Zenoh wildcards (``*/heartbeat``)
        as long as every row it matches carries one message type.

        zenoh-python gives each subscriber its own callback thread, so subscribers never
        block each other; but samples of one subscriber queue up behind its slow callback.
        Use ``latest_only=True`` for sensor streams and for any callback that does real
        work: older samples are then dropped instead of queued.
        """
        msg_type = self.table.message_type(self._name(topic))
        return self._track(TypedSubscriber(self, self.key(topic), msg_type, callback, latest_only))

    def latest(self, topic: str) -> LatestCache[Any]:
        """A latest-only cache of ``topic``: ``cache.get()`` returns the newest message."""
        msg_type = self.table.message_type(self._name(topic))
        return self._track(LatestCache(self, self.key(topic), msg_type))

    def follow_clock(self, topic: str = "sim/clock") -> LatestCache[Any]:
        """Stamp this bus's own messages with robot time from ``topic`` (sim time in
        simulation): :attr:`clock` then returns the newest ``Clock`` stamp (0.0 until the
        first one). On hardware, where robot time is wall time, simply don't call it."""
        cache = self.latest(topic)

        def robot_time() -> float:
            msg = cache.get()
            return 0.0 if msg is None else float(msg.stamp)

        self.clock = robot_time
        return cache

    # liveliness ------------------------------------------------------------------
    def declare_alive(self, service: str) -> zenoh.LivelinessToken:
        """Declare the liveliness token ``<service>/alive``; it vanishes with the process."""
        token = self.session.liveliness().declare_token(keys.alive_key(self.robot, service))
        return self._track(token)

    def watch_liveliness(
        self, callback: Callable[[str, bool], Any], service: str = "*"
    ) -> LivelinessWatcher:
        """Watch ``<service>/alive`` tokens (``*``: all services); already-alive ones are
        reported at once."""
        return self._track(LivelinessWatcher(self, self.key(f"{service}/alive"), callback))

    def alive_services(self, timeout: float = 1.0) -> set[str]:
        """Services whose liveliness token is currently visible (a one-shot query)."""
        replies = self.session.liveliness().get(self.key("*/alive"), timeout=timeout)
        out = set()
        for reply in replies:
            if reply.ok is not None:
                out.add(self.service_of(str(reply.ok.key_expr)))
        return out

    # actions (quadmanip.common.actions) -----------------------------------------------
    def action_server(
        self,
        service: str,
        name: str,
        execute: Callable[[GoalHandle], Message | None],
        *,
        accept: Callable[[Message], tuple[bool, str]] | None = None,
        policy: Literal["reject", "preempt", "parallel"] = "reject",
    ) -> ActionServer:
        """Serve action ``<service>/action/<name>`` (a key-table row, which gives the goal
        type); see :class:`ActionServer`."""
        from quadmanip.common.actions import ActionServer

        goal_type = self.table.action(service, name).goal_type
        return self._track(ActionServer(self, service, name, goal_type, execute, accept, policy))

    def action_client(self, service: str, name: str) -> ActionClient:
        """A client of action ``<service>/action/<name>`` (a key-table row); see
        :class:`ActionClient`."""
        from quadmanip.common.actions import ActionClient

        goal_type = self.table.action(service, name).goal_type
        return self._track(ActionClient(self, service, name, goal_type))

    # lifecycle -------------------------------------------------------------------
    def close(self, timeout: float | None = None) -> bool:
        """Undeclare everything and close the session within ``timeout`` (default
        ``close_timeout_s``); True when the close completed."""
        with self._lock:
            if self._closed:
                return True
            self._closed = True
            _open_buses.discard(self)
            entities = list(reversed(self._entities))
            self._entities.clear()
        budget = self.config.close_timeout_s if timeout is None else timeout
        for e in entities:  # stop our own workers first: they must not touch a dead session
            stop = getattr(e, "stop", None)
            if callable(stop):
                try:
                    stop(min(0.3, budget / 4))
                except Exception:  # noqa: BLE001
                    pass
        return safe_close(self.session, budget, entities)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
