"""Test-only service ``relay``: echoes every message type back and serves a test action.

For each registered message type T it subscribes ``test/in/<slug>`` (typed T) and
republishes what it receives on ``test/out/<slug>``, so a test in another process can
check end-to-end delivery of every type. It prints one JSON line per change of its
decode-error counters (``{"errors": {key: n}}``) so a test can see malformed input being
counted while the service keeps running. It serves action ``relay/action/count``: goal
``Clock(stamp=N)`` → N feedbacks 50 ms apart → result ``Clock(stamp=N)``; cancelable.

Run: ``python tests/integration/helpers/relay.py [run_service flags]`` (not registered
in the service registry: it exists only for the tests).
"""

from __future__ import annotations

import json
import sys
import time

import qm_examples
import qm_keys
from quadmanip.common.actions import ActionFailed, GoalHandle
from quadmanip.common.messages import Clock
from quadmanip.common.schema import message_types
from quadmanip.common.service import Input, Output, Service, run_service


class Relay(Service):
    """Echo every message type (test helper)."""

    name = "relay"
    key_table = qm_keys.TABLE
    inputs = tuple(Input(f"test/in/{qm_examples.slug(t)}") for t in message_types())
    outputs = tuple(Output(f"test/out/{qm_examples.slug(t)}") for t in message_types())
    actions = ("count",)
    loop_period = 0.05

    def setup(self) -> None:
        for inp, out in zip(self.inputs, self.outputs, strict=True):
            pub = self.publisher(out.topic)
            self.subscribe(inp.topic, pub.publish)
        self.action_server("count", self._count, accept=self._accept)
        self._reported: dict[str, int] = {}
        print(json.dumps({"ready": True}), flush=True)

    @staticmethod
    def _accept(goal: Clock) -> tuple[bool, str]:
        if goal.stamp < 0:
            return False, "count must be >= 0"
        return True, ""

    @staticmethod
    def _count(handle: GoalHandle) -> Clock:
        n = int(handle.goal.stamp)
        if n == 13:
            raise ActionFailed("13 is unlucky")
        for i in range(n):
            handle.check_cancel()
            handle.feedback((i + 1) / n, f"{i + 1}/{n}")
            time.sleep(0.05)
        return Clock(stamp=float(n))

    def step(self) -> None:
        errors = {
            k: v["decode_errors"]
            for k, v in self.bus.stats.snapshot().items()
            if v["decode_errors"]
        }
        if errors != self._reported:
            self._reported = errors
            print(json.dumps({"errors": errors}), flush=True)


if __name__ == "__main__":
    sys.exit(run_service(Relay, sys.argv[1:]))
