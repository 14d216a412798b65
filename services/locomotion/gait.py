"""Gait schedules: the paper's four-phase trot (Sec. 6.2.2, Fig. 16) and standing.

One trot cycle is swing_FLRR (T_sw) → stance (T_st, all four feet down) → swing_FRRL (T_sw)
→ stance (T_st), so each leg swings T_sw and stands T_sw + 2·T_st per cycle of
2·(T_sw + T_st). Legs are ordered FL, FR, RL, RR everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Diagonal pairs: FL+RR swing first, then FR+RL.
PAIR_A = np.array([True, False, False, True])
PAIR_B = ~PAIR_A


@dataclass(frozen=True)
class GaitParams:
    """Trot timing (paper Table 3: T_sw = 0.3 s, T_st = 0.1 s) and swing height."""

    t_swing: float = 0.3
    t_stance: float = 0.1
    foot_height: float = 0.08


class TrotGait:
    """Contact schedule of the four-phase trot, as a function of time since the gait began."""

    def __init__(self, params: GaitParams) -> None:
        if params.t_swing <= 0.0 or params.t_stance < 0.0:
            raise ValueError("t_swing must be > 0 and t_stance ≥ 0")
        self.params = params
        self.period = 2.0 * (params.t_swing + params.t_stance)

    def phase_info(self, t: float) -> tuple[np.ndarray, np.ndarray, int]:
        """Return (contact[4], swing_progress[4] in [0,1) or -1 in stance, phase index 0..3).

        Phase indices follow Fig. 16: 0 swing_FLRR, 1 stance_FLRR, 2 swing_FRRL, 3 stance_FRRL.
        """
        p = self.params
        tc = float(t) % self.period
        contact = np.ones(4, dtype=bool)
        progress = np.full(4, -1.0)
        if tc < p.t_swing:
            contact[PAIR_A] = False
            progress[PAIR_A] = tc / p.t_swing
            return contact, progress, 0
        if tc < p.t_swing + p.t_stance:
            return contact, progress, 1
        ts = tc - p.t_swing - p.t_stance
        if ts < p.t_swing:
            contact[PAIR_B] = False
            progress[PAIR_B] = ts / p.t_swing
            return contact, progress, 2
        return contact, progress, 3

    def contact(self, t: float) -> np.ndarray:
        """Which feet are scheduled down at time t."""
        return self.phase_info(t)[0]

    def schedule(self, t0: float, n: int, dt: float) -> np.ndarray:
        """Contact flags (n, 4) for the MPC horizon, sampled at t0 + k·dt, k = 0..n-1."""
        return np.stack([self.contact(t0 + k * dt) for k in range(n)])

    def in_all_stance(self, t: float) -> bool:
        """True in the two four-feet phases: the moments the gait may stop safely."""
        return self.phase_info(t)[2] in (1, 3)

    def stance_duration(self) -> float:
        """How long each foot stays down per cycle."""
        return self.params.t_swing + 2.0 * self.params.t_stance
