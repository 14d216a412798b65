"""Every quadmanip message: frozen, typed dataclasses with a schema name and version.

Conventions (docs/conventions.md): SI units; x forward, y left, z up; quaternions
[w, x, y, z]; ``stamp`` is robot time in seconds (sim time in simulation). Joint arrays of
16 are legs FL(abad, hip, knee), FR, RL, RR then arm j1..j4; leg arrays have 12
(the layout: :mod:`quadmanip.common.joint_layout`).

Arrays accept lists/tuples on construction (``LegCommand(stamp=0.0, tick=1, q_des=[0]*12,
...)``); they are converted to the declared dtype, validated (shape, finiteness) and made
read-only. Codec and validation live in :mod:`quadmanip.common.schema`.

To add a message: declare it here with ``@message("qm.Name", (1, 0))``; add fields to an
existing one only at the end *with a default* and bump the minor version; anything else
(rename, retype, remove) bumps the major version. The key table is in ``keys.py``.
"""

from __future__ import annotations

import math

import numpy as np
from quadmanip.common.joint_layout import N_ARM_JOINTS, N_JOINTS, N_LEG_JOINTS
from quadmanip.common.schema import (
    Message,
    MessageError,
    array,
    decode,
    encode,
    field_specs,
    message,
    message_types,
    registry,
    string,
    string_list,
)

__all__ = [
    "ActionCancel",
    "ActionFeedback",
    "ActionGoal",
    "ActionResponse",
    "ActionResult",
    "ArmTrajectory",
    "BodyPoseCommand",
    "BodyVelocityCommand",
    "Clock",
    "Detections",
    "Disturbance",
    "EmergencyStop",
    "DrawerGoal",
    "GraspGoal",
    "GraspRequest",
    "HandleRequest",
    "GripperCommand",
    "GroundTruthContacts",
    "GroundTruthPoses",
    "Heartbeat",
    "Imu",
    "InitialPose",
    "JointState",
    "HEALTH_STATES",
    "JUDGE_LOCATIONS",
    "JudgeReport",
    "LaserScan",
    "LegCommand",
    "LocomotionDebug",
    "LocomotionHealth",
    "LocomotionMode",
    "LowState",
    "Message",
    "MessageError",
    "ObjectTracks",
    "SEEN_FLOOR",
    "SEEN_TABLE",
    "SeenGrid",
    "Odometry",
    "Payload",
    "PlaceGoal",
    "PostureGoal",
    "RgbdImage",
    "RobotStatus",
    "TASK_STATES",
    "TaskProgress",
    "TidyUpGoal",
    "decode",
    "encode",
    "example",
    "message_types",
    "registry",
    "ApproachGoal",
    "ExploreGoal",
    "MapPose",
    "NAV_OUTCOMES",
    "NavigateGoal",
    "NavigationResult",
    "OccupancyGrid",
    "Path",
]

# Array sizes of the joint layout (legs + arm in wire order): common/joint_layout.py.

_MAX_TEXT = 4096  # free-text reasons / feedback


def _unit_quat(q: np.ndarray, what: str) -> None:
    """Reject quaternions that are far from unit norm (a zero quaternion is no rotation)."""
    w, x, y, z = q.tolist()
    n = w * w + x * x + y * y + z * z
    if not 0.81 <= n <= 1.21:  # |q| within 10 %: generous for float32 sources and noise
        raise MessageError(f"{what} must be a unit quaternion [w,x,y,z], |q|={math.sqrt(n):.3g}")


# --------------------------------------------------------------------------- time / state


@message("qm.Clock", (1, 0))
class Clock(Message):
    """Robot time, published by the sim (sim time) or a hardware adapter (wall time)."""

    stamp: float


@message("qm.JointState", (1, 0))
class JointState(Message):
    """Measured joint state: 16 joints (12 legs + 4 arm) and the gripper.

    ``tau`` is the torque the actuator layer applied (N·m); ``gripper_gap`` the finger
    gap (m); ``gripper_effort`` the gripper actuator force (N, >= 0 when squeezing).
    """

    stamp: float
    q: np.ndarray = array("f8", (N_JOINTS,))
    dq: np.ndarray = array("f8", (N_JOINTS,))
    tau: np.ndarray = array("f8", (N_JOINTS,))
    gripper_gap: float = 0.0
    gripper_effort: float = 0.0


@message("qm.Imu", (1, 0))
class Imu(Message):
    """IMU sample: orientation [w,x,y,z] of the base in the world/odom frame, body-frame
    angular velocity (rad/s) and specific force (m/s², +9.81 z when standing still)."""

    stamp: float
    orientation: np.ndarray = array("f8", (4,))
    angular_velocity: np.ndarray = array("f8", (3,))
    linear_acceleration: np.ndarray = array("f8", (3,))

    def _check(self) -> None:
        _unit_quat(self.orientation, "Imu.orientation")


@message("qm.LowState", (1, 0))
class LowState(Message):
    """The control-rate (500 Hz) state from sim/hardware. ``tick`` counts control ticks;
    a LegCommand echoes it (lockstep)."""

    stamp: float
    tick: int
    joints: JointState
    imu: Imu


# --------------------------------------------------------------------------- commands


@message("qm.RobotStatus", (1, 1))
class RobotStatus(Message):
    """The robot side's view of the control link (sim or hardware adapter), every
    ``1/status_rate`` s: ``ticks`` control ticks in the window, of which ``stale_ticks``
    had no new leg command (the last one was reused); the age (in ticks) of the leg
    command applied, median and max over the window; ``leg_timeouts``: times the legs fell
    back to damping because commands stopped (total since the start); ``rtf``: sim time
    over wall time in the window (1.0 on hardware); ``leg_mode``: active, damping, or
    estop (an emergency stop is latched; 1.1)."""

    stamp: float
    ticks: int = 0
    stale_ticks: int = 0
    cmd_age_p50: float = 0.0
    cmd_age_max: int = 0
    leg_timeouts: int = 0
    leg_mode: str = string(choices=("active", "damping", "estop"), default="damping")
    rtf: float = 0.0
    mode: str = string(max_len=16, default="")

    def _check(self) -> None:
        if min(self.ticks, self.stale_ticks, self.cmd_age_max, self.leg_timeouts) < 0:
            raise MessageError("RobotStatus counts must be >= 0")
        if self.stale_ticks > self.ticks:
            raise MessageError("RobotStatus.stale_ticks exceeds ticks")


@message("qm.LegCommand", (1, 0))
class LegCommand(Message):
    """Per-joint PD + feed-forward command for the 12 leg joints:
    tau = kp (q_des - q) + kd (dq_des - dq) + tau_ff, clamped by the actuator layer.
    ``tick`` echoes the LowState tick this command answers."""

    stamp: float
    tick: int
    q_des: np.ndarray = array("f8", (N_LEG_JOINTS,))
    dq_des: np.ndarray = array("f8", (N_LEG_JOINTS,))
    kp: np.ndarray = array("f8", (N_LEG_JOINTS,), nonneg=True)
    kd: np.ndarray = array("f8", (N_LEG_JOINTS,), nonneg=True)
    tau_ff: np.ndarray = array("f8", (N_LEG_JOINTS,))


@message("qm.ArmTrajectory", (1, 1))
class ArmTrajectory(Message):
    """Time-stamped arm joint trajectory (robot time ``t``, strictly increasing) that the
    actuator layer interpolates, with PD gains for the 4 arm joints and a feed-forward
    torque per knot (N m; e.g. the arm's gravity torque), interpolated like the positions:
    tau = kp (q(t) - q) + kd (dq(t) - dq) + tau_ff(t), clamped by the actuator layer.

    1.1: ``tau_ff`` (N, 4) added. Left out (or sent by a 1.0 sender) it is zeros; a
    received or constructed message always carries the full (N, 4) array.
    """

    stamp: float
    t: np.ndarray = array("f8", (None,), max_elements=100_000)
    q: np.ndarray = array("f8", (None, N_ARM_JOINTS), max_elements=400_000)
    dq: np.ndarray = array("f8", (None, N_ARM_JOINTS), max_elements=400_000)
    kp: np.ndarray = array("f8", (N_ARM_JOINTS,), nonneg=True)
    kd: np.ndarray = array("f8", (N_ARM_JOINTS,), nonneg=True)
    tau_ff: np.ndarray = array(
        "f8", (None, N_ARM_JOINTS), max_elements=400_000, default=np.zeros((0, N_ARM_JOINTS))
    )

    def _check(self) -> None:
        n = self.t.shape[0]
        if n < 1:
            raise MessageError("ArmTrajectory needs at least one point")
        if self.q.shape[0] != n or self.dq.shape[0] != n:
            raise MessageError(
                f"ArmTrajectory: t has {n} points but q {self.q.shape[0]}, dq {self.dq.shape[0]}"
            )
        if self.tau_ff.shape[0] == 0:  # not given: no feed-forward
            zeros = np.zeros((n, N_ARM_JOINTS))
            zeros.flags.writeable = False
            self.__dict__["tau_ff"] = zeros
        elif self.tau_ff.shape[0] != n:
            raise MessageError(f"ArmTrajectory: t has {n} points but tau_ff {self.tau_ff.shape[0]}")
        if n > 1 and not bool(np.all(np.diff(self.t) > 0.0)):
            raise MessageError("ArmTrajectory.t must be strictly increasing")


@message("qm.GripperCommand", (1, 0))
class GripperCommand(Message):
    """Target finger gap (m, >= 0) with a squeeze force limit (N, >= 0)."""

    stamp: float
    gap: float
    max_force: float

    def _check(self) -> None:
        if self.gap < 0.0 or self.max_force < 0.0:
            raise MessageError("GripperCommand: gap and max_force must be >= 0")


@message("qm.BodyVelocityCommand", (1, 0))
class BodyVelocityCommand(Message):
    """Body velocity in the base frame: vx, vy (m/s) and yaw rate wz (rad/s)."""

    stamp: float
    vx: float
    vy: float
    wz: float


@message("qm.BodyPoseCommand", (1, 0))
class BodyPoseCommand(Message):
    """Body pose offsets from the nominal standing pose (m, rad), used while standing
    (e.g. Algorithm 6's moveCOM and crouching for vertical grasps)."""

    stamp: float
    z_offset: float = 0.0
    x_offset: float = 0.0
    y_offset: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0


@message("qm.Payload", (1, 0))
class Payload(Message):
    """What the gripper holds, for the balance controller's model: ``mass`` (kg, 0 = empty)
    at the tool centre. Sent by manipulation when its grip verdict changes and once a
    second while holding."""

    stamp: float
    mass: float = 0.0
    object_name: str = ""

    def _check(self) -> None:
        if not (math.isfinite(self.mass) and 0.0 <= self.mass <= 10.0):
            raise MessageError(f"Payload.mass must be in [0, 10] kg, got {self.mass}")


@message("qm.LocomotionMode", (1, 1))
class LocomotionMode(Message):
    """Locomotion mode request: stand, sit, damp (passive damping), walk, or recover.

    1.1: ``recover`` clears a latched safety trip (the explicit reset) and gets the robot
    up: self-righting if it lies on a side, then standing up (docs/locomotion.md).
    """

    stamp: float
    mode: str = string(choices=("stand", "sit", "damp", "walk", "recover"))


HEALTH_STATES: tuple[str, ...] = ("ok", "degraded", "tripped")


@message("qm.LocomotionHealth", (1, 0))
class LocomotionHealth(Message):
    """Whether locomotion can be trusted right now (10 Hz, and at once on a change).

    ``state``: ``ok``; ``degraded`` (it cannot keep up with the control deadline, so it
    limits speed on purpose; ``max_speed`` is the forward speed it accepts now) or
    ``tripped`` (the safety checker latched safe mode: legs damped until a ``recover``
    mode command). ``reason`` says why in words. ``phase`` is the controller's phase
    (damp, sit, standing_up, balance, walk, stopping, safe, righting). ``upright`` is False
    when the IMU says the robot lies on a side or its back. Counters are totals since the
    start: ticks never answered (``missed_ticks``), answers later than the deadline
    (``late_answers``), MPC steps longer than their budget (``mpc_overruns``), and
    what the robot side reports (``leg_timeouts``; ``cmd_age_ticks``: median age of the
    leg command it applied, last window). ``scheduling`` says how the control loop runs
    (e.g. "SCHED_FIFO priority 80 on 9 threads").
    """

    stamp: float
    state: str = string(choices=HEALTH_STATES)
    reason: str = string(max_len=256, default="")
    phase: str = string(max_len=32, default="")
    upright: bool = True
    scheduling: str = string(max_len=128, default="")
    max_speed: float = 0.0
    missed_ticks: int = 0
    late_answers: int = 0
    mpc_overruns: int = 0
    answer_ms_p99: float = 0.0
    leg_timeouts: int = 0
    cmd_age_ticks: float = 0.0
    degraded_episodes: int = 0
    trips: int = 0
    rejected_commands: int = 0

    def _check(self) -> None:
        if self.state != "ok" and not self.reason:
            raise MessageError(f"LocomotionHealth: a {self.state} state needs a reason")
        counts = (self.missed_ticks, self.late_answers, self.mpc_overruns, self.leg_timeouts,
                  self.degraded_episodes, self.trips, self.rejected_commands)  # fmt: skip
        if min(counts) < 0 or self.max_speed < 0 or self.cmd_age_ticks < 0:
            raise MessageError("LocomotionHealth counters and speeds must be >= 0")


# --------------------------------------------------------------------------- sensors


@message("qm.RgbdImage", (1, 0))
class RgbdImage(Message):
    """An RGB-D frame with intrinsics and the camera pose in the base frame.

    ``depth`` is metres along the optical axis, float32, finite, >= 0; 0 means no return
    (we avoid NaN/inf on the wire so every float stays checkable). ``rgb`` may be empty
    (shape (0, 0, 3)) for a depth-only frame, else it matches depth's H×W. ``K`` is the
    OpenCV intrinsic matrix; ``position``/``orientation`` ([w,x,y,z]) are base_T_camera in
    the OpenCV optical convention (x right, y down, z forward).
    """

    stamp: float
    camera: str
    rgb: np.ndarray = array("u1", (None, None, 3))
    depth: np.ndarray = array("f4", (None, None), nonneg=True)
    K: np.ndarray = array("f8", (3, 3))
    position: np.ndarray = array("f8", (3,))
    orientation: np.ndarray = array("f8", (4,))

    def _check(self) -> None:
        if self.rgb.size and self.rgb.shape[:2] != self.depth.shape:
            raise MessageError(
                f"RgbdImage: rgb {self.rgb.shape[:2]} and depth {self.depth.shape} differ"
            )
        _unit_quat(self.orientation, "RgbdImage.orientation")


@message("qm.LaserScan", (1, 0))
class LaserScan(Message):
    """A 2D LiDAR scan in the ``lidar`` frame, counter-clockwise from ``angle_min``.

    Ranges in metres; a ray with no return is 0.0 (below ``range_min``), never inf/NaN.
    """

    stamp: float
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray = array("f4", (None,), nonneg=True, max_elements=1 << 16)

    def _check(self) -> None:
        if not 0.0 <= self.range_min <= self.range_max:
            raise MessageError("LaserScan: need 0 <= range_min <= range_max")


@message("qm.Odometry", (1, 0))
class Odometry(Message):
    """Base pose in the odom frame ([w,x,y,z]) and base-frame linear/angular velocity."""

    stamp: float
    position: np.ndarray = array("f8", (3,))
    orientation: np.ndarray = array("f8", (4,))
    linear_velocity: np.ndarray = array("f8", (3,))
    angular_velocity: np.ndarray = array("f8", (3,))

    def _check(self) -> None:
        _unit_quat(self.orientation, "Odometry.orientation")


@message("qm.LocomotionDebug", (1, 0))
class LocomotionDebug(Message):
    """Locomotion internals for plots: gait phase in [0, 1) per leg, scheduled contact,
    foot forces (N, world frame, ground on robot) per leg, MPC solve time and the MPC's
    predicted base positions over the horizon."""

    stamp: float
    gait_phase: np.ndarray = array("f8", (4,))
    contact: np.ndarray = array("?", (4,))
    foot_forces: np.ndarray = array("f8", (4, 3))
    mpc_solve_ms: float = 0.0
    mpc_predicted_positions: np.ndarray = array(
        "f8", (None, 3), max_elements=30_000, default=np.zeros((0, 3))
    )


# --------------------------------------------------------------------------- service / actions


@message("qm.Heartbeat", (1, 0))
class Heartbeat(Message):
    """1 Hz service heartbeat: ``seq`` increments; ``state`` is the lifecycle state
    (e.g. starting, running, stopping, error)."""

    stamp: float
    service: str
    seq: int
    state: str = string(max_len=64)


@message("qm.ActionGoal", (1, 0))
class ActionGoal(Message):
    """Request to start action ``action`` with any registered message as the goal."""

    stamp: float
    goal_id: str
    action: str
    goal: Message


@message("qm.ActionResponse", (1, 0))
class ActionResponse(Message):
    """Accepted or rejected (with a reason) answer to an ActionGoal."""

    stamp: float
    goal_id: str
    accepted: bool
    reason: str = string(max_len=_MAX_TEXT, default="")


@message("qm.ActionFeedback", (1, 0))
class ActionFeedback(Message):
    """Progress in [0, 1] (finite) and a short human-readable text."""

    stamp: float
    goal_id: str
    progress: float
    text: str = string(max_len=_MAX_TEXT, default="")


@message("qm.ActionResult", (1, 0))
class ActionResult(Message):
    """Final outcome of a goal; ``result`` optionally carries a message."""

    stamp: float
    goal_id: str
    status: str = string(choices=("succeeded", "failed", "canceled"))
    reason: str = string(max_len=_MAX_TEXT, default="")
    result: Message | None = None


@message("qm.ActionCancel", (1, 0))
class ActionCancel(Message):
    """Ask the server to cancel goal ``goal_id``."""

    stamp: float
    goal_id: str


# Goals of the manipulation actions (frame: base, unless said otherwise).


@message("qm.PostureGoal", (1, 0))
class PostureGoal(Message):
    """Move the arm to a named posture from the manipulation config (e.g. ``stow``)."""

    stamp: float
    posture: str
    duration: float = 0.0  # 0: let the planner choose from velocity limits


@message("qm.GraspGoal", (1, 4))
class GraspGoal(Message):
    """Grasp an object at ``position`` (base frame) about ``yaw`` (rad, base frame);
    ``approach`` vertical (from above), horizontal, or auto; ``width`` is the object's
    width across the fingers (m); ``tilt`` (rad, vertical grasps) leans the tool forward so
    the pads lie flat on a flared wall such as a bowl's (1.1: added, default 0; at most
    ``robot_description.GRASP_MAX_TILT``); ``mass``
    (kg) is the object's, from perception's catalogue, for the balance controller while it
    is held (1.2: added; 0 = unknown, manipulation assumes its configured default);
    ``hang`` (m) is how far the object reaches below the grasp point, from perception's
    model of it, so a place releases it just above the region (1.3: added; 0 = unknown,
    manipulation measures it for a grasp near the floor, else assumes 5 cm); ``center``
    (base frame, like ``position``) is the object's middle, so a place puts the object,
    not the grasp point, where it is asked to (a spoon is grasped at its bowl, 6.5 cm off
    its middle) (1.4: added; empty = unknown: the grasp point is placed)."""

    stamp: float
    position: np.ndarray = array("f8", (3,))
    yaw: float = 0.0
    approach: str = string(choices=("auto", "vertical", "horizontal"), default="auto")
    width: float = 0.05
    object_name: str = ""
    tilt: float = 0.0
    mass: float = 0.0
    hang: float = 0.0
    center: np.ndarray = array("f8", (None,), max_elements=3, default=[])

    def _check(self) -> None:
        for field in ("mass", "hang"):
            v = getattr(self, field)
            if not (math.isfinite(v) and v >= 0.0):
                raise MessageError(f"GraspGoal.{field} must be finite and >= 0, got {v}")
        if len(self.center) not in (0, 3):
            raise MessageError(
                f"GraspGoal.center must be empty or 3 numbers, got {len(self.center)}"
            )


@message("qm.PlaceGoal", (1, 1))
class PlaceGoal(Message):
    """Place the held object at ``position`` (base frame), released from above. With
    ``turn`` the gripper first turns to ``yaw`` (the grasp's convention: 0 = fingers along
    the body y axis), e.g. to lay a long object along a narrow region; without it the
    grasp's roll is kept (1.1: ``turn`` added; before, ``yaw`` was ignored)."""

    stamp: float
    position: np.ndarray = array("f8", (3,))
    yaw: float = 0.0
    turn: bool = False


@message("qm.DrawerGoal", (1, 0))
class DrawerGoal(Message):
    """Open a drawer: handle at ``handle_position`` (base frame), pulled ``distance`` (m)
    along ``pull_direction`` (unit vector, base frame)."""

    stamp: float
    handle_position: np.ndarray = array("f8", (3,))
    pull_direction: np.ndarray = array("f8", (3,))
    distance: float = 0.15

    def _check(self) -> None:
        n = float(np.linalg.norm(self.pull_direction))
        if abs(n - 1.0) > 0.05:
            raise MessageError(f"DrawerGoal.pull_direction must be a unit vector, |d|={n:.3g}")


# --------------------------------------------------------------------------- navigation

NAV_OUTCOMES: tuple[str, ...] = ("reached", "blocked", "no_path", "cancelled", "rejected", "lost")


def _check_heading(v: float, what: str) -> None:
    if not (math.isfinite(v) and abs(v) <= 4.0 * math.pi):
        raise MessageError(f"{what} must be a finite angle in radians, got {v}")


@message("qm.OccupancyGrid", (1, 0))
class OccupancyGrid(Message):
    """A 2D occupancy grid (ROS's convention): ``data[row, col]`` is -1 unknown or the
    occupancy probability in percent 0..100; row 0 is the lowest y. Cell (row, col) covers
    ``origin[:2] + resolution * [col, row]`` .. ``+ resolution`` in ``frame`` (the map's
    corner at ``origin``, rotated by ``origin[2]``, usually 0)."""

    stamp: float
    origin: np.ndarray = array("f8", (3,))
    data: np.ndarray = array("i1", (None, None), max_elements=4_000_000)
    resolution: float = 0.05
    frame: str = string(max_len=64, default="map")

    def _check(self) -> None:
        if not (math.isfinite(self.resolution) and 0.005 <= self.resolution <= 1.0):
            raise MessageError(
                f"OccupancyGrid.resolution must be in [0.005, 1] m, got {self.resolution}"
            )
        if self.data.size and (int(self.data.min()) < -1 or int(self.data.max()) > 100):
            raise MessageError("OccupancyGrid.data must hold -1 (unknown) or 0..100")


@message("qm.MapPose", (1, 0))
class MapPose(Message):
    """Where navigation believes the base is in the ``map`` frame (x, y, yaw) with the
    covariance of (x, y, yaw), and the map->odom correction (x, y, yaw) that takes the
    odometry's pose into the map. ``status``: ``localized``; ``converging`` (spread
    wider than the configured bound, e.g. after a global start); ``mapping`` (the pose of
    the map being built); ``lost`` (no recent scan or odometry)."""

    stamp: float
    x: float
    y: float
    yaw: float
    covariance: np.ndarray = array("f8", (3, 3))
    map_to_odom: np.ndarray = array("f8", (3,), default=np.zeros(3))
    status: str = string(
        choices=("localized", "converging", "mapping", "lost"), default="localized"
    )


@message("qm.InitialPose", (1, 0))
class InitialPose(Message):
    """A hint of where the base is in the ``map`` frame (x, y, yaw), with the standard
    deviations of that belief (``std_xy`` m on x and y, ``std_yaw`` rad): ROS's
    ``/initialpose``. Navigation re-initialises its localisation around it when it is not
    localised yet or its estimate disagrees strongly with the hint (services/navigation);
    the behavior service sends it when navigation comes back after a restart, from the
    last pose navigation gave before (carried along by the odometry since). ``source``
    says who sent it and why, for the log."""

    stamp: float
    x: float
    y: float
    yaw: float
    std_xy: float = 0.1
    std_yaw: float = 0.1
    source: str = string(max_len=256, default="")

    def _check(self) -> None:
        _check_heading(self.yaw, "InitialPose.yaw")
        for name in ("std_xy", "std_yaw"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 < v <= 100.0):
                raise MessageError(f"InitialPose.{name} must be in (0, 100], got {v}")


@message("qm.Path", (1, 0))
class Path(Message):
    """A planned path: poses (x, y, yaw) in ``frame``, start first."""

    stamp: float
    poses: np.ndarray = array("f8", (None, 3), max_elements=3 * 100_000)
    frame: str = string(max_len=64, default="map")


@message("qm.NavigateGoal", (1, 1))
class NavigateGoal(Message):
    """Walk to a pose in the map: ``place`` names a place of the map's places file (its
    stand pose), else ``pose`` (x, y, yaw in ``frame``, ``map`` or ``odom``). Reached
    within ``tolerance_xy`` (m) and ``tolerance_yaw`` (rad); ``ignore_yaw`` arrives facing
    any way. ``pass_through`` (1.1: added): reached as soon as the robot is within the
    tolerances, still under way and not stopped (an approach that follows takes it on)."""

    stamp: float
    place: str = string(max_len=128, default="")
    pose: np.ndarray = array("f8", (3,), default=np.zeros(3))
    frame: str = string(choices=("map", "odom"), default="map")
    tolerance_xy: float = 0.05
    tolerance_yaw: float = 0.05
    ignore_yaw: bool = False
    pass_through: bool = False

    def _check(self) -> None:
        for f in ("tolerance_xy", "tolerance_yaw"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0.0):
                raise MessageError(f"NavigateGoal.{f} must be > 0, got {v}")


@message("qm.ApproachGoal", (1, 1))
class ApproachGoal(Message):
    """A precise final approach (Algorithm 5's move to the probing area; standing square
    to a drawer or a box): stand so that ``target`` (x, y in ``frame``: ``base`` at the
    goal's stamp, or ``odom``) lies ``standoff`` m straight ahead of the base, facing
    ``heading`` (rad, in ``frame``), or facing the target from where the robot is when
    ``face_target``. Reached within ``tolerance_xy`` (m) and ``tolerance_yaw`` (rad).
    ``turn_free`` (1.1: added): the stance may turn about the target from ``heading`` to
    the nearest heading whose trunk stands clear of the furniture in navigation's map,
    reaching with its nose (not its middle) into a keepout area: an object on a table by
    one of its legs."""

    stamp: float
    target: np.ndarray = array("f8", (2,))
    frame: str = string(choices=("base", "odom"), default="odom")
    standoff: float = 0.5
    heading: float = 0.0
    face_target: bool = False
    tolerance_xy: float = 0.01
    tolerance_yaw: float = 0.0175
    turn_free: bool = False

    def _check(self) -> None:
        if not (math.isfinite(self.standoff) and 0.0 <= self.standoff <= 3.0):
            raise MessageError(f"ApproachGoal.standoff must be in [0, 3] m, got {self.standoff}")
        _check_heading(self.heading, "ApproachGoal.heading")
        for f in ("tolerance_xy", "tolerance_yaw"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0.0):
                raise MessageError(f"ApproachGoal.{f} must be > 0, got {v}")


@message("qm.ExploreGoal", (1, 0))
class ExploreGoal(Message):
    """Explore (mapping mode): walk to frontiers until none reachable is left or
    ``max_time`` (s of robot time, 0 = no limit) has passed."""

    stamp: float
    max_time: float = 0.0


@message("qm.NavigationResult", (1, 0))
class NavigationResult(Message):
    """How a navigation action ended (the ``result`` of its ActionResult): ``outcome`` one of
    ``NAV_OUTCOMES``, the final pose (x, y, yaw) in the goal's frame, the remaining
    position and heading errors, the distance walked and the time taken (robot time)."""

    stamp: float
    outcome: str = string(choices=NAV_OUTCOMES, default="reached")
    reason: str = string(max_len=_MAX_TEXT, default="")
    final_pose: np.ndarray = array("f8", (3,), default=np.zeros(3))
    error_xy: float = 0.0
    error_yaw: float = 0.0
    distance: float = 0.0
    duration: float = 0.0


# --------------------------------------------------------------------------- perception


def _same_rows(msg: Message, what: str, n: int, *fields: str) -> None:
    for f in fields:
        if len(getattr(msg, f)) != n:
            raise MessageError(f"{what}.{f} has {len(getattr(msg, f))} rows, labels have {n}")


@message("qm.Detections", (1, 0))
class Detections(Message):
    """The detector's output for one camera frame (``frame_stamp``): per object its class
    label, score and box (pixels x0, y0, x1, y1), and, where its depth pixels allowed,
    its centroid and axis-aligned extent in the ``odom`` frame (``located`` 0 otherwise,
    then centroid and extent are 0)."""

    stamp: float
    camera: str
    frame_stamp: float = 0.0
    labels: list[str] = string_list(default_empty=True)
    scores: np.ndarray = array("f4", (None,), default=np.zeros(0))
    boxes: np.ndarray = array("f4", (None, 4), default=np.zeros((0, 4)))
    centroids: np.ndarray = array("f8", (None, 3), default=np.zeros((0, 3)))
    extents: np.ndarray = array("f4", (None, 3), nonneg=True, default=np.zeros((0, 3)))
    located: np.ndarray = array("u1", (None,), default=np.zeros(0))

    def _check(self) -> None:
        n = len(self.labels)
        _same_rows(self, "Detections", n, "scores", "boxes", "centroids", "extents", "located")


@message("qm.ObjectTracks", (1, 0))
class ObjectTracks(Message):
    """Perception's object memory: what it has seen where. Per track an id (stable while
    it lives), class label, centroid and extent in ``odom``, confidence (0-1), number of
    observations, last-seen stamp and whether it is ``confirmed`` (seen often enough to
    act on). ``map_centroids`` are the centroids in the ``map`` frame when navigation has
    published a pose (``in_map`` true), else equal to the odom ones."""

    stamp: float
    ids: np.ndarray = array("i4", (None,), default=np.zeros(0))
    labels: list[str] = string_list(default_empty=True)
    centroids: np.ndarray = array("f8", (None, 3), default=np.zeros((0, 3)))
    extents: np.ndarray = array("f4", (None, 3), nonneg=True, default=np.zeros((0, 3)))
    confidences: np.ndarray = array("f4", (None,), default=np.zeros(0))
    observations: np.ndarray = array("i4", (None,), default=np.zeros(0))
    last_seen: np.ndarray = array("f8", (None,), default=np.zeros(0))
    confirmed: np.ndarray = array("u1", (None,), default=np.zeros(0))
    map_centroids: np.ndarray = array("f8", (None, 3), default=np.zeros((0, 3)))
    in_map: bool = False

    def _check(self) -> None:
        n = len(self.labels)
        _same_rows(
            self, "ObjectTracks", n, "ids", "centroids", "extents", "confidences",
            "observations", "last_seen", "confirmed", "map_centroids",
        )  # fmt: skip


SEEN_FLOOR = 1  # SeenGrid bit: the floor was seen in the cell
SEEN_TABLE = 2  # SeenGrid bit: a table top was seen in the cell


@message("qm.SeenGrid", (1, 0))
class SeenGrid(Message):
    """Where perception's cameras have seen the floor (bit 1 of ``cells``) and table tops
    (bit 2), within the range its detector finds objects reliably, in the ``map`` frame:
    cell (row, col) covers ``origin + resolution * (col, row)`` to ``+ resolution``.
    ``floor_at`` and ``table_at`` hold the stamp of each cell's latest view (0: never), so
    a reader can ask what was seen since something may have moved (an object dropped)."""

    stamp: float
    origin: np.ndarray = array("f8", (2,), default=[0.0, 0.0])
    resolution: float = 0.1
    cells: np.ndarray = array("u1", (None, None), max_elements=4_000_000,
                              default=np.zeros((0, 0), np.uint8))  # fmt: skip
    floor_at: np.ndarray = array("f4", (None, None), nonneg=True, max_elements=4_000_000,
                                 default=np.zeros((0, 0), np.float32))  # fmt: skip
    table_at: np.ndarray = array("f4", (None, None), nonneg=True, max_elements=4_000_000,
                                 default=np.zeros((0, 0), np.float32))  # fmt: skip

    def _check(self) -> None:
        if not (math.isfinite(self.resolution) and 0.01 <= self.resolution <= 1.0):
            raise MessageError(f"SeenGrid.resolution must be in [0.01, 1] m, got {self.resolution}")
        if self.cells.size and int(self.cells.max()) > SEEN_FLOOR | SEEN_TABLE:
            raise MessageError("SeenGrid.cells hold bits 1 (floor) and 2 (table top) only")
        if not (self.floor_at.shape == self.table_at.shape == self.cells.shape):
            raise MessageError(
                f"SeenGrid: cells {self.cells.shape}, floor_at {self.floor_at.shape} and "
                f"table_at {self.table_at.shape} must have one shape"
            )

    def seen(self, xy: np.ndarray, bit: int, since: float = -math.inf) -> np.ndarray:
        """Whether each map point (N, 2) lies in a cell with ``bit`` (``SEEN_FLOOR``,
        ``SEEN_TABLE``) set and viewed at or after ``since``; points off the grid are
        unseen."""
        q = np.asarray(xy, dtype=float).reshape(-1, 2)
        r = float(self.resolution)
        col = np.floor((q[:, 0] - self.origin[0]) / r + 1e-9).astype(np.int64)
        row = np.floor((q[:, 1] - self.origin[1]) / r + 1e-9).astype(np.int64)
        h, w = self.cells.shape if self.cells.ndim == 2 else (0, 0)
        ok = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        at = self.table_at if bit == SEEN_TABLE else self.floor_at
        out = np.zeros(len(q), bool)
        rr, cc = row[ok], col[ok]
        out[ok] = ((self.cells[rr, cc] & bit) > 0) & (at[rr, cc] >= since)
        return out


@message("qm.GraspRequest", (1, 0))
class GraspRequest(Message):
    """Ask perception for a grasp (its ``GraspGoal`` comes back as the action's result):
    of track ``track_id`` (>= 0), else of the best-seen object of class ``label``, else of
    the object nearest the image centre; seen by ``camera`` (``gripper_camera`` probes
    vertically, ``front_camera`` horizontally; empty: the camera whose frame holds the
    target best). ``max_distance`` (m, from the base; 0 = the configured reach) rejects
    targets beyond it."""

    stamp: float
    track_id: int = -1
    label: str = string(max_len=64, default="")
    camera: str = string(choices=("", "gripper_camera", "front_camera"), default="")
    max_distance: float = 0.0

    def _check(self) -> None:
        if not (math.isfinite(self.max_distance) and self.max_distance >= 0.0):
            raise MessageError(f"GraspRequest.max_distance must be >= 0, got {self.max_distance}")


@message("qm.HandleRequest", (1, 0))
class HandleRequest(Message):
    """Ask perception for a drawer handle near ``position`` (``base`` frame, within about
    10 cm) from the front camera; the action's result is a ``DrawerGoal`` (handle position
    and pull direction in the base frame, ``distance`` copied from here)."""

    stamp: float
    position: np.ndarray = array("f8", (3,))
    distance: float = 0.15


# --------------------------------------------------------------------------- behavior

#: How the tidy-up task stands (``TaskProgress.state``): not started, running, or how it
#: ended: everything searched and nothing graspable left (done), its time budget spent,
#: cancelled, or unable to go on (failed, the reason says why).
TASK_STATES: tuple[str, ...] = ("idle", "running", "done", "budget", "canceled", "failed")


@message("qm.TaskProgress", (1, 1))
class TaskProgress(Message):
    """The tidy-up task's account of itself (``behavior/progress`` at every step change and
    about once a second; also the result of ``behavior/action/tidy_up``): ``state`` (one of
    ``TASK_STATES``) and why it ended (``reason``), the current ``step`` in words (e.g.
    ``grasp: mug#3``) and object, robot time since the start against the ``budget``
    (s, 0 = none), the drawers opened (names of the places file), the zones searched of
    ``zones_total``, how many objects were given up (``failed``), and per object found
    (parallel lists): its class, perception's track id, when it was first seen (robot
    time), whether it was grasped, placed (the task's own claim: the judge decides), given
    up, the robot time spent on it, the failures it cost and their reasons (one line
    each, ``step: reason``, joined with newlines) and where it was first seen (map
    frame, m). ``taken_track_ids`` (1.1: added): the track each grasp took up (the
    object's track at that grasp, in perception's current numbering), in order. A
    record's own ``object_track_ids`` may later name another track, where its object
    fell out of the gripper or its box: that track is an object lying there, not taken."""

    stamp: float
    state: str = string(choices=TASK_STATES, default="idle")
    reason: str = string(max_len=_MAX_TEXT, default="")
    step: str = string(max_len=256, default="")
    current_object: str = string(max_len=128, default="")
    elapsed: float = 0.0
    budget: float = 0.0
    drawers_opened: list[str] = string_list(max_len=64, default_empty=True)
    zones_searched: list[str] = string_list(max_len=64, default_empty=True)
    zones_total: int = 0
    failed: int = 0
    objects: list[str] = string_list(max_len=64, default_empty=True)
    object_track_ids: np.ndarray = array("i4", (None,), default=np.zeros(0))
    object_found_at: np.ndarray = array("f8", (None,), default=np.zeros(0))
    object_grasped: np.ndarray = array("?", (None,), default=np.zeros(0, bool))
    object_placed: np.ndarray = array("?", (None,), default=np.zeros(0, bool))
    object_given_up: np.ndarray = array("?", (None,), default=np.zeros(0, bool))
    object_time_s: np.ndarray = array("f8", (None,), nonneg=True, default=np.zeros(0))
    object_attempts: np.ndarray = array("i4", (None,), default=np.zeros(0))
    object_failures: list[str] = string_list(max_len=_MAX_TEXT, default_empty=True)
    object_positions: np.ndarray = array("f8", (None, 3), default=np.zeros((0, 3)))
    taken_track_ids: np.ndarray = array("i4", (None,), default=np.zeros(0))

    def _check(self) -> None:
        _same_rows(
            self, "TaskProgress", len(self.objects), "object_track_ids", "object_found_at",
            "object_grasped", "object_placed", "object_given_up", "object_time_s",
            "object_attempts", "object_failures", "object_positions",
        )  # fmt: skip
        if self.elapsed < 0.0 or self.budget < 0.0 or min(self.zones_total, self.failed) < 0:
            raise MessageError("TaskProgress times and counts must be >= 0")
        if len(self.zones_searched) > self.zones_total:
            raise MessageError("TaskProgress: more zones searched than zones_total")
        if self.failed != int(np.count_nonzero(self.object_given_up)):
            raise MessageError("TaskProgress.failed disagrees with object_given_up")


@message("qm.TidyUpGoal", (1, 0))
class TidyUpGoal(Message):
    """Start a tidy-up (``behavior/action/tidy_up``): only objects of the classes in
    ``labels`` (empty: every class), within ``time_budget`` s of robot time (0: the
    configured budget). The result is the final :class:`TaskProgress`."""

    stamp: float
    labels: list[str] = string_list(max_len=64, default_empty=True)
    time_budget: float = 0.0

    def _check(self) -> None:
        if self.time_budget < 0.0:
            raise MessageError(f"TidyUpGoal.time_budget must be >= 0, got {self.time_budget}")


# --------------------------------------------------------------------------- sim test / ground truth


@message("qm.EmergencyStop", (1, 0))
class EmergencyStop(Message):
    """Software emergency stop for the robot side (sim or hardware adapter):
    ``engage`` true puts legs and arm in damping at once and latches; only a message
    with ``engage`` false releases it (then the legs wait for a fresh leg command)."""

    stamp: float
    engage: bool = True
    reason: str = string(max_len=200, default="")


@message("qm.Disturbance", (1, 0))
class Disturbance(Message):
    """TEST-ONLY external wrench (N, N·m, world frame) on body ``body`` for ``duration`` s.
    The sim applies it only when its test channel is enabled."""

    stamp: float
    force: np.ndarray = array("f8", (3,))
    torque: np.ndarray = array("f8", (3,))
    duration: float = 0.0
    body: str = "base"

    def _check(self) -> None:
        if self.duration < 0.0:
            raise MessageError("Disturbance.duration must be >= 0")


@message("qm.GroundTruthPoses", (1, 0))
class GroundTruthPoses(Message):
    """GROUND TRUTH (judge/tests/viz only): world poses of named bodies; the robot base is
    named ``base``."""

    stamp: float
    names: list[str] = string_list()
    positions: np.ndarray = array("f8", (None, 3), max_elements=3 * 4096)
    orientations: np.ndarray = array("f8", (None, 4), max_elements=4 * 4096)

    def _check(self) -> None:
        n = len(self.names)
        if self.positions.shape[0] != n or self.orientations.shape[0] != n:
            raise MessageError(
                f"GroundTruthPoses: {n} names but {self.positions.shape[0]} positions and "
                f"{self.orientations.shape[0]} orientations"
            )
        if n:
            norm2 = np.einsum("ij,ij->i", self.orientations, self.orientations)
            if not bool(np.all((norm2 >= 0.81) & (norm2 <= 1.21))):
                raise MessageError("GroundTruthPoses.orientations must be unit quaternions")


@message("qm.GroundTruthContacts", (1, 0))
class GroundTruthContacts(Message):
    """GROUND TRUTH: active contacts between named bodies: world contact point and the
    contact force on ``body1`` (world frame, N)."""

    stamp: float
    body1: list[str] = string_list()
    body2: list[str] = string_list()
    positions: np.ndarray = array("f8", (None, 3), max_elements=3 * 4096)
    forces: np.ndarray = array("f8", (None, 3), max_elements=3 * 4096)

    def _check(self) -> None:
        n = len(self.body1)
        if len(self.body2) != n or self.positions.shape[0] != n or self.forces.shape[0] != n:
            raise MessageError("GroundTruthContacts: body1, body2, positions, forces differ")


#: Where the judge finds an object (``JudgeReport.locations``): in its category's place
#: (placed, the only success); in another category's place (a failure); touching the robot;
#: on the floor; on a table, furniture or a place's rim; elsewhere (in the air, settling,
#: on another object).
JUDGE_LOCATIONS = ("in_place", "wrong_place", "held", "floor", "furniture", "elsewhere")


@message("qm.JudgeReport", (2, 1))
class JudgeReport(Message):
    """The sim judge's verdict from ground truth (``sim/judge.py`` says what "placed"
    means): the placed objects, the others, and per object (parallel lists) where it is,
    why it is not placed (``notes``, empty when placed), its position (world, m) and how
    long it has been at rest (s). ``valid`` is False when the honesty guard tripped during
    the trial (``violations`` say what); such a trial scores nothing.

    2.0: "placed" became strict (inside the inner volume, supported by the place, not
    touching the robot, at rest for a while); per-object locations; ``valid``.
    2.1: ``leg_timeouts``: times the legs fell back to damping because leg commands
    stopped arriving (a controller that could not keep up), for the trial's record.
    """

    stamp: float
    trial_time: float
    in_place: list[str] = string_list()
    misplaced: list[str] = string_list()
    total: int = 0
    objects: list[str] = string_list(default_empty=True)
    locations: list[str] = string_list(default_empty=True)
    notes: list[str] = string_list(default_empty=True)
    positions: np.ndarray = array("f8", (None, 3), max_elements=3 * 4096, default=np.zeros((0, 3)))
    rest_s: np.ndarray = array("f8", (None,), nonneg=True, max_elements=4096, default=np.zeros(0))
    valid: bool = True
    violations: list[str] = string_list(default_empty=True)
    leg_timeouts: int = 0

    def _check(self) -> None:
        if self.total < len(self.in_place) + len(self.misplaced) or self.total < 0:
            raise MessageError("JudgeReport.total is less than in_place + misplaced")
        n = len(self.objects)
        sizes = (
            len(self.locations),
            len(self.notes),
            self.positions.shape[0],
            self.rest_s.shape[0],
        )
        if any(k != n for k in sizes):
            raise MessageError(
                f"JudgeReport: {n} objects but locations/notes/positions/rest_s have {sizes}"
            )
        bad = sorted(set(self.locations) - set(JUDGE_LOCATIONS))
        if bad:
            raise MessageError(f"JudgeReport.locations: {bad} not in {JUDGE_LOCATIONS}")
        if n and sorted(self.in_place) != sorted(
            o for o, loc in zip(self.objects, self.locations, strict=True) if loc == "in_place"
        ):
            raise MessageError("JudgeReport.in_place disagrees with the per-object locations")
        if self.violations and self.valid:
            raise MessageError("JudgeReport: a trial with honesty violations is not valid")

    def location_of(self, name: str) -> str | None:
        """Where object ``name`` is (None if the report does not list it)."""
        try:
            return self.locations[self.objects.index(name)]
        except ValueError:
            return None


# --------------------------------------------------------------------------- examples


def example(cls: type[Message], **overrides: object) -> Message:
    """A small valid instance of ``cls`` (for tests, benchmarks and delivery checks).

    Zero values, every array filled (variable dimensions of 1), identity quaternions, the first allowed
    choice of a string; ``overrides`` replace fields.
    """
    kwargs: dict[str, object] = {}
    for spec in field_specs(cls):
        if spec.name in overrides:
            continue
        if spec.has_default and spec.kind != "array":
            continue
        if spec.kind == "float":
            kwargs[spec.name] = 0.0
        elif spec.kind == "int":
            kwargs[spec.name] = 0
        elif spec.kind == "bool":
            kwargs[spec.name] = True
        elif spec.kind == "str":
            kwargs[spec.name] = spec.choices[0] if spec.choices else "x"
        elif spec.kind == "str_list":
            kwargs[spec.name] = ["a"]
        elif spec.kind == "array":
            assert spec.array is not None
            shape = tuple(1 if s is None else s for s in spec.array.shape)
            a = np.zeros(shape, dtype=spec.array.dtype)
            if spec.name in ("orientation", "orientations"):
                a[..., 0] = 1.0
            kwargs[spec.name] = a
        elif spec.kind == "message":
            assert spec.msg_type is not None
            kwargs[spec.name] = example(spec.msg_type)
        elif spec.kind == "any_message":
            kwargs[spec.name] = Clock(stamp=0.0)
    kwargs.update(_EXAMPLE_FIXUPS.get(cls, {}))
    kwargs.update(overrides)
    return cls(**kwargs)


_EXAMPLE_FIXUPS: dict[type[Message], dict[str, object]] = {
    DrawerGoal: {"pull_direction": [-1.0, 0.0, 0.0]},
    GraspGoal: {"center": [0.0, 0.0, 0.0]},
    Detections: {"labels": ["a"]},
    ObjectTracks: {"labels": ["a"]},
    TaskProgress: {"objects": ["a"], "object_failures": ["x"]},
    JudgeReport: {
        "total": 2,
        "in_place": ["a"],
        "misplaced": ["b"],
        "objects": ["a", "b"],
        "locations": ["in_place", "floor"],
        "notes": ["", "belongs in tray"],
        "positions": np.zeros((2, 3)),
        "rest_s": np.zeros(2),
    },
}
