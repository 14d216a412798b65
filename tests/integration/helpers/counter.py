"""Test-only publisher/subscriber pair for the router-restart test.

``counter.py pub [flags]``: publishes ``Clock(stamp=i)`` (i = 0, 1, ...) every 20 ms on
``test/counter``. ``counter.py sub [flags]``: prints ``got <i>`` for each one received.
Both are full services (heartbeat, liveliness, SIGTERM) run by ``run_service``; pass
``--mode client`` to force all traffic through the router.
"""

from __future__ import annotations

import sys

import qm_keys
from quadmanip.common.messages import Clock
from quadmanip.common.service import Input, Output, Service, run_service


class CounterPub(Service):
    """Publish an increasing counter."""

    name = "counterpub"
    key_table = qm_keys.TABLE
    outputs = (Output("test/counter"),)
    loop_period = 0.02

    def setup(self) -> None:
        self.pub = self.publisher("test/counter")
        self.i = 0

    def step(self) -> None:
        self.pub.publish(Clock(stamp=float(self.i)))
        self.i += 1


class CounterSub(Service):
    """Print every counter value received."""

    name = "countersub"
    key_table = qm_keys.TABLE
    inputs = (Input("test/counter"),)

    def setup(self) -> None:
        self.subscribe("test/counter", lambda m: print(f"got {int(m.stamp)}", flush=True))


if __name__ == "__main__":
    role = sys.argv[1]
    cls = {"pub": CounterPub, "sub": CounterSub}[role]
    sys.exit(run_service(cls, sys.argv[2:]))
