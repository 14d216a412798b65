"""Rendered probing views of one object, with ground truth for scoring (TEST/BENCH ONLY).

A view is what perception gets while the robot stands in front of an object with its arm
in a probing posture (paper Fig. 5): the gripper camera looking down (``probe_floor`` for
a floor object, ``probe_table`` for one on a table) or, for a tall table object, the front
camera with the arm lifted away (``probe_horizontal``). The scene is the one of the
full-stack grasp trials (:func:`quadmanip.testbench.stack_trials.grasp_scenario`), placed
kinematically (no physics step): the robot stands at its ``home`` keyframe at the
scenario's start pose, the arm at the posture from ``configs/manipulation.toml``.

Besides the RGB-D frame (exactly what the sim publishes: K and the optical-frame pose in
the base frame) a view carries ground truth that only tests and benchmarks may read: the
object's segmentation mask (a MuJoCo segmentation render of the same camera), its 2-D box,
its world pose, the base pose, the supporting surface height and the harness's current
ground-truth grasp (:func:`quadmanip.testbench.manipulation_scenes.grasp_from_poses`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import (
    mat_to_quat,
    quat_from_axis_angle,
    quat_from_yaw,
    quat_mul,
    rot_z,
)
from quadmanip.sim.sensors import CameraConfig, RgbdFrame, RgbdRenderer
from quadmanip.sim.world.builder import World, build_world
from quadmanip.sim.world.house import load_house
from quadmanip.sim.world.objects import Catalogue, load_catalogue
from quadmanip.testbench.manipulation_scenes import GraspSpec, grasp_from_poses
from quadmanip.testbench.perception_trials import side_probe_back
from quadmanip.testbench.stack_trials import GRASP_TABLE, approach_for, grasp_scenario

__all__ = ["ProbeView", "probe_posture", "render_probe_view"]


@dataclass(frozen=True)
class ProbeView:
    """One rendered probing view and its ground truth (world frame unless stated)."""

    name: str
    where: str  # "floor" | "table"
    seed: int
    probing: str  # "vertical" (gripper camera) | "horizontal" (front camera)
    camera: str
    rgb: np.ndarray  # uint8 (H, W, 3)
    depth: np.ndarray  # float32 (H, W), metres, 0 = no return
    K: np.ndarray  # OpenCV intrinsics
    cam_position: np.ndarray  # optical frame origin in the base frame
    cam_orientation: np.ndarray  # [w, x, y, z], base -> optical (x right, y down, z fwd)
    # --- ground truth (tests and benchmarks only) ---
    mask: np.ndarray  # bool (H, W): pixels showing the object
    box: tuple[int, int, int, int] | None  # (u0, v0, u1, v1) pixel box, end exclusive
    obj_position: np.ndarray
    obj_rotation: np.ndarray  # 3x3
    base_position: np.ndarray
    base_rotation: np.ndarray  # 3x3
    surface_z: float  # height of the supporting surface
    gt: GraspSpec  # the harness's ground-truth grasp (base frame)

    def surface_z_base(self) -> float:
        """Supporting surface height in the base frame (at the object; the base may tilt)."""
        p = self.obj_position.copy()
        p[2] = self.surface_z
        return float((self.base_rotation.T @ (p - self.base_position))[2])


def probe_posture(cat: Catalogue, name: str, where: str) -> tuple[str, str, str]:
    """(posture, camera, probing direction) for ``name`` on the floor or on a table."""
    if where == "floor":
        return "probe_floor", rd.GRIPPER_CAMERA, "vertical"
    if approach_for(cat, name, where) == "horizontal":
        return "probe_tall", rd.FRONT_CAMERA, "horizontal"
    return "probe_table", rd.GRIPPER_CAMERA, "vertical"


_POSTURES: dict[str, tuple[np.ndarray, float]] | None = None


def _postures() -> dict[str, tuple[np.ndarray, float]]:
    """Posture name -> (arm joints, trunk pitch) from the manipulation config."""
    global _POSTURES
    if _POSTURES is None:
        from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
        from quadmanip.services.manipulation.config import load_manipulation_config
        from quadmanip.services.manipulation.postures import resolve_postures

        cfg = load_manipulation_config()
        joints = resolve_postures(ArmGeometry.from_description(), cfg)
        _POSTURES = {n: (q, cfg.postures[n].body_pitch) for n, q in joints.items()}
    return _POSTURES


def _stand(world: World, data: mujoco.MjData, arm_q: np.ndarray, pitch: float = 0.0) -> None:
    """Robot standing at its home keyframe where the scenario put it, arm at ``arm_q``,
    the trunk pitched by ``pitch`` (locomotion's sign: negative lifts the nose) about
    the base origin."""
    m = world.model
    home = rd.home_qpos()
    rm = rd.load_mujoco_model()
    adr = m.jnt_qposadr[m.joint(rd.FREE_JOINT).id]
    data.qpos[adr + 2] = home[rd.free_joint_qpos_index(rm) + 2]
    data.qpos[adr + 3 : adr + 7] = quat_mul(
        data.qpos[adr + 3 : adr + 7], quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), pitch)
    )
    for j in rd.LEG_JOINTS:
        data.qpos[m.jnt_qposadr[m.joint(j).id]] = home[rm.jnt_qposadr[rm.joint(j).id]]
    for j, q in zip(rd.ARM_JOINTS, arm_q, strict=True):
        data.qpos[m.jnt_qposadr[m.joint(j).id]] = q
    for j in rd.GRIPPER_JOINTS:  # fingers open: out of the gripper camera's view
        jid = m.joint(j).id
        data.qpos[m.jnt_qposadr[jid]] = m.jnt_range[jid][1]
    mujoco.mj_forward(m, data)


def _box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows, cols = np.any(mask, axis=1), np.any(mask, axis=0)
    if not rows.any():
        return None
    v = np.flatnonzero(rows)
    u = np.flatnonzero(cols)
    return int(u[0]), int(v[0]), int(u[-1]) + 1, int(v[-1]) + 1


def render_object(
    world: World,
    data: mujoco.MjData,
    camera: str,
    name: str,
    camera_config: CameraConfig | None = None,
) -> tuple[RgbdFrame, np.ndarray]:
    """``camera``'s RGB-D frame of ``data`` and the mask of object ``name``'s pixels in it
    (those with a depth return), from a segmentation render of the same camera."""
    renderer = RgbdRenderer(world.model, {camera: camera_config or CameraConfig()})
    try:
        frame = renderer.render(data, camera)
        seg = renderer.render_segmentation(data, camera)
    finally:
        renderer.close()
    geoms = np.flatnonzero(world.model.geom_bodyid == world.object_body_ids[name])
    return frame, np.isin(seg, geoms) & (frame.depth > 0)


def render_probe_view(
    name: str,
    where: str,
    seed: int,
    catalogue: Catalogue | None = None,
    camera_config: CameraConfig | None = None,
    standoff: float | None = None,
    turn: float | None = None,
) -> ProbeView:
    """Render the probing view of object ``name`` on the ``where`` ('floor'/'table') of the
    grasp trial ``seed``, with ground truth for scoring. A horizontal probe stands
    ``standoff`` (default: the task's ``side_probe_back``) behind the grasp stance.
    ``turn`` (rad) sets the object's yaw to the robot's heading plus it (default: the
    trial's random yaw)."""
    if standoff is None:
        standoff = side_probe_back()
    cat = catalogue or load_catalogue()
    house = load_house()
    scn = grasp_scenario(name, where, seed, house, cat)
    if turn is not None and scn.robot_start is not None:
        yaw = math.radians(scn.robot_start[2]) + turn
        pose = dataclasses.replace(scn.objects[0], quat=tuple(quat_from_yaw(yaw).tolist()))
        scn = dataclasses.replace(scn, objects=(pose,))
    posture, camera, probing = probe_posture(cat, name, where)
    if probing == "horizontal" and scn.robot_start is not None:
        # the front camera sits below a table top: it sees the object only from farther
        # back (the paper's "adjusts its position" before horizontal probing)
        x, y, yaw = scn.robot_start
        h = math.radians(yaw)
        back = (x - standoff * math.cos(h), y - standoff * math.sin(h), yaw)
        scn = dataclasses.replace(scn, robot_start=back)
    world = build_world(scn, house=house, catalogue=cat)
    data = world.initial_data()
    _stand(world, data, *_postures()[posture])
    frame, mask = render_object(world, data, camera, name, camera_config)
    bid = world.object_body_ids[name]
    base = world.model.body(rd.BASE_BODY).id
    base_pos = data.xpos[base].copy()
    # the level body frame (the heading only), as the node uses (perception.frames
    # .level_frame) and the live trials score in: a pitched trunk's probe is not tilted
    r_wb = data.xmat[base].reshape(3, 3)
    base_rot = rot_z(math.atan2(r_wb[1, 0], r_wb[0, 0]))
    tilt = base_rot.T @ r_wb  # level <- base
    obj_pos = data.xpos[bid].copy()
    obj_rot = data.xmat[bid].reshape(3, 3).copy()
    surface_z = 0.0
    if where == "table":
        surface_z = next(t for t in house.tables if t.name == GRASP_TABLE).height
    gt = grasp_from_poses(
        cat, name, obj_pos, obj_rot, base_pos, base_rot, surface_z, approach_for(cat, name, where)
    )
    return ProbeView(
        name=name,
        where=where,
        seed=seed,
        probing=probing,
        camera=camera,
        rgb=frame.rgb,
        depth=frame.depth,
        K=frame.K,
        cam_position=tilt @ frame.position,
        cam_orientation=quat_mul(mat_to_quat(tilt), frame.orientation),
        mask=mask,
        box=_box(mask),
        obj_position=obj_pos,
        obj_rotation=obj_rot,
        base_position=base_pos,
        base_rotation=base_rot,
        surface_z=surface_z,
        gt=gt,
    )
