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
from quadmanip.hardware.unitree.wire_format import (
    CDR_HEADER_LE,
    LOWCMD_FIELDS,
    LOWSTATE_FIELDS,
    c_struct,
    cdr_struct,
)
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
    "decode_lowcmd",
    "decode_lowstate",
    "fast_wire",
    "lowcmd_crc_ok",
    "lowstate_crc_ok",
    "read_lowstate",
    "read_lowstate_values",
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
_crc_core = getattr(_crc, "crc_lib", None)
_crc_core = _crc_core.crc32_core if _crc_core is not None else None
_LOWCMD_C = c_struct(LOWCMD_FIELDS)
_LOWSTATE_C = c_struct(LOWSTATE_FIELDS)
_LOWCMD_CDR = cdr_struct(LOWCMD_FIELDS)
_LOWSTATE_CDR = cdr_struct(LOWSTATE_FIELDS)
# Positions in the flat value tuples (IDL order, wire_format's field lists).
_HDR = 9  # head[2] level_flag frame_reserve sn[2] version[2] bandwidth
CMD_MOTOR0, CMD_MOTOR_STRIDE = _HDR, 9  # mode q dq tau kp kd reserve[3]
ST_IMU = _HDR  # quaternion[4] gyroscope[3] accelerometer[3] rpy[3] temperature
ST_MOTOR0, ST_MOTOR_STRIDE = _HDR + 14, 12  # mode q dq ddq tau_est ... (12 values)
ST_FOOT = ST_MOTOR0 + 20 * ST_MOTOR_STRIDE + 25  # after the BMS state's 25 values
ST_TICK = ST_FOOT + 8


def lowcmd_values(c: LowCmd_) -> list:
    """The LowCmd_'s fields flattened in IDL order."""
    v = [*c.head, c.level_flag, c.frame_reserve, *c.sn, *c.version, c.bandwidth]
    for m in c.motor_cmd:
        v += (m.mode, m.q, m.dq, m.tau, m.kp, m.kd, *m.reserve)
    b = c.bms_cmd
    v += (b.off, *b.reserve, *c.wireless_remote, *c.led, *c.fan, c.gpio, c.reserve, c.crc)
    return v


def lowstate_values(s: LowState_) -> list:
    """The LowState_'s fields flattened in IDL order."""
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


def _crc_of(layout: struct.Struct, values: tuple | list) -> int:
    raw = layout.pack(*values)
    words = np.frombuffer(raw, dtype="<u4")[:-1]  # every word but the crc itself
    if _crc_core is None:  # no C routine for this platform: the SDK's Python loop
        return int(_crc._crc_py(words.tolist()))
    return int(_crc_core(words.ctypes.data_as(ctypes.POINTER(ctypes.c_uint32)), len(words)))


def crc32(msg: LowCmd_ | LowState_) -> int:
    """The SDK's CRC-32 of a ``unitree_go`` LowCmd_ or LowState_."""
    if isinstance(msg, LowCmd_):
        return _crc_of(_LOWCMD_C, lowcmd_values(msg))
    if isinstance(msg, LowState_):
        return _crc_of(_LOWSTATE_C, lowstate_values(msg))
    raise TypeError(f"no CRC for {type(msg).__name__}")


def lowcmd_crc_ok(values: tuple) -> bool:
    """CRC check of a decoded LowCmd_ (:func:`decode_lowcmd`)."""
    return int(values[-1]) == _crc_of(_LOWCMD_C, values)


def lowstate_crc_ok(values: tuple) -> bool:
    """CRC check of a decoded LowState_ (:func:`decode_lowstate`)."""
    return int(values[-1]) == _crc_of(_LOWSTATE_C, values)


def decode_lowcmd(data: bytes) -> tuple:
    """A LowCmd_ sample's wire bytes → its flat field values (IDL order)."""
    if data[:4] != CDR_HEADER_LE:
        raise ValueError(f"not a little-endian XCDR1 sample (header {data[:4].hex()})")
    return _LOWCMD_CDR.unpack_from(data, 4)


def decode_lowstate(data: bytes) -> tuple:
    """A LowState_ sample's wire bytes → its flat field values (IDL order)."""
    if data[:4] != CDR_HEADER_LE:
        raise ValueError(f"not a little-endian XCDR1 sample (header {data[:4].hex()})")
    return _LOWSTATE_CDR.unpack_from(data, 4)


def fast_wire(msg: LowCmd_ | LowState_) -> None:
    """Give this message object the fast encoder (the writer calls ``serialize``); the
    bytes are the SDK's own (tests check), XCDR2 requests fall back to the SDK's path."""
    layout = _LOWCMD_CDR if isinstance(msg, LowCmd_) else _LOWSTATE_CDR
    values = lowcmd_values if isinstance(msg, LowCmd_) else lowstate_values
    slow = msg.serialize

    def serialize(
        buffer: object = None, endianness: object = None, use_version_2: object = None
    ) -> bytes:
        if buffer is not None or endianness is not None or use_version_2:
            return slow(buffer=buffer, endianness=endianness, use_version_2=use_version_2)
        return CDR_HEADER_LE + layout.pack(*values(msg))

    msg.serialize = serialize  # type: ignore[method-assign]


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
        fast_wire(self.cmd)

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


def read_lowstate_values(v: tuple, leg_map: LegJointMap = LEG_MAP) -> LegReading:
    """Our view of a decoded LowState_ (:func:`decode_lowstate`)."""
    m0, k = ST_MOTOR0, ST_MOTOR_STRIDE
    n = N_SDK_MOTORS
    q = np.array(v[m0 + 1 : m0 + k * n : k], dtype=float)
    dq = np.array(v[m0 + 2 : m0 + k * n : k], dtype=float)
    tau = np.array(v[m0 + 4 : m0 + k * n : k], dtype=float)
    return LegReading(
        q=leg_map.position_from_sdk(q),
        dq=leg_map.signed_from_sdk(dq),
        tau=leg_map.signed_from_sdk(tau),
        orientation=np.array(v[ST_IMU : ST_IMU + 4], dtype=float),
        angular_velocity=np.array(v[ST_IMU + 4 : ST_IMU + 7], dtype=float),
        linear_acceleration=np.array(v[ST_IMU + 7 : ST_IMU + 10], dtype=float),
        foot_force=np.array(v[ST_FOOT : ST_FOOT + 4], dtype=float),
        tick=int(v[ST_TICK]),
    )
