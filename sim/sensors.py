"""The robot's sensors, computed from the MuJoCo state the way real devices would see it.

* Encoders: joint positions and velocities, and the torque the motors apply.
* IMU: orientation, gyro and accelerometer from the model's sensors on the ``imu`` site,
  with configurable white noise and a constant bias per run (drawn once from the seed),
  as a MEMS IMU has.
* RGB-D cameras: one OpenGL pass per camera reads colour and depth together
  (``mjr_readPixels`` with both buffers), so depth costs no second render. Shadows,
  reflections, skybox and anti-aliasing are off, since they cost most of the time in
  software rendering and add nothing a detector needs. Depth is metric planar depth along
  the optical axis (what an RGB-D camera reports); pixels with no return before the far
  limit are 0. Intrinsics K follow OpenCV (x right, y down, z forward; pixel centres at
  integer coordinates) from the camera's ``fovy`` and the image size.
* 2D LiDAR: ``mj_multiRay`` from the ``lidar`` site in its horizontal plane against the
  world's geom groups; a ray that still hits one of the robot's own geoms is continued past
  it (a real LiDAR on a robot is mounted/masked so it does not see itself); Gaussian range
  noise; readings outside
  [range_min, range_max] are reported as 0 ("no return", the LaserScan contract: the wire
  carries no inf/NaN).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import mujoco
import numpy as np
from quadmanip.common.rotations import mat_to_quat, quat_from_axis_angle, quat_mul

# MuJoCo cameras look along -z with y up; OpenCV's optical frame looks along +z with y down.
_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class ImuConfig:
    """IMU noise model (section ``[sensors.imu]``)."""

    gyro_noise: float = 0.002  # rad/s, white noise std per sample
    gyro_bias: float = 0.001  # rad/s, std of the constant per-run bias
    accel_noise: float = 0.02  # m/s^2
    accel_bias: float = 0.02  # m/s^2
    orientation_noise: float = 0.0  # rad, small-angle noise on the reported attitude


@dataclass(frozen=True)
class CameraConfig:
    """One RGB-D camera (``[sensors.front_camera]``, ``[sensors.gripper_camera]``)."""

    width: int = 320
    height: int = 240
    rate: float = 10.0  # Hz
    near: float = 0.05  # m, depth below this is 0 (too close to measure)
    far: float = 10.0  # m, no return beyond this (depth 0)


@dataclass(frozen=True)
class LidarConfig:
    """2D LiDAR (``[sensors.lidar]``)."""

    rays: int = 360
    range_min: float = 0.1
    range_max: float = 12.0
    noise: float = 0.01  # m, Gaussian std on each valid range
    rate: float = 10.0  # Hz
    # Geom groups the rays can hit: the world's (0, 1), not the robot's (2 visual,
    # 3 collision; see the robot description). Robot geoms in a visible group are
    # skipped anyway.
    geomgroup: tuple[int, int, int, int, int, int] = (1, 1, 0, 0, 0, 0)


@dataclass(frozen=True)
class RenderConfig:
    """``[sensors.render]``: tessellation of MuJoCo's built-in shapes in camera images.

    Fewer slices/stacks/quads than MuJoCo's defaults (28/16/4) cut software-rendering time
    by about a fifth with no visible difference at 320x240 (measured, docs/sim.md).
    """

    numslices: int = 12
    numstacks: int = 8
    numquads: int = 1


@dataclass(frozen=True)
class SensorsConfig:
    """All sensors (section ``[sensors]`` of configs/sim.toml)."""

    seed: int = 0
    render: RenderConfig = RenderConfig()
    imu: ImuConfig = ImuConfig()
    front_camera: CameraConfig = CameraConfig()
    gripper_camera: CameraConfig = CameraConfig()
    lidar: LidarConfig = LidarConfig()


def _site(model: mujoco.MjModel, name: str) -> int:
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
    if sid < 0:
        raise KeyError(f"site {name!r} not in the model")
    return sid


# --------------------------------------------------------------------------- IMU


@dataclass(frozen=True)
class ImuReading:
    orientation: np.ndarray  # [w, x, y, z], world -> imu frame
    angular_velocity: np.ndarray  # rad/s, imu frame
    linear_acceleration: np.ndarray  # m/s^2, imu frame, specific force (+g at rest)


class Imu:
    """Orientation, gyro and accelerometer from the model's sensors on a site."""

    def __init__(
        self, model: mujoco.MjModel, config: ImuConfig, rng: np.random.Generator, site: str = "imu"
    ) -> None:
        self.config = config
        self.rng = rng
        sid = _site(model, site)
        self._site = sid
        self._adr: dict[int, int] = {}
        wanted = {
            mujoco.mjtSensor.mjSENS_FRAMEQUAT,
            mujoco.mjtSensor.mjSENS_GYRO,
            mujoco.mjtSensor.mjSENS_ACCELEROMETER,
        }
        for i in range(model.nsensor):
            st = int(model.sensor_type[i])
            on_site = (
                model.sensor_objtype[i] == mujoco.mjtObj.mjOBJ_SITE and model.sensor_objid[i] == sid
            )
            if st in wanted and on_site and st not in self._adr:
                if model.sensor_noise[i] != 0:
                    raise ValueError("IMU sensors must have noise=0; the sim adds its own noise")
                self._adr[st] = int(model.sensor_adr[i])
        self._gyro_bias = rng.normal(0.0, config.gyro_bias, 3)
        self._accel_bias = rng.normal(0.0, config.accel_bias, 3)

    def _sensor(self, data: mujoco.MjData, st: int, n: int) -> np.ndarray | None:
        adr = self._adr.get(int(st))
        return None if adr is None else data.sensordata[adr : adr + n].copy()

    def read(self, data: mujoco.MjData) -> ImuReading:
        """Noisy reading of the current state (sensors must be up to date)."""
        cfg = self.config
        quat = self._sensor(data, mujoco.mjtSensor.mjSENS_FRAMEQUAT, 4)
        if quat is None:
            quat = mat_to_quat(data.site_xmat[self._site])
        gyro = self._sensor(data, mujoco.mjtSensor.mjSENS_GYRO, 3)
        acc = self._sensor(data, mujoco.mjtSensor.mjSENS_ACCELEROMETER, 3)
        if gyro is None or acc is None:
            raise ValueError("the model needs gyro and accelerometer sensors on the IMU site")
        if cfg.orientation_noise > 0:
            # Small random rotation: rotation vector with std orientation_noise per axis.
            rv = self.rng.normal(0.0, cfg.orientation_noise, 3)
            dq = quat_from_axis_angle(rv / max(np.linalg.norm(rv), 1e-12), np.linalg.norm(rv))
            quat = quat_mul(quat, dq)
        quat = quat / np.linalg.norm(quat)
        noise = self.rng.standard_normal(6)
        gyro = gyro + self._gyro_bias + cfg.gyro_noise * noise[:3]
        acc = acc + self._accel_bias + cfg.accel_noise * noise[3:]
        return ImuReading(quat, gyro, acc)


# --------------------------------------------------------------------------- cameras


def gl_context_class() -> type:
    """The OpenGL context to render with. MuJoCo picks one from ``MUJOCO_GL`` when it is
    first imported; honour ``MUJOCO_GL`` as it is now (it may be set after that import),
    and on a headless Linux box (no DISPLAY) with it unset use EGL (software llvmpipe
    without a GPU) rather than GLFW, which cannot open a window there."""
    backend = os.environ.get("MUJOCO_GL", "").strip().lower()
    headless = sys.platform.startswith("linux") and not os.environ.get("DISPLAY")
    if backend == "egl" or (backend in ("", "glfw") and headless):
        from mujoco.egl import GLContext

        return GLContext
    if backend == "osmesa":
        from mujoco.osmesa import GLContext as OsMesaContext

        return OsMesaContext
    return mujoco.GLContext


def intrinsics(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """OpenCV K of a pinhole camera with vertical field of view ``fovy`` (square pixels).

    MuJoCo's frustum is symmetric, so the principal point is the image centre, which in
    OpenCV's pixel-centre convention is ((W-1)/2, (H-1)/2).
    """
    f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RgbdFrame:
    camera: str
    rgb: np.ndarray  # uint8 [H, W, 3]
    depth: np.ndarray  # float32 [H, W], metres, 0 = no return
    K: np.ndarray  # 3x3
    position: np.ndarray  # camera origin in the base frame
    orientation: np.ndarray  # [w,x,y,z], base -> optical frame (x right, y down, z fwd)


class RgbdRenderer:
    """Renders colour + depth of several model cameras with one shared GL context.

    Must be created and used in the same thread (OpenGL contexts are thread-bound).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        cameras: dict[str, CameraConfig],
        base_body: str = "base",
        render: RenderConfig | None = None,
    ) -> None:
        self.model = model
        self.cameras = dict(cameras)
        w = max(c.width for c in cameras.values())
        h = max(c.height for c in cameras.values())
        # Visual settings only; physics does not read them.
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), w)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), h)
        model.vis.quality.offsamples = 0  # no MSAA: a large cost in software GL
        model.vis.quality.shadowsize = 0
        rc = render or RenderConfig()
        model.vis.quality.numslices = rc.numslices
        model.vis.quality.numstacks = rc.numstacks
        model.vis.quality.numquads = rc.numquads
        self._cam_ids = {}
        for name in cameras:
            cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid < 0:
                raise KeyError(f"camera {name!r} not in the model")
            self._cam_ids[name] = cid
        self._base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, base_body)
        self._gl = gl_context_class()(
            int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        )
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=20000)
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
            mujoco.mjtRndFlag.mjRND_FOG,
            mujoco.mjtRndFlag.mjRND_HAZE,
        ):
            self._scene.flags[flag] = 0
        self._opt = mujoco.MjvOption()
        self._opt.flags[mujoco.mjtVisFlag.mjVIS_RANGEFINDER] = 0
        self._pert = mujoco.MjvPerturb()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._buffers = {
            n: (
                np.empty((c.height, c.width, 3), np.uint8),
                np.empty((c.height, c.width), np.float32),
            )
            for n, c in cameras.items()
        }

    def intrinsics(self, camera: str) -> np.ndarray:
        c = self.cameras[camera]
        return intrinsics(float(self.model.cam_fovy[self._cam_ids[camera]]), c.width, c.height)

    def pose_in_base(self, data: mujoco.MjData, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """Optical-frame pose of the camera in the base frame: (position, quat wxyz)."""
        cid = self._cam_ids[camera]
        r_wb = data.xmat[self._base].reshape(3, 3)
        p_wb = data.xpos[self._base]
        r_wc = data.cam_xmat[cid].reshape(3, 3) @ _MJ_TO_CV
        p = r_wb.T @ (data.cam_xpos[cid] - p_wb)
        return p, mat_to_quat(r_wb.T @ r_wc)

    def _update_scene(self, data: mujoco.MjData, camera: str) -> CameraConfig:
        """Make the GL context current and fill the scene as ``camera`` sees ``data``."""
        self._gl.make_current()
        self._cam.fixedcamid = self._cam_ids[camera]
        mujoco.mjv_updateScene(
            self.model,
            data,
            self._opt,
            self._pert,
            self._cam,
            mujoco.mjtCatBit.mjCAT_ALL,
            self._scene,
        )
        return self.cameras[camera]

    def render(self, data: mujoco.MjData, camera: str) -> RgbdFrame:
        """One render pass → colour and metric depth of ``camera`` (kinematics current)."""
        cfg = self._update_scene(data, camera)
        rect = mujoco.MjrRect(0, 0, cfg.width, cfg.height)
        mujoco.mjr_render(rect, self._scene, self._ctx)
        rgb, zbuf = self._buffers[camera]
        mujoco.mjr_readPixels(rgb, zbuf, rect, self._ctx)
        depth = self._linearize(zbuf, cfg)
        pos, quat = self.pose_in_base(data, camera)
        return RgbdFrame(
            camera=camera,
            rgb=np.ascontiguousarray(np.flipud(rgb)),
            depth=np.ascontiguousarray(np.flipud(depth)),
            K=self.intrinsics(camera),
            position=pos,
            orientation=quat,
        )

    def render_segmentation(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """Per-pixel geom id of ``camera`` (-1 where no geom), row 0 at the top.

        Labels for offline datasets and tests only: a real camera has no such image, and
        the sim never publishes it.
        """
        cfg = self._update_scene(data, camera)
        flags = (mujoco.mjtRndFlag.mjRND_SEGMENT, mujoco.mjtRndFlag.mjRND_IDCOLOR)
        for f in flags:
            self._scene.flags[f] = 1
        try:
            rect = mujoco.MjrRect(0, 0, cfg.width, cfg.height)
            mujoco.mjr_render(rect, self._scene, self._ctx)
            rgb = np.empty((cfg.height, cfg.width, 3), np.uint8)
            mujoco.mjr_readPixels(rgb, None, rect, self._ctx)
        finally:
            for f in flags:
                self._scene.flags[f] = 0
        # with IDCOLOR each scene geom is drawn in the colour of its segid + 1 (0: none)
        idx = rgb[..., 0].astype(np.int64) + (rgb[..., 1].astype(np.int64) << 8)
        idx += rgb[..., 2].astype(np.int64) << 16
        n = self._scene.ngeom
        lut = np.full(n + 2, -1, np.int64)
        for g in self._scene.geoms[:n]:
            if 0 <= g.segid <= n and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[g.segid + 1] = g.objid
        return np.ascontiguousarray(np.flipud(lut[np.clip(idx, 0, n + 1)]))

    def _linearize(self, zbuf: np.ndarray, cfg: CameraConfig) -> np.ndarray:
        """Reverse-Z buffer (1 at near, 0 at far) → metric depth, 0 where no return."""
        extent = self.model.stat.extent
        znear = np.float32(self.model.vis.map.znear * extent)
        zfar = np.float32(self.model.vis.map.zfar * extent)
        c = -(zfar + znear) / (zfar - znear)
        d = -(np.float32(2) * zfar * znear) / (zfar - znear)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        z = zbuf.astype(np.float64)
        with np.errstate(divide="ignore"):
            depth = d / (z + c)
        bad = (zbuf <= 0.0) | (depth > cfg.far) | (depth < cfg.near) | ~np.isfinite(depth)
        depth[bad] = 0.0
        return depth.astype(np.float32)

    def close(self) -> None:
        if self._ctx is not None:
            self._gl.make_current()
            self._ctx.free()
            self._ctx = None
            self._gl.free()


# --------------------------------------------------------------------------- LiDAR


@dataclass(frozen=True)
class ScanReading:
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray  # float32 [N]; 0 where there is no return


class Lidar:
    """2D 360-degree LiDAR in the horizontal plane of the ``lidar`` site."""

    def __init__(
        self,
        model: mujoco.MjModel,
        config: LidarConfig,
        rng: np.random.Generator,
        robot_root: str = "base",
        site: str = "lidar",
    ) -> None:
        self.model = model
        self.config = config
        self.rng = rng
        self._site = _site(model, site)
        n = config.rays
        self.angle_min = -np.pi
        self.angle_increment = 2 * np.pi / n
        ang = self.angle_min + self.angle_increment * np.arange(n)
        self._local = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], axis=1)
        root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, robot_root)
        self._robot_geom = model.body_rootid[model.geom_bodyid] == model.body_rootid[root]
        self._geomid = np.zeros(n, np.int32)
        self._dist = np.zeros(n)
        self._groups = np.asarray(config.geomgroup, dtype=np.uint8)

    def read(self, data: mujoco.MjData) -> ScanReading:
        cfg = self.config
        m = self.model
        origin = data.site_xpos[self._site].copy()
        rot = data.site_xmat[self._site].reshape(3, 3)
        vec = self._local @ rot.T
        mujoco.mj_multiRay(
            m,
            data,
            origin,
            vec.reshape(-1),
            self._groups,
            1,
            -1,
            self._geomid,
            self._dist,
            None,
            cfg.rays,
            cfg.range_max + 1.0,
        )
        dist = self._dist.copy()
        gid = self._geomid
        # Continue rays that hit the robot itself past the robot's geoms.
        for i in np.flatnonzero((gid >= 0) & self._robot_geom[np.maximum(gid, 0)]):
            travelled = 0.0
            g = int(gid[i])
            d = float(dist[i])
            hit = np.zeros(1, np.int32)
            for _ in range(8):
                if g < 0 or not self._robot_geom[g]:
                    break
                travelled += d + 1e-4
                p = origin + travelled * vec[i]
                d = mujoco.mj_ray(m, data, p, vec[i], self._groups, 1, int(m.geom_bodyid[g]), hit)
                g = int(hit[0])
            dist[i] = travelled + d if g >= 0 and not self._robot_geom[g] else -1.0
        ranges = dist + self.rng.normal(0.0, cfg.noise, cfg.rays)
        invalid = (dist < 0) | (ranges < cfg.range_min) | (ranges > cfg.range_max)
        ranges[invalid] = 0.0
        return ScanReading(
            angle_min=float(self.angle_min),
            angle_increment=float(self.angle_increment),
            range_min=cfg.range_min,
            range_max=cfg.range_max,
            ranges=ranges.astype(np.float32),
        )
