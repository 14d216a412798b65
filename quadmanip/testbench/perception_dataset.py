"""Labelled camera frames for the detector (OFFLINE TOOL: it reads the simulator's labels).

``quadmanip perception dataset --seeds 0:3000 --out data/detector/train`` renders, for every
seed, one randomised scene from both robot cameras and writes a COCO dataset:

* ``images/NNNNNN.png`` colour, ``depth/NNNNNN.png`` depth (uint16, millimetres, 0 = no
  return), ``masks/NNNNNN.png`` instance masks (0 = none, k = the image's k-th annotation);
* ``annotations.json``: COCO ``images`` (with ``camera``, ``mode``, ``seed``), ``annotations``
  (``bbox`` [x, y, w, h] in pixels, ``iscrowd`` 1 for objects too little visible to be
  asked of a detector: evaluation ignores detections on them), ``categories`` (the
  catalogue's 18 objects, ids 1-18 in catalogue order).

A scene is the robot, standing, in one of the paper's search or probing postures (Figs. 5, 12:
``floor_search``, ``table_search``, ``probe_floor``, ``probe_table``, ``probe_horizontal``,
``probe_tall``: the trunk's nose lifted 0.25 rad, 0.35-0.75 m farther from the table,
mostly a tall box in front) somewhere in the house, with several catalogue objects resting on the floor or a table in
front of it at random yaw, random floor, table and wall colours and lighting, a little base
height and pitch, and depth degraded like a structured-light/ToF camera's (depth-dependent
noise, lost returns at depth edges and in speckles). Poses are written straight into the
kinematic state and rendered, never simulated: this tool makes pictures, not trials. Every
draw comes from ``numpy.random.default_rng([seed, ...])``, so a seed gives the same frames
on every machine; training and evaluation use disjoint seed ranges.

This module, the judge and the tests are the only places the simulator's labels are used.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.config import load_config
from quadmanip.common.rotations import quat_from_axis_angle, quat_from_yaw, quat_mul
from quadmanip.services.behavior.config import BehaviorConfig
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
from quadmanip.services.manipulation.config import load_manipulation_config
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.sim.scenarios import Placement, Scenario
from quadmanip.sim.sensors import CameraConfig, RgbdRenderer
from quadmanip.sim.world.builder import World, build_world

__all__ = ["MODES", "DatasetWriter", "SceneRenderer", "degrade_depth", "parse_seeds"]

# posture -> the camera it is for (the other camera is rendered too)
MODES: dict[str, str] = {
    "probe_floor": rd.GRIPPER_CAMERA,
    "floor_search": rd.GRIPPER_CAMERA,
    "probe_table": rd.GRIPPER_CAMERA,
    "table_search": rd.GRIPPER_CAMERA,
    "probe_horizontal": rd.FRONT_CAMERA,
    "probe_tall": rd.FRONT_CAMERA,
}
# the modes a seed draws from; ``probe_tall`` is half of the ``probe_horizontal`` draws
# (its own random stream, so every other seed's scene is what it was before it existed)
DRAWN_MODES = ("probe_floor", "floor_search", "probe_table", "table_search", "probe_horizontal")
MODE_WEIGHTS = np.array([0.25, 0.25, 0.15, 0.2, 0.15])
TALL_SHARE = 0.5  # of probe_horizontal scenes, shown as probe_tall
TALL_BACK = (0.35, 0.75)  # m: a probe_tall stance is this much farther from the table edge
TALL_PITCH_NOISE = 0.05  # rad about the posture's body pitch
TALL_FIRST = 0.7  # share of probe_tall scenes whose object in front is a tall one
CAMERAS = (rd.FRONT_CAMERA, rd.GRIPPER_CAMERA)
PARK = (60.0, 60.0)  # objects not in a scene wait here, far outside the house
MIN_PIXELS = 60  # fewer visible pixels: labelled but ignored (iscrowd)
MIN_SIDE = 5  # px
EMPTY_KEEP = 0.1  # share of frames without objects kept as negatives
TABLE_EDGE_AHEAD = (0.22, 0.32)  # base to the table edge it faces (m)


def parse_seeds(text: str) -> list[int]:
    """``A:B`` (B excluded), ``A,B,C`` or one number."""
    try:
        if ":" in text:
            a, b = (int(v) for v in text.split(":", 1))
            if b <= a:
                raise ValueError
            return list(range(a, b))
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"seeds must be A:B (A<B), A,B,C or N, not {text!r}"
        ) from None


def degrade_depth(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A real RGB-D camera's depth from a perfect one: noise growing with distance
    (sigma = 1.2 mm + 1.9 mm * (z - 0.4)^2, the Kinect-type axial model of Nguyen et al.
    2012), half the pixels on depth edges lost (mixed pixels), and 0.3-1.5 % lost in
    speckles."""
    d = depth.astype(np.float32).copy()
    valid = d > 0
    sigma = 0.0012 + 0.0019 * (d - 0.4) ** 2
    d[valid] += (rng.standard_normal(int(valid.sum())) * sigma[valid]).astype(np.float32)
    gx = np.abs(np.diff(depth, axis=1, prepend=depth[:, :1]))
    gy = np.abs(np.diff(depth, axis=0, prepend=depth[:1, :]))
    edge = (np.maximum(gx, gy) > 0.04 * np.maximum(depth, 0.2)) & valid
    drop = edge & (rng.random(d.shape) < 0.5)
    drop |= rng.random(d.shape) < rng.uniform(0.003, 0.015)
    d[drop] = 0.0
    return np.clip(d, 0.0, None)


@dataclass(frozen=True)
class Label:
    """One visible object in one frame."""

    name: str
    box: tuple[int, int, int, int]  # x0, y0, x1, y1 (x1, y1 exclusive)
    pixels: int
    mask: np.ndarray  # bool [H, W]

    @property
    def ignored(self) -> bool:
        w, h = self.box[2] - self.box[0], self.box[3] - self.box[1]
        return self.pixels < MIN_PIXELS or min(w, h) < MIN_SIDE


@dataclass(frozen=True)
class Frame:
    camera: str
    mode: str
    rgb: np.ndarray
    depth: np.ndarray
    labels: tuple[Label, ...]


class SceneRenderer:
    """One world with every catalogue object (parked out of sight), re-posed per seed."""

    def __init__(self) -> None:
        parked = Scenario(
            "dataset",
            0,
            tuple(
                Placement(n, "floor", (PARK[0] + 2.0 * i, PARK[1], 1.0), (1.0, 0.0, 0.0, 0.0))
                for i, n in enumerate(_catalogue_names())
            ),
        )
        self.world: World = build_world(parked)
        m = self.world.model
        self.model = m
        self.data = self.world.initial_data()
        self.base_qpos = self.data.qpos.copy()
        self.cat = self.world.catalogue
        self.names = self.world.object_names
        self.obj_adr = {n: m.jnt_qposadr[m.joint(f"obj/{n}/free").id] for n in self.names}
        geom_body = m.geom_bodyid
        self.geom_object = np.full(m.ngeom + 1, -1, np.int64)  # geom id -> object index
        for k, n in enumerate(self.names):
            self.geom_object[:-1][geom_body == self.world.object_body_ids[n]] = k
        self.renderer = RgbdRenderer(m, {c: CameraConfig() for c in CAMERAS})
        cfg = load_manipulation_config()
        self.postures = resolve_postures(ArmGeometry.from_description(), cfg)
        self.body_pitch = {n: p.body_pitch for n, p in cfg.postures.items()}
        # what counts as a tall object: the tidy-up task's rule (configs/behavior.toml)
        self.tall_height = load_config(BehaviorConfig, "behavior").task.tall
        joints = rd.joint_qpos_indices(m)
        self.arm_adr, self.leg_adr = joints[-4:], joints[:-4]
        self.free_adr = rd.free_joint_qpos_index(m)
        # the robot stands (``home``) as it does when it searches and probes; the sim's
        # start keyframe (``lying``) put the cameras 0.19 m too low and hid the robot's
        # own body, which the live gripper camera sees and took for orange objects
        self.stand_z = float(rd.home_qpos()[2])
        self.stand_legs = rd.home_joint_positions()[:-4]
        self.finger_adr = np.array([m.jnt_qposadr[m.joint(j).id] for j in rd.GRIPPER_JOINTS])
        self.finger_range = np.array([m.jnt_range[m.joint(j).id] for j in rd.GRIPPER_JOINTS])
        self.floors = [s for s in self.world.surfaces if s.kind == "floor"]
        areas = np.array([(s.max[0] - s.min[0]) * (s.max[1] - s.min[1]) for s in self.floors])
        self.floor_p = areas / areas.sum()
        self.tables = list(self.world.table_surfaces)
        self._colours = _ColourState(m, [t.name for t in self.tables])

    # ------------------------------------------------------------------ scene sampling
    def _on_floor(self, x: float, y: float, margin: float) -> bool:
        return any(
            s.min[0] + margin <= x <= s.max[0] - margin
            and s.min[1] + margin <= y <= s.max[1] - margin
            for s in self.floors
        )

    def _robot_fits(self, x: float, y: float, r: float = 0.35) -> bool:
        """Inside one room with ``r`` to spare, and clear of the tables."""
        house = self.world.house
        room = house.room_at(x, y)
        if room is None:
            return False
        for dx, dy in ((r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)):
            if house.room_at(x + dx, y + dy) != room:
                return False
        return not any(
            t.min[0] - 0.15 < x < t.max[0] + 0.15 and t.min[1] - 0.15 < y < t.max[1] + 0.15
            for t in self.tables
        )

    def _robot_on_floor(self, rng: np.random.Generator) -> tuple[float, float, float]:
        for _ in range(200):
            s = self.floors[int(rng.choice(len(self.floors), p=self.floor_p))]
            x, y = rng.uniform(s.min[0], s.max[0]), rng.uniform(s.min[1], s.max[1])
            if self._on_floor(x, y, 0.45):
                return float(x), float(y), float(rng.uniform(-math.pi, math.pi))
        raise RuntimeError("no floor spot for the robot")

    def _place(
        self,
        rng: np.random.Generator,
        names: list[str],
        spots: list[tuple[float, float]],
        z: float,
        placed: list[tuple[str, float, float, float]],
        inside: Any,
    ) -> None:
        for name, (x, y) in zip(names, spots, strict=False):
            r = self.cat.objects[name].footprint_radius
            if not inside(x, y, r):
                continue
            if any(math.hypot(x - px, y - py) < r + pr + 0.02 for _, px, py, pr in placed):
                continue
            placed.append((name, x, y, r))
            adr = self.obj_adr[name]
            self.data.qpos[adr : adr + 3] = [x, y, z + self.cat.objects[name].size[2] / 2]
            self.data.qpos[adr + 3 : adr + 7] = quat_from_yaw(float(rng.uniform(-math.pi, math.pi)))

    def scene_mode(self, seed: int) -> str:
        """The posture scene ``seed`` shows (cheap: no posing, no rendering)."""
        mode = str(np.random.default_rng([seed, 0xDA7A]).choice(DRAWN_MODES, p=MODE_WEIGHTS))
        if (
            mode == "probe_horizontal"
            and np.random.default_rng([seed, 0x7A11]).random() < TALL_SHARE
        ):
            return "probe_tall"
        return mode

    def pose_scene(self, seed: int) -> str:
        """Pose robot, arm, objects, colours and lights for ``seed``; returns the mode."""
        rng = np.random.default_rng([seed, 0xDA7A])
        d = self.data
        d.qpos[:] = self.base_qpos
        d.qvel[:] = 0.0
        for i, n in enumerate(self.names):
            adr = self.obj_adr[n]
            d.qpos[adr : adr + 3] = [PARK[0] + 2.0 * i, PARK[1], 1.0]
        mode = str(rng.choice(DRAWN_MODES, p=MODE_WEIGHTS))
        order = [str(n) for n in rng.permutation(self.names)]
        # probe_tall (a draw of its own stream): the trunk's nose lifted, from farther back
        tall_rng = np.random.default_rng([seed, 0x7A11])
        tall = mode == "probe_horizontal" and tall_rng.random() < TALL_SHARE
        if tall and tall_rng.random() < TALL_FIRST:
            high = [n for n in order if self.cat.objects[n].size[2] > self.tall_height]
            first = high[int(tall_rng.integers(len(high)))]
            order.remove(first)
            order.insert(0, first)
        placed: list[tuple[str, float, float, float]] = []
        if mode in ("probe_floor", "floor_search"):
            x, y, yaw = self._robot_on_floor(rng)
            fwd, left = (
                np.array([math.cos(yaw), math.sin(yaw)]),
                np.array([-math.sin(yaw), math.cos(yaw)]),
            )
            if mode == "probe_floor":
                n_near = 1 + int(rng.integers(0, 4))
                ahead = np.r_[rng.uniform(0.30, 0.42), rng.uniform(0.2, 0.8, n_near - 1)]
                lat = np.r_[rng.uniform(-0.06, 0.06), rng.uniform(-0.4, 0.4, n_near - 1)]
            else:
                n_near = 2 + int(rng.integers(0, 6))
                ahead = rng.uniform(0.35, 2.2, n_near)
                lat = rng.uniform(-1.0, 1.0, n_near) * (0.15 + 0.45 * ahead)
            spots = [
                tuple(np.array([x, y]) + a * fwd + b * left)
                for a, b in zip(ahead, lat, strict=True)
            ]
            self._place(
                rng, order[:n_near], spots, 0.0, placed, lambda px, py, r: self._on_floor(px, py, r)
            )
        else:
            t = self.tables[int(rng.integers(len(self.tables)))]
            x, y, yaw, edge_pt, inward = self._robot_at_table(rng, t)
            if tall:
                back = float(tall_rng.uniform(*TALL_BACK))
                bx, by = x - back * float(inward[0]), y - back * float(inward[1])
                if self._robot_fits(bx, by):
                    x, y, mode = bx, by, "probe_tall"
            along = np.array([-inward[1], inward[0]])
            if mode == "table_search":
                n_near = 2 + int(rng.integers(0, 5))
                into = rng.uniform(0.04, 0.6, n_near)
                side = rng.uniform(-0.6, 0.6, n_near)
            else:
                n_near = 1 + int(rng.integers(0, 3))
                into = np.r_[rng.uniform(0.05, 0.14), rng.uniform(0.04, 0.5, n_near - 1)]
                side = np.r_[rng.uniform(-0.05, 0.05), rng.uniform(-0.45, 0.45, n_near - 1)]
            spots = [
                tuple(edge_pt + a * inward + b * along) for a, b in zip(into, side, strict=True)
            ]

            def on_table(px: float, py: float, r: float, t: Any = t) -> bool:
                m = r + 0.01
                return t.min[0] + m <= px <= t.max[0] - m and t.min[1] + m <= py <= t.max[1] - m

            self._place(rng, order[:n_near], spots, t.z, placed, on_table)
            if rng.random() < 0.3:  # a few more on the floor around
                extra = order[n_near : n_near + 2]
                fwd = np.array([math.cos(yaw), math.sin(yaw)])
                sp = [
                    tuple(
                        np.array([x, y]) + rng.uniform(0.4, 1.5) * fwd + rng.uniform(-0.8, 0.8, 2)
                    )
                    for _ in extra
                ]
                self._place(
                    rng, extra, sp, 0.0, placed, lambda px, py, r: self._on_floor(px, py, r)
                )
        # robot base: standing legs (a little spread, as in a gait's stance), a little height
        # and pitch, the mode's arm posture, the fingers anywhere from shut to open
        fa = self.free_adr
        d.qpos[fa : fa + 3] = [x, y, self.stand_z + rng.uniform(-0.03, 0.01)]
        d.qpos[self.leg_adr] = self.stand_legs + rng.normal(0.0, 0.08, len(self.leg_adr))
        lo, hi = self.finger_range[:, 0], self.finger_range[:, 1]
        d.qpos[self.finger_adr] = lo + rng.uniform() * (hi - lo)
        pitch = float(rng.uniform(-0.08, 0.08))
        if mode == "probe_tall":
            pitch = self.body_pitch[mode] + float(tall_rng.uniform(-1.0, 1.0)) * TALL_PITCH_NOISE
        tilt = quat_mul(
            quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), pitch),
            quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), float(rng.uniform(-0.03, 0.03))),
        )
        d.qpos[fa + 3 : fa + 7] = quat_mul(quat_from_yaw(yaw), tilt)
        q_arm = self.postures[mode] + rng.normal(0.0, 0.03, 4)
        d.qpos[self.arm_adr] = q_arm
        self._colours.randomise(rng)
        mujoco.mj_forward(self.model, d)
        return mode

    def _robot_at_table(
        self, rng: np.random.Generator, t: Any
    ) -> tuple[float, float, float, np.ndarray, np.ndarray]:
        """Robot on the floor facing a table side: (x, y, yaw, edge point, inward normal)."""
        cx, cy = 0.5 * (t.min[0] + t.max[0]), 0.5 * (t.min[1] + t.max[1])
        sides = [
            (np.array([t.min[0], cy]), np.array([1.0, 0.0]), t.max[1] - t.min[1]),
            (np.array([t.max[0], cy]), np.array([-1.0, 0.0]), t.max[1] - t.min[1]),
            (np.array([cx, t.min[1]]), np.array([0.0, 1.0]), t.max[0] - t.min[0]),
            (np.array([cx, t.max[1]]), np.array([0.0, -1.0]), t.max[0] - t.min[0]),
        ]
        for _ in range(100):
            mid, inward, length = sides[int(rng.integers(4))]
            along = np.array([-inward[1], inward[0]])
            edge = mid + along * rng.uniform(-0.4, 0.4) * length
            p = edge - inward * rng.uniform(*TABLE_EDGE_AHEAD)
            if self._robot_fits(float(p[0]), float(p[1])):
                yaw = math.atan2(inward[1], inward[0]) + rng.uniform(-0.25, 0.25)
                return float(p[0]), float(p[1]), yaw, edge, inward
        raise RuntimeError(f"no floor spot in front of {t.name}")

    # ------------------------------------------------------------------ rendering
    def render(self, seed: int, noise: bool = True) -> list[Frame]:
        """Both cameras of scene ``seed`` with their labels."""
        mode = self.pose_scene(seed)
        rng = np.random.default_rng([seed, 0xDE97])
        frames = []
        for cam in CAMERAS:
            f = self.renderer.render(self.data, cam)
            seg = self.renderer.render_segmentation(self.data, cam)
            obj = self.geom_object[np.where(seg >= 0, seg, -1)]
            labels = []
            for k in np.unique(obj[obj >= 0]):
                mask = obj == k
                ys, xs = np.nonzero(mask)
                box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
                labels.append(Label(self.names[int(k)], box, int(mask.sum()), mask))
            depth = degrade_depth(f.depth, rng) if noise else f.depth
            frames.append(Frame(cam, mode, f.rgb.copy(), depth, tuple(labels)))
        return frames

    def close(self) -> None:
        self.renderer.close()


class _ColourState:
    """Floor, wall and table colours and the lights, randomised around the house's own."""

    def __init__(self, m: mujoco.MjModel, tables: list[str]) -> None:
        self.m = m
        self.floor_mat = m.material("house/floor").id
        self.wall_mat = m.material("house/wall").id
        self.mat_rgba = m.mat_rgba.copy()
        names = [m.geom(i).name for i in range(m.ngeom)]
        self.table_geoms = np.array(
            [i for i, n in enumerate(names) if any(n.startswith(t) for t in tables)], int
        )
        self.geom_rgba = m.geom_rgba.copy()
        self.light_diffuse = m.light_diffuse.copy()
        self.headlight = (m.vis.headlight.ambient.copy(), m.vis.headlight.diffuse.copy())

    def randomise(self, rng: np.random.Generator) -> None:
        m = self.m
        m.mat_rgba[:] = self.mat_rgba
        m.geom_rgba[:] = self.geom_rgba
        # floor: the texture times a random tint (wood, tiles, grey carpet...)
        m.mat_rgba[self.floor_mat, :3] = rng.uniform(0.45, 1.15, 3).clip(0, 1)
        m.mat_rgba[self.wall_mat, :3] = rng.uniform(0.6, 1.0) * rng.uniform(0.85, 1.0, 3)
        if len(self.table_geoms):
            base = rng.uniform(0.15, 0.95) * rng.uniform(0.6, 1.0, 3)
            m.geom_rgba[self.table_geoms, :3] = base
        m.light_diffuse[:] = self.light_diffuse * rng.uniform(0.5, 1.5)
        amb, dif = self.headlight
        m.vis.headlight.ambient[:] = amb * rng.uniform(0.6, 1.4)
        m.vis.headlight.diffuse[:] = dif * rng.uniform(0.6, 1.4)


def _catalogue_names() -> tuple[str, ...]:
    from quadmanip.sim.world.objects import load_catalogue

    return load_catalogue().names


class DatasetWriter:
    """Writes frames as a COCO dataset (images, depth, masks, annotations.json)."""

    def __init__(self, out: Path, names: tuple[str, ...]) -> None:
        self.out = out
        for sub in ("images", "depth", "masks"):
            (out / sub).mkdir(parents=True, exist_ok=True)
        self.names = names
        self.coco: dict[str, Any] = {
            "info": {"description": "quadmanip detector dataset (rendered, MuJoCo)"},
            "categories": [{"id": i + 1, "name": n} for i, n in enumerate(names)],
            "images": [],
            "annotations": [],
        }

    def add(self, frame: Frame, seed: int) -> None:
        img_id = len(self.coco["images"]) + 1
        stem = f"{img_id:06d}.png"
        h, w = frame.depth.shape
        cv2.imwrite(str(self.out / "images" / stem), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
        mm = np.clip(np.round(frame.depth * 1000.0), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(self.out / "depth" / stem), mm)
        masks = np.zeros((h, w), np.uint8)
        for k, lab in enumerate(frame.labels):
            masks[lab.mask] = k + 1
            x0, y0, x1, y1 = lab.box
            self.coco["annotations"].append(
                {
                    "id": len(self.coco["annotations"]) + 1,
                    "image_id": img_id,
                    "category_id": self.names.index(lab.name) + 1,
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "area": lab.pixels,
                    "iscrowd": int(lab.ignored),
                    "mask_value": k + 1,
                }
            )
        cv2.imwrite(str(self.out / "masks" / stem), masks)
        self.coco["images"].append(
            {
                "id": img_id,
                "file_name": f"images/{stem}",
                "depth_file": f"depth/{stem}",
                "mask_file": f"masks/{stem}",
                "width": w,
                "height": h,
                "camera": frame.camera,
                "mode": frame.mode,
                "seed": seed,
            }
        )

    def save(self) -> Path:
        path = self.out / "annotations.json"
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.coco))
        tmp.replace(path)
        return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip perception dataset",
        description="Render labelled frames of both robot cameras in randomised scenes (COCO).",
    )
    ap.add_argument("--seeds", type=parse_seeds, required=True, help="scene seeds: A:B, A,B,C")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--no-noise", action="store_true", help="keep the perfect depth")
    ap.add_argument(
        "--modes",
        type=lambda t: tuple(t.split(",")),
        default=tuple(MODES),
        help=f"keep only scenes of these postures (comma-separated; of {', '.join(MODES)})",
    )
    args = ap.parse_args(argv)
    unknown = sorted(set(args.modes) - set(MODES))
    if unknown:
        print(f"unknown --modes {', '.join(unknown)} (known: {', '.join(MODES)})", file=sys.stderr)
        return 2
    if (args.out / "annotations.json").exists():
        print(f"{args.out} already holds a dataset; choose another --out", file=sys.stderr)
        return 2
    scenes = SceneRenderer()
    writer = DatasetWriter(args.out, scenes.names)
    t0 = time.monotonic()
    kept = 0
    try:
        for i, seed in enumerate(args.seeds):
            # (a probe_tall stance that does not fit in the room shows as probe_horizontal)
            frames = (
                scenes.render(seed, noise=not args.no_noise)
                if scenes.scene_mode(seed) in args.modes
                else []
            )
            for f in frames:
                if f.labels or np.random.default_rng([seed, len(f.camera)]).random() < EMPTY_KEEP:
                    writer.add(f, seed)
                    kept += 1
            if (i + 1) % 100 == 0 or i + 1 == len(args.seeds):
                el = time.monotonic() - t0
                print(
                    f"[dataset] {i + 1}/{len(args.seeds)} scenes, {kept} frames, "
                    f"{len(writer.coco['annotations'])} objects, {el:.0f} s",
                    flush=True,
                )
                writer.save()
    finally:
        scenes.close()
    print(f"[dataset] wrote {writer.save()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
