"""``quadmanip service unitree-sim-robot``: a simulated robot that speaks Unitree SDK2 DDS.

Test and demo tooling, not runtime (the way Unitree's own ``unitree_mujoco`` stands in for
a Go2): MuJoCo with our robot description in a house scenario, answering ``rt/lowcmd``
and publishing ``rt/lowstate`` at the control rate (500 Hz) over DDS, in real time like a
robot. Its arm servos answer ``rt/arm/lowcmd`` and publish ``rt/arm/lowstate`` (the
convention of hardware/unitree/arm_bus.py).

What it shares with the stack, and what it must not:

* Physics and the motors are the sim's engine and actuator layer: the motor drivers of a
  real robot run the same PD + feed-forward law, and the robot falls back to damping when
  its commands stop for ``motor_timeout`` (0.1 s: longer than the adapter's 50 ms, so the
  adapter is what normally damps; this one acts when the adapter itself dies).
* Its joint mapping is its own, from Unitree's naming (slot = 3 × leg + joint, legs FR,
  FL, RR, RL; joints hip, thigh, calf = our abad, hip, knee) resolved by joint *name*, not
  the adapter's table: a wrong row in that table drives the wrong motor here and shows.
* It uses the SDK's message types and CRC, and ignores a ``LowCmd_`` whose CRC is wrong,
  as the robot's firmware does. ``LowState_.tick`` counts milliseconds of the robot's own
  (physics) time, as a Go2's does; the adapter stamps with it, so the stack keeps the
  robot's time even when this machine runs the simulation slower than real time.
* Ground truth (the true base pose) goes on ``sim/gt/base`` over Zenoh for benchmarks and
  tests to score, stamped with the physics time offset to the wall clock at start.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import signal
import struct
import threading
import time
from typing import Any

import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common.bus import Bus, load_bus_config
from quadmanip.common.config import load_config
from quadmanip.common.joint_layout import ARM_JOINTS, JOINTS, N_LEG_JOINTS
from quadmanip.common.log import configure_logging, get_logger
from quadmanip.common.scheduling import SchedulingConfig, ThreadScheduler
from quadmanip.sim.engine import SimConfig, SimEngine

__all__ = ["SDK_LEGS", "sdk_slot_joints", "main"]

log = get_logger("unitree-sim-robot")

SDK_LEGS = ("FR", "FL", "RR", "RL")
"""Unitree's leg order in the motor slots."""
SDK_JOINT_KINDS = ("abad", "hip", "knee")
"""Unitree's hip, thigh, calf, named as in our description."""
N_SLOTS = 20
# The real-time factor that a 2-core machine holds for this robot's physics, the adapter,
# locomotion and a Zenoh router together without locomotion's deadline monitor degrading
# (measured with `quadmanip bench locomotion --over unitree-sim`: at 0.5 about 10 % of
# answers came later than 1.5 of the robot's ticks in every window; at 0.3 one run of three
# still had degraded windows; at 0.25 none of three). Benchmarks and tests use this pace.
SMALL_MACHINE_RTF = 0.25
ARM_GRIPPER_SLOT = 4


def sdk_slot_joints() -> tuple[str, ...]:
    """The description's joint name in each of the 12 leg slots (the firmware's view)."""
    return tuple(f"{leg}_{kind}" for leg in SDK_LEGS for kind in SDK_JOINT_KINDS)


class SimulatedUnitreeRobot:
    """The engine in real time behind the SDK's DDS topics (see the module doc)."""

    def __init__(self, args: argparse.Namespace) -> None:
        from quadmanip.hardware.unitree import dds
        from quadmanip.hardware.unitree.lowlevel import fast_wire, new_lowstate
        from quadmanip.sim.node import load_world
        from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_

        self.args = args
        base: SimConfig = load_config(SimConfig, "sim")
        sensors = base.sensors
        for name in ("front_camera", "gripper_camera", "lidar"):
            sensors = dataclasses.replace(
                sensors, **{name: dataclasses.replace(getattr(sensors, name), rate=0.0)}
            )
        self.config = dataclasses.replace(
            base,
            scenario=args.scenario,
            sensors=sensors,
            actuators=dataclasses.replace(base.actuators, leg_timeout=args.motor_timeout),
            ground_truth=dataclasses.replace(
                base.ground_truth, poses_rate=args.gt_rate, contacts_rate=0.0, judge_rate=0.0
            ),
        )
        self.engine = SimEngine(load_world(args.scenario), self.config)
        wire = {name: i for i, name in enumerate(JOINTS)}
        self.leg_wire = np.array([wire[n] for n in sdk_slot_joints()], dtype=np.intp)
        self.arm_wire = np.array([wire[n] for n in ARM_JOINTS], dtype=np.intp)
        self._lock = threading.Lock()
        self._cmd: Any = None
        self._arm_cmd: Any = None
        self.bad_crc = 0
        self.commands = 0
        control_rate = self.config.physics.control_rate
        self._arm_every = max(1, round(control_rate / args.arm_rate))
        self._arm_dt = 1.0 / args.arm_rate
        dds.init_dds(args.domain, args.interface)
        self._state = new_lowstate()
        self._arm_state = new_lowstate()
        fast_wire(self._state)
        fast_wire(self._arm_state)
        self._pub = dds.publisher(args.lowstate_topic, LowState_)
        self._arm_pub = dds.publisher(args.arm_state_topic, LowState_)
        self._sub = dds.raw_subscriber(args.lowcmd_topic, LowCmd_, self._on_cmd)
        self._arm_sub = dds.raw_subscriber(args.arm_cmd_topic, LowCmd_, self._on_arm_cmd)
        bus_cfg = load_bus_config()
        if args.connect:
            bus_cfg = dataclasses.replace(bus_cfg, connect=tuple(args.connect.split(",")))
        self.bus = Bus(dataclasses.replace(bus_cfg, robot_clock=""), robot=args.robot)
        self._gt = self.bus.publisher("sim/gt/base")
        log.info(
            "simulated Unitree robot ready",
            scenario=args.scenario,
            domain=args.domain,
            interface=args.interface,
            motor_timeout_s=args.motor_timeout,
        )

    # ---------------------------------------------------------------- DDS in
    def _decode(self, data: bytes) -> tuple | None:
        """A LowCmd_'s values, None (counted, logged) when its CRC is wrong."""
        from quadmanip.hardware.unitree.lowlevel import decode_lowcmd, lowcmd_crc_ok

        try:
            v = decode_lowcmd(data)
        except (ValueError, struct.error):
            v = None
        if v is None or not lowcmd_crc_ok(v):
            self.bad_crc += 1
            log.throttled("bad-crc", 1.0, logging.WARNING, "LowCmd with a bad CRC ignored",
                          total=self.bad_crc)  # fmt: skip
            return None
        return v

    def _on_cmd(self, data: bytes) -> None:
        v = self._decode(data)
        if v is not None:
            with self._lock:
                self._cmd = v

    def _on_arm_cmd(self, data: bytes) -> None:
        v = self._decode(data)
        if v is not None:
            with self._lock:
                self._arm_cmd = v

    @staticmethod
    def _motor(v: tuple, slot: int) -> tuple:
        """(mode, q, dq, tau, kp, kd) of a motor slot in LowCmd_ values."""
        from quadmanip.hardware.unitree.lowlevel import CMD_MOTOR0, CMD_MOTOR_STRIDE

        i = CMD_MOTOR0 + CMD_MOTOR_STRIDE * slot
        return v[i : i + 6]

    def _leg_command(self, cmd: tuple, tick: int) -> msg.LegCommand:
        """The motor slots → the engine's leg arrays (by joint name, not the adapter's
        table). A motor not in servo mode gives no torque."""
        f = np.zeros((5, N_LEG_JOINTS))
        for slot, j in enumerate(self.leg_wire):
            mode, q, dq, tau, kp, kd = self._motor(cmd, slot)
            if mode != 0x01:
                continue
            f[:, j] = (q, dq, kp, kd, tau)
        return msg.LegCommand(
            stamp=self.engine.time, tick=tick, q_des=f[0], dq_des=f[1], kp=f[2], kd=f[3],
            tau_ff=f[4],
        )  # fmt: skip

    def _apply_arm(self, cmd: tuple) -> None:
        eng = self.engine
        ms = np.array([self._motor(cmd, i) for i in range(len(ARM_JOINTS))], dtype=float)
        if np.all(ms[:, 0] == 0x01):
            # A servo that gets setpoints at arm_rate moves on between them with the
            # commanded velocity (then holds), instead of stepping.
            _, q, dq, tau, kp, kd = ms.T
            dt = self._arm_dt
            eng.apply_arm_trajectory(
                msg.ArmTrajectory(
                    stamp=eng.time,
                    t=np.array([eng.time, eng.time + dt]),
                    q=np.array([q, q + dq * dt]),
                    dq=np.array([dq, dq]),
                    kp=kp,
                    kd=kd,
                    tau_ff=np.array([tau, tau]),
                )
            )
        mode, gap, _, force, _, _ = self._motor(cmd, ARM_GRIPPER_SLOT)
        if mode == 0x01:
            eng.apply_gripper_command(msg.GripperCommand(stamp=eng.time, gap=gap, max_force=force))

    # --------------------------------------------------------------- DDS out
    def _publish(self, ls: msg.LowState, tick: int) -> None:
        from quadmanip.hardware.unitree.lowlevel import seal

        st = self._state
        j = ls.joints
        for slot, w in enumerate(self.leg_wire):
            m = st.motor_state[slot]
            m.mode = 0x01
            m.q, m.dq, m.tau_est = float(j.q[w]), float(j.dq[w]), float(j.tau[w])
        imu = st.imu_state
        imu.quaternion = [float(x) for x in ls.imu.orientation]
        imu.gyroscope = [float(x) for x in ls.imu.angular_velocity]
        imu.accelerometer = [float(x) for x in ls.imu.linear_acceleration]
        # The robot's clock: milliseconds of its own (physics) time, as a Go2's tick.
        st.tick = round(self.engine.time * 1000.0) & 0xFFFFFFFF
        seal(st)
        self._pub.Write(st)
        if tick % self._arm_every:
            return
        a = self._arm_state
        for slot, w in enumerate(self.arm_wire):
            m = a.motor_state[slot]
            m.q, m.dq, m.tau_est = float(j.q[w]), float(j.dq[w]), float(j.tau[w])
        g = a.motor_state[ARM_GRIPPER_SLOT]
        g.q, g.tau_est = float(j.gripper_gap), float(j.gripper_effort)
        a.tick = st.tick
        seal(a)
        self._arm_pub.Write(a)

    # ------------------------------------------------------------------ loop
    def run(self, stop: threading.Event, scheduler: ThreadScheduler | None = None) -> None:
        """Step the physics at the real-time factor until ``stop``; ``scheduler`` gives
        threads started later the physics loop's priority, as the services' heartbeat
        does (a command reader at normal priority competes with three real-time
        processes on a small computer)."""
        eng = self.engine
        out = eng.observe(sensors=False)
        period = eng.control_dt / max(self.args.realtime_factor, 1e-3)
        wall0 = time.time()
        sim0 = eng.time
        t_ref, tick_ref = time.monotonic(), eng.tick
        last_log = time.monotonic()
        slips = 0
        while not stop.is_set():
            with self._lock:
                cmd, self._cmd = self._cmd, None
                arm, self._arm_cmd = self._arm_cmd, None
            leg = None
            if cmd is not None:
                leg = self._leg_command(cmd, eng.tick)
                self.commands += 1
            if arm is not None:
                self._apply_arm(arm)
            out = eng.step_tick(leg, sensors=False)
            self._publish(out.lowstate, out.tick)
            eng.add_sensors(out)
            if out.gt_poses is not None:
                g = out.gt_poses
                self._gt.publish(
                    msg.GroundTruthPoses(
                        stamp=wall0 + (eng.time - sim0),
                        names=g.names[:1],
                        positions=g.positions[:1],
                        orientations=g.orientations[:1],
                    )
                )
            now = time.monotonic()
            target = t_ref + (eng.tick - tick_ref) * period
            if target > now:
                stop.wait(target - now)
            elif now - target > 0.1:  # cannot keep up: restart the schedule, no burst
                slips += 1
                t_ref, tick_ref = now, eng.tick
            if scheduler is not None and eng.tick % 500 == 0:
                scheduler.apply()
            if now - last_log >= 5.0:
                log.info(
                    "running",
                    sim_time=round(eng.time, 2),
                    legs=eng.actuators.leg_mode.value,
                    commands=self.commands,
                    bad_crc=self.bad_crc,
                    timeouts=eng.actuators.leg_timeouts,
                    schedule_slips=slips,
                )
                last_log = now

    def close(self) -> None:
        self.bus.close()
        self.engine.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadmanip service unitree-sim-robot",
        description="A simulated robot speaking Unitree SDK2 DDS (test and demo tooling).",
    )
    p.add_argument("--scenario", default="paper-1", help="house scenario (as the sim's)")
    p.add_argument("--domain", type=int, default=1, help="DDS domain id (default 1)")
    p.add_argument("--interface", default="lo", help="network interface (default lo)")
    p.add_argument("--lowcmd-topic", default="rt/lowcmd")
    p.add_argument("--lowstate-topic", default="rt/lowstate")
    p.add_argument("--arm-cmd-topic", default="rt/arm/lowcmd")
    p.add_argument("--arm-state-topic", default="rt/arm/lowstate")
    p.add_argument("--motor-timeout", type=float, default=0.1, help="s without LowCmd -> damping")
    p.add_argument("--realtime-factor", type=float, default=1.0)
    p.add_argument("--gt-rate", type=float, default=50.0, help="Hz of sim/gt/base (0: off)")
    p.add_argument("--arm-rate", type=float, default=100.0, help="Hz of rt/arm/lowstate")
    p.add_argument("--connect", help="Zenoh endpoints for ground truth (like QM_ZENOH_CONNECT)")
    p.add_argument("--robot", default="dog1", help="robot name on the bus")
    p.add_argument("--log-level", help="DEBUG, INFO, WARNING")
    p.add_argument("--no-realtime-priority", action="store_true", help="normal scheduling")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service unitree-sim-robot``."""
    args = build_parser().parse_args(argv)
    configure_logging("unitree-sim-robot", level=args.log_level)
    if min(args.motor_timeout, args.realtime_factor, args.arm_rate) <= 0:
        log.error("--motor-timeout, --realtime-factor and --arm-rate must be > 0")
        return 2
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    robot = SimulatedUnitreeRobot(args)
    scheduler = None
    if not args.no_realtime_priority:  # like the sim's physics loop in realtime mode
        scheduler = ThreadScheduler(SchedulingConfig(policy="fifo", priority=70, fallback_nice=-5))
        res = scheduler.apply()
        if res is not None:
            log.info("scheduling", applied=res.applied, reasons="; ".join(res.reasons))
    try:
        robot.run(stop, scheduler)
    finally:
        robot.close()
    return 0


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
