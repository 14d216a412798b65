"""Grasping an object: Algorithm 6's grasp-ready and grasp phases as a state machine.

Input: a grasp point in the body (``base``) frame, an approach (vertical from above or
horizontal along +x), the gripper yaw and the object's width across the fingers. All
geometry is checked *before* anything moves (:func:`plan_grasp`), so an unreachable goal
is rejected with a reason.

Sequence (Algorithm 6, with the corrections noted):

1. grasp-ready: open the fingers to ``width + open_margin``; ``moveCOM``: shift the body
   sideways by the grasp point's y so that it lies in the arm's vertical plane (the paper
   writes ``moveCOM(-y)`` for the COM measured in the object's frame; in the body frame the
   body moves *towards* the object, by +y); for a vertical grasp crouch (COM z) by the
   smallest amount that makes the grasp reachable; put the tool ``GRASP_READY_Z`` above the
   grasp point pointing down (vertical) or ``GRASP_READY_X`` behind it pointing forward
   (horizontal).
2. grasp: vertical - straight line down to the grasp point; horizontal - straight line
   forward up to ``MANIPULATOR_X_LIM`` and the rest by shifting the body forward (COM x).
   The paper descends a vertical grasp by crouching during the grasp phase; we crouch first
   and descend with the arm, which reaches the same pose with the body still while the
   fingers close (more robust against pushing the object).
3. close with the configured force, verify holding from gap and effort, lift ``lift_height``
   (15 cm) along a vertical line, verify still holding, send the body back to its nominal
   pose (not waited for).

The wrist roll for a vertical grasp is ``-yaw`` (``yaw = 0``: fingers close along the body
y axis; the symmetric ``roll + pi`` is used when the wrist range needs it). Horizontal grasps
approach along the body x axis with the fingers closing horizontally; their yaw is ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.common.robot_description import GRASP_MAX_TILT
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    body_collision,
    fk_tcp,
    solve_ik,
    target_from_base_pose,
)
from quadmanip.services.manipulation.config import ManipulationConfig, PrimitiveConfig
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
from quadmanip.services.manipulation.primitive import (
    BodyPoseRequest,
    Primitive,
    PrimitiveFailed,
    Script,
)

__all__ = ["GraspPlan", "GraspPrimitive", "GraspRejected", "plan_grasp"]


class GraspRejected(ValueError):
    """The goal cannot be executed from the current stance; ``reason`` is a short code."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class GraspPlan:
    """Everything the grasp needs, checked reachable: body offsets and arm targets."""

    approach: str
    body_ready: BodyPoseRequest
    body_grasp: BodyPoseRequest
    ready: ArmTarget
    reach: ArmTarget  # end of the arm's approach line (before any body x shift)
    lift: ArmTarget
    q_ready: tuple[float, float, float, float]
    open_gap: float


def _reachable(
    geom: ArmGeometry, targets: list[ArmTarget], q_ref: np.ndarray, margins: PrimitiveConfig
) -> str:
    """'' if every target is solvable continuing from q_ref (and clear of the trunk
    envelope of ``margins``)."""
    q = q_ref
    for tg in targets:
        sol = solve_ik(geom, tg, q_ref=q, roll_symmetric=False)
        if not sol.ok:
            return f"{sol.reason.value if sol.reason else 'unreachable'}: {sol.detail}"
        q = np.asarray(sol.q)
        if body_collision(geom, q, margins.trunk_front_x, margins.trunk_min_z):
            return f"self_collision: the arm would touch the trunk at x={tg.x:.3f}, z={tg.z:.3f}"
    return ""


def _line(a: ArmTarget, b: ArmTarget, n: int) -> list[ArmTarget]:
    return [
        ArmTarget(
            a.x + (b.x - a.x) * s,
            a.z + (b.z - a.z) * s,
            a.pitch + (b.pitch - a.pitch) * s,
            a.roll + (b.roll - a.roll) * s,
        )
        for s in np.linspace(0.0, 1.0, n)
    ]


def _wrist_roll(geom: ArmGeometry, roll: float, near: float | None = None) -> float:
    """Roll inside the wrist range, using the gripper's half-turn symmetry if needed; with
    ``near``, the one of the two fingers' ways nearest that roll (the shorter turn)."""
    lo, hi = geom.q_min[3], geom.q_max[3]
    cands = (roll, roll + math.pi, roll - math.pi, roll + 2 * math.pi, roll - 2 * math.pi)
    inside = [c for c in cands if lo <= c <= hi]
    if not inside:
        raise GraspRejected("roll_out_of_range", f"roll {roll:.3f} outside [{lo:.3f}, {hi:.3f}]")
    if near is None:
        return inside[0]
    return min(inside, key=lambda c: abs(c - near) - 1e-9 * (c == roll))


def plan_grasp(
    geom: ArmGeometry,
    cfg: ManipulationConfig,
    position_base: np.ndarray,
    approach: str,
    yaw: float,
    width: float,
    body: BodyPoseRequest | None = None,
    tilt: float = 0.0,
) -> GraspPlan:
    """Computes and checks Algorithm 6's poses; raises :class:`GraspRejected` with a reason.

    ``tilt`` (vertical grasps only, rad) leans the tool forward in the arm plane, pitch
    ``pi/2 - tilt``, and the approach runs along the tool axis. It lets the pads lie flat
    on a flared vessel wall (a bowl's wall leans ~37 deg): pinched with vertical pads, the
    wall touches them only at two edges at different heights and the vessel pivots out.
    Not in the paper (Algorithm 6 only knows vertical and horizontal).
    """
    g = cfg.grasp
    body = body or BodyPoseRequest()
    p = np.asarray(position_base, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or not math.isfinite(yaw):
        raise GraspRejected("invalid_goal", "position must be 3 finite numbers, yaw finite")
    if not math.isfinite(width) or width <= 0.0:
        raise GraspRejected("invalid_goal", f"width {width} must be > 0")
    if width + cfg.primitive.width_margin > cfg.gripper.open_gap:
        raise GraspRejected(
            "too_wide",
            f"object width {width:.3f} m >= gripper opening {cfg.gripper.open_gap:.3f} m",
        )
    if approach not in ("vertical", "horizontal"):
        raise GraspRejected("invalid_goal", f"approach {approach!r} (auto is resolved upstream)")
    if not math.isfinite(tilt) or abs(tilt) > GRASP_MAX_TILT or (tilt and approach != "vertical"):
        raise GraspRejected(
            "invalid_goal", f"tilt {tilt} (|tilt| <= {GRASP_MAX_TILT}, vertical grasps only)"
        )
    base_target, lateral = target_from_base_pose(geom, p, 0.0, 0.0)
    y_total = body.y_offset + lateral
    if abs(y_total) > g.max_lateral_shift + 1e-9:
        raise GraspRejected(
            "lateral_out_of_range",
            f"needs a body shift of {y_total:+.3f} m (limit {g.max_lateral_shift:.3f}); "
            "reposition the robot",
        )
    x, z = base_target.x, base_target.z
    open_gap = min(cfg.gripper.open_gap, width + g.open_margin)
    ref = np.asarray(cfg.motion.elbow_ref, dtype=float)
    if approach == "vertical":
        roll = _wrist_roll(geom, -yaw)
        first = ""
        # beyond the arm's reach upright, the tool leans forward (its wrist comes nearer
        # the shoulder by the tool's length x sin(lean)): a spoon's bowl on the living
        # table 2 cm past the reach from the table's edge, which the trunk cannot pass
        # (paper-2, 2026-12-07), given up. The pads still close across the object.
        most = min(tilt + g.max_reach_lean, GRASP_MAX_TILT)
        leans = [tilt, *np.arange(tilt + g.reach_lean_step, most + 1e-9, g.reach_lean_step)]
        for lean in leans:
            plan, last = _vertical(geom, cfg, x, z, float(lean), roll, y_total, body, open_gap)
            first = first or last
            if plan is not None:
                return plan
            if not last.startswith("too_far"):
                break
        raise GraspRejected(
            "unreachable", f"vertical grasp even crouched {g.max_crouch} m: {first}"
        )
    # horizontal
    r = g.lift_height
    wrist_z = z - geom.d1
    reach = geom.d2 + geom.d7 - cfg.primitive.reach_margin
    if abs(wrist_z) >= reach:
        raise GraspRejected("unreachable", f"grasp height {z:.3f} m out of the arm's reach")
    x_lim = min(g.manipulator_x_lim, geom.d5 + math.sqrt(reach**2 - wrist_z**2))
    dx = max(0.0, x - x_lim)
    if body.x_offset + dx > g.max_forward_shift + 1e-9:
        raise GraspRejected(
            "too_far", f"grasp x {x:.3f} m needs a body shift {dx:.3f} m beyond the limit"
        )
    x_reach = x - dx
    ready = ArmTarget(x_reach - g.grasp_ready_x, z, 0.0, 0.0)
    grasp = ArmTarget(x_reach, z, 0.0, 0.0)
    lift = ArmTarget(x_reach, z + r, 0.0, 0.0)
    last = _reachable(geom, [*_line(ready, grasp, 8), *_line(grasp, lift, 8)], ref, cfg.primitive)
    if last:
        raise GraspRejected("unreachable", f"horizontal grasp: {last}")
    sol = solve_ik(geom, ready, q_ref=ref, roll_symmetric=False)
    ready_body = BodyPoseRequest(body.x_offset, y_total, body.z_offset)
    grasp_body = BodyPoseRequest(body.x_offset + dx, y_total, body.z_offset)
    return GraspPlan("horizontal", ready_body, grasp_body, ready, grasp, lift, sol.q, open_gap)  # type: ignore[arg-type]


def _vertical(
    geom: ArmGeometry,
    cfg: ManipulationConfig,
    x: float,
    z: float,
    tilt: float,
    roll: float,
    y_total: float,
    body: BodyPoseRequest,
    open_gap: float,
) -> tuple[GraspPlan | None, str]:
    """A vertical grasp of arm-plane point (x, z) with the tool leaning ``tilt`` forward,
    crouching as little as it needs; (None, why) when no crouch reaches it."""
    g = cfg.grasp
    ref = np.asarray(cfg.motion.elbow_ref, dtype=float)
    pitch = math.pi / 2 - tilt
    # ready: grasp_ready_z back along the tool axis (straight above when not tilted)
    back_x, back_z = -g.grasp_ready_z * math.cos(pitch), g.grasp_ready_z * math.sin(pitch)
    last = ""
    for crouch in np.arange(0.0, g.max_crouch + 1e-9, 0.005):
        zg = z + crouch
        grasp = ArmTarget(x, zg, pitch, roll)
        ready = ArmTarget(x + back_x, zg + back_z, pitch, roll)
        lift = ArmTarget(x, zg + g.lift_height, pitch, roll)
        targets = [*_line(ready, grasp, 8), *_line(grasp, lift, 8)]
        last = _reachable(geom, targets, ref, cfg.primitive)
        if not last:
            sol = solve_ik(geom, ready, q_ref=ref, roll_symmetric=False)
            off = BodyPoseRequest(body.x_offset, y_total, body.z_offset - float(crouch))
            return GraspPlan("vertical", off, off, ready, grasp, lift, sol.q, open_gap), ""  # type: ignore[arg-type]
    return None, last


class GraspPrimitive(Primitive):
    """Runs a :class:`GraspPlan` (Algorithm 6) on the arm, the gripper and the body."""

    name = "grasp"

    def __init__(
        self,
        geom: ArmGeometry,
        cfg: ManipulationConfig,
        plan: GraspPlan,
        monitor: GraspMonitor | None = None,
        body: BodyPoseRequest | None = None,
        restore_body: bool = True,
        force: float | None = None,
    ) -> None:
        super().__init__(geom, cfg, monitor, body)
        self.plan = plan
        self.restore_body = restore_body
        self.force = force  # N squeeze (None: the configured max_force)
        self.t_lifted: float | None = None

    def script(self) -> Script:
        """Algorithm 6: grasp-ready phase, grasp phase, close, verify, lift, verify."""
        plan, g = self.plan, self.cfg.grasp
        self.stage("grasp_ready: open gripper, moveCOM, arm above/behind the grasp point", 0.05)
        yield []

        # the fingers open as the arm goes to its ready pose, and both while the trunk
        # settles into its offsets (0.8-1.2 s a grasp): the pose is planned for the trunk as
        # it will stand, and a trunk not yet down holds the tool higher than planned
        ready = self.together(
            self.open_gripper(plan.open_gap), self.move_joints(np.asarray(plan.q_ready))
        )
        b = plan.body_ready
        yield from self.move_body(b.x_offset, b.y_offset, b.z_offset, during=ready)
        self.stage("grasp: approach", 0.4)
        yield from self.line_to(plan.reach)
        b = plan.body_grasp
        if b != self.body:
            self.stage("grasp: shift the body forward (COM x)", 0.5)
            yield from self.move_body(b.x_offset, b.y_offset, b.z_offset)
        # the object is fixed in the world: follow the trunk's unplanned drift (a crouch
        # that stopped short lifts thin objects out of the pads)
        yield from self.follow_drift(plan.reach, "grasp")
        self.stage("grasp: close", 0.6)
        yield from self.close_gripper(self.force)
        if self.monitor.state is not GripState.HOLDING:
            yield from self.open_gripper()
            raise PrimitiveFailed("grasp_missed: fingers closed on nothing")
        self.stage("grasp: lift", 0.75)
        obs = self._last_obs
        assert obs is not None
        # lift relative to where the fingers actually closed (contact may stop the descent)
        here = fk_tcp(self.geom, obs.q_arm)
        lift = ArmTarget(here.x, here.z + g.lift_height, plan.lift.pitch, float(obs.q_arm[3]))
        if not solve_ik(self.geom, lift, q_ref=obs.q_arm, roll_symmetric=False).ok:
            lift = ArmTarget(plan.lift.x, plan.lift.z, plan.lift.pitch, float(obs.q_arm[3]))
        yield from self.line_to(lift)
        yield from self.wait(g.verify_time)
        self.require_holding("during lift")
        assert self._last_obs is not None
        self.t_lifted = self._last_obs.t
        if self.restore_body:
            # the trunk back to its stance, not waited for: what follows (the carry
            # posture move, a walk) watches the grip itself, and the trunk rises or
            # recentres while the arm swings to carry (1 s a grasp)
            self.stage("restore body pose", 0.9)
            yield from self.move_body(0.0, 0.0, 0.0, settle=False)
