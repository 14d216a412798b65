"""Named places of a map (paper Section 5.3: "predetermined search and deposit zones").

Shared by every service that walks to or reasons about places (navigation stands at them,
the behavior service searches the zones and carries objects to the deposit places), so
the file format has one reader (``services/navigation/places.py`` re-exports it).

One TOML file beside each map (``maps/house.places.toml`` next to ``maps/house.yaml``)
names, in that map's frame, every place the task walks to: the search zones (each room's
floor areas, each table), the deposit places, the cabinet and its drawers. Each place has
the pose the robot should stand at (``stand``: x, y in m, yaw in degrees, as a person
writes it), the point it is about (``target``: x, y, z in m, e.g. a box's centre or a
drawer's handle) and, for zones, their size (``size``: x, y in m, axis-aligned in the
map). It is written once per house, like annotating a floor plan; a drafting tool
(``quadmanip map``, from the house description) may write the first version. Services
read it; none reads the simulator's world.

A ``table`` is furniture objects may lie on that the task does not search: the table the
deposit places stand on (``size`` its top, ``target`` its middle at the top's height). An
object that slips from the fingers at a deposit place lands there, beside its box, and
is taken up from it as from a search table. A deposit place's ``size`` is its box's
footprint: what lies within it is in the box.

``keepout = true`` marks a place's area (``size`` around the target) as furniture the
robot can neither walk through nor under although its LiDAR sees only part of it: a
table, whose top lies above the scan's plane and whose legs alone are in the map.
Navigation keeps its paths out of such areas (Nav2's keepout filter); localisation still
matches the scans against the map alone.

``moves = true`` marks a place's area (``size`` around the target) as scenery that moves:
the drawers, whose fronts come up to 30 cm out of the cabinet as they open. The map shows
them shut; localisation ignores the scan's returns there. With the tools' drawer open
24 cm, the LiDAR's returns off its front pulled the pose 9.5 cm toward the cabinet at the
stances beside its middle, and a tool released there landed on the drawer's front panel
(paper-1 and paper-5, 2026-12-06).

Example::

    [places.tray]
    kind = "deposit"
    stand = [7.0, 2.62, 90.0]
    target = [7.0, 3.65, 0.43]
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "KINDS",
    "TABLE_KINDS",
    "Place",
    "PlacesError",
    "Pose2",
    "load_places",
    "places_path_for",
    "save_places",
]

Pose2 = tuple[float, float, float]
"""x, y (m), yaw (rad) in the map frame."""

KINDS: tuple[str, ...] = (
    "search_floor",
    "search_table",
    "table",
    "deposit",
    "cabinet",
    "drawer",
)
TABLE_KINDS: tuple[str, ...] = ("search_table", "table")  # a top objects may lie on
AREA_FLAGS: tuple[str, ...] = ("keepout", "moves")  # what a place may say of its area


class PlacesError(ValueError):
    """A places file that cannot be used (the message says which place and why)."""


@dataclass(frozen=True)
class Place:
    """A named place: what it is, where to stand (x, y, yaw rad), what it is about."""

    name: str
    kind: str
    stand: Pose2
    target: tuple[float, float, float]
    size: tuple[float, float] = (0.0, 0.0)
    note: str = ""
    keepout: bool = False
    moves: bool = False  # the area's scenery moves (drawers): localisation ignores it

    @property
    def area(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the place's area in the map."""
        hx, hy = self.size[0] / 2, self.size[1] / 2
        return (self.target[0] - hx, self.target[1] - hy, self.target[0] + hx, self.target[1] + hy)

    def covers(self, p: Sequence[float], margin: float = 0.0) -> bool:
        """Whether plan point ``p`` lies in the place's area (``size`` around the target's
        x, y), grown by ``margin`` on every side."""
        x0, y0, x1, y1 = self.area
        return x0 - margin <= p[0] <= x1 + margin and y0 - margin <= p[1] <= y1 + margin

    def outside_by(self, p: Sequence[float]) -> float:
        """Signed distance (m) of plan point ``p`` from the place's area: positive
        outside it, negative inside (how far in from its nearest edge)."""
        dx = abs(p[0] - self.target[0]) - self.size[0] / 2
        dy = abs(p[1] - self.target[1]) - self.size[1] / 2
        if dx > 0.0 or dy > 0.0:
            return math.hypot(max(dx, 0.0), max(dy, 0.0))
        return max(dx, dy)


def places_path_for(map_yaml: str | Path) -> Path:
    """The places file that belongs to a map: ``NAME.places.toml`` beside ``NAME.yaml``."""
    p = Path(map_yaml)
    return p.with_name(p.stem + ".places.toml")


def _floats(v: object, n: int, where: str) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) != n:
        raise PlacesError(f"{where}: want a list of {n} numbers, got {v!r}")
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise PlacesError(f"{where}: want finite numbers, got {v!r}")
        out.append(float(x))
    return tuple(out)


def load_places(path: str | Path) -> dict[str, Place]:
    """Read and check a places file; raises :class:`PlacesError` naming what is wrong."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise PlacesError(f"{path}: no places file (write one beside the map)") from None
    except tomllib.TOMLDecodeError as exc:
        raise PlacesError(f"{path}: not valid TOML ({exc})") from None
    table = doc.get("places")
    if not isinstance(table, dict) or not table:
        raise PlacesError(f"{path}: needs a [places.NAME] table per place")
    places: dict[str, Place] = {}
    for name, p in table.items():
        where = f"{path}: places.{name}"
        if not isinstance(p, dict):
            raise PlacesError(f"{where}: must be a table")
        unknown = set(p) - {"kind", "stand", "target", "size", "note", *AREA_FLAGS}
        if unknown:
            raise PlacesError(f"{where}: unknown keys {sorted(unknown)}")
        kind = p.get("kind")
        if kind not in KINDS:
            raise PlacesError(f"{where}: kind must be one of {KINDS}, got {kind!r}")
        if "stand" not in p or "target" not in p:
            raise PlacesError(f"{where}: needs 'stand' [x, y, yaw_deg] and 'target' [x, y, z]")
        sx, sy, syaw = _floats(p["stand"], 3, f"{where}.stand")
        target = _floats(p["target"], 3, f"{where}.target")
        size = _floats(p.get("size", [0.0, 0.0]), 2, f"{where}.size")
        # the flags that say something of the place's area: true needs a size
        flags = {}
        for flag in AREA_FLAGS:
            on = p.get(flag, False)
            if not isinstance(on, bool):
                raise PlacesError(f"{where}.{flag}: want true or false, got {on!r}")
            if on and min(size) <= 0.0:
                raise PlacesError(f"{where}: {flag} needs the area's 'size' [x, y], both > 0")
            flags[flag] = on
        places[name] = Place(
            name=name,
            kind=kind,
            stand=(sx, sy, math.radians(syaw)),
            target=(target[0], target[1], target[2]),
            size=(size[0], size[1]),
            note=str(p.get("note", "")),
            keepout=flags["keepout"],
            moves=flags["moves"],
        )
    return places


def save_places(path: str | Path, places: list[Place] | dict[str, Place], header: str = "") -> Path:
    """Write a places file (the format :func:`load_places` reads); returns its path."""
    items = list(places.values()) if isinstance(places, dict) else list(places)
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    for p in items:
        if p.kind not in KINDS:
            raise PlacesError(f"place {p.name}: kind must be one of {KINDS}")
        lines += [
            "",
            f"[places.{p.name}]",
            f'kind = "{p.kind}"',
            f"stand = [{p.stand[0]:.3f}, {p.stand[1]:.3f}, {math.degrees(p.stand[2]):.1f}]",
            f"target = [{p.target[0]:.3f}, {p.target[1]:.3f}, {p.target[2]:.3f}]",
        ]
        if p.size != (0.0, 0.0):
            lines.append(f"size = [{p.size[0]:.3f}, {p.size[1]:.3f}]")
        if p.keepout:
            lines.append("keepout = true")
        if p.moves:
            lines.append("moves = true")
        if p.note:
            lines.append(f'note = "{p.note}"')
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines).lstrip("\n") + "\n")
    return path
