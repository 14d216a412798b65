"""Typed message codec: frozen dataclasses <-> msgpack bytes, strict and bounded.

Why this exists: every quadmanip process talks over Zenoh with msgpack payloads, and a
malformed or hostile payload must never crash a controller or smuggle a NaN into a torque
command. So each message class declares its fields precisely (Python type annotations plus,
for numpy arrays, a dtype and shape), and one codec *plan* per class is compiled when the
class is defined. Encoding and decoding walk that plan; nothing is looked up per message.

Wire format (one msgpack array)::

    [schema_name: str, major: int, minor: int, {field_name: value, ...}]

- float/int/bool/str map to msgpack scalars; ``list[str]`` to an array of strings;
- numpy arrays to ``[dtype_str, [dim, ...], raw_bytes]`` with a little-endian dtype string
  (``"<f8"``, ``"<f4"``, ``"|u1"``, ``"|b1"``, ``"<i4"``...), row-major bytes;
- nested messages to their own 4-element array (recursively, with their own schema name);
- ``None`` for an optional nested message.

Versioning: a receiver accepts the same MAJOR version and any minor. Fields added in a
newer minor that it does not know are ignored; fields missing because the sender is older
take their declared defaults (so fields added in a minor version must have defaults).

Every failure while decoding surfaces as :class:`MessageError` (a ``ValueError``), and the
same validation runs on construction, so a service can never publish e.g. a non-finite
command. Decoded arrays are read-only views of the payload (zero-copy); constructed arrays
are copied and made read-only too, so a message is immutable all the way down.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Iterable
from typing import Any, ClassVar, TypeVar

import msgpack
import numpy as np

__all__ = [
    "MAX_PAYLOAD_BYTES",
    "MAX_ARRAY_ELEMENTS",
    "MAX_STR_LEN",
    "MAX_LIST_LEN",
    "MAX_NESTING",
    "ArraySpec",
    "FieldSpec",
    "Message",
    "MessageError",
    "array",
    "decode",
    "encode",
    "field_specs",
    "message",
    "message_types",
    "registry",
    "string",
    "string_list",
]

MAX_PAYLOAD_BYTES = 64 * 1024 * 1024
"""Largest payload `decode` accepts (a 1920x1080 RGB-D frame is ~14 MB)."""
MAX_ARRAY_ELEMENTS = 1 << 24
"""Default per-array element limit (16.7 M) unless a field declares its own."""
MAX_STR_LEN = 256
"""Default length limit of a string field (names, ids, short states)."""
MAX_LIST_LEN = 4096
"""Default item limit of a ``list[str]`` field."""
MAX_NESTING = 8
"""Nested messages deeper than this are rejected (bounds recursion on hostile input)."""

_SMALL = 64  # arrays up to this many elements are checked in pure Python (faster)
_INT64_MIN = -(1 << 63)
_INT64_MAX = (1 << 63) - 1

M = TypeVar("M", bound="Message")


class MessageError(ValueError):
    """A payload or a constructed message violates its schema."""


# --------------------------------------------------------------------------- field specs


@dataclasses.dataclass(frozen=True)
class ArraySpec:
    """Declared dtype and shape of a numpy array field.

    ``shape`` entries are fixed sizes or ``None`` for a variable dimension. ``finite``
    requires every float element to be finite. ``nonneg`` requires every element >= 0.
    """

    dtype: np.dtype
    shape: tuple[int | None, ...]
    finite: bool = True
    nonneg: bool = False
    max_elements: int = MAX_ARRAY_ELEMENTS

    @property
    def dtype_str(self) -> str:
        """The little-endian wire dtype string, e.g. ``"<f8"``."""
        return self.dtype.str


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    """Compiled description of one message field (public so tests can build strategies).

    ``kind`` is one of ``float``, ``int``, ``bool``, ``str``, ``str_list``, ``array``,
    ``message`` (a specific nested class, ``msg_type``) or ``any_message`` (any registered
    message). ``optional`` allows ``None``. Float scalars are always required finite: no
    field in the system needs NaN/inf, and a NaN that reaches a controller is a crash.
    """

    name: str
    kind: str
    optional: bool = False
    array: ArraySpec | None = None
    msg_type: type[Message] | None = None
    max_len: int = MAX_STR_LEN
    max_items: int = MAX_LIST_LEN
    choices: tuple[str, ...] | None = None
    has_default: bool = False


_META_KEY = "quadmanip"


def array(
    dtype: str | type | np.dtype,
    shape: tuple[int | None, ...],
    *,
    finite: bool = True,
    nonneg: bool = False,
    max_elements: int = MAX_ARRAY_ELEMENTS,
    default: Any = dataclasses.MISSING,
) -> Any:
    """Declare a numpy array field: ``q: np.ndarray = array("f8", (16,))``.

    A ``default`` (list/array) is converted per instance through a factory.
    """
    dt = np.dtype(dtype).newbyteorder("<") if np.dtype(dtype).itemsize > 1 else np.dtype(dtype)
    if dt.kind not in "fiub":
        raise TypeError(f"unsupported array dtype {dt}")
    spec = ArraySpec(dt, tuple(shape), finite, nonneg, max_elements)
    kw: dict[str, Any] = {"metadata": {_META_KEY: spec}}
    if default is not dataclasses.MISSING:
        frozen = np.asarray(default, dtype=dt)
        kw["default_factory"] = lambda: frozen.copy()
    return dataclasses.field(**kw)


def string(
    *,
    max_len: int = MAX_STR_LEN,
    choices: Iterable[str] | None = None,
    default: Any = dataclasses.MISSING,
) -> Any:
    """Declare a string field with a length limit and optionally a closed set of values."""
    meta = {"max_len": max_len, "choices": tuple(choices) if choices is not None else None}
    return dataclasses.field(default=default, metadata={_META_KEY: meta})


def string_list(
    *, max_len: int = MAX_STR_LEN, max_items: int = MAX_LIST_LEN, default_empty: bool = False
) -> Any:
    """Declare a ``list[str]`` field (stored as a tuple so the message stays immutable)."""
    meta = {"max_len": max_len, "max_items": max_items}
    if default_empty:
        return dataclasses.field(default=(), metadata={_META_KEY: meta})
    return dataclasses.field(metadata={_META_KEY: meta})


# --------------------------------------------------------------------------- registry

_REGISTRY: dict[str, type[Message]] = {}


def registry() -> dict[str, type[Message]]:
    """Schema name -> message class, for every registered message (a copy)."""
    return dict(_REGISTRY)


def message_types() -> tuple[type[Message], ...]:
    """Every registered message class, sorted by schema name."""
    return tuple(_REGISTRY[k] for k in sorted(_REGISTRY))


def field_specs(cls: type[Message]) -> tuple[FieldSpec, ...]:
    """The compiled field specs of a message class, in declaration order."""
    return cls.__qm_specs__


# --------------------------------------------------------------------------- base class


class Message:
    """Base of every message. Subclasses are declared with the :func:`message` decorator.

    Equality compares field by field, arrays exactly (dtype, shape, values).
    """

    SCHEMA: ClassVar[str]
    VERSION: ClassVar[tuple[int, int]]
    __qm_specs__: ClassVar[tuple[FieldSpec, ...]] = ()
    __qm_plan__: ClassVar[tuple[Any, ...]] = ()
    __qm_conv__: ClassVar[tuple[Any, ...]] = ()
    __qm_enc__: ClassVar[tuple[Any, ...]] = ()
    __qm_dec__: ClassVar[tuple[Any, ...]] = ()
    __qm_names__: ClassVar[frozenset[str]] = frozenset()
    __qm_defaults__: ClassVar[dict[str, tuple[bool, Any, Any]]] = {}

    stamp: float

    def __post_init__(self) -> None:
        d = self.__dict__
        for name, conv in type(self).__qm_conv__:
            try:
                d[name] = conv(d[name])
            except MessageError as e:
                raise MessageError(f"{type(self).SCHEMA}.{name}: {e}") from None
        self._check()

    def _check(self) -> None:
        """Cross-field validation hook; raise MessageError. Runs on construction and decode."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for spec in type(self).__qm_specs__:
            a = self.__dict__[spec.name]
            b = other.__dict__[spec.name]
            if isinstance(a, np.ndarray):
                if not (
                    isinstance(b, np.ndarray)
                    and a.dtype == b.dtype
                    and a.shape == b.shape
                    and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
                ):
                    return False
            elif isinstance(a, float) and isinstance(b, float):
                if not (a == b or (math.isnan(a) and math.isnan(b))):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]

    def replace(self: M, **changes: Any) -> M:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


# --------------------------------------------------------------------------- converters
# Each field compiles to (name, convert, encode, decode, spec):
#   convert(value) -> value   construction: coerce + validate, raise MessageError
#   encode(value)  -> wire    trusts a validated value
#   decode(wire, depth) -> value   strict validation of untrusted wire data


def _fail(msg: str) -> typing.NoReturn:
    raise MessageError(msg)


def _type_name(v: object) -> str:
    return type(v).__name__


def _make_float(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    optional = spec.optional

    def conv(v: Any) -> Any:
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
            _fail(f"expected a float, got {_type_name(v)}")
        try:
            f = float(v)
        except OverflowError:
            _fail("int too large for a float")
        if not math.isfinite(f):
            _fail(f"must be finite, got {f}")
        return f

    def dec(v: Any, depth: int) -> Any:
        if type(v) is float:
            if not math.isfinite(v):
                _fail(f"must be finite, got {v}")
            return v
        if type(v) is int:  # a non-Python sender may write 0 for 0.0; msgpack ints fit
            return float(v)
        if v is None and optional:
            return None
        _fail(f"expected a float, got {_type_name(v)}")

    return conv, _identity, dec


def _identity(v: Any) -> Any:
    return v


def _make_int(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    def conv(v: Any) -> Any:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            _fail(f"expected an int, got {_type_name(v)}")
        i = int(v)
        if not _INT64_MIN <= i <= _INT64_MAX:
            _fail(f"int out of int64 range: {i}")
        return i

    def dec(v: Any, depth: int) -> Any:
        if type(v) is not int:
            _fail(f"expected an int, got {_type_name(v)}")
        if not _INT64_MIN <= v <= _INT64_MAX:  # msgpack also yields uint64
            _fail(f"int out of int64 range: {v}")
        return v

    return conv, _identity, dec


def _make_bool(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    def conv(v: Any) -> Any:
        if not isinstance(v, (bool, np.bool_)):
            _fail(f"expected a bool, got {_type_name(v)}")
        return bool(v)

    def dec(v: Any, depth: int) -> Any:
        if type(v) is not bool:
            _fail(f"expected a bool, got {_type_name(v)}")
        return v

    return conv, _identity, dec


def _check_str(v: Any, spec: FieldSpec) -> str:
    if type(v) is not str:
        if isinstance(v, str):
            v = str(v)
        else:
            _fail(f"expected a str, got {_type_name(v)}")
    if len(v) > spec.max_len:
        _fail(f"string longer than {spec.max_len} characters ({len(v)})")
    if spec.choices is not None and v not in spec.choices:
        _fail(f"{v!r} is not one of {spec.choices}")
    return v


def _check_utf8(v: str) -> str:
    if not v.isascii():
        try:
            v.encode("utf-8")
        except UnicodeEncodeError:
            _fail("string is not encodable as UTF-8 (lone surrogate)")
    return v


def _make_str(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    def conv(v: Any) -> Any:
        return _check_utf8(_check_str(v, spec))

    def dec(v: Any, depth: int) -> Any:
        if type(v) is not str:
            _fail(f"expected a str, got {_type_name(v)}")
        return _check_str(v, spec)

    return conv, _identity, dec


def _make_str_list(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    def conv(v: Any) -> Any:
        if isinstance(v, (str, bytes)) or not isinstance(v, (list, tuple)):
            _fail(f"expected a list of str, got {_type_name(v)}")
        if len(v) > spec.max_items:
            _fail(f"more than {spec.max_items} items ({len(v)})")
        return tuple(_check_utf8(_check_str(s, spec)) for s in v)

    def enc(v: tuple[str, ...]) -> list[str]:
        return list(v)

    def dec(v: Any, depth: int) -> Any:
        if type(v) is not list:
            _fail(f"expected a list of str, got {_type_name(v)}")
        if len(v) > spec.max_items:
            _fail(f"more than {spec.max_items} items ({len(v)})")
        for s in v:
            if type(s) is not str:
                _fail(f"expected a str item, got {_type_name(s)}")
            _check_str(s, spec)
        return tuple(v)

    return conv, enc, dec


def _check_array_values(a: np.ndarray, spec: ArraySpec) -> None:
    kind = a.dtype.kind
    if a.size == 0:
        return
    if kind == "f":
        # Reductions without temporaries: NaN propagates through min/sum, inf through
        # max/sum; a non-finite sum of finite values (overflow) is confirmed element-wise.
        if spec.nonneg:
            lo = a.min()
            if not lo >= 0.0:  # also NaN
                if spec.finite and np.isnan(lo):
                    _fail("array must be finite (found NaN/inf)")
                _fail("array must be >= 0")
            if spec.finite and not math.isfinite(a.max()):
                _fail("array must be finite (found NaN/inf)")
        elif spec.finite:
            with np.errstate(over="ignore", invalid="ignore"):
                total = a.sum()
            if not math.isfinite(total) and not np.isfinite(a).all():
                _fail("array must be finite (found NaN/inf)")
    elif kind == "b":
        if a.view(np.uint8).max() > 1:
            _fail("bool array holds bytes other than 0/1")
    elif kind == "i" and spec.nonneg and (a < 0).any():
        _fail("array must be >= 0")


def _check_shape(shape: tuple[int, ...], spec: ArraySpec) -> None:
    if len(shape) != len(spec.shape):
        _fail(f"expected {len(spec.shape)} dims {_shape_str(spec.shape)}, got shape {shape}")
    for got, want in zip(shape, spec.shape, strict=True):
        if want is not None and got != want:
            _fail(f"expected shape {_shape_str(spec.shape)}, got {shape}")


def _shape_str(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"


def _make_array(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    aspec = spec.array
    assert aspec is not None
    dt = aspec.dtype
    dstr = dt.str
    itemsize = dt.itemsize
    ndim = len(aspec.shape)
    fixed = all(s is not None for s in aspec.shape)
    fixed_shape = tuple(aspec.shape) if fixed else None
    fixed_list = list(aspec.shape)
    fixed_n = math.prod(aspec.shape) if fixed else -1  # type: ignore[arg-type]
    is_float = dt.kind == "f"
    check_finite = is_float and aspec.finite
    nonneg = aspec.nonneg
    is_bool = dt.kind == "b"

    def check_values(a: np.ndarray, n: int) -> None:
        if is_float:
            if n > _SMALL:
                _check_array_values(a, aspec)
            elif n:
                # Small arrays: checking Python floats is ~4x cheaper than numpy reductions.
                vals = a.tolist() if ndim == 1 else a.ravel().tolist()
                # sum() is non-finite iff some element is, or on overflow near 1.8e308
                # (then the element-wise check decides).
                if check_finite and not math.isfinite(sum(vals)):
                    if not all(map(math.isfinite, vals)):
                        _fail("array must be finite (found NaN/inf)")
                if nonneg and min(vals) < 0.0:
                    _fail("array must be >= 0")
        elif is_bool:
            if n and a.view(np.uint8).max() > 1:
                _fail("bool array holds bytes other than 0/1")
        else:
            _check_array_values(a, aspec)

    def conv_slow(v: Any) -> np.ndarray:
        if isinstance(v, (str, bytes, dict)) or v is None:
            _fail(f"expected an array {dstr}{_shape_str(aspec.shape)}, got {_type_name(v)}")
        try:
            src = np.asarray(v)
        except Exception as e:  # ragged lists etc.
            _fail(f"not convertible to an array: {e}")
        if src.dtype == object or src.dtype.kind not in "fiub":
            _fail(f"expected numeric data for {dstr}, got dtype {src.dtype}")
        if src.dtype.kind == "f" and dt.kind != "f":
            _fail(f"expected dtype {dstr}, got float data")
        if src.dtype.kind == "b" and dt.kind != "b":
            _fail(f"expected dtype {dstr}, got bool data")
        if dt.kind == "b" and src.dtype.kind != "b":
            _fail(f"expected bool data, got {src.dtype}")
        if src.ndim == 1 and src.size == 0 and ndim > 1:
            # [] means "no rows": give it the declared trailing dims.
            src = src.reshape((0,) + tuple(s or 0 for s in aspec.shape[1:]))
        _check_shape(src.shape, aspec)
        if src.size > aspec.max_elements:
            _fail(f"array has {src.size} elements, limit {aspec.max_elements}")
        if src.dtype.kind in "iu" and dt.kind in "iu":
            info = np.iinfo(dt)
            if src.size and (src.min() < info.min or src.max() > info.max):
                _fail(f"values out of range for {dstr}")
        with np.errstate(over="ignore", invalid="ignore"):
            return np.array(src, dtype=dt, order="C", copy=True)

    def conv(v: Any) -> Any:
        if type(v) is np.ndarray and v.dtype == dt and fixed and v.shape == fixed_shape:
            a = v.copy()  # fast path for the hot loops (sim, controllers): right array already
        else:
            a = conv_slow(v)
        check_values(a, a.size)  # also catches f8 -> f4 overflow to inf
        a.flags.writeable = False
        return a

    def enc(a: np.ndarray) -> list:
        # Large arrays go out as a buffer view (no tobytes() copy); arrays are C-contiguous.
        data = a.data if a.nbytes > 4096 else a.tobytes()
        return [dstr, fixed_list if fixed else list(a.shape), data]

    def dec(v: Any, depth: int) -> Any:
        if type(v) is not list or len(v) != 3:
            _fail("expected an array as [dtype, shape, bytes]")
        wd, ws, wb = v
        if wd != dstr:
            _fail(f"expected dtype {dstr}, got {wd!r}")
        if type(wb) is not bytes:
            _fail(f"array data must be bytes, got {_type_name(wb)}")
        if type(ws) is not list:
            _fail("array shape must be a list")
        if fixed:
            if ws != fixed_list:
                _fail(f"expected shape {_shape_str(aspec.shape)}, got {ws}")
            for s in ws:
                if type(s) is not int:
                    _fail(f"bad array dimension {s!r}")
            shape = fixed_shape
            n = fixed_n
        else:
            n = 1
            for s in ws:
                if type(s) is not int or s < 0:
                    _fail(f"bad array dimension {s!r}")
                n *= s
                if n > aspec.max_elements:
                    _fail(f"array of shape {ws} exceeds {aspec.max_elements} elements")
            shape = tuple(ws)
            _check_shape(shape, aspec)
        if len(wb) != n * itemsize:
            _fail(f"array shape {ws} of {dstr} needs {n * itemsize} bytes, got {len(wb)}")
        a = np.frombuffer(wb, dt)  # positional dtype: ~4x faster than the keyword
        if ndim != 1:
            a = a.reshape(shape)
        check_values(a, n)
        return a

    return conv, enc, dec


def _make_message(spec: FieldSpec) -> tuple[Callable, Callable, Callable]:
    cls = spec.msg_type  # None means any registered message
    optional = spec.optional

    def conv(v: Any) -> Any:
        if v is None:
            if optional:
                return None
            _fail("a message is required, got None")
        if cls is None:
            if not isinstance(v, Message) or type(v).SCHEMA not in _REGISTRY:
                _fail(f"expected a registered message, got {_type_name(v)}")
        elif type(v) is not cls:
            _fail(f"expected {cls.__name__}, got {_type_name(v)}")
        return v

    def enc(v: Any) -> Any:
        if v is None:
            return None
        return _encode_obj(v)

    def dec(v: Any, depth: int) -> Any:
        if v is None:
            if optional:
                return None
            _fail("a message is required, got None")
        return _decode_obj(v, cls, depth + 1)

    return conv, enc, dec


_MAKERS: dict[str, Callable[[FieldSpec], tuple[Callable, Callable, Callable]]] = {
    "float": _make_float,
    "int": _make_int,
    "bool": _make_bool,
    "str": _make_str,
    "str_list": _make_str_list,
    "array": _make_array,
    "message": _make_message,
    "any_message": _make_message,
}


# --------------------------------------------------------------------------- class compile


def _spec_for(cls: type, f: dataclasses.Field, hint: Any) -> FieldSpec:
    meta = f.metadata.get(_META_KEY)
    has_default = (
        f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    )
    optional = False
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) != 1 or len(typing.get_args(hint)) != 2:
            raise TypeError(f"{cls.__name__}.{f.name}: only `X | None` unions are supported")
        optional = True
        hint = args[0]
        origin = typing.get_origin(hint)
    common = {"name": f.name, "optional": optional, "has_default": has_default}
    if isinstance(meta, ArraySpec):
        if hint is not np.ndarray:
            raise TypeError(f"{cls.__name__}.{f.name}: array() fields must be np.ndarray")
        if optional:
            raise TypeError(f"{cls.__name__}.{f.name}: optional arrays are not supported")
        return FieldSpec(kind="array", array=meta, **common)
    meta = meta or {}
    if hint is float:
        return FieldSpec(kind="float", **common)
    if (
        optional
        and hint is not Message
        and not (isinstance(hint, type) and issubclass(hint, Message))
    ):
        raise TypeError(f"{cls.__name__}.{f.name}: only float and message fields may be None")
    if hint is bool:
        return FieldSpec(kind="bool", **common)
    if hint is int:
        return FieldSpec(kind="int", **common)
    if hint is str:
        return FieldSpec(
            kind="str",
            max_len=meta.get("max_len", MAX_STR_LEN),
            choices=meta.get("choices"),
            **common,
        )
    if origin in (list, tuple) and typing.get_args(hint)[:1] == (str,):
        return FieldSpec(
            kind="str_list",
            max_len=meta.get("max_len", MAX_STR_LEN),
            max_items=meta.get("max_items", MAX_LIST_LEN),
            **common,
        )
    if hint is Message:
        return FieldSpec(kind="any_message", **common)
    if isinstance(hint, type) and issubclass(hint, Message):
        return FieldSpec(kind="message", msg_type=hint, **common)
    raise TypeError(f"{cls.__name__}.{f.name}: unsupported field type {hint!r}")


def message(schema: str, version: tuple[int, int] = (1, 0)) -> Callable[[type[M]], type[M]]:
    """Class decorator: make a frozen message dataclass, compile its codec plan, register it.

    Example::

        @message("qm.Clock", (1, 0))
        class Clock(Message):
            stamp: float
    """

    def wrap(cls: type[M]) -> type[M]:
        if not (isinstance(version, tuple) and len(version) == 2):
            raise TypeError("version must be (major, minor)")
        if schema in _REGISTRY:
            raise TypeError(f"schema {schema!r} is registered twice")
        cls.SCHEMA = schema
        cls.VERSION = (int(version[0]), int(version[1]))
        dc = dataclasses.dataclass(frozen=True, eq=False)(cls)
        hints = typing.get_type_hints(dc)
        specs = tuple(_spec_for(dc, f, hints[f.name]) for f in dataclasses.fields(dc))
        if not specs or specs[0].name != "stamp" or specs[0].kind != "float":
            raise TypeError(f"{dc.__name__}: the first field must be `stamp: float`")
        plan = []
        for s in specs:
            conv, enc, dec = _MAKERS[s.kind](s)
            plan.append((s.name, conv, enc, dec, s))
        dc.__qm_specs__ = specs
        dc.__qm_plan__ = tuple(plan)
        # Narrow views of the plan for the hot paths (fewer tuple unpacks per field).
        dc.__qm_conv__ = tuple((p[0], p[1]) for p in plan)
        dc.__qm_enc__ = tuple((p[0], None if p[2] is _identity else p[2]) for p in plan)
        dc.__qm_dec__ = tuple((p[0], p[3]) for p in plan)
        dc.__qm_names__ = frozenset(s.name for s in specs)
        defaults = {}
        convs = dict(dc.__qm_conv__)
        for f in dataclasses.fields(dc):
            if f.default is not dataclasses.MISSING:
                defaults[f.name] = (False, f.default, convs[f.name])
            elif f.default_factory is not dataclasses.MISSING:
                defaults[f.name] = (True, f.default_factory, convs[f.name])
        dc.__qm_defaults__ = defaults
        _REGISTRY[schema] = dc
        return dc

    return wrap


# --------------------------------------------------------------------------- encode/decode


def _encode_obj(msg: Message) -> list:
    cls = type(msg)
    d = msg.__dict__
    fields = {}
    for name, enc in cls.__qm_enc__:
        fields[name] = d[name] if enc is None else enc(d[name])
    return [cls.SCHEMA, cls.VERSION[0], cls.VERSION[1], fields]


def encode(msg: Message) -> bytes:
    """Serialise a message to msgpack bytes (the message was validated on construction)."""
    if not isinstance(msg, Message) or type(msg).SCHEMA not in _REGISTRY:
        raise MessageError(f"not a registered message: {_type_name(msg)}")
    try:
        return msgpack.packb(_encode_obj(msg), use_bin_type=True)
    except Exception as e:  # only reachable if a message was mutated behind validation
        raise MessageError(f"cannot encode {type(msg).SCHEMA}: {type(e).__name__}: {e}") from None


def _decode_obj(obj: Any, expected: type[Message] | None, depth: int) -> Message:
    if depth > MAX_NESTING:
        _fail(f"messages nested deeper than {MAX_NESTING}")
    if type(obj) is not list or len(obj) != 4:
        _fail("not a quadmanip message (expected [schema, major, minor, fields])")
    schema, major, minor, fields = obj
    if type(schema) is not str:
        _fail("schema name must be a str")
    cls = _REGISTRY.get(schema)
    if cls is None:
        _fail(f"unknown schema {schema[:80]!r}")
    if expected is not None and cls is not expected:
        _fail(f"expected {expected.SCHEMA}, got {schema}")
    if type(major) is not int or type(minor) is not int or major < 0 or minor < 0:
        _fail(f"{schema}: bad version {major!r}.{minor!r}")
    if major != cls.VERSION[0]:
        _fail(f"{schema}: unknown major version {major} (this build speaks {cls.VERSION[0]})")
    if type(fields) is not dict:
        _fail(f"{schema}: fields must be a map")
    msg = object.__new__(cls)
    out = msg.__dict__
    found = 0
    for name, dec in cls.__qm_dec__:
        try:
            v = fields[name]
        except KeyError:
            dflt = cls.__qm_defaults__.get(name)
            if dflt is None:
                _fail(f"{schema}: missing field {name!r}")
            # A field this (older-minor) sender does not know: its default, converted.
            out[name] = dflt[2](dflt[1]() if dflt[0] else dflt[1])
            continue
        found += 1
        try:
            out[name] = dec(v, depth)
        except MessageError as e:
            raise MessageError(f"{schema}.{name}: {e}") from None
    if found != len(fields) and minor <= cls.VERSION[1]:
        # Same or older minor: every key must be known to us; a newer minor may add fields.
        extra = sorted(str(k) for k in fields.keys() - cls.__qm_names__)
        _fail(f"{schema}: unknown fields {extra[:5]} in version {major}.{minor}")
    msg._check()
    return msg


def decode(data: bytes | bytearray | memoryview, expected: type[M] | None = None) -> M:
    """Parse and validate a payload. Any problem raises :class:`MessageError`.

    ``expected``: the message class the caller wants; another schema is an error.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"payload must be bytes, got {_type_name(data)}")
    n = len(data) if not isinstance(data, memoryview) else data.nbytes
    if n > MAX_PAYLOAD_BYTES:
        raise MessageError(f"payload of {n} bytes exceeds the {MAX_PAYLOAD_BYTES} byte limit")
    if n == 0:
        raise MessageError("empty payload")
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,
            use_list=True,
            strict_map_key=True,
            max_str_len=MAX_PAYLOAD_BYTES,
            max_bin_len=MAX_PAYLOAD_BYTES,
            max_array_len=1 << 20,
            max_map_len=1 << 16,
            max_ext_len=0,
        )
    except Exception as e:  # msgpack raises many types (ExtraData, FormatError, ValueError...)
        raise MessageError(f"not a valid msgpack payload: {type(e).__name__}: {e}") from None
    try:
        return _decode_obj(obj, expected, 0)  # type: ignore[return-value]
    except MessageError:
        raise
    except RecursionError:
        raise MessageError("payload nested too deeply") from None
    except Exception as e:  # defensive: no other exception type may escape decode
        raise MessageError(f"invalid payload: {type(e).__name__}: {e}") from None
