"""Draft a map's places file from the house description (tooling; reads the simulator's
world the way a person reads a floor plan, once per house).

Stand poses follow what the manipulation trials measured (``stack_trials``): containers
``PLACE_REACH`` ahead of the base, drawer handles ``HANDLE_STANDOFF`` ahead, table edges
``TABLE_EDGE_AHEAD`` ahead (plus a margin for the search posture, which looks from further
back). Floor zones get the side with the most room around it. Everything is expressed in
the map's frame through ``world_to_map``: the pose of the world in the map, which the
mapping run knows from where the robot started.
"""

from __future__ import annotations

import math

import numpy as np
from quadmanip.services.navigation.distance_field import DistanceField
from quadmanip.services.navigation.grid import Pose2, compose
from quadmanip.services.navigation.places import Place
from quadmanip.testbench.floor_plan import true_floor_plan
from quadmanip.testbench.stack_trials import HANDLE_STANDOFF, PLACE_REACH, TABLE_EDGE_AHEAD

__all__ = ["draft_places"]

SEARCH_MARGIN = 0.15  # the search posture looks from this much further back than a grasp
FLOOR_STANDOFF = 0.45  # stand this far outside a floor zone's edge
CABINET_STANDOFF = 0.9  # base to the cabinet front when looking at it


def _facing(target: tuple[float, float], heading: float, standoff: float) -> Pose2:
    return (
        target[0] - standoff * math.cos(heading),
        target[1] - standoff * math.sin(heading),
        heading,
    )


def draft_places(world_to_map: Pose2 = (0.0, 0.0, 0.0)) -> list[Place]:
    """Every place of the house, in the map frame given by ``world_to_map``."""
    from quadmanip.sim.world.builder import build_world

    world = build_world(None, robot=False)
    data = world.initial_data()
    plan = true_floor_plan()
    field = DistanceField(plan.mask, plan.geometry, max_distance=2.0)
    places: list[Place] = []

    def add(name: str, kind: str, stand: Pose2, target: tuple[float, float, float],
            size: tuple[float, float] = (0.0, 0.0), keepout: bool = False,
            moves: bool = False) -> None:  # fmt: skip
        s = compose(world_to_map, stand)
        t = compose(world_to_map, (target[0], target[1], 0.0))
        places.append(Place(name, kind, s, (t[0], t[1], target[2]), size, keepout=keepout,
                            moves=moves))  # fmt: skip

    def roomiest(cx: float, cy: float, hx: float, hy: float, standoff: float) -> Pose2:
        """Of the four sides of a rectangle, the stand pose facing its centre with the
        most clearance around it."""
        best: tuple[float, Pose2] | None = None
        for heading, reach in ((0.0, hx), (math.pi, hx), (math.pi / 2, hy), (-math.pi / 2, hy)):
            pose = _facing((cx, cy), heading, reach + standoff)
            clear = float(field.distance(np.array([pose[:2]]))[0])
            if best is None or clear > best[0]:
                best = (clear, pose)
        assert best is not None
        return best[1]

    for s in world.surfaces:
        cx, cy = (s.min[0] + s.max[0]) / 2, (s.min[1] + s.max[1]) / 2
        hx, hy = (s.max[0] - s.min[0]) / 2, (s.max[1] - s.min[1]) / 2
        if s.kind == "table":
            stand = roomiest(cx, cy, hx, hy, TABLE_EDGE_AHEAD + SEARCH_MARGIN)
            # its top lies above the LiDAR's plane, which sees only the legs
            add(s.name, "search_table", stand, (cx, cy, s.z), (2 * hx, 2 * hy), keepout=True)
        else:
            stand = roomiest(cx, cy, hx, hy, FLOOR_STANDOFF)
            add(s.name, "search_floor", stand, (cx, cy, 0.0), (2 * hx, 2 * hy))
    for t in world.house.tables:
        if t.spawn:
            continue
        # a table nobody searches (the deposit table): what slips from the fingers at a
        # deposit place lands on it, and is taken up from the room side (south)
        hy = t.size[1] / 2
        stand = _facing(t.center, math.pi / 2, hy + TABLE_EDGE_AHEAD + SEARCH_MARGIN)
        add(t.name, "table", stand, (*t.center, t.height), t.size)
    boxes = {c.name: c for c in world.house.containers}
    for r in world.regions:
        if r.body != "world":
            continue
        cx, cy, cz = r.center
        # containers on the deposit table are reached from the room side (south), floor
        # boxes against the south wall from the north
        heading = math.pi / 2 if cz > 0.3 else -math.pi / 2
        box = boxes[r.place].size[:2] if r.place in boxes else (0.0, 0.0)
        add(r.place, "deposit", _facing((cx, cy), heading, PLACE_REACH), (cx, cy, r.rim), box)
    handles = {k: data.body(v).xpos.copy() for k, v in world.drawer_handles.items()}
    # the cabinet's x axis points out of its front; the robot faces the other way
    heading = math.radians(world.house.cabinet.yaw) + math.pi
    heading = math.atan2(math.sin(heading), math.cos(heading))
    for name, h in handles.items():
        add(f"drawer_{name}", "drawer", _facing((h[0], h[1]), heading, HANDLE_STANDOFF),
            (float(h[0]), float(h[1]), float(h[2])))  # fmt: skip
    hc = np.mean(list(handles.values()), axis=0)
    # the drawers' fronts move: from the shut handles out by the travel and in as far
    # (the map's cabinet front among it), across the cabinet's width (axis-aligned)
    cab = world.house.cabinet
    along, across = 2.0 * cab.travel, cab.width + 0.02
    c, sn = abs(math.cos(heading)), abs(math.sin(heading))
    add("cabinet", "cabinet", _facing((hc[0], hc[1]), heading, CABINET_STANDOFF),
        (float(hc[0]), float(hc[1]), 0.0), (along * c + across * sn, along * sn + across * c),
        moves=True)  # fmt: skip
    return places
