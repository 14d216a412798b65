"""The judge says in_place for objects that physics dropped into their deposit region and
misplaced otherwise (paper Section 7.2 categories -> Figure 21 places)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from quadmanip.common.messages import JudgeReport
from quadmanip.common.schema import decode, encode
from quadmanip.sim.judge import judge_data, judge_poses
from quadmanip.sim.scenarios import Placement, Scenario
from quadmanip.sim.world import build_world

pytestmark = pytest.mark.unit

IDENT = (1.0, 0.0, 0.0, 0.0)


def _region(world, name):
    return next(r for r in world.regions if r.name == name)


def _above(world, region_name, dz):
    r = _region(world, region_name)
    return (r.center[0], r.center[1], r.center[2] + r.half_size[2] + dz)


@pytest.fixture(scope="module")
def dropped():
    """Tennis ball over the green box (right place), marker over the tray (wrong place),
    cracker box on the floor, padlock over the top drawer, which starts pulled open."""
    base = build_world(None, robot=False)
    data0 = base.initial_data()
    m0 = base.model
    # Where the open top drawer's region will be: its closed pose shifted by the travel.
    jid = m0.joint(base.drawer_joints["top"]).id
    travel = m0.jnt_range[jid][1]
    axis = data0.xaxis[jid]
    reg = _region(base, "drawer_top")
    bid = m0.body(reg.body).id
    centre = data0.xpos[bid] + data0.xmat[bid].reshape(3, 3) @ np.array(reg.center)
    # Over the drawer's front half, which is clear of the cabinet when open.
    over_drawer = centre + axis * (travel + 0.05) + [0, 0, reg.half_size[2] + 0.05]
    scenario = Scenario(
        "judge-test",
        0,
        (
            Placement("tennis_ball", "test", _above(base, "green_box", 0.05), IDENT),
            Placement("marker", "test", _above(base, "tray", 0.03), IDENT),
            Placement("cracker_box", "test", (2.0, 1.5, 0.106), IDENT),
            Placement("padlock", "test", tuple(over_drawer), IDENT),
        ),
    )
    world = build_world(scenario, robot=False)
    data = world.initial_data()
    # Test setup: the top drawer starts open (a scenario always starts with drawers closed).
    data.qpos[world.model.jnt_qposadr[jid]] = travel
    mujoco.mj_forward(world.model, data)
    early = judge_data(world, data)
    for _ in range(30):
        mujoco.mj_step(world.model, data)
    falling = judge_data(world, data)
    for _ in range(2000):
        mujoco.mj_step(world.model, data)
    return world, data, early, falling


def test_dropped_objects_judged_by_their_place(dropped):
    world, data, early, falling = dropped
    settled = judge_data(world, data)
    assert sorted(settled.in_place) == ["padlock", "tennis_ball"]
    assert sorted(settled.misplaced) == ["cracker_box", "marker"]
    assert settled.total == 4
    assert settled.trial_time == pytest.approx(data.time)
    # Before the drop, or while still falling, nothing counts.
    assert early.in_place == [] and falling.in_place == []
    # The marker did land inside the tray region: misplaced because it belongs elsewhere.
    marker = data.xpos[world.object_body_ids["marker"]]
    assert _region(world, "tray").contains_local(marker)


def test_drawer_region_moves_with_the_drawer(dropped):
    """Closing the drawer (pushing the handle: the test's disturbance) keeps the padlock in
    place; the world point where the drawer was open no longer is the drawer."""
    world, data, _, _ = dropped
    m = world.model
    handle = m.body(world.drawer_handles["top"]).id
    jid = m.joint(world.drawer_joints["top"]).id
    axis = data.xaxis[jid].copy()
    test_disturbance = data.xfrc_applied
    for _ in range(2000):
        test_disturbance[handle, :3] = -20.0 * axis
        mujoco.mj_step(m, data)
    test_disturbance[handle, :] = 0.0
    for _ in range(300):
        mujoco.mj_step(m, data)
    assert data.qpos[m.jnt_qposadr[jid]] < 0.01
    assert "padlock" in judge_data(world, data).in_place


def test_judge_from_pose_arrays_matches(dropped):
    world, data, _, _ = dropped
    m = world.model
    names = ["base"] + [f"obj/{n}" for n in world.object_names] + list(world.drawer_bodies.values())
    ids = (
        [0]
        + [world.object_body_ids[n] for n in world.object_names]
        + [m.body(b).id for b in world.drawer_bodies.values()]
    )
    place_of = {n: world.place_of(n) for n in world.object_names}
    res = judge_poses(
        world.regions, place_of, names, data.xpos[ids], data.xquat[ids], stamp=3.0, trial_time=2.5
    )
    ref = judge_data(world, data)
    assert sorted(res.in_place) == sorted(ref.in_place)
    assert sorted(res.misplaced) == sorted(ref.misplaced)
    assert res.total == 4
    # Fast-moving objects are not at rest.
    moving = judge_poses(
        world.regions, place_of, names, data.xpos[ids], data.xquat[ids], speeds=[1.0] * len(ids)
    )
    assert moving.in_place == []


def test_result_is_a_judge_report_message(dropped):
    world, data, _, _ = dropped
    msg = judge_data(world, data).to_message()
    assert isinstance(msg, JudgeReport)
    back = decode(encode(msg), JudgeReport)
    assert back.total == 4 and sorted(back.in_place) == ["padlock", "tennis_ball"]
