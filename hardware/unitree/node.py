"""``quadmanip service unitree-adapter``: the stack's sim keys on a Unitree SDK2 robot.

It takes the sim's place on the bus (docs/hardware.md; ARCHITECTURE.md "Hardware adapter
contract"): the same service name and keys, so locomotion, manipulation and everything
above run unchanged.

* Every ``LowState_`` the robot publishes on ``rt/lowstate`` (500 Hz on a Go2) becomes one
  control tick: its CRC is checked, the legs are mapped to our wire order
  (joint_map.py), the arm driver's newest reading is added, and ``sim/lowstate`` goes
  out with our own tick counter that locomotion echoes, stamped in robot time: the
  robot's own millisecond tick from the wall time at the first state (wall time, without
  the transport's jitter). ``sim/clock`` follows at ``node.clock_rate``.
* ``sim/leg_command`` goes through the safety layer (hardware/leg_safety.py: refusals,
  joint and torque clamps) and straight out as a sealed ``LowCmd_`` on ``rt/lowcmd``, so
  the adapter adds no tick of delay.
* If leg commands stop for ``safety.timeout`` (50 ms, the sim's), the next state tick sends
  damping instead, and every tick after it; ``sim/estop`` (engage) does the same at once,
  latched until a release. The arm driver streams its setpoint every tick and damps on
  the e-stop.
* ``sim/status`` carries the control link's numbers as the sim's does (command age in
  ticks, stale ticks, timeouts, leg mode), so locomotion's deadline monitor works here too.
* A robot that stops publishing is reported (warning, counter); the robot's own motor
  timeout makes it damp, and the adapter keeps sending damping until states return.
"""

from __future__ import annotations

import argparse
import logging
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common.actuator_commands import LegMode
from quadmanip.common.joint_layout import ARM_SLICE, LEG_SLICE, N_JOINTS
from quadmanip.common.link_stats import LinkStats
from quadmanip.common.robot_description import leg_joint_limits, robot_info
from quadmanip.common.scheduling import SchedulingConfig
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.hardware.arm_driver import ArmDriver, SimulatedArmDriver
from quadmanip.hardware.leg_safety import LegSafety, LegSafetyConfig, MotorTargets
from quadmanip.hardware.unitree import dds
from quadmanip.hardware.unitree.lowlevel import (
    LowCmdWriter,
    decode_lowstate,
    lowstate_crc_ok,
    read_lowstate_values,
)
from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_

__all__ = ["UnitreeAdapter", "UnitreeAdapterConfig", "main"]

ARM_DRIVERS = ("dds-servo", "simulated", "none")


@dataclass(frozen=True)
class DdsConfig:
    """``[dds]``: where the robot is."""

    domain_id: int = 0
    interface: str = "lo"  # the network interface wired to the robot (e.g. eth0)
    lowcmd_topic: str = "rt/lowcmd"
    lowstate_topic: str = "rt/lowstate"
    check_crc: bool = True  # drop states whose CRC is wrong
    # Seconds per unit of LowState_.tick (a Go2 counts milliseconds): states are stamped
    # with the robot's own clock, offset to the wall clock at the first state, so the
    # stamps carry no transport jitter. 0: stamp with the wall clock at arrival.
    tick_period: float = 0.001


@dataclass(frozen=True)
class ArmConfig:
    """``[arm]``: which arm driver, and its bus."""

    driver: str = "dds-servo"
    rate: float = 100.0  # Hz at which setpoints stream to the servos (a servo bus's rate)
    cmd_topic: str = "rt/arm/lowcmd"
    state_topic: str = "rt/arm/lowstate"
    hold_kp: float = 60.0
    hold_kd: float = 2.0
    damping_kd: float = 2.0
    default_force: float = 20.0

    def __post_init__(self) -> None:
        if self.driver not in ARM_DRIVERS:
            raise ValueError(f"arm.driver must be one of {ARM_DRIVERS}, got {self.driver!r}")
        if not self.rate > 0:
            raise ValueError("arm.rate must be > 0")


@dataclass(frozen=True)
class AdapterNodeConfig:
    """``[node]``: rates and the robot-silence alarm."""

    clock_rate: float = 100.0  # Hz of sim/clock (wall time)
    status_rate: float = 2.0  # Hz of sim/status
    state_timeout: float = 0.1  # s without a robot state -> warning and counter

    def __post_init__(self) -> None:
        if min(self.clock_rate, self.status_rate, self.state_timeout) <= 0:
            raise ValueError("node rates and state_timeout must be > 0")


@dataclass(frozen=True)
class UnitreeAdapterConfig:
    """Everything in configs/unitree_adapter.toml."""

    dds: DdsConfig = DdsConfig()
    arm: ArmConfig = ArmConfig()
    safety: LegSafetyConfig = LegSafetyConfig()
    node: AdapterNodeConfig = AdapterNodeConfig()
    scheduling: SchedulingConfig = field(
        default_factory=lambda: SchedulingConfig(policy="fifo", priority=75, fallback_nice=-5)
    )


def make_arm_driver(cfg: ArmConfig) -> ArmDriver | None:
    """The configured arm driver (DDS must be initialised for ``dds-servo``)."""
    info = robot_info()
    common = {
        "hold_kp": cfg.hold_kp,
        "hold_kd": cfg.hold_kd,
        "damping_kd": cfg.damping_kd,
        "gap_range": (0.0, info.gripper_max_gap),
        "default_force": cfg.default_force,
    }
    if cfg.driver == "dds-servo":
        from quadmanip.hardware.unitree.arm_bus import DdsServoArmDriver

        return DdsServoArmDriver(cfg.cmd_topic, cfg.state_topic, **common)
    if cfg.driver == "simulated":
        from quadmanip.common.robot_description import home_joint_positions

        return SimulatedArmDriver(home_joint_positions()[ARM_SLICE], **common)
    return None


class UnitreeAdapter(Service):
    """Zenoh ↔ Unitree SDK2 DDS (see the module doc)."""

    name = "sim"  # it fills the sim's role: same keys, same liveliness
    config_name = "unitree_adapter"
    config_type = UnitreeAdapterConfig
    inputs = (
        Input("sim/leg_command", doc="leg PD + feed-forward, echoes tick"),
        Input("sim/arm_trajectory", doc="arm joint trajectory"),
        Input("sim/gripper_command", doc="finger gap + force limit"),
        Input("sim/estop", doc="software e-stop: latched damping until reset"),
    )
    outputs = (Output("sim/clock"), Output("sim/lowstate"), Output("sim/status"))

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--interface", help="network interface to the robot (dds.interface)")
        parser.add_argument("--domain", type=int, help="DDS domain id (dds.domain_id)")

    def __init__(self, bus: Any, config: UnitreeAdapterConfig, args: Any = None) -> None:
        super().__init__(bus, config, args)
        d = config.dds
        self.interface = getattr(args, "interface", None) or d.interface
        self.domain = d.domain_id if getattr(args, "domain", None) is None else args.domain
        self._lock = threading.Lock()
        self._reading: Any = None
        self._tick = 0
        self._state_mono = -np.inf
        self._new_cmd: msg.LegCommand | None = None
        self._link = LinkStats()
        self._mode = LegMode.DAMPING
        self.bad_crc = 0
        self.lowcmd_sent = 0
        self.robot_silences = 0
        self._silent = False
        self.arm: ArmDriver | None = None
        self._arm_next = 0.0
        self._tick0: int | None = None
        self._last_raw = 0
        self._wall0 = 0.0
        self._robot_ticks = 0

    def setup(self) -> None:
        lo, hi, tau = leg_joint_limits()
        self.safety = LegSafety(self.config.safety, lo, hi, tau)
        dds.init_dds(self.domain, self.interface)
        self.writer = LowCmdWriter()
        self.arm = make_arm_driver(self.config.arm)
        self.pub = {o.topic: self.publisher(o.topic) for o in self.outputs}
        self._clock_every = max(1, round(500.0 / self.config.node.clock_rate))
        self._lowcmd = dds.publisher(self.config.dds.lowcmd_topic, LowCmd_)
        self.subscribe("sim/leg_command", self._on_leg)
        self.subscribe("sim/arm_trajectory", self._on_arm)
        self.subscribe("sim/gripper_command", self._on_gripper)
        self.subscribe("sim/estop", self._on_estop)
        self._lowstate = dds.raw_subscriber(
            self.config.dds.lowstate_topic, LowState_, self._on_lowstate
        )
        self.log.info(
            "unitree adapter ready",
            domain=self.domain,
            interface=self.interface,
            lowcmd=self.config.dds.lowcmd_topic,
            lowstate=self.config.dds.lowstate_topic,
            arm=self.config.arm.driver,
            timeout_s=self.config.safety.timeout,
        )

    # ------------------------------------------------------------------ helpers
    def _write(self, t: MotorTargets) -> None:
        """Send leg targets (lock held)."""
        self._lowcmd.Write(self.writer.fill(t))
        self.lowcmd_sent += 1
        if t.mode is not self._mode:
            level = self.log.warning if t.mode is not LegMode.ACTIVE else self.log.info
            reason = {
                LegMode.DAMPING: "leg commands stopped" if self._mode is LegMode.ACTIVE else "",
                LegMode.ESTOP: f"emergency stop: {self.safety.estop_reason}",
                LegMode.ACTIVE: "leg commands",
            }[t.mode]
            level("leg mode", old=self._mode.value, new=t.mode.value, reason=reason)
            self._mode = t.mode

    def _stamp(self, tick: int) -> float:
        """Robot time of a state: the robot's tick clock from the wall time at the first
        state (uint32 ticks wrap after 49 days at 1 ms: unwrapped here)."""
        period = self.config.dds.tick_period
        if period <= 0:
            return time.time()
        step = (tick - self._last_raw) & 0xFFFFFFFF
        if self._tick0 is None or step >= 1 << 31:  # first state, or the robot restarted
            if self._tick0 is not None:
                self.log.warning("robot clock went back: re-anchored", tick=tick)
            self._tick0, self._wall0, self._robot_ticks = tick, time.time(), 0
            step = 0
        self._robot_ticks += step
        self._last_raw = tick
        return self._wall0 + self._robot_ticks * period

    # ---------------------------------------------------------------- callbacks
    def _on_lowstate(self, data: bytes) -> None:
        """One robot state = one control tick (DDS listener thread)."""
        try:
            values = decode_lowstate(data)
        except (ValueError, struct.error) as exc:
            self.bad_crc += 1
            self.log.throttled("bad-state", 1.0, logging.WARNING, "undecodable robot state",
                               error=str(exc), total=self.bad_crc)  # fmt: skip
            return
        if self.config.dds.check_crc and not lowstate_crc_ok(values):
            self.bad_crc += 1
            self.log.throttled(
                "bad-crc",
                1.0,
                logging.WARNING,
                "robot state with a bad CRC dropped",
                total=self.bad_crc,
            )
            return
        r = read_lowstate_values(values)
        now = time.monotonic()
        stamp = self._stamp(r.tick)
        with self._lock:
            if self._silent:
                self.log.info("robot state back", after_s=round(now - self._state_mono, 3))
                self._silent = False
            self._link.record(self._tick, self._new_cmd)
            self._new_cmd = None
            self._tick += 1
            tick = self._tick
            self._reading = r
            self._state_mono = now
            t = self.safety.targets(now, r.q, r.dq)
            if t.mode is not LegMode.ACTIVE:
                self._write(t)
            if self.arm is not None:
                if stamp >= self._arm_next:
                    self._arm_next = stamp + 1.0 / self.config.arm.rate
                    self.arm.update(stamp)
                arm = self.arm.read()
            else:
                arm = None
        q = np.zeros(N_JOINTS)
        dq = np.zeros(N_JOINTS)
        tau = np.zeros(N_JOINTS)
        q[LEG_SLICE], dq[LEG_SLICE], tau[LEG_SLICE] = r.q, r.dq, r.tau
        gap = effort = 0.0
        if arm is not None:
            q[ARM_SLICE], dq[ARM_SLICE], tau[ARM_SLICE] = arm.q, arm.dq, arm.tau
            gap, effort = arm.gripper_gap, arm.gripper_effort
        quat = r.orientation
        if not np.isfinite(quat).all() or np.linalg.norm(quat) < 0.5:
            quat = np.array([1.0, 0.0, 0.0, 0.0])  # an IMU not yet up: no rotation
        ls = msg.LowState(
            stamp=stamp,
            tick=tick,
            joints=msg.JointState(
                stamp=stamp, q=q, dq=dq, tau=tau, gripper_gap=gap, gripper_effort=effort
            ),
            imu=msg.Imu(
                stamp=stamp,
                orientation=quat / np.linalg.norm(quat),
                angular_velocity=r.angular_velocity,
                linear_acceleration=r.linear_acceleration,
            ),
        )
        self.pub["sim/lowstate"].publish(ls)
        if tick % self._clock_every == 0:
            self.pub["sim/clock"].publish(msg.Clock(stamp=stamp))

    def _on_leg(self, cmd: msg.LegCommand) -> None:
        now = time.monotonic()
        with self._lock:
            reason = self.safety.command(now, cmd.q_des, cmd.dq_des, cmd.kp, cmd.kd, cmd.tau_ff)
            if reason:
                self.log.throttled("leg-reject", 1.0, logging.WARNING, "leg command refused", reason=reason,
                          total=self.safety.rejected)  # fmt: skip
                return
            self._new_cmd = cmd
            r = self._reading
            if r is None:
                return
            t = self.safety.targets(now, r.q, r.dq)
            if t.mode is LegMode.ACTIVE:
                self._write(t)

    def _on_arm(self, traj: msg.ArmTrajectory) -> None:
        if self.arm is None:
            self.log.throttled(
                "arm-none", 5.0, logging.WARNING, "arm trajectory ignored: no arm driver configured"
            )
            return
        args = {"t": traj.t, "q": traj.q, "dq": traj.dq, "kp": traj.kp, "kd": traj.kd,
                "tau_ff": traj.tau_ff if len(traj.tau_ff) else None}  # fmt: skip
        with self._lock:
            reason = self.arm.set_trajectory(time.time(), args)
        if reason:
            self.log.throttled(
                "arm-reject", 1.0, logging.WARNING, "arm trajectory refused", reason=reason
            )

    def _on_gripper(self, cmd: msg.GripperCommand) -> None:
        if self.arm is None:
            return
        with self._lock:
            reason = self.arm.set_gripper(cmd.gap, cmd.max_force)
        if reason:
            self.log.throttled(
                "grip-reject", 1.0, logging.WARNING, "gripper command refused", reason=reason
            )

    def _on_estop(self, e: msg.EmergencyStop) -> None:
        with self._lock:
            if e.engage:
                self.safety.engage_estop(e.reason or "sim/estop")
                if self.arm is not None:
                    self.arm.engage_estop()
                r = self._reading
                if r is not None:
                    self._write(self.safety.damping(r.q, LegMode.ESTOP))
                self.log.warning("emergency stop engaged: damping", reason=e.reason)
            else:
                self.safety.reset_estop()
                if self.arm is not None:
                    self.arm.reset_estop()
                self.log.info("emergency stop released")

    # -------------------------------------------------------------------- loop
    def run(self) -> None:
        """Status, and the robot-silence watch (states drive everything else)."""
        cfg = self.config.node
        status_t = time.monotonic()
        ticks_at = 0
        while not self.stop_event.wait(0.01):
            now = time.monotonic()
            with self._lock:
                silent_for = now - self._state_mono
                if np.isfinite(self._state_mono) and silent_for > cfg.state_timeout:
                    if not self._silent:
                        self._silent = True
                        self.robot_silences += 1
                        self.log.warning(
                            "no state from the robot: sending damping",
                            silent_s=round(silent_for, 3),
                            silences=self.robot_silences,
                        )
                    if self._reading is not None:
                        self._write(self.safety.damping(self._reading.q))
            if now - status_t >= 1.0 / cfg.status_rate:
                with self._lock:
                    ticks = self._tick
                    status = self._link.flush(
                        stamp=time.time(),
                        leg_timeouts=self.safety.timeouts,
                        leg_mode=self.safety.watchdog.mode_at(now).value,
                        rtf=1.0,
                        mode="hardware",
                    )
                self.pub["sim/status"].publish(status)
                if ticks == ticks_at and ticks == 0:
                    self.log.throttled("no-robot", 5.0, logging.WARNING, "waiting for the robot's first state",
                              topic=self.config.dds.lowstate_topic, domain=self.domain,
                              interface=self.interface)  # fmt: skip
                ticks_at = ticks
                status_t = now

    def teardown(self) -> None:
        # Stop the robot's states first: their callback publishes on the bus, which closes
        # after teardown (a state arriving then raised "Undeclared publisher").
        self._lowstate.close()
        with self._lock:
            r = self._reading
            if r is not None:  # leave the robot damped, not holding a stale command
                self._write(self.safety.damping(r.q))
        if self.arm is not None:
            self.arm.close()


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service unitree-adapter``."""
    return run_service(UnitreeAdapter, argv)


if __name__ == "__main__":
    import sys

    raise SystemExit(main(sys.argv[1:]))
