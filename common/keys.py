"""The one key table: every Zenoh key quadmanip uses, its owner, message type and kind.

Keys are ``qm/<robot>/<service>/<topic>``. A topic is named here by its path below the
robot, e.g. ``"sim/lowstate"``; :func:`key` turns it into the full key for a robot. The
README includes :func:`render_key_table_markdown`.

Kinds decide transport QoS in the bus: ``control`` (reliable, congestion control *block*,
higher priority), ``sensor`` (best effort, *drop*, latest-only), ``event`` (low-rate,
reliable: heartbeats), ``gt`` (ground truth, for the judge/tests/viz only — no service may
subscribe), ``action`` (action request/reply).

``sim/lowstate`` is ``control``, not ``sensor``: in lockstep the sim waits for the answer
to every LowState, so one must never be dropped.
"""

from __future__ import annotations

import dataclasses
import re

from quadmanip.common import messages as m
from quadmanip.common.schema import Message

__all__ = [
    "ACTIONS",
    "DEFAULT_ROBOT",
    "Action",
    "KINDS",
    "SERVICES",
    "TOPICS",
    "Topic",
    "action_key",
    "alive_key",
    "heartbeat_key",
    "key",
    "parse_key",
    "render_key_table_markdown",
    "topic",
    "validate_robot_name",
]

PREFIX = "qm"
DEFAULT_ROBOT = "dog1"
SERVICES: tuple[str, ...] = (
    "sim",
    "locomotion",
    "manipulation",
    "perception",
    "navigation",
    "behavior",
    "viz",
)
"""Every service name that may own keys (the process registry may run a subset)."""
KINDS: tuple[str, ...] = ("control", "sensor", "event", "gt", "action")

_ROBOT_RE = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
_CHUNK_RE = re.compile(r"^[a-z][a-z0-9_]*$")
KEY_RE = re.compile(r"^qm/[a-z][a-z0-9_]{0,31}(/[a-z][a-z0-9_]*)+$")
"""Every concrete key matches this (no wildcards, no empty chunks, lower-case snake)."""


@dataclasses.dataclass(frozen=True)
class Topic:
    """One row of the key table."""

    name: str  # path below the robot, "<service>/<suffix>"
    service: str  # owning (publishing) service; for inputs, the service that consumes it
    suffix: str
    msg_type: type[Message]
    kind: str
    direction: str  # "out": the owner publishes; "in": the owner subscribes (a command)
    doc: str


def _t(
    service: str, suffix: str, msg_type: type[Message], kind: str, direction: str, doc: str
) -> Topic:
    return Topic(f"{service}/{suffix}", service, suffix, msg_type, kind, direction, doc)


_TABLE: tuple[Topic, ...] = (
    # sim (or a hardware adapter speaking the same keys): outputs
    _t("sim", "clock", m.Clock, "sensor", "out", "robot time"),
    _t("sim", "lowstate", m.LowState, "control", "out", "500 Hz joint state + IMU"),
    _t("sim", "camera/front", m.RgbdImage, "sensor", "out", "front RGB-D camera"),
    _t("sim", "camera/gripper", m.RgbdImage, "sensor", "out", "gripper RGB-D camera"),
    _t("sim", "scan", m.LaserScan, "sensor", "out", "2D LiDAR"),
    # sim inputs (the actuator layer)
    _t("sim", "leg_command", m.LegCommand, "control", "in", "leg PD + torque (locomotion)"),
    _t("sim", "arm_trajectory", m.ArmTrajectory, "control", "in", "arm trajectory (manip.)"),
    _t("sim", "gripper_command", m.GripperCommand, "control", "in", "gripper gap (manip.)"),
    _t("sim", "test/disturbance", m.Disturbance, "control", "in", "TEST-ONLY external wrench"),
    # ground truth: judge, tests and visualisation only
    _t("sim", "gt/base", m.GroundTruthPoses, "gt", "out", "true base pose (name 'base')"),
    _t("sim", "gt/objects", m.GroundTruthPoses, "gt", "out", "true object poses"),
    _t("sim", "gt/drawers", m.GroundTruthPoses, "gt", "out", "true drawer-handle poses"),
    _t("sim", "gt/contacts", m.GroundTruthContacts, "gt", "out", "true contacts"),
    _t("sim", "gt/judge", m.JudgeReport, "gt", "out", "judge verdict"),
    # locomotion
    _t("locomotion", "cmd_vel", m.BodyVelocityCommand, "control", "in", "body velocity"),
    _t("locomotion", "body_pose", m.BodyPoseCommand, "control", "in", "body pose offsets"),
    _t("locomotion", "mode", m.LocomotionMode, "control", "in", "stand/sit/damp/walk"),
    _t("locomotion", "payload", m.Payload, "control", "in", "mass in the gripper (manip.)"),
    _t("locomotion", "odometry", m.Odometry, "sensor", "out", "estimated base state (odom)"),
    _t("locomotion", "debug", m.LocomotionDebug, "sensor", "out", "gait, forces, MPC"),
) + tuple(
    _t(s, "heartbeat", m.Heartbeat, "event", "out", "1 Hz service heartbeat") for s in SERVICES
)

TOPICS: dict[str, Topic] = {t.name: t for t in _TABLE}
"""Topic name ("sim/lowstate") -> row."""


@dataclasses.dataclass(frozen=True)
class Action:
    """One known action: its goal message type (carried in ``ActionGoal.goal``)."""

    name: str  # "<service>/action/<action>"
    service: str
    action: str
    goal_type: type[Message]
    doc: str


def _a(service: str, action: str, goal_type: type[Message], doc: str) -> Action:
    return Action(f"{service}/action/{action}", service, action, goal_type, doc)


ACTIONS: dict[str, Action] = {
    a.name: a
    for a in (
        _a("manipulation", "move_to_posture", m.PostureGoal, "arm to a named posture"),
        _a("manipulation", "grasp", m.GraspGoal, "grasp an object (Algorithm 6)"),
        _a("manipulation", "place", m.PlaceGoal, "place the held object"),
        _a("manipulation", "open_drawer", m.DrawerGoal, "pull a drawer open"),
    )
}
"""Action name ("manipulation/action/grasp") -> row. Servers may offer more; these are the
ones other services rely on."""


def validate_robot_name(robot: str) -> str:
    """Return ``robot`` if it is a valid key chunk (lower-case snake, <= 32 chars)."""
    if not isinstance(robot, str) or not _ROBOT_RE.match(robot):
        raise ValueError(
            f"invalid robot name {robot!r}: use 1-32 lower-case letters, digits, '_' "
            "starting with a letter"
        )
    return robot


def _validate_chunks(path: str, what: str) -> None:
    chunks = path.split("/")
    if not path or not all(_CHUNK_RE.match(c) for c in chunks):
        raise ValueError(f"invalid {what} {path!r}: lower-case snake chunks separated by '/'")


def topic(name: str) -> Topic:
    """The table row for a topic name; KeyError lists the known names."""
    try:
        return TOPICS[name]
    except KeyError:
        raise KeyError(f"unknown topic {name!r}; known: {sorted(TOPICS)}") from None


def key(robot: str, name: str) -> str:
    """Full key for a topic in the table: ``key("dog1", "sim/lowstate")``."""
    topic(name)
    return f"{PREFIX}/{validate_robot_name(robot)}/{name}"


def heartbeat_key(robot: str, service: str) -> str:
    """``qm/<robot>/<service>/heartbeat``."""
    return key(robot, f"{service}/heartbeat")


def alive_key(robot: str, service: str) -> str:
    """Liveliness token key ``qm/<robot>/<service>/alive`` (a token, no messages)."""
    _validate_chunks(service, "service name")
    return f"{PREFIX}/{validate_robot_name(robot)}/{service}/alive"


def action_key(robot: str, service: str, action: str) -> str:
    """Base key of an action, ``qm/<robot>/<service>/action/<name>``.

    The bus's action helpers derive their request/feedback/result keys below it.
    Goals are :class:`~quadmanip.common.messages.ActionGoal` envelopes.
    """
    _validate_chunks(service, "service name")
    _validate_chunks(action, "action name")
    return f"{PREFIX}/{validate_robot_name(robot)}/{service}/action/{action}"


def parse_key(full_key: str) -> tuple[str, str]:
    """Split a full key into (robot, topic name); raises ValueError if malformed."""
    if not KEY_RE.match(full_key):
        raise ValueError(f"not a quadmanip key: {full_key!r}")
    _, robot, rest = full_key.split("/", 2)
    return robot, rest


def render_key_table_markdown(robot: str = DEFAULT_ROBOT) -> str:
    """The key table as a Markdown table (the README includes it)."""
    lines = [
        "| key | message | kind | direction | owner | what |",
        "|---|---|---|---|---|---|",
    ]
    for t in _TABLE:
        lines.append(
            f"| `{key(robot, t.name)}` | `{t.msg_type.__name__}` | {t.kind} | {t.direction} "
            f"| {t.service} | {t.doc} |"
        )
    for a in ACTIONS.values():
        lines.append(
            f"| `{action_key(robot, a.service, a.action)}` | `ActionGoal({a.goal_type.__name__})`"
            f" | action | in | {a.service} | {a.doc} |"
        )
    lines.append(
        f"| `{PREFIX}/{robot}/<service>/action/<name>` | `ActionGoal` … `ActionResult` "
        "| action | in | service | long-running requests (goal, response, feedback, result, "
        "cancel) |"
    )
    lines.append(
        f"| `{PREFIX}/{robot}/<service>/alive` | liveliness token | — | out | service "
        "| present while the service runs |"
    )
    return "\n".join(lines) + "\n"
