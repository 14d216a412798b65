"""PNG sequences of full-stack trials: a floor grasp, a table grasp, a place, a drawer.

``MUJOCO_GL=egl python -m quadmanip.testbench.stack_record OUT_DIR [--docs DIR]`` runs four
acceptance trials of :mod:`quadmanip.testbench.stack_trials` (sim, locomotion and
manipulation as processes over Zenoh) and films each one: every ``--period`` sim seconds
it samples what went over the wire - the joint angles and finger gap in ``sim/lowstate``,
the ground-truth base, object and drawer-handle poses - and afterwards replays those
samples on its own copy of the world (``mj_forward`` only, like the viz service's
skeleton: a picture, not a simulation) from a camera that follows the robot. Writes
``OUT_DIR/<run>/frame_NNN.png``, a contact sheet per run, and with ``--docs`` one small
sheet per run for the documentation. Evidence for reviewers; no service uses it.
"""

from __future__ import annotations

import argparse
import json
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import quat_to_mat
from quadmanip.sim.scenarios import Scenario
from quadmanip.sim.world import build_world
from quadmanip.testbench.manipulation_record import contact_sheet
from quadmanip.testbench.stack import StackRun

__all__ = ["StackFilm", "main"]

WIDTH, HEIGHT = 480, 360


@dataclass(frozen=True)
class _Sample:
    t: float
    q: np.ndarray
    gap: float
    base: tuple[np.ndarray, np.ndarray]
    objects: dict[str, tuple[np.ndarray, np.ndarray]]
    drawers: dict[str, np.ndarray]


class StackFilm:
    """Samples a running :class:`StackRun` every ``period`` sim seconds; renders later."""

    def __init__(
        self, scenario: Scenario, out: Path, period: float = 0.25, azimuth: float = 125.0
    ) -> None:
        self.scenario = scenario
        self.azimuth = azimuth  # camera bearing from the robot's heading (deg)
        self.out = out
        self.period = period
        self.samples: list[_Sample] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ sampling
    def start(self, s: StackRun) -> None:
        """Begin sampling ``s`` (call after the stack is up)."""
        assert s.bus is not None
        self._low = s.bus.latest("sim/lowstate")
        self._s = s
        self._thread = threading.Thread(target=self._loop, name="stack-film", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop sampling."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _loop(self) -> None:
        next_t = -1.0
        while not self._stop.wait(0.01):
            t = self._s.now()
            low = self._low.get()
            if t < next_t or low is None:
                continue
            smp = sample_state(
                t, low, self._s.base.get(), self._s.objs.get(), self._s.drawers.get()
            )
            if smp is None:
                continue
            self.samples.append(smp)
            next_t = t + self.period

    # ------------------------------------------------------------------ replay
    def render(self) -> list[np.ndarray]:
        """The sampled states drawn on a kinematic copy of the world."""
        return render_states(self.scenario, self.samples, self.azimuth)

    def save(self, docs_sheet: Path | None = None) -> int:
        """Render and write the frames, a contact sheet and optionally a docs sheet."""
        from PIL import Image

        frames = self.render()
        self.out.mkdir(parents=True, exist_ok=True)
        for i, img in enumerate(frames):
            Image.fromarray(img).save(self.out / f"frame_{i:03d}.png")
        if frames:
            sheet = contact_sheet(frames)
            sheet.save(self.out / "sheet.png")
            if docs_sheet is not None:
                docs_sheet.parent.mkdir(parents=True, exist_ok=True)
                sheet.quantize(256).save(docs_sheet, optimize=True)
        return len(frames)


def sample_state(t: float, low: Any, base: Any, objs: Any, drawers: Any) -> _Sample | None:
    """One replayable state from the newest ``sim/lowstate``, ``sim/gt/base``,
    ``sim/gt/objects`` and ``sim/gt/drawers`` messages (None before the first of the two
    first ones, or for messages whose lists do not match: a missed frame, not an error that
    ends the trial being filmed)."""
    if low is None or base is None or "base" not in base.names:
        return None
    try:
        return _sample(t, low, base, objs, drawers)
    except (ValueError, IndexError):
        return None


def _sample(t: float, low: Any, base: Any, objs: Any, drawers: Any) -> _Sample:
    i = list(base.names).index("base")
    return _Sample(
        t=t,
        q=np.asarray(low.joints.q, dtype=float).copy(),
        gap=float(low.joints.gripper_gap),
        base=(np.asarray(base.positions[i]).copy(), np.asarray(base.orientations[i]).copy()),
        objects={}
        if objs is None
        else {
            n: (np.asarray(p), np.asarray(q))
            for n, p, q in zip(objs.names, objs.positions, objs.orientations, strict=True)
        },
        drawers={}
        if drawers is None
        else {n: np.asarray(p) for n, p in zip(drawers.names, drawers.positions, strict=True)},
    )


def render_states(
    scenario: Scenario | None,
    samples: list[_Sample],
    azimuth: float = 125.0,
    unblocked: bool = False,
) -> list[np.ndarray]:
    """``samples`` drawn on a kinematic copy of ``scenario``'s world (``mj_forward`` only)
    from a camera that follows the robot, ``azimuth`` degrees from its heading. With
    ``unblocked``, of ``azimuth`` and three more a quarter turn apart, the one that shows
    most of the robot (a wall between the camera and the robot hides it; counted on a
    segmentation render)."""
    world = build_world(scenario)
    model, data = world.model, world.initial_data()
    jq = rd.joint_qpos_indices(model)
    fingers = rd.joint_qpos_indices(model, rd.GRIPPER_JOINTS)
    free = rd.free_joint_qpos_index(model)
    obj_adr = {
        n: int(model.jnt_qposadr[model.body(f"obj/{n}").jntadr[0]]) for n in world.object_names
    }
    slide = {k: int(model.joint(j).qposadr[0]) for k, j in world.drawer_joints.items()}
    handle0: dict[str, np.ndarray] = {}
    renderer = mujoco.Renderer(model, HEIGHT, WIDTH)
    seg = mujoco.Renderer(model, HEIGHT // 4, WIDTH // 4) if unblocked else None
    if seg is not None:
        seg.enable_segmentation_rendering()
    root = model.body_rootid[model.body(rd.BASE_BODY).id]
    robot_geoms = np.flatnonzero(model.body_rootid[model.geom_bodyid] == root)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.elevation = 1.6, -22.0
    frames = []
    for smp in samples:
        data.qpos[jq] = smp.q
        data.qpos[fingers] = 0.5 * smp.gap
        bp, bq = smp.base
        data.qpos[free : free + 3], data.qpos[free + 3 : free + 7] = bp, bq
        for n, (p, q) in smp.objects.items():
            if n in obj_adr:
                a = obj_adr[n]
                data.qpos[a : a + 3], data.qpos[a + 3 : a + 7] = p, q
        for k, p in smp.drawers.items():
            handle0.setdefault(k, p)
            if k in slide:  # the drawer slides along world x (the cabinet faces west)
                data.qpos[slide[k]] = float(np.linalg.norm((p - handle0[k])[:2]))
        mujoco.mj_forward(model, data)
        r = quat_to_mat(bq)
        yaw = float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))
        cam.lookat[:] = bp + r @ np.array([0.35, 0.0, -0.12])
        cam.azimuth = yaw + azimuth
        if seg is not None:
            cam.azimuth = yaw + max(
                (azimuth + k * 90.0 for k in range(4)),
                key=lambda a: _robot_pixels(seg, data, cam, yaw + a, robot_geoms),
            )
        renderer.update_scene(data, cam)
        frames.append(renderer.render().copy())
    renderer.close()
    if seg is not None:
        seg.close()
    return frames


def _robot_pixels(
    seg: mujoco.Renderer,
    data: mujoco.MjData,
    cam: mujoco.MjvCamera,
    azimuth: float,
    geoms: np.ndarray,
) -> int:
    """How many pixels of the robot's geoms a segmentation render from ``azimuth`` shows."""
    cam.azimuth = azimuth
    seg.update_scene(data, cam)
    ids = seg.render()
    on_geom = ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    return int(np.isin(ids[..., 0][on_geom], geoms).sum())


def main(argv: list[str] | None = None) -> int:
    """Film the four runs into ``OUT_DIR/<run>/``."""
    from quadmanip.testbench import stack_trials as st

    ap = argparse.ArgumentParser(prog="python -m quadmanip.testbench.stack_record")
    ap.add_argument("out", type=Path)
    ap.add_argument("--period", type=float, default=0.25, help="sim seconds between frames")
    ap.add_argument("--docs", type=Path, help="also write one small sheet per run here")
    ap.add_argument(
        "--runs", nargs="+", help="only these runs (floor_grasp table_grasp place drawer)"
    )
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = (args.out / "stack.log").open("w")
    runs: list[tuple[str, Scenario, Any]] = [
        (
            "floor_grasp",
            st.grasp_scenario("tomato_soup_can", "floor", 0),
            lambda film: st.run_grasp_trial("tomato_soup_can", "floor", 0, log, film=film),
        ),
        (
            "table_grasp",
            st.grasp_scenario("sugar_box", "table", 0),
            lambda film: st.run_grasp_trial("sugar_box", "table", 0, log, film=film),
        ),
        (
            "place",
            st.place_scenario("brick", 0),
            lambda film: st.run_place_trial("brick", 0, log, film=film),
        ),
        (
            "drawer",
            st.drawer_scenario("top"),
            lambda film: st.run_drawer_trial("top", log, film=film),
        ),
    ]
    # from the front left; by a wall (the cabinet, the floor boxes) from behind left instead
    azimuth = {"drawer": 55.0, "place": 35.0}
    for name, scn, run in runs:
        if args.runs and name not in args.runs:
            continue
        film = StackFilm(scn, args.out / name, args.period, azimuth.get(name, 125.0))
        result = run(film)
        n = film.save(None if args.docs is None else args.docs / f"{name}.png")
        print(f"{name}: {'ok' if result['success'] else 'FAILED'}, {n} frames")
        print(json.dumps(result))
    log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
