"""Property tests for the message codec (issue 2): every message type round-trips exactly,
and malformed bytes of every sort are rejected with MessageError, never anything else.

Strategies are derived from each class's compiled field specs; classes with cross-field
constraints (quaternions, matching lengths, increasing times) get explicit composites.
STRATEGIES must name every registered type, so adding a message without a strategy fails.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from quadmanip.common import messages as m
from quadmanip.common.schema import (
    MAX_NESTING,
    FieldSpec,
    Message,
    MessageError,
    decode,
    encode,
    field_specs,
    message_types,
)

pytestmark = [pytest.mark.unit, pytest.mark.timeout(120)]

FUZZ = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# ----------------------------------------------------------------------------- strategies

finite64 = st.floats(allow_nan=False, allow_infinity=False)
text = st.text(max_size=12)


def _float_elements(dtype: np.dtype, nonneg: bool) -> st.SearchStrategy:
    width = 8 * dtype.itemsize
    return st.floats(
        min_value=0.0 if nonneg else None,
        allow_nan=False,
        allow_infinity=False,
        width=width,
    )


def array_strategy(spec: FieldSpec, dims: dict[int, int] | None = None) -> st.SearchStrategy:
    """Arrays of the declared dtype; variable dims drawn 0..4 unless fixed by ``dims``."""
    a = spec.array
    assert a is not None
    dims = dims or {}

    def shapes(draw_dims: list[int]) -> tuple[int, ...]:
        it = iter(draw_dims)
        out = []
        for i, s in enumerate(a.shape):
            if s is not None:
                out.append(s)
            elif i in dims:
                out.append(dims[i])
            else:
                out.append(next(it))
        return tuple(out)

    n_var = sum(1 for i, s in enumerate(a.shape) if s is None and i not in dims)
    if a.dtype.kind == "f":
        elements = _float_elements(a.dtype, a.nonneg)
    elif a.dtype.kind == "b":
        elements = st.booleans()
    else:
        info = np.iinfo(a.dtype)
        elements = st.integers(0 if a.nonneg else int(info.min), int(info.max))
    return st.lists(st.integers(0, 4), min_size=n_var, max_size=n_var).flatmap(
        lambda d: hnp.arrays(a.dtype, shapes(d), elements=elements)
    )


def field_strategy(spec: FieldSpec) -> st.SearchStrategy:
    if spec.kind == "float":
        s = finite64
    elif spec.kind == "int":
        s = st.integers(-(1 << 63), (1 << 63) - 1)
    elif spec.kind == "bool":
        s = st.booleans()
    elif spec.kind == "str":
        s = st.sampled_from(spec.choices) if spec.choices else text
    elif spec.kind == "str_list":
        s = st.lists(text, max_size=4)
    elif spec.kind == "array":
        s = array_strategy(spec)
    elif spec.kind == "message":
        assert spec.msg_type is not None
        s = st.deferred(lambda: STRATEGIES[spec.msg_type])
    elif spec.kind == "any_message":
        s = st.deferred(lambda: st.one_of([STRATEGIES[c] for c in LEAF_TYPES]))
    else:  # pragma: no cover - a new kind must get a strategy here
        raise AssertionError(f"no strategy for field kind {spec.kind}")
    if spec.optional:
        s = st.none() | s
    return s


def auto(cls: type[Message], **fixed: st.SearchStrategy) -> st.SearchStrategy:
    """st.builds over the field specs, with some fields given explicitly."""
    kw = {s.name: fixed.get(s.name, field_strategy(s)) for s in field_specs(cls)}
    return st.builds(cls, **kw)


def _spec(cls: type[Message], name: str) -> FieldSpec:
    return next(s for s in field_specs(cls) if s.name == name)


@st.composite
def seen_grid(draw: st.DrawFn) -> Message:
    """A SeenGrid whose three grids share one shape."""
    shape = draw(hnp.array_shapes(min_dims=2, max_dims=2, min_side=0, max_side=6))
    at = hnp.arrays(np.float32, shape, elements=st.floats(0.0, 1e4, width=32))
    return m.SeenGrid(
        stamp=draw(st.floats(0.0, 1e6)),
        origin=np.array(draw(st.lists(st.floats(-100, 100), min_size=2, max_size=2))),
        resolution=draw(st.floats(0.01, 1.0)),
        cells=draw(hnp.arrays(np.uint8, shape, elements=st.integers(0, 3))),
        floor_at=draw(at),
        table_at=draw(at),
    )


@st.composite
def unit_quat(draw: st.DrawFn) -> np.ndarray:
    v = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4)), dtype=float)
    n = float(np.linalg.norm(v))
    if n < 1e-3:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return v / n


@st.composite
def arm_trajectory(draw: st.DrawFn) -> m.ArmTrajectory:
    n = draw(st.integers(1, 6))
    dt = draw(st.lists(st.floats(1e-3, 10.0), min_size=n, max_size=n))
    t0 = draw(st.floats(0.0, 1e6))
    t = t0 + np.cumsum(dt)
    assert np.all(np.diff(t) > 0)
    return m.ArmTrajectory(
        stamp=draw(finite64),
        t=t,
        q=draw(array_strategy(_spec(m.ArmTrajectory, "q"), {0: n})),
        dq=draw(array_strategy(_spec(m.ArmTrajectory, "dq"), {0: n})),
        kp=draw(array_strategy(_spec(m.ArmTrajectory, "kp"))),
        kd=draw(array_strategy(_spec(m.ArmTrajectory, "kd"))),
        # per knot, or left out (then zeros, as from a 1.0 sender)
        tau_ff=draw(
            array_strategy(_spec(m.ArmTrajectory, "tau_ff"), {0: draw(st.sampled_from([n, 0]))})
        ),
    )


@st.composite
def rgbd(draw: st.DrawFn) -> m.RgbdImage:
    h, w = draw(st.integers(0, 5)), draw(st.integers(0, 5))
    rgb_shape = draw(st.sampled_from([(h, w, 3), (0, 0, 3)]))
    return m.RgbdImage(
        stamp=draw(finite64),
        camera=draw(text),
        rgb=draw(hnp.arrays(np.uint8, rgb_shape)),
        depth=draw(hnp.arrays(np.float32, (h, w), elements=_float_elements(np.dtype("f4"), True))),
        K=draw(array_strategy(_spec(m.RgbdImage, "K"))),
        position=draw(array_strategy(_spec(m.RgbdImage, "position"))),
        orientation=draw(unit_quat()),
    )


@st.composite
def gt_poses(draw: st.DrawFn) -> m.GroundTruthPoses:
    n = draw(st.integers(0, 4))
    return m.GroundTruthPoses(
        stamp=draw(finite64),
        names=draw(st.lists(text, min_size=n, max_size=n)),
        positions=draw(array_strategy(_spec(m.GroundTruthPoses, "positions"), {0: n})),
        orientations=np.array([draw(unit_quat()) for _ in range(n)]).reshape(n, 4),
    )


@st.composite
def rows_of(draw: st.DrawFn, cls: type[Message], list_fields: tuple[str, ...]) -> Message:
    """A message whose string lists and arrays all have the same number of rows."""
    n = draw(st.integers(0, 4))
    kwargs: dict[str, object] = {}
    for spec in field_specs(cls):
        if spec.name in list_fields:
            kwargs[spec.name] = draw(st.lists(text, min_size=n, max_size=n))
        elif spec.kind == "array" and spec.array is not None and spec.array.shape[0] is None:
            kwargs[spec.name] = draw(array_strategy(_spec(cls, spec.name), {0: n}))
    return draw(auto(cls, **{k: st.just(v) for k, v in kwargs.items()}))


@st.composite
def gt_contacts(draw: st.DrawFn) -> m.GroundTruthContacts:
    n = draw(st.integers(0, 4))
    return m.GroundTruthContacts(
        stamp=draw(finite64),
        body1=draw(st.lists(text, min_size=n, max_size=n)),
        body2=draw(st.lists(text, min_size=n, max_size=n)),
        positions=draw(array_strategy(_spec(m.GroundTruthContacts, "positions"), {0: n})),
        forces=draw(array_strategy(_spec(m.GroundTruthContacts, "forces"), {0: n})),
    )


@st.composite
def judge(draw: st.DrawFn) -> m.JudgeReport:
    a = draw(st.lists(text, max_size=4))
    b = draw(st.lists(text, max_size=4))
    return m.JudgeReport(
        stamp=draw(finite64),
        trial_time=draw(finite64),
        in_place=a,
        misplaced=b,
        total=draw(st.integers(len(a) + len(b), 1 << 40)),
    )


@st.composite
def health(draw: st.DrawFn) -> m.LocomotionHealth:
    state = draw(st.sampled_from(m.HEALTH_STATES))
    counts = st.integers(0, 1 << 40)
    return m.LocomotionHealth(
        stamp=draw(finite64),
        state=state,
        reason=draw(text) if state == "ok" else "why " + draw(text)[:200],
        phase=draw(text)[:32],
        upright=draw(st.booleans()),
        max_speed=draw(st.floats(0.0, 10.0)),
        missed_ticks=draw(counts),
        trips=draw(counts),
        cmd_age_ticks=draw(st.floats(0.0, 1e6)),
    )


@st.composite
def robot_status(draw: st.DrawFn) -> m.RobotStatus:
    ticks = draw(st.integers(0, 1 << 30))
    return m.RobotStatus(
        stamp=draw(finite64),
        ticks=ticks,
        stale_ticks=draw(st.integers(0, ticks)),
        cmd_age_p50=draw(st.floats(0.0, 1e6)),
        cmd_age_max=draw(st.integers(0, 1 << 30)),
        leg_timeouts=draw(st.integers(0, 1 << 30)),
        leg_mode=draw(st.sampled_from(["active", "damping", "estop"])),
        rtf=draw(st.floats(0.0, 100.0)),
    )


@st.composite
def laser_scan(draw: st.DrawFn) -> m.LaserScan:
    lo = draw(st.floats(0.0, 1e6))
    return m.LaserScan(
        stamp=draw(finite64),
        angle_min=draw(finite64),
        angle_increment=draw(finite64),
        range_min=lo,
        range_max=lo + draw(st.floats(0.0, 1e6)),
        ranges=draw(array_strategy(_spec(m.LaserScan, "ranges"))),
    )


@st.composite
def task_progress(draw: st.DrawFn) -> m.TaskProgress:
    n = draw(st.integers(0, 4))
    given_up = draw(hnp.arrays(np.bool_, n))
    zones = draw(st.lists(text, max_size=4))

    def rows(name: str) -> np.ndarray:
        return draw(array_strategy(_spec(m.TaskProgress, name), {0: n}))

    return m.TaskProgress(
        stamp=draw(finite64),
        state=draw(st.sampled_from(m.TASK_STATES)),
        reason=draw(text),
        step=draw(text),
        current_object=draw(text),
        elapsed=draw(st.floats(0.0, 1e9)),
        budget=draw(st.floats(0.0, 1e9)),
        drawers_opened=draw(st.lists(text, max_size=3)),
        zones_searched=zones,
        zones_total=len(zones) + draw(st.integers(0, 1 << 20)),
        failed=int(given_up.sum()),
        objects=draw(st.lists(text, min_size=n, max_size=n)),
        object_track_ids=rows("object_track_ids"),
        object_found_at=rows("object_found_at"),
        object_grasped=rows("object_grasped"),
        object_placed=rows("object_placed"),
        object_given_up=given_up,
        object_time_s=rows("object_time_s"),
        object_attempts=rows("object_attempts"),
        object_failures=draw(st.lists(text, min_size=n, max_size=n)),
        object_positions=rows("object_positions"),
        taken_track_ids=draw(array_strategy(_spec(m.TaskProgress, "taken_track_ids"), {0: n})),
    )


unit_vec = st.lists(st.floats(-1, 1), min_size=3, max_size=3).map(
    lambda v: np.array(v) / np.linalg.norm(v) if np.linalg.norm(v) > 1e-3 else np.array([1.0, 0, 0])
)
nonneg = st.floats(0.0, allow_infinity=False)
positive = st.floats(1e-6, 1e6)

STRATEGIES: dict[type[Message], st.SearchStrategy] = {
    m.Clock: auto(m.Clock),
    m.JointState: auto(m.JointState),
    m.Imu: auto(m.Imu, orientation=unit_quat()),
    m.LowState: auto(m.LowState),
    m.LegCommand: auto(m.LegCommand),
    m.ArmTrajectory: arm_trajectory(),
    m.GripperCommand: auto(m.GripperCommand, gap=nonneg, max_force=nonneg),
    m.BodyVelocityCommand: auto(m.BodyVelocityCommand),
    m.BodyPoseCommand: auto(m.BodyPoseCommand),
    m.LocomotionMode: auto(m.LocomotionMode),
    m.RgbdImage: rgbd(),
    m.LaserScan: laser_scan(),
    m.Odometry: auto(m.Odometry, orientation=unit_quat()),
    m.LocomotionDebug: auto(m.LocomotionDebug),
    m.Payload: auto(m.Payload, mass=st.floats(0.0, 10.0)),
    m.Heartbeat: auto(m.Heartbeat),
    m.ActionGoal: auto(m.ActionGoal),
    m.ActionResponse: auto(m.ActionResponse),
    m.ActionFeedback: auto(m.ActionFeedback),
    m.ActionResult: auto(m.ActionResult),
    m.ActionCancel: auto(m.ActionCancel),
    m.PostureGoal: auto(m.PostureGoal),
    m.GraspGoal: auto(
        m.GraspGoal,
        mass=nonneg,
        hang=nonneg,
        center=st.sampled_from([0, 3]).flatmap(
            lambda n: hnp.arrays(np.float64, (n,), elements=_float_elements(np.dtype("f8"), False))
        ),
    ),  # fmt: skip
    m.PlaceGoal: auto(m.PlaceGoal),
    m.DrawerGoal: auto(m.DrawerGoal, pull_direction=unit_vec),
    m.Disturbance: auto(m.Disturbance, duration=nonneg),
    m.EmergencyStop: auto(m.EmergencyStop),
    m.GroundTruthPoses: gt_poses(),
    m.GroundTruthContacts: gt_contacts(),
    m.JudgeReport: judge(),
    m.LocomotionHealth: health(),
    m.RobotStatus: robot_status(),
    m.OccupancyGrid: auto(
        m.OccupancyGrid,
        resolution=st.floats(0.005, 1.0),
        data=hnp.arrays(
            np.int8,
            hnp.array_shapes(min_dims=2, max_dims=2, max_side=6),
            elements=st.integers(-1, 100),
        ),
    ),
    m.MapPose: auto(m.MapPose),
    m.InitialPose: auto(
        m.InitialPose,
        yaw=st.floats(-12.0, 12.0),
        std_xy=st.floats(1e-6, 100.0),
        std_yaw=st.floats(1e-6, 100.0),
    ),
    m.Path: auto(m.Path),
    m.NavigateGoal: auto(m.NavigateGoal, tolerance_xy=positive, tolerance_yaw=positive),
    m.ApproachGoal: auto(
        m.ApproachGoal,
        standoff=st.floats(0.0, 3.0),
        heading=st.floats(-12.0, 12.0),
        tolerance_xy=positive,
        tolerance_yaw=positive,
    ),
    m.ExploreGoal: auto(m.ExploreGoal),
    m.NavigationResult: auto(m.NavigationResult),
    m.Detections: rows_of(m.Detections, ("labels",)),
    m.ObjectTracks: rows_of(m.ObjectTracks, ("labels",)),
    m.SeenGrid: seen_grid(),
    m.GraspRequest: auto(m.GraspRequest, max_distance=nonneg),
    m.HandleRequest: auto(m.HandleRequest),
    m.TaskProgress: task_progress(),
    m.TidyUpGoal: auto(m.TidyUpGoal, time_budget=st.floats(0.0, 1e9)),
}

# Messages that may ride inside ActionGoal.goal / ActionResult.result in the fuzz (no
# envelopes inside envelopes, to keep examples small; nesting is tested separately).
LEAF_TYPES = [c for c in STRATEGIES if not c.SCHEMA.startswith("qm.Action")]

ALL_TYPES = message_types()


def test_every_message_type_has_a_strategy() -> None:
    missing = [c.__name__ for c in ALL_TYPES if c not in STRATEGIES]
    assert not missing, f"add hypothesis strategies for: {missing}"
    assert len(ALL_TYPES) >= 28


# ----------------------------------------------------------------------------- round trip


def _assert_same(a: Message, b: Message) -> None:
    """Field-by-field exact comparison (stricter than ==: also array dtypes/flags)."""
    assert type(a) is type(b)
    for spec in field_specs(type(a)):
        x, y = getattr(a, spec.name), getattr(b, spec.name)
        if isinstance(x, np.ndarray):
            assert y.dtype == x.dtype and y.shape == x.shape
            assert x.tobytes() == y.tobytes()  # bit-exact, including -0.0
            assert not y.flags.writeable
        elif isinstance(x, Message):
            _assert_same(x, y)
        elif isinstance(x, float):
            assert type(y) is float and math.copysign(1, x) == math.copysign(1, y) and x == y
        else:
            assert type(x) is type(y) and x == y


@pytest.mark.parametrize("cls", ALL_TYPES, ids=lambda c: c.__name__)
@FUZZ
@given(data=st.data())
def test_round_trip(cls: type[Message], data: st.DataObject) -> None:
    msg = data.draw(STRATEGIES[cls])
    wire = encode(msg)
    back = decode(wire, cls)
    assert back == msg
    _assert_same(msg, back)
    assert encode(back) == wire  # deterministic encoding
    assert decode(bytearray(wire)) == msg and decode(memoryview(wire)) == msg


# ----------------------------------------------------------------------------- malformed


def _raises_message_error(data: object, expected: type[Message] | None = None) -> None:
    with pytest.raises(MessageError):
        decode(data, expected)  # type: ignore[arg-type]


@FUZZ
@given(st.binary(max_size=300))
def test_random_bytes_rejected(data: bytes) -> None:
    _raises_message_error(data)


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(1 << 63), (1 << 64) - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=16),
    lambda kids: (
        st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4)
    ),
    max_leaves=20,
)


@FUZZ
@given(msgpack_values)
def test_random_msgpack_structures_rejected(value: object) -> None:
    _raises_message_error(msgpack.packb(value, use_bin_type=True))


@FUZZ
@given(
    cls=st.sampled_from(ALL_TYPES),
    fake=msgpack_values,
    data=st.data(),
)
def test_field_replaced_by_random_value(
    cls: type[Message], fake: object, data: st.DataObject
) -> None:
    """A valid message with one field swapped for a random msgpack value: either it still
    validates (then it re-encodes to an equal message) or MessageError; nothing else."""
    msg = data.draw(STRATEGIES[cls])
    obj = msgpack.unpackb(encode(msg))
    name = data.draw(st.sampled_from(sorted(obj[3])))
    obj[3][name] = fake
    wire = msgpack.packb(obj, use_bin_type=True)
    try:
        back = decode(wire, cls)
    except MessageError:
        return
    assert decode(encode(back), cls) == back


@FUZZ
@given(cls=st.sampled_from(ALL_TYPES), data=st.data())
def test_byte_mutations_never_escape(cls: type[Message], data: st.DataObject) -> None:
    """Random byte flips in a real payload: MessageError or a message that validates."""
    wire = bytearray(encode(data.draw(STRATEGIES[cls])))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(wire) - 1))
        wire[i] = data.draw(st.integers(0, 255))
    try:
        back = decode(bytes(wire))
    except MessageError:
        return
    assert decode(encode(back)) == back


def _real_messages() -> list[Message]:
    js = m.JointState(
        stamp=1.5, q=np.linspace(-1, 1, 16), dq=np.ones(16), tau=np.zeros(16), gripper_gap=0.03
    )
    imu = m.example(m.Imu)
    rgb = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    return [
        m.LowState(stamp=1.5, tick=750, joints=js, imu=imu),
        m.RgbdImage(
            stamp=0.1,
            camera="front",
            rgb=rgb,
            depth=np.full((4, 5), 1.25, np.float32),
            K=np.eye(3),
            position=[0.3, 0.0, 0.1],
            orientation=[1, 0, 0, 0],
        ),
        m.ActionGoal(stamp=0.0, goal_id="g1", action="grasp", goal=m.example(m.GraspGoal)),
    ]


@pytest.mark.parametrize("msg", _real_messages(), ids=lambda x: type(x).__name__)
def test_truncated_at_every_cut_point(msg: Message) -> None:
    wire = encode(msg)
    assert decode(wire) == msg
    for cut in range(len(wire)):
        _raises_message_error(wire[:cut])
    # and trailing garbage is not silently ignored
    _raises_message_error(wire + b"\x00")


def test_deep_msgpack_nesting_rejected() -> None:
    deep = b"\x91" * 100_000 + b"\xc0"  # 100k nested one-element arrays
    _raises_message_error(deep)


def test_nested_envelopes_bounded() -> None:
    inner: Message = m.Clock(stamp=0.0)
    for i in range(MAX_NESTING + 2):
        inner = m.ActionGoal(stamp=0.0, goal_id=str(i), action="a", goal=inner)
    _raises_message_error(encode(inner))
    ok: Message = m.Clock(stamp=0.0)
    for i in range(MAX_NESTING):
        ok = m.ActionGoal(stamp=0.0, goal_id=str(i), action="a", goal=ok)
    assert decode(encode(ok)) == ok


WIRE_DTYPES = ["<f8", "<f4", ">f8", "|u1", "|i1", "<i4", "<i8", "<u2", "|b1", "<c16", "|O", "x"]


@FUZZ
@given(
    cls=st.sampled_from([c for c in ALL_TYPES if any(s.kind == "array" for s in field_specs(c))]),
    dtype=st.sampled_from(WIRE_DTYPES),
    shape=st.lists(st.integers(-2, 6) | st.just(1 << 40), max_size=4),
    data=st.data(),
)
def test_array_dtype_and_shape_mismatches(
    cls: type[Message], dtype: str, shape: list[int], data: st.DataObject
) -> None:
    """Any wire dtype/shape for an array field: accepted only if it is the declared dtype,
    a declared-compatible shape and the byte count matches; otherwise MessageError."""
    msg = m.example(cls)
    spec = data.draw(st.sampled_from([s for s in field_specs(cls) if s.kind == "array"]))
    assert spec.array is not None
    n = math.prod(shape) if all(s >= 0 for s in shape) else 0
    itemsize = 1 if dtype in ("|u1", "|i1", "|b1", "x", "|O") else int(dtype[-1:] or 1)
    raw = bytes(min(max(n, 0), 64) * itemsize)
    obj = msgpack.unpackb(encode(msg))
    obj[3][spec.name] = [dtype, shape, raw]
    declared_ok = (
        dtype == spec.array.dtype_str
        and len(shape) == len(spec.array.shape)
        and all(w is None or w == s for s, w in zip(shape, spec.array.shape, strict=True))
        and all(s >= 0 for s in shape)
        and len(raw) == n * spec.array.dtype.itemsize
    )
    try:
        back = decode(msgpack.packb(obj, use_bin_type=True), cls)
    except MessageError:
        return
    # Accepted: it must have been a well-formed encoding of the declared array.
    assert declared_ok
    assert getattr(back, spec.name).shape == tuple(shape)


@pytest.mark.parametrize("cls", ALL_TYPES, ids=lambda c: c.__name__)
def test_newer_minor_with_extra_fields_accepted_for_every_type(cls: type[Message]) -> None:
    msg = m.example(cls)
    obj = msgpack.unpackb(encode(msg))
    obj[2] += 1
    obj[3]["added_in_next_minor"] = {"anything": [1, 2.5, "x"]}
    assert decode(msgpack.packb(obj, use_bin_type=True), cls) == msg
    obj[1] += 1  # ... but a new major is refused
    with pytest.raises(MessageError, match="major"):
        decode(msgpack.packb(obj, use_bin_type=True), cls)
