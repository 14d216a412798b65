"""Rejected grasp estimates, kept for study: save their inputs, replay them offline.

With ``[node] save_rejected = "DIR"`` the perception node writes each rejected
``estimate_grasp`` to ``DIR/<stamp>_<label>.npz``: the depth and colour image, the box, K,
the camera pose in the level body frame, the label, floor or table, the probing direction
and the reason. ``quadmanip perception replay FILE.npz [--png OUT]`` runs the grasp
pipeline (:func:`grasp_pose.estimate_grasp_from_depth`) on them again with the current
``configs/perception.toml`` and prints what it decides, so a rejection seen on the robot
can be reproduced, explained and fixed at a desk. Nothing here reads the simulator.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from quadmanip.common.config import load_config
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.services.perception.config import PerceptionConfig
from quadmanip.services.perception.grasp_pose import GraspEstimate, estimate_grasp_from_depth

__all__ = ["main", "replay", "save_rejection"]


def save_rejection(
    folder: Path,
    *,
    stamp: float,
    depth: np.ndarray,
    rgb: np.ndarray,
    box: tuple[float, float, float, float],
    K: np.ndarray,  # noqa: N803
    position: np.ndarray,
    orientation: np.ndarray,
    label: str,
    camera: str,
    where: str,
    probing: str,
    reason: str,
) -> Path:
    """Write one rejected estimate's inputs; returns the file."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stamp:012.3f}_{label}.npz"
    np.savez_compressed(
        path,
        depth=np.asarray(depth, np.float32),
        rgb=np.asarray(rgb, np.uint8),
        box=np.asarray(box, np.float64),
        K=np.asarray(K, np.float64),
        position=np.asarray(position, np.float64),
        orientation=np.asarray(orientation, np.float64),
        meta=json.dumps(
            {
                "stamp": stamp,
                "label": label,
                "camera": camera,
                "where": where,
                "probing": probing,
                "reason": reason,
            }
        ),
    )
    return path


def replay(path: Path, cfg: PerceptionConfig | None = None) -> tuple[dict[str, Any], GraspEstimate]:
    """The saved inputs' metadata and the pipeline's estimate on them now."""
    cfg = cfg or load_config(PerceptionConfig, "perception")
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
        est = estimate_grasp_from_depth(
            f["depth"],
            tuple(float(v) for v in f["box"]),  # type: ignore[arg-type]
            f["K"],
            f["position"],
            f["orientation"],
            meta["label"],
            load_catalogue(),
            probing=meta["probing"],
            where=meta["where"],
            cfg=cfg.grasp,
        )
    return meta, est


def _picture(path: Path, out: Path, est: GraspEstimate) -> None:
    with np.load(path) as f:
        bgr = cv2.cvtColor(f["rgb"], cv2.COLOR_RGB2BGR)
        depth = f["depth"]
        x0, y0, x1, y1 = (int(round(v)) for v in f["box"])
    valid = depth[depth > 0]
    hi = float(np.percentile(valid, 99)) if valid.size else 1.0
    d8 = np.clip(depth / max(hi, 1e-3) * 255.0, 0, 255).astype(np.uint8)
    dcol = cv2.applyColorMap(d8, cv2.COLORMAP_VIRIDIS)
    for img in (bgr, dcol):
        cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), (0, 0, 255), 1)
    text = "ok" if est.ok else est.reason
    cv2.putText(bgr, text[:48], (4, 12), 0, 0.35, (0, 0, 255), 1)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.hstack([bgr, dcol]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip perception replay",
        description="Run the grasp pipeline again on rejected estimates saved by the node "
        "([node] save_rejected) and print what it decides now.",
    )
    ap.add_argument("files", type=Path, nargs="+", help=".npz files written by the node")
    ap.add_argument("--png", type=Path, default=None, help="folder: colour+depth with the box")
    args = ap.parse_args(argv)
    bad = 0
    for path in args.files:
        try:
            meta, est = replay(path)
        except (OSError, KeyError, ValueError) as exc:
            print(f"{path}: cannot replay: {exc}")
            bad += 1
            continue
        now = (
            f"ok {est.approach} at {np.round(est.position, 3).tolist()} yaw "
            f"{math.degrees(est.yaw):.0f} deg width {est.width:.3f}"
            if est.ok
            else f"rejected: {est.reason} {est.detail}".rstrip()
        )
        print(f"{path.name}: {meta['label']} ({meta['where']}, {meta['camera']}) "
              f"was '{meta['reason']}'; now {now}")  # fmt: skip
        if args.png is not None:
            _picture(path, args.png / (path.stem + ".png"), est)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
