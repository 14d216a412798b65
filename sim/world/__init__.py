"""The simulated home: house, object catalogue and the world builder (paper Section 7)."""

from quadmanip.sim.world.builder import World, build_world
from quadmanip.sim.world.house import DepositRegion, HouseConfig, Surface, load_house
from quadmanip.sim.world.objects import Catalogue, ObjectSpec, load_catalogue

__all__ = [
    "Catalogue",
    "DepositRegion",
    "HouseConfig",
    "ObjectSpec",
    "Surface",
    "World",
    "build_world",
    "load_catalogue",
    "load_house",
]
