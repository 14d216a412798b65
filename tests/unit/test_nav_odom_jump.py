"""A restarted locomotion's odometry jumps to a new frame: navigation keeps the map pose."""

from __future__ import annotations

import math

import numpy as np
import pytest
from quadmanip.services.navigation.amcl import AmclConfig, ParticleFilter
from quadmanip.services.navigation.grid import GridGeometry, compose, invert
from quadmanip.services.navigation.odom_watch import OdomJumpConfig, odometry_jumped

pytestmark = pytest.mark.unit

CFG = OdomJumpConfig()


def test_walking_is_motion_a_new_frame_is_a_jump():
    # 0.6 m/s for 20 ms and a 0.05 rad turn: motion
    assert not odometry_jumped((1.0, 2.0, 0.3), 10.0, (1.012, 2.0, 0.35), 10.02, CFG)
    # a whole second without odometry while the legs were damped, then the new process's
    # origin: metres away
    assert odometry_jumped((3.4, 1.2, 1.1), 10.0, (0.0, 0.0, 0.0), 11.0, CFG)
    # near the old origin, only the heading gives it away
    assert odometry_jumped((0.1, 0.05, 2.5), 10.0, (0.0, 0.0, 0.0), 10.02, CFG)
    # a long gap does not excuse a long step: the robot lay still
    assert odometry_jumped((1.0, 1.0, 0.0), 0.0, (2.0, 1.0, 0.0), 30.0, CFG)


def _room() -> tuple[np.ndarray, GridGeometry]:
    """A 4 x 3 m room with a box in one corner (5 cm cells), occupancy 0/100."""
    geo = GridGeometry(0.05, 0.0, 0.0, 80, 60)
    grid = np.zeros((60, 80), dtype=np.int8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    grid[40:50, 60:70] = 100
    return grid, geo


def test_rebase_keeps_the_map_pose_and_counts_motion_from_the_new_frame():
    grid, geo = _room()
    pf = ParticleFilter(AmclConfig(), grid, geo)
    pf.initialize((1.5, 1.0, 0.2), (0.01, 0.01, 0.01))
    pf.predict((0.5, 0.2, 0.1))  # the old frame: stored
    pf.predict((0.8, 0.3, 0.15))  # moved 0.3 m in it
    before, _ = pf.estimate()
    pf.rebase((0.0, 0.0, 0.0))  # locomotion restarted: the new origin, the robot still
    after, _ = pf.estimate()
    assert math.dist(before[:2], after[:2]) < 0.02 and abs(before[2] - after[2]) < 0.02
    # a step of 0.4 m straight ahead in the new frame moves it 0.4 m along its heading
    pf.predict((0.4, 0.0, 0.0))
    moved, _ = pf.estimate()
    ahead = compose(after, (0.4, 0.0, 0.0))
    assert math.dist(moved[:2], ahead[:2]) < 0.05, (moved, ahead)
    # without the rebase the jump would have been taken for 0.85 m of motion
    assert math.dist(compose(invert((0.8, 0.3, 0.15)), (0.0, 0.0, 0.0))[:2], (0, 0)) > 0.8
