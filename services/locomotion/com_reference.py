"""Reference trajectory for the MPC: COM controller (eqs. 10–12) and FSM (Algorithm 7).

Eq. (10) integrates the target position with the commanded velocity; eqs. (11)–(12) integrate
the target orientation quaternion [w, x, y, z] with the commanded body rate.

Corrections to the paper (OCR / logic):
* Eq. (11): the second row of Ω printed as [ω_x, 0, ω_z, -ω_z] must be [ω_x, 0, ω_z, -ω_y];
  with that row, q̇ = ½ Ω(ω) q equals ½ q ⊗ [0, ω] (ω in the body frame), and we renormalise
  q after each Euler step (I + ½ Ω Δt) since that step does not preserve the norm.
* Algorithm 7, lines 16–19: as printed the planned velocity *decreases* while the stopping
  distance v²/(2·a) is still below the remaining distance, which never reaches the target.
  We accelerate towards the target while it is possible to stop in time and |v| < VEL_LIMIT,
  decelerate once the stopping distance reaches the remaining distance, and also decelerate
  when |v| exceeds VEL_LIMIT (the printed FSM would keep an excess velocity forever).
* VEL_LIMIT is |v_target| per axis (Sec. 6.2.1), floored at FEED_BACK_VEL so that an axis
  with no commanded velocity can still correct a small offset.
* The target may not run further than ``max_lead`` ahead of the estimated pose (a robot
  that is held back must not build up a large position error that it later sprints for).
* Algorithm 7 plans roll, pitch and yaw as independent axes (Euler angles), while the MPC's
  state holds the world angular velocity ω: the plan starts from the Euler rates Rz(ψ)ᵀ ω
  and hands the MPC Rz(ψ) times its planned rates (the MPC's own small-angle model). Mixing
  the two is harmless facing 0° and tracks roll as pitch facing ±90°.
* While walking forward/backward, VEL_LIMIT gets a catch-up allowance of ``catch_up_gain`` ×
  the target's lead along the heading (at most ``catch_up_max``): without it the plan, which
  starts from the current velocity, settles about 10 % below the commanded speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from quadmanip.common.rotations import rot_z, wrap_angle, yaw_from_quat


@dataclass(frozen=True)
class FsmParams:
    """Algorithm 7 constants, per axis group (linear in m, m/s; angular in rad, rad/s)."""

    adjust_vel_threshold: float = 0.003
    feed_back_vel: float = 0.05
    planned_acc: float = 2.0
    adjust_ang_threshold: float = 0.005
    feed_back_ang_vel: float = 0.1
    planned_ang_acc: float = 4.0
    max_lead: float = 0.15
    max_lead_yaw: float = 0.3
    catch_up_gain: float = 1.0  # 1/s, extra VEL_LIMIT per metre the target leads
    catch_up_max: float = 0.1  # m/s


def omega_matrix(w: np.ndarray) -> np.ndarray:
    """Eq. (11), corrected: q̇ = ½ Ω(ω) q for q = [w, x, y, z] and body rate ω."""
    wx, wy, wz = (float(v) for v in w)
    return np.array(
        [
            [0.0, -wx, -wy, -wz],
            [wx, 0.0, wz, -wy],
            [wy, -wz, 0.0, wx],
            [wz, wy, -wx, 0.0],
        ]
    )


def integrate_quat(q: np.ndarray, w_body: np.ndarray, dt: float) -> np.ndarray:
    """Eq. (12): q(t+Δt) = (I + ½ Ω Δt) q(t), renormalised."""
    q_new = (np.eye(4) + 0.5 * omega_matrix(w_body) * dt) @ np.asarray(q, dtype=float)
    return q_new / np.linalg.norm(q_new)


def fsm_plan(
    pose: np.ndarray,
    vel: np.ndarray,
    desired: np.ndarray,
    vel_limit: np.ndarray,
    threshold: np.ndarray,
    feed_back_vel: np.ndarray,
    acc: np.ndarray,
    horizon: int,
    dt: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 7 for several independent axes (see module notes for the corrections).

    All inputs are arrays over axes; returns planned (pose, vel), each (horizon, n_axes).
    Plain Python floats: for a handful of axes this is several times faster than numpy.
    """
    n_ax = len(pose)
    planned_pose = np.empty((horizon, n_ax))
    planned_vel = np.empty((horizon, n_ax))
    for a in range(n_ax):
        p, v = float(pose[a]), float(vel[a])
        goal, lim, thr = float(desired[a]), float(vel_limit[a]), float(threshold[a])
        fbv, ac = float(feed_back_vel[a]), float(acc[a])
        for i in range(horizon):
            diff = goal - p
            if abs(diff) < thr:
                v, p = 0.0, goal
            else:
                sign = 1.0 if diff > 0.0 else -1.0
                if diff * v < 0.0:  # moving away: turn back at FEED_BACK_VEL
                    v = sign * fbv
                elif v * v / (2.0 * ac) < abs(diff) and abs(v) <= lim:
                    v = sign * min(abs(v) + ac * dt, lim)  # accelerate up to VEL_LIMIT
                else:  # must brake (or above VEL_LIMIT): decelerate, never reverse
                    v_new = v - ac * dt * (1.0 if v > 0.0 else -1.0)
                    v = 0.0 if v_new * v < 0.0 else v_new
                p += v * dt
            planned_pose[i, a] = p
            planned_vel[i, a] = v
    return planned_pose, planned_vel


class ComReference:
    """Target pose integration (eqs. 10–12) + FSM planning (Algorithm 7) for the MPC.

    Axes handled by the FSM: x, y, z (world) and roll, pitch, yaw. The walking target moves
    with the commanded body velocity; height and roll/pitch come from body pose commands.
    """

    def __init__(self, params: FsmParams) -> None:
        self.params = params
        self.p_target = np.zeros(3)
        self.q_target = np.array([1.0, 0.0, 0.0, 0.0])
        self.rp_target = np.zeros(2)
        self.v_target_world = np.zeros(3)
        self.yaw_rate_target = 0.0

    def reset(self, position: np.ndarray, yaw: float) -> None:
        """Put the target where the robot is (on stand-up or mode changes)."""
        self.p_target = np.array(position, dtype=float)
        self.q_target = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        self.v_target_world = np.zeros(3)
        self.yaw_rate_target = 0.0

    @property
    def yaw_target(self) -> float:
        """Yaw of the target orientation."""
        return yaw_from_quat(self.q_target)

    def advance(
        self,
        v_body: np.ndarray,
        yaw_rate: float,
        height: float,
        dt: float,
        position: np.ndarray,
        yaw: float,
    ) -> None:
        """Eqs. (10)–(12) for one control period; v_body = (vx, vy) commanded in the base frame."""
        pr = self.params
        yaw_t = self.yaw_target
        c, s = np.cos(yaw_t), np.sin(yaw_t)
        vw = np.array([c * v_body[0] - s * v_body[1], s * v_body[0] + c * v_body[1], 0.0])
        self.v_target_world = vw
        self.yaw_rate_target = float(yaw_rate)
        self.p_target = self.p_target + vw * dt  # eq. (10)
        self.p_target[2] = height
        self.q_target = integrate_quat(self.q_target, np.array([0.0, 0.0, yaw_rate]), dt)
        # Keep the target within reach of the estimated pose.
        lead = self.p_target[:2] - np.asarray(position[:2])
        d = float(np.linalg.norm(lead))
        if d > pr.max_lead:
            self.p_target[:2] = np.asarray(position[:2]) + lead * (pr.max_lead / d)
        dy = float(wrap_angle(self.yaw_target - yaw))
        if abs(dy) > pr.max_lead_yaw:
            yt = yaw + np.sign(dy) * pr.max_lead_yaw
            self.q_target = np.array([np.cos(yt / 2), 0.0, 0.0, np.sin(yt / 2)])

    def plan(
        self,
        rpy: np.ndarray,
        position: np.ndarray,
        omega_world: np.ndarray,
        velocity: np.ndarray,
        roll_pitch_des: np.ndarray,
        horizon: int,
        dt: float,
    ) -> np.ndarray:
        """Algorithm 7 over the horizon → x_ref (horizon, 12) = [Θ, p, ω, v] for the MPC."""
        pr = self.params
        yaw = float(rpy[2])
        yaw_des = yaw + float(wrap_angle(self.yaw_target - yaw))  # unwrap around the current yaw
        pose = np.array([position[0], position[1], position[2], rpy[0], rpy[1], yaw])
        # The roll/pitch/yaw axes plan Euler angles, so they start from Euler rates, and the
        # MPC's ω reference is in the world frame: Θ̇ = Rz(ψ)ᵀ ω both ways (the MPC's own
        # model). Handing it the world ω as if it were Euler rates tracked roll as pitch
        # when facing ±90°: a robot standing still at 90° rolled over in 10 s (measured).
        rz = rot_z(yaw)
        euler_rate = rz.T @ np.asarray(omega_world, dtype=float)
        vel = np.array(
            [velocity[0], velocity[1], velocity[2], euler_rate[0], euler_rate[1], euler_rate[2]]
        )
        desired = np.array(
            [
                self.p_target[0],
                self.p_target[1],
                self.p_target[2],
                roll_pitch_des[0],
                roll_pitch_des[1],
                yaw_des,
            ]
        )
        # VEL_LIMIT = |v_target| (Sec. 6.2.1) plus a catch-up allowance proportional to how
        # far the eq. (10) target leads along the robot's heading: integral action on the
        # forward speed, which the FSM (it starts from the current velocity) lacks.
        # Sideways it is left out: there it made the trunk roll over (measured).
        heading = np.array([np.cos(yaw), np.sin(yaw)])
        lead = float(np.dot(self.p_target[:2] - np.asarray(position[:2]), heading))
        moving = abs(float(np.dot(self.v_target_world[:2], heading))) > 1e-6
        catch_up = min(pr.catch_up_gain * abs(lead), pr.catch_up_max) if moving else 0.0
        lin_lim = np.maximum(
            np.abs(self.v_target_world[:2]) + catch_up * np.abs(heading), pr.feed_back_vel
        )
        ang_lim = max(abs(self.yaw_rate_target), pr.feed_back_ang_vel)
        vel_limit = np.array([lin_lim[0], lin_lim[1], 0.3, 0.5, 0.5, ang_lim])
        thr = np.array([pr.adjust_vel_threshold] * 3 + [pr.adjust_ang_threshold] * 3)
        fbv = np.array([pr.feed_back_vel] * 3 + [pr.feed_back_ang_vel] * 3)
        acc = np.array([pr.planned_acc] * 3 + [pr.planned_ang_acc] * 3)
        pp, pv = fsm_plan(pose, vel, desired, vel_limit, thr, fbv, acc, horizon, dt)
        x_ref = np.zeros((horizon, 12))
        x_ref[:, 0:3] = pp[:, 3:6]
        x_ref[:, 3:6] = pp[:, 0:3]
        c, s = np.cos(pp[:, 5]), np.sin(pp[:, 5])
        x_ref[:, 6] = c * pv[:, 3] - s * pv[:, 4]
        x_ref[:, 7] = s * pv[:, 3] + c * pv[:, 4]
        x_ref[:, 8] = pv[:, 5]
        x_ref[:, 9:12] = pv[:, 0:3]
        return x_ref
