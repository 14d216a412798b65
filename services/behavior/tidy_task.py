"""The tidy-up task (paper Sections 5 and 7.2) as an explicit state machine.

The robot opens the left, right and top drawers (Section 7.2; the tools' drawer is pulled
far enough for a tool to fit), then searches the zones of the places file: floors in the
floor-search posture with the gripper camera, tables in the table-search posture with the
front camera (Figure 12), from the viewpoints of :mod:`.coverage`. Whenever the object
memory holds a graspable object, it takes the nearest, approaches it into its probing
area (Algorithm 5), asks perception for a grasp, grasps (Algorithm 6), carries it to its
category's place, places it, and checks that it let go. The task ends when every zone has
been searched and nothing graspable is left, when the time budget is spent, or when it is
cancelled.

States (:class:`Step`) and what each does; every handler returns the next state::

    OPEN_DRAWERS -> GO_TO_VIEWPOINT -> LOOK -> CHOOSE_TARGET -> APPROACH -> PROBE -> GRASP
                          ^                         |                                 |
                          +---- (nothing left) -----+      CARRY <--------------------+
                          +-------------------------------- VERIFY <- PLACE <- CARRY
    CHOOSE_TARGET -> DONE when every zone is searched and nothing graspable remains

Retries are the ones a person would make: another grasp estimate after a failed grasp,
facing the grasp point again when manipulation says it lies too far to the side, a step
back (or closer) when it is too close (too far), another approach when the object was not
in view, another stance for a place out of reach. Every failure is recorded with its
reason and counts against the object; after ``max_attempts`` the object is given up, so
one stubborn object cannot eat the trial.

The task talks to the robot only through :class:`.robot_api.RobotApi` (the node
implements it over the other services' actions and topics; the unit tests with a
simulated house). It reads no ground truth: what it knows is the places file, the object
catalogue (each class's size and deposit place: robot knowledge, not where anything is)
and what the robot's own services report.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Literal

from quadmanip.common.object_catalogue import Catalogue
from quadmanip.common.places import Place
from quadmanip.services.behavior.coverage import SearchConfig, zone_viewpoints
from quadmanip.services.behavior.frames import Point3, Pose2, wrap
from quadmanip.services.behavior.report import (
    DrawerRecord,
    Failure,
    ObjectRecord,
    ObjectSummary,
    Progress,
    TaskReport,
)
from quadmanip.services.behavior.robot_api import (
    GraspPlan,
    Outcome,
    RobotApi,
    SeenObject,
)

__all__ = [
    "DepositSpec",
    "DrawerConfig",
    "ObjectClass",
    "Step",
    "TaskConfig",
    "TidyTask",
    "classes_from_catalogue",
    "knowledge_problems",
]

# Rejections of manipulation's grasp and place planners that a change of stance fixes
# (services/manipulation: grasp.py, place.py, arm_kinematics.py).
LATERAL = "lateral_out_of_range"
TOO_CLOSE = ("too_close", "self_collision")
TOO_FAR = "too_far"


# ------------------------------------------------------------------ what the robot knows


@dataclass(frozen=True)
class ObjectClass:
    """What the task knows of a class: where it goes and its resting size (m)."""

    place: str  # the catalogue's deposit place (pencil_case, tray, drawer, ...)
    height: float
    long_side: float


#: Name prefix of the search "zone" around where a held object fell (not a places-file zone).
DROP_ZONE = "dropped-at:"


def classes_from_catalogue(catalogue: Catalogue) -> dict[str, ObjectClass]:
    """Every catalogue class with its deposit place and size."""
    return {
        name: ObjectClass(
            place=catalogue.place_of(name),
            height=float(spec.size[2]),
            long_side=float(max(spec.size[0], spec.size[1])),
        )
        for name, spec in catalogue.objects.items()
    }


@dataclass(frozen=True)
class DepositSpec:
    """How to put an object into one deposit place (a person's measurements of it)."""

    place: str = ""  # the places file's name for it (the tools' drawer: drawer_top)
    reach: float = 0.43  # m: the release point this far ahead of the base
    # m: the release point this much nearer the robot than the place's target (the middle
    # of the near half of a box; for the drawer, of its open mouth)
    release_toward_robot: float = 0.0
    release_height: float = 0.0  # m above the target (its rim)
    # m: an object whose long side exceeds this goes in turned across the robot
    across_above: float = 1.0
    carry_posture: str = "carry"  # carry_high over a table's edge


@dataclass(frozen=True)
class DrawerConfig:
    """Opening the drawers (Section 7.2: left, right, top, before anything else)."""

    places: tuple[str, ...] = ("drawer_left", "drawer_right", "drawer_top")
    handle_standoff: float = 0.51  # m: base to the closed handle when pulling
    probe_posture: str = "probe_horizontal"  # the arm out of the front camera's view
    open_distance: float = 0.15  # m each drawer is opened
    # The tools go into this drawer, opened further: at 15 cm its mouth (11 cm) is
    # shorter than the clamp (16.5 cm); at 24 cm it is 20 cm.
    tool_drawer: str = "drawer_top"
    tool_drawer_open: float = 0.24
    max_pull: float = 0.19  # m one pull moves at most (the arm's and the body's travel)
    attempts: int = 3  # tries per pull (walk, locate, pull)


@dataclass(frozen=True)
class TaskConfig:
    """The task's choices: budgets, give-up rule, stances, what counts as graspable."""

    trial_budget_s: float = 1500.0  # s of robot time per trial; 0: none
    ready_timeout: float = 30.0  # s of robot time to wait for a map pose at the start
    max_attempts: int = 4  # failures an object may cost before it is given up
    zone_order: Literal["file", "nearest"] = "nearest"  # zones in file order or nearest next
    zones: tuple[str, ...] = ()  # the zones to search; empty: every search zone of the file
    walk_posture: str = "stow"  # the arm while walking without an object
    min_confidence: float = 0.3  # tracks below this are not acted on
    table_min_z: float = 0.25  # m: an object whose centre is higher lies on a table
    tall: float = 0.12  # m: table objects taller than this are probed from the side
    probe_floor_posture: str = "probe_floor"
    probe_table_posture: str = "probe_table"
    probe_side_posture: str = "probe_horizontal"
    probe_standoff: float = 0.36  # m: object centre ahead of the base to probe and grasp
    grasp_ahead: tuple[float, float] = (0.33, 0.40)  # m: a grasp point in this band is reachable
    side_probe_back: float = 0.70  # m farther back for the front camera (below a table top)
    step_back: float = 0.08  # m stepped back when the arm is too close
    step_closer: float = 0.05  # m stepped in when it is too far
    direct_approach_max: float = 1.5  # m: farther objects are walked to first
    walk_standoff: float = 0.8  # m short of the object that walk ends
    # Walks to a place's stand end this far behind it (along its heading), and the
    # approach does the last part: a stand next to furniture lies inside the costmap's
    # inflation once the LiDAR sees that furniture, and navigation then refuses the goal.
    stage_back: float = 0.5
    # A walk that fails this near its goal counts as arrived (the approach goes on).
    stage_accept: float = 0.6
    # After a drop: look at a drop_look_size square around where the grip was lost, from
    # drop_look_back behind that spot (the gripper camera sees 0.4-1.4 m ahead).
    drop_look_back: float = 0.8
    drop_look_size: float = 1.0
    same_object_radius: float = 0.25  # m: a track of the class this near is the same object
    # m: an object dropped on the way is looked for again in the zones this near its path
    drop_search_margin: float = 1.0
    tidy_radius: float = 0.4  # m: tracks this near a deposit place, drawer or cabinet are tidy
    place_attempts: int = 4  # place requests per attempt (out-of-reach steps between)
    place_step: float = 0.05  # m stepped when a place is out of reach
    verify_radius: float = 0.2  # m: a track of the class this near the release point saw it
    let_go_wait: float = 1.0  # s for the gripper to report empty after a place


class Step(Enum):
    """The task's states."""

    OPEN_DRAWERS = "open_drawers"
    GO_TO_VIEWPOINT = "go_to_viewpoint"
    LOOK = "look"
    CHOOSE_TARGET = "choose_target"
    APPROACH = "approach"
    PROBE = "probe"
    GRASP = "grasp"
    CARRY = "carry"
    PLACE = "place"
    VERIFY = "verify"
    DONE = "done"


@dataclass(frozen=True)
class _Probe:
    """How to probe the target: posture, camera, probing stance."""

    posture: str
    camera: str
    standoff: float
    horizontal: bool


class _Stop(Exception):
    """Raised inside a step when the budget is spent or the task is cancelled."""


def knowledge_problems(
    classes: Mapping[str, ObjectClass],
    places: Mapping[str, Place],
    cfg: TaskConfig,
    drawers: DrawerConfig,
    search: Mapping[str, SearchConfig],
    deposits: Mapping[str, DepositSpec],
    labels: Sequence[str] = (),
) -> list[str]:
    """What the task would miss to finish (empty: nothing), so a node refuses a bad
    configuration at start, before anything moves."""
    problems = []
    for name in (*cfg.zones, *drawers.places):
        if name not in places:
            problems.append(f"no place {name!r} in the places file")
    for kind in ("search_floor", "search_table"):
        if kind not in search:
            problems.append(f"no [search.{kind}] table")
    for label, cls in classes.items():
        dep = deposits.get(cls.place)
        if dep is None:
            problems.append(f"{label}: no deposit spec for its place {cls.place!r}")
        elif dep.place not in places:
            problems.append(f"{label}: deposit place {dep.place!r} not in the places file")
    unknown = sorted(set(labels) - set(classes))
    if unknown:
        problems.append(f"unknown classes {unknown}")
    return problems


def _dist(a: Sequence[float], b: Sequence[float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


class TidyTask:
    """One tidy-up trial. Construct, then :meth:`run` (blocking; from one thread).

    ``classes``: what the task knows of each class (:func:`classes_from_catalogue`);
    ``places``: the places file; ``search``: how each zone kind is searched;
    ``deposits``: how to put objects into each deposit place (catalogue place names);
    ``labels``: only these classes (empty: all); ``on_step``: called with a snapshot at
    every step change; ``cancelled``: polled between steps.
    """

    def __init__(
        self,
        robot: RobotApi,
        classes: Mapping[str, ObjectClass],
        places: Mapping[str, Place],
        cfg: TaskConfig,
        drawers: DrawerConfig,
        search: Mapping[str, SearchConfig],
        deposits: Mapping[str, DepositSpec],
        *,
        labels: Sequence[str] = (),
        time_budget: float | None = None,
        on_step: Callable[[Progress], None] | None = None,
        cancelled: Callable[[], bool] | None = None,
    ) -> None:
        self.robot = robot
        self.classes = dict(classes)
        self.places = dict(places)
        self.cfg = cfg
        self.drawer_cfg = drawers
        self.search = dict(search)
        self.deposits = dict(deposits)
        self.labels = frozenset(labels)
        self.budget = cfg.trial_budget_s if time_budget is None else time_budget
        self.on_step = on_step
        self.cancelled = cancelled or (lambda: False)
        problems = knowledge_problems(
            self.classes, self.places, cfg, drawers, self.search, self.deposits, self.labels
        )
        if problems:
            raise ValueError("; ".join(problems))
        zones = list(cfg.zones) or [
            p.name for p in self.places.values() if p.kind in ("search_floor", "search_table")
        ]
        self.zones_todo = zones
        self.report = TaskReport(zones_total=len(zones))
        self._lock = threading.Lock()
        self._step = Step.OPEN_DRAWERS
        # search state
        self.zone: Place | None = None
        self.viewpoints: list[Pose2] = []
        self.view_index = 0
        self.posture = ""
        # target state
        self.target: ObjectRecord | None = None
        self.probe: _Probe | None = None
        self.plan: GraspPlan | None = None
        self.done_tracks: set[int] = set()  # placed, given up or held: never a target again
        # a dropped object's track where it was last seen (in the gripper): not a target
        # until perception sees it somewhere else
        self.stale: dict[int, Point3] = {}
        self.picked_from: Point3 | None = None  # where the held object was grasped
        self.tidy_points = [
            p.target for p in self.places.values() if p.kind in ("deposit", "drawer", "cabinet")
        ]
        self._handlers: dict[Step, Callable[[], Step]] = {
            Step.OPEN_DRAWERS: self._open_drawers,
            Step.GO_TO_VIEWPOINT: self._go_to_viewpoint,
            Step.LOOK: self._look,
            Step.CHOOSE_TARGET: self._choose_target,
            Step.APPROACH: self._approach,
            Step.PROBE: self._probe,
            Step.GRASP: self._grasp,
            Step.CARRY: self._carry,
            Step.PLACE: self._place,
            Step.VERIFY: self._verify,
        }

    # ------------------------------------------------------------------ the loop
    def run(self) -> TaskReport:
        """Run the trial to its end; returns the report (also kept in :attr:`report`)."""
        rep = self.report
        rep.t_start = self.robot.now()
        step = Step.OPEN_DRAWERS
        try:
            self._wait_localised()
            while step is not Step.DONE:
                self._enter(step)
                t0, before = self.robot.now(), self.target
                try:
                    step = self._handlers[step]()
                finally:  # the step's time goes to the object it was for
                    rec = before or self.target
                    if rec is not None:
                        rec.time_spent += self.robot.now() - t0
            rep.outcome = "done"
        except _Stop as stop:
            rep.outcome, rep.reason = stop.args  # type: ignore[assignment]
        except Exception as exc:  # noqa: BLE001 - the report says why the trial ended
            rep.outcome, rep.reason = "failed", f"{type(exc).__name__}: {exc}"
        rep.t_end = self.robot.now()
        self._enter(Step.DONE, rep.reason or rep.outcome)
        return rep

    def _wait_localised(self) -> None:
        t_end = self.robot.now() + self.cfg.ready_timeout
        while self.robot.pose() is None:
            self._check_stop()
            if self.robot.now() >= t_end:
                raise _Stop("failed", f"not localised after {self.cfg.ready_timeout:.0f} s")
            self.robot.wait(0.5)

    def _check_stop(self) -> None:
        if self.cancelled():
            raise _Stop("canceled", "cancelled on request")
        elapsed = self.robot.now() - self.report.t_start
        if self.budget > 0 and elapsed >= self.budget:
            raise _Stop("budget", f"time budget of {self.budget:.0f} s spent")

    def _enter(self, step: Step, detail: str = "") -> None:
        """A step change: say so to the operator (and check budget and cancel)."""
        if step is not Step.DONE:
            self._check_stop()
            detail = detail or self._describe(step)
        with self._lock:
            self._step = step
            self.report.step = f"{step.value}: {detail}" if detail else step.value
        if self.on_step is not None:
            self.on_step(self.progress())

    def _say(self, detail: str) -> None:
        """A sub-step within the current step (shown, no budget check)."""
        with self._lock:
            self.report.step = f"{self._step.value}: {detail}"
        if self.on_step is not None:
            self.on_step(self.progress())

    def _describe(self, step: Step) -> str:
        if step in (Step.GO_TO_VIEWPOINT, Step.LOOK) and self.zone is not None:
            n = len(self.viewpoints)
            return f"{self.zone.name} view {min(self.view_index + 1, n)}/{n}"
        if self.target is not None and step not in (Step.CHOOSE_TARGET, Step.OPEN_DRAWERS):
            return self.target.name
        return ""

    def progress(self) -> Progress:
        """The current step and counts (thread-safe: the node publishes it at 1 Hz)."""
        with self._lock:
            rep = self.report
            end = rep.t_end if rep.outcome != "running" else self.robot.now()
            return Progress(
                state=rep.outcome,
                reason=rep.reason,
                step=rep.step,
                current_object=self.target.name if self.target is not None else "",
                elapsed=max(end - rep.t_start, 0.0),
                budget=self.budget,
                drawers_opened=tuple(d.place for d in rep.drawers if d.ok),
                zones_searched=tuple(rep.zones_searched),
                zones_total=rep.zones_total,
                objects=tuple(
                    ObjectSummary(
                        label=o.label,
                        track_id=o.track_id,
                        t_found=o.t_found,
                        grasped=o.grasped,
                        placed=o.placed,
                        given_up=o.given_up,
                        time_spent=o.time_spent,
                        attempts=o.attempts,
                        failures=tuple(f"{f.step}: {f.reason}" for f in o.failures),
                        first_position=o.first_position,
                    )
                    for o in rep.objects
                ),
            )

    # ------------------------------------------------------------------ helpers
    def _posture(self, name: str) -> Outcome:
        if name == self.posture:
            return Outcome(True)
        out = self.robot.move_to_posture(name)
        self.posture = name if out.ok else ""
        return out

    def _fail(self, step: Step, reason: str) -> bool:
        """Record a failure of the target; True when it is given up by that."""
        rec = self.target
        assert rec is not None
        with self._lock:
            rec.failures.append(Failure(step.value, reason, self.robot.now()))
            rec.attempts += 1
            if rec.attempts >= self.cfg.max_attempts:
                rec.given_up = True
                self.done_tracks.add(rec.track_id)
        return rec.given_up

    def _give_up_or(self, step: Step, reason: str, retry: Step) -> Step:
        """Record the failure; retry with ``retry``, or drop the object and search on."""
        if not self._fail(step, reason):
            return retry
        if self.robot.holding():
            self._put_down()
        self.target = None
        return Step.GO_TO_VIEWPOINT

    def _put_down(self) -> None:
        """Set a held object down on the floor ahead (after giving it up), so the gripper
        is free for the next one."""
        pose = self.robot.pose()
        if pose is None:
            return
        ahead = self.cfg.probe_standoff
        spot = (pose[0] + ahead * math.cos(pose[2]), pose[1] + ahead * math.sin(pose[2]), 0.0)
        self._say("putting the object down")
        self._posture(self.cfg.probe_floor_posture)
        self.robot.place(spot, None)

    def _walk_to_stand(self, place: Place) -> Outcome:
        """Walk to ``stage_back`` behind ``place``'s stand, facing its way; the caller's
        approach then steps in to where it needs to stand."""
        sx, sy, syaw = place.stand
        back = self.cfg.stage_back
        goal = (sx - back * math.cos(syaw), sy - back * math.sin(syaw), syaw)
        out = self.robot.navigate_to(pose=goal)
        if not out.ok and _dist(self._pose(), goal) < self.cfg.stage_accept:
            return Outcome(True)
        return out

    def _pose(self) -> Pose2:
        pose = self.robot.pose()
        if pose is None:
            raise _Stop("failed", "navigation lost the robot's pose")
        return pose

    def _tidy(self, obj: SeenObject) -> bool:
        """Already where objects go (a deposit place, a drawer): not to be picked up."""
        return any(_dist(obj.position, p) < self.cfg.tidy_radius for p in self.tidy_points)

    def _record_for(self, obj: SeenObject) -> ObjectRecord | None:
        """The record of this object: same track, or same class near where it was."""
        for rec in self.report.objects:
            if rec.track_id == obj.track_id and rec.label == obj.label:
                return rec
        for rec in self.report.objects:
            if (
                rec.label == obj.label
                and not rec.placed
                and _dist(rec.position, obj.position) < self.cfg.same_object_radius
            ):
                return rec
        return None

    def _graspable(self) -> list[tuple[SeenObject, ObjectRecord | None]]:
        """Confirmed, known, wanted, untidied objects not given up, with their records."""
        out = []
        for obj in self.robot.objects():
            if not obj.confirmed or obj.confidence < self.cfg.min_confidence:
                continue
            if obj.label not in self.classes or (self.labels and obj.label not in self.labels):
                continue
            if obj.track_id in self.done_tracks or self._tidy(obj):
                continue
            stale = self.stale.get(obj.track_id)
            if stale is not None:
                if _dist(stale, obj.position) < self.cfg.same_object_radius:
                    continue
                del self.stale[obj.track_id]  # seen where it fell
            rec = self._record_for(obj)
            if rec is not None and rec.finished:
                continue
            out.append((obj, rec))
        return out

    def _refresh_target(self) -> None:
        """The target's newest position from the memory (it may have been nudged)."""
        rec = self.target
        assert rec is not None
        for obj in self.robot.objects():
            if obj.track_id == rec.track_id and obj.label == rec.label:
                rec.position = obj.position
                return

    # ------------------------------------------------------------------ drawers
    def _open_drawers(self) -> Step:
        for name in self.drawer_cfg.places:
            rec = DrawerRecord(name)
            with self._lock:
                self.report.drawers.append(rec)
            want = self.drawer_cfg.open_distance
            if name == self.drawer_cfg.tool_drawer:
                want = max(want, self.drawer_cfg.tool_drawer_open)
            self._open_one(rec, want)
        self._posture(self.cfg.walk_posture)
        return Step.GO_TO_VIEWPOINT

    def _open_one(self, rec: DrawerRecord, want: float) -> None:
        """Pull drawer ``rec.place`` open by ``want`` m, in pulls of at most ``max_pull``
        (re-gripping the handle where the last pull left it)."""
        dc = self.drawer_cfg
        place = self.places[rec.place]
        handle = place.target
        # the pull goes out of the cabinet, toward where the robot stands to pull
        pull = (math.cos(place.stand[2] + math.pi), math.sin(place.stand[2] + math.pi))
        failures = 0
        while rec.opened < want - 1e-3 and failures < dc.attempts:
            self._check_stop()
            now_at = (
                handle[0] + pull[0] * rec.opened,
                handle[1] + pull[1] * rec.opened,
                handle[2],
            )
            pull_m = min(want - rec.opened, dc.max_pull)
            why = self._pull(rec.place, now_at, place.stand[2], pull_m)
            if why:
                failures += 1
                rec.failures.append(Failure(Step.OPEN_DRAWERS.value, why, self.robot.now()))
                self.posture = ""  # a failed arm motion: move it again next time
                continue
            rec.opened += pull_m
        # opened as far as every drawer is (the tools' drawer may have got its first pull only)
        rec.ok = rec.opened >= min(want, dc.open_distance) - 1e-3

    def _pull(self, name: str, handle: Point3, heading: float, distance: float) -> str:
        """One pull; "" when done, else why not."""
        dc = self.drawer_cfg
        if _dist(self._pose(), handle) > dc.handle_standoff + 0.5:
            self._say(f"{name}: walking to it")
            self._posture(self.cfg.walk_posture)
            out = self._walk_to_stand(self.places[name])
            if not out.ok:
                return f"walk: {out.reason}"
        out = self.robot.approach((handle[0], handle[1]), dc.handle_standoff, heading)
        if not out.ok:
            return f"square up: {out.reason}"
        out = self._posture(dc.probe_posture)
        if not out.ok:
            return f"posture: {out.reason}"
        self._say(f"{name}: locating the handle")
        out, plan = self.robot.locate_handle(handle, distance)
        if not out.ok or plan is None:
            return f"locate handle: {out.reason}"
        self._say(f"{name}: pulling {distance:.2f} m")
        out = self.robot.open_drawer(plan)
        self.posture = ""  # the pull ends with the arm wherever the handle left it
        if not out.ok:
            return f"pull: {out.reason}"
        return ""

    # ------------------------------------------------------------------ search
    def _next_zone(self) -> Place | None:
        if not self.zones_todo:
            return None
        if self.cfg.zone_order == "nearest" and self.robot.pose() is not None:
            here = self._pose()
            name = min(self.zones_todo, key=lambda z: _dist(self.places[z].stand, here))
        else:
            name = self.zones_todo[0]
        self.zones_todo.remove(name)
        return self.places[name]

    def _zone_search(self) -> SearchConfig:
        assert self.zone is not None
        return self.search[self.zone.kind]

    def _go_to_viewpoint(self) -> Step:
        if self.zone is None or self.view_index >= len(self.viewpoints):
            if self.zone is not None and not self.zone.name.startswith(DROP_ZONE):
                with self._lock:
                    self.report.zones_searched.append(self.zone.name)
            self.zone = self._next_zone()
            self.view_index = 0
            if self.zone is None:  # every zone searched: what is left in the memory
                return Step.CHOOSE_TARGET
            z = self.zone
            self.viewpoints = zone_viewpoints(
                z.stand, (z.target[0], z.target[1]), z.size, self._zone_search()
            )
            self._say(f"{z.name} view 1/{len(self.viewpoints)}")
        vp = self.viewpoints[self.view_index]
        here = self.robot.pose()
        if here is not None and _dist(here, vp) < 0.05 and abs(wrap(here[2] - vp[2])) < 0.05:
            return Step.LOOK
        # look while walking: the search posture shows the floor (or tables) on the way
        self._posture(self._zone_search().posture)
        out = self.robot.navigate_to(pose=vp)
        if not out.ok:  # a viewpoint in an obstacle or unreachable: the next one
            self.view_index += 1
            return Step.GO_TO_VIEWPOINT
        return Step.LOOK

    def _look(self) -> Step:
        sc = self._zone_search()
        self._posture(sc.posture)
        self.robot.wait(sc.dwell)
        return Step.CHOOSE_TARGET

    def _choose_target(self) -> Step:
        found = self._graspable()
        now = self.robot.now()
        with self._lock:  # every object seen gets its record (found, not yet tried)
            for obj, rec in found:
                if rec is None:
                    rec = ObjectRecord(
                        label=obj.label,
                        track_id=obj.track_id,
                        place=self.classes[obj.label].place,
                        position=obj.position,
                        t_found=now,
                    )
                    self.report.objects.append(rec)
                else:
                    rec.position, rec.track_id = obj.position, obj.track_id
        if not found:
            if self.zone is None:
                return Step.DONE
            self.view_index += 1
            return Step.GO_TO_VIEWPOINT
        here = self._pose()
        obj, _ = min(found, key=lambda f: _dist(f[0].position, here))
        rec = self._record_for(obj)
        assert rec is not None
        self.target = rec
        self.plan = None
        return Step.APPROACH

    # ------------------------------------------------------------------ one object
    def _probe_for(self, rec: ObjectRecord) -> _Probe:
        """Algorithm 5 and Figure 5: floor objects are probed from above with the gripper
        camera; on a table, low ones too, tall ones from the side with the front camera
        from farther back (it sits below the table top)."""
        c = self.cfg
        if rec.position[2] <= c.table_min_z:
            return _Probe(c.probe_floor_posture, "gripper_camera", c.probe_standoff, False)
        if self.classes[rec.label].height > c.tall:
            return _Probe(
                c.probe_side_posture,
                "front_camera",
                c.probe_standoff + c.side_probe_back,
                True,
            )
        return _Probe(c.probe_table_posture, "gripper_camera", c.probe_standoff, False)

    def _walk_near(self, rec: ObjectRecord) -> Outcome:
        """Walk to within reach of an approach: a table object from the table's stand
        pose, a floor object to a pose short of it, facing it."""
        here = self._pose()
        if rec.position[2] > self.cfg.table_min_z:
            tables = [p for p in self.places.values() if p.kind == "search_table"]
            if tables:
                table = min(tables, key=lambda p: _dist(p.target, rec.position))
                return self._walk_to_stand(table)
        bearing = math.atan2(rec.position[1] - here[1], rec.position[0] - here[0])
        back = self.cfg.walk_standoff
        goal = (
            rec.position[0] - back * math.cos(bearing),
            rec.position[1] - back * math.sin(bearing),
            bearing,
        )
        return self.robot.navigate_to(pose=goal)

    def _approach(self) -> Step:
        rec = self.target
        assert rec is not None
        self._refresh_target()
        self.probe = probe = self._probe_for(rec)
        if _dist(self._pose(), rec.position) > self.cfg.direct_approach_max:
            self._posture(self.cfg.walk_posture)
            out = self._walk_near(rec)
            if not out.ok:
                return self._give_up_or(Step.APPROACH, f"walk: {out.reason}", Step.APPROACH)
            self._refresh_target()
        out = self.robot.approach((rec.position[0], rec.position[1]), probe.standoff)
        if not out.ok:
            return self._give_up_or(Step.APPROACH, f"approach: {out.reason}", Step.APPROACH)
        return Step.PROBE

    def _probe(self) -> Step:
        rec, probe = self.target, self.probe
        assert rec is not None and probe is not None
        out = self._posture(probe.posture)
        if not out.ok:
            return self._give_up_or(Step.PROBE, f"posture: {out.reason}", Step.APPROACH)
        out, plan = self.robot.estimate_grasp(rec.label, probe.camera, rec.track_id)
        if not out.ok and "unknown track" in out.reason:
            # perception forgot the track (not seen for a while): the class in view will do
            out, plan = self.robot.estimate_grasp(rec.label, probe.camera, -1)
        if not out.ok or plan is None:
            # not in view, too far: another viewpoint (approach again from where it is now)
            return self._give_up_or(Step.PROBE, f"estimate: {out.reason}", Step.APPROACH)
        self.plan = plan
        if probe.horizontal:
            # probed from farther back: step in so the grasp point is in reach
            out = self.robot.approach(
                (plan.position_map[0], plan.position_map[1]), self.cfg.probe_standoff
            )
            if not out.ok:
                return self._give_up_or(Step.PROBE, f"step in: {out.reason}", Step.APPROACH)
        return Step.GRASP

    def _grasp(self) -> Step:
        rec, probe, plan = self.target, self.probe, self.plan
        assert rec is not None and probe is not None and plan is not None
        out = self.robot.grasp(plan)
        if out.ok:
            with self._lock:
                rec.grasped = True
                self.done_tracks.add(rec.track_id)  # its track now follows the gripper
            self.picked_from = rec.position
            self.posture = ""
            return Step.CARRY
        if not out.rejected:  # a failed grasp leaves the arm wherever it stopped
            self.posture = ""
        if self._fail(Step.GRASP, f"grasp: {out.reason}"):
            if self.robot.holding():
                self._put_down()
            self.target = None
            return Step.GO_TO_VIEWPOINT
        if not out.rejected:
            # it moved and missed (or slipped): the object may have moved; look again
            return Step.APPROACH
        # a rejection: a change of stance fixes it, then probe again from there
        c = self.cfg
        grasp_xy = (plan.position_map[0], plan.position_map[1])
        now_dist = _dist(self._pose(), grasp_xy)
        standoff = None
        if LATERAL in out.reason:
            # too far to the side for this grasp yaw: face the grasp point again
            standoff = min(max(now_dist, c.grasp_ahead[0]), c.grasp_ahead[1])
        elif any(r in out.reason for r in TOO_CLOSE):
            standoff = now_dist + c.step_back
        elif TOO_FAR in out.reason:
            standoff = max(now_dist - c.step_closer, c.grasp_ahead[0])
        if standoff is None:
            return Step.APPROACH
        moved = self.robot.approach(grasp_xy, standoff)
        if not moved.ok:
            return Step.APPROACH
        # a side probe cannot see the object from the grasping stance: start over
        return Step.APPROACH if probe.horizontal else Step.PROBE

    def _deposit(self) -> tuple[DepositSpec, Place]:
        rec = self.target
        assert rec is not None
        dep = self.deposits[rec.place]
        return dep, self.places[dep.place]

    def _release_point(self) -> tuple[Point3, float, float | None]:
        """Where to release (map), the heading to stand at, the gripper's yaw."""
        rec = self.target
        assert rec is not None
        dep, place = self._deposit()
        heading = place.stand[2]
        back = (-math.cos(heading), -math.sin(heading))  # from the target toward the robot
        tx, ty, tz = place.target
        point = (
            tx + back[0] * dep.release_toward_robot,
            ty + back[1] * dep.release_toward_robot,
            tz + dep.release_height,
        )
        # a long object goes in along the place's long side, across the robot; the others
        # with the fingers along the body y (yaw 0): the carry turned the wrist (manipulation's
        # held_across), the place turns it back
        yaw = math.pi / 2 if self.classes[rec.label].long_side > dep.across_above else 0.0
        return point, heading, yaw

    def _carry(self) -> Step:
        rec = self.target
        assert rec is not None
        dep, place = self._deposit()
        self._posture(dep.carry_posture)
        self._say(f"{rec.name} to {place.name}")
        out = self._walk_to_stand(place)
        if self.robot.holding() is False:
            # it fell on the way: it lies somewhere on the path; the search finds it again
            self._dropped("dropped while carrying", Step.CARRY)
            return Step.GO_TO_VIEWPOINT
        if not out.ok:
            return self._give_up_or(Step.CARRY, f"walk: {out.reason}", Step.CARRY)
        return Step.PLACE

    def _place(self) -> Step:
        rec = self.target
        assert rec is not None
        dep, _ = self._deposit()
        point, heading, yaw = self._release_point()
        out = self.robot.approach((point[0], point[1]), dep.reach, heading)
        if not out.ok:
            return self._give_up_or(Step.PLACE, f"stand: {out.reason}", Step.CARRY)
        for _ in range(self.cfg.place_attempts):
            out = self.robot.place(point, yaw)
            if out.ok:
                self.posture = ""
                return Step.VERIFY
            reach = [r for r in (TOO_FAR, *TOO_CLOSE) if r in out.reason]
            if not out.rejected or not reach:
                break
            # out of reach: a step in (or back) and ask again
            now_dist = _dist(self._pose(), point)
            step = -self.cfg.place_step if reach[0] == TOO_FAR else self.cfg.place_step
            self.robot.approach((point[0], point[1]), max(now_dist + step, 0.1), heading)
        self.posture = ""
        if self.robot.holding() is False:  # it let go somewhere other than asked
            self._dropped(f"place: {out.reason}; let go elsewhere", Step.PLACE)
            return Step.GO_TO_VIEWPOINT
        return self._give_up_or(Step.PLACE, f"place: {out.reason}", Step.PLACE)

    def _dropped(self, why: str, step: Step) -> None:
        """The held object fell: record it, and search again where it may lie (the zones
        near the way from where it was picked up to here)."""
        rec = self.target
        assert rec is not None
        with self._lock:
            rec.dropped = True
        for obj in self.robot.objects():
            if obj.track_id == rec.track_id:
                self.stale[rec.track_id] = obj.position
        self.done_tracks.discard(rec.track_id)
        self._fail(step, why)
        here = self._pose()
        self._search_again_near(self.picked_from or here, here)
        self.target = None
        self._look_where_it_fell(here)

    def _look_where_it_fell(self, here: Pose2) -> None:
        """Search the floor around where the grip was lost before any zone: the object
        lies at the robot's feet (it fell from the gripper there), often outside every
        search zone (by a deposit place). The zone in progress is searched again later."""
        if self.zone is not None and not self.zone.name.startswith(DROP_ZONE):
            self.zones_todo.insert(0, self.zone.name)
        back = self.cfg.drop_look_back
        stand = (here[0] - back * math.cos(here[2]), here[1] - back * math.sin(here[2]), here[2])
        size = (self.cfg.drop_look_size, self.cfg.drop_look_size)
        self.zone = Place(f"{DROP_ZONE}{here[0]:.2f},{here[1]:.2f}", "search_floor", stand,
                          (here[0], here[1], 0.0), size)  # fmt: skip
        self.viewpoints = zone_viewpoints(
            stand, (here[0], here[1]), size, self.search["search_floor"]
        )
        self.view_index = 0
        self._say(f"looking where it fell ({len(self.viewpoints)} views)")

    def _search_again_near(self, a: Sequence[float], b: Sequence[float]) -> None:
        """Queue again the searched zones within ``drop_search_margin`` of segment a-b."""
        margin = self.cfg.drop_search_margin
        n = max(int(_dist(a, b) / 0.1), 1)
        path = [(a[0] + (b[0] - a[0]) * i / n, a[1] + (b[1] - a[1]) * i / n) for i in range(n + 1)]
        for name in list(self.report.zones_searched):
            z = self.places[name]
            half = (z.size[0] / 2 + margin, z.size[1] / 2 + margin)
            if any(
                abs(x - z.target[0]) <= half[0] and abs(y - z.target[1]) <= half[1] for x, y in path
            ):
                with self._lock:
                    self.report.zones_searched.remove(name)
                self.zones_todo.append(name)

    def _verify(self) -> Step:
        """From the robot's own sensors: the gripper is empty, and (where a camera sees
        the place) a track of the class lies at the release point."""
        rec = self.target
        assert rec is not None
        point, _, _ = self._release_point()
        # the payload message may trail the place's result a little
        t_end = self.robot.now() + self.cfg.let_go_wait
        while self.robot.holding() and self.robot.now() < t_end:
            self.robot.wait(0.1)
        if self.robot.holding():
            return self._give_up_or(Step.VERIFY, "still holding after the place", Step.PLACE)
        seen = any(
            o.label == rec.label and _dist(o.position, point) < self.cfg.verify_radius
            for o in self.robot.objects()
        )
        with self._lock:
            rec.placed = True
            rec.release_seen = seen
            rec.position = point
        self._posture(self.cfg.walk_posture)
        self.target = None
        return Step.GO_TO_VIEWPOINT
