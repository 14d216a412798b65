"""The 18 objects of Section 7.1: YCB sizes and masses, categories, resting, real openings."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest
from quadmanip.sim.world import build_world, load_catalogue
from quadmanip.sim.world.objects import add_object

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
