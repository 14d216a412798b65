"""Drawer handle locator on the front camera's rendered depth, scored against the true
handle (ground truth is read here only, to score), and on bad input."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import math  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from quadmanip.common import robot_description as rd  # noqa: E402
from quadmanip.common.joint_layout import ARM_JOINTS  # noqa: E402
from quadmanip.common.rotations import quat_from_yaw, quat_mul, quat_to_mat  # noqa: E402
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry  # noqa: E402
from quadmanip.services.manipulation.config import load_manipulation_config  # noqa: E402
from quadmanip.services.manipulation.drawer import plan_drawer  # noqa: E402
from quadmanip.services.manipulation.postures import resolve_postures  # noqa: E402
from quadmanip.services.perception.handle_locator import (  # noqa: E402
    HandleConfig,
    locate_handle,
)
from quadmanip.sim.sensors import CameraConfig, RgbdRenderer  # noqa: E402
from quadmanip.sim.world.builder import build_world  # noqa: E402
from quadmanip.sim.world.house import load_house  # noqa: E402
from quadmanip.testbench.stack_trials import drawer_scenario  # noqa: E402

pytestmark = pytest.mark.unit

DRAWERS = tuple(d.name for d in load_house().cabinet.drawers)  # left, right, top
POS_TOL = 0.01  # m
ANGLE_TOL = 5.0  # deg
# the map's error on where a handle is: up to ~10 cm any way
OFFSETS = (
    (0.0, 0.0, 0.0),
    (0.06, 0.06, -0.05),
    (-0.05, -0.07, 0.05),
    (0.0, 0.09, 0.04),
    (0.04, -0.04, -0.08),
)


@dataclass
class Frame:
    depth: np.ndarray
    K: np.ndarray
    position: np.ndarray  # base_T_camera (optical)
    orientation: np.ndarray
    handles: dict[str, tuple[np.ndarray, np.ndarray]]  # true centre and out axis, base frame


def _stand(world, data: mujoco.MjData, arm_q: np.ndarray) -> None:
    """The robot standing (``home``) at its start, the arm in ``arm_q``."""
    m, ref = world.model, rd.load_mujoco_model()
    home = rd.home_qpos(ref)
    for j in range(ref.njnt):
        name, adr = ref.joint(j).name, ref.jnt_qposadr[j]
        dst = m.joint(name).qposadr[0]
        if ref.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            data.qpos[dst + 2] = home[2]
            data.qpos[dst + 3 : dst + 7] = quat_mul(quat_from_yaw(world.robot_start[2]), home[3:7])
        else:
            data.qpos[dst] = home[adr]
    for name, q in zip(ARM_JOINTS, arm_q, strict=True):
        data.qpos[m.joint(name).qposadr[0]] = q
    mujoco.mj_forward(m, data)


def _render(which: str, posture: str = "probe_horizontal") -> Frame:
    world = build_world(drawer_scenario(which))
    data = world.initial_data()
    postures = resolve_postures(ArmGeometry.from_description(), load_manipulation_config())
    _stand(world, data, postures[posture])
    r = RgbdRenderer(world.model, {rd.FRONT_CAMERA: CameraConfig()})
    try:
        f = r.render(data, rd.FRONT_CAMERA)
    finally:
        r.close()
    # ground truth, to score: the handle bodies in the base frame
    b = world.model.body(rd.BASE_BODY).id
    r_wb, p_wb = data.xmat[b].reshape(3, 3), data.xpos[b]
    handles = {}
    for name, body in world.drawer_handles.items():
        h = world.model.body(body).id
        handles[name] = (
            r_wb.T @ (data.xpos[h] - p_wb),
            r_wb.T @ data.xmat[h].reshape(3, 3)[:, 0],  # the drawer's x: out of the cabinet
        )
    return Frame(f.depth, f.K, f.position, f.orientation, handles)


@pytest.fixture(scope="module")
def frames() -> dict[str, Frame]:
    return {w: _render(w) for w in DRAWERS}


def _locate(f: Frame, expected: np.ndarray, depth: np.ndarray | None = None, **kw):
    d = f.depth if depth is None else depth
    return locate_handle(d, f.K, f.position, f.orientation, expected, **kw)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def test_three_drawers_cabinet_layout() -> None:
    assert set(DRAWERS) == {"left", "right", "top"}


@pytest.mark.parametrize("which", DRAWERS)
def test_finds_the_handle_from_an_approximate_place(frames, which: str) -> None:
    f = frames[which]
    truth, out = f.handles[which]
    for off in OFFSETS:
        res = _locate(f, truth + np.asarray(off))
        assert res.ok, (off, res.reason, res.detail)
        assert np.linalg.norm(res.position - truth) < POS_TOL, (off, res.position - truth)
        assert _angle_deg(res.pull_direction, out) < ANGLE_TOL, off
        assert abs(float(np.linalg.norm(res.pull_direction)) - 1.0) < 1e-9
        assert abs(float(res.pull_direction[2])) < 1e-9  # horizontal
        assert res.handle_length == pytest.approx(0.14, abs=0.01)  # the bar (house.toml)
        assert not res.truncated
        assert 0.5 < res.quality <= 1.0 and res.plane_inlier_fraction > 0.8


@pytest.mark.parametrize("which", DRAWERS)
def test_is_the_point_the_drawer_primitive_grips(frames, which: str) -> None:
    """The result plugs into the drawer action as the harness's ground-truth goal does
    (stack_trials._open_drawer: handle body centre, drawer x axis): same plan."""
    f = frames[which]
    truth, out = f.handles[which]
    res = _locate(f, truth + np.array([0.05, 0.05, 0.05]))
    geom, cfg = ArmGeometry.from_description(), load_manipulation_config()
    got = plan_drawer(geom, cfg, res.position, res.pull_direction, 0.15)
    want = plan_drawer(geom, cfg, truth, out, 0.15)
    assert abs(got.grip.x - want.grip.x) < POS_TOL and abs(got.grip.z - want.grip.z) < POS_TOL
    assert got.body.y_offset == pytest.approx(want.body.y_offset, abs=POS_TOL)


@pytest.mark.parametrize("which", DRAWERS)
def test_depth_noise(frames, which: str) -> None:
    f = frames[which]
    truth, out = f.handles[which]
    rng = np.random.default_rng(7)
    noisy = f.depth + rng.normal(0.0, 0.002, f.depth.shape).astype(np.float32)
    noisy[f.depth == 0.0] = 0.0
    res = _locate(f, truth + np.array([0.03, -0.05, 0.04]), noisy)
    assert res.ok, res.detail
    assert np.linalg.norm(res.position - truth) < POS_TOL
    assert _angle_deg(res.pull_direction, out) < ANGLE_TOL


def test_picks_the_handle_nearest_the_expected_place(frames) -> None:
    """The left drawer's view also shows the top drawer's handle, cut by the image's edge:
    an expected place near that one gives that one, flagged as cut off, its visible part's
    middle (on the bar, a safe grip) within a centimetre of the centre."""
    f = frames["left"]
    top, out = f.handles["top"]
    res = _locate(f, top + np.array([0.0, 0.04, -0.06]))
    assert res.ok, res.detail
    assert res.truncated and res.handle_length < 0.135
    assert np.linalg.norm(res.position - top) < POS_TOL
    assert _angle_deg(res.pull_direction, out) < ANGLE_TOL
    assert res.quality <= 0.5


def test_no_handle_between_the_handles(frames) -> None:
    """On the cabinet front midway between the two lower handles (17 cm from each)."""
    f = frames["left"]
    mid = 0.5 * (f.handles["left"][0] + f.handles["right"][0])
    res = _locate(f, mid)
    assert not res.ok and res.reason == "no_handle"
    assert "expected place" in res.detail
    assert res.plane_inlier_fraction > 0.5  # the front itself was found


def _wall_depth(f: Frame, x_wall: float) -> np.ndarray:
    """Depth of a flat vertical wall at base x = ``x_wall``, seen by ``f``'s camera."""
    h, w = f.depth.shape
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(f.K).T  # z = 1
    dx = rays @ quat_to_mat(f.orientation).T[:, 0]  # base x per unit depth
    with np.errstate(divide="ignore"):
        d = (x_wall - f.position[0]) / dx
    return np.where(dx > 1e-6, d, 0.0).astype(np.float32)


def test_flat_wall_has_no_handle(frames) -> None:
    f = frames["top"]
    truth, out = f.handles["top"]
    res = _locate(f, truth, _wall_depth(f, truth[0] + 0.035))
    assert not res.ok and res.reason == "no_handle", res.detail
    assert _angle_deg(res.plane_normal, out) < 1.0  # the wall was fitted, facing the robot


def test_something_standing_out_further_is_not_a_handle(frames) -> None:
    """A strip sloping from 2 to 12 cm out of the wall, handle-sized where it lies within a
    handle's depth: it is part of something standing further out (as the floor before a
    low drawer is), so no handle. The same strip flat at 4 cm is one."""
    f = frames["top"]
    truth, _ = f.handles["top"]
    wall_x = truth[0] + 0.035
    depth = _wall_depth(f, wall_x)
    assert _locate(f, truth, depth).reason == "no_handle"
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    pc = quat_to_mat(f.orientation).T @ (truth - f.position)
    uc, vc = f.K[0, 0] * pc[0] / pc[2] + f.K[0, 2], f.K[1, 1] * pc[1] / pc[2] + f.K[1, 2]
    patch = (np.abs(u - uc) < 40) & (np.abs(v - vc) < 4)
    slope = np.clip((u - (uc - 40)) / 80.0, 0.0, 1.0)  # 0 .. 1 across the strip
    sloped = depth.copy()
    for frac in np.linspace(0.0, 1.0, 81):
        cols = patch & (np.abs(slope - frac) <= 0.5 / 80)
        sloped[cols] = _wall_depth(f, wall_x - 0.02 - 0.10 * frac)[cols]
    res = _locate(f, truth, sloped)
    assert not res.ok and res.reason == "no_handle", res.detail
    assert "further out" in res.detail
    flat = depth.copy()
    flat[patch] = _wall_depth(f, wall_x - 0.04)[patch]
    res = _locate(f, truth, flat)
    assert res.ok, res.detail
    assert abs(res.position[1] - truth[1]) < POS_TOL and abs(res.position[2] - truth[2]) < POS_TOL


def test_empty_depth(frames) -> None:
    f = frames["left"]
    res = _locate(f, f.handles["left"][0], np.zeros_like(f.depth))
    assert not res.ok and res.reason == "empty_depth"


@pytest.mark.parametrize(
    "K",
    [
        np.zeros((3, 3)),
        np.full((3, 3), np.nan),
        np.diag([-188.0, 188.0, 1.0]) + np.array([[0, 0, 160], [0, 0, 120], [0, 0, 0]]),
        np.diag([1e7, 1e7, 1.0]) + np.array([[0, 0, 160], [0, 0, 120], [0, 0, 0]]),
        np.diag([188.0, 188.0, 1.0]) + np.array([[0, 0, 1e5], [0, 0, 120], [0, 0, 0]]),
        np.eye(2),
    ],
    ids=["zeros", "nan", "negative_f", "huge_f", "principal_point_off_image", "2x2"],
)
def test_absurd_intrinsics_are_refused(frames, K) -> None:
    f = frames["left"]
    res = locate_handle(f.depth, K, f.position, f.orientation, f.handles["left"][0])
    assert not res.ok and res.reason == "bad_input" and res.detail


def test_other_bad_input(frames) -> None:
    f = frames["left"]
    truth = f.handles["left"][0]
    cases = [
        (f.depth[0], f.K, f.position, f.orientation, truth),  # 1-D depth
        (f.depth, f.K, f.position, np.zeros(4), truth),  # no rotation
        (f.depth, f.K, f.position, f.orientation, np.array([np.inf, 0, 0])),
        (f.depth, f.K, [1, 2], f.orientation, truth),
        ("depth", f.K, f.position, f.orientation, truth),
    ]
    for args in cases:
        res = locate_handle(*args)
        assert not res.ok and res.reason == "bad_input", res.detail
    # NaN/inf/negative depths are no returns, not errors
    d = f.depth.copy()
    d[:10] = np.nan
    d[10:20] = -1.0
    d[20:30] = np.inf
    assert locate_handle(d, f.K, f.position, f.orientation, truth).ok


def test_expected_place_out_of_view(frames) -> None:
    f = frames["left"]
    behind = np.array([-1.0, 0.0, 0.0])  # behind the robot
    assert _locate(f, behind).reason == "not_in_view"
    high = f.handles["top"][0] + np.array([0.0, 0.0, 2.0])  # far above the image
    assert _locate(f, high).reason == "not_in_view"


def test_deterministic_and_config_checked(frames) -> None:
    f = frames["right"]
    truth = f.handles["right"][0] + 0.04
    a, b = _locate(f, truth), _locate(f, truth)
    np.testing.assert_array_equal(a.position, b.position)
    with pytest.raises(ValueError):
        HandleConfig(min_protrusion=0.1, max_protrusion=0.05)
    with pytest.raises(ValueError):
        HandleConfig(roi_radius=-1.0)


def test_arm_in_table_search_posture_does_not_matter() -> None:
    f = _render("top", "table_search")
    truth, out = f.handles["top"]
    res = _locate(f, truth + np.array([-0.04, 0.05, -0.03]))
    assert res.ok, res.detail
    assert np.linalg.norm(res.position - truth) < POS_TOL
    assert _angle_deg(res.pull_direction, out) < ANGLE_TOL
