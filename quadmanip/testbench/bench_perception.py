"""``quadmanip bench perception --json FILE [--seeds ...]``: the perception benchmark.

Parts (``--parts``, all by default):

* ``detect``: renders the scenes of ``--seeds`` (never the training seeds) with the dataset
  tool and scores the committed detector with COCO's evaluation: ``map50``,
  ``map50_95``, AP50 per class and its minimum, ``detector_ms_p50`` (one thread, 320x240).
* ``probe``: every object of ``--objects`` on the floor and on a table, at the probing
  posture, for each of ``--probe-seeds``: detector on the probing camera's frame, then
  its box to a ``GraspGoal`` (timed: ``pipeline_ms_p50``), scored against the harness's
  ground-truth grasp: ``grasp_pos_err_mm_p50/p95``, yaw error, per object.
* ``trials``: perception in the loop over the full stack (sim, locomotion, manipulation,
  perception processes): grasp trials per object x floor/table x ``--trial-seeds``
  (``grasp_success_overall``, ``grasp_success_min_per_object``) and ``drawers`` (the
  three drawers opened with handles located by perception: ``drawers_opened``).

The JSON is rewritten after every item (progress on stdout), so a long run can be
watched and an interrupted one keeps what it measured. Benchmarks may read ground
truth, to score; the services never do.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common import messages as m
from quadmanip.services.perception.config import PerceptionConfig
from quadmanip.services.perception.detector import Detector, weights_path
from quadmanip.services.perception.grasp_pose import estimate_grasp_from_depth
from quadmanip.sim.world.objects import load_catalogue
from quadmanip.testbench.perception_dataset import parse_seeds

__all__ = ["main"]

DEFAULT_SEEDS = "500000:500300"  # evaluation scenes; training uses 0:6000 (model card)


def _pct(v: list[float], q: float) -> float | None:
    return float(np.percentile(v, q)) if v else None


def bench_detect(seeds: list[int], det: Detector, out: dict[str, Any], sheet: Path | None) -> None:
    from quadmanip.testbench.detection_eval import evaluate
    from quadmanip.testbench.perception_dataset import DatasetWriter, SceneRenderer

    with tempfile.TemporaryDirectory(prefix="qm-det-") as tmp:
        scenes = SceneRenderer()
        w = DatasetWriter(Path(tmp), scenes.names)
        try:
            for i, seed in enumerate(seeds):
                for f in scenes.render(seed):
                    if f.labels:
                        w.add(f, seed)
                if (i + 1) % 100 == 0:
                    print(f"[bench perception] rendered {i + 1}/{len(seeds)} scenes", flush=True)
        finally:
            scenes.close()
        w.save()
        out["detect"] = evaluate(Path(tmp), det, sheet=sheet)


def bench_probe(
    objects: list[str], wheres: list[str], seeds: list[int], det: Detector, cfg: PerceptionConfig
) -> dict[str, Any]:
    """Detector + grasp pipeline on rendered probing views, scored against ground truth."""
    from quadmanip.testbench.perception_trials import grasp_error
    from quadmanip.testbench.probe_views import render_probe_view

    cat = load_catalogue()
    rows = []
    for name in objects:
        for where in wheres:
            for seed in seeds:
                v = render_probe_view(name, where, seed, cat)
                found = [d for d in det(v.rgb, v.depth) if d.label == name]
                row: dict[str, Any] = {"object": name, "where": where, "seed": seed}
                if not found:
                    row["reason"] = "not detected"
                    rows.append(row)
                    continue
                d = max(found, key=lambda x: x.score)
                t0 = time.perf_counter()
                est = estimate_grasp_from_depth(
                    v.depth, d.box, v.K, v.cam_position, v.cam_orientation, name, cat,
                    probing=v.probing, where=where, cfg=cfg.grasp,
                )  # fmt: skip
                row["pipeline_ms"] = (time.perf_counter() - t0) * 1000.0
                if not est.ok:
                    row["reason"] = est.reason
                else:
                    goal = m.GraspGoal(
                        stamp=0.0, position=est.position, yaw=est.yaw, width=est.width
                    )
                    pos, yaw = grasp_error(goal, v.gt)
                    row.update(pos_err_mm=pos * 1000.0, yaw_err_deg=yaw, ok=True)
                rows.append(row)
            print(f"[bench perception] probe {name}: {rows[-1]}", flush=True)
    per: dict[str, Any] = {}
    for name in objects:
        r = [x for x in rows if x["object"] == name]
        errs = [x["pos_err_mm"] for x in r if x.get("ok")]
        per[name] = {
            "n": len(r),
            "estimated": len(errs),
            "pos_err_mm_p50": _pct(errs, 50),
            "pos_err_mm_p95": _pct(errs, 95),
            "yaw_err_deg_p50": _pct([x["yaw_err_deg"] for x in r if x.get("ok")], 50),
            "failures": [x.get("reason") for x in r if not x.get("ok")],
        }
    errs = [x["pos_err_mm"] for x in rows if x.get("ok")]
    return {
        "rows": rows,
        "per_object": per,
        "pipeline_ms_p50": _pct([x["pipeline_ms"] for x in rows if "pipeline_ms" in x], 50),
        "grasp_pos_err_mm_p50": _pct(errs, 50),
        "grasp_pos_err_mm_p95": _pct(errs, 95),
        "yaw_err_deg_p50": _pct([x["yaw_err_deg"] for x in rows if x.get("ok")], 50),
        "estimated": len(errs),
        "n": len(rows),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip bench perception", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--json", type=Path, required=True, help="write results here")
    ap.add_argument("--seeds", type=parse_seeds, default=parse_seeds(DEFAULT_SEEDS),
                    help=f"detection scenes (default {DEFAULT_SEEDS})")  # fmt: skip
    ap.add_argument("--parts", default="detect,probe,trials", help="detect,probe,trials")
    ap.add_argument("--objects", default="", help="comma-separated (default: all 18)")
    ap.add_argument("--where", default="floor,table")
    ap.add_argument("--probe-seeds", type=parse_seeds, default=parse_seeds("0:3"))
    ap.add_argument("--trial-seeds", type=parse_seeds, default=parse_seeds("0:3"))
    ap.add_argument("--no-drawers", action="store_true", help="skip the drawer trials")
    ap.add_argument("--sheet", type=Path, default=None, help="detections picture (PNG)")
    ap.add_argument("--log", type=Path, default=None, help="stack logs of the trials")
    args = ap.parse_args(argv)
    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    bad = parts - {"detect", "probe", "trials"}
    if bad:
        ap.error(f"unknown parts: {sorted(bad)}")
    cat = load_catalogue()
    objects = [o.strip() for o in args.objects.split(",") if o.strip()] or list(cat.names)
    unknown = [o for o in objects if o not in cat.objects]
    if unknown:
        ap.error(f"unknown objects: {unknown}")
    wheres = [w.strip() for w in args.where.split(",") if w.strip()]
    if not set(wheres) <= {"floor", "table"}:
        ap.error("--where takes floor and/or table")
    cfg = PerceptionConfig()
    det = Detector(cfg.detector)
    out: dict[str, Any] = {
        "benchmark": "perception",
        "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "weights": str(weights_path(cfg.detector.weights)),
        "model_card": det.meta.get("card", {}),
        "summary": {"train_minutes": det.meta.get("train_minutes")},
    }

    def write() -> None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1, default=float))

    s = out["summary"]
    if "detect" in parts:
        from quadmanip.testbench.detection_eval import EVAL_MAX_DETECTIONS, EVAL_THRESHOLD

        ranked = Detector(replace(cfg.detector, score_threshold=EVAL_THRESHOLD,
                                  max_detections=EVAL_MAX_DETECTIONS))  # fmt: skip
        bench_detect(args.seeds, ranked, out, args.sheet)
        d = out["detect"]
        s.update(map50=d["map50"], map50_95=d["map50_95"], ap50_min_class=d["ap50_min_class"],
                 detector_ms_p50=d["detector_ms_p50"])  # fmt: skip
        write()
    if "probe" in parts:
        out["probe"] = bench_probe(objects, wheres, args.probe_seeds, det, cfg)
        p = out["probe"]
        s.update(pipeline_ms_p50=p["pipeline_ms_p50"],
                 grasp_pos_err_mm_p50=p["grasp_pos_err_mm_p50"],
                 grasp_pos_err_mm_p95=p["grasp_pos_err_mm_p95"])  # fmt: skip
        write()
    if "trials" in parts:
        from quadmanip.testbench.perception_trials import (
            run_perception_drawer_trial,
            run_perception_grasp_trial,
        )

        log = args.log.open("w") if args.log else io.StringIO()
        trials: list[dict[str, Any]] = []
        out["trials"] = trials
        try:
            for name in objects:
                for where in wheres:
                    for seed in args.trial_seeds:
                        r = run_perception_grasp_trial(name, where, seed, log, cat)
                        trials.append(r)
                        print(f"[bench perception] trial {name} {where} {seed}: "
                              f"{'ok' if r['success'] else r.get('reason')} "
                              f"({r['wall_s']:.0f} s)", flush=True)  # fmt: skip
                        ok = [t["success"] for t in trials]
                        per = {
                            o: float(np.mean([t["success"] for t in trials if t["object"] == o]))
                            for o in {t["object"] for t in trials}
                        }
                        s.update(
                            grasp_success_overall=float(np.mean(ok)),
                            grasp_success_min_per_object=min(per.values()),
                            grasp_trials=len(ok),
                        )
                        write()
            if not args.no_drawers:
                drawers = []
                out["drawers"] = drawers
                from quadmanip.sim.world.house import load_house

                for d in load_house().cabinet.drawers:
                    r = run_perception_drawer_trial(d.name, 0, log)
                    drawers.append(r)
                    print(f"[bench perception] drawer {d.name}: "
                          f"{'ok' if r['success'] else r.get('reason')}", flush=True)  # fmt: skip
                    s["drawers_opened"] = sum(bool(x["success"]) for x in drawers)
                    write()
        finally:
            if args.log:
                log.close()
    write()
    print(json.dumps(s, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
