"""The viz node's wiring without Zenoh: config, throttles, counters, error isolation.

A stand-in bus records the callbacks the node subscribes; the test feeds them decoded
messages directly and reads the resulting .rrd back. The real-bus path is covered by
tests/integration/test_viz_node.py.
"""

from __future__ import annotations

import dataclasses
import math
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from quadmanip.common import messages as m
from quadmanip.common.config import ConfigError, load_config
from quadmanip.common.robot_description import ROBOT_XML
from quadmanip.services.viz.config import VizConfig
from quadmanip.services.viz.node import VizNode, lidar_mount_from_description
from quadmanip.services.viz.sinks import resolve_output
from rerun.chunk import RrdReader

pytestmark = pytest.mark.unit


class _Sub:
    def __init__(self, key: str) -> None:
        self.key = key
        self.dropped_count = 0


class _KeyStats:
    decode_errors = 0


class _Stats:
    def key(self, key: str) -> _KeyStats:
        return _KeyStats()


class FakeBus:
    """Records subscriptions; ``deliver(topic, msg)`` calls every callback of a topic."""

    def __init__(self) -> None:
        self.callbacks: dict[str, list[Any]] = {}
        self.latest_only: dict[str, bool] = {}
        self.stats = _Stats()

    def subscribe(self, topic: str, callback: Any, latest_only: bool) -> _Sub:
        self.callbacks.setdefault(topic, []).append(callback)
        self.latest_only[topic] = latest_only
        return _Sub(topic)

    def deliver(self, topic: str, msg: Any) -> None:
        for cb in self.callbacks[topic]:
            cb(msg)


def _scalars(path: Path, entity: str) -> list[float]:
    out: list[float] = []
    for chunk in RrdReader(path).store().stream().to_chunks():
        if chunk.entity_path == entity and not chunk.is_static:
            out += [v[0] for v in chunk.to_record_batch().column("Scalars:scalars").to_pylist()]
    return out


def _entities(path: Path) -> set[str]:
    return set(RrdReader(path).store().schema().entity_paths())


@pytest.fixture
def node(tmp_path: Path) -> tuple[VizNode, FakeBus, Path]:
    out = tmp_path / "run.rrd"
    cfg = dataclasses.replace(
        load_config(VizConfig, "viz"), output=str(out), joints_rate=50.0, image_every=3
    )
    bus = FakeBus()
    n = VizNode(bus, cfg)  # type: ignore[arg-type]
    n.setup()
    return n, bus, out


def _lowstate(t: float) -> m.LowState:
    js = m.JointState(stamp=t, q=np.zeros(16), dq=np.zeros(16), tau=np.zeros(16))
    imu = m.Imu(
        stamp=t,
        orientation=[1, 0, 0, 0],
        angular_velocity=[0, 0, 0],
        linear_acceleration=[0, 0, 9.81],
    )
    return m.LowState(stamp=t, tick=round(t / 0.002), joints=js, imu=imu)


def _image(camera: str = "front_camera", stamp: float = 0.1) -> m.RgbdImage:
    return m.RgbdImage(
        stamp=stamp,
        camera=camera,
        rgb=np.zeros((4, 6, 3), np.uint8),
        depth=np.ones((4, 6), np.float32),
        K=[[5, 0, 3], [0, 5, 2], [0, 0, 1]],
        position=[0.2, 0, 0.03],
        orientation=[0.5, -0.5, 0.5, -0.5],
    )


def test_config_file_loads_and_rejects_nonsense() -> None:
    cfg = load_config(VizConfig, "viz")
    assert cfg.output.endswith(".rrd") and cfg.joints_rate == 50.0 and cfg.image_every >= 1
    with pytest.raises(ConfigError):
        load_config(VizConfig, "viz", {"imagee_every": 2})  # typo: unknown key
    for bad in (
        {"image_every": 0},
        {"jpeg_quality": 101},
        {"joints_rate": -1.0},
        {"output": "", "connect_url": "", "serve_port": 0},
        {"lidar_position": [1.0]},
        {"detections_rate": -1.0},
        {"objects_rate": -0.5},
    ):
        with pytest.raises((ConfigError, ValueError)):
            load_config(VizConfig, "viz", bad)


def test_resolve_output_time_template(tmp_path: Path) -> None:
    p = resolve_output(str(tmp_path / "sub" / "q_{time}.rrd"), now=0.0)
    assert p.name == "q_19700101_000000.rrd" and p.parent.is_dir()


def test_lidar_mount_is_the_description_site() -> None:
    # The lidar site sits directly on the base body in the MJCF: its pos is base_T_lidar.
    root = ET.parse(ROBOT_XML).getroot()
    base = root.find(".//body[@name='base']")
    assert base is not None
    site = base.find("site[@name='lidar']")
    assert site is not None
    expected = np.array([float(v) for v in site.get("pos", "0 0 0").split()])
    pos, quat = lidar_mount_from_description()
    np.testing.assert_allclose(pos, expected, atol=1e-9)
    np.testing.assert_allclose(np.abs(quat), [1, 0, 0, 0], atol=1e-9)


def test_node_throttles_counts_and_survives_bad_messages(node) -> None:
    n, bus, out = node
    # Sensor streams are latest-only; judge verdicts and heartbeats are kept one by one.
    assert bus.latest_only["sim/lowstate"] and bus.latest_only["sim/camera/front"]
    assert not bus.latest_only["sim/gt/judge"] and not bus.latest_only["sim/heartbeat"]
    assert set(bus.callbacks) >= {f"{s}/heartbeat" for s in ("sim", "locomotion", "viz")}

    for k in range(500):  # 1 s of LowState at 500 Hz → 50 logged at 50 Hz
        bus.deliver("sim/lowstate", _lowstate(0.002 * k))
    img = _image()
    for _ in range(7):  # image_every = 3 → frames 0, 3, 6
        bus.deliver("sim/camera/front", img)
    for k in range(30):  # odometry and ground truth at 10 Hz for 3 s: walking +x at 0.5 m/s
        t = 0.1 * k
        bus.deliver(
            "sim/gt/base",
            m.GroundTruthPoses(
                stamp=t,
                names=["base"],
                positions=[[0.5 * t, 0.01, 0.3]],
                orientations=[[math.cos(0.05), 0, 0, math.sin(0.05)]],
            ),
        )
        bus.deliver(
            "locomotion/odometry",
            m.Odometry(
                stamp=t,
                position=[0.5 * t, 0, 0.3],
                orientation=[1, 0, 0, 0],
                linear_velocity=[0.5, 0, 0],
                angular_velocity=[0, 0, 0],
            ),
        )
    # A message that passed decoding but breaks a converter: counted, not fatal.
    broken = m.GroundTruthPoses(
        stamp=5.0, names=[], positions=np.zeros((0, 3)), orientations=np.zeros((0, 4))
    )
    object.__setattr__(broken, "positions", "not an array")  # simulate a converter failure
    bus.deliver("sim/gt/objects", broken)
    bus.deliver("sim/heartbeat", m.Heartbeat(stamp=1.0, service="sim", seq=0, state="running"))
    bus.deliver("sim/heartbeat", m.Heartbeat(stamp=2.0, service="sim", seq=1, state="running"))

    st = n.stats()
    assert (st["lowstate"].received, st["lowstate"].logged, st["lowstate"].decimated) == (
        500,
        50,
        450,
    )
    assert (st["front_camera"].logged, st["front_camera"].decimated) == (3, 4)
    assert st["odometry"].logged == 30  # 10 Hz < 50 Hz limit: all kept
    assert st["gt_objects"].errors == 1
    assert (st["heartbeat"].logged, st["heartbeat"].decimated) == (1, 1)

    n.teardown()
    ents = _entities(out)
    for e in (
        "/plots/joints/position",
        "/world/odom/base/body/skeleton",
        "/world/odom/base/body/trunk",
        "/world/odom/base",
        "/world/odom/base/front_camera/rgb",
        "/world/odom/base/front_camera/depth",
        "/world/odom/trajectory",
        "/world/gt/base",
        "/world/gt/base_trajectory",
        "/plots/velocity/vx/gt",
        "/log/heartbeat/sim",
        "/log/viz",
    ):
        assert e in ents, e
    # Ground-truth velocity (finite differences) in the base frame: yaw 0.1 rad.
    vx = _scalars(out, "/plots/velocity/vx/gt")
    vy = _scalars(out, "/plots/velocity/vy/gt")
    assert len(vx) >= 10
    np.testing.assert_allclose(vx, 0.5 * math.cos(0.1), rtol=1e-6)
    np.testing.assert_allclose(vy, -0.5 * math.sin(0.1), rtol=1e-6)
    # The odom frame was placed in the world from the first (gt, odometry) pair at t = 0.
    tf = [
        c.to_record_batch()
        for c in RrdReader(out).store().stream().to_chunks()
        if c.entity_path == "/world/odom" and not c.is_static
    ]
    assert len(tf) == 1 and tf[0].num_rows == 1
    np.testing.assert_allclose(
        tf[0].column("Transform3D:translation").to_pylist()[0][0], [0, 0.01, 0], atol=1e-6
    )
    np.testing.assert_allclose(  # yaw 0.1 rad, [x, y, z, w]
        tf[0].column("Transform3D:quaternion").to_pylist()[0][0],
        [0, 0, math.sin(0.05), math.cos(0.05)],
        atol=1e-6,
    )
    # Logging after teardown is refused quietly (the bus may still deliver while closing).
    bus.deliver("sim/lowstate", _lowstate(9.0))
    assert n.stats()["lowstate"].received == 500


def test_unreachable_viewer_does_not_hold_the_file_or_the_stop(tmp_path: Path) -> None:
    # A live viewer that is not there: the file still closes complete, and the close
    # returns within the stop budget (Rerun itself would wait ~5 s for the viewer).
    from quadmanip.services.viz.sinks import open_recordings

    out = tmp_path / "v.rrd"
    recs, where = open_recordings("t", str(out), connect_url="rerun+http://127.0.0.1:9/proxy")
    assert where[0] == f"file:{out}" and where[1].startswith("viewer:")
    recs.set_time("robot_time", duration=1.0)
    recs.log("plots/x", rr.Scalars(1.0))
    t0 = time.monotonic()
    closed = recs.close(timeout=0.5)
    assert time.monotonic() - t0 < 1.5
    assert closed["file"] and not closed["live"]
    assert "/plots/x" in _entities(out)


def _times(path: Path, entity: str) -> list[float]:
    """Robot times (s) of an entity's non-static rows in the recording, sorted."""
    out: list[float] = []
    for chunk in RrdReader(path).store().stream().to_chunks():
        if chunk.entity_path == entity and not chunk.is_static:
            col = chunk.to_record_batch().column("robot_time").cast(pa.int64())
            out += [v / 1e9 for v in col.to_pylist()]
    return sorted(out)


def _detections(camera: str, t: float) -> m.Detections:
    return m.example(  # type: ignore[return-value]
        m.Detections,
        stamp=t,
        camera=camera,
        frame_stamp=t,
        labels=["cup"],
        scores=np.array([0.8], np.float32),
        boxes=np.array([[1, 1, 4, 3]], np.float32),
        centroids=[[1.0, 0.5, 0.7]],
        extents=np.array([[0.1, 0.1, 0.1]], np.float32),
        located=np.array([1], np.uint8),
    )


def _tracks(stamp: float, n: int) -> m.ObjectTracks:
    return m.ObjectTracks(
        stamp=stamp,
        ids=np.arange(n, dtype=np.int32),
        labels=["cup"] * n,
        centroids=np.ones((n, 3)),
        extents=np.full((n, 3), 0.1, np.float32),
        confidences=np.full(n, 0.9, np.float32),
        observations=np.full(n, 5, np.int32),
        last_seen=np.full(n, stamp),
        confirmed=np.ones(n, np.uint8),
        map_centroids=np.ones((n, 3)),
    )


def test_perception_boxes_follow_the_logged_frames_and_tracks_the_robot_clock(
    tmp_path: Path,
) -> None:
    out = tmp_path / "p.rrd"
    cfg = dataclasses.replace(
        load_config(VizConfig, "viz"),
        output=str(out),
        image_every=3,
        detections_rate=2.0,
        objects_rate=4.0,
        skeleton=False,
    )
    bus = FakeBus()
    n = VizNode(bus, cfg)  # type: ignore[arg-type]
    n.setup()
    # Both are sensor-like: only the newest matters if the recording falls behind.
    assert bus.latest_only["perception/detections"] and bus.latest_only["perception/objects"]

    stamps = [round(0.1 * k, 3) for k in range(7)]
    for t in stamps:  # image_every = 3: frames 0.0, 0.3 and 0.6 are logged
        bus.deliver("sim/camera/front", dataclasses.replace(_image(), stamp=t))
    for t in stamps:  # the detector saw every frame; its results arrive after the images
        bus.deliver("perception/detections", _detections("front_camera", t))
    # A camera whose images are not logged at all: its boxes at detections_rate only.
    for t in stamps:
        bus.deliver("perception/detections", _detections("gripper_camera", t))

    bus.deliver("sim/lowstate", _lowstate(2.0))  # the bridge's robot clock: 2.0 s
    bus.deliver("perception/objects", _tracks(1.2, 3))  # stamp = newest sighting, older
    bus.deliver("sim/lowstate", _lowstate(2.5))
    bus.deliver("perception/objects", _tracks(0.0, 0))  # memory emptied (stamp 0)
    bus.deliver("perception/objects", _tracks(0.0, 0))  # same clock: over objects_rate

    st = n.stats()
    # front: on a logged frame always (0.0, 0.3, 0.6), else at 2 Hz (0.5); gripper: 2 Hz.
    assert (st["detections"].logged, st["detections"].decimated) == (4 + 2, 3 + 5)
    assert (st["objects"].logged, st["objects"].decimated) == (2, 1)
    n.teardown()

    assert _times(out, "/world/odom/base/front_camera/detections") == pytest.approx(
        [0.0, 0.3, 0.5, 0.6]
    )
    assert _times(out, "/world/odom/base/front_camera/rgb") == pytest.approx([0.0, 0.3, 0.6])
    assert _times(out, "/world/odom/base/gripper_camera/detections") == pytest.approx([0.0, 0.5])
    assert _times(out, "/world/odom/perception/detections/front_camera") == pytest.approx(
        [0.0, 0.3, 0.5, 0.6]
    )
    # The memory lands at the robot clock, so the emptied one comes after the full one.
    assert _times(out, "/world/odom/perception/objects") == pytest.approx([2.0, 2.5])


def test_perception_streams_can_be_switched_off(tmp_path: Path) -> None:
    cfg = dataclasses.replace(
        load_config(VizConfig, "viz"),
        output=str(tmp_path / "off.rrd"),
        detections=False,
        objects=False,
        skeleton=False,
    )
    bus = FakeBus()
    n = VizNode(bus, cfg)  # type: ignore[arg-type]
    n.setup()
    assert "perception/detections" not in bus.callbacks
    assert "perception/objects" not in bus.callbacks
    assert "sim/camera/front" in bus.callbacks
    n.teardown()
