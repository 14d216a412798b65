"""The key table (issue 2 and the shared contracts): content, shape and helpers."""

from __future__ import annotations

import re

import pytest
from quadmanip.common import keys
from quadmanip.common import messages as m
from quadmanip.common.schema import registry

pytestmark = pytest.mark.unit

KEY_PATTERN = re.compile(r"^qm/[a-z][a-z0-9_]*/[a-z][a-z0-9_]*(/[a-z][a-z0-9_]*)+$")

# The table from the shared contracts, with the message each key carries.
CONTRACT = {
    "sim/clock": m.Clock,
    "sim/lowstate": m.LowState,
    "sim/camera/front": m.RgbdImage,
    "sim/camera/gripper": m.RgbdImage,
    "sim/scan": m.LaserScan,
    "sim/leg_command": m.LegCommand,
    "sim/arm_trajectory": m.ArmTrajectory,
    "sim/gripper_command": m.GripperCommand,
    "sim/test/disturbance": m.Disturbance,
    "sim/gt/base": m.GroundTruthPoses,
    "sim/gt/objects": m.GroundTruthPoses,
    "sim/gt/contacts": m.GroundTruthContacts,
    "sim/gt/judge": m.JudgeReport,
    "locomotion/cmd_vel": m.BodyVelocityCommand,
    "locomotion/body_pose": m.BodyPoseCommand,
    "locomotion/mode": m.LocomotionMode,
    "locomotion/odometry": m.Odometry,
    "locomotion/debug": m.LocomotionDebug,
}


def test_contract_keys_present_with_their_messages() -> None:
    for name, cls in CONTRACT.items():
        assert keys.topic(name).msg_type is cls, name
    for service in keys.SERVICES:
        assert keys.topic(f"{service}/heartbeat").msg_type is m.Heartbeat


def test_every_key_matches_pattern_unique_and_registered() -> None:
    full = [keys.key("dog1", name) for name in keys.TOPICS]
    assert len(full) == len(set(full)) == len(keys.TOPICS)
    reg = set(registry().values())
    for name, t in keys.TOPICS.items():
        k = keys.key("dog1", name)
        assert KEY_PATTERN.match(k) and keys.KEY_RE.match(k), k
        assert k == f"qm/dog1/{t.service}/{t.suffix}"
        assert t.service in keys.SERVICES
        assert t.kind in keys.KINDS and t.direction in ("in", "out")
        assert t.msg_type in reg
        assert keys.parse_key(k) == ("dog1", name)


def test_ground_truth_only_under_sim_gt() -> None:
    for name, t in keys.TOPICS.items():
        assert (t.kind == "gt") == name.startswith("sim/gt/"), name


def test_commands_are_control_and_sensors_drop() -> None:
    assert keys.topic("sim/leg_command").kind == "control"
    assert keys.topic("locomotion/cmd_vel").kind == "control"
    assert keys.topic("sim/camera/front").kind == "sensor"
    assert keys.topic("sim/scan").kind == "sensor"


def test_helpers() -> None:
    assert keys.key("dog1", "sim/lowstate") == "qm/dog1/sim/lowstate"
    assert keys.key("dog_2", "locomotion/cmd_vel") == "qm/dog_2/locomotion/cmd_vel"
    assert keys.heartbeat_key("dog1", "sim") == "qm/dog1/sim/heartbeat"
    assert keys.alive_key("dog1", "locomotion") == "qm/dog1/locomotion/alive"
    assert keys.action_key("dog1", "manipulation", "grasp") == ("qm/dog1/manipulation/action/grasp")
    assert keys.DEFAULT_ROBOT == "dog1"
    with pytest.raises(KeyError, match="not in the key table"):
        keys.key("dog1", "sim/nope")
    with pytest.raises(ValueError):
        keys.action_key("dog1", "manipulation", "Grasp*")
    with pytest.raises(ValueError):
        keys.parse_key("qm/dog1/**")


@pytest.mark.parametrize(
    "bad", ["", "Dog1", "dog/1", "*", "**", "dog 1", "1dog", "$dog", "d" * 33, None]
)
def test_validate_robot_name_rejects(bad: object) -> None:
    with pytest.raises(ValueError):
        keys.validate_robot_name(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.key(bad, "sim/clock")  # type: ignore[arg-type]


def test_markdown_lists_every_key() -> None:
    md = keys.render_key_table_markdown()
    for name, t in keys.TOPICS.items():
        assert f"`qm/dog1/{name}`" in md and t.msg_type.__name__ in md
    assert md.splitlines()[0].startswith("| key |")
    assert "/action/<name>" in md and "/alive" in md


def test_known_actions() -> None:
    reg = set(registry().values())
    assert set(keys.ACTIONS) >= {
        "manipulation/action/move_to_posture",
        "manipulation/action/grasp",
        "manipulation/action/place",
        "manipulation/action/open_drawer",
    }
    md = keys.render_key_table_markdown()
    for name, a in keys.ACTIONS.items():
        k = keys.action_key("dog1", a.service, a.action)
        assert k == f"qm/dog1/{name}" and KEY_PATTERN.match(k)
        assert a.goal_type in reg and f"`{k}`" in md
        assert name not in keys.TOPICS


# A hardware adapter runs under its own registry name but fills the sim's role (same
# service name, same keys); the simulated DDS robot is test tooling, not a Service.
ROLE = {"unitree-adapter": "sim"}
TOOLS = {"unitree-sim-robot"}


def _service_class(name: str, module_of: str | None = None) -> type:
    """The Service subclass a registry entry runs (found in its node module)."""
    import importlib

    from quadmanip import services_registry
    from quadmanip.common.service import Service

    module = importlib.import_module(services_registry.entry_point(module_of or name).module)
    found = [
        v
        for v in vars(module).values()
        if isinstance(v, type) and issubclass(v, Service) and v.name == name
    ]
    assert len(found) == 1, (name, found)
    return found[0]


@pytest.mark.parametrize(
    "name", __import__("quadmanip.services_registry").services_registry.names()
)
def test_every_registered_service_declares_rows_of_the_table(name: str) -> None:
    if name in TOOLS:
        pytest.skip(f"{name} is test tooling, not a Service (docs/hardware.md)")
    entry, name = name, ROLE.get(name, name)
    cls = _service_class(name, module_of=entry)
    assert cls.key_table is keys.TABLE  # the product table, never an extension
    cls.check_declarations()
    for out in cls.outputs:
        row = keys.topic(out.topic)
        if row.direction == "out":  # a topic the table gives to its owner alone
            assert row.service == name, (name, out.topic, row.service)
    for inp in cls.inputs:
        rows = keys.TABLE.match(inp.topic)
        if name not in ("viz", "sim"):  # ground truth is for the judge, tests and viz only
            assert all(r.kind != "gt" for r in rows), (name, inp.topic)
    served = {keys.TABLE.action(name, a).name for a in cls.actions}
    assert served == {a.name for a in keys.ACTIONS.values() if a.service == name}
    desc = cls.describe()
    for out in desc["outputs"]:
        assert out["kind"] == keys.topic(out["topic"]).kind


def test_extended_tables_keep_the_product_table_clean() -> None:
    extra = keys.TABLE.extended(
        (keys.row("probe", "out", m.Clock, "event", "out", "test"),),
        (keys.action_row("probe", "count", m.Clock, "test"),),
    )
    assert extra.topic("probe/out").msg_type is m.Clock
    assert extra.topic("probe/heartbeat").msg_type is m.Heartbeat  # added with the service
    assert extra.action("probe", "count").goal_type is m.Clock
    with pytest.raises(keys.UnknownKey):
        keys.topic("probe/out")
    with pytest.raises(ValueError, match="twice"):
        keys.TABLE.extended((keys.row("sim", "clock", m.Clock, "sensor", "out", "dup"),))
    with pytest.raises(ValueError, match="kind"):
        keys.row("probe", "x", m.Clock, "bulk", "out", "bad kind")
