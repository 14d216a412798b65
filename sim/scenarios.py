"""Scenarios: which objects lie where when a trial starts (paper Section 7.3, Table 4).

A seed gives 10 of the 18 catalogue objects at random, collision-free, resting poses on the
floor areas and spawn tables of the house, drawers closed. The five trials of Table 4 are the
named scenarios ``paper-1`` … ``paper-5`` with exactly the paper's object lists (their poses
are seeded by the trial number). Same seed, same world: everything is drawn from one
``numpy.random.Generator`` in a fixed order.

Collision-free means: no object touches or penetrates furniture, walls, another object or
the robot (checked with ``mj_forward`` contacts on the built world), and none lies in the
robot's start footprint. Objects are placed resting: upright in their catalogue pose, turned
about z, their lowest point 1 mm above the surface.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from quadmanip.common.rotations import quat_from_yaw
from quadmanip.sim.world.house import HouseConfig, Surface, load_house
from quadmanip.sim.world.objects import Catalogue, load_catalogue

__all__ = [
    "PAPER_TRIALS",
    "Placement",
    "Scenario",
    "generate",
    "get_scenario",
    "load_scenario_file",
    "object_contacts",
    "paper_scenario",
    "save_scenario_file",
    "scenario_names",
    "short_scenario",
]

#: Table 4 of the paper, as printed ("driver" = screwdriver, "cracker" = cracker box, ...).
PAPER_TRIALS: dict[int, tuple[str, ...]] = {
    1: (
        "Rubik's cube",
        "clamp",
        "marker",
        "cracker",
        "spoon",
        "Lego",
        "coffee can",
        "baseball",
        "bowl",
        "cup",
    ),
    2: (
        "tennis ball",
        "bowl",
        "driver",
        "padlock",
        "spoon",
        "sugar",
        "tomato soup",
        "toy gun",
        "mug",
        "brick",
    ),
    3: (
        "tennis ball",
        "mug",
        "driver",
        "toy gun",
        "padlock",
        "coffee can",
        "Rubik's cube",
        "tomato soup",
        "bowl",
        "brick",
    ),
    4: (
        "tennis ball",
        "bowl",
        "padlock",
        "Lego",
        "marker",
        "cracker",
        "brick",
        "mug",
        "tomato soup",
        "Rubik's cube",
    ),
    5: (
        "marker",
        "mug",
        "tomato soup",
        "Rubik's cube",
        "clamp",
        "driver",
        "cup",
        "bowl",
        "coffee can",
        "baseball",
    ),
}

N_OBJECTS = 10
TABLE_PROBABILITY = 0.4  # share of objects put on tables (Figure 18: floor and table)
CLEARANCE = 0.04  # free space between objects' footprint circles (m), room for the gripper
TABLE_EDGE = 0.03  # keep objects this far inside a table's edge (m)
#: Table objects lie within this much of the table's ``reach_edge`` (m, centre to edge): the
#: arm grasps at most about 0.45 m ahead of the base, whose front stays out from under the
#: top. Farther in, no stance of this robot reaches them (paper-2's spoon lay 0.43 m in from
#: the living table's only free side and was never grasped); the paper's house put its
#: objects within the reach of its robot as well.
TABLE_REACH_BAND = 0.2
DROP_GAP = 0.001  # lowest point above the surface at placement (m)


@dataclass(frozen=True)
class Placement:
    """One object's initial pose: the surface it rests on and its world pose (quat wxyz)."""

    name: str
    surface: str
    position: tuple[float, float, float]
    quat: tuple[float, float, float, float]


@dataclass(frozen=True)
class Obstacle:
    """A fixed box standing on the floor that is not part of the house (a moved-in chest,
    a box left in the corridor): centre (x, y) and size (x, y, z) in metres. Scenarios use
    them to test navigation against what its map does not have."""

    name: str
    center: tuple[float, float]
    size: tuple[float, float, float]


@dataclass(frozen=True)
class Scenario:
    """A trial's initial world: name, seed, the placed objects and, optionally, where the
    robot starts (x, y in m, yaw in deg; ``None``: the house config's ``robot_start``) and
    fixed obstacles that are not part of the house."""

    name: str
    seed: int
    objects: tuple[Placement, ...]
    robot_start: tuple[float, float, float] | None = None
    obstacles: tuple[Obstacle, ...] = ()

    @property
    def object_names(self) -> tuple[str, ...]:
        """Catalogue names of the scenario's objects."""
        return tuple(p.name for p in self.objects)


def _in_rect(x: float, y: float, lo: tuple[float, float], hi: tuple[float, float]) -> bool:
    return lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]


class _Sampler:
    """Draws resting, spaced poses on the house's surfaces from one random generator."""

    def __init__(
        self,
        rng: np.random.Generator,
        house: HouseConfig,
        catalogue: Catalogue,
        surfaces: tuple[Surface, ...],
    ) -> None:
        self.rng, self.house, self.catalogue = rng, house, catalogue
        self.tables = [s for s in surfaces if s.kind == "table"]
        self.floors = [s for s in surfaces if s.kind == "floor"]
        areas = np.array([(s.max[0] - s.min[0]) * (s.max[1] - s.min[1]) for s in self.floors])
        self.floor_weights = areas / areas.sum()
        rs = house.robot_start
        self.robot_lo = (rs.position[0] - rs.footprint[0] / 2, rs.position[1] - rs.footprint[1] / 2)
        self.robot_hi = (rs.position[0] + rs.footprint[0] / 2, rs.position[1] + rs.footprint[1] / 2)

    def _free(self, x: float, y: float, r: float, placed: list[tuple[Placement, float]]) -> bool:
        lo = (self.robot_lo[0] - r, self.robot_lo[1] - r)
        hi = (self.robot_hi[0] + r, self.robot_hi[1] + r)
        if _in_rect(x, y, lo, hi):
            return False
        for p, r_other in placed:
            if math.hypot(x - p.position[0], y - p.position[1]) < r + r_other + CLEARANCE:
                return False
        return True

    def place(
        self,
        name: str,
        placed: list[tuple[Placement, float]],
        on_table: bool | None = None,
    ) -> Placement:
        """A free resting pose for ``name``; on a table or the floor as drawn, or as
        ``on_table`` says; on a table within ``TABLE_REACH_BAND`` of its reach edge."""
        obj = self.catalogue.objects[name]
        r = obj.footprint_radius
        forced = on_table
        for _ in range(500):
            on_table = self.rng.random() < TABLE_PROBABILITY if forced is None else forced
            if on_table:
                surf = self.tables[int(self.rng.integers(len(self.tables)))]
                margin = r + TABLE_EDGE
            else:
                surf = self.floors[int(self.rng.choice(len(self.floors), p=self.floor_weights))]
                margin = r
            u, v = self.rng.random(2)
            yaw = float(self.rng.uniform(-math.pi, math.pi))
            lo_x, hi_x = surf.min[0] + margin, surf.max[0] - margin
            lo_y, hi_y = surf.min[1] + margin, surf.max[1] - margin
            lo_x, hi_x, lo_y, hi_y = _reach_band(surf, lo_x, hi_x, lo_y, hi_y)
            if lo_x > hi_x or lo_y > hi_y:
                continue
            x, y = lo_x + u * (hi_x - lo_x), lo_y + v * (hi_y - lo_y)
            if not self._free(x, y, r, placed):
                continue
            z = surf.z + obj.size[2] / 2 + DROP_GAP
            return Placement(
                name, surf.name, (float(x), float(y), float(z)), tuple(quat_from_yaw(yaw).tolist())
            )
        raise RuntimeError(f"no free place for {name!r}")


def _reach_band(
    surf: Surface, lo_x: float, hi_x: float, lo_y: float, hi_y: float
) -> tuple[float, float, float, float]:
    """The part of ``[lo_x, hi_x] x [lo_y, hi_y]`` within ``TABLE_REACH_BAND`` of the
    surface's reach edge (all of it for a floor or a table without one)."""
    b = TABLE_REACH_BAND
    edge = surf.reach_edge
    if edge == "south":
        hi_y = min(hi_y, surf.min[1] + b)
    elif edge == "north":
        lo_y = max(lo_y, surf.max[1] - b)
    elif edge == "west":
        hi_x = min(hi_x, surf.min[0] + b)
    elif edge == "east":
        lo_x = max(lo_x, surf.max[0] - b)
    return lo_x, hi_x, lo_y, hi_y


def object_contacts(model: mujoco.MjModel, data: mujoco.MjData) -> list[tuple[str, str, float]]:
    """Contacts that involve a scenario object: (body1, body2, distance); after
    ``mj_forward`` on a freshly placed world this list must be empty."""
    out = []
    for i in range(data.ncon):
        c = data.contact[i]
        b1, b2 = model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]
        n1, n2 = model.body(b1).name, model.body(b2).name
        if n1.startswith("obj/") or n2.startswith("obj/"):
            out.append((n1, n2, float(c.dist)))
    return out


def _scenario(
    name: str,
    seed: int,
    objects: list[str],
    house: HouseConfig,
    catalogue: Catalogue,
    verify: bool,
    surfaces: tuple[str, ...] = (),
    on_table: list[bool] | None = None,
) -> Scenario:
    """``objects`` placed by one seeded sampler; only on the named ``surfaces`` if given,
    each on a table or not as ``on_table`` says if given."""
    from quadmanip.sim.world.builder import build_world
    from quadmanip.sim.world.house import build_house

    all_surfaces = build_house(mujoco.MjSpec(), house).surfaces
    if surfaces:
        unknown = set(surfaces) - {s.name for s in all_surfaces}
        if unknown:
            raise ValueError(f"unknown surfaces {sorted(unknown)}")
        all_surfaces = tuple(s for s in all_surfaces if s.name in surfaces)
    rng = np.random.default_rng(seed)
    sampler = _Sampler(rng, house, catalogue, all_surfaces)
    placed: list[tuple[Placement, float]] = []
    for i, obj in enumerate(objects):
        where = None if on_table is None else on_table[i]
        placed.append((sampler.place(obj, placed, where), catalogue.objects[obj].footprint_radius))
    scenario = Scenario(name, seed, tuple(p for p, _ in placed))
    if not verify:
        return scenario
    for _ in range(10):
        world = build_world(scenario, robot=True, house=house, catalogue=catalogue)
        data = world.initial_data()
        bad = {b.removeprefix("obj/") for c in object_contacts(world.model, data) for b in c[:2]}
        bad &= set(objects)
        if not bad:
            return scenario
        keep = [(p, r) for p, r in placed if p.name not in bad]
        for p, _ in placed:
            if p.name in bad:
                where = None if on_table is None else on_table[objects.index(p.name)]
                keep.append(
                    (
                        sampler.place(p.name, keep, where),
                        catalogue.objects[p.name].footprint_radius,
                    )
                )
        order = {n: i for i, n in enumerate(objects)}
        placed = sorted(keep, key=lambda pr: order[pr[0].name])
        scenario = Scenario(name, seed, tuple(p for p, _ in placed))
    raise RuntimeError(f"scenario {name!r}: could not place objects without contact")


def generate(
    seed: int,
    *,
    verify: bool = True,
    house: HouseConfig | None = None,
    catalogue: Catalogue | None = None,
) -> Scenario:
    """Ten of the 18 objects at random collision-free resting poses, deterministic in ``seed``."""
    house = house or load_house()
    catalogue = catalogue or load_catalogue()
    rng = np.random.default_rng([seed, 0x51])  # object choice, independent of the poses
    chosen = [str(n) for n in rng.choice(list(catalogue.names), N_OBJECTS, replace=False)]
    return _scenario(f"seed-{seed}", seed, chosen, house, catalogue, verify)


def paper_scenario(
    trial: int,
    *,
    verify: bool = True,
    house: HouseConfig | None = None,
    catalogue: Catalogue | None = None,
) -> Scenario:
    """Trial ``trial`` (1-5) of Table 4: exactly its ten objects, poses seeded by the trial."""
    house = house or load_house()
    catalogue = catalogue or load_catalogue()
    names = [catalogue.resolve(n) for n in PAPER_TRIALS[trial]]
    return _scenario(f"paper-{trial}", trial, names, house, catalogue, verify)


#: Where a short tidy-up's objects lie: the living room, next to the robot's start.
SHORT_SURFACES = ("living_floor", "living_table")


def short_scenario(
    seed: int,
    n_objects: int = 2,
    *,
    verify: bool = True,
    house: HouseConfig | None = None,
    catalogue: Catalogue | None = None,
) -> Scenario:
    """A short tidy-up (the demo, the default suite's end-to-end test): ``n_objects`` of
    different categories in the living room, the first on the floor, the second on the
    table (within reach of its south edge), alternating; deterministic in ``seed``."""
    house = house or load_house()
    catalogue = catalogue or load_catalogue()
    cats = sorted(set(catalogue.categories))
    if not 1 <= n_objects <= len(cats):
        raise ValueError(f"a short scenario has 1..{len(cats)} objects, not {n_objects}")
    rng = np.random.default_rng([seed, 0x5A])
    chosen: list[str] = []
    for cat in rng.permutation(cats)[:n_objects]:
        members = sorted(n for n, o in catalogue.objects.items() if o.category == cat)
        chosen.append(str(rng.choice(members)))
    on_table = [i % 2 == 1 for i in range(n_objects)]
    return _scenario(
        f"short-{seed}",
        seed,
        chosen,
        house,
        catalogue,
        verify,
        SHORT_SURFACES,
        on_table,
    )


def scenario_names() -> tuple[str, ...]:
    """The named scenarios."""
    return tuple(f"paper-{i}" for i in PAPER_TRIALS)


def _floats(value: object, n: int, what: str) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or len(value) != n:
        raise ValueError(f"{what}: expected {n} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError(f"{what}: expected {n} finite numbers, got {value!r}")
        out.append(float(v))
    return tuple(out)


def load_scenario_file(path: str | Path, catalogue: Catalogue | None = None) -> Scenario:
    """A scenario from a TOML file (see :func:`save_scenario_file` for the format).

    An object's orientation is ``quat`` (w, x, y, z) or ``yaw`` (deg, upright); names must be
    catalogue names, each at most once. Raises ``ValueError`` naming the bad entry.
    """
    path = Path(path)
    catalogue = catalogue or load_catalogue()
    try:
        doc = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"scenario file {path}: {exc}") from exc
    unknown = set(doc) - {"name", "seed", "robot_start", "objects", "obstacles"}
    if unknown:
        raise ValueError(f"scenario file {path}: unknown keys {sorted(unknown)}")
    start = doc.get("robot_start")
    robot_start = None if start is None else _floats(start, 3, f"{path}: robot_start")
    placements: list[Placement] = []
    for i, o in enumerate(doc.get("objects", [])):
        where = f"{path}: objects[{i}]"
        bad = set(o) - {"name", "surface", "position", "quat", "yaw"}
        if bad:
            raise ValueError(f"{where}: unknown keys {sorted(bad)}")
        name = o.get("name")
        if name not in catalogue.objects:
            raise ValueError(f"{where}: unknown object {name!r} (see configs/objects.toml)")
        if any(p.name == name for p in placements):
            raise ValueError(f"{where}: {name!r} placed twice")
        if ("quat" in o) == ("yaw" in o):
            raise ValueError(f"{where}: give exactly one of quat or yaw")
        if "quat" in o:
            q = np.asarray(_floats(o["quat"], 4, f"{where}: quat"))
            if np.linalg.norm(q) < 1e-9:
                raise ValueError(f"{where}: quat is zero")
            if abs(np.linalg.norm(q) - 1.0) > 1e-9:  # keep a saved unit quaternion exact
                q = q / np.linalg.norm(q)
            quat = tuple(float(v) for v in q)
        else:
            yaw = math.radians(_floats([o["yaw"]], 1, f"{where}: yaw")[0])
            quat = tuple(quat_from_yaw(yaw).tolist())
        pos = _floats(o.get("position"), 3, f"{where}: position")
        placements.append(Placement(name, str(o.get("surface", "floor")), pos, quat))  # type: ignore[arg-type]
    obstacles: list[Obstacle] = []
    for i, o in enumerate(doc.get("obstacles", [])):
        where = f"{path}: obstacles[{i}]"
        bad = set(o) - {"name", "center", "size"}
        if bad:
            raise ValueError(f"{where}: unknown keys {sorted(bad)}")
        size = _floats(o.get("size"), 3, f"{where}: size")
        if min(size) <= 0.0:
            raise ValueError(f"{where}: size must be positive, got {size}")
        center = _floats(o.get("center"), 2, f"{where}: center")
        obstacles.append(Obstacle(str(o.get("name", f"box{i}")), center, size))  # type: ignore[arg-type]
    return Scenario(
        name=str(doc.get("name", path.stem)),
        seed=int(doc.get("seed", 0)),
        objects=tuple(placements),
        robot_start=robot_start,  # type: ignore[arg-type]
        obstacles=tuple(obstacles),
    )


def save_scenario_file(scenario: Scenario, path: str | Path) -> Path:
    """Write ``scenario`` as TOML that :func:`load_scenario_file` reads back exactly."""

    def arr(v: tuple[float, ...]) -> str:
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    lines = [
        "# A quadmanip scenario: the world when a trial starts (sim/scenarios.py).",
        f"name = {json.dumps(scenario.name)}",
        f"seed = {int(scenario.seed)}",
    ]
    if scenario.robot_start is not None:
        lines.append(f"robot_start = {arr(scenario.robot_start)}  # x, y (m), yaw (deg)")
    for p in scenario.objects:
        lines += [
            "",
            "[[objects]]",
            f"name = {json.dumps(p.name)}",
            f"surface = {json.dumps(p.surface)}",
            f"position = {arr(p.position)}",
            f"quat = {arr(p.quat)}",
        ]
    for b in scenario.obstacles:
        lines += [
            "",
            "[[obstacles]]",
            f"name = {json.dumps(b.name)}",
            f"center = {arr(b.center)}",
            f"size = {arr(b.size)}",
        ]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def get_scenario(name_or_seed: str | int) -> Scenario:
    """``"paper-3"`` → Table 4 trial 3; ``17``, ``"17"`` or ``"seed-17"`` → ``generate(17)``;
    ``"short-4"`` → ``short_scenario(4)`` (``"short-4x3"``: three objects);
    ``"empty"`` → the house without objects (locomotion and navigation runs); a path ending
    in ``.toml`` → :func:`load_scenario_file`."""
    if isinstance(name_or_seed, int):
        return generate(name_or_seed)
    text = str(name_or_seed).strip()
    if text.endswith(".toml"):
        return load_scenario_file(text)
    if text == "empty":
        return Scenario(name="empty", seed=0, objects=())
    m = re.fullmatch(r"paper-(\d+)", text)
    if m and int(m.group(1)) in PAPER_TRIALS:
        return paper_scenario(int(m.group(1)))
    m = re.fullmatch(r"short-(\d+)(?:x(\d+))?", text)
    if m:
        return short_scenario(int(m.group(1)), int(m.group(2) or 2))
    m = re.fullmatch(r"(?:seed-)?(\d+)", text)
    if m:
        return generate(int(m.group(1)))
    raise KeyError(
        f"unknown scenario {name_or_seed!r} (use paper-1..5, a seed, short-SEED[xN], "
        "'empty' or a .toml file)"
    )
