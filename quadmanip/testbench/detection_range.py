"""How far the front camera's detector finds each object on the floor (tooling).

The object memory counts a miss when a track in view is not detected
(:mod:`quadmanip.services.perception.object_memory`); beyond the distance at which the
detector finds a class, a miss says nothing, and counting it drops objects found before
(paper-1, 2026-12-07: a Lego confirmed four times, dropped each time). This renders each
catalogue object on the open living-room floor at a series of distances from the front
camera (the robot standing, arm stowed, as when it walks), with random yaws and small
sideways offsets, runs the perception service's detector on each view (its weights and
report threshold), and reports per class the farthest distance up to which it was found
in every view: the ``[memory.miss_ranges]`` of ``configs/perception.toml``. It reads the
objects' true poses, as a benchmark may; no service uses it.

    python -m quadmanip.testbench.detection_range --views 4 --json F
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

__all__ = ["detection_ranges", "main"]

START = (0.6, 1.65, 0.0)  # the living room's open floor, facing +x (x, y m, yaw deg)
RANGES = tuple(round(1.0 + 0.25 * k, 2) for k in range(9))  # m from the camera, 1-3 m
LATERAL = 0.2  # m: sideways offsets drawn within +-


def detection_ranges(
    views: int = 4,
    names: Sequence[str] | None = None,
    ranges: Sequence[float] = RANGES,
    seed: int = 0,
) -> dict[str, Any]:
    """Per class: views detected at each range (of those showing the object), and the
    farthest range up to which every view found it (0: not even at the first)."""
    from quadmanip.common import robot_description as rd
    from quadmanip.common.config import load_config
    from quadmanip.common.rotations import quat_from_yaw
    from quadmanip.services.perception.config import PerceptionConfig
    from quadmanip.services.perception.detector import Detector, box_iou
    from quadmanip.sim.scenarios import Placement, Scenario
    from quadmanip.sim.sensors import CameraConfig, RgbdRenderer
    from quadmanip.sim.world.builder import build_world
    from quadmanip.sim.world.house import load_house
    from quadmanip.sim.world.objects import load_catalogue
    from quadmanip.testbench.probe_views import _box, _postures, _stand

    cat, house = load_catalogue(), load_house()
    pcfg = load_config(PerceptionConfig, "perception")
    detector = Detector(pcfg.detector)
    q, pitch = _postures()["stow"]
    cam = rd.FRONT_CAMERA
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for name in names or list(cat.objects):
        spec = cat.objects[name]
        z = spec.size[2] / 2 + 0.002
        # one world per class, the object moved from view to view (a build and a GL
        # context per view cost ten times the detector)
        start = Placement(name, "floor", (START[0] + 2.0, START[1], z), (1.0, 0.0, 0.0, 0.0))
        world = build_world(Scenario("range", seed, (start,), START), house=house, catalogue=cat)
        m = world.model
        data = world.initial_data()
        _stand(world, data, q, pitch)
        cam_p = data.cam_xpos[m.camera(cam).id].copy()
        adr = m.jnt_qposadr[m.joint(f"obj/{name}/free").id]
        geoms = np.flatnonzero(m.geom_bodyid == world.object_body_ids[name])
        renderer = RgbdRenderer(m, {cam: CameraConfig()})
        row: dict[str, list[int]] = {}
        try:
            for r in ranges:
                ahead = math.sqrt(max(r * r - (cam_p[2] - z) ** 2, 0.0))
                hits = shown = 0
                for _ in range(views):
                    lat = float(rng.uniform(-LATERAL, LATERAL))
                    yaw = float(rng.uniform(-math.pi, math.pi))
                    data.qpos[adr : adr + 3] = (cam_p[0] + ahead, cam_p[1] + lat, z)
                    data.qpos[adr + 3 : adr + 7] = quat_from_yaw(yaw)
                    mujoco.mj_forward(m, data)
                    frame = renderer.render(data, cam)
                    mask = np.isin(renderer.render_segmentation(data, cam), geoms)
                    mask &= frame.depth > 0
                    if mask.sum() < 4:  # (not in the image at all)
                        continue
                    shown += 1
                    truth = _box(mask)
                    hits += any(
                        x.label == name
                        and x.score >= pcfg.detector.report_threshold
                        and box_iou(x.box, truth) > 0.3
                        for x in detector(frame.rgb, frame.depth)
                    )
                row[f"{r:.2f}"] = [hits, shown]
        finally:
            renderer.close()
        full = 0.0
        for r in ranges:
            hits, shown = row[f"{r:.2f}"]
            if shown == 0 or hits < shown:
                break
            full = float(r)
        out[name] = {"found_to_m": full, "per_range": row}
        print(f"{name:16s} found in every view to {full:.2f} m  {row}", flush=True)
    return {"camera": cam, "views": views, "ranges": list(ranges), "classes": out}


def main(argv: list[str] | None = None) -> int:
    """Entry point: measure, print the ``[memory.miss_ranges]`` lines, write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=4, help="views per class and range")
    ap.add_argument("--objects", nargs="*", default=None, help="catalogue names (all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="write the result here")
    args = ap.parse_args(argv)
    if args.views < 1:
        ap.error("--views must be >= 1")
    res = detection_ranges(args.views, args.objects, seed=args.seed)
    print("[memory.miss_ranges]")
    for name, row in res["classes"].items():
        # a class never found in every view even at the first range misses nowhere farther
        print(f"{name} = {max(row['found_to_m'], RANGES[0]):.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
