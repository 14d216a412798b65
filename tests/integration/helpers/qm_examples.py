"""One valid, non-trivial example instance of every registered message type.

Built from each class's compiled field specs, so a newly added message type gets an
example automatically. Values are distinct (``arange``-based) so that a delivery test
comparing sent and received messages catches swapped or corrupted elements; fields with
cross-field rules use the few conventions below (unit quaternions, unit directions,
one common length for the variable first dimension, ``_CROSS_FIELD``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import quadmanip.common.messages  # noqa: F401 - registers every message type
from quadmanip.common.schema import FieldSpec, Message, field_specs, message_types

N_ROWS = 3  # every variable first dimension (names, points, trajectory samples)
N_COLS = 5  # every variable second dimension (image width)
UNIT_VECTOR_FIELDS = {"pull_direction"}


def _array(spec: FieldSpec, seed: int) -> np.ndarray:
    a = spec.array
    assert a is not None
    shape = tuple((N_ROWS if i == 0 else N_COLS) if s is None else s for i, s in enumerate(a.shape))
    n = int(np.prod(shape)) if shape else 1
    if "orientation" in spec.name and shape[-1] == 4:
        out = np.zeros(shape, dtype=a.dtype)
        out[..., 0] = 1.0
        return out
    if spec.name in UNIT_VECTOR_FIELDS:
        v = np.zeros(shape, dtype=a.dtype)
        v.flat[0] = 1.0
        return v
    if a.dtype.kind == "b":
        return (np.arange(n) % 2 == 0).reshape(shape)
    if a.dtype.kind in "iu":
        return (np.arange(n) % 200 + seed % 50).astype(a.dtype).reshape(shape)
    return (0.25 + 0.5 * np.arange(n) + seed).astype(a.dtype).reshape(shape)


def _value(spec: FieldSpec, seed: int, depth: int) -> Any:
    if spec.kind == "float":
        return 0.5 + seed
    if spec.kind == "int":
        return 7 + seed
    if spec.kind == "bool":
        return True
    if spec.kind == "str":
        return spec.choices[-1] if spec.choices else f"s{seed}"
    if spec.kind == "str_list":
        return [f"name{i}" for i in range(N_ROWS)]
    if spec.kind == "array":
        return _array(spec, seed)
    if spec.kind == "message":
        assert spec.msg_type is not None
        return example(spec.msg_type, seed + 1, depth + 1)
    if spec.kind == "any_message":
        from quadmanip.common.messages import Clock

        return Clock(stamp=12.5 + seed)
    raise ValueError(f"no example rule for field kind {spec.kind!r} ({spec.name})")


# Fields whose values a message's own cross-field rules tie together (the judge's report:
# one location per object from a closed set, in_place = the objects located there, a trial
# with violations is invalid; the robot status: stale ticks are some of the ticks).
_CROSS_FIELD: dict[str, dict[str, Any]] = {
    "qm.JudgeReport": {
        "in_place": ["name0"],
        "misplaced": ["name1", "name2"],
        "total": 3,
        "locations": ["in_place", "wrong_place", "held"],
        "valid": False,
    },
    "qm.RobotStatus": {"ticks": 20, "stale_ticks": 3},
    # the given-up count is the number of objects given up (bool rows alternate, from True)
    "qm.TaskProgress": {"failed": (N_ROWS + 1) // 2, "zones_total": N_ROWS + 2},
    "qm.ApproachGoal": {"standoff": 0.5, "heading": 1.5},
    "qm.OccupancyGrid": {
        "resolution": 0.05,
        "data": (np.arange(N_ROWS * N_COLS) % 102 - 1).astype(np.int8).reshape(N_ROWS, N_COLS),
    },
    # cells hold the floor and table bits; the stamps share the cells' shape
    "qm.SeenGrid": {
        "resolution": 0.1,
        "cells": (np.arange(N_ROWS * N_COLS) % 4).astype(np.uint8).reshape(N_ROWS, N_COLS),
        "floor_at": np.arange(N_ROWS * N_COLS, dtype=np.float32).reshape(N_ROWS, N_COLS),
        "table_at": np.arange(N_ROWS * N_COLS, dtype=np.float32).reshape(N_ROWS, N_COLS) + 0.5,
    },
}


def example(cls: type[Message], seed: int = 1, depth: int = 0) -> Message:
    """A valid instance of ``cls`` (optional nested messages are filled, not None)."""
    kwargs = {s.name: _value(s, seed + i, depth) for i, s in enumerate(field_specs(cls))}
    kwargs.update(_CROSS_FIELD.get(cls.SCHEMA, {}))
    return cls(**kwargs)


def all_examples() -> dict[str, Message]:
    """Schema name → example, for every registered message type."""
    return {cls.SCHEMA: example(cls) for cls in message_types()}


def slug(cls: type[Message]) -> str:
    """A key chunk for a message type: ``qm.LowState`` → ``lowstate``."""
    return cls.SCHEMA.split(".")[-1].lower()
