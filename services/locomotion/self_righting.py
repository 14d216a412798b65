"""Self-righting: from lying on a side after a fall to lying on the belly, legs folded.

Plain algorithm, no transport. :func:`lying_side` tells from the IMU how the robot lies;
:class:`SelfRighting` then commands the 12 leg joints (joint-space PD, no feed-forward)
until the robot rests on its belly in the description's ``lying`` pose, from which the
locomotion controller's ``stand`` mode stands up.

Why this sequence. Like the recovery stands of Unitree's and MIT's Cheetah robots it folds
the legs and rolls the trunk with the legs on the floor side, but fitted to this robot: its
abduction range is only +-0.8 rad (a Cheetah pushes itself over with its abduction alone)
and the arm sits on its back. Pushed over, the robot rests rolled 113-136 deg (on its side,
leaning back on the arm), or propped at ~45 deg on its folded floor-side legs; it does not
come to rest on its back (the arm tips it onto a side).

1. ``tuck``: the upper legs fold into the lying pose (the trunk will land on them); the
   floor-side legs fold their knees with their plane of motion tilted off the floor (see
   3).
2. ``lower`` (only when propped on its legs, side roll below ``lean_max_roll``): the
   floor-side legs are what props it, and no leg can lift that side: they fold, slowly, and
   the trunk comes down onto its side; then ``tuck`` again.
3. ``turn`` / ``sweep``: the rear floor-side leg (the lever) swings its hip over to the
   *back* of the trunk (hip 2.6 rad: up and back, behind the arm's elbow). A leg's
   abduction ``a`` tilts its plane of motion about the trunk's long axis; at
   ``a = roll - 90 deg`` that plane is parallel to the floor, so with ``clear_angle`` more
   the leg crosses to the back without touching the floor. (Pressing a foot down near the
   belly-side edge would roll the trunk over the arm instead.) The front floor-side leg
   stays tucked: reaching over the back it would catch the trunk's edge and the gripper.
4. ``push``: the plane tilts ``dig_angle`` into the floor and the knee (the strongest
   joint) stretches: the foot presses the floor behind the trunk, beyond its centre of
   mass, and levers the back up about the belly-side edge. Past ~77 deg of roll the trunk
   tips over that edge by itself and falls onto its belly, onto the folded upper legs. The
   abduction follows the measured roll all along, so the same motion works from lying flat
   on the side and from leaning back on the arm. The arm only ever rises in this roll.
5. ``unlever`` / ``fold``: once the IMU shows the trunk near level (``rolled_tilt``), the
   lever legs bring their abduction back to zero and refold (in that order, so no calf
   sweeps through the trunk), then all legs go to the ``lying`` pose.
6. ``settle``: done when the trunk is level (``done_tilt``), the legs are at the lying
   pose and still.

If the trunk did not roll, or fell back onto a side, the sequence starts again from the
side it lies on, up to ``max_attempts`` times. It fails after too many attempts, on a
``timeout``, or when it ends on its back (``lying_side`` says "back": it needs help).

Conventions: ``gravity_base`` is the unit gravity axis in the base frame as the IMU gives
it: world +z expressed in the base frame, ``R[2, :]`` for the base orientation ``R``
(:func:`gravity_in_base`; the direction an accelerometer at rest measures, pointing away
from the floor). It is (0, 0, 1) when level, (0, -1, 0) when lying on the **left** side
(the base's +y axis, its left, points down), (0, +1, 0) on the **right** side and
(0, 0, -1) upside down on the back. Joint targets stay inside the description's joint
ranges (less ``joint_margin``), and the position error is clipped so that ``kp * error``
never asks a motor for more than its torque limit (both read from the MuJoCo model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.joint_layout import LEG_JOINTS, N_LEG_JOINTS, N_LEGS, leg_slice
from quadmanip.common.rotations import quat_to_mat

SIDES = ("upright", "left", "right", "back")
"""What :func:`lying_side` returns."""


@dataclass(frozen=True)
class RecoveryParams:
    """Tuning of the self-righting sequence ([recovery] table). Angles in rad, times in s."""

    # Side detection from the gravity direction in the base frame.
    upright_tilt: float = 0.35  # tilt from level at or below which it is "upright" (20 deg)
    back_tilt: float = 0.52  # base's -z within this of world up: on its "back" (30 deg)
    # Joint-space PD.
    kp: float = 60.0  # N m/rad
    kd: float = 2.0  # N m s/rad
    kp_push: float = 80.0  # on the lever leg from turn to the end of the push
    kd_push: float = 2.0
    joint_margin: float = 0.05  # rad kept from each joint-range end
    # Lever pose of the ground-side legs (abduction magnitude; its sign follows the side).
    lever_abad: float = 0.75  # largest abduction used
    lever_hip: float = 2.6  # hip angle that points the lever leg up and back
    clear_angle: float = 0.2  # lever leg above the floor line while it swings over
    dig_angle: float = 0.6  # lever leg below the floor line when it pushes
    # Propped on its ground-side legs (rolled less than lean_max_roll): first lowered
    # onto its side by those legs, slowly, so it does not roll on over its back.
    lean_max_roll: float = 1.22  # rad (70 deg)
    tuck_knee: float = -2.6  # knee folded while the legs move
    sweep_knee: float = -2.6  # knee while the lever legs swing over the back
    push_knee: float = -0.7  # knee stretched to push
    # Durations of the moves (smoothstep interpolation).
    t_tuck: float = 0.5
    t_lower: float = 1.0
    t_turn: float = 0.3
    t_sweep: float = 0.4
    t_push: float = 0.6
    t_hold: float = 0.8  # longest wait after the push for the roll
    t_unlever: float = 0.4
    t_fold: float = 0.8
    t_settle: float = 1.5  # longest wait in the lying pose for the trunk to come to rest
    # Transitions.
    rolled_tilt: float = 0.6  # tilt below which the trunk has rolled onto its belly (34 deg)
    relapse_tilt: float = 1.0  # tilt above which a rolled trunk fell back onto a side (57 deg)
    done_tilt: float = 0.26  # tilt below which it lies level enough to stand up (15 deg)
    done_joint_tol: float = 0.2  # rad from the lying pose, every joint
    done_speed: float = 0.5  # rad/s, every joint
    max_attempts: int = 2
    timeout: float = 8.0  # s for the whole sequence

    def __post_init__(self) -> None:
        times = (self.t_tuck, self.t_lower, self.t_turn, self.t_sweep, self.t_push,
                 self.t_hold, self.t_unlever, self.t_fold, self.t_settle, self.timeout)  # fmt: skip
        if min(times) <= 0.0:
            raise ValueError("recovery durations and timeout must be > 0")
        if min(self.kp, self.kd, self.kp_push, self.kd_push) <= 0.0:
            raise ValueError("recovery gains must be > 0")
        if not 0.0 < self.done_tilt < self.upright_tilt < math.pi - self.back_tilt:
            raise ValueError("recovery tilts: need 0 < done_tilt < upright_tilt < pi - back_tilt")
        if not self.done_tilt < self.rolled_tilt < self.relapse_tilt < math.pi / 2:
            raise ValueError("recovery tilts: need done_tilt < rolled_tilt < relapse_tilt < pi/2")
        if not 0.0 < self.lever_abad < math.pi / 2 or self.max_attempts < 1:
            raise ValueError("recovery lever_abad must be in (0, pi/2), max_attempts >= 1")


def gravity_in_base(quat: np.ndarray) -> np.ndarray:
    """``gravity_base`` from the IMU quaternion [w, x, y, z]: world +z in the base frame."""
    return quat_to_mat(np.asarray(quat, dtype=float))[2, :].copy()


def tilt_angle(gravity_base: np.ndarray) -> float:
    """Angle (rad) between the base's +z axis and world up: 0 level, pi upside down."""
    g = np.asarray(gravity_base, dtype=float)
    return math.acos(float(np.clip(g[2] / np.linalg.norm(g), -1.0, 1.0)))


def lying_side(gravity_base: np.ndarray, params: RecoveryParams) -> str:
    """How the robot lies: one of :data:`SIDES`, "upright", "left", "right" or "back".

    ``gravity_base``: world +z in the base frame, ``R[2, :]`` (module doc). "upright" (on
    its feet or belly) when the tilt is at most ``upright_tilt``; "back" when the base's -z
    is within ``back_tilt`` of world up (its back faces the floor); otherwise "left" when
    the base's +y (left) side is the lower one, "right" when -y is (a robot pitched onto its
    nose or tail is sorted by which side leans lower).
    """
    g = np.asarray(gravity_base, dtype=float)
    n = float(np.linalg.norm(g))
    if not np.all(np.isfinite(g)) or n < 1e-9:
        raise ValueError(f"gravity direction must be a finite nonzero vector, not {g.tolist()}")
    g = g / n
    if g[2] >= math.cos(params.upright_tilt):
        return "upright"
    if -g[2] >= math.cos(params.back_tilt):
        return "back"
    return "left" if g[1] <= 0.0 else "right"


def _smoothstep(s: float) -> tuple[float, float]:
    """Blend a(s) = 3s^2 - 2s^3 on [0, 1] and its derivative da/ds."""
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s)


def side_roll(gravity_base: np.ndarray, side: str) -> float:
    """How far (rad) the trunk is rolled from level towards ``side``: 0 level, pi/2 lying
    flat on that side, pi on its back (negative: rolled towards the other side)."""
    g = np.asarray(gravity_base, dtype=float)
    lateral = -g[1] if side == "left" else g[1]
    return math.atan2(float(lateral), float(g[2]))


class SelfRighting:
    """Joint-space self-righting sequence from a side onto the belly (see module doc).

    ``command(t, q12, dq12, gravity_base)`` is called every control tick with the time
    since the sequence started and returns (q_des, dq_des, kp, kd) for the 12 leg joints.
    """

    def __init__(
        self,
        params: RecoveryParams,
        side: str,
        q_start: np.ndarray,
        q_lying: np.ndarray,
        info: rd.RobotInfo | None = None,
    ) -> None:
        if side not in ("left", "right"):
            raise ValueError(f"self-righting starts from a side ('left' or 'right'), not {side!r}")
        q_start = np.asarray(q_start, dtype=float).reshape(-1)
        q_lying = np.asarray(q_lying, dtype=float).reshape(-1)
        if q_start.shape != (N_LEG_JOINTS,) or q_lying.shape != (N_LEG_JOINTS,):
            raise ValueError(f"q_start and q_lying must hold {N_LEG_JOINTS} leg joint angles")
        if not (np.all(np.isfinite(q_start)) and np.all(np.isfinite(q_lying))):
            raise ValueError("q_start and q_lying must be finite")
        self.params = params
        info = info if info is not None else rd.robot_info()
        lo = np.array([info.joint_ranges[j][0] for j in LEG_JOINTS]) + params.joint_margin
        hi = np.array([info.joint_ranges[j][1] for j in LEG_JOINTS]) - params.joint_margin
        self._lo, self._hi = lo, hi
        self._tau_max = np.asarray(info.torque_limits[:N_LEG_JOINTS], dtype=float)
        self.q_lying = np.clip(q_lying, lo, hi)
        self._set_side(side)
        self.phase = "tuck"
        self.attempts = 1
        self.reason = ""
        self.roll = math.nan  # last side roll (rad), for logs
        self._lowered = False  # lowered from propped on its legs onto its side already
        self._t0 = 0.0  # start time of the current phase
        self._from = np.clip(q_start, lo, hi)  # where the current move starts
        self._last = self._from.copy()  # the last commanded target (start of the next move)

    # ------------------------------------------------------------------ state
    @property
    def done(self) -> bool:
        """On its belly, legs folded in the lying pose and still: ready to stand up."""
        return self.phase == "done"

    @property
    def failed(self) -> bool:
        """Gave up (see :attr:`reason`): timeout, no roll after every attempt, on its back."""
        return self.phase == "failed"

    def _set_side(self, side: str) -> None:
        self.side = side
        # Legs on the ground side: the left legs (FL, RL) when lying on the left side; the
        # rear one is the lever (the front one, reaching over the back, would catch the
        # trunk's edge and the gripper that lies there).
        first = 0 if side == "left" else 1
        self.ground_legs = (first, first + 2)
        self.lever_leg = first + 2
        self.top_legs = tuple(i for i in range(N_LEGS) if i not in self.ground_legs)
        self._lever_mask = np.zeros(N_LEG_JOINTS, dtype=bool)
        self._lever_mask[leg_slice(self.lever_leg)] = True
        # The abduction angles below are written for the left legs lying on the left side;
        # the right legs on the right side mirror them (abduction axes are both +x).
        self._abad_sign = 1.0 if side == "left" else -1.0

    def _go(self, phase: str, t: float) -> None:
        self._from = self._last.copy()
        self.phase = phase
        self._t0 = t

    def _fail(self, reason: str) -> None:
        self.phase = "failed"
        self.reason = reason

    # ------------------------------------------------------------------ targets
    def _target(self, psi: float) -> np.ndarray:
        """Joint targets of the current phase, for a trunk rolled ``psi`` towards the side.

        A ground-side leg's abduction ``a`` tilts its plane of motion (the hip and knee
        plane) by ``a`` about the trunk's long axis; at ``a = psi - pi/2`` that plane is
        parallel to the floor, whether the trunk lies flat (psi = pi/2) or leans back on
        the arm (psi ~ 2.3). Around that angle the lever leg tilts its plane up
        (``clear_angle``) while it swings from the belly side to the back, so it touches
        nothing, then down (``dig_angle``) to plant its foot on the floor behind the
        trunk and push it over. Angles are for the left legs on the left side; the right
        legs mirror them.
        """
        p = self.params
        q = self.q_lying.copy()
        if self.phase in ("unlever", "fold", "settle", "done", "failed"):
            if self.phase == "unlever":  # keep the hip where it was
                for i in self.ground_legs:
                    s = leg_slice(i)
                    q[s] = (0.0, self._from[s][1], p.tuck_knee)
            return q
        level = psi - math.pi / 2.0
        for i in self.ground_legs:
            s = leg_slice(i)
            if self.phase == "tuck" or (i != self.lever_leg and self.phase != "lower"):
                # Folded, pointing to the belly, its plane tilted off the floor.
                q[s] = (level - p.clear_angle, q[s][1], p.tuck_knee)
            elif self.phase == "lower":  # the lying pose's leg, folded: the trunk comes down
                q[s] = (0.0, q[s][1], p.tuck_knee)
            elif self.phase == "turn":  # pointing backwards: plane tilted up on the back side
                q[s] = (level + p.clear_angle, 0.5 * math.pi, p.tuck_knee)
            elif self.phase == "sweep":
                q[s] = (level + p.clear_angle, p.lever_hip, p.sweep_knee)
            else:  # push, hold: plane tilted into the floor, knee stretched
                q[s] = (level - p.dig_angle, p.lever_hip, p.push_knee)
            q[s.start] = self._abad_sign * min(max(q[s.start], -p.lever_abad), p.lever_abad)
        return q

    # ------------------------------------------------------------------ control
    def command(
        self, t: float, q12: np.ndarray, dq12: np.ndarray, gravity_base: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Leg command (q_des, dq_des, kp, kd) at ``t`` s after the start (see class doc)."""
        p = self.params
        t = float(t)
        q12 = np.asarray(q12, dtype=float)
        dq12 = np.asarray(dq12, dtype=float)
        g = np.asarray(gravity_base, dtype=float)
        self._advance(t, q12, dq12, g)
        kd = np.full(N_LEG_JOINTS, p.kd)
        if self.phase == "failed":
            # Give up limp: damping only, as the controller's damp mode.
            q_hold = np.clip(q12, self._lo, self._hi)  # no stiffness: only kept in range
            return q_hold, np.zeros(N_LEG_JOINTS), np.zeros(N_LEG_JOINTS), kd
        self.roll = side_roll(g, self.side)
        target = self._target(self.roll)
        dur = {
            "tuck": p.t_tuck,
            "lower": p.t_lower,
            "turn": p.t_turn,
            "sweep": p.t_sweep,
            "push": p.t_push,
            "unlever": p.t_unlever,
            "fold": p.t_fold,
        }.get(self.phase, 0.0)
        if dur > 0.0:
            a, da = _smoothstep((t - self._t0) / dur)
            q_des = self._from + (target - self._from) * a
            dq_des = (target - self._from) * (da / dur)
        else:
            q_des, dq_des = target, np.zeros(N_LEG_JOINTS)
        self._last = q_des.copy()
        kp = np.full(N_LEG_JOINTS, p.kp)
        if self.phase in ("turn", "sweep", "push", "hold"):
            kp[self._lever_mask] = p.kp_push
            kd[self._lever_mask] = p.kd_push
        # Stay inside the joint ranges, and ask no motor for more than its torque limit.
        q_des = np.clip(q_des, self._lo, self._hi)
        reach = self._tau_max / kp
        q_des = np.clip(q_des, q12 - reach, q12 + reach)
        return q_des, dq_des, kp, kd

    def _advance(self, t: float, q12: np.ndarray, dq12: np.ndarray, g: np.ndarray) -> None:
        """Phase transitions from time and the measured state."""
        p = self.params
        if self.phase in ("done", "failed"):
            return
        if t > p.timeout:
            self._fail(f"timeout after {p.timeout:.1f} s in phase {self.phase}")
            return
        side = lying_side(g, p)
        tilt = tilt_angle(g)
        elapsed = t - self._t0
        if self.phase in ("tuck", "lower", "turn", "sweep", "push", "hold"):
            if tilt < p.rolled_tilt:
                self._go("unlever", t)
            elif self.phase == "tuck" and elapsed >= p.t_tuck:
                # Propped on its legs: lower it onto its side first (once), then lever.
                if side_roll(g, self.side) < p.lean_max_roll and not self._lowered:
                    self._lowered = True
                    self._go("lower", t)
                else:
                    self._go("turn", t)
            elif self.phase == "lower" and elapsed >= p.t_lower:
                self._go("tuck", t)
            elif self.phase == "turn" and elapsed >= p.t_turn:
                self._go("sweep", t)
            elif self.phase == "sweep" and elapsed >= p.t_sweep:
                self._go("push", t)
            elif self.phase == "push" and elapsed >= p.t_push:
                self._go("hold", t)
            elif self.phase == "hold" and elapsed >= p.t_hold:
                self._retry(t, side)
            return
        # Rolled: unlever, fold, settle; watch that it stays on its belly.
        if side == "back" or tilt > p.relapse_tilt:
            self._retry(t, side)
        elif self.phase == "unlever" and elapsed >= p.t_unlever:
            self._go("fold", t)
        elif self.phase == "fold" and elapsed >= p.t_fold:
            self._go("settle", t)
        elif self.phase == "settle":
            still = bool(np.all(np.abs(dq12) < p.done_speed))
            folded = bool(np.all(np.abs(q12 - self.q_lying) < p.done_joint_tol))
            if tilt < p.done_tilt and still and folded:
                self.phase = "done"
            elif elapsed >= p.t_settle:
                self._fail(
                    f"not at rest in the lying pose after {p.t_settle:.1f} s "
                    f"(tilt {math.degrees(tilt):.0f} deg)"
                )

    def _retry(self, t: float, side: str) -> None:
        """Start over from the side it lies on now, or give up."""
        if side == "back":
            self._fail("ended on its back")
        elif side == "upright":
            self._go("unlever", t)
        elif self.attempts >= self.params.max_attempts:
            self._fail(f"still on its {side} side after {self.attempts} attempts")
        else:
            self.attempts += 1
            self._set_side(side)
            self._go("tuck", t)
