"""The object catalogue's data model (``configs/objects.toml``): the 18 objects of the
paper's Section 7.1, their categories and deposit places (Section 7.2), sizes, masses,
materials and shape recipes.

It lives in ``common`` because more than the simulator reads it: the simulator builds the
objects from it (:mod:`quadmanip.sim.world.objects`), and perception uses it as its model of
each *class* (mass, size, shape), never of where an object is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

from quadmanip.common.config import load_config

__all__ = [
    "Catalogue",
    "Contact",
    "ObjectSpec",
    "PadFriction",
    "Part",
    "PartType",
    "Vessel",
    "load_catalogue",
]

PartType = Literal["box", "cylinder", "sphere", "capsule", "ellipsoid", "dish"]


@dataclass(frozen=True)
class Part:
    """One convex primitive of an object, in the object's body frame (MuJoCo size rules).

    ``dish``: a thin open elliptical shell (a spoon's bowl), opening up; ``size`` = rim
    half-axes x, y and the full height; ``thickness`` of its floor and walls; its walls
    lean in by ``inset`` (m) from the rim to the floor plate; ``segments`` wall slabs (a
    multiple of 4). ``material`` overrides the object's (a steel shaft in a plastic
    handle).
    """

    type: PartType
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)
    weight: float = 1.0
    rgba: tuple[float, float, float, float] | None = None
    material: str | None = None
    thickness: float | None = None
    inset: float | None = None
    segments: int | None = None

    def __post_init__(self) -> None:
        if self.type == "dish":
            if self.thickness is None or self.inset is None or self.segments is None:
                raise ValueError("a dish part needs thickness, inset and segments")
            if self.segments < 4 or self.segments % 4:
                raise ValueError("a dish needs a multiple of 4 wall segments")
            if not 0.0 <= self.inset < min(self.size[:2]):
                raise ValueError("a dish's inset must be smaller than its rim")


@dataclass(frozen=True)
class Vessel:
    """Recipe of an open container: wall and bottom thickness, foot diameter, slab count."""

    wall: float
    bottom: float
    bottom_diameter: float
    segments: int = 16
    handle: bool = False


@dataclass(frozen=True)
class ObjectSpec:
    """One catalogue entry: category, YCB source, bounding-box size, mass and shape recipe."""

    ycb: str
    category: str
    mass: float
    size: tuple[float, float, float]
    shape: Literal["box", "cylinder", "sphere", "parts", "vessel"]
    rgba: tuple[float, float, float, float]
    aliases: tuple[str, ...] = ()
    friction: tuple[float, float, float] = (0.9, 0.005, 0.0001)
    condim: int = 4
    # What its surface is made of (a key of the catalogue's pad_friction table).
    material: str = ""
    parts: tuple[Part, ...] = ()
    vessel: Vessel | None = None

    def __post_init__(self) -> None:
        if self.mass <= 0 or min(self.size) <= 0:
            raise ValueError("mass and size must be positive")
        if self.shape == "parts" and not self.parts:
            raise ValueError("shape 'parts' needs a non-empty parts list")
        if self.shape == "vessel" and self.vessel is None:
            raise ValueError("shape 'vessel' needs a vessel table")

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle around the object's footprint (for spacing at placement)."""
        return 0.5 * math.hypot(self.size[0], self.size[1])


@dataclass(frozen=True)
class Contact:
    """Contact parameters shared by every object geom (MuJoCo ``solref``, ``solmix``)."""

    solref: tuple[float, float] = (0.004, 1.0)
    solmix: float = 10.0


@dataclass(frozen=True)
class PadFriction:
    """MuJoCo friction of the finger pads against one material: sliding coefficient,
    torsional (m: the moment about the contact normal is at most torsional x normal force)
    and rolling (m)."""

    sliding: float
    torsional: float
    rolling: float


@dataclass(frozen=True)
class Catalogue:
    """All objects by name and the category → deposit place table (paper Section 7.2)."""

    categories: dict[str, str]
    objects: dict[str, ObjectSpec] = field(default_factory=dict)
    contact: Contact = field(default_factory=Contact)
    pad_friction: dict[str, PadFriction] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, obj in self.objects.items():
            if obj.category not in self.categories:
                raise ValueError(f"object {name!r}: unknown category {obj.category!r}")
            for m in (obj.material, *(p.material for p in obj.parts if p.material)):
                if m not in self.pad_friction:
                    raise ValueError(f"object {name!r}: material {m!r} not in pad_friction")

    @property
    def names(self) -> tuple[str, ...]:
        """Object names in catalogue order."""
        return tuple(self.objects)

    def place_of(self, name: str) -> str:
        """The deposit place (``pencil_case``, ``tray``, ``drawer``...) an object belongs in."""
        return self.categories[self.objects[name].category]

    def resolve(self, name: str) -> str:
        """Catalogue name of an object from its name or a paper alias ("driver", "sugar")."""
        if name in self.objects:
            return name
        key = name.strip().lower()
        for obj_name, obj in self.objects.items():
            if key == obj_name or key in (a.lower() for a in obj.aliases):
                return obj_name
        raise KeyError(f"unknown object {name!r}")


@lru_cache(maxsize=4)
def load_catalogue(name_or_path: str = "objects") -> Catalogue:
    """Load and validate the object catalogue (cached; it is immutable)."""
    return load_config(Catalogue, name_or_path)
