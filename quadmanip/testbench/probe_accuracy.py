"""Accuracy of perception's grasp-pose pipeline on rendered probing views (BENCH ONLY).

For every catalogue object, on the floor and on a table, for each seed: render the probing
view (:mod:`quadmanip.testbench.probe_views`), cut the object's box from the ground-truth
mask (a perfect detector), run :func:`quadmanip.services.perception.grasp_pose.estimate_grasp_from_depth`
and compare with the harness's ground-truth grasp
(:func:`quadmanip.testbench.manipulation_scenes.grasp_from_poses`).

Reported per object and place: position error p50 / p95 (mm, 3-D), yaw error (deg, modulo
the object's symmetry: none for round bodies, 90 deg for a square footprint, else 180),
width and hang errors (mm), approach agreement, rejections and the pipeline's median time
(ms, one thread). Usage::

    python -m quadmanip.testbench.probe_accuracy 0 1 2 --out bench-results/probe_accuracy.json
    python -m quadmanip.testbench.probe_accuracy 0 --config perception  # the service's config
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["main", "score_view", "yaw_period"]


def yaw_period(spec: Any) -> float | None:
    """Symmetry period (rad) of an object's grasp yaw: None for a round body (any yaw),
    pi/2 for a square footprint, pi otherwise (the gripper is symmetric)."""
    if spec.shape in ("sphere", "cylinder"):
        return None
    if spec.shape == "vessel" and spec.vessel is not None and not spec.vessel.handle:
        lean = math.atan2(0.5 * (spec.size[1] - spec.vessel.bottom_diameter), spec.size[2])
        return None if lean <= 0.35 else math.pi  # a flared bowl is pinched at one wall
    if spec.shape == "box" and abs(spec.size[0] - spec.size[1]) < 0.002:
        return math.pi / 2
    return math.pi


def _yaw_error(a: float, b: float, period: float | None) -> float | None:
    if period is None:
        return None
    return abs((a - b + period / 2) % period - period / 2)


def score_view(view: Any, catalogue: Any, cfg: Any = None) -> dict[str, Any]:
    """Run the pipeline on one probing view and score it against the view's ground truth."""
    from quadmanip.services.perception.grasp_pose import estimate_grasp_from_depth

    out: dict[str, Any] = {"object": view.name, "where": view.where, "seed": view.seed}
    if view.box is None:
        out.update(ok=False, reason="not visible", ms=None)
        return out
    t0 = time.perf_counter()
    est = estimate_grasp_from_depth(
        view.depth,
        view.box,
        view.K,
        view.cam_position,
        view.cam_orientation,
        view.name,
        catalogue,
        view.probing,
        view.where,
        cfg,
    )
    out["ms"] = (time.perf_counter() - t0) * 1000.0
    out.update(ok=est.ok, reason=est.reason, probe=est.probe)
    if not est.ok:
        return out
    gt = view.gt
    spec = catalogue.objects[view.name]
    period = yaw_period(spec) if gt.approach == "vertical" else math.pi
    yaw = _yaw_error(est.yaw, gt.yaw, period)
    out.update(
        pos_mm=float(np.linalg.norm(est.position - gt.position_base) * 1000.0),
        dpos_mm=[float(v) for v in (est.position - gt.position_base) * 1000.0],
        yaw_deg=None if yaw is None else math.degrees(yaw),
        width_mm=(est.width - gt.width) * 1000.0,
        hang_mm=(est.hang - gt.hang) * 1000.0,
        tilt_deg=math.degrees(est.tilt - gt.tilt),
        approach_ok=est.approach == gt.approach,
    )
    return out


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if r.get("ok")]
    pos = [r["pos_mm"] for r in ok]
    yaw = [r["yaw_deg"] for r in ok if r.get("yaw_deg") is not None]
    ms = [r["ms"] for r in rows if r.get("ms") is not None]

    def pct(v: list[float], q: float) -> float | None:
        return float(np.percentile(v, q)) if v else None

    return {
        "n": len(rows),
        "rejected": len(rows) - len(ok),
        "reasons": sorted({r["reason"] for r in rows if not r.get("ok")}),
        "pos_p50_mm": pct(pos, 50),
        "pos_p95_mm": pct(pos, 95),
        "yaw_p50_deg": pct(yaw, 50),
        "yaw_max_deg": max(yaw) if yaw else None,
        "width_max_abs_mm": max((abs(r["width_mm"]) for r in ok), default=None),
        "hang_max_abs_mm": max((abs(r["hang_mm"]) for r in ok), default=None),
        "approach_ok": all(r["approach_ok"] for r in ok),
        "ms_p50": pct(ms, 50),
    }


def _fmt(v: float | None, nd: int = 1) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the sweep; print a table and write JSON (``--out``)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seeds", nargs="*", type=int, default=[0])
    ap.add_argument("--objects", nargs="*", default=None, help="catalogue names (default all)")
    ap.add_argument("--where", nargs="*", default=["floor", "table"])
    ap.add_argument("--out", type=Path, default=None, help="JSON file to write")
    ap.add_argument(
        "--config",
        default=None,
        help="a config (name under configs/ or path) whose [grasp] table to use (default: "
        "GraspConfig's defaults)",
    )
    args = ap.parse_args(list(argv) if argv is not None else None)

    from quadmanip.sim.world.objects import load_catalogue
    from quadmanip.testbench.probe_views import render_probe_view

    cat = load_catalogue()
    cfg = None
    if args.config is not None:
        from quadmanip.common.config import from_dict, load_toml
        from quadmanip.services.perception.grasp_pose import GraspConfig

        cfg = from_dict(GraspConfig, load_toml(args.config).get("grasp", {}), source=args.config)
    names = args.objects or list(cat.names)
    rows: list[dict[str, Any]] = []
    table: dict[str, dict[str, Any]] = {}
    for name in names:
        for where in args.where:
            mine = []
            for seed in args.seeds:
                view = render_probe_view(name, where, seed, catalogue=cat)
                mine.append(score_view(view, cat, cfg))
            rows += mine
            table[f"{name}/{where}"] = _summary(mine)
    overall = _summary(rows)
    print(
        f"{'object/where':28s} {'n':>2s} {'rej':>3s} {'pos50':>6s} {'pos95':>6s} "
        f"{'yaw50':>6s} {'yawmax':>6s} {'|dw|':>5s} {'|dh|':>5s} {'appr':>4s} {'ms':>5s}"
    )
    for key, s in [*table.items(), ("ALL", overall)]:
        print(
            f"{key:28s} {s['n']:2d} {s['rejected']:3d} {_fmt(s['pos_p50_mm']):>6s} "
            f"{_fmt(s['pos_p95_mm']):>6s} {_fmt(s['yaw_p50_deg']):>6s} "
            f"{_fmt(s['yaw_max_deg']):>6s} {_fmt(s['width_max_abs_mm']):>5s} "
            f"{_fmt(s['hang_max_abs_mm']):>5s} {'ok' if s['approach_ok'] else 'NO':>4s} "
            f"{_fmt(s['ms_p50']):>5s}" + (f"  {', '.join(s['reasons'])}" if s["reasons"] else "")
        )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps(
                {"seeds": args.seeds, "summary": table, "all": overall, "views": rows}, indent=1
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
