"""Forward and analytic inverse kinematics of the 4-DOF arm (paper eqs. 1-9).

Chain (eq. 1), expressed in the ``arm_base`` frame::

    T = Ttr(0,0,d1) Ry(q1) Ttr(0,0,d2) Ry(q2) Ttr(d4,0,d3) Ry(q3) Rx(q4) Ttr(d5,0,0)

Joints 1-3 pitch about the common y axis, joint 4 rolls the tool about its x axis, so
every reachable tool pose has its position in the arm's vertical x-z plane (y = 0) and its
orientation equal to ``Ry(pitch) Rx(roll)`` with ``pitch = q1 + q2 + q3`` and
``roll = q4``. The task-space target of this module is therefore
``ArmTarget(x, z, pitch, roll)`` in ``arm_base``: a positive pitch points the tool down
(``pitch = pi/2`` is a vertical top-down grasp, ``pitch = 0`` a horizontal approach along
+x). A target with y != 0 is not reachable by the arm alone: :func:`target_from_base_pose`
reports the lateral body shift the body must make first (Algorithm 6's ``moveCOM(-y)``).

Corrections to the paper's OCR'd equations (derived from eq. 1, checked against pinocchio):

* eq. (6)/(7) use ``d1`` in the law of cosines; the triangle after removing the base
  offset (eq. 2) has sides ``d2`` (upper arm), ``d7`` (forearm, eq. 5) and ``d6`` (eq. 4),
  so ``d2`` is meant.
* eq. (6) writes ``atan(z', x')``; the quadrant-correct ``atan2`` is needed. We compute
  ``q1 = atan2(x', z') - atan2(vx, vz)`` with ``v`` the elbow-to-wrist vector for the
  chosen ``q2``, which is the same triangle and valid for both elbow branches.
* eq. (7) gives only one elbow branch; both ``q2 = +-acos(c) - atan2(d4, d3)`` are
  solutions and the one inside the joint limits closest to a reference is chosen.
* eq. (9) ``q3 = acos(R11)`` loses the sign; since the remaining rotation is ``Ry(q3)``
  we use ``q3 = atan2(R[0,2], R[0,0])``, which for an in-plane target reduces to
  ``q3 = pitch - q1 - q2`` (wrapped to [-pi, pi)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from quadmanip.common.joint_layout import ARM_JOINTS
from quadmanip.common.rotations import mat_to_quat, quat_to_mat, rot_x, rot_y, wrap_angle

__all__ = [
    "ArmGeometry",
    "ArmTarget",
    "IkError",
    "IkFailure",
    "IkSolution",
    "fk",
    "fk_tcp",
    "held_offset",
    "solve_ik",
    "solve_ik_pose",
    "target_from_base_pose",
]

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class ArmGeometry:
    """Arm dimensions d1..d5 (Table 2) and joint limits, read from the robot description.

    ``arm_base_pos`` and ``arm_base_quat`` (wxyz) place the ``arm_base`` frame in the body
    (``base``) frame so that grasp poses given in the body frame can be converted.
    """

    d1: float
    d2: float
    d3: float
    d4: float
    d5: float
    q_min: tuple[float, float, float, float]
    q_max: tuple[float, float, float, float]
    arm_base_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    arm_base_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    @property
    def d7(self) -> float:
        """Wrist-to-elbow distance, eq. (5)."""
        return math.hypot(self.d3, self.d4)

    @classmethod
    def from_description(cls, model=None) -> ArmGeometry:  # noqa: ANN001 - mujoco.MjModel
        """Reads d1..d5, joint ranges and the arm mount from the MJCF robot description.

        d1..d5 come from :func:`quadmanip.common.robot_description.arm_dimensions` (the
        only source of the arm's geometry); ``model`` defaults to the robot description.
        """
        import mujoco
        from quadmanip.common import robot_description as rd

        if model is None:
            model = rd.load_mujoco_model()
        dims = rd.arm_dimensions(model)
        q_min, q_max = [], []
        for jname in ARM_JOINTS:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, jname)
            if jid < 0:
                raise ValueError(f"robot description lacks joint {jname!r}")
            if model.jnt_limited[jid]:
                lo, hi = model.jnt_range[jid]
            else:
                lo, hi = -math.pi, math.pi
            q_min.append(float(lo))
            q_max.append(float(hi))
        pos, quat = _arm_base_in_base(model)
        return cls(
            d1=dims["d1"],
            d2=dims["d2"],
            d3=dims["d3"],
            d4=dims["d4"],
            d5=dims["d5"],
            q_min=tuple(q_min),  # type: ignore[arg-type]
            q_max=tuple(q_max),  # type: ignore[arg-type]
            arm_base_pos=pos,
            arm_base_quat=quat,  # type: ignore[arg-type]
        )


def _arm_base_in_base(model) -> tuple[tuple[float, float, float], tuple[float, ...]]:  # noqa: ANN001
    """Pose of the arm_base body in the base body, composed along the kinematic tree."""
    import mujoco

    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "arm_base")
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "base")
    if bid < 0 or base < 0:
        raise ValueError("robot description lacks body 'arm_base' or 'base'")
    pos = np.zeros(3)
    rot = np.eye(3)
    b = bid
    while b != base and b > 0:
        r_b = quat_to_mat(model.body_quat[b])
        pos = model.body_pos[b] + r_b @ pos
        rot = r_b @ rot
        b = model.body_parentid[b]
    quat = mat_to_quat(rot)
    return (float(pos[0]), float(pos[1]), float(pos[2])), tuple(float(v) for v in quat)


@dataclass(frozen=True)
class ArmTarget:
    """Tool-centre target in the ``arm_base`` frame: position in the x-z plane, pitch, roll."""

    x: float
    z: float
    pitch: float
    roll: float


class IkFailure(StrEnum):
    """Why a target cannot be reached (never a NaN)."""

    NON_FINITE = "non_finite"
    OUT_OF_PLANE = "out_of_plane"
    TOO_FAR = "too_far"
    TOO_CLOSE = "too_close"
    ROLL_OUT_OF_RANGE = "roll_out_of_range"
    JOINT_LIMIT = "joint_limit"


class IkError(ValueError):
    """Raised by the ``*_or_raise`` helpers; ``reason`` is an :class:`IkFailure`."""

    def __init__(self, reason: IkFailure, detail: str, lateral_shift: float = 0.0) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail
        self.lateral_shift = lateral_shift


@dataclass(frozen=True)
class IkSolution:
    """Result of an IK query: ``q`` when ``ok``, else ``reason`` and a human ``detail``."""

    ok: bool
    q: tuple[float, float, float, float] | None = None
    reason: IkFailure | None = None
    detail: str = ""
    lateral_shift: float = 0.0

    def q_array(self) -> np.ndarray:
        """Joint vector as numpy; raises :class:`IkError` when the solve failed."""
        if not self.ok or self.q is None:
            raise IkError(self.reason or IkFailure.JOINT_LIMIT, self.detail, self.lateral_shift)
        return np.array(self.q, dtype=float)


def _fail(reason: IkFailure, detail: str, lateral: float = 0.0) -> IkSolution:
    return IkSolution(ok=False, reason=reason, detail=detail, lateral_shift=lateral)


def _hom(rot: np.ndarray | None = None, pos: tuple[float, float, float] | None = None):  # noqa: ANN202
    t = np.eye(4)
    if rot is not None:
        t[:3, :3] = rot
    if pos is not None:
        t[:3, 3] = pos
    return t


def fk(geom: ArmGeometry, q: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Tool-centre transform (4x4) in ``arm_base``, the literal product of eq. (1)."""
    q1, q2, q3, q4 = (float(v) for v in q)
    g = geom
    return (
        _hom(pos=(0.0, 0.0, g.d1))
        @ _hom(rot_y(q1))
        @ _hom(pos=(0.0, 0.0, g.d2))
        @ _hom(rot_y(q2))
        @ _hom(pos=(g.d4, 0.0, g.d3))
        @ _hom(rot_y(q3))
        @ _hom(rot_x(q4))
        @ _hom(pos=(g.d5, 0.0, 0.0))
    )


def fk_tcp(geom: ArmGeometry, q: np.ndarray | tuple[float, ...]) -> ArmTarget:
    """Closed form of eq. (1): tool-centre (x, z, pitch, roll) in ``arm_base``."""
    q1, q2, q3, q4 = (float(v) for v in q)
    g = geom
    a12 = q1 + q2
    a123 = a12 + q3
    s1, c1 = math.sin(q1), math.cos(q1)
    s12, c12 = math.sin(a12), math.cos(a12)
    s123, c123 = math.sin(a123), math.cos(a123)
    x = g.d2 * s1 + g.d4 * c12 + g.d3 * s12 + g.d5 * c123
    z = g.d1 + g.d2 * c1 - g.d4 * s12 + g.d3 * c12 - g.d5 * s123
    return ArmTarget(x=x, z=z, pitch=wrap_angle(a123), roll=q4)


def held_offset(geom: ArmGeometry, grasp: ArmTarget, offset_base: np.ndarray) -> np.ndarray:
    """A held object's point (its middle) in the tool frame: ``offset_base`` (body frame)
    from the grasp point, the tool at ``grasp`` (eq. (1)'s rotation ``Ry(pitch) Rx(roll)``
    in ``arm_base``). The object turns with the tool from then on: at another tool pose
    ``Ry(pitch') Rx(roll') @ held_offset`` is where that point is from the tool centre."""
    d = quat_to_mat(geom.arm_base_quat).T @ np.asarray(offset_base, dtype=float)
    return (rot_y(grasp.pitch) @ rot_x(grasp.roll)).T @ d


def _in_range(v: float, lo: float, hi: float, tol: float = 1e-12) -> float | None:
    """Returns v shifted by a multiple of 2*pi into [lo, hi], or None."""
    for cand in (v, v - _TWO_PI, v + _TWO_PI):
        if lo - tol <= cand <= hi + tol:
            return min(max(cand, lo), hi)
    return None


def solve_ik(
    geom: ArmGeometry,
    target: ArmTarget,
    q_ref: tuple[float, ...] | np.ndarray | None = None,
    roll_symmetric: bool = True,
) -> IkSolution:
    """Analytic IK, eqs. (2)-(9) (corrected, see module doc) with limits and elbow choice.

    ``roll_symmetric`` accepts ``roll + pi`` when ``roll`` itself is outside the wrist
    limit: the two-finger gripper is symmetric under a half turn. The elbow branch inside
    the limits closest to ``q_ref`` (or the first valid one) is returned.
    """
    x, z, pitch, roll = target.x, target.z, target.pitch, target.roll
    if not (math.isfinite(x) and math.isfinite(z) and math.isfinite(pitch)):
        return _fail(IkFailure.NON_FINITE, "target has a non-finite value")
    if not math.isfinite(roll):
        return _fail(IkFailure.NON_FINITE, "target roll is not finite")
    g = geom
    # wrist roll first: it is independent of the planar chain
    q4 = _in_range(roll, g.q_min[3], g.q_max[3])
    if q4 is None and roll_symmetric:
        q4 = _in_range(roll + math.pi, g.q_min[3], g.q_max[3])
    if q4 is None:
        return _fail(
            IkFailure.ROLL_OUT_OF_RANGE,
            f"roll {roll:.3f} rad outside wrist range [{g.q_min[3]:.3f}, {g.q_max[3]:.3f}]",
        )
    # eqs. (2)-(3): wrist position relative to the shoulder
    cp, sp = math.cos(pitch), math.sin(pitch)
    xw = x - g.d5 * cp
    zw = z - g.d1 + g.d5 * sp
    d6 = math.hypot(xw, zw)  # eq. (4)
    d7 = math.hypot(g.d3, g.d4)  # eq. (5)
    reach_max = g.d2 + d7
    reach_min = abs(g.d2 - d7)
    if d6 > reach_max + 1e-12:
        return _fail(IkFailure.TOO_FAR, f"wrist {d6:.4f} m from shoulder > reach {reach_max:.4f} m")
    if d6 < reach_min - 1e-12:
        return _fail(
            IkFailure.TOO_CLOSE, f"wrist {d6:.4f} m from shoulder < minimum {reach_min:.4f} m"
        )
    # eq. (7), both branches: |v|^2 = d2^2 + d7^2 + 2 d2 d7 cos(q2 + alpha)
    alpha = math.atan2(g.d4, g.d3)
    c = (d6 * d6 - g.d2 * g.d2 - d7 * d7) / (2.0 * g.d2 * d7)
    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
    beta = math.acos(c)
    phi = math.atan2(xw, zw)  # direction of the wrist seen from the shoulder, eq. (6)
    best: tuple[float, float, float, float] | None = None
    best_cost = math.inf
    why = ""
    for sign in (1.0, -1.0):
        q2 = sign * beta - alpha
        # eq. (6): shoulder angle = wrist direction minus elbow-to-wrist direction
        vx = g.d4 * math.cos(q2) + g.d3 * math.sin(q2)
        vz = g.d2 - g.d4 * math.sin(q2) + g.d3 * math.cos(q2)
        q1 = phi - math.atan2(vx, vz)
        # eqs. (8)-(9): remaining pitch belongs to the wrist
        q3 = pitch - q1 - q2
        cand = []
        for qv, k in ((q1, 0), (q2, 1), (q3, 2)):
            r = _in_range(wrap_angle(qv), g.q_min[k], g.q_max[k])
            if r is None:
                why = f"joint arm_j{k + 1}={wrap_angle(qv):.3f} rad outside [{g.q_min[k]:.3f}, {g.q_max[k]:.3f}]"
                break
            cand.append(r)
        else:
            sol = (cand[0], cand[1], cand[2], q4)
            if q_ref is None:
                return IkSolution(ok=True, q=sol)
            cost = sum((a - float(b)) ** 2 for a, b in zip(sol, q_ref, strict=False))
            if cost < best_cost:
                best, best_cost = sol, cost
        if beta == 0.0:
            break  # both branches coincide
    if best is None:
        return _fail(IkFailure.JOINT_LIMIT, why)
    return IkSolution(ok=True, q=best)


def solve_ik_pose(
    geom: ArmGeometry,
    pose: np.ndarray,
    q_ref: tuple[float, ...] | np.ndarray | None = None,
    tol: float = 1e-6,
) -> IkSolution:
    """IK for a full 4x4 tool pose in ``arm_base`` (eq. 2's T_manipulator).

    The pose must lie in the arm plane (y = 0 and tool x-axis without y component);
    otherwise the reason is ``OUT_OF_PLANE`` with the needed lateral shift.
    """
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        return _fail(IkFailure.NON_FINITE, "pose must be a finite 4x4 matrix")
    r = pose[:3, :3]
    y = float(pose[1, 3])
    if abs(y) > tol:
        return _fail(
            IkFailure.OUT_OF_PLANE,
            f"target y={y:.4f} m off the arm plane; shift the body by {-y:+.4f} m",
            lateral=y,
        )
    if abs(r[1, 0]) > tol:
        return _fail(IkFailure.OUT_OF_PLANE, "tool approach axis has a lateral (yaw) component")
    pitch = math.atan2(-r[2, 0], r[0, 0])
    # R = Ry(pitch) Rx(roll) -> Ry(-pitch) R = Rx(roll)
    rx = rot_y(-pitch) @ r
    roll = math.atan2(rx[2, 1], rx[1, 1])
    return solve_ik(geom, ArmTarget(float(pose[0, 3]), float(pose[2, 3]), pitch, roll), q_ref)


def target_from_base_pose(
    geom: ArmGeometry, position_base: np.ndarray, pitch: float, roll: float
) -> tuple[ArmTarget, float]:
    """Converts a tool-centre target in the body frame into ``(ArmTarget, lateral_shift)``.

    ``lateral_shift`` is the arm-base y of the target: the body must move by that amount
    (Algorithm 6's ``moveCOM``; the target then lies in the arm plane). The arm mount is
    assumed not rotated about z relative to the body (checked).
    """
    p = np.asarray(position_base, dtype=float) - np.asarray(geom.arm_base_pos)
    w, qx, qy, qz = geom.arm_base_quat
    if abs(qx) > 1e-9 or abs(qz) > 1e-9 or abs(qy) > 1e-9:
        # general rotation: express in arm_base axes
        rot = quat_to_mat(geom.arm_base_quat)
        p = rot.T @ p
    return ArmTarget(x=float(p[0]), z=float(p[2]), pitch=pitch, roll=roll), float(p[1])


def solve_ik_or_raise(
    geom: ArmGeometry, target: ArmTarget, q_ref: tuple[float, ...] | np.ndarray | None = None
) -> np.ndarray:
    """Convenience: joint vector or :class:`IkError` with a typed reason."""
    return solve_ik(geom, target, q_ref).q_array()


def arm_points(geom: ArmGeometry, q: np.ndarray | tuple[float, ...], n: int = 4) -> np.ndarray:
    """Points (x, z) along the arm's centre line in ``arm_base``: shoulder to fingertips."""
    q1, q2, q3 = (float(v) for v in q[:3])
    g = geom
    sh = np.array([0.0, g.d1])
    el = sh + g.d2 * np.array([math.sin(q1), math.cos(q1)])
    a12 = q1 + q2
    wr = el + np.array(
        [g.d4 * math.cos(a12) + g.d3 * math.sin(a12), -g.d4 * math.sin(a12) + g.d3 * math.cos(a12)]
    )
    a = a12 + q3
    tip = wr + (g.d5 + 0.02) * np.array([math.cos(a), -math.sin(a)])
    s = np.linspace(0.0, 1.0, n)[:, None]
    return np.vstack([sh + s * (el - sh), el + s * (wr - el), wr + s * (tip - wr)])


def body_collision(
    geom: ArmGeometry, q: np.ndarray | tuple[float, ...], front_x: float, min_z: float
) -> bool:
    """True when the arm's centre line dips below ``min_z`` over the trunk (x < ``front_x``).

    A coarse self-collision guard for planning (trunk top, LiDAR dome); the physics decides
    the rest.
    """
    pts = arm_points(geom, q)[1:]  # the shoulder itself sits on the trunk
    return bool(np.any((pts[:, 0] < front_x) & (pts[:, 1] < min_z)))
