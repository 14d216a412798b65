"""The navigation service over a real Zenoh router, closed-loop with a kinematic robot.

`quadmanip service navigation` runs as a child process on a map of the true floor plan;
the test process plays the robot (:class:`quadmanip.testbench.kinematic_robot.KinematicRobot`:
it obeys navigation's body velocity commands with a lag and a creep, and publishes
odometry and simulated LiDAR scans). Success is judged from the kinematic robot's true
pose. The full-physics run through the doorway is in ``test_navigation_stack.py``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.services.navigation.map_io import save_map
from quadmanip.services.navigation.places import Place, places_path_for, save_places
from quadmanip.testbench.floor_plan import FloorPlan, true_floor_plan
from quadmanip.testbench.kinematic_robot import KinematicRobot
from scipy import ndimage

pytestmark = pytest.mark.integration

START = (0.8, 1.2, 0.0)


def _house_map(plan: FloorPlan) -> np.ndarray:
    """The floor plan as a map: occupied 100, the house's inside free, outside unknown."""
    labels, _ = ndimage.label(~plan.mask)
    (r,), (c,) = plan.geometry.to_cell(np.array([START[:2]]))
    occ = np.full(plan.mask.shape, -1, dtype=np.int8)
    occ[labels == labels[r, c]] = 0
    occ[plan.mask] = 100
    return occ


@pytest.fixture(scope="module")
def map_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    plan = true_floor_plan()
    stem = tmp_path_factory.mktemp("map") / "house"
    paths = save_map(stem, _house_map(plan), plan.geometry)
    save_places(
        places_path_for(paths["yaml"]),
        [
            Place("kitchen_spot", "search_floor", (6.5, 2.6, math.pi / 2), (6.5, 3.0, 0.0)),
            # a floor zone by the start (the lead-in test's object lies in it)
            Place("living_spot", "search_floor", (1.0, 1.0, 0.0), (1.4, 1.4, 0.0), (0.8, 0.6)),
        ],
    )
    return paths["yaml"]


def _wait(cond: Callable[[], bool], timeout: float, what: str, procs=()) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            logs = "\n".join("\n".join(p.lines[-15:]) for p in procs)
            raise TimeoutError(f"{what}\n{logs}")
        time.sleep(0.05)


@pytest.fixture
def nav(zenoh_router, spawn, bus_factory, map_yaml):
    """(bus, robot, navigation process, plan) with navigation running on the map."""
    plan = true_floor_plan()
    bus = bus_factory(zenoh_router)
    robot = KinematicRobot(bus, plan, START).start()
    proc = spawn(
        "-m", "quadmanip.cli", "service", "navigation",
        "--set", f"node.map={map_yaml}",
        "--set", f"node.initial_pose=[{START[0]}, {START[1]}, 0.0]",
        endpoint=zenoh_router,
    )  # fmt: skip
    pose = bus.latest("navigation/pose")
    _wait(lambda: pose.get() is not None, 60.0, "no navigation pose", (proc,))
    yield bus, robot, proc, plan
    robot.stop()


def _send(bus, action: str, goal: m.Message):
    h = bus.action_client("navigation", action).send_goal(goal, timeout=10.0)
    return h


def _result(h, proc, timeout: float = 90.0) -> m.ActionResult:
    deadline = time.monotonic() + timeout
    while True:
        r = h.result(timeout=1.0)
        if r is not None:
            return r
        if time.monotonic() > deadline:
            raise TimeoutError("no result\n" + "\n".join(proc.lines[-20:]))


def _one_track(
    track_id: int,
    label: str,
    odom_xy: tuple[float, float],
    map_xy: np.ndarray,
    z: float,
    extents: tuple[float, float, float],
    confirmed: int = 1,
) -> m.ObjectTracks:
    """Perception's memory holding one object (centroid in odom and in the map)."""
    return m.ObjectTracks(
        stamp=0.0,
        ids=np.array([track_id]),
        labels=[label],
        centroids=np.array([[odom_xy[0], odom_xy[1], z]]),
        extents=np.array([extents], dtype=np.float32),
        confidences=np.array([0.9], dtype=np.float32),
        observations=np.array([9]),
        last_seen=np.array([0.0]),
        confirmed=np.array([confirmed], dtype=np.uint8),
        map_centroids=np.array([[map_xy[0], map_xy[1], z]]),
        in_map=True,
    )


def test_walks_through_the_doorway_and_reports(nav):
    bus, robot, proc, _ = nav
    paths: list[m.Path] = []
    bus.subscribe("navigation/path", paths.append)
    grid = bus.latest("navigation/map")
    goal = (7.5, 2.8, math.pi / 2)
    h = _send(bus, "navigate_to", m.NavigateGoal(stamp=0.0, pose=np.array(goal)))
    assert h.accepted, h.reason
    r = _result(h, proc)
    assert r.status == "succeeded", (r.reason, proc.lines[-20:])
    err_xy, err_yaw = robot.error_to(goal)
    assert err_xy <= 0.05 and err_yaw <= math.radians(3.0), (err_xy, math.degrees(err_yaw))
    assert robot.contacts == 0
    res = r.result
    assert isinstance(res, m.NavigationResult) and res.outcome == "reached"
    assert res.distance > 6.5  # it walked through the doorway, not through the wall
    assert h.feedback and any("m left" in f.text for f in h.feedback)
    assert paths, "no path published"
    p = paths[0]  # the first plan, from the start (later re-plans start where the robot is)
    assert len(p.poses) > 10 and np.hypot(*(p.poses[-1, :2] - goal[:2])) < 0.05
    assert np.any(np.abs(p.poses[:, 0] - 5.0) < 0.1)  # the path crosses the middle wall ...
    crossing = p.poses[np.argmin(np.abs(p.poses[:, 0] - 5.0))]
    assert 1.5 < crossing[1] < 2.5  # ... in the doorway
    g = grid.get()
    assert g is not None and g.data.shape[0] > 50
    # standing still afterwards: the last command navigation sent is zero
    time.sleep(0.3)
    last = robot.last_cmd
    assert last is not None and (last.vx, last.vy, last.wz) == (0.0, 0.0, 0.0)


def test_named_place_and_bad_goals(nav):
    bus, robot, proc, _ = nav
    h = _send(bus, "navigate_to", m.NavigateGoal(stamp=0.0, place="sofa_top"))
    assert not h.accepted and "unknown place 'sofa_top'" in h.reason and "kitchen_spot" in h.reason
    # a goal inside a wall and one off the map are rejected with the reason
    for pose, why in (((4.98, 0.7, 0.0), "in an obstacle"), ((30.0, 0.0, 0.0), "off the map")):
        h = _send(bus, "navigate_to", m.NavigateGoal(stamp=0.0, pose=np.array(pose)))
        assert not h.accepted and why in h.reason, h.reason
    with pytest.raises(m.MessageError):
        m.NavigateGoal(stamp=0.0, pose=np.array([math.nan, 0.0, 0.0]))
    # a named place is walked to
    h = _send(bus, "navigate_to", m.NavigateGoal(stamp=0.0, place="kitchen_spot"))
    assert h.accepted, h.reason
    r = _result(h, proc)
    assert r.status == "succeeded", r.reason
    assert robot.error_to((6.5, 2.6, math.pi / 2))[0] <= 0.05


def test_cancel_and_lost_inputs_stop_the_robot(nav):
    bus, robot, proc, _ = nav
    client = bus.action_client("navigation", "navigate_to")
    h = client.send_goal(m.NavigateGoal(stamp=0.0, pose=np.array([3.5, 2.0, 0.0])), timeout=10)
    assert h.accepted, h.reason
    _wait(lambda: abs(robot.vel[0]) > 0.1 or abs(robot.vel[2]) > 0.2, 20.0, "not moving", (proc,))
    assert h.cancel()
    r = _result(h, proc, 20.0)
    assert r.status == "canceled", r.reason
    time.sleep(1.0)  # the lag's decay from a walk's top speed (0.8 m/s)
    assert math.hypot(robot.vel[0], robot.vel[1]) < 0.03
    # odometry stops mid-walk: navigation stops the robot and ends the goal "lost"
    h = client.send_goal(m.NavigateGoal(stamp=0.0, pose=np.array([3.5, 2.0, 0.0])), timeout=10)
    assert h.accepted, h.reason
    _wait(lambda: abs(robot.vel[0]) > 0.1 or abs(robot.vel[2]) > 0.2, 20.0, "not moving", (proc,))
    robot.publish_odometry = False
    r = _result(h, proc, 20.0)
    assert r.status == "failed" and r.reason.startswith("lost: no odometry"), r.reason
    assert r.result.outcome == "lost"

    def stopped() -> bool:
        last = robot.last_cmd
        return last is not None and (last.vx, last.vy, last.wz) == (0.0, 0.0, 0.0)

    # the stop is published before the result, on another key: it may arrive just after
    _wait(stopped, 1.0, f"no stop command after lost odometry: {robot.last_cmd}", (proc,))
    robot.publish_odometry = True


def test_precise_approach_in_the_odom_frame(nav):
    bus, robot, proc, _ = nav
    # a point 1.2 m ahead and 0.3 m to the left, to stand 0.5 m from, facing +x
    target = robot.odom_of((START[0] + 1.2, START[1] + 0.3, 0.0))
    goal = m.ApproachGoal(stamp=0.0, target=np.array(target[:2]), frame="odom", standoff=0.5,
                          heading=0.0)  # fmt: skip
    h = _send(bus, "approach", goal)
    assert h.accepted, h.reason
    r = _result(h, proc, 60.0)
    assert r.status == "succeeded", r.reason
    time.sleep(0.3)
    err_xy, err_yaw = robot.error_to((START[0] + 0.7, START[1] + 0.3, 0.0))
    assert err_xy <= 0.01 and err_yaw <= math.radians(1.0), (err_xy, math.degrees(err_yaw))


def test_a_blocked_approach_logs_its_nearest_lidar_return(nav):
    bus, robot, proc, _ = nav
    # a stance against the house's west wall (x = -0.5): the footprint meets it
    target = robot.odom_of((-0.45, START[1], 0.0))
    goal = m.ApproachGoal(stamp=0.0, target=np.array(target[:2]), frame="odom", standoff=0.1,
                          heading=math.pi)  # fmt: skip
    h = _send(bus, "approach", goal)
    assert h.accepted, h.reason
    r = _result(h, proc, 60.0)
    assert r.status == "failed" and r.reason.startswith("blocked"), r.reason
    _wait(lambda: any("goal ended" in x and "nearest_return=" in x for x in proc.lines), 5.0,
          "no nearest return in the log", (proc,))  # fmt: skip


def test_an_approach_whose_every_stance_meets_the_walls_ends_before_it_sets_off(nav):
    # paper-1 (2026-12-07): facing the Rubik's cube from where the robot stood, the
    # stance stood on the deposit table's leg and no turned one was clear; the approach
    # pushed against the table for 20 s. A stance that meets the map's furniture, 0.2 m
    # away or more, ends the approach at once, "touches the footprint": the task walks to
    # another side. Here: a target in the living room's south-west corner, 8 cm from both
    # walls, to stand 0.15 m from, facing it from the start
    bus, robot, proc, _ = nav
    before = robot.pose
    goal = m.ApproachGoal(stamp=0.0, target=np.array(robot.odom_of((0.08, 0.08, 0.0))[:2]),
                          frame="odom", standoff=0.15, face_target=True)  # fmt: skip
    h = _send(bus, "approach", goal)
    assert h.accepted, h.reason
    r = _result(h, proc, 60.0)
    assert r.status == "failed" and "touches the footprint" in r.reason, r.reason
    assert "no stance turned about the target is clear" in r.reason
    assert r.result.outcome == "blocked"
    x, y, _ = robot.pose
    assert math.hypot(x - before[0], y - before[1]) < 0.03  # it did not set off


@pytest.mark.parametrize("asked", ["face_target", "turn_free"])
def test_an_approach_whose_stance_meets_furniture_is_turned_about_the_target(nav, asked):
    # seed-106 (2026-12-05): approaches facing a floor object from where the robot stood
    # stopped against a leg at the trunk's corner, six times in a trial. Here the target
    # lies 0.15 m from an obstacle of the floor plan: facing it from the start, the stance
    # overlaps the obstacle; the approach stands turned about it, the target ahead. The
    # same for that heading given (``turn_free``, the task's heading clear of other floor
    # objects; approaches of every kind met furniture 18 times in ten trials):
    # the target on the floor, not on a table top, so the stance keeps its nose out too.
    bus, robot, proc, _ = nav
    tx, ty = 0.9, 2.6
    bearing = math.atan2(ty - START[1], tx - START[0])
    target = robot.odom_of((tx, ty, 0.0))
    heading = robot.odom_of((tx, ty, bearing))[2]  # facing the target from the start
    goal = m.ApproachGoal(stamp=0.0, target=np.array(target[:2]), frame="odom", standoff=0.36,
                          face_target=asked == "face_target", heading=float(heading),
                          turn_free=asked == "turn_free", tolerance_xy=0.02,
                          tolerance_yaw=0.035)  # fmt: skip
    h = _send(bus, "approach", goal)
    assert h.accepted, h.reason
    r = _result(h, proc, 60.0)
    assert r.status == "succeeded", (r.reason, robot.pose, proc.lines[-12:])
    assert any("approach stance turned" in x for x in proc.lines)
    time.sleep(0.3)
    x, y, yaw = robot.pose
    assert math.hypot(tx - x, ty - y) == pytest.approx(0.36, abs=0.03)
    assert abs(math.remainder(math.atan2(ty - y, tx - x) - yaw, math.tau)) < math.radians(3)
    assert abs(math.remainder(yaw - bearing, math.tau)) > 0.3  # not the straight stance


def test_a_floor_object_in_perceptions_memory_is_a_costmap_obstacle(nav):
    # the objects lie under the LiDAR's plane: navigation takes them from perception's
    # memory (seed-103: a cracker box walked into and knocked over)
    bus, robot, proc, plan = nav
    spot = np.array([6.5, 3.0])  # the places file's floor zone (kitchen_spot)
    costmap = bus.latest("navigation/costmap")
    pose = bus.latest("navigation/pose")
    _wait(lambda: costmap.get() is not None and pose.get() is not None, 30.0, "no costmap")

    def cost_at(xy: np.ndarray) -> int:
        g = costmap.get()
        c = np.floor((xy - g.origin[:2]) / g.resolution).astype(int)
        return int(g.data[c[1], c[0]])

    assert cost_at(spot) < 100
    mx, my, myaw = pose.get().map_to_odom  # the track's centroid is in odom
    d = spot - (mx, my)
    odom = (
        math.cos(myaw) * d[0] + math.sin(myaw) * d[1],
        -math.sin(myaw) * d[0] + math.cos(myaw) * d[1],
    )
    pub = bus.publisher("perception/objects")

    def publish(confirmed: int) -> None:
        box = (0.16, 0.08, 0.21)
        pub.publish(_one_track(7, "cracker_box", odom, spot, 0.105, box, confirmed))

    def marked() -> bool:
        publish(1)
        return cost_at(spot) == 100

    _wait(marked, 20.0, "the object never reached the costmap", (proc,))
    assert cost_at(spot + (0.6, 0.0)) < 100  # a disc, not the whole zone

    def cleared() -> bool:
        publish(0)  # no longer confirmed: gone from the layer
        return cost_at(spot) < 100

    _wait(cleared, 20.0, "the object never left the costmap", (proc,))


def _floor_object(
    bus, robot, proc, track: tuple[int, str, np.ndarray, float, tuple]
) -> Callable[[], None]:
    """Publish perception's memory holding one floor object (id, class, map xy, centroid
    height, extents) until navigation's costmap marks it; returns the publishing call
    (the memory is sent again and again, as perception does)."""
    track_id, label, xy, z, size = track
    pub = bus.publisher("perception/objects")
    odom_xy = robot.odom_of((*xy, 0.0))

    def publish() -> None:
        pub.publish(_one_track(track_id, label, odom_xy[:2], xy, z, size))

    costmap = bus.latest("navigation/costmap")

    def marked() -> bool:
        publish()
        g = costmap.get()
        if g is None:
            return False
        c = np.floor((xy - g.origin[:2]) / g.resolution).astype(int)
        return int(g.data[c[1], c[0]]) == 100

    _wait(marked, 20.0, f"the {label} never reached the costmap", (proc,))
    return publish


def _approach_past(bus, robot, proc, goal: m.ApproachGoal, publish, xy: np.ndarray) -> float:
    """Run ``goal`` to success, publishing the memory meanwhile; the nearest the robot's
    true centre came to ``xy``."""
    h = _send(bus, "approach", goal)
    assert h.accepted, h.reason
    nearest = math.inf
    deadline = time.monotonic() + 90.0
    while (r := h.result(timeout=0.05)) is None:
        publish()
        x, y, _ = robot.pose
        nearest = min(nearest, math.hypot(x - xy[0], y - xy[1]))
        assert time.monotonic() < deadline, proc.lines[-20:]
    assert r.status == "succeeded", (r.reason, robot.pose, proc.lines[-12:])
    return nearest


def test_an_approach_whose_straight_way_meets_a_floor_object_walks_round_it_first(nav):
    # paper-5 (2026-12-07): the straight way to a bowl on the living table's edge passed
    # 0.2 m beside a soup can on the floor, below the LiDAR's plane; the can was kicked
    # under the table and lost. Here a can from perception's memory lies halfway along
    # the straight way to a stance facing north: the approach walks by the planner to
    # behind the stance first, and its trunk never comes near the can.
    bus, robot, proc, _ = nav
    can = np.array([1.35, 1.40])
    target, heading, standoff = (1.9, 1.95), math.pi / 2, 0.36
    pose = bus.latest("navigation/pose")
    _wait(lambda: pose.get() is not None, 30.0, "no pose", (proc,))
    publish = _floor_object(
        bus, robot, proc, (3, "tomato_soup_can", can, 0.05, (0.067, 0.067, 0.1))
    )
    t = robot.odom_of((*target, 0.0))
    h_odom = robot.odom_of((*target, heading))[2]
    goal = m.ApproachGoal(stamp=0.0, target=np.array(t[:2]), frame="odom", standoff=standoff,
                          heading=float(h_odom), tolerance_xy=0.02,
                          tolerance_yaw=0.035)  # fmt: skip
    nearest = _approach_past(bus, robot, proc, goal, publish, can)
    # the feet's reach sideways (0.165 m from the middle) and the can's radius (0.034 m):
    # the straight way passed over it (0.02 m)
    assert nearest > 0.2, nearest
    assert any("approach lead-in" in x and 'map_lead="[' in x for x in proc.lines), [
        x for x in proc.lines if "approach" in x
    ]
    time.sleep(0.3)
    err_xy, err_yaw = robot.error_to((target[0], target[1] - standoff, heading))
    assert err_xy <= 0.02 and err_yaw <= math.radians(3.0), (err_xy, math.degrees(err_yaw))


def test_an_approach_right_after_a_walk_keeps_its_stance_off_a_floor_object(nav):
    # paper-4 (2026-12-07): a walk ended 0.8 m short of a padlock, a standing cracker box
    # 0.36 m beside the padlock and about 0.5 m from the walk's goal (a walk leaves the
    # objects by its goal out of its costmap). The approach facing the padlock began
    # 30 ms later: its stance stood on the box, which fell flat and was never grasped.
    # Now the layer is made afresh at an approach's start; the stance facing the target
    # stands on the box, so it turns about the target to a clear one, led in by the
    # planner round the box.
    bus, robot, proc, _ = nav
    box, target = np.array([1.48, 1.60]), (1.30, 1.30)
    walk_goal = (1.90, 1.66, math.atan2(target[1] - 1.66, target[0] - 1.90))
    pose = bus.latest("navigation/pose")
    _wait(lambda: pose.get() is not None, 30.0, "no pose", (proc,))
    publish = _floor_object(bus, robot, proc, (4, "cracker_box", box, 0.105, (0.16, 0.06, 0.21)))
    h = _send(bus, "navigate_to", m.NavigateGoal(stamp=0.0, pose=np.array(walk_goal)))
    assert h.accepted, h.reason
    while (r := h.result(timeout=0.05)) is None:
        publish()
    assert r.status == "succeeded", (r.reason, proc.lines[-12:])
    t = robot.odom_of((*target, 0.0))
    goal = m.ApproachGoal(stamp=0.0, target=np.array(t[:2]), frame="odom", standoff=0.36,
                          face_target=True, tolerance_xy=0.02, tolerance_yaw=0.035)  # fmt: skip
    nearest = _approach_past(bus, robot, proc, goal, publish, box)
    # facing the target from where the walk ended, the trunk's middle stood 0.17 m from
    # the box's middle
    assert nearest > 0.35, nearest
    assert any("stands on a floor object" in x for x in proc.lines), [
        x for x in proc.lines if "approach" in x
    ]
    x, y, _ = robot.pose
    assert abs(math.hypot(x - target[0], y - target[1]) - 0.36) < 0.03
