"""The navigate-to behaviour: plan, follow, re-plan, recover, and say how it ended.

A small state machine over the planner (:mod:`.global_planner`), the path follower
(:mod:`.path_follower`) and the costmap (:mod:`.costmap`), stepped by the node at its
control rate with the robot's map pose. It owns nothing but decisions:

* ``follow``: re-plan every ``replan_period`` and at once when the path ahead crosses a
  lethal cell (an obstacle that is not in the map) or enters the inscribed zone; the
  follower regulates speed near obstacles and stops when its collision check fires.
* ``recover`` when the follower is blocked, no plan is found, or the robot makes no
  progress for ``progress_window``: stop and let the obstacle layer see again, back up if
  the space behind is free, turn in place, re-plan. A bounded number of attempts and an
  overall deadline (``give_up_after``, stopped once the robot got ``recovered_distance``
  away) end it ``blocked`` with the last reason: Nav2's
  users most often report recoveries that never trigger or never end.
* A goal the static map itself cannot reach ends ``no_path`` at once.

Outcomes and reasons follow :data:`quadmanip.common.messages.NAV_OUTCOMES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from quadmanip.services.navigation.costmap import INSCRIBED, LETHAL, UNKNOWN, Costmap
from quadmanip.services.navigation.global_planner import (
    START_IN_OBSTACLE,
    PlannerConfig,
    PlanResult,
    path_cost,
    path_headings,
    plan_path,
)
from quadmanip.services.navigation.grid import Pose2, wrap
from quadmanip.services.navigation.path_follower import (
    FollowerConfig,
    PathFollower,
    costmap_collision_check,
)
from quadmanip.services.navigation.standing_nudge import NudgeConfig

__all__ = ["NavStep", "Navigator", "NavigatorConfig", "path_length"]


@dataclass(frozen=True)
class NavigatorConfig:
    """Re-planning and recovery rules (times in s of robot time)."""

    replan_period: float = 1.0
    progress_window: float = 8.0  # s without getting progress_distance closer: recover
    progress_distance: float = 0.1
    max_recoveries: int = 3
    recovery_wait: float = 1.0  # s standing still so the LiDAR refreshes the obstacles
    backup_distance: float = 0.2  # m
    backup_speed: float = 0.15  # m/s
    turn_angle: float = math.radians(60)  # per recovery, alternating sides
    turn_rate: float = 0.6  # rad/s
    give_up_after: float = 25.0  # s from the first recovery: then ``blocked``
    # m: a robot this far from where its last recovery began has got out: the give-up
    # clock stops (the recoveries still count). A walk out of a pocket of floor objects
    # and round them, 3 m on and walking freely, was ended "blocked" 25 s after it.
    recovered_distance: float = 1.0
    # A walk that starts beside furniture (after a grasp or a place at a table) met it
    # with its first turn, and the recovery's wait and turn cost ~3.5 s (four times in
    # seed-114, 2026-12-05): blocked within this long of the start, before any recovery,
    # it only steps back (once), and then follows its path.
    start_window: float = 2.0
    path_check_ahead: float = 2.0  # m of path ahead checked for new obstacles
    escape_speed: float = 0.12  # m/s: stepping out of the inscribed zone, away from obstacles
    escape_time: float = 4.0  # s at most per escape
    # m: a periodic re-plan replaces a free path only when this much shorter (a near-equal
    # route around a table, re-chosen each second, turned the robot back and forth)
    switch_margin: float = 0.3
    # s: obstacle marks about a refused goal that no scan has made for this long are
    # forgotten and the plan made again (see Navigator._plan_past_stale_marks)
    stale_obstacle_age: float = 20.0


@dataclass(frozen=True)
class NavStep:
    """One control step: the body velocity command, the state (``active`` or an outcome),
    the reason, the distance left along the path and a new path when it changed."""

    vx: float
    vy: float
    wz: float
    state: str
    reason: str = ""
    distance_left: float = math.inf
    new_path: np.ndarray | None = None
    mode: str = "follow"


def path_length(path: np.ndarray) -> float:
    """Length (m) of a polyline (N, 2)."""
    return float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if len(path) > 1 else 0.0


def remaining_path(path: np.ndarray, pose: Pose2) -> np.ndarray:
    """What is left of ``path`` from ``pose``: from the pose to its nearest vertex, then
    along the rest."""
    d = np.hypot(*(path - np.asarray(pose[:2])).T)
    return np.vstack([np.asarray(pose[:2], dtype=float)[None], path[int(np.argmin(d)) :]])


@dataclass
class _Goal:
    pose: Pose2
    tol_xy: float
    tol_yaw: float
    ignore_yaw: bool
    t_start: float
    pass_through: bool = False  # done once within the tolerances, still walking
    path: np.ndarray | None = None
    t_plan: float = -math.inf
    best_distance: float = math.inf
    t_progress: float = 0.0
    recoveries: int = 0
    t_first_recovery: float | None = None
    recovery: list[tuple[str, float, float]] = field(default_factory=list)  # (kind, until, arg)
    recovery_origin: Pose2 | None = None
    last_reason: str = ""
    escape_until: float = -math.inf
    stepped_back: bool = False  # the start's step back from what the first move met
    modes: dict[str, float] = field(default_factory=dict)  # s of robot time per step mode
    objects_off: bool = False  # the floor objects' layer left out for this goal


class Navigator:
    """Goal in, velocity commands out (see the module docstring)."""

    def __init__(
        self,
        config: NavigatorConfig | None = None,
        follower: FollowerConfig | None = None,
        planner: PlannerConfig | None = None,
        nudge: NudgeConfig | None = None,
    ) -> None:
        self.config = config or NavigatorConfig()
        self.follower_config = follower or FollowerConfig()
        self.planner_config = planner or PlannerConfig()
        self.follower = PathFollower(self.follower_config, nudge=nudge)
        self.goal: _Goal | None = None
        self.plan_ms: list[float] = []
        self._t_last = -math.inf
        # where the last goal's time went (s per step mode: rotate, track, final, settle,
        # backup, turn, wait, escape), for the log line that ends it
        self.last_modes: dict[str, float] = {}
        self.notice = ""  # a decision the node should log once (then clears it)

    # ------------------------------------------------------------------ goals
    def start(
        self,
        goal: Pose2,
        now: float,
        pose: Pose2,
        costmap: Costmap,
        static_costmap: Costmap | None = None,
        tol_xy: float = 0.05,
        tol_yaw: float = math.radians(3),
        ignore_yaw: bool = False,
        pass_through: bool = False,
    ) -> str:
        """Check and accept a goal; "" when accepted, else the reason (``no_path: ...``
        when even the static map has no way there). ``pass_through``: reached once within
        the tolerances, still under way (``NavigateGoal.pass_through``)."""
        self.last_modes = {}
        if not all(math.isfinite(v) for v in goal):
            return "rejected: the goal is not finite"
        ref = static_costmap or costmap
        if not ref.geometry.contains(goal[0], goal[1]):
            return "rejected: the goal is off the map"
        if not bool(ref.is_traversable(np.array([goal[:2]]))[0]):
            c = int(ref.cost_at(np.array([goal[:2]]))[0])
            what = "in an obstacle" if c == LETHAL else "too close to an obstacle or unknown"
            return f"rejected: the goal is {what}"
        if static_costmap is not None:
            res = plan_path(static_costmap, pose[:2], goal[:2], self.planner_config)
            # a start in an obstacle of the map is where the robot stands all the same (a
            # trunk under a table top the LiDAR does not see): the walk steps out first, by
            # its escape and recoveries, rather than every goal refused at once (paper-2,
            # 2026-12-07: 40 walks refused within 20 s, six objects given up)
            if not res.ok and res.reason != START_IN_OBSTACLE:
                return f"no_path: {res.reason} (on the map alone)"
        self.goal = _Goal(
            goal, tol_xy, tol_yaw, ignore_yaw, now, pass_through=pass_through, t_progress=now
        )
        self.follower.reset()
        return ""

    def cancel(self) -> None:
        """Forget the goal (the node sends the stop)."""
        if self.goal is not None:
            self.last_modes = self.goal.modes
        self.goal = None

    @property
    def active(self) -> bool:
        """Whether a goal is being pursued."""
        return self.goal is not None

    # ------------------------------------------------------------------ control
    def _plan(self, g: _Goal, now: float, pose: Pose2, costmap: Costmap) -> PlanResult:
        res = plan_path(costmap, pose[:2], g.pose[:2], self.planner_config)
        self.plan_ms.append(res.ms)
        g.t_plan = now
        if res.ok:
            g.path = res.path
        else:
            g.last_reason = res.reason
        return res

    def _plan_past_stale_marks(
        self, g: _Goal, now: float, pose: Pose2, costmap: Costmap, res: PlanResult
    ) -> PlanResult:
        """A goal refused for the obstacle layer's marks that no scan has confirmed for
        ``stale_obstacle_age``: those marks are forgotten and the plan made again; the
        LiDAR marks them anew if they are still there when the robot comes near. Else
        ``res`` with the marks' age in its reason. (paper-3, 2026-12-06: a table's stand,
        free on the map, was refused ten times from the far side of the house, and the
        screwdriver on that table was given up unapproached.)"""
        reach = costmap.config.robot_radius + costmap.geometry.resolution
        xy = (g.pose[0], g.pose[1])
        age = costmap.obstacle_age_near(xy, reach, now)
        if age is None:
            return res
        n = costmap.forget_unseen_near(xy, reach, now - self.config.stale_obstacle_age)
        if not n:
            return replace(res, reason=f"{res.reason} (LiDAR marks {age:.0f} s old)")
        self.notice = f"forgot {n} obstacle cells by the goal, unseen for {age:.0f} s"
        return self._plan(g, now, pose, costmap)

    def _cost(self, path: np.ndarray, costmap: Costmap) -> float:
        return path_cost(costmap, path, self.planner_config)

    def _path_blocked(self, g: _Goal, pose: Pose2, costmap: Costmap) -> bool:
        if g.path is None or len(g.path) < 2:
            return False
        d = np.hypot(*(g.path - np.asarray(pose[:2])).T)
        i0 = int(np.argmin(d))
        ahead = g.path[i0:]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ahead, axis=0).T))])
        ahead = ahead[s <= self.config.path_check_ahead]
        c = costmap.cost_at(ahead)
        # the inscribed zone counts once the path has left it (a start inside escapes): a
        # floor object confirmed beside a path planned before it, its disc short of the
        # path's points, closes it as surely (paper-1's first walk: a baseball 9 cm off;
        # the path was kept, every command stopped at the zone, three recoveries, 19 s)
        entered = (c >= INSCRIBED) & (c != UNKNOWN) & (np.cumsum(c < INSCRIBED) > 0)
        return bool(np.any((c == LETHAL) | entered))

    def _end(self, state: str, reason: str, distance: float = math.inf) -> NavStep:
        self.cancel()
        return NavStep(0.0, 0.0, 0.0, state, reason, distance)

    def _start_recovery(self, g: _Goal, now: float, pose: Pose2, costmap: Costmap) -> NavStep:
        cfg = self.config
        if g.t_first_recovery is None:
            g.t_first_recovery = now
        if g.recoveries >= cfg.max_recoveries:
            return self._end("blocked", f"blocked: {g.last_reason} after {g.recoveries} recoveries")
        g.recoveries += 1
        sign = 1.0 if g.recoveries % 2 else -1.0
        steps = [("wait", now + cfg.recovery_wait, 0.0)]
        t = now + cfg.recovery_wait
        # standing in an obstacle (the trunk walked in under a table top the LiDAR does not
        # see), back out as far as it takes, up to three backups: the way it came in
        inside = not costmap.footprint_free(pose)
        for k in (1, 2, 3) if inside else (1,):
            if costmap.footprint_free(self._back_pose(pose, k * cfg.backup_distance)):
                t += k * cfg.backup_distance / cfg.backup_speed
                steps.append(("backup", t, 0.0))
                break
        turned = (pose[0], pose[1], float(wrap(pose[2] + sign * cfg.turn_angle)))
        if costmap.footprint_free(turned):
            t += cfg.turn_angle / cfg.turn_rate
            steps.append(("turn", t, sign))
        g.recovery = steps
        g.recovery_origin = pose
        self.follower.reset()
        return NavStep(0.0, 0.0, 0.0, "active", f"recovering ({g.recoveries}): {g.last_reason}")

    def _back_pose(self, pose: Pose2, distance: float | None = None) -> Pose2:
        """``pose`` moved ``distance`` (default ``backup_distance``) straight back."""
        d = self.config.backup_distance if distance is None else distance
        return (pose[0] - d * math.cos(pose[2]), pose[1] - d * math.sin(pose[2]), pose[2])

    def _step_back(self, g: _Goal, now: float, pose: Pose2, costmap: Costmap) -> NavStep | None:
        """``backup_distance`` straight back, when free (``start_window``); None if not."""
        cfg = self.config
        back = self._back_pose(pose)
        if not costmap.footprint_free(back):
            return None
        g.recovery = [("backup", now + cfg.backup_distance / cfg.backup_speed, 0.0)]
        g.recovery_origin = pose
        self.follower.reset()
        return NavStep(0.0, 0.0, 0.0, "active", "stepping back: the first move meets an obstacle")

    def step(
        self, now: float, pose: Pose2, costmap: Costmap, standing: bool | None = None
    ) -> NavStep:
        """One control step at robot time ``now`` with the robot's map pose; ``standing``:
        whether locomotion stands (the final alignment's nudges; None: unknown)."""
        dt = min(max(now - self._t_last, 1e-3), 0.2) if self._t_last > -math.inf else None
        self._t_last = now
        g = self.goal
        if g is None:
            return NavStep(0.0, 0.0, 0.0, "idle")
        step = self._step(g, now, pose, costmap, standing, dt)
        if dt is not None:
            g.modes[step.mode] = g.modes.get(step.mode, 0.0) + dt
        return step

    def _step(
        self,
        g: _Goal,
        now: float,
        pose: Pose2,
        costmap: Costmap,
        standing: bool | None,
        dt: float | None,
    ) -> NavStep:
        cfg = self.config
        if g.t_first_recovery is not None and now - g.t_first_recovery > cfg.give_up_after:
            return self._end("blocked", f"blocked: {g.last_reason} for {cfg.give_up_after:.0f} s")
        # ---- a recovery in progress
        while g.recovery and now >= g.recovery[0][1]:
            g.recovery.pop(0)
        if g.recovery:
            kind, _, arg = g.recovery[0]
            if kind == "backup":
                return NavStep(-cfg.backup_speed, 0.0, 0.0, "active", "recovery: backing up",
                               mode="backup")  # fmt: skip
            if kind == "turn":
                return NavStep(0.0, 0.0, arg * cfg.turn_rate, "active", "recovery: turning",
                               mode="turn")  # fmt: skip
            return NavStep(0.0, 0.0, 0.0, "active", "recovery: waiting", mode="wait")
        # ---- standing too close to an obstacle (a tracking error, an obstacle that moved
        # in): step straight away from it first; the follower's checks would refuse to move
        esc = self._escape(g, now, pose, costmap)
        if esc is not None:
            return esc
        new_path = None
        # ---- (re)plan
        blocked = self._path_blocked(g, pose, costmap)
        if g.path is None or now - g.t_plan >= cfg.replan_period or blocked:
            kept = None if blocked else g.path
            res = self._plan(g, now, pose, costmap)
            if res.reason == "no path" and costmap.objects.any():
                # the discs of the floor objects perception has seen, inflated like walls
                # by the robot's radius, closed every way (seed-116: a brick and a Rubik's
                # cube 0.55 m apart before the doorway cut the living room off the kitchen;
                # the robot stood trapped, every walk "no path after 3 recoveries"): for
                # this goal the path may pass them as closely as the walls allow. The legs
                # pass beside (or over) a low object where the planner's disc allows none.
                costmap.set_objects([])
                g.objects_off = True
                self.notice = "no way around the floor objects: walking without their layer"
                res = self._plan(g, now, pose, costmap)
            if not res.ok and res.reason.startswith("goal"):
                res = self._plan_past_stale_marks(g, now, pose, costmap, res)
            if not res.ok:
                g.path = None
                if res.reason.startswith("goal"):
                    # what the LiDAR now sees covers the goal: backing up will not help
                    return self._end("blocked", f"blocked: {res.reason}")
                return self._start_recovery(g, now, pose, costmap)
            if kept is not None and self._cost(res.path, costmap) > (
                self._cost(remaining_path(kept, pose), costmap) - cfg.switch_margin
            ):
                g.path = kept  # still free and about as cheap: keep going the same way
            else:
                new_path = res.path
                if blocked:
                    # the way round is longer than what was left: progress counts along
                    # it (within the same window: a path re-planned again and again is no
                    # progress)
                    g.best_distance = math.inf
        assert g.path is not None
        clearance = float(costmap.clearance(np.array([pose[:2]]))[0])
        self.follower.collision = costmap_collision_check(costmap)
        cmd = self.follower.command(
            pose,
            g.path,
            None if g.ignore_yaw else g.pose[2],
            clearance,
            xy_tol=g.tol_xy,
            yaw_tol=g.tol_yaw,
            dt=dt,
            standing=standing,
            pass_through=g.pass_through,
        )
        if cmd.done:
            return self._end("reached", "reached", 0.0)
        if cmd.blocked:
            g.last_reason = "an obstacle in the way"
            early = now - g.t_start < cfg.start_window and g.recoveries == 0
            if early and not g.stepped_back:
                g.stepped_back = True
                step = self._step_back(g, now, pose, costmap)
                if step is not None:
                    return step
            return self._start_recovery(g, now, pose, costmap)
        # ---- progress watchdog (not while the follower settles within the tolerances:
        # a bounded wait to stand and nudges)
        if g.best_distance == math.inf:  # a new way round: measured from here, same clock
            g.best_distance = cmd.distance_left
        elif cmd.distance_left < g.best_distance - cfg.progress_distance or cmd.mode == "settle":
            g.best_distance = cmd.distance_left
            g.t_progress = now
            o = g.recovery_origin
            if (
                o is not None
                and math.hypot(pose[0] - o[0], pose[1] - o[1]) > cfg.recovered_distance
            ):
                g.t_first_recovery = g.recovery_origin = None
        elif now - g.t_progress > cfg.progress_window:
            g.last_reason = f"no progress for {cfg.progress_window:.0f} s"
            g.t_progress = now
            return self._start_recovery(g, now, pose, costmap)
        return NavStep(cmd.vx, cmd.vy, cmd.wz, "active", cmd.mode, cmd.distance_left,
                       new_path, cmd.mode)  # fmt: skip

    def _escape(self, g: _Goal, now: float, pose: Pose2, costmap: Costmap) -> NavStep | None:
        cfg = self.config
        xy = np.array([pose[:2]])
        inside = int(costmap.cost_at(xy)[0]) in (INSCRIBED, LETHAL)  # not unknown (255)
        if not inside:
            g.escape_until = -math.inf
            return None
        if g.escape_until == -math.inf:
            g.escape_until = now + cfg.escape_time
            self.follower.reset()
        if now > g.escape_until:
            return None  # could not get out: let the follower and the recoveries try
        h = 0.5 * costmap.geometry.resolution
        d = costmap.clearance(np.array([[pose[0] + h, pose[1]], [pose[0] - h, pose[1]],
                                        [pose[0], pose[1] + h], [pose[0], pose[1] - h]]))  # fmt: skip
        grad = np.array([d[0] - d[1], d[2] - d[3]])
        n = float(np.hypot(*grad))
        if n < 1e-9:
            return None
        gx, gy = grad / n
        c, s = math.cos(pose[2]), math.sin(pose[2])
        vx, vy = cfg.escape_speed * (c * gx + s * gy), cfg.escape_speed * (-s * gx + c * gy)
        return NavStep(vx, vy, 0.0, "active", "escaping: too close to an obstacle", mode="escape")

    def path_poses(self) -> np.ndarray | None:
        """The current path as poses (N, 3) with headings (for publishing)."""
        g = self.goal
        if g is None or g.path is None:
            return None
        return np.column_stack([g.path, path_headings(g.path)])
