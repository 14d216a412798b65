"""`quadmanip service viz` over a real router: messages of every kind in, a .rrd file out.

The test publishes (from its own bus) the streams the bridge subscribes to, plus one
undecodable payload, waits until the node's counters show every stream, stops it with
SIGTERM and reads the recording back with Rerun's reader: each stream's entity is there,
ground truth under ``world/gt``, perception's boxes under the camera and the object
memory in the odom tree, and the garbage was counted, not fatal.
"""

from __future__ import annotations

import math
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from quadmanip.common import messages as m
from rerun.chunk import RrdReader

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

STREAMS = (
    "lowstate",
    "front_camera",
    "gripper_camera",
    "scan",
    "odometry",
    "debug",
    "cmd_vel",
    "arm_trajectory",
    "gripper_command",
    "gt_base",
    "gt_objects",
    "gt_contacts",
    "judge",
    "heartbeat",
    "detections",
    "objects",
)


def _messages(t: float) -> dict[str, m.Message]:
    js = m.JointState(stamp=t, q=np.full(16, 0.1), dq=np.zeros(16), tau=np.zeros(16))
    imu = m.Imu(
        stamp=t,
        orientation=[1, 0, 0, 0],
        angular_velocity=[0, 0, 0],
        linear_acceleration=[0, 0, 9.81],
    )
    h, w = 24, 32
    K = [[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1]]

    def img(cam: str) -> m.RgbdImage:
        return m.RgbdImage(
            stamp=t,
            camera=cam,
            rgb=np.full((h, w, 3), 120, np.uint8),
            depth=np.full((h, w), 1.5, np.float32),
            K=K,
            position=[0.2, 0, 0.03],
            orientation=[0.5, -0.5, 0.5, -0.5],
        )

    yaw = 0.2
    q = [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]
    return {
        "sim/lowstate": m.LowState(stamp=t, tick=round(t / 0.002), joints=js, imu=imu),
        "sim/camera/front": img("front_camera"),
        "sim/camera/gripper": img("gripper_camera"),
        "sim/scan": m.LaserScan(
            stamp=t,
            angle_min=-math.pi,
            angle_increment=2 * math.pi / 360,
            range_min=0.1,
            range_max=10.0,
            ranges=np.full(360, 3.0, np.float32),
        ),
        "locomotion/odometry": m.Odometry(
            stamp=t,
            position=[0.3 * t, 0, 0.3],
            orientation=q,
            linear_velocity=[0.3, 0, 0],
            angular_velocity=[0, 0, 0],
        ),
        "locomotion/debug": m.LocomotionDebug(
            stamp=t,
            gait_phase=[0, 0.5, 0.5, 0],
            contact=[True, False, False, True],
            foot_forces=[[0, 0, 70], [0, 0, 0], [0, 0, 0], [0, 0, 70]],
            mpc_solve_ms=2.0,
            mpc_predicted_positions=[[0.3 * t + 0.01 * i, 0, 0.3] for i in range(10)],
        ),
        "locomotion/cmd_vel": m.BodyVelocityCommand(stamp=t, vx=0.3, vy=0.0, wz=0.0),
        "sim/gt/base": m.GroundTruthPoses(
            stamp=t, names=["base"], positions=[[0.3 * t, 0.01, 0.3]], orientations=[q]
        ),
        "sim/gt/objects": m.GroundTruthPoses(
            stamp=t,
            names=["cup", "banana"],
            positions=[[1, 2, 0.75], [3, -1, 0.02]],
            orientations=[[1, 0, 0, 0], [1, 0, 0, 0]],
        ),
        "sim/gt/contacts": m.GroundTruthContacts(
            stamp=t, body1=["FL_calf"], body2=["floor"], positions=[[0, 0, 0]], forces=[[0, 0, 40]]
        ),
        "sim/gt/judge": m.JudgeReport(
            stamp=t, trial_time=t, in_place=["cup"], misplaced=["banana"], total=2
        ),
        "sim/arm_trajectory": m.ArmTrajectory(
            stamp=t,
            t=[t, t + 0.5],
            q=[[0, 0, 0, 0], [0.2, -0.2, 0, 0]],
            dq=np.zeros((2, 4)),
            kp=[30] * 4,
            kd=[1] * 4,
        ),
        "sim/gripper_command": m.GripperCommand(stamp=t, gap=0.05, max_force=10.0),
        "sim/heartbeat": m.Heartbeat(stamp=t, service="sim", seq=int(t * 10), state="running"),
        "perception/detections": m.Detections(
            stamp=t,
            camera="front_camera",
            frame_stamp=t,  # the frame published above: its boxes overlay that image
            labels=["cup", "banana"],
            scores=np.array([0.9, 0.5], np.float32),
            boxes=np.array([[2, 3, 12, 15], [20, 4, 30, 20]], np.float32),
            centroids=[[1.0, 2.0, 0.75], [0.0, 0.0, 0.0]],
            extents=np.array([[0.1, 0.1, 0.12], [0, 0, 0]], np.float32),
            located=np.array([1, 0], np.uint8),
        ),
        "perception/objects": m.ObjectTracks(
            stamp=t,
            ids=np.array([0, 1], np.int32),
            labels=["cup", "banana"],
            centroids=[[1, 2, 0.75], [3, -1, 0.02]],
            extents=np.array([[0.1, 0.1, 0.12], [0.2, 0.05, 0.04]], np.float32),
            confidences=np.array([0.9, 0.3], np.float32),
            observations=np.array([8, 1], np.int32),
            last_seen=[t, t],
            confirmed=np.array([1, 0], np.uint8),
            map_centroids=[[1, 2, 0.75], [3, -1, 0.02]],
        ),
    }


def test_viz_records_every_stream(zenoh_router, spawn, bus_factory, tmp_path: Path) -> None:
    out = tmp_path / "viz.rrd"
    node = spawn(
        "-m",
        "quadmanip.cli",
        "service",
        "viz",
        "--set",
        f"output={out}",
        "--set",
        "stats_period=0.3",
        "--set",
        "image_every=1",
        endpoint=zenoh_router,
    )
    assert node.wait_for(r"INFO viz running", 30), node.output()[-3000:]

    bus = bus_factory(zenoh_router)
    first = _messages(0.0)
    pubs = {topic: bus.publisher(topic) for topic in first}
    deadline = time.monotonic() + 20.0
    t = 0.0
    seen: set[str] = set()
    while time.monotonic() < deadline and seen != set(STREAMS):
        for topic, msg in _messages(t).items():
            pubs[topic].publish(msg)
        bus.session.put(bus.key("sim/scan"), b"\x93not msgpack of a scan")
        t += 0.1
        time.sleep(0.1)
        seen = {s for s in STREAMS if re.search(rf"\b{s}=\"recv=[1-9]", node.output())}
    assert seen == set(STREAMS), node.output()[-3000:]

    node.signal(signal.SIGTERM)
    assert node.wait(5.0) == 0, node.output()[-3000:]
    final = node.wait_for(r"viz stats \(final\).*", 1.0)
    assert final is not None, node.output()[-3000:]
    # The garbage payloads were counted by the bus, and the scans still got through.
    assert re.search(r'scan="recv=[1-9]\d* logged=[1-9]\d* .*decode_errors=[1-9]', final.group(0))

    assert out.is_file() and out.stat().st_size > 10_000
    entities = set(RrdReader(out).store().schema().entity_paths())
    expected = {
        "/plots/joints/position",
        "/plots/imu/angular_velocity",
        "/world/odom/base",
        "/world/odom/base/body/skeleton",
        "/world/odom/base/foot_forces",
        "/world/odom/base/front_camera",
        "/world/odom/base/front_camera/rgb",
        "/world/odom/base/front_camera/depth",
        "/world/odom/base/gripper_camera/depth",
        "/world/odom/base/lidar",
        "/world/odom/base/lidar/scan",
        "/world/odom/trajectory",
        "/world/odom/mpc_prediction",
        "/plots/locomotion/foot_force_z",
        "/plots/locomotion/mpc_solve_ms",
        "/plots/velocity/vx/cmd",
        "/plots/arm/q_cmd",
        "/plots/gripper/gap_cmd",
        "/plots/velocity/vx/odom",
        "/plots/velocity/vx/gt",
        "/world/gt/base",
        "/world/gt/base_trajectory",
        "/world/gt/objects",
        "/world/gt/contacts",
        "/world/odom/base/front_camera/detections",
        "/world/odom/perception/detections/front_camera",
        "/world/odom/perception/objects",
        "/log/judge",
        "/log/heartbeat/sim",
        "/log/viz",
    }
    assert expected <= entities, sorted(expected - entities)
