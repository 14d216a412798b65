"""Navigation over the full stack: sim (lockstep, LiDAR on), locomotion and navigation as
separate processes on a private router, with the committed map of the house
(configs/maps/house.yaml). The test sends one ``navigate_to`` from the living room
through the doorway into the kitchen and judges the stop from ground truth."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.sim.scenarios import Scenario
from quadmanip.testbench.map_house import nav_stack

pytestmark = pytest.mark.integration

GOAL = (6.2, 2.2, 0.0)  # kitchen, past the doorway, facing east


def test_walks_from_the_living_room_into_the_kitchen():
    log = io.StringIO()
    with nav_stack(Scenario("empty", 0, ()), log, []) as s:
        assert s.bus is not None
        client = s.actions["navigate_to"]
        h = client.send_goal(m.NavigateGoal(stamp=s.now(), pose=np.array(GOAL)), timeout=10.0)
        assert h.accepted, h.reason
        res = None
        t0 = s.now()
        while res is None:
            s._check_alive()
            assert s.now() - t0 < 90.0, (
                "no result after 90 s of sim time\n" + log.getvalue()[-3000:]
            )
            res = h.result(timeout=1.0)
        assert res.status == "succeeded", (res.reason, log.getvalue()[-3000:])
        s.wait_sim(s.now() + 0.5)
        p, q = s.pose("base")
        err = math.hypot(p[0] - GOAL[0], p[1] - GOAL[1])
        yaw_err = abs(math.remainder(yaw_from_quat(q) - GOAL[2], 2 * math.pi))
        assert err <= 0.05 and yaw_err <= math.radians(3.0), (err, math.degrees(yaw_err))
        assert res.result.distance > 5.0
