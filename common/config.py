"""TOML configuration files → frozen dataclasses, strictly.

Every tunable parameter of quadmanip lives in a TOML file under ``configs/`` and is loaded
into a frozen dataclass with :func:`load_config`. Loading is strict on purpose: a typo in a
key name would otherwise silently fall back to the default and cost an afternoon of tuning,
so unknown keys, missing required keys and wrong value types all raise :class:`ConfigError`
naming the file and the dotted key.

Supported field types: ``bool``, ``int``, ``float`` (an integer literal is accepted),
``str``, ``pathlib.Path``, ``Literal[...]``, ``X | None`` (None only from the default;
TOML has no null), ``tuple[X, ...]``, ``tuple[X, Y]``, ``list[X]`` (stored as a tuple so
the dataclass stays hashable and immutable), ``dict[str, X]`` and nested dataclasses (a
TOML table). ``float`` fields reject NaN and infinity.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin

from quadmanip.paths import CONFIG_DIR

__all__ = [
    "ConfigError",
    "config_path",
    "expand_overrides",
    "from_dict",
    "load_config",
    "load_toml",
    "to_dict",
]

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file or override does not match its dataclass."""


def config_path(name_or_path: str | Path) -> Path:
    """Resolve ``"bus"`` → ``configs/bus.toml``, ``"robot/x"`` → ``configs/robot/x.toml``.

    A value that names an existing file, or ends in ``.toml``, is taken as a path as is.
    """
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file():
        return p
    return CONFIG_DIR / f"{name_or_path}.toml"


def load_toml(name_or_path: str | Path) -> dict[str, Any]:
    """Read a TOML file (by config name or path) into a plain dict."""
    path = config_path(name_or_path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {path}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from exc


def load_config(
    cls: type[T],
    name_or_path: str | Path,
    overrides: Mapping[str, Any] | None = None,
    *,
    section: str | None = None,
) -> T:
    """Load ``configs/<name>.toml`` (or a path) into the frozen dataclass ``cls``.

    ``section`` selects one top-level table of the file (for files that hold several
    components). ``overrides`` is merged over the file before validation; its keys may be
    nested dicts or dotted paths (``{"gait.period": 0.4}``), and they are validated like the
    file itself, so an override cannot add an unknown key either.
    """
    path = config_path(name_or_path)
    data = load_toml(path)
    source = str(path)
    if section is not None:
        if section not in data or not isinstance(data[section], dict):
            raise ConfigError(f"{source}: no table [{section}]")
        data = data[section]
        source = f"{source} [{section}]"
    if overrides:
        data = _merge(data, expand_overrides(overrides))
        source = f"{source} (+overrides)"
    return from_dict(cls, data, source=source)


def from_dict(cls: type[T], data: Mapping[str, Any], *, source: str = "<dict>") -> T:
    """Validate a plain mapping into the dataclass ``cls`` (what :func:`load_config` does)."""
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{cls!r} is not a dataclass type")
    return _build(cls, data, source, "")


def to_dict(obj: Any) -> Any:
    """The inverse of :func:`from_dict`: a dataclass → TOML-compatible plain data."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple | list):
        return [to_dict(v) for v in obj]
    if isinstance(obj, Mapping):
        return {k: to_dict(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


# --------------------------------------------------------------------------- internals


def expand_overrides(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1}`` → ``{"a": {"b": 1}}`` (nested mappings are expanded too)."""
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        parts = str(key).split(".")
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {key!r} conflicts with another override")
        if isinstance(value, Mapping):
            value = expand_overrides(value)
        node[parts[-1]] = value
    return out


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _where(source: str, key: str) -> str:
    return f"{source}: key '{key}'" if key else source


def _build(cls: type, data: Any, source: str, prefix: str) -> Any:
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{_where(source, prefix)}: expected a table for {cls.__name__}, "
            f"got {type(data).__name__}"
        )
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    if unknown:
        names = ", ".join(f"'{prefix + k}'" for k in unknown)
        allowed = ", ".join(sorted(fields))
        raise ConfigError(f"{source}: unknown key {names} for {cls.__name__} (allowed: {allowed})")
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        key = prefix + name
        if name not in data:
            no_default = (
                field.default is dataclasses.MISSING
                and field.default_factory is dataclasses.MISSING
            )
            if no_default:
                raise ConfigError(f"{_where(source, key)}: missing (required by {cls.__name__})")
            continue
        kwargs[name] = _coerce(hints[name], data[name], source, key)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{_where(source, prefix.rstrip('.'))}: {exc}") from exc


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp)


def _coerce(tp: Any, value: Any, source: str, key: str) -> Any:
    origin = get_origin(tp)
    where = _where(source, key)

    def bad(expected: str) -> ConfigError:
        return ConfigError(f"{where}: expected {expected}, got {type(value).__name__} {value!r}")

    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        non_none = [a for a in args if a is not type(None)]
        if value is None and len(non_none) != len(args):
            return None
        errors = []
        for arg in non_none:
            try:
                return _coerce(arg, value, source, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise bad(" or ".join(_type_name(a) for a in non_none))
    if origin is Literal:
        if value in get_args(tp) and type(value) in {type(a) for a in get_args(tp)}:
            return value
        raise bad("one of " + ", ".join(repr(a) for a in get_args(tp)))
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, source, key + ".")
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise bad("bool")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise bad("int")
    if tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ConfigError(f"{where}: must be finite, got {value!r}")
            return float(value)
        raise bad("float")
    if tp is str:
        if isinstance(value, str):
            return value
        raise bad("str")
    if tp is Path:
        if isinstance(value, str | Path):
            return Path(value)
        raise bad("path string")
    if origin in (tuple, list) or tp in (tuple, list):
        if not isinstance(value, list | tuple):
            raise bad("array")
        args = get_args(tp)
        if not args:
            return tuple(value)
        if origin is list or (len(args) == 2 and args[1] is Ellipsis):
            item = args[0]
            return tuple(_coerce(item, v, source, f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} items, got {len(value)}")
        return tuple(
            _coerce(a, v, source, f"{key}[{i}]")
            for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise bad("table")
        args = get_args(tp) or (str, Any)
        return {
            _coerce(args[0], k, source, key): _coerce(args[1], v, source, f"{key}.{k}")
            for k, v in value.items()
        }
    raise ConfigError(f"{where}: unsupported field type {tp!r} in config dataclass")
