"""Goal arbitration and policy of the manipulation service, free of any transport.

The manipulation node only converts messages and wires its four action servers
(``move_to_posture``, ``grasp``, ``place``, ``open_drawer``) to one :class:`Executive`,
which decides everything else:

* **One goal at a time, across the four actions.** :meth:`Executive.accept` checks the slot,
  plans the goal and reserves the slot under one lock, so of two goals accepted at the same
  moment exactly one is accepted and the other rejected with ``busy: ...``. An accepted
  goal is started by :meth:`Executive.start` (or :meth:`Executive.execute`, which also
  waits for it); a reservation that nobody starts within ``claim_timeout`` (the action
  server refused the goal after the accept, e.g. while shutting down) frees the slot again.
  The slot is freed the moment the primitive ends (succeeded, failed or canceled).
* **Plan once.** The plan made at accept is the one that runs; a goal that cannot be planned
  is rejected with the planner's reason before anything moves.
* **No side effect on accept.** A rejected goal changes nothing; even an accepted grasp
  tells locomotion about its object only once the grasp starts.
* **Policy.** ``approach = "auto"`` grasps vertically when the vertical grasp is reachable,
  else horizontally. The held object's hang below the tool centre (needed to place it from
  above) is the grasp goal's ``hang`` (perception's model of the object); when that is 0 it
  is measured as the grasp point's height above the floor for a vertical grasp below
  ``floor_grasp_max_z`` (the floor height comes from the description's standing pose), else
  taken as ``default_hang``.
* **Stepping.** :meth:`Executive.step` feeds each observation to the running primitive and
  returns what to send: arm trajectories with their gravity feed-forward torques
  (:class:`ArmServo`, see ``gravity.py``), gripper commands, body-pose requests and payload
  updates for locomotion's balance model (on every grip verdict change, and every
  ``payload_period`` while holding). A service that starts with an object squeezed in
  its fingers (it was restarted while carrying) infers the grip from the gripper's
  readings (:class:`.gripper.GraspMonitor`) and announces the configured default mass,
  with no object name, so a place is accepted; the hang below the tool is then
  ``default_hang`` (the grasp goal that knew it went with the old process).

Goals arrive here as the small request dataclasses below, not as bus messages.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from quadmanip.common import robot_description as rd
from quadmanip.common.reasons import reach_band_text
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    fk_tcp,
    held_offset,
)
from quadmanip.services.manipulation.config import ManipulationConfig
from quadmanip.services.manipulation.drawer import DrawerPrimitive, plan_drawer
from quadmanip.services.manipulation.grasp import (
    GraspPlan,
    GraspPrimitive,
    GraspRejected,
    plan_grasp,
)
from quadmanip.services.manipulation.gravity import GravityCompensator
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState, grasp_force
from quadmanip.services.manipulation.place import PlacePrimitive, place_hang, plan_place
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.services.manipulation.primitive import (
    ArmCommand,
    BodyPoseRequest,
    Command,
    GripperCmd,
    Observation,
    PostureMove,
    Primitive,
    Status,
)
from quadmanip.services.manipulation.trajectory import TrajectoryError

__all__ = [
    "ArmServo",
    "DrawerRequest",
    "Executive",
    "GraspRequest",
    "Outcome",
    "Output",
    "PayloadUpdate",
    "PlaceRequest",
    "PostureRequest",
    "Request",
    "Verdict",
]

CANCELED_REASON = "canceled: arm holds its measured position"


# --------------------------------------------------------------------------- goals
@dataclass(frozen=True)
class PostureRequest:
    """Move the arm to a named posture of the manipulation config."""

    posture: str


@dataclass(frozen=True)
class GraspRequest:
    """Grasp at ``position`` (base frame, m) about ``yaw`` (rad); see ``GraspGoal``."""

    position: tuple[float, float, float]
    yaw: float = 0.0
    approach: str = "auto"  # vertical, horizontal or auto
    width: float = 0.05
    object_name: str = ""
    tilt: float = 0.0
    mass: float = 0.0  # kg; 0 = unknown (the configured default is announced)
    hang: float = 0.0  # m below the grasp point; 0 = unknown (measured or default)
    # the object's middle (base frame); None = unknown: a place puts the grasp point there
    center: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class PlaceRequest:
    """Place the held object at ``position`` (base frame); ``yaw`` turns the gripper first
    (None keeps the grasp's roll)."""

    position: tuple[float, float, float]
    yaw: float | None = None


@dataclass(frozen=True)
class DrawerRequest:
    """Open the drawer whose handle is at ``handle_position`` (base frame) by pulling it
    ``distance`` m along the unit vector ``pull_direction``."""

    handle_position: tuple[float, float, float]
    pull_direction: tuple[float, float, float]
    distance: float = 0.15


Request = PostureRequest | GraspRequest | PlaceRequest | DrawerRequest


# --------------------------------------------------------------------------- outputs
@dataclass(frozen=True)
class ArmServo:
    """An arm trajectory for the actuator layer: knots ``t`` (N), ``q``/``dq``/``tau_ff``
    (N, 4) with the gravity feed-forward torque per knot, and the servo gains."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau_ff: np.ndarray
    kp: tuple[float, ...]
    kd: tuple[float, ...]


@dataclass(frozen=True)
class PayloadUpdate:
    """What the gripper holds, for locomotion's balance model (``mass`` 0: nothing).

    ``grip`` is the new grip verdict when this update reports a change of it (with the
    finger ``gap`` and ``effort`` that decided it); None for a periodic repeat.
    """

    mass: float
    object_name: str = ""
    grip: GripState | None = None
    gap: float = 0.0
    effort: float = 0.0


Output = ArmServo | GripperCmd | BodyPoseRequest | PayloadUpdate


@dataclass(frozen=True)
class Verdict:
    """Answer to a goal: accepted, or rejected with a reason."""

    accepted: bool
    reason: str = ""


@dataclass(frozen=True)
class Outcome:
    """How an executed goal ended: ``status`` succeeded, failed or canceled, and why."""

    status: Status
    reason: str = ""
    # what the goal was planned as, for the log (a place: the release pose and the held
    # object's middle; empty for the other goals)
    plan: str = ""


# --------------------------------------------------------------------------- runs
@dataclass(eq=False)
class _Run:
    """The goal holding the slot: reserved at accept, running once started."""

    token: object | None
    request: Request
    primitive: Primitive
    accepted_at: float
    started: bool = False
    cancel: bool = False  # cancel requested: the next step stops the arm
    finished: threading.Event = field(default_factory=threading.Event)


class Executive:
    """Arbitrates manipulation goals (one at a time) and runs them; see the module doc.

    Thread-safe: :meth:`accept` (action servers' threads), :meth:`execute` (one thread per
    goal) and :meth:`step` (the control loop) share one lock.
    """

    def __init__(
        self,
        geom: ArmGeometry,
        cfg: ManipulationConfig,
        postures: dict[str, np.ndarray] | None = None,
        gravity: GravityCompensator | None = None,
        floor_z: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.geom = geom
        self.cfg = cfg
        self.postures = resolve_postures(geom, cfg) if postures is None else postures
        self.gravity = GravityCompensator() if gravity is None else gravity
        # floor height in the body frame, standing (the description's home keyframe)
        self.floor_z = -float(rd.home_qpos()[2]) if floor_z is None else float(floor_z)
        self.clock = clock
        self.monitor = GraspMonitor(cfg.gripper)
        self.body = BodyPoseRequest()  # body offsets last requested from locomotion
        self.hang = cfg.executive.default_hang  # of the object held (m below the tool)
        # the held object's middle in the tool frame (None: not known; the grasp point is
        # placed): from the grasp goal's ``center`` (perception's model of the object)
        self.held: np.ndarray | None = None
        self.grasp_approach = ""  # how it was grasped (vertical, horizontal; "": not known)
        self._lock = threading.Lock()
        self._run: _Run | None = None
        self._grip_state = self.monitor.state
        self._grasp_payload = PayloadUpdate(0.0)  # the running/last grasp's object
        self._payload = PayloadUpdate(0.0)  # what locomotion was last told
        self._payload_t = 0.0

    @classmethod
    def from_description(cls, cfg: ManipulationConfig) -> Executive:
        """An executive for the robot description's arm."""
        return cls(ArmGeometry.from_description(), cfg)

    # ------------------------------------------------------------------ queries
    @property
    def busy(self) -> bool:
        """True while a goal holds the slot (accepted and not yet ended)."""
        with self._lock:
            return self._run is not None

    @property
    def running(self) -> bool:
        """True while a started goal runs (accepted and started, not yet ended)."""
        run = self._run
        return run is not None and run.started

    @property
    def active(self) -> Primitive | None:
        """The primitive of the goal holding the slot, if any."""
        run = self._run
        return run.primitive if run is not None else None

    @property
    def payload(self) -> PayloadUpdate:
        """What locomotion was last told the gripper holds."""
        return self._payload

    # ------------------------------------------------------------------ goals
    def accept(
        self, request: Request, obs: Observation | None, token: object | None = None
    ) -> Verdict:
        """Accepts ``request`` (and reserves the slot for it, planned) or rejects it with a
        reason. ``token`` identifies the goal to :meth:`start` (the node passes the goal
        message); nothing else changes, whatever the verdict."""
        if obs is None:
            return Verdict(False, "no_joint_state: no LowState received yet")
        with self._lock:
            run = self._run
            if run is not None:
                stale = self.clock() - run.accepted_at > self.cfg.executive.claim_timeout
                if run.started or not stale:
                    state = "running" if run.started else "starting"
                    return Verdict(False, f"busy: {run.primitive.name} {state}")
                self._run = None  # accepted but never started: the slot is free again
            try:
                prim = self._plan(request, obs)
            except (GraspRejected, TrajectoryError) as exc:
                return Verdict(False, str(exc))
            self._run = _Run(token, request, prim, self.clock())
        return Verdict(True)

    def start(self, token: object | None = None) -> Primitive | None:
        """Starts the accepted goal ``token``; its primitive, or None when the slot holds
        no such goal (never accepted, or its reservation lapsed)."""
        run = self._start(token)
        return run.primitive if run is not None else None

    def _start(self, token: object | None) -> _Run | None:
        with self._lock:
            run = self._run
            if run is None or run.started or run.token is not token:
                return None
            run.started = True
            if isinstance(run.request, GraspRequest):
                req = run.request
                mass = req.mass if req.mass > 0.0 else self.cfg.gripper.default_payload_mass
                self._grasp_payload = PayloadUpdate(mass, req.object_name)
            elif isinstance(run.request, DrawerRequest):
                # the fingers will close on the handle: nothing to carry
                self._grasp_payload = PayloadUpdate(0.0)
            return run

    def cancel(self, token: object | None = None) -> bool:
        """Asks the running goal ``token`` to stop: the next :meth:`step` holds the arm at
        its measured joints. False when that goal is not running."""
        with self._lock:
            run = self._run
            if run is None or not run.started or run.token is not token:
                return False
            run.cancel = True
            return True

    def execute(
        self,
        token: object | None = None,
        *,
        cancel_requested: Callable[[], bool] = lambda: False,
        feedback: Callable[[float, str], object] | None = None,
        poll: float = 0.01,
    ) -> Outcome:
        """Starts the accepted goal ``token`` and waits until it ends (blocking: call it from
        the goal's own thread while :meth:`step` runs). ``cancel_requested`` is polled;
        ``feedback(progress, text)`` is called whenever the primitive's stage changes."""
        run = self._start(token)
        if run is None:
            return Outcome(Status.FAILED, "not_accepted: the goal holds no slot (lapsed?)")
        prim = run.primitive
        last = ""
        while not run.finished.wait(poll):
            if cancel_requested():
                self.cancel(token)
                if not run.finished.wait(self.cfg.executive.cancel_wait):
                    self._release(run)  # nothing steps the arm (stopping): give up the slot
                    return Outcome(Status.CANCELED, "canceled: no joint state to stop on")
                return Outcome(Status.CANCELED, CANCELED_REASON)
            text = prim.progress.text
            if text != last and feedback is not None:
                last = text
                feedback(float(prim.progress.value), text)
        if prim.status is Status.SUCCEEDED:
            return Outcome(Status.SUCCEEDED, plan=prim.note)
        if prim.status is Status.CANCELED:
            why = CANCELED_REASON if run.cancel else prim.reason
            return Outcome(Status.CANCELED, why, plan=prim.note)
        return Outcome(Status.FAILED, prim.reason or "failed", plan=prim.note)

    # ------------------------------------------------------------------ control
    def step(self, obs: Observation) -> list[Output]:
        """Feeds ``obs`` (newest joint state) to the running goal; returns what to send."""
        with self._lock:
            run = self._run
            if run is None or not run.started:
                # keep watching the grip while carrying between actions (holding -> lost)
                self.monitor.update(obs.t, obs.gripper_gap, obs.gripper_effort)
                return self._watch_payload(obs)
            prim = run.primitive
            cmds = prim.cancel(obs) if run.cancel else prim.step(obs)
            # the grip verdict after this step, so that the step ending a goal carries
            # what the goal left: the task reads the grip the moment the result arrives
            out: list[Output] = self._watch_payload(obs)
            if prim.done:
                self._finish(run)
                out += self._trunk_back(prim)
        return out + self._outputs(cmds)

    def _trunk_back(self, prim: Primitive) -> list[Output]:
        """A primitive that failed (or was canceled) with the trunk shifted, crouched or
        raised for it asks locomotion for the nominal pose again (its pitch kept: that
        is the postures'). Left there, the offset stood under every later stance: the
        trunk came to rest 4.6 cm beside where the approach had brought it, and each
        approach after a place that lost the spoon during its trunk shift ended "did not
        settle" (paper-2, 2026-12-06: 15 approaches, the bowl given up)."""
        b = self.body
        if prim.status is Status.SUCCEEDED or (b.x_offset, b.y_offset, b.z_offset) == (0, 0, 0):
            return []
        self.body = BodyPoseRequest(0.0, 0.0, 0.0, b.pitch)
        return [self.body]

    def stop(self, obs: Observation | None) -> list[Output]:
        """The service stops: a running goal is canceled and the arm held where it is."""
        with self._lock:
            run = self._run
            if run is None:
                return []
            cmds: list[Command] = []
            if run.started and obs is not None and not run.primitive.done:
                run.cancel = True
                cmds = run.primitive.cancel(obs)
            self._finish(run)
        return self._outputs(cmds)

    # ------------------------------------------------------------------ internals
    def _plan(self, request: Request, obs: Observation) -> Primitive:
        """Plans ``request`` into a primitive; raises GraspRejected/TrajectoryError."""
        cfg = self.cfg
        kw = {"monitor": self.monitor, "body": self.body}
        if isinstance(request, PostureRequest):
            if request.posture not in self.postures:
                known = ", ".join(sorted(self.postures))
                raise GraspRejected("unknown_posture", f"{request.posture!r} (known: {known})")
            spec = cfg.postures[request.posture]
            return PostureMove(
                self.geom,
                cfg,
                self.postures[request.posture],
                spec.held_across,
                body_pitch=spec.body_pitch,
                **kw,
            )
        if isinstance(request, GraspRequest):
            if self.monitor.holding:
                # the pre-grasp opening would drop it wherever the arm is (paper-5: a soup
                # can left in the fingers was carried to the marker's box)
                raise GraspRejected(
                    "already_holding", "the gripper holds an object: place or put it down first"
                )
            force = grasp_force(cfg.gripper, request.mass)
            return GraspPrimitive(self.geom, cfg, self._plan_grasp(request), force=force, **kw)
        if isinstance(request, PlaceRequest):
            if not self.monitor.holding:
                raise GraspRejected("not_holding", "the gripper holds nothing to place")
            pitch = fk_tcp(self.geom, obs.q_arm).pitch
            hang = place_hang(self.hang, self.held, self.grasp_approach, pitch)
            plan = plan_place(
                self.geom,
                cfg,
                np.asarray(request.position, dtype=float),
                obs.q_arm,
                hang,
                self.body,
                yaw=request.yaw,
                held=self.held,
            )
            prim = PlacePrimitive(self.geom, cfg, plan, **kw)
            held = "unknown" if self.held is None else np.round(self.held, 3).tolist()
            prim.note = (
                f"asked {np.round(request.position, 3).tolist()} yaw {request.yaw}, "
                f"held middle {held}, hang {hang:.3f} ({self.grasp_approach} grasp's "
                f"{self.hang:.3f}); {plan.describe()}"
            )
            return prim
        if isinstance(request, DrawerRequest):
            plan = plan_drawer(
                self.geom,
                cfg,
                np.asarray(request.handle_position, dtype=float),
                np.asarray(request.pull_direction, dtype=float),
                request.distance,
                self.body,
            )
            return DrawerPrimitive(self.geom, cfg, plan, **kw)
        raise GraspRejected("invalid_goal", f"unsupported goal {type(request).__name__}")

    def _plan_grasp(self, req: GraspRequest) -> GraspPlan:
        """Policy: ``auto`` tries vertical, then horizontal; the first rejection is kept."""
        pos = np.asarray(req.position, dtype=float)
        approaches: Sequence[str] = (
            ("vertical", "horizontal") if req.approach == "auto" else (req.approach,)
        )
        err: GraspRejected | None = None
        for ap in approaches:
            try:
                return plan_grasp(
                    self.geom, self.cfg, pos, ap, req.yaw, req.width, self.body, tilt=req.tilt
                )
            except GraspRejected as exc:
                err = err or exc
        assert err is not None
        if err.reason == "unreachable":
            band = self._reach_band(req, approaches)
            if band is not None:
                lo, hi = band
                raise GraspRejected(
                    err.reason,
                    f"{err.detail}; {reach_band_text(lo, hi, float(pos[0]))}",
                )
        raise err

    def _reach_band(
        self, req: GraspRequest, approaches: Sequence[str]
    ) -> tuple[float, float] | None:
        """The band of distances ahead (body x) from which this grasp would be planned, the
        rest of it unchanged: the run of reachable x nearest to the one asked, searched
        ``reach_search`` either side in ``reach_step`` steps; None if none is. A stance
        rejection's own reason does not say which way to step: a floor grasp beyond the
        band's far edge fails on the trunk envelope ("self_collision") as one before its
        near edge does (paper-5: the task stepped back from a too-far marker, then in
        again, four times, and gave it up)."""
        ex = self.cfg.executive
        pos = np.asarray(req.position, dtype=float)
        n = int(round(ex.reach_search / ex.reach_step))
        xs = pos[0] + ex.reach_step * np.arange(-n, n + 1)
        ok = np.zeros(len(xs), dtype=bool)
        for i, x in enumerate(xs):
            p = np.array([x, pos[1], pos[2]])
            for ap in approaches:
                try:
                    plan_grasp(
                        self.geom, self.cfg, p, ap, req.yaw, req.width, self.body, tilt=req.tilt
                    )
                except GraspRejected:
                    continue
                ok[i] = True
                break
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return None
        lo = hi = int(idx[np.argmin(np.abs(idx - n))])  # the reachable x nearest the asked
        while lo > 0 and ok[lo - 1]:
            lo -= 1
        while hi < len(xs) - 1 and ok[hi + 1]:
            hi += 1
        return float(xs[lo]), float(xs[hi])

    def _hang_of(self, req: GraspRequest, approach: str) -> float:
        """Policy: the held object's hang below the tool centre after a grasp."""
        ex = self.cfg.executive
        above_floor = float(req.position[2]) - self.floor_z
        if req.hang > 0.0:
            return float(req.hang)
        if approach == "vertical" and above_floor < ex.floor_grasp_max_z:
            return max(0.01, above_floor)
        return ex.default_hang

    def _held_of(self, req: GraspRequest, grasp: ArmTarget) -> np.ndarray | None:
        """The object's middle in the tool frame after a grasp at ``grasp`` (None: the
        goal did not say where the middle is)."""
        if req.center is None:
            return None
        offset = np.subtract(req.center, req.position)
        return held_offset(self.geom, grasp, offset)

    def _finish(self, run: _Run) -> None:
        """The goal ended (call under the lock): keep what it leaves, free the slot."""
        prim = run.primitive
        if run.started:
            self.body = prim.body
            if isinstance(prim, GraspPrimitive):
                # (a grasp that failed may still leave something in the fingers: not the
                # object the last offset was of)
                self.held = None
                self.grasp_approach = ""
            if isinstance(prim, GraspPrimitive) and prim.status is Status.SUCCEEDED:
                assert isinstance(run.request, GraspRequest)
                self.hang = self._hang_of(run.request, prim.plan.approach)
                self.held = self._held_of(run.request, prim.plan.reach)
                self.grasp_approach = prim.plan.approach
        if self._run is run:
            self._run = None
        run.finished.set()

    def _release(self, run: _Run) -> None:
        with self._lock:
            self._finish(run)

    def _watch_payload(self, obs: Observation) -> list[Output]:
        """A payload update on each new grip verdict, and periodically while holding."""
        state = self.monitor.state
        if state is not self._grip_state:
            self._grip_state = state
            held = self._grasp_payload if state is GripState.HOLDING else PayloadUpdate(0.0)
            if state is GripState.HOLDING and self.monitor.inferred:
                # found holding at start (a restart): an object of unknown class and mass
                held = PayloadUpdate(self.cfg.gripper.default_payload_mass)
            self._payload = PayloadUpdate(
                held.mass, held.object_name, state, obs.gripper_gap, obs.gripper_effort
            )
            self._payload_t = obs.t
            return [self._payload]
        period = self.cfg.executive.payload_period
        if self._payload.mass > 0.0 and obs.t - self._payload_t >= period:
            self._payload_t = obs.t
            return [PayloadUpdate(self._payload.mass, self._payload.object_name)]
        return []

    def _outputs(self, cmds: Sequence[Command]) -> list[Output]:
        """Primitive commands -> outputs; arm trajectories get their gravity feed-forward."""
        out: list[Output] = []
        m = self.cfg.motion
        for c in cmds:
            if isinstance(c, ArmCommand):
                tr = c.traj
                tau_ff = self.gravity.feed_forward(tr.q)
                out.append(ArmServo(tr.t, tr.q, tr.dq, tau_ff, tuple(m.kp), tuple(m.kd)))
            else:
                out.append(c)
        return out
