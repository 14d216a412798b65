"""The demo's operator: until the task service exists, someone has to tell the robot what to do.

`quadmanip demo` plays the operator a person would be at a console: stand up, trot forward,
trot in a curve, stop. Commands are timed in robot time (``sim/clock``), so the script is
the same whether the sim runs in lockstep or in real time, and they go over the same keys
navigation will use (``locomotion/mode``, ``locomotion/cmd_vel``, at 20 Hz, as the
locomotion service expects ≥ 10 Hz). Ground truth is read only to show, next to the
robot's own odometry, where it really went.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.rotations import yaw_from_quat


@dataclass(frozen=True)
class ScriptStep:
    """From ``start`` seconds of robot time on: this mode and body velocity (vx, vy, wz)."""

    start: float
    label: str
    velocity: tuple[float, float, float] | None  # None: no velocity commands (stand still)


# Stand-up takes ~1.5 s; then 5 s straight, 4 s on a curve, and stop (commands cease).
WALK_SCRIPT: tuple[ScriptStep, ...] = (
    ScriptStep(0.0, "stand up", None),
    ScriptStep(3.0, "trot forward 0.3 m/s", (0.3, 0.0, 0.0)),
    ScriptStep(8.0, "trot on a curve 0.2 m/s, 0.5 rad/s", (0.2, 0.0, 0.5)),
    ScriptStep(12.0, "stop and stand", None),
)


class DemoOperator:
    """Sends the script's commands on the bus from a thread; reports progress lines."""

    def __init__(
        self, bus: object, script: tuple[ScriptStep, ...] = WALK_SCRIPT, rate_hz: float = 20.0
    ) -> None:
        self._bus = bus
        self._script = script
        self._period = 1.0 / rate_hz
        self._clock = bus.latest("sim/clock")  # type: ignore[attr-defined]
        self._odom = bus.latest("locomotion/odometry")  # type: ignore[attr-defined]
        self._gt = bus.latest("sim/gt/base")  # type: ignore[attr-defined]
        self._pub_mode = bus.publisher("locomotion/mode")  # type: ignore[attr-defined]
        self._pub_vel = bus.publisher("locomotion/cmd_vel")  # type: ignore[attr-defined]
        self._t0: float | None = None
        self._step = -1
        self._gt_start: np.ndarray | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="demo-operator", daemon=True)
        self._thread.start()

    def _now(self) -> float | None:
        clock = self._clock.get()
        return None if clock is None else float(clock.stamp)

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            now = self._now()
            if now is None:
                continue
            if self._t0 is None:
                self._t0 = now
            t = now - self._t0
            step = max(i for i, s in enumerate(self._script) if s.start <= t)
            if step == 0:
                # Repeated while standing up: a single message could go out before
                # locomotion's subscription is matched (both start together); "stand" is
                # idempotent.
                self._pub_mode.publish(m.LocomotionMode(stamp=now, mode="stand"))
            if step != self._step:
                self._step = step
                if step > 0 and self._gt_start is None:
                    self._gt_start = self.true_position()  # where the walk begins
            vel = self._script[step].velocity
            if vel is not None:
                vx, vy, wz = vel
                self._pub_vel.publish(m.BodyVelocityCommand(stamp=now, vx=vx, vy=vy, wz=wz))

    def true_position(self) -> np.ndarray | None:
        """The robot base's true position (display only)."""
        gt = self._gt.get()
        if gt is None or "base" not in gt.names:
            return None
        return np.asarray(gt.positions[list(gt.names).index("base")], dtype=float)

    def walked_m(self) -> float | None:
        """Straight-line distance the base really moved since the walk began (m)."""
        pos = self.true_position()
        if pos is None or self._gt_start is None:
            return None
        return float(np.linalg.norm(pos[:2] - self._gt_start[:2]))

    def lines(self) -> list[str]:
        """Progress for the demo's table."""
        now = self._now()
        if now is None or self._t0 is None:
            return ["operator: waiting for sim/clock"]
        step = self._script[max(self._step, 0)]
        out = [f"operator: t={now - self._t0:5.1f} s robot time: {step.label}"]
        odom = self._odom.get()
        if odom is not None:
            x, y, _ = odom.position
            yaw = math.degrees(yaw_from_quat(odom.orientation))
            out.append(f"odometry: x={x:+.2f} m y={y:+.2f} m yaw={yaw:+.0f}°")
        walked = self.walked_m()
        pos = self.true_position()
        if walked is not None and pos is not None:
            out.append(
                f"ground truth (display only): base at ({pos[0]:.2f}, {pos[1]:.2f}, "
                f"{pos[2]:.2f}) m, {walked:.2f} m from the start"
            )
        return out

    def stop(self) -> None:
        """Stop sending commands (the robot then stops and stands)."""
        self._stop.set()
        self._thread.join(timeout=1.0)
