"""The viz service process: bus messages → :mod:`.rerun_logging` → a Rerun recording.

``quadmanip service viz [--set output=run.rrd] [--set connect_url=rerun+http://host:9876/proxy]``

Every input is subscribed latest-only except the low-rate events (judge verdicts,
heartbeats, arm trajectories and gripper commands): a slow recording never queues up on the bus, and what the bus overwrote is
counted (``bus_dropped``). Heavy streams are further throttled here, by robot time
(``*_rate``) or frame count (``image_every``, ``scan_every``): counted as ``decimated``.
A message the bus could not decode is counted by the bus (``decode_errors``); a message
that fails to convert is counted (``errors``) and logged, throttled; the bridge keeps
running either way. Counters are reported every ``stats_period`` seconds, in the service
log and in the recording (``log/viz``).

Perception: ``perception/detections`` become boxes on the camera image they were computed
on (kept whenever that frame's image was logged, else at most ``detections_rate`` per
camera) and ``perception/objects`` (the object memory) 3-D boxes in the odom frame, at most
``objects_rate``.

Ground truth (``sim/gt/**``) is shown under its own ``world/gt`` tree: visualisation is one
of the three readers allowed (with the judge and the tests).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from quadmanip.common import keys
from quadmanip.common import messages as m
from quadmanip.common.bus import TypedSubscriber
from quadmanip.common.rotations import mat_to_quat
from quadmanip.common.service import Input, Service, run_service
from quadmanip.services.viz import rerun_logging as rl
from quadmanip.services.viz.config import VizConfig
from quadmanip.services.viz.sinks import Recordings, open_recordings
from quadmanip.services.viz.skeleton import RobotSkeleton

__all__ = ["StreamStats", "VizNode", "lidar_mount_from_description", "main"]

_KEPT_FRAMES = 8  # logged frame stamps remembered per camera (detections arrive after)


@dataclasses.dataclass
class StreamStats:
    """Counters of one input stream."""

    received: int = 0  # delivered to the bridge (after the bus's latest-only overwrite)
    logged: int = 0  # written to the recording
    decimated: int = 0  # skipped on purpose by the bridge's throttle
    errors: int = 0  # conversion failures
    bus_dropped: int = 0  # overwritten in the bus's latest-only slot before we took them
    decode_errors: int = 0  # bad payloads (counted by the bus)


def lidar_mount_from_description(model: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """base_T_lidar (position, [w, x, y, z]) from the robot description's ``lidar`` site."""
    import mujoco
    from quadmanip.common import robot_description as rd

    if model is None:
        model = rd.load_mujoco_model()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    bid = model.body(rd.BASE_BODY).id
    sid = model.site(rd.LIDAR_SITE).id
    r_base = data.xmat[bid].reshape(3, 3)
    pos = r_base.T @ (data.site_xpos[sid] - data.xpos[bid])
    rot = r_base.T @ data.site_xmat[sid].reshape(3, 3)
    return pos, mat_to_quat(rot)


class VizNode(Service):
    """Zenoh → Rerun bridge: records (or streams to a viewer) what the robot does."""

    name = "viz"
    config_type = VizConfig
    config_name = "viz"
    inputs = (
        Input("sim/lowstate", latest_only=True, doc="joints/IMU plots (decimated)"),
        Input("sim/camera/front", latest_only=True, doc="front RGB-D"),
        Input("sim/camera/gripper", latest_only=True, doc="gripper RGB-D"),
        Input("sim/scan", latest_only=True, doc="2D LiDAR points"),
        Input("locomotion/odometry", latest_only=True, doc="base pose, trail"),
        Input("locomotion/debug", latest_only=True, doc="MPC, gait, forces"),
        Input("locomotion/cmd_vel", latest_only=True, doc="cmd velocity"),
        Input("locomotion/health", doc="ok/degraded/tripped (plots, text log)"),
        Input("sim/arm_trajectory", doc="commanded arm trajectory (plots)"),
        Input("sim/gripper_command", doc="commanded finger gap (plots)"),
        Input("sim/gt/base", latest_only=True, doc="GROUND TRUTH base"),
        Input("sim/gt/objects", latest_only=True, doc="GROUND TRUTH objects"),
        Input("sim/gt/contacts", latest_only=True, doc="GT contacts"),
        Input("sim/gt/judge", doc="judge verdicts (text log)"),
        Input("perception/detections", latest_only=True, doc="boxes on the camera images"),
        Input("perception/objects", latest_only=True, doc="object memory (3-D boxes)"),
    ) + tuple(Input(f"{s}/heartbeat", doc="state changes (text log)") for s in keys.SERVICES)
    outputs = ()
    loop_period = 0.25  # step(): periodic counter report

    def setup(self) -> None:
        cfg: VizConfig = self.config
        self.rec, where = open_recordings(
            cfg.application_id, cfg.output, cfg.connect_url, cfg.serve_port
        )
        self._closed = False
        self._stats: dict[str, StreamStats] = {}
        self._locks: dict[str, threading.Lock] = {}
        self._subs: dict[str, list[TypedSubscriber[Any]]] = {}
        self._last_stamp = 0.0
        self._last_report = time.monotonic()
        self._reported: dict[str, tuple[int, ...]] = {}

        self._skeleton: RobotSkeleton | None = None
        self._feet: tuple[np.ndarray, np.ndarray] | None = None  # (feet in base, base quat)
        if cfg.skeleton:
            try:
                self._skeleton = RobotSkeleton()
                rl.log_robot_body(
                    self.rec, self._skeleton.trunk_half_size, self._skeleton.trunk_center
                )
            except Exception as exc:  # noqa: BLE001 - plots and sensors still work without it
                self.log.warning("no robot skeleton", error=repr(exc))
        self._lidar_mount(cfg)
        lim = rl.RateLimiter
        self._joints = lim(cfg.joints_rate)
        self._odom = lim(cfg.odometry_rate)
        self._odom_trail_rate = lim(cfg.trail_rate)
        self._odom_trail = rl.Trail(cfg.trail_max_points, cfg.trail_min_spacing)
        self._odom_trail_t = 0.0
        self._debug = lim(cfg.debug_rate)
        self._cmd = lim(cfg.command_rate)
        self._gt_base = lim(cfg.gt_rate)
        self._gt_trail_rate = lim(cfg.trail_rate)
        self._gt_trail = rl.Trail(cfg.trail_max_points, cfg.trail_min_spacing)
        self._gt_trail_t = 0.0
        self._gt_velocity = rl.VelocityFromPoses()
        self._gt_pose: tuple[float, np.ndarray, np.ndarray] | None = None
        self._aligned_at: float | None = None
        self._gt_objects = lim(cfg.gt_rate)
        self._gt_contacts = lim(cfg.gt_rate)
        self._images = {
            "sim/camera/front": rl.EveryNth(cfg.image_every),
            "sim/camera/gripper": rl.EveryNth(cfg.image_every),
        }
        self._scan = rl.EveryNth(cfg.scan_every)
        # Camera → stamps of its last logged frames (a tuple, replaced whole by the camera's
        # thread, read by the detections thread: no lock needed).
        self._logged_frames: dict[str, tuple[float, ...]] = {}
        self._detections: dict[str, rl.RateLimiter] = {}  # per camera
        self._objects = lim(cfg.objects_rate)
        self._heartbeats = rl.HeartbeatTracker()

        self._wire("lowstate", "sim/lowstate", self._on_lowstate)
        for topic in self._images:
            self._wire(topic.rsplit("/", 1)[1] + "_camera", topic, self._image_handler(topic))
        self._wire("scan", "sim/scan", self._on_scan)
        self._wire("odometry", "locomotion/odometry", self._on_odometry)
        self._wire("debug", "locomotion/debug", self._on_debug)
        self._wire("cmd_vel", "locomotion/cmd_vel", self._on_cmd_vel)
        self._health_last: tuple[str, str] | None = None
        self._wire("health", "locomotion/health", self._on_health)
        self._wire("arm_trajectory", "sim/arm_trajectory", self._on_arm_trajectory)
        self._wire("gripper_command", "sim/gripper_command", self._on_gripper_command)
        self._wire("gt_base", "sim/gt/base", self._on_gt_base)
        self._wire("gt_objects", "sim/gt/objects", self._on_gt_objects)
        self._wire("gt_contacts", "sim/gt/contacts", self._on_gt_contacts)
        self._wire("judge", "sim/gt/judge", self._on_judge)
        if cfg.detections:
            self._wire("detections", "perception/detections", self._on_detections)
        if cfg.objects:
            # Its stamp is the newest last_seen (0 for an empty memory), not a clock.
            self._wire("objects", "perception/objects", self._on_objects, robot_time=False)
        for s in keys.SERVICES:
            self._wire("heartbeat", f"{s}/heartbeat", self._on_heartbeat, robot_time=False)
        self.log.info("viz recording", sinks=",".join(where))

    def _lidar_mount(self, cfg: VizConfig) -> None:
        if cfg.lidar_position:
            pos = np.array(cfg.lidar_position, dtype=float)
            quat = np.array(cfg.lidar_orientation or (1.0, 0.0, 0.0, 0.0), dtype=float)
        else:
            try:
                model = self._skeleton.model if self._skeleton is not None else None
                pos, quat = lidar_mount_from_description(model)
            except Exception as exc:  # noqa: BLE001 - a viewer without the mount is still useful
                self.log.warning("no lidar mount from the description; using base", error=repr(exc))
                pos, quat = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        rl.log_lidar_mount(self.rec, pos, quat)

    # ------------------------------------------------------------------ wiring
    def _wire(
        self, stream: str, topic: str, fn: Callable[[Any], bool], robot_time: bool = True
    ) -> None:
        """Subscribe ``fn`` (returns True if it logged) with counting and error isolation.

        ``robot_time``: the stream's stamps are robot time and advance the bridge's clock
        (heartbeats may carry wall time). Each stream has its own lock: its throttle state
        is touched by one callback at a time, while streams run in parallel (a slow image
        never delays the joint plots).
        """
        stats = self._stats.setdefault(stream, StreamStats())
        lock = self._locks.setdefault(stream, threading.Lock())

        def callback(msg: Any) -> None:
            with lock:
                if self._closed:
                    return
                stats.received += 1
                if robot_time:
                    self._last_stamp = float(msg.stamp)
                try:
                    logged = fn(msg)
                except Exception as exc:  # noqa: BLE001 - never let one bad message stop us
                    stats.errors += 1
                    self.log.throttled(
                        f"convert-{stream}",
                        1.0,
                        logging.WARNING,
                        "message not logged",
                        stream=stream,
                        error=repr(exc),
                        errors=stats.errors,
                    )
                    return
                if logged:
                    stats.logged += 1
                else:
                    stats.decimated += 1

        self._subs.setdefault(stream, []).append(self.subscribe(topic, callback))

    # ------------------------------------------------------------------ handlers
    def _on_lowstate(self, msg: m.LowState) -> bool:
        if not self._joints.allow(msg.stamp):
            return False
        rl.log_lowstate(self.rec, msg)
        if self._skeleton is not None:
            pose = self._skeleton.pose(msg.joints.q, msg.joints.gripper_gap)
            rl.log_skeleton(self.rec, msg.stamp, pose.segments, pose.feet)
            self._feet = (pose.feet, msg.imu.orientation)  # read by the debug thread
        return True

    def _image_handler(self, topic: str) -> Callable[[m.RgbdImage], bool]:
        every = self._images[topic]
        cfg: VizConfig = self.config

        def handle(msg: m.RgbdImage) -> bool:
            if not every.allow():
                return False
            rl.log_rgbd(self.rec, msg, rgb=cfg.rgb, depth=cfg.depth, jpeg_quality=cfg.jpeg_quality)
            kept = self._logged_frames.get(msg.camera, ())[-(_KEPT_FRAMES - 1) :]
            self._logged_frames[msg.camera] = (*kept, float(msg.stamp))
            return True

        return handle

    def _on_detections(self, msg: m.Detections) -> bool:
        t = rl.detection_time(msg)
        limiter = self._detections.get(msg.camera)
        if limiter is None:
            limiter = self._detections[msg.camera] = rl.RateLimiter(self.config.detections_rate)
        allowed = limiter.allow(t)  # first: it records the time when it lets one through
        on_logged_frame = any(abs(t - s) < 1e-6 for s in self._logged_frames.get(msg.camera, ()))
        if not (allowed or on_logged_frame):
            return False
        rl.log_detections(self.rec, msg)
        return True

    def _on_objects(self, msg: m.ObjectTracks) -> bool:
        # At the bridge's robot clock (the memory as it is now), never before the newest
        # sighting: a track forgotten later must vanish later, not at an older stamp.
        t = max(float(msg.stamp), self._last_stamp)
        if not self._objects.allow(t):
            return False
        rl.log_object_tracks(self.rec, msg, stamp=t)
        return True

    def _on_scan(self, msg: m.LaserScan) -> bool:
        if not self._scan.allow():
            return False
        rl.log_scan(self.rec, msg)
        return True

    def _align_odom(self, msg: m.Odometry) -> None:
        """Place ``world/odom`` from the latest true base pose close enough in time."""
        gt = self._gt_pose
        if gt is None or abs(gt[0] - msg.stamp) > self.config.align_max_dt:
            return
        t, yaw = rl.odom_in_world(gt[1], gt[2], msg.position, msg.orientation)
        rl.log_odom_alignment(self.rec, msg.stamp, t, yaw)
        self._aligned_at = msg.stamp

    def _on_odometry(self, msg: m.Odometry) -> bool:
        if self.config.align_odom and (self._aligned_at is None or msg.stamp < self._aligned_at):
            self._align_odom(msg)  # first odometry, or the first of a new run
        if self._odom_trail_rate.allow(msg.stamp):
            if msg.stamp < self._odom_trail_t:  # time went back: a new run
                self._odom_trail.clear()
            self._odom_trail_t = msg.stamp
            if self._odom_trail.add(msg.position):
                rl.log_trail(self.rec, f"{rl.ODOM}/trajectory", msg.stamp, self._odom_trail.array())
        if not self._odom.allow(msg.stamp):
            return False
        rl.log_odometry(self.rec, msg)
        return True

    def _on_debug(self, msg: m.LocomotionDebug) -> bool:
        if not self._debug.allow(msg.stamp):
            return False
        rl.log_locomotion_debug(self.rec, msg)
        feet = self._feet
        if feet is not None:
            rl.log_foot_forces(
                self.rec, msg.stamp, feet[0], msg.foot_forces, feet[1], self.config.force_scale
            )
        return True

    def _on_cmd_vel(self, msg: m.BodyVelocityCommand) -> bool:
        if not self._cmd.allow(msg.stamp):
            return False
        rl.log_velocity_command(self.rec, msg)
        return True

    def _on_arm_trajectory(self, msg: m.ArmTrajectory) -> bool:
        return rl.log_arm_trajectory(self.rec, msg) > 0

    def _on_gripper_command(self, msg: m.GripperCommand) -> bool:
        rl.log_gripper_command(self.rec, msg)
        return True

    def _on_gt_base(self, msg: m.GroundTruthPoses) -> bool:
        if "base" not in msg.names:
            return False
        i = msg.names.index("base")
        pos, quat = msg.positions[i], msg.orientations[i]
        self._gt_pose = (float(msg.stamp), pos, quat)  # read by the odometry thread
        v = self._gt_velocity.update(msg.stamp, pos, quat)
        if v is not None:
            rl.log_velocity_estimate(self.rec, "gt", msg.stamp, *v)
        if self._gt_trail_rate.allow(msg.stamp):
            if msg.stamp < self._gt_trail_t:
                self._gt_trail.clear()
            self._gt_trail_t = msg.stamp
            if self._gt_trail.add(pos):
                rl.log_trail(
                    self.rec,
                    f"{rl.GT}/base_trajectory",
                    msg.stamp,
                    self._gt_trail.array(),
                    color=(255, 200, 0),
                )
        if not self._gt_base.allow(msg.stamp):
            return False
        rl.log_gt_base(self.rec, msg)
        return True

    def _on_gt_objects(self, msg: m.GroundTruthPoses) -> bool:
        if not self._gt_objects.allow(msg.stamp):
            return False
        rl.log_gt_objects(self.rec, msg)
        return True

    def _on_gt_contacts(self, msg: m.GroundTruthContacts) -> bool:
        if not self._gt_contacts.allow(msg.stamp):
            return False
        rl.log_gt_contacts(self.rec, msg)
        return True

    def _on_health(self, msg: m.LocomotionHealth) -> bool:
        self._health_last = rl.log_health(self.rec, msg, self._health_last)
        return True

    def _on_judge(self, msg: m.JudgeReport) -> bool:
        rl.log_judge(self.rec, msg)
        return True

    def _on_heartbeat(self, msg: m.Heartbeat) -> bool:
        return rl.log_heartbeat(self.rec, msg, self._heartbeats, robot_time=self._last_stamp)

    # ------------------------------------------------------------------ counters
    def stats(self) -> dict[str, StreamStats]:
        """A snapshot of every stream's counters (bus drops and decode errors included)."""
        out: dict[str, StreamStats] = {}
        for stream, st in self._stats.items():
            with self._locks[stream]:
                snap = dataclasses.replace(st)
            subs = self._subs.get(stream, [])
            snap.bus_dropped = sum(s.dropped_count for s in subs)
            snap.decode_errors = sum(self.bus.stats.key(s.key).decode_errors for s in subs)
            out[stream] = snap
        return out

    def _report(self, final: bool = False) -> None:
        stats = self.stats()
        summary = {
            k: (v.received, v.logged, v.decimated, v.bus_dropped, v.errors, v.decode_errors)
            for k, v in stats.items()
            if v.received or v.bus_dropped or v.decode_errors
        }
        if not final and summary == self._reported:
            return
        self._reported = summary
        fields = {
            k: f"recv={v[0]} logged={v[1]} decimated={v[2]} bus_dropped={v[3]} "
            f"errors={v[4]} decode_errors={v[5]}"
            for k, v in summary.items()
        }
        self.log.info("viz stats" + (" (final)" if final else ""), **fields)
        text = "; ".join(f"{k}: {v}" for k, v in fields.items()) or "nothing received yet"
        try:
            rl.log_text(self.rec, f"{rl.LOG}/viz", self._last_stamp, text, "DEBUG")
        except Exception as exc:  # noqa: BLE001
            self.log.warning("stats not recorded", error=repr(exc))

    def step(self) -> None:
        now = time.monotonic()
        if now - self._last_report >= self.config.stats_period:
            self._last_report = now
            self._report()

    def teardown(self) -> None:
        rec: Recordings | None = getattr(self, "rec", None)
        if rec is None:
            return
        self._report(final=True)
        # Wait (briefly) for callbacks mid-log, so none writes while the file closes.
        held = [lock for lock in self._locks.values() if lock.acquire(timeout=0.2)]
        self._closed = True
        for lock in held:
            lock.release()
        t0 = time.monotonic()
        closed = rec.close(self.config.flush_timeout)
        self.log.info("recording closed", close_s=round(time.monotonic() - t0, 3), **closed)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service viz``."""
    return run_service(VizNode, argv)


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
