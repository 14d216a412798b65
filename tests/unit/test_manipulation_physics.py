"""Grasp, place and drawer primitives in MuJoCo physics, pure friction (no weld, no attach).

The scene is the robot description on a floor with table slabs and deposit containers of
the house's sizes (or the house itself for the drawers). The legs are held by the sim's
actuator layer at standing targets (test stand-in for locomotion, see quadmanip/testbench/manipulation_scenes.py);
grasp poses come from ground truth (stand-in for perception). Everything else - arm,
gripper, objects - moves only through the actuator layer's torques and contacts.
"""

import math
from dataclasses import replace

import mujoco
import numpy as np
import pytest
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry, ArmTarget, held_offset
from quadmanip.services.manipulation.config import load_manipulation_config
from quadmanip.services.manipulation.drawer import DrawerPrimitive, plan_drawer
from quadmanip.services.manipulation.grasp import GraspPrimitive, GraspRejected, plan_grasp
from quadmanip.services.manipulation.place import PlacePrimitive, plan_place
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.services.manipulation.primitive import BodyPoseRequest, PostureMove, Status
from quadmanip.sim.world.objects import load_catalogue
from quadmanip.testbench.manipulation_scenes import (
    TABLE_HEIGHT,
    Box,
    PlacedObject,
    SimHarness,
    container_boxes,
    container_inner,
    drawer_mouth,
    drawer_place_world,
    drawer_world,
    grasp_from_ground_truth,
    in_region,
    table_boxes,
)

pytestmark = pytest.mark.unit

CAT = load_catalogue()
CFG = load_manipulation_config()
GEOM = ArmGeometry.from_description()
KP, KD = CFG.motion.kp, CFG.motion.kd

# one object of each category (paper Section 7.2), from the floor and from a table
FLOOR = ["brick", "tomato_soup_can", "padlock", "marker", "rubiks_cube", "mug"]
TABLE = [
    ("tennis_ball", "vertical"),
    ("sugar_box", "horizontal"),
    ("screwdriver", "vertical"),
    ("spoon", "vertical"),
    ("lego", "vertical"),
    ("cup", "vertical"),
]


def _assert_honest(h: SimHarness) -> None:
    m = h.model
    assert m.nmocap == 0
    # the only equality constraint is the gripper's own finger coupling (description)
    for i in range(m.neq):
        assert m.eq_type[i] == mujoco.mjtEq.mjEQ_JOINT, "no weld/connect may hold an object"
    assert not np.any(h.data.xfrc_applied)


def _grasp(h: SimHarness, name: str, surface: float, approach: str) -> GraspPrimitive:
    gs = grasp_from_ground_truth(h, name, surface, approach)
    plan = plan_grasp(GEOM, CFG, gs.position_base, gs.approach, gs.yaw, gs.width)
    return h.run(GraspPrimitive(GEOM, CFG, plan), KP, KD, timeout=30.0)  # type: ignore[return-value]


def _held_for(h: SimHarness, name: str, z0: float, seconds: float) -> float:
    """Lowest lift (m) of the object over ``seconds`` of holding."""
    low = np.inf
    for _ in range(int(seconds / 0.1)):
        h.settle(0.1)
        low = min(low, h.object_pos(name)[2] - z0)
    return float(low)


def _check_grasp(h: SimHarness, name: str, surface: float, approach: str) -> None:
    h.settle(0.3)
    z0 = h.object_pos(name)[2]
    prim = _grasp(h, name, surface, approach)
    assert prim.status is Status.SUCCEEDED, prim.reason
    # lifted 10 cm and held for 3 s by friction alone
    assert _held_for(h, name, z0, 3.0) >= 0.10
    assert prim.monitor.holding
    # time from goal to lifted, sim seconds (issue target: median <= 15 s)
    assert prim.t_lifted is not None and prim.t_lifted - prim.t_start < 15.0
    _assert_honest(h)


@pytest.mark.parametrize("name", FLOOR)
def test_floor_grasp_lift_hold(name):
    o = CAT.objects[name]
    h = SimHarness([PlacedObject(name, (0.36, 0.03, o.size[2] / 2 + 0.001), yaw=0.4)])
    _check_grasp(h, name, 0.0, "vertical")


@pytest.mark.parametrize(("name", "approach"), TABLE)
def test_table_grasp_lift_hold(name, approach):
    o = CAT.objects[name]
    yaw = 0.35 if approach == "vertical" else 0.0
    pos = (0.36, -0.03, TABLE_HEIGHT + o.size[2] / 2 + 0.001)
    h = SimHarness([PlacedObject(name, pos, yaw=yaw)], table_boxes())
    _check_grasp(h, name, TABLE_HEIGHT, approach)


def _turned_in_grip(h: SimHarness, name: str, since: np.ndarray) -> float:
    """How far (deg) the object turned relative to the tool since ``since`` (the tool's
    rotation matrix transposed times the object's, then)."""
    site = mujoco.mj_name2id(h.model, mujoco.mjtObj.mjOBJ_SITE, "gripper_tcp")
    obj = np.zeros(9)
    mujoco.mju_quat2Mat(obj, h.object_quat(name))
    rel = h.data.site_xmat[site].reshape(3, 3).T @ obj.reshape(3, 3)
    cos = (np.trace(since.T @ rel) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


@pytest.mark.parametrize(("name", "x"), [("spoon", 0.40), ("rubiks_cube", 0.46)])
def test_a_table_object_past_the_upright_reach_is_grasped_with_the_tool_leaning(name, x):
    """From a table's edge the trunk comes no nearer: a spoon's bowl 2 cm past the upright
    tool's reach was given up (paper-2, 2026-12-07). Leaning forward (GraspConfig.
    max_reach_lean) the tool takes it, and holds it lifted."""
    o = CAT.objects[name]
    h = SimHarness(
        [PlacedObject(name, (x, 0.0, TABLE_HEIGHT + o.size[2] / 2 + 0.001), yaw=0.15)],
        table_boxes(length=0.8),
    )
    h.settle(0.3)
    z0 = h.object_pos(name)[2]
    gs = grasp_from_ground_truth(h, name, TABLE_HEIGHT, "vertical")  # the bowl, far side
    upright = replace(CFG, grasp=replace(CFG.grasp, max_reach_lean=0.0))
    with pytest.raises(GraspRejected, match="too_far"):
        plan_grasp(GEOM, upright, gs.position_base, "vertical", gs.yaw, gs.width)
    plan = plan_grasp(GEOM, CFG, gs.position_base, "vertical", gs.yaw, gs.width)
    assert plan.reach.pitch < math.pi / 2 - 0.05  # leaning forward
    prim = h.run(GraspPrimitive(GEOM, CFG, plan), KP, KD, timeout=30.0)
    assert prim.status is Status.SUCCEEDED, prim.reason
    assert _held_for(h, name, z0, 3.0) >= 0.10
    _assert_honest(h)


def test_a_spoon_held_at_its_bowl_does_not_creep_round_in_the_fingers():
    """Held still in the carry posture for 20 s, the spoon pinched across its bowl stays
    put: the pads' static friction holds its handle's 0.012 N m. With the pads' contact
    softer (solimp 0.95-0.99), friction crept: it turned 1-2 deg/s about the grip, rolled
    onto its edge and was lost after 14 s; the same creep lost it in full-stack trials
    during walks and places (2026-12-07: 9 of 22 spoon grasps that held)."""
    o = CAT.objects["spoon"]
    h = SimHarness([PlacedObject("spoon", (0.33, 0.0, TABLE_HEIGHT + o.size[2] / 2 + 0.001),
                                 yaw=0.4)], table_boxes(length=0.7))  # fmt: skip
    h.settle(0.3)
    prim = _grasp(h, "spoon", TABLE_HEIGHT, "vertical")
    assert prim.status is Status.SUCCEEDED, prim.reason
    carry = resolve_postures(GEOM, CFG)["carry"]
    move = h.run(PostureMove(GEOM, CFG, carry, held_across=True, monitor=prim.monitor), KP, KD)
    assert move.status is Status.SUCCEEDED, move.reason
    site = mujoco.mj_name2id(h.model, mujoco.mjtObj.mjOBJ_SITE, "gripper_tcp")
    obj = np.zeros(9)
    mujoco.mju_quat2Mat(obj, h.object_quat("spoon"))
    start = h.data.site_xmat[site].reshape(3, 3).T @ obj.reshape(3, 3)
    for _ in range(10):
        h.settle(2.0)
        ob = h.observation()
        prim.monitor.update(ob.t, ob.gripper_gap, ob.gripper_effort)
    assert prim.monitor.holding
    assert _turned_in_grip(h, "spoon", start) < 5.0
    _assert_honest(h)


def _body_requests(h: SimHarness) -> list[tuple[float, BodyPoseRequest]]:
    """From now on, every body pose request the harness gets, with its sim time."""
    requests: list[tuple[float, BodyPoseRequest]] = []
    request_body = h.request_body

    def record(req: BodyPoseRequest) -> None:
        requests.append((float(h.data.time), req))
        request_body(req)

    h.request_body = record  # type: ignore[method-assign]
    return requests


def test_a_grasp_ends_once_the_trunk_is_sent_back_and_the_object_stays_held():
    # a crouched floor grasp sends the trunk back to its stance as its last step and ends
    # (the carry posture move follows while the trunk rises): 1 s a grasp not waited
    name = "rubiks_cube"
    o = CAT.objects[name]
    h = SimHarness([PlacedObject(name, (0.36, 0.03, o.size[2] / 2 + 0.001), yaw=0.4)])
    h.settle(0.3)
    z0 = h.object_pos(name)[2]
    requests = _body_requests(h)
    g = _grasp(h, name, 0.0, "vertical")
    assert g.status is Status.SUCCEEDED, g.reason
    assert requests[0][1].z_offset < -0.01  # (it crouched)
    t_back, back = requests[-1]
    assert (back.x_offset, back.y_offset, back.z_offset) == (0.0, 0.0, 0.0)
    assert g.t_end - t_back < 0.05
    assert _held_for(h, name, z0, 2.0) >= 0.10
    assert g.monitor.holding


# object, where it lies, deposit container (its size and walls from configs/house.toml)
# (place yaw pi/2: the fingers close along x, so the marker lies along the pencil case)
PLACES = [
    ("brick", 0.0, "green_box", 0.55, None),
    ("rubiks_cube", 0.0, "black_box", 0.55, None),
    ("mug", TABLE_HEIGHT, "small_box", 0.50, None),
    ("tomato_soup_can", TABLE_HEIGHT, "tray", 0.50, None),
    ("marker", TABLE_HEIGHT, "pencil_case", 0.46, math.pi / 2),
]


def _grasped_for_place(name: str, surface: float, place: str, cx: float, yaw: float | None):
    """The object grasped from ``surface`` 31 cm ahead, beside ``place``'s container ``cx``
    ahead, and a place plan over the container's near half: (harness, grasp, plan)."""
    o = CAT.objects[name]
    boxes = container_boxes(place, cx, surface)
    if surface > 0:
        boxes += table_boxes(length=0.7)
    h = SimHarness(
        [PlacedObject(name, (0.31, 0.0, surface + o.size[2] / 2 + 0.001), yaw=0.2)], boxes
    )
    h.settle(0.3)
    g = _grasp(h, name, surface, "vertical")
    assert g.status is Status.SUCCEEDED, g.reason
    # the object's hang below the tool centre: known from the grasp height over the surface
    hang = float(h.tcp_world()[2] - (h.object_pos(name)[2] - o.size[2] / 2))
    ix, _, height = container_inner(place, cx)
    target = np.array([cx - 0.6 * ix, 0.0, surface + height])
    q = h.observation().q_arm
    plan = plan_place(GEOM, CFG, h.world_to_base(target), q, hang, g.body, yaw=yaw)
    return h, g, plan


def _assert_in_container(h: SimHarness, name: str, surface: float, place: str, cx: float) -> None:
    h.settle(1.0)
    ix, iy, height = container_inner(place, cx)
    end = h.object_pos(name)
    assert abs(end[0] - cx) < ix and abs(end[1]) < iy, f"{name} ended at {end}"
    # the judge's region: the inner footprint, from the inner floor to 15 cm above the rim
    assert surface < end[2] < surface + height + 0.15


def test_a_spoon_held_at_its_bowl_is_placed_by_its_middle():
    # the spoon is grasped at its bowl, 6.5 cm from its middle; placed by the tool centre
    # its handle lay on the pencil case's rim and rocked (0.14-0.2 rad/s, the judge's rest
    # bound 0.2) in five tidy-up trials. Placed by its middle it lies flat and still.
    surface, place, cx, name = TABLE_HEIGHT, "pencil_case", 0.46, "spoon"
    o = CAT.objects[name]
    boxes = container_boxes(place, cx, surface) + table_boxes(length=0.7)
    for yaw in (0.2, -0.3):
        pos = (0.31, 0.0, surface + o.size[2] / 2 + 0.001)
        h = SimHarness([PlacedObject(name, pos, yaw=yaw)], boxes)
        h.settle(0.3)
        gs = grasp_from_ground_truth(h, name, surface, "vertical")
        middle = h.world_to_base(h.object_pos(name))  # (perception's GraspGoal.center)
        plan = plan_grasp(GEOM, CFG, gs.position_base, gs.approach, gs.yaw, gs.width)
        g = h.run(GraspPrimitive(GEOM, CFG, plan), KP, KD, timeout=30.0)
        assert g.status is Status.SUCCEEDED, g.reason
        held = held_offset(GEOM, plan.reach, middle - gs.position_base)
        assert np.linalg.norm((middle - gs.position_base)[:2]) > 0.05  # (the bowl)
        hang = float(h.tcp_world()[2] - (h.object_pos(name)[2] - o.size[2] / 2))
        _, _, height = container_inner(place, cx)
        target = np.array([cx, 0.0, surface + height])
        q = h.observation().q_arm
        pp = plan_place(GEOM, CFG, h.world_to_base(target), q, hang, g.body, math.pi / 2, held)
        p = h.run(PlacePrimitive(GEOM, CFG, pp, monitor=g.monitor, body=g.body), KP, KD, 40.0)
        assert p.status is Status.SUCCEEDED, p.reason
        h.settle(1.0)
        turning = 0.0
        for _ in range(10):
            h.settle(0.1)
            turning = max(turning, float(np.linalg.norm(h.data.body(f"obj/{name}").cvel[:3])))
        end = h.object_pos(name)
        # (by the tool centre: 6.5 cm off, 3.7 cm up on the rim, turning 0.14-0.2 rad/s)
        assert math.dist(end[:2], target[:2]) < 0.02, f"ended at {end - target}"
        assert end[2] < surface + 0.02, "not lying on the pencil case's bottom"
        assert turning < 0.05, f"still turning at {turning:.2f} rad/s"
        _assert_honest(h)


@pytest.mark.parametrize(("name", "surface", "place", "cx", "yaw"), PLACES)
def test_place_into_region(name, surface, place, cx, yaw):
    h, g, plan = _grasped_for_place(name, surface, place, cx, yaw)
    requests = _body_requests(h)
    p = h.run(PlacePrimitive(GEOM, CFG, plan, monitor=g.monitor, body=g.body), KP, KD, timeout=40.0)
    assert p.status is Status.SUCCEEDED, p.reason
    # the trunk's way back to its stance is the place's last request, not waited for
    t_back, back = requests[-1]
    assert (back.x_offset, back.y_offset, back.z_offset) == (0.0, 0.0, 0.0)
    assert p.t_end - t_back < 0.05
    _assert_in_container(h, name, surface, place, cx)
    assert p.t_end - p.t_start < 20.0
    _assert_honest(h)


@pytest.mark.parametrize("which", ["left", "right", "top"])
def test_open_drawer(which):
    world = drawer_world(which)
    h = SimHarness(world=world)
    h.settle(0.3)
    handle = h.world_to_base(h.data.body(world.drawer_handles[which]).xpos)
    # the cabinet faces the robot: its drawers slide towards -x of the body
    plan = plan_drawer(GEOM, CFG, handle, np.array([-1.0, 0.0, 0.0]), 0.15)
    prim = h.run(DrawerPrimitive(GEOM, CFG, plan), KP, KD, timeout=40.0)
    assert prim.status is Status.SUCCEEDED, prim.reason
    h.settle(0.5)
    opened = h.data.qpos[world.model.joint(world.drawer_joints[which]).qposadr[0]]
    assert opened >= 0.15
    assert math.isfinite(opened)
    _assert_honest(h)


def test_tools_drawer_opens_24cm_in_one_pull_from_the_tasks_long_pull_stance():
    """The task's one long pull (behavior DrawerConfig.long_pull_standoff, long_pull):
    from 0.59 m the arm grips farther out and pulls the tools' drawer to its 24 cm."""
    from quadmanip.common import robot_description as rd
    from quadmanip.common.config import load_config
    from quadmanip.services.behavior.config import BehaviorConfig

    dc = load_config(BehaviorConfig, "behavior").drawers
    world = drawer_world("top", handle_arm_x=dc.long_pull_standoff - float(rd.arm_mount()[0]))
    h = SimHarness(world=world)
    h.settle(0.3)
    handle = h.world_to_base(h.data.body(world.drawer_handles["top"]).xpos)
    assert handle[0] == pytest.approx(dc.long_pull_standoff, abs=0.005)
    plan = plan_drawer(GEOM, CFG, handle, np.array([-1.0, 0.0, 0.0]), dc.long_pull)
    prim = h.run(DrawerPrimitive(GEOM, CFG, plan), KP, KD, timeout=40.0)
    assert prim.status is Status.SUCCEEDED, prim.reason
    h.settle(0.5)
    opened = h.data.qpos[world.model.joint(world.drawer_joints["top"]).qposadr[0]]
    assert opened >= dc.tool_drawer_open - 0.005
    _assert_honest(h)


def test_place_tool_into_open_drawer():
    """Paper order (Section 7.2): open the drawer first, then put a tool in it."""
    world = drawer_place_world("padlock")
    h = SimHarness(world=world)
    h.settle(0.3)
    handle = h.world_to_base(h.data.body(world.drawer_handles["top"]).xpos)
    plan = plan_drawer(GEOM, CFG, handle, np.array([-1.0, 0.0, 0.0]), 0.15)
    assert h.run(DrawerPrimitive(GEOM, CFG, plan), KP, KD, 40.0).status is Status.SUCCEEDED
    carry = resolve_postures(GEOM, CFG)["carry"]
    assert h.run(PostureMove(GEOM, CFG, carry), KP, KD, 20.0).status is Status.SUCCEEDED
    g = _grasp(h, "padlock", 0.20, "vertical")
    assert g.status is Status.SUCCEEDED, g.reason
    hang = float(h.tcp_world()[2] - (h.object_pos("padlock")[2] - 0.012))
    mouth, front_top = drawer_mouth(h, world, "top")
    target = h.world_to_base(np.array([mouth[0], mouth[1], front_top]))
    pplan = plan_place(GEOM, CFG, target, h.observation().q_arm, hang, g.body)
    p = h.run(PlacePrimitive(GEOM, CFG, pplan, monitor=g.monitor, body=g.body), KP, KD, 40.0)
    assert p.status is Status.SUCCEEDED, p.reason
    h.settle(1.0)
    assert in_region(h, world, "drawer_top", "padlock")
    _assert_honest(h)


@pytest.mark.parametrize("short", [0.015, 0.025])
def test_a_standing_sugar_box_put_into_the_trays_near_row_across_stays_standing(short):
    # seed-132 and seed-133: the sugar box, grasped from its top standing on the floor and
    # released in the tray's near row with its 9 cm along the heading (1.2 cm from the
    # near wall), landed on the wall's top and toppled off the deposit table. Turned
    # across (behavior's tray across_above) it stands, released ``short`` m nearer the
    # robot than asked. (Along, in this scene, 4 of 6 such releases toppled.) The tray
    # stands on a 10 cm slab here: the robot cannot walk from the floor to the table.
    name, slab, cx = "sugar_box", 0.10, 0.545
    o = CAT.objects[name]
    boxes = container_boxes("tray", cx, slab) + [
        Box("slab", (0.80, 0.0, slab / 2), (0.40, 0.40, slab / 2))
    ]
    h = SimHarness([PlacedObject(name, (0.34, 0.0, o.size[2] / 2 + 0.001), yaw=0.1)], boxes)
    h.settle(0.3)
    middle = h.world_to_base(h.object_pos(name))
    top = middle + np.array([0.0, 0.0, o.size[2] / 2 - 0.03])  # (perception's, 3 cm down)
    plan = plan_grasp(GEOM, CFG, top, "vertical", 0.1, o.size[1])
    g = h.run(GraspPrimitive(GEOM, CFG, plan), KP, KD, timeout=30.0)
    assert g.status is Status.SUCCEEDED, g.reason
    held = held_offset(GEOM, plan.reach, middle - top)
    hang = float(h.tcp_world()[2] - (h.object_pos(name)[2] - o.size[2] / 2))
    near_row = np.array([cx - 0.085 - short, 0.0, slab + 0.025])  # (rim height)
    q = h.observation().q_arm
    pp = plan_place(GEOM, CFG, h.world_to_base(near_row), q, hang, g.body, math.pi / 2, held)
    p = h.run(PlacePrimitive(GEOM, CFG, pp, monitor=g.monitor, body=g.body), KP, KD, 40.0)
    assert p.status is Status.SUCCEEDED, p.reason
    h.settle(2.0)
    up = h.data.body(f"obj/{name}").xmat.reshape(3, 3)[2, 2]
    end = h.object_pos(name)
    assert abs(up) > 0.95, f"toppled: the cosine of its axis to the vertical is {up:.2f}"
    ix, iy, _ = container_inner("tray", cx)
    assert abs(end[0] - cx) < ix and abs(end[1]) < iy, f"ended at {end}"
    _assert_honest(h)


def test_place_clears_an_object_left_standing_between_the_fingers():
    """Released low with a short retract (the can sets down on the tray's floor and its top
    stays between the open fingers), the empty check closes on it: the fingers open, rise
    and check again, and the place succeeds with the can in the tray (paper-5's soup can
    failed object_stuck here and was carried on)."""
    name, place, cx = "tomato_soup_can", "tray", 0.50
    h, g, plan = _grasped_for_place(name, TABLE_HEIGHT, place, cx, None)
    r = plan.release
    low = CFG.grasp.place_release_z  # the can's bottom at the rim when the fingers open
    plan.release = ArmTarget(r.x, r.z - low, r.pitch, r.roll)
    plan.retract = ArmTarget(r.x, r.z - low + 0.01, r.pitch, r.roll)
    p = h.run(PlacePrimitive(GEOM, CFG, plan, monitor=g.monitor, body=g.body), KP, KD, timeout=40)
    stages = [text for _, text in p.progress.log]
    assert "place: clear the fingers" in stages  # the first check did close on the can
    assert p.status is Status.SUCCEEDED, p.reason
    _assert_in_container(h, name, TABLE_HEIGHT, place, cx)
