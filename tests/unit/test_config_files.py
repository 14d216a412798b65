"""Every field of every config dataclass is set in its TOML file (no silent code defaults).

A field left out of a file silently takes the dataclass default, and the two drift apart:
the file stops saying what runs. So each file under ``configs/`` must set every field of
the dataclass it is loaded into, recursively through nested tables, and through the
entries of tables of tables (``dict[str, Dataclass]``) and arrays of tables. Exempt are
fields whose default is ``None`` (TOML has no null), ``init=False`` fields and the few
record fields in :data:`OPTIONAL`, whose absence is their meaning.

The services' files are found through the service registry (``config_type`` and
``config_name`` of each registered service); the others are listed below.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from typing import Any, get_args, get_origin

import pytest
from quadmanip.common.config import config_path, load_config, load_toml

pytestmark = pytest.mark.unit


def _optional() -> dict[tuple[type, str], str]:
    """(dataclass, field) that a file may leave out, and why."""
    from quadmanip.services.locomotion.convex_mpc import MpcParams
    from quadmanip.services.manipulation.config import PostureSpec
    from quadmanip.sim.world.objects import ObjectSpec, Part

    return {
        (MpcParams, "weights"): "always replaced by the active profile's weights",
        (PostureSpec, "q"): "a posture gives exactly one of q and tcp",
        (PostureSpec, "tcp"): "a posture gives exactly one of q and tcp",
        (ObjectSpec, "parts"): "only objects of shape 'parts' have parts",
        (Part, "euler"): "a part without euler is not rotated",
        (Part, "weight"): "a part without weight has the object's mean density",
    }


OPTIONAL = _optional()


def _service_configs() -> dict[str, tuple[type, str]]:
    """{service: (config dataclass, config file name)} of every registered service."""
    from quadmanip import services_registry
    from quadmanip.common.service import Service

    out: dict[str, tuple[type, str]] = {}
    for name in services_registry.names():
        module = importlib.import_module(services_registry.entry_point(name).module)
        for v in vars(module).values():
            if isinstance(v, type) and issubclass(v, Service) and v.name == name:
                if dataclasses.is_dataclass(v.config_type):
                    out[name] = (v.config_type, v.config_name or v.name)
    return out


def _other_configs() -> dict[str, tuple[type, str]]:
    """Files loaded outside a service's own config (bus, world, launcher)."""
    from quadmanip.common.bus import BusConfig
    from quadmanip.launcher import LaunchConfig
    from quadmanip.sim.world.house import HouseConfig
    from quadmanip.sim.world.objects import Catalogue

    return {
        "bus": (BusConfig, "bus"),
        "house": (HouseConfig, "house"),
        "objects": (Catalogue, "objects"),
        "launch": (LaunchConfig, "launch"),
    }


def _all_configs() -> dict[str, tuple[type, str]]:
    return {**_other_configs(), **_service_configs()}


def _dataclass_in(tp: Any) -> type | None:
    """The dataclass a field type holds directly (``X`` or ``X | None``), else None."""
    if dataclasses.is_dataclass(tp):
        return tp
    if get_origin(tp) in (typing.Union, __import__("types").UnionType):
        found = [a for a in get_args(tp) if dataclasses.is_dataclass(a)]
        return found[0] if len(found) == 1 else None
    return None


def _missing(cls: type, data: Any, prefix: str = "") -> list[str]:
    """Dotted keys of the fields of ``cls`` (recursively) that ``data`` does not set."""
    if not isinstance(data, dict):
        return []  # a type error: the loader itself reports it
    hints = typing.get_type_hints(cls)
    out: list[str] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key = prefix + f.name
        if f.name not in data:
            if f.default is None or (cls, f.name) in OPTIONAL:
                continue  # TOML cannot write None; optional by design
            out.append(key)
            continue
        value, tp = data[f.name], hints[f.name]
        nested = _dataclass_in(tp)
        if nested is not None:
            out += _missing(nested, value, key + ".")
            continue
        origin, args = get_origin(tp), get_args(tp)
        if origin is dict and len(args) == 2 and dataclasses.is_dataclass(args[1]):
            for k, v in value.items():
                out += _missing(args[1], v, f"{key}.{k}.")
        elif origin in (tuple, list) and args and dataclasses.is_dataclass(args[0]):
            for i, v in enumerate(value):
                out += _missing(args[0], v, f"{key}[{i}].")
    return out


@dataclasses.dataclass(frozen=True)
class _Inner:
    a: float = 1.0
    b: float = 2.0


@dataclasses.dataclass(frozen=True)
class _Outer:
    x: int = 0
    note: str | None = None
    inner: _Inner = _Inner()
    table: dict[str, _Inner] = dataclasses.field(default_factory=dict)
    rows: tuple[_Inner, ...] = ()


def test_the_walk_finds_what_a_file_leaves_out():
    data = {"inner": {"a": 3.0}, "table": {"k": {"b": 1.0}}, "rows": [{"a": 1.0, "b": 1.0}, {}]}
    assert _missing(_Outer, data) == ["x", "inner.b", "table.k.a", "rows[1].a", "rows[1].b"]


def test_every_registered_service_with_a_config_has_its_file():
    services = _service_configs()
    assert {"sim", "locomotion", "manipulation", "viz"} <= set(services)
    for name, (_, file) in services.items():
        assert config_path(file).is_file(), f"service {name}: configs/{file}.toml missing"


@pytest.mark.parametrize("name", sorted(_all_configs()))
def test_toml_sets_every_field(name):
    cls, file = _all_configs()[name]
    load_config(cls, file)  # the file is valid for its dataclass (no unknown keys, types)
    missing = _missing(cls, load_toml(file))
    assert not missing, (
        f"configs/{file}.toml leaves {len(missing)} field(s) of {cls.__name__} to code "
        f"defaults; set them explicitly: {', '.join(missing)}"
    )
