"""``quadmanip service sim``: the simulator as a Zenoh node (the robot's stand-in).

It speaks exactly the keys a hardware adapter would (docs/architecture.md, "Processes and
ownership"): LowState every control tick on ``sim/lowstate``, ``sim/clock``, RGB-D frames on
``sim/camera/front`` and ``sim/camera/gripper``, LiDAR on ``sim/scan``; it takes
``sim/leg_command``, ``sim/arm_trajectory``, ``sim/gripper_command`` and the software
emergency stop ``sim/estop`` (latched damping of legs and arm, as on the hardware adapter). Ground truth goes
only under ``sim/gt/**`` (base, object and drawer-handle poses, contacts, the judge's report), and the
test-only ``sim/test/disturbance`` is obeyed only when ``allow_test_disturbance`` is set.

Threading: Zenoh callbacks only put commands into inboxes; one loop thread owns the engine
(MuJoCo data and the OpenGL context), so no lock ever guards physics. Cameras render in
that loop at their sensor ticks: deterministic, and cheap enough not to stall control.

``sim/status`` (``status_rate``) tells the controller how its answers arrive: the age in
ticks of the leg command applied at each tick, ticks that reused an old command, and the
leg-command timeouts (legs fell back to damping), which also go into the judge's report.

Modes:

* ``realtime``: free-running, each tick scheduled at ``tick * dt / realtime_factor`` of
  wall time; the newest leg command is used. If the machine cannot keep up, the schedule
  is reset instead of bursting to catch up. The achieved RTF is logged every
  ``rtf_log_period`` seconds. The loop runs at real-time priority where the OS allows
  (``[scheduling]``, common/scheduling.py), as a robot's actuator loop does.
* ``lockstep``: after publishing LowState tick k the sim waits for a LegCommand whose
  ``tick`` is k, then advances one tick (as fast as the machine allows). With no
  controller running it waits forever: it logs "waiting for leg command" every
  ``lockstep_log_period`` seconds and republishes the last LowState every
  ``lockstep_republish_period`` seconds so a controller started late still gets tick k.
"""

from __future__ import annotations

import argparse
import collections
import threading
import time
from typing import Any

from quadmanip.common import messages as msg
from quadmanip.common.link_stats import LinkStats
from quadmanip.common.robot_description import FRONT_CAMERA, GRIPPER_CAMERA
from quadmanip.common.scheduling import SchedulingConfig
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.sim.engine import SimConfig, SimEngine, TickOutput

CAMERA_TOPICS = {FRONT_CAMERA: "sim/camera/front", GRIPPER_CAMERA: "sim/camera/gripper"}


def load_world(scenario: str) -> Any:
    """Build the house with the named scenario (``paper-1``..``paper-5``, ``seed-N``, N)."""
    from quadmanip.sim.scenarios import get_scenario
    from quadmanip.sim.world import build_world

    return build_world(get_scenario(scenario))


class SimNode(Service):
    """MuJoCo simulator serving the robot's keys (physics 1 kHz, control 500 Hz)."""

    name = "sim"
    config_type = SimConfig
    inputs = (
        Input("sim/leg_command", doc="leg PD + feed-forward, echoes tick"),
        Input("sim/arm_trajectory", doc="arm joint trajectory"),
        Input("sim/gripper_command", doc="finger gap + force limit"),
        Input("sim/test/disturbance", doc="TEST ONLY, needs the config flag"),
        Input("sim/estop", doc="software e-stop: latched damping until reset"),
    )
    outputs = (
        Output("sim/clock"),
        Output("sim/lowstate"),
        Output("sim/camera/front"),
        Output("sim/camera/gripper"),
        Output("sim/scan"),
        Output("sim/status"),
        Output("sim/gt/base"),
        Output("sim/gt/objects"),
        Output("sim/gt/drawers"),
        Output("sim/gt/contacts"),
        Output("sim/gt/judge"),
    )

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--scenario", help="scenario name (overrides the config)")
        parser.add_argument("--lockstep", action="store_true", help="lockstep mode")
        parser.add_argument("--realtime", action="store_true", help="realtime mode")

    def __init__(self, bus: Any, config: SimConfig, args: argparse.Namespace | None = None):
        super().__init__(bus, config, args)
        mode = config.node.mode
        if args is not None and getattr(args, "lockstep", False):
            mode = "lockstep"
        if args is not None and getattr(args, "realtime", False):
            mode = "realtime"
        self.mode = mode
        self.scenario = (getattr(args, "scenario", None) if args else None) or config.scenario
        self._cond = threading.Condition()
        self._leg: msg.LegCommand | None = None
        self._leg_new = False
        self._inbox: collections.deque[msg.Message] = collections.deque()
        self.engine: SimEngine | None = None
        self._link = LinkStats()

    def scheduling(self) -> SchedulingConfig | None:
        """Real-time priority for the physics loop in realtime mode only."""
        return self.config.scheduling if self.mode == "realtime" else None

    # ---------------------------------------------------------------- callbacks
    def _on_leg(self, cmd: msg.LegCommand) -> None:
        with self._cond:
            self._leg = cmd
            self._leg_new = True
            self._cond.notify()

    def _on_other(self, m: msg.Message) -> None:
        self._inbox.append(m)

    # ------------------------------------------------------------------- setup
    def setup(self) -> None:
        t0 = time.monotonic()
        world = load_world(self.scenario)
        self.engine = SimEngine(world, self.config)
        self.bus.clock = lambda: self.engine.time if self.engine else 0.0
        self.log.info(
            "world loaded",
            scenario=self.scenario,
            objects=len(self.engine.object_names),
            mode=self.mode,
            build_s=round(time.monotonic() - t0, 2),
            test_disturbance=self.config.allow_test_disturbance,
        )
        self.pub = {o.topic: self.publisher(o.topic) for o in self.outputs}
        rates = self.config.physics.control_rate / max(self.config.node.clock_rate, 1e-9)
        self._clock_every = max(1, round(rates))
        self.subscribe("sim/leg_command", self._on_leg)
        self.subscribe("sim/arm_trajectory", self._on_other)
        self.subscribe("sim/gripper_command", self._on_other)
        self.subscribe("sim/test/disturbance", self._on_other)
        self.subscribe("sim/estop", self._on_other)

    # ------------------------------------------------------------------ output
    def _publish(self, out: TickOutput) -> None:
        """LowState (and the clock) first, then the sensors due at this tick."""
        p = self.pub
        p["sim/lowstate"].publish(out.lowstate)
        if out.tick % self._clock_every == 0:
            p["sim/clock"].publish(msg.Clock(stamp=out.stamp))
        assert self.engine is not None
        self.engine.add_sensors(out)
        for img in out.images:
            p[CAMERA_TOPICS[img.camera]].publish(img)
        if out.scan is not None:
            p["sim/scan"].publish(out.scan)
        if out.gt_poses is not None:
            g = out.gt_poses
            p["sim/gt/base"].publish(
                msg.GroundTruthPoses(
                    stamp=g.stamp,
                    names=g.names[:1],
                    positions=g.positions[:1],
                    orientations=g.orientations[:1],
                )
            )
            p["sim/gt/objects"].publish(
                msg.GroundTruthPoses(
                    stamp=g.stamp,
                    names=g.names[1:],
                    positions=g.positions[1:],
                    orientations=g.orientations[1:],
                )
            )
        if out.gt_drawers is not None:
            p["sim/gt/drawers"].publish(out.gt_drawers)
        if out.gt_contacts is not None:
            p["sim/gt/contacts"].publish(out.gt_contacts)
        if out.judge is not None:
            p["sim/gt/judge"].publish(out.judge)

    def _drain_inbox(self) -> None:
        eng = self.engine
        assert eng is not None
        while self._inbox:
            m = self._inbox.popleft()
            if isinstance(m, msg.ArmTrajectory):
                eng.apply_arm_trajectory(m)
            elif isinstance(m, msg.GripperCommand):
                eng.apply_gripper_command(m)
            elif isinstance(m, msg.Disturbance):
                eng.apply_disturbance(m)
            elif isinstance(m, msg.EmergencyStop):
                if m.engage:
                    eng.actuators.engage_estop(m.reason or "sim/estop")
                else:
                    eng.actuators.reset_estop()

    # -------------------------------------------------------------------- loop
    def run(self) -> None:
        eng = self.engine
        assert eng is not None
        eng.ensure_renderer()  # the GL context lives in this thread
        out = eng.observe(sensors=False)
        self._publish(out)
        if self.mode == "lockstep":
            self._run_lockstep(out)
        else:
            self._run_realtime()

    def _take_leg(self) -> msg.LegCommand | None:
        with self._cond:
            if not self._leg_new:
                return None
            self._leg_new = False
            return self._leg

    def _run_realtime(self) -> None:
        eng = self.engine
        assert eng is not None
        rtf = max(self.config.node.realtime_factor, 1e-3)
        period = eng.control_dt / rtf
        t_ref, tick_ref = time.monotonic(), eng.tick
        log_t, log_sim = time.monotonic(), eng.time
        status_t, status_sim = time.monotonic(), eng.time
        status_period = 1.0 / max(self.config.node.status_rate, 1e-6)
        while not self.stop_event.is_set():
            self._drain_inbox()
            leg = self._take_leg()
            self._link.record(eng.tick, leg)
            out = eng.step_tick(leg, sensors=False)
            self._publish(out)
            now = time.monotonic()
            if now - status_t >= status_period:
                self._publish_status(now - status_t, eng.time - status_sim)
                status_t, status_sim = now, eng.time
            target = t_ref + (eng.tick - tick_ref) * period
            if target > now:
                self.stop_event.wait(target - now)
            elif now - target > 0.1:  # cannot keep up: restart the schedule, no burst
                t_ref, tick_ref = now, eng.tick
            if now - log_t >= self.config.node.rtf_log_period:
                self._log_rtf(now - log_t, eng.time - log_sim)
                log_t, log_sim = now, eng.time

    def _run_lockstep(self, out: TickOutput) -> None:
        eng = self.engine
        assert eng is not None
        log_t, log_sim = time.monotonic(), eng.time
        status_t, status_sim = log_t, log_sim
        status_period = 1.0 / max(self.config.node.status_rate, 1e-6)
        while not self.stop_event.is_set():
            cmd = self._wait_answer(out)
            if cmd is None:
                break
            self._drain_inbox()
            self._link.record(eng.tick, cmd)
            out = eng.step_tick(cmd, sensors=False)
            self._publish(out)
            now = time.monotonic()
            if now - status_t >= status_period:
                self._publish_status(now - status_t, eng.time - status_sim)
                status_t, status_sim = now, eng.time
            if now - log_t >= self.config.node.rtf_log_period:
                self._log_rtf(now - log_t, eng.time - log_sim)
                log_t, log_sim = now, eng.time

    def _wait_answer(self, out: TickOutput) -> msg.LegCommand | None:
        """Block until a LegCommand answers ``out.tick`` (None when stopping)."""
        period = self.config.node.lockstep_log_period
        republish = self.config.node.lockstep_republish_period
        start = last_pub = time.monotonic()
        last_log = start
        with self._cond:
            while not self.stop_event.is_set():
                leg = self._leg
                if leg is not None and leg.tick == out.tick:
                    self._leg_new = False
                    return leg
                self._cond.wait(0.05)
                now = time.monotonic()
                if now - last_pub >= republish:
                    self.pub["sim/lowstate"].publish(out.lowstate)
                    last_pub = now
                if now - last_log >= period:
                    self.log.info(
                        "lockstep: waiting for leg command",
                        tick=out.tick,
                        waited_s=round(now - start, 1),
                        last_cmd_tick=None if leg is None else leg.tick,
                    )
                    last_log = now
        return None

    def _publish_status(self, wall: float, sim: float) -> None:
        eng = self.engine
        assert eng is not None
        status = self._link.flush(
            stamp=eng.time,
            leg_timeouts=eng.actuators.leg_timeouts,
            leg_mode=eng.actuators.leg_mode.value,
            rtf=sim / max(wall, 1e-9),
            mode=self.mode,
        )
        self.pub["sim/status"].publish(status)

    def _log_rtf(self, wall: float, sim: float) -> None:
        eng = self.engine
        assert eng is not None
        self.log.info(
            "rtf",
            mode=self.mode,
            rtf=round(sim / max(wall, 1e-9), 3),
            sim_time=round(eng.time, 3),
            legs=eng.actuators.leg_mode.value,
            rejected=eng.actuators.rejected,
            leg_timeouts=eng.actuators.leg_timeouts,
        )

    def teardown(self) -> None:
        if self.engine is not None:
            self.engine.close()


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service sim``."""
    return run_service(SimNode, argv)


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
