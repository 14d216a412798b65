"""Train the detector from scratch: ``quadmanip perception train --data DIR [...]``.

Reads COCO datasets written by ``quadmanip perception dataset`` (colour, depth and boxes),
trains the CenterNet of :mod:`detector` on random crops with colour, noise, scale and
flip augmentation, and checkpoints every ``--save-every`` iterations (model, optimiser,
iteration, accumulated training minutes, the data's seeds): an interrupted run resumes
from its checkpoint with ``--resume``, so a schedule longer than one sitting is run in
parts. The weights file written at the end (``--out``) holds the model, its classes, its
shape and a model card's numbers.

On a machine with a GPU, ``--device cuda --workers N`` moves the network there and makes
the augmented batches in N processes (the augmentation, not the network, is then the
bottleneck); ``--budget-minutes M`` sets the cosine schedule's length from the measured
rate so that the run ends, at the schedule's low learning rate, within M minutes.

Losses (CenterNet): penalty-reduced focal loss on the class heat maps (alpha 2, beta 4;
objects labelled too little visible are ignored, not negatives), L1 on the log box size
and on the sub-cell offset at each object's centre cell, and a GIoU loss on the decoded
box there (it rewards tight boxes, which mAP50-95 asks for).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from quadmanip.services.perception.detector import (
    PACKAGE_DIR,
    STRIDE,
    CenterNet,
    NetworkShape,
    encode_input,
)

__all__ = ["CocoFrames", "make_targets", "main", "repeat_weights", "train"]

CROP = (192, 256)  # h, w of training crops (the network is fully convolutional)


class CocoFrames:
    """A COCO dataset of RGB-D frames held in memory (decoded once)."""

    def __init__(self, roots: list[Path]) -> None:
        # The frames go straight into arrays allocated once for all datasets: a list of
        # frames stacked at the end needed twice the memory (four 10k-frame sets: 26 GB).
        sets, classes = [], None
        for root in roots:
            coco = json.loads((root / "annotations.json").read_text())
            names = [c["name"] for c in sorted(coco["categories"], key=lambda c: c["id"])]
            if classes is None:
                classes = names
            elif names != classes:
                raise ValueError(f"{root}: categories differ from the first dataset's")
            sets.append((root, coco))
        total = sum(len(coco["images"]) for _, coco in sets)
        if not total:
            raise ValueError(f"no frames in {', '.join(map(str, roots))}")
        first = next(im for _, coco in sets for im in coco["images"])
        hw = (int(first["height"]), int(first["width"]))
        # the dataset's format: RGB uint8, depth uint16 millimetres (perception_dataset)
        self.rgb = np.empty((total, *hw, 3), np.uint8)
        self.depth = np.empty((total, *hw), np.uint16)
        self.anns: list[np.ndarray] = []
        self.seeds: list[int] = []
        for root, coco in sets:
            per: dict[int, list[list[float]]] = {im["id"]: [] for im in coco["images"]}
            for a in coco["annotations"]:
                x, y, w, h = a["bbox"]
                per[a["image_id"]].append([a["category_id"] - 1, x, y, x + w, y + h, a["iscrowd"]])

            def read(im: dict[str, Any], root: Path = root) -> tuple[np.ndarray, np.ndarray]:
                bgr = cv2.imread(str(root / im["file_name"]), cv2.IMREAD_COLOR)
                d = cv2.imread(str(root / im["depth_file"]), cv2.IMREAD_UNCHANGED)
                if bgr is None or d is None:
                    raise OSError(f"{root}: cannot read frame {im['file_name']}")
                return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), d

            # OpenCV's decoders release the GIL: threads read the PNGs in parallel.
            with ThreadPoolExecutor(max_workers=8) as pool:
                for im, (c, d) in zip(coco["images"], pool.map(read, coco["images"]), strict=True):
                    i = len(self.anns)
                    if c.shape != self.rgb.shape[1:] or d.shape != hw or d.dtype != np.uint16:
                        raise ValueError(
                            f"{root}: frame {im['file_name']} is not {hw} with uint16 depth"
                        )
                    self.rgb[i] = c
                    self.depth[i] = d
                    self.anns.append(np.array(per[im["id"]], np.float32).reshape(-1, 6))
                    self.seeds.append(int(im.get("seed", -1)))
        self.classes: tuple[str, ...] = tuple(classes or ())

    def __len__(self) -> int:
        return len(self.anns)


def _gaussian_radius(h: float, w: float, min_overlap: float = 0.7) -> float:
    """CenterNet's radius: the largest centre shift keeping IoU >= min_overlap (cells)."""
    a1, b1 = 1.0, h + w
    c1 = w * h * (1 - min_overlap) / (1 + min_overlap)
    r1 = (b1 + math.sqrt(b1**2 - 4 * a1 * c1)) / 2
    a2, b2, c2 = 4.0, 2 * (h + w), (1 - min_overlap) * w * h
    r2 = (b2 + math.sqrt(b2**2 - 4 * a2 * c2)) / 2
    a3, b3, c3 = 4 * min_overlap, -2 * min_overlap * (h + w), (min_overlap - 1) * w * h
    r3 = (b3 + math.sqrt(b3**2 - 4 * a3 * c3)) / 2
    return max(0.0, min(r1, r2, r3))


def make_targets(
    boxes: np.ndarray, n_classes: int, hw: tuple[int, int], max_objs: int = 32
) -> dict[str, np.ndarray]:
    """Boxes [N,6] (class, x0, y0, x1, y1, ignore) in input pixels -> CenterNet targets on
    the stride-4 grid: heat [C,h,w], ignore [h,w], and per object (up to ``max_objs``)
    centre index, log size, offset, box and a validity mask."""
    h, w = hw[0] // STRIDE, hw[1] // STRIDE
    heat = np.zeros((n_classes, h, w), np.float32)
    ignore = np.zeros((h, w), np.float32)
    ind = np.zeros(max_objs, np.int64)
    size = np.zeros((max_objs, 2), np.float32)
    off = np.zeros((max_objs, 2), np.float32)
    box = np.zeros((max_objs, 4), np.float32)
    mask = np.zeros(max_objs, np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    k = 0
    for c, x0, y0, x1, y1, ign in boxes:
        bw, bh = (x1 - x0) / STRIDE, (y1 - y0) / STRIDE
        if bw <= 0 or bh <= 0:
            continue
        if ign:
            ignore[
                max(0, int(y0 // STRIDE)) : int(math.ceil(y1 / STRIDE)),
                max(0, int(x0 // STRIDE)) : int(math.ceil(x1 / STRIDE)),
            ] = 1.0
            continue
        cx, cy = (x0 + x1) / 2 / STRIDE, (y0 + y1) / 2 / STRIDE
        ix, iy = min(w - 1, max(0, int(cx))), min(h - 1, max(0, int(cy)))
        r = max(0.0, _gaussian_radius(bh, bw))
        sigma = (2 * int(r) + 1) / 6
        g = np.exp(-((xx - ix) ** 2 + (yy - iy) ** 2) / (2 * sigma**2))
        np.maximum(heat[int(c)], g, out=heat[int(c)])
        if k < max_objs:
            ind[k] = iy * w + ix
            size[k] = (math.log(bw), math.log(bh))
            off[k] = (cx - ix, cy - iy)
            box[k] = (x0, y0, x1, y1)
            mask[k] = 1.0
            k += 1
    return {
        "heat": heat,
        "ignore": ignore,
        "ind": ind,
        "size": size,
        "off": off,
        "box": box,
        "mask": mask,
    }


def _augment(
    data: CocoFrames, i: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random scale, crop (pad) to CROP, flip, colour jitter and noise of frame ``i``."""
    rgb, depth, boxes = data.rgb[i], data.depth[i].astype(np.float32) / 1000.0, data.anns[i].copy()
    s = float(rng.uniform(0.75, 1.3))
    if abs(s - 1.0) > 0.02:
        rgb = cv2.resize(rgb, None, fx=s, fy=s, interpolation=cv2.INTER_LINEAR)
        depth = cv2.resize(depth, None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
        boxes[:, 1:5] *= s
    ch, cw = CROP
    hh, ww = depth.shape
    oy = int(rng.integers(min(0, hh - ch), max(0, hh - ch) + 1))
    ox = int(rng.integers(min(0, ww - cw), max(0, ww - cw) + 1))
    out_rgb = np.full((ch, cw, 3), 127, np.uint8)
    out_d = np.zeros((ch, cw), np.float32)
    sy0, sx0 = max(0, oy), max(0, ox)
    sy1, sx1 = min(hh, oy + ch), min(ww, ox + cw)
    out_rgb[sy0 - oy : sy1 - oy, sx0 - ox : sx1 - ox] = rgb[sy0:sy1, sx0:sx1]
    out_d[sy0 - oy : sy1 - oy, sx0 - ox : sx1 - ox] = depth[sy0:sy1, sx0:sx1]
    if len(boxes):
        area0 = (boxes[:, 3] - boxes[:, 1]) * (boxes[:, 4] - boxes[:, 2])
        boxes[:, [1, 3]] -= ox
        boxes[:, [2, 4]] -= oy
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, cw)
        boxes[:, [2, 4]] = boxes[:, [2, 4]].clip(0, ch)
        area1 = (boxes[:, 3] - boxes[:, 1]) * (boxes[:, 4] - boxes[:, 2])
        gone = area1 <= 1.0
        boxes[(area1 < 0.4 * area0) & ~gone, 5] = 1.0  # mostly cut off: ignore, not negative
        boxes = boxes[~gone]
    if rng.random() < 0.5:
        out_rgb, out_d = out_rgb[:, ::-1], out_d[:, ::-1]
        boxes[:, [1, 3]] = cw - boxes[:, [3, 1]]
    x = out_rgb.astype(np.float32)
    x = x * rng.uniform(0.7, 1.3) + rng.uniform(-20, 20)  # contrast, brightness
    x = x * rng.uniform(0.92, 1.08, 3)  # white balance
    x += rng.normal(0.0, rng.uniform(0.0, 5.0), x.shape)
    out_rgb = np.clip(x, 0, 255).astype(np.uint8)
    return out_rgb, np.ascontiguousarray(out_d), boxes


def _batch(
    data: CocoFrames, idx: np.ndarray, rng: np.random.Generator
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    xs, ts = [], []
    for i in idx:
        rgb, d, boxes = _augment(data, int(i), rng)
        xs.append(encode_input(rgb, d))
        ts.append(make_targets(boxes, len(data.classes), CROP))
    x = torch.from_numpy(np.stack(xs))
    t = {k: torch.from_numpy(np.stack([tt[k] for tt in ts])) for k in ts[0]}
    return x, t


class _Batches(torch.utils.data.IterableDataset):
    """Endless augmented batches, in this process or in DataLoader workers (each its own
    random stream)."""

    def __init__(
        self, data: CocoFrames, batch: int, seed: int, start: int, weights: np.ndarray | None
    ) -> None:
        self.data, self.batch, self.seed, self.start = data, batch, seed, start
        self.p = None if weights is None else weights / weights.sum()

    def __iter__(self) -> Any:
        info = torch.utils.data.get_worker_info()
        rng = np.random.default_rng([self.seed, self.start, info.id if info else 0])
        while True:
            yield _batch(self.data, rng.choice(len(self.data), self.batch, p=self.p), rng)


def repeat_weights(data: CocoFrames, repeat: dict[str, float]) -> np.ndarray | None:
    """Frame sampling weights for repeat-factor sampling (Gupta et al. 2019, LVIS): a frame
    is drawn as often as the largest repeat factor of the classes it shows (1 for none).
    It spends more of the schedule on classes the detector confuses (spoon and marker,
    clamp and toy gun) without changing what a frame's labels say."""
    if not repeat:
        return None
    unknown = set(repeat) - set(data.classes)
    if unknown:
        raise ValueError(f"--repeat: no class {sorted(unknown)} (classes: {data.classes})")
    if any(f < 1.0 for f in repeat.values()):
        raise ValueError("--repeat: factors are >= 1")
    factor = np.ones(len(data.classes))
    for name, f in repeat.items():
        factor[data.classes.index(name)] = f
    return np.array([max([1.0, *(factor[int(c)] for c in a[:, 0])]) for a in data.anns], np.float64)


def _focal(logits: torch.Tensor, gt: torch.Tensor, ignore: torch.Tensor) -> torch.Tensor:
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = gt.eq(1).float()
    neg = (1 - pos) * (1 - ignore[:, None])
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p**2 * (1 - gt) ** 4 * neg
    n = pos.sum().clamp(min=1.0)
    return -(pos_loss.sum() + neg_loss.sum()) / n


def _gather(feat: torch.Tensor, ind: torch.Tensor) -> torch.Tensor:
    b, c = feat.shape[:2]
    return (
        feat.view(b, c, -1).gather(2, ind[:, None, :].expand(b, c, ind.shape[1])).permute(0, 2, 1)
    )


def _giou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    ix0, iy0 = torch.max(a[..., 0], b[..., 0]), torch.max(a[..., 1], b[..., 1])
    ix1, iy1 = torch.min(a[..., 2], b[..., 2]), torch.min(a[..., 3], b[..., 3])
    inter = (ix1 - ix0).clamp(min=0) * (iy1 - iy0).clamp(min=0)
    area_a = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area_b = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    union = area_a + area_b - inter
    iou = inter / union.clamp(min=1e-6)
    cx0, cy0 = torch.min(a[..., 0], b[..., 0]), torch.min(a[..., 1], b[..., 1])
    cx1, cy1 = torch.max(a[..., 2], b[..., 2]), torch.max(a[..., 3], b[..., 3])
    hull = ((cx1 - cx0) * (cy1 - cy0)).clamp(min=1e-6)
    return iou - (hull - union) / hull


def detection_loss(
    out: tuple[torch.Tensor, torch.Tensor, torch.Tensor], t: dict[str, torch.Tensor]
) -> tuple[torch.Tensor, dict[str, float]]:
    """The CenterNet losses of one batch (see the module docstring)."""
    heat, size, off = out
    l_heat = _focal(heat, t["heat"], t["ignore"])
    m = t["mask"][..., None]
    n = m.sum().clamp(min=1.0)
    ps, po = _gather(size, t["ind"]), _gather(off, t["ind"])
    l_size = (torch.abs(ps - t["size"]) * m).sum() / n
    l_off = (torch.abs(po - t["off"]) * m).sum() / n
    w = heat.shape[-1]
    cx = ((t["ind"] % w).float()[..., None] + po[..., :1]) * STRIDE
    cy = ((t["ind"] // w).float()[..., None] + po[..., 1:]) * STRIDE
    wh = torch.exp(ps.clamp(max=6.0)) * STRIDE
    pred = torch.cat(
        [cx - wh[..., :1] / 2, cy - wh[..., 1:] / 2, cx + wh[..., :1] / 2, cy + wh[..., 1:] / 2], -1
    )
    l_giou = ((1 - _giou(pred, t["box"])) * t["mask"]).sum() / n
    loss = l_heat + l_size + l_off + l_giou
    return loss, {
        "heat": float(l_heat.detach()),
        "size": float(l_size.detach()),
        "off": float(l_off.detach()),
        "giou": float(l_giou.detach()),
    }


def _lr(it: int, iters: int, base: float, warmup: int) -> float:
    if it < warmup:
        return base * (it + 1) / warmup
    p = (it - warmup) / max(1, iters - warmup)
    return base * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(1.0, p))))


def train(
    data: CocoFrames,
    iters: int,
    batch: int,
    out: Path,
    checkpoint: Path,
    resume: bool,
    lr: float = 2e-3,
    save_every: int = 200,
    threads: int = 2,
    seed: int = 0,
    log: Any = sys.stdout,
    stop_after_s: float | None = None,
    device: str = "cpu",
    workers: int = 0,
    budget_minutes: float | None = None,
    restart: bool = False,
    repeat: dict[str, float] | None = None,
) -> dict[str, Any]:
    """Train (or resume) for ``iters`` iterations in all; returns the final state's card.

    ``budget_minutes`` replaces ``iters`` by what fits: after 100 iterations (or a
    minute) the rate is measured and the schedule's end set so that the whole call ends
    within the budget. ``restart`` starts a new cosine (warm-up included) at the resumed
    iteration instead of following the old one to ``iters``; ``repeat`` draws frames
    showing the named classes that many times as often (:func:`repeat_weights`)."""
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    torch.backends.cudnn.benchmark = device.startswith("cuda")
    cfg = NetworkShape()
    net = CenterNet(len(data.classes), cfg).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    state: dict[str, Any] = {"iteration": 0, "train_minutes": 0.0, "history": []}
    if resume and checkpoint.exists():
        ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
        if tuple(ck["classes"]) != data.classes:
            raise ValueError(f"{checkpoint}: classes differ from the dataset's")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        state = {k: ck[k] for k in ("iteration", "train_minutes", "history")}
        state["schedule_start"] = ck.get("schedule_start", 0)
        print(
            f"[train] resumed at iteration {state['iteration']} from {checkpoint}",
            file=log,
            flush=True,
        )
    stop = {"now": False}

    def on_signal(signum: int, frame: Any) -> None:
        stop["now"] = True

    old = signal.signal(signal.SIGTERM, on_signal)
    net.train()
    card = {
        "data_seeds": [min(data.seeds), max(data.seeds)],
        "frames": len(data),
        "batch": batch,
        "crop": list(CROP),
        "lr": lr,
        "iters_planned": iters,
        "repeat": dict(repeat or {}),
    }

    def save(path: Path, with_opt: bool) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        blob = {
            "model": {k: v.detach().cpu() for k, v in net.state_dict().items()},
            "classes": list(data.classes),
            "config": asdict(cfg),
            **state,
            "card": card,
        }
        if with_opt:
            blob["optimizer"] = opt.state_dict()
        tmp = path.with_suffix(".tmp")
        torch.save(blob, tmp)
        tmp.replace(path)

    t_start = time.monotonic()
    t_seg = t_start
    losses: list[float] = []
    source = _Batches(data, batch, seed, state["iteration"], repeat_weights(data, repeat or {}))
    batches = iter(
        torch.utils.data.DataLoader(
            source,
            batch_size=None,
            num_workers=workers,
            pin_memory=device != "cpu",
            prefetch_factor=4,
        )
        if workers > 0
        else source
    )
    it0 = state["iteration"]
    if restart:
        state["schedule_start"] = it0  # kept in the checkpoint: a resumed part follows it
    sched0 = state.get("schedule_start", 0)  # where the current cosine started
    try:
        while state["iteration"] < iters and not stop["now"]:
            it = state["iteration"]
            if budget_minutes is not None and (
                it - it0 == 100 or (it > it0 and time.monotonic() - t_start > 60)
            ):
                rate = (it - it0) / (time.monotonic() - t_start)
                left = budget_minutes * 60.0 - (time.monotonic() - t_start)
                iters = it + max(1, int(rate * left))
                budget_minutes = None  # measured once
                card["iters_planned"] = iters
                print(f"[train] {rate:.1f} it/s: the schedule ends at {iters}", file=log)
            lr_now = _lr(it - sched0, iters - sched0, lr, 200)
            for g in opt.param_groups:
                g["lr"] = lr_now
            x, t = next(batches)
            x = x.to(device, non_blocking=True)
            t = {k: v.to(device, non_blocking=True) for k, v in t.items()}
            loss, parts = detection_loss(net(x), t)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
            losses.append(float(loss.detach()))
            state["iteration"] = it + 1
            if state["iteration"] % 20 == 0:
                now = time.monotonic()
                state["train_minutes"] += (now - t_seg) / 60.0
                t_seg = now
                mean = float(np.mean(losses[-20:]))
                state["history"].append([state["iteration"], round(mean, 4)])
                print(
                    f"[train] it {state['iteration']}/{iters} loss {mean:.3f} "
                    + " ".join(f"{k} {v:.3f}" for k, v in parts.items())
                    + f" lr {lr_now:.2e} {state['train_minutes']:.1f} min",
                    file=log,
                    flush=True,
                )
            if state["iteration"] % save_every == 0:
                save(checkpoint, True)
            if stop_after_s is not None and time.monotonic() - t_start > stop_after_s:
                break
    finally:
        signal.signal(signal.SIGTERM, old)
        state["train_minutes"] += (time.monotonic() - t_seg) / 60.0
        save(checkpoint, True)
    if state["iteration"] >= iters:
        save(out, False)
        print(f"[train] done: {out}", file=log, flush=True)
    else:
        print(
            f"[train] stopped at {state['iteration']}/{iters}; resume with --resume",
            file=log,
            flush=True,
        )
    return {**state, "card": card}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip perception train",
        description="Train the detector from scratch on rendered datasets (resumable).",
    )
    ap.add_argument("--data", type=Path, nargs="+", required=True, help="dataset folders (COCO)")
    ap.add_argument("--iters", type=int, default=6000, help="iterations in all (default 6000)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--out", type=Path, default=PACKAGE_DIR / "models" / "detector.pt")
    ap.add_argument("--checkpoint", type=Path, default=PACKAGE_DIR / "models" / "detector_ckpt.pt")
    ap.add_argument("--resume", action="store_true", help="continue from --checkpoint")
    ap.add_argument("--save-every", type=int, default=200)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stop-after", type=float, default=None, help="stop after S seconds")
    ap.add_argument("--device", default="cpu", help="cpu, or cuda on a machine with a GPU")
    ap.add_argument("--workers", type=int, default=0, help="batch-making processes (0: inline)")
    ap.add_argument(
        "--budget-minutes", type=float, default=None, help="fit the schedule to this time"
    )
    ap.add_argument(
        "--restart", action="store_true", help="with --resume: a new cosine from the checkpoint"
    )
    ap.add_argument(
        "--repeat",
        nargs="*",
        default=[],
        metavar="CLASS=F",
        help="draw frames showing CLASS F times as often (repeat-factor sampling)",
    )
    args = ap.parse_args(argv)
    try:
        repeat = {k: float(v) for k, v in (r.split("=", 1) for r in args.repeat)}
    except ValueError:
        ap.error(f"--repeat takes CLASS=FACTOR, got {args.repeat}")
    if args.iters <= 0 or args.batch <= 0 or args.workers < 0:
        ap.error("--iters and --batch must be positive, --workers not negative")
    if args.device != "cpu" and not torch.cuda.is_available():
        ap.error(f"--device {args.device}: no GPU here (torch sees none)")
    if not args.resume and args.checkpoint.exists():
        ap.error(f"{args.checkpoint} exists: pass --resume to continue it, or remove it")
    for d in args.data:
        if not (d / "annotations.json").exists():
            ap.error(f"{d} is not a dataset (no annotations.json)")
    t0 = time.monotonic()
    data = CocoFrames(args.data)
    print(f"[train] {len(data)} frames loaded in {time.monotonic() - t0:.0f} s", flush=True)
    train(
        data,
        args.iters,
        args.batch,
        args.out,
        args.checkpoint,
        args.resume,
        lr=args.lr,
        save_every=args.save_every,
        threads=args.threads,
        seed=args.seed,
        stop_after_s=args.stop_after,
        device=args.device,
        workers=args.workers,
        budget_minutes=args.budget_minutes,
        restart=args.restart,
        repeat=repeat,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
