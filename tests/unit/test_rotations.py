"""common/rotations.py: known values, round trips, and agreement with MuJoCo's mju_* functions."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from quadmanip.common import rotations as rot

pytestmark = pytest.mark.unit

TOL = 1e-12


def _unit_quats(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _mju_quat2mat(q: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, dtype=float))
    return out.reshape(3, 3)


def _mju_mat2quat(r: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mat2Quat(out, np.asarray(r, dtype=float).reshape(9))
    return out


def _same_rotation(a: np.ndarray, b: np.ndarray, tol: float = TOL) -> bool:
    """q and -q are the same rotation."""
    return bool(np.allclose(a, b, atol=tol) or np.allclose(a, -b, atol=tol))


# --------------------------------------------------------------------------- known values


def test_known_values():
    s = math.sqrt(0.5)
    assert rot.quat_from_yaw(math.pi / 2) == pytest.approx([s, 0.0, 0.0, s])
    assert rot.yaw_from_quat([s, 0.0, 0.0, s]) == pytest.approx(math.pi / 2)
    assert rot.yaw_from_quat([1.0, 0.0, 0.0, 0.0]) == 0.0
    # 90 deg about z maps x to y
    assert rot.quat_to_mat([s, 0.0, 0.0, s]) @ [1.0, 0.0, 0.0] == pytest.approx([0, 1, 0])
    assert rot.rot_z(math.pi / 2) @ [1.0, 0.0, 0.0] == pytest.approx([0.0, 1.0, 0.0])
    assert rot.rot_y(math.pi / 2) @ [0.0, 0.0, 1.0] == pytest.approx([1.0, 0.0, 0.0])
    assert rot.rot_x(math.pi / 2) @ [0.0, 1.0, 0.0] == pytest.approx([0.0, 0.0, 1.0])
    assert np.array_equal(rot.quat_to_mat([1.0, 0.0, 0.0, 0.0]), np.eye(3))
    assert np.array_equal(rot.mat_to_quat(np.eye(3)), [1.0, 0.0, 0.0, 0.0])
    assert rot.quat_from_axis_angle([1.0, 0.0, 0.0], math.pi) == pytest.approx([0, 1, 0, 0])
    # i * j = k
    assert rot.quat_mul([0, 1, 0, 0], [0, 0, 1, 0]) == pytest.approx([0, 0, 0, 1])
    assert rot.quat_conj([0.5, 0.5, -0.5, 0.5]) == pytest.approx([0.5, -0.5, 0.5, -0.5])
    assert np.linalg.norm(rot.quat_normalize([2.0, 0.0, 0.0, 0.0])) == pytest.approx(1.0)


def test_rpy_is_zyx():
    roll, pitch, yaw = 0.3, -0.2, 2.5
    r = rot.rot_z(yaw) @ rot.rot_y(pitch) @ rot.rot_x(roll)
    assert rot.rpy_from_mat(r) == pytest.approx([roll, pitch, yaw])
    q = rot.mat_to_quat(r)
    assert rot.yaw_from_quat(q) == pytest.approx(yaw)


def test_euler_xyz_is_intrinsic_like_mjcf():
    angles = (30.0, -45.0, 60.0)
    q = rot.quat_from_euler_xyz(angles, degrees=True)
    a, b, c = (math.radians(v) for v in angles)
    expected = rot.rot_x(a) @ rot.rot_y(b) @ rot.rot_z(c)  # intrinsic x, then y, then z
    assert rot.quat_to_mat(q) == pytest.approx(expected, abs=TOL)
    assert rot.quat_from_euler_xyz((a, b, c)) == pytest.approx(q, abs=TOL)
    assert np.array_equal(rot.quat_from_euler_xyz((0.0, 0.0, 0.0)), [1.0, 0.0, 0.0, 0.0])
    # what MuJoCo compiles from <geom euler="30 -45 60"> (degrees, default eulerseq "xyz")
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom size="0.1" euler="30 -45 60"/></worldbody></mujoco>'
    )
    assert _same_rotation(model.geom_quat[0], q, 1e-9)


def test_skew_is_the_cross_product_for_stacks():
    rng = np.random.default_rng(3)
    v, u = rng.normal(size=(5, 2, 3)), rng.normal(size=(5, 2, 3))
    s = rot.skew(v)
    assert s.shape == (5, 2, 3, 3)
    assert np.einsum("...ij,...j->...i", s, u) == pytest.approx(np.cross(v, u))
    assert rot.skew(v[0, 0]) == pytest.approx(-rot.skew(v[0, 0]).T)


def test_wrap_angle():
    assert rot.wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert rot.wrap_angle(-3 * math.pi / 2) == pytest.approx(math.pi / 2)
    assert rot.wrap_angle(math.pi) == pytest.approx(-math.pi)  # [-pi, pi)
    assert isinstance(rot.wrap_angle(1.0), float)
    a = np.linspace(-20.0, 20.0, 101)
    w = rot.wrap_angle(a)
    assert isinstance(w, np.ndarray) and w.shape == a.shape
    assert np.all((w >= -math.pi) & (w < math.pi))
    assert np.cos(w) == pytest.approx(np.cos(a)) and np.sin(w) == pytest.approx(np.sin(a))


# --------------------------------------------------------------------------- round trips


def test_round_trips():
    for q in _unit_quats(500):
        r = rot.quat_to_mat(q)
        assert r @ r.T == pytest.approx(np.eye(3), abs=TOL)
        assert np.linalg.det(r) == pytest.approx(1.0)
        back = rot.mat_to_quat(r)
        assert back[0] >= 0.0 and _same_rotation(back, q)
        assert rot.quat_to_mat(rot.quat_mul(q, rot.quat_conj(q))) == pytest.approx(np.eye(3))
        roll, pitch, yaw = rot.rpy_from_mat(r)
        assert rot.rot_z(yaw) @ rot.rot_y(pitch) @ rot.rot_x(roll) == pytest.approx(r, abs=1e-9)
        assert rot.yaw_from_quat(q) == pytest.approx(yaw, abs=1e-9)
    for yaw in np.linspace(-math.pi + 1e-9, math.pi - 1e-9, 37):
        assert rot.yaw_from_quat(rot.quat_from_yaw(yaw)) == pytest.approx(yaw)
        assert rot.quat_to_mat(rot.quat_from_yaw(yaw)) == pytest.approx(rot.rot_z(yaw))


def test_mat_to_quat_every_branch():
    """Rotations by ~180 deg about x, y, z exercise Shepperd's non-trace branches."""
    for axis in np.eye(3):
        for angle in (math.pi, math.pi - 1e-3, 2.5):
            q = rot.quat_from_axis_angle(axis, angle)
            assert _same_rotation(rot.mat_to_quat(rot.quat_to_mat(q)), q)
    assert rot.mat_to_quat(np.eye(3).reshape(9)) == pytest.approx([1.0, 0.0, 0.0, 0.0])


def test_quat_to_mat_normalises():
    q = _unit_quats(1, seed=7)[0]
    assert rot.quat_to_mat(3.0 * q) == pytest.approx(rot.quat_to_mat(q), abs=TOL)


# --------------------------------------------------------------------------- against MuJoCo


def test_against_mujoco():
    rng = np.random.default_rng(11)
    qs = _unit_quats(1000, seed=5)
    for a, b in zip(qs[:500], qs[500:], strict=True):
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, a, b)
        assert rot.quat_mul(a, b) == pytest.approx(out, abs=TOL)
        r = _mju_quat2mat(a)
        assert rot.quat_to_mat(a) == pytest.approx(r, abs=TOL)
        assert _same_rotation(rot.mat_to_quat(r), _mju_mat2quat(r))
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = float(rng.uniform(-7.0, 7.0))
        mujoco.mju_axisAngle2Quat(out, axis, angle)
        assert rot.quat_from_axis_angle(axis, angle) == pytest.approx(out, abs=TOL)
        v = rng.normal(size=3)
        rotated = np.zeros(3)
        mujoco.mju_rotVecQuat(rotated, v, a)
        assert rot.quat_to_mat(a) @ v == pytest.approx(rotated, abs=1e-9)


def test_fast_enough_for_the_leg_loop():
    """The estimator converts the IMU quaternion every 2 ms tick: a few microseconds each."""
    import time

    q = _unit_quats(1)[0]
    n = 2000
    t0 = time.process_time()
    for _ in range(n):
        rot.rpy_from_mat(rot.quat_to_mat(q))
        rot.mat_to_quat(rot.quat_to_mat(q))
    per_call = (time.process_time() - t0) / n
    assert per_call < 200e-6  # generous: shared CI machines
