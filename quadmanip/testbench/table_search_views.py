"""What the table search sees: detector recall on rendered table-search views (tooling).

Every catalogue object is put at random spots on the living and the kitchen table (random
yaw, at least 3 cm inside the edge); the robot stands on the table's stand line, stepped
sideways to at most 0.2 m from the object (as the search's viewpoints, 0.4 m apart, put
it), in the ``table_search`` posture of ``configs/manipulation.toml``. For each view it
reports whether the object is in the gripper camera's image, whether the detector (the
service's weights and thresholds) reports it (its class, score >= report threshold, box
IoU > 0.3 with the object's true box), and the camera's look-down angle: perception's
object memory takes gripper camera frames only from ``gripper_min_look_down`` down. It
reads the house and the objects' true poses, as a benchmark may; no service uses it.

    python -m quadmanip.testbench.table_search_views --spots 8 --seed 0
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np

__all__ = ["main", "table_search_recall"]

TABLES = ("living_table", "kitchen_table")


def table_search_recall(spots: int, seed: int = 0) -> dict[str, Any]:
    """Per object: views in which it was in the image / detected; and the look-down."""
    from quadmanip.common import robot_description as rd
    from quadmanip.common.config import CONFIG_DIR, load_config
    from quadmanip.common.places import load_places
    from quadmanip.common.rotations import quat_from_yaw
    from quadmanip.services.perception.config import PerceptionConfig
    from quadmanip.services.perception.detector import Detector, box_iou
    from quadmanip.sim.scenarios import Placement, Scenario
    from quadmanip.sim.world.builder import build_world
    from quadmanip.sim.world.house import load_house
    from quadmanip.sim.world.objects import load_catalogue
    from quadmanip.testbench.probe_views import _box, _postures, _stand, render_object

    cat, house = load_catalogue(), load_house()
    places = load_places(CONFIG_DIR / "maps" / "house.places.toml")
    pcfg = load_config(PerceptionConfig, "perception")
    detector = Detector(pcfg.detector)
    q, pitch = _postures()["table_search"]
    rng = np.random.default_rng(seed)
    cam = rd.GRIPPER_CAMERA
    per: dict[str, dict[str, int]] = {}
    look_down = None
    for name, spec in cat.objects.items():
        row = per.setdefault(name, {"views": 0, "in_image": 0, "detected": 0})
        for k in range(spots):
            t = places[TABLES[k % len(TABLES)]]
            h = t.stand[2]
            inward = np.array([math.cos(h), math.sin(h)])
            along = np.array([-inward[1], inward[0]])
            edge = np.array(t.target[:2]) - inward * t.size[1] / 2
            r = 0.5 * math.hypot(spec.size[0], spec.size[1])
            into = rng.uniform(r + 0.03, t.size[1] - r - 0.03)
            side = rng.uniform(-t.size[0] / 2 + r + 0.03, t.size[0] / 2 - r - 0.03)
            p = edge + into * inward + side * along
            off = float(np.clip(side + rng.uniform(-0.2, 0.2), -t.size[0] / 2, t.size[0] / 2))
            stand = np.array(t.stand[:2]) + off * along
            yaw = float(rng.uniform(-math.pi, math.pi))
            z = t.target[2] + spec.size[2] / 2 + 0.002
            obj = Placement(
                name, t.name, (float(p[0]), float(p[1]), z), tuple(quat_from_yaw(yaw).tolist())
            )
            scn = Scenario(
                f"table-search-{k}",
                seed,
                (obj,),
                (float(stand[0]), float(stand[1]), math.degrees(h)),
            )
            world = build_world(scn, house=house, catalogue=cat)
            data = world.initial_data()
            _stand(world, data, q, pitch)
            if look_down is None:
                axis = -data.cam_xmat[world.model.camera(cam).id].reshape(3, 3)[:, 2]
                look_down = math.degrees(math.asin(-axis[2]))
            frame, mask = render_object(world, data, cam, name)
            row["views"] += 1
            if mask.sum() < 20:
                continue
            row["in_image"] += 1
            truth = _box(mask)
            row["detected"] += any(
                d.label == name
                and d.score >= pcfg.detector.report_threshold
                and box_iou(d.box, truth) > 0.3
                for d in detector(frame.rgb, frame.depth)
            )
        print(f"{name:16s} {row}", flush=True)
    views = sum(r["views"] for r in per.values())
    return {
        "look_down_deg": look_down,
        "memory_min_look_down_deg": math.degrees(pcfg.node.gripper_min_look_down),
        "views": views,
        "in_image": sum(r["in_image"] for r in per.values()),
        "detected": sum(r["detected"] for r in per.values()),
        "per_object": per,
    }


def main(argv: list[str] | None = None) -> int:
    """Command line: ``--spots`` per object, ``--seed``, ``--json`` for the report."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spots", type=int, default=8, help="spots per object (both tables)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="", help="write the report here")
    args = ap.parse_args(argv)
    out = table_search_recall(args.spots, args.seed)
    print(json.dumps({k: v for k, v in out.items() if k != "per_object"}, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
