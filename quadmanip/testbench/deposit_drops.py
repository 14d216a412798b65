"""Drop objects into a deposit place at its release slots and ask the judge (tooling).

The behavior service releases the n-th object put into a place at the place's n-th slot
(``configs/behavior.toml`` ``[deposits.*] slots``). Whether a slot layout keeps every
object in is physics, so this measures it without the robot: the first two objects stand
at rest on the place's bottom at their slots, the later ones are let go 1 cm above its
rim at theirs (the fingers open at the rim: ``release_height`` 0), each with a few
centimetres of release error and a small yaw, and after ``settle_s`` the judge says where
each one ended. It reads the house description, as the judge does; no service uses it.

    python -m quadmanip.testbench.deposit_drops tray coffee_can cracker_box tomato_soup_can

prints one line per permutation of the named objects and the count kept in.
"""

from __future__ import annotations

import argparse
import itertools
import math
import random
from collections.abc import Sequence

import mujoco
from quadmanip.common.config import CONFIG_DIR, load_config
from quadmanip.common.object_catalogue import load_catalogue
from quadmanip.common.places import load_places
from quadmanip.services.behavior.config import BehaviorConfig
from quadmanip.sim.judge import Judge
from quadmanip.sim.scenarios import Placement, Scenario
from quadmanip.sim.world.builder import build_world
from quadmanip.sim.world.house import load_house

__all__ = ["drop_into", "main"]

RELEASE_ERROR = 0.02  # m: uniform, each axis (the localisation error while placing: p95 ~1.4-6 cm)
YAW_ERROR = 0.3  # rad


def _release_points(place: str, n: int) -> list[tuple[float, float, float]]:
    """(x, y, rim z) of the first ``n`` release points of ``place``, as the task picks them."""
    cfg = load_config(BehaviorConfig, "behavior")
    dep = next(d for d in cfg.deposits.values() if d.place == place)
    spot = load_places(CONFIG_DIR / "maps" / "house.places.toml")[place]
    return [dep.release_point(spot, k) for k in range(n)]


def drop_into(
    place: str, names: Sequence[str], seed: int = 0, settle_s: float = 4.0
) -> dict[str, str]:
    """Where each of ``names`` ended (the judge's location) after being put into ``place``
    at its slots in that order."""
    house = load_house()
    box = next(c for c in house.containers if c.name == place)
    floor = 0.0 if box.on == "floor" else house.table(box.on).height
    bottom = floor + box.bottom
    sizes = load_catalogue().objects
    rng = random.Random(seed)
    placements = []
    for k, (name, (x, y, rim)) in enumerate(
        zip(names, _release_points(place, len(names)), strict=True)
    ):
        z = (bottom if k < 2 else rim + 0.01) + sizes[name].size[2] / 2
        yaw = rng.uniform(-YAW_ERROR, YAW_ERROR)
        placements.append(Placement(
            name, "drop",
            (x + rng.uniform(-RELEASE_ERROR, RELEASE_ERROR), y + rng.uniform(-RELEASE_ERROR, RELEASE_ERROR), z),
            (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
        ))  # fmt: skip
    world = build_world(Scenario(f"drop-{place}", seed, tuple(placements)), robot=False)
    model, data = world.model, world.initial_data()
    mujoco.mj_forward(model, data)
    judge = Judge(world)
    every = max(int(round(1.0 / (judge.config.track_rate * model.opt.timestep))), 1)
    steps = 0
    while data.time < settle_s:
        mujoco.mj_step(model, data)
        steps += 1
        if steps % every == 0:
            judge.track(data)
    report = judge.report(data)
    return dict(zip(report.objects, report.locations, strict=True))


def main(argv: list[str] | None = None) -> int:
    """Entry point: every order of the named objects into the place, a line each."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("place", help="a deposit place (tray, green_box, ...)")
    ap.add_argument("objects", nargs="+", help="catalogue names, put in in this order")
    ap.add_argument("--seeds", type=int, default=1, help="release errors drawn per order")
    args = ap.parse_args(argv)
    kept = total = 0
    for order in itertools.permutations(args.objects):
        for seed in range(args.seeds):
            where = drop_into(args.place, order, seed)
            ok = all(v == "in_place" for v in where.values())
            kept, total = kept + ok, total + 1
            print(("kept  " if ok else "LOST  ") + ", ".join(f"{k}: {v}" for k, v in where.items()))
    print(f"{kept} of {total} orders kept every object in {args.place}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
