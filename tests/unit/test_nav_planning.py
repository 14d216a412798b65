"""Navigation planning and control on the true floor plan: costmap layers, the global
planner's routes and refusals, the path follower and the final approach closed around a
kinematic model of a legged base (first-order velocity lag, noise, deadband)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from quadmanip.services.navigation.approach import (
    ApproachConfig,
    ApproachController,
    approach_pose,
    free_approach_heading,
)
from quadmanip.services.navigation.costmap import (
    INSCRIBED,
    LETHAL,
    Costmap,
    CostmapConfig,
)
from quadmanip.services.navigation.global_planner import PlannerConfig, path_cost, plan_path
from quadmanip.services.navigation.grid import GridGeometry, compose, wrap
from quadmanip.services.navigation.path_follower import (
    FollowerConfig,
    PathFollower,
    costmap_collision_check,
    project_motion,
)
from quadmanip.services.navigation.standing_nudge import NudgeConfig
from quadmanip.testbench.floor_plan import simulate_scan, true_floor_plan

DOORWAY = (5.0, 2.0)
START = (0.8, 1.2)
KITCHEN = (8.5, 2.8)


@pytest.fixture(scope="module")
def plan():
    return true_floor_plan()


def _costmap(plan, **kw) -> Costmap:
    occ = np.where(plan.mask, 100, 0).astype(np.int8)
    return Costmap(CostmapConfig(**kw), occ, plan.geometry)


@pytest.fixture()
def costmap(plan):
    return _costmap(plan)


def _scan_points(plan, pose, rng=None):
    """A simulated scan's returns in the map frame (the LiDAR at the pose)."""
    r = simulate_scan(plan, pose, rng=rng)
    a = pose[2] - math.pi + np.arange(len(r)) * (2 * math.pi / len(r))
    ok = r > 0
    return np.stack([pose[0] + r[ok] * np.cos(a[ok]), pose[1] + r[ok] * np.sin(a[ok])], axis=1)


# ---------------------------------------------------------------- costmap


def test_costmap_layers_and_inflation(costmap):
    cfg = costmap.config
    assert costmap.cost[costmap.static_lethal].min() == LETHAL
    # the inscribed ring: 0.15 m off the bottom wall's face (y = 0); a far one is free
    assert costmap.cost_at(np.array([[2.0, 0.15]]))[0] == INSCRIBED
    assert costmap.cost_at(np.array([[2.5, 2.0]]))[0] == 0
    # the cost falls off with clearance, and clearance reads metres
    ys = np.array([[3.0, 0.35], [3.0, 0.45], [3.0, 0.6]])
    c = costmap.cost_at(ys).astype(int)
    assert c[0] > c[1] > c[2] > 0
    cl = costmap.clearance(ys)
    assert np.all(np.diff(cl) > 0) and abs(cl[1] - 0.45) < 0.03  # the wall's face is y = 0
    assert costmap.is_traversable(np.array([[2.5, 2.0]]))[0]
    assert not costmap.is_traversable(np.array([[2.0, 0.15]]))[0]
    # footprint: free in the open; in the doorway only along the passage, not across it
    assert costmap.footprint_free((2.5, 2.0, 0.3))
    assert costmap.footprint_free((5.0, 2.0, 0.0))
    assert not costmap.footprint_free((0.2, 2.0, 0.0))
    # 0.25 m from the middle wall's face (x = 4.95): the footprint (half width 0.185,
    # half length 0.27) fits sideways-on but not facing the wall; clear at 0.28 m
    assert costmap.footprint_free((4.95 - 0.25, 0.8, math.pi / 2))
    assert not costmap.footprint_free((4.95 - 0.25, 0.8, 0.0))
    assert costmap.footprint_free((4.95 - 0.28, 0.8, 0.0))
    assert cfg.robot_radius > 0.5 * cfg.footprint_width


def test_obstacle_layer_marks_and_clears(plan, costmap):
    box = np.array([[3.0 + dx, 1.0 + dy] for dx in np.arange(0, 0.3, 0.04) for dy in (0.0, 0.28)])
    box = np.vstack([box, [[3.0, 1.0 + dy] for dy in np.arange(0, 0.3, 0.04)]])
    sensor = (2.0, 1.1, 0.0)
    costmap.update_obstacles(box, sensor)
    assert costmap.cost_at(np.array([[3.0, 1.1]]))[0] == LETHAL
    assert not costmap.is_traversable(np.array([[2.85, 1.1]]))[0]
    # blocked for the planner too
    r = plan_path(costmap, (2.0, 1.1), (3.1, 1.1))
    assert r.reason != "ok"
    # the box went away: scans of the empty room from two places see through its cells
    for pose in [(2.0, 1.1, 0.0), (3.5, 2.0, 0.3)]:
        costmap.update_obstacles(_scan_points(plan, pose), pose)
    assert not costmap.obstacles[costmap.geometry.to_cell(box)].any()
    assert costmap.cost_at(np.array([[3.1, 1.1]]))[0] == 0
    assert plan_path(costmap, (2.0, 1.1), (3.1, 1.1)).reason == "ok"


# ---------------------------------------------------------------- planner


def test_plan_through_the_doorway(costmap):
    ms = [plan_path(costmap, START, KITCHEN).ms for _ in range(15)]
    r = plan_path(costmap, START, KITCHEN)
    assert r.reason == "ok" and r.path is not None
    print(f"house plan: {r.length:.2f} m, median {np.median(ms):.1f} ms, {len(r.path)} points")
    np.testing.assert_allclose(r.path[0], START)
    np.testing.assert_allclose(r.path[-1], KITCHEN)
    # through the doorway: crossing the middle wall's line within the opening
    i = int(np.argmin(np.abs(r.path[:, 0] - 5.0)))
    assert 1.55 < r.path[i, 1] < 2.45
    # never through lethal or inscribed cells (sampled densely: the spacing is 5 cm)
    assert costmap.cost_at(r.path).max() < INSCRIBED
    assert np.max(np.hypot(*np.diff(r.path, axis=0).T)) <= 0.051
    via = math.dist(START, DOORWAY) + math.dist(DOORWAY, KITCHEN)
    assert r.length <= 1.15 * via
    assert len(r.headings) == len(r.path)


def test_path_cost_is_the_length_in_the_open_and_more_near_obstacles(costmap):
    cfg = PlannerConfig()
    r = plan_path(costmap, START, KITCHEN)
    cost = path_cost(costmap, r.path, cfg)
    # every cell costs at least its length (factor 1), at most 1 + cost_weight
    assert r.length <= cost <= (1.0 + cfg.cost_weight) * r.length
    # the same path's costs add up when it is cut in two
    k = len(r.path) // 2
    halves = path_cost(costmap, r.path[: k + 1], cfg) + path_cost(costmap, r.path[k:], cfg)
    assert halves == pytest.approx(cost, rel=1e-3)
    # along a wall (20 cm from the south wall, inside its inflation) it costs more than
    # its length; in the middle of the room, its length
    along = np.array([[1.0, 0.2], [3.0, 0.2]])
    middle = np.array([[1.0, 1.2], [3.0, 1.2]])
    assert path_cost(costmap, along, cfg) > 2.0 * 1.5
    assert path_cost(costmap, middle, cfg) == pytest.approx(2.0, rel=0.05)
    assert path_cost(costmap, along[:1], cfg) == 0.0


def test_plan_refusals(plan, costmap):
    assert plan_path(costmap, START, (4.98, 0.8)).reason == "goal in an obstacle"
    assert plan_path(costmap, START, (12.0, 2.0)).reason == "goal off the map"
    assert plan_path(costmap, START, (-5.0, 2.0)).reason == "goal off the map"
    ys = np.arange(1.3, 2.71, 0.03)
    wall = np.stack([np.full_like(ys, 5.0), ys], axis=1)
    costmap.update_obstacles(wall, (4.0, 2.0, 0.0))
    assert plan_path(costmap, START, KITCHEN).reason == "no path"
    assert plan_path(costmap, START, (2.5, 2.0)).reason == "ok"


def test_start_near_a_wall_escapes(costmap):
    start = (2.0, 0.12)  # after a grasp: the centre 0.07 m from the wall's surface
    assert costmap.cost_at(np.array([start]))[0] >= INSCRIBED
    r = plan_path(costmap, start, (3.0, 2.0))
    assert r.reason == "ok"
    c = costmap.cost_at(r.path)
    out = int(np.argmax(c < INSCRIBED))  # once out of the inscribed zone it stays out
    # it steps straight out: no farther than the inscribed radius less its distance to the wall
    assert out * 0.05 <= costmap.config.robot_radius - 0.07 + 0.05
    assert c[out:].max() < INSCRIBED and c.max() < LETHAL


# ------------------------------------------------------------ kinematic sim


class LeggedBase:
    """Unicycle + strafe body with a first-order velocity lag, noise (the gait's creep)
    and a command deadband, integrated at 200 Hz."""

    def __init__(self, pose, lag=0.25, noise=0.01, deadband=0.0, deadband_wz=0.0, seed=0):
        self.pose = tuple(pose)
        self.v = np.zeros(3)
        self.lag, self.noise = lag, noise
        self.dead = np.array([deadband, deadband, deadband_wz])
        self.rng = np.random.default_rng(seed)

    def step(self, cmd, dt=0.05, sub=10):
        cmd = np.asarray(cmd, dtype=float)
        cmd = np.where(np.abs(cmd) >= self.dead, cmd, 0.0)
        creep = self.rng.uniform(-self.noise, self.noise, 3)
        h = dt / sub
        a = 1.0 - math.exp(-h / self.lag)
        for _ in range(sub):
            self.v += a * (cmd - self.v)
            vx, vy, wz = self.v + creep
            self.pose = compose(self.pose, (vx * h, vy * h, wz * h))
        return self.pose


def test_follower_reaches_random_goals(costmap):
    cfg = FollowerConfig()
    follower = PathFollower(cfg, costmap_collision_check(costmap))
    rng = np.random.default_rng(7)
    base = LeggedBase((*START, 0.0), seed=3)
    goals = []
    while len(goals) < 10:
        xy = rng.uniform([0.3, 0.3], [9.7, 3.7])
        side = len(goals) % 2  # alternate rooms
        if (xy[0] < 5.0) != (side == 0) or costmap.clearance(xy[None])[0] < 0.4:
            continue
        goals.append((float(xy[0]), float(xy[1]), float(rng.uniform(-math.pi, math.pi))))
    results, worst_cost, dt = [], 0, 0.05
    for goal in goals:
        r = plan_path(costmap, base.pose[:2], goal[:2])
        assert r.reason == "ok", r.reason
        start_yaw = base.pose[2]
        follower.reset()
        t, done = 0.0, False
        while t < 120.0:
            pose = base.pose
            cmd = follower.command(
                pose, r.path, goal[2], float(costmap.clearance(np.array([pose[:2]]))[0])
            )
            assert not cmd.blocked
            if cmd.done:
                done = True
                break
            base.step((cmd.vx, cmd.vy, cmd.wz), dt)
            worst_cost = max(worst_cost, int(costmap.cost_at(np.array([base.pose[:2]]))[0]))
            t += dt
        assert done, f"no arrival at {goal}"
        for _ in range(10):  # zero commands: the lag and the creep settle
            base.step((0.0, 0.0, 0.0), dt)
        exy = math.dist(base.pose[:2], goal[:2])
        eyaw = abs(wrap(base.pose[2] - goal[2]))
        # turning: onto the path, and from its last heading to the goal's yaw
        h = r.headings
        turns = abs(wrap(h[0] - start_yaw)) + abs(wrap(goal[2] - h[-1]))
        turn_time = turns / cfg.max_wz
        # + the time to reach top speed and to stop from it (at 0.8 m/s, 0.8 s each: on
        # a 2 m walk that is a third of the time)
        budget = 1.3 * (r.length / cfg.max_vx + turn_time) + 2.0 * cfg.max_vx / cfg.max_ax
        results.append((r.length, t, budget, exy, eyaw))
        assert exy <= 0.05 and eyaw <= math.radians(3), (goal, exy, math.degrees(eyaw))
    for length, t, budget, exy, eyaw in results:
        print(
            f"len {length:5.2f} m  t {t:5.2f} s  budget {budget:5.2f} s  "
            f"err {exy * 100:.1f} cm {math.degrees(eyaw):.1f} deg"
        )
    print(f"worst cost at the robot's centre: {worst_cost}")
    assert worst_cost < LETHAL
    assert all(t <= b for _, t, b, _, _ in results)


def test_the_first_turn_sets_off_in_the_open_and_turns_on_the_spot_by_furniture():
    cfg = FollowerConfig()
    follower = PathFollower(cfg)
    path = np.stack([np.arange(2.0, 4.0, 0.05), np.full(40, 2.0)], axis=1)
    facing_away = (2.0, 2.0, math.pi)  # the path leads off behind the robot
    for clearance, sets_off in (
        (cfg.slow_clearance + 0.2, True),
        (cfg.slow_clearance - 0.1, False),
    ):
        follower.reset()
        for _ in range(10):
            cmd = follower.command(facing_away, path, None, clearance)
        assert cmd.mode == "rotate" and abs(cmd.wz) > 1.0
        if sets_off:  # it steps back toward the path as it turns
            assert cmd.vx < -0.1 and math.hypot(cmd.vx, cmd.vy) <= cfg.rotate_walk_speed + 1e-9
        else:
            assert cmd.vx == 0.0 and cmd.vy == 0.0


def test_collision_check_stops_before_an_obstacle(costmap):
    check = costmap_collision_check(costmap)
    pose = (4.95 - 0.45, 0.8, 0.0)  # facing the middle wall 0.45 m away
    assert check(pose, project_motion(pose, 0.5, 0.0, 0.0, 0.5))
    assert not check(pose, project_motion(pose, -0.3, 0.0, 0.0, 0.5))
    # a path that runs into the wall (a stale plan): the robot stops short of it
    follower = PathFollower(FollowerConfig(), check)
    base = LeggedBase((3.5, 0.8, 0.0), seed=5)
    path = np.stack([np.arange(3.5, 5.6, 0.05), np.full(42, 0.8)], axis=1)
    blocked, worst = 0, 0
    for _ in range(200):
        pose = base.pose
        cmd = follower.command(pose, path, None, float(costmap.clearance(np.array([pose[:2]]))[0]))
        blocked += cmd.blocked
        base.step((cmd.vx, cmd.vy, cmd.wz))
        worst = max(worst, int(costmap.cost_at(np.array([base.pose[:2]]))[0]))
    print(f"stopped at x = {base.pose[0]:.3f} m (wall face 4.95), worst cost {worst}")
    assert blocked > 0 and worst < INSCRIBED
    assert base.pose[0] > 4.5  # it did get near


# ------------------------------------------------------------ final approach


def test_approach_pose():
    p = approach_pose((2.0, 1.0), 0.5, math.pi / 2)
    np.testing.assert_allclose(p, (2.0, 0.5, math.pi / 2), atol=1e-12)


def test_approach_controller_reaches_targets_precisely():
    cfg = ApproachConfig()
    rng = np.random.default_rng(11)
    tol_xy, tol_yaw = 0.01, math.radians(1.0)
    times = []
    for k in range(8):
        start = (0.0, 0.0, float(rng.uniform(-math.pi, math.pi)))
        dist = rng.uniform(0.5, 1.5)
        bearing = rng.uniform(-math.pi, math.pi)
        goal = (
            dist * math.cos(bearing),
            dist * math.sin(bearing),
            float(wrap(start[2] + rng.uniform(-1.0, 1.0))),
        )
        base = LeggedBase(start, deadband=0.02, deadband_wz=0.05, seed=k)
        ctl = ApproachController(cfg)
        t, done = 0.0, False
        while t < 30.0:
            vx, vy, wz, done = ctl.command(base.pose, goal, tol_xy, tol_yaw)
            if done:
                break
            base.step((vx, vy, wz))
            t += 0.05
        assert done, f"target {goal} not reached"
        assert not ctl.stalled  # converging approaches never count as stalled
        exy = math.dist(base.pose[:2], goal[:2])
        eyaw = abs(wrap(base.pose[2] - goal[2]))
        times.append(t)
        print(
            f"approach {dist:.2f} m in {t:.2f} s: {exy * 1000:.1f} mm {math.degrees(eyaw):.2f} deg"
        )
        assert exy <= tol_xy and eyaw <= tol_yaw
    assert max(times) < 20.0


def test_every_walk_and_approach_command_is_one_locomotion_accepts():
    # locomotion rejects a command beyond its limits whole, and the robot stands: at
    # 0.5 m/s an approach asked for vy up to 0.46 m/s (limit 0.4) and stood 10 s, four
    # times in seed-116's trial. The configured caps, and the commands themselves.
    from quadmanip.common.config import load_config, load_toml
    from quadmanip.services.navigation.config import NavigationConfig

    lim = load_toml("locomotion")["limits"]
    nav = load_config(NavigationConfig, "navigation")
    f, a = nav.follower, nav.approach
    assert f.max_vx <= lim["vx"] and f.max_vy <= lim["vy"] and f.max_wz <= lim["wz"]
    assert a.max_vy <= lim["vy"] and min(a.max_speed, lim["vx"]) == a.max_speed
    assert a.max_wz <= lim["wz"]
    rng = np.random.default_rng(5)
    worst = np.zeros(3)
    for k in range(12):
        start = (0.0, 0.0, 0.0)
        bearing = math.pi / 2 * (1 if k % 2 else -1) + rng.uniform(-0.6, 0.6)  # sideways
        dist = rng.uniform(0.3, 1.0)
        goal = (dist * math.cos(bearing), dist * math.sin(bearing), rng.uniform(-1.0, 1.0))
        base = LeggedBase(start, deadband=0.02, deadband_wz=0.05, seed=k)
        ctl = ApproachController(a)
        for _ in range(300):
            vx, vy, wz, done = ctl.command(base.pose, goal, 0.01, math.radians(1.0))
            if done:
                break
            worst = np.maximum(worst, np.abs((vx, vy, wz)))
            base.step((vx, vy, wz))
        assert done, f"target {goal} not reached"
    print(f"largest commands: vx {worst[0]:.3f} vy {worst[1]:.3f} wz {worst[2]:.3f}")
    assert worst[1] > 0.8 * a.max_vy  # (the sideways cap was met: this tests it)
    assert worst[0] <= lim["vx"] + 1e-9 and worst[1] <= lim["vy"] + 1e-9
    assert worst[2] <= lim["wz"] + 1e-9


def test_an_approach_that_turns_as_it_walks_keeps_to_its_straight_line():
    # the turned stances of free_approach_heading are checked along the straight way to
    # them; turning 2.5 rad on the way, the approach used to bow 6.6 cm off it (its
    # commands acted in a base frame turned by wz x lag), into a sofa's corner
    cfg = ApproachConfig()
    start, goal = (0.8, 1.2, 0.0), (1.2, 2.4, 2.55)
    a, b = np.array(start[:2]), np.array(goal[:2])
    u = (b - a) / np.linalg.norm(b - a)
    for turn in (1.0, -1.0):
        g = (goal[0], goal[1], turn * goal[2])
        base = LeggedBase(start, noise=0.0, deadband=0.02, deadband_wz=0.05)
        ctl = ApproachController(cfg)
        off, t, done = 0.0, 0.0, False
        while t < 20.0 and not done:
            vx, vy, wz, done = ctl.command(base.pose, g, 0.02, 0.035)
            base.step((vx, vy, wz))
            d = np.array(base.pose[:2]) - a
            off = max(off, abs(float(d[0] * u[1] - d[1] * u[0])))
            t += 0.05
        assert done
        # (1.9-2.3 cm at 0.35 m/s and 0.8 rad/s, 2.6-3.6 cm at 0.5 m/s and 1.0 rad/s: well
        # inside the 10 cm the turned stances keep clear, ``free_margin``)
        assert off < 0.04, f"{off * 100:.1f} cm off the straight way"


class StoppingBase(LeggedBase):
    """A legged base that stands after 0.3 s of zero commands: its creep stops and, as the
    last feet land and the balance centres the trunk over them, it shifts up to 8 mm.
    Standing, a command within the deadband moves the trunk over its feet (locomotion's
    nudge: exact, up to ``reach`` from where the robot stopped; ``reach=0``: no nudges).
    A trot started from standing first kicks the trunk up to ``kick`` in any direction
    (measured in-process: 5-16 mm per stop and go, often not the way it was told)."""

    def __init__(self, pose, seed=0, reach=0.04, kick=0.0, **kw):
        super().__init__(pose, seed=seed, **kw)
        self.idle = 0.0
        self.standing = True
        self.reach, self.kick = reach, kick
        self.offset = np.zeros(3)  # the trunk's nudge from where it stopped (base frame)

    def step(self, cmd, dt=0.05, sub=10):
        raw = np.asarray(cmd, dtype=float)
        cmd = np.where(np.abs(raw) >= self.dead, raw, 0.0)
        self.idle = self.idle + dt if not np.any(cmd) else 0.0
        if self.standing and not np.any(cmd):
            off = self.offset + raw * dt
            n = math.hypot(off[0], off[1])
            if n > self.reach:
                off[:2] *= self.reach / n if n > 0.0 else 0.0
            move = off - self.offset
            self.offset = off
            self.pose = compose(self.pose, (float(move[0]), float(move[1]), float(move[2])))
            return self.pose
        if self.standing and self.kick > 0.0:
            a = self.rng.uniform(-math.pi, math.pi)
            r = self.rng.uniform(0.5, 1.0) * self.kick
            self.pose = compose(self.pose, (r * math.cos(a), r * math.sin(a), 0.0))
        self.offset = np.zeros(3)
        if self.idle >= 0.3:
            shift = self.rng.uniform(-0.008, 0.008, 2)
            self.pose = compose(self.pose, (float(shift[0]), float(shift[1]), 0.0))
            self.v[:] = 0.0
            self.standing = True
            return self.pose
        self.standing = False
        return super().step(cmd, dt, sub)


def test_the_approach_ends_standing_within_tolerance():
    """Told whether the robot stands, the approach says done only while it stands, so the
    stance shift of the stop is inside the result; without it (and without the aim's
    margin), 'done' came while trotting and the stop moved the robot out of the tolerance."""
    tol_xy, tol_yaw = 0.01, math.radians(1.0)
    rng = np.random.default_rng(5)
    out_without = 0
    for k in range(8):
        goal = (float(rng.uniform(0.5, 1.2)), float(rng.uniform(-0.4, 0.4)), 0.3)
        for told in (True, False):
            base = StoppingBase((0.0, 0.0, 0.0), deadband=0.02, deadband_wz=0.05, seed=k)
            ctl = ApproachController(ApproachConfig() if told else ApproachConfig(aim=1.0))
            t, done = 0.0, False
            while t < 30.0 and not done:
                standing = base.standing if told else None
                vx, vy, wz, done = ctl.command(base.pose, goal, tol_xy, tol_yaw, standing=standing)
                if not done:
                    base.step((vx, vy, wz))
                t += 0.05
            assert done, (k, told)
            for _ in range(10):  # nothing more is commanded: the robot stops and stands
                base.step((0.0, 0.0, 0.0))
            err = math.dist(base.pose[:2], goal[:2])
            if told:
                assert base.standing and err <= tol_xy, (k, err)
            else:
                out_without += err > tol_xy
    assert out_without >= 1


def test_the_last_centimetres_are_nudged_standing_not_stepped():
    """Where each stop and go kicks the trunk up to 1.6 cm any way, stepping the last
    centimetres is a random walk that ends wherever it is within the tolerance after the
    patience; nudging the standing trunk ends within millimetres, sooner. (Here without
    nudges, reach 0: errors up to 9.7 mm, approaches up to 11.9 s.)"""
    tol_xy, tol_yaw = 0.01, math.radians(1.0)
    worst = {}
    for reach in (0.04, 0.0):
        rng = np.random.default_rng(3)
        errs, times = [], []
        for k in range(10):
            goal = (float(rng.uniform(0.5, 1.2)), float(rng.uniform(-0.4, 0.4)), 0.3)
            base = StoppingBase(
                (0.0, 0.0, 0.0), deadband=0.02, deadband_wz=0.05, seed=k, reach=reach, kick=0.016
            )
            ctl = ApproachController(ApproachConfig())
            t, done = 0.0, False
            while t < 30.0 and not done:
                vx, vy, wz, done = ctl.command(
                    base.pose, goal, tol_xy, tol_yaw, standing=base.standing
                )
                if not done:
                    base.step((vx, vy, wz))
                t += 0.05
            assert done and base.standing, (reach, k)
            errs.append(math.dist(base.pose[:2], goal[:2]))
            times.append(t)
        worst[reach] = (max(errs), max(times))
    assert worst[0.04][0] <= 0.3 * tol_xy, worst
    assert worst[0.0][0] > 0.5 * tol_xy, worst  # the kicks are what the nudges remove
    assert worst[0.04][1] < worst[0.0][1], worst


def _approach_run(cfg: ApproachConfig, goal: tuple[float, float, float], seed: int):
    """One approach of a StoppingBase from the origin: (time, overshoot past the goal
    along the start-goal line, final error)."""
    base = StoppingBase((0.0, 0.0, 0.0), deadband=0.02, deadband_wz=0.05, seed=seed)
    ctl = ApproachController(cfg)
    line = np.array(goal[:2]) / math.hypot(goal[0], goal[1])
    t, done, past = 0.0, False, -math.inf
    while t < 30.0 and not done:
        vx, vy, wz, done = ctl.command(base.pose, goal, 0.015, 0.03, standing=base.standing)
        if not done:
            base.step((vx, vy, wz))
        past = max(past, float(np.dot(np.array(base.pose[:2]) - goal[:2], line)))
        t += 0.05
    assert done, (goal, seed)
    return t, past, math.dist(base.pose[:2], goal[:2])


def test_the_approach_gain_is_what_the_lag_allows_not_less():
    """With the lag-predicted error the loop's poles are -K and -1/lag (module doc): at
    K = 2 the tail decays at 2/s where the 0.25 s lag allows up to 4/s. The default (3)
    is faster than 2 on the task's probing tolerance and still stops short of the goal,
    not past it. (Full stack, ``bench navigation --parts nav --approaches 16``, the same
    targets: median 4.71 s at K = 2, 4.00 s at 3, 4.49 s at 4; true errors alike.)"""
    rng = np.random.default_rng(17)
    goals = [
        (float(rng.uniform(0.4, 0.9)), float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.4, 0.4)))
        for _ in range(10)
    ]
    slow = replace(ApproachConfig(), gain_xy=2.0, gain_yaw=2.0)
    runs = {
        name: [_approach_run(cfg, g, k) for k, g in enumerate(goals)]
        for name, cfg in (("default", ApproachConfig()), ("K2", slow))
    }
    t_default = float(np.median([r[0] for r in runs["default"]]))
    t_slow = float(np.median([r[0] for r in runs["K2"]]))
    assert ApproachConfig().gain_xy * ApproachConfig().lag < 1.0  # below the double pole
    assert t_default <= 0.95 * t_slow, (t_default, t_slow)
    assert max(r[1] for r in runs["default"]) <= 0.015  # not past the goal's tolerance
    assert max(r[2] for r in runs["default"]) <= 0.015


def test_an_approach_taking_over_a_moving_walk_goes_on_at_its_speed():
    """A walk an approach follows ends still under way (behavior's lead-in walks): told
    the body's velocity, the approach's first command keeps it, where from a standing
    start it brakes to the ramp's first step and accelerates again."""
    results = {}
    for told in (True, False):
        times = []
        for k in range(6):
            base = StoppingBase((0.0, 0.0, 0.0), deadband=0.02, deadband_wz=0.05, seed=k)
            base.standing = False
            for _ in range(30):  # trotting at 0.4 m/s
                base.step((0.4, 0.0, 0.0))
            start = base.pose
            goal = compose(start, (0.6, 0.05 * (k - 3), 0.1))
            ctl = ApproachController(ApproachConfig())
            ctl.reset(tuple(base.v) if told else None)
            first = None
            t, done = 0.0, False
            while t < 30.0 and not done:
                vx, vy, wz, done = ctl.command(base.pose, goal, 0.015, 0.03, standing=base.standing)
                first = vx if first is None else first
                if not done:
                    base.step((vx, vy, wz))
                t += 0.05
            assert done and math.dist(base.pose[:2], goal[:2]) <= 0.015
            times.append(t)
            if told:
                assert first >= 0.3, first
            else:
                assert first <= 2 * ApproachConfig().min_speed, first
        results[told] = float(np.median(times))
    assert results[True] < results[False] - 0.2, results


def test_the_final_alignment_nudges_a_standing_robot():
    """``navigate_to``'s last centimetres: told the robot stands 2 cm and 1.5 degrees off,
    the follower sends a nudge (within the trot's deadband, toward the goal) where it
    would otherwise restart the trot at its minimum speed; standing within the
    tolerance it is done at once; out of patience it steps again."""
    cfg = FollowerConfig()
    goal_yaw = math.radians(1.5)
    path = np.array([[-0.5, 0.0], [0.0, 0.0]])
    pose = (-0.02 * math.cos(0.5), -0.02 * math.sin(0.5), 0.0)
    tol = dict(xy_tol=0.01, yaw_tol=math.radians(1.0), dt=0.05)
    stepped = PathFollower(cfg).command(pose, path, goal_yaw, 1.0, **tol)
    assert stepped.mode == "final" and math.hypot(stepped.vx, stepped.vy) >= cfg.final_min_speed
    f = PathFollower(cfg)
    c = f.command(pose, path, goal_yaw, 1.0, standing=True, **tol)
    nudge = NudgeConfig()
    assert not c.done and 0.0 < max(abs(c.vx), abs(c.vy)) <= nudge.speed
    assert math.atan2(c.vy, c.vx) == pytest.approx(0.5, abs=0.05)  # toward the goal
    assert 0.0 < c.wz <= nudge.wz
    for _ in range(round(nudge.patience / 0.05) + 1):
        c = f.command(pose, path, goal_yaw, 1.0, standing=True, **tol)
    assert math.hypot(c.vx, c.vy) > nudge.speed  # out of reach: it steps again
    # standing within the tolerance: nudged onto half of it (the aim), then done
    f = PathFollower(cfg)
    inside = f.command((-0.008, 0.0, goal_yaw), path, goal_yaw, 1.0, standing=True, **tol)
    assert inside.mode == "settle" and not inside.done and 0.0 < inside.vx <= nudge.speed
    on_aim = (-0.004, 0.0, math.radians(1.2))
    assert f.command(on_aim, path, goal_yaw, 1.0, standing=True, **tol).done
    # stopped within it but still stepping: it waits, standing still, at most stop_wait
    f = PathFollower(cfg)
    waits = [
        f.command((-0.008, 0.0, goal_yaw), path, goal_yaw, 1.0, standing=False, **tol)
        for _ in range(round(cfg.stop_wait / 0.05) + 1)
    ]
    assert all(c.vx == c.vy == c.wz == 0.0 for c in waits)
    assert not waits[0].done and waits[-1].done


def test_a_loose_goal_ends_where_the_body_stops_without_waiting_to_stand():
    # the task's walks (10 cm) before an approach steps in precisely; a tight goal
    # (3 cm) waits, standing still, until the robot stands
    cfg = FollowerConfig()
    path = np.array([[-0.5, 0.0], [0.0, 0.0]])
    inside = (-0.02, 0.0, 0.0)
    for tol, ends_at_once in ((0.10, True), (0.03, False)):
        c = PathFollower(cfg).command(
            inside, path, 0.0, 1.0, xy_tol=tol, yaw_tol=0.15, standing=False
        )
        assert c.done == ends_at_once, tol
        assert c.vx == c.vy == c.wz == 0.0


def test_a_pass_through_goal_ends_within_its_tolerance_still_walking():
    """A walk an approach follows (``NavigateGoal.pass_through``) ends the moment the
    robot is within the tolerance, at speed and facing any way; the same loose goal
    otherwise brakes to a near stop and turns to its yaw first."""
    ends = {}
    for through in (True, False):
        f = PathFollower(FollowerConfig())
        base = LeggedBase((0.0, 0.0, 0.0), noise=0.0)
        path = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
        t, c = 0.0, None
        while t < 20.0:
            c = f.command(
                base.pose, path, 1.0 if not through else None, 1.0, xy_tol=0.25,
                yaw_tol=0.15, dt=0.05, pass_through=through,
            )  # fmt: skip
            if c.done:
                break
            base.step((c.vx, c.vy, c.wz))
            t += 0.05
        assert c is not None and c.done
        ends[through] = (t, float(base.v[0]), 2.0 - base.pose[0])
    t_on, v_on, left_on = ends[True]
    assert 0.15 <= left_on <= 0.25 and v_on >= 0.3, ends  # within it, still walking
    t_stop, v_stop, _ = ends[False]
    assert v_stop < 0.25 and t_stop >= t_on + 0.5, ends


def test_planner_config_is_frozen():
    with pytest.raises(AttributeError):
        PlannerConfig().cost_weight = 1.0  # type: ignore[misc]


def test_an_approach_that_makes_no_progress_is_stalled_after_stall_time() -> None:
    """A robot that walks and stands without getting nearer (the tidy-up's walk / stand
    cycles that ran into the 30 s limit) is reported stalled after ``stall_time``; one
    that keeps getting nearer, however slowly, is not."""
    cfg = ApproachConfig()
    goal = (0.5, 0.1, 0.0)
    ctl = ApproachController(cfg)
    t = 0.0
    while t < cfg.stall_time - 1.0:  # stuck 6 cm short: nothing it commands moves it
        ctl.command((0.44, 0.1, 0.0), goal, 0.015, 0.03)
        t += 0.05
    assert not ctl.stalled
    while t < cfg.stall_time + 0.5:
        ctl.command((0.44, 0.1, 0.0), goal, 0.015, 0.03)
        t += 0.05
    assert ctl.stalled and ctl.error[0] == pytest.approx(0.06)
    assert ctl.off() == "6.0 cm and 0.0 deg off"
    slow = ApproachController(cfg)
    x = 0.2
    for _ in range(int(3 * cfg.stall_time / 0.05)):  # 5 mm nearer every 1.5 s: progress
        slow.command((x, 0.1, 0.0), goal, 0.015, 0.03)
        x += 0.005 * 0.05 / 1.5
    assert not slow.stalled
    slow.reset()
    assert not slow.stalled and slow.error[0] == math.inf


def test_paths_go_round_the_tables_the_lidar_sees_only_the_legs_of():
    """paper-4 (2026-12-05): walks from the kitchen table's far side to the boxes were
    planned between its legs, under its top, and ended blocked. The places file's
    keepout areas close the tables; every place's stand stays reachable."""
    from quadmanip.services.navigation.costmap import with_keepouts
    from quadmanip.services.navigation.map_io import load_map
    from quadmanip.services.navigation.node import resolve_map_path
    from quadmanip.services.navigation.places import load_places, places_path_for

    path = resolve_map_path("maps/house.yaml")
    occ, geo = load_map(path)
    places = load_places(places_path_for(path))
    table = places["kitchen_table"]
    assert table.keepout
    x0, y0, x1, y1 = table.area

    def under(p: np.ndarray) -> bool:
        return bool(np.any((p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1)))

    start, box = (7.2, 2.5), places["black_box"].stand[:2]
    bare = plan_path(Costmap(CostmapConfig(), occ, geo), start, box)
    assert bare.path is not None and under(bare.path)  # the map alone: between the legs
    kept = Costmap(CostmapConfig(), with_keepouts(occ, geo, [p.area for p in places.values()
                                                             if p.keepout]), geo)  # fmt: skip
    r = plan_path(kept, start, box)
    assert r.reason == "ok" and r.path is not None and not under(r.path)
    assert r.length > bare.length + 0.5  # round the table's end
    for p in places.values():
        assert kept.is_traversable(np.array([p.stand[:2]]))[0], p.name
    with pytest.raises(ValueError, match="x_min < x_max"):
        with_keepouts(occ, geo, [(1.0, 1.0, 0.5, 2.0)])


# ---------------------------------------------------------------- object layer


def test_paths_go_round_the_floor_objects_perception_has_seen():
    """seed-103 (2026-12-05): a cracker box standing in the living room's way to the
    doorway, below the LiDAR's plane, was walked into and knocked over (lying, it is too
    wide for the gripper). Its track is a disc in the costmap: the path passes it by the
    robot's radius; the track the robot handles (near it) and one at the walk's goal are
    not discs."""
    from quadmanip.services.navigation.map_io import load_map
    from quadmanip.services.navigation.node import resolve_map_path
    from quadmanip.services.navigation.object_layer import ObjectLayerConfig, floor_obstacles
    from quadmanip.services.navigation.places import load_places, places_path_for

    path = resolve_map_path("maps/house.yaml")
    occ, geo = load_map(path)
    places = load_places(places_path_for(path))
    zones = [p.area for p in places.values() if p.kind == "search_floor"]
    cfg = ObjectLayerConfig()
    box = np.array([[3.65, 1.53, 0.105]])  # the cracker box, standing
    ext = np.array([[0.16, 0.08, 0.21]])
    start, goal = (2.2, 1.5), (6.0, 1.8)
    cm = Costmap(CostmapConfig(), occ, geo)
    bare = plan_path(cm, start, goal)
    assert bare.path is not None
    near = np.hypot(*(bare.path - box[0, :2]).T).min()
    assert near < CostmapConfig().robot_radius  # the map alone: the body over the box
    discs = floor_obstacles(box, ext, [True], zones, goal, cfg)
    assert discs == [pytest.approx((3.65, 1.53, 0.13))]
    assert cm.set_objects(discs) and not cm.set_objects(discs)  # rebuilt once
    r = plan_path(cm, start, goal)
    assert r.reason == "ok" and r.path is not None
    clear = np.hypot(*(r.path - box[0, :2]).T).min()
    assert clear >= cfg.margin + 0.08 + CostmapConfig().robot_radius - geo.resolution
    assert not cm.is_traversable(box[:, :2])[0]
    # what is not a disc: near the goal, unconfirmed, on a table, off the zones, exempt
    assert floor_obstacles(box, ext, [True], zones, (3.9, 1.6), cfg) == []
    assert floor_obstacles(box, ext, [False], zones, goal, cfg) == []
    on_table = np.array([[2.6, 3.3, 0.45]])
    assert floor_obstacles(on_table, ext, [True], zones, goal, cfg) == []
    doorway = np.array([[5.0, 2.0, 0.05]])
    assert floor_obstacles(doorway, ext, [True], zones, goal, cfg) == []
    # the box stays a disc however near the robot passes, unless it lay where the walk
    # began and the robot handled it there (exempt; paper-1, 2026-12-06: the disc vanished
    # 0.6 m from the robot, the path ran through it again and the trunk knocked it over)
    assert floor_obstacles(box, ext, [True], zones, goal, cfg, np.array([True])) == []
    # the object gone from the memory: the layer empties, the straight path is back
    assert cm.set_objects([]) and not cm.objects.any()
    assert plan_path(cm, start, goal).length == pytest.approx(bare.length)
    with pytest.raises(ValueError, match="r > 0"):
        cm.set_objects([(1.0, 1.0, 0.0)])


# ---------------------------------------------------------------- approach stance


def test_an_approach_stance_against_furniture_is_turned_about_the_target():
    """seed-106 (2026-12-05): six approaches to floor objects stopped with a return
    against the trunk's front corner (a leg 0.25-0.28 m away at 22-33 degrees), each
    followed by a walk to another side. Facing the target from here, the stance meets a
    post; the approach is turned about the target to the nearest free stance, the way
    to it clear too. The target's own disc in the object layer is no obstacle; another
    object's is."""
    geo = GridGeometry(origin_x=0.0, origin_y=0.0, resolution=0.05, width=80, height=80)
    occ = np.zeros((80, 80), dtype=np.int8)
    post = (1.80, 1.82)  # beside the target, right of the straight line to it
    r, c = geo.to_cell(np.array([post]))
    occ[int(r[0]) - 1 : int(r[0]) + 1, int(c[0]) - 1 : int(c[0]) + 1] = 100
    cm = Costmap(CostmapConfig(), occ, geo)
    target, standoff, start = (2.0, 2.0), 0.36, (1.2, 2.0, 0.0)
    assert cm.set_objects([(target[0], target[1], 0.1)])
    lethal = cm.lethal_except_near(target, 0.25)
    assert cm.lethal[geo.to_cell(np.array([target]))].all()  # the target is a disc ...
    assert not lethal[geo.to_cell(np.array([target]))].any()  # ... but not to its approach

    cfg = ApproachConfig()
    turns, keep, wide = cfg.free_turns, 0.03, cfg.free_margin

    def free(pose, margin=keep) -> bool:
        return cm.footprint_free(pose, margin, lethal)

    assert not free(approach_pose(target, standoff, 0.0))  # facing it from here: the post
    h = free_approach_heading(free, start, target, standoff, 0.0, turns, keep, wide)
    assert h is not None and h != 0.0 and abs(h) <= max(abs(t) for t in turns)
    stance = approach_pose(target, standoff, h)
    # the post lies outside the approach guard's box about the turned stance
    c_, s_ = math.cos(h), math.sin(h)
    dx, dy = post[0] - stance[0], post[1] - stance[1]
    lx, ly = c_ * dx + s_ * dy, -s_ * dx + c_ * dy
    cc = CostmapConfig()
    assert abs(lx) > cc.footprint_length / 2 + wide or abs(ly) > cc.footprint_width / 2 + wide

    # the way counts, not only the stance: something halfway along the straight way
    # (within 0.1 m of (1.42, 2.0)) rules out the straight stance and the 0.35 rad turns,
    # whose ways pass 6 cm from it; the first turn whose way passes clear is 0.7 rad
    def clear_of_it(p, m) -> bool:
        return math.hypot(p[0] - 1.42, p[1] - 2.0) > 0.1

    assert free_approach_heading(clear_of_it, start, target, standoff, 0.0, turns, keep,
                                 wide) == pytest.approx(0.7)  # fmt: skip

    # no turn clear by the wide margin, the straight stance not even by the guard's: the
    # first turn free by the guard's margin (grazing, rather than meeting the post)
    def narrow_only(p, m) -> bool:  # the straight stance is (1.64, 2.0)
        return m <= keep and math.hypot(p[0] - 1.64, p[1] - 2.0) > 0.05

    assert free_approach_heading(narrow_only, start, target, standoff, 0.0, turns, keep,
                                 wide) == pytest.approx(0.35)  # fmt: skip
    # nowhere free: None (the caller keeps its heading and the guard)
    never, always = (lambda p, m: False), (lambda p, m: True)
    assert free_approach_heading(never, start, target, standoff, 0.0, turns, keep, wide) is None
    # free ahead: the heading itself
    assert free_approach_heading(always, start, target, standoff, 0.3, turns, keep, wide) == 0.3


def _house_costmap():
    """(navigation config, costmap of the committed house map with its keepouts, the
    map's occupancy, the places), as the node builds them."""
    from quadmanip.common.config import load_config
    from quadmanip.services.navigation.config import NavigationConfig
    from quadmanip.services.navigation.costmap import with_keepouts
    from quadmanip.services.navigation.map_io import load_map
    from quadmanip.services.navigation.node import resolve_map_path
    from quadmanip.services.navigation.places import load_places, places_path_for

    nav = load_config(NavigationConfig, "navigation")
    path = resolve_map_path(nav.node.map)
    occ, geo = load_map(path)
    places = load_places(places_path_for(path))
    static = with_keepouts(occ, geo, [p.area for p in places.values() if p.keepout])
    return nav, Costmap(nav.costmap, static, geo), occ, places


def test_a_table_stance_by_a_leg_turns_about_the_object_nose_under_the_top():
    # paper-5 (2026-12-06): a mug 13 cm in from the kitchen table's west end, 20 cm from
    # its edge. Square to the table the trunk stands on the leg at the corner; the keepout
    # of the table (its top lies above the LiDAR) holds every stance near it, so the
    # turned stances were never tried. With the nose allowed in under the top (not the
    # trunk's middle) a stance turned toward the table's middle is clear of the leg.
    from quadmanip.services.navigation.approach import stance_clear

    nav, cm, occ, places = _house_costmap()
    under_top = cm.static_lethal & ~(occ >= nav.costmap.occupied_threshold)
    table = places["kitchen_table"]
    mug, square, standoff = (6.881, 2.005), table.stand[2], 0.36
    guard, margin = nav.node.approach_guard, nav.approach.free_margin
    start = table.stand

    def free(pose, m, nose_in=under_top):
        return stance_clear(cm, cm.lethal, pose, m, nose_in)

    square_stance = approach_pose(mug, standoff, square)
    assert not free(square_stance, guard)  # the leg
    assert not free(square_stance, guard, None)  # (and the keepout)
    h = free_approach_heading(free, start, mug, standoff, square, nav.approach.free_turns,
                              guard, margin)  # fmt: skip
    assert h is not None and 0.3 < abs(wrap(h - square)) < 1.1, h
    stance = approach_pose(mug, standoff, h)
    assert stance[0] > mug[0]  # moved toward the table's middle, away from the leg
    assert stance[1] > table.area[3]  # its middle outside the table's top
    # without the nose rule nothing near the table is free: the square stance it keeps
    keep = free_approach_heading(
        lambda p, m: free(p, m, None), start, mug, standoff, square, nav.approach.free_turns,
        guard, margin,
    )  # fmt: skip
    assert keep is None


def test_a_floor_stance_grazing_a_table_leg_turns_clear_of_it():
    # paper-1 (2026-12-07): the Rubik's cube on the kitchen floor, 26 cm east of the
    # deposit table's legs. Faced from the south (82 deg here) the stance is clear of a
    # leg by the approach guard's 3 cm but not by 10 cm, so it was kept; in the trial
    # approach after approach stopped "an obstacle touches the footprint". A stance clear
    # by the turned stances' margin is now preferred to the asked heading grazing
    from quadmanip.services.navigation.approach import stance_clear

    nav, cm, occ, places = _house_costmap()
    cube, standoff, start = (8.158, 3.592), 0.36, (8.0, 2.5, 1.4)
    lethal = cm.lethal_except_near(cube, nav.objects.max_radius + 0.05)
    guard, margin = nav.node.approach_guard, nav.approach.free_margin

    def free(pose, m):
        return stance_clear(cm, lethal, pose, m)

    asked = math.atan2(cube[1] - start[1], cube[0] - start[0])  # facing it: 82 deg
    grazing = approach_pose(cube, standoff, asked)
    assert free(grazing, guard) and not free(grazing, margin)
    h = free_approach_heading(free, start, cube, standoff, asked, nav.approach.free_turns,
                              guard, margin)  # fmt: skip
    assert h is not None and h != asked
    assert free(approach_pose(cube, standoff, h), margin)
    assert abs(wrap(h - asked)) <= 0.7  # the nearest clear turn (measured: +20 deg)


def _node_on_the_house_map():
    """A navigation node (no transport) holding the committed house map as it loads it,
    odometry = map."""
    from types import SimpleNamespace

    from quadmanip.services.navigation.costmap import area_mask
    from quadmanip.services.navigation.node import NavigationNode
    from quadmanip.services.navigation.places import TABLE_KINDS

    nav, cm, occ, places = _house_costmap()
    node = NavigationNode.__new__(NavigationNode)
    node.config, node.costmap, node.map_to_odom = nav, cm, (0.0, 0.0, 0.0)
    node.keepout_only = cm.static_lethal & ~(occ >= nav.costmap.occupied_threshold)
    tops = [p.area for p in places.values() if p.kind in TABLE_KINDS]
    node.table_tops = area_mask(cm.geometry, tops)
    node.log = SimpleNamespace(info=lambda *a, **k: None)
    return node


def test_an_approach_whose_stance_meets_furniture_from_where_it_stands_ends_before_it_sets_off():
    # paper-1 (2026-12-07, every run): after a place at the deposit table the robot stood
    # at (7.61, 3.15) facing north, the Rubik's cube 0.6 m east on the floor beside the
    # table's leg. Facing the cube, the trunk stood on the leg; no stance turned about the
    # cube was clear on the way from there, so the asked one was kept: the approach pushed
    # against the leg and the top for 20 s until "no progress", then the task walked to
    # another side. Now it ends at once, so the task walks there at once.
    node = _node_on_the_house_map()
    cube, standoff, start = (8.158, 3.592), 0.356, (7.61, 3.15, math.pi / 2)
    asked = math.atan2(cube[1] - start[1], cube[0] - start[0])  # 38 deg
    assert node._free_heading(cube, standoff, asked, start) == (asked, True)
    # from the south, where the task's walk brought it: a turned stance, set off to
    south = (8.0, 2.5, 1.4)
    asked = math.atan2(cube[1] - south[1], cube[0] - south[0])
    heading, meets = node._free_heading(cube, standoff, asked, south)
    assert not meets and heading != asked
    # a step in (the stance within 0.2 m) goes on: its guard stops it if it must. (One
    # turn, as blocked: the step in is 0.1 m behind the stance facing 38 deg, 0.2 m more
    # from the start)
    cfg = node.config
    node.config = replace(cfg, approach=replace(cfg.approach, free_turns=(0.02,)))
    facing = math.atan2(cube[1] - start[1], cube[0] - start[0])
    near = approach_pose(cube, standoff + 0.1, facing)
    assert node._free_heading(cube, standoff, facing, near) == (facing, False)
    back = approach_pose(cube, standoff + 0.2, facing)
    assert node._free_heading(cube, standoff, facing, back) == (facing, True)
    # in under a keepout table's top with the nose (an object on it): never "meets"
    assert node._free_heading(cube, standoff, facing, start, nose_in=True) == (facing, False)


def test_an_approach_stance_keeps_its_trunk_from_under_the_deposit_tables_top():
    # the deposit table is no keepout (its boxes' stances come within 1 cm of its edge),
    # so only its legs were in the stances' costmap; the LiDAR housing and the arm stand
    # above its top's underside. A floor object 0.2 m south of its middle, faced from the
    # north-west: a stance between the legs, the trunk under the top, is not taken.
    from quadmanip.services.navigation.approach import stance_clear

    node = _node_on_the_house_map()
    cm = node.costmap
    thing, standoff, asked = (7.0, 3.25), 0.36, -math.pi / 4
    under = approach_pose(thing, standoff, asked)
    assert stance_clear(cm, cm.lethal, under, node.config.node.approach_guard)  # legs only
    assert not stance_clear(cm, cm.lethal | node.table_tops, under, 0.0)
    heading, meets = node._free_heading(thing, standoff, asked, (6.3, 2.8, 0.0))
    assert not meets and heading != asked
    x, y, h = approach_pose(thing, standoff, heading)
    half_length, half_width = 0.5 * cm.config.footprint_length, 0.5 * cm.config.footprint_width
    north = y + half_length * abs(math.sin(h)) + half_width * abs(math.cos(h))
    assert north < 3.45, (math.degrees(h), north)  # the trunk south of the top's edge


def test_a_walk_keeps_the_floor_objects_it_passes_but_not_those_where_it_began():
    # paper-1 (2026-12-06): the node left out every track within 0.6 m of the robot at
    # each scan (the rule for the object it handles or holds): the disc of a standing
    # cracker box vanished as a walk came near, and the box was knocked over
    from types import SimpleNamespace

    from quadmanip.common import messages as m
    from quadmanip.services.navigation.config import NavigationConfig
    from quadmanip.services.navigation.node import NavigationNode

    plan = true_floor_plan()
    node = NavigationNode.__new__(NavigationNode)
    node.config = NavigationConfig()
    node.map_to_odom = (0.0, 0.0, 0.0)
    node.costmap = _costmap(plan)
    node.floor_zones = [(1.0, 0.5, 4.0, 2.5)]
    box = (2.3, 1.45)
    tracks = m.ObjectTracks(
        stamp=0.0, ids=np.array([9]), labels=["cracker_box"],
        centroids=np.array([[*box, 0.105]]),
        extents=np.array([[0.16, 0.08, 0.21]], dtype=np.float32),
        confidences=np.array([0.9], dtype=np.float32), observations=np.array([9]),
        last_seen=np.array([0.0]), confirmed=np.array([1], dtype=np.uint8),
        map_centroids=np.array([[*box, 0.105]]), in_map=True,
    )  # fmt: skip
    node.objects_cache = SimpleNamespace(get=lambda: tracks)
    node.navigator = SimpleNamespace(goal=None)
    node.walk_exempt = set()
    node.job = None
    beside = (box[0] - 0.4, box[1] - 0.1, 0.0)  # the robot 0.41 m from the box

    def disc_there() -> bool:
        node._update_objects()
        return bool(node.costmap.objects.any())

    # standing by it, no walk: a disc (an approach's stance check leaves its own target
    # out; paper-4, 2026-12-07: a stance's way past a neighbour 0.58 m off was taken clear)
    assert disc_there()
    node.navigator.goal = SimpleNamespace(pose=(3.8, 1.2, 0.0), objects_off=False)
    assert disc_there()  # walking past it: an obstacle however near
    assert node._tracks_near(beside) == {9}  # ahead, 0.41 m: what it handles
    node.walk_exempt = node._tracks_near(beside)  # a walk that began beside it
    assert not disc_there()
    assert node._tracks_near((0.8, 1.2, 0.0)) == set()
    # 0.5 m off but 50 deg to the side: a neighbour, not what it handles (paper-4,
    # 2026-12-07: a cracker box 0.53 m and 46 deg off the padlock's stance, left out of the
    # walk that turned away from it, was found lying)
    side = (box[0] - 0.5 * math.cos(0.87), box[1] - 0.5 * math.sin(0.87), 0.0)
    assert node._tracks_near(side) == set()
    assert node._tracks_near((box[0] - 0.25, box[1] - 0.1, 2.0)) == {9}  # at the trunk


def test_a_straight_way_meeting_a_floor_object_is_led_in_from_behind_the_stance():
    # paper-5 (2026-12-07), as the trial's logs have it (map frame): the robot stood at
    # (2.84, 2.19) facing west, to approach the bowl at (2.94, 3.19) on the living table's
    # edge, square to the table (north), 0.36 m short; a soup can lay on the floor at
    # (2.69, 2.61). The straight way passed 0.2 m beside it and the trunk kicked it under
    # the table. Now the approach walks to behind the stance first, and comes in north.
    node = _node_on_the_house_map()
    bowl, start, can = (2.94, 3.19), (2.84, 2.19, 3.09), (2.69, 2.61)
    stance = approach_pose(bowl, 0.36, math.pi / 2)
    assert node._lead_in(bowl, stance, start) == (False, None)  # no objects: straight
    node.costmap.set_objects([(*can, 0.083)])
    meets, lead = node._lead_in(bowl, stance, start)
    assert meets and lead is not None
    assert lead[0] == pytest.approx(stance[0]) and lead[2] == pytest.approx(math.pi / 2)
    back = stance[1] - lead[1]
    assert min(abs(back - b) for b in node.config.approach.lead_backs) < 1e-9
    # from the lead-in the way north passes the can clear of the trunk and its feet
    assert abs(lead[0] - can[0]) - 0.5 * node.costmap.config.footprint_width > 0.083
    # already behind the stance: straight in
    assert node._lead_in(bowl, stance, (stance[0], stance[1] - 0.6, math.pi / 2)) == (
        False,
        None,
    )
    # the bowl's own disc is no obstacle to its approach (on the floor, the target)
    node.costmap.set_objects([(*bowl, 0.1)])
    assert node._lead_in(bowl, stance, start) == (False, None)


def test_lead_in_pose_tries_its_backs_in_order_and_needs_the_way_in_clear():
    from quadmanip.services.navigation.approach import lead_in_pose, straight_way

    stance = (2.0, 0.0, 0.0)
    way = straight_way((0.0, 0.0, math.pi), stance, step=0.1)
    assert way[-1] == stance and len(way) == 21
    assert all(abs(b[0] - a[0]) <= 0.1 + 1e-9 for a, b in zip(way, way[1:], strict=False))
    assert way[10][2] == pytest.approx(math.pi / 2)  # the heading turns evenly

    def clear_of(x0: float, x1: float, y0: float, y1: float):
        return lambda p: not (x0 <= p[0] <= x1 and y0 <= p[1] <= y1)

    # an object halfway, on the way from (0, 1): led in from 0.45 m behind
    obj = clear_of(0.9, 1.1, 0.4, 0.6)
    meets, lead = lead_in_pose(obj, lambda p: True, (0.0, 1.0, 0.0), stance, (0.45, 0.6))
    assert meets and lead == pytest.approx((1.55, 0.0, 0.0))
    # that one taken (the robot may not stand there): the next
    meets, lead = lead_in_pose(obj, lambda p: p[0] < 1.5, (0.0, 1.0, 0.0), stance, (0.45, 0.6))
    assert meets and lead == pytest.approx((1.4, 0.0, 0.0))
    # an object on the stance's own line in: no lead-in is clear
    on_line = clear_of(1.5, 1.8, -0.1, 0.3)
    assert lead_in_pose(on_line, lambda p: True, (0.0, 1.0, 0.0), stance, (0.45, 0.6)) == (
        True,
        None,
    )
    # where the robot stands (the first quarter of the way) does not count
    at_start = clear_of(-0.1, 0.1, 0.9, 1.1)
    assert lead_in_pose(at_start, lambda p: True, (0.0, 1.0, 0.0), stance, (0.45,)) == (
        False,
        None,
    )


def test_a_stance_standing_on_a_floor_object_turns_to_a_clear_one():
    # paper-4 (2026-12-07), map frame from the log: facing the padlock from where the walk
    # ended, the stance stood 0.17 m from a standing cracker box. No heading had a clear
    # straight way too (the way from there passes the box), so the asked one was kept and
    # the box was knocked flat. Now the nearest heading whose stance is clear is taken;
    # the lead-in walks round the box to it.
    node = _node_on_the_house_map()
    pad, box, start, standoff = (2.71, 2.24), (2.89, 2.54), (3.50, 2.71), 0.358
    asked = math.atan2(pad[1] - start[1], pad[0] - start[0])
    here = (*start, 2.68)  # (as logged: the walk's heading, 57 deg off the asked one)
    assert node._free_heading(pad, standoff, asked, here) == (asked, False)  # nothing there
    node.costmap.set_objects([(*box, 0.13)])
    assert node._stance_on_object(pad, approach_pose(pad, standoff, asked))
    heading, meets = node._free_heading(pad, standoff, asked, here)
    stance = approach_pose(pad, standoff, heading)
    assert not meets and heading != asked
    assert not node._stance_on_object(pad, stance)
    assert math.dist(stance[:2], box) > 0.4
    # its straight way from there is clear of the box: no lead-in needed
    assert node._lead_in(pad, stance, here) == (False, None)
