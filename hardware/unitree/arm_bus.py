"""An arm whose servos speak Unitree's motor messages on their own DDS topics.

The simulated robot (quadmanip/testbench/unitree_sim_robot.py) exposes its arm this way,
and so can a real arm whose driver bridges it (docs/hardware.md): ``LowCmd_`` on
``cmd_topic`` and ``LowState_`` on ``state_topic`` with slots 0..3 the arm joints in our
wire order (``arm_j1..arm_j4``, no sign change) and slot 4 the gripper: ``q`` the finger
gap (m), ``tau`` the force limit (N) in commands; ``q`` the gap and ``tau_est`` the finger
effort in states. Every message carries the SDK's CRC.
"""

from __future__ import annotations

import struct
import threading

import numpy as np
from quadmanip.common.joint_layout import N_ARM_JOINTS
from quadmanip.hardware.arm_driver import ArmReading, ArmSetpoint, StreamingArmDriver
from quadmanip.hardware.unitree import dds
from quadmanip.hardware.unitree.lowlevel import (
    MOTOR_SERVO,
    ST_MOTOR0,
    ST_MOTOR_STRIDE,
    decode_lowstate,
    fast_wire,
    lowstate_crc_ok,
    new_lowcmd,
    seal,
)
from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_

__all__ = ["ARM_SLOTS", "GRIPPER_SLOT", "DdsServoArmDriver"]

ARM_SLOTS = tuple(range(N_ARM_JOINTS))
GRIPPER_SLOT = N_ARM_JOINTS


class DdsServoArmDriver(StreamingArmDriver):
    """See the module doc (DDS must be initialised first, :func:`dds.init_dds`)."""

    def __init__(self, cmd_topic: str, state_topic: str, **kwargs: float) -> None:
        super().__init__(**kwargs)
        self._lock = threading.Lock()
        self._reading: ArmReading | None = None
        self.bad_crc = 0
        self.cmd = new_lowcmd(np.array([*ARM_SLOTS, GRIPPER_SLOT]))
        fast_wire(self.cmd)
        self._pub = dds.publisher(cmd_topic, LowCmd_)
        self._sub = dds.raw_subscriber(state_topic, LowState_, self._on_state)

    def _on_state(self, data: bytes) -> None:
        try:
            v = decode_lowstate(data)
        except (ValueError, struct.error):
            v = None
        if v is None or not lowstate_crc_ok(v):
            self.bad_crc += 1
            return
        m = [ST_MOTOR0 + ST_MOTOR_STRIDE * i for i in (*ARM_SLOTS, GRIPPER_SLOT)]
        reading = ArmReading(
            q=np.array([v[i + 1] for i in m[:N_ARM_JOINTS]], dtype=float),
            dq=np.array([v[i + 2] for i in m[:N_ARM_JOINTS]], dtype=float),
            tau=np.array([v[i + 4] for i in m[:N_ARM_JOINTS]], dtype=float),
            gripper_gap=float(v[m[-1] + 1]),
            gripper_effort=float(v[m[-1] + 4]),
        )
        with self._lock:
            self._reading = reading

    def read(self) -> ArmReading | None:
        with self._lock:
            return self._reading

    def send(self, now: float, sp: ArmSetpoint) -> None:
        mc = self.cmd.motor_cmd
        for i in ARM_SLOTS:
            m = mc[i]
            m.mode = MOTOR_SERVO
            m.q, m.dq = float(sp.q[i]), float(sp.dq[i])
            m.kp, m.kd, m.tau = float(sp.kp[i]), float(sp.kd[i]), float(sp.tau[i])
        g = mc[GRIPPER_SLOT]
        g.mode = MOTOR_SERVO
        g.q, g.tau = float(sp.gripper_gap), float(sp.gripper_force)
        seal(self.cmd)
        self._pub.Write(self.cmd)

    def close(self) -> None:
        self._sub.close()
        self._pub.Close()
