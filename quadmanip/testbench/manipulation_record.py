"""PNG sequences of a floor grasp, a table grasp, a place and a drawer opening.

``python -m quadmanip.testbench.manipulation_record OUT_DIR`` renders the in-process physics
runs of the tests (``quadmanip/testbench/manipulation_scenes.py``) from a fixed side camera, one frame every
``--period`` sim seconds, plus a contact sheet per run. Evidence for reviewers; not used
by the service.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
from quadmanip.services.manipulation.config import ManipulationConfig, load_manipulation_config
from quadmanip.services.manipulation.drawer import DrawerPrimitive, plan_drawer
from quadmanip.services.manipulation.grasp import GraspPrimitive, plan_grasp
from quadmanip.services.manipulation.place import PlacePrimitive, plan_place
from quadmanip.services.manipulation.primitive import Primitive
from quadmanip.testbench.manipulation_scenes import (
    TABLE_HEIGHT,
    PlacedObject,
    SimHarness,
    container_boxes,
    container_inner,
    drawer_world,
    grasp_from_ground_truth,
    table_boxes,
)

__all__ = ["main"]


class _Recorder:
    def __init__(self, h: SimHarness, out: Path, period: float) -> None:
        self.h = h
        self.out = out
        self.period = period
        self.next_t = 0.0
        self.frames: list[np.ndarray] = []
        self.renderer = mujoco.Renderer(h.model, 360, 480)
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        base, _ = h.base_pose()
        self.cam.lookat[:] = base + np.array([0.3, 0.0, -0.1])
        self.cam.distance = 1.3
        self.cam.azimuth = 120.0
        self.cam.elevation = -20.0
        out.mkdir(parents=True, exist_ok=True)

    def __call__(self, h: SimHarness) -> None:
        if h.data.time + 1e-9 < self.next_t:
            return
        self.next_t = h.data.time + self.period
        self.renderer.update_scene(h.data, self.cam)
        img = self.renderer.render()
        self.frames.append(img.copy())

    def save(self) -> int:
        import cv2

        for i, img in enumerate(self.frames):
            cv2.imwrite(str(self.out / f"frame_{i:03d}.png"), img[:, :, ::-1])
        if self.frames:
            pick = self.frames[:: max(1, len(self.frames) // 8)][:8]
            while len(pick) < 8:
                pick.append(np.zeros_like(self.frames[0]))
            sheet = np.vstack([np.hstack(pick[:4]), np.hstack(pick[4:8])])
            cv2.imwrite(str(self.out / "sheet.png"), sheet[:, :, ::-1])
        return len(self.frames)

    def save_compact(self, path: Path) -> None:
        """A small contact sheet for the docs (see :func:`contact_sheet`)."""
        if self.frames:
            path.parent.mkdir(parents=True, exist_ok=True)
            contact_sheet(self.frames).quantize(256).save(path, optimize=True)


def contact_sheet(frames: list[np.ndarray]) -> Any:
    """8 frames evenly over a run, 320x240 each, 2 x 4, as a PIL image."""
    from PIL import Image

    idx = np.linspace(0, len(frames) - 1, 8).round().astype(int)
    tiles = [Image.fromarray(frames[i]).resize((320, 240)) for i in idx]
    sheet = Image.new("RGB", (4 * 320, 2 * 240))
    for k, tile in enumerate(tiles):
        sheet.paste(tile, ((k % 4) * 320, (k // 4) * 240))
    return sheet


def main(argv: list[str] | None = None) -> int:
    """Renders the four runs into ``OUT_DIR/<run>/``."""
    ap = argparse.ArgumentParser(prog="python -m quadmanip.testbench.manipulation_record")
    ap.add_argument("out", type=Path)
    ap.add_argument("--period", type=float, default=0.25)
    ap.add_argument("--docs", type=Path, help="also write one compact sheet per run here")
    args = ap.parse_args(argv)
    cfg = load_manipulation_config()
    geom = ArmGeometry.from_description()
    kp, kd = cfg.motion.kp, cfg.motion.kd

    # floor grasp
    h = SimHarness([PlacedObject("tomato_soup_can", (0.36, 0.02, 0.051), yaw=0.3)])
    rec = _Recorder(h, args.out / "floor_grasp", args.period)
    gs = grasp_from_ground_truth(h, "tomato_soup_can", 0.0, "vertical")
    plan = plan_grasp(geom, cfg, gs.position_base, gs.approach, gs.yaw, gs.width)
    p = h.run(GraspPrimitive(geom, cfg, plan), kp, kd, 30.0, every_tick=rec)
    h.run(_Idle(geom, cfg, 2.0), kp, kd, 3.0, every_tick=rec)
    if args.docs:
        rec.save_compact(args.docs / "floor_grasp.png")
    print("floor_grasp", p.status.value, rec.save())

    # table grasp (horizontal)
    o = "sugar_box"
    h = SimHarness([PlacedObject(o, (0.36, 0.0, TABLE_HEIGHT + 0.0885))], table_boxes())
    rec = _Recorder(h, args.out / "table_grasp", args.period)
    gs = grasp_from_ground_truth(h, o, TABLE_HEIGHT, "horizontal")
    plan = plan_grasp(geom, cfg, gs.position_base, gs.approach, gs.yaw, gs.width)
    p = h.run(GraspPrimitive(geom, cfg, plan), kp, kd, 30.0, every_tick=rec)
    h.run(_Idle(geom, cfg, 2.0), kp, kd, 3.0, every_tick=rec)
    if args.docs:
        rec.save_compact(args.docs / "table_grasp.png")
    print("table_grasp", p.status.value, rec.save())

    # place into the green box
    h = SimHarness(
        [PlacedObject("brick", (0.31, 0.0, 0.026), yaw=0.2)], container_boxes("green_box", 0.55)
    )
    rec = _Recorder(h, args.out / "place", args.period)
    gs = grasp_from_ground_truth(h, "brick", 0.0, "vertical")
    plan = plan_grasp(geom, cfg, gs.position_base, gs.approach, gs.yaw, gs.width)
    g = h.run(GraspPrimitive(geom, cfg, plan), kp, kd, 30.0, every_tick=rec)
    hang = float(h.tcp_world()[2] - (h.object_pos("brick")[2] - 0.025))
    ix, _, height = container_inner("green_box", 0.55)
    target = h.world_to_base(np.array([0.55 - 0.6 * ix, 0.0, height]))
    pplan = plan_place(geom, cfg, target, h.observation().q_arm, hang, g.body)
    p = h.run(
        PlacePrimitive(geom, cfg, pplan, monitor=g.monitor, body=g.body),
        kp,
        kd,
        40.0,
        every_tick=rec,
    )
    if args.docs:
        rec.save_compact(args.docs / "place.png")
    print("place", p.status.value, rec.save())

    # drawer
    world = drawer_world("top")
    h = SimHarness(world=world)
    rec = _Recorder(h, args.out / "drawer", args.period)
    handle = h.world_to_base(h.data.body(world.drawer_handles["top"]).xpos)  # type: ignore[attr-defined]
    dplan = plan_drawer(geom, cfg, handle, np.array([-1.0, 0.0, 0.0]), 0.15)
    p = h.run(DrawerPrimitive(geom, cfg, dplan), kp, kd, 40.0, every_tick=rec)
    if args.docs:
        rec.save_compact(args.docs / "drawer.png")
    print("drawer", p.status.value, rec.save())
    return 0


class _Idle(Primitive):
    """Holds still for a while (to film the object being held)."""

    name = "idle"

    def __init__(self, geom: ArmGeometry, cfg: ManipulationConfig, seconds: float) -> None:
        super().__init__(geom, cfg)
        self.seconds = seconds

    def script(self):  # noqa: ANN201
        """Waits ``seconds``."""
        yield []
        yield from self.wait(self.seconds)


if __name__ == "__main__":
    raise SystemExit(main())
