"""Sensors against geometry: LiDAR ranges to a wall, depth of known planes, K from fovy, IMU.

The world is the robot (home pose, not stepped) on a floor with a wall 2 m ahead, so every
expected number follows from the model's poses and plane geometry.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import mujoco  # noqa: E402
import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.sim.sensors import (
    CameraConfig,
    Imu,
    ImuConfig,
    Lidar,
    LidarConfig,
    RgbdRenderer,
    intrinsics,
)

pytestmark = pytest.mark.unit

WALL_X = 2.0  # world x of the wall's near face


@pytest.fixture(scope="module")
def scene():
    spec = rd.robot_spec()
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], group=0
    )
    spec.worldbody.add_geom(
        name="wall",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.05, 4.0, 1.5],
        pos=[WALL_X + 0.05, 0.0, 1.5],
        group=0,
    )
    spec.worldbody.add_light(pos=[0, 0, 3], dir=[0, 0, -1], castshadow=False)
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key(rd.HOME_KEY).id)
    mujoco.mj_forward(m, d)
    return m, d


def test_lidar_sees_wall_at_known_distance(scene):
    m, d = scene
    cfg = LidarConfig(rays=360, noise=0.01)
    lidar = Lidar(m, cfg, np.random.default_rng(0))
    s = lidar.read(d)
    assert s.ranges.shape == (360,) and s.ranges.dtype == np.float32
    site = d.site_xpos[m.site(rd.LIDAR_SITE).id]
    angles = s.angle_min + s.angle_increment * np.arange(360)
    front = np.abs(angles) < np.deg2rad(40)
    expected = (WALL_X - site[0]) / np.cos(angles[front])
    err = s.ranges[front] - expected
    # Unbiased (mean within 3 sigma of the mean), single rays within 3 sigma (all but the
    # 0.3 % Gaussian tail, none beyond 5 sigma), and the noise has about the right size.
    n = err.size
    assert abs(err.mean()) < 3 * cfg.noise / np.sqrt(n)
    assert np.mean(np.abs(err) < 3 * cfg.noise) > 0.97
    assert np.all(np.abs(err) < 5 * cfg.noise)
    assert 0.5 * cfg.noise < np.std(err) < 1.5 * cfg.noise
    # Behind the robot there is nothing within 12 m: no return (0), and the robot's own
    # body (legs, arm) is never reported.
    back = np.abs(angles) > np.deg2rad(100)
    assert np.all(s.ranges[back] == 0.0)
    assert np.all((s.ranges == 0) | (s.ranges >= cfg.range_min))


def test_intrinsics_from_fovy():
    K = intrinsics(60.0, 320, 240)
    # f = (H/2) / tan(fovy/2): 120 / tan(30 deg) = 207.846 px; principal point at centre.
    assert K[1, 1] == pytest.approx(120 / np.tan(np.pi / 6))
    assert K[0, 0] == K[1, 1]
    assert (K[0, 2], K[1, 2]) == (159.5, 119.5)


def _expected_depth(K, p_wc, r_wc, h, w):
    """Planar depth of the floor (z=0) and the wall (x=WALL_X) seen through K."""
    v, u = np.mgrid[0:h, 0:w]
    rays_cam = np.linalg.solve(K, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
    rays_w = r_wc @ rays_cam  # depth-1 rays in world (z_cam = 1)
    depth = np.full(u.size, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = -p_wc[2] / rays_w[2]
        t_wall = (WALL_X - p_wc[0]) / rays_w[0]
    for t in (t_floor, t_wall):
        ok = np.isfinite(t) & (t > 0)
        depth[ok] = np.minimum(depth[ok], t[ok])
    return depth.reshape(h, w)


@pytest.mark.parametrize("size", [(320, 240), (160, 120)])
def test_front_depth_matches_plane_geometry(scene, size):
    m, d = scene
    w, h = size
    r = RgbdRenderer(m, {rd.FRONT_CAMERA: CameraConfig(width=w, height=h, far=10.0)})
    try:
        f = r.render(d, rd.FRONT_CAMERA)
    finally:
        r.close()
    assert f.rgb.shape == (h, w, 3) and f.rgb.dtype == np.uint8
    assert f.depth.shape == (h, w) and f.depth.dtype == np.float32
    fovy = m.cam_fovy[m.camera(rd.FRONT_CAMERA).id]
    np.testing.assert_allclose(f.K, intrinsics(fovy, w, h))
    # Camera pose in the base frame -> world, then ray-plane intersections.
    base = m.body(rd.BASE_BODY).id
    r_wb = d.xmat[base].reshape(3, 3)
    r_bc = np.zeros(9)
    mujoco.mju_quat2Mat(r_bc, f.orientation)
    r_wc = r_wb @ r_bc.reshape(3, 3)
    p_wc = d.xpos[base] + r_wb @ f.position
    # The optical z axis looks forward (+x) and pitched down; x points right (-y).
    assert r_wc[0, 2] > 0.9 and r_wc[2, 2] < 0 and r_wc[1, 0] < -0.9
    exp = _expected_depth(f.K, p_wc, r_wc, h, w)
    got = f.depth.astype(float)
    # Skip the pixels on the wall/floor edge (a pixel covers both planes there).
    edge = np.zeros_like(got, dtype=bool)
    v_edge = np.abs(np.diff(exp, axis=0)) > 0.05
    edge[:-1] |= v_edge
    edge[1:] |= v_edge
    rel = np.abs(got - exp)[~edge] / exp[~edge]
    assert np.all(got > 0)
    assert np.percentile(rel, 99) < 2e-3
    assert np.max(rel) < 1e-2


def test_depth_zero_beyond_far(scene):
    m, d = scene
    r = RgbdRenderer(m, {rd.FRONT_CAMERA: CameraConfig(width=80, height=60, far=1.0)})
    try:
        f = r.render(d, rd.FRONT_CAMERA)
    finally:
        r.close()
    # The wall (about 1.8 m) is beyond far = 1 m: no return; the near floor is seen.
    assert np.all(f.depth[: 60 // 3] == 0.0)
    assert np.all(f.depth[-3:] > 0.0) and np.all(f.depth[-3:] <= 1.0)


def test_imu_noise_matches_config(scene):
    m, d = scene
    cfg = ImuConfig(gyro_noise=0.01, gyro_bias=0.0, accel_noise=0.05, accel_bias=0.0)
    imu = Imu(m, cfg, np.random.default_rng(1))
    dd = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dd, m.key(rd.HOME_KEY).id)
    dd.qvel[:] = 0
    mujoco.mj_forward(m, dd)
    # The state is not stepped, so the readings differ only by the sensor noise.
    readings = [imu.read(dd) for _ in range(400)]
    quat = np.array([r.orientation for r in readings])
    gyro = np.array([r.angular_velocity for r in readings])
    np.testing.assert_allclose(quat, np.tile([1, 0, 0, 0], (400, 1)), atol=1e-9)
    assert np.abs(gyro.mean(axis=0)).max() < 4 * cfg.gyro_noise / np.sqrt(400)
    assert np.std(gyro) == pytest.approx(cfg.gyro_noise, rel=0.15)
    acc = np.array([r.linear_acceleration for r in readings])
    assert np.std(acc - acc.mean(axis=0)) == pytest.approx(cfg.accel_noise, rel=0.15)


def test_imu_orientation_noise(scene):
    m, _ = scene
    dd = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dd, m.key(rd.HOME_KEY).id)
    mujoco.mj_forward(m, dd)
    sigma = 0.01
    imu = Imu(m, ImuConfig(orientation_noise=sigma), np.random.default_rng(2))
    quats = np.array([imu.read(dd).orientation for _ in range(500)])
    # Angle from the true (level) attitude: RMS of a 3-axis rotation vector = sqrt(3) sigma.
    angles = 2 * np.arccos(np.clip(np.abs(quats[:, 0]), -1, 1))
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(np.sqrt(3) * sigma, rel=0.1)
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)
