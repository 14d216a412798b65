"""The full stack for one trial: a private router and the sim, locomotion and manipulation
services as separate processes, plus the harness's view of it over Zenoh.

``StackRun`` starts ``quadmanip router`` and ``quadmanip service sim|locomotion|manipulation``
through :class:`quadmanip.launcher.Launcher` (the sim in lockstep with a scenario file, the
cameras and LiDAR off because nothing here looks at them), waits until the robot stands,
and gives the harness what a later navigation and perception service will give the task:
walking on ground truth (velocity commands to locomotion) and ground-truth poses. The
manipulation service does everything else through its actions. Success is judged from
ground truth (``sim/gt/**``), never from a service's own claim.

TEST AND BENCHMARK HARNESS ONLY: it reads ground truth.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from quadmanip.common import keys
from quadmanip.common import messages as m
from quadmanip.common.bus import Bus
from quadmanip.common.rotations import quat_to_mat, rot_z, wrap_angle, yaw_from_quat
from quadmanip.launcher import Launcher, free_endpoint, observer_bus
from quadmanip.sim.scenarios import Scenario, save_scenario_file

__all__ = ["ActionOutcome", "StackError", "StackRun", "harness_bus"]

SERVICES = ("sim", "locomotion", "manipulation")
QUIET_SIM = (
    "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
    "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
)  # fmt: skip
CAMERAS_ONLY = (
    "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
)  # fmt: skip
LIDAR_ONLY = (
    "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
    "--set", "ground_truth.contacts_rate=0",
)  # fmt: skip
STAND_HEIGHT_M = 0.25  # base height above which the robot counts as standing
LEVEL_DEG = 0.5  # ... and level once tilted less than this
SETTLE_MAX_S = 4.0  # sim seconds to wait for that


def harness_bus(endpoint: str) -> Bus:
    """The harness's own peer session on a private stack's router (ignores QM_ZENOH_*)."""
    return observer_bus(endpoint)


class StackError(RuntimeError):
    """The stack did not come up or stopped answering (the message carries its logs)."""


class ActionOutcome:
    """What one manipulation action did: accepted, its final status and reason, sim times."""

    def __init__(
        self,
        accepted: bool,
        status: str,
        reason: str,
        t_goal: float,
        t_end: float,
        feedback: Sequence[m.ActionFeedback] = (),
        result: m.Message | None = None,
    ) -> None:
        self.accepted = accepted
        self.result = result  # the ActionResult's message (e.g. perception's GraspGoal)
        self.status = status
        self.reason = reason
        self.t_goal = t_goal
        self.t_end = t_end
        self.feedback = list(feedback)

    def stage_time(self, prefix: str) -> float | None:
        """Sim time of the first feedback whose text starts with ``prefix`` (None: none)."""
        return next((float(f.stamp) for f in self.feedback if f.text.startswith(prefix)), None)

    @property
    def ok(self) -> bool:
        return self.accepted and self.status == "succeeded"

    @property
    def duration(self) -> float:
        return self.t_end - self.t_goal

    def __repr__(self) -> str:
        return f"ActionOutcome({self.status!r}, {self.reason!r}, {self.duration:.1f} s)"


class StackRun:
    """Context manager: the three services on a private router for ``scenario``.

    ``log`` receives every child's output, prefixed by its name. ``extra_args`` adds
    command-line arguments per service (e.g. ``{"sim": ["--set", "..."]}``); ``services``
    chooses which run (the sim and locomotion at least), ``sim_sensors`` the sim's sensor
    settings (default: cameras and LiDAR off; :data:`LIDAR_ONLY` for navigation).
    """

    def __init__(
        self,
        scenario: Scenario,
        log: TextIO,
        extra_args: dict[str, Sequence[str]] | None = None,
        stand_timeout_s: float = 120.0,
        services: Sequence[str] = SERVICES,
        sim_sensors: Sequence[str] = QUIET_SIM,
    ) -> None:
        self.scenario = scenario
        self.services = tuple(services)
        self.sim_sensors = list(sim_sensors)
        self.log = log
        self.extra_args = {k: list(v) for k, v in (extra_args or {}).items()}
        self.stand_timeout_s = stand_timeout_s
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self.launcher: Launcher | None = None
        self.bus: Bus | None = None
        self.t_wall = time.monotonic()

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> StackRun:
        self._tmp = tempfile.TemporaryDirectory(prefix="qm-stack-")
        scn = save_scenario_file(self.scenario, Path(self._tmp.name) / "scenario.toml")
        args = {
            "sim": ["--lockstep", "--scenario", str(scn), *self.sim_sensors],
            "locomotion": ["--set", "node.start_mode=stand"],
            "manipulation": [],
        }
        for k, v in self.extra_args.items():
            args[k] = args.get(k, []) + v
        endpoint = free_endpoint()
        self.launcher = Launcher(
            listen=endpoint,
            services=list(self.services),
            service_args={k: v for k, v in args.items() if k in self.services},
            out=self.log,
        )
        try:
            self.launcher.start()
            self.bus = harness_bus(self.launcher.connect or endpoint)
            self._wire()
            self._wait_standing()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        if self.launcher is not None:
            self.launcher.stop()
            self.launcher = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def _wire(self) -> None:
        bus = self.bus
        assert bus is not None
        self.objs = bus.latest("sim/gt/objects")
        self.base = bus.latest("sim/gt/base")
        self.drawers = bus.latest("sim/gt/drawers")
        self.judge = bus.latest("sim/gt/judge")
        self.clock = bus.latest("sim/clock")
        self.payload = bus.latest("locomotion/payload")
        self.health = bus.latest("locomotion/health")
        self.vel = bus.publisher("locomotion/cmd_vel")
        self.actions = {
            n: bus.action_client(a.service, n)
            for a in keys.ACTIONS.values()
            if a.service in self.services
            for n in (a.action,)
        }

    def _check_alive(self) -> None:
        """A child that died, or locomotion's safety trip, ends the trial with its reason
        (a tripped robot ignores velocity commands: the walk would only time out)."""
        assert self.launcher is not None
        dead = self.launcher.dead_child()
        if dead is not None:
            raise StackError(
                f"{dead.name} exited (code {dead.proc.returncode if dead.proc else '?'})"
            )
        h = self.health.get() if "locomotion" in self.services else None
        if h is not None and h.state == "tripped":
            raise StackError(f"locomotion tripped at {h.stamp:.2f} s: {h.reason}")

    def _wait_standing(self) -> None:
        assert self.bus is not None
        deadline = time.monotonic() + self.stand_timeout_s
        last = self.services[-1]
        while last not in self.bus.alive_services(0.5) or self.base.get() is None:
            self._check_alive()
            if time.monotonic() > deadline:
                raise StackError("the services did not come up")
            time.sleep(0.1)
        while self.pose("base")[0][2] < STAND_HEIGHT_M:
            self._check_alive()
            if time.monotonic() > deadline:
                raise StackError("the robot did not stand up")
            time.sleep(0.1)
        self.wait_sim(self.now() + 1.0)
        t_level = self.now() + SETTLE_MAX_S  # the stand-up's pitch transient dies out
        while self.tilt_deg() > LEVEL_DEG and self.now() < t_level:
            self.wait_sim(self.now() + 0.1)

    # ------------------------------------------------------------------ ground truth
    def now(self) -> float:
        """Sim time of the newest clock message (-1 before the first)."""
        c = self.clock.get()
        return -1.0 if c is None else float(c.stamp)

    def wait_sim(self, t: float, timeout_s: float = 120.0) -> None:
        """Block until sim time reaches ``t``."""
        deadline = time.monotonic() + timeout_s
        while self.now() < t:
            self._check_alive()
            if time.monotonic() > deadline:
                raise StackError(f"sim stuck before t={t:.2f}")
            time.sleep(0.02)

    def pose(self, name: str, cache: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """GROUND TRUTH world position and quaternion of ``base``, an object or a drawer
        handle (``cache=self.drawers``)."""
        msg = (cache or (self.base if name == "base" else self.objs)).get()
        if msg is None:
            raise StackError("no ground truth yet")
        i = list(msg.names).index(name)
        return np.asarray(msg.positions[i], dtype=float), np.asarray(msg.orientations[i])

    def base_frame(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Base position, the rotation of the *level* body frame (the base's heading only)
        and the heading, from ground truth.

        Goals go to manipulation in this frame: the service plans for a level trunk (what
        locomotion holds while the arm works), and the trunk's pitch at the moment a goal
        is computed (a transient of 1-3 deg right after standing up) would otherwise move
        a target 0.35 m ahead by 1-2 cm in height.
        """
        p, q = self.pose("base")
        yaw = yaw_from_quat(q)
        return p, rot_z(yaw), yaw

    def tilt_deg(self) -> float:
        """The trunk's tilt from level (deg, ground truth)."""
        r = quat_to_mat(self.pose("base")[1])
        return math.degrees(math.acos(float(np.clip(r[2, 2], -1.0, 1.0))))

    def to_base(self, p_world: np.ndarray) -> np.ndarray:
        """A world point in the level body frame (see :meth:`base_frame`)."""
        bp, br, _ = self.base_frame()
        return br.T @ (np.asarray(p_world, dtype=float) - bp)

    def min_height(self, name: str, seconds: float) -> float:
        """Lowest true height of object ``name`` over the next ``seconds`` of sim time."""
        t = self.now()
        low = math.inf
        while self.now() < t + seconds:
            self._check_alive()
            low = min(low, float(self.pose(name)[0][2]))
            time.sleep(0.05)
        return low

    def in_place(self, name: str, within_s: float = 4.0) -> bool:
        """The sim judge's verdict on ``name`` (placed as a referee means it, see
        ``quadmanip.sim.judge``): True at the first report within ``within_s`` of sim
        time that says so. :meth:`judged` then tells where the judge last saw it."""
        t_end = self.now() + within_s
        seen = -1.0
        while True:
            r = self.judge.get()
            if r is not None and r.stamp > seen:
                seen = float(r.stamp)
                if name in r.in_place:
                    return True
                if seen >= t_end:
                    return False
            self.wait_sim(self.now() + 0.05)

    def judged(self, name: str) -> tuple[str | None, str]:
        """Where the judge's latest report has ``name`` and why it is not placed."""
        r = self.judge.get()
        if r is None or name not in r.objects:
            return None, ""
        i = r.objects.index(name)
        return r.locations[i], r.notes[i]

    # ------------------------------------------------------------------ navigation stand-in
    def stop(self) -> None:
        """Zero velocity, then 1.5 s for the gait to settle."""
        for _ in range(10):
            self.vel.publish(m.BodyVelocityCommand(stamp=self.now(), vx=0.0, vy=0.0, wz=0.0))
            time.sleep(0.02)
        self.wait_sim(self.now() + 1.5)

    def walk(
        self,
        waypoints: Sequence[tuple[float, float, float]],
        tol: float = 0.03,
        sim_timeout: float = 40.0,
    ) -> None:
        """Drive through (x, y, yaw) waypoints on ground truth; the last one to within
        ``tol`` and 0.05 rad, the others to within 15 cm."""
        t_end = self.now() + sim_timeout
        for k, (gx, gy, gyaw) in enumerate(waypoints):
            last = k == len(waypoints) - 1
            while True:
                bp, _, yaw = self.base_frame()
                dx, dy = gx - bp[0], gy - bp[1]
                ex = math.cos(yaw) * dx + math.sin(yaw) * dy
                ey = -math.sin(yaw) * dx + math.cos(yaw) * dy
                dist = math.hypot(dx, dy)
                eyaw = wrap_angle(gyaw - yaw)
                if (last and dist < tol and abs(eyaw) < 0.05) or (not last and dist < 0.15):
                    break
                self._check_alive()
                if self.now() > t_end:
                    raise StackError(f"walk to ({gx:.2f}, {gy:.2f}) stuck at {bp[:2].round(3)}")
                if dist > 0.35:  # face the waypoint and walk
                    eh = wrap_angle(math.atan2(dy, dx) - yaw)
                    wz = float(np.clip(1.5 * eh, -0.8, 0.8))
                    vx = float(np.clip(0.8 * ex, 0.0, 0.4)) if abs(eh) < 0.4 else 0.0
                    vy = float(np.clip(1.0 * ey, -0.1, 0.1))
                else:  # close: holonomic, final heading
                    wz = float(np.clip(1.5 * eyaw, -0.6, 0.6))
                    vx = float(np.clip(1.0 * ex, -0.25, 0.25))
                    vy = float(np.clip(1.0 * ey, -0.15, 0.15))
                self.vel.publish(m.BodyVelocityCommand(stamp=self.now(), vx=vx, vy=vy, wz=wz))
                time.sleep(0.05)
        self.stop()

    def face(
        self, target_xy: Sequence[float], heading: float, standoff: float, tol: float = 0.03
    ) -> None:
        """Walk so that ``target_xy`` lies ``standoff`` ahead on the body axis, at ``heading``."""
        gx = target_xy[0] - standoff * math.cos(heading)
        gy = target_xy[1] - standoff * math.sin(heading)
        self.walk([(gx, gy, heading)], tol)

    # ------------------------------------------------------------------ actions
    def act(self, action: str, goal: m.Message, timeout_s: float = 300.0) -> ActionOutcome:
        """Send ``goal`` to action ``action`` (of any service in the stack) and wait for
        its result."""
        t0 = self.now()
        h = self.actions[action].send_goal(goal, timeout=5.0)
        if not h.accepted:
            return ActionOutcome(False, "rejected", h.reason, t0, self.now())
        deadline = time.monotonic() + timeout_s
        res = None
        while res is None:
            self._check_alive()
            if time.monotonic() > deadline:
                raise StackError(f"{action}: no result after {timeout_s:.0f} s")
            res = h.result(timeout=0.5)
        return ActionOutcome(True, res.status, res.reason, t0, self.now(), h.feedback, res.result)

    def place_within_reach(
        self, target: np.ndarray, yaw: float | None = None, attempts: int = 4
    ) -> tuple[ActionOutcome, int]:
        """``place`` at world point ``target``; when manipulation rejects it as out of
        reach (``too_far`` / ``too_close``) step 5 cm closer / back on the body axis and
        ask again, as a task does. Returns the last outcome and the number of steps."""
        steps = 0
        while True:
            goal = m.PlaceGoal(
                stamp=self.now(),
                position=self.to_base(target),
                yaw=0.0 if yaw is None else yaw,
                turn=yaw is not None,
            )
            out = self.act("place", goal)
            reach = [r for r in ("too_far", "too_close") if r in out.reason]
            if out.accepted or not reach or steps + 1 >= attempts:
                return out, steps
            step_m = 0.05 if reach[0] == "too_far" else -0.05
            _, _, heading = self.base_frame()
            self.face(target[:2], heading, float(self.to_base(target)[0]) - step_m, tol=0.015)
            steps += 1

    def posture(self, name: str) -> ActionOutcome:
        """``move_to_posture``: stow, carry, floor_search, ..."""
        return self.act("move_to_posture", m.PostureGoal(stamp=self.now(), posture=name))

    def payload_kg(self) -> float | None:
        """The mass manipulation last told locomotion the gripper holds (None: not yet)."""
        p = self.payload.get()
        return None if p is None else float(p.mass)

    def elapsed(self) -> str:
        """Sim and wall time since the stack was created, for progress lines."""
        return f"sim {self.now():.1f} s, wall {time.monotonic() - self.t_wall:.0f} s"
