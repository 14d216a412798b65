"""Unitree SDK2 low-level messages ↔ our arrays, with the SDK's CRC.

Uses the SDK's own IDL types (``unitree_go`` LowCmd_/LowState_) and its CRC, so what leaves
here is byte for byte what a Go2/Go1/B2 expects on ``rt/lowcmd``. Conversions between SDK
slots and our wire order go through :data:`~quadmanip.hardware.unitree.joint_map.LEG_MAP`
only. Slots we do not drive get the SDK's "stop" values (mode 0, ``PosStopF``,
``VelStopF``), as Unitree's examples do.
"""

from __future__ import annotations

import ctypes
import struct
from dataclasses import dataclass

import numpy as np
from quadmanip.hardware.leg_safety import MotorTargets
from quadmanip.hardware.unitree.joint_map import LEG_MAP, N_SDK_MOTORS, LegJointMap
from unitree_sdk2py.idl.default import unitree_go_msg_dds__LowCmd_, unitree_go_msg_dds__LowState_
from unitree_sdk2py.idl.unitree_go.msg.dds_ import LowCmd_, LowState_
from unitree_sdk2py.utils.crc import CRC

__all__ = [
    "HEAD",
    "LEVEL_LOW",
    "MOTOR_SERVO",
    "LegReading",
    "LowCmdWriter",
    "crc32",
    "crc_ok",
    "new_lowcmd",
    "new_lowstate",
    "read_lowstate",
    "seal",
]

HEAD = (0xFE, 0xEF)
"""Frame head of every low-level message."""
LEVEL_LOW = 0xFF
"""``level_flag`` of low-level control."""
MOTOR_SERVO = 0x01
"""Motor mode: servo (PD + torque, FOC)."""
MOTOR_OFF = 0x00
POS_STOP_F = 2.146e9
VEL_STOP_F = 16000.0

_crc = CRC()
# The messages' C layouts (little-endian, 4-byte aligned), over which the robot computes
# its CRC-32 (the SDK's algorithm and C routine). The SDK's own CRC builds a Python list
# word by word (about 150 us a message); packing with one Struct and handing the words
# to the same C routine gives the same value in a fraction of that, which matters at
# 500 Hz in Python. tests/unit/test_unitree_adapter.py checks both agree.
_LOWCMD = struct.Struct("<4B4IH2x" + "B3x5f3I" * N_SDK_MOTORS + "4B" + "55Bx2I")
_LOWSTATE = struct.Struct(
    "<4B4IH2x" + "13fb3x" + "B3x7fb3x3I" * N_SDK_MOTORS + "4BiH4b15H" + "8hI41B3xf2b2x2f4h2I"
)
_crc_core = _crc.crc_lib.crc32_core if getattr(_crc, "crc_lib", None) is not None else None


def _lowcmd_values(c: LowCmd_) -> list:
    v = [*c.head, c.level_flag, c.frame_reserve, *c.sn, *c.version, c.bandwidth]
    for m in c.motor_cmd:
        v += (m.mode, m.q, m.dq, m.tau, m.kp, m.kd, *m.reserve)
    b = c.bms_cmd
    v += (b.off, *b.reserve, *c.wireless_remote, *c.led, *c.fan, c.gpio, c.reserve, c.crc)
    return v


def _lowstate_values(s: LowState_) -> list:
    v = [*s.head, s.level_flag, s.frame_reserve, *s.sn, *s.version, s.bandwidth]
    i = s.imu_state
    v += (*i.quaternion, *i.gyroscope, *i.accelerometer, *i.rpy, i.temperature)
    for m in s.motor_state:
        v += (m.mode, m.q, m.dq, m.ddq, m.tau_est, m.q_raw, m.dq_raw, m.ddq_raw)
        v += (m.temperature, m.lost, *m.reserve)
    b = s.bms_state
    v += (b.version_high, b.version_low, b.status, b.soc, b.current, b.cycle)
    v += (*b.bq_ntc, *b.mcu_ntc, *b.cell_vol, *s.foot_force, *s.foot_force_est, s.tick)
    v += (*s.wireless_remote, s.bit_flag, s.adc_reel, s.temperature_ntc1, s.temperature_ntc2)
    v += (s.power_v, s.power_a, *s.fan_frequency, s.reserve, s.crc)
    return v


def crc32(msg: LowCmd_ | LowState_) -> int:
    """The SDK's CRC-32 of a ``unitree_go`` LowCmd_ or LowState_ (every word but the last,
    which is the crc itself)."""
    if _crc_core is None:  # no C routine for this platform: the SDK's own path
        return int(_crc.Crc(msg))
    if isinstance(msg, LowCmd_):
        raw = _LOWCMD.pack(*_lowcmd_values(msg))
    elif isinstance(msg, LowState_):
        raw = _LOWSTATE.pack(*_lowstate_values(msg))
    else:
        raise TypeError(f"no CRC for {type(msg).__name__}")
    words = np.frombuffer(raw, dtype="<u4")[:-1]
    return int(_crc_core(words.ctypes.data_as(ctypes.POINTER(ctypes.c_uint32)), len(words)))


def crc_ok(msg: LowCmd_ | LowState_) -> bool:
    """True when the message's ``crc`` matches its contents."""
    return int(msg.crc) == crc32(msg)


def seal(msg: LowCmd_ | LowState_) -> None:
    """Write the CRC into the message (last, after every other field)."""
    msg.crc = crc32(msg)


def new_lowcmd(used: np.ndarray) -> LowCmd_:
    """A LowCmd_ with the head set and the slots not in ``used`` stopped."""
    cmd = unitree_go_msg_dds__LowCmd_()
    cmd.head = list(HEAD)
    cmd.level_flag = LEVEL_LOW
    cmd.gpio = 0
    used_set = {int(i) for i in used}
    for i in range(N_SDK_MOTORS):
        m = cmd.motor_cmd[i]
        m.mode = MOTOR_SERVO if i in used_set else MOTOR_OFF
        m.q, m.dq = POS_STOP_F, VEL_STOP_F
        m.kp = m.kd = m.tau = 0.0
    return cmd


def new_lowstate() -> LowState_:
    """An empty LowState_ with the head set."""
    st = unitree_go_msg_dds__LowState_()
    st.head = list(HEAD)
    st.level_flag = LEVEL_LOW
    return st


class LowCmdWriter:
    """Fills one reusable LowCmd_ from our leg targets (wire order) and seals it."""

    def __init__(self, leg_map: LegJointMap = LEG_MAP) -> None:
        self.map = leg_map
        self.cmd = new_lowcmd(leg_map.motor)

    def fill(self, t: MotorTargets) -> LowCmd_:
        """The sealed message for ``t`` (the same object every call)."""
        lm = self.map
        q = lm.position_to_sdk(t.q)
        dq = lm.signed_to_sdk(t.dq)
        tau = lm.signed_to_sdk(t.tau)
        kp = lm.gains_to_sdk(t.kp)
        kd = lm.gains_to_sdk(t.kd)
        mc = self.cmd.motor_cmd
        for i in lm.motor.tolist():
            m = mc[i]
            m.mode = MOTOR_SERVO
            m.q = float(q[i])
            m.dq = float(dq[i])
            m.kp = float(kp[i])
            m.kd = float(kd[i])
            m.tau = float(tau[i])
        seal(self.cmd)
        return self.cmd


@dataclass(frozen=True)
class LegReading:
    """One LowState_ in our terms: legs in wire order, IMU [w,x,y,z] and body frame."""

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    orientation: np.ndarray
    angular_velocity: np.ndarray
    linear_acceleration: np.ndarray
    foot_force: np.ndarray
    tick: int


def read_lowstate(st: LowState_, leg_map: LegJointMap = LEG_MAP) -> LegReading:
    """Our view of a LowState_ (the caller checks the CRC first where it matters)."""
    ms = st.motor_state
    q = np.fromiter((m.q for m in ms), float, N_SDK_MOTORS)
    dq = np.fromiter((m.dq for m in ms), float, N_SDK_MOTORS)
    tau = np.fromiter((m.tau_est for m in ms), float, N_SDK_MOTORS)
    imu = st.imu_state
    return LegReading(
        q=leg_map.position_from_sdk(q),
        dq=leg_map.signed_from_sdk(dq),
        tau=leg_map.signed_from_sdk(tau),
        orientation=np.asarray(imu.quaternion, dtype=float),
        angular_velocity=np.asarray(imu.gyroscope, dtype=float),
        linear_acceleration=np.asarray(imu.accelerometer, dtype=float),
        foot_force=np.asarray(st.foot_force, dtype=float),
        tick=int(st.tick),
    )
