"""The judge: from ground truth, which objects lie in their correct deposit place.

Paper Section 7.2: each object belongs in the place of its category (pencil case, tray,
drawer, green box, black box, small box). An object counts as *in place* when its centre
(body origin = centre of its bounding box) lies inside one of its place's regions and it is
at rest; the drawer place has one region per drawer, attached to the drawer body so it moves
with it. Everything else is *misplaced*. Only the sim (and tests) call this: it reads ground
truth, which no service may.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np
from quadmanip.common.messages import JudgeReport
from quadmanip.common.rotations import quat_to_mat
from quadmanip.sim.world.builder import World
from quadmanip.sim.world.house import DepositRegion

__all__ = [
    "REST_ANGULAR",
    "REST_LINEAR",
    "JudgeResult",
    "judge_data",
    "judge_poses",
]

REST_LINEAR = 0.02  # m/s: slower than this counts as at rest
REST_ANGULAR = 0.3  # rad/s


@dataclass(frozen=True)
class JudgeResult:
    """The verdict, field for field the ``JudgeReport`` message."""

    stamp: float
    trial_time: float
    in_place: list[str] = field(default_factory=list)
    misplaced: list[str] = field(default_factory=list)
    total: int = 0

    def to_message(self) -> JudgeReport:
        """As a ``quadmanip.common.messages.JudgeReport``."""
        return JudgeReport(
            stamp=self.stamp,
            trial_time=self.trial_time,
            in_place=list(self.in_place),
            misplaced=list(self.misplaced),
            total=self.total,
        )


def _inside(
    region: DepositRegion, p: np.ndarray, frames: Mapping[str, tuple[np.ndarray, np.ndarray]]
) -> bool:
    if region.body == "world":
        return region.contains_local(p)
    if region.body not in frames:
        return False
    pos, rot = frames[region.body]
    return region.contains_local(rot.T @ (np.asarray(p, float) - pos))


def _verdict(
    names: Sequence[str],
    positions: np.ndarray,
    moving: Sequence[bool],
    regions: Sequence[DepositRegion],
    place_of: Mapping[str, str],
    frames: Mapping[str, tuple[np.ndarray, np.ndarray]],
    stamp: float,
    trial_time: float,
) -> JudgeResult:
    in_place, misplaced = [], []
    for name, p, mov in zip(names, positions, moving, strict=True):
        place = place_of[name]
        ok = not mov and any(_inside(r, p, frames) for r in regions if r.place == place)
        (in_place if ok else misplaced).append(name)
    return JudgeResult(stamp, trial_time, in_place, misplaced, len(names))


def judge_data(world: World, data: mujoco.MjData, trial_start: float = 0.0) -> JudgeResult:
    """Judge the objects of ``world`` in the simulation state ``data`` (after mj_forward or
    mj_step, so body poses are current); trial time = ``data.time - trial_start``."""
    m = world.model
    positions, moving = [], []
    for name in world.object_names:
        bid = world.object_body_ids[name]
        positions.append(data.xpos[bid].copy())
        adr = m.jnt_dofadr[m.joint(f"obj/{name}/free").id]
        v = data.qvel[adr : adr + 6]
        moving.append(
            bool(np.linalg.norm(v[:3]) > REST_LINEAR or np.linalg.norm(v[3:]) > REST_ANGULAR)
        )
    frames = {}
    for r in world.regions:
        if r.body != "world":
            bid = m.body(r.body).id
            frames[r.body] = (data.xpos[bid].copy(), data.xmat[bid].reshape(3, 3).copy())
    place_of = {n: world.place_of(n) for n in world.object_names}
    return _verdict(
        list(world.object_names),
        np.array(positions).reshape(-1, 3),
        moving,
        world.regions,
        place_of,
        frames,
        float(data.time),
        float(data.time - trial_start),
    )


def judge_poses(
    regions: Sequence[DepositRegion],
    place_of: Mapping[str, str],
    names: Sequence[str],
    positions: np.ndarray,
    orientations: np.ndarray,
    *,
    speeds: Sequence[float] | None = None,
    stamp: float = 0.0,
    trial_time: float = 0.0,
) -> JudgeResult:
    """Judge from pose arrays, e.g. a ``GroundTruthPoses`` message.

    ``names`` may be catalogue names or body names (``obj/<name>``); entries that are region
    bodies (the drawers, ``cabinet/drawer_top``...) give the regions' frames, other entries
    not in ``place_of`` (the robot ``base``) are ignored. ``speeds`` (m/s per entry) decide
    "at rest"; without them every object is taken to be at rest.
    """
    positions = np.asarray(positions, float).reshape(-1, 3)
    orientations = np.asarray(orientations, float).reshape(-1, 4)
    frames = {}
    region_bodies = {r.body for r in regions}
    obj_names, obj_pos, moving = [], [], []
    for i, raw in enumerate(names):
        if raw in region_bodies:
            frames[raw] = (positions[i], quat_to_mat(orientations[i]))
            continue
        name = raw.removeprefix("obj/")
        if name not in place_of:
            continue
        obj_names.append(name)
        obj_pos.append(positions[i])
        moving.append(bool(speeds is not None and speeds[i] > REST_LINEAR))
    return _verdict(
        obj_names,
        np.array(obj_pos).reshape(-1, 3),
        moving,
        regions,
        place_of,
        frames,
        stamp,
        trial_time,
    )
