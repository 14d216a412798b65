"""Planning rejections with reasons, and cancel stopping the arm (in-process physics)."""

import math

import numpy as np
import pytest
from quadmanip.common.rotations import rot_x, rot_y
from quadmanip.services.locomotion.controller import load_locomotion_config
from quadmanip.services.manipulation.arm_kinematics import (
    ArmGeometry,
    ArmTarget,
    fk_tcp,
    held_offset,
)
from quadmanip.services.manipulation.config import load_manipulation_config
from quadmanip.services.manipulation.drawer import plan_drawer
from quadmanip.services.manipulation.grasp import GraspPrimitive, GraspRejected, plan_grasp
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
from quadmanip.services.manipulation.place import PlacePrimitive, plan_place
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.services.manipulation.primitive import (
    ArmCommand,
    BodyPoseRequest,
    Observation,
    Status,
)
from quadmanip.testbench.manipulation_scenes import PlacedObject, SimHarness

pytestmark = pytest.mark.unit

CFG = load_manipulation_config()
GEOM = ArmGeometry.from_description()
FLOOR_Z = -0.30  # floor in the body frame when standing (home keyframe)


def _reason(fn, *args, **kw) -> str:
    with pytest.raises(GraspRejected) as err:
        fn(*args, **kw)
    return err.value.reason


def test_grasp_rejections():
    ok = np.array([0.36, 0.0, FLOOR_Z + 0.025])
    assert plan_grasp(GEOM, CFG, ok, "vertical", 0.0, 0.05).approach == "vertical"
    # 0.2 m to the side: the body cannot shift that far (moveCOM limit)
    assert (
        _reason(plan_grasp, GEOM, CFG, ok + [0, 0.2, 0], "vertical", 0.0, 0.05)
        == "lateral_out_of_range"
    )
    # 1 m ahead: out of reach even crouched
    assert _reason(plan_grasp, GEOM, CFG, ok + [0.7, 0, 0], "vertical", 0.0, 0.05) == "unreachable"
    # wider than the open gripper
    assert _reason(plan_grasp, GEOM, CFG, ok, "vertical", 0.0, 0.12) == "too_wide"
    assert _reason(plan_grasp, GEOM, CFG, ok * np.nan, "vertical", 0.0, 0.05) == "invalid_goal"
    assert _reason(plan_grasp, GEOM, CFG, ok, "sideways", 0.0, 0.05) == "invalid_goal"
    # horizontal beyond MANIPULATOR_X_LIM + the body's forward shift
    far = np.array([0.9, 0.0, 0.1])
    assert _reason(plan_grasp, GEOM, CFG, far, "horizontal", 0.0, 0.05) == "too_far"


def test_vertical_grasp_crouches_only_when_needed():
    # a table-height object: no crouch
    high = plan_grasp(GEOM, CFG, np.array([0.36, 0.0, 0.13]), "vertical", 0.0, 0.05)
    assert high.body_grasp.z_offset == 0.0
    # floor objects: Algorithm 6 crouches (COM z), the further out the deeper
    near = plan_grasp(GEOM, CFG, np.array([0.36, 0.0, FLOOR_Z + 0.025]), "vertical", 0.0, 0.05)
    far = plan_grasp(GEOM, CFG, np.array([0.44, 0.0, FLOOR_Z + 0.025]), "vertical", 0.0, 0.05)
    assert -CFG.grasp.max_crouch <= far.body_grasp.z_offset < near.body_grasp.z_offset <= 0.0
    # and shifts the body sideways by the grasp point's y (moveCOM)
    side = plan_grasp(GEOM, CFG, np.array([0.36, 0.04, FLOOR_Z + 0.025]), "vertical", 0.0, 0.05)
    assert side.body_ready.y_offset == pytest.approx(0.04)
    assert side.reach.pitch == pytest.approx(math.pi / 2)


def test_horizontal_grasp_shifts_com_beyond_x_lim():
    p = np.array([0.06 + CFG.grasp.manipulator_x_lim + 0.04, 0.0, 0.10])
    plan = plan_grasp(GEOM, CFG, p, "horizontal", 0.0, 0.05)
    assert plan.reach.x == pytest.approx(CFG.grasp.manipulator_x_lim)
    assert plan.body_grasp.x_offset == pytest.approx(0.04)
    assert plan.reach.pitch == 0.0


def test_place_and_drawer_rejections():
    q = resolve_postures(GEOM, CFG)["carry"]
    assert _reason(plan_place, GEOM, CFG, np.array([1.5, 0, 0]), q, 0.05) == "unreachable"
    assert (
        _reason(plan_place, GEOM, CFG, np.array([0.4, 0.3, 0]), q, 0.05) == "lateral_out_of_range"
    )
    h = np.array([0.5, 0.0, -0.16])
    sideways = np.array([0.0, 1.0, 0.0])
    assert _reason(plan_drawer, GEOM, CFG, h, sideways, 0.15) == "pull_direction_unsupported"
    assert _reason(plan_drawer, GEOM, CFG, h, np.array([-1.0, 0, 0]), -0.1) == "invalid_goal"


def test_place_keeps_a_tall_object_upright():
    """A tall held object is released from a vertical tool or the place is rejected as too
    far (the task steps closer): released leaning, the sugar box landed on its edge and
    tipped out of the tray."""
    q = resolve_postures(GEOM, CFG)["carry"]
    tray = 0.125  # the tray's rim in the body frame, deposit table in front of the robot
    hang = 0.145  # the sugar box held by its top
    assert "too_far" in str(_rejection(plan_place, GEOM, CFG, np.array([0.50, 0, tray]), q, hang))
    plan = plan_place(GEOM, CFG, np.array([0.39, 0.0, tray]), q, hang)
    assert plan.release.pitch == pytest.approx(math.pi / 2, abs=0.05)
    # released as high above the rim as a short object is (the bottom clears it)
    short = plan_place(GEOM, CFG, np.array([0.39, 0.0, tray]), q, 0.03)
    bottom = plan.release.z - hang + plan.body.z_offset
    assert bottom == pytest.approx(short.release.z - 0.03 + short.body.z_offset, abs=1e-9)
    # out of reach at that height, it is released lower before the tool leans: over the
    # tray's near row from its stance (0.43 m) the sugar box was out of reach, and the
    # steps closer brought the trunk to the table's edge
    low = plan_place(GEOM, CFG, np.array([0.41, 0.0, tray]), q, hang)
    # (released leaning 0.1 rad there, the sugar box landed on its edge and fell back)
    assert low.release.pitch == pytest.approx(math.pi / 2, abs=0.05)
    g = CFG.grasp
    lower = bottom - (low.release.z - hang + low.body.z_offset)
    assert lower == pytest.approx(g.place_release_z - g.place_min_release_z, abs=1e-9)
    assert 0.0 < g.place_min_release_z < g.place_release_z
    # a short object may lean to reach farther still
    far = plan_place(GEOM, CFG, np.array([0.52, 0.0, tray]), q, 0.03)
    assert far.release.pitch < math.pi / 2 - 0.05


def test_a_place_puts_the_held_objects_middle_where_it_is_asked():
    """Held 4 cm to the side of the grasp point (a spoon by its bowl), then turned a quarter
    by the place's yaw: the tool goes where the object's middle comes over the point."""
    q = resolve_postures(GEOM, CFG)["carry"]
    grasp = ArmTarget(0.35, -0.25, math.pi / 2, 0.0)  # fingers along the body y
    held = held_offset(GEOM, grasp, np.array([0.0, 0.04, -0.005]))
    point = np.array([0.40, 0.01, 0.125])
    plain = plan_place(GEOM, CFG, point, q, 0.03, yaw=math.pi / 2)
    plan = plan_place(GEOM, CFG, point, q, 0.03, yaw=math.pi / 2, held=held)
    r = plan.release
    mid = rot_y(r.pitch) @ rot_x(r.roll) @ held  # the middle from the tool, arm_base axes
    # in the body frame before the shift: the arm's plane lies the body shift to the side
    x = GEOM.arm_base_pos[0] + r.x + mid[0]
    y = plan.body.y_offset + mid[1]
    assert (x, y) == pytest.approx((point[0], point[1]), abs=1e-6)
    # turned a quarter, the 4 cm now lie along the body x: the tool stands 4 cm off there
    assert abs(r.x - plain.release.x) == pytest.approx(0.04, abs=0.002)
    assert plan.body.y_offset == pytest.approx(plain.body.y_offset, abs=0.002)
    # a shift beyond the body's limit is cut to it (placed as near as it allows)
    far = held_offset(GEOM, grasp, np.array([0.10, 0.0, 0.0]))  # 10 cm: the body y
    cut = plan_place(GEOM, CFG, point, q, 0.03, yaw=math.pi / 2, held=far)
    assert abs(cut.body.y_offset) == pytest.approx(CFG.grasp.max_lateral_shift)


@pytest.mark.parametrize("carried", [math.pi / 2, -math.pi / 2])
def test_a_place_turns_the_wrist_the_shorter_way_to_the_fingers_line(carried):
    """Carried across (the wrist turned a quarter, either way) and placed across, the
    fingers already lie as asked: no turn (not a half turn, 4-5 s); placed along, a
    quarter turn at most. The held middle is placed where asked either way."""
    q = resolve_postures(GEOM, CFG)["carry"].copy()
    q[3] = carried
    grasp = ArmTarget(0.35, -0.25, math.pi / 2, 0.0)
    held = held_offset(GEOM, grasp, np.array([0.0, 0.04, -0.005]))
    point = np.array([0.40, 0.01, 0.125])
    across = plan_place(GEOM, CFG, point, q, 0.03, yaw=math.pi / 2, held=held)
    assert across.release.roll == pytest.approx(carried)
    along = plan_place(GEOM, CFG, point, q, 0.03, yaw=0.0, held=held)
    assert abs(along.release.roll - carried) == pytest.approx(math.pi / 2)
    for plan in (across, along):
        r = plan.release
        mid = rot_y(r.pitch) @ rot_x(r.roll) @ held
        x = GEOM.arm_base_pos[0] + r.x + mid[0]
        y = plan.body.y_offset + mid[1]
        assert (x, y) == pytest.approx((point[0], point[1]), abs=1e-6)


def test_body_requests_stay_within_locomotion_limits():
    """Manipulation never asks for a body pose that locomotion rejects (z_raise 3 cm: a 6 cm
    rise was refused mid-place and the open fingers stayed around the can)."""
    lim = load_locomotion_config().limits
    g = CFG.grasp
    assert g.max_rise <= lim.z_raise
    assert g.max_crouch <= lim.z_crouch
    assert max(g.max_lateral_shift, g.max_forward_shift) <= lim.shift
    # a place after one that failed with the trunk risen (paper-1, 2026-12-06: 6 cm asked)
    q = resolve_postures(GEOM, CFG)["carry"]
    up = BodyPoseRequest(0.0, 0.0, g.max_rise)
    for x, z in ((0.36, 0.25), (0.36, 0.3), (0.38, 0.225)):  # (these asked 4.5-6 cm)
        try:
            plan = plan_place(GEOM, CFG, np.array([x, 0.0, z]), q, 0.03, up)
        except GraspRejected:
            continue
        assert -lim.z_crouch <= plan.body.z_offset <= lim.z_raise


def test_place_fails_when_the_object_is_lost_on_the_way():
    """The object slides out as the place begins (fingers meet): the place fails with
    object_lost instead of releasing nothing and reporting success."""
    q = resolve_postures(GEOM, CFG)["carry"]
    plan = plan_place(GEOM, CFG, np.array([0.36, 0.0, -0.10]), q, 0.03)
    assert plan.body == BodyPoseRequest()  # no body move: the first check comes at once
    monitor = GraspMonitor(CFG.gripper)
    monitor.command_close(0.0)
    for k in range(200):  # squeezing a 2 cm object until the monitor says holding
        monitor.update(0.002 * k, 0.02, 20.0)
    assert monitor.holding
    prim = PlacePrimitive(GEOM, CFG, plan, monitor)
    t = 0.4
    while not prim.done and t < 5.0:  # the fingers have met: the object is gone
        prim.step(Observation(t, q.copy(), np.zeros(4), 0.0, 20.0))
        t += 0.002
    assert prim.status is Status.FAILED
    assert prim.reason.startswith("object_lost"), prim.reason
    assert monitor.state is GripState.LOST


def _rejection(fn, *args, **kw) -> GraspRejected:
    with pytest.raises(GraspRejected) as err:
        fn(*args, **kw)
    return err.value


def test_cancel_holds_the_arm_where_it_is():
    h = SimHarness([PlacedObject("brick", (0.36, 0.0, 0.026))])
    h.settle(0.3)
    plan = plan_grasp(GEOM, CFG, h.world_to_base([0.36, 0.0, 0.025]), "vertical", 0.0, 0.05)
    prim = GraspPrimitive(GEOM, CFG, plan)
    kp, kd = CFG.motion.kp, CFG.motion.kd
    # run until the arm is moving fast towards the grasp-ready pose, then cancel
    while prim.progress.text.find("arm above") < 0 or np.max(np.abs(h.observation().dq_arm)) < 1:
        h.apply(prim.step(h.observation()), kp, kd)
        h.step()
        assert h.data.time < 10.0 and not prim.done
    assert float(np.max(np.abs(h.observation().dq_arm))) > 0.2  # really moving
    cmds = prim.cancel(h.observation())
    assert prim.status is Status.CANCELED and prim.done
    assert len(cmds) == 1 and isinstance(cmds[0], ArmCommand) and len(cmds[0].traj.t) == 1
    h.apply(cmds, kp, kd)
    q_cancel = h.observation().q_arm
    h.settle(1.5)
    o = h.observation()
    # the arm stopped: it settles next to where the cancel found it, and stays
    assert float(np.max(np.abs(o.dq_arm))) < 0.02
    assert float(np.max(np.abs(o.q_arm - q_cancel))) < 0.15
    tcp = fk_tcp(GEOM, o.q_arm)
    assert math.isfinite(tcp.x) and prim.step(o) == []  # a canceled primitive sends nothing


def test_tilted_vertical_grasp_approaches_along_the_tool_axis():
    # a bowl's flared wall (37 deg lean) is pinched with the tool leaned along it
    tilt = math.radians(37.0)
    p = np.array([0.45, 0.0, FLOOR_Z + 0.04])
    plan = plan_grasp(GEOM, CFG, p, "vertical", math.pi / 2, 0.015, tilt=tilt)
    pitch = math.pi / 2 - tilt
    assert plan.reach.pitch == pytest.approx(pitch) and plan.ready.pitch == pytest.approx(pitch)
    d = np.array([plan.reach.x - plan.ready.x, plan.reach.z - plan.ready.z])
    axis = np.array([math.cos(pitch), -math.sin(pitch)])  # tool x axis in the arm plane
    assert np.linalg.norm(d) == pytest.approx(CFG.grasp.grasp_ready_z)
    assert float(d @ axis) == pytest.approx(CFG.grasp.grasp_ready_z)  # straight down the axis
    assert plan.lift.z - plan.reach.z == pytest.approx(CFG.grasp.lift_height)
    for bad in (1.2, float("nan")):
        assert _reason(plan_grasp, GEOM, CFG, p, "vertical", 0.0, 0.015, tilt=bad) == (
            "invalid_goal"
        )
    assert _reason(plan_grasp, GEOM, CFG, p, "horizontal", 0.0, 0.05, tilt=0.3) == "invalid_goal"


def test_body_drift_is_odometry_minus_requested_body_offsets():
    from quadmanip.services.manipulation.primitive import (
        BodyPoseRequest,
        Observation,
        PostureMove,
    )

    q = np.zeros(4)
    prim = PostureMove(GEOM, CFG, q)

    def obs(t, base):
        return Observation(t, q, q, 0.0, 0.0, base=base)

    prim.step(obs(0.0, (2.0, 1.0, 0.30, math.pi / 2)))  # facing +y in the odometry frame
    assert np.allclose(prim.body_drift(), 0.0)
    # the trunk backed off 2 cm (world -y = body -x) and sagged 5 mm, unrequested
    prim.step(obs(0.1, (2.0, 0.98, 0.295, math.pi / 2)))
    assert np.allclose(prim.body_drift(), [-0.02, 0.0, -0.005], atol=1e-12)
    # a requested 4 cm lateral shift (moveCOM, body +y = world -x) is not drift
    prim.body = BodyPoseRequest(0.0, 0.04, 0.0)
    prim.step(obs(0.2, (1.96, 0.98, 0.295, math.pi / 2)))
    assert np.allclose(prim.body_drift(), [-0.02, 0.0, -0.005], atol=1e-12)
    # without odometry (the in-process harness) there is no drift
    fresh = PostureMove(GEOM, CFG, q)
    fresh.step(obs(0.0, None))
    assert np.allclose(fresh.body_drift(), 0.0)
