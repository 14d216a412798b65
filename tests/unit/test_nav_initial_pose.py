"""Pose hints (``navigation/initial_pose``): navigation re-initialises its particle filter
around a hint when it is not localised or disagrees strongly with it, and the behavior
service sends one when navigation comes back after a restart.

The filter runs on the real house's floor plan with synthetic scans, as in
test_nav_localization.py; the node and the behavior's :class:`PoseHint` are driven
without Zenoh.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common.keys import topic
from quadmanip.common.rotations import quat_from_yaw
from quadmanip.services.behavior.node import HINT_EVERY_S, HINT_TRIES, BehaviorNode, PoseHint
from quadmanip.services.navigation.amcl import ParticleFilter
from quadmanip.services.navigation.config import NavigationConfig
from quadmanip.services.navigation.grid import compose, invert
from quadmanip.services.navigation.node import NavigationNode

from tests.unit.test_nav_localization import RASTER, errors, make_house, scan_at, true_walk

pytestmark = pytest.mark.unit

START_STD = (0.1, 0.1, math.radians(5.0))  # navigation's configured initial_std


@pytest.fixture(scope="module")
def house():
    return make_house()


@pytest.fixture(scope="module")
def truth():
    return true_walk()


def _track(pf: ParticleFilter, plan, mount, poses, odom0=(0.3, -0.2, 0.4), seed=0):
    """Walk the filter along ``poses`` with exact odometry (the odom frame at ``odom0``
    where the walk starts); the odometry of the last pose."""
    rng = np.random.default_rng(seed)
    o = odom0
    for i, p in enumerate(poses):
        if i:
            o = compose(o, compose(invert(poses[i - 1]), p))
        pf.predict(o)
        pf.update(scan_at(plan, mount, p, rng))
    return o


def test_a_restarted_filter_that_converged_on_its_start_pose_takes_the_hint(house, truth):
    """The restart case: the new filter starts at the configured start pose with a spread
    already below the convergence bound, so it says "converged" 3 m from the robot; the
    hint puts it back where the robot is, and the scans then pin it down."""
    plan, occ, mount = house
    here = truth[200]
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(1))
    pf.initialize(truth[0], START_STD)
    assert pf.converged  # converged on its prior, nowhere near the robot
    assert errors(pf.estimate()[0], here)[0] > 2.0
    hinted = (here[0] + 0.08, here[1] - 0.05, here[2] + math.radians(3.0))  # a bit off
    odom = (1.0, 2.0, 0.3)
    assert pf.hint(hinted, START_STD, odom) == "initialized"
    assert errors(pf.estimate()[0], hinted)[0] < 0.03  # at the hint, at once
    _track(pf, plan, mount, truth[200:240], odom0=odom, seed=2)
    e_xy, e_yaw = errors(pf.estimate()[0], truth[239])
    assert pf.converged and e_xy < 0.05 and e_yaw < math.radians(2.0)


def test_a_converged_filter_keeps_its_estimate_when_the_hint_agrees(house, truth):
    plan, occ, mount = house
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(3))
    pf.initialize(truth[0], (0.05, 0.05, 0.03))
    _track(pf, plan, mount, truth[:30], seed=4)
    assert pf.converged
    particles, weights = pf.particles.copy(), pf.weights.copy()
    before, _ = pf.estimate()
    near = (truth[29][0] + 0.2, truth[29][1] - 0.1, truth[29][2] + math.radians(10.0))
    assert pf.hint(near, START_STD) == "kept"
    np.testing.assert_array_equal(pf.particles, particles)
    np.testing.assert_array_equal(pf.weights, weights)
    assert pf.estimate()[0] == before
    # but one that disagrees strongly (here: the heading, 40 deg) re-initialises it
    turned = (truth[29][0], truth[29][1], truth[29][2] + math.radians(40.0))
    assert pf.hint(turned, START_STD) == "initialized"
    assert errors(pf.estimate()[0], turned)[1] < math.radians(2.0)


def test_a_filter_that_has_not_converged_takes_even_a_nearby_hint(house, truth):
    plan, occ, mount = house
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(5))
    pf.initialize_global()
    assert not pf.converged
    assert pf.hint(truth[0], (0.3, 0.3, 0.3)) == "initialized"
    assert pf.particle_count == RASTER.max_particles
    # a hint's spread wider than the convergence bound is honest doubt: converging
    assert not pf.converged
    _track(pf, plan, mount, truth[:40], seed=6)
    assert pf.converged and errors(pf.estimate()[0], truth[39])[0] < 0.05


def test_the_hint_stands_at_the_odometry_it_names(house, truth):
    """After a hint at odometry O1, a move to O2 too small for a filter step carries the
    estimate by O1^-1 O2 (not by the motion since the last filter step)."""
    plan, occ, mount = house
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(7))
    pf.initialize_global()
    pf.predict((5.0, 5.0, 1.0))  # an old odometry pose, far from the one of the hint
    o1, o2 = (0.0, 0.0, 0.0), (0.03, 0.02, 0.05)
    assert pf.hint(truth[0], (0.05, 0.05, 0.03), o1) == "initialized"
    pf.predict(o2)
    e_xy, e_yaw = errors(pf.estimate()[0], compose(truth[0], compose(invert(o1), o2)))
    assert e_xy < 0.01 and e_yaw < 0.01


# ------------------------------------------------------------------ the navigation node


def _nav_node(house, mode: str = "localization") -> NavigationNode:
    """A navigation node's state without its bus: the filter converged on the start pose."""
    plan, occ, _ = house
    node = NavigationNode.__new__(NavigationNode)
    node.config = NavigationConfig()
    node.log = SimpleNamespace(info=lambda *a, **k: None)
    node.map_to_odom = (0.0, 0.0, 0.0)
    node.status = "localized"
    node.amcl = None
    if mode == "localization":
        node.amcl = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(8))
        node.amcl.initialize((0.8, 1.2, 0.0), START_STD)
    return node


def test_the_node_relocalises_on_a_hint_and_publishes_the_new_map_to_odom(house):
    node = _nav_node(house)
    odom = (0.5, 0.5, 0.5)
    hint = m.InitialPose(stamp=100.0, x=6.0, y=1.5, yaw=1.0, std_xy=0.1, std_yaw=0.08)
    assert node.apply_hint(hint, odom, now=100.5) == "initialized"
    pose = compose(node.map_to_odom, odom)  # what navigation/pose will say
    assert errors(pose, (6.0, 1.5, 1.0))[0] < 0.03 and errors(pose, (6.0, 1.5, 1.0))[1] < 0.02
    assert node.status == "localized"
    # a stale hint (the robot may have walked since) and any hint in mapping mode: ignored
    old = hint.replace(stamp=90.0, x=2.0)
    assert node.apply_hint(old, odom, now=100.5).startswith("ignored")
    assert compose(node.map_to_odom, odom) == pose
    mapping = _nav_node(house, "mapping")
    assert mapping.apply_hint(hint, odom, now=100.5) == "ignored: mapping mode"
    assert mapping.map_to_odom == (0.0, 0.0, 0.0)


def test_the_key_is_a_command_to_navigation_that_behavior_sends():
    row = topic("navigation/initial_pose")
    assert row.msg_type is m.InitialPose and row.direction == "in"
    assert row.service == "navigation" and row.kind == "event"
    assert "navigation/initial_pose" in {i.topic for i in NavigationNode.inputs}
    assert "navigation/initial_pose" in {o.topic for o in BehaviorNode.outputs}


# ------------------------------------------------------------------ behavior: PoseHint


def _map_pose(x: float, y: float, yaw: float, m2o=(1.0, 0.0, math.pi / 2), status="localized"):
    return m.MapPose(stamp=0.0, x=x, y=y, yaw=yaw, covariance=np.diag([0.01**2, 0.01**2, 1e-4]),
                     map_to_odom=list(m2o), status=status)  # fmt: skip


def _odom(x: float, y: float, yaw: float) -> m.Odometry:
    return m.Odometry(stamp=0.0, position=[x, y, 0.27], orientation=quat_from_yaw(yaw),
                      linear_velocity=np.zeros(3), angular_velocity=np.zeros(3))  # fmt: skip


def test_behavior_hints_a_restarted_navigation_with_the_last_pose_carried_by_odometry():
    h = PoseHint()
    # navigation localised: base at odom (2, 1, 90 deg), map->odom (1, 0, 90 deg) -> map
    # (0, 2, 180 deg); nothing is sent while navigation runs on
    assert (
        h.update(0.0, 10.0, _map_pose(0.0, 2.0, math.pi), _odom(2.0, 1.0, math.pi / 2), 0) is None
    )
    # a converging pose (e.g. just after a global start) is not remembered
    assert h.update(0.1, 10.1, _map_pose(5.0, 5.0, 0.0, status="converging"), None, 0) is None
    # navigation dies; the robot shuffles 0.1 m forward in odom (+y) meanwhile
    assert h.update(1.0, 11.0, None, _odom(2.0, 1.1, math.pi / 2), 0) is None
    # it comes back and its new run says "localized" at the configured start pose
    start = _map_pose(0.8, 1.2, 0.0, m2o=(0.0, 0.0, 0.0))
    hint = h.update(2.0, 12.0, start, _odom(2.0, 1.1, math.pi / 2), 0, nav_restarted=True)
    assert isinstance(hint, m.InitialPose) and hint.stamp == 12.0
    # map (0, 2) carried 0.1 m along the heading (180 deg in the map): (-0.1, 2)
    assert hint.x == pytest.approx(-0.1, abs=1e-9) and hint.y == pytest.approx(2.0, abs=1e-9)
    assert abs(math.remainder(hint.yaw - math.pi, 2 * math.pi)) < 1e-9
    assert hint.std_xy == pytest.approx(0.1) and hint.std_yaw == pytest.approx(math.radians(5.0))
    # not again at once; again after HINT_EVERY_S while navigation still disagrees
    assert h.update(2.0 + HINT_EVERY_S / 2, 12.5, start, _odom(2.0, 1.1, math.pi / 2), 0) is None
    again = h.update(2.0 + HINT_EVERY_S, 13.0, start, _odom(2.0, 1.1, math.pi / 2), 0)
    assert again is not None and again.x == pytest.approx(hint.x)
    # navigation took it: no more hints, and its poses are remembered again
    took = _map_pose(-0.12, 2.01, math.pi, m2o=(1.1, 0.0, math.pi / 2))
    assert h.update(10.0, 20.0, took, _odom(2.0, 1.1, math.pi / 2), 0) is None
    assert not h.pending and h.last is not None and h.last[0] is took
    assert h.update(100.0, 90.0, took, _odom(2.0, 1.1, math.pi / 2), 0) is None


def test_behavior_gives_up_hinting_and_widens_the_doubt_after_locomotion_restarted():
    h = PoseHint()
    h.update(0.0, 10.0, _map_pose(0.0, 2.0, math.pi), _odom(2.0, 1.0, math.pi / 2), 0)
    # locomotion restarted too (outage count 1): its odometry started again at 0
    start = _map_pose(0.8, 1.2, 0.0, m2o=(0.0, 0.0, 0.0))
    sent = []
    for i in range(HINT_TRIES + 3):
        hint = h.update(1.0 + i * HINT_EVERY_S, 11.0 + i, start, _odom(0.0, 0.0, 0.0), 1,
                        nav_restarted=(i == 0))  # fmt: skip
        if hint is not None:
            sent.append(hint)
    assert len(sent) == HINT_TRIES and not h.pending  # then navigation owns the pose
    assert (sent[0].x, sent[0].y) == (0.0, 2.0)  # the pose as it was, not carried
    assert sent[0].std_xy == pytest.approx(0.25) and sent[0].std_yaw > math.radians(10.0)
    # a navigation that starts for the first time (no pose known) gets no hint
    fresh = PoseHint()
    assert fresh.update(0.0, 1.0, start, _odom(0.0, 0.0, 0.0), 0, nav_restarted=True) is None
    assert not fresh.pending
