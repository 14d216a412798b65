"""The engine in the house: standing on PD only, damping fall-back, honesty, schedules.

Every test runs the real world of scenario ``paper-1`` (house, 10 objects, robot) through
``SimEngine.step_tick`` with ``LegCommand`` messages, i.e. the same path the node uses.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import mujoco  # noqa: E402
import numpy as np
import pytest
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.sim.actuators import LegMode
from quadmanip.sim.engine import SimConfig, SimEngine, standing_data
from quadmanip.sim.node import load_world

pytestmark = pytest.mark.unit

KP, KD = 150.0, 3.0  # test gains of a plain joint PD holding the home pose
G = 9.81


@pytest.fixture(scope="module")
def world():
    return load_world("paper-1")


def _engine(world, **kw):
    cfg = SimConfig(allow_test_disturbance=kw.pop("allow_test_disturbance", False))
    kw.setdefault("cameras", False)
    kw.setdefault("lidar", False)
    return SimEngine(world, cfg, data=standing_data(world), **kw)


def _hold(eng, tick):
    q0 = rd.home_joint_positions()[:12]
    z = np.zeros(12)
    return msg.LegCommand(
        stamp=eng.time,
        tick=tick,
        q_des=q0,
        dq_des=z,
        kp=np.full(12, KP),
        kd=np.full(12, KD),
        tau_ff=z,
    )


def _tilt_deg(quat):
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, quat)
    return np.degrees(np.arccos(np.clip(r[8], -1, 1)))


def test_stands_for_10s_on_pd_only(world):
    eng = _engine(world)
    z0 = float(eng.data.xpos[eng.base][2])
    out = eng.observe()
    heights, tilts, acc, stamps = [], [], [], []
    while eng.time < 10.0 - 1e-9:
        out = eng.step_tick(_hold(eng, out.tick))
        heights.append(eng.data.xpos[eng.base][2])
        tilts.append(_tilt_deg(eng.data.xquat[eng.base]))
        stamps.append(out.stamp)
        if eng.time > 2.0:
            acc.append(out.lowstate.imu.linear_acceleration)
        assert out.leg_mode is LegMode.ACTIVE
    heights = np.array(heights)
    assert out.tick == 5000
    np.testing.assert_allclose(np.diff(stamps), 0.002, atol=1e-9)
    # Stands: trunk within 2 cm of its start height and level for the whole 10 s.
    assert np.max(np.abs(heights - z0)) < 0.02, (heights.min(), heights.max(), z0)
    assert max(tilts) < 3.0
    # At rest the accelerometer reads the specific force +g along the body z axis.
    acc = np.array(acc).mean(axis=0)
    assert acc[2] == pytest.approx(G, abs=0.15)
    assert np.hypot(acc[0], acc[1]) < 0.3
    # Joint encoders report the held pose (PD error under the weight is small).
    q = out.lowstate.joints.q[:12]
    assert np.max(np.abs(q - rd.home_joint_positions()[:12])) < 0.1
    assert eng.honesty_violations() == []


def test_stops_commanding_goes_to_damping_and_sinks_slowly(world):
    eng = _engine(world)
    out = eng.observe()
    while eng.time < 0.5 - 1e-9:
        out = eng.step_tick(_hold(eng, out.tick))
    z_start = float(eng.data.xpos[eng.base][2])
    t_stop = eng.time
    modes, heights, qd = [], [], []
    while eng.time < t_stop + 3.0 - 1e-9:
        out = eng.step_tick(None)
        modes.append((eng.time - t_stop, out.leg_mode))
        heights.append(eng.data.xpos[eng.base][2])
        qd.append(np.abs(out.lowstate.joints.dq).max())
        assert np.all(np.isfinite(out.lowstate.joints.q))
    # Damping starts 50 ms after the last command (within one control tick).
    first_damp = next(t for t, m in modes if m is LegMode.DAMPING)
    assert 0.05 - 1e-9 <= first_damp <= 0.05 + 0.002 + 1e-9
    assert all(m is LegMode.ACTIVE for t, m in modes if t < 0.05 - 1e-9)
    heights = np.array(heights)
    # It sinks: clearly lower after 3 s, but never below the folded trunk resting on the
    # floor, and slowly: far slower than a free fall from this height (sqrt(2 g h)).
    assert heights[-1] < z_start - 0.05
    assert heights.min() > 0.05
    sink_speed = -np.diff(heights) / eng.control_dt
    free_fall = np.sqrt(2 * G * (z_start - 0.05))
    assert sink_speed.max() < 0.5 * free_fall
    # Monotone-ish: it never rises by more than 5 mm on the way down.
    assert np.max(heights - np.minimum.accumulate(heights)) < 0.005
    assert max(qd) < 15.0  # joint speeds stay bounded (rad/s)


def test_honesty_external_forces_only_from_the_channel(world):
    eng = _engine(world, allow_test_disturbance=True)
    m, d = eng.model, eng.data
    watched = set(eng.robot_bodies.tolist()) | set(eng._object_bodies.tolist())
    # No mocap body, and no weld/connect equality, involves the robot or an object.
    assert all(m.body_mocapid[b] < 0 for b in watched)
    assert eng.honesty_violations() == []
    # A push on an object: upward force of twice its weight for 0.2 s lifts it by about
    # (F/m - g) t^2 / 2 (it starts at rest, asleep; the force wakes it).
    name = eng.object_names[0]
    bid = world.object_body_ids[name]
    mass = float(m.body_subtreemass[bid])
    z0 = float(d.xpos[bid][2])
    out = eng.observe()
    for _ in range(10):
        out = eng.step_tick(_hold(eng, out.tick))
    push = msg.Disturbance(
        stamp=eng.time,
        force=[0, 0, 2 * mass * G],
        torque=[0, 0, 0],
        duration=0.2,
        body=f"obj/{name}",
    )
    assert eng.apply_disturbance(push)
    t_push = float(d.time)
    seen_nonzero = 0
    for _ in range(150):
        eng.apply_leg_command(_hold(eng, out.tick))
        for _ in range(eng.substeps):
            active = t_push <= d.time < t_push + 0.2
            eng.physics_step()
            nz = set(np.flatnonzero(np.any(d.xfrc_applied != 0, axis=1)).tolist())
            if nz:
                seen_nonzero += 1
                assert nz == {bid} and active
        if abs(d.time - (t_push + 0.2)) < 1e-6:
            lift = float(d.xpos[bid][2]) - z0
    assert seen_nonzero == 200  # exactly the 0.2 s of the push, 1 kHz
    assert lift == pytest.approx(0.5 * G * 0.2**2, rel=0.15)
    assert not d.xfrc_applied.any()
    assert eng.honesty_violations() == []
    # Anything else writing xfrc_applied is caught.
    d.xfrc_applied[eng.base, 2] = 5.0
    eng.physics_step()
    assert any("external force" in v for v in eng.honesty_violations())


def test_disturbance_rejected_when_disabled(world):
    eng = _engine(world, allow_test_disturbance=False)
    push = msg.Disturbance(stamp=0.0, force=[50, 0, 0], torque=[0, 0, 0], duration=0.1)
    assert not eng.apply_disturbance(push)
    out = eng.observe()
    for _ in range(50):
        out = eng.step_tick(_hold(eng, out.tick))
        assert not eng.data.xfrc_applied.any()
    assert eng.disturbance.rejected == 1


def test_no_teleport_free_bodies_move_by_their_velocity(world):
    eng = _engine(world)
    m, d = eng.model, eng.data
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    out = eng.observe()
    worst = 0.0
    for _ in range(200):
        eng.apply_leg_command(_hold(eng, out.tick))
        for _ in range(eng.substeps):
            p0 = np.array([d.qpos[m.jnt_qposadr[j] : m.jnt_qposadr[j] + 3] for j in free])
            eng.physics_step()
            p1 = np.array([d.qpos[m.jnt_qposadr[j] : m.jnt_qposadr[j] + 3] for j in free])
            v1 = np.array([d.qvel[m.jnt_dofadr[j] : m.jnt_dofadr[j] + 3] for j in free])
            # Semi-implicit Euler: x1 = x0 + dt * v1 (free-joint linear velocity is world).
            worst = max(worst, float(np.abs(p1 - p0 - m.opt.timestep * v1).max()))
        out = eng.observe()
    assert worst < 1e-9


def test_ground_truth_contact_forces_carry_the_robot(world):
    eng = _engine(world)
    out = eng.observe()
    while eng.time < 1.0:
        out = eng.step_tick(_hold(eng, out.tick))
    c = eng.gt_contacts()
    robot_names = {eng.model.body(b).name for b in eng.robot_bodies}
    total = np.zeros(3)
    for b1, b2, f in zip(c.body1, c.body2, c.forces, strict=True):
        if b1 in robot_names and b2 not in robot_names:
            total += f
        elif b2 in robot_names and b1 not in robot_names:
            total -= f
    mass = float(eng.model.body_subtreemass[eng.base])
    # Standing still: the ground pushes the robot up with its weight.
    assert total[2] == pytest.approx(mass * G, rel=0.03)
    assert np.hypot(total[0], total[1]) < 0.05 * mass * G


def test_sensor_schedule_and_outputs(world):
    eng = _engine(world, cameras=True, lidar=True)
    out = eng.observe()
    counts = {"front_camera": 0, "gripper_camera": 0, "scan": 0, "poses": 0, "judge": 0}
    outs = [out]
    while eng.time < 1.0 - 1e-9:
        out = eng.step_tick(_hold(eng, out.tick))
        outs.append(out)
    phase = {"front_camera": 0, "gripper_camera": 25}
    for o in outs:
        assert len(o.images) <= 1  # the cameras are staggered: one render per tick at most
        for img in o.images:
            counts[img.camera] += 1
            assert o.tick % 50 == phase[img.camera]
            assert img.rgb.shape == (240, 320, 3) and img.depth.shape == (240, 320)
            assert img.stamp == o.stamp
        if o.scan is not None:
            counts["scan"] += 1
            assert o.tick % 50 == 12
        counts["poses"] += o.gt_poses is not None
        counts["judge"] += o.judge is not None
    # Ticks 0..500 of 1 s: 10 Hz sensors fire every 50 ticks, staggered: the front camera
    # at 0, 50, ..., 500 (11 times), the LiDAR at 12, 62, ... and the gripper camera at
    # 25, 75, ... (10 times each).
    assert counts == {
        "front_camera": 11,
        "gripper_camera": 10,
        "scan": 10,
        "poses": 51,
        "judge": 2,
    }
    gt = outs[-1].gt_poses
    assert gt.names[0] == "base" and set(gt.names[1:]) == set(eng.object_names)
    scan = next(o.scan for o in reversed(outs) if o.scan is not None)
    assert scan.ranges.shape == (360,)
    assert np.all((scan.ranges == 0) | (scan.ranges >= scan.range_min))
    j = outs[-1].judge
    assert j.total == len(eng.object_names) and j.trial_time == pytest.approx(1.0)
    eng.close()


def test_drawer_handle_ground_truth_comes_with_the_poses(world):
    eng = _engine(world)
    out = eng.observe()
    while out.gt_drawers is None:
        out = eng.step_tick(_hold(eng, out.tick))
    assert out.gt_poses is not None and out.gt_drawers.stamp == out.gt_poses.stamp
    gt = out.gt_drawers
    assert sorted(gt.names) == ["left", "right", "top"]
    for name, pos in zip(gt.names, gt.positions, strict=True):
        handle = eng.data.body(world.drawer_handles[name])
        assert pos == pytest.approx(handle.xpos)
    # the cabinet faces west (house.toml yaw 180): the left drawer is the northern one
    y = dict(zip(gt.names, gt.positions[:, 1], strict=True))
    assert y["left"] > y["top"] > y["right"]
    eng.close()
