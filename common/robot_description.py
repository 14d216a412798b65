"""The robot description: names, loaders and facts read from the one MJCF.

`configs/robot/quadmanip_dog.xml` is the single source of truth for MuJoCo and pinocchio
(docs/architecture.md, "One source for every fact"). This module gives every service the same names, loads the
model for either library, maps MuJoCo's generalized coordinates to pinocchio's, and reads
dimensions, masses and limits from the model so nobody copies Table 1/Table 2 constants.

Joint order (arrays of 16): FL(abad, hip, knee), FR, RL, RR, then arm_j1..arm_j4.
Actuator order (17): those 16 joints, then the gripper (a force on the `gripper_gap`
tendon, whose length is the finger gap in metres). The layout (names, counts, slices) is
defined once in :mod:`quadmanip.common.joint_layout` and re-exported here.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from quadmanip.common.joint_layout import (  # noqa: F401 - re-exported
    ACTUATORS,
    ARM_JOINTS,
    ARM_SLICE,
    GRIPPER_ACTUATOR,
    JOINTS,
    JOINTS_PER_LEG,
    LEG_JOINT_KINDS,
    LEG_JOINTS,
    LEG_NAMES,
    LEG_SLICE,
    N_ARM_JOINTS,
    N_JOINTS,
    N_LEG_JOINTS,
    N_LEGS,
    leg_slice,
)
from quadmanip.common.rotations import quat_to_mat
from quadmanip.paths import CONFIG_DIR

if TYPE_CHECKING:  # pinocchio is imported lazily: it is slow to import and only some need it
    import pinocchio as pin

ROBOT_XML: Path = CONFIG_DIR / "robot" / "quadmanip_dog.xml"

# --- names (contracts; see docs/conventions.md and docs/robot.md) ------------------------
BASE_BODY = "base"
FREE_JOINT = "base_free"
TRUNK_GEOM = "trunk"
# The joint layout (LEG_NAMES, LEG_JOINTS, ARM_JOINTS, JOINTS, ACTUATORS, the counts and
# slices) is imported from quadmanip.common.joint_layout above and re-exported.
GRIPPER_JOINTS: tuple[str, ...] = ("gripper_left", "gripper_right")
GRIPPER_TENDON = "gripper_gap"

FOOT_SITES: tuple[str, ...] = tuple(f"{leg}_foot" for leg in LEG_NAMES)
FOOT_GEOMS: tuple[str, ...] = FOOT_SITES
"""Foot collision spheres carry the same names as the foot sites (sphere centres)."""
HIP_BODIES: tuple[str, ...] = tuple(f"{leg}_abad_link" for leg in LEG_NAMES)
THIGH_BODIES: tuple[str, ...] = tuple(f"{leg}_thigh" for leg in LEG_NAMES)
CALF_BODIES: tuple[str, ...] = tuple(f"{leg}_calf" for leg in LEG_NAMES)
ARM_BASE_BODY = "arm_base"
ARM_BODIES: tuple[str, ...] = ("arm_link1", "arm_link2", "arm_link3", "arm_link4")
FINGER_BODIES: tuple[str, ...] = ("gripper_left_finger", "gripper_right_finger")
FINGER_PAD_GEOMS: tuple[str, ...] = ("gripper_left_pad", "gripper_right_pad")

IMU_SITE = "imu"
IMU_SENSORS: dict[str, str] = {
    "orientation": "imu_quat",
    "angular_velocity": "imu_gyro",
    "linear_acceleration": "imu_acc",
}
LIDAR_SITE = "lidar"
GRIPPER_TCP_SITE = "gripper_tcp"
#: Largest forward lean (rad) of the gripper in a vertical grasp (``GraspGoal.tilt``, so the
#: pads lie flat on a flared wall): what manipulation executes; perception clamps a
#: steeper wall's lean to it.
GRASP_MAX_TILT = 0.8
#: Deepest (m) the tool centre goes behind a box's near face in a horizontal grasp. The pads
#: reach 2 cm either side of the tool centre, so at 3 cm they lie wholly on the box while
#: the fingers pass as little of a long, turned box as they can: a grasp at the centre of a
#: cracker box standing 16 cm deep slid the fingers 10 cm along it, and a turn of a few
#: degrees made a finger push the box off the grasp (half of the table trials).
HORIZONTAL_GRASP_DEPTH = 0.03
FRONT_CAMERA = "front_camera"
GRIPPER_CAMERA = "gripper_camera"
CAMERAS: tuple[str, ...] = (FRONT_CAMERA, GRIPPER_CAMERA)
CAMERA_OPTICAL_SITES: dict[str, str] = {
    FRONT_CAMERA: "front_camera_optical",
    GRIPPER_CAMERA: "gripper_camera_optical",
}
"""Sites at each camera in OpenCV's optical convention (x right, y down, z forward)."""
MUJOCO_CAMERA_TO_OPTICAL: np.ndarray = np.diag([1.0, -1.0, -1.0])
"""R such that R_world_optical = R_world_mujococam @ this (MuJoCo cameras look along -z)."""

ROBOT_VISUAL_GROUP = 2
"""Geom group of visual-only robot geoms (no contacts, no mass); rendered by cameras."""
ROBOT_COLLISION_GROUP = 3
"""Geom group of robot collision primitives; hidden in renders by default."""

HOME_KEY = "home"
LYING_KEY = "lying"
VELOCITY_LIMITS_NUMERIC = "velocity_limits"


# --- MuJoCo --------------------------------------------------------------------------------
def load_mujoco_model(xml: Path | str = ROBOT_XML) -> mujoco.MjModel:
    """Compile the robot alone (no floor) as MuJoCo sees it."""
    return mujoco.MjModel.from_xml_path(str(xml))


def robot_spec(xml: Path | str = ROBOT_XML) -> mujoco.MjSpec:
    """The robot as an editable MjSpec, for world builders that add a scene around it."""
    return mujoco.MjSpec.from_file(str(xml))


def robot_only_with_floor(
    xml: Path | str = ROBOT_XML, floor_friction: float = 1.0
) -> mujoco.MjModel:
    """The robot on an infinite flat floor with a light, for controller tests.

    The floor lies in geom group 0 (the world's group) at z = 0. Start from a keyframe with
    ``mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)``; never overwrite
    ``qpos0`` (MuJoCo measures hinge angles from it).
    """
    spec = robot_spec(xml)
    spec.worldbody.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 0.05],
        friction=[floor_friction, 0.005, 0.0001],
        rgba=[0.6, 0.6, 0.6, 1.0],
        group=0,
    )
    spec.worldbody.add_light(
        pos=[0.0, 0.0, 3.0],
        dir=[0.0, 0.0, -1.0],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        castshadow=False,
    )
    return spec.compile()


def _ids(model: mujoco.MjModel, obj: mujoco.mjtObj, names: tuple[str, ...]) -> np.ndarray:
    ids = [mujoco.mj_name2id(model, obj, n) for n in names]
    missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
    if missing:
        raise KeyError(f"robot description lacks {obj.name} {missing}")
    return np.asarray(ids, dtype=np.int64)


def joint_qpos_indices(model: mujoco.MjModel, names: tuple[str, ...] = JOINTS) -> np.ndarray:
    """qpos addresses of the named 1-DOF joints (default: the 16 in wire order)."""
    return model.jnt_qposadr[_ids(model, mujoco.mjtObj.mjOBJ_JOINT, names)].copy()


def joint_dof_indices(model: mujoco.MjModel, names: tuple[str, ...] = JOINTS) -> np.ndarray:
    """qvel/dof addresses of the named 1-DOF joints (default: the 16 in wire order)."""
    return model.jnt_dofadr[_ids(model, mujoco.mjtObj.mjOBJ_JOINT, names)].copy()


def actuator_indices(model: mujoco.MjModel, names: tuple[str, ...] = ACTUATORS) -> np.ndarray:
    """Actuator ids in `ACTUATORS` order (16 joint motors then the gripper)."""
    return _ids(model, mujoco.mjtObj.mjOBJ_ACTUATOR, names)


def free_joint_qpos_index(model: mujoco.MjModel) -> int:
    """qpos address of the base free joint (position xyz, then quaternion wxyz)."""
    return int(model.jnt_qposadr[_ids(model, mujoco.mjtObj.mjOBJ_JOINT, (FREE_JOINT,))[0]])


@lru_cache(maxsize=1)
def _robot_model_cached() -> mujoco.MjModel:
    return load_mujoco_model()


def _model(model: mujoco.MjModel | None) -> mujoco.MjModel:
    return _robot_model_cached() if model is None else model


def home_qpos(model: mujoco.MjModel | None = None) -> np.ndarray:
    """MuJoCo qpos of the `home` keyframe: standing, trunk centre 0.30 m up, arm stowed."""
    return _model(model).key(HOME_KEY).qpos.copy()


def lying_qpos(model: mujoco.MjModel | None = None) -> np.ndarray:
    """MuJoCo qpos of the `lying` keyframe (the sim's initial pose; stand-up starts here)."""
    return _model(model).key(LYING_KEY).qpos.copy()


def home_joint_positions(model: mujoco.MjModel | None = None) -> np.ndarray:
    """The 16 joint angles of `home` in wire order (what a standing controller holds)."""
    m = _model(model)
    return m.key(HOME_KEY).qpos[joint_qpos_indices(m)].copy()


def lying_joint_positions(model: mujoco.MjModel | None = None) -> np.ndarray:
    """The 16 joint angles of `lying` in wire order."""
    m = _model(model)
    return m.key(LYING_KEY).qpos[joint_qpos_indices(m)].copy()


def leg_joint_limits(
    model: mujoco.MjModel | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, upper, torque limit) of the 12 leg joints in wire order: the joint ranges
    (rad) and the motors' ``ctrlrange`` times gear (N m)."""
    m = _model(model)
    lo, hi, tau = [], [], []
    for name in LEG_JOINTS:
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        lo.append(float(m.jnt_range[jid, 0]))
        hi.append(float(m.jnt_range[jid, 1]))
        act = [
            a for a in range(m.nu)
            if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and m.actuator_trnid[a, 0] == jid
        ]  # fmt: skip
        if not act:
            raise KeyError(f"no motor drives leg joint {name!r}")
        a = act[0]
        tau.append(float(np.max(np.abs(m.actuator_ctrlrange[a])) * abs(m.actuator_gear[a, 0])))
    return np.array(lo), np.array(hi), np.array(tau)


def arm_dimensions(model: mujoco.MjModel | None = None) -> dict[str, float]:
    """d1..d5 of eq. (1) / Table 2, read from the body offsets of the compiled model.

    d1 = arm_base -> arm_j1 (z), d2 = arm_j1 -> arm_j2 (z), d3 and d4 = arm_j2 -> arm_j3
    (z and x), d5 = wrist -> gripper_tcp (x).
    """
    m = _model(model)
    link1, link2, link3 = (m.body(n).pos for n in ARM_BODIES[:3])
    tcp = m.site(GRIPPER_TCP_SITE).pos
    return {
        "d1": float(link1[2]),
        "d2": float(link2[2]),
        "d3": float(link3[2]),
        "d4": float(link3[0]),
        "d5": float(tcp[0]),
    }


def tcp_in_gripper_camera(model: mujoco.MjModel | None = None) -> np.ndarray:
    """Position of the gripper's tool centre in the gripper camera's optical frame (m):
    where a held object is, for whoever knows only the camera's pose. Both sites ride the
    same link, so the offset is constant."""
    m = _model(model)
    cam, tcp = m.site(CAMERA_OPTICAL_SITES[GRIPPER_CAMERA]), m.site(GRIPPER_TCP_SITE)
    if int(cam.bodyid[0]) != int(tcp.bodyid[0]):
        raise ValueError("the gripper camera and the tool centre ride different links")
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, cam.quat)
    return r.reshape(3, 3).T @ (tcp.pos - cam.pos)


def arm_mount(model: mujoco.MjModel | None = None) -> np.ndarray:
    """Position of the `arm_base` body in the base frame (m)."""
    return _model(model).body(ARM_BASE_BODY).pos.copy()


@dataclass(frozen=True)
class LegGeometry:
    """Leg and trunk dimensions (m) read from the model; Table 1 in `docs/robot.md`."""

    trunk_length: float
    trunk_width: float
    trunk_height: float
    hip_positions: np.ndarray
    """(4, 3) abduction-axis origins in the base frame, leg order FL, FR, RL, RR."""
    abad_offsets: np.ndarray
    """(4,) signed lateral offset from the abduction axis to the thigh plane."""
    thigh_length: float
    calf_length: float
    foot_radius: float


def leg_geometry(model: mujoco.MjModel | None = None) -> LegGeometry:
    """Trunk box size and leg link lengths as compiled (thigh/calf from body offsets)."""
    m = _model(model)
    size = m.geom(TRUNK_GEOM).size
    hips = np.array([m.body(b).pos for b in HIP_BODIES])
    abad = np.array([m.body(b).pos[1] for b in THIGH_BODIES])
    thigh = {-float(m.body(b).pos[2]) for b in CALF_BODIES}
    calf = {-float(m.site(s).pos[2]) for s in FOOT_SITES}
    radius = {float(m.geom(g).size[0]) for g in FOOT_GEOMS}
    if len(thigh) != 1 or len(calf) != 1 or len(radius) != 1:
        raise ValueError("legs of the robot description differ in length")
    return LegGeometry(
        trunk_length=2.0 * float(size[0]),
        trunk_width=2.0 * float(size[1]),
        trunk_height=2.0 * float(size[2]),
        hip_positions=hips,
        abad_offsets=abad,
        thigh_length=thigh.pop(),
        calf_length=calf.pop(),
        foot_radius=radius.pop(),
    )


def _subtree_mass(m: mujoco.MjModel, body: str) -> float:
    return float(m.body_subtreemass[m.body(body).id])


@dataclass(frozen=True)
class RobotInfo:
    """Masses and limits read from the model (see docs/robot.md for the reasons)."""

    total_mass: float
    trunk_mass: float
    leg_mass: float
    """All four legs below the abduction joints."""
    arm_mass: float
    """Arm incl. its mount pedestal and the gripper."""
    torque_limits: np.ndarray
    """(17,) |torque| limits in N·m (N for the gripper), `ACTUATORS` order."""
    velocity_limits: np.ndarray
    """(17,) speed limits in rad/s (m/s of the gap for the gripper), `ACTUATORS` order."""
    joint_ranges: dict[str, tuple[float, float]]
    """Position limits of the 16 joints and the two finger joints."""
    armature: np.ndarray
    """(16,) reflected rotor inertia of the joints in wire order."""
    damping: np.ndarray
    """(16,) viscous joint damping in wire order (N·m·s/rad)."""
    gripper_max_gap: float
    gripper_max_force: float


def robot_info(model: mujoco.MjModel | None = None) -> RobotInfo:
    """Gather masses and limits from the compiled model."""
    m = _model(model)
    legs = sum(_subtree_mass(m, b) for b in HIP_BODIES)
    arm = _subtree_mass(m, ARM_BASE_BODY)
    total = _subtree_mass(m, BASE_BODY)
    act = actuator_indices(m)
    torque = np.abs(m.actuator_ctrlrange[act]).max(axis=1)
    jids = _ids(m, mujoco.mjtObj.mjOBJ_JOINT, JOINTS + GRIPPER_JOINTS)
    ranges = {
        n: (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1]))
        for n, j in zip(JOINTS + GRIPPER_JOINTS, jids, strict=True)
    }
    dofs = joint_dof_indices(m)
    vel = np.asarray(m.numeric(VELOCITY_LIMITS_NUMERIC).data, dtype=float).copy()
    if vel.shape != (len(ACTUATORS),):
        raise ValueError(f"numeric {VELOCITY_LIMITS_NUMERIC} must hold {len(ACTUATORS)} values")
    max_gap = sum(ranges[j][1] for j in GRIPPER_JOINTS)
    return RobotInfo(
        total_mass=total,
        trunk_mass=float(m.body_mass[m.body(BASE_BODY).id]),
        leg_mass=legs,
        arm_mass=arm,
        torque_limits=torque,
        velocity_limits=vel,
        joint_ranges=ranges,
        armature=m.dof_armature[dofs].copy(),
        damping=m.dof_damping[dofs].copy(),
        gripper_max_gap=float(max_gap),
        gripper_max_force=float(torque[-1]),
    )


# --- pinocchio -----------------------------------------------------------------------------
def load_pinocchio_model(xml: Path | str = ROBOT_XML) -> tuple[pin.Model, pin.Data]:
    """Build the same robot in pinocchio from the same MJCF (free-flyer base).

    `pin.buildModelFromMJCF` turns the MJCF `freejoint` into a `JointModelFreeFlyer` named
    `base_free`; sites become operational frames with the same names (feet, tcp, imu,
    lidar, camera optical sites). Its configuration is [x y z qx qy qz qw, joints...]:
    use `mujoco_qpos_to_pinocchio` to convert a MuJoCo qpos.
    """
    import pinocchio as pin

    model = pin.buildModelFromMJCF(str(xml))
    if model.joints[1].shortname() != "JointModelFreeFlyer":
        raise ValueError("expected pinocchio to parse base_free as a free-flyer joint")
    return model, model.createData()


def _pin_qpos_map(pmodel: pin.Model, mmodel: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (pinocchio q index, MuJoCo qpos index) of the 1-DOF joints."""
    pin_idx, mj_idx = [], []
    for jid in range(2, pmodel.njoints):
        name = pmodel.names[jid]
        pin_idx.append(pmodel.idx_qs[jid])
        mj_idx.append(mmodel.jnt_qposadr[mmodel.joint(name).id])
    return np.asarray(pin_idx), np.asarray(mj_idx)


@lru_cache(maxsize=1)
def _default_maps() -> tuple[np.ndarray, np.ndarray]:
    pmodel, _ = load_pinocchio_model()
    return _pin_qpos_map(pmodel, _robot_model_cached())


@lru_cache(maxsize=1)
def _robot_joint_names() -> tuple[str, ...]:
    m = _robot_model_cached()
    return tuple(m.joint(j).name for j in range(m.njnt))


def robot_qpos(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """The robot's own 25 coordinates, in robot-only order, from a bigger model's qpos.

    A world model (house, objects) holds the robot's joints under the same names; this
    gathers them so `mujoco_qpos_to_pinocchio` and the keyframe helpers apply.
    """
    ref = _robot_model_cached()
    out = np.empty(ref.nq)
    for name in _robot_joint_names():
        src, dst = model.joint(name), ref.joint(name)
        n = 7 if dst.type[0] == mujoco.mjtJoint.mjJNT_FREE else 1
        out[dst.qposadr[0] : dst.qposadr[0] + n] = qpos[src.qposadr[0] : src.qposadr[0] + n]
    return out


def mujoco_qpos_to_pinocchio(qpos: np.ndarray) -> np.ndarray:
    """MuJoCo qpos [p, q_wxyz, joints] -> pinocchio q [p, q_xyzw, joints] (default robot).

    The joint blocks share the same depth-first order in both libraries (checked by name
    once); only the free-flyer quaternion is reordered.
    """
    qpos = np.asarray(qpos, dtype=float)
    pin_idx, mj_idx = _default_maps()
    q = np.empty_like(qpos)
    q[0:3] = qpos[0:3]
    q[3:6] = qpos[4:7]
    q[6] = qpos[3]
    q[pin_idx] = qpos[mj_idx]
    return q


def pinocchio_q_to_mujoco(q: np.ndarray) -> np.ndarray:
    """Inverse of `mujoco_qpos_to_pinocchio`."""
    q = np.asarray(q, dtype=float)
    pin_idx, mj_idx = _default_maps()
    qpos = np.empty_like(q)
    qpos[0:3] = q[0:3]
    qpos[3] = q[6]
    qpos[4:7] = q[3:6]
    qpos[mj_idx] = q[pin_idx]
    return qpos


def mujoco_qvel_to_pinocchio(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """MuJoCo qvel -> pinocchio v.

    MuJoCo's free joint velocity is [linear velocity of the base origin in the world
    frame, angular velocity in the base frame]; pinocchio's free flyer uses both in the
    base (local) frame. Joint velocities keep their order (same tree traversal).
    """
    qpos = np.asarray(qpos, dtype=float)
    v = np.asarray(qvel, dtype=float).copy()
    v[0:3] = quat_to_mat(qpos[3:7]).T @ v[0:3]
    return v
