"""``quadmanip bench navigation``: mapping, localisation, navigation and the precise
approach over the full stack (sim, locomotion, navigation as processes), scored from
ground truth (BENCHMARK: reads ``sim/gt``; the services never do).

Parts (``--parts``, default all):

* ``map``: per seed, the robot starts at a random free pose in the living room, explores
  (``quadmanip map``'s run) and the map is scored against the house's true floor plan
  (:mod:`.floor_plan`): precision = occupied map cells within one cell of a true
  obstacle; recall = true obstacle *surface* cells (those facing free space at least
  20 cm wide that the robot can reach: walls, furniture legs, the blocks' faces; not the
  5 cm slits behind the sofa and the shelf) with an occupied map cell within one cell;
  F1. Also the exploration time (sim).
* ``nav``: on the committed map (configs/maps/house.yaml, localisation mode), goals at
  random free poses (seeded), alternating rooms so many cross the doorway: success =
  the true pose within 5 cm and 3 deg after ``navigate_to`` reports; time ratio = time /
  (shortest path / top speed + turning / top turn rate); contacts between the robot and
  walls or furniture (simulator contacts above the floor). The same run scores
  localisation: the true pose against navigation's map pose at every scan; the scans
  are replayed afterwards through the particle filter and the planner for their times.
* ``approach``: targets 0.5-1.5 m away in the odom frame; final true error.
* ``obstacles``: a box that is not in the map on the way (passed around, no contact),
  and a box filling the doorway (``blocked`` with a reason within 30 s, standing).
* ``reloc``: navigation started 1 m and 90 deg off; the harness walks the robot (velocity
  commands, a safe straight line in the open); time until the map pose is within 5 cm
  and 2 deg and stays there.

The JSON's ``summary`` holds the issue's keys; ``runs`` the per-goal details.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.services.navigation.amcl import AmclConfig, ParticleFilter
from quadmanip.services.navigation.config import NavigationConfig
from quadmanip.services.navigation.costmap import Costmap, CostmapConfig
from quadmanip.services.navigation.global_planner import plan_path
from quadmanip.services.navigation.grid import (
    Pose2,
    compose,
    invert,
    transform_points,
    wrap,
)
from quadmanip.services.navigation.map_io import load_map
from quadmanip.services.navigation.node import resolve_map_path
from quadmanip.services.navigation.path_follower import FollowerConfig
from quadmanip.services.navigation.scan import lidar_mount, scan_points
from quadmanip.sim.scenarios import Obstacle, Scenario
from quadmanip.testbench.floor_plan import FloorPlan, true_floor_plan
from quadmanip.testbench.map_house import grid_geometry, nav_stack, run_mapping
from quadmanip.testbench.nav_record import NavRecorder
from quadmanip.testbench.stack import StackError, StackRun
from scipy import ndimage

__all__ = ["main", "map_scores", "random_free_poses"]

HOUSE_START = (0.8, 1.2, 0.0)
CONTACTS_ON = ("--set", "ground_truth.contacts_rate=20")
GOAL_TOL = (0.03, math.radians(2.0))  # what the bench asks navigate_to for


# ------------------------------------------------------------------ scoring helpers
def _reachable_free(plan: FloorPlan, start: tuple[float, float]) -> np.ndarray:
    labels, _ = ndimage.label(~plan.mask)
    (r,), (c,) = plan.geometry.to_cell(np.array([start]))
    return labels == labels[r, c]


def visible_surface(plan: FloorPlan, start: tuple[float, float] = HOUSE_START[:2]) -> np.ndarray:
    """The obstacle cells a LiDAR can see: the faces turned to free space that the robot
    can reach (from ``start``) and look along, i.e. free space at least 20 cm wide and the
    cells between it and the face. Not the inside of a 10 cm wall (its second row of cells,
    which the first version of this score counted: 1334 cells where the faces are 774),
    nor the raster's 5 cm slits between the sofa or the shelf and the wall, nor the inside
    of the cabinet."""
    dist = ndimage.distance_transform_edt(~plan.mask) * plan.geometry.resolution
    reach = _reachable_free(plan, start)
    open_free = reach & (dist >= 0.1)
    # free cells within two of open space: the 5 cm in front of a face, a slit's mouth
    before_face = reach & ndimage.binary_dilation(open_free, iterations=2)
    return plan.mask & ndimage.binary_dilation(before_face, iterations=1)


def map_scores(
    occupancy: np.ndarray, geometry: Any, world_T_map: Pose2, plan: FloorPlan
) -> dict[str, float]:
    """Precision, recall and F1 of a map's occupied cells against the true plan (one cell
    tolerance); recall counts the obstacle surface the robot can see."""
    r, c = np.nonzero(occupancy >= 65)
    pts = transform_points(world_T_map, geometry.cell_center(r, c))
    g = plan.geometry
    rr, cc = g.to_cell(pts)
    ins = g.inside(rr, cc)
    near_true = ndimage.binary_dilation(plan.mask, iterations=1)
    tp = int(near_true[rr[ins], cc[ins]].sum())
    precision = tp / max(len(rr), 1)
    pred = np.zeros_like(plan.mask)
    pred[rr[ins], cc[ins]] = True
    surface = visible_surface(plan)
    recall = float(ndimage.binary_dilation(pred, iterations=1)[surface].mean())
    f1 = 2 * precision * recall / max(precision + recall, 1e-9)
    return {"precision": round(precision, 4), "recall": round(recall, 4), "f1": round(f1, 4)}


def standable(plan: FloorPlan, clearance: float) -> np.ndarray:
    """Cells of the house's reachable free space at least ``clearance`` from any obstacle,
    table top or box on the floor: where the robot can be sent."""
    free = _reachable_free(plan, HOUSE_START[:2])
    # under a table the LiDAR sees only legs, but the robot (and its arm) do not fit there
    from quadmanip.sim.world.house import load_house

    # nor on furniture below the LiDAR's plane (the boxes on the floor: a goal on the
    # black box's edge was drawn, and refused as "too close to an obstacle")
    house = load_house()
    blocked = plan.mask.copy()
    footprints = [(t.center, t.size) for t in house.tables]
    footprints += [(b.center, b.size[:2]) for b in house.blocks]
    footprints += [(c.center, c.size[:2]) for c in house.containers if c.on == "floor"]
    for center, size in footprints:
        lo = np.asarray(center) - np.asarray(size) / 2
        hi = np.asarray(center) + np.asarray(size) / 2
        (r0, r1), (c0, c1) = plan.geometry.to_cell(np.array([lo, hi]))
        blocked[max(r0, 0) : r1 + 1, max(c0, 0) : c1 + 1] = True
    dist = ndimage.distance_transform_edt(~blocked) * plan.geometry.resolution
    return free & (dist >= clearance)


def random_free_poses(plan: FloorPlan, n: int, seed: int, clearance: float = 0.5) -> list[Pose2]:
    """``n`` poses where the robot can be sent (:func:`standable`), alternating between the
    two rooms (x < 5 and x > 5)."""
    rng = np.random.default_rng([seed, 0x4E41])
    rows, cols = np.nonzero(standable(plan, clearance))
    centres = plan.geometry.cell_center(rows, cols)
    rooms = [centres[centres[:, 0] < 4.9], centres[centres[:, 0] > 5.1]]
    out: list[Pose2] = []
    for k in range(n):
        pool = rooms[(k + 1) % 2]
        x, y = pool[rng.integers(len(pool))]
        out.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
    return out


def _gt_pose(s: StackRun) -> Pose2:
    p, q = s.pose("base")
    return (float(p[0]), float(p[1]), yaw_from_quat(q))


class _Contacts:
    """Counts new robot-vs-house contacts (above the floor) from ``sim/gt/contacts``."""

    def __init__(self, s: StackRun) -> None:
        import mujoco
        from quadmanip.common import robot_description as rd

        model = rd.load_mujoco_model()
        self.robot = {
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, model.nbody)
        }
        self.active: set[tuple[str, str]] = set()
        self.count = 0
        self.examples: list[str] = []
        assert s.bus is not None
        s.bus.subscribe("sim/gt/contacts", self._on)

    def _on(self, msg: m.GroundTruthContacts) -> None:
        now: set[tuple[str, str]] = set()
        for b1, b2, p in zip(msg.body1, msg.body2, msg.positions, strict=True):
            r1, r2 = b1 in self.robot, b2 in self.robot
            if r1 == r2:
                continue
            other = b2 if r1 else b1
            if other.startswith("obj/") or (other == "world" and p[2] < 0.05):
                continue  # objects (the arm's business) and the floor under the feet
            now.add((b1 if r1 else b2, other))
        for pair in now - self.active:
            self.count += 1
            if len(self.examples) < 10:
                self.examples.append(f"{pair[0]} - {pair[1]}")
        self.active = now


def _send_and_wait(s: StackRun, action: str, goal: m.Message, timeout_s: float) -> Any:
    h = s.actions[action].send_goal(goal, timeout=10.0)
    if not h.accepted:
        return None, h.reason
    deadline = time.monotonic() + timeout_s
    res = None
    while res is None:
        s._check_alive()
        if time.monotonic() > deadline:
            h.cancel()
            return None, f"no result after {timeout_s:.0f} s"
        res = h.result(timeout=1.0)
    return res, res.reason


def _ideal_time(plan_cm: Costmap, start: Pose2, goal: Pose2) -> tuple[float, float]:
    """(shortest path length on the true plan, time at top speed and turn rate)."""
    fc = FollowerConfig()
    res = plan_path(plan_cm, start[:2], goal[:2])
    if not res.ok:
        return math.nan, math.nan
    assert res.path is not None and res.headings is not None
    turns = abs(wrap(res.headings[0] - start[2])) + abs(wrap(goal[2] - res.headings[-1]))
    turns += float(np.sum(np.abs(wrap(np.diff(res.headings)))))
    return res.length, res.length / fc.max_vx + turns / fc.max_wz


# ------------------------------------------------------------------ parts
def part_map(seeds: list[int], log: Any) -> dict[str, Any]:
    plan = true_floor_plan()
    runs = []
    for seed in seeds:
        start = random_free_poses(plan, 2, seed, clearance=0.6)[1]  # a living-room pose
        scn = Scenario(f"empty-{seed}", seed, (), robot_start=(start[0], start[1],
                                                               math.degrees(start[2])))  # fmt: skip
        print(f"map seed {seed}: start {np.round(start, 2).tolist()} ...", flush=True)
        run = run_mapping(scn, 600.0, log, progress=False)
        row: dict[str, Any] = {"seed": seed, "status": run.status, "reason": run.reason,
                               "explore_time_s": round(run.explore_time_s, 1)}  # fmt: skip
        if run.grid is not None:
            geo = grid_geometry(run.grid)
            row.update(map_scores(np.asarray(run.grid.data), geo, run.world_T_map, plan))
        print(f"  {row}", flush=True)
        runs.append(row)
    return {"runs": runs}


def part_nav(
    seed: int,
    n_goals: int,
    n_approach: int,
    log: Any,
    record: str = "",
    approach_tolerance: tuple[float, float] = (0.01, 0.0175),
) -> dict[str, Any]:
    plan = true_floor_plan()
    occ, geo = load_map(resolve_map_path(NavigationConfig().node.map))
    plan_cm = Costmap(CostmapConfig(), np.where(plan.mask, 100, 0).astype(np.int8), plan.geometry)
    goals = random_free_poses(plan, n_goals, seed)
    out: dict[str, Any] = {"goals": [], "approach": []}
    with nav_stack(Scenario("empty", seed, ()), log, [],
                   extra_sim=CONTACTS_ON) as s:  # fmt: skip
        assert s.bus is not None
        rec = NavRecorder(s.bus)
        contacts = _Contacts(s)
        out["goals_planned"], out["approaches_planned"] = len(goals), n_approach
        walking_to = None  # the goal under way, for the row of a run a fall ends
        try:
            for k, goal in enumerate(goals):
                walking_to = goal
                start = _gt_pose(s)
                length, ideal = _ideal_time(plan_cm, start, goal)
                c0 = contacts.count
                t0 = s.now()
                # asked 3 cm / 2 deg by its own estimate, so that the true pose is within the
                # issue's 5 cm / 3 deg with the localisation's error on top
                res, reason = _send_and_wait(
                    s,
                    "navigate_to",
                    m.NavigateGoal(stamp=t0, pose=np.array(goal), tolerance_xy=GOAL_TOL[0],
                                   tolerance_yaw=GOAL_TOL[1]),
                    300.0,
                )  # fmt: skip
                s.wait_sim(s.now() + 0.5)
                end = _gt_pose(s)
                err = math.hypot(end[0] - goal[0], end[1] - goal[1])
                yerr = abs(float(wrap(end[2] - goal[2])))
                dur = (res.result.duration if res is not None and res.result is not None
                       else s.now() - t0)  # fmt: skip
                row = {
                    "goal": np.round(goal, 3).tolist(),
                    "status": None if res is None else res.status,
                    "reason": reason,
                    "error_m": round(err, 4),
                    "error_deg": round(math.degrees(yerr), 2),
                    "reached": bool(
                        res is not None
                        and res.status == "succeeded"
                        and err <= 0.05
                        and yerr <= math.radians(3.0)
                    ),  # fmt: skip
                    "time_s": round(dur, 2),
                    "path_m": round(length, 2),
                    "time_ratio": round(dur / ideal, 3) if ideal > 0 else None,
                    "contacts": contacts.count - c0,
                }
                out["goals"].append(row)
                walking_to = None
                print(f"  goal {k + 1}/{len(goals)}: {row}", flush=True)
            rng = np.random.default_rng([seed, 0xA7])
            fits = standable(plan, 0.45)
            odom = s.bus.latest("locomotion/odometry")
            for k in range(n_approach):
                # back to open floor first, then a target 0.5-1.5 m ahead (+-30 deg) in odom
                centre = (2.6, 1.6, float(rng.uniform(-math.pi, math.pi)))
                _send_and_wait(s, "navigate_to", m.NavigateGoal(stamp=s.now(),
                               pose=np.array(centre), tolerance_xy=0.1, tolerance_yaw=0.2), 200.0)  # fmt: skip
                s.wait_sim(s.now() + 0.5)
                od = odom.get()
                o: Pose2 = (float(od.position[0]), float(od.position[1]),
                            yaw_from_quat(od.orientation))  # fmt: skip
                g = _gt_pose(s)
                # where a stand pose is in the world, through the odometry at the goal
                w_T_o = compose(g, invert(o))
                for _ in range(100):  # a target the robot fits at (one by the sofa was drawn)
                    dist = float(rng.uniform(0.5, 1.5))
                    bearing = float(rng.uniform(-0.5, 0.5))
                    heading = o[2] + float(rng.uniform(-0.5, 0.5))
                    target_odom = (o[0] + dist * math.cos(o[2] + bearing),
                                   o[1] + dist * math.sin(o[2] + bearing))  # fmt: skip
                    want = compose(w_T_o, (target_odom[0], target_odom[1], heading))
                    (r,), (c,) = plan.geometry.to_cell(np.array([want[:2]]))
                    if fits[r, c]:
                        break
                t_start = s.now()
                res, reason = _send_and_wait(
                    s, "approach",
                    m.ApproachGoal(stamp=s.now(), target=np.array(target_odom), frame="odom",
                                   standoff=0.0, heading=heading,
                                   tolerance_xy=approach_tolerance[0],
                                   tolerance_yaw=approach_tolerance[1]), 120.0)  # fmt: skip
                s.wait_sim(s.now() + 0.5)
                end = _gt_pose(s)
                row = {
                    "distance_m": round(dist, 3),
                    "t_start": round(t_start, 3),  # sim time: to find it in the recording
                    "status": None if res is None else res.status,
                    "reason": reason,
                    "error_m": round(math.hypot(end[0] - want[0], end[1] - want[1]), 4),
                    "error_deg": round(math.degrees(abs(float(wrap(end[2] - want[2])))), 3),
                    "time_s": None
                    if res is None or res.result is None
                    else round(res.result.duration, 2),
                    # the error navigation itself saw, in the odom frame: the controller's share
                    "odom_error_m": None
                    if res is None or res.result is None
                    else round(res.result.error_xy, 4),
                }
                out["approach"].append(row)
                print(f"  approach {k + 1}/{n_approach}: {row}", flush=True)
        except StackError as exc:  # the robot fell: keep what was measured, and say so
            out["tripped"] = str(exc)
            print(f"  stopped: {exc}", flush=True)
            if walking_to is not None:
                out["goals"].append({"goal": np.round(walking_to, 3).tolist(), "status": "tripped",
                                     "reason": str(exc), "reached": False, "contacts": 0,
                                     "time_ratio": None})  # fmt: skip
        out["contacts_examples"] = contacts.examples
        data = rec.arrays()
        if record:
            rec.save(record)
    out["loc"] = _loc_scores(data)
    out["algo"] = _algo_times(data, occ, geo)
    return out


def _loc_scores(d: dict[str, np.ndarray]) -> dict[str, Any]:
    """Localisation error: each map pose against the truth at that pose's own stamp
    (``gt_at_nav``; see :mod:`.nav_record`); the error against the newest truth at the
    scan, which adds up to a control step of walking, is kept as ``*_at_scan``."""
    if not d:
        return {}
    nav, gt = d["nav"], d["gt"]
    ref = d.get("gt_at_nav", gt)

    def errors(truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ok = ~np.isnan(nav[:, 0]) & ~np.isnan(truth[:, 0])
        e = np.hypot(nav[ok, 0] - truth[ok, 0], nav[ok, 1] - truth[ok, 1])
        return e, np.degrees(np.abs(wrap(nav[ok, 2] - truth[ok, 2])))

    e, ey = errors(ref)
    e0, ey0 = errors(gt)
    return {
        "scans": len(e),
        "rmse_m": round(float(np.sqrt(np.mean(e**2))), 4),
        "max_m": round(float(e.max()), 4),
        "yaw_rmse_deg": round(float(np.sqrt(np.mean(ey**2))), 3),
        "rmse_m_at_scan": round(float(np.sqrt(np.mean(e0**2))), 4),
        "max_m_at_scan": round(float(e0.max()), 4),
        "yaw_rmse_deg_at_scan": round(float(np.sqrt(np.mean(ey0**2))), 3),
    }


def _algo_times(d: dict[str, np.ndarray], occ: np.ndarray, geo: Any) -> dict[str, Any]:
    """The recorded scans replayed through the particle filter (its update time), and
    plans between random pairs over the whole map (the planner's time)."""
    if not d:
        return {}
    pf = ParticleFilter(AmclConfig(), occ, geo, np.random.default_rng(0))
    od = d["odom"]
    pf.initialize(tuple(d["gt"][0, :3]), (0.05, 0.05, 0.05))
    mount = lidar_mount()
    times = []
    for i in range(len(d["stamp"])):
        o = (float(od[i, 0]), float(od[i, 1]), yaw_from_quat(od[i, 3:7]))
        pf.predict(o)
        sp = scan_points(d["stamp"][i], d["ranges"][i], float(d["angles"][0]),
                         float(d["angles"][1]), 0.1, 12.0, mount)  # fmt: skip
        t = time.perf_counter()
        if pf.update(sp):
            times.append((time.perf_counter() - t) * 1e3)
    cm = Costmap(CostmapConfig(), occ, geo)
    plan = true_floor_plan()
    poses = random_free_poses(plan, 60, 7)
    pms = [plan_path(cm, a[:2], b[:2]).ms for a, b in zip(poses[:-1], poses[1:], strict=True)]
    return {
        "loc_update_ms_p50": round(float(np.median(times)), 2) if times else None,
        "loc_updates": len(times),
        "plan_ms_p50": round(float(np.median(pms)), 2),
        "plan_ms_p95": round(float(np.percentile(pms, 95)), 2),
    }


def part_obstacles(seed: int, log: Any) -> dict[str, Any]:
    """A box that is not in the map stands on the way (it must be passed around without
    touching it), and a box fills the doorway (the goal beyond must end ``blocked`` with
    a reason within 30 s, the robot standing)."""
    out: dict[str, Any] = {}
    box = Scenario("box-in-the-way", seed, (),
                   obstacles=(Obstacle("box", (2.4, 1.2), (0.5, 0.5, 0.6)),))  # fmt: skip
    with nav_stack(box, log, [], extra_sim=CONTACTS_ON) as s:
        contacts = _Contacts(s)
        goal = (4.0, 1.2, 0.0)
        res, reason = _send_and_wait(s, "navigate_to", m.NavigateGoal(
            stamp=s.now(), pose=np.array(goal), tolerance_xy=GOAL_TOL[0],
            tolerance_yaw=GOAL_TOL[1]), 200.0)  # fmt: skip
        s.wait_sim(s.now() + 0.5)
        end = _gt_pose(s)
        err = math.hypot(end[0] - goal[0], end[1] - goal[1])
        out["box"] = {
            "status": None if res is None else res.status,
            "reason": reason,
            "error_m": round(err, 4),
            "contacts": contacts.count,
            "contact_examples": contacts.examples,
            "passed": bool(
                res is not None
                and res.status == "succeeded"
                and err <= 0.05
                and contacts.count == 0
            ),  # fmt: skip
        }
        print(f"  box in the way: {out['box']}", flush=True)
    door = Scenario("doorway-blocked", seed, (),
                    obstacles=(Obstacle("door", (5.0, 2.0), (0.3, 1.3, 0.8)),))  # fmt: skip
    with nav_stack(door, log, [], extra_sim=CONTACTS_ON) as s:
        contacts = _Contacts(s)
        t0 = s.now()
        res, reason = _send_and_wait(s, "navigate_to", m.NavigateGoal(
            stamp=t0, pose=np.array([8.3, 2.0, 0.0])), 200.0)  # fmt: skip
        took = s.now() - t0
        s.wait_sim(s.now() + 1.0)
        standing = bool(s.pose("base")[0][2] > 0.25 and s.tilt_deg() < 10.0)
        outcome = None if res is None or res.result is None else res.result.outcome
        out["doorway"] = {
            "status": None if res is None else res.status,
            "outcome": outcome,
            "reason": reason,
            "time_s": round(took, 2),
            "standing": standing,
            "contacts": contacts.count,
            "passed": bool(
                outcome == "blocked" and took <= 30.0 and standing and contacts.count == 0
            ),  # fmt: skip
        }
        print(f"  doorway blocked: {out['doorway']}", flush=True)
    return out


def part_reloc(seed: int, log: Any) -> dict[str, Any]:
    """Navigation started 1 m and 90 deg off (with a spread that covers it, as a person
    gives a rough pose), and started with no pose at all (global localisation)."""
    off = (HOUSE_START[0] + 1.0, HOUSE_START[1], 90.0)
    offset = ["--set", f"node.initial_pose=[{off[0]}, {off[1]}, {off[2]}]",
              "--set", "node.initial_std=[0.7, 0.7, 60.0]"]  # fmt: skip
    out = {"offset": _reloc_run(seed, log, offset)}
    out["global"] = _reloc_run(seed, log, ["--set", "node.global_localization=true"])
    out["converged"] = bool(out["offset"]["converged"] and out["global"]["converged"])
    out["time_s"] = out["offset"]["time_s"]
    return out


def _reloc_run(seed: int, log: Any, args: list[str]) -> dict[str, Any]:
    """Walk straight in the open living room (velocity commands from the harness) and
    time how long navigation's map pose takes to come within 5 cm and 2 deg and stay."""
    with nav_stack(Scenario("empty", seed, ()), log, args) as s:
        assert s.bus is not None
        pose = s.bus.latest("navigation/pose")
        vel = s.bus.publisher("locomotion/cmd_vel")
        t0 = s.now()
        within_since = None
        converged_at = None
        trace: list[tuple[float, float, float, str]] = []
        while s.now() - t0 < 30.0:
            g = _gt_pose(s)
            vx = 0.3 if g[0] < 3.8 else 0.0
            vel.publish(m.BodyVelocityCommand(stamp=s.now(), vx=vx, vy=0.0, wz=0.0))
            p = pose.get()
            if p is not None:
                e = math.hypot(p.x - g[0], p.y - g[1])
                ey = abs(float(wrap(p.yaw - g[2])))
                if int(s.now() * 2) != int((s.now() - 0.05) * 2):
                    trace.append((round(s.now() - t0, 2), round(e, 3), round(math.degrees(ey), 2),
                                  p.status))  # fmt: skip
                if e <= 0.05 and ey <= math.radians(2.0):
                    within_since = within_since if within_since is not None else s.now()
                    if s.now() - within_since >= 2.0:
                        converged_at = within_since - t0
                        break
                else:
                    within_since = None
            time.sleep(0.05)
        return {"converged": converged_at is not None,
                "time_s": None if converged_at is None else round(converged_at, 2),
                "trace": trace[:60]}  # fmt: skip


# ------------------------------------------------------------------ main
def _summary(res: dict[str, Any]) -> dict[str, Any]:
    s: dict[str, Any] = {}
    if "map" in res:
        runs = res["map"]["runs"]
        s["map_f1"] = min((r.get("f1", 0.0) for r in runs), default=None)
        s["explore_time_s"] = max((r["explore_time_s"] for r in runs), default=None)
    if "nav" in res:
        g = res["nav"]["goals"]
        loc = res["nav"].get("loc", {})
        s["loc_rmse_m"] = loc.get("rmse_m")
        s["loc_max_m"] = loc.get("max_m")
        s["loc_yaw_rmse_deg"] = loc.get("yaw_rmse_deg")
        planned = res["nav"].get("goals_planned", len(g))  # a fall ends the run early
        s["nav_success"] = round(sum(r["reached"] for r in g) / max(planned, len(g), 1), 3)
        ratios = [r["time_ratio"] for r in g if r["reached"] and r["time_ratio"]]
        s["nav_time_ratio_p50"] = round(float(np.median(ratios)), 3) if ratios else None
        s["collisions"] = sum(r["contacts"] for r in g)
        s["tripped"] = res["nav"].get("tripped", "")
        a = [r["error_m"] for r in res["nav"]["approach"]]
        s["approach_err_m_p95"] = round(float(np.percentile(a, 95)), 4) if a else None
        ad = [r["error_deg"] for r in res["nav"]["approach"]]
        s["approach_err_deg_p95"] = round(float(np.percentile(ad, 95)), 3) if ad else None
        algo = res["nav"].get("algo", {})
        s["plan_ms_p50"] = algo.get("plan_ms_p50")
        s["loc_update_ms_p50"] = algo.get("loc_update_ms_p50")
    if "obstacles" in res:
        s["obstacle_passed"] = res["obstacles"]["box"]["passed"]
        s["doorway_blocked_reported"] = res["obstacles"]["doorway"]["passed"]
        s["doorway_blocked_time_s"] = res["obstacles"]["doorway"]["time_s"]
    if "reloc" in res:
        s["relocalized"] = res["reloc"]["converged"]
        s["relocalize_time_s"] = res["reloc"]["time_s"]
    return s


def main(argv: list[str] | None = None) -> int:
    """``quadmanip bench navigation --json FILE [--seeds 0,1] [--parts map,nav,reloc]``."""
    ap = argparse.ArgumentParser(
        prog="quadmanip bench navigation", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--json", required=True, help="output file")
    ap.add_argument("--seeds", default="0", help="comma-separated scenario seeds")
    ap.add_argument("--parts", default="map,nav,obstacles,reloc",
                    help="map, nav, obstacles, reloc")  # fmt: skip
    ap.add_argument("--goals", type=int, default=50, help="navigation goals per seed")
    ap.add_argument("--approaches", type=int, default=20, help="approach trials per seed")
    ap.add_argument("--approach-tolerance", type=float, nargs=2, default=(0.01, 0.0175),
                    metavar=("XY", "YAW"),
                    help="the approaches' tolerance, m and rad (the task probes at 0.015 0.03)")  # fmt: skip
    ap.add_argument("--log", default="", help="file for the services' output")
    ap.add_argument("--record", default="", help="save the nav run's scans here (.npz)")
    ap.add_argument("--pictures", default="", help="draw the map and a run into this folder")
    ap.add_argument("--pictures-only", action="store_true",
                    help="only draw the pictures (from --record's file)")  # fmt: skip
    args = ap.parse_args(argv)
    if args.pictures_only:
        for p in draw_pictures(args.record, args.pictures or "docs/img"):
            print(p)
        return 0
    seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    unknown = parts - {"map", "nav", "obstacles", "reloc"}
    if unknown or not seeds:
        ap.error(f"unknown parts {sorted(unknown)}" if unknown else "no seeds")
    log = open(args.log, "w") if args.log else open("/dev/null", "w")  # noqa: SIM115
    res: dict[str, Any] = {"seeds": seeds}
    t0 = time.monotonic()
    try:
        if "map" in parts:
            res["map"] = part_map(seeds, log)
        if "nav" in parts:
            res["nav"] = part_nav(seeds[0], args.goals, args.approaches, log, args.record,
                                  tuple(args.approach_tolerance))  # fmt: skip
        if "obstacles" in parts:
            res["obstacles"] = part_obstacles(seeds[0], log)
        if "reloc" in parts:
            res["reloc"] = part_reloc(seeds[0], log)
    finally:
        log.close()
    res["summary"] = _summary(res)
    if args.pictures:
        res["pictures"] = [str(p) for p in draw_pictures(args.record, args.pictures)]
    res["wall_s"] = round(time.monotonic() - t0, 1)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res["summary"], indent=2))
    return 0


# ------------------------------------------------------------------ pictures
def draw_pictures(record: str | Path, out_dir: str | Path, goals_shown: int = 8) -> list[Path]:
    """``navigation_map.png`` (the committed map beside the true floor plan, differences
    coloured) and ``navigation_run.png`` (a recorded navigation run on the map: the true
    path, navigation's own estimate and the goals)."""
    import cv2

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plan = true_floor_plan()
    occ, geo = load_map(resolve_map_path(NavigationConfig().node.map))
    g = plan.geometry
    # the map resampled onto the plan's raster (both in the floor-plan frame)
    rows, cols = np.mgrid[0 : g.height, 0 : g.width]
    centres = g.cell_center(rows.ravel(), cols.ravel())
    mr, mc = geo.to_cell(centres)
    inside = geo.inside(mr, mc)
    mp = np.full(len(centres), -1, dtype=np.int16)
    mp[inside] = occ[mr[inside], mc[inside]]
    mp = mp.reshape(g.shape)
    scale = 6

    def canvas() -> np.ndarray:
        return np.full(g.shape + (3,), 255, dtype=np.uint8)

    truth = canvas()
    truth[plan.mask] = (40, 40, 40)
    built = canvas()
    built[mp < 0] = (170, 170, 170)
    built[mp >= 65] = (40, 40, 40)
    near_true = ndimage.binary_dilation(plan.mask, iterations=1)
    near_map = ndimage.binary_dilation(mp >= 65, iterations=1)
    built[(mp >= 65) & ~near_true] = (0, 0, 230)  # red (BGR): mapped, not there
    missed = visible_surface(plan) & ~near_map
    truth[missed] = (230, 120, 0)  # blue: visible, not mapped

    def big(img: np.ndarray, title: str) -> np.ndarray:
        im = cv2.resize(img[::-1], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        bar = np.full((36, im.shape[1], 3), 255, dtype=np.uint8)
        cv2.putText(bar, title, (8, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 2)
        return np.vstack([bar, im])

    sep = np.full((g.height * scale + 36, 12, 3), 255, dtype=np.uint8)
    p1 = out / "navigation_map.png"
    cv2.imwrite(str(p1), np.hstack([big(truth, "true floor plan at the LiDAR's height "
                                                "(blue: not mapped)"), sep,
                                    big(built, "map built by exploring (red: not there)")]))  # fmt: skip
    paths = [p1]
    d = dict(np.load(record)) if Path(record).is_file() else {}
    if d:
        img = big(built, "a navigation run: true path (blue), navigation's estimate (orange)")

        def px(xy: np.ndarray) -> np.ndarray:
            fr = g.to_fractional(xy)
            return np.stack([(fr[:, 1] + 0.5) * scale, (g.height - fr[:, 0] - 0.5) * scale + 36],
                            axis=1).astype(np.int32)  # fmt: skip

        gt, nav = d["gt"], d["nav"]
        n = len(gt)
        # the first ``goals_shown`` goals: cut where the robot stood still the n-th time
        speed = np.hypot(*np.diff(gt[:, :2], axis=0).T)
        stops = np.flatnonzero((speed[1:] < 1e-3) & (speed[:-1] >= 1e-3))
        end = int(stops[min(goals_shown, len(stops)) - 1]) + 2 if len(stops) else n
        cv2.polylines(img, [px(gt[:end, :2])], False, (200, 80, 0), 2)
        ok = ~np.isnan(nav[:end, 0])
        cv2.polylines(img, [px(nav[:end][ok, :2])], False, (0, 140, 255), 1)
        for k in stops[: goals_shown - 1]:
            cv2.drawMarker(img, tuple(px(gt[k + 1 : k + 2, :2])[0]), (0, 0, 220),
                           cv2.MARKER_TILTED_CROSS, 14, 2)  # fmt: skip
        p2 = out / "navigation_run.png"
        cv2.imwrite(str(p2), img)
        paths.append(p2)
    return paths


if __name__ == "__main__":
    sys.exit(main())
