"""An arm whose servos speak Unitree's motor messages on their own DDS topics.

The simulated robot (quadmanip/testbench/unitree_sim_robot.py) exposes its arm this way,
and so can a real arm whose driver bridges it (docs/hardware.md): ``LowCmd_`` on
``cmd_topic`` and ``LowState_`` on ``state_topic`` with slots 0..3 the arm joints in our
wire order (``arm_j1..arm_j4``, no sign change) and slot 4 the gripper: ``q`` the finger
gap (m), ``tau`` the force limit (N) in commands; ``q`` the gap and ``tau_est`` the finger
effort in states. Every message carries the SDK's CRC.
"""

from __future__ import annotations

import threading

import numpy as np
from quadmanip.common.joint_layout import N_ARM_JOINTS
from quadmanip.hardware.arm_driver import ArmReading, ArmSetpoint, StreamingArmDriver
from quadmanip.hardware.unitree import dds
from quadmanip.hardware.unitree.lowlevel import MOTOR_SERVO, crc_ok, new_lowcmd, seal
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
        self._pub = dds.publisher(cmd_topic, LowCmd_)
        self._sub = dds.subscriber(state_topic, LowState_, self._on_state)

    def _on_state(self, st: LowState_) -> None:
        if not crc_ok(st):
            self.bad_crc += 1
            return
        ms = st.motor_state
        reading = ArmReading(
            q=np.array([ms[i].q for i in ARM_SLOTS], dtype=float),
            dq=np.array([ms[i].dq for i in ARM_SLOTS], dtype=float),
            tau=np.array([ms[i].tau_est for i in ARM_SLOTS], dtype=float),
            gripper_gap=float(ms[GRIPPER_SLOT].q),
            gripper_effort=float(ms[GRIPPER_SLOT].tau_est),
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
        self._sub.Close()
        self._pub.Close()
