"""The perception service: detections, object memory, grasp poses and drawer handles.

Inputs: ``sim/camera/front`` and ``sim/camera/gripper`` (RGB-D with K and the camera pose
in the base frame), ``sim/lowstate`` (joint states: grasps are computed from frames taken
while the arm stands still), ``locomotion/odometry`` (the odom frame of the object
memory), ``navigation/pose`` (map-frame centroids when navigation runs) and
``behavior/progress`` (the tracks of objects the task took up are forgotten). Never
anything under ``sim/gt``.

Outputs: ``perception/detections`` (per processed frame: boxes, classes, scores and the
3-D placement of each), ``perception/objects`` (the object memory, every
``objects_period`` and on a change).

Actions: ``estimate_grasp`` (``GraspRequest`` -> a ``GraspGoal`` for the manipulation
service, paper Sections 4.3-4.6) and ``locate_handle`` (``HandleRequest`` -> a
``DrawerGoal``).

Threads: Zenoh callbacks only store the newest frame per camera (a frame that arrives
while the previous one is processed replaces it: latest only, counted as dropped); one
worker thread detects and places objects and updates the memory; action threads wait for
a fresh processed frame and compute the grasp or handle from it. Bad frames (no colour,
absurd intrinsics, empty depth) are skipped with a throttled log line and a counter, and a
camera that stops publishing is reported once per outage; an action then fails with the
reason.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.actions import ActionFailed, GoalHandle
from quadmanip.common.joint_layout import N_LEG_JOINTS
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.common.reasons import refusal_text
from quadmanip.common.robot_description import (
    FRONT_CAMERA,
    GRIPPER_CAMERA,
    tcp_in_gripper_camera,
)
from quadmanip.common.rotations import quat_from_yaw, quat_to_mat, yaw_from_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.perception.config import PerceptionConfig
from quadmanip.services.perception.detector import Detection, Detector, reported
from quadmanip.services.perception.frames import (
    Located,
    camera_in_odom,
    close_view_class,
    cut_off,
    frame_problem,
    implausible_grasp,
    level_frame,
    locate_detection,
    look_down,
    pick_target,
    plausible_extent,
    surface_of,
)
from quadmanip.services.perception.grasp_pose import GraspEstimate, estimate_grasp_from_depth
from quadmanip.services.perception.handle_locator import locate_handle
from quadmanip.services.perception.object_memory import (
    CameraView,
    MapAnchor,
    ObjectMemory,
    Observation,
    planar_pose_matrix,
)
from quadmanip.services.perception.rejections import save_rejection
from quadmanip.services.perception.seen_area import FLOOR, TABLE, SeenArea

__all__ = ["PerceptionNode", "main"]

CAMERA_TOPICS = {FRONT_CAMERA: "sim/camera/front", GRIPPER_CAMERA: "sim/camera/gripper"}


@dataclass
class Processed:
    """One processed frame: the image, the base pose in odom at its stamp (None: no
    odometry near it), every detection candidate, their 3-D placements, whether the arm
    stood still, and the detections reported (published, remembered)."""

    img: m.RgbdImage
    base: tuple[np.ndarray, np.ndarray] | None
    detections: list[Detection]
    located: list[Located]
    arm_still: bool
    problem: str = ""  # why the frame was not used ("" if it was)
    reported: list[Detection] = field(default_factory=list)  # what was published
    wall: float = field(default_factory=time.monotonic)


def _xyz(p: np.ndarray) -> str:
    """A point as the log writes it: ``[x, y, z]`` to the centimetre."""
    return f"[{p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}]"


def seen_grid(area: SeenArea, stamp: float) -> m.SeenGrid:
    """``area`` as the ``perception/seen`` message (copies)."""
    x0, y0 = area.origin
    cells = area.seen(FLOOR) * m.SEEN_FLOOR | area.seen(TABLE) * m.SEEN_TABLE
    return m.SeenGrid(stamp=stamp, origin=[x0, y0], resolution=area.config.resolution,
                      cells=cells.astype(np.uint8), floor_at=area.seen_at(FLOOR).copy(),
                      table_at=area.seen_at(TABLE).copy())  # fmt: skip


class PerceptionNode(Service):
    """Detects, places and remembers objects; serves grasp and handle estimates."""

    name = "perception"
    config_type = PerceptionConfig
    inputs = (
        Input("sim/camera/front", latest_only=True, doc="front RGB-D"),
        Input("sim/camera/gripper", latest_only=True, doc="gripper RGB-D"),
        Input("sim/lowstate", latest_only=True, doc="joint speeds: is the arm still"),
        Input("locomotion/odometry", doc="base pose in odom (history kept)"),
        Input("navigation/pose", latest_only=True, doc="map->odom for map-frame tracks"),
        Input("behavior/progress", doc="objects the task took up: their tracks forgotten"),
    )
    outputs = (
        Output("perception/detections", doc="detections per frame"),
        Output("perception/objects", doc="object memory"),
        Output("perception/seen", doc="floor and table tops seen (map frame)"),
    )
    actions = ("estimate_grasp", "locate_handle")
    loop_period = 0.1

    # ------------------------------------------------------------------ setup
    def setup(self) -> None:
        cfg: PerceptionConfig = self.config
        self.detector = Detector(cfg.detector)
        self.catalogue = load_catalogue()
        unknown = [c for c in self.detector.classes if c not in self.catalogue.objects]
        if unknown:
            raise ValueError(f"detector classes not in the object catalogue: {unknown}")
        unknown = sorted(set(cfg.memory.miss_ranges) - set(self.catalogue.objects))
        if unknown:
            raise ValueError(f"memory.miss_ranges names classes not in the catalogue: {unknown}")
        self.memory = ObjectMemory(cfg.memory)
        self.seen = SeenArea(cfg.seen)
        self.t_seen = -math.inf
        self.t_frame = 0.0  # stamp of the newest frame marked in the seen grid
        self.lock = threading.Lock()
        self.cond = threading.Condition(self.lock)
        self.pending: dict[str, m.RgbdImage] = {}
        # newest gripper camera pose in the base frame (stamp, position, orientation)
        self.gripper_pose: tuple[float, np.ndarray, np.ndarray] | None = None
        self.tcp_in_camera = tcp_in_gripper_camera()
        self.processed: dict[str, Processed] = {}
        self.last_frame_wall = {c: time.monotonic() for c in CAMERA_TOPICS}
        self.camera_silent = {c: False for c in CAMERA_TOPICS}
        self.odom: deque[m.Odometry] = deque(maxlen=400)
        self.counters = {
            "frames": 0,
            "frames_dropped": 0,
            "bad_frames": 0,
            "no_odometry": 0,
            "camera_timeouts": 0,
            "detections": 0,
            "frame_errors": 0,
            "views_not_remembered": 0,
            "implausible_extent": 0,
            "implausible_grasp": 0,
        }
        self.frame_ms: deque[float] = deque(maxlen=200)
        self.t_objects = -math.inf
        self.lowstate = self.latest("sim/lowstate")
        self.map_pose = self.latest("navigation/pose")
        self.map_anchor = MapAnchor()
        self.pub_det = self.publisher("perception/detections")
        self.pub_obj = self.publisher("perception/objects")
        self.pub_seen = self.publisher("perception/seen")
        for cam, topic in CAMERA_TOPICS.items():
            self.subscribe(topic, lambda img, cam=cam: self._on_frame(cam, img))
        self.subscribe("locomotion/odometry", self._on_odom)
        # track ids the task reported taken up (None until its first progress message)
        self.taken: set[int] | None = None
        self.subscribe("behavior/progress", self._on_progress)
        self.worker = threading.Thread(target=self._work, name="perception-worker", daemon=True)
        self.worker.start()
        self.action_server("estimate_grasp", self._grasp, accept=self._accept, policy="parallel")
        self.action_server("locate_handle", self._handle, accept=self._accept, policy="parallel")
        self.log.info("detector loaded", classes=len(self.detector.classes),
                      weights=str(cfg.detector.weights))  # fmt: skip
        self.set_state("running")

    # ------------------------------------------------------------------ inputs
    def _on_frame(self, cam: str, img: m.RgbdImage) -> None:
        with self.cond:
            if cam == GRIPPER_CAMERA:  # where the tool centre is, for the held sphere
                self.gripper_pose = (img.stamp, img.position.copy(), img.orientation.copy())
            if cam in self.pending:
                self.counters["frames_dropped"] += 1
            self.pending[cam] = img
            self.last_frame_wall[cam] = time.monotonic()
            self.cond.notify_all()

    def _on_odom(self, od: m.Odometry) -> None:
        with self.lock:
            self.odom.append(od)

    def _on_progress(self, p: m.TaskProgress) -> None:
        """Forget the tracks of the objects the task took up: a track stays where its
        object lay until a camera shows the spot empty, and navigation keeps a floor
        track's spot as an obstacle (seed-120: a soup can's spot, 0.1 m from the living
        table's stand, refused every walk to that table after the can was placed). The ids
        taken up before this perception started are not its own (a restart numbers its
        tracks afresh): the first message only says which they are. The tracks taken are
        the ones at each grasp, not a grasped record's track now: after its object fell
        out of the gripper or its box, that names the object lying there (paper-1,
        2026-12-07: the cracker box's track on the floor was forgotten at once, its
        estimate refused as of an unknown track)."""
        ids = {int(t) for t in p.taken_track_ids}
        with self.lock:
            if self.taken is None:
                self.taken = ids
                return
            new = ids - self.taken
            self.taken |= new
            gone = [t for t in sorted(new) if self.memory.remove(t)]
        for t in gone:
            self.log.info("track forgotten: the task took the object up", id=t)

    def _base_at(self, stamp: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Base pose in odom nearest ``stamp`` (None if none within ``odom_max_skew``)."""
        with self.lock:
            hist = list(self.odom)
        if not hist:
            return None
        od = min(hist, key=lambda o: abs(o.stamp - stamp))
        if abs(od.stamp - stamp) > self.config.node.odom_max_skew:
            return None
        return od.position.copy(), od.orientation.copy()

    def _held_sphere(
        self, stamp: float, base_position: np.ndarray, base_orientation: np.ndarray
    ) -> tuple[np.ndarray, float] | None:
        """The sphere about the tool centre in odom at ``stamp`` that the memory ignores
        (what the gripper holds is no object lying there; None: no recent gripper pose)."""
        with self.lock:
            pose = self.gripper_pose
        nc = self.config.node
        if pose is None or abs(pose[0] - stamp) > nc.held_pose_max_age:
            return None
        _, p, q = pose
        tcp_base = p + quat_to_mat(q) @ self.tcp_in_camera
        return base_position + quat_to_mat(base_orientation) @ tcp_base, nc.held_radius

    def _arm_still(self) -> bool:
        ls = self.lowstate.get()
        if ls is None:
            return False
        qd = np.asarray(ls.joints.dq)[N_LEG_JOINTS:]
        return bool(np.all(np.abs(qd) < self.config.node.arm_still))

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        while not self.stopping:
            with self.cond:
                while not self.pending and not self.stopping:
                    self.cond.wait(0.2)
                if self.stopping:
                    return
                # the older of the waiting frames first: both cameras keep their turn
                cam = min(self.pending, key=lambda c: self.pending[c].stamp)
                img = self.pending.pop(cam)
            try:
                self._process(cam, img)
            except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the worker
                self.counters["frame_errors"] += 1
                self.log.exception("frame processing failed", camera=cam, error=repr(exc))

    def _process(self, cam: str, img: m.RgbdImage) -> None:
        cfg: PerceptionConfig = self.config
        t0 = time.perf_counter()
        why = frame_problem(img, cfg.frames)
        if why:
            self.counters["bad_frames"] += 1
            self.log.throttled(f"bad:{cam}", 5.0, logging.WARNING, "frame skipped", camera=cam,
                               reason=why, count=self.counters["bad_frames"])  # fmt: skip
            with self.cond:
                self.processed[cam] = Processed(img, None, [], [], False, problem=why)
                self.cond.notify_all()
            return
        still = self._arm_still()
        dc = cfg.detector
        candidates = self.detector(img.rgb, img.depth)  # down to score_threshold
        dets = reported(candidates, dc.report_threshold, dc.overlap_iou)
        base = self._base_at(img.stamp)
        held = None if base is None else self._held_sphere(img.stamp, *base)
        if base is None:
            self.counters["no_odometry"] += 1
            # the base frame alone still serves a grasp; the memory needs odom
            base_pose = (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
        else:
            # from here on the camera pose is in the level body frame (manipulation's)
            img = level_frame(img, base[1])
            base = base_pose = (base[0], quat_from_yaw(yaw_from_quat(base[1])))
        located = []
        placed: dict[tuple[float, ...], Located | None] = {}
        for d in candidates:  # every candidate: a grasp request may name a runner-up class
            # one object's class peaks share the box (the size head is class-agnostic):
            # place each box once
            if d.box not in placed:
                placed[d.box] = locate_detection(img, d, *base_pose, cfg.frames, cfg.grasp.filter)
            loc = placed[d.box]
            if loc is not None:
                located.append(replace(loc, detection=d))
        # the robot's own fingers in the gripper camera are not objects (too near), nor is
        # its trunk (its points fall in the filter's self box: nothing is left to place)
        near = {id(x.detection) for x in located if x.camera_range < cfg.frames.min_range}
        located = [x for x in located if id(x.detection) not in near]
        placed_ids = {id(x.detection) for x in located}
        dets = [d for d in dets if id(d) in placed_ids]
        candidates = [d for d in candidates if id(d) in placed_ids]
        self.counters["frames"] += 1
        self.counters["detections"] += len(dets)
        # the gripper camera looking ahead (arm stowed) sees the trunk: not for the memory
        remember = cam != GRIPPER_CAMERA or look_down(img) >= cfg.node.gripper_min_look_down
        if not remember:
            self.counters["views_not_remembered"] += 1
        if base is not None and remember:
            cam_p, cam_q = camera_in_odom(img, *base)
            view = CameraView(
                camera=cam,
                K=img.K,
                width=img.depth.shape[1],
                height=img.depth.shape[0],
                position=cam_p,
                orientation=cam_q,
                depth=img.depth,
            )
            shown = {id(d) for d in dets}
            nc = cfg.node
            # a box that framed furniture is far larger than any object of its class
            shown_loc = [x for x in located if id(x.detection) in shown]
            sized = [
                x
                for x in shown_loc
                if plausible_extent(
                    x.extent,
                    self.catalogue.objects[x.detection.label].size,
                    nc.extent_ratio,
                    nc.extent_margin,
                )
            ]
            self.counters["implausible_extent"] += len(shown_loc) - len(sized)
            h, w = img.depth.shape
            obs = [
                Observation(
                    class_name=x.detection.label,
                    score=x.detection.score,
                    centroid=x.centroid_odom,
                    extent=x.extent,
                    camera=cam,
                    partial=cut_off(x.detection.box, w, h, nc.edge_px),
                )
                for x in sized
            ]
            with self.lock:
                self._follow_the_map()
                before = self.memory.confirmed_ids()
                self.memory.update(obs, view, img.stamp, blind=held)
                fresh = self.memory.confirmed_ids() - before  # (copies of these only)
                new = [t for i in sorted(fresh) if (t := self.memory.get(i)) is not None]
                gone = list(self.memory.missed_out)
            self._mark_seen(cam, img, cam_p, cam_q, np.asarray(base[0])[:2])
            for t in new:  # where a track comes from, for whoever reads a trial's log
                self.log.info("track confirmed", id=t.id, cls=t.class_name, camera=cam,
                              odom=_xyz(t.centroid), seen=t.observations)  # fmt: skip
            for t, far in gone:  # ... and where it went from the memory
                self.log.info("track dropped: not seen where it was expected", id=t.id,
                              cls=t.class_name, camera=cam, range_m=round(far, 2),
                              odom=_xyz(t.centroid), seen=t.observations)  # fmt: skip
        where = {id(x.detection): x for x in located}
        n = len(dets)
        cents = np.zeros((n, 3))
        exts = np.zeros((n, 3), np.float32)
        ok = np.zeros(n, np.uint8)
        for i, d in enumerate(dets):
            x = where.get(id(d))
            if x is not None and base is not None:
                cents[i], exts[i], ok[i] = x.centroid_odom, x.extent, 1
        self.pub_det.publish(
            m.Detections(
                stamp=img.stamp,
                camera=cam,
                frame_stamp=img.stamp,
                labels=[d.label for d in dets],
                scores=np.array([d.score for d in dets], np.float32),
                boxes=np.array([d.box for d in dets], np.float32).reshape(n, 4),
                centroids=cents,
                extents=exts,
                located=ok,
            )
        )
        with self.cond:
            self.processed[cam] = Processed(img, base, candidates, located, still, reported=dets)
            self.cond.notify_all()
        self.frame_ms.append((time.perf_counter() - t0) * 1000.0)

    # ------------------------------------------------------------------ loop
    def step(self) -> None:
        now = time.monotonic()
        timeout = self.config.node.frame_timeout
        for cam, t in self.last_frame_wall.items():
            silent = now - t > timeout
            if silent and not self.camera_silent[cam]:
                self.counters["camera_timeouts"] += 1
                self.log.warning("camera silent", camera=cam, seconds=round(now - t, 1),
                                 count=self.counters["camera_timeouts"])  # fmt: skip
            elif not silent and self.camera_silent[cam]:
                self.log.info("camera back", camera=cam)
            self.camera_silent[cam] = silent
        if now - self.t_objects >= self.config.node.objects_period:
            self._publish_objects()
            self.t_objects = now
        if now - self.t_seen >= self.config.seen.period:
            with self.lock:
                grid = seen_grid(self.seen, self.t_frame)
            self.pub_seen.publish(grid)
            self.t_seen = now

    def _follow_the_map(self) -> None:
        """The tracks follow navigation's map->odom correction (``MapAnchor``). Caller
        holds the lock."""
        mp = self.map_pose.get()
        ok = mp is not None and mp.status in ("localized", "mapping")
        move = self.map_anchor.step(mp.map_to_odom if ok and mp is not None else None)
        if move is not None:
            self.memory.move_frame(move)

    def _mark_seen(
        self, cam: str, img: m.RgbdImage, cam_p: np.ndarray, cam_q: np.ndarray, base_xy: np.ndarray
    ) -> None:
        """The floor and table top this remembered frame shows, into the seen grid (map
        frame: only while navigation publishes where the map lies)."""
        mp = self.map_pose.get()
        if mp is None or mp.status == "lost":
            return
        cfg = self.config.seen
        reach = cfg.front_range if cam == FRONT_CAMERA else cfg.gripper_range
        se2 = planar_pose_matrix(*(float(v) for v in mp.map_to_odom))
        with self.lock:
            self.seen.mark_frame(
                img.depth, img.K, cam_p, cam_q, reach, se2, base_xy, float(img.stamp)
            )
            self.t_frame = max(self.t_frame, float(img.stamp))

    def _publish_objects(self) -> None:
        mp = self.map_pose.get()
        with self.lock:
            self._follow_the_map()  # also while no frame comes (the cameras stopped)
            tracks = self.memory.tracks(confirmed_only=False)
        n = len(tracks)
        cents = np.array([t.centroid for t in tracks], float).reshape(n, 3)
        in_map = mp is not None and mp.status != "lost"
        if in_map:
            se2 = planar_pose_matrix(*(float(v) for v in mp.map_to_odom))
            map_c = cents.copy()
            map_c[:, :2] = cents[:, :2] @ se2[:2, :2].T + se2[:2, 2]
        else:
            map_c = cents.copy()
        self.pub_obj.publish(
            m.ObjectTracks(
                stamp=max((t.last_seen for t in tracks), default=0.0),
                ids=np.array([t.id for t in tracks], np.int32),
                labels=[t.class_name for t in tracks],
                centroids=cents,
                extents=np.array([t.extent for t in tracks], np.float32).reshape(n, 3),
                confidences=np.array([t.confidence for t in tracks], np.float32),
                observations=np.array([t.observations for t in tracks], np.int32),
                last_seen=np.array([t.last_seen for t in tracks], float),
                confirmed=np.array([t.confirmed for t in tracks], np.uint8),
                map_centroids=map_c,
                in_map=bool(in_map),
            )
        )

    # ------------------------------------------------------------------ actions
    def _accept(self, goal: m.Message) -> tuple[bool, str]:
        now = time.monotonic()
        cams = (FRONT_CAMERA,) if isinstance(goal, m.HandleRequest) else tuple(CAMERA_TOPICS)
        if isinstance(goal, m.GraspRequest) and goal.camera:
            cams = (goal.camera,)
        fresh = [c for c in cams if now - self.last_frame_wall[c] <= self.config.node.frame_timeout]
        if not fresh:
            ages = ", ".join(f"{c} {now - self.last_frame_wall[c]:.1f} s" for c in cams)
            return False, f"no camera frame: {ages} since the last"
        if isinstance(goal, m.GraspRequest):
            if goal.label and goal.label not in self.detector.classes:
                return False, f"unknown class {goal.label!r}"
            if goal.track_id >= 0:
                with self.lock:
                    known = any(t.id == goal.track_id for t in self.memory.tracks(False))
                if not known:
                    return False, f"unknown track {goal.track_id}"
        return True, ""

    def _fresh(self, cams: tuple[str, ...], after: float, handle: GoalHandle) -> list[Processed]:
        """Wait for processed frames of ``cams`` taken (robot time) after ``after`` while
        the arm stood still; returns those that came within ``grasp_timeout``."""
        deadline = time.monotonic() + self.config.node.grasp_timeout
        with self.cond:
            while True:
                got = [
                    p
                    for c in cams
                    if (p := self.processed.get(c)) is not None
                    and p.img.stamp > after
                    and (p.arm_still or p.problem)
                ]
                if len(got) == len(cams) or time.monotonic() >= deadline:
                    return got
                if handle.cancel_requested:
                    return got
                self.cond.wait(0.05)

    def _robot_now(self) -> float:
        with self.lock:
            return self.odom[-1].stamp if self.odom else -math.inf

    def _reach(self, goal: m.GraspRequest, camera: str) -> float:
        """How far from the base a grasp target may lie (m): the request's, else the
        configured reach (a side probe with the front camera looks from farther back)."""
        node = self.config.node
        side = camera == FRONT_CAMERA
        return goal.max_distance or (node.max_side_probe if side else node.max_reach)

    def _save_rejection(
        self, img: m.RgbdImage, det: Detection, where: str, probing: str, reason: str
    ) -> None:
        try:
            path = save_rejection(
                Path(self.config.node.save_rejected),
                stamp=img.stamp,
                depth=img.depth,
                rgb=img.rgb,
                box=det.box,
                K=img.K,
                position=img.position,
                orientation=img.orientation,
                label=det.label,
                camera=img.camera,
                where=where,
                probing=probing,
                reason=reason,
            )
            self.log.info("rejected estimate saved", file=str(path))
        except OSError as exc:  # a full disk must not turn a rejection into a crash
            self.log.warning("cannot save a rejected estimate", error=repr(exc))

    def _grasp(self, handle: GoalHandle) -> m.Message:
        goal: m.GraspRequest = handle.goal  # type: ignore[assignment]
        cfg: PerceptionConfig = self.config
        cams = (goal.camera,) if goal.camera else tuple(CAMERA_TOPICS)
        near = None
        label = goal.label
        if goal.track_id >= 0:
            with self.lock:
                tr = next((t for t in self.memory.tracks(False) if t.id == goal.track_id), None)
            if tr is None:
                raise ActionFailed(f"not in view: track {goal.track_id} was forgotten")
            near, label = np.asarray(tr.centroid), tr.class_name
        # a target missed in one frame (a detector's miss, the camera still settling) is
        # looked for in the next ones, up to ``view_frames`` per camera
        after = self._robot_now()
        choices: list[tuple[float, Processed, Detection, Located | None]] = []
        reasons: list[str] = []
        for _ in range(cfg.node.view_frames):
            frames = self._fresh(cams, after, handle)
            handle.check_cancel()
            if not frames:
                reasons.append("no fresh frame with the arm still")
                break
            after = max(p.img.stamp for p in frames)
            reasons = []
            for p in frames:
                if p.problem:
                    reasons.append(f"{p.img.camera}: bad frame: {p.problem}")
                    continue
                if near is not None and p.base is None:
                    reasons.append(f"{p.img.camera}: no odometry to match the track")
                    continue
                # a named class may be taken from every candidate; an unnamed target only
                # from what perception reports
                pool = p.detections if label else p.reported
                det, loc, why = pick_target(
                    p.located,
                    pool,
                    p.img.depth.shape,
                    label,
                    near,
                    cfg.node.track_gate,
                    self._reach(goal, p.img.camera),
                )
                if det is None:
                    reasons.append(f"{p.img.camera}: {why}")
                    continue
                area = (det.box[2] - det.box[0]) * (det.box[3] - det.box[1])
                choices.append((area, p, det, loc))
            if choices:
                break
        if not choices:
            raise ActionFailed("; ".join(reasons) or "not in view")
        _, p, det, loc = max(choices, key=lambda c: c[0])
        if label:
            named = close_view_class(
                det, p.reported, cfg.detector.overlap_iou, cfg.node.relabel_margin
            )
            if named is not det:
                self.log.info("the close view names it otherwise", asked=label,
                              asked_score=round(det.score, 2), named=named.label,
                              named_score=round(named.score, 2))  # fmt: skip
                det = named
                loc = next((x for x in p.located if x.detection is named), None)
        reach = self._reach(goal, p.img.camera)
        if loc is not None and loc.distance > reach:
            raise ActionFailed(f"too far: {det.label} {loc.distance:.2f} m away (reach {reach} m)")
        img = p.img
        probing = "vertical" if img.camera == GRIPPER_CAMERA else "horizontal"

        def estimate(where: str) -> GraspEstimate:
            return estimate_grasp_from_depth(
                img.depth,
                det.box,
                img.K,
                img.position,
                img.orientation,
                det.label,
                self.catalogue,
                probing=probing,
                where=where,
                cfg=cfg.grasp,
            )

        # floor or table decides 4.3's probing direction: from the object's top less the
        # class's height (a tall box seen from above would otherwise look like a table's)
        spec = self.catalogue.objects.get(det.label)
        where = surface_of(loc, p.base, float(spec.size[2]) if spec is not None else 0.0)
        est = estimate(where)
        why = None
        if spec is not None:  # (a refusal too: "probe horizontally" a 0.40 m "sugar box")
            nc = cfg.node
            measured = math.isfinite(est.height)  # (a hang is no height: never "flat")
            tall = est.height if measured else est.hang
            flat = nc.flat_ratio if measured else 0.0
            why = implausible_grasp(
                det.label, tall, spec.size, nc.extent_ratio, nc.extent_margin, flat
            )
        if why is not None:
            self.counters["implausible_grasp"] += 1
            raise ActionFailed(f"{img.camera}: {why}")
        if not est.ok:
            reason = refusal_text(est.reason, det.label, img.camera, est.detail)
            if cfg.node.save_rejected:
                self._save_rejection(img, det, where, probing, reason)
            raise ActionFailed(reason)
        self.log.info(
            "grasp estimated", cls=det.label, camera=img.camera, approach=est.approach,
            position=np.round(est.position, 3).tolist(), center=np.round(est.center, 3).tolist(),
            yaw=round(float(est.yaw), 3), width=round(float(est.width), 3),
        )  # fmt: skip
        return m.GraspGoal(
            stamp=img.stamp,
            position=est.position,
            yaw=est.yaw,
            approach=est.approach,  # type: ignore[arg-type]
            width=est.width,
            object_name=det.label,
            tilt=est.tilt,
            mass=est.mass,
            hang=est.hang,
            center=list(est.center) if np.all(np.isfinite(est.center)) else [],
        )

    def _handle(self, handle: GoalHandle) -> m.Message:
        goal: m.HandleRequest = handle.goal  # type: ignore[assignment]
        frames = self._fresh((FRONT_CAMERA,), self._robot_now(), handle)
        handle.check_cancel()
        if not frames:
            raise ActionFailed("not in view: no fresh front-camera frame")
        img = frames[0].img
        if frames[0].problem:
            raise ActionFailed(f"bad frame: {frames[0].problem}")
        res = locate_handle(
            img.depth, img.K, img.position, img.orientation, goal.position, self.config.handle
        )
        if not res.ok:
            raise ActionFailed(f"{res.reason}: {res.detail}")
        return m.DrawerGoal(
            stamp=img.stamp,
            handle_position=res.position,
            pull_direction=res.pull_direction,
            distance=goal.distance,
        )

    def teardown(self) -> None:
        with self.cond:
            self.cond.notify_all()
        self.worker.join(timeout=1.0)
        ms = sorted(self.frame_ms)
        self.log.info("perception counters", **self.counters,
                      frame_ms_p50=round(ms[len(ms) // 2], 1) if ms else None)  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service perception``."""
    return run_service(PerceptionNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
