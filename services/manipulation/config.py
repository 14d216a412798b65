"""Configuration of the manipulation service (``configs/manipulation.toml``)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from quadmanip.common.config import load_config
from quadmanip.services.manipulation.gripper import GripperConfig

__all__ = [
    "DrawerConfig",
    "ExecutiveConfig",
    "GraspConfig",
    "ManipulationConfig",
    "MotionConfig",
    "PostureSpec",
    "PrimitiveConfig",
    "load_manipulation_config",
]


@dataclass(frozen=True)
class MotionConfig:
    """Arm rate limits (rad/s, rad/s^2), servo gains and trajectory sampling."""

    v_max: tuple[float, float, float, float] = (3.0, 3.0, 4.0, 4.0)
    a_max: tuple[float, float, float, float] = (9.0, 9.0, 14.0, 14.0)
    kp: tuple[float, float, float, float] = (80.0, 80.0, 40.0, 10.0)
    kd: tuple[float, float, float, float] = (3.0, 3.0, 1.5, 0.3)
    dt: float = 0.02
    linear_speed: float = 0.2  # m/s: straight tool moves with an object in the fingers
    empty_linear_speed: float = 0.25  # m/s: ... with nothing in them
    angular_speed: float = 1.0
    # Posture moves with an object in the gripper run at this share of v_max (a_max
    # squared): a spoon pinched edge-on fell out of a full-speed move to ``carry``.
    holding_speed_scale: float = 0.5
    # Elbow reference used when a posture or goal gives no current joints.
    elbow_ref: tuple[float, float, float, float] = (0.3, 1.2, 0.0, 0.0)


@dataclass(frozen=True)
class PostureSpec:
    """A named arm posture: joints ``q`` or a tool target ``tcp = [x, z, pitch, roll]``.

    Exactly one of the two is given. ``tcp`` is in the arm_base frame and is solved with
    the analytic IK (elbow closest to ``MotionConfig.elbow_ref``).
    """

    q: tuple[float, ...] = ()
    tcp: tuple[float, ...] = ()
    doc: str = ""
    # With an object in the gripper, turn the wrist a quarter turn from this posture's roll
    # so the fingers close along the body x axis: an object pinched across its narrow side
    # then lies across the body. A spoon held by its bowl otherwise carried its 13 cm
    # handle back into the front legs and was levered out of the grip.
    held_across: bool = False
    # Trunk pitch held in this posture (rad, locomotion's sign: negative lifts the nose).
    # Probing a tall box on a table from the side, the front camera (below the table top)
    # saw the sugar and cracker boxes cut by the image's top edge from 0.7 m back and
    # detected neither in 6 trials; nose up 0.25 rad from 0.5 m back, both are whole in
    # the frame. Any other primitive levels the trunk first.
    body_pitch: float = 0.0


@dataclass(frozen=True)
class GraspConfig:
    """Algorithm 6 parameters (names follow the paper's constants)."""

    # Height of the grasp-ready pose above a vertical grasp point (GRASP_READY_Z).
    grasp_ready_z: float = 0.10
    # Stand-off of the grasp-ready pose before a horizontal grasp (GRASP_READY_X), m
    # behind the grasp point along x.
    grasp_ready_x: float = 0.10
    # Furthest TCP x (arm_base frame) used for horizontal grasps (MANIPULATOR_X_LIM).
    manipulator_x_lim: float = 0.42
    # Body pose limits of the standing robot (offsets from the nominal pose).
    max_lateral_shift: float = 0.06
    max_forward_shift: float = 0.06
    max_crouch: float = 0.10
    # How much taller than nominal the body may stand to reach a high region (m).
    max_rise: float = 0.03
    # A vertical grasp beyond the upright tool's reach leans the tool forward in steps of
    # reach_lean_step, up to max_reach_lean (rad) more than asked (GraspGoal.tilt)
    reach_lean_step: float = 0.1
    max_reach_lean: float = 0.3
    # Lift after the grasp (m) and hold-to-verify time (s).
    lift_height: float = 0.10
    verify_time: float = 0.3
    # Time the body is given to reach a commanded pose offset (s): at most
    # body_settle_time, at least body_settle_min, body_settle_per_m per metre of the
    # largest offset change between (locomotion's stand, unit-test plant: a 3 cm rise
    # within 3 mm after 0.53 s, an 8 cm crouch after 0.57 s, a 6 mm shift after 0.13 s;
    # a whole second for every place's few millimetres cost ~0.6 s per object)
    body_settle_time: float = 1.0
    body_settle_min: float = 0.3
    body_settle_per_m: float = 10.0
    # Tolerance between the commanded and measured arm joints at the end of a move (rad).
    arm_tolerance: float = 0.08
    # Extra time beyond a trajectory's end before the arm is declared stuck (s).
    arm_timeout: float = 2.0
    # Gripper pre-opening: object width plus this margin, clamped to the open gap.
    open_margin: float = 0.03
    # Place: release height above the region's top surface and retract height.
    place_release_z: float = 0.06
    # ... this low where place_release_z is out of reach, before the tool leans (a tall
    # box over the tray from the task's stance)
    place_min_release_z: float = 0.03
    retract_height: float = 0.10
    # Place: how far (m) the held object's bottom may swing sideways when the tool leans
    # forward to reach; a tall box released leaning lands on its edge and topples.
    place_max_lean: float = 0.02
    # Drawer: pull distance (m) and approach stand-off in front of the handle.
    drawer_pull: float = 0.18
    drawer_standoff: float = 0.08


@dataclass(frozen=True)
class PrimitiveConfig:
    """Margins and tolerances shared by the primitives (``[primitive]``)."""

    # Re-aim the tool when the trunk drifted more than this from where it was asked to be
    # (m), after letting it settle this long (s).
    drift_tol: float = 0.004
    drift_settle_time: float = 0.2
    # The arm has come to rest at a trajectory end below this joint speed (rad/s).
    arm_still_speed: float = 0.3
    # Coarse trunk envelope in the arm_base frame: the trunk's front is this far ahead of
    # the mount (m), and over the trunk the arm's centre line must stay this high (m; the
    # LiDAR dome reaches 0.035 m above the mount).
    trunk_front_x: float = 0.15
    trunk_min_z: float = 0.045
    # Grasp: an object must be at least this much narrower than the open gripper (m).
    width_margin: float = 0.004
    # Horizontal grasp: the wrist stays this far inside the arm's full stretch (m).
    reach_margin: float = 0.005
    # Place: the transit pose is at most this high above the release pose (m).
    transit_clearance: float = 0.05


@dataclass(frozen=True)
class DrawerConfig:
    """Drawer opening (``[drawer]``; pull distance and stand-off are in ``[grasp]``)."""

    # Bar thickness the fingers open around (plus grasp.open_margin), m.
    handle_width: float = 0.02
    # Closest tool-centre x (arm_base frame) of a pull, below / above ``low_z``: with the
    # wrist rolled a quarter turn the palm stands 13 cm tall, and above trunk level it would
    # meet the LiDAR dome / trunk edge nearer.
    min_pull_x_low: float = 0.25
    min_pull_x_high: float = 0.32
    low_z: float = -0.12
    # Tool centre this far behind the bar at the grip (m). 0: the bar sits mid-pad, +-1.3 cm
    # of tolerance either way. Under real locomotion the trunk backs off ~1 cm while the arm
    # reaches forward (the balance controller keeps the whole-robot COM over the feet),
    # which pushed a bar held in the pads' front half (1.2 cm) off the fingertips.
    grip_behind: float = 0.0
    # After the release: back off along the pull this far (m), then rise this high (m).
    retreat: float = 0.045
    retreat_rise: float = 0.08
    # Tool speed of the pull (m/s) and the longest pull a goal may ask for (m).
    pull_speed: float = 0.1
    max_pull: float = 0.4


@dataclass(frozen=True)
class ExecutiveConfig:
    """Goal arbitration and policy of the manipulation executive (``[executive]``)."""

    # Hang of a held object below the tool centre (m) when the grasp goal gives none and
    # it cannot be measured (see Executive: hang estimate).
    default_hang: float = 0.05
    # A vertical grasp point lower than this above the floor (m) is a floor grasp, whose
    # hang is measured as its height: the house's tables are 40 cm high, the tallest
    # object (the cracker box) 21 cm.
    floor_grasp_max_z: float = 0.30
    # While holding, the payload is repeated this often (s) for a locomotion started later.
    payload_period: float = 1.0
    # Odometry older than this (s, robot time) is not used for the body-drift correction.
    odom_max_age: float = 0.5
    # An accepted goal whose execution has not started within this (s, wall clock) frees
    # the slot again (the action server refused it after the accept, e.g. shutting down).
    claim_timeout: float = 2.0
    # After a cancel request, how long (s, wall clock) to wait for the arm to stop.
    cancel_wait: float = 2.0
    # A grasp refused as unreachable says from which distances ahead it would be planned:
    # searched this far either side of the asked one (m), in these steps (m).
    reach_search: float = 0.24
    reach_step: float = 0.02


@dataclass(frozen=True)
class ManipulationConfig:
    """Everything the manipulation service is configured with."""

    motion: MotionConfig = field(default_factory=MotionConfig)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    grasp: GraspConfig = field(default_factory=GraspConfig)
    primitive: PrimitiveConfig = field(default_factory=PrimitiveConfig)
    drawer: DrawerConfig = field(default_factory=DrawerConfig)
    postures: dict[str, PostureSpec] = field(default_factory=dict)
    executive: ExecutiveConfig = field(default_factory=ExecutiveConfig)
    heartbeat_period: float = 0.5

    def __post_init__(self) -> None:
        # The fingers' travel is the description's (joint ranges of both fingers), never a
        # copied constant: gripper.open_gap = 0 (the default) means "fully open". Done
        # here so every loader (the service runtime's too) gets it.
        from quadmanip.common.robot_description import robot_info

        info = robot_info()
        max_gap = info.gripper_max_gap
        if self.gripper.rated_force <= 0.0:
            # the description's force limit, never a copied constant (like open_gap)
            g = replace(self.gripper, rated_force=info.gripper_max_force)
            object.__setattr__(self, "gripper", g)
        if self.gripper.open_gap <= 0.0:
            object.__setattr__(self, "gripper", replace(self.gripper, open_gap=max_gap))
        elif self.gripper.open_gap > max_gap + 1e-9:
            raise ValueError(
                f"gripper.open_gap {self.gripper.open_gap} exceeds the description's "
                f"{max_gap:.3f} m"
            )


def load_manipulation_config(name_or_path: str = "manipulation") -> ManipulationConfig:
    """Loads and validates ``configs/manipulation.toml`` (unknown keys are errors)."""
    cfg = load_config(ManipulationConfig, name_or_path)
    for name, spec in cfg.postures.items():
        if (len(spec.q) == 4) == (len(spec.tcp) == 4) or (spec.q and spec.tcp):
            raise ValueError(f"posture {name!r}: give exactly one of q (4) or tcp (4)")
    return cfg
