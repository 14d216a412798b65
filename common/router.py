"""A Zenoh router run from the eclipse-zenoh Python package itself (no ``zenohd`` binary).

``quadmanip router --listen tcp/127.0.0.1:7447`` starts it. A Zenoh session opened in
``router`` mode *is* a router: it accepts client and peer links on its listen endpoints,
routes data between them and relays liveliness and discovery. Multicast scouting is off so
that two stacks on one LAN never join each other by accident; peers learn about each
other through the router (gossip), then link directly for the lowest latency.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Sequence

import zenoh
from quadmanip.common.bus import BusConfig, open_session, safe_close
from quadmanip.common.log import configure_logging, get_logger

__all__ = ["DEFAULT_LISTEN", "main", "router_bus_config", "run_router"]

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
log = get_logger("router")


def router_bus_config(listen: Sequence[str], base: BusConfig | None = None) -> BusConfig:
    """The :class:`BusConfig` of a router listening on ``listen`` (keeps ``base``'s tuning)."""
    base = base or BusConfig()
    return BusConfig(
        mode="router",
        connect=(),
        listen=tuple(listen),
        multicast_scouting=False,
        gossip=base.gossip,
        lease_ms=base.lease_ms,
        keep_alive=base.keep_alive,
        reconnect_period_ms=base.reconnect_period_ms,
        close_timeout_s=base.close_timeout_s,
        error_log_period_s=base.error_log_period_s,
        env_override=False,
    )


def run_router(
    listen: Sequence[str],
    stop_event: threading.Event,
    ready: threading.Event | None = None,
    base: BusConfig | None = None,
) -> None:
    """Run a router until ``stop_event`` is set; ``ready`` is set once it listens."""
    session: zenoh.Session = open_session(router_bus_config(listen, base))
    try:
        log.info("router listening", listen=",".join(listen), zid=str(session.zid()))
        if ready is not None:
            ready.set()
        while not stop_event.wait(0.5):
            pass
    finally:
        safe_close(session, timeout_s=(base or BusConfig()).close_timeout_s)
        log.info("router stopped")


def main(argv: list[str] | None = None) -> int:
    """``quadmanip router``: run a Zenoh router until SIGINT/SIGTERM."""
    parser = argparse.ArgumentParser(
        prog="quadmanip router",
        description="Run a Zenoh router (from the eclipse-zenoh package) for the quadmanip bus.",
    )
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default {DEFAULT_LISTEN})",
    )
    args = parser.parse_args(argv)
    configure_logging("router")
    listen = args.listen or [DEFAULT_LISTEN]
    stop = threading.Event()

    def _on_signal(signum: int, _frame: object) -> None:
        log.info("stopping", signal=signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    t0 = time.monotonic()
    try:
        run_router(listen, stop)
    except zenoh.ZError as exc:
        log.error("router failed", error=str(exc), after_s=round(time.monotonic() - t0, 3))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
