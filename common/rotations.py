"""Rotations: quaternions, rotation matrices, Euler angles and angle wrapping, in one place.

Conventions (docs/conventions.md): quaternions are ``[w, x, y, z]`` (MuJoCo's order, the
wire order), Hamilton product, active rotations; a quaternion ``q`` and the matrix
``quat_to_mat(q)`` map body-frame vectors into the parent frame. Roll, pitch and yaw are
ZYX (yaw about z first, then pitch about the new y, then roll about the new x):
``R = Rz(yaw) Ry(pitch) Rx(roll)``.

Plain ``math`` and numpy on tiny arrays: every function here runs in microseconds, fast
enough for the 500 Hz leg loop (no scipy ``Rotation`` objects in hot paths). This module
imports no transport (no Zenoh, no bus, no messages), so algorithm modules may use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import overload

import numpy as np

__all__ = [
    "mat_to_quat",
    "quat_conj",
    "quat_from_axis_angle",
    "quat_from_euler_xyz",
    "quat_from_yaw",
    "quat_mul",
    "quat_normalize",
    "quat_to_mat",
    "rot_x",
    "rot_y",
    "rot_z",
    "rpy_from_mat",
    "skew",
    "wrap_angle",
    "yaw_from_quat",
]

QuatLike = Sequence[float] | np.ndarray
"""Anything with four numbers [w, x, y, z]."""

_TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------- quaternions


def quat_normalize(q: QuatLike) -> np.ndarray:
    """``q / |q|`` as a new float array."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q)


def quat_conj(q: QuatLike) -> np.ndarray:
    """Conjugate ``[w, -x, -y, -z]`` (the inverse of a unit quaternion)."""
    w, x, y, z = (float(v) for v in q)
    return np.array([w, -x, -y, -z])


def quat_mul(a: QuatLike, b: QuatLike) -> np.ndarray:
    """Hamilton product ``a * b`` (rotate by ``b`` first, then by ``a``); as ``mju_mulQuat``."""
    a0, a1, a2, a3 = (float(v) for v in a)
    b0, b1, b2, b3 = (float(v) for v in b)
    return np.array(
        [
            a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
        ]
    )


def quat_from_axis_angle(axis: Sequence[float] | np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the unit vector ``axis``; as ``mju_axisAngle2Quat``."""
    h = float(angle) * 0.5
    s = math.sin(h)
    return np.array([math.cos(h), float(axis[0]) * s, float(axis[1]) * s, float(axis[2]) * s])


def quat_from_yaw(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` (rad) about z."""
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def quat_from_euler_xyz(angles: Sequence[float], degrees: bool = False) -> np.ndarray:
    """Intrinsic x-y-z Euler angles (x first, then the new y, then the new z) → quaternion.

    This is the order of MJCF's default ``euler`` attribute (``eulerseq="xyz"``).
    """
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, angle in zip(
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), angles, strict=True
    ):
        if angle:
            a = math.radians(angle) if degrees else float(angle)
            q = quat_mul(q, quat_from_axis_angle(axis, a))
    return q


def yaw_from_quat(q: QuatLike) -> float:
    """Yaw (ZYX, rad, in [-pi, pi]) of a unit quaternion."""
    w, x, y, z = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# --------------------------------------------------------------------------- matrices


def quat_to_mat(q: QuatLike) -> np.ndarray:
    """3x3 rotation matrix of ``q`` (normalised first)."""
    w, x, y, z = (float(v) for v in np.asarray(q, dtype=float) / np.linalg.norm(q))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def mat_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrix (3x3, or 9 values row-major) → unit quaternion with ``w >= 0``.

    Shepperd's method: the largest of w, x, y, z is computed from the diagonal, the others
    from the off-diagonal terms, so it is accurate for every rotation.
    """
    r = np.asarray(r, dtype=float).reshape(3, 3)
    tr = float(np.trace(r))
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2.0
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2.0
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2.0
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    qa = np.asarray(q)
    qa = qa / np.linalg.norm(qa)
    return qa if qa[0] >= 0 else -qa


def rpy_from_mat(r: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` (rad) of a rotation matrix."""
    pitch = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
    roll = np.arctan2(r[2, 1], r[2, 2])
    yaw = np.arctan2(r[1, 0], r[0, 0])
    return np.array([roll, pitch, yaw])


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` (``[v]x @ u == v x u``) for a stack (..., 3) → (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


# --------------------------------------------------------------------------- angles


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...
def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) wrapped to [-pi, pi); a Python number gives a float, an array an array."""
    if hasattr(a, "__len__"):  # an array or a sequence (the cheapest test for the IK's floats)
        return (np.asarray(a, dtype=float) + math.pi) % _TWO_PI - math.pi
    # one number: plain math (the arm's IK wraps several angles per solution)
    w = math.fmod(a + math.pi, _TWO_PI)
    return (w + _TWO_PI if w < 0.0 else w) - math.pi
