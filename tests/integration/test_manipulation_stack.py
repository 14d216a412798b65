"""Issue 5 acceptance over the real stack: sim, locomotion and manipulation as processes.

One stack for the module (a real router on a free loopback port; ``quadmanip service sim
--lockstep`` through the test launcher ``stack_sim`` that only sets the robot's start pose
and adds drawer ground truth; ``quadmanip service locomotion``; ``quadmanip service
manipulation``), scenario ``paper-2``, the robot starting in the kitchen in front of the
cabinet. The test plays navigation (velocity commands from the ground-truth base pose)
and perception (grasp poses from ground-truth object poses, ``grasp_from_poses``); the
manipulation service does everything else through the sim's actuator layer (arm, gripper)
and locomotion's body-pose interface (moveCOM, crouch). Success is judged from ground
truth. In order, as the paper does (Section 7.2, drawers first):

1. open the top drawer >= 15 cm;
2. table grasp (tomato soup can on the kitchen table), lifted >= 10 cm;
3. carry it to the deposit table and place it into the tray (its category's place);
4. floor grasp (padlock), lifted >= 10 cm and held for 3 s.
"""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.services.manipulation.sim_harness import TABLE_HEIGHT, grasp_from_poses
from quadmanip.sim.world.house import load_house
from quadmanip.sim.world.objects import load_catalogue

pytestmark = pytest.mark.integration

SCENARIO = "paper-2"
# in front of the top drawer: handle (9.46, 1.5) minus arm mount (0.06) minus 0.44 m
START = (8.96, 1.5, 0.0)
SIM_ARGS = (
    "-m", "quadmanip.services.manipulation.stack_sim", "--lockstep", "--scenario", SCENARIO,
    "--robot-start", *map(str, START),
    "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
    "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
)  # fmt: skip
LOCO_ARGS = ("-m", "quadmanip.cli", "service", "locomotion", "--set", "node.start_mode=stand")
MANIP_ARGS = ("-m", "quadmanip.cli", "service", "manipulation")


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _rot(q: np.ndarray) -> np.ndarray:
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(q, dtype=float))
    return r.reshape(3, 3)


class Stack:
    """The test's view of the running stack: ground truth, clock, actions, walking."""

    def __init__(self, bus, procs) -> None:
        self.procs = procs
        self.objs = bus.latest("sim/gt/objects", m.GroundTruthPoses)
        self.base = bus.latest("sim/gt/base", m.GroundTruthPoses)
        self.drawers = bus.latest("sim/gt/drawers", m.GroundTruthPoses)
        self.clock = bus.latest("sim/clock", m.Clock)
        self.vel = bus.publisher("locomotion/cmd_vel", m.BodyVelocityCommand)
        self.actions = {
            n: bus.action_client("manipulation", n)
            for n in ("grasp", "place", "open_drawer", "move_to_posture")
        }
        self.t_wall = time.monotonic()

    def now(self) -> float:
        c = self.clock.get()
        return -1.0 if c is None else float(c.stamp)

    def logs(self) -> str:
        return "\n".join("\n".join(p.lines[-12:]) for p in self.procs)

    def wait_sim(self, t: float, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while self.now() < t:
            assert time.monotonic() < deadline, f"sim stuck before t={t}\n{self.logs()}"
            time.sleep(0.02)

    def pose(self, name: str, cache=None) -> tuple[np.ndarray, np.ndarray]:
        msg = (cache or (self.base if name == "base" else self.objs)).get()
        assert msg is not None
        i = list(msg.names).index(name)
        return np.asarray(msg.positions[i], dtype=float), np.asarray(msg.orientations[i])

    def base_frame(self) -> tuple[np.ndarray, np.ndarray, float]:
        p, q = self.pose("base")
        r = _rot(q)
        return p, r, math.atan2(r[1, 0], r[0, 0])

    def to_base(self, p_world: np.ndarray) -> np.ndarray:
        bp, br, _ = self.base_frame()
        return br.T @ (np.asarray(p_world, dtype=float) - bp)

    def stop(self) -> None:
        for _ in range(10):
            self.vel.publish(m.BodyVelocityCommand(stamp=self.now(), vx=0.0, vy=0.0, wz=0.0))
            time.sleep(0.02)
        self.wait_sim(self.now() + 1.5)

    def walk(
        self, waypoints: list[tuple[float, float, float]], tol: float = 0.03, sim_timeout=40.0
    ) -> None:
        """Navigation stand-in: drive through (x, y, yaw) waypoints on ground truth; the
        last one to within ``tol`` / 0.05 rad, the others to within 15 cm."""
        t_end = self.now() + sim_timeout
        for k, (gx, gy, gyaw) in enumerate(waypoints):
            last = k == len(waypoints) - 1
            while True:
                bp, _, yaw = self.base_frame()
                dx, dy = gx - bp[0], gy - bp[1]
                ex = math.cos(yaw) * dx + math.sin(yaw) * dy
                ey = -math.sin(yaw) * dx + math.cos(yaw) * dy
                dist = math.hypot(dx, dy)
                eyaw = _wrap(gyaw - yaw)
                if (last and dist < tol and abs(eyaw) < 0.05) or (not last and dist < 0.15):
                    break
                assert self.now() < t_end, f"walk to {gx, gy} stuck at {bp[:2]}\n{self.logs()}"
                if dist > 0.35:  # face the waypoint and walk
                    eh = _wrap(math.atan2(dy, dx) - yaw)
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

    def face(self, target_xy, heading: float, standoff: float, tol: float = 0.03) -> None:
        """Walk so that ``target_xy`` lies ``standoff`` ahead on the body axis."""
        gx = target_xy[0] - standoff * math.cos(heading)
        gy = target_xy[1] - standoff * math.sin(heading)
        self.walk([(gx, gy, heading)], tol)

    def act(self, action: str, goal: m.Message, timeout: float = 300.0) -> m.ActionResult:
        h = self.actions[action].send_goal(goal, timeout=5.0)
        assert h.accepted, f"{action} rejected: {h.reason}"
        res = h.result(timeout=timeout)
        assert res is not None, f"{action}: no result\n{self.logs()}"
        assert res.status == "succeeded", f"{action}: {res.status} {res.reason}\n{self.logs()}"
        return res

    def grasp(self, name: str, surface_z: float) -> float:
        """Grasp ``name`` with a pose from ground truth; returns its resting height."""
        p, q = self.pose(name)
        bp, br, _ = self.base_frame()
        gs = grasp_from_poses(load_catalogue(), name, p, _rot(q), bp, br, surface_z)
        goal = m.GraspGoal(
            stamp=self.now(),
            position=gs.position_base,
            yaw=gs.yaw,
            approach=gs.approach,
            width=gs.width,
            object_name=name,
        )
        self.act("grasp", goal)
        return float(p[2])

    def min_height(self, name: str, seconds: float) -> float:
        t = self.now()
        low = math.inf
        while self.now() < t + seconds:
            low = min(low, float(self.pose(name)[0][2]))
            time.sleep(0.05)
        return low

    def mark(self, what: str) -> None:
        print(f"{what}: sim {self.now():.1f} s, wall {time.monotonic() - self.t_wall:.0f} s")


def test_drawer_table_grasp_place_floor_grasp_over_the_stack(zenoh_router, spawn, bus_factory):
    ep = zenoh_router
    procs = [
        spawn(*SIM_ARGS, endpoint=ep, env={"MUJOCO_GL": "egl"}),
        spawn(*LOCO_ARGS, endpoint=ep),
        spawn(*MANIP_ARGS, endpoint=ep),
    ]
    bus = bus_factory(ep)
    s = Stack(bus, procs)
    s.wait_sim(3.0, 180.0)
    deadline = time.monotonic() + 60
    while "manipulation" not in bus.alive_services(0.5):
        assert time.monotonic() < deadline, s.logs()
    deadline = time.monotonic() + 60
    while s.pose("base")[0][2] < 0.25:  # standing up from the start keyframe
        assert time.monotonic() < deadline, s.logs()
        time.sleep(0.1)
    s.wait_sim(s.now() + 1.0)
    s.mark("stack up")

    # 1. the top drawer, >= 15 cm (paper: drawers first)
    h0, _ = s.pose("top", s.drawers)
    s.face(h0[:2], 0.0, 0.51, tol=0.012)  # square to the drawer, handle ~0.45 m ahead of the arm
    _, br, _ = s.base_frame()
    s.act(
        "open_drawer",
        m.DrawerGoal(
            stamp=s.now(),
            handle_position=s.to_base(h0),
            pull_direction=br.T @ np.array([-1.0, 0.0, 0.0]),
            distance=0.15,
        ),
    )
    s.wait_sim(s.now() + 1.0)
    opened = float(h0[0] - s.pose("top", s.drawers)[0][0])
    s.mark(f"drawer opened {opened:.3f} m")
    assert opened >= 0.15, f"top drawer opened only {opened:.3f} m"

    # 2. table grasp: the tomato soup can, from the kitchen table's north side
    s.act("move_to_posture", m.PostureGoal(stamp=s.now(), posture="stow"))
    can = "tomato_soup_can"
    cp, _ = s.pose(can)
    s.walk([(8.0, 2.6, math.pi)])  # round the table's north-east corner
    s.face(cp[:2], -math.pi / 2, 0.40)  # the table edge 0.27 m ahead
    z0 = s.grasp(can, TABLE_HEIGHT)
    lift = s.min_height(can, 1.0) - z0
    s.mark(f"table grasp {can}: lifted {lift:.3f} m")
    assert lift >= 0.10, f"{can} only {lift:.3f} m above the table"

    # 3. carry it to the tray on the deposit table and place it there
    s.act("move_to_posture", m.PostureGoal(stamp=s.now(), posture="carry"))
    tray = next(c for c in load_house().containers if c.name == "tray")
    ix, iy = tray.size[1] / 2 - tray.wall, tray.size[0] / 2 - tray.wall  # robot faces +y
    s.face(tray.center, math.pi / 2, 0.55)
    target = np.array([tray.center[0], tray.center[1] - 0.6 * ix, TABLE_HEIGHT + tray.size[2]])
    s.act("place", m.PlaceGoal(stamp=s.now(), position=s.to_base(target)))
    s.wait_sim(s.now() + 1.0)
    end, _ = s.pose(can)
    s.mark(f"placed {can} at {np.round(end, 3)}")
    assert abs(end[0] - tray.center[0]) < iy and abs(end[1] - tray.center[1]) < ix, end
    assert TABLE_HEIGHT < end[2] < TABLE_HEIGHT + 0.15, end

    # 4. floor grasp: the padlock, lifted 10 cm and held for 3 s
    lock = "padlock"
    lp, _ = s.pose(lock)
    s.face(lp[:2], math.pi / 2, 0.36)
    z0 = s.grasp(lock, 0.0)
    lift = s.min_height(lock, 3.0) - z0
    s.mark(f"floor grasp {lock}: lifted {lift:.3f} m for 3 s")
    assert lift >= 0.10, f"{lock} only {lift:.3f} m above the floor"
