"""A kinematic stand-in for the sim and locomotion, for testing navigation over Zenoh fast.

TEST HARNESS ONLY (it knows the true floor plan). It subscribes to
``locomotion/cmd_vel`` and moves a planar body with a first-order velocity lag and a small
creep, then publishes what navigation reads: ``locomotion/odometry`` (50 Hz, the odom
frame at the start pose, with an optional scale error), ``sim/scan`` (10 Hz, simulated on
the floor plan plus any extra obstacles) and ``sim/clock``. Time runs with the wall clock.
It counts contacts: moments the body's footprint overlaps an occupied cell.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.bus import Bus
from quadmanip.common.rotations import quat_from_yaw
from quadmanip.services.navigation.grid import Pose2, compose, invert, wrap
from quadmanip.services.navigation.scan import lidar_mount
from quadmanip.testbench.floor_plan import FloorPlan, simulate_scan

__all__ = ["KinematicRobot", "RobotModel"]


@dataclass(frozen=True)
class RobotModel:
    """The body's response: velocity time constant, creep noise, odometry scale error,
    footprint (trunk) for contact counting, command timeout like locomotion's."""

    lag: float = 0.25
    creep: float = 0.005  # m/s std of the velocity noise
    odom_scale: float = 1.0
    length: float = 0.419
    width: float = 0.2505
    cmd_timeout: float = 0.15


class KinematicRobot:
    """Run with ``start()``; ``pose`` is the true (world) pose; ``stop()`` ends it."""

    def __init__(
        self,
        bus: Bus,
        plan: FloorPlan,
        start: Pose2,
        model: RobotModel | None = None,
        seed: int = 0,
    ) -> None:
        self.bus = bus
        self.plan = plan
        self.model = model or RobotModel()
        self.pose: Pose2 = start
        self.start_pose = start
        self.vel = np.zeros(3)
        self.cmd = np.zeros(3)
        self.t_cmd = -math.inf
        self.t = 0.0
        self.rng = np.random.default_rng(seed)
        self.mount = lidar_mount()
        self.odom: Pose2 = (0.0, 0.0, 0.0)
        self.publish_odometry = True
        self.publish_scans = True
        self.contacts = 0
        self.commands = 0
        self.last_cmd: m.BodyVelocityCommand | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pub_odom = bus.publisher("locomotion/odometry")
        self._pub_scan = bus.publisher("sim/scan")
        self._pub_clock = bus.publisher("sim/clock")
        bus.subscribe("locomotion/cmd_vel", self._on_cmd)

    def _on_cmd(self, msg: m.BodyVelocityCommand) -> None:
        self.cmd = np.array([msg.vx, msg.vy, msg.wz])
        self.t_cmd = self.t
        self.commands += 1
        self.last_cmd = msg

    def start(self) -> KinematicRobot:
        """Start the 50 Hz loop in a thread."""
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the loop."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def _touching(self) -> bool:
        x, y, yaw = self.pose
        hx, hy = self.model.length / 2, self.model.width / 2
        u = np.linspace(-1, 1, 9)
        local = np.concatenate(
            [
                np.stack([u * hx, np.full(9, hy)], 1),
                np.stack([u * hx, np.full(9, -hy)], 1),
                np.stack([np.full(9, hx), u * hy], 1),
                np.stack([np.full(9, -hx), u * hy], 1),
            ]
        )
        c, s = math.cos(yaw), math.sin(yaw)
        pts = np.stack([x + c * local[:, 0] - s * local[:, 1],
                        y + s * local[:, 0] + c * local[:, 1]], 1)  # fmt: skip
        return bool(self.plan.occupied(pts).any())

    def _loop(self) -> None:
        dt = 0.02
        k = 0
        next_t = time.monotonic()
        was_touching = False
        while not self._stop.is_set():
            cmd = self.cmd if self.t - self.t_cmd <= self.model.cmd_timeout else np.zeros(3)
            a = dt / self.model.lag
            self.vel = self.vel + a * (cmd - self.vel)
            v = self.vel + self.rng.normal(0.0, self.model.creep, 3) * np.array([1, 1, 0.5])
            step = (v[0] * dt, v[1] * dt, v[2] * dt)
            self.pose = compose(self.pose, step)
            s = self.model.odom_scale
            self.odom = compose(self.odom, (step[0] * s, step[1] * s, step[2]))
            self.t += dt
            touching = self._touching()
            if touching and not was_touching:
                self.contacts += 1
            was_touching = touching
            if self.publish_odometry:
                self._pub_odom.publish(
                    m.Odometry(
                        stamp=self.t,
                        position=np.array([self.odom[0], self.odom[1], 0.3]),
                        orientation=quat_from_yaw(self.odom[2]),
                        linear_velocity=np.array([v[0], v[1], 0.0]),
                        angular_velocity=np.array([0.0, 0.0, v[2]]),
                    )
                )
            self._pub_clock.publish(m.Clock(stamp=self.t))
            if self.publish_scans and k % 5 == 0:
                lp = compose(self.pose, self.mount)
                ranges = simulate_scan(self.plan, lp, rng=self.rng)
                self._pub_scan.publish(
                    m.LaserScan(
                        stamp=self.t,
                        angle_min=-math.pi,
                        angle_increment=2 * math.pi / len(ranges),
                        range_min=0.1,
                        range_max=12.0,
                        ranges=ranges.astype(np.float32),
                    )
                )
            k += 1
            next_t += dt
            time.sleep(max(0.0, next_t - time.monotonic()))

    def error_to(self, goal: Pose2) -> tuple[float, float]:
        """True position and heading error (m, rad) to a world pose."""
        return (
            math.hypot(goal[0] - self.pose[0], goal[1] - self.pose[1]),
            abs(float(wrap(goal[2] - self.pose[2]))),
        )

    def odom_of(self, world: Pose2) -> Pose2:
        """A world pose in this robot's odometry frame (exact when odom_scale is 1)."""
        return compose(invert(self.start_pose), world)
