"""The navigate-to state machine (services/navigation/navigator.py) closed-loop with a
kinematic body (0.25 s velocity lag, creep) on the true floor plan: it reaches goals
through the doorway, passes an obstacle that is not in the map, gives up on a blocked
doorway within the issue's 30 s with a reason, and says ``no_path`` at once for a goal the
map cannot reach."""

from __future__ import annotations

import math

import numpy as np
import pytest
from quadmanip.services.navigation.costmap import Costmap, CostmapConfig
from quadmanip.services.navigation.grid import GridGeometry, Pose2, compose, transform_points
from quadmanip.services.navigation.navigator import Navigator, NavigatorConfig
from quadmanip.services.navigation.path_follower import FollowerConfig
from quadmanip.services.navigation.scan import lidar_mount, scan_points
from quadmanip.testbench.floor_plan import FloorPlan, simulate_scan, true_floor_plan

pytestmark = pytest.mark.unit

START = (0.8, 1.2, 0.0)
KITCHEN = (7.5, 2.8, math.pi / 2)
DT = 0.05


def _occupancy(mask: np.ndarray) -> np.ndarray:
    return np.where(mask, 100, 0).astype(np.int8)


def _with_box(plan: FloorPlan, lo: tuple[float, float], hi: tuple[float, float]) -> FloorPlan:
    mask = plan.mask.copy()
    g = plan.geometry
    (r0, r1), (c0, c1) = g.to_cell(np.array([lo, hi]))
    mask[r0 : r1 + 1, c0 : c1 + 1] = True
    return FloorPlan(mask, g)


def _run(
    world: FloorPlan,
    map_mask: np.ndarray,
    goal: Pose2,
    limit_s: float = 90.0,
    seed: int = 0,
    start: Pose2 = START,
    follower: FollowerConfig | None = None,
    navs: list[Navigator] | None = None,
    objects: list[tuple[float, float, float]] | None = None,
    marks: tuple[np.ndarray, float] | None = None,
    t0: float = 0.0,
    objects_after: float = 0.0,
) -> tuple[str, str, Pose2, float, int]:
    """Closed loop from robot time ``t0``: (final state, reason, final pose, time, steps
    touching the world); the navigator is appended to ``navs``; ``objects``: floor
    objects' discs in the costmap (not in the world: low objects the LiDAR does not see),
    from ``objects_after`` s into the walk (perception confirms them as it goes);
    ``marks``: obstacle-layer points (N, 2) made before the start, and their stamp."""
    rng = np.random.default_rng(seed)
    geo = world.geometry
    cm = Costmap(CostmapConfig(), _occupancy(map_mask), geo)
    static = Costmap(CostmapConfig(), _occupancy(map_mask), geo)
    if objects and objects_after <= 0.0:
        cm.set_objects(objects)
    if marks is not None:
        pts, stamp = marks
        cm.update_obstacles(pts, (pts[0, 0], pts[0, 1] - 0.05, 0.0), stamp=stamp)
    nav = Navigator(follower=follower)
    if navs is not None:
        navs.append(nav)
    pose: Pose2 = start
    vel = np.zeros(3)
    why = nav.start(goal, t0, pose, cm, static)
    if why:
        return why.split(":")[0], why, pose, t0, 0
    mount = lidar_mount()
    touching = 0
    t = t0
    k = 0
    while t < t0 + limit_s:
        if k % 2 == 0:  # 10 Hz scans into the obstacle layer
            lp = compose(pose, mount)
            r = simulate_scan(world, lp, rng=rng)
            pts = scan_points(t, r, -math.pi, 2 * math.pi / len(r), 0.1, 12.0, mount)
            cm.update_obstacles(transform_points(pose, pts.points), lp, stamp=t)
        if objects and objects_after > 0.0 and t - t0 >= objects_after and not cm.objects.any():
            cm.set_objects(objects)
        st = nav.step(t, pose, cm)
        if st.state != "active":
            return st.state, st.reason, pose, t, touching
        vel += DT / 0.25 * (np.array([st.vx, st.vy, st.wz]) - vel)
        v = vel + rng.normal(0.0, 0.005, 3)
        pose = compose(pose, (v[0] * DT, v[1] * DT, v[2] * DT))
        if world.occupied(np.array([pose[:2]]))[0]:
            touching += 1
        t += DT
        k += 1
    return "timeout", "", pose, t, touching


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return true_floor_plan()


def test_reaches_the_kitchen_through_the_doorway(plan):
    navs: list[Navigator] = []
    state, reason, pose, t, touching = _run(plan, plan.mask, KITCHEN, navs=navs)
    assert state == "reached", reason
    assert math.hypot(pose[0] - KITCHEN[0], pose[1] - KITCHEN[1]) <= 0.06
    assert touching == 0
    # about 8 m at up to 0.5 m/s plus turns
    assert t < 30.0, t
    # where the time went, for the log line that ends the walk: it all went somewhere
    modes = navs[0].last_modes
    assert modes["track"] > modes.get("final", 0.0) > 0.0, modes
    assert sum(modes.values()) == pytest.approx(t, abs=0.1)


def test_a_command_that_would_meet_a_corner_is_slowed_before_the_walk_counts_blocked(plan):
    # kitchen to living room through the doorway: pure pursuit cuts the frame's corner by
    # its look-ahead, and the full-speed projection met it (a recovery: wait, back up, turn)
    walks = [((5.43, 3.38, 1.32), (1.02, 1.09, -0.63)), ((6.69, 3.4, 2.56), (1.92, 2.79, 2.81))]
    recovering, reached, touching = {}, {}, {}
    for slow in ((), FollowerConfig().collision_slowdowns):
        recovering[slow] = reached[slow] = touching[slow] = 0
        for start, goal in walks:
            for seed in range(3):
                navs: list[Navigator] = []
                state, _, _, _, touched = _run(
                    plan, plan.mask, goal, start=start, navs=navs, seed=seed, limit_s=60,
                    follower=FollowerConfig(collision_slowdowns=slow),
                )  # fmt: skip
                m = navs[0].last_modes
                recovering[slow] += sum(m.get(k, 0.0) for k in ("wait", "backup", "turn"))
                reached[slow] += state == "reached"
                touching[slow] += touched
    stop, slowed = recovering
    # measured: 68 s of recoveries and 2 of 6 reached stopping, 20 s and 5 of 6 slowing
    assert recovering[slowed] < 0.5 * recovering[stop], recovering
    assert reached[slowed] > reached[stop], reached
    assert touching[slowed] == touching[stop] == 0


def test_a_walk_turns_to_its_goal_yaw_on_the_way_not_at_the_end(plan):
    # 3 m straight on, to stand facing back the way it came (a stance facing its object)
    goal = (3.8, 1.2, math.pi)
    runs = {}
    for ahead in (0.0, FollowerConfig().turn_ahead):
        state, reason, pose, t, touching = _run(
            plan, plan.mask, goal, follower=FollowerConfig(turn_ahead=ahead)
        )
        assert state == "reached", reason
        assert touching == 0
        assert math.hypot(pose[0] - goal[0], pose[1] - goal[1]) <= 0.06
        runs[ahead] = t
    turned_at_the_end, turned_on_the_way = runs.values()
    # the half turn (pi at 1.4 rad/s: 2.2 s and more) overlaps the last metre's walk
    # (measured 7.55 -> 6.55 s)
    assert turned_on_the_way < turned_at_the_end - 0.6, runs


def test_a_walk_that_starts_facing_away_sets_off_as_it_turns(plan):
    goal = (3.8, 1.2, 0.0)
    start = (0.8, 1.2, math.pi)
    runs = {}
    for speed in (0.0, FollowerConfig().rotate_walk_speed):
        state, reason, pose, t, touching = _run(
            plan, plan.mask, goal, start=start, follower=FollowerConfig(rotate_walk_speed=speed)
        )
        assert state == "reached", reason
        assert touching == 0
        runs[speed] = t
    on_the_spot, setting_off = runs.values()
    assert setting_off < on_the_spot - 0.3, runs  # measured 8.1 -> 7.05 s


def test_floor_objects_that_close_every_way_are_left_out_for_the_walk(plan):
    # seed-116: a brick and a Rubik's cube 0.55 m apart before the doorway; their discs,
    # inflated like walls, cut the living room off the kitchen and the robot stood
    # trapped ("no path after 3 recoveries", walk after walk)
    objects = [(4.45, 2.04, 0.1), (4.23, 1.5, 0.1), (4.4, 2.6, 0.1)]
    start = (3.6, 0.85, math.pi / 2)
    navs: list[Navigator] = []
    state, reason, pose, t, touching = _run(
        plan, plan.mask, KITCHEN, start=start, navs=navs, objects=objects
    )
    assert state == "reached", reason
    assert touching == 0
    assert "floor objects" in navs[0].notice
    assert "wait" not in navs[0].last_modes  # no recovery: at once
    # with a way round them the layer stays (one object in the open)
    navs = []
    state, reason, _, _, _ = _run(
        plan, plan.mask, KITCHEN, start=start, navs=navs, objects=[(3.6, 1.6, 0.1)]
    )
    assert state == "reached", reason
    assert navs[0].notice == ""


# paper-1's living-room floor objects as perception saw them (map frame), as the discs the
# object layer makes of them: marker, cracker box, baseball, coffee can, spoon, lego, cup
PAPER1_FLOOR = [(2.42, 2.2, 0.12), (2.62, 1.07, 0.155), (2.99, 1.56, 0.087), (3.27, 2.19, 0.1),
                (2.83, 2.52, 0.13), (2.23, 0.96, 0.08), (3.67, 0.94, 0.09)]  # fmt: skip
DRAWERS = (8.45, 1.67, 0.0)


def _to_the_drawers(
    plan, start: Pose2, confirmed_after: float
) -> tuple[str, str, float, int, dict]:
    """paper-1's walk to the drawers from ``start``, the floor objects confirmed this
    long into it: (state, reason, time, steps touching, the walk's modes)."""
    navs: list[Navigator] = []
    state, reason, _, t, touching = _run(
        plan, plan.mask, DRAWERS, start=start, navs=navs, objects=PAPER1_FLOOR,
        objects_after=confirmed_after,
    )  # fmt: skip
    return state, reason, t, touching, navs[0].last_modes


def test_floor_objects_confirmed_across_the_path_are_walked_round_without_a_recovery(plan):
    # paper-1's first walk, to the drawers: the path, planned before perception confirmed
    # the baseball, passed 9 cm from it, short of its disc but across its inscribed zone.
    # The path was kept (cheaper than the way round), every command stopped at the zone,
    # and the walk ended "blocked after 3 recoveries" (19 s) by the ball, as it does here
    # on the code before (measured: blocked at (2.59, 1.60) after 18.8 s)
    state, reason, t, touching, modes = _to_the_drawers(plan, (2.0, 1.5, 0.2), 0.1)
    assert state == "reached", reason
    assert touching == 0
    assert not {"wait", "backup", "turn"} & set(modes), modes
    assert t < 20.0, t  # measured 15.9 s


def test_a_walk_that_got_out_after_a_recovery_is_not_given_up_on_its_clock(plan):
    # confirmed with the robot already in the pocket: one recovery gets it out, and the
    # walk round and through the doorway (then 3 m on, walking freely) was ended
    # "blocked" 25 s after that recovery (measured: at (5.23, 1.95)); its detour, longer
    # than what the old path had left, also counted as no progress (two more recoveries)
    state, reason, _, touching, modes = _to_the_drawers(plan, (2.3, 1.55, 0.2), 1.0)
    assert state == "reached", reason
    assert touching == 0
    assert modes.get("wait", 0.0) <= NavigatorConfig().recovery_wait + 0.1


def test_passes_a_box_that_is_not_in_the_map(plan):
    world = _with_box(plan, (2.3, 1.0), (2.7, 1.4))  # on the straight line ahead
    goal = (3.8, 1.2, 0.0)
    state, reason, pose, _, touching = _run(world, plan.mask, goal)
    assert state == "reached", reason
    assert touching == 0
    assert math.hypot(pose[0] - goal[0], pose[1] - goal[1]) <= 0.06


# a short line of LiDAR marks 0.15 m beyond the kitchen goal: inside the robot's radius
_BY_GOAL = np.array([[KITCHEN[0] + dx, KITCHEN[1] + 0.15] for dx in (-0.05, 0.0, 0.05)])


def test_old_marks_by_a_far_goal_are_forgotten_and_walked_to(plan):
    # marked 30 s ago and not seen since (20 s is the config's age): the walk goes
    state, reason, pose, t, touching = _run(plan, plan.mask, KITCHEN, marks=(_BY_GOAL, 0.0),
                                            t0=30.0)  # fmt: skip
    assert state == "reached", reason
    assert touching == 0
    assert math.hypot(pose[0] - KITCHEN[0], pose[1] - KITCHEN[1]) <= 0.06


def test_fresh_marks_by_a_goal_refuse_it_at_once_and_say_how_old(plan):
    state, reason, _, t, _ = _run(plan, plan.mask, KITCHEN, marks=(_BY_GOAL, 0.0), t0=5.0)
    assert state == "blocked", (state, reason)
    assert "goal too close to an obstacle" in reason and "marks 5 s old" in reason, reason
    assert t == 5.0


def test_a_forgotten_mark_that_is_really_there_is_seen_again_and_refuses_the_goal(plan):
    lo, hi = _BY_GOAL.min(axis=0) - 0.02, _BY_GOAL.max(axis=0) + 0.02
    world = _with_box(plan, (float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))
    state, reason, pose, t, touching = _run(world, plan.mask, KITCHEN,
                                            marks=(_BY_GOAL, 0.0), t0=30.0)  # fmt: skip
    assert state == "blocked", (state, reason)
    assert "goal too close to an obstacle" in reason and "marks 0 s old" in reason, reason
    assert touching == 0
    # it set off, and stopped when its LiDAR (4 m marking range) saw the box again
    assert t > 32.0
    assert pose[0] > START[0] + 1.0
    assert math.hypot(pose[0] - KITCHEN[0], pose[1] - KITCHEN[1]) < 4.2


def test_a_blocked_doorway_ends_blocked_with_a_reason_within_30_s(plan):
    world = _with_box(plan, (4.9, 1.45), (5.1, 2.55))
    state, reason, pose, t, touching = _run(world, plan.mask, KITCHEN, limit_s=60.0)
    assert state == "blocked", (state, reason)
    assert "recover" in reason or "for" in reason
    assert t <= 30.0
    assert touching == 0
    assert pose[0] < 4.9  # it stayed in the living room


def test_a_goal_the_map_cannot_reach_is_no_path_at_once(plan):
    sealed = _with_box(plan, (4.9, 1.45), (5.1, 2.55))  # the doorway closed in the map
    state, reason, _, t, _ = _run(sealed, sealed.mask, KITCHEN)
    assert state == "no_path" and "map" in reason, reason
    assert t == 0.0


def test_bad_goals_are_rejected(plan):
    cm = Costmap(CostmapConfig(), _occupancy(plan.mask), plan.geometry)
    nav = Navigator()
    assert "not finite" in nav.start((math.nan, 1.0, 0.0), 0.0, START, cm)
    assert "off the map" in nav.start((40.0, 1.0, 0.0), 0.0, START, cm)
    assert "obstacle" in nav.start((5.0, 0.5, 0.0), 0.0, START, cm)  # in the middle wall
    assert not nav.active


def test_a_robot_standing_too_close_to_a_wall_steps_out_and_goes(plan):
    # 0.15 m from the south wall, facing it (after a grasp at the wall): inside the
    # inscribed zone, where the follower alone refuses to move
    start = (2.0, 0.15, -math.pi / 2)
    state, reason, pose, _, touching = _run(plan, plan.mask, (2.5, 1.8, 0.0), start=start)
    assert state == "reached", reason
    assert touching == 0


def test_a_robot_standing_in_an_obstacle_of_the_map_backs_out_and_goes(plan):
    # paper-2, 2026-12-07: the trunk in under a table top the LiDAR does not see (the map
    # has the table; the world here, as the scan, has only the walls), its middle 8 cm
    # inside, facing it. Every walk was refused "start in an obstacle (on the map alone)"
    # at once, 40 in 20 s; now it backs out the way it came and walks
    table = _with_box(plan, (2.0, 1.4), (2.9, 2.0))
    start = (2.45, 1.48, math.pi / 2)
    state, reason, pose, t, touching = _run(plan, table.mask, (1.2, 0.8, 0.0), start=start)
    assert state == "reached", reason
    assert touching == 0 and t < 20.0


def test_a_walk_whose_first_turn_meets_the_wall_steps_back_without_a_recovery(plan, monkeypatch):
    # 0.32 m from the south wall, facing it (after a place at a table, seed-114): outside
    # the inscribed zone, but the first turn sweeps the trunk's corners into the wall.
    # The recovery (wait, back up, turn) cost 10.05 s to the goal; a step back 8.0 s.
    recoveries = []
    real = Navigator._start_recovery

    def counted(self, g, now, pose, costmap):
        recoveries.append(g.last_reason)
        return real(self, g, now, pose, costmap)

    monkeypatch.setattr(Navigator, "_start_recovery", counted)
    start = (2.0, 0.32, -math.pi / 2)
    state, reason, _, t, touching = _run(plan, plan.mask, (2.5, 1.8, 0.0), start=start)
    assert state == "reached", reason
    assert touching == 0 and recoveries == []
    assert t < 9.0


def _pillar_room() -> tuple[Costmap, FloorPlan]:
    """A 6 x 4 m room with a 1 m pillar in its middle: two equal ways past it."""
    geo = GridGeometry.covering((0.0, 0.0), (6.0, 4.0), 0.05)
    mask = np.zeros(geo.shape, dtype=bool)
    mask[[0, -1], :] = True
    mask[:, [0, -1]] = True
    room = _with_box(FloorPlan(mask, geo), (2.5, 1.5), (3.5, 2.5))
    return Costmap(CostmapConfig(), _occupancy(room.mask), geo), room


def _side(path: np.ndarray) -> float:
    """+1 when the path passes the pillar above its centre line (y = 2), -1 below."""
    mid = path[np.argmin(np.abs(path[:, 0] - 3.0))]
    return float(np.sign(mid[1] - 2.0))


def _route(nav: Navigator, t: float, pose: Pose2, cm: Costmap) -> tuple[float, bool]:
    """(side of the route the navigator follows after a step at ``t``, whether it changed)."""
    st = nav.step(t, pose, cm)
    assert st.state == "active", st.reason
    return _side(nav.goal.path), st.new_path is not None


def test_a_periodic_replan_keeps_a_free_route_unless_another_is_much_cheaper():
    cm, room = _pillar_room()
    goal = (5.2, 2.0, 0.0)
    above, below = (0.8, 2.5, 0.0), (0.8, 2.4, 0.0)
    # planned afresh, 10 cm make the difference between the two ways past the pillar (an
    # 8-connected grid prices both ways nearly alike; the shortcut paths differ more)
    fresh = [Navigator(), Navigator()]
    for n, p in zip(fresh, (above, below), strict=True):
        n.start(goal, 0.0, p, cm)
    assert [_route(n, 0.0, p, cm)[0] for n, p in zip(fresh, (above, below), strict=True)] == [
        1.0,
        -1.0,
    ]
    nav = Navigator()
    assert nav.start(goal, 0.0, above, cm) == ""
    assert _route(nav, 0.0, above, cm) == (1.0, True)
    # the 1 s re-plans from the other pose keep the route: no turning back and forth
    assert _route(nav, 1.1, below, cm) == (1.0, False)
    assert _route(nav, 2.2, above, cm) == (1.0, False)
    # an obstacle across the route ahead: the other way at once
    walled = _with_box(room, (2.0, 2.3), (2.2, 4.0))
    cm_walled = Costmap(CostmapConfig(), _occupancy(walled.mask), room.geometry)
    assert _route(nav, 2.3, below, cm_walled) == (-1.0, True)
    # the obstacle gone and the robot well above the centre line: the upper way is much
    # cheaper now, and the periodic re-plan takes it
    high = (0.8, 3.2, 0.0)
    assert _route(nav, 3.4, high, cm) == (1.0, True)
