"""Message → Rerun converters of the viz service, read back from a real .rrd file.

Each converter logs into a recording with a file sink; the file is then read with Rerun's
own chunk reader (``rerun.chunk.RrdReader``) and the archetype columns are compared with the
message: shapes, values, frames and the robot-time timeline.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from quadmanip.common import messages as m
from quadmanip.common.joint_layout import JOINTS
from quadmanip.common.rotations import quat_from_yaw
from quadmanip.services.viz import rerun_logging as rl
from rerun.chunk import RrdReader

pytestmark = pytest.mark.unit

_SKIP = {"rerun.controls.RowId", "log_time"}


def read_rrd(path: Path) -> dict[str, list[dict[str, Any]]]:
    """Entity path → rows (dicts of column → value, ``robot_time`` in s), by robot time."""
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).store().stream().to_chunks():
        rb = chunk.to_record_batch()
        cols: dict[str, list[Any]] = {}
        for name in rb.schema.names:
            if name in _SKIP:
                continue
            col = rb.column(name)
            if name == rl.TIMELINE:
                cols[name] = [v / 1e9 for v in col.cast(pa.int64()).to_pylist()]
            else:
                cols[name] = col.to_pylist()
        for i in range(rb.num_rows):
            row = {k: v[i] for k, v in cols.items()}
            row["static"] = chunk.is_static
            rows[chunk.entity_path].append(row)
    for entity in rows.values():
        entity.sort(key=lambda r: r.get(rl.TIMELINE, -1.0))
    return dict(rows)


class Recording:
    """A recording stream writing to a temp file; ``read()`` closes it and parses it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rec = rr.RecordingStream("quadmanip_test")
        self.rec.set_sinks(rr.FileSink(str(path)))

    def read(self) -> dict[str, list[dict[str, Any]]]:
        self.rec.flush(timeout_sec=5.0)
        self.rec.disconnect()
        return read_rrd(self.path)


@pytest.fixture
def recording(tmp_path: Path) -> Recording:
    return Recording(tmp_path / "t.rrd")


# --------------------------------------------------------------------------- robot state


def test_lowstate_plots_every_joint_on_robot_time(recording: Recording) -> None:
    q = np.linspace(-1.5, 1.5, 16)
    js = m.JointState(stamp=2.5, q=q, dq=q * 2, tau=q * 10, gripper_gap=0.061, gripper_effort=3.5)
    imu = m.Imu(
        stamp=2.5,
        orientation=[1, 0, 0, 0],
        angular_velocity=[0.1, -0.2, 0.3],
        linear_acceleration=[0.0, 0.0, 9.81],
    )
    rl.log_static_layout(recording.rec)
    rl.log_lowstate(recording.rec, m.LowState(stamp=2.5, tick=1250, joints=js, imu=imu))
    rows = recording.read()

    pos = rows["/plots/joints/position"]
    names = [r for r in pos if r["static"]][0]["SeriesLines:names"]
    assert names == list(JOINTS) and len(names) == 16
    assert names[:3] == ["FL_abad", "FL_hip", "FL_knee"] and names[12] == "arm_j1"
    data = [r for r in pos if not r["static"]]
    assert len(data) == 1 and data[0][rl.TIMELINE] == pytest.approx(2.5)
    np.testing.assert_allclose(data[0]["Scalars:scalars"], q)
    vel = [r for r in rows["/plots/joints/velocity"] if not r["static"]][0]
    np.testing.assert_allclose(vel["Scalars:scalars"], 2 * q)
    tau = [r for r in rows["/plots/joints/torque"] if not r["static"]][0]
    np.testing.assert_allclose(tau["Scalars:scalars"], 10 * q)
    arm = [r for r in rows["/plots/arm/q"] if not r["static"]][0]
    np.testing.assert_allclose(arm["Scalars:scalars"], q[12:])  # arm j1..j4 on their own plot
    assert rows["/plots/gripper/gap"][0]["Scalars:scalars"] == pytest.approx([0.061])
    assert rows["/plots/gripper/effort"][0]["Scalars:scalars"] == pytest.approx([3.5])
    acc = [r for r in rows["/plots/imu/linear_acceleration"] if not r["static"]][0]
    np.testing.assert_allclose(acc["Scalars:scalars"], [0.0, 0.0, 9.81])


def test_odometry_moves_the_base_frame_and_plots_velocity(recording: Recording) -> None:
    yaw = 0.7
    odo = m.Odometry(
        stamp=1.0,
        position=[1.0, -2.0, 0.3],
        orientation=quat_from_yaw(yaw),
        linear_velocity=[0.4, 0.1, 0.0],
        angular_velocity=[0.0, 0.0, 0.25],
    )
    rl.log_odometry(recording.rec, odo)
    rl.log_velocity_command(recording.rec, m.BodyVelocityCommand(stamp=1.0, vx=0.5, vy=0, wz=0.3))
    rows = recording.read()
    tf = rows["/world/odom/base"][0]
    np.testing.assert_allclose(tf["Transform3D:translation"][0], [1.0, -2.0, 0.3], atol=1e-6)
    # Wire [w, x, y, z] → Rerun [x, y, z, w]
    np.testing.assert_allclose(
        tf["Transform3D:quaternion"][0], [0, 0, math.sin(yaw / 2), math.cos(yaw / 2)], atol=1e-6
    )
    assert rows["/plots/velocity/vx/odom"][0]["Scalars:scalars"] == pytest.approx([0.4])
    assert rows["/plots/velocity/wz/odom"][0]["Scalars:scalars"] == pytest.approx([0.25])
    assert rows["/plots/velocity/vx/cmd"][0]["Scalars:scalars"] == pytest.approx([0.5])
    assert rows["/plots/velocity/wz/cmd"][0]["Scalars:scalars"] == pytest.approx([0.3])


def test_locomotion_debug(recording: Recording) -> None:
    forces = np.array([[1, 2, 60], [0, 0, 0], [0, 0, 0], [-1, 3, 58]], dtype=float)
    pred = np.column_stack([np.linspace(0, 0.3, 10), np.zeros(10), np.full(10, 0.3)])
    msg = m.LocomotionDebug(
        stamp=3.0,
        gait_phase=[0.1, 0.6, 0.6, 0.1],
        contact=[True, False, False, True],
        foot_forces=forces,
        mpc_solve_ms=1.7,
        mpc_predicted_positions=pred,
    )
    rl.log_locomotion_debug(recording.rec, msg)
    rows = recording.read()
    assert rows["/plots/locomotion/foot_force_z"][0]["Scalars:scalars"] == pytest.approx(
        [60, 0, 0, 58]
    )
    assert rows["/plots/locomotion/contact"][0]["Scalars:scalars"] == [1.0, 0.0, 0.0, 1.0]
    assert rows["/plots/locomotion/gait_phase"][0]["Scalars:scalars"] == pytest.approx(
        [0.1, 0.6, 0.6, 0.1]
    )
    assert rows["/plots/locomotion/mpc_solve_ms"][0]["Scalars:scalars"] == pytest.approx([1.7])
    strip = rows["/world/odom/mpc_prediction"][0]["LineStrips3D:strips"]
    assert len(strip) == 1
    np.testing.assert_allclose(np.array(strip[0]), pred, atol=1e-6)


def test_locomotion_health_plots_always_and_logs_changes(recording: Recording) -> None:
    ok = m.LocomotionHealth(stamp=1.0, state="ok", phase="balance", answer_ms_p99=0.8)
    late = m.LocomotionHealth(
        stamp=2.0, state="degraded", reason="cannot keep up: 30 of 500 ticks missed",
        phase="walk", missed_ticks=30, cmd_age_ticks=2.5,
    )  # fmt: skip
    fell = m.LocomotionHealth(
        stamp=3.0, state="tripped", reason="roll 40° beyond ±34°", phase="safe", upright=False
    )
    last = None
    for msg in (ok, ok, late, fell):
        last = rl.log_health(recording.rec, msg, last)
    rows = recording.read()
    states = [r["Scalars:scalars"][0] for r in rows["/plots/locomotion/health/state"]]
    assert states == [0.0, 0.0, 1.0, 2.0]
    assert rows["/plots/locomotion/health/missed_ticks"][-2]["Scalars:scalars"] == [30.0]
    lines = rows["/log/locomotion/health"]
    assert [r["TextLog:level"] for r in lines] == [["INFO"], ["WARN"], ["ERROR"]]  # no repeat
    assert "ticks missed" in lines[1]["TextLog:text"][0]
    assert lines[2]["TextLog:text"][0].endswith("roll 40° beyond ±34° [not upright]")


# --------------------------------------------------------------------------- sensors


def _rgbd(camera: str = "front_camera", h: int = 6, w: int = 8) -> m.RgbdImage:
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[..., 0] = np.arange(w, dtype=np.uint8)[None, :] * 30
    depth = np.linspace(0.2, 4.0, h * w, dtype=np.float32).reshape(h, w)
    depth[0, 0] = 0.0  # no return
    K = np.array([[50.0, 0.0, w / 2], [0.0, 50.0, h / 2], [0.0, 0.0, 1.0]])
    # Optical frame looking forward (+x of the base): z_opt = x_base, x_opt = -y_base.
    return m.RgbdImage(
        stamp=0.5,
        camera=camera,
        rgb=rgb,
        depth=depth,
        K=K,
        position=[0.2255, 0.0, 0.03],
        orientation=[0.5, -0.5, 0.5, -0.5],
    )


def test_rgbd_logs_pose_pinhole_rgb_and_metric_depth(recording: Recording) -> None:
    msg = _rgbd()
    path = rl.log_rgbd(recording.rec, msg)
    assert path == "world/odom/base/front_camera"
    rows = recording.read()
    cam = {k: v for r in rows["/world/odom/base/front_camera"] for k, v in r.items()}
    np.testing.assert_allclose(cam["Transform3D:translation"][0], msg.position, atol=1e-6)
    np.testing.assert_allclose(cam["Transform3D:quaternion"][0], [-0.5, 0.5, -0.5, 0.5])
    # Rerun stores the 3x3 column-major.
    np.testing.assert_allclose(
        np.array(cam["Pinhole:image_from_camera"][0]).reshape(3, 3).T, msg.K, atol=1e-6
    )
    assert cam["Pinhole:resolution"][0] == [8.0, 6.0]  # [width, height]
    rdf = rr.ViewCoordinates.RDF.as_arrow_array()[0].as_py()
    assert cam["Pinhole:camera_xyz"][0] == list(rdf)  # OpenCV optical: x right, y down

    rgb = rows["/world/odom/base/front_camera/rgb"][0]
    fmt = rgb["Image:format"][0]
    assert (fmt["width"], fmt["height"]) == (8, 6)
    np.testing.assert_array_equal(
        np.array(rgb["Image:buffer"][0], np.uint8).reshape(6, 8, 3), msg.rgb
    )
    depth = rows["/world/odom/base/front_camera/depth"][0]
    assert depth["DepthImage:meter"] == [1.0]
    buf = np.frombuffer(bytes(depth["DepthImage:buffer"][0]), np.float32).reshape(6, 8)
    np.testing.assert_array_equal(buf, msg.depth)
    assert depth[rl.TIMELINE] == pytest.approx(0.5)


def test_rgbd_options_jpeg_and_depth_only(recording: Recording) -> None:
    rl.log_rgbd(recording.rec, _rgbd("gripper_camera", 16, 16), jpeg_quality=80)
    rl.log_rgbd(recording.rec, _rgbd("front_camera"), rgb=False)
    rows = recording.read()
    jpg = rows["/world/odom/base/gripper_camera/rgb"][0]
    assert jpg["EncodedImage:media_type"] == ["image/jpeg"]
    assert bytes(jpg["EncodedImage:blob"][0][:2]) == b"\xff\xd8"  # JPEG SOI marker
    assert "/world/odom/base/front_camera/rgb" not in rows
    assert "/world/odom/base/front_camera/depth" in rows


def test_scan_points_see_a_flat_wall() -> None:
    # A wall at x = 2 m seen from the lidar: r(θ) = 2 / cos θ for |θ| < 60°.
    angles = np.deg2rad(np.arange(-60, 61, 5, dtype=float))
    ranges = (2.0 / np.cos(angles)).astype(np.float32)
    ranges[3] = 0.0  # no return
    ranges[4] = 0.05  # below range_min
    scan = m.LaserScan(
        stamp=0.1,
        angle_min=float(angles[0]),
        angle_increment=math.radians(5),
        range_min=0.1,
        range_max=12.0,
        ranges=ranges,
    )
    pts = rl.scan_points(scan)
    assert pts.shape == (len(angles) - 2, 3)
    np.testing.assert_allclose(pts[:, 0], 2.0, atol=1e-5)
    np.testing.assert_allclose(pts[:, 2], 0.0)
    keep = np.ones(len(angles), bool)
    keep[[3, 4]] = False
    np.testing.assert_allclose(pts[:, 1], 2.0 * np.tan(angles[keep]), atol=1e-5)


def test_scan_logged_under_the_lidar_mount(recording: Recording) -> None:
    scan = m.LaserScan(
        stamp=0.2,
        angle_min=0.0,
        angle_increment=math.pi / 2,
        range_min=0.1,
        range_max=10.0,
        ranges=np.array([1.0, 2.0, 11.0, 3.0], np.float32),  # 11 m: beyond range_max
    )
    rl.log_lidar_mount(recording.rec, [0.185, 0.0, 0.075], [1.0, 0.0, 0.0, 0.0])
    assert rl.log_scan(recording.rec, scan) == 3
    rows = recording.read()
    mount = rows["/world/odom/base/lidar"][0]
    assert mount["static"]
    np.testing.assert_allclose(mount["Transform3D:translation"][0], [0.185, 0, 0.075], atol=1e-6)
    pts = np.array(rows["/world/odom/base/lidar/scan"][0]["Points3D:positions"])
    np.testing.assert_allclose(pts, [[1, 0, 0], [0, 2, 0], [0, -3, 0]], atol=1e-5)


# --------------------------------------------------------------------------- perception


def _rgba(packed: int) -> tuple[int, int, int, int]:
    """Rerun's colour column (one uint32 0xRRGGBBAA) → (r, g, b, a)."""
    return tuple(int(b) for b in packed.to_bytes(4, "big"))  # type: ignore[return-value]


def _detections(camera: str = "front_camera", stamp: float = 1.5) -> m.Detections:
    return m.example(  # type: ignore[return-value]
        m.Detections,
        stamp=stamp,
        camera=camera,
        frame_stamp=stamp,
        labels=["cup", "banana", "cup"],
        scores=np.array([0.91, 0.4, 0.756], np.float32),
        boxes=np.array([[10, 20, 50, 80], [0, 0, 8, 6], [100, 40, 120, 70]], np.float32),
        centroids=[[1.0, 2.0, 0.75], [0.0, 0.0, 0.0], [1.5, -0.5, 0.8]],
        extents=np.array([[0.08, 0.08, 0.1], [0, 0, 0], [0.07, 0.07, 0.09]], np.float32),
        located=np.array([1, 0, 1], np.uint8),  # the banana had no usable depth
    )


def test_detections_boxes_on_the_camera_image_and_located_points(recording: Recording) -> None:
    msg = _detections()
    late = dataclasses.replace(msg, stamp=1.9, frame_stamp=1.7)  # published after the frame
    assert rl.log_detections(recording.rec, msg) == 3
    rl.log_detections(recording.rec, late)
    rl.log_detections(recording.rec, m.Detections(stamp=2.0, camera="front_camera"))
    rows = recording.read()

    # Under the camera entity (its Pinhole): pixels on the image, at the frame's time.
    boxes = rows["/world/odom/base/front_camera/detections"]
    assert [r[rl.TIMELINE] for r in boxes] == pytest.approx([1.5, 1.7, 2.0])
    b = boxes[0]
    xyxy = np.hstack(
        [
            np.array(b["Boxes2D:centers"]) - b["Boxes2D:half_sizes"],
            np.array(b["Boxes2D:centers"]) + b["Boxes2D:half_sizes"],
        ]
    )
    np.testing.assert_allclose(xyxy, msg.boxes, atol=1e-5)
    assert b["Boxes2D:labels"] == ["cup 0.91", "banana 0.40", "cup 0.76"]
    assert b["Boxes2D:show_labels"] == [True]
    colors = [_rgba(c) for c in b["Boxes2D:colors"]]
    assert colors[0] == colors[2] != colors[1]  # one colour per class
    assert colors[0][:3] == tuple(rl.label_color("cup")) and colors[0][3] == 255
    assert boxes[2]["Boxes2D:centers"] == []  # a frame with nothing clears the boxes

    # Only located detections become points, in the odom frame, per camera.
    pts = rows["/world/odom/perception/detections/front_camera"]
    assert [r[rl.TIMELINE] for r in pts] == pytest.approx([1.5, 1.7, 2.0])
    np.testing.assert_allclose(pts[0]["Points3D:positions"], msg.centroids[[0, 2]], atol=1e-6)
    assert pts[0]["Points3D:labels"] == ["cup 0.91", "cup 0.76"]
    assert pts[2]["Points3D:positions"] == []


def test_detections_of_each_camera_keep_their_own_entities(recording: Recording) -> None:
    rl.log_detections(recording.rec, _detections("front_camera", 1.0))
    rl.log_detections(recording.rec, _detections("gripper_camera", 1.1))
    rows = recording.read()
    assert rows["/world/odom/base/gripper_camera/detections"][0][rl.TIMELINE] == pytest.approx(1.1)
    assert "/world/odom/perception/detections/gripper_camera" in rows
    assert len(rows["/world/odom/base/front_camera/detections"]) == 1
    # An old publisher without frame_stamp: the message stamp places the boxes.
    legacy = dataclasses.replace(_detections(), frame_stamp=0.0, stamp=3.0)
    assert rl.detection_time(legacy) == 3.0


def test_object_tracks_as_labelled_boxes_confirmed_solid_tentative_faded(
    recording: Recording,
) -> None:
    tracks = m.example(
        m.ObjectTracks,
        stamp=4.0,
        ids=np.array([3, 12], np.int32),
        labels=["cup", "cup"],
        centroids=[[1.0, 2.0, 0.75], [-0.5, 0.3, 0.02]],
        extents=np.array([[0.08, 0.1, 0.12], [0.0, 0.0, 0.0]], np.float32),
        confidences=np.array([0.9, 0.2], np.float32),
        observations=np.array([14, 1], np.int32),
        last_seen=[4.0, 3.2],
        confirmed=np.array([1, 0], np.uint8),
        map_centroids=[[1.0, 2.0, 0.75], [-0.5, 0.3, 0.02]],
    )
    assert rl.log_object_tracks(recording.rec, tracks) == 2
    rl.log_object_tracks(recording.rec, m.ObjectTracks(stamp=0.0), stamp=6.0)  # memory emptied
    rows = recording.read()
    objs = rows["/world/odom/perception/objects"]
    assert [r[rl.TIMELINE] for r in objs] == pytest.approx([4.0, 6.0])
    o = objs[0]
    np.testing.assert_allclose(o["Boxes3D:centers"], tracks.centroids, atol=1e-6)
    # Extents are sizes: half of them, and a small box for a track without one yet.
    np.testing.assert_allclose(
        o["Boxes3D:half_sizes"], [[0.04, 0.05, 0.06], [0.01, 0.01, 0.01]], atol=1e-6
    )
    assert o["Boxes3D:labels"] == ["cup #3", "cup #12"]
    solid, faded = (_rgba(c) for c in o["Boxes3D:colors"])
    assert solid == (*rl.label_color("cup"), 255)
    assert faded[3] < 255 and faded[:3] != solid[:3]  # same class, tentative: faded
    assert o["Boxes3D:radii"][0] > o["Boxes3D:radii"][1]
    assert objs[1]["Boxes3D:centers"] == []  # forgotten tracks vanish


def test_label_colors_are_stable_and_not_ground_truth_amber() -> None:
    assert tuple(rl.label_color("cup")) == tuple(rl.label_color("cup"))
    colors = {tuple(rl.label_color(f"class{i}")) for i in range(50)}
    assert len(colors) > 5 and (255, 200, 0) not in colors


# --------------------------------------------------------------------------- ground truth


def test_ground_truth_has_its_own_tree(recording: Recording) -> None:
    base = m.GroundTruthPoses(
        stamp=4.0, names=["base"], positions=[[0.5, 0.2, 0.31]], orientations=[quat_from_yaw(0.1)]
    )
    objs = m.GroundTruthPoses(
        stamp=4.0,
        names=["cup", "banana"],
        positions=[[1.0, 2.0, 0.75], [3.0, -1.0, 0.02]],
        orientations=[[1, 0, 0, 0], [1, 0, 0, 0]],
    )
    contacts = m.GroundTruthContacts(
        stamp=4.0,
        body1=["FL_calf"],
        body2=["floor"],
        positions=[[0.7, 0.3, 0.0]],
        forces=[[0.0, 0.0, 50.0]],
    )
    rl.log_static_layout(recording.rec)
    rl.log_gt_base(recording.rec, base)
    rl.log_gt_objects(recording.rec, objs)
    rl.log_gt_contacts(recording.rec, contacts, newton_to_m=0.002)
    rows = recording.read()
    # Everything the ground-truth converters logged is under world/gt, nothing elsewhere.
    dynamic = {p for p, rs in rows.items() if any(not r["static"] for r in rs)}
    assert dynamic == {"/world/gt/base", "/world/gt/objects", "/world/gt/contacts"}
    assert "GROUND TRUTH" in rows["/world/gt"][0]["TextDocument:text"][0]
    tf = [r for r in rows["/world/gt/base"] if not r["static"]][0]
    np.testing.assert_allclose(tf["Transform3D:translation"][0], [0.5, 0.2, 0.31], atol=1e-6)
    o = rows["/world/gt/objects"][0]
    assert o["Points3D:labels"] == ["cup", "banana"]
    np.testing.assert_allclose(o["Points3D:positions"], objs.positions, atol=1e-6)
    c = rows["/world/gt/contacts"][0]
    np.testing.assert_allclose(c["Arrows3D:vectors"][0], [0, 0, 0.1], atol=1e-6)  # 50 N
    np.testing.assert_allclose(c["Arrows3D:origins"][0], [0.7, 0.3, 0.0], atol=1e-6)


def test_gt_base_without_a_base_entry_is_ignored(recording: Recording) -> None:
    rl.log_gt_base(
        recording.rec,
        m.GroundTruthPoses(
            stamp=1, names=["cup"], positions=[[0, 0, 0]], orientations=[[1, 0, 0, 0]]
        ),
    )
    rl.log_text(recording.rec, "log/x", 1.0, "marker", "INFO")
    assert "/world/gt/base" not in recording.read()


def test_judge_and_heartbeat_text(recording: Recording) -> None:
    judge = m.JudgeReport(
        stamp=30.0,
        trial_time=30.0,
        in_place=["cup"],
        misplaced=["banana", "can"],
        total=3,
        objects=["cup", "banana", "can"],
        locations=["in_place", "held", "floor"],
        notes=["", "touches the robot", "belongs in tray"],
        positions=np.zeros((3, 3)),
        rest_s=np.zeros(3),
    )
    rl.log_judge(recording.rec, judge)
    rl.log_judge(
        recording.rec, judge.replace(stamp=31.0, valid=False, violations=["qfrc_applied x2"])
    )
    tracker = rl.HeartbeatTracker()
    hb = [
        m.Heartbeat(stamp=1.0, service="sim", seq=0, state="running"),
        m.Heartbeat(stamp=2.0, service="sim", seq=1, state="running"),  # routine
        m.Heartbeat(stamp=3.0, service="sim", seq=2, state="degraded"),
        m.Heartbeat(stamp=6.0, service="sim", seq=5, state="degraded"),  # 2 missed
        m.Heartbeat(stamp=7.0, service="sim", seq=0, state="starting"),  # restart
    ]
    logged = [rl.log_heartbeat(recording.rec, h, tracker) for h in hb]
    assert logged == [True, False, True, True, True]
    assert tracker.services == {"sim": "starting"}
    rows = recording.read()
    j = rows["/log/judge"][0]
    assert "1/3 in place" in j["TextLog:text"][0]
    assert "banana (held: touches the robot), can (floor: belongs in tray)" in j["TextLog:text"][0]
    bad = rows["/log/judge"][1]
    assert bad["TextLog:text"][0].startswith("INVALID TRIAL (qfrc_applied x2)")
    assert bad["TextLog:level"][0] == "ERROR"
    assert "/world/gt/judge" in rows
    assert rows["/plots/judge/in_place"][0]["Scalars:scalars"] == [1.0]
    lines = rows["/log/heartbeat/sim"]
    assert [r[rl.TIMELINE] for r in lines] == [1.0, 3.0, 6.0, 7.0]
    texts = [r["TextLog:text"][0] for r in lines]
    assert "running -> degraded" in texts[1] and "missed 2" in texts[2]
    assert "restarted" in texts[3]
    assert [r["TextLog:level"][0] for r in lines] == ["INFO", "WARN", "WARN", "WARN"]


def test_blueprint_and_layout_paths() -> None:
    bp = rl.blueprint()
    assert isinstance(bp, rr.blueprint.Blueprint)
    assert rl.camera_entity("front_camera") == "world/odom/base/front_camera"
    assert rl.camera_entity("weird name/x") == "world/odom/base/weird_name_x"


# --------------------------------------------------------------------------- throttles


def test_rate_limiter_decimates_by_robot_time() -> None:
    lim = rl.RateLimiter(50.0)
    stamps = np.arange(0, 1.0, 0.002)  # LowState at 500 Hz for 1 s of robot time
    kept = [s for s in stamps if lim.allow(float(s))]
    assert len(kept) == 50  # 500 Hz → 50 Hz
    np.testing.assert_allclose(np.diff(kept), 0.02, atol=1e-9)
    # A sim restart (time goes back) starts over instead of going silent.
    assert lim.allow(0.0)
    assert not lim.allow(0.01)
    everything = rl.RateLimiter(0.0)
    assert all(everything.allow(float(s)) for s in stamps[:20])


def test_every_nth() -> None:
    e = rl.EveryNth(3)
    assert [e.allow() for _ in range(7)] == [True, False, False, True, False, False, True]


def test_trail_spacing_and_bound() -> None:
    t = rl.Trail(max_points=4, min_spacing=0.05)
    assert t.add([0, 0, 0]) and not t.add([0.01, 0, 0]) and t.add([0.1, 0, 0])
    for x in (0.2, 0.3, 0.4):
        t.add([x, 0, 0])
    assert len(t) == 4
    np.testing.assert_allclose(t.array()[:, 0], [0.1, 0.2, 0.3, 0.4])


def test_ground_truth_velocity_in_the_base_frame() -> None:
    # The base faces +y (yaw 90°) and walks forward at 0.5 m/s while turning at 0.3 rad/s.
    est = rl.VelocityFromPoses(min_dt=0.05)
    out = []
    for k in range(40):
        t = 0.02 * k
        yaw = math.pi / 2 + 0.3 * t
        # Straight-line world motion along +y is exact only at the start: use short steps
        # and compare the first few estimates.
        pos = np.array([0.0, 0.5 * t, 0.3])
        v = est.update(t, pos, quat_from_yaw(yaw))
        if v is not None:
            out.append((t, v))
    t1, (vx, vy, wz) = out[0]
    assert t1 == pytest.approx(0.06)
    assert wz == pytest.approx(0.3, rel=1e-6)
    assert math.hypot(vx, vy) == pytest.approx(0.5, rel=1e-6)
    assert vx == pytest.approx(0.5 * math.cos(0.3 * t1), rel=1e-6)  # heading drifted 0.3 t
    # Yaw wraps across ±π without a spike.
    est = rl.VelocityFromPoses(min_dt=0.0)
    est.update(0.0, np.zeros(3), quat_from_yaw(math.pi - 0.01))
    _, _, wz = est.update(0.1, np.zeros(3), quat_from_yaw(-math.pi + 0.01))
    assert wz == pytest.approx(0.2)


def test_odom_in_world_maps_the_estimate_onto_the_truth() -> None:
    # The robot starts at (0.8, 1.2) facing yaw 0.5 in the world; odom starts at its origin
    # and the estimate now reads (0.1, 0.0) with yaw 0.2 (e.g. yaw drift of 0.3 rad).
    p_gt, yaw_gt = np.array([0.8, 1.2, 0.30]), 0.5
    p_od, yaw_od = np.array([0.1, 0.0, 0.29]), 0.2
    t, yaw = rl.odom_in_world(p_gt, quat_from_yaw(yaw_gt), p_od, quat_from_yaw(yaw_od))
    assert yaw == pytest.approx(0.3)
    c, s = math.cos(yaw), math.sin(yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(rz @ p_od + t, p_gt, atol=1e-12)  # world_T_odom · p_odom


def test_heartbeat_with_wall_clock_stamp_lands_at_robot_time(recording: Recording) -> None:
    # Services that do not follow the sim clock stamp heartbeats with wall time (~1.8e9 s).
    hb = m.Heartbeat(stamp=1.79e9, service="locomotion", seq=0, state="running")
    assert rl.log_heartbeat(recording.rec, hb, rl.HeartbeatTracker(), robot_time=12.5)
    (row,) = recording.read()["/log/heartbeat/locomotion"]
    assert row[rl.TIMELINE] == pytest.approx(12.5)


def test_arm_trajectory_points_land_at_their_own_times(recording: Recording) -> None:
    t = 10.0 + np.linspace(0.0, 1.5, 7)
    q = np.column_stack([np.linspace(0, 1.2, 7), -np.linspace(0, 0.6, 7), np.zeros(7), t - 10])
    traj = m.ArmTrajectory(stamp=10.0, t=t, q=q, dq=np.zeros((7, 4)), kp=[30] * 4, kd=[1] * 4)
    assert rl.log_arm_trajectory(recording.rec, traj) == 7
    long_t = np.linspace(0.0, 9.0, 2001)
    long = m.ArmTrajectory(
        stamp=0.0,
        t=long_t,
        q=np.tile(long_t[:, None], (1, 4)),
        dq=np.zeros((2001, 4)),
        kp=[30] * 4,
        kd=[1] * 4,
    )
    assert rl.log_arm_trajectory(recording.rec, long, max_points=100) <= 101
    rl.log_gripper_command(recording.rec, m.GripperCommand(stamp=10.2, gap=0.04, max_force=15.0))
    rows = recording.read()
    cmd = [r for r in rows["/plots/arm/q_cmd"] if not r["static"]]
    first = [r for r in cmd if r[rl.TIMELINE] >= 10.0]
    np.testing.assert_allclose([r[rl.TIMELINE] for r in first], t, atol=1e-9)
    np.testing.assert_allclose([r["Scalars:scalars"] for r in first], q, atol=1e-12)
    thinned = [r for r in cmd if r[rl.TIMELINE] < 10.0]
    assert 90 <= len(thinned) <= 101
    assert max(r["Scalars:scalars"][0] for r in thinned) == pytest.approx(9.0)  # last kept
    assert rows["/plots/gripper/gap_cmd"][0]["Scalars:scalars"] == [0.04]
    assert rows["/plots/gripper/max_force_cmd"][0][rl.TIMELINE] == pytest.approx(10.2)
