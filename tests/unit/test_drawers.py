"""The cabinet's three drawers (paper Figure 20: left, right, top) slide open when their
handle is pulled and close again when pushed.

The pull and push are this test's disturbance: a force on the handle body through
``data.xfrc_applied``, set and cleared here only (the sim service's own disturbance channel
belongs to the sim engineer and acts on the robot base).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from quadmanip.sim.world import build_world

pytestmark = pytest.mark.unit

PULL_N = 20.0  # a firm one-hand pull


@pytest.fixture(scope="module")
def world():
    return build_world(None, robot=False)


def _outward(world, data, drawer: str) -> np.ndarray:
    """World direction in which the drawer opens (its slide axis)."""
    m = world.model
    j = m.joint(world.drawer_joints[drawer]).id
    return data.xaxis[j].copy()


def _run(world, data, handle_body: int, force: np.ndarray, seconds: float) -> None:
    test_disturbance = data.xfrc_applied  # the test's own, clearly named disturbance
    for _ in range(int(seconds / world.model.opt.timestep)):
        test_disturbance[handle_body, :3] = force
        mujoco.mj_step(world.model, data)
    test_disturbance[handle_body, :] = 0.0


def test_three_drawers_on_damped_limited_slides(world):
    m = world.model
    assert set(world.drawer_joints) == {"left", "right", "top"}
    for name, jname in world.drawer_joints.items():
        j = m.joint(jname).id
        assert m.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE
        assert m.jnt_limited[j]
        lo, hi = m.jnt_range[j]
        assert lo == 0.0 and 0.25 <= hi <= 0.35
        assert m.dof_damping[m.jnt_dofadr[j]] > 0
        mass = m.body_subtreemass[m.body(world.drawer_bodies[name]).id]
        assert 1.0 <= mass <= 4.0  # a small wooden drawer
    # Top drawer above the lower pair; left/right as seen facing the front.
    data = world.initial_data()
    z = {n: data.xpos[m.body(b).id][2] for n, b in world.drawer_bodies.items()}
    assert z["top"] > z["left"] + 0.15 and abs(z["left"] - z["right"]) < 1e-9
    out = _outward(world, data, "top")
    left = data.xpos[m.body(world.drawer_bodies["left"]).id]
    right = data.xpos[m.body(world.drawer_bodies["right"]).id]
    facing = -out  # a viewer in front of the cabinet looks against the outward axis
    viewer_left = np.cross([0.0, 0.0, 1.0], facing)
    assert np.dot(left - right, viewer_left) > 0.2


@pytest.mark.parametrize("drawer", ["left", "right", "top"])
def test_drawer_opens_when_pulled_and_closes_when_pushed(world, drawer):
    m = world.model
    data = world.initial_data()
    jadr = m.jnt_qposadr[m.joint(world.drawer_joints[drawer]).id]
    handle = m.body(world.drawer_handles[drawer]).id
    out = _outward(world, data, drawer)

    # Left alone (gravity only), a closed drawer stays closed.
    _run(world, data, handle, np.zeros(3), 0.3)
    assert abs(data.qpos[jadr]) < 1e-3

    _run(world, data, handle, PULL_N * out, 1.0)
    opened = data.qpos[jadr]
    assert opened >= 0.15, f"{drawer} opened only {opened:.3f} m"
    assert opened <= m.jnt_range[m.joint(world.drawer_joints[drawer]).id][1] + 0.005
    # The handle moved with the drawer, out of the cabinet.
    assert np.dot(data.xpos[handle] - world.initial_data().xpos[handle], out) >= 0.15

    # Damped: once let go, it stops within a moment and stays open.
    _run(world, data, handle, np.zeros(3), 0.5)
    assert abs(data.qvel[m.jnt_dofadr[m.joint(world.drawer_joints[drawer]).id]]) < 0.01
    assert data.qpos[jadr] > 0.15

    _run(world, data, handle, -PULL_N * out, 1.5)
    assert data.qpos[jadr] < 0.01, f"{drawer} did not close ({data.qpos[jadr]:.3f} m)"
