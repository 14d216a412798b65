"""The navigation service: map, localise, plan and walk (paper Sections 5.1-5.3).

Inputs: ``sim/scan`` (2D LiDAR), ``locomotion/odometry``, ``locomotion/health``,
``navigation/initial_pose`` (a pose hint: localisation re-initialises around it when it
is not localised or disagrees strongly, :meth:`.amcl.ParticleFilter.hint`; the behavior
service sends one when navigation comes back after a restart); never anything under
``sim/gt``. Outputs: ``locomotion/cmd_vel`` (navigation owns the body
velocity while one of its actions runs, and only then), ``navigation/map`` (on change and
every ``map_period``), ``navigation/pose`` (map pose, covariance, map->odom),
``navigation/path``, ``navigation/costmap``.

Two modes (``[node] mode``):

* ``mapping``: online SLAM (:mod:`.slam`) builds the map from the robot start (map = odom
  there); the ``explore`` action walks to frontiers (:mod:`.frontier`) until none
  reachable is left. ``quadmanip map`` runs this and saves the map.
* ``localization``: the saved map and its places file; an AMCL-style particle filter
  (:mod:`.amcl`) from ``initial_pose`` or globally.

Actions: ``navigate_to`` (a map pose or a named place), ``approach`` (the precise final
approach, in the odom frame: it does not need the map) and ``explore``. One runs at a
time; a goal while one runs is rejected ``busy``. Every algorithm runs in the control loop
(``step``); action threads only hand goals in and wait for outcomes, so no algorithm
state is shared between threads. When the inputs stop (no odometry or scan for
``input_timeout``), locomotion's tripped, or a goal is cancelled, the robot is told to
stand still and the goal ends with the reason.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.actions import ActionCanceled, ActionFailed, GoalHandle
from quadmanip.common.config import CONFIG_DIR
from quadmanip.common.rotations import quat_to_mat, yaw_from_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.navigation.amcl import ParticleFilter
from quadmanip.services.navigation.approach import (
    ApproachController,
    approach_pose,
    free_approach_heading,
    lead_in_pose,
    stance_clear,
)
from quadmanip.services.navigation.config import NavigationConfig
from quadmanip.services.navigation.costmap import INSCRIBED, Costmap, area_mask, with_keepouts
from quadmanip.services.navigation.frontier import find_frontiers
from quadmanip.services.navigation.global_planner import plan_path
from quadmanip.services.navigation.grid import (
    GridGeometry,
    Pose2,
    compose,
    invert,
    transform_points,
    wrap,
)
from quadmanip.services.navigation.map_io import load_map, load_surface
from quadmanip.services.navigation.navigator import Navigator
from quadmanip.services.navigation.object_layer import floor_obstacles, handled
from quadmanip.services.navigation.odom_watch import odometry_jumped
from quadmanip.services.navigation.places import (
    TABLE_KINDS,
    Place,
    load_places,
    places_path_for,
)
from quadmanip.services.navigation.pose_history import PoseHistory
from quadmanip.services.navigation.scan import (
    ScanPoints,
    lidar_height_above_base,
    lidar_mount,
    nearest_return,
    scan_points,
)
from quadmanip.services.navigation.scan_anchor import ScanAnchor
from quadmanip.services.navigation.slam import OnlineSlam

__all__ = ["STANCE_MEETS_FURNITURE", "NavigationNode", "main", "resolve_map_path"]

# an approach ended before it set off: its stance meets furniture (ApproachGoal's face_target
# and turn_free); it says "touches the footprint", as the stop by the approach's guard does
STANCE_MEETS_FURNITURE = (
    "blocked: an obstacle touches the footprint at the stance asked, and no stance turned "
    "about the target is clear from here"
)


def resolve_map_path(name: str) -> Path:
    """A map YAML by path, else under configs/ (``maps/house.yaml``)."""
    p = Path(name)
    if p.is_file():
        return p
    q = CONFIG_DIR / name
    return q if q.is_file() else p


def _pose_of(od: m.Odometry) -> Pose2:
    return (float(od.position[0]), float(od.position[1]), yaw_from_quat(od.orientation))


@dataclass
class _Job:
    """A goal handed from an action thread to the control loop."""

    kind: str  # navigate | approach | explore
    goal: m.Message
    done: threading.Event = field(default_factory=threading.Event)
    cancel: bool = False
    started: bool = False
    outcome: str = ""
    reason: str = ""
    progress: float = 0.0
    text: str = ""
    t0: float = math.nan
    start_pose: Pose2 | None = None
    target: Pose2 | None = None  # navigate: map pose; approach: odom pose
    total: float = 1.0
    walked: float = 0.0
    last_pose: Pose2 | None = None
    final_pose: Pose2 = (0.0, 0.0, 0.0)
    frame: str = "map"
    # explore
    blacklist: list[tuple[float, float]] = field(default_factory=list)
    t_check: float = -math.inf
    frontier_goal: tuple[float, float] | None = None
    frontier_raw: tuple[float, float] | None = None
    start_problem: str = ""
    start_retries: int = 0
    anchor: ScanAnchor | None = None
    anchor_scan: float = -math.inf
    t_settle: float | None = None
    lead: Pose2 | None = None  # approach: the map pose it walks to first (planner)


class NavigationNode(Service):
    """Serves navigate_to, approach and explore; publishes the map and the map pose."""

    name = "navigation"
    config_type = NavigationConfig
    inputs = (
        Input("sim/scan", latest_only=True, doc="2D LiDAR"),
        Input("locomotion/odometry", latest_only=True, doc="base pose in odom"),
        Input("locomotion/health", latest_only=True, doc="tripped: stop"),
        Input("navigation/initial_pose", latest_only=True, doc="pose hint: re-localise"),
        Input("perception/objects", latest_only=True, doc="floor objects: costmap discs"),
    )
    outputs = (
        Output("locomotion/cmd_vel", doc="body velocity while an action runs"),
        Output("navigation/map", doc="occupancy map"),
        Output("navigation/surface", doc="mapping: the fine raster of surfaces seen"),
        Output("navigation/pose", doc="map pose + map->odom"),
        Output("navigation/path", doc="the planned path"),
        Output("navigation/costmap", doc="costmap"),
    )
    actions = ("navigate_to", "approach", "explore")
    loop_period = 0.05

    # ------------------------------------------------------------------ setup
    def setup(self) -> None:
        """Loads the map (localisation) or starts an empty one (mapping); serves actions."""
        cfg: NavigationConfig = self.config
        nc = cfg.node
        if nc.mode not in ("mapping", "localization"):
            raise ValueError(f"[node] mode must be mapping or localization, not {nc.mode!r}")
        self.mount = lidar_mount()
        self.mount_z = lidar_height_above_base()
        self.attitude = np.eye(3)
        self.base_height = 0.0
        self.lock = threading.Lock()
        self.job: _Job | None = None
        self.navigator = Navigator(cfg.navigator, cfg.follower, cfg.planner, cfg.nudge)
        self.approacher = ApproachController(cfg.approach, cfg.nudge)
        self.places: dict[str, Place] = {}
        self.slam: OnlineSlam | None = None
        self.amcl: ParticleFilter | None = None
        self.map_to_odom: Pose2 = (0.0, 0.0, 0.0)
        self.keepout_only: np.ndarray | None = None
        self.table_tops: np.ndarray | None = None
        self.walk_exempt: set[int] = set()  # tracks near where the current walk began
        if nc.mode == "mapping":
            self.slam = OnlineSlam(cfg.slam)
            self.costmap: Costmap | None = None
            self.static_costmap: Costmap | None = None
        else:
            path = resolve_map_path(nc.map)
            self.map_grid, self.map_geo = load_map(path)
            pp = places_path_for(path)
            if pp.is_file():
                self.places = load_places(pp)
            surface = load_surface(path) if nc.fine_surface else None
            self.amcl = ParticleFilter(cfg.amcl, self.map_grid, self.map_geo, surface=surface)
            if nc.global_localization:
                self.amcl.initialize_global()
            else:
                x, y, yaw = nc.initial_pose
                sx, sy, syaw = nc.initial_std
                self.amcl.initialize((x, y, math.radians(yaw)), (sx, sy, math.radians(syaw)))
            # localisation ignores what moves (the drawers' fronts: the map shows them shut)
            self.amcl.ignore_areas([p.area for p in self.places.values() if p.moves])
            # the costmaps keep paths out of the keepout areas; localisation uses the map
            keepouts = [p.area for p in self.places.values() if p.keepout]
            static = with_keepouts(self.map_grid, self.map_geo, keepouts)
            self.costmap = Costmap(cfg.costmap, static, self.map_geo)
            self.static_costmap = Costmap(cfg.costmap, static, self.map_geo)
            # cells lethal only as keepouts (a table top the LiDAR passes under), for a
            # stance that reaches in under the top with its nose (ApproachGoal.turn_free)
            self.keepout_only = self.costmap.static_lethal & ~(
                self.map_grid >= cfg.costmap.occupied_threshold
            )
            # every table's top (the deposit table's too, which is no keepout: its boxes'
            # stances come within 1 cm of its edge): the LiDAR passes under a top, the
            # trunk's LiDAR housing and the arm do not, so an approach stance keeps out
            self.table_tops = area_mask(
                self.map_geo, [p.area for p in self.places.values() if p.kind in TABLE_KINDS]
            )
            self.log.info("map loaded", map=str(path), places=len(self.places),
                          keepouts=len(keepouts),
                          cells=f"{self.map_geo.width}x{self.map_geo.height}",
                          surface="none" if surface is None else
                          f"{surface[1].resolution:g} m, {int(surface[0].sum())} cells")  # fmt: skip
        self.map_version = 0
        self.t_costmap_build = -math.inf
        self.scan_cache = self.latest("sim/scan")
        self.odom_cache = self.latest("locomotion/odometry")
        # the odometry of each scan's own instant (see pose_history); every 500 Hz message:
        # decoding and keeping one costs ~13 us here, about 0.7 % of a core
        self.odom_history = PoseHistory()
        self.subscribe("locomotion/odometry",
                       lambda od: self.odom_history.add(float(od.stamp), _pose_of(od)))  # fmt: skip
        self.health_cache = self.latest("locomotion/health")
        self.hint_cache = self.latest("navigation/initial_pose")
        self.hint_stamp = -math.inf  # of the last hint handled
        self.objects_cache = self.latest("perception/objects")
        self.floor_zones = [p.area for p in self.places.values() if p.kind == "search_floor"]
        self.pub_vel = self.publisher("locomotion/cmd_vel")
        self.pub_map = self.publisher("navigation/map")
        self.pub_surface = self.publisher("navigation/surface")
        self.pub_pose = self.publisher("navigation/pose")
        self.pub_path = self.publisher("navigation/path")
        self.pub_costmap = self.publisher("navigation/costmap")
        self.last_scan_stamp = -math.inf
        self.last_odom_stamp = -math.inf
        self.t_wall_odom = time.monotonic()
        self.odom_prev: tuple[Pose2, float] | None = None  # the last odometry used, robot time
        self.odom_rebases = 0
        self.t_wall_map = -math.inf
        self.t_wall_costmap = -math.inf
        self.published_map_version = -1
        self.inputs_ok = False
        self.loc_ms: list[float] = []
        self.dt = self.loop_period
        self.t_step = -1.0
        self.status = "mapping" if self.slam else "converging"
        for action in self.actions:
            self.action_server(action, self._execute, accept=self._accept, policy="parallel")
        self.set_state("running")

    # ------------------------------------------------------------------ actions (threads)
    def _accept(self, goal: m.Message) -> tuple[bool, str]:
        with self.lock:
            if self.job is not None:
                return False, f"busy: {self.job.kind} running"
        if isinstance(goal, m.NavigateGoal):
            if self.slam is not None and goal.place:
                return False, "rejected: named places need a saved map (mapping mode)"
            if goal.place and goal.place not in self.places:
                known = ", ".join(sorted(self.places)) or "none"
                return False, f"rejected: unknown place {goal.place!r} (known: {known})"
            static = self.static_costmap if self.slam is None else None
            if static is not None and not goal.place and goal.frame == "map":
                x, y = float(goal.pose[0]), float(goal.pose[1])
                if not static.geometry.contains(x, y):
                    return False, "rejected: the goal is off the map"
                if not bool(static.is_traversable(np.array([[x, y]]))[0]):
                    return False, "rejected: the goal is in an obstacle or too close to one"
        elif isinstance(goal, m.ExploreGoal):
            if self.slam is None:
                return False, "rejected: explore needs mapping mode ([node] mode = mapping)"
        elif not isinstance(goal, m.ApproachGoal):
            return False, f"rejected: unsupported goal {type(goal).__name__}"
        return True, ""

    def _execute(self, handle: GoalHandle) -> m.Message | None:
        goal = handle.goal
        kind = {m.NavigateGoal: "navigate", m.ApproachGoal: "approach"}.get(type(goal), "explore")
        job = _Job(kind, goal)
        with self.lock:
            if self.job is not None:
                raise ActionFailed(f"busy: {self.job.kind} running")
            self.job = job
        last_text = None
        while not job.done.wait(0.2):
            if handle.cancel_requested:
                job.cancel = True
            if job.text and job.text != last_text:
                handle.feedback(min(max(job.progress, 0.0), 1.0), job.text)
                last_text = job.text
        result = m.NavigationResult(
            stamp=self._now(),
            outcome=job.outcome,
            reason=job.reason,
            final_pose=job.final_pose,
            error_xy=float(self._errors(job)[0]),
            error_yaw=float(self._errors(job)[1]),
            distance=job.walked,
            duration=0.0 if math.isnan(job.t0) else max(self._now() - job.t0, 0.0),
        )
        if job.outcome == "reached":
            return result
        if job.outcome == "cancelled":
            raise ActionCanceled(job.reason or "cancelled", result)
        raise ActionFailed(job.reason or job.outcome, result)

    # ------------------------------------------------------------------ helpers
    def _now(self) -> float:
        od = self.odom_cache.get()
        return float(od.stamp) if od is not None else 0.0

    def _errors(self, job: _Job) -> tuple[float, float]:
        if job.target is None:
            return 0.0, 0.0
        p = job.final_pose
        return (
            math.hypot(job.target[0] - p[0], job.target[1] - p[1]),
            abs(float(wrap(job.target[2] - p[2]))),
        )

    def _finish(
        self, job: _Job, outcome: str, reason: str, pose: Pose2 | None, stop: bool = True
    ) -> None:
        if pose is not None:
            job.final_pose = pose
        job.outcome, job.reason = outcome, reason
        self.navigator.cancel()
        with self.lock:
            # the stop after any command for this job: a control tick that read the job
            # before it ended cannot command the robot after the stop (``_send``)
            self.job = None
            if stop:
                self._stop_robot()
        extra: dict[str, object] = {}
        if job.anchor is not None:
            extra = {"anchor_matches": job.anchor.matches, "anchor_refused": job.anchor.refused}
        if job.kind == "navigate" and self.navigator.last_modes:
            # where the walk's time went (s of robot time per step mode)
            modes = self.navigator.last_modes.items()
            extra["modes"] = " ".join(f"{k} {v:.1f}" for k, v in modes)
        if outcome == "blocked":  # where, and what was nearest: the log alone should tell
            if pose is not None and job.kind == "navigate":  # (a map pose; an approach's: odom)
                extra["map_pose"] = f"[{pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f}]"
                if job.target is not None:
                    t = job.target
                    extra["map_goal"] = f"[{t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}]"
            scan = self.scan_cache.get()
            near = None if scan is None else nearest_return(self._scan_points(scan).points)
            if near is not None:
                extra["nearest_return"] = f"{near[0]:.2f} m at {math.degrees(near[1]):.0f} deg"
        self.log.info("goal ended", kind=job.kind, outcome=outcome, reason=reason, **extra)
        job.done.set()

    def _stop_robot(self) -> None:
        self.pub_vel.publish(m.BodyVelocityCommand(stamp=self._now(), vx=0.0, vy=0.0, wz=0.0))

    def _send(self, job: _Job, vx: float, vy: float, wz: float) -> None:
        """Command the robot for ``job``, unless it has ended meanwhile (another thread's
        ``_finish`` for lost inputs: a stale command after its stop kept the robot walking)."""
        with self.lock:
            if self.job is job:
                self.pub_vel.publish(m.BodyVelocityCommand(stamp=self._now(), vx=vx, vy=vy, wz=wz))

    # ------------------------------------------------------------------ perception of self
    def _scan_points(self, scan: m.LaserScan) -> ScanPoints:
        return scan_points(
            float(scan.stamp),
            scan.ranges,
            float(scan.angle_min),
            float(scan.angle_increment),
            float(scan.range_min),
            float(scan.range_max),
            self.mount,
            self.attitude,
            self.base_height + self.mount_z,
            self.config.node.min_hit_height,
        )

    def _localize(self, scan: m.LaserScan, odom: Pose2, now: float) -> None:
        """Update the map->odom transform from ``scan`` and ``odom``, the odometry at the
        scan's stamp."""
        pts = self._scan_points(scan)
        t0 = time.perf_counter()
        if self.slam is not None:
            est = self.slam.update(pts, odom)
            self.map_to_odom = est.map_to_odom
            if est.matched or self.slam.grid.scans <= 1:
                self.map_version += 1
        elif self.amcl is not None:
            self.amcl.predict(odom)
            self.amcl.update(pts)
            pose, _ = self.amcl.estimate()
            self.map_to_odom = compose(pose, invert(odom))
            self.status = "localized" if self.amcl.converged else "converging"
        self.loc_ms.append((time.perf_counter() - t0) * 1e3)
        if self.slam is not None and now - self.t_costmap_build >= (
            self.config.node.mapping_costmap_period
        ):
            self._build_mapping_costmap()
            self.t_costmap_build = now
        if self.costmap is not None and len(pts.points):
            sensor = compose(compose(self.map_to_odom, odom), self.mount)
            base = compose(self.map_to_odom, odom)
            self.costmap.update_obstacles(
                transform_points(base, pts.points), sensor, stamp=float(scan.stamp)
            )
            self._update_objects()

    def _update_objects(self) -> None:
        """The costmap's object layer from perception's latest memory (object_layer's
        docstring: the floor objects under the LiDAR's plane), in this node's map frame."""
        tracks = self.objects_cache.get()
        if tracks is None or self.costmap is None or not self.floor_zones:
            return
        g = self.navigator.goal
        if g is not None and g.objects_off:
            return  # left out for this walk (Navigator: no way around them)
        c = np.asarray(tracks.centroids, dtype=float).reshape(-1, 3)
        xy = transform_points(self.map_to_odom, c[:, :2]) if len(c) else c[:, :2]
        goal = self.navigator.goal.pose[:2] if self.navigator.goal is not None else None
        # walking: what the robot handled or held where the walk began is none; every other
        # track stays an obstacle however near it passes. Standing or approaching: every
        # track is one (an approach's stance check leaves its own target out)
        walking = goal is not None
        job = self.job
        if job is not None and job.lead is not None:
            goal = None  # a lead-in goes up to no object: those by its goal are obstacles too
        exempt = np.isin(np.asarray(tracks.ids), list(self.walk_exempt)) if walking else None
        discs = floor_obstacles(
            np.column_stack([xy, c[:, 2]]),
            tracks.extents,
            tracks.confirmed,
            self.floor_zones,
            None if goal is None else (float(goal[0]), float(goal[1])),
            self.config.objects,
            exempt,
        )
        self.costmap.set_objects(discs)

    def _tracks_near(self, pose: Pose2) -> set[int]:
        """Ids of perception's tracks that a robot at ``pose`` (map frame) handles or holds
        (:func:`object_layer.handled`)."""
        tracks = self.objects_cache.get()
        if tracks is None or not len(tracks.ids):
            return set()
        c = np.asarray(tracks.centroids, dtype=float).reshape(-1, 3)
        xy = transform_points(self.map_to_odom, c[:, :2])
        near = handled(xy, pose, self.config.objects)
        return {int(i) for i in np.asarray(tracks.ids)[near]}

    def _build_mapping_costmap(self) -> None:
        """The costmap of the SLAM map's known area (+ a margin): the planner's graph
        stays small however large the SLAM grid is."""
        assert self.slam is not None
        if self.slam.grid.known_bounds() is None:
            return
        occ, sub = self._map_view()
        # exploring: unknown space is crossable (at a cost); the LiDAR sees it as the robot
        # comes near. Lethal unknown made every frontier goal "blocked" as the robot's
        # projected footprint reached past the frontier.
        cfg = replace(self.config.costmap, unknown_is_lethal=False)
        self.costmap = Costmap(cfg, occ, sub)
        self.static_costmap = self.costmap

    # ------------------------------------------------------------------ loop
    def step(self) -> None:
        """Localise on a new scan, publish the pose, step the running job."""
        od = self.odom_cache.get()
        scan = self.scan_cache.get()
        wall = time.monotonic()
        if od is not None and float(od.stamp) > self.last_odom_stamp:
            self.last_odom_stamp = float(od.stamp)
            self.t_wall_odom = wall
        timeout = self.config.node.input_timeout
        lost = []
        if od is None or wall - self.t_wall_odom > timeout:
            lost.append("odometry")
        # scans are judged in robot time, against odometry's stamp: in lockstep on a busy
        # machine (real-time factor 0.2) the 10 Hz scans come more than a wall second apart
        # and navigation gave up ("lost") while nothing was wrong; on a robot the two clocks
        # are one, and a LiDAR that stops is still caught
        if scan is None or (od is not None and float(od.stamp) - float(scan.stamp) > timeout):
            lost.append("LiDAR scans")
        if lost:
            self._lost(f"lost: no {' or '.join(lost)} for {timeout:.1f} s")
            return
        assert od is not None and scan is not None
        odom = _pose_of(od)
        now = float(od.stamp)
        if self.odom_prev is not None and odometry_jumped(
            self.odom_prev[0], self.odom_prev[1], odom, now, self.config.odom_jump
        ):
            self._rebase_odometry(self.odom_prev[0], odom)
        self.odom_prev = (odom, now)
        # robot time per control step (lockstep runs slower than the wall clock)
        self.dt = min(max(now - self.t_step, 1e-3), 0.2) if self.t_step > 0 else self.loop_period
        self.t_step = now
        hint = self.hint_cache.get()
        if hint is not None and float(hint.stamp) != self.hint_stamp:
            self.hint_stamp = float(hint.stamp)
            self.apply_hint(hint, odom, now)
        stamp = float(scan.stamp)
        if stamp > self.last_scan_stamp:
            at_scan = self.odom_history.at(stamp)
            if at_scan is not None or stamp < now:  # else its odometry is yet to come
                self.last_scan_stamp = stamp
                if at_scan is not None and self._upright(od):
                    self._localize(scan, at_scan, now)
        pose = compose(self.map_to_odom, odom)
        self._publish_state(now, pose)
        self._step_job(now, pose, odom)

    def _rebase_odometry(self, before: Pose2, after: Pose2) -> None:
        """Odometry went on in a new frame (locomotion restarted): the robot is where it
        was in the map; map->odom and the localiser follow the new frame, and an approach
        (its goal in the old frame) ends."""
        pose = compose(self.map_to_odom, before)
        self.map_to_odom = compose(pose, invert(after))
        if self.amcl is not None:
            self.amcl.rebase(after)
        self.odom_rebases += 1
        self.odom_history.clear()  # no interpolation across the jump
        self.log.warning(
            "odometry jumped: a new odom frame (locomotion restarted?); the map pose is kept",
            before=[round(v, 3) for v in before],
            after=[round(v, 3) for v in after],
            rebases=self.odom_rebases,
        )
        job = self.job
        if job is not None and job.kind == "approach":
            self._finish(job, "blocked", "blocked: odometry restarted in a new frame", after)

    def apply_hint(self, hint: m.InitialPose, odom: Pose2, now: float) -> str:
        """Handle a pose hint (``navigation/initial_pose``) at odometry ``odom``, robot time
        ``now``; returns what was done (logged): ``initialized``, ``kept`` (the filter's
        converged estimate agrees with it), or ``ignored: ...`` (mapping mode, where the
        map frame is this run's own; or a hint older than ``hint_max_age``)."""
        if self.amcl is None:
            what = "ignored: mapping mode"
        elif now - float(hint.stamp) > self.config.node.hint_max_age:
            what = f"ignored: {now - float(hint.stamp):.1f} s old"
        else:
            std = (float(hint.std_xy), float(hint.std_xy), float(hint.std_yaw))
            what = self.amcl.hint((float(hint.x), float(hint.y), float(hint.yaw)), std, odom)
            if what == "initialized":
                pose, _ = self.amcl.estimate()
                self.map_to_odom = compose(pose, invert(odom))
                self.status = "localized" if self.amcl.converged else "converging"
        self.log.info("pose hint", result=what, source=hint.source,
                      pose=[round(float(hint.x), 3), round(float(hint.y), 3),
                            round(float(hint.yaw), 3)])  # fmt: skip
        return what

    def _standing(self) -> bool | None:
        """Whether locomotion stands (phase ``balance``) rather than trots; None unknown."""
        h = self.health_cache.get()
        return None if h is None or not h.phase else h.phase == "balance"

    def _upright(self, od: m.Odometry) -> bool:
        """Whether the trunk stands high and level enough for its scan to be a plan view
        (not while lying or standing up); keeps its attitude for the floor filter."""
        R = quat_to_mat(od.orientation)
        yaw = math.atan2(R[1, 0], R[0, 0])
        c, s = math.cos(yaw), math.sin(yaw)
        # the attitude without its heading: base to a level, heading-aligned frame
        self.attitude = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
        self.base_height = float(od.position[2])
        nc = self.config.node
        tilt = math.acos(max(-1.0, min(1.0, float(R[2, 2]))))
        return self.base_height >= nc.min_base_height and tilt <= nc.max_tilt

    def _lost(self, reason: str) -> None:
        if self.inputs_ok:
            self.log.warning("inputs lost: standing still", reason=reason)
        self.inputs_ok = False
        with self.lock:
            job = self.job
        if job is not None:
            self._finish(job, "lost", reason, None)

    def _publish_state(self, now: float, pose: Pose2) -> None:
        self.inputs_ok = True
        if self.amcl is not None:
            _, cov = self.amcl.estimate()
        else:
            cov = np.diag([1e-4, 1e-4, 1e-4])
        self.pub_pose.publish(
            m.MapPose(
                stamp=now,
                x=pose[0],
                y=pose[1],
                yaw=pose[2],
                covariance=cov,
                map_to_odom=np.array(self.map_to_odom),
                status=self.status,
            )
        )
        wall = time.monotonic()
        nc = self.config.node
        changed = self.slam is not None and self.map_version != self.published_map_version
        if wall - self.t_wall_map >= nc.map_period or (changed and wall - self.t_wall_map >= 1.0):
            grid, geo = self._map_view()
            self.pub_map.publish(
                m.OccupancyGrid(
                    stamp=now,
                    origin=np.array([geo.origin_x, geo.origin_y, 0.0]),
                    data=grid,
                    resolution=geo.resolution,
                )
            )
            surface = self.slam.surface() if self.slam is not None else None
            if surface is not None:
                mask, sgeo = surface
                self.pub_surface.publish(
                    m.OccupancyGrid(
                        stamp=now,
                        origin=np.array([sgeo.origin_x, sgeo.origin_y, 0.0]),
                        data=np.where(mask, 100, 0).astype(np.int8),
                        resolution=sgeo.resolution,
                    )
                )
            self.published_map_version = self.map_version
            self.t_wall_map = wall
        if self.costmap is not None and wall - self.t_wall_costmap >= nc.costmap_period:
            c = self.costmap.cost
            data = np.where(c == 255, -1, np.minimum(c.astype(np.int16) * 100 // 254, 100))
            geo = self.costmap.geometry
            self.pub_costmap.publish(
                m.OccupancyGrid(
                    stamp=now,
                    origin=np.array([geo.origin_x, geo.origin_y, 0.0]),
                    data=data.astype(np.int8),
                    resolution=geo.resolution,
                )
            )
            self.t_wall_costmap = wall

    def _map_view(self) -> tuple[np.ndarray, GridGeometry]:
        """The map: the saved one, or the SLAM grid's known part (+ a margin), so that
        messages and costmaps stay small however large the SLAM grid is."""
        if self.slam is None:
            return self.map_grid, self.map_geo
        geo = self.slam.geometry
        b = self.slam.grid.known_bounds()
        if b is None:
            return self.slam.occupancy(), geo
        pad = int(self.config.node.costmap_margin / geo.resolution)
        r0, r1 = max(b[0] - pad, 0), min(b[1] + pad, geo.height)
        c0, c1 = max(b[2] - pad, 0), min(b[3] + pad, geo.width)
        sub = GridGeometry(geo.resolution, geo.origin_x + c0 * geo.resolution,
                           geo.origin_y + r0 * geo.resolution, c1 - c0, r1 - r0)  # fmt: skip
        return self.slam.occupancy()[r0:r1, c0:c1], sub

    # ------------------------------------------------------------------ jobs
    def _step_job(self, now: float, pose: Pose2, odom: Pose2) -> None:
        with self.lock:
            job = self.job
        if job is None:
            return
        h = self.health_cache.get()
        if h is not None and h.state == "tripped":
            self._finish(job, "blocked", f"robot_down: locomotion tripped ({h.reason})", pose)
            return
        if job.cancel:
            self._finish(job, "cancelled", "cancelled", odom if job.kind == "approach" else pose)
            return
        here = odom if job.kind == "approach" else pose
        if job.last_pose is not None:
            job.walked += math.hypot(here[0] - job.last_pose[0], here[1] - job.last_pose[1])
        job.last_pose = here
        if not job.started:
            job.started = True
            job.t0 = now
            job.start_pose = here
            if not self._start_job(job, now, pose, odom):
                return
        if job.kind == "approach" and job.lead is not None:
            self._step_lead_in(job, now, pose, odom)
        elif job.kind == "approach":
            self._step_approach(job, now, odom)
        elif job.kind == "navigate":
            self._step_navigate(job, now, pose)
        else:
            self._step_explore(job, now, pose)

    def _start_job(self, job: _Job, now: float, pose: Pose2, odom: Pose2) -> bool:
        g = job.goal
        if isinstance(g, m.NavigateGoal):
            if g.place:
                target = self.places[g.place].stand
            elif g.frame == "odom":
                target = compose(self.map_to_odom, tuple(float(v) for v in g.pose))
            else:
                target = (float(g.pose[0]), float(g.pose[1]), float(g.pose[2]))
            job.target = target
            return self._start_navigation(job, now, pose, target, g.tolerance_xy,
                                          g.tolerance_yaw, g.ignore_yaw,
                                          g.pass_through)  # fmt: skip
        if isinstance(g, m.ApproachGoal):
            job.frame = "odom"
            # every track an obstacle from the start: the layer as the last walk left it
            # exempts those near its goal, where the stance lies (paper-4, 2026-12-07: the
            # padlock's stance stood on the cracker box 0.36 m from it, 30 ms after the
            # walk; the box, knocked flat, could not be grasped)
            self._update_objects()
            t = (float(g.target[0]), float(g.target[1]))
            heading = float(g.heading)
            if g.frame == "base":
                t = compose(odom, (t[0], t[1], 0.0))[:2]
                heading += odom[2]
            meets = False
            if g.face_target:
                heading = math.atan2(t[1] - odom[1], t[0] - odom[0])
                heading, meets = self._free_heading(t, float(g.standoff), heading, odom)
            elif g.turn_free:
                # the nose reaches in under a table top for an object on it, not for one on
                # the floor beside it (the arm, over the object, would meet the top)
                on_top = self._in_keepout(t)
                heading, meets = self._free_heading(
                    t, float(g.standoff), heading, odom, nose_in=on_top
                )
            job.target = approach_pose(t, float(g.standoff), heading)
            # what was asked and where it stands, for a reader of the log (a stalled
            # approach is explained by its stance)
            self.log.info(
                "approach stance",
                target=f"[{t[0]:.2f}, {t[1]:.2f}]",
                stance=f"[{job.target[0]:.2f}, {job.target[1]:.2f}, {job.target[2]:.2f}]",
                start=f"[{odom[0]:.2f}, {odom[1]:.2f}, {odom[2]:.2f}]",
                asked=(
                    "face_target" if g.face_target else "turn_free" if g.turn_free else "heading"
                ),
                frame="odom",
                map_stance="[{:.2f}, {:.2f}, {:.2f}]".format(
                    *compose(self.map_to_odom, job.target)
                ),
            )
            if meets:
                # the approach would stop against it (paper-1's Rubik's cube, beside the
                # deposit table's leg and under its top: 20 s to "no progress", in every
                # run); the task walks to another side of the object and approaches again
                self._finish(job, "blocked", STANCE_MEETS_FURNITURE, odom)
                return False
            meets_object, lead = self._lead_in(t, job.target, odom)
            if meets_object:
                self.log.info(
                    "approach lead-in",
                    why="the straight way meets a floor object",
                    map_lead="none clear" if lead is None else
                    "[{:.2f}, {:.2f}, {:.2f}]".format(*lead),
                )  # fmt: skip
            if lead is not None:
                c = self.config.approach
                self.walk_exempt = self._tracks_near(pose)
                why = self.navigator.start(lead, now, pose, self.costmap, self.static_costmap,
                                           c.lead_tolerance_xy, c.lead_tolerance_yaw,
                                           pass_through=True)  # fmt: skip
                if not why:
                    job.lead = lead
                    self._update_objects()
                    return True
                self.log.info("approach lead-in refused", why=why)
            self._begin_straight(job, now, odom)
            return True
        return True  # explore chooses its goals as it goes

    def _begin_straight(self, job: _Job, now: float, odom: Pose2) -> None:
        """Start an approach's straight way (from the start, or where its lead-in ends)."""
        assert job.target is not None
        job.t0 = now
        job.total = max(math.hypot(job.target[0] - odom[0], job.target[1] - odom[1]), 1e-3)
        od = self.odom_cache.get()
        self.approacher.reset(
            None
            if od is None
            else (*od.linear_velocity[:2], od.angular_velocity[2])  # (base frame)
        )
        scan = self.scan_cache.get()
        if scan is not None:
            # (the newest odometry when the scan's is not known: the robot stands still
            # at an approach's start, and an approach without an anchor drifts cm)
            at_scan = self.odom_history.at(float(scan.stamp)) or odom
            job.anchor = ScanAnchor(self._scan_points(scan).points, at_scan,
                                    self.config.anchor)  # fmt: skip
            job.anchor_scan = float(scan.stamp)

    def _target_in_map(self, target: tuple[float, float]) -> tuple[tuple[float, float], float]:
        """An approach's odometry ``target`` in the map, and the radius about it within
        which the object layer is its own object (no obstacle to its approach)."""
        x, y, _ = compose(self.map_to_odom, (target[0], target[1], 0.0))
        return (x, y), self.config.objects.max_radius + 0.05

    def _stance_lethal(self, cm: Costmap, xy: tuple[float, float], near: float) -> np.ndarray:
        """What a stance's trunk may not overlap: the costmap's lethal cells but the target
        object's own, and the table tops."""
        lethal = cm.lethal_except_near(xy, near)
        return lethal if self.table_tops is None else lethal | self.table_tops

    def _other_objects(self, target: tuple[float, float]) -> np.ndarray | None:
        """The costmap's object layer without the approach's ``target`` (odometry frame);
        None when it holds nothing else."""
        cm = self.costmap
        if cm is None or not cm.objects.any():
            return None
        objects = cm.objects_except_near(*self._target_in_map(target))
        return objects if objects.any() else None

    def _stance_on_object(self, target: tuple[float, float], stance: Pose2) -> bool:
        """Whether the trunk at ``stance`` (odometry frame) overlaps a floor object of the
        costmap's object layer other than the approach's ``target``."""
        objects = self._other_objects(target)
        return objects is not None and not stance_clear(
            self.costmap, objects, compose(self.map_to_odom, stance), 0.0
        )

    def _lead_in(
        self, target: tuple[float, float], stance: Pose2, odom: Pose2
    ) -> tuple[bool, Pose2 | None]:
        """Whether an approach's straight way from ``odom`` to ``stance`` (odometry frame)
        meets a floor object of the costmap's object layer other than its ``target``, and
        the map pose to walk to first (:func:`approach.lead_in_pose`): clear of the
        costmap's obstacles, table tops and objects, and where the planner may stand."""
        cm, c = self.costmap, self.config.approach
        objects = self._other_objects(target) if c.lead_backs else None
        if cm is None or objects is None:
            return False, None
        lethal = self._stance_lethal(cm, *self._target_in_map(target))

        def way_clear(p: Pose2) -> bool:
            return stance_clear(cm, objects, p, c.lead_margin)

        def stand_clear(p: Pose2) -> bool:
            ok = bool(cm.is_traversable(np.array([p[:2]]))[0])
            return ok and stance_clear(cm, lethal, p, c.lead_margin)

        return lead_in_pose(
            way_clear,
            stand_clear,
            compose(self.map_to_odom, odom),
            compose(self.map_to_odom, stance),
            c.lead_backs,
        )

    def _step_lead_in(self, job: _Job, now: float, pose: Pose2, odom: Pose2) -> None:
        """An approach's walk to its lead-in pose; then (reached, or not: the straight way
        as before) its straight way in."""
        assert self.costmap is not None
        st = self.navigator.step(now, pose, self.costmap, standing=self._standing())
        late = now - job.t0 > self.config.node.approach_timeout
        if st.state == "active" and not late:
            self._send(job, st.vx, st.vy, st.wz)
            job.text = f"lead-in: {st.reason}"
            return
        self.navigator.cancel()
        self.log.info("approach lead-in ended", state="late" if late else st.state,
                      reason=st.reason)  # fmt: skip
        job.lead = None
        self._begin_straight(job, now, odom)

    def _start_navigation(self, job: _Job, now: float, pose: Pose2, target: Pose2,
                          tol_xy: float, tol_yaw: float, ignore_yaw: bool,
                          pass_through: bool = False) -> bool:  # fmt: skip
        if self.costmap is None:
            self._finish(job, "no_path", "no_path: no map yet", pose)
            return False
        self.walk_exempt = self._tracks_near(pose)
        why = self.navigator.start(target, now, pose, self.costmap, self.static_costmap,
                                   tol_xy, tol_yaw, ignore_yaw, pass_through)  # fmt: skip
        if why:
            outcome = "no_path" if why.startswith("no_path") else "rejected"
            self._finish(job, outcome, why, pose)
            return False
        self._update_objects()  # the walk's layer (what it handles exempt) from its first step
        job.total = max(math.hypot(target[0] - pose[0], target[1] - pose[1]), 1e-3)
        return True

    def _step_navigate(self, job: _Job, now: float, pose: Pose2) -> None:
        assert self.costmap is not None
        st = self.navigator.step(now, pose, self.costmap, standing=self._standing())
        if self.navigator.notice:
            self.log.info("navigate", decision=self.navigator.notice,
                          map_pose=f"[{pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f}]")  # fmt: skip
            self.navigator.notice = ""
        if st.new_path is not None:
            poses = self.navigator.path_poses()
            if poses is not None:
                self.pub_path.publish(m.Path(stamp=now, poses=poses))
        if st.state == "active":
            if st.reason.startswith(("recovering", "stepping back")):  # once each: logged
                self.log.info("navigate recovery", why=st.reason,
                              map_pose=f"[{pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f}]")  # fmt: skip
            self._send(job, st.vx, st.vy, st.wz)
            if math.isfinite(st.distance_left):
                job.progress = 1.0 - st.distance_left / job.total
                job.text = f"{st.distance_left:.2f} m left ({st.reason})"
            else:
                job.text = st.reason
            return
        if job.kind == "navigate":
            g = job.goal
            # a pass-through goal reached hands the robot on walking: no stop (the next
            # request, an approach, comes within locomotion's cmd_timeout; else that stops it)
            walking_on = st.state == "reached" and isinstance(g, m.NavigateGoal) and g.pass_through
            self._finish(job, st.state, st.reason, pose, stop=not walking_on)

    def _in_keepout(self, target: tuple[float, float]) -> bool:
        """Whether odometry point ``target`` lies in a keepout area (a table top)."""
        if self.costmap is None or self.keepout_only is None:
            return False
        in_map = compose(self.map_to_odom, (target[0], target[1], 0.0))
        geo = self.costmap.geometry
        (r,), (c,) = geo.to_cell(np.array([in_map[:2]], dtype=float))
        return bool(geo.inside(r, c) and self.keepout_only[r, c])

    def _free_heading(
        self,
        target: tuple[float, float],
        standoff: float,
        heading: float,
        odom: Pose2,
        nose_in: bool = False,
    ) -> tuple[float, bool]:
        """An approach's heading, turned about the target when at ``heading`` the stance
        (or the way to it) meets an obstacle of the costmap or a table's top within the
        approach's guard (``ApproachConfig.free_turns``; the objects layer counts, but not
        the target's own disc), and whether the stance meets the furniture: no heading is
        free, the stance is ``meets_furniture_from`` away or more, and the trunk itself at
        ``heading`` overlaps the static map (walls, legs, keepouts; no margin: not a graze
        but a stop; the deposit table's top is left out: rounded out to whole cells it
        reaches 4 cm past its edge, where a stance may stand). ``nose_in``: keepout areas
        hold only the
        trunk's middle out, the rest may reach under a table top (paper-5: a mug 13 cm in
        from the kitchen table's end; square to the table the trunk met a leg, and twelve
        approaches stopped); such a stance is never said to meet the furniture."""
        cm, turns = self.costmap, self.config.approach.free_turns
        if cm is None or not turns:
            return heading, False
        lethal = self._stance_lethal(cm, *self._target_in_map(target))
        keepout = self.keepout_only if nose_in else None
        guard = self.config.node.approach_guard

        def free(pose: Pose2, margin: float) -> bool:
            return stance_clear(cm, lethal, compose(self.map_to_odom, pose), margin, keepout)

        margin = self.config.approach.free_margin
        turned = free_approach_heading(free, odom, target, standoff, heading, turns, guard, margin)
        why = "at the heading asked the stance meets an obstacle"
        if turned is None and self._stance_on_object(
            target, approach_pose(target, standoff, heading)
        ):
            # no heading is clear with its straight way, and the asked stance stands on a
            # floor object: the nearest whose stance is clear, the lead-in walks round to
            # it (``_lead_in``). Kept, the approach walked onto the object and knocked it
            # over (paper-4, 2026-12-07: the cracker box, beside the padlock)
            turned = free_approach_heading(
                free, odom, target, standoff, heading, turns, guard, margin, way=False
            )
            why = "at the heading asked the stance stands on a floor object"
        if turned is None:
            stance = approach_pose(target, standoff, heading)
            far = math.hypot(stance[0] - odom[0], stance[1] - odom[1])
            meets = (
                not nose_in
                and far >= self.config.node.meets_furniture_from
                and not stance_clear(cm, cm.static_lethal, compose(self.map_to_odom, stance), 0.0)
            )
            return heading, meets
        if turned != heading:  # (not turned: the very heading it was given)
            self.log.info(
                "approach stance turned",
                by_deg=round(math.degrees(wrap(turned - heading)), 1),
                why=why,
            )
        return turned, False

    def _step_approach(self, job: _Job, now: float, odom: Pose2) -> None:
        g = job.goal
        assert isinstance(g, m.ApproachGoal) and job.target is not None
        if now - job.t0 > self.config.node.approach_timeout:
            why = f"blocked: the approach did not settle in time ({self.approacher.off()})"
            self._finish(job, "blocked", why, odom)
            return
        if job.anchor is not None:  # hold the odometry to the scan taken at the start
            scan = self.scan_cache.get()
            at_scan = None if scan is None else self.odom_history.at(float(scan.stamp))
            if scan is not None and at_scan is not None and float(scan.stamp) > job.anchor_scan:
                job.anchor_scan = float(scan.stamp)
                job.anchor.update(self._scan_points(scan).points, at_scan)
            odom = job.anchor.pose(odom)
        vx, vy, wz, done = self.approacher.command(
            odom, job.target, float(g.tolerance_xy), float(g.tolerance_yaw), dt=self.dt,
            standing=self._standing(),
        )  # fmt: skip
        if done:
            self._finish(job, "reached", "reached", odom)
            return
        if self.approacher.stalled:
            quiet = self.approacher.config.stall_time
            why = (f"blocked: the approach did not settle in time (no progress for "
                   f"{quiet:.0f} s, {self.approacher.off()})")  # fmt: skip
            self._finish(job, "blocked", why, odom)
            return
        if self._too_close(vx, vy):
            self._finish(job, "blocked", "blocked: an obstacle touches the footprint", odom)
            return
        self._send(job, vx, vy, wz)
        err = math.hypot(job.target[0] - odom[0], job.target[1] - odom[1])
        job.progress = 1.0 - err / job.total
        job.text = f"{err * 100:.1f} cm, {math.degrees(wrap(job.target[2] - odom[2])):.1f} deg left"

    def _too_close(self, vx: float, vy: float) -> bool:
        """Whether the last scan has a return against the trunk on the side it moves to."""
        scan = self.scan_cache.get()
        if scan is None:
            return False
        pts = self._scan_points(scan).points
        c = self.config.costmap
        gx = c.footprint_length / 2 + self.config.node.approach_guard
        gy = c.footprint_width / 2 + self.config.node.approach_guard
        inside = (np.abs(pts[:, 0]) < gx) & (np.abs(pts[:, 1]) < gy)
        if not inside.any():
            return False
        p = pts[inside]
        return bool(np.any(p[:, 0] * vx + p[:, 1] * vy > 0))

    def _step_explore(self, job: _Job, now: float, pose: Pose2) -> None:
        g = job.goal
        assert isinstance(g, m.ExploreGoal) and self.slam is not None
        ec = self.config.explore
        if g.max_time > 0 and now - job.t0 > g.max_time:
            self._finish(job, "reached", f"explore: time limit {g.max_time:.0f} s", pose)
            return
        if self.navigator.active:
            if now - job.t_check >= ec.recheck_period:
                job.t_check = now
                if not self._frontier_still_open(job):
                    self.log.info("frontier seen: next one")
                    self.navigator.cancel()
                    self._stop_robot()
                    return
            st = self.navigator.step(now, pose, self.costmap) if self.costmap else None
            if st is None:
                return
            if st.new_path is not None and (poses := self.navigator.path_poses()) is not None:
                self.pub_path.publish(m.Path(stamp=now, poses=poses))
            if st.state == "active":
                self._send(job, st.vx, st.vy, st.wz)
                return
            self.log.info("frontier goal ended", state=st.state, reason=st.reason)
            # unreachable, or reached and still open (it cannot be seen from the nearest
            # place the robot fits, e.g. a gap behind furniture): not again
            if job.frontier_raw is not None and (
                st.state != "reached" or self._frontier_still_open(job)
            ):
                job.blacklist.append(job.frontier_raw)
            job.frontier_goal = None
            return
        # choose the next frontier (after a moment: before the first scans are in the map
        # and its costmap there is no frontier at all, which is not "explored")
        if self.costmap is None or now - job.t0 < self.config.explore.settle_time:
            job.text = "exploring: looking around"
            return
        goal = self._next_frontier(job, pose)
        if goal is None and job.start_problem:
            job.start_retries += 1
            if job.start_retries * self.loop_period < self.config.explore.start_patience:
                return  # e.g. the costmap just rebuilt around the robot: try again
            self._finish(job, "blocked", f"blocked: cannot plan from here ({job.start_problem})",
                         pose)  # fmt: skip
            return
        job.start_retries = 0
        if goal is None:
            self._finish(job, "reached", "explored: no reachable frontier left", pose)
            return
        job.frontier_goal = goal
        job.t_check = now
        why = self.navigator.start((goal[0], goal[1], 0.0), now, pose, self.costmap, None,
                                   ec.goal_tolerance, math.pi, True)  # fmt: skip
        if why:
            if job.frontier_raw is not None:
                job.blacklist.append(job.frontier_raw)
            job.frontier_goal = None
        else:
            job.text = f"exploring: frontier at ({goal[0]:.2f}, {goal[1]:.2f})"

    def _frontier_still_open(self, job: _Job) -> bool:
        """Whether unknown space still borders the free space near the chosen frontier."""
        if job.frontier_raw is None or self.slam is None:
            return False
        fr = find_frontiers(self.slam.occupancy(), self.slam.geometry, self.config.frontier)
        x, y = job.frontier_raw
        r = self.config.explore.open_radius
        return any(
            bool(np.any(np.hypot(*(self.slam.geometry.cell_center(*f.cells.T) - (x, y)).T) < r))
            for f in fr
        )

    def _next_frontier(self, job: _Job, pose: Pose2) -> tuple[float, float] | None:
        """The nearest frontier the planner can reach (its goal pulled back into known free
        space); unreachable ones are blacklisted so they are not tried again."""
        assert self.slam is not None and self.costmap is not None
        ec = self.config.explore
        fr = find_frontiers(self.slam.occupancy(), self.slam.geometry, self.config.frontier)
        cands: list[tuple[float, tuple[float, float], tuple[float, float]]] = []
        for f in fr:
            raw = (float(f.goal_xy[0]), float(f.goal_xy[1]))
            if any(math.hypot(raw[0] - b[0], raw[1] - b[1]) < ec.blacklist_radius
                   for b in job.blacklist):  # fmt: skip
                continue
            goal = self._free_near(raw)
            if goal is None:
                job.blacklist.append(raw)
                continue
            cands.append((math.hypot(goal[0] - pose[0], goal[1] - pose[1]), goal, raw))
        cands.sort()
        job.start_problem = ""
        for _, goal, raw in cands:
            res = plan_path(self.costmap, pose[:2], goal, self.config.planner)
            if res.ok:
                job.frontier_raw = raw
                return goal
            if res.reason.startswith("start"):
                job.start_problem = res.reason  # the robot's spot, not the frontier
                return None
            self.log.info("frontier unreachable", at=[round(raw[0], 2), round(raw[1], 2)],
                          reason=res.reason)  # fmt: skip
            job.blacklist.append(raw)
        return None

    def _free_near(self, xy: np.ndarray | tuple[float, float]) -> tuple[float, float] | None:
        """The traversable cell nearest to ``xy`` within the search radius."""
        assert self.costmap is not None
        cm = self.costmap
        geo = cm.geometry
        n = int(self.config.explore.goal_search_radius / geo.resolution)
        (r,), (c,) = geo.to_cell(np.array([xy], dtype=float))
        rr, cc = np.mgrid[r - n : r + n + 1, c - n : c + n + 1]
        rr, cc = rr.ravel(), cc.ravel()
        ok = geo.inside(rr, cc)
        rr, cc = rr[ok], cc[ok]
        if not len(rr):
            return None
        centres = geo.cell_center(rr, cc)
        trav = cm.cost_at(centres) < INSCRIBED  # known free, room to stand (not unknown)
        if not trav.any():
            return None
        centres = centres[trav]
        d = np.hypot(*(centres - np.asarray(xy, dtype=float)).T)
        i = int(np.argmin(d))
        return float(centres[i][0]), float(centres[i][1])

    def teardown(self) -> None:
        """Ends a running goal and leaves the robot standing still."""
        with self.lock:
            job = self.job
        if job is not None and hasattr(self, "pub_vel"):
            self._finish(job, "cancelled", "cancelled: navigation stopping", None)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service navigation``."""
    return run_service(NavigationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
