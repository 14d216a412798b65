"""Message contract (issue 2): construction, validation, wire format, versioning, limits."""

from __future__ import annotations

import dataclasses
import math

import msgpack
import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common import schema
from quadmanip.common.schema import (
    MAX_PAYLOAD_BYTES,
    Message,
    MessageError,
    decode,
    encode,
    field_specs,
    message,
    message_types,
    registry,
)

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def _leg_command(**kw: object) -> m.LegCommand:
    args: dict[str, object] = dict(
        stamp=0.0, tick=1, q_des=[0] * 12, dq_des=[0] * 12, kp=[30] * 12, kd=[1] * 12,
        tau_ff=[0] * 12,
    )  # fmt: skip
    args.update(kw)
    return m.LegCommand(**args)  # type: ignore[arg-type]


def _wire(msg: Message) -> list:
    return msgpack.unpackb(encode(msg))


def _pack(obj: object) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


# ----------------------------------------------------------------------------- registry


def test_registry_holds_every_contract_message() -> None:
    names = {c.__name__ for c in message_types()}
    contract = {
        "Clock", "JointState", "Imu", "LowState", "LegCommand", "ArmTrajectory",
        "GripperCommand", "RgbdImage", "LaserScan", "Odometry", "BodyVelocityCommand",
        "BodyPoseCommand", "Heartbeat", "ActionGoal", "ActionResponse", "ActionFeedback",
        "ActionResult", "ActionCancel", "Disturbance", "GroundTruthPoses",
        "GroundTruthContacts", "JudgeReport", "LocomotionDebug", "LocomotionMode",
    }  # fmt: skip
    assert contract <= names
    for cls in message_types():
        assert issubclass(cls, Message) and registry()[cls.SCHEMA] is cls
        assert cls.SCHEMA.startswith("qm.") and len(cls.VERSION) == 2
        assert field_specs(cls)[0].name == "stamp"
        assert dataclasses.is_dataclass(cls)


def test_contract_field_names() -> None:
    def names(cls: type[Message]) -> list[str]:
        return [s.name for s in field_specs(cls)]

    assert names(m.JointState) == ["stamp", "q", "dq", "tau", "gripper_gap", "gripper_effort"]
    assert names(m.LowState) == ["stamp", "tick", "joints", "imu"]
    assert names(m.LegCommand) == ["stamp", "tick", "q_des", "dq_des", "kp", "kd", "tau_ff"]
    assert names(m.BodyPoseCommand) == [
        "stamp", "z_offset", "x_offset", "y_offset", "roll", "pitch", "yaw",
    ]  # fmt: skip
    assert names(m.Disturbance)[-1] == "body" and m.example(m.Disturbance).body == "base"


def test_duplicate_schema_and_bad_declarations_refused() -> None:
    with pytest.raises(TypeError, match="registered twice"):

        @message("qm.Clock", (1, 0))
        class Clock2(Message):
            stamp: float

    with pytest.raises(TypeError, match="stamp"):

        @message("qm.test.NoStamp", (1, 0))
        class NoStamp(Message):
            x: float

    with pytest.raises(TypeError, match="unsupported"):

        @message("qm.test.BadType", (1, 0))
        class BadType(Message):
            stamp: float
            d: dict

    assert "qm.test.NoStamp" not in registry() and "qm.test.BadType" not in registry()


# ----------------------------------------------------------------------------- construction


def test_lists_convert_to_validated_read_only_arrays() -> None:
    cmd = _leg_command(tick=np.int64(7), stamp=np.float32(0.5))
    assert cmd.q_des.dtype == np.dtype("<f8") and cmd.q_des.shape == (12,)
    assert type(cmd.stamp) is float and type(cmd.tick) is int and cmd.tick == 7
    with pytest.raises(ValueError):
        cmd.kp[0] = 1.0  # read-only: a published message cannot change under the bus
    with pytest.raises(dataclasses.FrozenInstanceError):
        cmd.tick = 3  # type: ignore[misc]
    src = np.zeros(12)
    cmd2 = _leg_command(q_des=src)
    src[0] = 5.0
    assert cmd2.q_des[0] == 0.0  # copied on construction


@pytest.mark.parametrize(
    "change, match",
    [
        ({"q_des": [0.0] * 11}, "shape"),
        ({"q_des": [[0.0] * 12]}, "dims"),
        ({"q_des": [math.nan] + [0.0] * 11}, "finite"),
        ({"tau_ff": [math.inf] + [0.0] * 11}, "finite"),
        ({"kp": [-1.0] + [0.0] * 11}, ">= 0"),
        ({"q_des": "zeros"}, "array"),
        ({"q_des": [True] * 12}, "bool"),
        ({"stamp": math.nan}, "finite"),
        ({"stamp": "0"}, "float"),
        ({"stamp": True}, "float"),
        ({"stamp": 10**400}, "too large"),
        ({"tick": 1.0}, "int"),
        ({"tick": 1 << 64}, "int64"),
    ],
)
def test_invalid_construction_raises(change: dict, match: str) -> None:
    with pytest.raises(MessageError, match=match):
        _leg_command(**change)


def test_float32_overflow_is_not_finite() -> None:
    with pytest.raises(MessageError, match="finite"):
        m.LaserScan(
            stamp=0.0, angle_min=0.0, angle_increment=0.1, range_min=0.1, range_max=12.0,
            ranges=[1e300],
        )  # fmt: skip


def test_cross_field_checks() -> None:
    with pytest.raises(MessageError, match="strictly increasing"):
        m.ArmTrajectory(stamp=0, t=[0.0, 0.0], q=np.zeros((2, 4)), dq=np.zeros((2, 4)),
                        kp=[1] * 4, kd=[0] * 4)  # fmt: skip
    with pytest.raises(MessageError, match="points"):
        m.ArmTrajectory(stamp=0, t=[0.0, 1.0], q=np.zeros((3, 4)), dq=np.zeros((2, 4)),
                        kp=[1] * 4, kd=[0] * 4)  # fmt: skip
    with pytest.raises(MessageError, match="at least one"):
        m.ArmTrajectory(stamp=0, t=[], q=[], dq=[], kp=[1] * 4, kd=[0] * 4)
    with pytest.raises(MessageError, match="tau_ff"):
        m.ArmTrajectory(stamp=0, t=[0.0, 1.0], q=np.zeros((2, 4)), dq=np.zeros((2, 4)),
                        kp=[1] * 4, kd=[0] * 4, tau_ff=np.zeros((3, 4)))  # fmt: skip
    with pytest.raises(MessageError, match="tau_ff"):
        m.ArmTrajectory(stamp=0, t=[0.0, 1.0], q=np.zeros((2, 4)), dq=np.zeros((2, 4)),
                        kp=[1] * 4, kd=[0] * 4, tau_ff=np.full((2, 4), np.nan))  # fmt: skip
    with pytest.raises(MessageError, match="unit quaternion"):
        m.example(m.Imu, orientation=[0, 0, 0, 0])
    with pytest.raises(MessageError, match="differ"):
        m.example(m.RgbdImage, rgb=np.zeros((2, 2, 3), np.uint8), depth=np.zeros((2, 3)))
    depth_only = m.example(m.RgbdImage, rgb=np.zeros((0, 0, 3), np.uint8), depth=np.ones((2, 3)))
    assert decode(encode(depth_only)) == depth_only
    with pytest.raises(MessageError, match=">= 0"):
        m.example(m.RgbdImage, depth=-np.ones((1, 1)))
    with pytest.raises(MessageError, match="not one of"):
        m.LocomotionMode(stamp=0.0, mode="run")
    with pytest.raises(MessageError, match="not one of"):
        m.ActionResult(stamp=0.0, goal_id="g", status="done")
    with pytest.raises(MessageError, match="longer"):
        m.Heartbeat(stamp=0.0, service="s" * 300, seq=0, state="running")
    with pytest.raises(MessageError, match="UTF-8"):
        m.Heartbeat(stamp=0.0, service="s\ud800", seq=0, state="running")
    with pytest.raises(MessageError, match="UTF-8"):
        m.JudgeReport(stamp=0.0, trial_time=0.0, in_place=["\udfff"], misplaced=[], total=1)
    hb = m.Heartbeat(stamp=0.0, service="Küche-ロボット", seq=0, state="running")
    assert decode(encode(hb)) == hb
    with pytest.raises(MessageError, match="names"):
        m.GroundTruthPoses(stamp=0, names=["a", "b"], positions=np.zeros((1, 3)),
                           orientations=[[1, 0, 0, 0]])  # fmt: skip
    with pytest.raises(MessageError, match="unit quaternions"):
        m.GroundTruthPoses(stamp=0, names=["a"], positions=np.zeros((1, 3)),
                           orientations=[[0, 0, 0, 0]])  # fmt: skip
    with pytest.raises(MessageError, match="range_min"):
        m.LaserScan(stamp=0, angle_min=0, angle_increment=0.1, range_min=5.0, range_max=1.0,
                    ranges=[1.0])  # fmt: skip
    with pytest.raises(MessageError, match="registered message"):
        m.ActionGoal(stamp=0, goal_id="g", action="a", goal="not a message")  # type: ignore[arg-type]
    with pytest.raises(MessageError, match="JointState"):
        m.LowState(stamp=0, tick=0, joints=m.example(m.Imu), imu=m.example(m.Imu))  # type: ignore[arg-type]


def test_replace_revalidates() -> None:
    cmd = _leg_command()
    assert cmd.replace(tick=2).tick == 2
    with pytest.raises(MessageError):
        cmd.replace(stamp=math.inf)


# ----------------------------------------------------------------------------- wire format


def test_wire_layout_is_documented_format() -> None:
    ls = m.example(m.LowState, tick=42)
    schema_name, major, minor, fields = _wire(ls)
    assert (schema_name, major, minor) == ("qm.LowState", 1, 0)
    assert fields["tick"] == 42
    assert fields["joints"][0] == "qm.JointState"  # nested with its own schema
    dtype, shape, raw = fields["joints"][3]["q"]
    assert (dtype, shape, len(raw)) == ("<f8", [16], 16 * 8)
    rgbd = m.example(m.RgbdImage)
    f = _wire(rgbd)[3]
    assert f["rgb"][:2] == ["|u1", [1, 1, 3]] and f["depth"][:2] == ["<f4", [1, 1]]


def test_nested_any_message_and_optional() -> None:
    goal = m.ActionGoal(stamp=1.0, goal_id="g7", action="grasp",
                        goal=m.GraspGoal(stamp=1.0, position=[0.5, 0.0, 0.1], width=0.04))  # fmt: skip
    back = decode(encode(goal), m.ActionGoal)
    assert isinstance(back.goal, m.GraspGoal) and back.goal.width == 0.04
    res = m.ActionResult(stamp=2.0, goal_id="g7", status="succeeded")
    assert decode(encode(res)).result is None
    res2 = m.ActionResult(stamp=2.0, goal_id="g7", status="failed", reason="lost",
                          result=m.example(m.JointState))  # fmt: skip
    assert decode(encode(res2)) == res2


def test_expected_type_mismatch() -> None:
    with pytest.raises(MessageError, match="expected qm.LegCommand, got qm.Clock"):
        decode(encode(m.Clock(stamp=0.0)), m.LegCommand)


def _edit(msg: Message, fn: object) -> bytes:
    obj = _wire(msg)
    fn(obj)  # type: ignore[operator]
    return _pack(obj)


def test_unknown_schema_and_major_version() -> None:
    clk = m.Clock(stamp=1.0)
    with pytest.raises(MessageError, match="unknown schema"):
        decode(_edit(clk, lambda o: o.__setitem__(0, "qm.Nope")))
    with pytest.raises(MessageError, match="unknown major version 2"):
        decode(_edit(clk, lambda o: o.__setitem__(1, 2)))
    with pytest.raises(MessageError, match="version"):
        decode(_edit(clk, lambda o: o.__setitem__(2, -1)))


def test_newer_minor_with_extra_field_accepted_same_minor_rejected() -> None:
    cmd = _leg_command(tick=9)

    def newer(o: list) -> None:
        o[2] += 1
        o[3]["future_field"] = [1, 2, 3]

    back = decode(_edit(cmd, newer), m.LegCommand)
    assert back == cmd
    with pytest.raises(MessageError, match="unknown fields"):
        decode(_edit(cmd, lambda o: o[3].__setitem__("future_field", 1)))


def test_missing_fields_defaulted_or_rejected() -> None:
    # An older sender without a defaulted field: the default fills in.
    dist = m.Disturbance(stamp=0.0, force=[1, 0, 0], torque=[0, 0, 0], duration=0.1)
    back = decode(_edit(dist, lambda o: o[3].pop("body")), m.Disturbance)
    assert back.body == "base"
    dbg = m.example(m.LocomotionDebug)
    back2 = decode(_edit(dbg, lambda o: o[3].pop("mpc_predicted_positions")))
    assert back2.mpc_predicted_positions.shape == (0, 3)
    assert not back2.mpc_predicted_positions.flags.writeable
    with pytest.raises(MessageError, match="missing field 'force'"):
        decode(_edit(dist, lambda o: o[3].pop("force")))


def test_arm_trajectory_feed_forward_per_knot_zeros_from_a_1_0_sender() -> None:
    ff = np.arange(8.0).reshape(2, 4)
    traj = m.ArmTrajectory(stamp=0.0, t=[0.0, 0.5], q=np.zeros((2, 4)), dq=np.zeros((2, 4)),
                           kp=[1] * 4, kd=[0] * 4, tau_ff=ff)  # fmt: skip
    assert m.ArmTrajectory.VERSION == (1, 1)
    assert decode(encode(traj)) == traj and np.array_equal(traj.tau_ff, ff)
    # left out on construction, or sent by a 1.0 sender: zeros, one row per knot
    plain = traj.replace(tau_ff=np.zeros((0, 4)))
    assert plain.tau_ff.shape == (2, 4) and not plain.tau_ff.any()
    assert not plain.tau_ff.flags.writeable

    def old_sender(o: list) -> None:
        o[2] = 0
        o[3].pop("tau_ff")

    back = decode(_edit(traj, old_sender), m.ArmTrajectory)
    assert back == plain
    with pytest.raises(MessageError, match="tau_ff"):  # rows must match the knots
        decode(_edit(traj, lambda o: o[3].__setitem__("tau_ff", ["<f8", [1, 4], b"\0" * 32])))


WRONG_TYPE_VALUES = ["text", 1.5, -3, True, None, [1, 2], {"a": 1}, b"\x00" * 8]


@pytest.mark.parametrize("cls", message_types(), ids=lambda c: c.__name__)
def test_wrong_type_in_every_field_rejected(cls: type[Message]) -> None:
    msg = m.example(cls)
    good = _wire(msg)
    for spec in field_specs(cls):
        for bad in WRONG_TYPE_VALUES:
            obj = _wire(msg)
            obj[3][spec.name] = bad
            ok_types = {
                "float": (float, int),
                "int": (int,),
                "bool": (bool,),
                "str": (str,),
            }.get(spec.kind, ())
            if isinstance(bad, ok_types) and not (isinstance(bad, bool) and spec.kind != "bool"):
                continue  # a valid value of the right type
            if bad is None and spec.optional:
                continue
            with pytest.raises(MessageError, match=spec.name):
                decode(_pack(obj), cls)
    assert decode(_pack(good), cls) == msg


def _float_paths(msg: Message) -> list[tuple[str, str]]:
    return [
        (s.name, s.kind)
        for s in field_specs(type(msg))
        if s.kind == "float"
        or (s.kind == "array" and s.array is not None and s.array.dtype.kind == "f")
    ]


@pytest.mark.parametrize("cls", message_types(), ids=lambda c: c.__name__)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_rejected_on_wire(cls: type[Message], bad: float) -> None:
    msg = m.example(cls)
    for name, kind in _float_paths(msg):
        obj = _wire(msg)
        if kind == "float":
            obj[3][name] = bad
        else:
            dtype, shape, raw = obj[3][name]
            arr = np.frombuffer(raw, dtype=dtype).copy()
            arr.reshape(-1)[0] = bad
            obj[3][name] = [dtype, shape, arr.tobytes()]
        with pytest.raises(MessageError, match="finite|>= 0"):
            decode(_pack(obj), cls)


def test_large_float_arrays_checked_too() -> None:
    depth = np.ones((240, 320), np.float32)
    img = m.example(m.RgbdImage, rgb=np.zeros((240, 320, 3), np.uint8), depth=depth)
    obj = _wire(img)
    bad = depth.copy()
    bad[100, 200] = np.nan
    obj[3]["depth"][2] = bad.tobytes()
    with pytest.raises(MessageError, match="finite"):
        decode(_pack(obj))
    # finite values whose sum overflows are still valid
    big = m.example(m.JointState, q=np.full(16, 1e308))
    assert decode(encode(big)) == big


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("q_des", ["<f4", [12], b"\x00" * 48], "dtype"),
        ("q_des", ["<f8", [13], b"\x00" * 104], "shape"),
        ("q_des", ["<f8", [12], b"\x00" * 95], "bytes"),
        ("q_des", ["<f8", [12.0], b"\x00" * 96], "dimension"),
        ("q_des", ["<f8", [12], "x" * 96], "bytes"),
        ("q_des", ["<f8", 12, b"\x00" * 96], "shape"),
        ("q_des", ["<f8", [12]], "dtype, shape, bytes"),
    ],
)
def test_bad_array_encodings(field: str, value: object, match: str) -> None:
    def edit(o: list) -> None:
        o[3][field] = value

    with pytest.raises(MessageError, match=match):
        decode(_edit(_leg_command(), edit))


@pytest.mark.parametrize("shape", [[1 << 40, 3], [-1, 3], [1 << 62, 1 << 62], [2, 3, 4], [5, 4]])
def test_huge_or_bad_declared_shapes_rejected_fast(shape: list[int]) -> None:
    traj = m.example(m.GroundTruthPoses)

    def edit(o: list) -> None:
        o[3]["positions"] = ["<f8", shape, b"\x00" * 24]

    with pytest.raises(MessageError):
        decode(_edit(traj, edit))


def test_huge_declared_msgpack_lengths() -> None:
    # bin32 header claiming 4 GiB, str32 claiming 2 GiB, array32 claiming 2^32-1 items
    for head in (b"\xc6\xff\xff\xff\xff", b"\xdb\x7f\xff\xff\xff", b"\xdd\xff\xff\xff\xff"):
        with pytest.raises(MessageError, match="msgpack"):
            decode(head + b"\x00" * 16)


def test_oversized_payload_rejected() -> None:
    with pytest.raises(MessageError, match="exceeds"):
        decode(b"\x00" * (MAX_PAYLOAD_BYTES + 1))
    with pytest.raises(MessageError, match="empty"):
        decode(b"")
    with pytest.raises(MessageError, match="bytes"):
        decode("a string")  # type: ignore[arg-type]


def test_bool_array_bytes_must_be_0_or_1() -> None:
    dbg = m.example(m.LocomotionDebug, contact=[True, False, True, True])
    assert decode(encode(dbg)).contact.tolist() == [True, False, True, True]

    def edit(o: list) -> None:
        o[3]["contact"][2] = b"\x01\x02\x00\x01"

    with pytest.raises(MessageError, match="0/1"):
        decode(_edit(dbg, edit))


def test_string_limits_on_wire() -> None:
    hb = m.Heartbeat(stamp=0.0, service="sim", seq=1, state="running")
    with pytest.raises(MessageError, match="longer than"):
        decode(_edit(hb, lambda o: o[3].__setitem__("service", "x" * 10_000)))
    poses = m.example(m.GroundTruthPoses)
    with pytest.raises(MessageError, match="str item"):
        decode(_edit(poses, lambda o: o[3].__setitem__("names", [1])))


def test_only_message_error_escapes_decode(monkeypatch: pytest.MonkeyPatch) -> None:
    """Even a bug in a validator surfaces as MessageError (the bus counts those)."""

    def broken(self: Message) -> None:
        raise ZeroDivisionError("bug")

    monkeypatch.setattr(m.Clock, "_check", broken)
    with pytest.raises(MessageError, match="ZeroDivisionError"):
        decode(_pack(["qm.Clock", 1, 0, {"stamp": 0.0}]))
    assert issubclass(MessageError, ValueError)
    assert schema.MessageError is m.MessageError


def test_msgpack_oddities_rejected() -> None:
    good = _wire(m.Clock(stamp=1.0))
    cases = [
        _pack(msgpack.ExtType(5, b"abc")),
        _pack(["qm.Clock", 1, 0, {"stamp": msgpack.ExtType(1, b"\x00" * 8)}]),
        _pack(["qm.Clock", 1, 0, {"stamp": msgpack.Timestamp(1, 0)}]),
        _pack(["qm.Clock", 1, 0, {1: 0.0}]),  # non-str map key
        b"\x94\xa8qm.Clock\x01\x00\x81\xa5st\xffmp\xcb" + b"\x00" * 8,  # invalid UTF-8 key
        _pack(good) + _pack(good),  # two messages in one payload
        _pack([b"qm.Clock", 1, 0, {"stamp": 0.0}]),  # schema as bytes
        _pack(["qm.Clock", 1, 0, {"stamp": 0.0}, "extra"]),
        _pack(["qm.Clock", 1.0, 0, {"stamp": 0.0}]),
        _pack(["qm.Clock", True, 0, {"stamp": 0.0}]),
        _pack(["qm.Clock", 1, 0, [0.0]]),
        _pack(["qm.LowState", 1, 0, {"stamp": 0.0, "tick": 1 << 63, "joints": None, "imu": None}]),
    ]
    for data in cases:
        with pytest.raises(MessageError):
            decode(data)


def test_float_fields_accept_wire_ints_but_not_bools() -> None:
    assert decode(_pack(["qm.Clock", 1, 0, {"stamp": 3}])) == m.Clock(stamp=3.0)
    assert type(decode(_pack(["qm.Clock", 1, 0, {"stamp": 3}])).stamp) is float
    with pytest.raises(MessageError, match="float"):
        decode(_pack(["qm.Clock", 1, 0, {"stamp": False}]))


def test_initial_pose_needs_a_positive_doubt_and_a_finite_heading() -> None:
    hint = m.InitialPose(stamp=1.0, x=2.0, y=-1.0, yaw=3.0, std_xy=0.2, std_yaw=0.1)
    assert m.decode(m.encode(hint)) == hint
    for bad in ({"std_xy": 0.0}, {"std_yaw": -0.1}, {"std_xy": math.inf}, {"yaw": 100.0}):
        with pytest.raises(m.MessageError):
            hint.replace(**bad)
