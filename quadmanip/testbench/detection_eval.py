"""Score the detector on a rendered COCO dataset (BENCHMARK ONLY: reads the labels).

``quadmanip perception evaluate --data DIR [--weights F] [--json OUT] [--sheet PNG]``
runs the detector on every frame and scores it with pycocotools (COCO's own evaluation:
AP at IoU 0.5 and averaged over 0.5:0.95, per class; objects labelled ``iscrowd`` are
too little visible to ask for and are ignored). It also times the detector, one thread,
per frame (median), and can draw a contact sheet of detections.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from quadmanip.services.perception.detector import (
    Detection,
    Detector,
    DetectorConfig,
    reported,
)

__all__ = ["EVAL_MAX_DETECTIONS", "EVAL_THRESHOLD", "draw_detections", "evaluate", "main"]

EVAL_THRESHOLD = 0.02  # detections kept for scoring (COCO ranks them all)
EVAL_MAX_DETECTIONS = 100


def _coco_scores(gt_path: Path, results: list[dict[str, Any]]) -> dict[str, Any]:
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    with contextlib.redirect_stdout(io.StringIO()):
        gt = COCO(str(gt_path))
        if not results:
            return {"map50": 0.0, "map50_95": 0.0, "ap50_per_class": {}}
        dt = gt.loadRes(results)
        ev = COCOeval(gt, dt, "bbox")
        ev.params.maxDets = [1, 10, 100]
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    prec = ev.eval["precision"]  # [T, R, K, A, M]: IoU thresholds, recall, class, area, maxdet
    per_class = {}
    for k, cid in enumerate(ev.params.catIds):
        p = prec[0, :, k, 0, -1]
        p = p[p > -1]
        per_class[gt.cats[cid]["name"]] = float(p.mean()) if p.size else float("nan")
    return {
        "map50": float(ev.stats[1]),
        "map50_95": float(ev.stats[0]),
        "ap50_per_class": per_class,
    }


def draw_detections(
    rgb: np.ndarray, dets: list[Detection], truth: list[tuple[str, list[float]]] | None = None
) -> np.ndarray:
    """BGR picture: ground-truth boxes thin white, detections coloured with class and score."""
    img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    for _, (x, y, w, h) in truth or []:
        cv2.rectangle(img, (int(x), int(y)), (int(x + w), int(y + h)), (255, 255, 255), 1)
    for d in dets:
        x0, y0, x1, y1 = (int(round(v)) for v in d.box)
        col = tuple(
            int(c) for c in np.random.default_rng(abs(hash(d.label)) % 2**32).integers(60, 255, 3)
        )
        cv2.rectangle(img, (x0, y0), (x1, y1), col, 1)
        cv2.putText(img, f"{d.label} {d.score:.2f}", (x0, max(8, y0 - 2)), 0, 0.3, col, 1)
    return img


def evaluate(
    data: Path, detector: Detector, limit: int | None = None, sheet: Path | None = None
) -> dict[str, Any]:
    """Detections on every frame of ``data`` -> COCO scores, per-class AP50 and timing."""
    coco = json.loads((data / "annotations.json").read_text())
    images = coco["images"][:limit] if limit else coco["images"]
    names = {c["name"]: c["id"] for c in coco["categories"]}
    results, times, tiles = [], [], []
    truth: dict[int, list[tuple[str, list[float]]]] = {}
    cats = {c["id"]: c["name"] for c in coco["categories"]}
    for a in coco["annotations"]:
        truth.setdefault(a["image_id"], []).append((cats[a["category_id"]], a["bbox"]))
    for n, im in enumerate(images):
        rgb = cv2.cvtColor(cv2.imread(str(data / im["file_name"])), cv2.COLOR_BGR2RGB)
        depth = cv2.imread(str(data / im["depth_file"]), cv2.IMREAD_UNCHANGED).astype(np.float32)
        depth /= 1000.0
        t = time.perf_counter()
        dets = detector(rgb, depth)
        times.append(time.perf_counter() - t)
        for d in dets:
            x0, y0, x1, y1 = d.box
            results.append(
                {
                    "image_id": im["id"],
                    "category_id": names[d.label],
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "score": d.score,
                }
            )
        if sheet is not None and len(tiles) < 24 and truth.get(im["id"]):
            # what the service reports (not the ranked list COCO scores)
            rc = DetectorConfig()
            shown = reported(dets, rc.report_threshold, rc.overlap_iou)
            tiles.append(draw_detections(rgb, shown, truth.get(im["id"])))
        if (n + 1) % 200 == 0:
            print(f"[evaluate] {n + 1}/{len(images)} frames", flush=True)
    gt_path = data / "annotations.json"
    if limit:
        sub = {**coco, "images": images}
        ids = {im["id"] for im in images}
        sub["annotations"] = [a for a in coco["annotations"] if a["image_id"] in ids]
        gt_path = Path(f"/tmp/quadmanip_eval_{time.monotonic_ns()}.json")
        gt_path.write_text(json.dumps(sub))
    scores = _coco_scores(gt_path, results)
    if sheet is not None and tiles:
        while len(tiles) % 4:
            tiles.append(np.zeros_like(tiles[0]))
        rows = [np.hstack(tiles[i : i + 4]) for i in range(0, len(tiles), 4)]
        sheet.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(sheet), np.vstack(rows))
    ap = [v for v in scores["ap50_per_class"].values() if np.isfinite(v)]
    return {
        **scores,
        "ap50_min_class": float(min(ap)) if ap else 0.0,
        "frames": len(images),
        "detector_ms_p50": float(np.median(times) * 1000.0),
        "detector_ms_p95": float(np.percentile(times, 95) * 1000.0),
        "data_seeds": [min(im["seed"] for im in images), max(im["seed"] for im in images)],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip perception evaluate",
        description="Score the detector on a rendered COCO dataset (mAP50, mAP50-95, per class).",
    )
    ap.add_argument("--data", type=Path, required=True, help="dataset folder (COCO)")
    ap.add_argument("--weights", type=Path, default=None, help="weights file (default: config)")
    ap.add_argument("--json", type=Path, default=None, help="write the scores here")
    ap.add_argument("--sheet", type=Path, default=None, help="draw detections on 24 frames")
    ap.add_argument("--limit", type=int, default=None, help="first N frames only")
    args = ap.parse_args(argv)
    # COCO scores the whole ranked list: a run-time score threshold would cut recall
    cfg = DetectorConfig(score_threshold=EVAL_THRESHOLD, max_detections=EVAL_MAX_DETECTIONS)
    if args.weights is not None:
        cfg = replace(cfg, weights=str(args.weights.resolve()))
    det = Detector(cfg)
    out = evaluate(args.data, det, args.limit, args.sheet)
    out["weights"] = str(cfg.weights)
    print(json.dumps({k: v for k, v in out.items() if k != "ap50_per_class"}, indent=1))
    print("AP50 per class: " + ", ".join(f"{k} {v:.3f}" for k, v in out["ap50_per_class"].items()))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
