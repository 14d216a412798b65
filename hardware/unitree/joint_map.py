"""Our leg joints ↔ the Unitree SDK's motor slots: the one table (docs/hardware.md).

Unitree's low-level messages carry 20 motor slots; a quadruped uses the first 12, legs in
the order FR, FL, RR, RL, each (hip, thigh, calf) = our (abad, hip, knee). Our wire order
is FL, FR, RL, RR (:mod:`quadmanip.common.joint_layout`). Each row also carries the sign
and the zero offset between our joint angle and the motor's: ``sdk = sign * ours +
offset`` for positions, ``sdk = sign * ours`` for velocities and torques, gains unchanged.
Our description uses the Go2's axes and zero pose (abad about x, hip and knee about y,
legs straight down at zero), so every sign is +1 and every offset 0; a robot that differs
changes this table and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from quadmanip.common.joint_layout import LEG_JOINTS, N_LEG_JOINTS

__all__ = [
    "N_SDK_MOTORS",
    "TABLE",
    "JointMapRow",
    "LegJointMap",
    "LEG_MAP",
]

N_SDK_MOTORS = 20
"""Motor slots in ``unitree_go`` LowCmd_/LowState_."""


@dataclass(frozen=True)
class JointMapRow:
    """One leg joint: our name, the SDK motor slot, sign and zero offset (rad)."""

    joint: str
    motor: int
    sign: float = 1.0
    offset: float = 0.0


TABLE: tuple[JointMapRow, ...] = (
    JointMapRow("FR_abad", 0),
    JointMapRow("FR_hip", 1),
    JointMapRow("FR_knee", 2),
    JointMapRow("FL_abad", 3),
    JointMapRow("FL_hip", 4),
    JointMapRow("FL_knee", 5),
    JointMapRow("RR_abad", 6),
    JointMapRow("RR_hip", 7),
    JointMapRow("RR_knee", 8),
    JointMapRow("RL_abad", 9),
    JointMapRow("RL_hip", 10),
    JointMapRow("RL_knee", 11),
)
"""The Go2/Go1/B2 layout (FR_0 = slot 0 ... RL_2 = slot 11)."""


class LegJointMap:
    """Vectorised conversions between our wire-order leg arrays (12) and SDK slots."""

    def __init__(self, rows: tuple[JointMapRow, ...] = TABLE) -> None:
        joints = [r.joint for r in rows]
        motors = [r.motor for r in rows]
        if sorted(joints) != sorted(LEG_JOINTS) or len(rows) != N_LEG_JOINTS:
            raise ValueError(f"the table must name each leg joint once: {joints}")
        if len(set(motors)) != len(motors) or not all(0 <= m < N_SDK_MOTORS for m in motors):
            raise ValueError(f"motor slots must be distinct and in 0..{N_SDK_MOTORS - 1}")
        if any(r.sign not in (1.0, -1.0) for r in rows):
            raise ValueError("signs must be +1 or -1")
        wire = {name: i for i, name in enumerate(LEG_JOINTS)}
        order = sorted(rows, key=lambda r: wire[r.joint])  # rows in our wire order
        self.rows = tuple(order)
        self.motor = np.array([r.motor for r in order], dtype=np.intp)
        """SDK slot of each of our leg joints (wire order)."""
        self.sign = np.array([r.sign for r in order])
        self.offset = np.array([r.offset for r in order])

    def position_to_sdk(self, q: np.ndarray) -> np.ndarray:
        """Our 12 positions → a 20-slot SDK array (unused slots 0)."""
        out = np.zeros(N_SDK_MOTORS)
        out[self.motor] = self.sign * np.asarray(q, dtype=float) + self.offset
        return out

    def position_from_sdk(self, q_sdk: np.ndarray) -> np.ndarray:
        """SDK slot positions (≥ 12 values) → our 12 in wire order."""
        return self.sign * (np.asarray(q_sdk, dtype=float)[self.motor] - self.offset)

    def signed_to_sdk(self, v: np.ndarray) -> np.ndarray:
        """Velocities or torques: ours → 20 SDK slots."""
        out = np.zeros(N_SDK_MOTORS)
        out[self.motor] = self.sign * np.asarray(v, dtype=float)
        return out

    def signed_from_sdk(self, v_sdk: np.ndarray) -> np.ndarray:
        """Velocities or torques: SDK slots → ours."""
        return self.sign * np.asarray(v_sdk, dtype=float)[self.motor]

    def gains_to_sdk(self, k: np.ndarray) -> np.ndarray:
        """Gains (kp, kd) only move to their slot."""
        out = np.zeros(N_SDK_MOTORS)
        out[self.motor] = np.asarray(k, dtype=float)
        return out


LEG_MAP = LegJointMap()
