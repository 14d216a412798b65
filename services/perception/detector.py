"""The object detector (the paper's YOLOv7 role, Section 4.1): a small CenterNet.

Why not YOLOv7: it is trained from ImageNet weights on a GPU, and no weights can be
downloaded here; this detector must train from scratch on two CPU cores in about two hours
and run at 10 Hz on one core. A CenterNet (Zhou et al. 2019, "Objects as Points") fits:
one class heat map, a box size and a sub-cell offset per output cell, no anchors and no
NMS (a 3x3 max-pool keeps the peaks). It sees colour *and* depth (4 channels): depth
separates an object from the floor or table it lies on whatever their colours.

Architecture (``DetectorConfig``): a plain ResNet-like backbone (3x3 convolutions,
batch norm, ReLU; strides 2, 4, 8, 16) and a two-level feature pyramid back to stride 4,
so at 320x240 the heads see an 80x60 grid: a marker 2 m away (about 14x4 px) still has
its own cell. Sizes are regressed as log(w/stride), log(h/stride).

The module holds the network, the input encoding and the decoding; training is in
``train.py``. Nothing here reads the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

__all__ = [
    "CenterNet",
    "Detection",
    "Detector",
    "DetectorConfig",
    "NetworkShape",
    "box_iou",
    "rank_runner_ups",
    "reported",
    "decode",
    "encode_input",
]

DEPTH_SCALE = 3.0  # m: depth / DEPTH_SCALE is the network's 4th channel (0 = no return)
RGB_MEAN = np.array([0.5, 0.5, 0.5], np.float32)
RGB_STD = np.array([0.25, 0.25, 0.25], np.float32)


@dataclass(frozen=True)
class NetworkShape:
    """The network's widths (training chooses them; the weights file records them)."""

    widths: tuple[int, int, int, int] = (16, 32, 64, 128)  # strides 2, 4, 8, 16
    neck: int = 32  # channels of the stride-8 and stride-4 pyramid levels
    head: int = 32


@dataclass(frozen=True)
class DetectorConfig:
    """Which weights to run and how to decode (``[detector]`` of configs/perception.toml)."""

    weights: str = "models/detector.pt"  # relative to the perception package, or absolute
    # Decoding keeps peaks down to this score: a grasp request that names a class may take
    # that class's box at a low score (the task knows what it looks for); what perception
    # reports and remembers on its own needs ``report_threshold``.
    score_threshold: float = 0.1
    report_threshold: float = 0.3
    # One object, one report: a box overlapping a better-scored one of another class by
    # more than this IoU is that object's runner-up class, not a second object.
    overlap_iou: float = 0.6
    # The same object's second guess (a box overlapping a better-scored box of another
    # class by more than ``overlap_iou``) is scored x this, so that it ranks below the
    # first guesses of its class: the CenterNet heads score each class alone, and the
    # spoon/marker and clamp/toy-gun pairs often peak on the same object.
    runner_up_scale: float = 0.7
    max_detections: int = 30
    threads: int = 1  # torch intra-op threads at run time (the node's budget is one core)
    classes: tuple[str, ...] = field(default_factory=tuple)  # empty: from the weights file


@dataclass(frozen=True)
class Detection:
    """One detected object: class, score and box (pixels, x0, y0, x1, y1)."""

    label: str
    score: float
    box: tuple[float, float, float, float]


def _cbr(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


class _Residual(nn.Module):
    def __init__(self, c: int) -> None:
        super().__init__()
        self.a = _cbr(c, c)
        self.b = nn.Sequential(nn.Conv2d(c, c, 3, 1, 1, bias=False), nn.BatchNorm2d(c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.b(self.a(x)), inplace=True)


class CenterNet(nn.Module):
    """Backbone + pyramid + heads. ``forward`` returns (heat logits [B,C,H/4,W/4],
    log-size [B,2,...], offset [B,2,...])."""

    def __init__(self, n_classes: int, cfg: NetworkShape | None = None) -> None:
        super().__init__()
        cfg = cfg or NetworkShape()
        w1, w2, w3, w4 = cfg.widths
        self.n_classes = n_classes
        self.stem = _cbr(4, w1, 2)  # /2
        self.s4 = nn.Sequential(_cbr(w1, w2, 2), _Residual(w2))  # /4
        self.s8 = nn.Sequential(_cbr(w2, w3, 2), _Residual(w3))  # /8
        self.s16 = nn.Sequential(_cbr(w3, w4, 2), _Residual(w4), _Residual(w4))  # /16
        n = cfg.neck
        self.lat16 = nn.Conv2d(w4, n, 1)
        self.lat8 = nn.Conv2d(w3, n, 1)
        self.lat4 = nn.Conv2d(w2, n, 1)
        self.fuse8 = _cbr(n, n)
        self.fuse4 = _cbr(n, n)
        h = cfg.head
        self.head = _cbr(n, h)
        self.heat = nn.Conv2d(h, n_classes, 1)
        self.size = nn.Conv2d(h, 2, 1)
        self.offset = nn.Conv2d(h, 2, 1)
        nn.init.constant_(self.heat.bias, -math.log((1 - 0.01) / 0.01))  # prior 1 %

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        f4 = self.s4(self.stem(x))
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        p8 = self.fuse8(self.lat8(f8) + F.interpolate(self.lat16(f16), size=f8.shape[-2:]))
        p4 = self.fuse4(self.lat4(f4) + F.interpolate(p8, size=f4.shape[-2:]))
        h = self.head(p4)
        return self.heat(h), self.size(h), self.offset(h)


STRIDE = 4


def encode_input(rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """uint8 RGB [H,W,3] + depth (m) [H,W] -> float32 [4,H,W] network input."""
    x = np.empty((4, *depth.shape), np.float32)
    x[:3] = ((rgb.astype(np.float32) / 255.0 - RGB_MEAN) / RGB_STD).transpose(2, 0, 1)
    x[3] = np.clip(depth, 0.0, 2.0 * DEPTH_SCALE) / DEPTH_SCALE
    return x


def decode(
    heat: torch.Tensor,
    size: torch.Tensor,
    offset: torch.Tensor,
    k: int = 30,
    threshold: float = 0.3,
) -> list[list[tuple[int, float, tuple[float, float, float, float]]]]:
    """Peaks of the heat map (3x3 max-pool) -> per image [(class, score, box px)]."""
    prob = torch.sigmoid(heat)
    peaks = prob * (F.max_pool2d(prob, 3, 1, 1) == prob)
    b, c, h, w = prob.shape
    scores, idx = peaks.view(b, -1).topk(min(k, c * h * w))
    out = []
    for i in range(b):
        keep = scores[i] >= threshold
        sc, ix = scores[i][keep], idx[i][keep]
        cls = ix // (h * w)
        cell = ix % (h * w)
        ys, xs = cell // w, cell % w
        off = offset[i, :, ys, xs]
        sz = torch.exp(size[i, :, ys, xs].clamp(max=6.0)) * STRIDE
        cx = (xs.float() + off[0]) * STRIDE
        cy = (ys.float() + off[1]) * STRIDE
        boxes = torch.stack([cx - sz[0] / 2, cy - sz[1] / 2, cx + sz[0] / 2, cy + sz[1] / 2], 1)
        out.append(
            [
                (int(cl), float(s), tuple(float(v) for v in bx))
                for cl, s, bx in zip(cls.tolist(), sc.tolist(), boxes.tolist(), strict=True)
            ]
        )
    return out


PACKAGE_DIR = Path(__file__).resolve().parent


def weights_path(weights: str) -> Path:
    """A configured weights path: absolute, or relative to this package's folder."""
    p = Path(weights).expanduser()
    return p if p.is_absolute() else PACKAGE_DIR / p


def box_iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Intersection over union of two boxes (x0, y0, x1, y1)."""
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def reported(dets: list[Detection], threshold: float, overlap_iou: float) -> list[Detection]:
    """What perception reports on its own: scores >= ``threshold``, and of boxes that
    overlap by more than ``overlap_iou`` only the best-scored (class-agnostic NMS)."""
    keep: list[Detection] = []
    for d in sorted(dets, key=lambda x: -x.score):
        if d.score < threshold:
            break
        if all(box_iou(d.box, k.box) <= overlap_iou for k in keep):
            keep.append(d)
    return keep


def rank_runner_ups(dets: list[Detection], overlap_iou: float, scale: float) -> list[Detection]:
    """Scores of second guesses x ``scale``: a box overlapping a better-scored box of
    another class by more than ``overlap_iou`` (the same object, read as another class).
    Unlike ``reported`` nothing is dropped, so a request for a class still finds its box."""
    ranked = sorted(dets, key=lambda x: -x.score)
    if len(ranked) < 2:
        return ranked
    # every pair at once (this runs on every frame): IoU of box i with each better box j
    b = np.array([d.box for d in ranked], dtype=float)
    ix = np.clip(
        np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0]), 0, None
    )
    iy = np.clip(
        np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1]), 0, None
    )
    inter = ix * iy
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area[:, None] + area[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    labels = np.array([d.label for d in ranked])
    better = np.tri(len(ranked), k=-1, dtype=bool)  # j ranked before i
    second = ((iou > overlap_iou) & (labels[:, None] != labels[None, :]) & better).any(axis=1)
    out = [
        Detection(d.label, d.score * scale, d.box) if s else d
        for d, s in zip(ranked, second, strict=True)
    ]
    return sorted(out, key=lambda x: -x.score)


def load_checkpoint(path: Path) -> dict[str, Any]:
    """A weights file: ``{"model": state_dict, "classes": [...], "config": {...}, ...}``."""
    return torch.load(path, map_location="cpu", weights_only=False)


class Detector:
    """Run-time detector: weights file -> detections per RGB-D frame (no gradients)."""

    def __init__(self, cfg: DetectorConfig) -> None:
        path = weights_path(cfg.weights)
        if not path.exists():
            raise FileNotFoundError(f"detector weights not found: {path}")
        ck = load_checkpoint(path)
        net_cfg = NetworkShape(**{k: tuple(v) if isinstance(v, list) else v
                                   for k, v in ck.get("config", {}).items()})  # fmt: skip
        self.classes: tuple[str, ...] = tuple(ck["classes"])
        if cfg.classes and tuple(cfg.classes) != self.classes:
            raise ValueError(f"weights are for classes {self.classes}, config asks {cfg.classes}")
        self.cfg = cfg
        self.net = CenterNet(len(self.classes), net_cfg)
        self.net.load_state_dict(ck["model"])
        self.net.eval()
        self.meta = {k: v for k, v in ck.items() if k not in ("model", "optimizer")}

    def __call__(self, rgb: np.ndarray, depth: np.ndarray) -> list[Detection]:
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[:2] != depth.shape:
            raise ValueError(f"need rgb [H,W,3] and depth [H,W], got {rgb.shape}, {depth.shape}")
        h, w = depth.shape
        # the network's strides need multiples of 16: pad, never resize
        ph, pw = (-h) % 16, (-w) % 16
        x = encode_input(rgb, depth)
        if ph or pw:
            x = np.pad(x, ((0, 0), (0, ph), (0, pw)))
        torch.set_num_threads(self.cfg.threads)
        with torch.inference_mode():
            heat, size, off = self.net(torch.from_numpy(x)[None])
            dets = decode(heat, size, off, self.cfg.max_detections, self.cfg.score_threshold)[0]
        out = []
        for cl, s, (x0, y0, x1, y1) in dets:
            box = (max(0.0, x0), max(0.0, y0), min(float(w), x1), min(float(h), y1))
            if box[2] > box[0] and box[3] > box[1]:
                out.append(Detection(self.classes[cl], s, box))
        if self.cfg.runner_up_scale < 1.0:
            out = rank_runner_ups(out, self.cfg.overlap_iou, self.cfg.runner_up_scale)
        return out
