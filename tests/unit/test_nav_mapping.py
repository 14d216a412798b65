"""Navigation's mapping half: log-odds grid, scan matcher, online SLAM, frontiers, map files.

Synthetic scans come from the house's true floor plan (quadmanip.testbench.floor_plan),
the same raster the navigation benchmark scores maps against."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from quadmanip.services.navigation.distance_field import DistanceField
from quadmanip.services.navigation.frontier import (
    FrontierConfig,
    find_frontiers,
    rank_frontiers,
)
from quadmanip.services.navigation.grid import (
    GridGeometry,
    compose,
    invert,
    transform_points,
    wrap,
)
from quadmanip.services.navigation.map_io import MapFileError, load_map, save_map
from quadmanip.services.navigation.occupancy_grid import LogOddsGrid, OccupancyConfig
from quadmanip.services.navigation.scan import scan_points
from quadmanip.services.navigation.scan_matcher import ScanMatcher
from quadmanip.services.navigation.slam import OnlineSlam
from quadmanip.testbench.floor_plan import simulate_scan, true_floor_plan
from scipy import ndimage

pytestmark = pytest.mark.unit

MOUNT = (0.185, 0.0, 0.0)  # the LiDAR in the base frame (robot description's lidar site)
START = (0.8, 1.2, 0.0)
# left room -> doorway (x = 5, y 1.5..2.5) -> right room, around the furniture, and back
WAYPOINTS = [(0.8, 1.2), (3.0, 1.5), (4.5, 2.0), (5.5, 2.0), (6.3, 1.0), (8.3, 1.0), (8.6, 2.6)]


def _scan(plan, pose, rng, noise=0.01, dropout=0.0):
    r = simulate_scan(plan, compose(pose, MOUNT), noise=noise, rng=rng, dropout=dropout)
    return scan_points(0.0, r, -math.pi, 2 * math.pi / 360, 0.1, 12.0, MOUNT)


def _walk(step=0.1, turn_deg=5.0):
    """True base poses: turn in place toward each waypoint, then walk to it; out and back."""
    pts = WAYPOINTS + WAYPOINTS[::-1][1:]
    poses = [START]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        yaw = math.atan2(b[1] - a[1], b[0] - a[0])
        cur = poses[-1]
        dyaw = wrap(yaw - cur[2])
        n = int(math.ceil(abs(dyaw) / math.radians(turn_deg)))
        poses += [(cur[0], cur[1], float(wrap(cur[2] + dyaw * k / n))) for k in range(1, n + 1)]
        n = max(int(math.ceil(math.hypot(b[0] - a[0], b[1] - a[1]) / step)), 1)
        poses += [
            (a[0] + (b[0] - a[0]) * k / n, a[1] + (b[1] - a[1]) * k / n, yaw)
            for k in range(1, n + 1)
        ]
    return poses


def _odometry(poses, scale=1.03, drift_deg_per_m=2.0):
    """Dead reckoning with a 3 % scale error and a yaw drift of 2 degrees per metre walked;
    it starts at the true start (odom = world at the first scan)."""
    odom = [poses[0]]
    for p, q in zip(poses[:-1], poses[1:], strict=True):
        d = compose(invert(p), q)
        dist = math.hypot(d[0], d[1])
        odom.append(
            compose(
                odom[-1], (d[0] * scale, d[1] * scale, d[2] + math.radians(drift_deg_per_m) * dist)
            )
        )
    return odom


def _map_scores(occupied, free, geometry, plan):
    """(precision, recall, F1) of a map's occupied cells against the true plan, with one
    cell of tolerance. Recall counts the true occupied cells the walk could see: those
    within one cell of a cell the map holds as free (a wall's inside is never seen)."""
    tol = np.ones((3, 3), dtype=bool)
    truth_near = ndimage.binary_dilation(plan.mask, tol)
    tg = plan.geometry
    r, c = tg.to_cell(geometry.cell_center(*np.nonzero(occupied)))
    inside = tg.inside(r, c)
    hits = np.zeros(len(r), dtype=bool)
    hits[inside] = truth_near[r[inside], c[inside]]
    precision = float(hits.mean()) if len(hits) else 0.0
    mr, mc = geometry.to_cell(tg.cell_center(*np.nonzero(plan.mask)))
    ok = geometry.inside(mr, mc)
    mr, mc = mr[ok], mc[ok]
    seen = ndimage.binary_dilation(free, tol)[mr, mc]
    found = ndimage.binary_dilation(occupied, tol)[mr, mc]
    recall = float(found[seen].mean()) if seen.any() else 0.0
    f1 = 2 * precision * recall / max(precision + recall, 1e-12)
    return precision, recall, f1


def _pose_error(a, b):
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(math.degrees(wrap(a[2] - b[2])))


@pytest.fixture(scope="module")
def plan():
    return true_floor_plan()


@pytest.fixture(scope="module")
def walk(plan):
    """The SLAM run of the whole walk, and the same scans mapped at the odometry poses."""
    truth = _walk()
    odom = _odometry(truth)
    rng = np.random.default_rng(7)
    slam = OnlineSlam()
    dead = LogOddsGrid(slam.geometry)
    times = []
    matched = 0
    for p, o in zip(truth, odom, strict=True):
        scan = _scan(plan, p, rng, dropout=0.02)
        t0 = time.perf_counter()
        est = slam.update(scan, o)
        times.append(time.perf_counter() - t0)
        matched += est.matched
        dead.integrate(compose(o, MOUNT), transform_points(o, scan.points))
    return {
        "truth": truth,
        "odom": odom,
        "slam": slam,
        "est": est,
        "dead": dead,
        "times": np.array(times),
        "matched": matched,
    }


# ---------------------------------------------------------------------------- SLAM
def test_slam_walk_through_both_rooms_builds_an_accurate_map(walk, plan):
    truth, odom, slam = walk["truth"], walk["odom"], walk["slam"]
    assert len(truth) > 300  # ~19 m of walking and turning, a scan every 10 cm / 5 degrees
    assert walk["matched"] >= len(truth) - 3  # every scan but the first matched

    pos_err, yaw_err = _pose_error(walk["est"].pose, truth[-1])
    odo_pos, odo_yaw = _pose_error(odom[-1], truth[-1])
    assert pos_err <= 0.05 and yaw_err <= 1.0, (pos_err, yaw_err)
    assert odo_pos > 0.5 and odo_yaw > 10.0  # what the matcher corrected
    # the published correction reproduces the estimate from the raw odometry
    assert _pose_error(compose(slam.map_to_odom, odom[-1]), slam.pose)[0] < 1e-9

    p, r, f1 = _map_scores(slam.grid.occupied_mask(), slam.grid.free_mask(), slam.geometry, plan)
    assert f1 >= 0.95, (p, r, f1)
    # both rooms were seen: walls of the left room's far end and the right room's far end
    occ = slam.occupancy()
    assert occ.dtype == np.int8 and occ.shape == slam.geometry.shape
    for x, y in [(0.3, 1.2), (9.6, 2.0)]:  # free space in each room
        rr, cc = slam.geometry.to_cell(np.array([[x, y]]))
        assert 0 <= occ[rr[0], cc[0]] < 35

    # mapping at the odometry poses instead: clearly worse
    dp, dr, dead_f1 = _map_scores(
        walk["dead"].occupied_mask(), walk["dead"].free_mask(), slam.geometry, plan
    )
    assert dead_f1 < f1 - 0.2, (dead_f1, f1)


def test_slam_rejects_an_implausible_match(plan):
    rng = np.random.default_rng(3)
    slam = OnlineSlam()
    slam.update(_scan(plan, START, rng), START)
    # odometry claims a 1 m jump that did not happen: the match would have to correct
    # 1 m, more than allowed, so the odometry is kept and the scan reported unmatched
    est = slam.update(_scan(plan, START, rng), (START[0] + 1.0, START[1], START[2]))
    assert not est.matched
    assert est.pose[0] == pytest.approx(START[0] + 1.0)


# ---------------------------------------------------------------------------- matcher
def test_matcher_recovers_a_10cm_5deg_error_on_the_true_map(plan):
    field = DistanceField(plan.mask, plan.geometry, 1.0)
    matcher = ScanMatcher()
    rng = np.random.default_rng(11)
    for true in [(0.8, 1.2, 0.0), (3.0, 2.0, 1.0), (7.0, 1.0, -2.0), (8.6, 2.8, 3.0)]:
        scan = _scan(plan, true, rng)
        for dx, dy, dyaw in [(0.1, 0.0, 5.0), (-0.07, 0.07, -5.0), (0.0, -0.1, 5.0)]:
            initial = (true[0] + dx, true[1] + dy, true[2] + math.radians(dyaw))
            res = matcher.match(scan.points, field, initial)
            pos, yaw = _pose_error(res.pose, true)
            assert pos <= 0.01 and yaw <= 0.3, (true, initial, res)
            assert res.fit < 0.02 and res.inlier_fraction > 0.95


def test_matcher_reports_a_bad_fit_for_a_scan_of_another_place(plan):
    field = DistanceField(plan.mask, plan.geometry, 1.0)
    # a scan of a 1.5 m x 1.5 m box room that is nowhere in the house
    a = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    r = 0.75 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a)))
    pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    res = ScanMatcher().match(pts, field, (2.5, 2.0, 0.0))
    assert res.inlier_fraction < 0.5 or res.fit > 0.03


# ---------------------------------------------------------------------------- log-odds
def _line_geometry():
    return GridGeometry(0.05, 0.0, 0.0, 60, 20)


def test_beam_marks_free_cells_and_its_endpoint():
    g = _line_geometry()
    grid = LogOddsGrid(g)
    grid.integrate((0.025, 0.525, 0.0), np.array([[2.025, 0.525]]))
    occ = grid.occupancy()
    row = 10
    assert occ[row, 40] > 65  # the endpoint's cell: one hit makes it occupied
    assert np.all((occ[row, 0:40] >= 0) & (occ[row, 0:40] < 50))  # every cell on the way
    assert np.all(occ[row, 41:] == -1) and np.all(occ[row + 2, :] == -1)
    grid.integrate((0.025, 0.525, 0.0), np.array([[2.025, 0.525]]))
    # a pass weighs half a hit: two beams make the way free
    assert np.all(grid.occupancy()[row, 0:40] < 35)
    assert grid.known_bounds() == (row, row + 1, 0, 41)
    assert grid.unknown_mask().sum() == g.width * g.height - 41


def test_cell_seen_free_then_hit_repeatedly_becomes_occupied():
    g = _line_geometry()
    grid = LogOddsGrid(g)
    sensor = (0.025, 0.525, 0.0)
    for _ in range(5):  # the cell at x = 1.0 is passed through by beams ending at 2 m
        grid.integrate(sensor, np.array([[2.025, 0.525]]))
    cell = (10, 20)
    assert grid.free_mask()[cell]
    hits = 0
    while not grid.occupied_mask()[cell]:
        grid.integrate(sensor, np.array([[1.025, 0.525]]))  # something appeared at 1 m
        hits += 1
        assert hits < 20
    assert 3 <= hits <= 8  # not on one spurious return, not after ages
    assert grid.occupancy()[cell] > 65


def test_moved_obstacle_is_cleared_by_repeated_free_observations():
    g = _line_geometry()
    grid = LogOddsGrid(g)
    sensor = (0.025, 0.525, 0.0)
    for _ in range(30):  # a chair seen for a long time: log-odds saturate at l_max
        grid.integrate(sensor, np.array([[1.025, 0.525]]))
    cell = (10, 20)
    assert grid.log_odds[cell] == pytest.approx(grid.config.l_max)
    n = 0
    while not grid.free_mask()[cell]:
        grid.integrate(sensor, np.array([[2.025, 0.525]]))  # the chair has gone
        n += 1
        assert n < 40
    # from saturation down past the free threshold, one pass-through at a time
    c = grid.config
    assert n == math.ceil(
        (c.l_max - math.log(c.free_threshold / (1 - c.free_threshold))) / -c.l_free
    )


def test_one_update_per_cell_per_scan():
    g = _line_geometry()
    grid = LogOddsGrid(g)
    # 50 beams fanning out from one sensor: the cells near it are crossed by all of them
    a = np.linspace(-0.3, 0.3, 50)
    ends = np.stack([0.025 + 2.0 * np.cos(a), 0.525 + 2.0 * np.sin(a)], axis=1)
    grid.integrate((0.025, 0.525, 0.0), ends)
    assert grid.log_odds.min() == pytest.approx(grid.config.l_free)
    assert grid.log_odds.max() == pytest.approx(grid.config.l_occ)


def test_no_return_beams_clear_only_when_configured():
    g = _line_geometry()
    none = LogOddsGrid(g)
    none.integrate((0.025, 0.525, 0.0), np.zeros((0, 2)), no_return_angles=np.array([0.0]))
    assert none.known_bounds() is None
    far = LogOddsGrid(g, OccupancyConfig(max_free_range=1.0))
    for _ in range(2):  # a pass weighs half a hit: two make a cell free
        far.integrate((0.025, 0.525, 0.0), np.zeros((0, 2)), no_return_angles=np.array([0.0]))
    free = far.free_mask()[10]
    assert free[:20].all() and not free[21:].any() and not far.occupied_mask().any()


# ---------------------------------------------------------------------------- frontiers
def _room_occupancy(explored_to_col=None):
    """A 4 m x 3 m walled room (5 cm cells) on a larger unknown grid, explored entirely or
    only up to a column."""
    g = GridGeometry(0.05, 0.0, 0.0, 120, 100)
    occ = np.full(g.shape, -1, dtype=np.int8)
    occ[20:80, 20:100] = 100
    occ[21:79, 21:99] = 0
    if explored_to_col is not None:
        occ[:, explored_to_col:] = -1
    return occ, g


def test_frontiers_of_a_half_explored_room_lie_at_the_boundary():
    occ, g = _room_occupancy(explored_to_col=60)
    fronts = find_frontiers(occ, g)
    assert len(fronts) == 1
    f = fronts[0]
    assert np.all(f.cells[:, 1] == 59)  # the last explored column
    assert f.size == 58  # the room's free rows 21..78
    assert f.centroid_xy[0] == pytest.approx(59.5 * 0.05)
    assert f.centroid_xy[1] == pytest.approx(50.0 * 0.05, abs=0.03)
    rr, cc = g.to_cell(f.goal_xy[None])
    assert occ[rr[0], cc[0]] == 0  # a free cell to walk to
    assert f.length == pytest.approx(58 * 0.05)


def test_a_fully_explored_enclosed_map_has_no_frontiers():
    occ, g = _room_occupancy()
    assert find_frontiers(occ, g) == []


def test_small_frontiers_are_dropped():
    occ, g = _room_occupancy()
    occ[50:53, 98:100] = -1  # a 3-cell hole in the far wall, next to free cells
    occ[50:53, 98] = 0
    fr = find_frontiers(occ, g, FrontierConfig(min_cells=6))
    assert fr == []
    assert len(find_frontiers(occ, g, FrontierConfig(min_cells=2))) == 1


def test_ranking_prefers_the_nearer_reachable_frontier_and_drops_unreachable():
    occ, g = _room_occupancy()
    occ[45:56, 20] = 0  # a gap in the left wall (x = 1 m), near the robot
    occ[79, 60:71] = 0  # a gap in the top wall (y = 4 m), farther
    occ[45:56, 99] = 0  # a gap in the right wall (x = 5 m) ...
    occ[20:80, 80] = 100  # ... behind a wall at x = 4 m: unreachable
    fronts = find_frontiers(occ, g)
    assert len(fronts) == 3
    robot = np.array([1.5, 2.5])

    def cost(goals):
        d = np.hypot(*(goals - robot).T)
        return np.where(goals[:, 0] > 4.0, np.inf, d)

    ranked = rank_frontiers(fronts, cost)
    assert len(ranked) == 2
    (first, c1), (second, c2) = ranked
    assert first.goal_xy[0] == pytest.approx(1.025)  # the left gap
    assert second.goal_xy[1] == pytest.approx(3.975)  # the top gap
    assert c1 == pytest.approx(0.475, abs=0.01) and c1 < c2

    # the same through a cost-to-go grid: straight-line cost over the robot's free region
    free = (occ >= 0) & (occ < 35)
    reach, _ = ndimage.label(free)
    rr, cc = g.to_cell(robot[None])
    rows, cols = np.mgrid[0 : g.height, 0 : g.width]
    dist = np.hypot(*(g.cell_center(rows.ravel(), cols.ravel()) - robot).T).reshape(g.shape)
    grid_cost = np.where(reach == reach[rr[0], cc[0]], dist, np.inf)
    ranked_grid = rank_frontiers(fronts, grid_cost, g)
    assert [id(f) for f, _ in ranked_grid] == [id(first), id(second)]
    with pytest.raises(ValueError, match="geometry"):
        rank_frontiers(fronts, grid_cost)  # a grid needs its geometry


def test_a_bigger_frontier_wins_a_near_tie():
    occ, g = _room_occupancy(explored_to_col=60)
    big = find_frontiers(occ, g)[0]  # 58 cells, 2.9 m
    small = dataclasses.replace(big, cells=big.cells[:6], size=6, length=6 * 0.05)
    ranked = rank_frontiers([small, big], lambda goals: np.array([1.0, 1.05]))
    assert ranked[0][0] is big  # 5 cm farther, 2.6 m longer
    ranked = rank_frontiers([small, big], lambda goals: np.array([1.0, 2.0]))
    assert ranked[0][0] is small  # the bonus is small: 1 m farther loses


# ---------------------------------------------------------------------------- map files
def test_map_round_trip_keeps_values_origin_and_orientation(tmp_path: Path):
    g = GridGeometry(0.05, -15.0, -15.0, 600, 600)
    occ = np.full(g.shape, -1, dtype=np.int8)
    occ[300:340, 300:380] = 0
    occ[300, 300:380] = 100  # a wall along the map's bottom edge of the known part
    occ[339, 379] = 100  # one occupied cell in the top-right corner of the known part
    paths = save_map(tmp_path / "house", occ, g, crop=True, margin_cells=5)
    assert {k: p.name for k, p in paths.items()} == {
        "pgm": "house.pgm",
        "yaml": "house.yaml",
        "png": "house.png",
    }
    loaded, lg = load_map(paths["yaml"])
    assert lg.resolution == pytest.approx(0.05)
    assert (lg.width, lg.height) == (80 + 10, 40 + 10)
    assert lg.origin_x == pytest.approx(-15.0 + 295 * 0.05)
    assert lg.origin_y == pytest.approx(-15.0 + 295 * 0.05)
    assert np.array_equal(loaded, occ[295:345, 295:385])
    # the same cell at the same place in the world
    xy = g.cell_center(np.array([339]), np.array([379]))
    r, c = lg.to_cell(xy)
    assert loaded[r[0], c[0]] == 100

    img = cv2.imread(str(paths["pgm"]), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint8 and img.shape == (50, 90)
    assert set(np.unique(img)) == {0, 205, 254}
    assert img[-1 - 5, 5:85].tolist() == [0] * 80  # the bottom wall is the image's bottom
    png = cv2.imread(str(paths["png"]))
    assert png is not None and png.shape[0] > img.shape[0]
    text = paths["yaml"].read_text()
    for key in ("image: house.pgm", "negate: 0", "occupied_thresh: 0.65", "free_thresh: 0.196"):
        assert key in text


def test_map_uncertain_cells_follow_the_thresholds(tmp_path: Path):
    g = GridGeometry(0.1, 0.0, 0.0, 4, 1)
    occ = np.array([[10, 50, 90, -1]], dtype=np.int8)
    paths = save_map(tmp_path / "m", occ, g, crop=False, picture=False)
    assert "png" not in paths
    loaded, _ = load_map(paths["yaml"])
    assert loaded.tolist() == [[0, -1, 100, -1]]


def test_map_load_errors_are_clear(tmp_path: Path):
    with pytest.raises(MapFileError, match="no map description"):
        load_map(tmp_path / "missing.yaml")
    g = GridGeometry(0.05, 0.0, 0.0, 10, 8)
    occ = np.zeros(g.shape, dtype=np.int8)
    paths = save_map(tmp_path / "m", occ, g, crop=False, picture=False)
    yaml = paths["yaml"]
    good = yaml.read_text()

    yaml.write_text(good.replace("resolution", "resolutoin"))
    with pytest.raises(MapFileError, match="missing key.*resolution"):
        load_map(yaml)
    yaml.write_text(good.replace("image: m.pgm", "image: other.pgm"))
    with pytest.raises(MapFileError, match="not found"):
        load_map(yaml)
    yaml.write_text(good.replace(", 0.0]", ", 0.5]"))
    with pytest.raises(MapFileError, match="yaw"):
        load_map(yaml)
    yaml.write_text(good.replace("resolution: 0.05", "resolution: fine"))
    with pytest.raises(MapFileError, match="bad value"):
        load_map(yaml)
    yaml.write_text(good + "this line is not yaml\n")
    with pytest.raises(MapFileError, match="key: value"):
        load_map(yaml)
    yaml.write_text(good)
    data = paths["pgm"].read_bytes()
    paths["pgm"].write_bytes(data[:-7])  # truncated pixels
    with pytest.raises(MapFileError, match="10x8 = 80 pixels, data has 73"):
        load_map(yaml)
    with pytest.raises(MapFileError, match="shape"):
        save_map(tmp_path / "bad", np.zeros((3, 3), dtype=np.int8), g)


def test_a_map_saved_in_the_floor_plan_frame_keeps_its_walls_where_they_are():
    """``quadmanip map`` resamples the SLAM start's turn into the cells (map files hold no
    rotation): a wall 10 m long lies on its true line within a cell's half diagonal; with
    no turn the cells are kept as they are and only the origin moves."""
    from quadmanip.services.navigation.grid import GridGeometry
    from quadmanip.testbench.map_house import into_world_frame

    geo = GridGeometry(0.05, 0.0, 0.0, 200, 60)
    occ = np.zeros(geo.shape, dtype=np.int8)
    occ[30, :] = 100  # a wall along x at y = 1.525 m in the map frame
    same, geo0 = into_world_frame(occ, geo, (0.012, -0.007, 0.0))
    assert np.array_equal(same, occ)
    assert (geo0.origin_x, geo0.origin_y) == pytest.approx((0.012, -0.007))
    t = (0.012, -0.007, math.radians(0.5))
    out, geo_w = into_world_frame(occ, geo, t)
    r, c = np.nonzero(out == 100)
    pts = geo_w.cell_center(r, c)
    # the wall's line in the world: through t + R (0, 1.525), along R (1, 0)
    n = np.array([-math.sin(t[2]), math.cos(t[2])])
    off = (pts - np.array(t[:2])) @ n - 1.525
    assert len(pts) >= 190 and np.abs(off).max() <= 0.5 * 0.05 * math.sqrt(2)
    # only shifted, as the tool saved maps before, the far end lies 8 cm off the line
    r0, c0 = np.nonzero(occ == 100)
    off0 = (geo0.cell_center(r0, c0) - np.array(t[:2])) @ n - 1.525
    assert np.abs(off0).max() > 0.08


def _room(lo=(0.01, 0.01), hi=(4.01, 3.01), res=0.005):
    """A bare room whose walls lie on 2 cm cell centres and 5 cm cell edges of the SLAM's
    rasters (the 5 cm map can only put them 2.5 cm off), rasterised at 5 mm."""
    from quadmanip.testbench.floor_plan import FloorPlan

    geo = GridGeometry.covering((lo[0] - 0.3, lo[1] - 0.3), (hi[0] + 0.3, hi[1] + 0.3), res)
    xy = geo.cell_center(*np.indices(geo.shape).reshape(2, -1))
    inside = (xy[:, 0] > lo[0]) & (xy[:, 0] < hi[0]) & (xy[:, 1] > lo[1]) & (xy[:, 1] < hi[1])
    return FloorPlan(~inside.reshape(geo.shape), geo), lo, hi


def test_the_surface_raster_puts_the_walls_within_millimetres_and_localises_on_them():
    """``OnlineSlam.surface()`` (saved beside the map by ``quadmanip map``): the densest 2 cm
    cells of the returns lie on the walls, where the 5 cm map's cells are a cell's half
    off; the localisation's final correction aligned with them places a standing robot to
    millimetres."""
    from quadmanip.services.navigation.amcl import AmclConfig, ParticleFilter

    plan, lo, hi = _room()
    rng = np.random.default_rng(3)
    slam = OnlineSlam()
    poses = [(1.0 + 0.1 * k, 1.5 + 0.02 * k, 0.05 * k) for k in range(21)]
    for p in poses:
        slam.update(_scan(plan, p, rng), p)  # odometry = truth: the map frame is the world

    def off_wall(pts):
        return np.min(np.abs(np.column_stack([pts[:, 0] - lo[0], pts[:, 0] - hi[0],
                                              pts[:, 1] - lo[1], pts[:, 1] - hi[1]])), axis=1)  # fmt: skip

    mask, geo = slam.surface()
    assert geo.resolution == pytest.approx(0.02)
    d_surf = off_wall(geo.cell_center(*np.nonzero(mask)))
    d_map = off_wall(slam.geometry.cell_center(*np.nonzero(slam.grid.occupied_mask())))
    print(f"\nwall offset: surface raster ({len(d_surf)} cells) median {1e3 * np.median(d_surf):.1f}"
          f" mm, p95 {1e3 * np.percentile(d_surf, 95):.1f} mm; 5 cm map median "
          f"{1e3 * np.median(d_map):.1f} mm")  # fmt: skip
    assert len(d_surf) >= 2 * (4.0 + 3.0) / 0.02 * 0.9  # every wall, one cell thick
    assert np.median(d_surf) <= 0.005 and np.percentile(d_surf, 95) <= 0.012
    assert np.median(d_surf) < 0.5 * np.median(d_map)

    stands = [(1.3, 0.8, 0.3), (2.5, 2.2, -1.0), (3.3, 1.1, 2.5), (0.7, 2.5, 1.2), (3.6, 2.7, 0.0)]
    errs = {}
    for name, surface in (("surface", (mask, geo)), ("map", None)):
        e = []
        for k, p in enumerate(stands):
            pf = ParticleFilter(AmclConfig(), slam.occupancy(), slam.geometry,
                                np.random.default_rng(k), surface=surface)  # fmt: skip
            pf.initialize(p, (0.02, 0.02, math.radians(1.0)))
            pf.predict(p)
            scans = np.random.default_rng(50 + k)
            for _ in range(5):
                pf.update(_scan(plan, p, scans))
            e.append(_pose_error(pf.estimate()[0], p)[0])
        errs[name] = np.array(e)
    print("standing errors (mm):", {k: np.round(1e3 * v, 1).tolist() for k, v in errs.items()})
    assert errs["surface"].max() <= 0.008
    assert errs["surface"].max() < errs["map"].max()


def test_the_surface_raster_is_saved_beside_its_map_and_read_back(tmp_path: Path):
    from quadmanip.services.navigation.map_io import load_surface, save_surface, surface_path_for

    stem = tmp_path / "house"
    occ = np.zeros((8, 10), dtype=np.int8)
    occ[0, :] = 100
    save_map(stem, occ, GridGeometry(0.05, -0.2, 0.1, 10, 8))
    assert load_surface(stem.with_suffix(".yaml")) is None  # a map without one
    mask = np.zeros((20, 25), dtype=bool)
    mask[3, 2:20] = True
    mask[4:15, 7] = True
    geo = GridGeometry(0.02, -0.213, 0.094, 25, 20)
    path = save_surface(stem, mask, geo)
    assert path == surface_path_for(stem.with_suffix(".yaml")) == tmp_path / "house_surface.yaml"
    got, g = load_surface(stem.with_suffix(".yaml"))
    np.testing.assert_array_equal(got, mask)
    assert (g.resolution, g.origin_x, g.origin_y, g.width, g.height) == pytest.approx(
        (0.02, -0.213, 0.094, 25, 20)
    )
    save_surface(stem, np.zeros_like(mask), geo)
    with pytest.raises(MapFileError, match="no surface"):
        load_surface(stem.with_suffix(".yaml"))
