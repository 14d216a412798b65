"""The behavior service: the tidy-up task (paper Sections 5 and 7.2) wired to the bus.

The task itself (:mod:`.tidy_task`) is transport-free; this node gives it a
:class:`BusRobot`, its :class:`~.robot_api.RobotApi` over the other services:

* actions (clients): manipulation's ``move_to_posture``, ``grasp``, ``place``,
  ``open_drawer``; navigation's ``navigate_to`` and ``approach``; perception's
  ``estimate_grasp`` and ``locate_handle``;
* inputs: ``navigation/pose`` (the map pose and map->odom), ``perception/objects`` (the
  object memory), ``locomotion/odometry`` (the base in odom: manipulation's goals are in
  the level body frame), ``locomotion/payload`` (what the gripper holds, as manipulation
  told locomotion), ``locomotion/health`` (standing?), ``*/heartbeat`` and the liveliness
  tokens ``*/alive`` (which services run). Never anything under ``sim/gt``.

Outputs: ``behavior/progress`` (:class:`~quadmanip.common.messages.TaskProgress`, at every
step change and every ``progress_period``; ``idle`` before the first task),
``locomotion/mode`` (``stand`` when the robot lies damped before a task or after
locomotion restarted; ``recover`` first when it is tripped or lies on a side) and
``navigation/initial_pose`` (where the robot is, for a navigation that came back after a
restart: :class:`PoseHint`).

Action (server): ``tidy_up`` (``TidyUpGoal``: a class filter and a time budget; the
result is the final ``TaskProgress``). With ``[node] start_on_launch`` the node runs one
tidy-up on its own at start (what ``quadmanip tidyup`` and ``quadmanip up`` rely on); a
goal while a task runs is rejected ``busy``.

Before a task starts the node waits (``start_timeout``, wall) until the required services
run, locomotion stands and navigation has localised the robot.

Restarts (:mod:`.service_watch`): the launcher restarts a service that dies. The node
follows the required services' liveliness tokens and heartbeats; a request whose service
went away (or any request when locomotion went away: the robot lies down) is cancelled and
ends at once with ``Outcome.interrupted``, instead of waiting out ``action_timeout`` for
a result that the new process will never send; one to a service that does not run is not
sent. Readings from before a restart are not trusted after it: locomotion's health (until
it stands again), navigation's pose (``localised``), manipulation's payload (``holding``
is None until it speaks again) and, once the task forgets them, perception's tracks.

Threads: the task runs in its own thread (the action's, or the launch thread) and blocks
in one request at a time; Zenoh callbacks only fill latest-value caches; the control loop
(``step``) publishes progress.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.actions import ActionCanceled, ActionClient, ActionFailed, GoalHandle
from quadmanip.common.bus import LatestCache
from quadmanip.common.config import CONFIG_DIR
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.common.places import load_places
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.behavior.config import BehaviorConfig
from quadmanip.services.behavior.frames import (
    BasePose,
    Point3,
    Pose2,
    base_from_odom,
    carried_over,
    compose,
    map_from_odom,
    odom_from_base,
    odom_from_map,
    wrap,
)
from quadmanip.services.behavior.report import Progress
from quadmanip.services.behavior.robot_api import GraspPlan, HandlePlan, Outcome, SeenObject
from quadmanip.services.behavior.service_watch import ServiceWatch, stand_command
from quadmanip.services.behavior.tidy_task import (
    TidyTask,
    classes_from_catalogue,
    knowledge_problems,
)

__all__ = ["BehaviorNode", "BusRobot", "PoseHint", "main", "progress_message"]

#: action name -> the service that serves it
CLIENTS = {
    "move_to_posture": "manipulation",
    "grasp": "manipulation",
    "place": "manipulation",
    "open_drawer": "manipulation",
    "navigate_to": "navigation",
    "approach": "navigation",
    "estimate_grasp": "perception",
    "locate_handle": "perception",
}
STAND_EVERY_S = 2.0  # wall s between stand requests while the robot lies damped
# pose hints to a navigation that came back after a restart (PoseHint)
HINT_EVERY_S = 2.0  # wall s between repeats while navigation has not taken it
HINT_TRIES = 5
HINT_STD_XY = 0.1  # m: the least doubt a hint claims (navigation's own start spread)
HINT_STD_YAW = math.radians(5.0)
HINT_STD_LAID = (0.25, math.radians(15.0))  # m, rad: locomotion restarted since
HINT_AGREE_XY = 0.3  # m: navigation localised this near the hint has it (its hint_agree_xy)


def _xyz(v: Sequence[float]) -> Point3:
    return (float(v[0]), float(v[1]), float(v[2]))


def resolve_places(name: str) -> Path:
    """A places file by path, else under configs/ (``maps/house.places.toml``)."""
    p = Path(name)
    return p if p.is_file() else CONFIG_DIR / name


def fresh(cache: LatestCache[Any], since: float) -> Any:
    """The cache's newest message if it arrived at or after wall time ``since``, else None
    (a reading from before a service's restart)."""
    age = cache.age
    if age is None or time.monotonic() - age < since:
        return None
    return cache.get()


def progress_message(p: Progress, stamp: float) -> m.TaskProgress:
    """The task's snapshot as a message."""
    objs = p.objects
    return m.TaskProgress(
        stamp=stamp,
        state=p.state,
        reason=p.reason[:4096],
        step=p.step[:256],
        current_object=p.current_object[:128],
        elapsed=p.elapsed,
        budget=max(p.budget, 0.0),
        drawers_opened=list(p.drawers_opened),
        zones_searched=list(p.zones_searched),
        zones_total=p.zones_total,
        failed=sum(o.given_up for o in objs),
        objects=[o.label for o in objs],
        object_track_ids=np.array([o.track_id for o in objs], np.int32),
        object_found_at=np.array([o.t_found for o in objs], float),
        object_grasped=np.array([o.grasped for o in objs], bool),
        object_placed=np.array([o.placed for o in objs], bool),
        object_given_up=np.array([o.given_up for o in objs], bool),
        object_time_s=np.array([max(o.time_spent, 0.0) for o in objs], float),
        object_attempts=np.array([o.attempts for o in objs], np.int32),
        object_failures=["\n".join(o.failures)[:4096] for o in objs],
        object_positions=np.array([o.first_position for o in objs], float).reshape(-1, 3),
        taken_track_ids=np.array(p.taken_tracks, np.int32),
    )


def _ended(state: str, reason: str, budget: float) -> Progress:
    """The snapshot of a task that never started (``state`` ``idle`` or ``failed``)."""
    return Progress(state, reason, "", "", 0.0, budget, (), (), 0, ())


class PoseHint:
    """Tells a restarted navigation where the robot is (``navigation/initial_pose``).

    A new navigation process starts its localisation at the configured start pose, not
    where the robot stands; navigation re-initialises around a pose hint when its filter
    disagrees strongly with it (:meth:`quadmanip.services.navigation.amcl.ParticleFilter.hint`).
    This remembers the last ``localized`` map pose of navigation's current run (with its
    map->odom and locomotion's life at the time) and, when navigation comes back after a
    restart, sends that pose carried along by the odometry since (the map->odom does not
    change while nobody corrects it), with the pose's own doubt (at least navigation's
    usual start spread). When locomotion restarted meanwhile its odometry started again,
    so the pose is sent as it was, with a wider doubt (the robot lay down and stood up).

    The hint is repeated every ``HINT_EVERY_S`` (wall) until navigation's pose from its new
    run is ``localized`` within ``HINT_AGREE_XY`` of it, at most ``HINT_TRIES`` times (a
    hint published as the new process's subscriber is still being matched can be lost);
    after that navigation owns the pose. No transport here: :meth:`update` is fed by the
    node's control loop and returns the message to publish.
    """

    def __init__(self) -> None:
        self.last: tuple[m.MapPose, int] | None = None  # pose, locomotion's life then
        self.pending = False
        self.tries = 0
        self.t_sent = -math.inf
        self.sent: m.InitialPose | None = None

    def hint(self, stamp: float, odometry: m.Odometry | None, loco_life: int) -> m.InitialPose:
        """The hint for now (only while a last pose is known)."""
        assert self.last is not None
        mp, life = self.last
        cov = np.asarray(mp.covariance, dtype=float)
        sxy = math.sqrt(max(float(cov[0, 0]), float(cov[1, 1]), 0.0))
        syaw = math.sqrt(max(float(cov[2, 2]), 0.0))
        if odometry is not None and life == loco_life:
            m2o = (float(mp.map_to_odom[0]), float(mp.map_to_odom[1]), float(mp.map_to_odom[2]))
            od = odometry
            pose = compose(m2o, (float(od.position[0]), float(od.position[1]),
                                 yaw_from_quat(od.orientation)))  # fmt: skip
            floor, why = (HINT_STD_XY, HINT_STD_YAW), "carried by the odometry"
        else:
            pose = (float(mp.x), float(mp.y), float(mp.yaw))
            floor, why = HINT_STD_LAID, "locomotion restarted since"
        return m.InitialPose(
            stamp=stamp,
            x=pose[0],
            y=pose[1],
            yaw=wrap(pose[2]),
            std_xy=max(sxy, floor[0]),
            std_yaw=max(syaw, floor[1]),
            source=f"behavior: the last pose before navigation restarted ({why})",
        )

    def update(
        self,
        wall: float,
        stamp: float,
        nav_pose: m.MapPose | None,
        odometry: m.Odometry | None,
        loco_life: int,
        nav_restarted: bool = False,
    ) -> m.InitialPose | None:
        """One control step at wall time ``wall`` (robot time ``stamp``): ``nav_pose`` is
        navigation's newest pose *from its current run* (None when it does not run or has
        not spoken since it started), ``loco_life`` counts locomotion's outages,
        ``nav_restarted`` says navigation just came back after a restart. Returns the hint
        to publish now, or None."""
        if nav_restarted:
            self.pending = self.last is not None
            self.tries, self.t_sent, self.sent = 0, -math.inf, None
        localised = nav_pose if nav_pose is not None and nav_pose.status == "localized" else None
        if self.pending and localised is not None:
            hint = self.hint(stamp, odometry, loco_life)
            if (
                math.hypot(float(localised.x) - hint.x, float(localised.y) - hint.y)
                <= HINT_AGREE_XY
            ):
                self.pending = False  # navigation has taken it (or knew)
        if not self.pending:
            if localised is not None:
                self.last = (localised, loco_life)
            return None
        if wall - self.t_sent < HINT_EVERY_S:
            return None
        if self.tries >= HINT_TRIES:
            self.pending = False  # navigation owns the pose: the task will see where it is
            return None
        hint = self.hint(stamp, odometry, loco_life)
        self.tries += 1
        self.t_sent = wall
        self.sent = hint
        return hint


class BusRobot:
    """:class:`~.robot_api.RobotApi` over the bus (see the module docstring).

    Frames: the task speaks the map frame; navigation's ``approach`` takes odom targets
    (map->odom from ``navigation/pose``), manipulation's goals and perception's requests
    the level body frame (odometry's base pose).
    """

    def __init__(self, node: BehaviorNode, cancelled: Callable[[], bool]) -> None:
        self.node = node
        self.cfg = node.config.node
        self.cancelled = cancelled
        self.watch: ServiceWatch = node.watch
        # robot time before which perception's tracks are not trusted (forget_objects)
        self.objects_since = -math.inf
        # a posture move sent without waiting (move_to_posture(wait=False)) and its goal
        self._arm_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="posture")
        self._arm_moving: tuple[Future[tuple[Outcome, m.Message | None]], m.PostureGoal] | None
        self._arm_moving = None

    # ------------------------------------------------------------------ state
    def now(self) -> float:
        return self.node.bus.clock()

    def wait(self, seconds: float) -> None:
        t_end = self.now() + seconds
        deadline = time.monotonic() + self.cfg.action_timeout
        while self.now() < t_end and not self.cancelled() and time.monotonic() < deadline:
            time.sleep(0.02)

    def _map_to_odom(self) -> Pose2:
        mp = self.node.map_pose.get()
        if mp is None:
            return (0.0, 0.0, 0.0)
        return (float(mp.map_to_odom[0]), float(mp.map_to_odom[1]), float(mp.map_to_odom[2]))

    def _base(self) -> BasePose:
        od = self.node.odometry.get()
        if od is None:
            raise RuntimeError("no odometry: the base frame is unknown")
        p = od.position
        return BasePose(float(p[0]), float(p[1]), float(p[2]), yaw_from_quat(od.orientation))

    def _to_base(self, p_map: Point3) -> Point3:
        return base_from_odom(self._base(), odom_from_map(self._map_to_odom(), p_map))

    def pose(self) -> Pose2 | None:
        mp = self.node.map_pose.get()
        if mp is None or mp.status == "lost":
            return None
        return (float(mp.x), float(mp.y), float(mp.yaw))

    def objects(self) -> list[SeenObject]:
        tracks = self.node.tracks.get()
        if tracks is None:
            return []
        m2o = self._map_to_odom()
        return [
            SeenObject(
                track_id=int(tracks.ids[i]),
                label=tracks.labels[i],
                position=map_from_odom(m2o, _xyz(tracks.centroids[i])),
                confirmed=bool(tracks.confirmed[i]),
                confidence=float(tracks.confidences[i]),
            )
            for i in range(len(tracks.labels))
            if float(tracks.last_seen[i]) >= self.objects_since
        ]

    def seen(
        self, points: Sequence[tuple[float, float]], table: bool, since: float = -math.inf
    ) -> list[bool] | None:
        grid = self.node.seen_grid.get()
        if grid is None:
            return None
        bit = m.SEEN_TABLE if table else m.SEEN_FLOOR
        xy = np.asarray(points, float).reshape(-1, 2)
        return [bool(v) for v in grid.seen(xy, bit, since)]

    def holding(self) -> bool | None:
        since = -math.inf
        if self.watch.outages().get("manipulation", 0) > 0:
            # away, or restarted and not yet said what it holds: only what it says now
            if not self.watch.running("manipulation"):
                return None
            since = self.watch.running_since("manipulation")
        payload = fresh(self.node.payload, since)
        if payload is None:
            return None
        return float(payload.mass) > self.cfg.holding_min_mass

    # ------------------------------------------------------------------ services
    def outages(self) -> dict[str, int]:
        return self.watch.outages()

    def wait_for_services(self, services: Collection[str], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not all(self.watch.running(s) for s in services):
            if self.cancelled() or time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def stand_up(self) -> Outcome:
        """Ask for ``stand`` (or ``recover``, :func:`.service_watch.stand_command`) every
        ``STAND_EVERY_S`` until a health message from locomotion's current run says it
        stands; at most ``stand_timeout`` (wall)."""
        deadline = time.monotonic() + self.cfg.stand_timeout
        t_asked = -math.inf
        h = None
        while True:
            if not self.watch.running("locomotion"):
                return Outcome(False, "locomotion is not running", interrupted="locomotion")
            h = fresh(self.node.health, self.watch.running_since("locomotion"))
            if h is not None:
                if h.state != "tripped" and h.phase in self.cfg.standing_phases:
                    return Outcome(True)
                mode = stand_command(h.state, h.phase, bool(h.upright))
                if mode is not None and time.monotonic() - t_asked > STAND_EVERY_S:
                    self.node.pub_mode.publish(m.LocomotionMode(stamp=self.now(), mode=mode))
                    t_asked = time.monotonic()
            if self.cancelled():
                return Outcome(False, "cancelled")
            if time.monotonic() > deadline:
                said = "no health" if h is None else f"{h.state}/{h.phase} {h.reason}".strip()
                return Outcome(False, f"not standing after {self.cfg.stand_timeout:.0f} s ({said})")
            time.sleep(0.05)

    def localised(self) -> bool:
        if not self.watch.running("navigation"):
            return False
        mp = fresh(self.node.map_pose, self.watch.running_since("navigation"))
        return mp is not None and mp.status in ("localized", "mapping")

    def forget_objects(self) -> None:
        self.objects_since = self.now()

    # ------------------------------------------------------------------ requests
    def _lost(self, services: Collection[str], before: dict[str, int]) -> str:
        """The first of ``services`` that does not run now or went away since ``before``
        (outage counts), "" when none."""
        now = self.watch.outages()
        for s in sorted(services):
            if not self.watch.running(s) or now.get(s, 0) != before.get(s, 0):
                return s
        return ""

    def _act(self, action: str, goal: m.Message) -> tuple[Outcome, m.Message | None]:
        """Send ``goal`` and wait for its end (cancelled with the task, or cut short when
        its service or one of ``interrupt_all_on`` goes away); a request that did not
        succeed is logged with its reason (a refusal leaves no trace in its server's log)."""
        out, res = self._act_once(action, goal)
        if not out.ok:
            self.node.log.info("request not done", action=action, rejected=out.rejected,
                               reason=out.reason)  # fmt: skip
        return out, res

    def _act_once(self, action: str, goal: m.Message) -> tuple[Outcome, m.Message | None]:
        service = CLIENTS[action]
        depends = {service, *self.cfg.interrupt_all_on} & set(self.watch.services)
        before = self.watch.outages()
        gone = self._lost(depends, before)
        if gone:  # not sent: nobody would answer it (or it would run on a robot lying down)
            return Outcome(False, f"{gone} is not running", interrupted=gone), None
        handle = self.node.clients[action].send_goal(goal, timeout=self.cfg.goal_timeout)
        if not handle.accepted:
            gone = self._lost(depends, before)
            if gone:
                return Outcome(False, f"{action}: {gone} went away", interrupted=gone), None
            return Outcome(False, f"{handle.reason or 'rejected'}", rejected=True), None
        deadline = time.monotonic() + self.cfg.action_timeout
        res = None
        while res is None:
            gone = self._lost(depends, before)
            if gone:
                # its server may be gone with the process: a short cancel, no waiting
                handle.cancel(timeout=0.5)
                return Outcome(False, f"{action}: {gone} went away", interrupted=gone), None
            if self.cancelled() or time.monotonic() > deadline:
                handle.cancel()
                res = handle.result(timeout=2.0)
                why = "cancelled" if self.cancelled() else f"{action}: no result in time"
                return Outcome(False, why), None
            res = handle.result(timeout=1.0, poll_s=1.0)
        if res.status == "succeeded":
            return Outcome(True), res.result
        return Outcome(False, res.reason or res.status), res.result

    def navigate_to(
        self, place: str = "", pose: Pose2 | None = None, lead_in: bool = False
    ) -> Outcome:
        c = self.cfg
        goal = m.NavigateGoal(
            stamp=self.now(),
            place=place,
            pose=list(pose) if pose is not None else [0.0, 0.0, 0.0],
            frame="map",
            tolerance_xy=c.lead_in_tolerance_xy if lead_in else c.nav_tolerance_xy,
            tolerance_yaw=c.nav_tolerance_yaw,
            ignore_yaw=lead_in,  # the approach turns the robot to its stance
            pass_through=lead_in,
        )
        return self._act("navigate_to", goal)[0]

    def approach(
        self,
        target: tuple[float, float],
        standoff: float,
        heading: float | None = None,
        loose: bool = False,
        turn_free: bool = False,
    ) -> Outcome:
        c = self.cfg
        m2o = self._map_to_odom()
        t_odom = odom_from_map(m2o, (target[0], target[1], 0.0))
        goal = m.ApproachGoal(
            stamp=self.now(),
            target=[t_odom[0], t_odom[1]],
            frame="odom",
            standoff=float(standoff),
            heading=wrap(heading - m2o[2]) if heading is not None else 0.0,
            face_target=heading is None,
            tolerance_xy=c.stand_tolerance_xy if loose else c.approach_tolerance_xy,
            tolerance_yaw=c.stand_tolerance_yaw if loose else c.approach_tolerance_yaw,
            turn_free=turn_free and heading is not None,
        )
        return self._act("approach", goal)[0]

    def wait_for_arm(self) -> Outcome:
        """Wait for a posture move sent without waiting; one that failed is sent again,
        blocking (what the request after it needs is the arm at that posture)."""
        moving, self._arm_moving = self._arm_moving, None
        if moving is None:
            return Outcome(True)
        future, goal = moving
        out = future.result()[0]
        if out.ok or out.interrupted or self.cancelled():
            return out
        again = m.PostureGoal(stamp=self.now(), posture=goal.posture)
        return self._act("move_to_posture", again)[0]

    def move_to_posture(self, posture: str, wait: bool = True) -> Outcome:
        out = self.wait_for_arm()
        if not out.ok:
            return out
        goal = m.PostureGoal(stamp=self.now(), posture=posture)
        if wait:
            return self._act("move_to_posture", goal)[0]
        self._arm_moving = (self._arm_pool.submit(self._act, "move_to_posture", goal), goal)
        return Outcome(True)

    def estimate_grasp(
        self, label: str, camera: str, track_id: int = -1
    ) -> tuple[Outcome, GraspPlan | None]:
        if not (settled := self.wait_for_arm()).ok:
            return settled, None
        req = m.GraspRequest(stamp=self.now(), track_id=track_id, label=label, camera=camera)
        out, res = self._act("estimate_grasp", req)
        if not out.ok or not isinstance(res, m.GraspGoal):
            return (out if not out.ok else Outcome(False, "no grasp in the result")), None
        # the robot stood still while probing: the base now is the base the frame saw
        base = self._base()
        seen = odom_from_base(base, _xyz(res.position))
        return out, GraspPlan(
            position=_xyz(res.position),
            yaw=float(res.yaw),
            approach=res.approach,
            width=float(res.width),
            object_name=res.object_name,
            seen_from=base,
            position_map=map_from_odom(self._map_to_odom(), seen),
            tilt=float(res.tilt),
            mass=float(res.mass),
            hang=float(res.hang),
            center=_xyz(res.center) if len(res.center) == 3 else None,
        )

    def grasp(self, plan: GraspPlan) -> Outcome:
        if not (settled := self.wait_for_arm()).ok:
            return settled
        base = self._base()
        position, yaw = carried_over(plan.position, plan.yaw, plan.seen_from, base)
        center = []
        if plan.center is not None:
            center = list(carried_over(plan.center, plan.yaw, plan.seen_from, base)[0])
        goal = m.GraspGoal(
            stamp=self.now(),
            position=list(position),
            yaw=yaw,
            approach=plan.approach,
            width=plan.width,
            object_name=plan.object_name,
            tilt=plan.tilt,
            mass=plan.mass,
            hang=plan.hang,
            center=center,
        )
        return self._act("grasp", goal)[0]

    def place(self, position: Point3, yaw: float | None = None) -> Outcome:
        if not (settled := self.wait_for_arm()).ok:
            return settled
        goal = m.PlaceGoal(
            stamp=self.now(),
            position=list(self._to_base(position)),
            yaw=0.0 if yaw is None else float(yaw),
            turn=yaw is not None,
        )
        return self._act("place", goal)[0]

    def locate_handle(self, hint: Point3, distance: float) -> tuple[Outcome, HandlePlan | None]:
        if not (settled := self.wait_for_arm()).ok:
            return settled, None
        req = m.HandleRequest(
            stamp=self.now(), position=list(self._to_base(hint)), distance=float(distance)
        )
        out, res = self._act("locate_handle", req)
        if not out.ok or not isinstance(res, m.DrawerGoal):
            return (out if not out.ok else Outcome(False, "no handle in the result")), None
        return out, HandlePlan(
            _xyz(res.handle_position), _xyz(res.pull_direction), float(res.distance)
        )

    def open_drawer(self, handle: HandlePlan) -> Outcome:
        if not (settled := self.wait_for_arm()).ok:
            return settled
        goal = m.DrawerGoal(
            stamp=self.now(),
            handle_position=list(handle.position),
            pull_direction=list(handle.pull_direction),
            distance=handle.distance,
        )
        return self._act("open_drawer", goal)[0]


class BehaviorNode(Service):
    """Runs the tidy-up task; serves ``tidy_up``; publishes its progress."""

    name = "behavior"
    config_type = BehaviorConfig
    inputs = (
        Input("navigation/pose", latest_only=True, doc="map pose + map->odom"),
        Input("perception/objects", latest_only=True, doc="the object memory"),
        Input("perception/seen", latest_only=True, doc="floor and table tops seen"),
        Input("locomotion/odometry", latest_only=True, doc="base in odom: the body frame"),
        Input("locomotion/payload", latest_only=True, doc="what the gripper holds"),
        Input("locomotion/health", latest_only=True, doc="standing? tripped?"),
        Input("*/heartbeat", doc="which services run, and when one restarted"),
    )
    outputs = (
        Output("behavior/progress", doc="the task's step and per-object record"),
        Output("locomotion/mode", doc="stand up before a task"),
        Output("navigation/initial_pose", doc="where the robot is, after navigation restarted"),
    )
    actions = ("tidy_up",)
    loop_period = 0.1

    def setup(self) -> None:
        """Loads the places file and the catalogue, checks them against the config, wires
        the caches and clients; starts a task when ``start_on_launch``."""
        cfg: BehaviorConfig = self.config
        self.places = load_places(resolve_places(cfg.node.places_file))
        self.classes = classes_from_catalogue(load_catalogue())
        problems = knowledge_problems(
            self.classes, self.places, cfg.task, cfg.drawers, cfg.search, cfg.deposits
        )
        if problems:
            raise ValueError(f"behavior config: {'; '.join(problems)}")
        self.map_pose = self.latest("navigation/pose")
        self.tracks = self.latest("perception/objects")
        self.seen_grid = self.latest("perception/seen")
        self.odometry = self.latest("locomotion/odometry")
        self.payload = self.latest("locomotion/payload")
        self.health = self.latest("locomotion/health")
        self.pub_progress = self.publisher("behavior/progress")
        self.pub_mode = self.publisher("locomotion/mode")
        self.pub_hint = self.publisher("navigation/initial_pose")
        self.pose_hint = PoseHint()
        self.watch = ServiceWatch(cfg.node.required_services, cfg.node.heartbeat_timeout)
        self.bus.watch_liveliness(
            lambda service, alive: self.watch.liveliness(service, alive, time.monotonic())
        )
        self.subscribe("*/heartbeat", self._on_heartbeat)
        self.clients: dict[str, ActionClient] = {
            action: self.bus.action_client(service, action) for action, service in CLIENTS.items()
        }
        self.lock = threading.Lock()
        self.busy = False
        self.task: TidyTask | None = None
        self.last = _ended("idle", "", cfg.task.trial_budget_s)
        self.t_published = -math.inf
        self.action_server("tidy_up", self._execute, accept=self._accept, policy="reject")
        if cfg.node.start_on_launch:
            self.busy = True
            threading.Thread(target=self._run_on_launch, name="tidy-up", daemon=True).start()
        self.log.info("ready", places=len(self.places), classes=len(self.classes),
                      start_on_launch=cfg.node.start_on_launch)  # fmt: skip
        self.set_state("running")

    def _on_heartbeat(self, msg: m.Heartbeat) -> None:
        self.watch.heartbeat(msg.service, int(msg.seq), msg.state, time.monotonic())

    # ------------------------------------------------------------------ progress
    def _publish(self, p: Progress) -> None:
        self.pub_progress.publish(progress_message(p, self.bus.clock()))
        self.t_published = time.monotonic()

    def _on_step(self, p: Progress) -> None:
        self.last = p
        self._publish(p)

    def step(self) -> None:
        """Services gone silent; progress about once a second between step changes (and
        ``idle`` before)."""
        self.watch.tick(time.monotonic())
        nav_restarted = False
        for t in self.watch.drain():
            if t.what == "back":
                self.log.info("service running", service=t.service)
                if t.service == "navigation" and self.watch.outages().get("navigation", 0):
                    nav_restarted = True
            else:
                self.log.warning("service went away", service=t.service, why=t.why)
        self._hint_pose(nav_restarted)
        if time.monotonic() - self.t_published < self.config.node.progress_period:
            return
        task = self.task
        self._publish(task.progress() if task is not None else self.last)

    def _hint_pose(self, nav_restarted: bool) -> None:
        """Feed :class:`PoseHint`; publish the hint it asks for."""
        nav = None
        if self.watch.running("navigation"):
            nav = fresh(self.map_pose, self.watch.running_since("navigation"))
        loco_life = self.watch.outages().get("locomotion", 0)
        hint = self.pose_hint.update(time.monotonic(), self.bus.clock(), nav,
                                     self.odometry.get(), loco_life, nav_restarted)  # fmt: skip
        if hint is not None:
            self.pub_hint.publish(hint)
            self.log.info("pose hint to navigation", x=round(hint.x, 3), y=round(hint.y, 3),
                          yaw=round(hint.yaw, 3), tries=self.pose_hint.tries)  # fmt: skip

    # ------------------------------------------------------------------ running a task
    def _get_ready(self, cancelled: Callable[[], bool]) -> str:
        """Wait until the robot can start (module docstring); "" or why it cannot."""
        nc = self.config.node
        deadline = time.monotonic() + nc.start_timeout
        t_stand = -math.inf
        while True:
            missing = sorted(set(nc.required_services) & self.watch.not_running())
            h = self.health.get()
            standing = h is not None and h.state != "tripped" and h.phase in nc.standing_phases
            # lying damped: stand up (a trip at the start is a person's to clear: not here),
            # once every service runs: a standing robot's control loops take most of a
            # small computer, and the others would then start (import, load models) slowly
            if h is not None and h.state != "tripped" and not missing:
                mode = stand_command(h.state, h.phase, bool(h.upright))
                if mode is not None and time.monotonic() - t_stand > STAND_EVERY_S:
                    self.pub_mode.publish(m.LocomotionMode(stamp=self.bus.clock(), mode=mode))
                    t_stand = time.monotonic()
            mp = self.map_pose.get()
            localised = mp is not None and mp.status in ("localized", "mapping")
            if not missing and standing and localised:
                return ""
            if cancelled():
                return "cancelled before the start"
            if time.monotonic() > deadline:
                why = []
                if missing:
                    why.append(f"services not running: {', '.join(missing)}")
                if not standing:
                    state = "no health" if h is None else f"{h.state}/{h.phase} {h.reason}"
                    why.append(f"locomotion not standing ({state.strip()})")
                if not localised:
                    why.append(f"not localised ({'no pose' if mp is None else mp.status})")
                return "; ".join(why)
            time.sleep(0.2)

    def _run(
        self,
        labels: Sequence[str],
        budget: float | None,
        cancelled: Callable[[], bool],
        feedback: Callable[[Progress], None] | None = None,
    ) -> Progress:
        """One task from readiness to report (in the calling thread)."""
        cfg: BehaviorConfig = self.config
        full_budget = cfg.task.trial_budget_s if budget is None else budget
        self._on_step(Progress("running", "", "getting ready", "", 0.0, full_budget, (), (), 0, ()))
        why = self._get_ready(lambda: cancelled() or self.stopping)
        if why:
            self.log.error("tidy-up not started", reason=why)
            end = _ended("canceled" if "cancelled" in why else "failed", why, full_budget)
            self._on_step(end)
            return end

        def on_step(p: Progress) -> None:
            self._on_step(p)
            if feedback is not None:
                feedback(p)

        task = TidyTask(
            BusRobot(self, lambda: cancelled() or self.stopping),
            self.classes,
            self.places,
            cfg.task,
            cfg.drawers,
            cfg.search,
            cfg.deposits,
            labels=labels,
            time_budget=budget,
            on_step=on_step,
            cancelled=lambda: cancelled() or self.stopping,
        )
        self.task = task
        self.log.info("tidy-up started", budget=task.budget, labels=list(labels))
        try:
            report = task.run()
        finally:
            self.task = None
        end = task.progress()
        self._on_step(end)
        self.log.info(
            "tidy-up ended",
            outcome=report.outcome,
            reason=report.reason,
            found=len(report.objects),
            placed=end.placed,
            given_up=end.given_up,
            drawers=list(end.drawers_opened),
            views_skipped=task.views_skipped,
            seconds=round(end.elapsed, 1),
        )
        return end

    def _run_on_launch(self) -> None:
        try:
            self._run((), None, lambda: False)
        except Exception as exc:  # noqa: BLE001 - say why in the log and the progress
            self.log.exception("tidy-up crashed", error=repr(exc))
            self._on_step(_ended("failed", repr(exc), self.config.task.trial_budget_s))
        finally:
            with self.lock:
                self.busy = False

    # ------------------------------------------------------------------ action
    def _accept(self, goal: m.Message) -> tuple[bool, str]:
        if not isinstance(goal, m.TidyUpGoal):
            return False, f"unsupported goal {type(goal).__name__}"
        unknown = sorted(set(goal.labels) - set(self.classes))
        if unknown:
            return False, f"unknown classes {unknown}"
        with self.lock:
            if self.busy:
                return False, "busy: a tidy-up is running"
            self.busy = True  # claimed until the goal's thread ends
        return True, ""

    def _execute(self, handle: GoalHandle) -> m.Message | None:
        goal: m.TidyUpGoal = handle.goal  # type: ignore[assignment]

        def feedback(p: Progress) -> None:
            done = p.elapsed / p.budget if p.budget > 0 else 0.0
            handle.feedback(min(max(done, 0.0), 1.0), p.step[:4096])

        try:
            end = self._run(
                list(goal.labels),
                goal.time_budget or None,
                lambda: handle.cancel_requested,
                feedback,
            )
        finally:
            with self.lock:
                self.busy = False
        result = progress_message(end, self.bus.clock())
        if end.state == "canceled":
            raise ActionCanceled(end.reason, result)
        if end.state == "failed":
            raise ActionFailed(end.reason, result)
        return result


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service behavior``."""
    return run_service(BehaviorNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
