"""The perception service over a real Zenoh router, fed rendered camera frames.

`quadmanip service perception` runs as a child process; the test process plays the robot:
it publishes rendered RGB-D frames of a probing view (the object at its resting pose in
front of the robot), odometry and joint states (arm still). Answers are checked against
the ground truth of the render. Bad input (empty depth, absurd intrinsics, a frame with
no object, a camera that stops) must give reasons, never a crash.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common.robot_description import tcp_in_gripper_camera
from quadmanip.common.rotations import quat_to_mat
from quadmanip.testbench.probe_views import render_probe_view

pytestmark = pytest.mark.integration

OBJECT, WHERE = "baseball", "floor"


def _wait(cond: Callable[[], bool], timeout: float, what: str, proc) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}\n" + "\n".join(proc.lines[-25:]))
        time.sleep(0.05)


class FakeRobot:
    """Publishes a frame (swappable), odometry and an arm standing still at 10/50 Hz."""

    def __init__(self, bus, frame: m.RgbdImage, topic: str) -> None:
        self.bus, self.frame, self.topic = bus, frame, topic
        self.also: dict[str, m.RgbdImage] = {}  # more frames, by topic, at the same rate
        self.t = 100.0
        self.running = True
        self.cameras_on = True
        self.pubs = {
            t: bus.publisher(t)
            for t in (
                "sim/camera/front",
                "sim/camera/gripper",
                "sim/lowstate",
                "locomotion/odometry",
            )
        }
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        k = 0
        while self.running:
            self.t += 0.02
            stamp = self.t
            self.pubs["locomotion/odometry"].publish(
                m.example(m.Odometry, stamp=stamp, position=[1.0, 2.0, 0.3])
            )
            ls = m.example(m.LowState, stamp=stamp)
            self.pubs["sim/lowstate"].publish(ls)
            if k % 5 == 0 and self.cameras_on:
                for topic, f in [(self.topic, self.frame), *self.also.items()]:
                    self.pubs[topic].publish(
                        m.RgbdImage(
                            stamp=stamp,
                            camera=f.camera,
                            rgb=f.rgb,
                            depth=f.depth,
                            K=f.K,
                            position=f.position,
                            orientation=f.orientation,
                        )  # fmt: skip
                    )
            k += 1
            time.sleep(0.02)

    def stop(self) -> None:
        self.running = False
        self.thread.join(2.0)


@pytest.fixture(scope="module")
def view():
    return render_probe_view(OBJECT, WHERE, 0)


def _frame(v) -> m.RgbdImage:
    return m.RgbdImage(stamp=0.0, camera=v.camera, rgb=v.rgb, depth=v.depth, K=v.K,
                       position=v.cam_position, orientation=v.cam_orientation)  # fmt: skip


def _result(bus, action: str, goal: m.Message, proc, timeout: float = 30.0):
    h = bus.action_client("perception", action).send_goal(goal, timeout=10.0)
    if not h.accepted:
        return h, None
    deadline = time.monotonic() + timeout
    while (r := h.result(timeout=0.5)) is None:
        if time.monotonic() > deadline:
            raise TimeoutError("no result\n" + "\n".join(proc.lines[-25:]))
    return h, r


def test_detects_remembers_and_grasps_then_survives_bad_input(
    zenoh_router, spawn, bus_factory, view
):
    bus = bus_factory(zenoh_router)
    proc = spawn("-m", "quadmanip.cli", "service", "perception", endpoint=zenoh_router)
    dets: list[m.Detections] = []
    bus.subscribe("perception/detections", dets.append)
    objects = bus.latest("perception/objects")
    topic = "sim/camera/gripper" if view.camera == "gripper_camera" else "sim/camera/front"
    robot = FakeRobot(bus, _frame(view), topic)
    try:
        # 1. detections of the object, placed in 3-D near the truth (odom = base + (1, 2, 0.3))
        _wait(lambda: any(OBJECT in d.labels for d in dets), 90.0, "no detection", proc)
        d = next(d for d in dets if OBJECT in d.labels)
        i = list(d.labels).index(OBJECT)
        assert d.located[i] == 1
        truth_odom = view.base_rotation.T @ (view.obj_position - view.base_position)
        truth_odom += np.array([1.0, 2.0, 0.3])
        assert np.linalg.norm(d.centroids[i][:2] - truth_odom[:2]) < 0.05
        seen_at = d.centroids[i].copy()  # where the frames place it (odom)
        # 2. the memory holds it, confirmed, after a few frames
        _wait(
            lambda: (o := objects.get()) is not None
            and any(lab == OBJECT and c for lab, c in zip(o.labels, o.confirmed, strict=True)),
            30.0, "no confirmed track", proc,
        )  # fmt: skip
        # 3. a grasp of the class: a GraspGoal near the harness's ground-truth grasp
        _, r = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, label=OBJECT), proc)
        assert r is not None and r.status == "succeeded", r
        g = r.result
        assert isinstance(g, m.GraspGoal) and g.object_name == OBJECT
        assert np.linalg.norm(g.position - view.gt.position_base) < 0.02
        assert g.approach == view.gt.approach and g.mass > 0.0
        # ... and of its track
        o = objects.get()
        tid = int(o.ids[list(o.labels).index(OBJECT)])
        _, r = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, track_id=tid), proc)
        assert r.status == "succeeded", r
        # 4. an unknown class or track is rejected at once
        h, _ = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, label="teapot"), proc)
        assert not h.accepted and "unknown class" in h.reason
        h, _ = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, track_id=9999), proc)
        assert not h.accepted and "unknown track" in h.reason
        # 5. navigation's map->odom correction changes (the odometry drifted): the tracks
        # keep their map positions, their odom positions move (cameras off: nothing seen
        # meanwhile, where the fake robot's unmoving odometry would put it elsewhere)
        robot.cameras_on = False
        pose_pub = bus.publisher("navigation/pose")

        def localized(correction) -> m.MapPose:
            return m.example(m.MapPose, stamp=robot.t, map_to_odom=np.array(correction),
                             status="localized")  # fmt: skip

        def track_of(msg: m.ObjectTracks | None, tid: int):
            if msg is None or tid not in list(msg.ids):
                return None
            i = list(msg.ids).index(tid)
            return msg.centroids[i].copy(), msg.map_centroids[i].copy(), bool(msg.in_map)

        t0, t1 = (0.0, 0.0, 0.0), (0.12, -0.09, 0.05)
        pose_pub.publish(localized(t0))
        _wait(lambda: (x := track_of(objects.get(), tid)) is not None and x[2], 10.0,
              "no map-frame track", proc)  # fmt: skip
        odom0, map0, _ = track_of(objects.get(), tid)
        np.testing.assert_allclose(map0, odom0, atol=1e-9)
        pose_pub.publish(localized(t1))
        # where the map position lies in the drifted odom frame
        c, s_ = np.cos(t1[2]), np.sin(t1[2])
        d = map0[:2] - np.array(t1[:2])
        expected = np.array([c * d[0] + s_ * d[1], -s_ * d[0] + c * d[1]])
        assert np.linalg.norm(expected - odom0[:2]) > 0.02
        _wait(lambda: (x := track_of(objects.get(), tid)) is not None
              and np.linalg.norm(x[0][:2] - expected) < 1e-6, 10.0,
              "the track did not follow the correction", proc)  # fmt: skip
        _, map1, _ = track_of(objects.get(), tid)
        np.testing.assert_allclose(map1, map0, atol=1e-6)
        robot.cameras_on = True
        # 5b. localised, the frames mark the floor they show in the map-frame seen grid:
        # around the object (the probe view shows the floor about it), and no table top
        seen = bus.latest("perception/seen")
        obj_map = map1[:2]
        ring = obj_map + 0.15 * np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0.7, 0.7]])
        _wait(lambda: (g := seen.get()) is not None and g.seen(ring, m.SEEN_FLOOR).sum() >= 3,
              15.0, "no seen floor about the object", proc)  # fmt: skip
        g = seen.get()
        assert not g.seen(ring, m.SEEN_TABLE).any()
        assert not g.seen(obj_map + np.array([[5.0, 5.0]]), m.SEEN_FLOOR).any()
        # 6. the task took the object up: its track is forgotten (it would lie where the
        # object was, an obstacle to navigation, until a camera showed the spot empty)
        robot.cameras_on = False  # (nothing seen meanwhile: no new track)
        assert track_of(objects.get(), tid) is not None
        progress = bus.publisher("behavior/progress")

        def took(grasped: bool, taken: list[int]) -> m.TaskProgress:
            return m.TaskProgress(
                stamp=robot.t, state="running", objects=[OBJECT],
                object_track_ids=np.array([tid]), object_found_at=np.zeros(1),
                object_grasped=np.array([grasped]), object_placed=np.zeros(1, bool),
                object_given_up=np.zeros(1, bool), object_time_s=np.zeros(1),
                object_attempts=np.zeros(1, np.int32), object_failures=[""],
                object_positions=np.zeros((1, 3)), taken_track_ids=np.array(taken, np.int32),
            )  # fmt: skip

        # (the first message: what was taken before it started)
        progress.publish(took(False, [tid + 1000]))
        time.sleep(0.5)
        assert track_of(objects.get(), tid) is not None
        # a record grasped before whose object now lies at this track (it fell out of
        # the gripper or its box): the track is the object lying there, kept
        progress.publish(took(True, [tid + 1000, tid + 2000]))
        time.sleep(0.5)
        assert track_of(objects.get(), tid) is not None
        progress.publish(took(True, [tid + 1000, tid + 2000, tid]))
        _wait(lambda: track_of(objects.get(), tid) is None, 10.0, "the track stayed", proc)
        assert any("track forgotten" in line for line in proc.lines)
        # 6b. what the gripper holds is no object lying there: the front camera's view of
        # the object, shifted to lie at the tool centre of the gripper camera's pose (a
        # frame without depth), starts no track; shifted 0.4 m beyond, it does
        assert view.camera == "gripper_camera"
        frame = _frame(view)
        robot.frame = m.RgbdImage(**{**frame.__dict__, "depth": np.zeros_like(view.depth)})
        tcp = frame.position + quat_to_mat(frame.orientation) @ tcp_in_gripper_camera()
        lying = seen_at - np.array([1.0, 2.0, 0.3])  # base frame (odom = base + that)

        def front_at(where: np.ndarray) -> m.RgbdImage:
            shifted = frame.position + (where - lying)
            return m.RgbdImage(**{**frame.__dict__, "position": shifted})

        def tracked() -> bool:
            o = objects.get()
            return o is not None and OBJECT in list(o.labels)

        n_dets = len(dets)
        robot.also = {"sim/camera/front": front_at(tcp)}
        robot.cameras_on = True
        _wait(lambda: len(dets) > n_dets + 20, 20.0, "no frames", proc)
        held = [x for x in dets[n_dets:] if OBJECT in x.labels]
        assert held, "the held object is no longer detected"
        assert not tracked()
        robot.also = {"sim/camera/front": front_at(tcp + np.array([0.4, 0.0, 0.0]))}
        _wait(tracked, 20.0, "no track of the object set down", proc)
        robot.cameras_on = False
        robot.frame, robot.also = _frame(view), {}
        robot.cameras_on = True
        # 7. bad frames: a reason, no crash
        bad = _frame(view)
        for frame, why in (
            (m.RgbdImage(**{**bad.__dict__, "depth": np.zeros_like(view.depth)}), "empty depth"),
            (m.RgbdImage(**{**bad.__dict__, "K": np.diag([1e6, 1e6, 1.0])}), "absurd focal"),
            (m.RgbdImage(**{**bad.__dict__, "rgb": np.full_like(view.rgb, 90),
                            "depth": np.full_like(view.depth, 2.0)}), "not in view"),
        ):  # fmt: skip
            robot.frame = frame
            time.sleep(0.5)
            _, r = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, label=OBJECT), proc)
            assert r is not None and r.status == "failed" and why in r.reason, (why, r)
        # 8. the camera stops: goals are rejected with the reason, the node lives on
        robot.cameras_on = False
        time.sleep(1.5)
        h, _ = _result(bus, "estimate_grasp", m.GraspRequest(stamp=0.0, label=OBJECT), proc)
        assert not h.accepted and "no camera frame" in h.reason
        assert proc.proc.poll() is None
        assert any("camera silent" in line for line in proc.lines)
    finally:
        robot.stop()
