"""SLAM and localisation on scans recorded in the simulator (tests/data/nav_walk.npz).

The recording: the robot trotting through the living room, the doorway and the kitchen
and back (51 s of sim time, steered on ground truth by a test harness), every second
LiDAR scan (5 Hz) with the odometry locomotion estimated at its stamp and the true base
pose. Recorded with ``quadmanip.testbench.nav_record`` (fields documented there). Unlike
the synthetic scans of the other tests, these carry what the real stack produces: the
trunk's bobbing and tilt, the odometry's drift, returns off table legs and the cabinet.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.services.navigation.amcl import AmclConfig, ParticleFilter
from quadmanip.services.navigation.grid import compose, invert
from quadmanip.services.navigation.map_io import load_map
from quadmanip.services.navigation.node import resolve_map_path
from quadmanip.services.navigation.scan import lidar_mount, scan_points
from quadmanip.services.navigation.slam import OnlineSlam
from quadmanip.testbench.bench_navigation import map_scores
from quadmanip.testbench.floor_plan import true_floor_plan

pytestmark = pytest.mark.unit

DATA = Path(__file__).resolve().parents[1] / "data" / "nav_walk.npz"


@pytest.fixture(scope="module")
def walk() -> dict[str, np.ndarray]:
    return dict(np.load(DATA))


def _odom(d: dict[str, np.ndarray], i: int) -> tuple[float, float, float]:
    o = d["odom"][i]
    return (float(o[0]), float(o[1]), yaw_from_quat(o[3:7]))


def _scan(d: dict[str, np.ndarray], i: int):
    a0, da = d["angles"]
    return scan_points(d["stamp"][i], d["ranges"][i], a0, da, 0.1, 12.0, lidar_mount())


def test_slam_tracks_the_recorded_walk_and_maps_what_it_saw(walk):
    slam = OnlineSlam()
    gt = walk["gt"]
    err, odom_err = [], []
    world_T_map = None
    for i in range(len(walk["stamp"])):
        est = slam.update(_scan(walk, i), _odom(walk, i))
        if world_T_map is None:
            world_T_map = compose(tuple(gt[i, :3]), invert(est.pose))
        p = compose(world_T_map, est.pose)
        o = compose(world_T_map, _odom(walk, i))
        err.append(math.hypot(p[0] - gt[i, 0], p[1] - gt[i, 1]))
        odom_err.append(math.hypot(o[0] - gt[i, 0], o[1] - gt[i, 1]))
    err = np.array(err)
    assert math.sqrt(np.mean(err**2)) < 0.02 and err.max() < 0.05, (err.mean(), err.max())
    assert max(odom_err) > 3 * err.max()  # the matching is what keeps it there
    # what it mapped lies on the true obstacles (one 5 cm cell tolerance)
    scores = map_scores(slam.occupancy(), slam.geometry, world_T_map, true_floor_plan())
    assert scores["precision"] > 0.98, scores


def test_amcl_on_the_committed_map_tracks_the_recorded_walk(walk):
    occ, geo = load_map(resolve_map_path("maps/house.yaml"))
    gt = walk["gt"]
    pf = ParticleFilter(AmclConfig(), occ, geo, np.random.default_rng(0))
    pf.initialize(tuple(gt[0, :3]), (0.05, 0.05, 0.05))
    err, yaw = [], []
    for i in range(len(walk["stamp"])):
        pf.predict(_odom(walk, i))
        pf.update(_scan(walk, i))
        p, _ = pf.estimate()
        err.append(math.hypot(p[0] - gt[i, 0], p[1] - gt[i, 1]))
        yaw.append(abs(math.remainder(p[2] - gt[i, 2], 2 * math.pi)))
    err, yaw = np.array(err), np.degrees(yaw)
    # the targets: RMS <= 3 cm, max <= 8 cm, heading RMS <= 1 deg
    assert math.sqrt(np.mean(err**2)) <= 0.03 and err.max() <= 0.08, (err.mean(), err.max())
    assert math.sqrt(np.mean(yaw**2)) <= 1.0


def test_the_scan_anchor_removes_the_odometry_drift_of_a_one_metre_move(walk):
    from quadmanip.services.navigation.scan_anchor import ScanAnchor

    gt = walk["gt"]
    worst_anchor, worst_odom = 0.0, 0.0
    for i0 in (5, 40, 100, 150, 200):  # five 1 m stretches of the walk
        anchor = ScanAnchor(_scan(walk, i0).points, _odom(walk, i0))
        g0, o0 = tuple(gt[i0, :3]), _odom(walk, i0)
        for i in range(i0 + 1, i0 + 15):
            anchor.update(_scan(walk, i).points, _odom(walk, i))
        true = compose(invert(g0), tuple(gt[i0 + 14, :3]))
        held = compose(invert(o0), anchor.pose(_odom(walk, i0 + 14)))
        raw = compose(invert(o0), _odom(walk, i0 + 14))
        assert math.hypot(*true[:2]) > 0.7
        worst_anchor = max(worst_anchor, math.hypot(held[0] - true[0], held[1] - true[1]))
        worst_odom = max(worst_odom, math.hypot(raw[0] - true[0], raw[1] - true[1]))
    # Algorithm 5's ±1 cm needs the anchor; the odometry drifts several centimetres
    assert worst_anchor < 0.01 and worst_odom > 0.03, (worst_anchor, worst_odom)


def test_the_visible_surface_is_the_faces_not_the_inside_of_walls():
    from quadmanip.services.navigation.grid import GridGeometry
    from quadmanip.testbench.bench_navigation import visible_surface
    from quadmanip.testbench.floor_plan import FloorPlan

    geo = GridGeometry(0.05, 0.0, 0.0, 40, 40)
    mask = np.zeros((40, 40), dtype=bool)
    mask[:2, :] = mask[-2:, :] = mask[:, :2] = mask[:, -2:] = True  # 10 cm walls
    mask[20:27, 3:12] = True  # a block 5 cm from the west wall: a slit between them
    surf = visible_surface(FloorPlan(mask, geo), start=(1.0, 0.5))
    assert surf[1, 10] and not surf[0, 10]  # the south wall's face, not its back
    assert surf[23, 11] and surf[20, 8] and surf[26, 8]  # the block's end and sides
    assert not surf[23, 3] and not surf[23, 5]  # its back (a 5 cm slit) and its inside


GLOBAL_STARTS = Path(__file__).resolve().parents[1] / "data" / "nav_global_starts.npz"


def _node_scan(d, k: int, i: int):
    """Scan ``i`` of slice ``k`` as the node makes it: floor hits of the tilted scan
    plane dropped with the trunk's attitude (from the odometry) and height."""
    from quadmanip.common.rotations import quat_to_mat
    from quadmanip.services.navigation.scan import lidar_height_above_base

    o = d[f"odom{k}"][i]
    R = quat_to_mat(o[3:7])
    yaw = math.atan2(R[1, 0], R[0, 0])
    c, s = math.cos(yaw), math.sin(yaw)
    level = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    a0, da = d["angles"]
    return scan_points(d[f"stamp{k}"][i], d[f"ranges{k}"][i], a0, da, 0.1, 12.0,
                       lidar_mount(), level, float(o[2]) + lidar_height_above_base())  # fmt: skip


@pytest.mark.parametrize("k, seed", [(0, 150), (0, 1), (1, 750), (1, 2)])
def test_global_localisation_waits_for_the_walk_to_tell_the_rooms_apart(k, seed):
    """Two 4 s stretches (20 Hz scans) of a recorded approach run in the living room
    where, weighing its first scan at full weight, the filter put all its mass on one
    cluster 3.6 m (2.3 m) from the truth and never left it. Tempered and held for ten
    weighings, it settles on the truth."""
    d = dict(np.load(GLOBAL_STARTS))
    occ, geo = load_map(resolve_map_path("maps/house.yaml"))
    gt = d[f"gt{k}"]
    pf = ParticleFilter(AmclConfig(), occ, geo, np.random.default_rng(seed))
    pf.initialize_global()
    settled = None
    for i in range(len(gt)):
        o = d[f"odom{k}"][i]
        pf.predict((float(o[0]), float(o[1]), yaw_from_quat(o[3:7])))
        pf.update(_node_scan(d, k, i))
        p, _ = pf.estimate()
        if pf.converged:
            settled = settled if settled is not None else i
            assert math.hypot(p[0] - gt[i, 0], p[1] - gt[i, 1]) < 0.05, (i, p, gt[i])
    assert settled is not None, "never converged"


@pytest.mark.parametrize("start", [0, 70, 140, 200])
def test_global_localisation_on_the_committed_map_finds_the_right_room(walk, start):
    """No pose at all, from four places of the recorded walk (both rooms): the filter
    must settle on the truth, not on the other room that looks alike from one place."""
    occ, geo = load_map(resolve_map_path("maps/house.yaml"))
    gt = walk["gt"]
    pf = ParticleFilter(AmclConfig(), occ, geo, np.random.default_rng(start))
    pf.initialize_global()
    err = []
    for i in range(start, min(start + 50, len(walk["stamp"]))):
        pf.predict(_odom(walk, i))
        pf.update(_scan(walk, i))
        p, _ = pf.estimate()
        err.append(math.hypot(p[0] - gt[i, 0], p[1] - gt[i, 1]) if pf.converged else math.inf)
    err = np.array(err)
    assert np.isfinite(err).any(), "never converged"
    first = int(np.argmax(np.isfinite(err)))
    assert err[first:].max() < 0.08, (first, err[first:].max())
