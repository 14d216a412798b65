"""The 18 objects of Section 7.1: YCB sizes and masses, categories, resting, real openings."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest
from quadmanip.common.rotations import quat_from_euler_xyz
from quadmanip.sim.world import build_world, load_catalogue
from quadmanip.sim.world.objects import add_object, object_parts

pytestmark = pytest.mark.unit

# Section 7.2: category examples -> deposit places (Figure 21).
PAPER_PLACES = {
    "marker": "pencil_case",
    "spoon": "pencil_case",
    "coffee_can": "tray",
    "sugar_box": "tray",
    "tomato_soup_can": "tray",
    "cracker_box": "tray",
    "screwdriver": "drawer",
    "clamp": "drawer",
    "padlock": "drawer",
    "baseball": "green_box",
    "tennis_ball": "green_box",
    "cup": "green_box",
    "brick": "green_box",
    "rubiks_cube": "black_box",
    "toy_gun": "black_box",
    "lego": "black_box",
    "bowl": "small_box",
    "mug": "small_box",
}

# A few YCB numbers written out independently of the catalogue (Calli et al. 2015 / brief).
YCB = {
    "cracker_box": ((0.16, 0.06, 0.21), 0.411),
    "sugar_box": ((0.09, 0.045, 0.175), 0.514),
    "tomato_soup_can": ((0.066, 0.066, 0.101), 0.349),
    "coffee_can": ((0.102, 0.102, 0.139), 0.414),
    "baseball": ((0.073, 0.073, 0.073), 0.148),
    "tennis_ball": ((0.065, 0.065, 0.065), 0.058),
    "bowl": ((0.159, 0.159, 0.053), 0.147),
    "mug": ((None, 0.080, 0.082), 0.118),
}


def body_bbox(model: mujoco.MjModel, body: int) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of all geoms of a body, in the body frame (from compiled geom AABBs)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for g in np.flatnonzero(model.geom_bodyid == body):
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        rot = rot.reshape(3, 3)
        c, h = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        for s in itertools.product((-1, 1), repeat=3):
            p = model.geom_pos[g] + rot @ (c + np.array(s) * h)
            lo, hi = np.minimum(lo, p), np.maximum(hi, p)
    return lo, hi


@pytest.fixture(scope="module")
def catalogue():
    return load_catalogue()


def test_catalogue_has_the_papers_18_objects_and_places(catalogue):
    assert set(catalogue.names) == set(PAPER_PLACES)
    for name, place in PAPER_PLACES.items():
        assert catalogue.place_of(name) == place, name
    assert set(catalogue.categories.values()) == {
        "pencil_case",
        "tray",
        "drawer",
        "green_box",
        "black_box",
        "small_box",
    }


def test_catalogue_matches_ycb_numbers(catalogue):
    for name, (size, mass) in YCB.items():
        obj = catalogue.objects[name]
        assert obj.mass == pytest.approx(mass, rel=0.01), name
        for got, want in zip(obj.size, size, strict=True):
            if want is not None:
                assert got == pytest.approx(want, abs=0.002), name


def test_built_objects_match_catalogue_size_and_mass(catalogue):
    spec = mujoco.MjSpec()
    for i, (name, obj) in enumerate(catalogue.objects.items()):
        add_object(spec.worldbody, name, obj, pos=(0.4 * i, 0.0, 0.5))
    model = spec.compile()
    for name, obj in catalogue.objects.items():
        b = model.body(f"obj/{name}").id
        lo, hi = body_bbox(model, b)
        np.testing.assert_allclose(hi - lo, obj.size, atol=0.002, err_msg=name)
        np.testing.assert_allclose((hi + lo) / 2, 0.0, atol=0.002, err_msg=f"{name} centre")
        assert model.body_mass[b] == pytest.approx(obj.mass, rel=0.01), name
        # A real body: positive inertia that obeys the triangle inequality.
        inertia = model.body_inertia[b]
        assert np.all(inertia > 0), name
        assert inertia.sum() >= 2 * inertia.max() - 1e-12, name
        assert model.jnt_type[model.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE


def test_vessels_are_several_convex_pieces(catalogue):
    spec = mujoco.MjSpec()
    for name in ("bowl", "mug", "cup"):
        add_object(spec.worldbody, name, catalogue.objects[name])
    model = spec.compile()
    for name in ("bowl", "mug", "cup"):
        n = np.count_nonzero(model.geom_bodyid == model.body(f"obj/{name}").id)
        assert n >= 9, name


def _settle_positions(world, data, seconds):
    m = world.model
    ids = [world.object_body_ids[n] for n in world.object_names]
    start = data.xpos[ids].copy()
    start_quat = data.xquat[ids].copy()
    vmax = 0.0
    for _ in range(int(seconds / m.opt.timestep)):
        mujoco.mj_step(m, data)
        vmax = max(vmax, float(np.abs(data.qvel).max()))
    return start, start_quat, data.xpos[ids].copy(), data.xquat[ids].copy(), vmax


def test_every_object_rests_on_floor_and_table_for_5s(catalogue):
    """All 18 objects on the floor and all 18 on the tables, in one model, 5 s of physics."""
    from quadmanip.sim.scenarios import DROP_GAP, Placement, Scenario

    by_length = sorted(catalogue.names, key=lambda n: -catalogue.objects[n].size[0])
    placements = []
    # Floor: a grid in the living room's open floor.
    for i, name in enumerate(by_length):
        x, y = 1.6 + 0.3 * (i % 9), 0.9 + 0.5 * (i // 9)
        z = catalogue.objects[name].size[2] / 2 + DROP_GAP
        placements.append(Placement(name, "floor", (x, y, z), (1.0, 0.0, 0.0, 0.0)))
    world0 = build_world(None, robot=False)
    tables = {s.name: s for s in world0.surfaces if s.kind == "table"}
    living, kitchen = tables["living_table"], tables["kitchen_table"]
    for i, name in enumerate(by_length):
        surf, k, cols = (living, i, 5) if i < 10 else (kitchen, i - 10, 4)
        dx = (surf.max[0] - surf.min[0]) / cols
        dy = (surf.max[1] - surf.min[1]) / 2
        x = surf.min[0] + dx * (k % cols + 0.5)
        y = surf.min[1] + dy * (k // cols + 0.5)
        z = surf.z + catalogue.objects[name].size[2] / 2 + DROP_GAP
        placements.append(Placement(name, surf.name, (x, y, z), (1.0, 0.0, 0.0, 0.0)))

    # Build the 36 bodies under distinct names: floor copies keep the catalogue name, table
    # copies get a "table_" prefix through a renamed catalogue.
    from dataclasses import replace

    objects = dict(catalogue.objects)
    objects.update({f"table_{n}": catalogue.objects[n] for n in catalogue.names})
    big = replace(catalogue, objects=objects)
    placements = [
        p if i < 18 else replace(p, name=f"table_{p.name}") for i, p in enumerate(placements)
    ]
    world = build_world(Scenario("rest-test", 0, tuple(placements)), robot=False, catalogue=big)
    data = world.initial_data()
    assert data.ncon == 0  # placed 1 mm above their surfaces, touching nothing
    start, q0, end, q1, vmax = _settle_positions(world, data, 5.0)
    assert vmax < 1.0, "no explosion"
    for i, name in enumerate(world.object_names):
        drop = start[i, 2] - end[i, 2]
        moved_xy = np.linalg.norm(end[i, :2] - start[i, :2])
        assert moved_xy < 0.01, (name, moved_xy)
        assert -0.001 < drop < DROP_GAP + 0.003, (name, drop)  # settles the gap, no sinking
        tilt = 2 * np.arccos(min(1.0, abs(float(np.dot(q0[i], q1[i])))))
        assert tilt < 0.1, (name, tilt)
    # Objects end at rest.
    assert np.abs(data.qvel).max() < 0.02


def _drop_ball(obj_name: str, catalogue) -> tuple[float, float, float]:
    """Drop a 1 cm marble 3 cm above the object's top centre; return its final (r, z) and
    the object's top height."""
    obj = catalogue.objects[obj_name]
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.001
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1])
    h = obj.size[2]
    add_object(spec.worldbody, obj_name, obj, pos=(0.0, 0.0, h / 2 + 0.0005))
    # The opening's axis: for a mug the body axis is shifted by half the handle reach.
    axis_x = -(obj.size[0] - obj.size[1]) / 2
    ball = spec.worldbody.add_body(name="marble", pos=[axis_x, 0.0, h + 0.03])
    ball.add_freejoint()
    ball.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.01, 0, 0], mass=0.005)
    model = spec.compile()
    data = mujoco.MjData(model)
    for _ in range(1500):
        mujoco.mj_step(model, data)
    p = data.body("marble").xpos
    return float(np.hypot(p[0] - axis_x, p[1])), float(p[2]), h


@pytest.mark.parametrize("name", ["bowl", "mug", "cup"])
def test_vessel_has_a_real_opening(name, catalogue):
    r, z, h = _drop_ball(name, catalogue)
    inner = catalogue.objects[name].size[1] / 2 - catalogue.objects[name].vessel.wall
    assert z < h - 0.02, f"marble should fall inside, below the rim (z={z:.3f}, rim={h:.3f})"
    assert r < inner


def test_solid_can_has_no_opening(catalogue):
    """Control for the opening test: on a solid can the marble stays on top."""
    _, z, h = _drop_ball("tomato_soup_can", catalogue)
    assert z > h


# --------------------------------------------------------------- pad friction per material
def test_pads_touch_objects_through_per_material_pairs(catalogue):
    """With the robot in the world every object geom has one explicit contact pair per
    finger pad, with the pad friction of the geom's material (a part may differ from its
    object: the screwdriver's steel shaft), the pad's softness and the larger condim; the
    pads cannot also touch the object dynamically, everything else still can."""
    from quadmanip.common import robot_description as rd
    from quadmanip.sim.scenarios import Placement, Scenario
    from quadmanip.sim.world.objects import OBJECT_CONAFFINITY, OBJECT_CONTYPE

    names = ("spoon", "tomato_soup_can", "screwdriver", "baseball")
    placements = tuple(
        Placement(
            n, "floor", (1.6 + 0.3 * i, 0.9, catalogue.objects[n].size[2] / 2 + 0.001), (1, 0, 0, 0)
        )
        for i, n in enumerate(names)
    )
    world = build_world(Scenario("pairs", 0, placements))
    m = world.model
    pads = [m.geom(p).id for p in rd.FINGER_PAD_GEOMS]
    pair_of = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])): i for i in range(m.npair)}
    floor = m.geom("house/floor").id

    def collides(g1: int, g2: int) -> bool:
        return bool(
            m.geom_contype[g1] & m.geom_conaffinity[g2]
            or m.geom_contype[g2] & m.geom_conaffinity[g1]
        )

    expected_pairs = 0
    for name in names:
        obj = catalogue.objects[name]
        mats = [g.material or obj.material for g in object_parts(obj)]
        geoms = np.flatnonzero(m.geom_bodyid == world.object_body_ids[name])
        assert len(geoms) == len(mats)
        for g, mat in zip(geoms, mats, strict=True):
            f = catalogue.pad_friction[mat]
            assert collides(g, floor) and not any(collides(g, p) for p in pads)
            for p in pads:
                i = pair_of[(p, int(g))]
                np.testing.assert_allclose(
                    m.pair_friction[i], [f.sliding, f.sliding, f.torsional, f.rolling, f.rolling]
                )
                assert m.pair_dim[i] == max(int(m.geom_condim[p]), obj.condim)
                np.testing.assert_allclose(m.pair_solref[i], m.geom_solref[p])
                np.testing.assert_allclose(m.pair_solimp[i], m.geom_solimp[p])
                expected_pairs += 1
        assert int(m.geom_contype[geoms[0]]) == OBJECT_CONTYPE
        assert int(m.geom_conaffinity[geoms[0]]) == OBJECT_CONAFFINITY
    assert m.npair == expected_pairs
    # the pads still touch the house (its own, generic pad friction)
    assert all(collides(p, floor) for p in pads)
    # a steel shaft is more slippery in the pads than the screwdriver's plastic handle
    shaft, handle = (
        catalogue.pad_friction[m].sliding
        for m in ("steel", catalogue.objects["screwdriver"].material)
    )
    assert shaft < handle
    # Without the robot there is nothing to pair: objects keep ordinary collision bits.
    bare = build_world(Scenario("pairs", 0, placements), robot=False).model
    assert bare.npair == 0
    assert set(bare.geom_contype[bare.geom_bodyid > 0].tolist()) <= {0, 1}


def test_pad_friction_values_are_those_of_a_real_gripper(catalogue):
    for mat, f in catalogue.pad_friction.items():
        assert 0.4 <= f.sliding <= 1.1, mat  # silicone on steel 0.5-0.7 ... on foam ~1
        assert 0.002 <= f.torsional <= 0.006, mat  # a contact patch of a few mm
        assert f.rolling <= 2e-4, mat
    f = catalogue.pad_friction
    assert f[catalogue.objects["spoon"].material].sliding <= 0.7  # steel
    assert f[catalogue.objects["tomato_soup_can"].material].sliding <= 0.6  # glossy can


# ------------------------------------------------------------------ thin spoon and cup
def _lowest_point(m: mujoco.MjModel, d: mujoco.MjData, body: int) -> float:
    """World z of the lowest point of a body's boxes and cylinders."""
    low = np.inf
    for g in np.flatnonzero(m.geom_bodyid == body):
        rot, c, size = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g], m.geom_size[g]
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            low = min(low, c[2] - float(np.abs(rot[2]) @ size))
        elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            az = abs(rot[2, 2])
            low = min(low, c[2] - size[1] * az - size[0] * np.sqrt(max(0.0, 1 - az * az)))
        else:
            raise AssertionError("thin objects are boxes and cylinders")
    return low


def _physics_spec() -> mujoco.MjSpec:
    from quadmanip.common import robot_description as rd

    spec, robot = mujoco.MjSpec(), rd.robot_spec()
    for attr in ("timestep", "integrator", "cone", "impratio"):
        setattr(spec.option, attr, getattr(robot.option, attr))
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], friction=[1, 0.005, 1e-4]
    )
    return spec


@pytest.mark.parametrize("name", ["spoon", "cup"])
def test_thin_shells_survive_drops(name, catalogue):
    """Dropped 20 cm (2 m/s) in any pose onto the floor or onto an 8 mm board (a tray's
    bottom), the thin spoon / cup comes to rest on top: nothing tunnels through the 1.2-2 mm
    pieces (MuJoCo's soft contacts sink ~3 mm at that speed, harmless against the thicker
    partner)."""
    obj = catalogue.objects[name]
    for board in (False, True):
        for euler in ((0, 0, 0), (180, 0, 0), (90, 0, 0), (30, 20, 10), (150, 40, 70)):
            spec = _physics_spec()
            top = 0.0
            if board:
                spec.worldbody.add_geom(
                    type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.2, 0.15, 0.004], pos=[0, 0, 0.304]
                )
                top = 0.308
            q = quat_from_euler_xyz(euler, degrees=True)
            add_object(spec.worldbody, name, obj, (0, 0, top + 0.2 + max(obj.size) / 2), q)
            m = spec.compile()
            d = mujoco.MjData(m)
            for _ in range(1500):
                mujoco.mj_step(m, d)
            low = _lowest_point(m, d, m.body(f"obj/{name}").id) - top
            assert -0.0005 < low < 0.08, (name, board, euler, low)


def _pad_rig(spec: mujoco.MjSpec, tcp: tuple[float, float, float]) -> None:
    """The robot's gripper on a fixed palm pointing down (fingers close along world y): the
    description's pads (size, offset, friction, softness, collision bits), finger slides,
    gap tendon, sync equality and gripper motor; dummy leg and arm joints so the actuator
    layer can drive it."""
    from quadmanip.common import robot_description as rd

    robot = rd.robot_spec()
    d5 = rd.arm_dimensions()["d5"]  # the tcp's offset from the palm along the approach
    palm = spec.worldbody.add_body(
        name="palm",
        pos=[tcp[0], tcp[1], tcp[2] + d5],
        quat=list(quat_from_euler_xyz((0, 90, 0), True)),
    )
    for side, sign in (("left", 1), ("right", -1)):
        name = f"gripper_{side}"
        rj = robot.joint(name)
        finger = palm.add_body(name=f"{name}_finger")
        finger.add_joint(
            name=name,
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[0, sign, 0],
            range=list(rj.range),
            armature=rj.armature,
            damping=rj.damping,
        )
        rb = robot.body(f"{name}_finger")
        finger.mass, finger.inertia, finger.explicitinertial = rb.mass, rb.inertia, True
        pad = robot.geom(f"{name}_pad")
        g = finger.add_geom(
            name=f"{name}_pad",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(pad.size),
            pos=list(pad.pos),
        )
        for attr in (
            "friction",
            "condim",
            "priority",
            "contype",
            "conaffinity",
            "solref",
            "solimp",
        ):
            setattr(g, attr, getattr(pad, attr))
    tendon = spec.add_tendon(name="gap")
    tendon.wrap_joint("gripper_left", 1.0)
    tendon.wrap_joint("gripper_right", 1.0)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_JOINT,
        name1="gripper_right",
        name2="gripper_left",
        objtype=mujoco.mjtObj.mjOBJ_JOINT,
        solref=[0.005, 1],
    )
    for i, name in enumerate(rd.LEG_JOINTS + rd.ARM_JOINTS):
        b = spec.worldbody.add_body(pos=[5 + i, 5, 1])
        b.add_joint(name=name, axis=[0, 1, 0])
        b.add_geom(
            type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.02, 0, 0], mass=1, contype=0, conaffinity=0
        )
        spec.add_actuator(
            name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT, ctrlrange=[-10, 10]
        )
    grip = robot.actuator("gripper")
    spec.add_actuator(
        name="gripper",
        target="gap",
        trntype=mujoco.mjtTrn.mjTRN_TENDON,
        ctrlrange=list(grip.ctrlrange),
    )
    spec.add_numeric(name="velocity_limits", data=list(robot.numeric("velocity_limits").data))


@pytest.mark.parametrize("name", ["cup", "spoon"])
def test_pads_squeezing_a_thin_wall_stop_at_it(name, catalogue):
    """The pads close (at the rated speed) on the cup's 1.2 mm wall 3 cm below its rim, or
    across the spoon bowl's 1.5 mm rim, at the gripper's full 40 N: they stop at the outside
    of the wall, sink less than half its thickness, and squeeze at the full force."""
    from quadmanip.common import robot_description as rd
    from quadmanip.sim.actuators import ActuatorConfig, ActuatorLayer
    from quadmanip.sim.world.objects import pad_contacts

    obj = catalogue.objects[name]
    spec = _physics_spec()
    if name == "cup":
        centre, wall, width = np.zeros(2), obj.vessel.wall, obj.size[1]
    else:  # the bowl's centre at the origin
        bowl = obj.parts[0]
        centre, wall, width = -np.asarray(bowl.pos[:2]), bowl.thickness, 2 * bowl.size[1]
    _pad_rig(spec, (0.0, 0.0, max(0.021, obj.size[2] - 0.03)))
    add_object(
        spec.worldbody,
        name,
        obj,
        (centre[0], centre[1], obj.size[2] / 2 + 0.0005),
        contact=catalogue.contact,
        pads=pad_contacts(spec, catalogue),
    )
    m = spec.compile()
    d = mujoco.MjData(m)
    act = ActuatorLayer(m, ActuatorConfig(), rd.LEG_JOINTS, rd.ARM_JOINTS, rd.GRIPPER_JOINTS)
    d.qpos[act.gripper.qpos] = 0.05  # open, 10 cm
    assert act.set_gripper_command(d.time, 0.0, 40.0)
    body = m.body(f"obj/{name}").id
    pads = {m.geom(p).id for p in rd.FINGER_PAD_GEOMS}
    sink = 0.0
    for _ in range(1500):
        act.apply(d)
        mujoco.mj_step(m, d)
        for c in d.contact[: d.ncon]:
            if {c.geom1, c.geom2} & pads and body in (
                m.geom_bodyid[c.geom1],
                m.geom_bodyid[c.geom2],
            ):
                sink = min(sink, c.dist)
    gap = act.gripper_gap(d)
    assert width - 0.01 < gap < width, gap  # at the outside of the (flared) wall
    assert -0.5 * wall < sink < 0.0, sink
    assert act.tau[act.gripper.act] == pytest.approx(-40.0)


@pytest.mark.parametrize("ball", ["baseball", "tennis_ball"])
def test_ball_dropped_into_the_thin_cup_stays_in(ball, catalogue):
    cup, b = catalogue.objects["cup"], catalogue.objects[ball]
    spec = _physics_spec()
    add_object(spec.worldbody, "cup", cup, (0, 0, cup.size[2] / 2 + 0.0005))
    add_object(spec.worldbody, ball, b, (0, 0, cup.size[2] + 0.2))
    m = spec.compile()
    d = mujoco.MjData(m)
    for _ in range(2000):
        mujoco.mj_step(m, d)
    rel = d.body(f"obj/{ball}").xpos - d.body("obj/cup").xpos
    assert np.hypot(rel[0], rel[1]) < 0.005 and rel[2] < cup.size[2] / 2
    assert d.body("obj/cup").xpos[2] == pytest.approx(cup.size[2] / 2, abs=0.002)  # upright
