"""Time-stamped arm joint trajectories within velocity and acceleration limits.

Two generators, both producing knots ``(t, q, dq)`` that the actuator layer interpolates
with cubic Hermite splines:

* :func:`plan_joint_path` - rest-to-rest quintic segments through joint waypoints, all
  joints synchronised per segment. For a quintic with zero boundary velocity and
  acceleration the peaks are ``v = 15/8 |D|/T`` and ``a = 10/sqrt(3) |D|/T^2``, so the
  minimum segment time that respects both limits is known in closed form.
* :func:`plan_cartesian_line` - a straight tool-centre line in the arm plane (approach,
  lift, retract) with a quintic time scaling; IK is solved along the line with the previous
  sample as elbow reference, continuity is verified, and time is stretched uniformly until
  the joint limits hold (velocity scales with 1/k, acceleration with 1/k^2).

Every trajectory passes :func:`validate` before it is returned: finite values, joint
position, velocity and acceleration limits. Nothing that fails is ever sent to the arm.

Both start from the *measured* joints, which an arm pushed against furniture can carry a
little past a limit (paper-3, 2026-12-05: the elbow read 2.012 rad against its 2.000
limit after a blocked place, and every later move was refused, the held object with
them). A start within ``START_SLACK`` beyond a limit is taken from the limit: the first
knot sits on it and the joint's position loop pulls the arm back inside.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    fk_tcp,
    solve_ik,
)

__all__ = [
    "JointTrajectory",
    "MotionLimits",
    "TrajectoryError",
    "hold",
    "plan_cartesian_line",
    "plan_joint_path",
    "start_within_limits",
    "validate",
]

#: rad: how far past a limit a measured start joint is still taken from the limit
START_SLACK = 0.05
_QUINTIC_V = 15.0 / 8.0
_QUINTIC_A = 10.0 / math.sqrt(3.0)


class TrajectoryError(ValueError):
    """A trajectory cannot be built or would break a limit; ``reason`` is a short code."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class MotionLimits:
    """Joint limits a trajectory must respect (position from the description, rates from config)."""

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray

    @classmethod
    def build(
        cls,
        geom: ArmGeometry,
        v_max: Sequence[float],
        a_max: Sequence[float],
    ) -> MotionLimits:
        """Joint range from the geometry, rate limits from configuration."""
        return cls(
            q_min=np.asarray(geom.q_min, dtype=float),
            q_max=np.asarray(geom.q_max, dtype=float),
            v_max=np.asarray(v_max, dtype=float),
            a_max=np.asarray(a_max, dtype=float),
        )


@dataclass(frozen=True)
class JointTrajectory:
    """Knots of an arm trajectory in robot time: ``t[N]``, ``q[N,4]``, ``dq[N,4]``."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray

    @property
    def start_time(self) -> float:
        """First knot time (s)."""
        return float(self.t[0])

    @property
    def end_time(self) -> float:
        """Last knot time (s); the arm holds ``q[-1]`` afterwards."""
        return float(self.t[-1])

    @property
    def q_end(self) -> np.ndarray:
        """Final joint vector."""
        return self.q[-1].copy()

    def then(self, other: JointTrajectory) -> JointTrajectory:
        """Concatenates a trajectory that starts at (or after) this one's end."""
        if other.t[0] < self.t[-1] - 1e-12:
            raise TrajectoryError("overlap", "second trajectory starts before the first ends")
        skip = 1 if abs(other.t[0] - self.t[-1]) < 1e-12 else 0
        return JointTrajectory(
            t=np.concatenate([self.t, other.t[skip:]]),
            q=np.vstack([self.q, other.q[skip:]]),
            dq=np.vstack([self.dq, other.dq[skip:]]),
        )


def start_within_limits(q: Sequence[float], limits: MotionLimits) -> np.ndarray:
    """The measured start joints, a joint up to ``START_SLACK`` past its limit taken from
    the limit (module docstring); farther out they are returned as they are (and the
    plan is refused with ``joint_limit``)."""
    qa = np.asarray(q, dtype=float)
    near = (qa >= limits.q_min - START_SLACK) & (qa <= limits.q_max + START_SLACK)
    return np.where(near, np.clip(qa, limits.q_min, limits.q_max), qa)


def hold(q: Sequence[float], t0: float) -> JointTrajectory:
    """A single-knot trajectory: hold ``q`` from ``t0`` on (used to stop the arm)."""
    qa = np.asarray(q, dtype=float).reshape(1, 4)
    return JointTrajectory(t=np.array([float(t0)]), q=qa.copy(), dq=np.zeros((1, 4)))


def _quintic(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-to-rest quintic blend and its first two derivatives on s in [0, 1]."""
    s2 = s * s
    s3 = s2 * s
    p = 10 * s3 - 15 * s3 * s + 6 * s3 * s2
    v = 30 * s2 - 60 * s3 + 30 * s3 * s
    a = 60 * s - 180 * s2 + 120 * s3
    return p, v, a


def plan_joint_path(
    waypoints: Sequence[Sequence[float]],
    t0: float,
    limits: MotionLimits,
    dt: float = 0.02,
    min_segment: float = 0.2,
) -> JointTrajectory:
    """Quintic rest-to-rest segments through ``waypoints`` (first = current joints)."""
    wps = np.array(waypoints, dtype=float)  # a copy: the start may be clipped
    if wps.ndim != 2 or wps.shape[1] != 4 or len(wps) < 1:
        raise TrajectoryError("shape", f"waypoints shape {wps.shape} is not (N>=1, 4)")
    if not np.all(np.isfinite(wps)) or not math.isfinite(t0):
        raise TrajectoryError("non_finite", "waypoint or start time is not finite")
    wps[0] = start_within_limits(wps[0], limits)
    _check_positions(wps, limits)
    ts, qs, dqs = [np.array([t0])], [wps[:1]], [np.zeros((1, 4))]
    t_cur = float(t0)
    for a, b in zip(wps[:-1], wps[1:], strict=True):
        delta = b - a
        dist = np.abs(delta)
        if float(dist.max()) < 1e-9:
            continue
        t_v = float(np.max(_QUINTIC_V * dist / limits.v_max))
        t_a = float(np.max(np.sqrt(_QUINTIC_A * dist / limits.a_max)))
        dur = max(t_v, t_a, min_segment)
        n = max(int(math.ceil(dur / dt)), 4)
        s = np.linspace(0.0, 1.0, n + 1)[1:]
        p, v, _ = _quintic(s)
        ts.append(t_cur + s * dur)
        qs.append(a + np.outer(p, delta))
        dqs.append(np.outer(v / dur, delta))
        t_cur += dur
    traj = JointTrajectory(t=np.concatenate(ts), q=np.vstack(qs), dq=np.vstack(dqs))
    validate(traj, limits)
    return traj


def plan_cartesian_line(
    geom: ArmGeometry,
    q_start: Sequence[float],
    goal: ArmTarget,
    t0: float,
    limits: MotionLimits,
    linear_speed: float = 0.15,
    angular_speed: float = 1.0,
    dt: float = 0.02,
    max_step: float = 0.15,
) -> JointTrajectory:
    """Straight tool-centre line from FK(q_start) to ``goal`` (pitch, roll interpolated).

    Raises :class:`TrajectoryError` when any sample is unreachable (reason from IK), the
    joint path jumps (elbow flip: more than ``max_step`` rad between fine samples), or
    limits cannot be met.
    """
    q0 = np.asarray(q_start, dtype=float)
    if q0.shape != (4,) or not np.all(np.isfinite(q0)):
        raise TrajectoryError("non_finite", "start joints must be 4 finite values")
    q0 = start_within_limits(q0, limits)
    start = fk_tcp(geom, q0)
    g = np.array([goal.x, goal.z, goal.pitch, goal.roll], dtype=float)
    if not np.all(np.isfinite(g)):
        raise TrajectoryError("non_finite", "goal has a non-finite value")
    s0 = np.array([start.x, start.z, start.pitch, q0[3]])
    # shortest angular interpolation for pitch
    g[2] = s0[2] + math.remainder(g[2] - s0[2], 2 * math.pi)
    d = g - s0
    lin = math.hypot(d[0], d[1])
    ang = max(abs(d[2]), abs(d[3]))
    if lin < 1e-9 and ang < 1e-9:
        return hold(q0, t0)
    dur = max(_QUINTIC_V * lin / linear_speed, _QUINTIC_V * ang / angular_speed, 0.2)
    # fine geometric sampling along the path for IK continuity
    n_fine = max(int(math.ceil(max(lin / 0.002, ang / 0.01))), 20)
    u = np.linspace(0.0, 1.0, n_fine + 1)
    path = np.empty((n_fine + 1, 4))
    q_prev = q0
    path[0] = q0
    for i in range(1, n_fine + 1):
        p = s0 + u[i] * d
        sol = solve_ik(geom, ArmTarget(p[0], p[1], p[2], p[3]), q_ref=q_prev, roll_symmetric=False)
        if not sol.ok:
            raise TrajectoryError(
                f"unreachable_{sol.reason.value if sol.reason else 'unknown'}",
                f"at {u[i] * 100:.0f}% of the line: {sol.detail}",
            )
        q = np.array(sol.q)
        if float(np.max(np.abs(q - q_prev))) > max_step:
            raise TrajectoryError("discontinuous", f"joint jump at {u[i] * 100:.0f}% of the line")
        path[i] = q
        q_prev = q
    # path derivative dq/du by finite differences on the fine path
    dqdu = np.gradient(path, u, axis=0)
    d2qdu2 = np.gradient(dqdu, u, axis=0)
    for _ in range(4):
        n = max(int(math.ceil(dur / dt)), 4)
        tau = np.linspace(0.0, 1.0, n + 1)
        sp, sv, sa = _quintic(tau)
        q = _interp_rows(sp, u, path)
        dqu = _interp_rows(sp, u, dqdu)
        d2qu = _interp_rows(sp, u, d2qdu2)
        dq = dqu * (sv / dur)[:, None]
        ddq = d2qu * ((sv / dur) ** 2)[:, None] + dqu * (sa / dur**2)[:, None]
        k_v = float(np.max(np.abs(dq) / limits.v_max))
        k_a = float(np.sqrt(np.max(np.abs(ddq) / limits.a_max)))
        k = max(k_v, k_a)
        if k <= 1.0:
            break
        dur *= k * 1.02
    q[0] = q0
    q[-1] = path[-1]
    dq[0] = 0.0
    dq[-1] = 0.0
    traj = JointTrajectory(t=t0 + tau * dur, q=q, dq=dq)
    validate(traj, limits)
    return traj


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(x, xp, fp[:, j]) for j in range(fp.shape[1])], axis=1)


def _check_positions(q: np.ndarray, limits: MotionLimits, tol: float = 1e-9) -> None:
    low = q < limits.q_min - tol
    high = q > limits.q_max + tol
    if np.any(low | high):
        i, j = np.argwhere(low | high)[0]
        raise TrajectoryError(
            "joint_limit",
            f"arm_j{j + 1}={q[i, j]:.3f} rad outside [{limits.q_min[j]:.3f}, {limits.q_max[j]:.3f}]",
        )


def validate(traj: JointTrajectory, limits: MotionLimits, slack: float = 1.05) -> None:
    """Rejects a trajectory with non-finite values, bad shapes or limit violations.

    Velocity is checked at the knots; acceleration from knot-to-knot velocity differences.
    ``slack`` tolerates sampling error of the finite differences, not real violations.
    """
    t, q, dq = traj.t, traj.q, traj.dq
    n = len(t)
    if t.ndim != 1 or n < 1 or q.shape != (n, 4) or dq.shape != (n, 4):
        raise TrajectoryError("shape", f"t{t.shape} q{q.shape} dq{dq.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.all(np.isfinite(dq))):
        raise TrajectoryError("non_finite", "trajectory contains NaN or inf")
    if n > 1 and np.any(np.diff(t) <= 0.0):
        raise TrajectoryError("time", "time stamps are not strictly increasing")
    _check_positions(q, limits)
    over_v = np.abs(dq) > limits.v_max * slack
    if np.any(over_v):
        i, j = np.argwhere(over_v)[0]
        raise TrajectoryError(
            "velocity_limit", f"arm_j{j + 1} {dq[i, j]:.3f} rad/s > {limits.v_max[j]:.3f}"
        )
    if n > 1:
        acc = np.diff(dq, axis=0) / np.diff(t)[:, None]
        over_a = np.abs(acc) > limits.a_max * slack
        if np.any(over_a):
            i, j = np.argwhere(over_a)[0]
            raise TrajectoryError(
                "acceleration_limit",
                f"arm_j{j + 1} {acc[i, j]:.3f} rad/s^2 > {limits.a_max[j]:.3f}",
            )
