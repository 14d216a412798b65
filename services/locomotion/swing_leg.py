"""Swing-foot trajectory (paper Algorithm 8) and foot placement.

Algorithm 8 places the foot at the hip's nominal position plus a Raibert-style step
(velocity times TIME_CONST = T_sw/2 + EXTRA) with a yaw-rate term, moves it in x/y with the
cosine profile 0.5·(1 − cos(π t / T_sw)) and lifts it with z = h · sin(π t / T_sw).

Corrections / choices (documented deviations):
* The printed T_em and T_res are T_sw (OCR).
* The printed yaw terms use the same sign for the left and right legs; the hip's velocity due
  to the yaw rate is ω × r_hip = (−ω_z·y_hip, ω_z·x_hip), which flips sign between left and
  right (and front and rear). We use ω × r_hip.
* The printed trajectory starts at the hip's nominal position, which is not where the foot
  lifted off (it is behind the hip after stance): the cosine profile here blends from the
  lift-off point to the touchdown target, so the foot does not jump at lift-off.
* Placement adds the capture-point feedback k·(v − v_cmd) of the Cheetah controllers, which
  Algorithm 8 omits; it is what stops a pushed robot. Where the hip will be at touchdown is
  predicted with the measured velocity (plus the yaw-rate term), not the commanded one: a
  robot that lags its command (in a tight turn) would otherwise step too far ahead and
  brake itself (tight-turn RMSE 0.14 → 0.11 m/s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SwingParams:
    """Foot placement and swing tracking gains."""

    extra_time: float = 0.0  # EXTRA_DIST of Algorithm 8, expressed in seconds
    feedback_gain: float = 0.15  # s, capture-point gain on (v - v_cmd)
    max_step: float = 0.15  # m, bound on the step offset from the hip
    kp_cartesian: tuple[float, float, float] = (500.0, 500.0, 500.0)  # N/m
    kd_cartesian: tuple[float, float, float] = (12.0, 12.0, 12.0)  # N s/m


def touchdown_target(
    hip_world: np.ndarray,
    v_world: np.ndarray,
    v_cmd_world: np.ndarray,
    yaw_rate: float,
    hip_offset_world: np.ndarray,
    stance_time: float,
    time_to_touchdown: float,
    params: SwingParams,
    foot_radius: float,
) -> np.ndarray:
    """Algorithm 8 placement: where a swinging foot should land (world frame, (4, 3))."""
    # Hip position when the foot lands, predicted with the commanded motion.
    hip_vel = v_cmd_world[None, :2] + yaw_rate * np.stack(
        [-hip_offset_world[:, 1], hip_offset_world[:, 0]], axis=1
    )
    # The hip moves with the actual velocity until touchdown (plus the yaw-rate term).
    hip_act = v_world[None, :2] + (hip_vel - v_cmd_world[None, :2])
    hip_td = hip_world[:, :2] + hip_act * time_to_touchdown[:, None]
    time_const = 0.5 * stance_time + params.extra_time
    step = hip_vel * time_const + params.feedback_gain * (v_world[None, :2] - v_cmd_world[None, :2])
    norm = np.linalg.norm(step, axis=1, keepdims=True)
    step = step * np.minimum(1.0, params.max_step / np.maximum(norm, 1e-9))
    target = np.empty((hip_world.shape[0], 3))
    target[:, :2] = hip_td + step
    target[:, 2] = foot_radius
    return target


def swing_profile(
    start: np.ndarray, target: np.ndarray, progress: float, t_swing: float, height: float
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 8 lines 16–19: cosine x/y blend and sine z lift; returns (pos, vel)."""
    s = float(np.clip(progress, 0.0, 1.0))
    xy = 0.5 * (1.0 - np.cos(np.pi * s))
    dxy = 0.5 * np.pi * np.sin(np.pi * s) / t_swing
    pos = start + (target - start) * xy
    vel = (target - start) * dxy
    base_z = start[2] + (target[2] - start[2]) * xy
    pos[2] = base_z + height * np.sin(np.pi * s)
    vel[2] = (target[2] - start[2]) * dxy + height * np.pi * np.cos(np.pi * s) / t_swing
    return pos, vel
