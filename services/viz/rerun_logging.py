"""Decoded quadmanip messages → Rerun archetypes (no transport: pure functions + small state).

Every ``log_*`` function takes a decoded message and a ``rr.RecordingStream`` (or anything
:class:`RecordingLike`), sets the
robot-time timeline (:data:`TIMELINE`, seconds of the message's ``stamp``) on the calling
thread and logs under a fixed entity tree, so a recording from any run opens with the
same layout (:func:`blueprint`)::

    world                         z-up, x forward (the sim's world; odom starts there)
    world/odom                    odom frame; placed in the world from ground truth when
                                  the sim publishes it (display only), else identity
    world/odom/base               estimated base pose (locomotion/odometry)
    world/odom/base/body          trunk box + stick figure from measured joint angles
    world/odom/base/foot_forces   MPC ground reaction forces as arrows at the feet
    world/odom/base/<camera>      base_T_camera + Pinhole(K); ./rgb, ./depth
    world/odom/base/lidar/scan    2D LiDAR returns (lidar frame; mount from the description)
    world/odom/base/<camera>/detections
                                  perception's boxes ("label score") on that camera's image
    world/odom/perception/objects the object memory: 3-D boxes "label #id" (odom frame)
    world/odom/perception/detections/<camera>
                                  located detections' centroids (odom frame)
    world/odom/trajectory         odometry trail; world/odom/mpc_prediction the MPC horizon
    world/gt/...                  GROUND TRUTH (sim only): base, base_trajectory, objects,
                                  contacts — its own tree, never mixed with estimates
    plots/...                     time series: joints, arm (measured vs commanded trajectory),
                                  IMU, gripper (gap vs command), velocity (cmd/odom/gt),
                                  locomotion (foot forces, gait phase, contact, MPC solve ms)
    log/...                       text logs: judge verdicts, heartbeats (state changes), viz

Quaternions arrive [w, x, y, z] on the wire (conventions.md) and go to Rerun as [x, y, z, w].
"""

from __future__ import annotations

import math
import re
import zlib
from collections import deque
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from quadmanip.common.joint_layout import ARM_JOINTS, ARM_SLICE, JOINTS, LEG_NAMES
from quadmanip.common.rotations import quat_from_yaw, quat_to_mat, rot_z, wrap_angle, yaw_from_quat

if TYPE_CHECKING:  # messages only name the inputs' types: this module imports no transport
    from quadmanip.common import messages as m

__all__ = [
    "BASE",
    "EveryNth",
    "GT",
    "LOG",
    "ODOM",
    "PERCEPTION",
    "PLOTS",
    "WORLD",
    "TIMELINE",
    "HeartbeatTracker",
    "RecordingLike",
    "RateLimiter",
    "Trail",
    "VelocityFromPoses",
    "blueprint",
    "camera_entity",
    "detection_time",
    "label_color",
    "log_arm_trajectory",
    "log_detections",
    "log_foot_forces",
    "log_gt_base",
    "log_gt_contacts",
    "log_gripper_command",
    "log_gt_objects",
    "log_heartbeat",
    "log_judge",
    "log_lidar_mount",
    "log_locomotion_debug",
    "log_lowstate",
    "log_odom_alignment",
    "log_object_tracks",
    "log_odometry",
    "log_rgbd",
    "log_robot_body",
    "log_scan",
    "log_skeleton",
    "log_static_layout",
    "log_text",
    "log_trail",
    "log_velocity_command",
    "log_velocity_estimate",
    "odom_in_world",
    "quat_xyzw",
    "scan_points",
    "set_time",
]

TIMELINE = "robot_time"
"""The timeline every message is logged on: its ``stamp`` (robot time, s)."""

WORLD = "world"
ODOM = "world/odom"
BASE = "world/odom/base"
GT = "world/gt"
PERCEPTION = "world/odom/perception"  # perception's estimates live in odom, like its centroids
PLOTS = "plots"
LOG = "log"

# Joint order on the wire: common/joint_layout.py (no MuJoCo import, unlike the description).

_FOOT_COLORS = np.array(
    [[230, 60, 60], [60, 160, 230], [240, 170, 30], [90, 190, 90]], dtype=np.uint8
)
_GT_COLOR = np.array([255, 200, 0], dtype=np.uint8)  # ground truth: always amber
_ODOM_COLOR = np.array([40, 140, 255], dtype=np.uint8)
_MPC_COLOR = np.array([200, 60, 220], dtype=np.uint8)
_ENTITY_RE = re.compile(r"[^A-Za-z0-9_\-]")
# Object classes: one colour per label (stable across runs and between detections and
# tracks, so a "cup" box on the image and its 3-D track match); no amber (ground truth).
_LABEL_PALETTE = np.array(
    [
        [31, 119, 180],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [23, 190, 207],
        [227, 119, 194],
        [140, 86, 75],
        [188, 189, 34],
        [255, 127, 14],
        [0, 128, 128],
    ],
    dtype=np.uint8,
)


# --------------------------------------------------------------------------- helpers


class RecordingLike(Protocol):
    """What the converters need of a recording: ``rr.RecordingStream`` or a tee of them."""

    def log(self, entity_path: str, entity: Any, *extra: Any, static: bool = False) -> None: ...

    def set_time(self, timeline: str, *, duration: float | None = None) -> None: ...

    def send_columns(self, entity_path: str, indexes: Any, columns: Any) -> None: ...


def set_time(rec: RecordingLike, stamp: float) -> None:
    """Put the calling thread's :data:`TIMELINE` at ``stamp`` (Rerun's time is per thread)."""
    rec.set_time(TIMELINE, duration=float(stamp))


def quat_xyzw(q_wxyz: Sequence[float] | np.ndarray) -> rr.Quaternion:
    """Wire quaternion [w, x, y, z] → Rerun quaternion (stored [x, y, z, w])."""
    w, x, y, z = (float(v) for v in q_wxyz)
    return rr.Quaternion(xyzw=[x, y, z, w])


def camera_entity(camera: str) -> str:
    """Entity path of a camera (``front_camera`` → ``world/odom/base/front_camera``)."""
    name = _ENTITY_RE.sub("_", camera.strip()) or "camera"
    return f"{BASE}/{name}"


def log_text(rec: RecordingLike, path: str, stamp: float, text: str, level: str) -> None:
    """One :class:`rr.TextLog` line at ``path`` (level: INFO, WARN, ERROR ...)."""
    set_time(rec, stamp)
    rec.log(path, rr.TextLog(text, level=level))


# --------------------------------------------------------------------------- static layout


def log_static_layout(rec: RecordingLike) -> None:
    """Static parts of the tree: world axes convention, series names, per-series colours.

    Logged once at start; the time series then carry bare :class:`rr.Scalars` batches whose
    i-th value is the i-th named series.
    """
    rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        f"{GT}",
        rr.TextDocument("GROUND TRUTH from the simulator (not seen by services)"),
        static=True,
    )
    rec.log(BASE, rr.TransformAxes3D(0.25), static=True)
    rec.log(f"{GT}/base", rr.TransformAxes3D(0.2), static=True)
    for quantity in ("position", "velocity", "torque"):
        rec.log(f"{PLOTS}/joints/{quantity}", rr.SeriesLines(names=list(JOINTS)), static=True)
    arm = list(ARM_JOINTS)
    rec.log(f"{PLOTS}/arm/q", rr.SeriesLines(names=arm), static=True)
    rec.log(
        f"{PLOTS}/arm/q_cmd",
        rr.SeriesLines(names=[f"{j} cmd" for j in arm], widths=[1.0] * len(arm)),
        static=True,
    )
    rec.log(f"{PLOTS}/imu/angular_velocity", rr.SeriesLines(names=["wx", "wy", "wz"]), static=True)
    rec.log(
        f"{PLOTS}/imu/linear_acceleration", rr.SeriesLines(names=["ax", "ay", "az"]), static=True
    )
    for what in ("foot_force_z", "gait_phase", "contact"):
        rec.log(
            f"{PLOTS}/locomotion/{what}",
            rr.SeriesLines(names=list(LEG_NAMES), colors=_FOOT_COLORS),
            static=True,
        )
    colors = {"cmd": [150, 150, 150], "odom": _ODOM_COLOR, "gt": _GT_COLOR}
    for axis in ("vx", "vy", "wz"):
        for source, color in colors.items():
            rec.log(
                f"{PLOTS}/velocity/{axis}/{source}",
                rr.SeriesLines(names=[f"{axis} {source}"], colors=[color]),
                static=True,
            )


def blueprint() -> rrb.Blueprint:
    """Default viewer layout: 3D world | cameras | plots, text logs below."""
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(origin=WORLD, name="world (odom + ground truth)"),
                rrb.Vertical(
                    rrb.Spatial2DView(origin=camera_entity("front_camera"), name="front camera"),
                    rrb.Spatial2DView(
                        origin=camera_entity("gripper_camera"), name="gripper camera"
                    ),
                ),
                rrb.Tabs(
                    rrb.TimeSeriesView(origin=f"{PLOTS}/velocity", name="velocity"),
                    rrb.TimeSeriesView(origin=f"{PLOTS}/locomotion", name="locomotion"),
                    rrb.TimeSeriesView(origin=f"{PLOTS}/joints", name="joints"),
                    rrb.TimeSeriesView(origin=f"{PLOTS}/imu", name="imu"),
                    rrb.TimeSeriesView(origin=f"{PLOTS}/gripper", name="gripper"),
                ),
                column_shares=[2, 1, 2],
            ),
            rrb.TextLogView(origin=LOG, name="log"),
            row_shares=[4, 1],
        ),
        collapse_panels=True,
    )


# --------------------------------------------------------------------------- robot state


def log_lowstate(rec: RecordingLike, msg: m.LowState) -> None:
    """Joint positions/velocities/torques (16 series each), gripper gap/effort, IMU rates."""
    set_time(rec, msg.stamp)
    js = msg.joints
    rec.log(f"{PLOTS}/joints/position", rr.Scalars(js.q))
    rec.log(f"{PLOTS}/joints/velocity", rr.Scalars(js.dq))
    rec.log(f"{PLOTS}/joints/torque", rr.Scalars(js.tau))
    rec.log(f"{PLOTS}/arm/q", rr.Scalars(js.q[ARM_SLICE]))
    rec.log(f"{PLOTS}/gripper/gap", rr.Scalars(js.gripper_gap))
    rec.log(f"{PLOTS}/gripper/effort", rr.Scalars(js.gripper_effort))
    rec.log(f"{PLOTS}/imu/angular_velocity", rr.Scalars(msg.imu.angular_velocity))
    rec.log(f"{PLOTS}/imu/linear_acceleration", rr.Scalars(msg.imu.linear_acceleration))


def log_arm_trajectory(rec: RecordingLike, msg: m.ArmTrajectory, max_points: int = 500) -> int:
    """The commanded arm trajectory, each point at its own (future) robot time, beside the
    measured arm joints (``plots/arm/q`` from LowState): tracking error at a glance.

    Logged once as columns; a trajectory that supersedes another mid-way leaves the old
    tail visible (it is what was sent). Long ones are thinned to ``max_points`` (the last
    point always kept). Returns the number of points logged.
    """
    n = len(msg.t)
    if n == 0:
        return 0
    idx = np.arange(n)
    if n > max_points:
        idx = np.unique(np.append(np.linspace(0, n - 1, max_points).astype(int), n - 1))
    rec.send_columns(
        f"{PLOTS}/arm/q_cmd",
        indexes=[rr.TimeColumn(TIMELINE, duration=msg.t[idx])],
        columns=rr.Scalars.columns(scalars=msg.q[idx]),
    )
    return len(idx)


def log_gripper_command(rec: RecordingLike, msg: m.GripperCommand) -> None:
    """Commanded finger gap (m) beside the measured one, and the force limit (N)."""
    set_time(rec, msg.stamp)
    rec.log(f"{PLOTS}/gripper/gap_cmd", rr.Scalars(msg.gap))
    rec.log(f"{PLOTS}/gripper/max_force_cmd", rr.Scalars(msg.max_force))


def log_odometry(rec: RecordingLike, msg: m.Odometry) -> None:
    """Estimated base pose → transform of :data:`BASE`; base-frame velocity → plots."""
    set_time(rec, msg.stamp)
    rec.log(
        BASE,
        rr.Transform3D(translation=msg.position, quaternion=quat_xyzw(msg.orientation)),
    )
    log_velocity_estimate(
        rec,
        "odom",
        msg.stamp,
        float(msg.linear_velocity[0]),
        float(msg.linear_velocity[1]),
        float(msg.angular_velocity[2]),
    )


def log_velocity_estimate(
    rec: RecordingLike, source: str, stamp: float, vx: float, vy: float, wz: float
) -> None:
    """Base-frame (vx, vy, wz) of one source (``cmd``, ``odom``, ``gt``) on shared plots, so
    commanded, estimated and true velocity overlay in one view per axis."""
    set_time(rec, stamp)
    for axis, value in (("vx", vx), ("vy", vy), ("wz", wz)):
        rec.log(f"{PLOTS}/velocity/{axis}/{source}", rr.Scalars(value))


def log_velocity_command(rec: RecordingLike, msg: m.BodyVelocityCommand) -> None:
    """The body velocity command (locomotion/cmd_vel) as the ``cmd`` velocity series."""
    log_velocity_estimate(rec, "cmd", msg.stamp, msg.vx, msg.vy, msg.wz)


def log_trail(
    rec: RecordingLike,
    path: str,
    stamp: float,
    points: np.ndarray,
    *,
    color: Sequence[int] | np.ndarray = _ODOM_COLOR,
) -> None:
    """A trajectory as one line strip (``points`` N×3 in the parent frame); < 2 points: no-op."""
    if len(points) < 2:
        return
    set_time(rec, stamp)
    rec.log(
        path, rr.LineStrips3D([np.asarray(points, dtype=np.float32)], colors=[color], radii=0.01)
    )


def log_locomotion_debug(rec: RecordingLike, msg: m.LocomotionDebug) -> None:
    """Foot forces (vertical component, N, ground on robot), gait phase, scheduled
    contact, MPC solve time, and the MPC's predicted base positions over the horizon as a
    line in the odom frame (the estimator's frame, where the MPC plans)."""
    set_time(rec, msg.stamp)
    rec.log(f"{PLOTS}/locomotion/foot_force_z", rr.Scalars(msg.foot_forces[:, 2]))
    rec.log(f"{PLOTS}/locomotion/gait_phase", rr.Scalars(msg.gait_phase))
    rec.log(f"{PLOTS}/locomotion/contact", rr.Scalars(msg.contact.astype(np.float64)))
    rec.log(f"{PLOTS}/locomotion/mpc_solve_ms", rr.Scalars(msg.mpc_solve_ms))
    pred = msg.mpc_predicted_positions
    if len(pred) >= 2:
        rec.log(
            f"{ODOM}/mpc_prediction",
            rr.LineStrips3D([pred.astype(np.float32)], colors=[_MPC_COLOR], radii=0.008),
        )


def log_robot_body(
    rec: RecordingLike, trunk_half_size: np.ndarray, trunk_center: np.ndarray
) -> None:
    """Static trunk box in the base frame (the legs and arm are the skeleton's lines)."""
    rec.log(
        f"{BASE}/body/trunk",
        rr.Boxes3D(half_sizes=[trunk_half_size], centers=[trunk_center], colors=[[120, 120, 130]]),
        static=True,
    )


def log_skeleton(rec: RecordingLike, stamp: float, segments: np.ndarray, feet: np.ndarray) -> None:
    """The robot's stick figure (segments K×2×3) and foot centres (4×3), base frame."""
    set_time(rec, stamp)
    rec.log(
        f"{BASE}/body/skeleton",
        rr.LineStrips3D(segments.astype(np.float32), radii=0.012, colors=[[70, 70, 80]]),
    )
    rec.log(
        f"{BASE}/body/feet",
        rr.Points3D(feet.astype(np.float32), radii=0.02, colors=_FOOT_COLORS),
    )


def log_foot_forces(
    rec: RecordingLike,
    stamp: float,
    feet_base: np.ndarray,
    forces_world: np.ndarray,
    base_orientation_wxyz: np.ndarray,
    metres_per_newton: float = 0.002,
) -> None:
    """Ground reaction forces (world frame, N; e.g. the MPC's) drawn as arrows at the feet.

    Arrows live under the base entity, so the world-frame forces are rotated into the base
    frame with the base orientation (``R^T f``).
    """
    r = quat_to_mat(base_orientation_wxyz)
    vectors = (np.asarray(forces_world, dtype=float) @ r) * metres_per_newton  # rows: R^T f
    set_time(rec, stamp)
    rec.log(
        f"{BASE}/foot_forces",
        rr.Arrows3D(
            origins=np.asarray(feet_base, dtype=np.float32),
            vectors=vectors.astype(np.float32),
            colors=_FOOT_COLORS,
            radii=0.008,
        ),
    )


# --------------------------------------------------------------------------- sensors


def log_rgbd(
    rec: RecordingLike,
    msg: m.RgbdImage,
    *,
    rgb: bool = True,
    depth: bool = True,
    jpeg_quality: int = 0,
) -> str:
    """A camera frame: base_T_camera transform, Pinhole from K (OpenCV optical frame: RDF),
    RGB image (raw, or JPEG if ``jpeg_quality`` in 1..100) and metric depth image.

    Returns the camera's entity path.
    """
    path = camera_entity(msg.camera)
    h, w = msg.depth.shape
    set_time(rec, msg.stamp)
    rec.log(path, rr.Transform3D(translation=msg.position, quaternion=quat_xyzw(msg.orientation)))
    rec.log(
        path,
        rr.Pinhole(
            image_from_camera=msg.K,
            resolution=[w, h],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.2,
        ),
    )
    if rgb and msg.rgb.size:
        image = rr.Image(msg.rgb, color_model="RGB")
        if 0 < jpeg_quality <= 100:
            image = image.compress(jpeg_quality=jpeg_quality)
        rec.log(f"{path}/rgb", image)
    if depth:
        # 0 = no return on the wire, which Rerun also treats as invalid.
        rec.log(f"{path}/depth", rr.DepthImage(msg.depth, meter=1.0))
    return path


def scan_points(msg: m.LaserScan) -> np.ndarray:
    """Valid LiDAR returns as N×3 points in the ``lidar`` frame (z = 0).

    A ray counts when ``range_min <= r <= range_max`` and r > 0 (0 means no return).
    """
    r = msg.ranges.astype(np.float64)
    angles = msg.angle_min + msg.angle_increment * np.arange(r.size)
    ok = (r > 0.0) & (r >= msg.range_min) & (r <= msg.range_max)
    pts = np.zeros((int(ok.sum()), 3), dtype=np.float32)
    pts[:, 0] = r[ok] * np.cos(angles[ok])
    pts[:, 1] = r[ok] * np.sin(angles[ok])
    return pts


def log_lidar_mount(
    rec: RecordingLike, position: Sequence[float], orientation_wxyz: Sequence[float]
) -> None:
    """Static base_T_lidar (from the robot description) so scans sit where the sensor is."""
    rec.log(
        f"{BASE}/lidar",
        rr.Transform3D(translation=list(position), quaternion=quat_xyzw(orientation_wxyz)),
        static=True,
    )


def log_scan(rec: RecordingLike, msg: m.LaserScan) -> int:
    """LiDAR returns as Points3D under ``world/odom/base/lidar/scan``; returns the count."""
    pts = scan_points(msg)
    set_time(rec, msg.stamp)
    rec.log(f"{BASE}/lidar/scan", rr.Points3D(pts, radii=0.015, colors=[[255, 80, 80]]))
    return len(pts)


# --------------------------------------------------------------------------- perception


def label_color(label: str) -> np.ndarray:
    """RGB (uint8) of an object class: a fixed palette entry picked by a CRC of the label,
    so it is the same in every run, on the image boxes and on the 3-D tracks."""
    return _LABEL_PALETTE[zlib.crc32(label.encode()) % len(_LABEL_PALETTE)]


def _label_colors(labels: Sequence[str]) -> np.ndarray:
    cache = {lab: label_color(lab) for lab in set(labels)}
    return np.array([cache[lab] for lab in labels], dtype=np.uint8).reshape(-1, 3)


def detection_time(msg: m.Detections) -> float:
    """Robot time of the camera frame the detections were computed on (``frame_stamp``; the
    message ``stamp`` if a publisher left it 0): the boxes land on that frame's image."""
    return float(msg.frame_stamp) if msg.frame_stamp > 0.0 else float(msg.stamp)


def log_detections(rec: RecordingLike, msg: m.Detections) -> int:
    """One camera frame's detections: Boxes2D (pixels, "label score") under the camera's
    entity, so they overlay its image in the 2-D view (and its frustum in 3-D), and the
    located ones' centroids as Points3D in the odom frame, both at the frame's time.

    An empty message is logged too: it clears the previous frame's boxes. Returns the
    number of boxes.
    """
    n = len(msg.labels)
    text = [f"{lab} {float(s):.2f}" for lab, s in zip(msg.labels, msg.scores, strict=True)]
    colors = _label_colors(msg.labels)
    set_time(rec, detection_time(msg))
    rec.log(
        f"{camera_entity(msg.camera)}/detections",
        rr.Boxes2D(
            array=np.asarray(msg.boxes, dtype=np.float32).reshape(n, 4),
            array_format=rr.Box2DFormat.XYXY,
            labels=text,
            colors=colors,
            show_labels=True,
        ),
    )
    ok = np.asarray(msg.located, dtype=bool)
    name = _ENTITY_RE.sub("_", msg.camera.strip()) or "camera"
    rec.log(
        f"{PERCEPTION}/detections/{name}",  # per camera: one camera's frame leaves the other's
        rr.Points3D(
            np.asarray(msg.centroids, dtype=np.float32).reshape(n, 3)[ok],
            radii=0.025,
            colors=colors[ok],
            labels=[t for t, keep in zip(text, ok, strict=True) if keep],
            show_labels=False,  # the track boxes carry the text in 3-D; these show on hover
        ),
    )
    return n


_TENTATIVE_ALPHA = 110  # faded: a track not yet seen often enough to act on
_MIN_HALF_SIZE = 0.01  # m: a track with no extent yet still shows as a small box


def log_object_tracks(rec: RecordingLike, msg: m.ObjectTracks, stamp: float | None = None) -> int:
    """Perception's object memory as Boxes3D in the odom frame (``world/odom/perception/
    objects``): at each centroid, the extent as the box size, labelled "label #id", in the
    class colour, solid when confirmed and faded (lighter, translucent, thinner) while
    tentative. Logged at ``stamp`` (default: the message's). Returns the track count.

    The whole memory is replaced each time: a forgotten track disappears.
    """
    n = len(msg.labels)
    confirmed = np.asarray(msg.confirmed, dtype=bool)
    rgb = _label_colors(msg.labels).astype(np.float32)
    faded = 0.5 * rgb + 0.5 * 200.0  # half-way to light grey: reads as faded even when opaque
    rgb = np.where(confirmed[:, None], rgb, faded)
    alpha = np.where(confirmed, 255, _TENTATIVE_ALPHA)[:, None]
    colors = np.hstack([rgb, alpha]).astype(np.uint8).reshape(n, 4)
    half = np.maximum(np.asarray(msg.extents, dtype=np.float32).reshape(n, 3) / 2, _MIN_HALF_SIZE)
    set_time(rec, msg.stamp if stamp is None else stamp)
    rec.log(
        f"{PERCEPTION}/objects",
        rr.Boxes3D(
            centers=np.asarray(msg.centroids, dtype=np.float32).reshape(n, 3),
            half_sizes=half,
            colors=colors,
            radii=np.where(confirmed, 0.01, 0.004).astype(np.float32),
            labels=[f"{lab} #{int(i)}" for lab, i in zip(msg.labels, msg.ids, strict=True)],
            show_labels=True,
        ),
    )
    return n


# --------------------------------------------------------------------------- ground truth


def log_gt_base(rec: RecordingLike, msg: m.GroundTruthPoses) -> None:
    """GROUND TRUTH base pose (entry named ``base``) → transform of ``world/gt/base``."""
    if "base" not in msg.names:
        return
    i = msg.names.index("base")
    set_time(rec, msg.stamp)
    rec.log(
        f"{GT}/base",
        rr.Transform3D(translation=msg.positions[i], quaternion=quat_xyzw(msg.orientations[i])),
    )


def log_gt_objects(rec: RecordingLike, msg: m.GroundTruthPoses) -> None:
    """GROUND TRUTH object positions, labelled with their names, as one Points3D batch."""
    set_time(rec, msg.stamp)
    rec.log(
        f"{GT}/objects",
        rr.Points3D(
            msg.positions.astype(np.float32),
            labels=list(msg.names),
            radii=0.03,
            colors=[_GT_COLOR],
            show_labels=True,
        ),
    )


def log_gt_contacts(
    rec: RecordingLike, msg: m.GroundTruthContacts, newton_to_m: float = 0.002
) -> None:
    """GROUND TRUTH contact forces on ``body1`` as arrows at the contact points."""
    set_time(rec, msg.stamp)
    labels = [f"{a}|{b}" for a, b in zip(msg.body1, msg.body2, strict=True)]
    rec.log(
        f"{GT}/contacts",
        rr.Arrows3D(
            origins=msg.positions.astype(np.float32),
            vectors=(msg.forces * newton_to_m).astype(np.float32),
            labels=labels,
            colors=[_GT_COLOR],
            show_labels=False,
        ),
    )


#: Colours of the judge's locations (``JUDGE_LOCATIONS``): green placed, red wrong place,
#: blue held, grey on the floor or furniture, amber elsewhere.
_LOCATION_COLORS = {
    "in_place": (40, 200, 80),
    "wrong_place": (230, 40, 40),
    "held": (40, 140, 255),
    "floor": (150, 150, 150),
    "furniture": (120, 110, 100),
    "elsewhere": (255, 200, 0),
}


def log_judge(rec: RecordingLike, msg: m.JudgeReport) -> None:
    """The judge's verdict: a text line (each object not placed with where it is and why),
    an ``in_place`` count series, and (2.0 reports) each object as a labelled point
    coloured by its location under ``world/gt/judge``."""
    where = {
        o: (loc, note) for o, loc, note in zip(msg.objects, msg.locations, msg.notes, strict=True)
    }
    missing = [
        f"{o} ({where[o][0]}: {where[o][1]})" if o in where and where[o][1] else o
        for o in msg.misplaced
    ]
    text = (
        f"judge t={msg.trial_time:.1f}s: {len(msg.in_place)}/{msg.total} in place"
        f" | in place: {', '.join(msg.in_place) or '-'}"
        f" | misplaced: {', '.join(missing) or '-'}"
    )
    level = "INFO"
    if not msg.valid:
        text = f"INVALID TRIAL ({'; '.join(msg.violations)}) | {text}"
        level = "ERROR"
    log_text(rec, f"{LOG}/judge", msg.stamp, text, level)
    rec.log(f"{PLOTS}/judge/in_place", rr.Scalars(float(len(msg.in_place))))
    if msg.objects:
        rec.log(
            f"{GT}/judge",
            rr.Points3D(
                msg.positions.astype(np.float32),
                radii=0.03,
                colors=np.array([_LOCATION_COLORS[loc] for loc in msg.locations], np.uint8),
                labels=[f"{o}: {loc}" for o, loc in zip(msg.objects, msg.locations, strict=True)],
                show_labels=False,
            ),
        )


# --------------------------------------------------------------------------- heartbeats


_HEARTBEAT_LEVEL = {
    "starting": "INFO",
    "running": "INFO",
    "stopping": "INFO",
    "stopped": "INFO",
    "degraded": "WARN",
    "failed": "ERROR",
}


_HEALTH_LEVEL = {"ok": "INFO", "degraded": "WARN", "tripped": "ERROR"}
HEALTH_CODE = {"ok": 0.0, "degraded": 1.0, "tripped": 2.0}


def log_health(
    rec: RecordingLike, msg: m.LocomotionHealth, last: tuple[str, str] | None
) -> tuple[str, str]:
    """Locomotion's health: plots every time (state as 0 ok / 1 degraded / 2 tripped,
    answer p99, command age at the robot, missed ticks), and a text line (INFO, WARN,
    ERROR) when the state or its reason changed since ``last``; returns the new ``last``."""
    set_time(rec, msg.stamp)
    base = f"{PLOTS}/locomotion/health"
    rec.log(f"{base}/state", rr.Scalars(HEALTH_CODE[msg.state]))
    rec.log(f"{base}/answer_ms_p99", rr.Scalars(msg.answer_ms_p99))
    rec.log(f"{base}/cmd_age_ticks", rr.Scalars(msg.cmd_age_ticks))
    rec.log(f"{base}/missed_ticks", rr.Scalars(float(msg.missed_ticks)))
    now = (msg.state, msg.reason)
    if now != last:
        text = f"locomotion {msg.state} ({msg.phase})" + (f": {msg.reason}" if msg.reason else "")
        if not msg.upright:
            text += " [not upright]"
        log_text(rec, f"{LOG}/locomotion/health", msg.stamp, text, _HEALTH_LEVEL[msg.state])
    return now


class HeartbeatTracker:
    """Remembers each service's last heartbeat, so only news is logged: first sight, a
    state change, a sequence gap (missed beats) or a restart (seq went back)."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[int, str]] = {}

    def news(self, msg: m.Heartbeat) -> tuple[str, str] | None:
        """(text, level) worth a log line, or None for a routine beat."""
        prev = self._last.get(msg.service)
        self._last[msg.service] = (msg.seq, msg.state)
        level = _HEARTBEAT_LEVEL.get(msg.state, "WARN")
        if prev is None:
            return f"{msg.service}: {msg.state} (seq {msg.seq})", level
        seq, state = prev
        if msg.seq < seq:
            return f"{msg.service}: restarted, now {msg.state} (seq {msg.seq})", "WARN"
        if msg.state != state:
            return f"{msg.service}: {state} -> {msg.state}", level
        if msg.seq > seq + 1:
            return f"{msg.service}: missed {msg.seq - seq - 1} heartbeat(s)", "WARN"
        return None

    @property
    def services(self) -> dict[str, str]:
        """Service → last reported state."""
        return {k: v[1] for k, v in self._last.items()}


def log_heartbeat(
    rec: RecordingLike,
    msg: m.Heartbeat,
    tracker: HeartbeatTracker,
    robot_time: float | None = None,
) -> bool:
    """Log a heartbeat line under ``log/heartbeat/<service>`` if it is news; True if logged.

    ``robot_time`` places the line on the timeline instead of ``msg.stamp``: a service that
    does not follow the sim clock stamps its heartbeats with wall time, which would land
    decades away from the sim-time data.
    """
    news = tracker.news(msg)
    if news is None:
        return False
    text, level = news
    name = _ENTITY_RE.sub("_", msg.service) or "unknown"
    stamp = msg.stamp if robot_time is None else robot_time
    log_text(rec, f"{LOG}/heartbeat/{name}", stamp, text, level)
    return True


# --------------------------------------------------------------------------- throttling


class RateLimiter:
    """Lets a stream through at most ``rate`` times per second of ROBOT time (the stamps),
    so decimation is the same whether the sim runs in real time or lockstep.

    ``rate <= 0`` lets everything through. A stamp that jumps back (sim restart) resets it.
    """

    def __init__(self, rate: float) -> None:
        self.period = 1.0 / rate if rate > 0 else 0.0
        self._last: float | None = None

    def allow(self, stamp: float) -> bool:
        """Whether a message stamped ``stamp`` should be logged (and, if so, record it)."""
        if self._last is not None and stamp < self._last - 1e-9:
            self._last = None  # time went backwards: a new run
        if self._last is not None and stamp - self._last < self.period - 1e-9:
            return False
        self._last = stamp
        return True


class EveryNth:
    """Lets every ``n``-th message through (the first one included): image throttling."""

    def __init__(self, n: int) -> None:
        self.n = max(1, int(n))
        self._count = 0

    def allow(self) -> bool:
        """Whether this message is one to keep."""
        keep = self._count % self.n == 0
        self._count += 1
        return keep


class Trail:
    """A bounded trajectory: points closer than ``min_spacing`` to the last are skipped,
    the oldest are forgotten beyond ``max_points``."""

    def __init__(self, max_points: int = 5000, min_spacing: float = 0.01) -> None:
        self._points: deque[np.ndarray] = deque(maxlen=max(2, max_points))
        self.min_spacing = min_spacing

    def add(self, p: Sequence[float] | np.ndarray) -> bool:
        """Append ``p`` if it moved far enough; True if added."""
        q = np.asarray(p, dtype=np.float64)[:3]
        if self._points and float(np.linalg.norm(q - self._points[-1])) < self.min_spacing:
            return False
        self._points.append(q)
        return True

    def clear(self) -> None:
        self._points.clear()

    def __len__(self) -> int:
        return len(self._points)

    def array(self) -> np.ndarray:
        """N×3 array of the kept points."""
        return np.array(self._points, dtype=np.float64).reshape(-1, 3)


def odom_in_world(
    gt_position: np.ndarray,
    gt_orientation: np.ndarray,
    odom_position: np.ndarray,
    odom_orientation: np.ndarray,
) -> tuple[np.ndarray, float]:
    """world_T_odom as (translation, yaw) from one simultaneous pair of base poses: the
    true one (world) and the estimated one (odom).

    Planar on purpose: odom's z axis is gravity-aligned like the world's (the estimator
    takes roll/pitch from the IMU), so only a yaw and a translation separate the frames;
    a full SE(3) from one sample would tilt the whole odom tree by the estimate's error.
    """
    yaw = yaw_from_quat(gt_orientation) - yaw_from_quat(odom_orientation)
    t = np.asarray(gt_position, dtype=float) - rot_z(yaw) @ np.asarray(odom_position, dtype=float)
    return t, wrap_angle(yaw)


def log_odom_alignment(
    rec: RecordingLike, stamp: float, translation: np.ndarray, yaw: float
) -> None:
    """Place the odom frame in the world (display only; see :func:`odom_in_world`)."""
    set_time(rec, stamp)
    rec.log(
        ODOM,
        rr.Transform3D(
            translation=translation,
            quaternion=quat_xyzw(quat_from_yaw(yaw)),
        ),
    )
    rec.log(
        f"{LOG}/viz",
        rr.TextLog(
            "odom frame placed in world from ground truth (display only): "
            f"t=({translation[0]:.3f}, {translation[1]:.3f}, {translation[2]:.3f}) m, "
            f"yaw={math.degrees(yaw):.1f} deg",
            level="INFO",
        ),
    )


class VelocityFromPoses:
    """Base-frame (vx, vy, wz) by finite differences of successive poses (the sim's
    ground-truth base pose has no velocity field); differences over less than ``min_dt``
    of robot time are skipped so 50 Hz pose jitter does not become velocity noise.

    ``wz`` is the yaw rate, equal to the body z rate for a level base (a trotting body
    rolls/pitches a few degrees: error of order 1 - cos(tilt), well under 1 %)."""

    def __init__(self, min_dt: float = 0.05) -> None:
        self.min_dt = min_dt
        self._prev: tuple[float, np.ndarray, float] | None = None

    def update(
        self, stamp: float, position: np.ndarray, orientation_wxyz: np.ndarray
    ) -> tuple[float, float, float] | None:
        """Feed a pose; returns (vx, vy, wz) in the base frame when enough time passed."""
        p = np.asarray(position, dtype=np.float64)
        yaw = yaw_from_quat(orientation_wxyz)
        if self._prev is None or stamp < self._prev[0]:
            self._prev = (stamp, p, yaw)
            return None
        t0, p0, yaw0 = self._prev
        dt = stamp - t0
        if dt < self.min_dt:
            return None
        self._prev = (stamp, p, yaw)
        v_world = (p - p0) / dt
        v_base = quat_to_mat(orientation_wxyz).T @ v_world
        dyaw = wrap_angle(yaw - yaw0)
        return float(v_base[0]), float(v_base[1]), dyaw / dt
