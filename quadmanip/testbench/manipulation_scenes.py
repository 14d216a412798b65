"""In-process MuJoCo harness for the manipulation primitives (TEST AND BENCHMARK ONLY).

This is scaffolding, not part of the service: it reads ground truth (object poses) to
hand the primitives grasp poses, the way perception will later. It never moves anything
except through physics:

* the arm and the gripper are driven by the simulator's own actuator layer
  (:class:`quadmanip.sim.actuators.ActuatorLayer`) from the primitives' trajectories;
* the legs are held by the same actuator layer's PD at standing joint targets, as a
  stand-in for the locomotion service. A body-pose request (moveCOM, crouch) is executed
  by re-solving the leg joint targets with the feet kept where they stand (numeric
  foot-position IK on the description), moved smoothly over ``body_move_time``, plus a
  static gravity feed-forward. When locomotion's body-pose interface is available, the
  integration tests use it instead.

Objects come from the sim's catalogue (``quadmanip.sim.world.objects``); a scene is the
robot on a floor with optional table slabs and deposit boxes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import quat_from_yaw, quat_to_mat
from quadmanip.services.manipulation.gravity import GravityCompensator
from quadmanip.services.manipulation.primitive import (
    ArmCommand,
    BodyPoseRequest,
    Command,
    GripperCmd,
    Observation,
    Primitive,
)
from quadmanip.sim.actuators import ActuatorConfig, ActuatorLayer
from quadmanip.sim.world.objects import add_object, load_catalogue, pad_contacts

__all__ = [
    "grasp_from_poses",
    "plan_grasp_from_ground_truth",
    "Box",
    "GraspSpec",
    "PlacedObject",
    "SimHarness",
    "container_boxes",
    "container_inner",
    "drawer_mouth",
    "drawer_place_world",
    "drawer_world",
    "grasp_from_ground_truth",
    "in_region",
    "resting_in_box",
    "table_boxes",
]

FEET = rd.FOOT_SITES


@dataclass(frozen=True)
class Box:
    """A static box (table top, tray wall, drawer body...) in world coordinates."""

    name: str
    center: tuple[float, float, float]
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.55, 0.4, 0.25, 1.0)
    friction: float = 0.8


@dataclass(frozen=True)
class PlacedObject:
    """A catalogue object at a world pose (z of its bounding-box centre)."""

    name: str
    pos: tuple[float, float, float]
    yaw: float = 0.0
    quat: tuple[float, float, float, float] | None = None


def _quat(o: PlacedObject) -> tuple[float, float, float, float]:
    if o.quat is not None:
        return o.quat
    return tuple(quat_from_yaw(o.yaw).tolist())  # type: ignore[return-value]


@dataclass
class _BodyMotion:
    start: np.ndarray
    goal: np.ndarray
    t0: float
    duration: float


@dataclass
class HarnessLog:
    """Per-tick samples the tests inspect (robot time, TCP, object heights...)."""

    t: list[float] = field(default_factory=list)
    q_arm: list[np.ndarray] = field(default_factory=list)


class SimHarness:
    """Robot + floor + boxes + objects in MuJoCo, stepped with the actuator layer."""

    def __init__(
        self,
        objects: Sequence[PlacedObject] = (),
        boxes: Sequence[Box] = (),
        control_rate: float = 500.0,
        body_move_time: float = 0.8,
        leg_kp: float = 180.0,
        leg_kd: float = 4.0,
        world: object | None = None,
    ) -> None:
        """Builds robot + floor + ``boxes`` + ``objects``, or uses a ``world`` from
        :func:`quadmanip.sim.world.build_world` (the house) as it is."""
        cat = load_catalogue()
        self.catalogue = cat
        self.world = world
        if world is not None:
            self.model = world.model  # type: ignore[attr-defined]
            self.data = world.initial_data()  # type: ignore[attr-defined]
            # stand at the start pose (the house may start the robot lying down)
            key = self.model.key("home").id
            saved = self.data.qpos.copy()
            mujoco.mj_resetDataKeyframe(self.model, self.data, key)
            robot = rd.free_joint_qpos_index(self.model) + np.arange(rd.load_mujoco_model().nq)
            keep = np.ones(self.model.nq, dtype=bool)
            keep[robot] = False
            self.data.qpos[keep] = saved[keep]
            objects = ()
        else:
            self.model = self._build(objects, boxes)
            self.data = mujoco.MjData(self.model)
            home = rd.home_qpos()
            self.data.qpos[: len(home)] = home
        m, d = self.model, self.data
        for o in objects:
            j = m.joint(f"obj/{o.name}/free")
            adr = j.qposadr[0]
            d.qpos[adr : adr + 3] = o.pos
            d.qpos[adr + 3 : adr + 7] = _quat(o)
        mujoco.mj_forward(m, d)
        self.act = ActuatorLayer(
            m, ActuatorConfig(), rd.LEG_JOINTS, rd.ARM_JOINTS, rd.GRIPPER_JOINTS
        )
        self.substeps = max(1, round(1.0 / (control_rate * m.opt.timestep)))
        self.base_id = m.body("base").id
        # leg stand-in
        self._kin = mujoco.MjData(m)
        self._leg_q = d.qpos[self.act.legs.qpos].copy()
        self._feet_world = np.array([d.site(f).xpos.copy() for f in FEET])
        self._base_home = d.qpos[:3].copy()
        self._base_quat = d.qpos[3:7].copy()
        self.leg_kp = leg_kp
        self.leg_kd = leg_kd
        self.body_move_time = body_move_time
        self._body_offset = np.zeros(3)
        self._motion: _BodyMotion | None = None
        self._tau_ff = self._gravity_ff(self._leg_q)
        self._send_legs()
        self.log = HarnessLog()
        self.object_names = (
            list(world.object_names) if world is not None else [o.name for o in objects]  # type: ignore[attr-defined]
        )
        self.gravity = GravityCompensator()

    def _build(self, objects: Sequence[PlacedObject], boxes: Sequence[Box]) -> mujoco.MjModel:
        spec = rd.robot_spec()
        spec.worldbody.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[0.0, 0.0, 0.05],
            friction=[1.0, 0.005, 0.0001],
            rgba=[0.6, 0.6, 0.6, 1.0],
            group=0,
        )
        spec.worldbody.add_light(pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0], castshadow=False)
        for b in boxes:
            spec.worldbody.add_geom(
                name=b.name,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=list(b.half_size),
                pos=list(b.center),
                rgba=list(b.rgba),
                friction=[b.friction, 0.005, 0.0001],
                group=0,
            )
        contact = getattr(self.catalogue, "contact", None)
        pads = pad_contacts(spec, self.catalogue)
        for o in objects:
            add_object(
                spec.worldbody,
                o.name,
                self.catalogue.objects[o.name],
                o.pos,
                _quat(o),
                contact,
                pads,
            )
        return spec.compile()

    # ------------------------------------------------------------ ground truth
    def object_pos(self, name: str) -> np.ndarray:
        """GROUND TRUTH world position of an object's body origin (tests only)."""
        return self.data.body(f"obj/{name}").xpos.copy()

    def object_quat(self, name: str) -> np.ndarray:
        """GROUND TRUTH world orientation (wxyz) of an object (tests only)."""
        return self.data.body(f"obj/{name}").xquat.copy()

    def base_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """GROUND TRUTH base position and rotation matrix (tests only)."""
        return self.data.xpos[self.base_id].copy(), self.data.xmat[self.base_id].reshape(
            3, 3
        ).copy()

    def world_to_base(self, p_world: np.ndarray) -> np.ndarray:
        """Expresses a world point in the current base frame (what perception would report)."""
        pos, rot = self.base_pose()
        return rot.T @ (np.asarray(p_world, dtype=float) - pos)

    def tcp_world(self) -> np.ndarray:
        """GROUND TRUTH tool-centre position."""
        return self.data.site("gripper_tcp").xpos.copy()

    # -------------------------------------------------------------- robot side
    def observation(self) -> Observation:
        """Encoders and gripper state, as the sim's JointState carries them."""
        d = self.data
        return Observation(
            t=float(d.time),
            q_arm=d.qpos[self.act.arm.qpos].copy(),
            dq_arm=d.qvel[self.act.arm.dof].copy(),
            gripper_gap=self.act.gripper_gap(d),
            gripper_effort=float(abs(self.act.tau[self.act.gripper.act].sum())),
        )

    def apply(self, cmds: Sequence[Command], kp: Sequence[float], kd: Sequence[float]) -> None:
        """Routes primitive commands to the actuator layer and the leg stand-in."""
        now = float(self.data.time)
        for c in cmds:
            if isinstance(c, ArmCommand):
                tr = c.traj
                tau_ff = self.gravity.feed_forward(tr.q)  # as the manipulation node sends it
                ok = self.act.set_arm_trajectory(now, tr.t, tr.q, tr.dq, kp, kd, tau_ff)
                if not ok:
                    raise RuntimeError(
                        f"actuator layer rejected a trajectory: {self.act.reject_reasons}"
                    )
            elif isinstance(c, GripperCmd):
                self.act.set_gripper_command(now, c.gap, c.max_force)
            elif isinstance(c, BodyPoseRequest):
                self.request_body(c)

    def request_body(self, req: BodyPoseRequest) -> None:
        """Starts a smooth body move to the requested offsets (feet stay in place)."""
        goal = np.array([req.x_offset, req.y_offset, req.z_offset])
        self._motion = _BodyMotion(
            self._body_offset.copy(), goal, float(self.data.time), self.body_move_time
        )

    def _leg_ik(self, offset: np.ndarray) -> np.ndarray:
        """Leg joints that keep the feet at their standing spots with the base at home+offset."""
        m, k = self.model, self._kin
        k.qpos[:] = self.data.qpos
        r0 = quat_to_mat(self._base_quat)
        k.qpos[:3] = self._base_home + r0 @ offset  # offsets are in the body frame
        k.qpos[3:7] = self._base_quat
        k.qpos[self.act.legs.qpos] = self._leg_q
        jac = np.zeros((3, m.nv))
        for _ in range(20):
            mujoco.mj_kinematics(m, k)
            mujoco.mj_comPos(m, k)
            err_max = 0.0
            for i, f in enumerate(FEET):
                sid = m.site(f).id
                err = self._feet_world[i] - k.site_xpos[sid]
                err_max = max(err_max, float(np.abs(err).max()))
                mujoco.mj_jacSite(m, k, jac, None, sid)
                cols = self.act.legs.dof[3 * i : 3 * i + 3]
                j3 = jac[:, cols]
                dq = np.linalg.solve(j3 + 1e-9 * np.eye(3), err)
                k.qpos[self.act.legs.qpos[3 * i : 3 * i + 3]] += dq
            if err_max < 1e-7:
                break
        return k.qpos[self.act.legs.qpos].copy()

    def _gravity_ff(self, q_leg: np.ndarray) -> np.ndarray:
        """Static leg torques that carry the robot's weight equally on four feet."""
        m, k = self.model, self._kin
        k.qpos[:] = self.data.qpos
        k.qpos[self.act.legs.qpos] = q_leg
        k.qvel[:] = 0.0
        mujoco.mj_forward(m, k)
        robot = np.flatnonzero(m.body_rootid == m.body_rootid[self.base_id])
        mass = float(m.body_mass[robot].sum())
        f = np.array([0.0, 0.0, mass * 9.81 / 4.0])
        tau = np.zeros(rd.N_LEG_JOINTS)
        jac = np.zeros((3, m.nv))
        for i, name in enumerate(FEET):
            mujoco.mj_jacSite(m, k, jac, None, m.site(name).id)
            cols = self.act.legs.dof[rd.leg_slice(i)]
            tau[rd.leg_slice(i)] = -jac[:, cols].T @ f
        return tau + k.qfrc_bias[self.act.legs.dof]

    def _send_legs(self) -> None:
        now = float(self.data.time)
        self.act.set_leg_command(
            now,
            self._leg_q,
            np.zeros(rd.N_LEG_JOINTS),
            np.full(rd.N_LEG_JOINTS, self.leg_kp),
            np.full(rd.N_LEG_JOINTS, self.leg_kd),
            self._tau_ff,
        )

    def _update_body(self) -> None:
        mo = self._motion
        if mo is None:
            return
        s = min(1.0, (float(self.data.time) - mo.t0) / mo.duration)
        s = s * s * (3 - 2 * s)
        self._body_offset = mo.start + s * (mo.goal - mo.start)
        self._leg_q = self._leg_ik(self._body_offset)
        self._tau_ff = self._gravity_ff(self._leg_q)
        if s >= 1.0:
            self._motion = None

    def step(self) -> None:
        """One control tick: leg stand-in update, then ``substeps`` physics steps."""
        self._update_body()
        self._send_legs()
        for _ in range(self.substeps):
            self.act.apply(self.data)
            mujoco.mj_step(self.model, self.data)

    def settle(self, seconds: float) -> None:
        """Lets physics run (robot standing, objects resting) for ``seconds``."""
        n = int(round(seconds / (self.substeps * self.model.opt.timestep)))
        for _ in range(n):
            self.step()

    def run(
        self,
        prim: Primitive,
        kp: Sequence[float],
        kd: Sequence[float],
        timeout: float = 60.0,
        every_tick: object | None = None,
    ) -> Primitive:
        """Runs a primitive to completion (or ``timeout`` s of sim time)."""
        t_end = float(self.data.time) + timeout
        while not prim.done and float(self.data.time) < t_end:
            cmds = prim.step(self.observation())
            self.apply(cmds, kp, kd)
            self.step()
            if callable(every_tick):
                every_tick(self)
        if not prim.done:
            self.apply(prim.cancel(self.observation()), kp, kd)
            prim.reason = "timeout"
        return prim


# --------------------------------------------------------------------------- ground truth
@dataclass(frozen=True)
class GraspSpec:
    """A grasp pose for the primitives, computed from ground truth (stands in for perception)."""

    position_base: np.ndarray
    approach: str
    yaw: float
    width: float
    tilt: float = 0.0  # tool lean for a flared vessel wall (plan_grasp's ``tilt``)
    hang: float = 0.0  # how far the object reaches below the grasp point (GraspGoal.hang)


def _part_extent(g: object) -> tuple[np.ndarray, np.ndarray]:
    """Centre and axis-aligned half extents (object frame) of one catalogue part."""
    size = np.asarray(g.size, dtype=float)  # type: ignore[attr-defined]
    kind = g.type  # type: ignore[attr-defined]
    if kind == "sphere":
        h = np.full(3, size[0])
    elif kind in ("cylinder", "capsule"):
        h = np.array([size[0], size[0], size[1] + (size[0] if kind == "capsule" else 0.0)])
    else:
        h = size[:3]
    rot = quat_to_mat(g.quat)  # type: ignore[attr-defined]
    return np.asarray(g.pos, dtype=float), np.abs(rot) @ h  # type: ignore[attr-defined]


# Where a person would pinch a part-built object (object frame: centre, half extents): the
# clamp's bar between its jaws (its bounding-box centre is next to a jaw); the spoon's bowl
# across its rim (the bowl is a thin shell of many pieces, the largest being the handle,
# whose thin strip was tried and missed: the fingers closed on nothing in every trial).
GRASP_HINTS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "clamp": ((-0.027, 0.0545, 0.0), (0.02, 0.008, 0.010)),
    "spoon": ((0.065, 0.0, 0.0), (0.0325, 0.019, 0.007)),
}


def grasp_from_ground_truth(
    h: SimHarness,
    name: str,
    surface_z: float,
    approach: str = "vertical",
    max_width: float = 0.085,
    far_side: bool = False,
) -> GraspSpec:
    """Grasp pose for object ``name`` from its true pose in the harness (TEST HARNESS ONLY);
    see :func:`grasp_from_poses`."""
    base_pos, base_rot = h.base_pose()
    return grasp_from_poses(
        h.catalogue,
        name,
        h.object_pos(name),
        h.data.body(f"obj/{name}").xmat.reshape(3, 3).copy(),
        base_pos,
        base_rot,
        surface_z,
        approach,
        max_width,
        far_side,
    )


def grasp_from_poses(
    catalogue: object,
    name: str,
    p_world: np.ndarray,
    rot_world: np.ndarray,
    base_pos: np.ndarray,
    base_rot: np.ndarray,
    surface_z: float,
    approach: str = "vertical",
    max_width: float = 0.085,
    far_side: bool = False,
) -> GraspSpec:
    """Grasp pose for object ``name`` from its true world pose and the base's (TEST HARNESS ONLY:
    stands in for perception; also used by the full-stack tests on ground-truth messages),
    with the object's hang below the grasp point (it rests on ``surface_z``).

    Vertical: above the largest part's centre, fingers across its narrower horizontal side,
    tool centre 3 cm below the object's top (the palm is 5 cm above the tool centre) but at
    least 2.1 cm above the supporting surface (the fingertips reach 2 cm beyond it). Vessels
    are grasped at the rim, fingers across the wall, on the side nearest the robot away from
    a handle. Horizontal: at the object's centre (at most 5 cm above the surface), a box's
    at most ``HORIZONTAL_GRASP_DEPTH`` behind its near face, fingers across the object's
    extent along the body y axis.
    """
    from quadmanip.sim.world.objects import object_parts

    spec = catalogue.objects[name]  # type: ignore[attr-defined]
    p = np.asarray(p_world, dtype=float).copy()
    rot = np.asarray(rot_world, dtype=float).reshape(3, 3)
    base_pos = np.asarray(base_pos, dtype=float)
    base_rot = np.asarray(base_rot, dtype=float).reshape(3, 3)
    obj_yaw = math.atan2(rot[1, 0], rot[0, 0])
    base_yaw = math.atan2(base_rot[1, 0], base_rot[0, 0])

    def world_to_base(q: np.ndarray) -> np.ndarray:
        return base_rot.T @ (np.asarray(q, dtype=float) - base_pos)

    def grasp_at(
        pt: np.ndarray, approach: str, yaw: float, width: float, tilt: float = 0.0
    ) -> GraspSpec:
        # the object reaches from the grasp point down to the surface it rests on
        hang = max(0.0, float(pt[2]) - surface_z)
        return GraspSpec(world_to_base(pt), approach, yaw, width, tilt=tilt, hang=hang)

    top = surface_z + spec.size[2]
    if spec.shape == "vessel" and approach == "vertical":
        v = spec.vessel
        assert v is not None
        reach = spec.size[0] - spec.size[1]
        axis = p + rot @ np.array([-0.5 * reach, 0.0, 0.0])
        r = 0.5 * spec.size[1] - 0.5 * v.wall
        lean = math.atan2(0.5 * (spec.size[1] - v.bottom_diameter), spec.size[2])
        if spec.size[1] <= max_width and lean <= 0.35:
            # narrow enough to close around (cup, mug): across the body, clear of a handle
            # (the fingers close along the object's y, the handle sticks out along x),
            # 3 cm below the rim. A pinch of the 3 mm rim missed one time in ten when the
            # tool stood 3-4 mm off (the light cup tipped away from the first finger).
            pt = axis.copy()
            pt[2] = max(surface_z + 0.021, top - 0.03)
            return grasp_at(pt, "vertical", obj_yaw - base_yaw, spec.size[1])
        if not v.handle and lean > 0.35:
            # strongly flared, round (bowl): pinch the wall facing the robot (or the far
            # one, ``far_side``, when the near one is too close to the trunk) with the tool
            # leaned along it, fingers across it, pads 1.5 cm down the wall
            d_world = axis - base_pos
            d_world[2] = 0.0
            d_world = (1.0 if far_side else -1.0) * d_world / np.linalg.norm(d_world)
            depth = 0.015
            c = math.cos(lean)
            r_pt = 0.5 * spec.size[1] - 0.5 * v.wall / c - depth * math.tan(lean)
            pt = axis + r_pt * d_world
            pt[2] = top - depth
            ang = math.atan2(d_world[1], d_world[0])
            return grasp_at(
                pt,
                "vertical",
                ang - math.pi / 2 - base_yaw,
                v.wall / c + 0.01,
                tilt=-lean if far_side else lean,
            )
        best = None
        for th in (0.5 * math.pi, math.pi, 1.5 * math.pi) + ((0.0,) if not v.handle else ()):
            d_world = rot @ np.array([math.cos(th), math.sin(th), 0.0])
            pt = axis + r * d_world
            dist = float(np.linalg.norm(pt[:2] - base_pos[:2]))
            if best is None or dist < best[0]:
                best = (dist, pt, math.atan2(d_world[1], d_world[0]))
        assert best is not None
        _, pt, ang = best
        pt = pt.copy()
        pt[2] = top - RIM_DEPTH
        return grasp_at(pt, "vertical", ang - math.pi / 2 - base_yaw, v.wall + 0.01)
    parts = object_parts(spec)
    if name in GRASP_HINTS:
        centre, half = GRASP_HINTS[name]
        centre, half = np.asarray(centre, dtype=float), np.asarray(half, dtype=float)
    elif spec.shape == "parts":
        vols = []
        for g in parts:
            _, he = _part_extent(g)
            vols.append(g.weight * float(np.prod(he)))
        centre, half = _part_extent(parts[int(np.argmax(vols))])
    else:
        centre, half = np.zeros(3), 0.5 * np.asarray(spec.size)
    pt = p + rot @ centre
    if approach == "vertical":
        # close across the narrower of the part's horizontal sides that fits
        if 2 * half[1] <= max_width and (half[1] <= half[0] or 2 * half[0] > max_width):
            yaw, width = obj_yaw, 2 * half[1]
        else:
            yaw, width = obj_yaw + math.pi / 2, 2 * half[0]
        pt[2] = max(surface_z + 0.021, top - 0.03)
        return grasp_at(pt, "vertical", yaw - base_yaw, float(width))
    # horizontal: extent across the body's y axis (a round object's diameter)
    ext = np.abs(base_rot.T @ rot) @ (0.5 * np.asarray(spec.size))  # in the base frame
    if spec.shape in ("cylinder", "sphere"):
        ext[1] = 0.5 * spec.size[0]
    pt = p.copy()
    if spec.shape == "box":  # pads near the front face, not along a deep box's whole depth
        pt -= base_rot[:, 0] * max(0.0, float(ext[0]) - rd.HORIZONTAL_GRASP_DEPTH)
    pt[2] = surface_z + min(0.05, max(0.02, 0.5 * spec.size[2]))
    return grasp_at(pt, "horizontal", 0.0, float(2 * ext[1]))


def plan_grasp_from_ground_truth(
    h: SimHarness,
    geom: object,
    cfg: object,
    name: str,
    surface_z: float,
    approach: str = "vertical",
) -> tuple[GraspSpec, object]:
    """Ground-truth grasp pose and its checked plan (TEST HARNESS ONLY).

    A flared vessel is pinched at the wall facing the robot; if the planner rejects that
    one (too close to the trunk on the floor) the far wall is tried, as a grasp planner
    would try its next candidate. Raises the near wall's ``GraspRejected`` otherwise.
    """
    from quadmanip.services.manipulation.grasp import GraspRejected, plan_grasp

    gs = grasp_from_ground_truth(h, name, surface_z, approach)

    def plan(g: GraspSpec) -> object:
        return plan_grasp(geom, cfg, g.position_base, g.approach, g.yaw, g.width, tilt=g.tilt)  # type: ignore[arg-type]

    try:
        return gs, plan(gs)
    except GraspRejected as near:
        if not gs.tilt:
            raise
        far = grasp_from_ground_truth(h, name, surface_z, approach, far_side=True)
        try:
            return far, plan(far)
        except GraspRejected:
            raise near from None


# --------------------------------------------------------------------------- test scenes
RIM_DEPTH = 0.012  # tool centre below a vessel rim (m)
TABLE_HEIGHT = 0.40  # the house's tables (configs/house.toml)


def table_boxes(x_near: float = 0.27, length: float = 0.6, width: float = 0.8) -> list[Box]:
    """A table top slab (top at TABLE_HEIGHT) whose near edge is ``x_near`` ahead of the base."""
    return [
        Box(
            "table",
            (x_near + length / 2, 0.0, TABLE_HEIGHT - 0.015),
            (length / 2, width / 2, 0.015),
        )
    ]


def container_boxes(place: str, center_x: float, surface_z: float = 0.0) -> list[Box]:
    """An open box with the size, wall and bottom of the house's deposit container ``place``,
    turned so its shorter side faces the robot, centred at (center_x, 0) on ``surface_z``."""
    from quadmanip.sim.world.house import load_house

    c = next(c for c in load_house().containers if c.name == place)
    sx, sy, h = c.size
    if sx > sy:
        sx, sy = sy, sx
    ix, iy, t = sx / 2 - c.wall, sy / 2 - c.wall, c.wall
    z0 = surface_z
    return [
        Box(
            f"{place}_bottom",
            (center_x, 0.0, z0 + c.bottom / 2),
            (sx / 2, sy / 2, c.bottom / 2),
            c.rgba,
        ),
        Box(
            f"{place}_w1", (center_x - ix - t / 2, 0.0, z0 + h / 2), (t / 2, sy / 2, h / 2), c.rgba
        ),
        Box(
            f"{place}_w2", (center_x + ix + t / 2, 0.0, z0 + h / 2), (t / 2, sy / 2, h / 2), c.rgba
        ),
        Box(f"{place}_w3", (center_x, -iy - t / 2, z0 + h / 2), (ix, t / 2, h / 2), c.rgba),
        Box(f"{place}_w4", (center_x, iy + t / 2, z0 + h / 2), (ix, t / 2, h / 2), c.rgba),
    ]


def resting_in_box(
    h: SimHarness,
    name: str,
    center_x: float,
    inner: tuple[float, float],
    bottom: float,
    rim: float,
) -> bool:
    """GROUND TRUTH: the judge's rule (``quadmanip.sim.judge``) for a harness container
    centred at (center_x, 0): the object's centre inside the inner footprint, between the
    inner bottom and ``max(rim, bottom + half its longest side) + tolerance``, at rest and
    touching no part of the robot. (The harness has no judge: its boxes are not the house's
    places. Call it after the object had the judge's rest time to settle.)"""
    from quadmanip.common.config import load_config
    from quadmanip.sim.engine import SimConfig
    from quadmanip.sim.judge import highest_centre

    cfg = load_config(SimConfig, "sim").judge  # the sim's judge settings (configs/sim.toml)
    m, d = h.model, h.data
    body = m.body(f"obj/{name}").id
    p = d.xpos[body]
    top = highest_centre(bottom, rim, 0.5 * max(h.catalogue.objects[name].size), cfg)
    inside = abs(p[0] - center_x) <= inner[0] and abs(p[1]) <= inner[1] and bottom <= p[2] <= top
    v = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, body, v, 0)
    at_rest = np.linalg.norm(v[3:]) < cfg.rest_linear and np.linalg.norm(v[:3]) < cfg.rest_angular
    roots = m.body_rootid[m.geom_bodyid[d.contact.geom[: d.ncon]]]  # (ncon, 2)
    pair = np.sort([m.body_rootid[m.body("base").id], m.body_rootid[body]])
    touches_robot = bool(np.any(np.all(np.sort(roots, axis=1) == pair, axis=1)))
    return bool(inside and at_rest and not touches_robot)


def container_inner(place: str, center_x: float) -> tuple[float, float, float]:
    """Inner half-extents (x, y) and outer height of a container placed by
    :func:`container_boxes`."""
    from quadmanip.sim.world.house import load_house

    c = next(c for c in load_house().containers if c.name == place)
    sx, sy, h = c.size
    if sx > sy:
        sx, sy = sy, sx
    return sx / 2 - c.wall, sy / 2 - c.wall, h


def drawer_world(which: str, handle_arm_x: float = 0.44, scenario: object | None = None) -> object:
    """The house with the robot standing square in front of drawer ``which`` (handle
    ``handle_arm_x`` ahead of the arm mount) - where navigation would have brought it."""

    from quadmanip.sim.world.builder import build_world
    from quadmanip.sim.world.house import load_house

    house = load_house()
    empty = build_world(None, robot=False, house=house)
    d = mujoco.MjData(empty.model)
    mujoco.mj_forward(empty.model, d)
    hp = d.body(empty.drawer_handles[which]).xpos.copy()
    mount_x = float(rd.arm_mount()[0])
    start = dataclasses.replace(
        house.robot_start, position=(hp[0] - mount_x - handle_arm_x, hp[1]), yaw=0.0
    )
    return build_world(scenario, robot=True, house=dataclasses.replace(house, robot_start=start))  # type: ignore[arg-type]


def drawer_place_world(
    name: str, stool_height: float = 0.20, ahead: float = 0.25, yaw: float = 0.0
) -> object:
    """The house, the robot square in front of the top drawer, and object ``name`` on a
    stool ``ahead`` m in front of the base (a low side table, stand-in for navigation
    bringing the object within reach of the drawer)."""

    from quadmanip.sim.scenarios import Placement, Scenario

    spec = load_catalogue().objects[name]
    w0 = drawer_world("top")
    bx, by = w0.robot_start[:2]  # type: ignore[attr-defined]
    z = stool_height + spec.size[2] / 2 + 0.001
    c, sn = math.cos(yaw / 2), math.sin(yaw / 2)
    sc = Scenario(
        "drawer-place",
        0,
        (Placement(name, "stool", (bx + ahead, by, z), (c, 0.0, 0.0, sn)),),
    )
    world = drawer_world("top", scenario=sc)
    world.spec.worldbody.add_geom(  # type: ignore[attr-defined]
        name="stool",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.06, 0.08, stool_height / 2],
        pos=[bx + ahead, by, stool_height / 2],
        group=0,
    )
    return dataclasses.replace(world, model=world.spec.compile())  # type: ignore[attr-defined]


def drawer_mouth(h: SimHarness, world: object, which: str = "top") -> tuple[np.ndarray, float]:
    """GROUND TRUTH: the middle of an open drawer's exposed opening (world) and the height
    of its front panel top (what a place must clear)."""
    body = h.data.body(world.drawer_bodies[which])  # type: ignore[attr-defined]
    rot = body.xmat.reshape(3, 3)
    jname = world.drawer_joints[which]  # type: ignore[attr-defined]
    opened = float(h.data.qpos[h.model.joint(jname).qposadr[0]])
    inner = body.xpos - rot[:, 0] * 0.018  # drawer frame x points out of the cabinet
    mouth = inner - rot[:, 0] * (opened - 0.018 - 0.02) / 2
    front_top = float(body.xpos[2]) + 0.175
    return mouth.copy(), front_top


def in_region(h: SimHarness, world: object, region: str, name: str) -> bool:
    """GROUND TRUTH: is object ``name`` inside deposit region ``region`` (judge's box)?"""
    reg = next(r for r in world.regions if r.name == region)  # type: ignore[attr-defined]
    body = h.data.body(reg.body)
    rot = body.xmat.reshape(3, 3)
    loc = rot.T @ (h.object_pos(name) - body.xpos) - np.asarray(reg.center)
    return bool(np.all(np.abs(loc) < np.asarray(reg.half_size)))
