"""The acceptance trials' scenarios: deterministic, resting, free, in reach of the robot.

The trials themselves run over the full stack (tests/integration/test_manipulation_acceptance.py);
here the worlds they load are checked without starting a process.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.sim.scenarios import object_contacts
from quadmanip.sim.world import build_world, load_catalogue
from quadmanip.testbench import stack_trials as st

pytestmark = pytest.mark.unit

CAT = load_catalogue()


def _base_frame(world):
    d = world.initial_data()
    adr = rd.free_joint_qpos_index(world.model)
    q = d.qpos[adr : adr + 7]
    yaw = 2 * math.atan2(q[6], q[3])
    return d, q[:2], yaw


def _ahead_of_robot(scn):
    """The object's (forward, lateral) offset in the robot's start frame."""
    x, y, yaw_deg = scn.robot_start
    (p,) = scn.objects
    h = math.radians(yaw_deg)
    dx, dy = p.position[0] - x, p.position[1] - y
    return math.cos(h) * dx + math.sin(h) * dy, -math.sin(h) * dx + math.cos(h) * dy


@pytest.mark.parametrize("where", ["floor", "table"])
@pytest.mark.parametrize("name", CAT.names)
def test_grasp_scenarios_put_the_object_at_rest_in_front_of_the_robot(name, where):
    scn = st.grasp_scenario(name, where, seed=1)
    assert scn == st.grasp_scenario(name, where, seed=1)
    assert scn != st.grasp_scenario(name, where, seed=2)
    fwd, lat = _ahead_of_robot(scn)
    assert st.AHEAD[0] <= fwd <= st.AHEAD[1] and abs(lat) <= st.LATERAL
    world = build_world(scn)
    data, xy, yaw = _base_frame(world)
    assert xy == pytest.approx(scn.robot_start[:2])
    assert math.degrees(yaw) == pytest.approx(scn.robot_start[2])
    assert object_contacts(world.model, data) == []  # touches nothing, robot included
    oid = world.object_body_ids[name]
    start = data.xpos[oid].copy()
    for _ in range(300):
        mujoco.mj_step(world.model, data)
    assert np.linalg.norm(data.xpos[oid] - start) < 0.01  # resting, not falling


def test_table_objects_lie_on_the_table_and_tall_ones_are_grasped_sideways():
    table = next(t for t in build_world(None, robot=False).house.tables if t.name == "living_table")
    for name in CAT.names:
        (p,) = st.grasp_scenario(name, "table", seed=0).objects
        assert p.surface == "living_table"
        assert p.position[2] == pytest.approx(table.height + CAT.objects[name].size[2] / 2 + 0.001)
    assert st.approach_for(CAT, "cracker_box", "table") == "horizontal"
    assert st.approach_for(CAT, "cracker_box", "floor") == "vertical"
    assert st.approach_for(CAT, "mug", "table") == "vertical"


@pytest.mark.parametrize("name", CAT.names)
def test_place_scenarios_are_free(name):
    scn = st.place_scenario(name, seed=0)
    world = build_world(scn)
    data, _, _ = _base_frame(world)
    assert object_contacts(world.model, data) == []


@pytest.mark.parametrize("which", ["left", "right", "top"])
def test_drawer_scenarios_square_the_robot_to_the_handle(which):
    scn = st.drawer_scenario(which)
    world = build_world(scn)
    data, xy, yaw = _base_frame(world)
    handle = data.body(world.drawer_handles[which]).xpos
    fwd = math.cos(yaw) * (handle[0] - xy[0]) + math.sin(yaw) * (handle[1] - xy[1])
    lat = -math.sin(yaw) * (handle[0] - xy[0]) + math.cos(yaw) * (handle[1] - xy[1])
    assert fwd == pytest.approx(st.HANDLE_STANDOFF, abs=1e-6)
    assert lat == pytest.approx(0.0, abs=1e-6)


def test_unknown_inputs_are_errors():
    with pytest.raises(ValueError, match="floor"):
        st.grasp_scenario("mug", "shelf", 0)
    with pytest.raises(ValueError, match="no drawer"):
        st.drawer_scenario("bottom")
