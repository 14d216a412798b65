"""Scenarios: deterministic, collision-free, resting; paper-1..5 hold Table 4's lists."""

from __future__ import annotations

import itertools
import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from quadmanip.common import robot_description as rd
from quadmanip.sim.scenarios import (
    CLEARANCE,
    DROP_GAP,
    N_OBJECTS,
    TABLE_REACH_BAND,
    generate,
    get_scenario,
    object_contacts,
    paper_scenario,
)
from quadmanip.sim.world import build_world, load_catalogue

pytestmark = pytest.mark.unit

_SURFACES = build_world(None, robot=False).surfaces

# Table 4, translated by hand to catalogue names ("driver" = screwdriver, "cracker" =
# cracker box, "sugar" = sugar box, "tomato soup" = tomato soup can).
TABLE_4 = {
    1: {"rubiks_cube", "clamp", "marker", "cracker_box", "spoon", "lego", "coffee_can",
        "baseball", "bowl", "cup"},
    2: {"tennis_ball", "bowl", "screwdriver", "padlock", "spoon", "sugar_box",
        "tomato_soup_can", "toy_gun", "mug", "brick"},
    3: {"tennis_ball", "mug", "screwdriver", "toy_gun", "padlock", "coffee_can",
        "rubiks_cube", "tomato_soup_can", "bowl", "brick"},
    4: {"tennis_ball", "bowl", "padlock", "lego", "marker", "cracker_box", "brick", "mug",
        "tomato_soup_can", "rubiks_cube"},
    5: {"marker", "mug", "tomato_soup_can", "rubiks_cube", "clamp", "screwdriver", "cup",
        "bowl", "coffee_can", "baseball"},
}  # fmt: skip


def _check_placed_at_rest_and_free(scenario):
    """Poses lie on their surfaces, nothing touches anything, and 0.5 s of physics with the
    passive robot leaves every object where it was."""
    cat = load_catalogue()
    world = build_world(scenario, robot=True)
    surfaces = {s.name: s for s in world.surfaces}
    for p in scenario.objects:
        s = surfaces[p.surface]
        obj = cat.objects[p.name]
        assert s.min[0] <= p.position[0] <= s.max[0] and s.min[1] <= p.position[1] <= s.max[1]
        assert p.position[2] == pytest.approx(s.z + obj.size[2] / 2 + DROP_GAP)
        assert np.linalg.norm(p.quat) == pytest.approx(1.0)
    data = world.initial_data()
    assert object_contacts(world.model, data) == []
    # Not inside the robot's start footprint.
    rs = world.house.robot_start
    for p in scenario.objects:
        r = cat.objects[p.name].footprint_radius
        assert (abs(p.position[0] - rs.position[0]) > rs.footprint[0] / 2 + r - 1e-9) or (
            abs(p.position[1] - rs.position[1]) > rs.footprint[1] / 2 + r - 1e-9
        )
    ids = [world.object_body_ids[n] for n in world.object_names]
    start = data.xpos[ids].copy()
    for _ in range(500):
        mujoco.mj_step(world.model, data)
    moved = np.linalg.norm(data.xpos[ids] - start, axis=1)
    assert moved.max() < 0.01, dict(zip(world.object_names, moved.round(4), strict=True))
    return world


def test_same_seed_same_world_different_seed_different_world():
    a, b, c = generate(11), generate(11), generate(12)
    assert a == b
    assert a.object_names != c.object_names or any(
        pa.position != pc.position for pa, pc in zip(a.objects, c.objects, strict=True)
    )
    assert get_scenario(11) == a == get_scenario("seed-11") == get_scenario("11")


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_generated_scenarios_are_ten_objects_collision_free(seed):
    scenario = generate(seed)
    names = scenario.object_names
    assert len(names) == N_OBJECTS == 10 and len(set(names)) == 10
    assert set(names) <= set(load_catalogue().names)
    kinds = {s.name: s.kind for s in build_world(None, robot=False).surfaces}
    assert {kinds[p.surface] for p in scenario.objects} <= {"floor", "table"}
    _check_placed_at_rest_and_free(scenario)


def test_seeds_use_floor_and_tables_and_all_objects():
    """Across seeds the generator uses both kinds of surface and every object eventually."""
    kinds, seen = set(), set()
    surf_kind = {s.name: s.kind for s in build_world(None, robot=False).surfaces}
    for seed in range(8):
        sc = generate(seed, verify=False)
        kinds |= {surf_kind[p.surface] for p in sc.objects}
        seen |= set(sc.object_names)
    assert kinds == {"floor", "table"}
    assert len(seen) >= 16


@pytest.mark.parametrize("trial", [1, 2, 3, 4, 5])
def test_paper_scenarios_hold_table_4_lists(trial):
    scenario = get_scenario(f"paper-{trial}")
    assert scenario.name == f"paper-{trial}"
    assert len(scenario.objects) == 10
    assert set(scenario.object_names) == TABLE_4[trial]
    assert scenario == paper_scenario(trial)  # deterministic


def test_paper_scenario_is_collision_free_with_the_robot():
    world = _check_placed_at_rest_and_free(get_scenario("paper-2"))
    # The robot starts in the living room and the objects are spread over both rooms.
    base = world.initial_data().xpos[world.model.body(rd.BASE_BODY).id]
    assert world.house.room_at(base[0], base[1]) == "living_room"


def test_empty_scenario_is_the_house_without_objects():
    scenario = get_scenario("empty")
    assert scenario.objects == ()
    world = build_world(scenario)
    assert world.object_names == ()
    assert not any(world.model.body(i).name.startswith("obj/") for i in range(world.model.nbody))


def test_unknown_scenario_is_an_error():
    with pytest.raises(KeyError):
        get_scenario("paper-9")
    with pytest.raises(KeyError):
        get_scenario("kitchen")


def test_yaw_only_orientations():
    for p in generate(5, verify=False).objects:
        w, x, y, z = p.quat
        assert x == 0.0 and y == 0.0
        assert math.isclose(w * w + z * z, 1.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**31 - 1))
def test_any_seed_gives_spaced_objects_on_their_surfaces(seed):
    """For any seed, footprints never overlap and every object lies fully on its surface."""
    cat = load_catalogue()
    scenario = generate(seed, verify=False)
    surfaces = {s.name: s for s in _SURFACES}
    for p in scenario.objects:
        s, r = surfaces[p.surface], cat.objects[p.name].footprint_radius
        assert s.min[0] + r <= p.position[0] + 1e-9 and p.position[0] - 1e-9 <= s.max[0] - r
        assert s.min[1] + r <= p.position[1] + 1e-9 and p.position[1] - 1e-9 <= s.max[1] - r
    for a, b in itertools.combinations(scenario.objects, 2):
        ra, rb = cat.objects[a.name].footprint_radius, cat.objects[b.name].footprint_radius
        gap = math.dist(a.position[:2], b.position[:2]) - ra - rb
        assert gap >= CLEARANCE - 1e-9, (a.name, b.name, gap)


def _reach_depth(surface, p) -> float:
    """How far in from its table's reach edge an object's centre lies (m)."""
    x, y = p.position[:2]
    return {
        "south": y - surface.min[1],
        "north": surface.max[1] - y,
        "west": x - surface.min[0],
        "east": surface.max[0] - x,
    }[surface.reach_edge]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(min_value=0, max_value=2**31 - 1))
def test_table_objects_lie_within_reach_of_their_tables_free_side(seed):
    """Any seed and every paper trial: each table object within the band the arm reaches
    from the side of the table a robot can stand at (the house names it)."""
    surfaces = {s.name: s for s in _SURFACES}
    tables = [s for s in _SURFACES if s.kind == "table"]
    assert tables and all(t.reach_edge for t in tables)
    scenarios = [generate(seed, verify=False)] + [paper_scenario(t, verify=False) for t in TABLE_4]
    on_tables = 0
    for scn in scenarios:
        for p in scn.objects:
            s = surfaces[p.surface]
            if s.kind == "table":
                on_tables += 1
                assert 0.0 < _reach_depth(s, p) <= TABLE_REACH_BAND + 1e-9, (scn.name, p)
    assert on_tables > 0


def test_a_table_reach_edge_must_be_a_side():
    from quadmanip.sim.world.house import Table

    with pytest.raises(ValueError, match="reach_edge 'up'"):
        Table("t", "r", (0.0, 0.0), (1.0, 0.5), 0.4, (1, 1, 1, 1), reach_edge="up")


# ------------------------------------------------------------------ scenario files
def test_scenario_file_round_trip_and_robot_start(tmp_path):
    import dataclasses

    from quadmanip.sim.scenarios import load_scenario_file, save_scenario_file

    scn = dataclasses.replace(paper_scenario(2, verify=False), robot_start=(8.9, 1.4, 30.0))
    path = save_scenario_file(scn, tmp_path / "kitchen.toml")
    assert load_scenario_file(path) == scn
    assert get_scenario(str(path)) == scn
    world = build_world(scn)
    adr = rd.free_joint_qpos_index(world.model)
    q = world.initial_data().qpos
    assert q[adr : adr + 2] == pytest.approx([8.9, 1.4])
    assert 2 * math.atan2(q[adr + 6], q[adr + 3]) == pytest.approx(math.radians(30.0))


def test_scenario_obstacles_round_trip_and_stand_in_the_world(tmp_path):
    import mujoco
    from quadmanip.sim.scenarios import Obstacle, Scenario, load_scenario_file, save_scenario_file

    scn = Scenario("corridor", 0, (), obstacles=(Obstacle("box", (2.5, 1.2), (0.4, 0.3, 0.6)),))
    path = save_scenario_file(scn, tmp_path / "corridor.toml")
    assert load_scenario_file(path) == scn
    world = build_world(scn, robot=False)
    data = world.initial_data()
    g = world.model.geom("obstacle/box")
    assert world.model.geom_size[g.id] == pytest.approx([0.2, 0.15, 0.3])
    assert data.geom_xpos[g.id] == pytest.approx([2.5, 1.2, 0.3])
    # a fixed box: it stands on the floor and does not move
    for _ in range(50):
        mujoco.mj_step(world.model, data)
    assert data.geom_xpos[g.id] == pytest.approx([2.5, 1.2, 0.3])


def test_scenario_file_yaw_form(tmp_path):
    from quadmanip.sim.scenarios import load_scenario_file

    f = tmp_path / "one.toml"
    f.write_text('[[objects]]\nname = "mug"\nposition = [2.0, 1.0, 0.042]\nyaw = 90.0\n')
    scn = load_scenario_file(f)
    assert scn.name == "one" and scn.robot_start is None
    (p,) = scn.objects
    assert p.surface == "floor"
    assert p.quat == pytest.approx((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('[[objects]]\nname = "vase"\nposition = [1, 1, 0.1]\nyaw = 0', "unknown object 'vase'"),
        ('[[objects]]\nname = "mug"\nposition = [1, 1]\nyaw = 0', "position: expected 3"),
        ('[[objects]]\nname = "mug"\nposition = [1, 1, nan]\nyaw = 0', "finite"),
        ('[[objects]]\nname = "mug"\nposition = [1, 1, 0.1]', "exactly one of quat or yaw"),
        ('[[objects]]\nname = "mug"\nposition = [1, 1, 0.1]\nyaw = 0\ncolour = 1', "colour"),
        ('[[objects]]\nname = "mug"\nposition = [1, 1, 0.1]\nquat = [0, 0, 0, 0]', "zero"),
        (
            '[[objects]]\nname = "mug"\nposition = [1, 1, 0.1]\nyaw = 0\n'
            '[[objects]]\nname = "mug"\nposition = [2, 1, 0.1]\nyaw = 0',
            "placed twice",
        ),
        ("robot_start = [1, 2]", "robot_start: expected 3"),
        ("[[obstacles]]\ncenter = [1, 1]\nsize = [0.4, 0.4, 0]", "size must be positive"),
        ("[[obstacles]]\ncenter = [1, 1]\nsize = [0.4, 0.4, 0.6]\nmass = 3", "mass"),
        ("robots = 1", "unknown keys ['robots']"),
        ("name = ", "scenario file"),
    ],
)
def test_bad_scenario_files_say_what_is_wrong(tmp_path, text, why):
    from quadmanip.sim.scenarios import load_scenario_file

    f = tmp_path / "bad.toml"
    f.write_text(text + "\n")
    with pytest.raises(ValueError, match=why.replace("[", r"\[").replace("]", r"\]")):
        load_scenario_file(f)


@pytest.mark.parametrize("seed", [0, 1, 5, 11])
def test_short_scenarios_floor_then_table_in_the_living_room_distinct_categories(seed):
    cat = load_catalogue()
    s = get_scenario(f"short-{seed}x3")
    assert s.name == f"short-{seed}" and len(s.objects) == 3
    assert [p.surface for p in s.objects] == ["living_floor", "living_table", "living_floor"]
    assert len({cat.objects[p.name].category for p in s.objects}) == 3
    assert get_scenario(f"short-{seed}") == get_scenario(f"short-{seed}x2")
    assert get_scenario(f"short-{seed}") != get_scenario(f"short-{seed + 1}")
    table = next(t for t in _SURFACES if t.name == "living_table")
    r = cat.objects[s.objects[1].name].footprint_radius
    # within the arm's reach of the table's south edge (the room's side)
    assert table.reach_edge == "south"
    assert table.min[1] + r <= s.objects[1].position[1] <= table.min[1] + TABLE_REACH_BAND
    _check_placed_at_rest_and_free(s)


def test_short_scenario_bad_size_is_an_error():
    with pytest.raises(ValueError, match="1..6"):
        get_scenario("short-0x9")
