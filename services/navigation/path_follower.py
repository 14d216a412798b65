"""Path following for a legged base: regulated pure pursuit (Macenski et al., 2023, the
controller Nav2 ships) with the legged robot's extras.

- Pure pursuit steers at a look-ahead point on the path (the look-ahead grows with speed).
- A large heading error (> ``rotate_threshold``) is removed first by turning in place:
  a quadruped turns on the spot at no cost, and arcing through a doorway would not fit.
- The speed is regulated down on tight curvature, near obstacles (the clearance given
  to it) and towards the end of the path; commands change no faster than the
  acceleration limits (the gait tracks steps in the command sluggishly anyway).
- Near the goal a holonomic final alignment (vx, vy, wz on the pose error in the base
  frame) brings the robot within the tolerances, with a minimum speed so small commands
  are not lost in the gait's deadband; ``done`` once within them. Told that the robot
  stands near the goal, it finishes by standing nudges (standing_nudge.py) instead of
  stop-and-go trots, which moved the robot 2-6 cm about a goal for 8 s without meeting
  a 3 cm / 2 degree tolerance (one goal of 50 missed that way).
- A collision check projects the command ``collision_horizon`` seconds ahead; a command
  that would take the robot into lethal cost (see ``costmap_collision_check``) is slowed
  (``collision_slowdowns``: a shorter projection round a corner the look-ahead cut), and
  the robot stops when even the slowest meets it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.costmap import INSCRIBED, LETHAL, Costmap
from quadmanip.services.navigation.grid import Pose2, compose, invert, wrap
from quadmanip.services.navigation.standing_nudge import NudgeConfig, StandingNudge

__all__ = [
    "CollisionCheck",
    "FollowCommand",
    "FollowerConfig",
    "PathFollower",
    "costmap_collision_check",
    "project_motion",
]

CollisionCheck = Callable[[Pose2, np.ndarray], bool]
"""(current pose, projected poses (K, 3)) -> whether the projected motion collides."""


@dataclass(frozen=True)
class FollowerConfig:
    """Path follower parameters (limits within locomotion's vx 0.9, vy 0.4, wz 1.6)."""

    dt: float = 0.05  # s: control period (when ``command`` is not told otherwise)
    max_vx: float = 0.8
    max_vy: float = 0.3
    max_wz: float = 1.4
    max_ax: float = 1.0  # m/s^2
    max_ay: float = 0.8  # m/s^2
    max_aw: float = 3.0  # rad/s^2
    lookahead_time: float = 1.0  # s: look-ahead = speed x this, clamped below
    lookahead_min: float = 0.3
    lookahead_max: float = 0.7
    rotate_threshold: float = math.radians(40)  # turn in place above this heading error
    rotate_exit: float = math.radians(20)  # ... until it is below this
    rotate_gain: float = 3.0  # 1/s
    # m/s toward the path while turning in place, where the clearance is above
    # ``slow_clearance`` (a walk's first turn: 1.4-2.9 s of standing still per walk on the
    # navigation bench); 0: turn on the spot
    rotate_walk_speed: float = 0.3
    regulation_radius: float = 0.9  # m: turn radii below this scale the speed down
    slow_clearance: float = 0.35  # m: clearances below this scale the speed down
    stop_clearance: float = 0.1  # m: ... to min_speed at this clearance
    approach_gain: float = 1.0  # 1/s: speed <= this x distance left
    min_speed: float = 0.08  # m/s: the regulated speed's floor while tracking
    final_distance: float = 0.4  # m: the holonomic final alignment takes over here
    final_gain: float = 3.0  # 1/s, on the predicted stop error (overdamped with the lag)
    final_yaw_gain: float = 4.0  # 1/s, likewise (critically damped at lag 0.25 s)
    final_max_speed: float = 0.4
    final_min_speed: float = 0.03  # m/s: above the gait's deadband
    final_min_wz: float = 0.06  # rad/s
    xy_tolerance: float = 0.05
    yaw_tolerance: float = math.radians(3)
    response_lag: float = 0.25  # s: the gait's velocity time constant (stopping distance)
    collision_horizon: float = 0.5  # s
    # A command whose projection meets an obstacle is tried again at these shares of
    # itself (same curvature, a shorter projection) before the walk counts as blocked:
    # pure pursuit cuts a corner by its look-ahead, and at full speed the projection of a
    # doorway's or a table leg's corner ended the walk in a recovery (backing up, waiting,
    # turning: 4-6 s each, 1-4 per trial). Slower, it rounds the corner. Empty: stop.
    collision_slowdowns: tuple[float, ...] = (0.5, 0.25)
    search_window: float = 1.0  # m: how far along the path the progress search looks
    # The body turns to the goal's yaw as it walks the path's last stretch, stepping along
    # the path holonomically (vx, vy toward the look-ahead point): turned only at the
    # goal, the last turn (often 2-3 rad: a stance faces its object, not the way it came)
    # took 2-3 s of the final alignment per walk (kinematic model, 16 goals). It starts
    # ``turn_ahead`` m before the end, or earlier by the distance walked while turning at
    # ``max_wz``. 0: off.
    turn_ahead: float = 0.8
    # Told whether the robot stands: stopped within the tolerances, it waits (at most
    # ``stop_wait``) until it stands, then nudges itself onto ``aim`` of them (at most the
    # nudges' patience): what the robot stands at is what the task gets, and the
    # localisation's own error comes on top (two goals of 50 ended 5.0-5.4 cm off with
    # navigation's 3 cm tolerance).
    aim: float = 0.5
    stop_wait: float = 1.5  # s
    # m: a goal whose xy tolerance is at least this (the task's walks, 10 cm, before an
    # approach steps in precisely) ends once the body will stop inside it, without
    # waiting to stand or nudging onto the aim (0.5-1 s of each walk's end, kinematic model)
    loose_tolerance: float = 0.06


@dataclass(frozen=True)
class FollowCommand:
    """A body velocity command; ``done`` when the goal is reached within tolerance,
    ``blocked`` when the collision check stopped the robot."""

    vx: float
    vy: float
    wz: float
    done: bool
    distance_left: float
    blocked: bool = False
    mode: str = "track"


def project_motion(pose: Pose2, vx: float, vy: float, wz: float, horizon: float) -> np.ndarray:
    """Poses (K, 3) the body reaches holding (vx, vy, wz) for up to ``horizon`` s."""
    ts = np.linspace(0.0, horizon, 6)[1:]
    out = []
    for t in ts:
        # exact integration of a constant body twist
        th = wz * t
        if abs(wz) > 1e-6:
            s, c = math.sin(th) / wz, (1 - math.cos(th)) / wz
            dx, dy = s * vx - c * vy, c * vx + s * vy
        else:
            dx, dy = vx * t, vy * t
        out.append(compose(pose, (dx, dy, th)))
    return np.asarray(out)


def costmap_collision_check(costmap: Costmap) -> CollisionCheck:
    """The costmap's collision check: blocked when a projected centre lands on a lethal
    cell, enters the inscribed zone from outside it (a robot already inside, after a
    grasp, may move out), or when the projected footprint overlaps an obstacle that the
    current footprint does not (in-place turns beside furniture)."""

    def check(pose: Pose2, poses: np.ndarray) -> bool:
        c = costmap.cost_at(poses[:, :2])
        if np.any(c == LETHAL):
            return True
        here = int(costmap.cost_at(np.array([pose[:2]]))[0])
        if here < INSCRIBED and np.any(c >= INSCRIBED):
            return True
        last = tuple(float(v) for v in poses[-1])
        return costmap.footprint_free(pose) and not costmap.footprint_free(last)

    return check


class PathFollower:
    """Regulated pure pursuit with in-place turns and a holonomic final alignment."""

    def __init__(
        self,
        config: FollowerConfig | None = None,
        collision: CollisionCheck | None = None,
        nudge: NudgeConfig | None = None,
    ):
        self.config = config or FollowerConfig()
        self.collision = collision
        self.nudge = StandingNudge(nudge)
        self.reset()

    def reset(self) -> None:
        """Forget progress and the last command (a new path, or after a stop)."""
        self._path: np.ndarray | None = None
        self._s: np.ndarray | None = None
        self._idx = 0
        self._last = (0.0, 0.0, 0.0)
        self._vel = np.zeros(3)  # the body velocity the commands produce, first-order model
        self._rotating = False
        self._ahead = False
        self._final = False
        self._waited = 0.0  # s stopped within the tolerances, waiting to stand
        self._settling = False  # within the tolerances, standing still or nudged
        self.nudge.reset()

    def _set_path(self, path: np.ndarray, pose: Pose2) -> None:
        self._path = path
        seg = np.hypot(*np.diff(path, axis=0).T) if len(path) > 1 else np.zeros(0)
        self._s = np.r_[0.0, np.cumsum(seg)]
        self._idx = int(np.argmin(np.hypot(*(path - pose[:2]).T)))
        self._final = False
        self._rotating = False
        self._ahead = False  # turning to the goal's yaw on the way (``turn_ahead``)

    def command(
        self,
        pose: Pose2,
        path: np.ndarray,
        goal_yaw: float | None,
        clearance: float,
        xy_tol: float | None = None,
        yaw_tol: float | None = None,
        dt: float | None = None,
        standing: bool | None = None,
        pass_through: bool = False,
    ) -> FollowCommand:
        """The body velocity command (base frame) that follows ``path`` (N, 2, map frame)
        from ``pose`` and ends at its last point facing ``goal_yaw`` (None: any yaw);
        ``clearance`` is the robot's distance to the nearest obstacle (m); ``standing``
        whether locomotion stands (None: unknown, no standing nudges). ``pass_through``:
        done the moment the robot is within the tolerances, however fast it still walks
        (``NavigateGoal.pass_through``)."""
        cfg = self.config
        dt = cfg.dt if dt is None else dt
        xy_tol = cfg.xy_tolerance if xy_tol is None else xy_tol
        yaw_tol = cfg.yaw_tolerance if yaw_tol is None else yaw_tol
        path = np.asarray(path, dtype=float).reshape(-1, 2)
        if self._path is None or path is not self._path:
            if (
                self._path is None
                or path.shape != self._path.shape
                or not np.array_equal(path, self._path)
            ):
                self._set_path(path, pose)
        assert self._s is not None
        # progress: the nearest path point within the search window ahead
        spacing = max(self._s[-1] / max(len(path) - 1, 1), 1e-3)
        hi = min(len(path), self._idx + int(cfg.search_window / spacing) + 2)
        win = path[self._idx : hi]
        self._idx += int(np.argmin(np.hypot(*(win - pose[:2]).T)))
        goal = path[-1]
        to_goal = math.hypot(goal[0] - pose[0], goal[1] - pose[1])
        left = float(self._s[-1] - self._s[self._idx]) + math.hypot(
            path[self._idx][0] - pose[0], path[self._idx][1] - pose[1]
        )
        if pass_through and to_goal <= xy_tol and self._s[-1] - self._s[self._idx] <= xy_tol:
            eyaw = 0.0 if goal_yaw is None else float(wrap(goal_yaw - pose[2]))
            if abs(eyaw) <= yaw_tol:
                return FollowCommand(*self._last, True, to_goal, False, "pass")
        if to_goal < cfg.final_distance and self._s[-1] - self._s[self._idx] < cfg.final_distance:
            self._final = True
        if self._final:
            self._settling = False
            vx, vy, wz, done = self._align(pose, goal, goal_yaw, xy_tol, yaw_tol, standing, dt)
            mode = "settle" if self._settling else "final"
            if done:
                self._emit((0.0, 0.0, 0.0), dt)
                return FollowCommand(0.0, 0.0, 0.0, True, to_goal, False, mode)
        else:
            vx, vy, wz, mode = self._track(pose, path, clearance, left, goal_yaw)
        kappa = wz / vx if mode == "track" and vx > 1e-6 else None
        vx, vy, wz = self._limit_accel(vx, vy, wz, dt, kappa)
        if self.collision is not None and (vx or vy or wz):
            h = cfg.collision_horizon
            # a slowed command is checked on the motion the robot makes under it, its
            # speed still decaying from what it walks at (the gait's lag): the mean
            # velocity over the horizon (a slowed command checked as if obeyed at once
            # let the robot run on into the inscribed band, toward a wall)
            lag = max(cfg.response_lag, 1e-6)
            decay = lag / h * (1.0 - math.exp(-h / lag))
            for k in (1.0, *cfg.collision_slowdowns):
                c = np.array([k * vx, k * vy, k * wz])
                # (and it must still stop short after it: the stop under the slowed speed,
                # lag x speed, comes on top)
                moved = c if k == 1.0 else c + (self._vel - c) * decay + c * lag / h
                if not self.collision(pose, project_motion(pose, *map(float, moved), h)):
                    vx, vy, wz = (float(v) for v in c)
                    break
            else:
                self._emit((0.0, 0.0, 0.0), dt)
                return FollowCommand(0.0, 0.0, 0.0, False, left, True, mode)
        self._emit((vx, vy, wz), dt)
        return FollowCommand(vx, vy, wz, False, left, False, mode)

    def _emit(self, cmd: tuple[float, float, float], dt: float) -> None:
        self._last = cmd
        a = 1.0 - math.exp(-dt / max(self.config.response_lag, 1e-6))
        self._vel = self._vel + a * (np.asarray(cmd) - self._vel)

    def _track(
        self,
        pose: Pose2,
        path: np.ndarray,
        clearance: float,
        left: float,
        goal_yaw: float | None = None,
    ) -> tuple[float, float, float, str]:
        cfg = self.config
        assert self._s is not None
        speed = abs(self._last[0])
        look = min(max(speed * cfg.lookahead_time, cfg.lookahead_min), cfg.lookahead_max)
        s_target = self._s[self._idx] + look
        if s_target >= self._s[-1]:
            target = path[-1]
        else:
            target = np.array(
                [np.interp(s_target, self._s, path[:, 0]), np.interp(s_target, self._s, path[:, 1])]
            )
        lx, ly, _ = compose(invert(pose), (float(target[0]), float(target[1]), 0.0))
        alpha = math.atan2(ly, lx)
        if goal_yaw is not None and cfg.turn_ahead > 0.0 and not self._rotating:
            turn = abs(float(wrap(goal_yaw - pose[2]))) / cfg.max_wz  # s at the top rate
            if left < max(cfg.turn_ahead, math.hypot(*self._last[:2]) * turn):
                self._ahead = True  # latched for this path: the turn shrinks as it goes
            if self._ahead:
                return self._turn_ahead(pose, lx, ly, clearance, left, goal_yaw)
        if abs(alpha) > cfg.rotate_threshold:
            self._rotating = True
        elif abs(alpha) < cfg.rotate_exit:
            self._rotating = False
        if self._rotating:
            wz = float(np.clip(cfg.rotate_gain * alpha, -cfg.max_wz, cfg.max_wz))
            if clearance < cfg.slow_clearance or cfg.rotate_walk_speed <= 0.0:
                return 0.0, 0.0, wz, "rotate"
            # in the open it sets off along the path as it turns (any direction)
            vx, vy = self._step_toward(lx, ly, cfg.rotate_walk_speed)
            return vx, vy, wz, "rotate"
        d2 = lx * lx + ly * ly
        kappa = 2.0 * ly / max(d2, 1e-6)
        v = cfg.max_vx
        if abs(kappa) > 1.0 / cfg.regulation_radius:  # curvature regulation
            v *= 1.0 / (abs(kappa) * cfg.regulation_radius)
        v = self._speed_limit(clearance, left, v)
        wz = v * kappa
        if abs(wz) > cfg.max_wz:  # keep the arc: slow down rather than cut it
            v *= cfg.max_wz / abs(wz)
            wz = math.copysign(cfg.max_wz, wz)
        return v, 0.0, wz, "track"

    def _speed_limit(self, clearance: float, left: float, v: float) -> float:
        """``v`` regulated near obstacles (proximity regulation) and near the end."""
        cfg = self.config
        if clearance < cfg.slow_clearance:
            f = (clearance - cfg.stop_clearance) / (cfg.slow_clearance - cfg.stop_clearance)
            v *= float(np.clip(f, 0.0, 1.0))
        v = max(v, cfg.min_speed)
        return min(v, max(cfg.approach_gain * left, cfg.final_min_speed))

    def _turn_ahead(
        self, pose: Pose2, lx: float, ly: float, clearance: float, left: float, goal_yaw: float
    ) -> tuple[float, float, float, str]:
        """The path's last stretch: step toward the look-ahead point (base frame ``lx,
        ly``) in any direction, turning to ``goal_yaw`` meanwhile (``turn_ahead``)."""
        cfg = self.config
        eyaw = float(wrap(goal_yaw - pose[2])) - self._vel[2] * cfg.response_lag  # at the stop
        wz = float(np.clip(cfg.final_yaw_gain * eyaw, -cfg.max_wz, cfg.max_wz))
        vx, vy = self._step_toward(lx, ly, self._speed_limit(clearance, left, cfg.max_vx))
        return vx, vy, wz, "turn_ahead"

    def _step_toward(self, lx: float, ly: float, speed: float) -> tuple[float, float]:
        """(vx, vy): at most ``speed`` toward the base-frame point (lx, ly), within the
        gait's forward and sideways limits, given in the frame the body will have turned
        to: the gait follows over ``response_lag`` while the body turns (else the walk
        bows to the turn's side)."""
        cfg = self.config
        d = math.hypot(lx, ly)
        if d < 1e-6:
            return 0.0, 0.0
        ux, uy = lx / d, ly / d
        v = min(speed, cfg.max_vy / max(abs(uy), 1e-6), cfg.max_vx / max(abs(ux), 1e-6))
        vx, vy, _ = compose((0.0, 0.0, -self._vel[2] * cfg.response_lag), (v * ux, v * uy, 0.0))
        return vx, vy

    def _align(
        self,
        pose: Pose2,
        goal: np.ndarray,
        goal_yaw: float | None,
        xy_tol: float,
        yaw_tol: float,
        standing: bool | None,
        dt: float,
    ) -> tuple[float, float, float, bool]:
        cfg = self.config
        yaw = pose[2] if goal_yaw is None else goal_yaw
        ex, ey, eyaw = compose(invert(pose), (float(goal[0]), float(goal[1]), float(yaw)))
        eyaw = float(wrap(eyaw))
        dist = math.hypot(ex, ey)
        within = dist <= xy_tol and abs(eyaw) <= yaw_tol
        if xy_tol >= cfg.loose_tolerance:
            standing = None  # a loose goal: no waiting to stand, no nudges onto the aim
        if within and standing:
            self._settling = True  # bounded: the nudges' patience
            on_aim = dist <= cfg.aim * xy_tol and abs(eyaw) <= cfg.aim * yaw_tol
            nudge = None if on_aim else self.nudge.command((ex, ey, eyaw), standing, dt)
            if nudge is None:
                return 0.0, 0.0, 0.0, True  # standing there: nothing moves it any more
            return *nudge, False
        nudge = self.nudge.command((ex, ey, eyaw), standing, dt)
        if nudge is not None:
            return *nudge, False
        # done when within tolerance now and where the still-moving robot will stop, and
        # it has all but stopped
        # (its velocity, modelled from the commands, decays over ``response_lag``)
        px, py, pw = (float(v) for v in np.array([ex, ey, eyaw]) - self._vel * cfg.response_lag)
        stops = math.hypot(px, py) <= xy_tol and abs(pw) <= yaw_tol
        # (all but stopped: slow enough that the stop after ``done`` stays well inside; a
        # loose goal's end need not wait for the last creep to die out)
        lag4 = 4.0 * cfg.response_lag
        stops &= bool(
            math.hypot(self._vel[0], self._vel[1]) < max(0.5 * cfg.final_min_speed, xy_tol / lag4)
            and abs(self._vel[2]) < max(0.5 * cfg.final_min_wz, yaw_tol / lag4)
        )
        if within and stops:
            if standing is None:
                return 0.0, 0.0, 0.0, True
            # stopped but still stepping: wait for it to stand (then the aim, above)
            self._settling = True  # bounded: stop_wait
            self._waited += dt
            return 0.0, 0.0, 0.0, self._waited >= cfg.stop_wait
        ex, ey, eyaw, dist = px, py, pw, math.hypot(px, py)  # steer on where it stops
        vx, vy = cfg.final_gain * ex, cfg.final_gain * ey
        sp = math.hypot(vx, vy)
        if sp > cfg.final_max_speed:
            vx, vy = vx * cfg.final_max_speed / sp, vy * cfg.final_max_speed / sp
        elif dist > 0.5 * xy_tol and sp < cfg.final_min_speed:
            vx, vy = vx * cfg.final_min_speed / sp, vy * cfg.final_min_speed / sp
        elif dist <= 0.5 * xy_tol:
            vx = vy = 0.0
        wz = float(np.clip(cfg.final_yaw_gain * eyaw, -cfg.max_wz, cfg.max_wz))
        if abs(eyaw) > 0.5 * yaw_tol and abs(wz) < cfg.final_min_wz:
            wz = math.copysign(cfg.final_min_wz, eyaw)
        elif abs(eyaw) <= 0.5 * yaw_tol:
            wz = 0.0
        return vx, vy, wz, False

    def _limit_accel(
        self, vx: float, vy: float, wz: float, dt: float, kappa: float | None = None
    ) -> tuple[float, float, float]:
        """Rate-limit the command; while tracking, the turn rate follows the limited
        forward speed so the commanded arc keeps its curvature."""
        cfg = self.config
        lx, ly, lw = self._last
        vx = lx + float(np.clip(vx - lx, -cfg.max_ax * dt, cfg.max_ax * dt))
        vy = ly + float(np.clip(vy - ly, -cfg.max_ay * dt, cfg.max_ay * dt))
        if kappa is not None:
            wz = vx * kappa
        wz = lw + float(np.clip(wz - lw, -cfg.max_aw * dt, cfg.max_aw * dt))
        vx = float(np.clip(vx, -cfg.max_vx, cfg.max_vx))
        vy = float(np.clip(vy, -cfg.max_vy, cfg.max_vy))
        wz = float(np.clip(wz, -cfg.max_wz, cfg.max_wz))
        return vx, vy, wz
