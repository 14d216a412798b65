"""Byte layouts of the SDK's ``unitree_go`` LowCmd_ and LowState_, for speed at 500 Hz.

Two layouts of the same fields (IDL order, :data:`LOWCMD_FIELDS`, :data:`LOWSTATE_FIELDS`):

* the C struct the robot's firmware computes its CRC-32 over (natural alignment, each
  nested struct padded to its own alignment), and
* the DDS wire encoding (XCDR1, little endian: a 4-byte encapsulation header, then each
  primitive aligned to its size from the start of the payload; no struct padding).

The SDK's Python (de)serialiser and CRC take about 0.5 ms and 0.15 ms a LowState_ in
Python, more than a 2 ms control tick can spare across three processes on a small
computer; one ``struct`` call does either in tens of microseconds. Both layouts are
generated from the field lists below, and tests/unit/test_unitree_adapter.py checks them
byte for byte against the SDK's serialiser and CRC, so the wire stays exactly the SDK's.
"""

from __future__ import annotations

import struct

__all__ = [
    "CDR_HEADER_LE",
    "LOWCMD_FIELDS",
    "LOWSTATE_FIELDS",
    "c_struct",
    "cdr_struct",
]

CDR_HEADER_LE = b"\x00\x01\x00\x00"
"""XCDR1 encapsulation, little endian."""

Field = tuple  # (code, count) or ("struct", fields, count)

MOTOR_CMD: list[Field] = [("B", 1), ("f", 5), ("I", 3)]  # mode, q dq tau kp kd, reserve
MOTOR_STATE: list[Field] = [
    ("B", 1),  # mode
    ("f", 7),  # q dq ddq tau_est q_raw dq_raw ddq_raw
    ("B", 1),  # temperature
    ("I", 1),  # lost
    ("I", 2),  # reserve
]
IMU_STATE: list[Field] = [("f", 13), ("B", 1)]  # quaternion gyro accel rpy, temperature
BMS_CMD: list[Field] = [("B", 4)]  # off, reserve[3]
BMS_STATE: list[Field] = [
    ("B", 4),  # version_high version_low status soc
    ("i", 1),  # current
    ("H", 1),  # cycle
    ("B", 4),  # bq_ntc[2] mcu_ntc[2]
    ("H", 15),  # cell_vol
]
HEADER: list[Field] = [("B", 4), ("I", 4), ("H", 1)]  # head level frame, sn version, bw

LOWCMD_FIELDS: list[Field] = [
    *HEADER,
    ("struct", MOTOR_CMD, 20),
    ("struct", BMS_CMD, 1),
    ("B", 40 + 12 + 2 + 1),  # wireless_remote led fan gpio
    ("I", 2),  # reserve crc
]
LOWSTATE_FIELDS: list[Field] = [
    *HEADER,
    ("struct", IMU_STATE, 1),
    ("struct", MOTOR_STATE, 20),
    ("struct", BMS_STATE, 1),
    ("h", 8),  # foot_force foot_force_est
    ("I", 1),  # tick
    ("B", 41),  # wireless_remote bit_flag
    ("f", 1),  # adc_reel
    ("B", 2),  # temperature_ntc1 temperature_ntc2
    ("f", 2),  # power_v power_a
    ("H", 4),  # fan_frequency
    ("I", 2),  # reserve crc
]


def _align(fields: list[Field]) -> int:
    return max(_align(f[1]) if f[0] == "struct" else struct.calcsize(f[0]) for f in fields)


def _layout(fields: list[Field], offset: int, c: bool, out: list[str]) -> int:
    for f in fields:
        if f[0] == "struct":
            sub, n = f[1], f[2]
            a = _align(sub)
            for _ in range(n):
                if c:  # a C struct starts at its alignment...
                    pad = -offset % a
                    out.append(f"{pad}x" if pad else "")
                    offset += pad
                offset = _layout(sub, offset, c, out)
                if c:  # ...and its size is a multiple of it
                    pad = -offset % a
                    out.append(f"{pad}x" if pad else "")
                    offset += pad
            continue
        code, n = f
        size = struct.calcsize(code)
        pad = -offset % min(size, 8)
        if pad:
            out.append(f"{pad}x")
            offset += pad
        out.append(f"{n}{code}")
        offset += size * n
    return offset


def c_struct(fields: list[Field]) -> struct.Struct:
    """The C layout (the CRC's)."""
    out: list[str] = []
    size = _layout(fields, 0, True, out)
    pad = -size % _align(fields)
    return struct.Struct("<" + "".join(out) + (f"{pad}x" if pad else ""))


def cdr_struct(fields: list[Field]) -> struct.Struct:
    """The XCDR1 payload layout (after :data:`CDR_HEADER_LE`)."""
    out: list[str] = []
    _layout(fields, 0, False, out)
    return struct.Struct("<" + "".join(out))
