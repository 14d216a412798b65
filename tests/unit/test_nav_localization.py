"""The AMCL-style particle filter on the real house's floor plan, with synthetic scans.

The map is the true floor plan as a SLAM map would hold it: walls and furniture occupied,
the inside free, the outside unknown. The robot walks at 0.5 m/s with 10 Hz scans (5 cm
between scans) through both rooms and the doorway; its odometry has a 2 % scale error, a
yaw drift and per-step noise.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from quadmanip.services.navigation.amcl import AmclConfig, ParticleFilter
from quadmanip.services.navigation.grid import Pose2, compose, invert, wrap
from quadmanip.services.navigation.scan import (
    ScanPoints,
    lidar_mount,
    nearest_return,
    scan_points,
)
from quadmanip.testbench.floor_plan import FloorPlan, simulate_scan, true_floor_plan
from scipy import ndimage

pytestmark = pytest.mark.unit

# the maps here are rasters of the true geometry: a return lies on an occupied cell's edge
RASTER = AmclConfig(surface_offset=None)

STEP = 0.05  # m between scans: 0.5 m/s at 10 Hz
RAYS = 360


def make_house():
    """(plan, occupancy int8, mount)."""
    plan = true_floor_plan()
    occ = np.zeros(plan.geometry.shape, dtype=np.int8)
    occ[plan.mask] = 100
    outside, _ = ndimage.label(~plan.mask)
    border = set(
        np.unique(np.concatenate([outside[0], outside[-1], outside[:, 0], outside[:, -1]]))
    )
    border.discard(0)
    occ[np.isin(outside, list(border))] = -1  # never seen from inside: unknown
    return plan, occ, lidar_mount()


@pytest.fixture(scope="module")
def house():
    return make_house()


# waypoints (x, y, mode): "fwd" walks facing the way it goes, "side" keeps its heading and
# steps sideways, "turn" turns in place to the given yaw (the x, y are ignored)
ROUTE = [
    (1.5, 1.0, "start"),
    (3.0, 1.0, "fwd"),
    (3.0, 2.0, "side"),
    (4.4, 2.0, "fwd"),
    (0.0, 0.0, "turn"),  # to face +x again (already), then through the doorway
    (6.2, 2.0, "fwd"),
    (6.2, 1.0, "fwd"),
    (8.8, 1.0, "fwd"),
    (8.8, 2.8, "fwd"),
    (7.8, 2.8, "side"),
    (5.8, 2.8, "fwd"),
    (5.8, 2.0, "fwd"),
    (4.0, 2.0, "fwd"),
    (2.0, 2.6, "fwd"),
]


def true_walk(route=ROUTE, step: float = STEP) -> list[Pose2]:
    """Base poses every ``step`` metres along the route (turns at ~10 deg per scan)."""
    x, y, _ = route[0]
    yaw = 0.0
    poses: list[Pose2] = [(x, y, yaw)]
    for tx, ty, mode in route[1:]:
        if mode == "turn":
            continue
        dx, dy = tx - x, ty - y
        dist = math.hypot(dx, dy)
        if mode == "fwd":
            goal = math.atan2(dy, dx)
            while abs(wrap(goal - yaw)) > 1e-9:  # turn in place first, 10 deg a scan
                yaw = float(wrap(yaw + float(np.clip(wrap(goal - yaw), -0.17, 0.17))))
                poses.append((x, y, yaw))
        n = max(int(round(dist / step)), 1)
        for i in range(1, n + 1):
            poses.append((x + dx * i / n, y + dy * i / n, yaw))
        x, y = tx, ty
    return poses


def noisy_odometry(truth: list[Pose2], rng: np.random.Generator) -> list[Pose2]:
    """Odometry integrating the true increments with a 2 % scale error, a yaw drift of
    1 deg per metre, and per-step noise (2 mm, 0.2 deg)."""
    odom = [(0.3, -0.2, 0.4)]  # the odom frame is anywhere
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        d = compose(invert(a), b)
        dist = math.hypot(d[0], d[1])
        inc = (
            1.02 * d[0] + rng.normal(0, 0.002),
            1.02 * d[1] + rng.normal(0, 0.002),
            1.01 * d[2] + math.radians(1.0) * dist + rng.normal(0, math.radians(0.2)),
        )
        odom.append(compose(odom[-1], inc))
    return odom


def scan_at(plan, mount: Pose2, pose: Pose2, rng, noise=0.01, dropout=0.0) -> ScanPoints:
    ranges = simulate_scan(plan, compose(pose, mount), RAYS, noise=noise, rng=rng, dropout=dropout)
    return scan_points(0.0, ranges, -math.pi, 2 * math.pi / RAYS, 0.1, 12.0, mount)


def errors(est: Pose2, truth: Pose2) -> tuple[float, float]:
    return math.hypot(est[0] - truth[0], est[1] - truth[1]), abs(float(wrap(est[2] - truth[2])))


def run(pf: ParticleFilter, plan, mount, truth, odom, rng, dropout=0.0, timing=None):
    """Walk the filter along; (position errors, yaw errors, converged flags)."""
    pos, yaw, conv = [], [], []
    for t, o in zip(truth, odom, strict=True):
        scan = scan_at(plan, mount, t, rng, dropout=dropout)
        pf.predict(o)
        t0 = time.perf_counter()
        weighed = pf.update(scan)
        if timing is not None and weighed:
            timing.append((time.perf_counter() - t0, pf.particle_count))
        e = errors(pf.estimate()[0], t)
        pos.append(e[0])
        yaw.append(e[1])
        conv.append(pf.converged)
    return np.array(pos), np.array(yaw), np.array(conv)


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def settled_at(pos: np.ndarray, tol: float) -> int | None:
    """First scan from which the position error stays within tol to the end."""
    bad = np.flatnonzero(pos > tol)
    if len(bad) == 0:
        return 0
    return None if bad[-1] == len(pos) - 1 else int(bad[-1] + 1)


@pytest.fixture(scope="module")
def walk():
    truth = true_walk()
    return truth, noisy_odometry(truth, np.random.default_rng(1))


def test_walk_crosses_both_rooms(house, walk):
    plan, _, _ = house
    truth, odom = walk
    xs = np.array([p[0] for p in truth])
    assert xs.min() < 2.0 and xs.max() > 8.5  # both rooms, through the doorway twice
    assert not plan.occupied(np.array([p[:2] for p in truth])).any()
    drift = [
        errors(compose(invert(odom[0]), o), compose(invert(truth[0]), t))
        for t, o in zip(truth, odom, strict=True)
    ]
    assert max(d[0] for d in drift) > 0.3  # dead reckoning alone would be far off


def test_tracking_walk_is_centimetre_accurate(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(2))
    pf.initialize(truth[0], (0.05, 0.05, math.radians(2.0)))
    timing: list[tuple[float, int]] = []
    pos, yaw, conv = run(pf, plan, mount, truth, odom, np.random.default_rng(3), timing=timing)
    ms = 1e3 * float(np.median([t for t, _ in timing]))
    count = int(np.median([n for _, n in timing]))
    print(
        f"\ntracking {len(truth)} scans: position RMS {100 * rms(pos):.2f} cm, max "
        f"{100 * pos.max():.2f} cm, yaw RMS {math.degrees(rms(yaw)):.3f} deg; filter update "
        f"median {ms:.2f} ms with {count} particles ({len(timing)} updates)"
    )
    assert rms(pos) <= 0.03
    assert pos.max() <= 0.08
    assert math.degrees(rms(yaw)) <= 1.0
    assert conv[5:].all()
    assert pf.config.min_particles <= count <= 1000  # KLD shrank the initial 3000


def test_rough_initial_pose_converges_within_ten_seconds(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    t0 = truth[0]
    rough = (t0[0] + 0.7071, t0[1] + 0.7071, float(wrap(t0[2] + math.pi / 2)))  # 1 m, 90 deg
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(4))
    pf.initialize(rough, (0.7, 0.7, 1.0))
    assert errors(pf.estimate()[0], t0)[0] > 0.5
    pos, yaw, _ = run(pf, plan, mount, truth[:100], odom[:100], np.random.default_rng(5))
    first = settled_at(pos, 0.05)
    print(f"\nrough initial pose (1 m, 90 deg off): within 5 cm from scan {first} on")
    assert first is not None and first < 100
    assert pos[-1] <= 0.02 and yaw[-1] <= math.radians(1.0)


@pytest.mark.parametrize("start", [0, 220])
def test_global_localisation_in_the_house(house, walk, start):
    """Uniform over the free space of both rooms: the rooms are alike (and nearly point-
    symmetric about the doorway), yet one short walk inside one room suffices."""
    plan, occ, mount = house
    truth, odom = walk
    n = 120
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(6 + start))
    pf.initialize_global()
    assert pf.particle_count == pf.config.global_particles and not pf.converged
    tr, od = truth[start : start + n], odom[start : start + n]
    pos, yaw, conv = run(pf, plan, mount, tr, od, np.random.default_rng(7 + start))
    first = settled_at(pos, 0.05)
    travelled = sum(
        math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(tr[:-1], tr[1:], strict=True)
    )
    print(
        f"\nglobal localisation from walk scan {start}: within 5 cm from scan {first} on, "
        f"converged flag from {int(np.argmax(conv))}; {pf.particle_count} particles at the end"
    )
    assert first is not None and first <= 30
    settled = int(np.argmax(conv))  # a global start settles over a few scans first
    assert conv[settled:].all() and settled <= 30 and pos[settled] <= 0.05
    assert rms(pos[settled:]) <= 0.01 and math.degrees(rms(yaw[settled:])) <= 1.0
    assert travelled > 1.0


def test_half_the_returns_dropped_still_tracks(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(8))
    pf.initialize(truth[0], (0.05, 0.05, math.radians(2.0)))
    pos, yaw, _ = run(pf, plan, mount, truth[:200], odom[:200], np.random.default_rng(9), 0.5)
    print(f"\n50 % dropout: position RMS {100 * rms(pos):.2f} cm, max {100 * pos.max():.2f} cm")
    assert rms(pos) <= 0.03 and pos.max() <= 0.08 and math.degrees(rms(yaw)) <= 1.0


def test_unmapped_clutter_does_not_disturb_tracking(house, walk):
    """Boxes the map does not hold (a bag, a chair) in the scans: their returns are
    outliers for the likelihood field and for the fine correction."""
    plan, occ, mount = house
    truth, odom = walk
    g = plan.geometry
    mask = plan.mask.copy()
    for x0, y0, x1, y1 in [(2.2, 1.6, 2.5, 1.8), (4.0, 3.0, 4.3, 3.3), (0.5, 0.4, 0.8, 0.6)]:
        r0, c0 = g.to_cell(np.array([[x0, y0]]))
        r1, c1 = g.to_cell(np.array([[x1, y1]]))
        mask[r0[0] : r1[0], c0[0] : c1[0]] = True
    cluttered = FloorPlan(mask, g)
    pf = ParticleFilter(RASTER, occ, g, np.random.default_rng(19))
    pf.initialize(truth[0], (0.05, 0.05, 0.03))
    pos, yaw, _ = run(pf, cluttered, mount, truth[:150], odom[:150], np.random.default_rng(20))
    print(f"\nunmapped clutter: position RMS {100 * rms(pos):.2f} cm, max {100 * pos.max():.2f} cm")
    assert rms(pos) <= 0.03 and pos.max() <= 0.08 and math.degrees(rms(yaw)) <= 1.0


def test_kidnapped_robot_recovers(house, walk):
    """Tracking well, then carried to the other room: the odometry knows nothing of it.
    Augmented MCL's random particles find it again."""
    plan, occ, mount = house
    truth, _ = walk
    tr = truth[:60] + truth[301:]
    rng = np.random.default_rng(10)
    odom = noisy_odometry(truth[:60], rng)
    for a, b in zip(truth[300:-1], truth[301:], strict=True):
        odom.append(compose(odom[-1], compose(invert(a), b)))
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(11))
    pf.initialize(truth[0], (0.05, 0.05, 0.03))
    pos, _, _ = run(pf, plan, mount, tr, odom, rng)
    first = settled_at(pos, 0.05)
    print(f"\nkidnapped at scan 60 ({pos[60]:.1f} m away): within 5 cm again from scan {first}")
    assert pos[59] < 0.02 and pos[60] > 3.0
    assert first is not None and first - 60 <= 100


def test_standing_still_leaves_the_particles_alone(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(12))
    pf.initialize(truth[0], (0.2, 0.2, 0.2))
    rng = np.random.default_rng(13)
    pf.predict(odom[0])
    assert pf.update(scan_at(plan, mount, truth[0], rng))  # the first scan is always weighed
    particles, weights = pf.particles.copy(), pf.weights.copy()
    for i in range(30):
        jitter = (odom[0][0] + 1e-4 * (i % 2), odom[0][1], odom[0][2])  # odometry noise
        pf.predict(jitter)
        assert not pf.update(scan_at(plan, mount, truth[0], rng))
    np.testing.assert_array_equal(pf.particles, particles)
    np.testing.assert_array_equal(pf.weights, weights)
    assert pf.stats.resampled <= 1


def test_scan_without_returns_changes_nothing(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(14))
    pf.initialize(truth[0], (0.05, 0.05, 0.03))
    rng = np.random.default_rng(15)
    pf.predict(odom[0])
    pf.update(scan_at(plan, mount, truth[0], rng))
    pf.predict(odom[4])  # moved 20 cm: a filter step is due
    before = (pf.particles.copy(), pf.weights.copy(), pf.estimate()[0], pf.stats.weighed)
    empty = scan_points(0.0, np.zeros(RAYS), -math.pi, 2 * math.pi / RAYS, 0.1, 12.0, mount)
    assert len(empty.points) == 0
    assert not pf.update(empty)
    np.testing.assert_array_equal(pf.particles, before[0])
    np.testing.assert_array_equal(pf.weights, before[1])
    assert pf.estimate()[0] == before[2] and pf.stats.weighed == before[3]
    assert pf.update(scan_at(plan, mount, truth[4], rng))  # the due step happens on the next


def test_scan_off_the_map_is_finite_and_map_to_odom_closes(house, walk):
    plan, occ, mount = house
    truth, odom = walk
    pf = ParticleFilter(RASTER, occ, plan.geometry, np.random.default_rng(16))
    pf.initialize((10.8, 4.8, 0.0), (0.1, 0.1, 0.1))  # outside the house, on unknown cells
    pf.predict(odom[0])
    assert pf.update(scan_at(plan, mount, truth[0], np.random.default_rng(17)))
    assert np.isfinite(pf.weights).all() and abs(pf.weights.sum() - 1.0) < 1e-9
    pf.initialize(truth[0], (0.05, 0.05, 0.03))
    run(pf, plan, mount, truth[:20], odom[:20], np.random.default_rng(18))
    pose, cov = pf.estimate()
    assert cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(cov) >= -1e-12)
    m2o = pf.map_to_odom(odom[19])
    np.testing.assert_allclose(compose(m2o, odom[19]), pose, atol=1e-9)
    assert errors(compose(m2o, odom[19]), truth[19])[0] < 0.02


def test_kld_sample_count():
    from quadmanip.services.navigation.amcl import kld_sample_count

    n = kld_sample_count(np.array([1, 2, 10, 100]), 0.02, 2.326)
    assert n[0] == 1 and np.all(np.diff(n) > 0)
    assert 150 < n[1] < 250 and 2000 < n[3] < 5000  # Fox 2003: ~linear in the bins


# ------------------------------------------------------------ the approach's scan anchor


def _anchored(house, truth: list[Pose2], seed: int):
    """Hold noisy odometry along ``truth`` to the first scan; (anchor, errors in m)."""
    from quadmanip.services.navigation.scan_anchor import ScanAnchor

    plan, _, mount = house
    rng = np.random.default_rng(seed)
    odom = noisy_odometry(truth, rng)
    anchor = ScanAnchor(scan_at(plan, mount, truth[0], rng).points, odom[0])
    world_T_odom = compose(truth[0], invert(odom[0]))
    err = []
    for t, o in zip(truth[1:], odom[1:], strict=True):
        anchor.update(scan_at(plan, mount, t, rng).points, o)
        est = compose(world_T_odom, anchor.pose(o))
        err.append(errors(est, t)[0])
    return anchor, np.array(err)


def test_the_scan_anchor_holds_a_standing_robot_to_millimetres(house):
    """Scans of a robot standing still, 1 cm range noise on each: the matched pose must
    not wander (a distance field of one noisy scan has a flat bottom 2-4 cm wide; the
    anchor's lines through neighbouring returns do not)."""
    still = [(2.4, 1.5, 1.9)] * 40
    drift = [(2.4 + 0.0005 * k, 1.5 - 0.0003 * k, 1.9 + 0.0002 * k) for k in range(40)]
    for seed, truth in enumerate((still, drift)):  # the odometry creeps on its own too
        anchor, err = _anchored(house, truth, seed)
        assert anchor.refused == 0
        assert err.max() < 0.003, err.max()


def test_the_scan_anchor_grows_with_the_view_on_a_long_move(house):
    """1.5 m from the living room into the doorway: half of what the last scans see was
    hidden from the first. The anchor takes the new surfaces in and keeps matching."""
    truth = [(3.6 + 0.05 * k, 2.0, 0.0) for k in range(31)]
    anchor, err = _anchored(house, truth, 3)
    assert anchor.extended >= 1 and anchor.refused <= 2, (anchor.extended, anchor.refused)
    assert err.max() < 0.006, err.max()


def test_a_scan_anchor_on_an_empty_scan_refuses_its_matches(house):
    """A start scan with no returns (a LiDAR blinded at the approach's start) holds
    nothing: matches are refused and the pose is the odometry's, no exception."""
    from quadmanip.services.navigation.scan_anchor import ScanAnchor

    plan, _, mount = house
    anchor = ScanAnchor(np.zeros((0, 2)), (1.0, 1.0, 0.0))
    scan = scan_at(plan, mount, (1.5, 1.5, 0.0), np.random.default_rng(0)).points
    assert not anchor.update(scan, (1.01, 1.0, 0.0)) and anchor.refused == 1
    np.testing.assert_allclose(anchor.pose((1.2, 1.0, 0.1)), (1.2, 1.0, 0.1), atol=1e-12)


def test_the_nearest_return_is_what_a_blocked_walk_reports():
    # base-frame returns: a wall 2 m ahead, a box 0.4 m to the left, a chair behind
    pts = np.array([[2.0, 0.0], [2.0, 0.3], [0.0, 0.4], [-1.0, -1.0]])
    d, bearing = nearest_return(pts)
    assert d == pytest.approx(0.4) and bearing == pytest.approx(math.pi / 2)
    assert nearest_return(np.zeros((0, 2))) is None


def test_an_open_drawer_does_not_pull_the_pose_where_the_places_say_scenery_moves(house):
    """The map shows the cabinet's drawers shut. The tools' drawer open 24 cm puts its
    front in the scans 24 cm out of the cabinet's; at a stance beside the drawer's middle
    the fine correction pulled the pose 9.5 cm toward the cabinet (rendered in MuJoCo),
    and a tool released there landed on the drawer's front panel (paper-1 and paper-5,
    2026-12-06). The places file marks the drawers' sweep (``moves``): ignored."""
    from quadmanip.common.config import CONFIG_DIR
    from quadmanip.common.places import load_places

    plan, occ, mount = house
    g = plan.geometry
    mask = plan.mask.copy()
    r0, c0 = g.to_cell(np.array([[9.20, 1.18]]))  # the top drawer's front, 24 cm out
    r1, c1 = g.to_cell(np.array([[9.26, 1.82]]))
    mask[r0[0] : r1[0] + 1, c0[0] : c1[0] + 1] = True
    opened = FloorPlan(mask, g)
    places = load_places(CONFIG_DIR / "maps" / "house.places.toml")
    moves = [p.area for p in places.values() if p.moves]
    assert moves, "the places file marks no moving scenery"
    truth = (8.92, 1.65, 0.0)  # the stance for the drawer's slot 15 cm left of its middle
    errs = {}
    for ignore in (False, True):
        pf = ParticleFilter(RASTER, occ, g, np.random.default_rng(3))
        if ignore:
            pf.ignore_areas(moves)
        pf.initialize(truth, (0.02, 0.02, 0.01))
        rng = np.random.default_rng(4)
        for _ in range(20):
            pf.predict(truth)
            pf.update(scan_at(opened, mount, truth, rng))
        errs[ignore] = errors(pf.estimate()[0], truth)[0]
    print(
        f"\nopen drawer: {100 * errs[False]:.1f} cm off, ignoring its sweep {100 * errs[True]:.1f}"
    )
    assert errs[True] < 0.02
    assert errs[False] > 0.04  # (what it did before)


def test_ignored_areas_must_be_rectangles(house):
    _, occ, _ = house
    pf = ParticleFilter(RASTER, occ, house[0].geometry)
    with pytest.raises(ValueError, match="x_min < x_max"):
        pf.ignore_areas([(1.0, 1.0, 0.5, 2.0)])
