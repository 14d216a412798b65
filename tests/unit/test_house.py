"""The house (paper Section 7, Figures 17-21): rooms, doorway, walls the LiDAR sees, reachable
tables, the six deposit places, the robot's start, cameras, 1 kHz physics."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.sim.world import build_world, load_house

pytestmark = pytest.mark.unit

ROBOT_WIDTH = 0.2505  # Table 1 body width (m)


@pytest.fixture(scope="module")
def world():
    return build_world(None, robot=True)


def _ray(model, data, origin, direction, exclude_body=-1) -> float:
    geomid = np.zeros(1, dtype=np.int32)
    d = np.asarray(direction, float)
    return mujoco.mj_ray(
        model, data, np.asarray(origin, float), d / np.linalg.norm(d), None, 1, exclude_body, geomid
    )


def test_two_rooms_of_about_5_by_4_m():
    house = load_house()
    assert len(house.rooms) >= 2
    for room in house.rooms:
        w, d = room.max[0] - room.min[0], room.max[1] - room.min[1]
        assert 4.0 <= max(w, d) <= 6.0 and 3.5 <= min(w, d) <= 5.0, room.name


def test_physics_at_1khz(world):
    assert world.model.opt.timestep == pytest.approx(0.001)


def test_walls_enclose_each_room_and_the_lidar_sees_them(world):
    """Horizontal rays at LiDAR height (0.35 m) from inside each room hit something within
    the house in every direction, and the walls are taller than the scan plane."""
    m = world.model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    house = world.house
    assert house.wall_height >= 0.5
    for room in house.rooms:
        c = [(room.min[0] + room.max[0]) / 2, (room.min[1] + room.max[1]) / 2 - 0.8, 0.35]
        for k in range(72):
            a = 2 * math.pi * k / 72
            dist = _ray(m, data, c, [math.cos(a), math.sin(a), 0.0])
            assert 0 < dist < 11.0, (room.name, k)


def test_doorway_is_wide_enough_for_the_robot(world):
    """Rays through the doorway at several heights pass into the next room; the free gap is
    at least 0.9 m, over three times the robot's width."""
    m = world.model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    living, kitchen = world.house.rooms[0], world.house.rooms[1]
    wall_x = (living.max[0] + kitchen.min[0]) / 2
    ys = np.arange(0.05, 3.95, 0.01)
    open_y = []
    for y in ys:
        hits = [_ray(m, data, [wall_x - 0.3, y, z], [1, 0, 0]) for z in (0.05, 0.3, 0.6)]
        if all(h < 0 or h > 0.6 for h in hits):
            open_y.append(y)
    assert open_y, "no doorway"
    gap = max(open_y) - min(open_y) + 0.01
    assert gap >= 0.9
    assert gap >= 3 * ROBOT_WIDTH
    assert max(np.diff(open_y)) < 0.011  # one contiguous doorway


def test_tables_are_within_the_arms_reach(world):
    spawn = [t for t in world.house.tables if t.spawn]
    assert len(spawn) >= 2
    for t in world.house.tables:
        assert 0.35 <= t.height <= 0.45, t.name
    surfaces = {s.name: s for s in world.surfaces}
    for t in spawn:
        assert surfaces[t.name].z == t.height


def test_six_deposit_places_with_regions(world):
    places = {r.place for r in world.regions}
    assert places == {"pencil_case", "tray", "drawer", "green_box", "black_box", "small_box"}
    drawer_regions = world.regions_for("drawer")
    assert {r.body for r in drawer_regions} == set(world.drawer_bodies.values())
    m = world.model
    data = world.initial_data()
    for r in world.regions:
        assert min(r.half_size[:2]) > 0.02 and r.half_size[2] > 0.005, r.name
        assert m.body_geomnum[m.body(r.support_body).id] > 0, r.name
        if r.body == "world":
            # A fixed region is the container's inside: its bottom on the container's bottom
            # plate (straight down from the rim), its rim at the top of the walls (a ray
            # across, just below the rim, meets a wall; just above, it does not).
            c = np.array(r.center)
            top = c + [0.0, 0.0, r.half_size[2]]
            dist = _ray(m, data, top, [0, 0, -1])
            assert dist > 0 and abs((top[2] - dist) - r.bottom) < 0.002, r.name
            assert 0 < _ray(m, data, top - [0, 0, 0.003], [1, 0, 0]) <= r.half_size[0] + 1e-3
            assert not 0 < _ray(m, data, top + [0, 0, 0.003], [1, 0, 0]) <= r.half_size[0] + 0.02


def test_robot_starts_on_the_floor_of_room_1(world):
    m = world.model
    data = world.initial_data()
    base = data.xpos[m.body(rd.BASE_BODY).id]
    living = world.house.rooms[0]
    assert living.min[0] < base[0] < living.max[0] and living.min[1] < base[1] < living.max[1]
    assert world.start_keyframe in ("lying", "sit", "home")
    key = rd.load_mujoco_model().key(world.start_keyframe).qpos
    assert base[2] == pytest.approx(key[2])
    adr = rd.joint_qpos_indices(m)
    np.testing.assert_allclose(data.qpos[adr], key[rd.joint_qpos_indices(rd.load_mujoco_model())])
    # Nothing but the floor touches the robot at the start.
    floor = m.geom("house/floor").id
    robot_bodies = set(range(m.body(rd.BASE_BODY).id, m.nbody)) & {
        b for b in range(m.nbody) if m.body_rootid[b] == m.body(rd.BASE_BODY).id
    }
    for i in range(data.ncon):
        c = data.contact[i]
        b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
        if b1 in robot_bodies or b2 in robot_bodies:
            assert floor in (c.geom1, c.geom2)


def test_snapshot_cameras_exist(world):
    names = {world.model.camera(i).name for i in range(world.model.ncam)}
    assert "overview" in names
    assert {f"room/{r.name}" for r in world.house.rooms} <= names
    assert {rd.FRONT_CAMERA, rd.GRIPPER_CAMERA} <= names


def test_house_is_cheap_to_render_and_collide(world):
    m = world.model
    static = [g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] == 0]
    allowed = {
        int(mujoco.mjtGeom.mjGEOM_BOX),
        int(mujoco.mjtGeom.mjGEOM_PLANE),
        int(mujoco.mjtGeom.mjGEOM_CYLINDER),
    }
    assert static and all(int(m.geom_type[g]) in allowed for g in static)
    assert all(not m.light_castshadow[i] for i in range(m.nlight))
    assert max(m.tex_width) <= 512


def test_nothing_but_physics_holds_objects_or_drawers():
    """Honest simulation: no mocap body, no weld or connect constraint on the house, the
    objects or the drawers; objects are free bodies and drawers are plain slide joints."""
    from quadmanip.sim.scenarios import get_scenario

    world = build_world(get_scenario("paper-1"), robot=True)
    m = world.model
    assert m.nmocap == 0
    robot_root = m.body(rd.BASE_BODY).id
    for e in range(m.neq):
        assert m.eq_type[e] not in (mujoco.mjtEq.mjEQ_CONNECT, mujoco.mjtEq.mjEQ_WELD)
        if m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT:  # e.g. the robot's finger coupling
            for j in (m.eq_obj1id[e], m.eq_obj2id[e]):
                if j >= 0:
                    assert m.body_rootid[m.jnt_bodyid[j]] == robot_root
    for name, bid in world.object_body_ids.items():
        assert m.body_parentid[bid] == 0, name
        assert m.body_jntnum[bid] == 1
        assert m.jnt_type[m.body_jntadr[bid]] == mujoco.mjtJoint.mjJNT_FREE
        assert m.body_gravcomp[bid] == 0
    assert len(world.table_surfaces) == 2
