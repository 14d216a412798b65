"""``build_world``: house + scenario objects + robot as one MuJoCo model.

The world is built *into* the robot description's own spec
(``configs/robot/quadmanip_dog.xml``, loaded as is, never copied by hand), so MuJoCo and
pinocchio keep one source of truth, the robot keeps its names, defaults, keyframes and
physics options (1 kHz timestep, implicit-fast integrator, elliptic cones, impratio), and
its free joint stays at qpos[0:7]. The base body and the keyframes are moved to the start
pose in the house, so ``mj_resetDataKeyframe(model, data, model.key("home").id)`` stands
the robot at its start with the objects at their placements. The scenario's object poses are the model's initial poses and are applied once
by :meth:`World.initial_data`; after that only physics moves anything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import quat_from_yaw, quat_mul
from quadmanip.sim.world.house import (
    DepositRegion,
    HouseConfig,
    Surface,
    add_obstacle,
    build_house,
    load_house,
)
from quadmanip.sim.world.objects import Catalogue, add_object, load_catalogue, pad_contacts

if TYPE_CHECKING:
    from quadmanip.sim.scenarios import Scenario

__all__ = ["World", "build_world"]


@dataclass
class World:
    """A compiled world and everything needed to use it by name."""

    model: mujoco.MjModel
    spec: mujoco.MjSpec
    house: HouseConfig
    catalogue: Catalogue
    scenario: Scenario | None
    object_names: tuple[str, ...]
    object_body_ids: dict[str, int]
    regions: tuple[DepositRegion, ...]
    surfaces: tuple[Surface, ...]
    drawer_joints: dict[str, str]
    drawer_bodies: dict[str, str]
    drawer_handles: dict[str, str]
    cameras: tuple[str, ...]
    robot: bool
    robot_start: tuple[float, float, float]  # x, y, yaw (rad) in the world
    start_keyframe: str | None = None
    _robot_qpos: dict[str, float] = field(default_factory=dict, repr=False)

    @property
    def table_surfaces(self) -> tuple[Surface, ...]:
        """The table tops objects may lie on (the deposit table is not one)."""
        return tuple(s for s in self.surfaces if s.kind == "table")

    def place_of(self, name: str) -> str:
        """The deposit place an object belongs in."""
        return self.catalogue.place_of(name)

    def regions_for(self, place: str) -> tuple[DepositRegion, ...]:
        """All judge regions of a deposit place (the drawer place has one per drawer)."""
        return tuple(r for r in self.regions if r.place == place)

    def initial_data(self) -> mujoco.MjData:
        """A fresh ``MjData`` in the scenario's initial state: objects at their placements,
        drawers closed, the robot at its start pose in its start keyframe, at rest."""
        m = self.model
        data = mujoco.MjData(m)
        if self.robot:
            x, y, yaw = self.robot_start
            for jname, value in self._robot_qpos.items():
                if "[" in jname:
                    continue
                data.qpos[m.jnt_qposadr[m.joint(jname).id]] = value
            adr = m.jnt_qposadr[m.joint(rd.FREE_JOINT).id]
            key_quat = np.array(self._robot_qpos_base[3:7])
            q = quat_mul(quat_from_yaw(yaw), key_quat)
            data.qpos[adr : adr + 3] = [x, y, self._robot_qpos_base[2]]
            data.qpos[adr + 3 : adr + 7] = q
        if self.scenario is not None:
            for p in self.scenario.objects:
                adr = m.jnt_qposadr[m.joint(f"obj/{p.name}/free").id]
                data.qpos[adr : adr + 3] = p.position
                data.qpos[adr + 3 : adr + 7] = p.quat
        for jname in self.drawer_joints.values():
            data.qpos[m.jnt_qposadr[m.joint(jname).id]] = 0.0
        data.qvel[:] = 0.0
        mujoco.mj_forward(m, data)
        return data

    @property
    def _robot_qpos_base(self) -> list[float]:
        return [self._robot_qpos[f"{rd.FREE_JOINT}[{i}]"] for i in range(7)]


def _copy_physics_options(dst: mujoco.MjSpec, src: mujoco.MjSpec) -> None:
    dst.option.timestep = src.option.timestep
    dst.option.integrator = src.option.integrator
    dst.option.cone = src.option.cone
    dst.option.impratio = src.option.impratio


def _place_robot(spec: mujoco.MjSpec, x: float, y: float, yaw: float, key: str | None) -> None:
    """Move the robot's base body (free-joint reference pose) and every keyframe's base pose
    to the start position and heading in the house."""
    rm = rd.load_mujoco_model()
    adr = rd.free_joint_qpos_index(rm)
    yaw_q = quat_from_yaw(yaw)

    def turned(q: np.ndarray) -> list[float]:
        return list(quat_mul(yaw_q, q))

    ref = rm.key(key).qpos if key else rm.qpos0
    base = spec.body(rd.BASE_BODY)
    base.pos = [x, y, float(ref[adr + 2])]
    base.quat = turned(ref[adr + 3 : adr + 7])
    for k in spec.keys:
        q = np.array(k.qpos, float)
        if q.size >= adr + 7:
            q[adr : adr + 2] = [x, y]
            q[adr + 3 : adr + 7] = turned(q[adr + 3 : adr + 7])
            k.qpos = list(q)


def _start_keyframe(house: HouseConfig) -> tuple[str | None, dict[str, float]]:
    """The first configured start keyframe the robot has, as {joint: value} (free joint
    entries as ``base_free[i]``)."""
    rm = rd.load_mujoco_model()
    names = [rm.key(i).name for i in range(rm.nkey)]
    chosen = next((k for k in house.robot_start.keyframes if k in names), None)
    qpos = rm.key(chosen).qpos if chosen else rm.qpos0
    out: dict[str, float] = {}
    for j in range(rm.njnt):
        jname = rm.joint(j).name
        adr = rm.jnt_qposadr[j]
        if rm.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            for i in range(7):
                out[f"{jname}[{i}]"] = float(qpos[adr + i])
        elif rm.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            continue
        else:
            out[jname] = float(qpos[adr])
    return chosen, out


CAMERA_NEAR_CLIP_M = 0.01
CAMERA_FAR_CLIP_M = 30.0


def build_world(
    scenario: Scenario | None = None,
    robot: bool = True,
    house: HouseConfig | None = None,
    catalogue: Catalogue | None = None,
) -> World:
    """Compile the house with the scenario's objects (and the robot unless ``robot=False``).

    Objects start at their scenario placements, the robot at the scenario's ``robot_start``
    (else the house's); a scenario of ``None`` gives the empty house.
    """
    house = house or load_house()
    catalogue = catalogue or load_catalogue()
    x, y = house.robot_start.position
    yaw = math.radians(house.robot_start.yaw)
    if scenario is not None and scenario.robot_start is not None:
        x, y, yaw_deg = scenario.robot_start
        yaw = math.radians(yaw_deg)
    key_name, robot_qpos = (None, {})
    if robot:
        key_name, robot_qpos = _start_keyframe(house)
        spec = rd.robot_spec()  # its <option> (timestep, integrator, ...) as described
        _place_robot(spec, x, y, yaw, key_name)
    else:
        spec = mujoco.MjSpec()
        _copy_physics_options(spec, rd.robot_spec())
    spec.modelname = "quadmanip_house"
    layout = build_house(spec, house)

    names: list[str] = []
    if scenario is not None:
        for b in scenario.obstacles:
            add_obstacle(spec, b.name, b.center, b.size)
        pads = pad_contacts(spec, catalogue)  # pad x object pairs (None without the robot)
        for p in scenario.objects:
            add_object(
                spec.worldbody,
                p.name,
                catalogue.objects[p.name],
                p.position,
                p.quat,
                catalogue.contact,
                pads,
            )
            names.append(p.name)

    model = spec.compile()
    # MuJoCo scales the clip planes by the model extent (~14 m for the house), which would
    # put the near plane 14 cm in front of the gripper camera; set them in metres instead.
    model.vis.map.znear = CAMERA_NEAR_CLIP_M / model.stat.extent
    model.vis.map.zfar = CAMERA_FAR_CLIP_M / model.stat.extent
    body_ids = {n: model.body(f"obj/{n}").id for n in names}
    return World(
        model=model,
        spec=spec,
        house=house,
        catalogue=catalogue,
        scenario=scenario,
        object_names=tuple(names),
        object_body_ids=body_ids,
        regions=layout.regions,
        surfaces=layout.surfaces,
        drawer_joints=dict(layout.drawer_joints),
        drawer_bodies=dict(layout.drawer_bodies),
        drawer_handles=dict(layout.drawer_handles),
        cameras=layout.cameras,
        robot=robot,
        robot_start=(x, y, yaw),
        start_keyframe=key_name,
        _robot_qpos=robot_qpos,
    )
