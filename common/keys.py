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
    "TABLE",
    "Action",
    "KINDS",
    "KeyTable",
    "SERVICES",
    "TOPICS",
    "Topic",
    "UnknownKey",
    "action_row",
    "heartbeat_row",
    "row",
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


@dataclasses.dataclass(frozen=True)
class Action:
    """One known action: its goal message type (carried in ``ActionGoal.goal``)."""

    name: str  # "<service>/action/<action>"
    service: str
    action: str
    goal_type: type[Message]
    doc: str


def row(
    service: str, suffix: str, msg_type: type[Message], kind: str, direction: str, doc: str
) -> Topic:
    """A topic row ``<service>/<suffix>`` (for :meth:`KeyTable.extended` in tests, benches)."""
    _validate_chunks(service, "service name")
    _validate_chunks(suffix, "topic suffix")
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, not {kind!r}")
    if direction not in ("in", "out"):
        raise ValueError(f"direction must be 'in' or 'out', not {direction!r}")
    return Topic(f"{service}/{suffix}", service, suffix, msg_type, kind, direction, doc)


def action_row(service: str, action: str, goal_type: type[Message], doc: str) -> Action:
    """An action row ``<service>/action/<action>``."""
    _validate_chunks(service, "service name")
    _validate_chunks(action, "action name")
    return Action(f"{service}/action/{action}", service, action, goal_type, doc)


class UnknownKey(KeyError):
    """A topic or action that is not in the key table."""

    def __str__(self) -> str:  # KeyError would print the message with quotes around it
        return str(self.args[0]) if self.args else ""


class KeyTable:
    """Topics and actions by name: the wiring contract that the bus enforces.

    The runtime uses :data:`TABLE`. Tests and benchmarks that need keys of their own build
    ``TABLE.extended(...)`` and hand it to their :class:`~quadmanip.common.bus.Bus`; the
    product table never carries them.
    """

    def __init__(self, topics: tuple[Topic, ...], actions: tuple[Action, ...]) -> None:
        self.topics: dict[str, Topic] = {}
        for t in topics:
            if t.name in self.topics:
                raise ValueError(f"topic {t.name!r} is in the key table twice")
            self.topics[t.name] = t
        self.actions: dict[str, Action] = {}
        for a in actions:
            if a.name in self.actions:
                raise ValueError(f"action {a.name!r} is in the key table twice")
            self.actions[a.name] = a

    @property
    def services(self) -> tuple[str, ...]:
        """Every service that owns a row, in table order."""
        seen = dict.fromkeys(t.service for t in self.topics.values())
        seen.update(dict.fromkeys(a.service for a in self.actions.values()))
        return tuple(seen)

    def extended(
        self,
        topics: tuple[Topic, ...] = (),
        actions: tuple[Action, ...] = (),
        services: tuple[str, ...] = (),
    ) -> KeyTable:
        """This table plus ``topics`` and ``actions``; a heartbeat row is added for every
        service that has none yet (those named in ``services``, ``topics`` and
        ``actions``)."""
        new = (*services, *(t.service for t in topics), *(a.service for a in actions))
        beats = tuple(
            heartbeat_row(s)
            for s in dict.fromkeys(new)
            if f"{s}/heartbeat" not in self.topics
            and not any(t.name == f"{s}/heartbeat" for t in topics)
        )
        return KeyTable(
            (*self.topics.values(), *topics, *beats), (*self.actions.values(), *actions)
        )

    def topic(self, name: str) -> Topic:
        """The row of topic ``name`` ("sim/lowstate"); :class:`UnknownKey` otherwise."""
        try:
            return self.topics[name]
        except KeyError:
            raise UnknownKey(
                f"topic {name!r} is not in the key table (quadmanip.common.keys); "
                f"known: {', '.join(sorted(self.topics))}"
            ) from None

    def match(self, pattern: str) -> list[Topic]:
        """Rows whose name matches a Zenoh key expression (``*`` one chunk, ``**`` any)."""
        if "*" not in pattern:
            return [self.topic(pattern)]
        rx = re.compile(
            "^"
            + "/".join(
                ".*" if c == "**" else "[^/]+" if c == "*" else re.escape(c)
                for c in pattern.split("/")
            )
            + "$"
        )
        rows = [t for t in self.topics.values() if rx.match(t.name)]
        if not rows:
            raise UnknownKey(f"no topic of the key table matches {pattern!r}")
        return rows

    def message_type(self, pattern: str) -> type[Message]:
        """The one message type of the rows matching ``pattern``."""
        types = {t.msg_type for t in self.match(pattern)}
        if len(types) != 1:
            names = sorted(t.__name__ for t in types)
            raise UnknownKey(f"{pattern!r} matches topics of several message types: {names}")
        return types.pop()

    def action(self, service: str, action: str) -> Action:
        """The row of action ``<service>/action/<action>``; :class:`UnknownKey` otherwise."""
        name = f"{service}/action/{action}"
        try:
            return self.actions[name]
        except KeyError:
            raise UnknownKey(
                f"action {name!r} is not in the key table (quadmanip.common.keys); "
                f"known: {', '.join(sorted(self.actions)) or 'none'}"
            ) from None

    def render_markdown(self, robot: str = DEFAULT_ROBOT) -> str:
        """The table as Markdown (the README and ``quadmanip keys`` show it)."""
        lines = [
            "| key | message | kind | direction | owner | what |",
            "|---|---|---|---|---|---|",
        ]
        for t in self.topics.values():
            lines.append(
                f"| `{key(robot, t.name, self)}` | `{t.msg_type.__name__}` | {t.kind} "
                f"| {t.direction} | {t.service} | {t.doc} |"
            )
        for a in self.actions.values():
            lines.append(
                f"| `{action_key(robot, a.service, a.action)}` "
                f"| `ActionGoal({a.goal_type.__name__})` | action | in | {a.service} | {a.doc} |"
            )
        lines.append(
            f"| `{PREFIX}/{robot}/<service>/action/<name>/…` | `ActionGoal` … `ActionResult` "
            "| action | in | service | goal, response, feedback, result, cancel, status |"
        )
        lines.append(
            f"| `{PREFIX}/{robot}/<service>/alive` | liveliness token | — | out | service "
            "| present while the service runs |"
        )
        return "\n".join(lines) + "\n"


def heartbeat_row(service: str) -> Topic:
    """The heartbeat row every service has."""
    return row(service, "heartbeat", m.Heartbeat, "event", "out", "1 Hz service heartbeat")


_TABLE: tuple[Topic, ...] = (
    # sim (or a hardware adapter speaking the same keys): outputs
    row("sim", "clock", m.Clock, "sensor", "out", "robot time"),
    row("sim", "lowstate", m.LowState, "control", "out", "500 Hz joint state + IMU"),
    row("sim", "camera/front", m.RgbdImage, "sensor", "out", "front RGB-D camera"),
    row("sim", "camera/gripper", m.RgbdImage, "sensor", "out", "gripper RGB-D camera"),
    row("sim", "scan", m.LaserScan, "sensor", "out", "2D LiDAR"),
    row("sim", "status", m.RobotStatus, "event", "out", "control link: command age, timeouts"),
    # sim inputs (the actuator layer)
    row("sim", "leg_command", m.LegCommand, "control", "in", "leg PD + torque (locomotion)"),
    row("sim", "arm_trajectory", m.ArmTrajectory, "control", "in", "arm trajectory (manip.)"),
    row("sim", "gripper_command", m.GripperCommand, "control", "in", "gripper gap (manip.)"),
    row("sim", "test/disturbance", m.Disturbance, "control", "in", "TEST-ONLY external wrench"),
    row("sim", "estop", m.EmergencyStop, "control", "in", "software e-stop (latched damping)"),
    # ground truth: judge, tests and visualisation only
    row("sim", "gt/base", m.GroundTruthPoses, "gt", "out", "true base pose (name 'base')"),
    row("sim", "gt/objects", m.GroundTruthPoses, "gt", "out", "true object poses"),
    row("sim", "gt/drawers", m.GroundTruthPoses, "gt", "out", "true drawer-handle poses"),
    row("sim", "gt/contacts", m.GroundTruthContacts, "gt", "out", "true contacts"),
    row("sim", "gt/judge", m.JudgeReport, "gt", "out", "judge verdict"),
    # locomotion
    row("locomotion", "cmd_vel", m.BodyVelocityCommand, "control", "in", "body velocity"),
    row("locomotion", "body_pose", m.BodyPoseCommand, "control", "in", "body pose offsets"),
    row("locomotion", "mode", m.LocomotionMode, "control", "in", "stand/sit/damp/walk/recover"),
    row("locomotion", "payload", m.Payload, "control", "in", "mass in the gripper (manip.)"),
    row("locomotion", "odometry", m.Odometry, "sensor", "out", "estimated base state (odom)"),
    row("locomotion", "debug", m.LocomotionDebug, "sensor", "out", "gait, forces, MPC"),
    row("locomotion", "health", m.LocomotionHealth, "event", "out", "ok/degraded/tripped + why"),
    # navigation
    row("navigation", "map", m.OccupancyGrid, "event", "out", "occupancy map (on change, 0.2 Hz)"),
    row(
        "navigation",
        "surface",
        m.OccupancyGrid,
        "event",
        "out",
        "mapping: surfaces seen, 2 cm raster (with the map)",
    ),
    row("navigation", "pose", m.MapPose, "sensor", "out", "base pose in the map + map->odom"),
    row("navigation", "path", m.Path, "event", "out", "the planned path (map frame)"),
    row("navigation", "costmap", m.OccupancyGrid, "sensor", "out", "costmap (1 Hz)"),
    row("navigation", "initial_pose", m.InitialPose, "event", "in", "pose hint: relocalise"),
    # perception
    row("perception", "detections", m.Detections, "sensor", "out", "detections per frame"),
    row("perception", "objects", m.ObjectTracks, "event", "out", "object memory (2 Hz)"),
    row("perception", "seen", m.SeenGrid, "event", "out", "floor and tables seen (1 Hz)"),
    # behavior
    row("behavior", "progress", m.TaskProgress, "event", "out", "task step + record (1 Hz)"),
)


TABLE = KeyTable(
    _TABLE + tuple(heartbeat_row(s) for s in SERVICES),
    (
        action_row("manipulation", "move_to_posture", m.PostureGoal, "arm to a named posture"),
        action_row("manipulation", "grasp", m.GraspGoal, "grasp an object (Algorithm 6)"),
        action_row("manipulation", "place", m.PlaceGoal, "place the held object"),
        action_row("manipulation", "open_drawer", m.DrawerGoal, "pull a drawer open"),
        action_row("navigation", "navigate_to", m.NavigateGoal, "walk to a map pose or place"),
        action_row("navigation", "approach", m.ApproachGoal, "precise final approach (Alg. 5)"),
        action_row("navigation", "explore", m.ExploreGoal, "map the house (frontiers)"),
        action_row("perception", "estimate_grasp", m.GraspRequest, "grasp pose (Sec. 4.3-4.6)"),
        action_row("perception", "locate_handle", m.HandleRequest, "drawer handle from depth"),
        action_row("behavior", "tidy_up", m.TidyUpGoal, "tidy the house (Sec. 5, 7.2)"),
    ),
)
"""The product's key table."""
TOPICS: dict[str, Topic] = TABLE.topics
"""Topic name ("sim/lowstate") -> row."""
ACTIONS: dict[str, Action] = TABLE.actions
"""Action name ("manipulation/action/grasp") -> row."""


def topic(name: str) -> Topic:
    """The product table's row for a topic name; :class:`UnknownKey` lists the known names."""
    return TABLE.topic(name)


def key(robot: str, name: str, table: KeyTable | None = None) -> str:
    """Full key for a topic in the table: ``key("dog1", "sim/lowstate")``."""
    (table or TABLE).topic(name)
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
    """The product key table as Markdown (the README includes it)."""
    return TABLE.render_markdown(robot)
