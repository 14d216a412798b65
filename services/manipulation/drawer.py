"""Opening a drawer: grip the handle bar and pull it straight back (paper Section 7.2).

The handle is a horizontal bar in front of the drawer. The tool approaches horizontally
(pitch 0) with the wrist rolled a quarter turn so the fingers close vertically around the
bar, from ``drawer_standoff`` in front of it; it closes, verifies the bar is held (gap and
effort), and pulls along the drawer's axis, which must point back towards the robot in the
arm plane (the body turns to face the cabinet first - navigation's job). The pull goes as
far as the arm reaches; the rest (if any) is done by moving the body backwards (COM x), as
Algorithm 6 does for reaching forward. Then it releases and backs off.
"""

from __future__ import annotations

import math

import numpy as np
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    fk_tcp,
    solve_ik,
    target_from_base_pose,
)
from quadmanip.services.manipulation.config import DrawerConfig, ManipulationConfig
from quadmanip.services.manipulation.grasp import GraspRejected, _line, _reachable
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
from quadmanip.services.manipulation.primitive import (
    BodyPoseRequest,
    Primitive,
    PrimitiveFailed,
    Script,
)

__all__ = ["DrawerPlan", "DrawerPrimitive", "plan_drawer"]


def _min_pull_x(dc: DrawerConfig, z: float) -> float:
    """Closest tool-centre x of a pull at height ``z`` (arm_base frame)."""
    return dc.min_pull_x_low if z < dc.low_z else dc.min_pull_x_high


class DrawerPlan:
    """Checked poses of a drawer opening."""

    def __init__(
        self,
        body: BodyPoseRequest,
        ready: ArmTarget,
        grip: ArmTarget,
        pulled: ArmTarget,
        body_pull: float,
        q_ready: tuple[float, ...],
    ) -> None:
        self.body = body
        self.ready = ready
        self.grip = grip
        self.pulled = pulled
        self.body_pull = body_pull
        self.q_ready = q_ready


def plan_drawer(
    geom: ArmGeometry,
    cfg: ManipulationConfig,
    handle_base: np.ndarray,
    pull_direction: np.ndarray,
    distance: float,
    body: BodyPoseRequest | None = None,
) -> DrawerPlan:
    """Computes and checks the drawer poses; raises :class:`GraspRejected` with a reason."""
    g, dc = cfg.grasp, cfg.drawer
    body = body or BodyPoseRequest()
    p = np.asarray(handle_base, dtype=float)
    d = np.asarray(pull_direction, dtype=float)
    if (
        p.shape != (3,)
        or d.shape != (3,)
        or not (np.all(np.isfinite(p)) and np.all(np.isfinite(d)))
    ):
        raise GraspRejected("invalid_goal", "handle position and pull direction must be finite")
    if not math.isfinite(distance) or distance <= 0.0 or distance > dc.max_pull:
        raise GraspRejected(
            "invalid_goal", f"pull distance {distance} outside (0, {dc.max_pull:g}] m"
        )
    n = float(np.linalg.norm(d))
    if n < 1e-6:
        raise GraspRejected("invalid_goal", "pull direction is zero")
    d = d / n
    if d[0] > -0.95:
        raise GraspRejected(
            "pull_direction_unsupported",
            "the pull must point back towards the robot along its x axis (within 18 deg); "
            "turn the body to face the drawer",
        )
    target, lateral = target_from_base_pose(geom, p, 0.0, 0.0)
    y_total = body.y_offset + lateral
    if abs(y_total) > g.max_lateral_shift + 1e-9:
        raise GraspRejected(
            "lateral_out_of_range",
            f"needs a body shift of {y_total:+.3f} m (limit {g.max_lateral_shift:.3f}); "
            "reposition the robot",
        )
    pull = max(distance, g.drawer_pull)
    roll = math.pi / 2
    ref = np.asarray(cfg.motion.elbow_ref, dtype=float)
    best: tuple[float, float, float] | None = None  # (arm pull, crouch, pitch)
    why = "no candidate"
    need_arm = pull - (g.max_forward_shift + body.x_offset)
    # a level tool first; crouching (COM z) and pitching the tool down widen the low
    # drawers' pull range
    for pitch in (0.0, 0.3, 0.6):
        for crouch in (0.0, 0.05, g.max_crouch):
            z = target.z + crouch
            grip = ArmTarget(target.x - dc.grip_behind, z, pitch, roll)
            ready = ArmTarget(target.x - g.drawer_standoff, z, pitch, roll)
            fail = _reachable(geom, _line(ready, grip, 6), ref, cfg.primitive)
            if fail:
                why = fail
                continue
            arm_pull = 0.0
            max_arm = min(pull, grip.x - _min_pull_x(dc, z))
            for cand in np.arange(max_arm, -1e-9, -0.01):
                end = ArmTarget(grip.x - cand, z, pitch, roll)
                line = _line(grip, end, max(3, int(cand / 0.01)))
                if not _reachable(geom, line, ref, cfg.primitive):
                    arm_pull = float(cand)
                    break
            if best is None or arm_pull > best[0] + 1e-9:
                best = (arm_pull, crouch, pitch)
            if arm_pull >= need_arm - 1e-9:
                break
        if best is not None and best[0] >= need_arm - 1e-9:
            break
    if best is None:
        raise GraspRejected("unreachable", f"drawer handle: {why}")
    arm_pull, crouch, pitch = best
    body_pull = pull - arm_pull
    if body.x_offset - body_pull < -g.max_forward_shift - 1e-9:
        raise GraspRejected(
            "unreachable", f"pull of {pull:.2f} m: arm reaches {arm_pull:.2f} m only"
        )
    z = target.z + crouch
    grip = ArmTarget(target.x - dc.grip_behind, z, pitch, roll)
    ready = ArmTarget(target.x - g.drawer_standoff, z, pitch, roll)
    sol = solve_ik(geom, ready, q_ref=ref, roll_symmetric=False)
    pulled = ArmTarget(grip.x - arm_pull, z, pitch, roll)
    return DrawerPlan(
        BodyPoseRequest(body.x_offset, y_total, body.z_offset - crouch),
        ready,
        grip,
        pulled,
        body_pull,
        sol.q,  # type: ignore[arg-type]
    )


class DrawerPrimitive(Primitive):
    """Runs a :class:`DrawerPlan`: approach, grip the handle, pull, release, back off."""

    name = "open_drawer"

    def __init__(
        self,
        geom: ArmGeometry,
        cfg: ManipulationConfig,
        plan: DrawerPlan,
        monitor: GraspMonitor | None = None,
        body: BodyPoseRequest | None = None,
    ) -> None:
        super().__init__(geom, cfg, monitor, body)
        self.plan = plan

    def script(self) -> Script:
        """Approach, grip, pull (arm, then body), release, back off."""
        plan, dc = self.plan, self.cfg.drawer
        self.stage("drawer: moveCOM, open gripper, in front of the handle", 0.05)
        yield []
        # as the grasp does: the fingers open as the arm goes in front of the handle, both
        # while the trunk settles into its offsets (one after another: 1.5-2 s a drawer)
        ready = self.together(
            self.open_gripper(dc.handle_width + self.cfg.grasp.open_margin),
            self.move_joints(np.asarray(plan.q_ready)),
        )
        b = plan.body
        yield from self.move_body(b.x_offset, b.y_offset, b.z_offset, during=ready)
        self.stage("drawer: reach the handle", 0.35)
        yield from self.line_to(plan.grip)
        # the handle is fixed in the world: follow the trunk's unplanned drift (odometry)
        yield from self.follow_drift(plan.grip, "drawer")
        self.stage("drawer: grip", 0.45)
        yield from self.close_gripper()
        if self.monitor.state is not GripState.HOLDING:
            yield from self.open_gripper()
            raise PrimitiveFailed("handle_missed: fingers closed on nothing")
        self.stage("drawer: pull", 0.6)
        yield from self.line_to(plan.pulled, speed=dc.pull_speed)
        if plan.body_pull > 0.0:
            yield from self.move_body(b.x_offset - plan.body_pull, b.y_offset, b.z_offset)
        if self.monitor.state is not GripState.HOLDING:
            raise PrimitiveFailed(f"handle_lost during the pull ({self.monitor.state.value})")
        self.stage("drawer: release", 0.85)
        # release just wide enough to clear the bar: fully open (0.12 m) fingers reach the
        # drawer front / cabinet frame and push the drawer shut by ~4 cm when backing off
        yield from self.open_gripper(dc.handle_width + 2 * self.cfg.grasp.open_margin)
        # back off along the pull, then rise above the handle before the body returns
        # forward (open fingers would otherwise push the drawer shut again)
        # (the wrist may have to pitch to back off near its range limit)
        for dx, dz in ((-dc.retreat, 0.0), (0.0, dc.retreat_rise)):
            obs = self._last_obs
            assert obs is not None
            here = fk_tcp(self.geom, obs.q_arm)
            for dp in (0.0, 0.3, -0.3, 0.6):
                nxt = ArmTarget(here.x + dx, here.z + dz, here.pitch + dp, float(obs.q_arm[3]))
                if solve_ik(self.geom, nxt, q_ref=obs.q_arm, roll_symmetric=False).ok:
                    yield from self.line_to(nxt)
                    break
        yield from self.move_body(0.0, 0.0, 0.0, settle=False)  # (as the place's end)
