"""Pictures of the perception pipeline, one per grasp type (as the paper's Figs. 3, 6, 9):
the probing camera's frame with the detections, and the object's height map with the
chosen grasp (grasp point, finger closing line at the estimated width).

``python -m quadmanip.testbench.perception_figures --out docs/img`` (BENCHMARK/DOCS ONLY:
the scenes are rendered with the simulator; the pipeline sees only the frame).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.services.perception.config import PerceptionConfig
from quadmanip.services.perception.detector import Detector, reported
from quadmanip.services.perception.grasp_pose import estimate_grasp_from_depth
from quadmanip.services.perception.height_map import (
    build_height_map,
    horizontal_axes,
    vertical_axes,
)
from quadmanip.services.perception.outlier_filter import filter_object
from quadmanip.services.perception.point_cloud import lift_box
from quadmanip.testbench.detection_eval import draw_detections
from quadmanip.testbench.probe_views import render_probe_view

__all__ = ["CASES", "main"]

# (object, where, what the picture shows)
CASES: tuple[tuple[str, str, str], ...] = (
    ("toy_gun", "floor", "vertical grasp of a floor object"),
    ("mug", "table", "vertical grasp of a vessel on a table, across its wall, clear of the handle"),
    ("bowl", "floor", "wall pinch of a flared bowl (tilted tool)"),
    ("cracker_box", "table", "horizontal grasp from the front camera"),
)
SCALE = 3  # picture pixels per frame pixel / per height-map cell (at least)


def _height_picture(points: np.ndarray, probing: str, est: object, size: int) -> np.ndarray:
    up = np.array([0.0, 0.0, 1.0])
    axes = vertical_axes(up, 0.0) if probing == "vertical" else horizontal_axes(up)
    hm = build_height_map(points, axes, None, cell=0.004)
    h = hm.heights.copy()
    occ = hm.occupied
    top = float(h[occ].max()) if occ.any() else 1.0
    norm = np.where(occ, 40 + 215 * np.clip(h / max(top, 1e-6), 0, 1), 0).astype(np.uint8)
    img = cv2.applyColorMap(norm, cv2.COLORMAP_VIRIDIS)
    img[~occ] = 30
    nu, nv = h.shape
    # drawn as the camera sees it: vertical (u = x ahead, v = y left) with ahead up and
    # left on the left; horizontal (u = y left, v = up) with up up and left on the left
    if probing == "vertical":
        img = img[::-1, ::-1]

        def pix(i: float, j: float) -> tuple[float, float]:
            return nv - 1 - j, nu - 1 - i  # (x, y) picture coordinates
    else:
        img = np.ascontiguousarray(img.transpose(1, 0, 2)[::-1, ::-1])

        def pix(i: float, j: float) -> tuple[float, float]:
            return nu - 1 - i, nv - 1 - j

    k = max(1, size // max(img.shape[:2]))
    img = cv2.resize(img, (img.shape[1] * k, img.shape[0] * k), interpolation=cv2.INTER_NEAREST)
    if getattr(est, "ok", False):
        p = np.asarray(est.position)  # type: ignore[attr-defined]
        yaw = float(est.yaw)  # type: ignore[attr-defined]
        close = np.array([-math.sin(yaw), math.cos(yaw), 0.0])  # yaw 0: fingers along base y
        if probing == "horizontal":
            close = np.array([0.0, 1.0, 0.0])
        half = 0.5 * float(est.width)  # type: ignore[attr-defined]
        c = hm.map_coords(np.array([p - half * close, p, p + half * close]))
        ends = []
        for cc in c:
            x, y = pix((cc[0] - hm.u0) / hm.cell - 0.5, (cc[1] - hm.v0) / hm.cell - 0.5)
            ends.append((int(round((x + 0.5) * k)), int(round((y + 0.5) * k))))
        cv2.line(img, ends[0], ends[2], (0, 0, 255), 2)
        cv2.circle(img, ends[1], 5, (255, 255, 255), 2)
    return img


def figure(name: str, where: str, det: Detector, cfg: PerceptionConfig) -> np.ndarray:
    """The frame with detections | the height map with the grasp, side by side."""
    cat = load_catalogue()
    v = render_probe_view(name, where, 0, cat)
    dets = det(v.rgb, v.depth)
    mine = [d for d in dets if d.label == name]
    shown = reported(dets, cfg.detector.report_threshold, cfg.detector.overlap_iou)
    left = cv2.resize(draw_detections(v.rgb, shown), None, fx=SCALE, fy=SCALE,
                      interpolation=cv2.INTER_NEAREST)  # fmt: skip
    right = np.full_like(left, 30)
    text = "not detected"
    if mine:
        d = max(mine, key=lambda x: x.score)
        est = estimate_grasp_from_depth(
            v.depth, d.box, v.K, v.cam_position, v.cam_orientation, name, cat,
            probing=v.probing, where=where, cfg=cfg.grasp,
        )  # fmt: skip
        cloud = lift_box(v.depth, d.box, v.K, v.cam_position, v.cam_orientation)
        obj = filter_object(cloud.points, cloud.camera_position, cfg.grasp.filter).object_points
        if obj.shape[0]:
            hp = _height_picture(obj, v.probing, est, left.shape[0])
            hh, ww = min(hp.shape[0], right.shape[0]), min(hp.shape[1], right.shape[1])
            right[:hh, :ww] = hp[:hh, :ww]
        text = (
            f"{est.approach} grasp, width {1000 * est.width:.0f} mm, tilt {est.tilt:.2f} rad"
            if est.ok
            else f"rejected: {est.reason}"
        )
    out = np.hstack([left, right])
    cv2.putText(out, f"{name} on the {where}: {text}", (8, 24), cv2.FONT_HERSHEY_SIMPLEX,
                0.7, (255, 255, 255), 2)  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("docs/img"))
    args = ap.parse_args(argv)
    cfg = PerceptionConfig()
    det = Detector(cfg.detector)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, where, _ in CASES:
        path = args.out / f"perception_{name}_{where}.png"
        cv2.imwrite(str(path), figure(name, where, det, cfg))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
