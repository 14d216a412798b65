"""The robot stick figure of the viz (forward kinematics of the description) and the foot
force arrows drawn at its feet."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from quadmanip.common import robot_description as rd
from quadmanip.services.viz import rerun_logging as rl
from quadmanip.services.viz.skeleton import RobotSkeleton
from rerun.chunk import RrdReader

pytestmark = pytest.mark.unit

THIGH = 0.22  # MJCF: calf body 0.22 m below the hip axis
CALF = 0.22  # foot site 0.22 m below the knee


@pytest.fixture(scope="module")
def skeleton() -> RobotSkeleton:
    return RobotSkeleton()


def _segment_lengths(pose) -> np.ndarray:
    return np.linalg.norm(pose.segments[:, 1] - pose.segments[:, 0], axis=1)


def test_straight_legs_hang_thigh_plus_calf_below_the_hips(skeleton: RobotSkeleton) -> None:
    pose = skeleton.pose(np.zeros(16))
    # Hips at (±0.1745, ±(0.08 + 0.075), 0) in the base frame; straight legs point down.
    for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
        np.testing.assert_allclose(
            pose.feet[i], [sx * 0.1745, sy * 0.155, -(THIGH + CALF)], atol=1e-6
        )


def test_links_keep_their_lengths_whatever_the_joints(skeleton: RobotSkeleton) -> None:
    rng = np.random.default_rng(3)
    ref = _segment_lengths(skeleton.pose(np.zeros(16)))
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, 16)
        np.testing.assert_allclose(_segment_lengths(skeleton.pose(q)), ref, atol=1e-9)
    # A bent knee brings the foot closer to the hip: |hip→foot| = 2 L cos(knee/2) (L1 = L2).
    pose = skeleton.pose(rd.home_joint_positions())
    knee = float(rd.home_joint_positions()[2])
    hip = np.array([0.1745, 0.155, 0.0])
    assert np.linalg.norm(pose.feet[0] - hip) == pytest.approx(
        2 * THIGH * math.cos(knee / 2), abs=1e-6
    )


def test_finger_gap(skeleton: RobotSkeleton) -> None:
    q = rd.home_joint_positions()
    closed, opened = skeleton.pose(q, 0.0), skeleton.pose(q, 0.08)

    # The two finger stubs (last segments before the TCP) separate by the gap.
    def pads(pose):
        return pose.segments[-3:-1, 1]

    assert np.linalg.norm(pads(opened)[0] - pads(opened)[1]) - np.linalg.norm(
        pads(closed)[0] - pads(closed)[1]
    ) == pytest.approx(0.08, abs=1e-6)


def test_foot_force_arrows_are_rotated_into_the_base(tmp_path: Path) -> None:
    path = tmp_path / "f.rrd"
    rec = rr.RecordingStream("t")
    rec.set_sinks(rr.FileSink(str(path)))
    feet = np.array(
        [[0.17, 0.15, -0.28], [0.17, -0.15, -0.28], [-0.17, 0.15, -0.28], [-0.17, -0.15, -0.28]]
    )
    forces = np.array([[10.0, 0.0, 100.0], [0, 0, 0], [0, 0, 0], [0.0, -5.0, 90.0]])
    yaw90 = [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]  # base faces world +y
    rl.log_foot_forces(rec, 1.0, feet, forces, yaw90, metres_per_newton=0.01)
    rec.flush()
    rec.disconnect()
    (chunk,) = [
        c
        for c in RrdReader(path).store().stream().to_chunks()
        if c.entity_path == "/world/odom/base/foot_forces"
    ]
    rb = chunk.to_record_batch()
    vec = np.array(rb.column("Arrows3D:vectors").to_pylist()[0])
    org = np.array(rb.column("Arrows3D:origins").to_pylist()[0])
    np.testing.assert_allclose(org, feet, atol=1e-6)
    # World +x is the base's -y; world -y is the base's -x.
    np.testing.assert_allclose(vec[0], [0.0, -0.1, 1.0], atol=1e-6)
    np.testing.assert_allclose(vec[3], [-0.05, 0.0, 0.9], atol=1e-6)
