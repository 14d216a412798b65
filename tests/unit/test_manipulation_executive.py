"""The manipulation executive without transport: arbitration, plan-once, policy, cancel.

A perfect plant stands in for the arm: the measured joints follow the last commanded
trajectory exactly, and closing fingers stop on a 3 cm object and squeeze it.
"""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest
from quadmanip.common.reasons import parse_reach_band
from quadmanip.services.manipulation import executive as ex_mod
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
from quadmanip.services.manipulation.config import load_manipulation_config
from quadmanip.services.manipulation.executive import (
    ArmServo,
    DrawerRequest,
    Executive,
    GraspRequest,
    PayloadUpdate,
    PlaceRequest,
    PostureRequest,
)
from quadmanip.services.manipulation.gravity import GravityCompensator
from quadmanip.services.manipulation.gripper import GripState
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.services.manipulation.primitive import (
    BodyPoseRequest,
    GripperCmd,
    Observation,
    Status,
)
from quadmanip.sim.actuators import hermite

pytestmark = pytest.mark.unit

CFG = load_manipulation_config()
GEOM = ArmGeometry.from_description()
POSTURES = resolve_postures(GEOM, CFG)
GRAVITY = GravityCompensator()
DT = 0.002


def _executive(**kw: object) -> Executive:
    return Executive(GEOM, CFG, POSTURES, GRAVITY, **kw)  # type: ignore[arg-type]


class Plant:
    """Perfect arm tracking; fingers stop on an object ``width`` wide and squeeze it."""

    def __init__(self, q0: np.ndarray, width: float = 0.03) -> None:
        self.t = 1.0
        self.q0 = np.asarray(q0, dtype=float)
        self.servo: ArmServo | None = None
        self.gap_cmd = CFG.gripper.open_gap
        self.width = width
        self.sent: list[object] = []

    def obs(self) -> Observation:
        if self.servo is None:
            q, dq = self.q0.copy(), np.zeros(4)
        else:
            q, dq = hermite(self.servo.t, self.servo.q, self.servo.dq, self.t)
        squeezing = self.gap_cmd < self.width
        gap = self.width if squeezing else self.gap_cmd
        return Observation(self.t, q, dq, gap, 20.0 if squeezing else 0.0)

    def apply(self, outputs: list[object]) -> None:
        for c in outputs:
            self.sent.append(c)
            if isinstance(c, ArmServo):
                self.servo = c
            elif isinstance(c, GripperCmd):
                self.gap_cmd = c.gap

    def tick(self, ex: Executive) -> None:
        self.apply(ex.step(self.obs()))
        self.t += DT

    def run(self, ex: Executive, timeout: float = 60.0) -> None:
        t_end = self.t + timeout
        while ex.running and self.t < t_end:
            self.tick(ex)


def _floor_grasp(ex: Executive, approach: str = "vertical", **kw: object) -> GraspRequest:
    """A vertical grasp 2.5 cm above the floor, 36 cm ahead: reachable from the stance."""
    return GraspRequest(position=(0.36, 0.0, ex.floor_z + 0.025), approach=approach, **kw)  # type: ignore[arg-type]


def test_accept_and_reject_reasons():
    ex = _executive()
    obs = Plant(POSTURES["stow"]).obs()
    assert ex.accept(PostureRequest("stow"), None).reason.startswith("no_joint_state")
    assert ex.accept(PostureRequest("dance"), obs).reason.startswith("unknown_posture")
    far = GraspRequest(position=(2.0, 0.0, -0.2), approach="vertical")
    assert ex.accept(far, obs).reason.startswith("unreachable")
    side = GraspRequest(position=(0.4, 0.5, -0.25), approach="vertical")
    assert ex.accept(side, obs).reason.startswith("lateral_out_of_range")
    assert ex.accept(PlaceRequest((0.4, 0.0, 0.0)), obs).reason.startswith("not_holding")
    sideways = DrawerRequest((0.5, 0.0, -0.16), (0.0, 1.0, 0.0))
    assert ex.accept(sideways, obs).reason.startswith("pull_direction_unsupported")
    assert not ex.busy  # nothing rejected holds the slot
    ok = ex.accept(PostureRequest("floor_search"), obs)
    assert ok.accepted and ok.reason == "" and ex.busy
    busy = ex.accept(_floor_grasp(ex), obs)
    assert not busy.accepted and busy.reason == "busy: move_to_posture starting"


def test_auto_approach_is_vertical_when_reachable_else_horizontal():
    ex = _executive()
    obs = Plant(POSTURES["stow"]).obs()
    assert ex.accept(_floor_grasp(ex, approach="auto"), obs).accepted
    assert ex.active.plan.approach == "vertical"  # type: ignore[union-attr]
    ex = _executive()
    high = GraspRequest(position=(0.5, 0.0, 0.10), approach="auto")  # too far from above
    assert ex.accept(high, obs).accepted
    assert ex.active.plan.approach == "horizontal"  # type: ignore[union-attr]


def test_a_goal_is_planned_once(monkeypatch):
    calls: list[str] = []
    real = ex_mod.plan_grasp

    def counting(*args: object, **kw: object) -> object:
        calls.append(str(args[3]))
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(ex_mod, "plan_grasp", counting)
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    token = object()
    assert ex.accept(_floor_grasp(ex), plant.obs(), token=token).accepted
    prim = ex.active
    assert calls == ["vertical"]
    assert ex.start(token) is prim  # the primitive planned at accept is the one that runs
    for _ in range(500):
        plant.tick(ex)
    assert calls == ["vertical"]


def test_no_side_effect_of_a_rejected_or_unstarted_grasp():
    """Neither a rejected grasp nor an accepted one that never started changes what
    locomotion is told the gripper holds, or the held object's hang."""
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    heavy = GraspRequest(position=(2.0, 0.0, -0.2), approach="vertical", mass=0.4, hang=0.2)
    assert not ex.accept(heavy, plant.obs(), token="a").accepted
    assert ex.accept(_floor_grasp(ex, mass=0.4, object_name="can"), plant.obs(), "b").accepted
    assert ex.stop(plant.obs()) == []  # the service stops before the goal started
    assert not ex.busy and ex.start("b") is None
    # the fingers now squeeze something (a drawer handle, say): nothing is announced held
    ex.monitor.command_close(plant.t)
    plant.gap_cmd = 0.0
    for _ in range(200):
        plant.tick(ex)
    updates = [c for c in plant.sent if isinstance(c, PayloadUpdate)]
    assert updates and updates[-1].grip is GripState.HOLDING
    assert all(u.mass == 0.0 and u.object_name == "" for u in updates)
    assert ex.hang == CFG.executive.default_hang


def test_grasp_runs_announces_its_payload_and_measures_the_hang():
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    req = _floor_grasp(ex, mass=0.35, object_name="tomato_soup_can")
    assert ex.accept(req, plant.obs(), token=req).accepted
    assert ex.start(req) is not None
    plant.run(ex)
    assert not ex.busy and ex.active is None
    assert ex.hang == pytest.approx(0.025)  # measured: grasp point height above the floor
    held = [c for c in plant.sent if isinstance(c, PayloadUpdate) and c.mass > 0.0]
    assert held[0].mass == 0.35 and held[0].object_name == "tomato_soup_can"
    assert held[0].grip is GripState.HOLDING
    # every arm trajectory carries the gravity torque of its knots as feed-forward
    servos = [c for c in plant.sent if isinstance(c, ArmServo)]
    assert len(servos) >= 3
    for s in servos:
        assert s.tau_ff.shape == s.q.shape
        assert np.allclose(s.tau_ff, GRAVITY.feed_forward(s.q))
        assert s.kp == tuple(CFG.motion.kp) and s.kd == tuple(CFG.motion.kd)
    assert np.abs(servos[-1].tau_ff).max() > 0.1
    # the goal's own hang wins over the measurement; a table grasp takes the default
    for hang, pos, want in ((0.07, req.position, 0.07), (0.0, (0.5, 0.0, 0.1), None)):
        ex2 = _executive()
        plant2 = Plant(POSTURES["stow"])
        r = GraspRequest(position=pos, approach="auto", hang=hang)  # type: ignore[arg-type]
        assert ex2.accept(r, plant2.obs()).accepted
        ex2.start()
        plant2.run(ex2)
        assert ex2.hang == pytest.approx(want or CFG.executive.default_hang)


def test_a_grasp_keeps_where_the_objects_middle_is_in_the_fingers() -> None:
    """The goal's ``center`` becomes the held object's middle in the tool frame, which the
    place uses; a grasp without it (or one that fails) leaves none."""
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    base = _floor_grasp(ex)
    middle = (base.position[0], base.position[1] + 0.05, base.position[2])
    req = dataclasses.replace(base, center=middle)
    assert ex.accept(req, plant.obs(), token=req).accepted
    ex.start(req)
    plant.run(ex)
    assert ex.held is not None  # 5 cm, turned into the tool frame
    assert np.linalg.norm(ex.held) == pytest.approx(0.05, abs=1e-9)
    ex2 = _executive()
    plant2 = Plant(POSTURES["stow"])
    assert ex2.accept(base, plant2.obs(), token=base).accepted
    ex2.start(base)
    plant2.run(ex2)
    assert ex2.held is None


def test_a_pitched_posture_lifts_the_nose_and_the_next_grasp_levels_the_trunk_first():
    """PostureSpec.body_pitch: probe_tall asks locomotion for its trunk pitch (and waits
    for it to settle); a grasp planned for a level trunk first asks for pitch 0, before
    its first arm move, and a posture without a pitch levels it too."""
    pitch = CFG.postures["probe_tall"].body_pitch
    assert pitch < -0.1  # nose up
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    t0 = plant.t
    assert ex.accept(PostureRequest("probe_tall"), plant.obs()).accepted
    ex.start()
    plant.run(ex)
    bodies = [c for c in plant.sent if isinstance(c, BodyPoseRequest)]
    assert [b.pitch for b in bodies] == [pitch]
    assert ex.body.pitch == pitch
    assert plant.t - t0 >= CFG.grasp.body_settle_time  # it waited for the trunk
    np.testing.assert_allclose(plant.obs().q_arm, POSTURES["probe_tall"], atol=1e-6)

    plant.sent.clear()
    req = _floor_grasp(ex)
    assert ex.accept(req, plant.obs()).accepted
    ex.start()
    plant.run(ex)
    first_arm = next(i for i, c in enumerate(plant.sent) if isinstance(c, ArmServo))
    level = [i for i, c in enumerate(plant.sent) if isinstance(c, BodyPoseRequest)]
    assert level and level[0] < first_arm
    assert plant.sent[level[0]].pitch == 0.0  # type: ignore[attr-defined]
    assert all(c.pitch == 0.0 for c in plant.sent if isinstance(c, BodyPoseRequest))
    assert ex.body.pitch == 0.0

    # every posture sends its pitch: after a restart the executive does not know it
    for name, want in (("probe_tall", [pitch]), ("stow", [0.0]), ("probe_table", [0.0])):
        plant.sent.clear()
        assert ex.accept(PostureRequest(name), plant.obs()).accepted
        ex.start()
        plant.run(ex)
        assert [c.pitch for c in plant.sent if isinstance(c, BodyPoseRequest)] == want


def test_a_grasp_that_fails_with_the_trunk_crouched_stands_it_back_up():
    """paper-2 (2026-12-06): a place lost the spoon during its trunk shift (4.6 cm to the
    side) and the offset stayed; every approach after it ended "did not settle". A
    primitive that fails with the trunk offset asks for the nominal pose as it ends."""
    ex = _executive()
    plant = Plant(POSTURES["stow"], width=0.0)  # the fingers close on nothing
    req = _floor_grasp(ex)
    assert ex.accept(req, plant.obs()).accepted
    prim = ex.start()
    assert prim is not None
    plant.run(ex)
    assert prim.status is Status.FAILED and "grasp_missed" in prim.reason
    bodies = [c for c in plant.sent if isinstance(c, BodyPoseRequest)]
    assert any(b.z_offset < -0.01 or abs(b.x_offset) > 0.01 for b in bodies)  # it crouched
    assert bodies[-1] == BodyPoseRequest(0.0, 0.0, 0.0, 0.0)
    assert ex.body == BodyPoseRequest()
    # one that succeeds keeps what it ends with (a grasp stands back up itself)
    ok = _executive()
    plant = Plant(POSTURES["stow"])
    assert ok.accept(req, plant.obs()).accepted
    prim = ok.start()
    assert prim is not None
    plant.run(ok)
    assert prim.status is Status.SUCCEEDED
    assert ok.body == BodyPoseRequest()


def test_two_goals_at_once_one_accepted_one_busy(monkeypatch):
    """Two goals for two actions at the same moment: exactly one is accepted, the other is
    rejected "busy", however long planning takes (a check-then-set would let both in)."""
    ex = _executive()
    real_plan = ex._plan

    def slow_plan(*args: object) -> object:
        time.sleep(0.02)  # widen the window between the check and the reservation
        return real_plan(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(ex, "_plan", slow_plan)
    obs = Plant(POSTURES["stow"]).obs()
    for _ in range(5):
        gate = threading.Barrier(2)
        verdicts: dict[str, object] = {}

        def send(
            name: str, request: object, gate: threading.Barrier = gate, verdicts: dict = verdicts
        ) -> None:
            gate.wait()
            verdicts[name] = ex.accept(request, obs, token=name)  # type: ignore[arg-type]

        threads = [
            threading.Thread(target=send, args=("posture", PostureRequest("floor_search"))),
            threading.Thread(target=send, args=("grasp", _floor_grasp(ex))),
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join(5.0)
        accepted = [n for n, v in verdicts.items() if v.accepted]  # type: ignore[attr-defined]
        rejected = [v for v in verdicts.values() if not v.accepted]  # type: ignore[attr-defined]
        assert len(accepted) == 1 and len(rejected) == 1, verdicts
        assert rejected[0].reason.startswith("busy"), rejected[0]
        assert ex.start(accepted[0]) is not None
        ex.stop(obs)  # end it: the slot is free for the next round
        assert not ex.busy


def test_cancel_holds_the_arm_and_frees_the_slot():
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    token = object()
    assert ex.accept(PostureRequest("floor_search"), plant.obs(), token=token).accepted
    cancel = threading.Event()
    feedback: list[tuple[float, str]] = []
    result: list[object] = []
    worker = threading.Thread(
        target=lambda: result.append(
            ex.execute(
                token, cancel_requested=cancel.is_set, feedback=lambda p, t: feedback.append((p, t))
            )
        )
    )
    worker.start()
    deadline = time.monotonic() + 5.0
    while not ex.running and time.monotonic() < deadline:
        time.sleep(0.001)
    t_cancel = plant.t + 0.3
    while worker.is_alive() and time.monotonic() < deadline:
        if plant.t >= t_cancel:
            cancel.set()
        plant.tick(ex)
        time.sleep(0.0005)
    worker.join(1.0)
    assert result and result[0].status is Status.CANCELED  # type: ignore[attr-defined]
    assert result[0].reason == ex_mod.CANCELED_REASON  # type: ignore[attr-defined]
    assert feedback and feedback[0][1] == "moving"
    hold = [c for c in plant.sent if isinstance(c, ArmServo)][-1]
    assert len(hold.t) == 1 and hold.t[0] >= t_cancel  # a one-knot hold at the cancel
    assert not ex.busy
    assert ex.accept(PostureRequest("stow"), plant.obs()).accepted


def test_an_unstarted_reservation_lapses():
    now = [0.0]
    ex = _executive(clock=lambda: now[0])
    obs = Plant(POSTURES["stow"]).obs()
    assert ex.accept(PostureRequest("floor_search"), obs, token="a").accepted
    now[0] = CFG.executive.claim_timeout * 0.5
    assert ex.accept(PostureRequest("stow"), obs, token="b").reason.startswith("busy")
    now[0] = CFG.executive.claim_timeout + 0.1  # "a" was refused after its accept
    assert ex.accept(PostureRequest("stow"), obs, token="b").accepted
    assert ex.start("a") is None
    assert ex.execute("a").status is Status.FAILED
    assert ex.start("b") is not None
    assert ex.accept(PostureRequest("stow"), obs).reason == "busy: move_to_posture running"


def test_a_restart_while_carrying_announces_an_unknown_payload_and_can_place():
    """A new manipulation process starts with the fingers still squeezing the object (the
    actuator layer keeps the last command): it infers the grip from the readings, tells
    locomotion once (default mass, no name) and accepts a place."""
    ex = _executive()
    plant = Plant(POSTURES["carry"], width=0.03)
    plant.gap_cmd = 0.0  # the old process's close command
    obs = plant.obs()
    assert ex.accept(PlaceRequest((0.4, 0.0, 0.0)), obs).reason.startswith("not_holding")
    for _ in range(200):  # 0.4 s of readings
        plant.tick(ex)
    payloads = [c for c in plant.sent if isinstance(c, PayloadUpdate)]
    assert len(payloads) == 1  # one message (then the usual repeat every payload_period)
    (p,) = payloads
    assert p.grip is GripState.HOLDING and p.object_name == ""
    assert p.mass == pytest.approx(CFG.gripper.default_payload_mass) and p.gap == 0.03
    assert ex.payload.mass == pytest.approx(CFG.gripper.default_payload_mass)
    # it refuses a grasp until it has let go: the pre-grasp opening would drop it
    assert ex.accept(_floor_grasp(ex), plant.obs()).reason.startswith("already_holding")
    verdict = ex.accept(PlaceRequest((0.36, 0.0, ex.floor_z + 0.05)), plant.obs())
    assert verdict.accepted, verdict.reason


def test_an_unreachable_grasp_names_the_distances_it_would_be_planned_from():
    """A floor grasp beyond the reachable band fails on the trunk envelope, as one before
    it does: the refusal names the band (body x), which holds the nominal 36 cm probing
    distance and excludes the asked one."""
    ex = _executive()
    obs = Plant(POSTURES["stow"]).obs()
    far = GraspRequest(position=(0.50, 0.0, ex.floor_z + 0.01), approach="vertical")
    reason = ex.accept(far, obs).reason
    assert reason.startswith("unreachable")
    band = parse_reach_band(reason)
    assert band is not None, reason
    lo, hi, asked = band
    assert asked == pytest.approx(0.50)
    assert lo < 0.36 < hi < 0.50
    # nothing reachable anywhere near: no band
    nowhere = GraspRequest(position=(0.4, 0.0, ex.floor_z - 0.3), approach="vertical")
    reason = ex.accept(nowhere, obs).reason
    assert reason.startswith("unreachable") and parse_reach_band(reason) is None
    # the band's middle is planned
    mid = GraspRequest(position=((lo + hi) / 2, 0.0, ex.floor_z + 0.01), approach="vertical")
    assert ex.accept(mid, obs).accepted


@pytest.mark.parametrize("stuck", [False, True], ids=["let_go", "stuck"])
def test_the_grip_verdict_is_sent_before_the_goal_ends(stuck):
    """The task judges a place by the grip it reads the moment the result arrives: the
    step that ends a goal must already carry the grip verdict that goal left. A place
    whose empty check closes on the object again (stuck between the fingers) ends on
    that check; its "holding" used to follow one step after the result."""
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    req = _floor_grasp(ex, mass=0.35, object_name="tomato_soup_can")
    assert ex.accept(req, plant.obs(), token=req).accepted and ex.start(req) is not None
    plant.run(ex)
    place = PlaceRequest((0.36, 0.0, ex.floor_z + 0.05))
    assert ex.accept(place, plant.obs(), token=place).accepted
    prim = ex.start(place)
    assert prim is not None
    # the log says where it was asked and planned to let go (a tool left on the drawer's
    # front in paper-5, 2026-12-06, and nothing said where it was released)
    assert prim.note.startswith("asked [0.36, 0.0, ") and "release x 0." in prim.note
    if not stuck:
        plant.width = 0.0  # the object stays where it was put: the fingers close on nothing
    plant.run(ex)  # stops on the step that ended the place
    assert not ex.running
    verdicts = [c for c in plant.sent if isinstance(c, PayloadUpdate) and c.grip is not None]
    if stuck:
        assert verdicts[-1].grip is GripState.HOLDING and verdicts[-1].mass == 0.35
    else:
        assert verdicts[-1].grip is not GripState.HOLDING and verdicts[-1].mass == 0.0


def test_a_side_held_object_carried_tool_down_is_placed_by_its_far_end() -> None:
    """seed-139 (2026-12-07): a cracker box side-grasped from a table hung 5 cm under the
    level tool; carried tool down it hangs 13 cm along the tool's axis. Placed with the
    grasp's 5 cm it went 8 cm into the tray's floor and stuck between the fingers ten
    times. A vertical grasp's hang, or a side grasp placed level, is the grasp's own."""
    from quadmanip.common.robot_description import HORIZONTAL_GRASP_DEPTH
    from quadmanip.services.manipulation.place import place_hang

    held = np.array([0.051, 0.0, 0.055])  # the trial's held middle (tool frame)
    down = POSTURES["carry"]
    pitch = float(ex_mod.fk_tcp(GEOM, down).pitch)
    assert pitch > 1.5
    assert place_hang(0.05, held, "horizontal", pitch) == pytest.approx(
        0.102 + HORIZONTAL_GRASP_DEPTH
    )
    assert place_hang(0.05, held, "horizontal", 0.0) == 0.05  # still level
    assert place_hang(0.05, held, "vertical", pitch) == 0.05
    assert place_hang(0.05, None, "horizontal", pitch) == 0.05  # middle unknown
    # the executive keeps how the object was grasped, for its place
    ex = _executive()
    plant = Plant(POSTURES["stow"])
    req = dataclasses.replace(_floor_grasp(ex), center=(0.36, 0.0, ex.floor_z + 0.05))
    assert ex.accept(req, plant.obs(), token=req).accepted
    ex.start(req)
    plant.run(ex)
    assert ex.grasp_approach == "vertical"
