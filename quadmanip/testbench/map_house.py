"""``quadmanip map``: the robot maps the house by itself and the map is saved.

Runs the sim (lockstep, LiDAR on), locomotion and navigation in ``mapping`` mode as
separate processes over a private router, sends navigation's ``explore`` goal, prints its
progress, and when no reachable frontier is left saves the map navigation published in
the ROS map_server format (``NAME.pgm`` + ``NAME.yaml``) with a picture (``NAME.png``),
and drafts the places file beside it (``NAME.places.toml``).

The map frame: navigation's SLAM starts its map at the robot's start (map = odom there).
Before saving, this tool shifts the map's origin so that the map frame is the house's
floor-plan frame (the simulator's world), as a person annotating the floor plan would
choose: the shift is where the robot stood when the map began, read from ground truth
once (tooling; the services never read it). The map itself comes from the LiDAR alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.services.navigation.grid import GridGeometry, compose, invert
from quadmanip.services.navigation.map_io import save_map
from quadmanip.services.navigation.places import places_path_for, save_places
from quadmanip.sim.scenarios import Scenario, get_scenario
from quadmanip.testbench.nav_record import NavRecorder
from quadmanip.testbench.places_draft import draft_places
from quadmanip.testbench.stack import LIDAR_ONLY, StackRun

__all__ = ["MappingRun", "grid_geometry", "main", "run_mapping"]

NAV_SERVICES = ("sim", "locomotion", "navigation")


class MappingRun:
    """What a mapping run produced: the map message, the world pose of the map frame at
    the start, the explore result and timings."""

    def __init__(self) -> None:
        self.grid: m.OccupancyGrid | None = None
        self.world_T_map: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.status = ""
        self.reason = ""
        self.explore_time_s = math.nan
        self.wall_s = math.nan


def _empty(seed: int = 0) -> Scenario:
    return Scenario("empty", seed, ())


def nav_stack(
    scenario: Scenario,
    log: object,
    nav_args: list[str],
    stand_timeout_s: float = 180.0,
    extra_sim: tuple[str, ...] = (),
) -> StackRun:
    """The sim (LiDAR on, cameras off, plus ``extra_sim`` arguments), locomotion and
    navigation with ``nav_args``."""
    return StackRun(
        scenario,
        log,  # type: ignore[arg-type]
        extra_args={"navigation": nav_args, "sim": list(extra_sim)},
        stand_timeout_s=stand_timeout_s,
        services=NAV_SERVICES,
        sim_sensors=LIDAR_ONLY,
    )


def world_T_map(s: StackRun, timeout_s: float = 30.0) -> tuple[float, float, float]:
    """The map frame's pose in the world: ground-truth base pose ⊕ inverse(map pose), from
    one navigation pose and the ground truth of the same instant (TOOLING: reads gt)."""
    assert s.bus is not None
    pose = s.bus.latest("navigation/pose")
    deadline = time.monotonic() + timeout_s
    while True:
        p = pose.get()
        if p is not None:
            gt = s.base.get()
            if gt is not None and abs(float(gt.stamp) - float(p.stamp)) < 0.03:
                i = list(gt.names).index("base")
                g = (float(gt.positions[i][0]), float(gt.positions[i][1]),
                     yaw_from_quat(gt.orientations[i]))  # fmt: skip
                return compose(g, invert((float(p.x), float(p.y), float(p.yaw))))
        if time.monotonic() > deadline:
            raise RuntimeError("navigation published no pose")
        time.sleep(0.02)


def run_mapping(
    scenario: Scenario,
    max_time: float,
    log: object,
    progress: bool = True,
    record: str | Path = "",
) -> MappingRun:
    """Explore ``scenario``'s house with navigation in mapping mode; the final map
    (``record``: also save what navigation saw, see :mod:`.nav_record`)."""
    out = MappingRun()
    t_wall = time.monotonic()
    with nav_stack(scenario, log, ["--set", "node.mode=mapping"]) as s:
        assert s.bus is not None
        recorder = NavRecorder(s.bus) if record else None
        maps = s.bus.latest("navigation/map")
        out.world_T_map = world_T_map(s)
        client = s.actions["explore"]
        last = [""]

        def on_feedback(fb: m.ActionFeedback) -> None:
            if progress and fb.text != last[0]:
                last[0] = fb.text
                print(f"  [{s.elapsed()}] {fb.text}", flush=True)

        t0 = s.now()
        h = client.send_goal(
            m.ExploreGoal(stamp=t0, max_time=max_time), timeout=10.0, feedback_cb=on_feedback
        )
        if not h.accepted:
            raise RuntimeError(f"explore rejected: {h.reason}")
        res = None
        while res is None:
            s._check_alive()
            res = h.result(timeout=1.0)
        out.explore_time_s = s.now() - t0
        out.status = res.status
        out.reason = res.reason or (res.result.reason if res.result is not None else "")
        # the newest map, published after the explore ended
        t_end = time.monotonic() + 8.0
        first = maps.get()
        while time.monotonic() < t_end:
            g = maps.get()
            if g is not None and (first is None or g.stamp > first.stamp):
                break
            time.sleep(0.1)
        out.grid = maps.get()
        if recorder is not None:
            recorder.save(record)
    out.wall_s = time.monotonic() - t_wall
    return out


def grid_geometry(grid: m.OccupancyGrid) -> GridGeometry:
    """Where an ``OccupancyGrid`` message's cells lie (its origin yaw is 0 here)."""
    rows, cols = grid.data.shape
    return GridGeometry(float(grid.resolution), float(grid.origin[0]), float(grid.origin[1]),
                        int(cols), int(rows))  # fmt: skip


def save_in_world_frame(run: MappingRun, stem: Path) -> dict[str, Path]:
    """Save the map with its origin shifted into the floor-plan frame (the rotation of the
    SLAM start, a fraction of a degree, is not resampled; it is reported)."""
    assert run.grid is not None
    geo = dataclasses.replace(
        grid_geometry(run.grid),
        origin_x=float(run.grid.origin[0]) + run.world_T_map[0],
        origin_y=float(run.grid.origin[1]) + run.world_T_map[1],
    )
    paths = save_map(stem, np.asarray(run.grid.data), geo)
    header = (
        f"Places of {stem.name}.yaml, in its map frame (the house's floor-plan frame).\n"
        "Drafted by `quadmanip map` from the house description; edit by hand as needed:\n"
        "stand = [x, y, yaw_deg] where the robot stands, target = [x, y, z] what it is about."
    )
    paths["places"] = save_places(places_path_for(paths["yaml"]), draft_places(), header)
    return paths


def main(argv: list[str] | None = None) -> int:
    """``quadmanip map --scenario S --out DIR/NAME``."""
    ap = argparse.ArgumentParser(prog="quadmanip map", description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="empty",
                    help="scenario name or seed ('empty': the house without objects)")  # fmt: skip
    ap.add_argument("--out", required=True, help="output stem, e.g. configs/maps/house")
    ap.add_argument("--max-time", type=float, default=600.0, help="sim seconds to explore")
    ap.add_argument("--log", default="", help="file for the services' output")
    ap.add_argument("--json", default="", help="write the run's summary here")
    ap.add_argument("--record", default="", help="save scans, odometry, truth here (.npz)")
    args = ap.parse_args(argv)
    scenario = _empty() if args.scenario == "empty" else get_scenario(args.scenario)
    log = open(args.log, "w") if args.log else open("/dev/null", "w")  # noqa: SIM115
    try:
        print(f"mapping the house (scenario {scenario.name}) ...", flush=True)
        run = run_mapping(scenario, args.max_time, log, record=args.record)
    finally:
        log.close()
    if run.grid is None:
        print("no map was published", file=sys.stderr)
        return 1
    paths = save_in_world_frame(run, Path(args.out))
    summary = {
        "status": run.status,
        "reason": run.reason,
        "explore_time_s": round(run.explore_time_s, 1),
        "wall_s": round(run.wall_s, 1),
        "map_start_yaw_deg": round(math.degrees(run.world_T_map[2]), 3),
        "files": {k: str(v) for k, v in paths.items()},
    }
    print(json.dumps(summary, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")
    return 0 if run.status == "succeeded" else 1


if __name__ == "__main__":
    raise SystemExit(main())
