"""Base position/velocity estimation from IMU + leg kinematics (linear Kalman filter).

The filter of the MIT Cheetah software (Bledt et al., 2018) that ref. [20] builds on:
orientation and body rates come from the IMU directly; a linear Kalman filter estimates

    x = [p (3), v (3), p_foot (4×3)]  in the odometry frame,

predicting with the IMU's specific force rotated to the odom frame plus gravity, and
correcting with, per foot,
    p_foot − p = R · r_foot            (foot position from joint encoders),
    −v = R · (ω × r_foot + J q̇)        (a foot in stance does not slide),
    p_foot,z = foot radius              (a foot in stance is on the flat floor).
Contact comes from the gait schedule (no foot sensors). Feet in swing, and a foot in its first
moments of stance, get a very large measurement noise so they do not corrupt the estimate.
Nothing here reads ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from quadmanip.common.rotations import quat_to_mat

GRAVITY_VEC = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class EstimatorParams:
    """Noise levels (standard deviations) of the Kalman filter."""

    accel_noise: float = 0.5  # m/s² (process, on v)
    position_process_noise: float = 0.002  # m per step
    foot_process_noise: float = 0.002  # m per step, stance foot
    foot_swing_noise: float = 1.0  # m per step, swing foot (free to move)
    foot_kin_noise: float = 0.005  # m, kinematic foot position
    foot_vel_noise: float = 0.1  # m/s, stance foot velocity
    foot_height_noise: float = 0.02  # m, stance foot on the floor
    swing_factor: float = 1000.0  # noise multiplier for feet not in stance
    foot_radius: float = 0.02  # m, the foot sphere sits this high on the floor


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for a (3,) and b (n, 3) (np.cross is slow for tiny arrays)."""
    out = np.empty_like(b)
    out[:, 0] = a[1] * b[:, 2] - a[2] * b[:, 1]
    out[:, 1] = a[2] * b[:, 0] - a[0] * b[:, 2]
    out[:, 2] = a[0] * b[:, 1] - a[1] * b[:, 0]
    return out


class StateEstimator:
    """Linear Kalman filter for base position and velocity (see module doc)."""

    def __init__(self, params: EstimatorParams) -> None:
        self.params = params
        self.x = np.zeros(18)
        self.P = np.eye(18) * 0.01
        self.R = np.eye(3)
        self.omega_body = np.zeros(3)
        self.initialised = False
        # Constant measurement matrix: [p_f - p (12); v (12); p_f,z (4)] from x.
        h = np.zeros((28, 18))
        for i in range(4):
            h[3 * i : 3 * i + 3, 0:3] = -np.eye(3)
            h[3 * i : 3 * i + 3, 6 + 3 * i : 9 + 3 * i] = np.eye(3)
            h[12 + 3 * i : 15 + 3 * i, 3:6] = np.eye(3)
            h[24 + i, 8 + 3 * i] = 1.0
        self._h = h
        self._eye18 = np.eye(18)

    def reset(
        self, quat: np.ndarray, foot_rel_body: np.ndarray, height: float | None = None
    ) -> None:
        """Start at the odom origin (x, y = 0) with the base height from leg kinematics."""
        self.R = quat_to_mat(np.asarray(quat, dtype=float))
        feet_w = (self.R @ foot_rel_body.T).T
        z = (
            height
            if height is not None
            else float(-np.mean(feet_w[:, 2]) + self.params.foot_radius)
        )
        self.x[:] = 0.0
        self.x[2] = z
        self.x[6:18] = (feet_w + self.x[:3]).reshape(-1)
        self.P = np.eye(18) * 1e-4
        self.initialised = True

    @property
    def position(self) -> np.ndarray:
        """Estimated base position in odom."""
        return self.x[0:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        """Estimated base velocity in odom (world-aligned)."""
        return self.x[3:6].copy()

    def update(
        self,
        dt: float,
        quat: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        foot_rel_body: np.ndarray,
        foot_vel_body: np.ndarray,
        stance: np.ndarray,
    ) -> None:
        """One predict + correct step.

        quat: IMU orientation [w, x, y, z]; gyro: body rates; accel: specific force (body);
        foot_rel_body (4, 3): foot positions relative to the base, base frame;
        foot_vel_body (4, 3): J q̇ of each foot, base frame; stance (4,): trust weights in
        [0, 1] (1 = firmly in stance by the schedule).
        """
        pr = self.params
        if not self.initialised:
            self.reset(quat, foot_rel_body)
        r = quat_to_mat(np.asarray(quat, dtype=float))
        self.R = r
        self.omega_body = np.asarray(gyro, dtype=float)
        a_world = r @ np.asarray(accel, dtype=float) + GRAVITY_VEC
        # Predict.
        x = self.x
        x[0:3] += x[3:6] * dt + 0.5 * a_world * dt * dt
        x[3:6] += a_world * dt
        stance = np.clip(np.asarray(stance, dtype=float), 0.0, 1.0)
        q_diag = np.empty(18)
        q_diag[0:3] = pr.position_process_noise**2
        q_diag[3:6] = (pr.accel_noise * dt) ** 2
        foot_q = np.where(stance > 0.5, pr.foot_process_noise, pr.foot_swing_noise) ** 2
        q_diag[6:18] = np.repeat(foot_q, 3)
        # F P Fᵀ for F = I + dt·E(p ← v), written out (F is identity but for one block).
        p_mat = self.P.copy()
        p_mat[0:3, :] += dt * p_mat[3:6, :]
        p_mat[:, 0:3] += dt * p_mat[:, 3:6]
        p_mat[np.diag_indices(18)] += q_diag
        # Measurements.
        rel_w = (r @ np.asarray(foot_rel_body, dtype=float).T).T  # (4, 3)
        wxr = _cross(self.omega_body, np.asarray(foot_rel_body, dtype=float))
        vel_w = -(r @ (wxr + np.asarray(foot_vel_body, dtype=float)).T).T  # base vel per foot
        y = np.concatenate([rel_w.reshape(-1), vel_w.reshape(-1), np.full(4, pr.foot_radius)])
        h = self._h
        trust = 1.0 + (1.0 - stance) * (pr.swing_factor - 1.0)
        r_diag = np.concatenate(
            [
                np.full(12, pr.foot_kin_noise**2),
                np.repeat(trust, 3) * pr.foot_vel_noise**2,
                trust * pr.foot_height_noise**2,
            ]
        )
        s = h @ p_mat @ h.T
        s[np.diag_indices(28)] += r_diag
        k = np.linalg.solve(s, h @ p_mat).T
        self.x = x + k @ (y - h @ x)
        self.P = (self._eye18 - k @ h) @ p_mat
        self.P = 0.5 * (self.P + self.P.T)
