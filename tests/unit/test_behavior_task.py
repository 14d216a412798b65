"""The tidy-up task (services/behavior) against a small simulated house.

:class:`FakeHouse` plays the robot behind :class:`RobotApi`: it walks where it is asked,
its cameras see what lies in a band ahead when the arm is in a posture that looks that
way (floor postures see the floor, table postures the tables), it grasps what is in reach,
and puts an object down where it is asked. Failures are injected per object. Time is the
fake robot's own clock (seconds per request), so nothing here depends on the machine.

Restarts: an :class:`Outage` kills one of the robot's services in the middle of a request
and has it run again some seconds later, as the launcher does after a SIGKILL. While it is
away its requests (and every request, for locomotion) fail as the node ends them:
``interrupted``. What it loses is lost: perception its memory; locomotion the standing
robot (the legs damped: no walking until it stands up) and the odom frame of the memory
(the remembered positions are off until forgotten); manipulation what it knew of the grip
(until it commands the arm again); navigation its pose (until it runs again).

The task runs on the real places file, object catalogue and ``configs/behavior.toml``.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common.config import CONFIG_DIR, load_config
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.common.places import Place, load_places
from quadmanip.common.reasons import narrow_side_text, reach_band_text
from quadmanip.services.behavior.config import BehaviorConfig
from quadmanip.services.behavior.coverage import sees, view_samples, zone_viewpoints
from quadmanip.services.behavior.frames import (
    BasePose,
    base_from_odom,
    carried_over,
    map_from_odom,
    odom_from_base,
    odom_from_map,
    wrap,
)
from quadmanip.services.behavior.node import progress_message
from quadmanip.services.behavior.report import ObjectRecord, Progress, TaskReport
from quadmanip.services.behavior.robot_api import GraspPlan, HandlePlan, Outcome, SeenObject
from quadmanip.services.behavior.service_watch import ServiceWatch
from quadmanip.services.behavior.tidy_task import (
    Step,
    TidyTask,
    _clear_of,
    _in_box,
    classes_from_catalogue,
    knowledge_problems,
)

pytestmark = pytest.mark.unit

CFG = load_config(BehaviorConfig, "behavior")
PLACES = load_places(CONFIG_DIR / "maps" / "house.places.toml")
CATALOGUE = load_catalogue()
CLASSES = classes_from_catalogue(CATALOGUE)
FLOOR_LOOKS = ("floor_search", "probe_floor")
TABLE_LOOKS = ("table_search", "probe_table", "probe_horizontal", "probe_tall")
START = (0.8, 1.2, 0.0)


#: which service serves each request (the node's CLIENTS)
SERVES = {
    "navigate_to": "navigation",
    "approach": "navigation",
    "move_to_posture": "manipulation",
    "grasp": "manipulation",
    "place": "manipulation",
    "open_drawer": "manipulation",
    "estimate_grasp": "perception",
    "locate_handle": "perception",
}
WATCHED = ("locomotion", "manipulation", "navigation", "perception")


@dataclass
class Outage:
    """``service`` dies in the middle of the ``nth`` request ``at`` (counting only those
    sent while an object is held, when ``holding`` says so) and runs again ``down_s``
    later (inf: never). ``drops``: the held object falls as the robot lies down."""

    service: str
    at: str
    nth: int = 1
    down_s: float = 6.0
    holding: bool | None = None
    drops: bool = False


@dataclass
class Thing:
    """An object of the fake house (its truth, which only the fake knows)."""

    label: str
    track_id: int
    position: tuple[float, float, float]
    on_table: bool = False
    released_in: str = ""  # the place it was put down in ("floor": none)


def _bearing(pose: tuple[float, float, float], p: tuple[float, ...]) -> tuple[float, float]:
    dx, dy = p[0] - pose[0], p[1] - pose[1]
    b = math.atan2(dy, dx) - pose[2]
    return math.hypot(dx, dy), (b + math.pi) % (2 * math.pi) - math.pi


class FakeHouse:
    """A RobotApi over a handful of objects (see the module docstring)."""

    def __init__(
        self,
        things: list[Thing],
        *,
        grasp_failures: dict[str, list[str]] | None = None,
        drop_while_carrying: dict[str, int] | None = None,
        drop_at_the_end: bool = False,
        sticky: dict[str, int] | None = None,
        seconds_per_walk: float = 8.0,
        localised: bool = True,
        outages: list[Outage] | None = None,
        phantoms: list[Thing] | None = None,
    ) -> None:
        self.things = {t.track_id: t for t in things}
        # false detections: the memory holds them from afar, a probe detects nothing
        self.phantoms = {t.track_id: t for t in phantoms or []}
        self.grasp_failures = {k: list(v) for k, v in (grasp_failures or {}).items()}
        self.drops = dict(drop_while_carrying or {})
        self.drop_at_the_end = drop_at_the_end  # at the walk's goal, not half way
        # a dropped object's track: a new id where it lies (perception forgot the track
        # of the object taken up) instead of the old id following it
        self.renumber_drops = False
        self.fell_at: list[tuple[float, float, float]] = []  # where dropped objects fell
        self.sticky = dict(sticky or {})  # places that "succeed" but keep the object
        # places that fail "object_stuck" (the fingers closed on it again); the grip
        # state, as the payload message, reads "let go" until grip_lag s after such a result
        self.stuck: dict[str, int] = {}
        self.grip_lag = 0.0
        self.stale_grip_until = -1.0
        self.walk_s = seconds_per_walk
        self.localised_ok = localised
        self.t = 0.0
        self.at = START
        self.posture = "stow"
        # a posture move sent without waiting ends at this time; (the request, the posture)
        # of every walk or approach that started while it moved
        self.arm_until = 0.0
        self.arm_moving_during: list[tuple[str, str]] = []
        self.posture_waits: list[bool] = []  # per move_to_posture: whether it was waited for
        self.looked_still: list[bool] = []  # per wait_for_arm: the arm had arrived already
        self.dwelt_while_moving = 0  # waits (a look's dwell) begun before the arm arrived
        self.memory: dict[int, SeenObject] = {}
        self.held: Thing | None = None
        self.drawers: dict[str, float] = {}
        self.calls: list[tuple[str, object]] = []
        self.lead_ins: list[bool] = []  # per navigate_to: whether an approach follows it
        self.cancel_after: float | None = None
        # restarts
        self.outage_plan = list(outages or [])
        self.counts: dict[str, int] = {}
        self.dead: dict[str, float] = {}  # service -> fake time it runs again
        self.outage_counts = dict.fromkeys(WATCHED, 0)
        self.killed_at: list[int] = []  # index in calls of each killing request
        self.sent_while_down: list[tuple[str, str]] = []
        self.standing = True
        self.grip_known = True
        self.settle_s = 3.0  # s a restarted navigation takes to localise again
        self.waits: list[tuple[tuple[float, float, float], str, bool]] = []  # where, how, seeing
        self.settled_at = 0.0
        self.loose_approaches = 0
        self.turn_free_approaches = 0
        # perception's seen grid: None says nothing; a list collects (pose, table) of every
        # look the cameras made, and a point is seen where such a look would find objects
        self.looks: list[tuple[tuple[float, float, float], bool, float]] | None = None
        self.look_range, self.look_bearing = 1.6, 0.7  # what a look shows (and finds)
        # (heading asked, heading navigation turns a turn_free stance to) near an object
        self.free_turn: tuple[float, float] | None = None
        # walk goals within 1.1 m of these objects that navigation refuses (in an
        # obstacle), this many times each
        self.refuse_near: dict[str, int] = {}
        # how the refusal reads: navigation refuses a goal in the map's obstacles at once,
        # and stops a walk whose goal the LiDAR finds too close to one on the way
        self.refusal = "rejected: the goal is in an obstacle or too close to one"
        self.blocked_goals: list[tuple[float, float]] = []  # walk goals found too near something
        self.blocked_reason = "blocked: goal too close to an obstacle"  # (found on the way)
        # label -> s: walk goals within 1.1 m of it (once seen) are refused as too close to
        # an obstacle, for this long after the first such refusal (then clear)
        self.refuse_near_for: dict[str, float] = {}
        self.refuse_near_until: dict[str, float] = {}
        # (heading, near): approaches at this heading to targets near there stop at once
        self.blocked_headings: list[tuple[float, tuple[float, float]]] = []
        self.stuck_drawers: dict[str, int] = {}  # pulls of this drawer manipulation refuses
        self.arm_pull = 1.0  # m: longer pulls are refused as beyond the arm's reach
        self.unsettled = 0  # approaches that end near the goal but not within tolerance
        # objects that slip out of the fingers as the arm moves to a posture (at the
        # robot's feet), this many times each
        self.posture_drops: dict[str, int] = {}
        # the robot stands against furniture: an approach from here stops at once on
        # navigation's footprint guard, until a walk (navigate_to) leads it clear
        self.by_furniture = False
        self.furniture_reason = "blocked: an obstacle touches the footprint"
        # furniture (x, y) on the floor: an approach whose stance comes within 0.35 m of
        # one stops at once on the footprint guard, from wherever it starts
        self.furniture: list[tuple[float, float]] = []
        # label -> (near, far): its grasp is refused from a stance nearer than ``near`` (the
        # arm against the trunk) or farther than ``far`` (out of reach), m to the object
        self.reach_bands: dict[str, tuple[float, float]] = {}
        self.band_hints = False  # refusals name the reachable band (manipulation does)
        # request name -> its nth call trips locomotion's safety (the robot falls over,
        # the legs damped); every request fails "robot_down" until it gets up
        self.trip_at: dict[str, int] = {}
        self.tripped = False
        # labels whose track lies off from afar: probes miss them until a look from the
        # search posture, from a step back, places them afresh
        self.placed_off: set[str] = set()
        # labels whose surface seen from above is not level (Section 4.3): perception asks
        # for a probe from the side with the front camera
        self.not_level: set[str] = set()
        # label -> its long axis's map yaw (a long box, the cracker box): the front camera
        # refuses it turned more than 20 deg off the view, naming the turn to its end
        self.long_axis: dict[str, float] = {}
        self.probed_with: list[tuple[str, str]] = []  # (label, camera) of each estimate
        # track id -> the class the memory gives it (voted from afar); a probe from close
        # by detects its true class
        self.mistaken: dict[int, str] = {}
        # mistaken track ids whose probe names them by their true class all the same (a
        # weak candidate of the mistaken class under a clearly better box: perception's
        # close view decides, frames.close_view_class)
        self.named_close: set[int] = set()
        self.missed = False  # the last probe missed a real object (out of view, or missed)
        # phantoms (track ids) detected only from beyond 1 m: a look from nearer, with them
        # in view, makes the memory drop them (it removes what should be seen and is not)
        self.far_only: set[int] = set()
        # track ids perception has forgotten: an estimate naming one is refused ("unknown
        # track"); one naming none takes the nearest object of the class in view
        self.forgotten: set[int] = set()
        # label -> probes that detect nothing once a probe has planned its grasp (a thin
        # object the detector misses now and then)
        self.misses_after_estimate: dict[str, int] = {}
        self.estimated: set[str] = set()
        # approach targets (x, y) it holds blocked: the robot stops ``block_short`` m short
        # of such a stance, its approach stalled (something at its feet, paper-3)
        self.blocked_stance: Callable[[tuple[float, float]], bool] | None = None
        # approach targets whose stance a piece of furniture touches: stopped at once
        self.touching: Callable[[tuple[float, float]], bool] | None = None
        self.block_short = 0.06
        # label -> the heading its first approach had: that approach, and every later one
        # within 0.3 rad of its heading, stops making progress 14.6 cm short (furniture the
        # LiDAR does not see by the stance: paper-1's Rubik's cube by the deposit table)
        self.stalls: dict[str, float | None] = {}
        self.stalled = 0
        self.stall_why = "no progress for 10 s, 14.6 cm and 17.8 deg off"
        self.place_reach = 0.6  # m: a release point farther off is refused too_far
        # label -> reasons its next places fail with (not rejected: the arm was stopped)
        self.place_failures: dict[str, list[str | Outcome]] = {}
        # label -> places in which it slips out of the fingers on the way over its box and
        # lands on the box's table, 15 cm before the box and 8 cm to the side
        self.place_drops: dict[str, int] = {}
        self.place_drop_seen_as = ""  # the class the memory gives it where it fell ("": its own)
        self.place_drop_at = (0.15, 0.08)  # m before the box's middle, and to the side
        # label -> places after which it topples out of its box and off the table, the
        # place done: it lies on the floor 0.35 m before the box, seen there (a new track)
        self.place_topples: dict[str, int] = {}
        # class -> the camera whose probe finds nothing graspable of it
        self.no_candidate_from: dict[str, str] = {}
        self.no_candidate_why = "no graspable candidate"  # or "too wide"

    # -------------------------------------------------------------- restarts
    def _strike(self, name: str) -> Outage | None:
        """Count a request (or a wait); the outage planned for it, if any, strikes."""
        holding = self.held is not None
        self.counts[name] = self.counts.get(name, 0) + 1
        key = f"{name}/{holding}"
        self.counts[key] = self.counts.get(key, 0) + 1
        for o in self.outage_plan:
            n = self.counts[name] if o.holding is None else self.counts[key]
            if o.at == name and n == o.nth and o.holding in (None, holding):
                self.outage_plan.remove(o)
                self._kill(o)
                self.killed_at.append(len(self.calls) - 1)
                return o
        return None

    def _request(self, name: str) -> Outcome | None:
        """Every request starts here: a planned outage may strike; a request that needs a
        service that is away fails as the node ends it (None: it goes on)."""
        o = self._strike(name)
        if o is not None:
            return Outcome(False, f"{name}: {o.service} went away", interrupted=o.service)
        self._revive()
        for svc in (SERVES[name], "locomotion"):
            if svc in self.dead:
                self.sent_while_down.append((name, svc))
                return Outcome(False, f"{svc} is not running", interrupted=svc)
        nth = self.counts.get(f"trip:{name}", 0) + 1
        self.counts[f"trip:{name}"] = nth
        if self.trip_at.get(name) == nth:
            self.tripped, self.standing = True, False
            if self.held is not None:  # it falls out as the robot falls, onto the floor
                x, y, yaw = self.at
                self.held.position = (x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw), 0.05)
                self.held.on_table = False
                self.held = None
        if self.tripped and name != "estimate_grasp":
            return Outcome(False, "robot_down: locomotion tripped (roll -34° beyond ±34°)")
        if name in ("navigate_to", "approach") and not self.standing:
            return Outcome(False, "velocity commands need mode stand or walk (now damp)")
        if name == "navigate_to" and not self.localised():
            return Outcome(False, "not localised: the filter is converging")
        if SERVES[name] == "manipulation":
            self.grip_known = True  # a new manipulation feels the fingers once it works
        return None

    def _kill(self, o: Outage) -> None:
        self.dead[o.service] = self.t + o.down_s
        self.outage_counts[o.service] += 1
        if o.service == "navigation":  # a new filter takes a while to settle
            self.settled_at = self.t + o.down_s + self.settle_s
        if o.service == "perception":
            self.memory.clear()
        elif o.service == "manipulation":
            self.grip_known = False
            self.posture = ""
        elif o.service == "locomotion":
            self.standing = False
            # the odom frame the memory was kept in starts again elsewhere
            self.memory = {
                k: replace(v, position=(v.position[0] + 0.7, v.position[1] - 0.5, v.position[2]))
                for k, v in self.memory.items()
            }
            if o.drops and self.held is not None:
                x, y, yaw = self.at
                self.held.position = (x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw), 0.05)
                self.held = None

    def _revive(self) -> None:
        for svc, t_back in list(self.dead.items()):
            if self.t >= t_back:
                del self.dead[svc]

    def outages(self) -> dict[str, int]:
        return dict(self.outage_counts)

    def wait_for_services(self, services, timeout: float) -> bool:
        self.calls.append(("wait_for_services", tuple(sorted(services))))
        back = max((self.dead.get(s, self.t) for s in services), default=self.t)
        if math.isinf(back):
            return False
        self.t = max(self.t, back)
        self._revive()
        return True

    def stand_up(self) -> Outcome:
        self.calls.append(("stand_up", None))
        if "locomotion" in self.dead:
            return Outcome(False, "locomotion is not running", interrupted="locomotion")
        self.t += 2.0
        self.standing, self.tripped = True, False  # (recover first when tripped)
        return Outcome(True)

    def localised(self) -> bool:
        self._revive()
        return self.localised_ok and "navigation" not in self.dead and self.t >= self.settled_at

    def forget_objects(self) -> None:
        self.calls.append(("forget_objects", None))
        self.memory.clear()

    # -------------------------------------------------------------- senses
    def _look(self) -> None:
        self._revive()
        for t in (*self.things.values(), *self.phantoms.values()):
            if t is self.held:
                continue
            dist, bearing = _bearing(self.at, t.position)
            looks = TABLE_LOOKS if t.on_table else FLOOR_LOOKS
            seeing = "perception" not in self.dead
            if seeing and self.looks is not None and self.posture in looks:
                self.looks.append((self.at, self.posture in TABLE_LOOKS, self.t))
            shown = 0.25 <= dist <= self.look_range and abs(bearing) <= self.look_bearing
            if seeing and self.posture in looks and shown:
                if t.track_id in self.far_only and dist < 1.0:
                    self.memory.pop(t.track_id, None)
                    continue
                label = self.mistaken.get(t.track_id, t.label)
                self.memory[t.track_id] = SeenObject(t.track_id, label, t.position)
        if self.held is not None:  # the held object's track follows the gripper
            x, y, yaw = self.at
            p = (x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw), 0.35)
            self.memory[self.held.track_id] = SeenObject(self.held.track_id, self.held.label, p)

    def now(self) -> float:
        return self.t

    def wait(self, seconds: float) -> None:
        self._strike("wait")
        self.dwelt_while_moving += self.arm_until > self.t
        self.t += seconds
        self._look()
        if self.posture in ("floor_search", "table_search"):
            for t in self.things.values():
                # (a look before the first miss: the track is as off as it was)
                missed = ("estimate_grasp", (t.label, t.track_id)) in self.calls
                near = 0.6 <= _bearing(self.at, t.position)[0] <= 1.6
                if t.label in self.placed_off and missed and near:
                    self.placed_off.discard(t.label)
        self.waits.append((self.at, self.posture, "perception" not in self.dead))

    def pose(self) -> tuple[float, float, float] | None:
        return self.at if self.localised_ok else None

    def objects(self) -> list[SeenObject]:
        return list(self.memory.values())

    def seen(self, points, table, since=-math.inf):
        if self.looks is None:
            return None

        def shown(p):
            for at, on_table, t in self.looks:
                if t < since:
                    continue
                dist, bearing = _bearing(at, (*p, 0.0))
                near = 0.25 <= dist <= self.look_range and abs(bearing) <= self.look_bearing
                if on_table == table and near:
                    return True
            return False

        return [shown(p) for p in points]

    def holding(self) -> bool | None:
        if not self.grip_known:
            return None
        if self.t < self.stale_grip_until:
            return False  # the message saying it holds again has not come yet
        return self.held is not None

    # -------------------------------------------------------------- walking
    def navigate_to(
        self, place: str = "", pose: tuple[float, float, float] | None = None, lead_in=False
    ):
        self._walks("navigate_to")
        self.calls.append(("navigate_to", place or pose))
        self.lead_ins.append(lead_in)
        if (refused := self._request("navigate_to")) is not None:
            return refused
        for label, span in self.refuse_near_for.items():
            t = next(x for x in self.things.values() if x.label == label)
            if (
                pose is not None
                and t.track_id in self.memory
                and math.dist(pose[:2], t.position[:2]) < 1.1
            ):
                until = self.refuse_near_until.setdefault(label, self.t + span)
                if self.t < until:
                    return Outcome(False, "blocked: goal too close to an obstacle")
        if pose is not None and any(math.dist(pose[:2], b) < 0.1 for b in self.blocked_goals):
            return Outcome(
                False, self.blocked_reason, rejected=self.blocked_reason.startswith("rej")
            )
        for label, n in self.refuse_near.items():
            t = next(x for x in self.things.values() if x.label == label)
            seen = t.track_id in self.memory  # (a viewpoint walk before it was seen is fine)
            if pose is not None and n > 0 and seen and math.dist(pose[:2], t.position[:2]) < 1.1:
                self.refuse_near[label] -= 1
                return Outcome(False, self.refusal)
        self.t += self.walk_s
        self.by_furniture = False
        goal = PLACES[place].stand if place else pose
        assert goal is not None
        if self.held is not None and self.drops.get(self.held.label, 0) > 0:
            self.drops[self.held.label] -= 1  # it slips out on the way, half-way there
            f = 1.0 if self.drop_at_the_end else 0.5
            fell = (
                self.at[0] + f * (goal[0] - self.at[0]),
                self.at[1] + f * (goal[1] - self.at[1]),
            )
            self.held.position = (*fell, 0.05)
            self.fell_at.append(self.held.position)
            if self.renumber_drops:
                self.memory.pop(self.held.track_id, None)
                del self.things[self.held.track_id]
                self.held.track_id += 100
                self.things[self.held.track_id] = self.held
            self.held = None
        self.at = goal
        self._look()
        return Outcome(True)

    def approach(self, target, standoff, heading=None, loose=False, turn_free=False):
        self._walks("approach")
        self.calls.append(("approach", (tuple(target), standoff, heading)))
        self.turn_free_approaches += bool(turn_free)
        self.loose_approaches += bool(loose)
        if (refused := self._request("approach")) is not None:
            return refused
        if self.by_furniture:
            self.t += 0.2
            return Outcome(False, self.furniture_reason)
        if self.touching is not None and self.touching(tuple(target[:2])):
            self.t += 0.2
            return Outcome(False, "blocked: an obstacle touches the footprint")
        if turn_free and self.free_turn is not None and abs(heading - self.free_turn[0]) < 0.05:
            heading = self.free_turn[1]  # navigation turned the stance clear of the leg
        if heading is not None and any(
            abs(heading - b) < 0.05 and math.dist(target[:2], at) < 0.5
            for b, at in self.blocked_headings
        ):
            self.t += 0.2  # a leg by the stance at this heading: stopped at once
            return Outcome(False, "blocked: an obstacle touches the footprint")
        h = (
            heading
            if heading is not None
            else math.atan2(target[1] - self.at[1], target[0] - self.at[0])
        )
        stalls = [
            t
            for t in self.things.values()
            if t.label in self.stalls and math.dist(t.position[:2], target[:2]) < 0.1
        ]
        if stalls:
            bad = self.stalls[stalls[0].label]
            if bad is None or abs(math.remainder(h - bad, 2 * math.pi)) < 0.3:
                self.stalls[stalls[0].label] = h if bad is None else bad
                short = standoff + 0.146
                self.t += 10.0
                self.stalled += 1
                self.at = (target[0] - short * math.cos(h), target[1] - short * math.sin(h), h)
                self._look()
                why = f"blocked: the approach did not settle in time ({self.stall_why})"
                return Outcome(False, why)
        if self.blocked_stance is not None and self.blocked_stance(tuple(target[:2])):
            short = standoff + self.block_short
            self.t += 10.0
            self.at = (target[0] - short * math.cos(h), target[1] - short * math.sin(h), h)
            self._look()
            why = "blocked: the approach did not settle in time (no progress for 10 s, 6.0 cm)"
            return Outcome(False, why)
        stance = (target[0] - standoff * math.cos(h), target[1] - standoff * math.sin(h))
        if any(math.dist(stance, f) < 0.35 for f in self.furniture):
            # it walked until the footprint touched it: from here every approach stops at
            # once, until a walk leads it clear
            self.t += 0.2
            self.by_furniture = True
            return Outcome(False, "blocked: an obstacle touches the footprint")
        self.t += self.walk_s / 2
        self.at = (*stance, h)
        self._look()
        if self.unsettled > 0:
            self.unsettled -= 1
            self.t += 30.0
            return Outcome(False, "blocked: the approach did not settle in time")
        return Outcome(True)

    def _arm_settled(self) -> None:
        """An arm or camera request waits for a posture move sent without waiting."""
        self.t = max(self.t, self.arm_until)

    def _walks(self, request: str) -> None:
        if self.arm_until > self.t:
            self.arm_moving_during.append((request, self.posture))

    def wait_for_arm(self) -> Outcome:
        self.looked_still.append(self.arm_until <= self.t)
        self._arm_settled()
        return Outcome(True)

    def move_to_posture(self, posture: str, wait: bool = True) -> Outcome:
        self._arm_settled()
        self.calls.append(("move_to_posture", posture))
        self.posture_waits.append(wait)
        if (refused := self._request("move_to_posture")) is not None:
            return refused
        if wait:
            self.t += 1.0
        else:
            self.arm_until = self.t + 1.0
        self.posture = posture
        if self.held is not None and self.posture_drops.get(self.held.label, 0) > 0:
            self.posture_drops[self.held.label] -= 1
            x, y, h = self.at
            self.held.position = (x + 0.3 * math.cos(h), y + 0.3 * math.sin(h), 0.05)
            self.held = None
        self._look()
        return Outcome(True)

    # -------------------------------------------------------------- hands
    def estimate_grasp(self, label, camera, track_id=-1):
        self._arm_settled()
        self.calls.append(("estimate_grasp", (label, track_id)))
        self.probed_with.append((label, camera))
        if (refused := self._request("estimate_grasp")) is not None:
            return refused, None
        self.t += 1.0
        if track_id in self.forgotten:
            return Outcome(False, f"unknown track {track_id}", rejected=True), None
        if label in self.not_level and camera == "gripper_camera":
            return Outcome(False, f"probe horizontally: {label} in gripper_camera"), None
        if self.no_candidate_from.get(label) == camera:
            return Outcome(False, f"{self.no_candidate_why}: {label} in {camera}"), None
        if track_id in self.phantoms:
            return Outcome(False, f"not in view: no {label} detected"), None
        if label:
            self.missed = False
            t = self.things.get(track_id)
            if t is not None and self.mistaken.get(track_id) == label:
                if track_id not in self.named_close:
                    return Outcome(False, f"not in view: no {label} detected"), None
                label = t.label
            if track_id == -1:
                same = [x for x in self.things.values() if x.label == label and x is not self.held]
                t = min(same, key=lambda x: _bearing(self.at, x.position)[0], default=None)
        else:  # any class: what the probing view shows nearest its middle
            if self.missed:  # what the last probe missed is out of view for every class
                return Outcome(False, "not in view: no object detected"), None
            near = [x for x in self.things.values() if x is not self.held]
            t = min(near, key=lambda x: _bearing(self.at, x.position)[0], default=None)
            label = t.label if t is not None else ""
            if label in self.not_level and camera == "gripper_camera":
                return Outcome(False, f"probe horizontally: {label} in gripper_camera"), None
        if t is None or t is self.held:
            return Outcome(False, "not in view"), None
        if t.label in self.placed_off:
            self.missed = True
            return Outcome(False, f"not in view: no {label} detected"), None
        if t.label in self.estimated and self.misses_after_estimate.get(t.label, 0) > 0:
            self.misses_after_estimate[t.label] -= 1
            self.missed = True
            return Outcome(False, f"not in view: no {label} detected"), None
        dist, bearing = _bearing(self.at, t.position)
        if t.label in self.long_axis and camera == "front_camera":
            turn = (self.long_axis[t.label] - self.at[2]) % math.pi
            turn = turn - math.pi if turn > math.pi / 2 else turn
            if abs(turn) > 0.35:
                why = (
                    f"long side turned off the view: {label} in {camera} ({narrow_side_text(turn)})"
                )
                return Outcome(False, why), None
        looks = TABLE_LOOKS if t.on_table else FLOOR_LOOKS
        if self.posture not in looks or dist > 1.2 or abs(bearing) > 0.7:
            return Outcome(False, f"not in view: {label} in {camera}"), None
        self.estimated.add(t.label)
        base = BasePose(self.at[0], self.at[1], 0.27, self.at[2])
        plan = GraspPlan(
            position=(dist, 0.0, t.position[2] - 0.27),
            yaw=0.0,
            approach="vertical",
            width=0.05,
            object_name=label,
            seen_from=base,
            position_map=t.position,
        )
        return Outcome(True), plan

    def grasp(self, plan: GraspPlan) -> Outcome:
        self._arm_settled()
        t = next(
            x
            for x in self.things.values()
            if x.label == plan.object_name and x.position == plan.position_map
        )
        self.calls.append(("grasp", t.label))
        if (refused := self._request("grasp")) is not None:
            return refused
        if self.held is not None:  # as manipulation: the opening would drop it anywhere
            return Outcome(False, "already_holding: place or put it down first", rejected=True)
        self.t += 5.0
        failures = self.grasp_failures.get(t.label)
        if failures:
            why = failures.pop(0)
            rejected = why.startswith(("lateral", "too_", "self_"))
            return Outcome(False, why, rejected=rejected)
        dist, bearing = _bearing(self.at, t.position)
        near, far = self.reach_bands.get(t.label, (0.2, 0.6))
        # as manipulation: the refusal names the band (beyond its far edge a floor grasp
        # also fails on the trunk envelope, so the code alone does not say which way)
        band = f"; {reach_band_text(near, far, dist)}" if self.band_hints else ""
        if dist < near or (self.band_hints and dist > far):
            return Outcome(
                False,
                f"unreachable: self_collision: the arm would touch the trunk at {dist:.3f}{band}",
                rejected=True,
            )
        if dist > far or abs(bearing) > 0.3:
            return Outcome(False, f"too_far: {dist:.2f} m at {bearing:.2f} rad", rejected=True)
        self.held = t
        self._look()
        return Outcome(True)

    def place(self, position, yaw=None) -> Outcome:
        self._arm_settled()
        self.calls.append(("place", (tuple(position), yaw)))
        if (refused := self._request("place")) is not None:
            return refused
        self.t += 4.0
        if self.held is None:
            return Outcome(False, "invalid_goal: nothing held", rejected=True)
        if _bearing(self.at, position)[0] > self.place_reach:
            return Outcome(False, "too_far: out of reach", rejected=True)
        if self.place_failures.get(self.held.label):
            why = self.place_failures[self.held.label].pop(0)
            return why if isinstance(why, Outcome) else Outcome(False, why)
        if self.place_drops.get(self.held.label, 0) > 0:
            self.place_drops[self.held.label] -= 1
            box = min(PLACES.values(), key=lambda p: math.dist(p.target, position))
            h = box.stand[2]
            before, side = self.place_drop_at
            x = box.target[0] - before * math.cos(h) + side * math.sin(h)
            y = box.target[1] - before * math.sin(h) - side * math.cos(h)
            self.held.position, self.held.on_table = (x, y, 0.404), True
            self.fell_at.append(self.held.position)
            if self.place_drop_seen_as:
                self.mistaken[self.held.track_id] = self.place_drop_seen_as
            self.held = None
            return Outcome(False, "object_lost on the way to the region (lost)")
        if self.sticky.get(self.held.label, 0) > 0:
            self.sticky[self.held.label] -= 1
            self.stale_grip_until = self.t + self.grip_lag
            return Outcome(True)  # the action says done; the gripper still holds it
        if self.stuck.get(self.held.label, 0) > 0:
            self.stuck[self.held.label] -= 1
            self.stale_grip_until = self.t + self.grip_lag
            return Outcome(False, "object_stuck: the fingers still hold something after release")
        if self.place_topples.get(self.held.label, 0) > 0:
            self.place_topples[self.held.label] -= 1
            box = min(PLACES.values(), key=lambda p: math.dist(p.target, position))
            h = box.stand[2]
            fell = (box.target[0] - 0.35 * math.cos(h), box.target[1] - 0.35 * math.sin(h), 0.04)
            self.held.position, self.held.on_table, self.held.released_in = fell, False, "floor"
            self.fell_at.append(fell)
            self.memory.pop(self.held.track_id, None)
            del self.things[self.held.track_id]
            self.held.track_id += 100
            self.things[self.held.track_id] = self.held
            self.memory[self.held.track_id] = SeenObject(self.held.track_id, self.held.label, fell)
            self.held = None
            return Outcome(True)
        tidy = [p for p in PLACES.values() if p.kind in ("deposit", "drawer")]
        # nearest in 3-D: the tools' drawer's side slots lie over the lower drawers' handles
        near = min(tidy, key=lambda p: math.dist(p.target, position))
        inside = math.dist(near.target[:2], position[:2]) < 0.2
        self.held.released_in = near.name if inside else "floor"
        self.held.position = tuple(position)
        self.memory[self.held.track_id] = SeenObject(
            self.held.track_id, self.held.label, self.held.position
        )
        self.held = None
        return Outcome(True)

    def locate_handle(self, hint, distance):
        self._arm_settled()
        self.calls.append(("locate_handle", tuple(hint)))
        if (refused := self._request("locate_handle")) is not None:
            return refused, None
        self.t += 1.0
        return Outcome(True), HandlePlan((0.5, 0.0, 0.1), (-1.0, 0.0, 0.0), distance)

    def open_drawer(self, handle: HandlePlan) -> Outcome:
        self._arm_settled()
        drawer = min(
            (p for p in PLACES.values() if p.kind == "drawer"),
            key=lambda p: math.dist(p.stand[:2], self.at[:2]),
        )
        self.calls.append(("open_drawer", (drawer.name, handle.distance)))
        if (refused := self._request("open_drawer")) is not None:
            return refused
        if self.stuck_drawers.get(drawer.name, 0) > 0:
            self.stuck_drawers[drawer.name] -= 1
            return Outcome(False, "too_far: the handle is out of reach", rejected=True)
        if handle.distance > self.arm_pull + 1e-9:
            why = f"unreachable: pull of {handle.distance:.2f} m: arm reaches {self.arm_pull:.2f} m only"
            return Outcome(False, why, rejected=True)
        self.t += 6.0
        self.drawers[drawer.name] = self.drawers.get(drawer.name, 0.0) + handle.distance
        return Outcome(True)

    def cancelled(self) -> bool:
        return self.cancel_after is not None and self.t >= self.cancel_after


def _things() -> list[Thing]:
    """Four objects of four categories in four zones (one on a table)."""
    return [
        Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05)),  # living floor -> tray
        Thing("screwdriver", 2, (6.0, 2.3, 0.016)),  # kitchen floor -> the top drawer
        Thing("bowl", 3, (2.6, 3.2, 0.43), on_table=True),  # living table -> small box
        Thing("baseball", 4, (4.0, 3.2, 0.037)),  # living corner -> green box
    ]


def _task(house: FakeHouse, **kw: object) -> TidyTask:
    cfg = kw.pop("cfg", CFG.task)
    deposits = kw.pop("deposits", CFG.deposits)
    return TidyTask(
        house,
        CLASSES,
        PLACES,
        cfg,  # type: ignore[arg-type]
        CFG.drawers,
        CFG.search,
        deposits,  # type: ignore[arg-type]
        cancelled=house.cancelled,
        **kw,  # type: ignore[arg-type]
    )


def _record(report: TaskReport, label: str):
    recs = [r for r in report.objects if r.label == label]
    assert len(recs) == 1, (label, recs)
    return recs[0]


def _calls(house: FakeHouse, name: str) -> list[object]:
    return [arg for what, arg in house.calls if what == name]


def _under_feet(p: tuple[float, ...], pose: tuple[float, float, float]) -> bool:
    """Whether ``p`` lies in the feet's box (``feet_box``) about a stance ``pose``."""
    return _in_box(p, pose, CFG.task.feet_box)


CAN = Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05))
CAN_START = (1.0, 1.4, 0.0)  # straight from the west: the stance at x = 2.5 - standoff


def _approach_can(*others: Thing) -> tuple[FakeHouse, str]:
    """The task approaches the soup can on the floor from ``CAN_START``, the memory
    holding ``others`` too; the house and the step the approach went on to."""
    house = FakeHouse([CAN, *others])
    house.at = CAN_START
    for t in (CAN, *others):
        house.memory[t.track_id] = SeenObject(t.track_id, t.label, t.position)
    task = _task(house)
    task.target = ObjectRecord("tomato_soup_can", 1, "tray", CAN.position, t_found=0.0)
    return house, task._approach().value


def test_a_table_object_across_its_table_is_walked_round_to_not_approached_under_it() -> None:
    # paper-2, 2026-12-07: after a place at the black box, south of the kitchen table, the
    # soup can 1.3 m away on the table's north side (its stand side) was approached straight
    # through the table: the trunk met a leg, and the robot stood in the table on the map
    can = Thing("tomato_soup_can", 1, (6.98, 2.11, 0.45), on_table=True)
    house = FakeHouse([can])
    house.at = (7.1, 0.85, math.pi / 2)
    house.memory[can.track_id] = SeenObject(can.track_id, can.label, can.position)
    task = _task(house)
    task.target = ObjectRecord("tomato_soup_can", 1, "tray", can.position, t_found=0.0)
    task._approach()
    first = next(what for what, _ in house.calls if what in ("navigate_to", "approach"))
    assert first == "navigate_to"
    walk = _calls(house, "navigate_to")[0]  # to the table's stand side (north), facing it
    assert walk[1] > 2.2 + 0.3 and walk[2] == pytest.approx(-math.pi / 2)
    # from the stand side, 1.3 m off, the approach is straight
    house = FakeHouse([can])
    house.at = (7.1, 3.4, -math.pi / 2)
    house.memory[can.track_id] = SeenObject(can.track_id, can.label, can.position)
    task = _task(house)
    task.target = ObjectRecord("tomato_soup_can", 1, "tray", can.position, t_found=0.0)
    task._approach()
    assert _calls(house, "navigate_to") == [] and _calls(house, "approach")


def _home(label: str) -> str:
    """The places-file name where ``label`` belongs."""
    return CFG.deposits[CATALOGUE.place_of(label)].place


# ------------------------------------------------------------------ the whole trial


@pytest.fixture(scope="module")
def tidy_run() -> tuple[FakeHouse, TaskReport, list[Progress]]:
    house = FakeHouse(_things())
    seen: list[Progress] = []
    report = _task(house, on_step=seen.append).run()
    return house, report, seen


def test_viewpoints_the_cameras_have_seen_already_are_skipped_and_nothing_is_missed() -> None:
    """A viewpoint whose zone points perception's seen grid shows is not walked to: the
    same house, everything still found and placed, with fewer viewpoint walks."""

    def run(with_grid: bool) -> tuple[FakeHouse, TaskReport, TidyTask]:
        house = FakeHouse(_things())
        house.looks = [] if with_grid else None
        house.look_range, house.look_bearing = 2.5, 1.0  # the front camera's reach, as seen
        task = _task(house)
        return house, task.run(), task

    plain, plain_report, plain_task = run(False)
    house, report, task = run(True)
    assert plain_task.views_skipped == 0
    assert task.views_skipped > 0
    assert report.outcome == "done" and sorted(report.zones_searched) == sorted(
        plain_report.zones_searched
    )
    for t in house.things.values():
        assert t.released_in == _home(t.label), t.label
    walks = lambda h: len(_calls(h, "navigate_to"))  # noqa: E731
    assert walks(house) < walks(plain)
    assert report.t_end < plain_report.t_end


def test_drawers_open_first_left_right_top_and_the_tools_drawer_wide(tidy_run) -> None:
    house, report, _ = tidy_run
    pulls = _calls(house, "open_drawer")
    # the top drawer (tools) is pulled to 24 cm in one pull, from farther back
    assert [d for d, _ in pulls] == ["drawer_left", "drawer_right", "drawer_top"]
    assert house.drawers == pytest.approx(
        {"drawer_left": 0.15, "drawer_right": 0.15, "drawer_top": 0.24}
    )
    dc = CFG.drawers
    for name, standoff in (
        ("drawer_left", dc.handle_standoff),
        ("drawer_right", dc.handle_standoff),
        ("drawer_top", dc.long_pull_standoff),
    ):
        k = next(i for i, c in enumerate(house.calls) if c[0] == "open_drawer" and c[1][0] == name)
        squared = next(c for c in reversed(house.calls[:k]) if c[0] == "approach")
        assert squared[1][1] == pytest.approx(standoff), name
    last_pull = max(i for i, (what, _) in enumerate(house.calls) if what == "open_drawer")
    first_grasp = min(i for i, (what, _) in enumerate(house.calls) if what == "grasp")
    assert last_pull < first_grasp
    assert [(d.place, d.ok) for d in report.drawers] == [
        ("drawer_left", True),
        ("drawer_right", True),
        ("drawer_top", True),
    ]
    # each pull from a handle perception located near the places file's handle
    for hint in _calls(house, "locate_handle")[:3]:
        assert any(math.dist(hint, p.target) < 1e-9 for p in PLACES.values())


def test_every_object_goes_to_its_categorys_place(tidy_run) -> None:
    house, report, _ = tidy_run
    assert report.outcome == "done", report.reason
    for t in house.things.values():
        assert t.released_in == _home(t.label), t.label
        rec = _record(report, t.label)
        assert rec.grasped and rec.placed and not rec.given_up and rec.failures == []
    assert sorted(report.zones_searched) == sorted(
        p.name for p in PLACES.values() if p.kind.startswith("search_")
    )
    assert report.zones_total == len(report.zones_searched)


def test_the_arm_moves_to_its_next_posture_while_the_robot_walks(tidy_run) -> None:
    """The carry posture as the walk to the box sets off, the folded one as the walk to the
    next object does, the probing one as the approach steps in; never a side probe's,
    which may lift the nose, and never one the next arm request does not wait for (the
    house's arm requests wait, as the node's do)."""
    house, report, _ = tidy_run
    during = set(house.arm_moving_during)
    assert {
        ("navigate_to", "carry"),
        ("navigate_to", "stow"),
        ("approach", "probe_floor"),
        ("approach", "probe_table"),
        ("approach", CFG.drawers.probe_posture),  # squaring up to a drawer's handle
        ("navigate_to", "floor_search"),  # to a viewpoint, looking on the way
        ("navigate_to", "table_search"),
    } <= during
    # but a look from a viewpoint looks from the posture itself: it waits for the arm
    assert house.dwelt_while_moving == 0 and house.looked_still
    assert all(r.placed for r in report.objects)
    # a tall box on a table is probed from the side: its posture, which lifts the nose,
    # is sent once the robot stands
    house, report = _cracker_box_on_the_kitchen_table((6.96, 2.05), 90.0)
    assert _record(report, "cracker_box").placed
    assert "probe_tall" in _calls(house, "move_to_posture")
    assert "probe_tall" not in {p for _, p in house.arm_moving_during}


def test_the_arm_folds_as_the_robot_walks_off_from_a_place_but_the_drawer(tidy_run) -> None:
    """After a place the arm folds while the robot walks off (it stands above the rim of
    an open box); from the drawer, whose mouth is by the cabinet's front, it folds first."""
    house, report, _ = tidy_run
    assert all(r.placed for r in report.objects)
    top = PLACES["drawer_top"].target
    postures = iter(house.posture_waits)
    waits = [next(postures) if c[0] == "move_to_posture" else None for c in house.calls]
    folds = {True: 0, False: 0}  # per place: into the drawer
    for i, (what, arg) in enumerate(house.calls):
        if what != "place":
            continue
        j = next(k for k in range(i + 1, len(house.calls)) if house.calls[k][0] != "place")
        assert house.calls[j] == ("move_to_posture", "stow"), house.calls[j]
        drawer = math.dist(arg[0][:2], top[:2]) < 0.3
        assert waits[j] is drawer, (arg, drawer)
        folds[drawer] += 1
        if not drawer:  # the next request is a walk, or the task's end
            after = [c[0] for c in house.calls[j + 1 :] if c[0] != "move_to_posture"][:1]
            assert after in ([], ["navigate_to"], ["approach"]), after
    assert folds[True] >= 1 and folds[False] >= 2


def test_a_walk_an_approach_follows_ends_as_a_lead_in_and_no_other_does(tidy_run) -> None:
    """Walks to an object, to a place's or a drawer's stand: an approach steps in after
    each, so they end loosely, still under way (``lead_in``); a walk to a viewpoint, which
    the robot looks from, ends as a walk does."""
    house, report, _ = tidy_run
    assert all(r.placed for r in report.objects)
    acts = [c for c in house.calls if c[0] != "move_to_posture"]
    walks = [i for i, c in enumerate(acts) if c[0] == "navigate_to"]
    assert len(walks) == len(house.lead_ins)
    followed = {i: next((c[0] for c in acts[i + 1 :] if c[0] != "navigate_to"), "") for i in walks}
    for i, lead_in in zip(walks, house.lead_ins, strict=True):
        if lead_in:
            assert followed[i] == "approach", acts[i]
    assert sum(house.lead_ins) >= len(report.objects)  # at least to each one's place
    # the viewpoints (an object seen from one may be approached straight from there)
    assert not all(house.lead_ins)


def test_the_screwdriver_goes_into_the_drawer_across(tidy_run) -> None:
    house, _, _ = tidy_run
    top = PLACES["drawer_top"]
    (release, yaw) = next(
        arg for arg in _calls(house, "place") if math.dist(arg[0][:2], top.target[:2]) < 0.2
    )
    # 8.6 cm out of the closed handle (the middle of the 24 cm mouth), 7 cm above it
    assert release[0] == pytest.approx(top.target[0] - 0.086)
    assert release[2] == pytest.approx(top.target[2] + 0.07)
    assert yaw == pytest.approx(math.pi / 2)  # 21.5 cm long, the mouth 20 cm


def test_floors_are_searched_looking_down_and_tables_with_the_front_camera(tidy_run) -> None:
    house, _, _ = tidy_run
    postures = set(_calls(house, "move_to_posture"))
    assert {"floor_search", "table_search", "probe_floor", "probe_table"} <= postures
    # the bowl (on a table) was probed with the table posture, the can with the floor one
    order = [(w, a) for w, a in house.calls if w in ("move_to_posture", "estimate_grasp")]
    before = {}
    for i, (w, a) in enumerate(order):
        if w == "estimate_grasp":
            before[a[0]] = next(p for ww, p in reversed(order[:i]) if ww == "move_to_posture")
    assert before["bowl"] == "probe_table"
    assert before["tomato_soup_can"] == "probe_floor"


def test_report_and_progress_say_what_happened(tidy_run) -> None:
    house, report, seen = tidy_run
    assert seen[0].step.startswith("open_drawers") and seen[-1].state == "done"
    assert report.t_end == house.t and report.t_start == 0.0
    for rec in report.objects:
        assert 0.0 < rec.time_spent < report.t_end
        assert 0.0 < rec.t_found < report.t_end
    final = seen[-1]
    assert final.placed == 4 and final.given_up == 0
    assert final.drawers_opened == ("drawer_left", "drawer_right", "drawer_top")
    assert final.elapsed == pytest.approx(house.t)
    # the message the node publishes carries the same record
    msg = progress_message(final, stamp=house.t)
    assert m.decode(m.encode(msg)) == msg
    assert msg.state == "done" and sorted(msg.objects) == sorted(t.label for t in _things())
    assert msg.object_placed.all() and msg.failed == 0
    assert len(msg.zones_searched) == msg.zones_total == 6


# ------------------------------------------------------------------ retries and give-up


def test_a_table_stance_navigation_turned_clear_of_a_leg_is_kept_for_probe_and_grasp() -> None:
    """paper-5 (2026-12-06): a mug 13 cm in from the kitchen table's end; square to the
    table the trunk met a leg, and the slanted stances met it too: twelve approaches,
    given up. The first approach to a table object lets navigation turn the stance about
    the object (its map holds the legs); the task keeps the heading it stood at."""
    bowl = _things()[2]
    house = FakeHouse([bowl])
    square = PLACES["living_table"].stand[2]
    house.blocked_headings = [(square, bowl.position[:2])]  # a leg by the square stance
    house.free_turn = (square, square + 0.7)
    report = _task(house).run()
    rec = _record(report, "bowl")
    assert rec.placed and rec.attempts == 0 and not rec.failures, rec.failures
    assert house.turn_free_approaches == 1  # the first approach only
    # the heading it stood at is the one the probe's step in and the grasp keep
    assert rec.table_heading == pytest.approx(square + 0.7)
    # no walk back to the table's stand for a slanted try: from the approach to the grasp
    kinds = [w for w, _ in house.calls]
    i = next(k for k, (w, a) in enumerate(house.calls) if w == "approach" and a[2] == square)
    assert "navigate_to" not in kinds[i : kinds.index("grasp")], kinds[i:]


def test_a_lateral_rejection_at_a_slanted_table_stance_steps_sideways() -> None:
    """seed-111: a clamp at the kitchen table's corner, approached slanted (square met a
    leg), lay 13.5 cm to the side; turning back square met the leg at once, three rounds,
    and it was given up. Now the robot steps sideways at the slanted heading."""
    bowl = _things()[2]
    house = FakeHouse([bowl], grasp_failures={"bowl": ["lateral_out_of_range: y 0.13"]})
    square = PLACES["living_table"].stand[2]
    house.blocked_headings = [(square, bowl.position[:2])]  # a leg by the bowl's stance
    report = _task(house).run()
    rec = _record(report, "bowl")
    assert rec.placed and rec.attempts == 1, rec.failures
    i = [w for w, _ in house.calls].index("grasp")
    after = [a for w, a in house.calls[i:] if w == "approach"]
    # sideways at the slanted heading, at once: the stance keeps the heading that kept it
    # clear of the leg (square first met the leg again, 2026-12-05)
    assert abs(after[0][2] - square) > 0.3


def test_a_sideways_step_that_did_not_settle_probes_from_where_it_stands() -> None:
    """seed-111: the step sideways ended 3.6 cm off ("did not settle"); going back to the
    slanted approach met the leg once more. From there the probe and grasp go on."""
    bowl = _things()[2]
    house = FakeHouse([bowl], grasp_failures={"bowl": ["lateral_out_of_range: y 0.13"]})
    house.blocked_headings = [(PLACES["living_table"].stand[2], bowl.position[:2])]
    real_grasp = house.grasp

    def grasp_then_unsettled(plan):
        out = real_grasp(plan)
        if not out.ok:
            house.unsettled = 1  # the next approach that moves ends unsettled
        return out

    house.grasp = grasp_then_unsettled
    report = _task(house).run()
    rec = _record(report, "bowl")
    assert rec.placed and rec.attempts == 1, rec.failures
    i = [w for w, _ in house.calls].index("grasp")
    assert [w for w, _ in house.calls[i : i + 4]] == [
        "grasp",
        "approach",  # sideways at the slanted heading: did not settle
        "estimate_grasp",  # probed from there (the arm still in the probing posture)
        "grasp",
    ]


def test_a_lateral_rejection_faces_the_grasp_point_again_and_probes_again() -> None:
    house = FakeHouse(
        _things()[:1], grasp_failures={"tomato_soup_can": ["lateral_out_of_range: y 0.08"]}
    )
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and rec.attempts == 1
    assert [f.reason for f in rec.failures] == ["grasp: lateral_out_of_range: y 0.08"]
    assert house.things[1].released_in == "tray"
    # after the rejection: an approach facing the object, a new estimate, the grasp
    i = [w for w, _ in house.calls].index("grasp")
    assert [w for w, _ in house.calls[i : i + 4]] == [
        "grasp",
        "approach",
        "estimate_grasp",
        "grasp",
    ]
    target, standoff, heading = house.calls[i + 1][1]  # type: ignore[misc]
    assert heading is None and CFG.task.grasp_ahead[0] <= standoff <= CFG.task.grasp_ahead[1]


def test_too_close_steps_back() -> None:
    house = FakeHouse(_things()[:1], grasp_failures={"tomato_soup_can": ["too_close: x 0.2"]})
    report = _task(house).run()
    assert _record(report, "tomato_soup_can").placed
    i = [w for w, _ in house.calls].index("grasp")
    assert house.calls[i + 1][0] == "approach"
    _, standoff, _ = house.calls[i + 1][1]  # type: ignore[misc]
    # it stood at the probing standoff: one step back from there
    assert standoff == pytest.approx(CFG.task.probe_standoff + CFG.task.step_back)


def test_an_object_once_estimated_is_not_given_up_as_false_when_probes_miss_it() -> None:
    # paper-2 (2026-12-05): the spoon's grasp refused as out of reach, then a probe saw no
    # spoon and the task gave it up as a false detection, though perception had planned
    # its grasp a minute before
    house = FakeHouse(_things()[:1], grasp_failures={"tomato_soup_can": ["too_far: x 0.5"]})
    house.misses_after_estimate = {"tomato_soup_can": 2}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and not rec.given_up, rec.failures
    assert rec.estimated and rec.unseen == 2
    assert not any("false detection" in f.reason for f in rec.failures)


def test_a_narrow_reach_band_is_found_between_a_too_far_and_a_too_close_stance() -> None:
    # paper-2's bowl: too far from the probing stance, the arm against the trunk one step
    # closer, too far again one step back, and given up; the stance lies in between
    house = FakeHouse(_things()[:1])
    house.reach_bands = {"tomato_soup_can": (0.34, 0.355)}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and len(rec.failures) == 2, rec.failures
    assert "too_far" in rec.failures[0].reason and "self_collision" in rec.failures[1].reason
    # probing stance (0.36) too far, one step closer (0.33) too close, then half way
    can = _things()[0].position[:2]
    stances = [a[1] for what, a in house.calls if what == "approach" and a[0] == can][:3]
    assert stances == pytest.approx([0.36, 0.33, 0.345])


def test_no_stance_between_too_close_and_too_far_is_given_up_not_walked_forever() -> None:
    house = FakeHouse(_things()[:1])
    house.reach_bands = {"tomato_soup_can": (0.5, 0.3)}  # nowhere
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.given_up and not rec.grasped and len(rec.failures) == CFG.task.max_attempts


def test_a_stubborn_object_is_given_up_and_the_others_are_tidied() -> None:
    house = FakeHouse(_things(), grasp_failures={"baseball": ["grip_lost: slipped"] * 20})
    report = _task(house).run()
    ball = _record(report, "baseball")
    assert ball.given_up and not ball.placed and not ball.grasped
    assert ball.attempts == CFG.task.max_attempts == len(ball.failures)
    assert all(f.step == "grasp" and "slipped" in f.reason for f in ball.failures)
    assert _calls(house, "grasp").count("baseball") == CFG.task.max_attempts
    assert report.outcome == "done"
    for label in ("tomato_soup_can", "screwdriver", "bowl"):
        assert _record(report, label).placed
    assert house.things[4].released_in == ""  # never moved
    msg = progress_message(_task(house).progress(), 0.0)  # a fresh task: nothing yet
    assert msg.objects == () and msg.failed == 0


def test_a_false_detection_is_given_up_after_two_probes_that_see_nothing() -> None:
    things = _things()[:2]
    ghost = replace(things[0], track_id=90, label="clamp")
    ghost.position = (things[0].position[0] + 0.6, things[0].position[1], 0.05)
    house = FakeHouse(things, phantoms=[ghost])
    report = _task(house).run()
    rec = _record(report, "clamp")
    assert rec.given_up and not rec.grasped
    assert rec.unseen == CFG.task.max_unseen == 2
    assert len(rec.failures) == 2 and "false detection" in rec.failures[-1].reason
    assert _calls(house, "estimate_grasp").count(("clamp", 90)) == 2
    # the class in view from close by names it only within estimate_gate of the track:
    # the real object 0.6 m away is not what this phantom is renamed to
    assert not rec.close_label
    for t in things:  # the real ones are tidied all the same
        assert _record(report, t.label).placed


def test_an_object_of_a_class_taken_from_the_side_seen_from_close_is_side_probed() -> None:
    """seed-139 (2026-12-07): a coffee can on the kitchen table, a "mug" from afar; the
    probe from above found no mug, and the close view's any-class estimate saw a coffee
    can too tall to take from above ("probe horizontally"). It was given up as a false
    mug; now it is renamed and probed from the side."""
    things = _things()
    can = Thing("coffee_can", 5, (3.0, 3.2, 0.47), on_table=True)
    house = FakeHouse([*things, can])
    house.mistaken[5] = "mug"
    house.not_level.add("coffee_can")
    report = _task(house).run()
    rec = _record(report, "coffee_can")
    assert rec.placed and not rec.given_up and rec.close_label == "coffee_can"
    assert can.released_in == CLASSES["coffee_can"].place
    assert ("estimate_grasp", ("mug", 5)) in house.calls
    assert ("coffee_can", "front_camera") in house.probed_with  # the side probe


def test_an_object_of_another_class_from_close_by_goes_where_that_class_goes() -> None:
    # seed-103: a marker on the living table taken for a bowl from afar; the probe from
    # close by found no bowl, and the marker was given up as a false detection
    things = _things()
    marker = Thing("marker", 5, (3.0, 3.2, 0.41), on_table=True)
    house = FakeHouse([*things, marker])
    house.mistaken[5] = "bowl"
    report = _task(house).run()
    rec = _record(report, "marker")
    assert rec.placed and not rec.given_up and rec.close_label == "marker"
    assert rec.place == CLASSES["marker"].place != CLASSES["bowl"].place
    assert marker.released_in == CLASSES["marker"].place
    assert ("estimate_grasp", ("bowl", 5)) in house.calls
    assert ("estimate_grasp", ("", -1)) in house.calls
    for t in things:  # the real bowl is still tidied, as a bowl
        assert _record(report, t.label).placed


def test_an_object_the_probe_names_otherwise_goes_where_that_class_goes() -> None:
    # seed-112: a tennis ball on the kitchen table, a "lego" from one view afar and a
    # tennis ball from another (two tracks); the lego's probe planned the grasp of the
    # ball by its true class, the task carried it to the lego's box all the same
    things = _things()
    ball = Thing("tennis_ball", 5, (3.0, 3.2, 0.41), on_table=True)
    twin = Thing("tennis_ball", 6, (3.0, 3.25, 0.41), on_table=True)  # the second track
    house = FakeHouse([*things, ball], phantoms=[twin])
    house.mistaken[5] = "lego"
    house.named_close.add(5)
    report = _task(house).run()
    rec = next(r for r in report.objects if r.track_id == 5)
    assert rec.placed and rec.label == rec.close_label == "tennis_ball"
    assert ball.released_in == CLASSES["tennis_ball"].place != CLASSES["lego"].place
    # the ball's second track is the same object: dropped, never approached
    assert all(r.track_id != 6 for r in report.objects)
    assert ("estimate_grasp", ("tennis_ball", 6)) not in house.calls
    assert not any(r.given_up for r in report.objects)
    for t in things:
        assert _record(report, t.label).placed


def test_a_record_of_another_class_where_an_object_was_grasped_is_that_object() -> None:
    # paper-1 (2026-12-07): a "coffee can" track 6 cm from the bowl (the bowl from afar)
    # and a "clamp" where the marker lay stayed unfinished after those were placed; the
    # views that see there were walked at the trial's end to look for them
    things = _things()
    house = FakeHouse(things)
    can = things[0]  # on the living floor
    house.at = (can.position[0] - CFG.task.probe_standoff, can.position[1], 0.0)
    task = _task(house)
    rec = ObjectRecord(can.label, can.track_id, "tray", can.position, t_found=0.0)
    x, y, _ = can.position
    near = ObjectRecord("coffee_can", 40, "tray", (x + 0.06, y, 0.07), t_found=0.0)
    other = ObjectRecord("lego", 41, "black_box", (x + 0.2, y, 0.02), t_found=0.0)
    same = ObjectRecord(can.label, 42, "tray", (x + 0.3, y, 0.05), t_found=0.0)
    task.report.objects.extend([rec, near, other, same])
    task.target, task.probe = rec, task._probe_for(rec)
    house.posture = task.probe.posture
    out, task.plan = house.estimate_grasp(can.label, task.probe.camera, can.track_id)
    assert out.ok
    assert task._grasp().value == "carry"
    assert near not in task.report.objects and 40 in task.done_tracks
    # farther off, or of its own class (another of the class stands for another object
    # unless perception's tracks say so): other objects
    assert other in task.report.objects and 41 not in task.done_tracks
    assert same in task.report.objects


def test_a_second_track_of_the_grasped_object_where_it_lay_is_never_a_target() -> None:
    """paper-5 (2026-12-06): the baseball's record named a track perception had dropped
    (estimate: "unknown track 280"), the probe by class grasped the ball all the same,
    and the track it had been seen as since (#349, the same spot) stayed in the memory:
    after the place it was a new object, walked to and probed for 20 s."""
    things = _things()
    can = next(t for t in things if t.label == "tomato_soup_can")
    house = FakeHouse(things)
    house.forgotten.add(can.track_id)
    real_grasp = house.grasp

    def grasp_and_a_twin_confirmed(plan):
        out = real_grasp(plan)
        if out.ok and house.held is can:  # the same object's newer track, where it lay
            house.memory[77] = SeenObject(77, can.label, can_at)
        return out

    can_at = can.position
    house.grasp = grasp_and_a_twin_confirmed
    report = _task(house).run()
    assert _record(report, "tomato_soup_can").placed
    assert all(r.track_id != 77 for r in report.objects)
    assert not any(a == ("tomato_soup_can", 77) for w, a in house.calls if w == "estimate_grasp")
    for t in things:
        assert _record(report, t.label).placed


def test_a_table_object_not_level_from_above_is_probed_from_the_side() -> None:
    # Section 4.3: when the surface the camera above sees is not level, perception asks
    # for a horizontal probe; asking from above again got the same answer four times
    things = _things()
    house = FakeHouse(things)
    house.not_level.add("bowl")
    report = _task(house).run()
    rec = _record(report, "bowl")
    assert rec.placed and rec.side_probe
    cams = [c for label, c in house.probed_with if label == "bowl"]
    assert cams[0] == "gripper_camera" and set(cams[1:]) == {"front_camera"}, cams
    assert len(rec.failures) == 1 and "probe horizontally" in rec.failures[0].reason
    for t in things:
        assert _record(report, t.label).placed


def test_a_false_detection_gone_from_the_memory_after_a_look_is_given_up_at_once() -> None:
    # the memory drops a track that should be in view and is not: after the first empty
    # probe and the look from a step back, a phantom seen only from afar is gone, and a
    # second approach and probe would be wasted (short-20: ~15 s each, 2-3 phantoms a run)
    things = _things()[:2]
    ghost = replace(things[0], track_id=90, label="clamp")
    ghost.position = (things[0].position[0] + 1.2, things[0].position[1], 0.05)
    house = FakeHouse(things, phantoms=[ghost])
    house.far_only.add(90)
    report = _task(house).run()
    rec = _record(report, "clamp")
    assert rec.given_up and not rec.grasped and rec.unseen == 1
    assert "not seen from a step back" in rec.failures[-1].reason
    assert _calls(house, "estimate_grasp").count(("clamp", 90)) == 1
    for t in things:
        assert _record(report, t.label).placed


def test_a_new_track_at_a_spot_probed_as_a_false_detection_is_not_acted_on() -> None:
    # seed-109: a "sugar box", then a "cracker box", at one corner of the kitchen table:
    # the second cost an approach and two probes
    things = _things()[:2]
    ghost = replace(things[0], track_id=90, label="clamp")
    ghost.position = (things[0].position[0] + 1.2, things[0].position[1], 0.05)
    house = FakeHouse(things, phantoms=[ghost])
    house.far_only.add(90)
    task = _task(house)
    # once the clamp is given up, the same spot is reported as a padlock
    real_give_up = task._give_up_now

    def give_up_then_rename(step, reason):
        out = real_give_up(step, reason)
        again = replace(ghost, track_id=91, label="padlock")
        again.position = (ghost.position[0] + 0.05, ghost.position[1], 0.05)
        house.phantoms[91] = again
        house.memory[91] = SeenObject(91, "padlock", again.position)
        return out

    task._give_up_now = give_up_then_rename
    report = task.run()
    assert _record(report, "clamp").given_up
    assert not [r for r in report.objects if r.label == "padlock"]
    assert ("padlock", 91) not in _calls(house, "estimate_grasp")
    for t in things:
        assert _record(report, t.label).placed


def test_a_real_object_the_look_places_afresh_is_not_taken_for_a_false_detection() -> None:
    # a real object missed by the first probe (its track lay off) is in the memory after
    # the look from a step back: it is approached again and tidied
    things = _things()[:1]
    house = FakeHouse(things)
    house.placed_off.add(things[0].label)
    task = _task(house)
    report = task.run()
    rec = _record(report, things[0].label)
    assert rec.placed and rec.unseen == 1


def test_an_estimate_of_another_object_of_the_class_is_not_taken_for_the_target() -> None:
    # perception forgot the target's track; the estimate of the class in view found
    # another object 0.5 m away (paper-4: a grasp planned 0.49 m to the side, refused)
    x, y, _ = _things()[0].position
    things = [replace(_things()[0], position=(x, y + 0.8, 0.05))]  # nothing where 90 lies
    real = Thing("clamp", 91, (x - 0.5, y, 0.05))
    ghost = Thing("clamp", 90, (x, y, 0.05))
    house = FakeHouse([*things, real], phantoms=[ghost])
    house.forgotten.add(90)
    house.memory[90] = SeenObject(90, "clamp", ghost.position)
    report = _task(house).run()
    recs = {r.track_id: r for r in report.objects if r.label == "clamp"}
    assert recs[90].given_up and not recs[90].grasped
    assert any("0.50 m off" in f.reason for f in recs[90].failures), recs[90].failures
    assert recs[91].placed  # the other one, on its own record
    assert _record(report, things[0].label).placed


def test_a_floor_object_not_level_from_above_counts_as_not_seen() -> None:
    # on the floor there is no side probe: a track where perception finds nothing level
    # to grasp from above is given up like one it does not see (paper-5: a "sugar box"
    # in the kitchen asked for three times)
    things = _things()[:2]
    ghost = replace(things[0], track_id=90, label="clamp")
    ghost.position = (things[0].position[0] + 0.6, things[0].position[1], 0.05)
    house = FakeHouse(things, phantoms=[ghost])
    house.not_level.add("clamp")
    report = _task(house).run()
    rec = _record(report, "clamp")
    assert rec.given_up and rec.unseen == CFG.task.max_unseen and not rec.side_probe
    assert [c for label, c in house.probed_with if label == "clamp"] == ["gripper_camera"] * 2
    for t in things:
        assert _record(report, t.label).placed


def test_a_track_at_table_height_away_from_any_table_is_not_acted_on() -> None:
    # short-20: a "cracker box" at table height 1.2 m from the living table was approached
    # as a table object; the tennis ball 1 m from it was not seen again in that run
    things = _things()
    ghost = Thing("cracker_box", 90, (2.9, 1.9, 0.5))  # over the living room's floor
    house = FakeHouse(things, phantoms=[ghost])
    house.memory[90] = SeenObject(90, "cracker_box", ghost.position)
    report = _task(house).run()
    assert not [r for r in report.objects if r.label == "cracker_box"]
    assert ("cracker_box", 90) not in _calls(house, "estimate_grasp")
    for t in things:  # the bowl on the living table is a table object still
        assert _record(report, t.label).placed


def test_a_floor_track_higher_than_its_class_stands_is_not_acted_on() -> None:
    # paper-5, 2026-12-07: the front camera saw the held soup can as it was lifted and
    # filed it 22 cm up, over the floor: walked back to and probed (13 s). A can stands
    # 10 cm tall, so its centre rests 5 cm up; a cracker box stood on end, 10.5 cm
    things = _things()
    ghost = Thing("tomato_soup_can", 90, (2.9, 1.9, 0.22))  # the living room's floor
    box = Thing("cracker_box", 91, (3.3, 1.4, 0.12))  # standing on end: it rests there
    house = FakeHouse([*things, box], phantoms=[ghost])
    house.memory[90] = SeenObject(90, "tomato_soup_can", ghost.position)
    report = _task(house).run()
    assert ("tomato_soup_can", 90) not in _calls(house, "estimate_grasp")
    assert not [r for r in report.objects if r.track_id == 90]
    for t in [*things, box]:
        assert _record(report, t.label).placed


def test_a_detection_outside_the_searched_zones_is_not_acted_on() -> None:
    # the kitchen's deposit furniture and cabinet gave false detections that each cost an
    # approach and two probes: objects lie in the zones the task searches
    things = _things()
    ghost = Thing("clamp", 90, (7.5, 0.9, 0.05))  # kitchen floor between the boxes: no zone
    house = FakeHouse(things, phantoms=[ghost])
    house.memory[90] = SeenObject(90, "clamp", ghost.position)  # the memory holds it
    report = _task(house).run()
    assert not [r for r in report.objects if r.label == "clamp"]
    assert ("clamp", 90) not in _calls(house, "estimate_grasp")
    for t in things:
        assert _record(report, t.label).placed
    # the same, with the search restricted to the living room: the kitchen's objects too
    house = FakeHouse(_things())
    cfg = replace(CFG.task, zones=("living_floor", "living_table", "living_corner"))
    report = _task(house, cfg=cfg).run()
    assert {r.label for r in report.objects} == {"tomato_soup_can", "bowl", "baseball"}


def test_a_real_object_missed_by_a_probe_is_looked_at_from_a_step_back_and_taken() -> None:
    # paper-3: a soup can and a brick, tracked 10-20 cm off from afar, were not in the
    # probing view twice and given up as false detections
    house = FakeHouse(_things())
    house.placed_off = {"tomato_soup_can"}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and rec.unseen == 1, rec.failures
    assert len(rec.failures) == 1 and "no tomato_soup_can detected" in rec.failures[0].reason
    # the look: an approach to 0.8 m in the floor-search posture, then a wait
    i = next(
        k for k, c in enumerate(house.calls) if c == ("estimate_grasp", ("tomato_soup_can", 1))
    )
    # (after the question what else the probing view shows: nothing, it missed the can)
    assert house.calls[i + 1] == ("estimate_grasp", ("", -1))
    after = house.calls[i + 2 : i + 5]
    assert after[0] == ("move_to_posture", "floor_search")
    assert after[1][0] == "approach" and after[1][1][1] == pytest.approx(CFG.task.relook_standoff)
    can = _things()[0].position
    assert any(
        p == "floor_search" and math.dist(at[:2], can[:2]) == pytest.approx(0.8)
        for at, p, _ in house.waits
    )


def test_a_pull_longer_than_the_arm_reaches_is_asked_again_shorter() -> None:
    house = FakeHouse(_things())
    house.arm_pull = 0.12  # paper-2: "pull of 0.19 m: arm reaches 0.12 m only"
    report = _task(house).run()
    top = next(d for d in report.drawers if d.place == "drawer_top")
    assert top.ok and top.opened == pytest.approx(0.24)
    assert house.drawers["drawer_top"] == pytest.approx(0.24)
    pulls = [c[1][1] for c in house.calls if c[0] == "open_drawer" and c[1][0] == "drawer_top"]
    assert pulls[0] == pytest.approx(0.24) and all(p <= 0.12 for p in pulls[1:])
    assert len(top.failures) == 1  # one refusal, then pulls the arm can make
    assert _record(report, "screwdriver").placed


def test_a_drawer_left_shut_is_opened_again_before_a_tool_is_taken() -> None:
    house = FakeHouse(_things())
    house.stuck_drawers = {"drawer_top": CFG.drawers.attempts}  # every pull at the start
    report = _task(house).run()
    top = next(d for d in report.drawers if d.place == "drawer_top")
    assert top.ok and house.drawers["drawer_top"] == pytest.approx(0.24)
    assert len(top.failures) == CFG.drawers.attempts  # the three pulls at the start
    tops = [
        i for i, c in enumerate(house.calls) if c[0] == "open_drawer" and c[1][0] == "drawer_top"
    ]
    failed, again = tops[: CFG.drawers.attempts], tops[CFG.drawers.attempts :]
    # opened again later (after a search walk), before the tool is taken up
    between = house.calls[failed[-1] : again[0]]
    assert any(what == "navigate_to" for what, _ in between)
    assert again[-1] < house.calls.index(("grasp", "screwdriver"))
    assert _record(report, "screwdriver").placed
    assert house.things[2].released_in == "drawer_top"


def test_a_tool_whose_drawer_stays_shut_is_given_up_not_dropped() -> None:
    house = FakeHouse(_things())
    house.stuck_drawers = {"drawer_top": 100}
    report = _task(house).run()
    rec = _record(report, "screwdriver")
    assert rec.given_up and not rec.grasped and "drawer_top is shut" in rec.failures[-1].reason
    assert ("grasp", "screwdriver") not in house.calls
    for label in ("tomato_soup_can", "bowl", "baseball"):
        assert _record(report, label).placed


def test_a_walk_goal_in_an_obstacle_is_tried_from_other_sides() -> None:
    house = FakeHouse(_things())
    house.at = (2.0, 2.3, 0.0)  # 4 m west of the screwdriver: walked to first
    task = _task(house)
    screwdriver = house.things[2]
    house.memory[2] = SeenObject(2, "screwdriver", screwdriver.position)
    house.refuse_near = {"screwdriver": 4}  # the goals on the robot's side are in a sofa
    rec = ObjectRecord("screwdriver", 2, "drawer", screwdriver.position, t_found=0.0)
    assert task._walk_near(rec).ok
    goals = [p for what, p in house.calls if what == "navigate_to"]
    assert len(goals) == 5 and house.refuse_near["screwdriver"] == 0
    # the side it comes from at 0.8, 1.0 and 0.6 m, then turned: facing the object each time
    assert [round(math.dist(g[:2], screwdriver.position[:2]), 2) for g in goals[:3]] == [
        0.8,
        1.0,
        0.6,
    ]
    assert goals[0][2] == pytest.approx(0.0) and goals[3][2] == pytest.approx(0.6)
    for g in goals:
        assert _bearing(g, screwdriver.position)[1] == pytest.approx(0.0, abs=1e-9)


def test_a_walk_stopped_because_its_goal_is_too_close_to_an_obstacle_tries_other_sides() -> None:
    # the LiDAR finds the goal too close to an obstacle only on the way (paper-4: the
    # marker's walk blocked so four times, the same goal each time)
    house = FakeHouse(_things())
    house.at = (2.0, 2.3, 0.0)
    task = _task(house)
    screwdriver = house.things[2]
    house.memory[2] = SeenObject(2, "screwdriver", screwdriver.position)
    house.refuse_near = {"screwdriver": 2}
    house.refusal = "blocked: goal too close to an obstacle"
    rec = ObjectRecord("screwdriver", 2, "drawer", screwdriver.position, t_found=0.0)
    assert task._walk_near(rec).ok
    goals = [p for what, p in house.calls if what == "navigate_to"]
    assert len(goals) == 3 and len({g[:2] for g in goals}) == 3


def test_an_approach_blocked_by_furniture_after_the_walk_comes_from_another_side() -> None:
    # paper-4: the tennis ball 0.46 m from the bookshelf; every approach from the side
    # the robot walked to stopped on the footprint guard, four times, then given up
    things = _things()
    house = FakeHouse(things)
    house.at = (2.0, 2.3, 0.0)  # west of the screwdriver: walked to first
    house.furniture = [(5.55, 2.5)]  # beside the stance facing it from the west
    report = _task(house).run()
    rec = _record(report, "screwdriver")
    assert rec.placed
    # the walk from the side it comes from (the stop may be the robot's own stance against
    # furniture) is stopped once more; the next walk comes from another side
    assert len([f for f in rec.failures if "footprint" in f.reason]) == 1, rec.failures


def test_an_approach_stopped_by_furniture_at_once_walks_clear_and_approaches_again() -> None:
    # paper-2: after a place, four approaches to the next object, 1 m away, stopped
    # within a second on the footprint guard (the deposit shelf beside the trunk), and
    # the object was given up without a step taken
    house = FakeHouse(_things())
    can = house.things[1]
    house.at = (can.position[0] - 1.0, can.position[1], 0.0)
    house.by_furniture = True
    house.memory[1] = SeenObject(1, "tomato_soup_can", can.position)
    task = _task(house)
    task.target = rec = ObjectRecord("tomato_soup_can", 1, "tray", can.position, t_found=0.0)
    assert task._approach().value == "probe"
    assert rec.failures == [] and not house.by_furniture
    moves = [what for what, _ in house.calls if what in ("approach", "navigate_to")]
    assert moves == ["approach", "navigate_to", "approach"]
    assert math.dist(house.at[:2], can.position[:2]) == pytest.approx(CFG.task.probe_standoff)


def test_an_approach_with_no_stance_clear_from_here_walks_to_the_next_side_at_once() -> None:
    # paper-1 (2026-12-07): navigation ended the Rubik's cube's approach before it set off
    # (no stance about it clear from where the robot stood); the walk to the side it came
    # from ended 0.2 m back and the approach from there ended at once again. The walk goes
    # to the next side at once
    house = FakeHouse(_things())
    can = house.things[1]
    house.at = (can.position[0] - 0.6, can.position[1], 0.0)
    house.by_furniture = True
    house.furniture_reason = (
        "blocked: an obstacle touches the footprint at the stance asked, and no stance "
        "turned about the target is clear from here"
    )
    house.memory[1] = SeenObject(1, "tomato_soup_can", can.position)
    task = _task(house)
    task.target = ObjectRecord("tomato_soup_can", 1, "tray", can.position, t_found=0.0)
    assert task._approach().value == "probe"
    moves = [(what, p) for what, p in house.calls if what in ("approach", "navigate_to")]
    assert [what for what, _ in moves] == ["approach", "navigate_to", "approach"]
    walk = moves[1][1]  # facing the can, turned about it from the way the robot faced it
    assert walk[2] == pytest.approx(CFG.task.walk_sides[1]), walk
    # any other stop by furniture, and the first walk comes from the side it comes from
    house = FakeHouse(_things())
    house.at = (can.position[0] - 0.6, can.position[1], 0.0)
    house.by_furniture = True
    house.memory[1] = SeenObject(1, "tomato_soup_can", can.position)
    task = _task(house)
    task.target = ObjectRecord("tomato_soup_can", 1, "tray", can.position, t_found=0.0)
    assert task._approach().value == "probe"
    walk = next(p for what, p in house.calls if what == "navigate_to")
    assert walk[2] == pytest.approx(CFG.task.walk_sides[0]), walk


def test_a_floor_object_under_a_tables_top_is_given_up_before_any_approach() -> None:
    # paper-2 (2026-12-07): a "baseball" track 3 cm in under the deposit table's corner;
    # seven approaches ended at once and walks went to three sides before a probe found
    # nothing there (20 s). Under a top the arm cannot reach it, real or not
    house = FakeHouse(_things())
    table = PLACES["deposit_table"]
    x0, y0, x1, y1 = table.area
    under = (x1 - 0.03, y1 - 0.06, 0.037)
    house.at = (7.6, 3.1, 1.57)
    task = _task(house)
    task.target = rec = ObjectRecord("baseball", 9, "green_box", under, t_found=0.0)
    assert task._approach().value == "choose_target"
    assert rec.given_up and "under deposit_table's top" in rec.failures[-1].reason
    assert not [c for c in house.calls if c[0] in ("approach", "navigate_to")]
    assert under in task.false_spots
    # beside the table, or on it: taken up as ever
    for beside in ((x1 + 0.05, y1 - 0.06, 0.037), (x1 - 0.01, y0 + 0.1, 0.037)):
        task.target = ObjectRecord("baseball", 9, "green_box", beside, t_found=0.0)
        assert task._top_over(task.target) is None, beside
    task.target = ObjectRecord("baseball", 9, "green_box", (x1 - 0.1, y1 - 0.1, 0.44), t_found=0.0)
    assert task._top_over(task.target) is None


def test_an_approach_keeps_other_floor_objects_from_under_the_stances_feet() -> None:
    # paper-5: the line from the robot to its stance passed clear of a Rubik's cube, but
    # the cube lay beside the stance, under a hind foot, and the robot fell
    stance_x = CAN.position[0] - CFG.task.probe_standoff
    # by the left front foot, beyond the line's end: over step_clearance from the line
    cube = Thing("rubiks_cube", 5, (stance_x + 0.25, 1.4 + 0.22, 0.03))
    assert math.hypot(0.25, 0.22) > CFG.task.step_clearance
    house, step = _approach_can(cube)
    assert step == "probe"
    (_, standoff, heading), *_ = _calls(house, "approach")
    assert heading is not None and abs(heading) > 0.3  # turned: the cube is off its feet
    stance = (2.5 - standoff * math.cos(heading), 1.4 - standoff * math.sin(heading), heading)
    assert not _under_feet(cube.position, stance)


def test_a_walk_goal_with_another_floor_object_under_its_feet_is_not_used() -> None:
    house = FakeHouse(_things())
    house.at = (2.0, 2.3, 0.0)  # 4 m west of the screwdriver: walked to first
    task = _task(house)
    screwdriver = house.things[2]
    house.memory[2] = SeenObject(2, "screwdriver", screwdriver.position)
    cube = (5.2, 2.35, 0.03)  # where the first goal (0.8 m short, from the west) stands
    house.memory[5] = SeenObject(5, "rubiks_cube", cube)
    rec = ObjectRecord("screwdriver", 2, "drawer", screwdriver.position, t_found=0.0)
    assert task._walk_near(rec).ok
    goals = [p for what, p in house.calls if what == "navigate_to"]
    assert len(goals) == 1
    assert not _under_feet(cube, goals[0])


def test_an_approach_goes_round_another_object_on_the_floor_not_over_it() -> None:
    # paper-3: an approach among a mug, a Rubik's cube and a coffee can tripped the robot;
    # objects on the floor are below the LiDAR, so neither navigation nor the approach's
    # guard sees them: the task steers the straight approach clear of those it knows
    cube = Thing("rubiks_cube", 5, (2.25, 1.45, 0.03))  # just short of the can, on its line
    start = CAN_START
    house, step = _approach_can(cube)
    assert step == "probe"
    (target, standoff, heading), *_ = _calls(house, "approach")
    assert heading is not None and abs(heading) > 0.3  # turned off the straight line
    stance = (2.5 - standoff * math.cos(heading), 1.4 - standoff * math.sin(heading))
    (ux, uy), (vx, vy) = np.subtract(stance, start[:2]), np.subtract(cube.position[:2], start[:2])
    assert abs(ux * vy - uy * vx) / math.dist(stance, start[:2]) > CFG.task.step_clearance
    # with nothing in the way, it faces the object from where it comes (Algorithm 5)
    house, _ = _approach_can()
    assert _calls(house, "approach")[0][2] is None


def test_a_floor_heading_chosen_clear_of_other_objects_may_be_turned_clear_of_furniture():
    """The task chooses a floor approach's heading by the objects it knows of, not by the
    walls and furniture, which navigation's map holds: such a heading is sent turnable
    (``turn_free``): approaches of every kind stopped against furniture and were walked
    round 18 times in ten trials. Facing the object from where the robot comes, navigation turns
    it anyway."""
    cube = Thing("rubiks_cube", 5, (2.25, 1.45, 0.03))
    house, step = _approach_can(cube)
    assert step == "probe"
    assert _calls(house, "approach")[0][2] is not None
    assert house.turn_free_approaches == 1
    house, _ = _approach_can()
    assert _calls(house, "approach")[0][2] is None
    assert house.turn_free_approaches == 0


def test_a_table_object_is_approached_square_to_its_table() -> None:
    # a stance turned toward an object near the table's end put a trunk corner against a
    # table leg; square to the table from its stand side, the object straight ahead
    house = FakeHouse(_things())
    report = _task(house).run()
    assert _record(report, "bowl").placed
    table = PLACES["living_table"]
    bowl = house.things[3].position
    to_bowl = [a for what, a in house.calls if what == "approach" and a[0] == bowl[:2]]
    assert to_bowl and all(h == pytest.approx(table.stand[2]) for _, _, h in to_bowl)
    floor = [a for what, a in house.calls if what == "approach" and a[0] == (2.5, 1.4)]
    assert floor and all(h is None for _, _, h in floor)  # the floor: facing the object


def test_an_approach_that_ends_near_but_unsettled_goes_on_from_there() -> None:
    # navigation gives up settling to +-1.5 cm after its timeout: the robot stands close;
    # probing and placing from there costs nothing, walking back again cost ~30 s a time
    house = FakeHouse(_things()[:2])
    house.unsettled = 100
    report = _task(house).run()
    for t in _things()[:2]:
        rec = _record(report, t.label)
        assert rec.placed and rec.failures == []
    # the places' stands are asked loosely (the place plans from where the robot is)
    assert house.loose_approaches == 2


def test_an_object_dropped_on_the_way_is_found_again_and_placed() -> None:
    house = FakeHouse(_things()[:1], drop_while_carrying={"tomato_soup_can": 1})
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed
    assert [f.reason for f in rec.failures] == ["dropped while carrying"]
    assert _calls(house, "grasp") == ["tomato_soup_can"] * 2
    assert house.things[1].released_in == "tray"


def test_a_view_where_a_found_object_is_left_undone_is_not_skipped() -> None:
    """paper-3 (2026-12-06): a Rubik's cube found early dropped from the memory later
    (missed from afar); every view of its floor was skipped as seen and it was never
    taken up. A view showing a found, unfinished object's spot is walked to."""
    from quadmanip.services.behavior.coverage import sees
    from quadmanip.services.behavior.report import ObjectRecord

    house = FakeHouse(_things())
    house.seen = lambda points, table, since=-math.inf: [True] * len(points)
    task = _task(house)
    task.zone = PLACES["living_floor"]
    z = task.zone
    sc = CFG.search["search_floor"]
    vp = zone_viewpoints(z.stand, (z.target[0], z.target[1]), z.size, sc)[1]
    assert task._view_seen(vp)  # everything seen: skipped
    spot = next(
        p for p in view_samples(vp, (z.target[0], z.target[1]), z.size, sc) if sees(vp, p, sc)
    )
    rec = ObjectRecord(label="rubiks_cube", track_id=5, place="black_box",
                       position=(*spot, 0.03), t_found=10.0)  # fmt: skip
    task.report.objects.append(rec)
    assert not task._view_seen(vp)
    # and says so (paper-1, 2026-12-07: a Lego's look again left no trace in the log)
    assert f"looking again for rubiks_cube at ({spot[0]:.2f}, {spot[1]:.2f})" in task.report.step
    # once: paper-1 (2026-12-07) walked nine views after its last object for two
    # phantoms' records, every floor and table view whose band held their spots
    assert task._view_seen(vp)
    task.relooked.clear()  # (its track seen again, and lost again)
    rec.placed = True  # done with it: nothing to look for there
    assert task._view_seen(vp)
    # a table's view does not look for an object on the floor under it
    task.zone = PLACES["living_table"]
    zt, st = task.zone, CFG.search["search_table"]
    for vt in zone_viewpoints(zt.stand, (zt.target[0], zt.target[1]), zt.size, st):
        p = view_samples(vt, (zt.target[0], zt.target[1]), zt.size, st)[0]
        assert sees(vt, p, st)
        rec = ObjectRecord(label="lego", track_id=6, place="black_box",
                           position=(*p, 0.02), t_found=10.0)  # fmt: skip
        task.report.objects.append(rec)
        assert task._view_seen(vt)
        rec.position = (*p, 0.43)  # on the table: looked for
        assert not task._view_seen(vt)


@pytest.mark.parametrize("at_the_end", [False, True])
def test_a_dropped_object_is_looked_for_even_where_the_cameras_had_seen(at_the_end) -> None:
    """paper-2 (2026-12-06): the spoon slipped from the fingers at the pencil case; every
    view of the search again was skipped as seen (before it fell) and the task ended
    without it. Views count for skipping only from the drop on."""
    house = FakeHouse(
        _things(), drop_while_carrying={"tomato_soup_can": 1}, drop_at_the_end=at_the_end
    )
    house.looks = []
    house.look_range, house.look_bearing = 2.5, 1.0
    task = _task(house)
    report = task.run()
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed, rec.failures
    assert _calls(house, "grasp").count("tomato_soup_can") == 2
    assert task.views_skipped > 0  # the grid still saved walks
    for t in house.things.values():
        assert t.released_in == _home(t.label), t.label


def test_an_object_dropped_outside_every_zone_along_the_walk_is_taken_up_again() -> None:
    # paper-2 (2026-12-06): the spoon fell in the doorway, 1.6 m before the robot noticed
    # at the walk's end; perception confirmed a new spoon track there, outside every search
    # zone (taken for a false detection), and the task ended without it
    can = Thing("tomato_soup_can", 1, (3.4, 1.0, 0.05))  # its walk to the tray: the doorway
    house = FakeHouse([can], drop_while_carrying={"tomato_soup_can": 1})
    house.renumber_drops = True
    house.look_range = 2.5
    task = _task(house)
    report = task.run()
    assert len(house.fell_at) == 1 and not task._in_zones(house.fell_at[0])
    fell = house.things[101]
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed, rec.failures
    assert _calls(house, "grasp") == ["tomato_soup_can"] * 2
    assert fell.released_in == "tray"


@pytest.mark.parametrize("seen_as", ["", "marker"])
def test_an_object_that_slips_out_over_its_box_onto_the_table_is_taken_up_from_there(seen_as):
    # paper-1 (2026-12-06): the spoon slipped out as the arm turned it over the pencil case
    # and lay on the deposit table 15 cm before the case: within tidy_radius of a deposit
    # place, so taken for tidy and never taken up. Later the same day the detector took it
    # there for a marker (which goes into the pencil case too)
    spoon = Thing("spoon", 1, (2.5, 1.4, 0.01))
    house = FakeHouse([spoon])
    house.place_drops = {"spoon": 1}
    house.place_drop_seen_as = seen_as
    task = _task(house)
    report = task.run()
    assert len(house.fell_at) == 1 and house.fell_at[0][2] > 0.3  # on the deposit table
    rec = _record(report, "spoon")
    assert rec.dropped and rec.placed, rec.failures
    assert rec.dropped_by == "pencil_case"
    assert _calls(house, "grasp") == ["spoon"] * 2
    assert spoon.released_in == "pencil_case"
    # the table look came first: the table-search posture right after the failed place
    after = house.calls[[c[0] for c in house.calls].index("place") + 1 :]
    assert [a for c, a in after if c == "move_to_posture"][0] == "table_search"


def test_an_object_that_slips_out_just_before_its_box_is_taken_up_from_there() -> None:
    # paper-2 (2026-12-06): the spoon slipped out as the place shifted the trunk and lay
    # 6 cm before the pencil case (its footprint 12 cm deep); the detector took it for a
    # marker there, its track lay within the footprint's 3 cm margin and was taken for
    # in the case; no marker was in the scene, and the task ended without the spoon
    spoon = Thing("spoon", 1, (2.5, 1.4, 0.01))
    house = FakeHouse([spoon])
    house.place_drops = {"spoon": 1}
    house.place_drop_seen_as = "marker"
    house.place_drop_at = (0.075, 0.0)
    report = _task(house).run()
    rec = _record(report, "spoon")
    assert rec.dropped and rec.placed, rec.failures
    assert _calls(house, "grasp") == ["spoon"] * 2
    assert spoon.released_in == "pencil_case"


def test_an_object_in_its_box_is_not_taken_for_one_that_slipped_out_beside_it() -> None:
    # the first marker slips out over the pencil case onto the table; the second, placed
    # in the case meanwhile, is in the box: only the one beside it is taken up again
    m1 = Thing("marker", 1, (2.5, 1.4, 0.01))
    house = FakeHouse([m1])
    house.place_drops = {"marker": 1}
    task = _task(house)
    task.run()
    case = PLACES["pencil_case"]
    inside = SeenObject(77, "marker", (case.target[0] + 0.05, case.target[1] + 0.01, 0.42))
    beside = SeenObject(78, "marker", (case.target[0] - 0.05, case.target[1] - 0.15, 0.404))
    can = SeenObject(79, "tomato_soup_can", beside.position)  # goes to the tray
    rec = _record(task.report, "marker")
    rec.placed = False  # as if still to be taken up
    second = replace(rec, track_id=99, placed=True, dropped_by="")  # the one in the case
    task.report.objects.append(second)
    assert task._tidy(inside) and not task._tidy(beside) and task._tidy(can)
    assert task._record_for(beside) is rec and task._record_for(can) is None
    # with no marker put into the case, a marker track by it can only be the dropped one,
    # wherever it lies (paper-2, 2026-12-06: the spoon, taken for a marker, 6 cm before
    # the case, its track within the footprint's margin)
    task.report.objects.remove(second)
    assert not task._tidy(inside) and task._record_for(inside) is rec
    rec.placed = True
    assert task._tidy(beside)


def test_an_object_that_topples_out_of_its_box_onto_the_floor_is_taken_up_again() -> None:
    # seed-132 (2026-12-06): the sugar box, released standing in the tray beside two cans,
    # toppled over the near wall and off the deposit table; its track on the floor 0.35 m
    # from the tray's middle was within tidy_radius of it, taken for tidy, and the task
    # counted the box placed
    box = Thing("sugar_box", 1, (2.5, 1.4, 0.08))
    house = FakeHouse([box])
    house.place_topples = {"sugar_box": 1}
    task = _task(house)
    real_grasp, taken_at_grasp = house.grasp, []

    def grasp(plan):
        taken_at_grasp.append(progress_message(task.progress(), 0.0).taken_track_ids.tolist())
        return real_grasp(plan)

    house.grasp = grasp
    report = task.run()
    assert len(house.fell_at) == 1 and house.fell_at[0][2] < 0.25  # on the floor
    # perception is told to forget the track each grasp took up, and only that: the
    # record, grasped before, names the track on the floor while the box lies there
    # (paper-1, 2026-12-07: that track forgotten at once, the estimate refused)
    assert taken_at_grasp == [[], [1]]
    assert box.track_id == 101 and _record(report, "sugar_box").track_id == 101
    assert task.progress().taken_tracks == (1, 101)
    rec = _record(report, "sugar_box")
    assert rec.placed and rec.dropped
    assert [f.reason for f in rec.failures] == ["fell out of tray: on the floor 0.35 m from it"]
    assert _calls(house, "grasp") == ["sugar_box"] * 2
    assert box.released_in == "tray"
    # the second time into another slot of the tray
    releases = [a[0] for c, a in house.calls if c == "place"]
    assert math.dist(releases[0][:2], releases[1][:2]) > 0.05


def test_an_object_that_topples_out_every_time_is_given_up() -> None:
    box = Thing("sugar_box", 1, (2.5, 1.4, 0.08))
    house = FakeHouse([box])
    house.place_topples = {"sugar_box": 99}
    report = _task(house).run()
    rec = _record(report, "sugar_box")
    assert rec.given_up and not rec.placed
    assert len(_calls(house, "grasp")) == CFG.task.max_attempts


def test_what_lies_on_the_floor_by_a_box_on_a_table_is_not_in_it() -> None:
    # a track of a placed object's class on the floor near its box is that object,
    # fallen out; in the box (at table height) it is tidy; another class beside the box on
    # the floor is nobody's record, and a floor box's neighbour is told by nothing
    house = FakeHouse([Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05))])
    task = _task(house)
    task.run()
    tray, green = PLACES["tray"], PLACES["green_box"]
    rec = _record(task.report, "tomato_soup_can")
    assert rec.placed
    inside = SeenObject(77, "tomato_soup_can", (tray.target[0], tray.target[1], 0.45))
    floor = SeenObject(78, "tomato_soup_can", (tray.target[0] + 0.1, tray.target[1] - 0.4, 0.04))
    other = SeenObject(79, "coffee_can", floor.position)
    by_green = SeenObject(80, "brick", (green.target[0], green.target[1] + 0.3, 0.03))
    assert task._tidy(inside) and not task._tidy(floor) and not task._tidy(other)
    assert task._tidy(by_green)
    assert task._fell_out(inside) is None and task._fell_out(floor) is rec
    assert task._fell_out(other) is None


def test_an_object_that_slips_out_as_the_arm_moves_to_carry_is_not_carried() -> None:
    # seed-107: a cup slipped out during the move to the carry posture, and the robot
    # walked to the green box with empty fingers before it noticed
    house = FakeHouse(_things()[:1])
    house.posture_drops = {"tomato_soup_can": 1}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed
    assert [f.reason for f in rec.failures] == ["dropped while moving to carry it"]
    assert _calls(house, "grasp") == ["tomato_soup_can"] * 2
    tray = PLACES["tray"].stand[:2]
    walks = [a for a in _calls(house, "navigate_to") if isinstance(a, tuple)]
    to_tray = [i for i, a in enumerate(walks) if math.dist(a[:2], tray) < 0.6]
    assert len(to_tray) == 1  # one walk to the tray: with the object, after the second grasp
    assert house.things[1].released_in == "tray"


def test_after_a_drop_the_robot_looks_where_it_fell_first() -> None:
    # it slips out at the tray, outside every search zone: only a look there finds it
    house = FakeHouse(
        _things()[:1], drop_while_carrying={"tomato_soup_can": 1}, drop_at_the_end=True
    )
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed
    assert _calls(house, "grasp") == ["tomato_soup_can"] * 2
    fell = house.things[1]  # placed now; it fell where the carry walk ended
    walks = [a for a in _calls(house, "navigate_to") if isinstance(a, tuple)]
    stage = next(i for i, a in enumerate(walks) if math.dist(a[:2], PLACES["tray"].stand[:2]) < 0.6)
    # the next walk after the carry is to look at the spot, not to a zone far away
    assert math.dist(walks[stage + 1][:2], walks[stage][:2]) < 1.5
    assert fell.released_in == "tray"
    assert not any(z.startswith("dropped") for z in report.zones_searched)


def test_a_place_is_checked_from_the_gripper_and_tried_again() -> None:
    house = FakeHouse(_things()[:1], sticky={"tomato_soup_can": 1})
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and [f.reason for f in rec.failures] == ["still holding after the place"]
    assert len(_calls(house, "place")) == 2
    assert house.things[1].released_in == "tray"


def test_a_place_whose_fingers_close_on_it_again_is_tried_again_on_the_spot() -> None:
    """object_stuck: the object is still in the fingers above the region, whatever the grip
    message (trailing the result) says at that moment; it is released there once more, not
    taken for let go and carried along to the next grasp (paper-5's soup can)."""
    house = FakeHouse(_things()[:2])
    house.stuck = {"tomato_soup_can": 1}
    house.grip_lag = 0.05
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and not rec.dropped
    assert [f.reason for f in rec.failures] == []  # (a retry on the spot, not a failure)
    tray = [c for c in _calls(house, "place") if math.dist(c[0][:2], (7.0, 3.6)) < 0.2]
    assert len(tray) == 2
    assert house.things[1].released_in == "tray"
    assert all(r.placed for r in report.objects)


@pytest.mark.parametrize(
    "why",
    [
        "blocked: goal too close to an obstacle",
        "rejected: the goal is in an obstacle or too close to one",
    ],
)
def test_a_staging_pose_too_near_an_obstacle_is_moved_toward_the_stand(why: str) -> None:
    """seed-111: a soup can lay 15 cm from the green box's staging pose; the four walks
    there were refused, and the baseball was put down and given up. Found on the way or
    refused before the walk (navigation's node says "rejected: the goal is in ...")."""
    house = FakeHouse([_things()[3]])
    house.blocked_reason = why
    sx, sy, syaw = PLACES["green_box"].stand
    back = CFG.task.stage_back
    house.blocked_goals = [(sx - back * math.cos(syaw), sy - back * math.sin(syaw))]
    report = _task(house).run()
    rec = _record(report, "baseball")
    assert rec.placed and rec.failures == []
    walks = [c for c in _calls(house, "navigate_to") if isinstance(c, tuple)]
    half = (sx - back / 2 * math.cos(syaw), sy - back / 2 * math.sin(syaw))
    assert any(math.dist(w[:2], half) < 1e-6 for w in walks)


def test_an_object_stuck_twice_at_one_slot_is_released_at_the_next() -> None:
    """Jammed in the fingers twice at one slot (seed-107: a cracker box, 8 times at one slot
    of the tray, then the robot tripped over it): the robot stands in front of the place's
    next slot and releases it there."""
    house = FakeHouse(_things()[:2])
    house.stuck = {"tomato_soup_can": 2}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and not rec.dropped
    tray = [c[0] for c in _calls(house, "place") if math.dist(c[0][:2], (7.0, 3.6)) < 0.3]
    assert len(tray) == 3
    assert tray[0] == tray[1]  # once more at the same slot, then the next one
    assert math.dist(tray[1][:2], tray[2][:2]) > 0.1
    assert house.things[1].released_in == "tray"


def test_a_grasp_refused_while_holding_sets_the_held_object_down_first() -> None:
    """A grasp refused as already_holding (here the place said done, the gripper kept the
    screwdriver and its message came after the check read "let go"): it is put down, taken
    for not placed, and every object ends in its place."""
    house = FakeHouse(_things(), sticky={"screwdriver": 1})  # (the first one taken up)
    house.grip_lag = 0.05
    report = _task(house).run()
    reasons = [f.reason for r in report.objects for f in r.failures]
    assert reasons == ["still in the gripper at the next grasp"]
    assert len([c for c in _calls(house, "grasp") if c == "screwdriver"]) == 2
    assert all(r.placed for r in report.objects), reasons
    assert {t.label: t.released_in for t in house.things.values()} == {
        "tomato_soup_can": "tray",
        "screwdriver": "drawer_top",
        "bowl": "small_box",
        "baseball": "green_box",
    }


def test_the_last_object_still_in_the_fingers_at_the_end_is_set_down_and_placed() -> None:
    """The last place said done and the check read "let go" before the grip message came:
    with nothing left to do the gripper still holds it, so it is set down, found and
    placed (not left in the gripper with the trial reported done)."""
    house = FakeHouse(_things(), sticky={"tomato_soup_can": 1})  # (the last one taken up)
    house.grip_lag = 0.05
    report = _task(house).run()
    assert report.outcome == "done"
    assert house.held is None
    assert house.things[1].released_in == "tray"
    rec = _record(report, "tomato_soup_can")
    assert [f.reason for f in rec.failures] == ["still in the gripper when nothing was left"]


def test_a_grasp_refused_with_its_reachable_band_is_taken_from_the_bands_middle() -> None:
    """Beyond the band's far edge the refusal reads "self_collision" as one too close does
    (paper-5: the marker, stepped back from and in again four times, given up); with the
    band named, one step into its middle and the grasp is done."""
    house = FakeHouse(_things()[:1])
    house.reach_bands = {"tomato_soup_can": (0.22, 0.30)}  # the probe stands 0.36 off
    house.band_hints = True
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and len([f for f in rec.failures if "self_collision" in f.reason]) == 1
    assert _calls(house, "grasp") == ["tomato_soup_can", "tomato_soup_can"]
    steps = [a for what, a in house.calls if what == "approach" and a[0] == (2.5, 1.4)]
    assert steps[-1][1] == pytest.approx(0.26, abs=0.01)  # the band's middle


# ------------------------------------------------------------------ ends


def test_the_time_budget_ends_the_trial() -> None:
    house = FakeHouse(_things(), seconds_per_walk=20.0)
    budget = 300.0
    report = _task(house, time_budget=budget).run()
    assert report.outcome == "budget" and "300" in report.reason
    # it stopped at the first step change past the budget, with objects left
    assert budget <= report.t_end - report.t_start < budget + 120.0
    assert sum(r.placed for r in report.objects) < len(house.things)


def test_not_localised_fails_after_the_ready_timeout() -> None:
    house = FakeHouse(_things(), localised=False)
    report = _task(house).run()
    assert report.outcome == "failed" and "not localised" in report.reason
    assert house.calls == [] and report.t_end >= CFG.task.ready_timeout


def test_cancel_ends_the_trial() -> None:
    house = FakeHouse(_things())
    house.cancel_after = 40.0
    report = _task(house).run()
    assert report.outcome == "canceled"
    assert not any(r.placed for r in report.objects)


def test_only_the_wanted_classes_and_nothing_already_in_place() -> None:
    tray = PLACES["tray"].target
    things = [*_things(), Thing("coffee_can", 5, (tray[0] + 0.05, tray[1] - 0.05, 0.47), True)]
    house = FakeHouse(things)
    report = _task(house, labels=("baseball", "coffee_can")).run()
    assert report.outcome == "done"
    assert [r.label for r in report.objects] == ["baseball"]
    assert set(_calls(house, "grasp")) == {"baseball"}
    assert house.things[4].released_in == "green_box"


def test_objects_put_into_one_place_go_to_its_slots_side_by_side() -> None:
    # two food objects into the 2.5 cm deep tray: released on one spot, the second would
    # land on the first (paper-2, 2026-12-05: the soup can ended beside the tray)
    things = [
        Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05)),
        Thing("coffee_can", 2, (3.2, 1.9, 0.07)),
    ]
    house = FakeHouse(things)
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    assert {t.released_in for t in house.things.values()} == {"tray"}
    side, slots = _tray_sides()
    sides = [side(pos) for pos, _ in _calls(house, "place")]
    assert sides == pytest.approx(slots[:2])
    assert abs(sides[0] - sides[1]) > 0.15  # farther apart than a can's diameter and more


def test_four_food_objects_go_into_the_tray_each_on_a_spot_of_its_own() -> None:
    # random scenes hold three or four of the four food objects in 4 of 10 draws; the
    # third released between the first two knocked one off the table in MuJoCo drops
    things = [
        Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05)),
        Thing("coffee_can", 2, (3.2, 1.9, 0.07)),
        Thing("tomato_soup_can", 3, (2.0, 2.2, 0.05)),
        Thing("coffee_can", 4, (3.6, 1.2, 0.07)),
    ]
    house = FakeHouse(things)
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    assert [t.released_in for t in house.things.values()] == ["tray"] * 4
    tray = PLACES["tray"]
    points = np.array([pos[:2] for pos, _ in _calls(house, "place")])
    assert len(points) == 4
    gaps = [np.hypot(*(a - b)) for i, a in enumerate(points) for b in points[i + 1 :]]
    # rows 10 cm apart: in the MuJoCo drops that kept all four in, the coffee can's
    # 0.102 m touching a neighbour at most; nothing released onto another
    assert min(gaps) > 0.099
    # every release point lies inside the tray (0.40 x 0.30 m outside) a can's radius in
    inner = np.abs(points - np.array(tray.target[:2])) + 0.051
    assert np.all(inner <= np.array([0.192, 0.142]))


def test_the_tools_go_into_the_drawer_each_on_a_spot_of_its_own() -> None:
    # released on one spot, the second tool landed on the first and one ended outside the
    # drawer (seed-124: the clamp hanging on the front panel, then the padlock on the floor)
    things = [
        Thing("padlock", 1, (2.5, 1.4, 0.012)),
        Thing("clamp", 2, (3.2, 1.9, 0.016)),
        Thing("screwdriver", 3, (2.0, 2.2, 0.016)),
    ]
    house = FakeHouse(things)
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    drawer = PLACES[CFG.deposits["drawer"].place]
    assert [t.released_in for t in house.things.values()] == [drawer.name] * 3
    side = _left_of(drawer.name)
    sides = sorted(side(pos) for pos, _ in _calls(house, "place"))
    # apart by more than the clamp's 12.5 cm width, and the outer ones with the clamp's
    # 16.5 cm length inside the drawer's 64 cm (its inner half width: 0.30 m)
    assert len(sides) == 3
    assert min(b - a for a, b in zip(sides, sides[1:], strict=False)) > 0.125
    assert max(abs(s) for s in sides) + 0.165 / 2 < 0.30


def _two_cans() -> list[Thing]:
    """Two food objects on the floor: both go into the tray, to its first two slots."""
    return [
        Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05)),
        Thing("coffee_can", 2, (3.2, 1.9, 0.07)),
    ]


def _left_of(name: str) -> Callable[[Sequence[float]], float]:
    """How far a point lies left of place ``name``'s centre line, seen from its stand."""
    place = PLACES[name]
    left = (-math.sin(place.stand[2]), math.cos(place.stand[2]))

    def side(p: Sequence[float]) -> float:
        return (p[0] - place.target[0]) * left[0] + (p[1] - place.target[1]) * left[1]

    return side


def _tray_sides() -> tuple[Callable[[Sequence[float]], float], list[float]]:
    """(how far a point lies left of the tray's centre line, seen from its stand; the
    slots' left offsets)."""
    return _left_of("tray"), [sd for sd, _ in CFG.deposits["tray"].slots]


def test_a_blocked_stance_at_a_place_backs_off_to_the_next_slot() -> None:
    # paper-3 (2026-12-05): the stance for the black box's second slot stopped 5 cm short
    # at every step in; the place was refused too_far eight times (130 s)
    house = FakeHouse(_two_cans())
    side, slots = _tray_sides()
    house.blocked_stance = lambda xy: abs(side(xy) - slots[1]) < 0.02
    house.place_reach = CFG.deposits["tray"].reach + 0.03  # 6 cm short is out of reach
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    assert {t.released_in for t in house.things.values()} == {"tray"}
    second = [r for r in report.objects if r.placed][1]
    assert any("stance blocked" in f.reason for f in second.failures)
    places = _calls(house, "place")
    assert side(places[-1][0]) == pytest.approx(slots[0])  # released at the free stance
    assert len(places) <= 4  # one for the first; the second given up on its slot at once


def test_a_place_stance_that_meets_furniture_takes_the_next_slot_at_once() -> None:
    # seed-114 (2026-12-05): the tray's third slot (its far row) stood a leg of the
    # deposit table against the trunk; the task walked to the same stance again, stepped
    # in, refused, and put the cracker box down after four attempts
    house = FakeHouse(_two_cans())
    side, slots = _tray_sides()
    house.touching = lambda xy: abs(side(xy) - slots[1]) < 0.02
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    assert {t.released_in for t in house.things.values()} == {"tray"}
    second = [r for r in report.objects if r.placed][1]
    assert second.failures == []  # no attempt lost to it
    places = _calls(house, "place")
    assert len(places) == 2 and side(places[1][0]) == pytest.approx(slots[2])


def test_a_failed_put_down_does_not_unplace_the_object_placed_before() -> None:
    # paper-3 (2026-12-05): the given-up Rubik's cube's put-down failed (the arm blocked);
    # the next grasp was refused already_holding, and the coffee can placed before it was
    # taken for the object still held
    things = [
        Thing("tomato_soup_can", 1, (2.5, 1.4, 0.05)),
        Thing("baseball", 4, (1.5, 1.0, 0.037)),  # the farthest from the drawers: the last
        Thing("coffee_can", 2, (3.2, 1.9, 0.07)),
    ]
    house = FakeHouse(things)
    blocked = "arm_blocked: 0.122 rad from the trajectory end after timeout"
    n_places = CFG.task.max_attempts + 2  # every place of it, and both put-down tries
    house.place_failures = {"baseball": [blocked] * n_places}
    report = _task(house).run()
    assert _calls(house, "grasp")[-1] == "baseball"
    ball = _record(report, "baseball")
    assert ball.given_up and not ball.placed
    assert house.held is house.things[4]  # both put-downs failed: it is still held
    for label, tid in (("tomato_soup_can", 1), ("coffee_can", 2)):
        rec = _record(report, label)
        assert rec.placed and house.things[tid].released_in == "tray", label
        assert not any("still in the gripper" in f.reason for f in rec.failures), label


# ------------------------------------------------------------------ restarts


def _after_kill(house: FakeHouse, i: int = 0) -> list[tuple[str, object]]:
    """The calls after the ``i``-th killing request."""
    return house.calls[house.killed_at[i] + 1 :]


def _all_home(house: FakeHouse, report: TaskReport) -> None:
    """The trial ended, every object in its place, none given up."""
    assert report.outcome == "done", report.reason
    for t in house.things.values():
        assert t.released_in == _home(t.label), (t.label, t.released_in)
    assert not any(r.given_up for r in report.objects)
    assert house.sent_while_down == []  # nothing was asked of a service that was away


def test_locomotion_restart_while_carrying_stands_up_and_carries_on() -> None:
    house = FakeHouse(_things(), outages=[Outage("locomotion", "navigate_to", holding=True)])
    report = _task(house).run()
    _all_home(house, report)
    after = [w for w, _ in _after_kill(house)]
    # wait for it, stand up, forget the memory (its frame restarted), then carry on
    assert after[:3] == ["wait_for_services", "stand_up", "forget_objects"]
    assert after.index("stand_up") < after.index("navigate_to")
    carried = [r for r in report.objects if "locomotion restarted" in str(r.failures)]
    assert len(carried) == 1
    rec = carried[0]
    assert rec.placed and not rec.dropped and rec.restarts == 1 and rec.attempts == 0
    assert [f.reason for f in rec.failures] == ["locomotion restarted"]
    # the arm is moved to the carry posture first, and the carry goes on to its place
    assert after[3] == "move_to_posture"
    assert _calls(house, "grasp").count(rec.label) == 1


def test_locomotion_restart_that_drops_the_object_finds_it_again() -> None:
    house = FakeHouse(
        _things()[:1], outages=[Outage("locomotion", "navigate_to", holding=True, drops=True)]
    )
    report = _task(house).run()
    _all_home(house, report)
    rec = _record(report, "tomato_soup_can")
    assert rec.dropped and rec.placed and rec.attempts == 0
    assert [f.reason for f in rec.failures] == ["locomotion restarted"]
    assert _calls(house, "grasp") == ["tomato_soup_can"] * 2
    assert "stand_up" in [w for w, _ in _after_kill(house)]


@pytest.mark.parametrize(("request_name", "nth"), [("approach", 2), ("navigate_to", 12)])
def test_a_trip_gets_the_robot_up_and_the_task_goes_on(request_name: str, nth: int) -> None:
    # paper-3: a walk tripped locomotion's safety (roll -34 degrees); every request after
    # it failed at once, and the task ran through its objects and zones to "done"
    house = FakeHouse(_things())
    house.trip_at = {request_name: nth}
    report = _task(house).run()
    assert house.counts[f"trip:{request_name}"] >= nth  # it did trip
    assert report.trips == 1 and report.outcome == "done"
    assert ("stand_up", None) in house.calls
    _all_home(house, report)


def test_a_robot_that_keeps_tripping_ends_the_trial_with_the_reason() -> None:
    house = FakeHouse(_things())
    house.trip_at = {"navigate_to": 1}

    def trip_again(stand_up=house.stand_up) -> Outcome:
        out = stand_up()
        house.tripped, house.standing = True, False  # down again at once
        return out

    house.stand_up = trip_again  # type: ignore[method-assign]
    report = _task(house).run()
    assert report.outcome == "failed" and "tripped" in report.reason
    assert report.trips == CFG.task.max_trips + 1


def test_locomotion_restart_during_an_approach_looks_again_from_standing() -> None:
    house = FakeHouse(_things(), outages=[Outage("locomotion", "approach", nth=2)])
    report = _task(house).run()
    _all_home(house, report)
    after = [w for w, _ in _after_kill(house)]
    assert after[:3] == ["wait_for_services", "stand_up", "forget_objects"]
    # the remembered positions were in the old odom frame: it looked again before
    # approaching anything (a search posture, then an estimate from a fresh memory)
    first_probe = after.index("estimate_grasp")
    looks = [a for w, a in _after_kill(house)[:first_probe] if w == "move_to_posture"]
    assert set(looks) & {"floor_search", "table_search"}
    assert all(r.attempts == 0 for r in report.objects)
    assert len(report.objects) == len(house.things)  # one record per object, the same


def test_navigation_restart_waits_for_a_pose_and_walks_on() -> None:
    # killed while carrying an object; and while walking to a viewpoint
    for outage in (
        Outage("navigation", "navigate_to", holding=True),
        Outage("navigation", "navigate_to", nth=6, holding=False),
    ):
        house = FakeHouse(_things(), outages=[outage])
        report = _task(house).run()
        _all_home(house, report)
        killed = house.calls[house.killed_at[0]]
        after = _after_kill(house)
        assert after[0] == ("wait_for_services", ("navigation",))
        assert "stand_up" not in [w for w, _ in after]  # the robot stood all along
        assert "forget_objects" not in [w for w, _ in after]  # perception's memory is intact
        # the walk that was cut short is walked again, once localised (a viewpoint is not
        # skipped; a carry is not counted as a failure)
        assert next(a for w, a in after if w == "navigate_to") == killed[1]
        assert all(r.attempts == 0 for r in report.objects)
        assert all(not d.failures for d in report.drawers)


def test_perception_restart_looks_again_before_choosing_a_target() -> None:
    house = FakeHouse(_things(), outages=[Outage("perception", "estimate_grasp", nth=2)])
    task = _task(house)
    report = task.run()
    _all_home(house, report)
    killed = house.calls[house.killed_at[0]]
    after = _after_kill(house)
    # perception numbers its tracks afresh: only the grasps since name its tracks
    taken = task.progress().taken_tracks
    assert len(taken) == sum(w == "grasp" for w, _ in after) == len(report.objects) - 1
    assert set(taken) == {r.track_id for r in report.objects} - {report.objects[0].track_id}
    assert after[0] == ("wait_for_services", ("perception",))
    assert ("forget_objects", None) in after
    # a look in a search posture comes before the next estimate
    first_probe = [w for w, _ in after].index("estimate_grasp")
    assert {a for w, a in after[:first_probe] if w == "move_to_posture"} & {
        "floor_search",
        "table_search",
    }
    label = killed[1][0]  # type: ignore[index]
    rec = _record(report, label)  # the target keeps its one record
    assert rec.placed and rec.attempts == 0 and rec.restarts == 1
    assert [f.reason for f in rec.failures] == ["perception restarted"]


def test_perception_restart_after_every_zone_was_searched_searches_again() -> None:
    # the last estimate of the trial: every zone is searched by then, the objects left
    # are only in the memory that the restart wipes
    house = FakeHouse(_things())
    _task(house).run()
    n = len(_calls(house, "estimate_grasp"))
    house = FakeHouse(_things(), outages=[Outage("perception", "estimate_grasp", nth=n)])
    report = _task(house).run()
    _all_home(house, report)


def test_perception_restart_during_a_look_looks_again_from_the_same_viewpoint() -> None:
    house = FakeHouse(_things(), outages=[Outage("perception", "wait", nth=1)])
    report = _task(house).run()
    _all_home(house, report)
    viewpoint, posture, seeing = house.waits[0]
    assert not seeing  # it saw nothing during that look
    assert _after_kill(house)[0] == ("wait_for_services", ("perception",))
    # the next look is from the same viewpoint (not the next one), seeing
    assert house.waits[1] == (viewpoint, posture, True)


def test_manipulation_restart_moves_the_arm_to_a_known_posture_first() -> None:
    house = FakeHouse(_things(), outages=[Outage("manipulation", "grasp")])
    report = _task(house).run()
    _all_home(house, report)
    after = _after_kill(house)
    assert after[0] == ("wait_for_services", ("manipulation",))
    arm = [(w, a) for w, a in after if SERVES.get(w) == "manipulation"]
    assert arm[0] == ("move_to_posture", CFG.task.walk_posture)
    label = house.calls[house.killed_at[0]][1]
    rec = _record(report, label)  # type: ignore[arg-type]
    assert rec.placed and rec.attempts == 0
    assert [f.reason for f in rec.failures] == ["manipulation restarted"]


def test_manipulation_restart_while_holding_checks_the_grip_and_places_it() -> None:
    house = FakeHouse(_things()[:1], outages=[Outage("manipulation", "place")])
    report = _task(house).run()
    _all_home(house, report)
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and not rec.dropped and rec.attempts == 0
    after = _after_kill(house)
    carry = CFG.deposits[CATALOGUE.place_of("tomato_soup_can")].carry_posture
    arm = [(w, a) for w, a in after if SERVES.get(w) == "manipulation"]
    assert arm[0] == ("move_to_posture", carry) and arm[1][0] == "place"
    assert _calls(house, "grasp") == ["tomato_soup_can"]


def test_a_restart_does_not_give_up_an_object_on_its_last_attempt() -> None:
    last = CFG.task.max_attempts  # the estimate of its last attempt
    fails = {"baseball": ["grip_lost: slipped"] * (last - 1)}
    house = FakeHouse(
        _things()[3:4],
        grasp_failures=fails,
        outages=[Outage("perception", "estimate_grasp", nth=last)],
    )
    report = _task(house).run()
    _all_home(house, report)
    rec = _record(report, "baseball")
    assert rec.attempts == last - 1 and rec.restarts == 1
    assert [f.reason for f in rec.failures][-1] == "perception restarted"
    # with no restart free, the same restart is its last failure
    house = FakeHouse(
        _things()[3:4],
        grasp_failures={"baseball": ["grip_lost: slipped"] * (last - 1)},
        outages=[Outage("perception", "estimate_grasp", nth=last)],
    )
    report = _task(house, cfg=replace(CFG.task, restart_free=0)).run()
    assert _record(report, "baseball").given_up


def test_a_drawer_pull_cut_by_a_restart_is_pulled_again() -> None:
    house = FakeHouse([], outages=[Outage("manipulation", "open_drawer", nth=2)])
    report = _task(house).run()
    assert report.outcome == "done"
    assert all(d.ok for d in report.drawers) and len(report.drawers) == 3
    right = next(d for d in report.drawers if d.place == "drawer_right")
    assert [f.reason for f in right.failures] == ["manipulation restarted"]
    assert house.drawers["drawer_right"] == pytest.approx(CFG.drawers.open_distance)
    assert house.sent_while_down == []


def test_a_service_that_does_not_come_back_ends_the_trial() -> None:
    house = FakeHouse(_things(), outages=[Outage("navigation", "navigate_to", down_s=math.inf)])
    report = _task(house).run()
    assert report.outcome == "failed"
    assert "navigation did not run again" in report.reason


# ------------------------------------------------------------------ knowledge, geometry


def test_the_shipped_config_knows_every_class_and_place() -> None:
    problems = knowledge_problems(CLASSES, PLACES, CFG.task, CFG.drawers, CFG.search, CFG.deposits)
    assert problems == []
    bad_deposits = {k: v for k, v in CFG.deposits.items() if k != "tray"}
    bad = knowledge_problems(
        CLASSES, PLACES, CFG.task, CFG.drawers, CFG.search, bad_deposits, ("unicorn",)
    )
    assert any("no deposit spec for its place 'tray'" in p for p in bad)
    assert any("unicorn" in p for p in bad)
    with pytest.raises(ValueError, match="no place 'drawer_middle'"):
        _task(FakeHouse([]), cfg=replace(CFG.task, zones=("drawer_middle",)))


def _zone_points(z: Place) -> list[tuple[float, float]]:
    """A grid over the zone (its outer 2.5 % left out: the band's edges are exact)."""
    return [
        (
            z.target[0] + (i / 10 - 0.5) * z.size[0] * 0.95,
            z.target[1] + (j / 10 - 0.5) * z.size[1] * 0.95,
        )
        for i in range(11)
        for j in range(11)
    ]


@pytest.mark.parametrize("zone", [n for n, p in PLACES.items() if p.kind == "search_floor"])
def test_floor_viewpoints_see_the_whole_zone(zone: str) -> None:
    z = PLACES[zone]
    cfg = CFG.search["search_floor"]
    vps = zone_viewpoints(z.stand, z.target[:2], z.size, cfg)
    assert vps[0] == pytest.approx(z.stand)
    unseen = [p for p in _zone_points(z) if not any(sees(v, p, cfg) for v in vps)]
    assert unseen == []
    assert len(vps) <= 16
    for x, y, _ in vps:  # at the stand, or inside the zone (on the stand's line into it)
        inside = abs(x - z.target[0]) <= z.size[0] / 2 and abs(y - z.target[1]) <= z.size[1] / 2
        assert inside or (x, y) == pytest.approx(z.stand[:2])


def test_a_table_is_searched_from_its_stand_line_stepping_sideways() -> None:
    z = PLACES["living_table"]
    cfg = CFG.search["search_table"]
    vps = zone_viewpoints(z.stand, z.target[:2], z.size, cfg)
    assert len(vps) == 3
    assert all(v[1] == pytest.approx(z.stand[1]) and v[2] == z.stand[2] for v in vps)
    assert all(any(sees(v, p, cfg) for v in vps) for p in _zone_points(z))
    assert sorted(v[0] for v in vps) == pytest.approx(
        [z.stand[0] - cfg.shift, z.stand[0], z.stand[0] + cfg.shift]
    )


def test_frames_round_trip_and_a_grasp_is_carried_over_a_step() -> None:
    m2o = (0.3, -0.2, 0.4)
    p = (2.0, 1.0, 0.3)
    assert map_from_odom(m2o, odom_from_map(m2o, p)) == pytest.approx(p)
    base = BasePose(1.0, 2.0, 0.27, math.pi / 2)
    assert base_from_odom(base, (1.0, 2.5, 0.0)) == pytest.approx((0.5, 0.0, -0.27))
    assert odom_from_base(base, (0.5, 0.0, -0.27)) == pytest.approx((1.0, 2.5, 0.0))
    # seen 0.9 m ahead from the far stance; stepped 0.55 m in and turned a little
    then = BasePose(0.0, 0.0, 0.27, 0.0)
    now = BasePose(0.55, 0.0, 0.26, 0.1)
    pos, yaw = carried_over((0.9, 0.0, 0.13), 0.2, then, now)
    assert odom_from_base(now, pos) == pytest.approx(odom_from_base(then, (0.9, 0.0, 0.13)))
    assert pos[0] == pytest.approx(0.35 * math.cos(0.1)) and yaw == pytest.approx(0.1)
    assert pos[2] == pytest.approx(0.14)


# ------------------------------------------------------------------ the node's adapter


class _Cache:
    """A latest-value cache: ``get`` answers the message; ``age`` is how long ago (wall s)
    it arrived (just now unless the test says otherwise)."""

    def __init__(self, msg: object = None) -> None:
        self.msg = msg
        self.arrived = time.monotonic()

    def get(self) -> object:
        return self.msg

    def put(self, msg: object) -> None:
        self.msg, self.arrived = msg, time.monotonic()

    @property
    def age(self) -> float | None:
        return None if self.msg is None else time.monotonic() - self.arrived


def _running_watch(t: float = 0.0) -> ServiceWatch:
    """A watch that has seen the four services start and run (at wall time ``t``)."""
    watch = ServiceWatch(WATCHED, heartbeat_timeout=15.0)
    for s in WATCHED:
        watch.liveliness(s, True, t)
        watch.heartbeat(s, 0, "running", t)
    return watch


class _Handle:
    def __init__(self, accepted: bool, reason: str, result: m.ActionResult | None) -> None:
        self.accepted, self.reason, self._result = accepted, reason, result
        self.done = result is not None

    def result(self, timeout: float | None = None, poll_s: float = 2.0) -> m.ActionResult | None:
        return self._result

    def cancel(self, timeout: float = 1.0) -> bool:
        return True


class _Client:
    """An action client that answers every goal at once."""

    def __init__(self, result: m.Message | None = None, reject: str = "", fail: str = "") -> None:
        self.sent: list[m.Message] = []
        self.answer, self.reject, self.fail = result, reject, fail

    def send_goal(self, goal: m.Message, timeout: float = 2.0) -> _Handle:
        self.sent.append(goal)
        if self.reject:
            return _Handle(False, self.reject, None)
        status = "failed" if self.fail else "succeeded"
        res = m.ActionResult(stamp=0.0, goal_id="g", status=status, reason=self.fail,
                             result=self.answer)  # fmt: skip
        return _Handle(True, "", res)


def _bus_robot(config: BehaviorConfig = CFG, **clients: _Client):
    """A BusRobot on a stub node: map->odom (1, 0, 90 deg), the base at odom (2, 1, 0.27)
    heading 90 deg (so at map (0, 2) heading 180 deg); the four services run."""
    from types import SimpleNamespace

    from quadmanip.common.rotations import quat_from_yaw
    from quadmanip.services.behavior.node import CLIENTS, BusRobot

    node = SimpleNamespace(
        config=config,
        bus=SimpleNamespace(clock=lambda: 12.0),
        map_pose=_Cache(
            m.MapPose(
                stamp=12.0,
                x=0.0,
                y=2.0,
                yaw=math.pi,
                covariance=np.eye(3) * 1e-4,
                map_to_odom=[1.0, 0.0, math.pi / 2],
            )  # fmt: skip
        ),
        odometry=_Cache(
            m.Odometry(
                stamp=12.0,
                position=[2.0, 1.0, 0.27],
                orientation=quat_from_yaw(math.pi / 2),
                linear_velocity=np.zeros(3),
                angular_velocity=np.zeros(3),
            )  # fmt: skip
        ),
        tracks=_Cache(),
        payload=_Cache(),
        health=_Cache(),
        clients={name: clients.get(name, _Client()) for name in CLIENTS},
        watch=_running_watch(time.monotonic() - 10.0),
        pub_mode=SimpleNamespace(sent=[]),
        log=SimpleNamespace(lines=[]),
    )
    node.pub_mode.publish = node.pub_mode.sent.append
    node.log.info = lambda what, **kv: node.log.lines.append((what, kv))
    return BusRobot(node, lambda: False), node  # type: ignore[arg-type]


def test_the_adapter_speaks_each_services_frame() -> None:
    grasp_answer = m.GraspGoal(stamp=12.0, position=[0.4, 0.0, -0.2], yaw=0.3, width=0.06,
                               object_name="mug", mass=0.1, center=[0.45, 0.02, -0.22])  # fmt: skip
    clients = {"estimate_grasp": _Client(grasp_answer), "grasp": _Client(), "place": _Client()}
    robot, node = _bus_robot(**clients, approach=_Client())
    assert robot.pose() == pytest.approx((0.0, 2.0, math.pi))
    # a map point 1 m ahead of the robot (map (-1, 2)) is 1 m ahead in the body frame
    out = robot.place((-1.0, 2.0, 0.27), yaw=None)
    assert out.ok
    place = node.clients["place"].sent[0]
    assert place.position == pytest.approx([1.0, 0.0, 0.0]) and not place.turn
    # navigation's approach takes odom targets and headings
    robot.approach((-1.0, 2.0), 0.36, heading=math.pi)
    goal = node.clients["approach"].sent[0]
    assert goal.frame == "odom" and goal.target == pytest.approx([2.0, 2.0])
    assert goal.heading == pytest.approx(math.pi / 2) and not goal.face_target
    robot.approach((-1.0, 2.0), 0.36)
    assert node.clients["approach"].sent[1].face_target
    # a grasp 0.4 m ahead is at map (-0.4, 2); after a 0.1 m step in it is 0.3 m ahead
    out, plan = robot.estimate_grasp("mug", "gripper_camera", 7)
    assert out.ok and plan is not None
    assert plan.position_map == pytest.approx((-0.4, 2.0, 0.07))
    assert node.clients["estimate_grasp"].sent[0].track_id == 7
    node.odometry.msg = node.odometry.msg.replace(position=[2.0, 1.1, 0.27])
    assert robot.grasp(plan).ok
    sent = node.clients["grasp"].sent[0]
    assert sent.position == pytest.approx([0.3, 0.0, -0.2]) and sent.yaw == pytest.approx(0.3)
    assert sent.mass == 0.1 and sent.object_name == "mug"
    # the object's middle is carried over the step with the grasp point
    assert sent.center == pytest.approx([0.35, 0.02, -0.22])


def test_the_adapter_reports_rejections_failures_and_what_it_holds() -> None:
    robot, node = _bus_robot(
        grasp=_Client(reject="lateral_out_of_range: y 0.09"),
        place=_Client(fail="released_early: the object slipped"),
    )
    plan = GraspPlan((0.4, 0.0, -0.2), 0.0, "vertical", 0.05, "mug",
                     BasePose(2.0, 1.0, 0.27, math.pi / 2), (-0.4, 2.0, 0.07))  # fmt: skip
    out = robot.grasp(plan)
    assert not out.ok and out.rejected and out.reason.startswith("lateral_out_of_range")
    out = robot.place((-1.0, 2.0, 0.3))
    assert not out.ok and not out.rejected and "slipped" in out.reason
    # both are in the service's log with their reasons (a refusal is in no other log)
    assert [(kv["action"], kv["rejected"]) for _, kv in node.log.lines] == [
        ("grasp", True),
        ("place", False),
    ]
    assert "lateral_out_of_range" in node.log.lines[0][1]["reason"]
    assert robot.holding() is None  # nothing heard from manipulation yet
    node.payload.msg = m.Payload(stamp=12.0, mass=0.12, object_name="mug")
    assert robot.holding() is True
    node.payload.msg = m.Payload(stamp=13.0, mass=0.0)
    assert robot.holding() is False
    node.tracks.msg = m.ObjectTracks(
        stamp=12.0, ids=[5], labels=["mug"], centroids=[[2.0, 2.0, 0.04]], extents=[[0.1] * 3],
        confidences=[0.9], observations=[4], last_seen=[12.0], confirmed=[1],
        map_centroids=[[0.0, 0.0, 0.0]],
    )  # fmt: skip
    (seen,) = robot.objects()
    assert seen.track_id == 5 and seen.confirmed  # odom (2, 2) is map (-1, 2)
    assert seen.position == pytest.approx((-1.0, 2.0, 0.04))


# ------------------------------------------------------------------ the adapter and restarts


def _restart(watch: ServiceWatch, service: str) -> None:
    """``service`` is killed and restarted (now, wall time)."""
    now = time.monotonic()
    watch.liveliness(service, False, now)
    watch.liveliness(service, True, now)
    watch.heartbeat(service, 0, "running", now)


class _Hanging(_Client):
    """An action client whose goals are accepted; the first wait for the result is when
    ``on_wait`` happens (a kill). Then the goal never ends (its server died), or it
    succeeds when ``ends``."""

    def __init__(self, on_wait, ends: bool = False) -> None:
        super().__init__()
        self.on_wait, self.ends = on_wait, ends
        self.cancelled = 0

    def send_goal(self, goal: m.Message, timeout: float = 2.0) -> _Handle:
        self.sent.append(goal)
        client = self

        class Pending(_Handle):
            def result(self, timeout: float | None = None, poll_s: float = 2.0):
                if client.on_wait is not None:
                    client.on_wait()
                    client.on_wait = None
                    return None
                if client.ends:
                    return m.ActionResult(stamp=0.0, goal_id="g", status="succeeded")
                return None

            def cancel(self, timeout: float = 1.0) -> bool:
                client.cancelled += 1
                return False  # nobody there to acknowledge it

        return Pending(True, "", None)


def test_a_request_to_a_service_that_dies_ends_at_once_not_after_the_action_timeout() -> None:
    robot, node = _bus_robot()
    nav = _Hanging(lambda: node.watch.liveliness("navigation", False, time.monotonic()))
    node.clients["navigate_to"] = nav
    t0 = time.monotonic()
    out = robot.navigate_to(pose=(1.0, 2.0, 0.0))
    assert time.monotonic() - t0 < 1.0  # (action_timeout is 900 s)
    assert not out.ok and not out.rejected and out.interrupted == "navigation"
    assert "navigation went away" in out.reason and nav.cancelled == 1
    # a restart while a manipulation goal runs: locomotion's ends it too (the robot lies)
    arm = _Hanging(lambda: _restart(node.watch, "locomotion"))
    node.clients["move_to_posture"] = arm
    out = robot.move_to_posture("stow")
    assert out.interrupted == "locomotion" and arm.cancelled == 1
    # but perception's does not: a grasp does not need it
    grasp = _Hanging(lambda: _restart(node.watch, "perception"), ends=True)
    node.clients["grasp"] = grasp
    plan = GraspPlan((0.4, 0.0, -0.2), 0.0, "vertical", 0.05, "mug",
                     BasePose(2.0, 1.0, 0.27, math.pi / 2), (-0.4, 2.0, 0.07))  # fmt: skip
    assert robot.grasp(plan).ok and grasp.cancelled == 0
    assert robot.outages()["perception"] == 1


class _Moving(_Client):
    """A posture client whose goals end when ``done`` is set: the first ``fails`` of them
    failed, the rest succeeded."""

    def __init__(self, fails: int = 0) -> None:
        super().__init__()
        self.done, self.fails = threading.Event(), fails

    def send_goal(self, goal: m.Message, timeout: float = 2.0) -> _Handle:
        self.sent.append(goal)
        client, failed = self, len(self.sent) <= self.fails

        class Moving(_Handle):
            def result(self, timeout: float | None = None, poll_s: float = 2.0):
                if not client.done.wait(0.05 if timeout is None else min(timeout, 0.05)):
                    return None
                status, why = ("failed", "trajectory") if failed else ("succeeded", "")
                return m.ActionResult(stamp=0.0, goal_id="g", status=status, reason=why)

        return Moving(True, "", None)


def test_a_posture_sent_without_waiting_lets_a_walk_start_and_holds_the_next_arm_request() -> None:
    robot, node = _bus_robot()
    arm = _Moving()
    node.clients["move_to_posture"] = arm
    assert robot.move_to_posture("carry", wait=False).ok  # back while the arm moves
    assert robot.navigate_to(pose=(1.0, 2.0, 0.0)).ok  # the walk does not wait for it
    placed: list[Outcome] = []
    place = threading.Thread(target=lambda: placed.append(robot.place((-1.0, 2.0, 0.27))))
    place.start()
    time.sleep(0.3)
    assert placed == [] and node.clients["place"].sent == []  # the place waits for the arm
    arm.done.set()
    place.join(5.0)
    assert placed[0].ok and len(node.clients["place"].sent) == 1
    assert [g.posture for g in arm.sent] == ["carry"]
    # a look waits for the arm as such
    arm = _Moving()
    node.clients["move_to_posture"] = arm
    assert robot.move_to_posture("floor_search", wait=False).ok
    waited: list[Outcome] = []
    look = threading.Thread(target=lambda: waited.append(robot.wait_for_arm()))
    look.start()
    time.sleep(0.2)
    assert waited == []
    arm.done.set()
    look.join(5.0)
    assert waited[0].ok and robot.wait_for_arm().ok  # (nothing moving: at once)
    # a move that failed meanwhile is sent once more before the estimate, which goes on
    arm = _Moving(fails=1)
    arm.done.set()
    node.clients["move_to_posture"] = arm
    assert robot.move_to_posture("probe_floor", wait=False).ok
    robot.estimate_grasp("mug", "gripper_camera")
    assert [g.posture for g in arm.sent] == ["probe_floor", "probe_floor"]
    assert len(node.clients["estimate_grasp"].sent) == 1


def test_nothing_is_sent_to_a_service_that_is_away() -> None:
    robot, node = _bus_robot()
    node.watch.liveliness("locomotion", False, time.monotonic())
    out = robot.approach((1.0, 2.0), 0.4)
    assert out.interrupted == "locomotion" and "not running" in out.reason
    assert robot.move_to_posture("stow").interrupted == "locomotion"
    assert node.clients["approach"].sent == [] and node.clients["move_to_posture"].sent == []
    assert robot.outages()["locomotion"] == 1
    assert not robot.wait_for_services(["locomotion"], timeout=0.05)
    _restart(node.watch, "locomotion")
    assert robot.wait_for_services(["locomotion"], timeout=0.05)
    assert robot.approach((1.0, 2.0), 0.4).ok


def test_after_restarts_old_readings_are_not_trusted() -> None:
    robot, node = _bus_robot()
    node.payload.put(m.Payload(stamp=12.0, mass=0.12, object_name="mug"))
    assert robot.holding() is True
    node.watch.liveliness("manipulation", False, time.monotonic())
    assert robot.holding() is None  # nobody to say
    _restart(node.watch, "manipulation")
    assert robot.holding() is None  # the new manipulation has not said what it holds
    node.payload.put(m.Payload(stamp=13.0, mass=0.12, object_name="mug"))
    assert robot.holding() is True
    # navigation: its last pose is from before; a new one converging is not settled
    assert robot.localised()
    _restart(node.watch, "navigation")
    assert not robot.localised()
    node.map_pose.put(node.map_pose.msg.replace(status="converging"))
    assert not robot.localised()
    node.map_pose.put(node.map_pose.msg.replace(status="localized"))
    assert robot.localised()
    # perception: once forgotten, only what it saw from then on
    node.tracks.put(
        m.ObjectTracks(
            stamp=12.0,
            ids=[5, 6],
            labels=["mug", "bowl"],
            centroids=[[2.0, 2.0, 0.04]] * 2,
            extents=[[0.1] * 3] * 2,
            confidences=[0.9] * 2,
            observations=[4] * 2,
            last_seen=[11.0, 12.0],
            confirmed=[1, 1],
            map_centroids=[[0.0, 0.0, 0.0]] * 2,
        )  # fmt: skip
    )
    assert [o.track_id for o in robot.objects()] == [5, 6]
    robot.forget_objects()  # at robot time 12.0
    assert [o.track_id for o in robot.objects()] == [6]


class _Replies(_Cache):
    """Locomotion's health as it answers: the next message each time it is read."""

    def __init__(self, *msgs: m.Message) -> None:
        super().__init__(msgs[0])
        self.msgs = list(msgs)

    def get(self) -> object:
        if len(self.msgs) > 1:
            self.msg = self.msgs.pop(0)
        else:
            self.msg = self.msgs[0]
        return self.msg


def _health(phase: str, state: str = "ok", upright: bool = True) -> m.LocomotionHealth:
    reason = "" if state == "ok" else "fell"
    return m.LocomotionHealth(stamp=12.0, state=state, reason=reason, phase=phase,
                              upright=upright)  # fmt: skip


def test_after_a_locomotion_restart_the_robot_is_stood_up() -> None:
    robot, node = _bus_robot()
    _restart(node.watch, "locomotion")
    node.health = _Replies(_health("damp"), _health("standing_up"), _health("balance"))
    assert robot.stand_up().ok
    assert [msg.mode for msg in node.pub_mode.sent] == ["stand"]
    # tripped: recover first (stand would be refused)
    node.pub_mode.sent.clear()
    node.health = _Replies(_health("safe", "tripped"), _health("righting", "tripped", False),
                           _health("standing_up"), _health("balance"))  # fmt: skip
    assert robot.stand_up().ok
    assert [msg.mode for msg in node.pub_mode.sent] == ["recover"]


def test_standing_up_trusts_no_health_from_before_the_restart() -> None:
    quick = replace(CFG, node=replace(CFG.node, stand_timeout=0.2))
    robot, node = _bus_robot(config=quick)
    node.health.put(_health("balance"))  # the dead locomotion's last word
    time.sleep(0.01)
    _restart(node.watch, "locomotion")
    out = robot.stand_up()
    assert not out.ok and "no health" in out.reason
    node.watch.liveliness("locomotion", False, time.monotonic())
    out = robot.stand_up()
    assert not out.ok and out.interrupted == "locomotion"


def _by_a_table_leg(
    label: str, z: float, leg: tuple[float, float]
) -> tuple[TaskReport, list[float]]:
    """A run with ``label`` on the living table by its west end (2.1, 3.2, ``z``) and a
    leg at ``leg``: the report and the headings of the approaches to it."""
    things = _things()
    things[2] = Thing(label, 3, (2.1, 3.2, z), on_table=True)
    house = FakeHouse(things)
    house.furniture = [leg]
    report = _task(house).run()
    # (a square approach aims up to table_end_shift toward the table's middle)
    heads = [
        a[2]
        for what, a in house.calls
        if what == "approach" and math.dist(a[0][:2], (2.1, 3.2)) <= CFG.task.table_end_shift + 1e-9
    ]
    return report, heads


def test_a_tall_table_object_whose_step_in_meets_a_leg_is_probed_again_turned() -> None:
    # seed-115: a coffee can 23 cm from the kitchen table's end; the side probe's stance
    # 0.86 m back was clear, its step in to 0.36 m met the leg, four times, and the can
    # was given up
    # (the leg 5 cm nearer than in the test below: the stance's shift does not clear it)
    report, heads = _by_a_table_leg("coffee_can", 0.47, (2.0, 3.15))
    rec = _record(report, "coffee_can")
    assert rec.placed, rec.failures
    square = PLACES["living_table"].stand[2]
    assert heads[0] == pytest.approx(square)  # square first
    assert heads[-1] != pytest.approx(square)  # the grasp's step in, turned
    assert not any("step in" in f.reason for f in rec.failures)


def test_a_table_object_near_the_tables_end_is_stood_at_moved_toward_the_middle() -> None:
    # seed-124: a sugar box 23.5 cm in from the living table's end; every square step in
    # was stopped by the leg 3.8 cm inside the footprint, the slants too, and it was given
    # up. The square stance moves toward the table's middle (the grasp shifts the trunk
    # back), its axis table_end_clear in from the end, at most table_end_shift.
    report, heads = _by_a_table_leg("coffee_can", 0.47, (1.95, 3.15))
    rec = _record(report, "coffee_can")
    assert rec.placed and rec.failures == []
    square = PLACES["living_table"].stand[2]
    assert heads and all(h == pytest.approx(square) for h in heads)  # never turned
    table, c = PLACES["living_table"], CFG.task
    west_end = table.target[0] - table.size[0] / 2  # the object lies 0.1 m in from it
    assert c.table_end_clear - (2.1 - west_end) > c.table_end_shift  # the shift is capped
    task = _task(FakeHouse([]))
    near = ObjectRecord("coffee_can", 3, "tray", (2.1, 3.2, 0.47), t_found=0.0)
    assert task._square_target(near, near.position) == pytest.approx(
        (2.1 + c.table_end_shift, 3.2, 0.47)
    )
    # 0.23 m in: shifted until its axis stands table_end_clear in; the middle: not at all
    x = west_end + 0.23
    assert task._square_target(near, (x, 3.2, 0.47))[0] == pytest.approx(
        west_end + c.table_end_clear
    )
    assert task._square_target(near, (2.6, 3.2, 0.47))[0] == pytest.approx(2.6)
    near.table_heading = square + 0.35  # stood at a slant: no shift
    assert task._square_target(near, near.position)[0] == pytest.approx(2.1)


def test_a_table_object_by_a_leg_is_approached_turned_toward_the_tables_middle() -> None:
    # paper-5: a mug 13 cm in from the kitchen table's end; square to the table the
    # stance met the table's leg, four times, and the mug was given up
    report, heads = _by_a_table_leg("bowl", 0.43, (2.0, 3.1))
    assert _record(report, "bowl").placed
    table = PLACES["living_table"]
    assert heads[0] == pytest.approx(table.stand[2])  # square first
    # then turned at once: square again from the table's stand met the same leg
    # (seed-107: a sugar box, two square approaches stopped, 26 s each)
    assert heads[1] != pytest.approx(table.stand[2])
    ok = heads[-1]
    assert ok != pytest.approx(table.stand[2])
    # the stance it took lies toward the table's middle from the object, clear of the leg
    stance = (
        2.1 - CFG.task.probe_standoff * math.cos(ok),
        3.2 - CFG.task.probe_standoff * math.sin(ok),
    )
    assert stance[0] > 2.1 and math.dist(stance, (2.0, 3.1)) >= 0.35


def test_an_object_found_and_never_taken_up_says_why() -> None:
    # seed-116: a tennis ball found, never tried, and the report said nothing about why
    ball, can = Thing("tennis_ball", 7, (1.5, 1.3, 0.03)), Thing("tomato_soup_can", 8, CAN.position)
    house = FakeHouse([ball, can])
    task = _task(house)
    recs = {
        t.label: ObjectRecord(t.label, t.track_id, "green_box", t.position, t_found=0.0)
        for t in (ball, can)
    }
    task.report.objects.extend(recs.values())
    house.memory[7] = SeenObject(7, "tennis_ball", ball.position, confirmed=False)
    task._left_behind()
    assert [f.reason for f in recs["tennis_ball"].failures] == [
        "not taken up: its track 7 is not confirmed (confidence 1.00)"
    ]
    assert [f.reason for f in recs["tomato_soup_can"].failures] == [
        "not taken up: not in perception's memory at the end"
    ]


def _cracker_box_on_the_kitchen_table(
    xy: tuple[float, float], axis_deg: float
) -> tuple[FakeHouse, TaskReport]:
    """A cracker box standing on the kitchen table at ``xy``, its long axis at
    ``axis_deg`` in the map; the square stance (from the north, heading -90) sees it
    turned off the view."""
    things = _things()
    things[2] = Thing("cracker_box", 3, (*xy, 0.506), on_table=True)
    house = FakeHouse(things)
    house.long_axis["cracker_box"] = math.radians(axis_deg)
    return house, _task(house).run()


def test_a_long_box_turned_off_the_view_is_stood_at_end_on_and_taken() -> None:
    # seed-113: a cracker box near the kitchen table's west end, turned 75 deg off the
    # view, was probed four times from the square stance and given up
    house, report = _cracker_box_on_the_kitchen_table((6.96, 2.05), -14.6)
    rec = _record(report, "cracker_box")
    assert rec.placed, rec.failures
    assert len(rec.failures) == 1 and "narrow side seen turned" in rec.failures[0].reason
    # walked (the planner, around the table's corner) to a stance along its long side,
    # from the west end (its grasp stance 0.41 m back stands 0.19 m out from under the
    # table; the east end's would be in under it)
    refused = next(
        i
        for i, (what, a) in enumerate(house.calls)
        if what == "estimate_grasp" and a[0] == "cracker_box"
    )
    walk = next(a for what, a in house.calls[refused:] if what == "navigate_to")
    assert wrap(walk[2] - math.radians(-14.6)) == pytest.approx(0.0, abs=math.radians(1.0))
    assert walk[0] < PLACES["kitchen_table"].area[0]  # west of the table
    assert ("grasp", "cracker_box") in house.calls


def test_an_end_on_walk_goal_near_something_is_walked_farther_out_or_later() -> None:
    # seed-113: the end-on goal 0.86 m out was "too close to an obstacle", and the next
    # try stood square to the table again (four probes "turned -85 deg", given up)
    things = _things()
    box = Thing("cracker_box", 3, (6.96, 2.05, 0.506), on_table=True)
    things[2] = box
    house = FakeHouse(things)
    house.long_axis["cracker_box"] = math.radians(-14.6)
    h = math.radians(-14.6)
    out = CFG.task.probe_standoff + CFG.task.side_probe_back
    house.blocked_goals = [(6.96 - out * math.cos(h), 2.05 - out * math.sin(h))]
    report = _task(house).run()
    rec = _record(report, "cracker_box")
    assert rec.placed, rec.failures
    assert len(rec.failures) == 1  # the turned probe only; the blocked goal cost nothing
    walks = [
        a
        for what, a in house.calls
        if what == "navigate_to" and isinstance(a, tuple) and abs(wrap(a[2] - h)) < 0.02
    ]
    assert len(walks) == 2  # the blocked goal, then 0.25 m farther out
    assert math.dist(walks[1][:2], (6.96, 2.05)) == pytest.approx(out + 0.25, abs=1e-6)


def test_an_end_on_stance_stopped_by_furniture_is_not_turned_square_again() -> None:
    # seed-113 (second run): the end-on approach met the footprint guard, and the table
    # slants then stood it nearly square: four probes saw the box's wide side
    things = _things()
    things[2] = Thing("cracker_box", 3, (6.96, 2.05, 0.506), on_table=True)
    house = FakeHouse(things)
    house.long_axis["cracker_box"] = math.radians(-14.6)
    h = math.radians(-15.0)  # (perception's turn is in whole degrees)
    out = CFG.task.probe_standoff + CFG.task.side_probe_back
    stance = (6.96 - out * math.cos(h), 2.05 - out * math.sin(h))
    house.furniture = [(stance[0], stance[1] - 0.25)]
    report = _task(house).run()
    rec = _record(report, "cracker_box")
    assert not rec.placed
    square = PLACES["kitchen_table"].stand[2]
    refused = next(
        i
        for i, (what, a) in enumerate(house.calls)
        if what == "estimate_grasp" and a[0] == "cracker_box"
    )
    later = [
        a[2] for what, a in house.calls[refused:] if what == "approach" and a[0] == (6.96, 2.05)
    ]
    assert later and all(abs(wrap(x - h)) < 0.02 for x in later), later
    assert all(abs(wrap(x - square)) > 1.0 for x in later)


def test_a_long_box_whose_ends_lie_under_the_table_is_given_up_at_once() -> None:
    # seed-120: the box 0.35 m in from the table's west end, turned 68 deg off the view:
    # the end's grasp stance stands 3 cm out, the arm's mount under the top (three
    # grasps closed on nothing); one probe, then given up (not four, nor a walk there)
    house, report = _cracker_box_on_the_kitchen_table((7.097, 2.016), 21.6)
    rec = _record(report, "cracker_box")
    assert not rec.placed and rec.given_up
    assert len(rec.failures) == 1 and "no stance at its ends clear" in rec.failures[0].reason
    assert ("grasp", "cracker_box") not in house.calls


def test_an_object_whose_walk_goals_are_all_blocked_waits_while_others_are_taken_up() -> None:
    # seed-120: the living table's staging goals were "too close to an obstacle" (a soup
    # can's track left where it had been picked up); the tennis ball there spent its four
    # attempts in 0.3 s and was given up. Here every walk goal by the can is refused for
    # 20 s; the baseball, farther, is known too
    ball = Thing("baseball", 4, (4.0, 3.2, 0.037))
    house = FakeHouse([CAN, ball])
    house.at = (0.0, 1.4, 0.0)  # 2.5 m from the can: it is walked to
    for t in (CAN, ball):
        house.memory[t.track_id] = SeenObject(t.track_id, t.label, t.position)
    house.refuse_near_for = {"tomato_soup_can": 20.0}
    task = _task(house)
    assert task._choose_target().value == "approach" and task.target.label == "tomato_soup_can"
    can = task.target
    step = task._approach()
    assert step.value == "choose_target"  # not the same walk again at once
    assert len(can.failures) == 1 and "too close to an obstacle" in can.failures[0].reason
    assert can.wait_until == pytest.approx(house.t + CFG.task.blocked_wait)
    # the next object is the ball, though the can is nearer
    assert task._choose_target().value == "approach" and task.target.label == "baseball"
    # with nothing else left, the can is tried again at once (the task does not end on it)
    house.memory.pop(ball.track_id)
    assert task._choose_target().value == "approach" and task.target is can


def test_a_step_in_toward_a_place_out_of_reach_keeps_the_trunk_out_from_under_the_table() -> None:
    # a sugar box over the tray's far row was out of reach from the slot's stance; the
    # steps in put the LiDAR housing under the table top (full stack: the trunk tipped
    # 13 deg, the box stuck in the fingers). Near-row slots may be stepped toward, down to
    # the deposit's min_standoff; a far-row one is not, and the next free slot is tried
    # (here the slots are taken in list order: the far row's other).
    things = [*_two_cans(), Thing("sugar_box", 3, (3.6, 1.2, 0.09))]
    house = FakeHouse(things)
    dep, tray = CFG.deposits["tray"], PLACES["tray"]
    in_order = {**CFG.deposits, "tray": dataclasses.replace(dep, tall_above=0.0)}
    house.place_reach = dep.reach - 0.07  # only the steps in reach
    ahead = (math.cos(tray.stand[2]), math.sin(tray.stand[2]))
    standoffs = []
    real_place = house.place

    def place(position, yaw=None):
        at = house.at
        standoffs.append((tray.target[0] - at[0]) * ahead[0] + (tray.target[1] - at[1]) * ahead[1])
        return real_place(position, yaw)

    house.place = place  # type: ignore[method-assign]
    report = _task(house, deposits=in_order).run()
    assert min(standoffs) >= dep.min_standoff - 1e-3
    # two in the near row, reached by stepping in; the third object's far-row stances
    # each given up at once, without a step in, and it is not dropped onto another
    placed = [r for r in report.objects if r.placed]
    assert sorted(r.slot for r in placed) == [0, 1]
    (third,) = [r for r in report.objects if not r.placed]
    assert third.failures and all("under the furniture" in f.reason for f in third.failures)


def test_tall_objects_take_the_trays_near_row_and_the_cans_its_far_row_first() -> None:
    tray = CFG.deposits["tray"]
    tall, short = CLASSES["cracker_box"].height, CLASSES["tomato_soup_can"].height
    assert short < tray.tall_above < CLASSES["sugar_box"].height < tall
    near = [i for i, (_, toward) in enumerate(tray.slots) if toward == 0.0]
    far = [i for i, (_, toward) in enumerate(tray.slots) if toward < 0.0]
    assert set(tray.slot_order(tall)[:2]) == set(near)
    assert set(tray.slot_order(short)[:2]) == set(far)
    # a can after a box in the near row: the far slot not behind it
    behind = next(j for j in far if tray.slots[j][0] == tray.slots[near[0]][0])
    assert tray.slot_order(short, {near[0]})[0] == next(j for j in far if j != behind)
    # a box after the cans: the near row; everything taken: from the first again
    assert tray.slot_order(tall, set(far))[0] in near
    # a box after one can: the near slot not in front of it (paper-1, 2026-12-07)
    ahead = next(j for j in near if tray.slots[j][0] == tray.slots[far[0]][0])
    assert tray.slot_order(tall, {far[0]})[0] == next(j for j in near if j != ahead)
    assert tray.slot_order(tall, {far[1]})[0] == ahead
    assert tray.slot_order(tall, set(range(4))) == tray.slot_order(tall)
    # the full task: two cans, then the cracker box (which reaches the near row only)
    things = [*_two_cans(), Thing("cracker_box", 3, (3.6, 1.2, 0.11))]
    house = FakeHouse(things)
    report = _task(house).run()
    assert all(r.placed for r in report.objects)
    box_slot = _record(report, "cracker_box").slot
    assert box_slot in near
    # the box is not lowered in front of the first can (2 cm from it), nor the second
    # can behind the box (over it): it goes in in front of the first
    order = [a for c, a in house.calls if c == "grasp"]
    assert order[0] != "cracker_box" and _record(report, order[0]).slot in far
    by_side: dict[float, list[str]] = {}
    for name in order:
        by_side.setdefault(tray.slots[_record(report, name).slot][0], []).append(name)
    assert by_side[tray.slots[box_slot][0]] == ["cracker_box"]
    # the cracker box goes in turned across the robot (paper-1: along the heading its 16 cm
    # lay over the tray's near wall and a far-row can, and it stuck in the fingers); the
    # sugar box too (seed-132, seed-133: along the heading its 9 cm landed on the near
    # wall's top and it toppled off the table); the cans, round, as they are held
    assert CLASSES["sugar_box"].across(tray.across_above)
    assert CLASSES["cracker_box"].across(tray.across_above)
    assert CLASSES["coffee_can"].long_side > tray.across_above
    assert not CLASSES["coffee_can"].across(tray.across_above)
    assert not CLASSES["tomato_soup_can"].across(tray.across_above)
    box = tray.release_point(PLACES["tray"], _record(report, "cracker_box").slot)
    yaws = {tuple(round(v, 3) for v in pos[:2]): yaw for pos, yaw in _calls(house, "place")}
    assert yaws.pop(tuple(round(v, 3) for v in box[:2])) == pytest.approx(math.pi / 2)
    assert all(y == 0.0 for y in yaws.values())


def test_the_sugar_box_goes_into_the_tray_across_and_a_can_as_held() -> None:
    house = FakeHouse(
        [Thing("sugar_box", 1, (3.6, 1.2, 0.09)), Thing("coffee_can", 2, (3.0, 1.0, 0.07))]
    )
    report = _task(house).run()
    assert all(r.placed for r in report.objects)
    order = [a for c, a in house.calls if c == "grasp"]
    yaws = dict(zip(order, (yaw for _, yaw in _calls(house, "place")), strict=True))
    assert yaws == {"sugar_box": pytest.approx(math.pi / 2), "coffee_can": 0.0}


def test_a_tall_object_on_the_floor_is_approached_from_a_little_farther_back() -> None:
    # paper-1 (2026-12-06): the standing cracker box, 16 cm of it facing the robot, was
    # knocked onto its 16 x 21 cm face by an approach to 0.36 m; nothing grasps it so
    where = {"cracker_box": (3.0, 1.0, 0.105), "tomato_soup_can": (2.4, 1.6, 0.05)}
    house = FakeHouse([Thing(name, i, p) for i, (name, p) in enumerate(where.items(), 1)])
    report = _task(house).run()
    assert all(r.placed for r in report.objects)
    first: dict[str, float] = {}
    for target, standoff, _ in _calls(house, "approach"):
        for name, p in where.items():
            if math.dist(target[:2], p[:2]) < 0.05:
                first.setdefault(name, standoff)
    c = CFG.task
    assert first["cracker_box"] == pytest.approx(c.probe_standoff + c.tall_floor_back)
    assert first["tomato_soup_can"] == pytest.approx(c.probe_standoff)
    assert c.probe_standoff + c.tall_floor_back <= c.grasp_ahead[1]


@pytest.mark.parametrize(
    "why", ["no progress for 10 s, 14.6 cm and 17.8 deg off", "14.3 cm and 19.8 deg off"]
)
def test_an_approach_stopped_far_short_is_tried_from_the_next_side(why) -> None:
    # paper-1 (2026-12-06): the Rubik's cube 26 cm from the deposit table's end; three
    # approaches from the side the robot came from stopped 12-15 cm short (the table's
    # top, which the LiDAR does not see), each grasp refused 13-15 cm to the side
    cube = Thing("rubiks_cube", 1, (3.0, 1.0, 0.03))
    house = FakeHouse([cube])
    house.stalls = {"rubiks_cube": None}
    house.stall_why = why  # (the second: its approach ran out of time, paper-1 again)
    house.reach_bands = {"rubiks_cube": (0.3, 0.42)}  # (the stop leaves it 0.51 m off)
    report = _task(house).run()
    rec = _record(report, "rubiks_cube")
    assert rec.placed
    assert house.stalled == 1
    assert [f.reason for f in rec.failures] == [
        f"approach: blocked: the approach did not settle in time ({why})"
    ]


def test_a_place_refused_as_too_far_to_the_side_faces_the_release_point_again() -> None:
    # seed-124: after the stuck cracker box was opened over once more, the next place was
    # refused (a body shift of 9 cm, limit 6) and the attempt was lost
    house = FakeHouse(_things()[:1])
    side = Outcome(False, "lateral_out_of_range: needs a body shift of -0.092 m", rejected=True)
    house.place_failures = {"tomato_soup_can": [side]}
    report = _task(house).run()
    rec = _record(report, "tomato_soup_can")
    assert rec.placed and rec.failures == []
    places = [i for i, (what, _) in enumerate(house.calls) if what == "place"]
    assert len(places) == 2
    between = [what for what, _ in house.calls[places[0] : places[1]]]
    assert "approach" in between  # it stood square to the release point again


@pytest.mark.parametrize("why", ["no graspable candidate", "too wide"])
def test_a_tall_box_lying_on_a_table_is_probed_from_above_after_a_side_probe_finds_nothing(why):
    # paper-2 (2026-12-06): the sugar box, knocked onto its side on the kitchen table by a
    # grasp that closed on nothing (4.5 cm tall then); three side probes found "no
    # graspable candidate" and it was given up. seed-130 (2026-12-06): the sugar box
    # lying on the living table, its 17.5 cm long side to the robot: "too wide" three times
    def run(z: float) -> tuple[TaskReport, FakeHouse]:
        things = _things()
        things[2] = Thing("sugar_box", 3, (2.6, 3.3, z), on_table=True)
        house = FakeHouse(things)
        house.no_candidate_from = {"sugar_box": "front_camera"}
        house.no_candidate_why = why
        return _task(house).run(), house

    report, house = run(0.42)  # its middle 2 cm over the top: lying
    rec = _record(report, "sugar_box")
    assert rec.placed and rec.top_probe
    cams = [cam for label, cam in house.probed_with if label == "sugar_box"]
    assert cams[0] == "front_camera" and cams[-1] == "gripper_camera"
    assert [f.reason for f in rec.failures] == [f"estimate: {why}: sugar_box in front_camera"]
    report, house = run(0.49)  # standing: the side probe stays
    rec = _record(report, "sugar_box")
    assert not rec.placed and not rec.top_probe
    assert {cam for label, cam in house.probed_with if label == "sugar_box"} == {"front_camera"}


def test_a_viewpoint_by_an_object_standing_on_the_floor_is_moved_clear_of_it() -> None:
    # paper-4, 2026-12-07: the walk to a living-table view ended 0.38 m from a standing
    # cracker box, turned there on the spot for 2 s and knocked it flat
    house = FakeHouse(_things())
    task = _task(house)
    zone = PLACES["living_table"]
    task.zone = zone
    task.viewpoints = zone_viewpoints(
        zone.stand, (zone.target[0], zone.target[1]), zone.size, CFG.search[zone.kind]
    )
    vp = task.viewpoints[0]
    box = (vp[0] + 0.38 * math.cos(0.3), vp[1] + 0.38 * math.sin(0.3), 0.1)
    house.memory[9] = SeenObject(9, "cracker_box", box)
    assert task._go_to_viewpoint() == Step.LOOK
    goal = _calls(house, "navigate_to")[-1]
    assert math.dist(goal[:2], box[:2]) == pytest.approx(CFG.task.view_clearance)
    assert goal[2] == vp[2]  # the view's heading kept
    # moved straight away from the box: no farther than needed
    assert math.dist(goal[:2], vp[:2]) == pytest.approx(CFG.task.view_clearance - 0.38)


def test_a_point_clear_of_every_object_is_found_or_none_is() -> None:
    c = 0.55
    assert _clear_of((0.0, 0.0, 1.0), [(2.0, 0.0, 0.0)], c) == (0.0, 0.0, 1.0)
    # between two objects 1.4 m apart: the pose moves off both
    moved = _clear_of((0.1, 0.2, 0.0), [(-0.7, 0.0, 0.0), (0.7, 0.0, 0.0)], c)
    assert moved is not None
    assert min(math.dist(moved[:2], p[:2]) for p in ((-0.7, 0, 0), (0.7, 0, 0))) >= c - 1e-9
    # on a ring of objects closer together than the clearance: nowhere near it will do
    ring = [
        (0.4 * math.cos(a), 0.4 * math.sin(a), 0.0)
        for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)
    ]
    assert _clear_of((0.0, 0.0, 0.0), ring, c) is None


def test_a_far_row_stance_that_meets_the_table_takes_the_near_row_at_once() -> None:
    # paper-5, 2026-12-08: both far-row stances of the tray (the trunk's front 2 cm inside
    # the approach's guard from the deposit table's edge) stopped the coffee can's
    # approach; the next try stood at them again, and the can was given up
    house = FakeHouse([Thing("coffee_can", 2, (3.2, 1.9, 0.07))])
    tray = PLACES["tray"]
    h = tray.stand[2]

    def toward(p: Sequence[float]) -> float:  # toward the robot from the tray's target
        return -((p[0] - tray.target[0]) * math.cos(h) + (p[1] - tray.target[1]) * math.sin(h))

    house.touching = lambda xy: toward(xy) < 0.03  # the far row's release points
    report = _task(house).run()
    assert report.outcome == "done", report.reason
    assert house.things[2].released_in == "tray"
    assert _record(report, "coffee_can").failures == []
    ((spot, _),) = _calls(house, "place")
    assert toward(spot) > 0.05  # the near row
    tray_approaches = [
        a for a in _calls(house, "approach") if math.dist(a[0], tray.target[:2]) < 0.5
    ]
    assert len(tray_approaches) == 2  # the far row's, blocked, then the near row's


def test_a_given_up_object_is_put_down_clear_of_the_furniture_ahead() -> None:
    # paper-5, 2026-12-08: the coffee can given up at the tray's stance was put down
    # 0.36 m ahead, under the deposit table's top; the arm met it and the robot fell
    can = Thing("coffee_can", 2, (3.2, 1.9, 0.07))
    house = FakeHouse([can])
    task = _task(house)
    table = PLACES["deposit_table"]
    house.at = (7.0, 3.23, math.pi / 2)  # the tray's far-row stance, 0.22 m from the edge
    house.held = can
    task._put_down()
    ((spot, _),) = _calls(house, "place")
    clear = CFG.task.put_down_clearance
    assert not table.covers(spot, clear)
    (back,) = _calls(house, "approach")  # it backed off first, straight back
    assert house.at[1] < 3.23 - 0.3 and house.at[0] == pytest.approx(7.0, abs=1e-6)
    assert back[2] == pytest.approx(math.pi / 2)
    # in the open, it is put down where it stands
    house = FakeHouse([can])
    task = _task(house)
    house.at, house.held = (2.0, 1.5, 0.0), can
    task._put_down()
    assert _calls(house, "approach") == [] and len(_calls(house, "place")) == 1


def test_a_floor_object_where_a_table_objects_stance_stands_is_taken_up_first() -> None:
    # paper-5, 2026-12-08 (twice): a soup can on the floor where the square stance for the
    # bowl on the living table puts the feet; the bowl, nearer, was taken first from a
    # stance turned 60 deg off square, and given up
    bowl = Thing("bowl", 3, (2.88, 3.26, 0.43), on_table=True)
    can = Thing("tomato_soup_can", 1, (2.75, 2.60, 0.05))
    house = FakeHouse([bowl, can])
    house.at = (3.6, 3.0, math.pi)  # the bowl 0.77 m away, the can 0.94 m
    for t in (bowl, can):
        house.memory[t.track_id] = SeenObject(t.track_id, t.label, t.position)
    task = _task(house)
    assert task._choose_target() == Step.APPROACH
    assert task.target is not None and task.target.label == "tomato_soup_can"
    # the can elsewhere on the floor: the nearer bowl first, as ever
    house = FakeHouse([bowl, can])
    house.at = (3.6, 3.0, math.pi)
    house.memory[bowl.track_id] = SeenObject(bowl.track_id, bowl.label, bowl.position)
    house.memory[can.track_id] = SeenObject(can.track_id, can.label, (2.2, 2.2, 0.05))
    task = _task(house)
    task._choose_target()
    assert task.target is not None and task.target.label == "bowl"
    # and the whole trial takes both
    house = FakeHouse([bowl, can])
    house.at = (3.6, 3.0, math.pi)
    report = _task(house).run()
    assert report.outcome == "done" and all(r.placed for r in report.objects)
