"""``quadmanip map``: the robot maps the house by itself and the map is saved.

Runs the sim (lockstep, LiDAR on), locomotion and navigation in ``mapping`` mode as
separate processes over a private router, sends navigation's ``explore`` goal, prints its
progress, and when no reachable frontier is left saves the map navigation published in
the ROS map_server format (``NAME.pgm`` + ``NAME.yaml``) with a picture (``NAME.png``),
and drafts the places file beside it (``NAME.places.toml``).

The map frame: navigation's SLAM starts its map at the robot's start (map = odom there).
Before saving, this tool shifts the map's origin so that the map frame is the house's
floor-plan frame (the simulator's world), as a person annotating the floor plan would
choose: the shift and turn are where the robot stood when the map began, read from ground
truth once (tooling; the services never read it); the turn is resampled into the cells.
The map itself comes from the LiDAR alone.
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
from quadmanip.services.navigation.grid import GridGeometry, compose, invert, transform_points
from quadmanip.services.navigation.map_io import save_map, save_surface
from quadmanip.services.navigation.places import places_path_for, save_places
from quadmanip.sim.scenarios import Scenario, get_scenario
from quadmanip.testbench.nav_record import NavRecorder
from quadmanip.testbench.places_draft import draft_places
from quadmanip.testbench.stack import LIDAR_ONLY, StackRun

__all__ = [
    "MappingRun",
    "fit_to_floor_plan",
    "grid_geometry",
    "into_world_frame",
    "main",
    "run_mapping",
]

NAV_SERVICES = ("sim", "locomotion", "navigation")


class MappingRun:
    """What a mapping run produced: the map message, the world pose of the map frame at
    the start, the explore result and timings."""

    def __init__(self) -> None:
        self.grid: m.OccupancyGrid | None = None
        self.surface: m.OccupancyGrid | None = None  # the 2 cm raster of surfaces seen
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
        surfaces = s.bus.latest("navigation/surface")
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
        out.surface = surfaces.get()
        if recorder is not None:
            recorder.save(record)
    out.wall_s = time.monotonic() - t_wall
    return out


def grid_geometry(grid: m.OccupancyGrid) -> GridGeometry:
    """Where an ``OccupancyGrid`` message's cells lie (its origin yaw is 0 here)."""
    rows, cols = grid.data.shape
    return GridGeometry(float(grid.resolution), float(grid.origin[0]), float(grid.origin[1]),
                        int(cols), int(rows))  # fmt: skip


def into_world_frame(
    occupancy: np.ndarray, geometry: GridGeometry, world_T_map: tuple[float, float, float]
) -> tuple[np.ndarray, GridGeometry]:
    """The grid in the floor-plan frame: its origin shifted by ``world_T_map``'s
    translation (exact) and its cells resampled by the rotation (each new cell takes the
    value of the map cell under its centre; unknown outside). Map files hold no rotation
    (origin yaw 0), and a turn of a tenth of a degree put the far room's walls 1-2 cm off
    the floor plan, which the localisation then carried to every goal there."""
    occ = np.asarray(occupancy)
    geo_w = dataclasses.replace(
        geometry,
        origin_x=geometry.origin_x + world_T_map[0],
        origin_y=geometry.origin_y + world_T_map[1],
    )
    rows, cols = np.mgrid[0 : geo_w.height, 0 : geo_w.width]
    centres = geo_w.cell_center(rows.ravel(), cols.ravel())
    r, k = geometry.to_cell(transform_points(invert(world_T_map), centres))
    inside = geometry.inside(r, k)
    out = np.full(occ.size, -1, dtype=occ.dtype)
    out[inside] = occ[r[inside], k[inside]]
    return out.reshape(occ.shape), geo_w


def fit_to_floor_plan(occupancy: np.ndarray, geometry: GridGeometry) -> tuple[float, float, float]:
    """The map frame's pose in the floor-plan frame that best lays the map's occupied cells
    on the house's true floor plan (rasterised at 1 cm; least squares of the distance,
    clipped at 5 cm; a grid search then Nelder-Mead). TOOLING: reads the simulator's
    world, as a person would lay a map on the floor plan."""
    from quadmanip.testbench.floor_plan import true_floor_plan
    from scipy import ndimage
    from scipy.optimize import minimize

    plan = true_floor_plan(resolution=0.01)
    r, c = np.nonzero(np.asarray(occupancy) >= 65)
    pts = geometry.cell_center(r, c)
    g = plan.geometry
    dist = ndimage.distance_transform_edt(~plan.mask) * g.resolution

    def cost(x: np.ndarray) -> float:
        p = transform_points((float(x[0]), float(x[1]), float(x[2])), pts)
        rr, cc = g.to_cell(p)
        ok = g.inside(rr, cc)
        d = np.full(len(p), 0.05)
        d[ok] = np.minimum(dist[rr[ok], cc[ok]], 0.05)
        return float(np.mean(d**2))

    steps = np.linspace(-0.03, 0.03, 7)
    starts = [
        np.array([dx, dy, math.radians(th)])
        for th in np.linspace(-0.4, 0.4, 17)
        for dx in steps
        for dy in steps
    ]
    x0 = min(starts, key=cost)
    # the cost is flat within the raster's 1 cm: a simplex of cell-sized steps
    simplex = np.array([x0, x0 + [0.005, 0, 0], x0 + [0, 0.005, 0], x0 + [0, 0, 1e-3]])
    res = minimize(
        cost, x0, method="Nelder-Mead",
        options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-10},
    )  # fmt: skip
    return float(res.x[0]), float(res.x[1]), float(res.x[2])


def save_in_world_frame(run: MappingRun, stem: Path) -> dict[str, Path]:
    """Save the map in the floor-plan frame (:func:`into_world_frame`)."""
    assert run.grid is not None
    occ, geo = into_world_frame(np.asarray(run.grid.data), grid_geometry(run.grid), run.world_T_map)
    paths = save_map(stem, occ, geo)
    if run.surface is not None:
        surface = np.asarray(run.surface.data) >= 65, grid_geometry(run.surface)
        paths["surface"] = _save_surface_moved(stem, surface, run.world_T_map)
    header = (
        f"Places of {stem.name}.yaml, in its map frame (the house's floor-plan frame).\n"
        "Drafted by `quadmanip map` from the house description; edit by hand as needed:\n"
        "stand = [x, y, yaw_deg] where the robot stands, target = [x, y, z] what it is about."
    )
    paths["places"] = save_places(places_path_for(paths["yaml"]), draft_places(), header)
    return paths


def register_saved(stem: Path) -> int:
    """``quadmanip map --register --out STEM``: re-save a map registered to the floor plan
    (its places file is left as it is: places are in the floor-plan frame already); its
    surface raster, if any, is moved with it."""
    from quadmanip.services.navigation.map_io import load_map, load_surface

    occ, geo = load_map(stem.with_suffix(".yaml"))
    surface = load_surface(stem.with_suffix(".yaml"))
    # the fine surface places the walls to a cell of 2 cm, the map to one of 5 cm
    t = (fit_to_floor_plan(occ, geo) if surface is None
         else fit_to_floor_plan(surface[0].astype(np.int8) * 100, surface[1]))  # fmt: skip
    print(f"{stem}: laid on the floor plan by dx={t[0] * 100:.2f} cm dy={t[1] * 100:.2f} cm "
          f"turn={math.degrees(t[2]):.3f} deg", flush=True)  # fmt: skip
    occ_w, geo_w = into_world_frame(np.asarray(occ), geo, t)
    save_map(stem, occ_w, geo_w, crop=False)
    if surface is not None:
        _save_surface_moved(stem, surface, t)
    return 0


def _save_surface_moved(
    stem: Path, surface: tuple[np.ndarray, GridGeometry], t: tuple[float, float, float]
) -> Path:
    """Save a surface raster (mask, geometry) beside the map ``stem``, moved by ``t`` as
    :func:`into_world_frame` moves the map."""
    occ, geo = into_world_frame(surface[0].astype(np.int8) * 100, surface[1], t)
    return save_surface(stem, occ >= 65, geo)


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
    ap.add_argument("--register", action="store_true",
                    help="no mapping: lay the saved map --out on the house's floor plan "
                         "(rotation included) and save it again")  # fmt: skip
    args = ap.parse_args(argv)
    if args.register:
        return register_saved(Path(args.out))
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
