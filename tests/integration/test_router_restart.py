"""A router restarted mid-run: services in other processes resume without a restart.

Publisher and subscriber are separate ``run_service`` processes. In ``client`` mode all
their traffic goes through the router, so killing it (SIGKILL) stops the flow; a new
router on the same port must be rejoined by both (the bus retries its connect endpoint
every ``reconnect_period_ms``) and the counter must flow again within 10 s. In ``peer``
mode the two processes also hold a direct link, so the flow must not stop at all, and
after the restart a newcomer that only talks through the router (a client) must reach
the old publisher, which proves it re-registered with the new router.
"""

from __future__ import annotations

import queue
import re
import time

import pytest
import qm_examples
import qm_keys

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]

COUNTER = str(qm_examples.__file__).replace("qm_examples.py", "counter.py")
RESUME_LIMIT_S = 10.0


def _last_value(child) -> int:
    for line in reversed(child.lines):
        m = re.match(r"got (\d+)$", line)
        if m:
            return int(m.group(1))
    return -1


def test_client_mode_publisher_and_subscriber_resume_after_router_restart(router_factory, spawn):
    router = router_factory()
    pub = spawn(COUNTER, "pub", "--mode", "client", endpoint=router.endpoint)
    sub = spawn(COUNTER, "sub", "--mode", "client", endpoint=router.endpoint)
    assert sub.wait_for(r"^got \d+", 30), sub.output() + pub.output()

    router.kill()
    time.sleep(0.5)
    before = _last_value(sub)  # anything still in flight has landed by now
    n_lines = len(sub.lines)
    time.sleep(0.5)
    assert _last_value(sub) == before, "data flowed without a router in client mode"

    t_restart = time.monotonic()
    router_factory(router.port)
    m = sub.wait_for(r"^got \d+", RESUME_LIMIT_S, start=n_lines)
    assert m, f"no data {RESUME_LIMIT_S}s after restart\n{sub.output()[-1500:]}"
    resumed_after = time.monotonic() - t_restart
    assert int(m.group(0).split()[1]) > before  # new data from the same publisher process
    assert pub.proc.poll() is None and sub.proc.poll() is None
    assert resumed_after < RESUME_LIMIT_S
    print(f"client-mode flow resumed {resumed_after:.2f} s after the router restart")


def test_peer_mode_flow_survives_and_peers_rejoin_a_restarted_router(
    router_factory, spawn, bus_factory
):
    router = router_factory()
    pub = spawn(COUNTER, "pub", "--mode", "peer", endpoint=router.endpoint)
    sub = spawn(COUNTER, "sub", "--mode", "peer", endpoint=router.endpoint)
    assert sub.wait_for(r"^got \d+", 30), sub.output() + pub.output()

    router.kill()
    n_lines = len(sub.lines)
    assert sub.wait_for(r"^got \d+", 2.0, start=n_lines), "peer link died with the router"

    router_factory(router.port)
    late = bus_factory(router.endpoint, mode="client", table=qm_keys.TABLE)
    got: queue.Queue = queue.Queue()
    late.subscribe("test/counter", got.put)
    msg = got.get(timeout=RESUME_LIMIT_S)
    assert msg.stamp > 0
