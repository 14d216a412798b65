"""Configuration of the navigation service (``configs/navigation.toml``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from quadmanip.services.navigation.amcl import AmclConfig
from quadmanip.services.navigation.approach import ApproachConfig
from quadmanip.services.navigation.costmap import CostmapConfig
from quadmanip.services.navigation.frontier import FrontierConfig
from quadmanip.services.navigation.global_planner import PlannerConfig
from quadmanip.services.navigation.navigator import NavigatorConfig
from quadmanip.services.navigation.object_layer import ObjectLayerConfig
from quadmanip.services.navigation.odom_watch import OdomJumpConfig
from quadmanip.services.navigation.path_follower import FollowerConfig
from quadmanip.services.navigation.scan_anchor import AnchorConfig
from quadmanip.services.navigation.slam import SlamConfig
from quadmanip.services.navigation.standing_nudge import NudgeConfig

__all__ = ["ExploreConfig", "NavigationConfig", "NodeConfig"]


@dataclass(frozen=True)
class NodeConfig:
    """How the node runs: ``mode`` ``mapping`` (build a map with SLAM, explore) or
    ``localization`` (on the saved ``map``, a map_server YAML: a path, or a name under
    configs/, with its places file beside it), where it starts, its rates and input
    timeouts."""

    mode: str = "localization"
    map: str = "maps/house.yaml"
    initial_pose: tuple[float, float, float] = (0.8, 1.2, 0.0)  # x, y (m), yaw (deg) in the map
    initial_std: tuple[float, float, float] = (0.1, 0.1, 5.0)  # m, m, deg
    global_localization: bool = False
    fine_surface: bool = True  # refine on the map's surface raster (NAME_surface.yaml) if any
    input_timeout: float = 1.0  # s without odometry (wall) or scans (robot time): "lost"
    map_period: float = 5.0  # s (wall) between map publications (and on every change)
    costmap_period: float = 1.0
    mapping_costmap_period: float = 1.0  # s (robot time) between costmap rebuilds while mapping
    costmap_margin: float = 1.0  # m around the known area of the SLAM map
    approach_timeout: float = 30.0  # s (robot time)
    approach_guard: float = 0.03  # m: scan points this close to the trunk stop an approach
    # m: an approach that would walk at least this far to a stance (its own heading and no
    # turned one free) whose trunk overlaps the map's furniture ends before it sets off
    # (``STANCE_MEETS_FURNITURE``); a shorter step in goes on, its guard stops it if it must
    meets_furniture_from: float = 0.2
    # scans are used only while the robot stands or walks upright (not while it stands up)
    min_base_height: float = 0.22  # m, odometry's base height
    max_tilt: float = 0.2  # rad
    min_hit_height: float = 0.05  # m: lower returns are the floor seen by a tilted scan
    # navigation/initial_pose: a hint older than this (robot s, against the odometry) is
    # ignored (the robot may have walked since); in mapping mode every hint is ignored
    hint_max_age: float = 5.0


@dataclass(frozen=True)
class ExploreConfig:
    """Frontier exploration: frontier goals are pulled back into known free space, reached
    loosely, and given up (blacklisted) when unreachable."""

    goal_tolerance: float = 0.3
    goal_search_radius: float = 1.0  # m: nearest traversable cell to a frontier's goal
    candidates: int = 6  # nearest frontiers tried by planning, per choice
    blacklist_radius: float = 0.4
    recheck_period: float = 2.0  # s: drop the current goal once its frontier is gone
    open_radius: float = 0.5  # m: ... i.e. no frontier cell is left this close to it
    settle_time: float = 1.5  # s (robot time) of scans before the first frontier is chosen
    start_patience: float = 3.0  # s of failing to plan from the robot's spot before giving up


@dataclass(frozen=True)
class NavigationConfig:
    """Every navigation parameter, one table per component."""

    node: NodeConfig = field(default_factory=NodeConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    amcl: AmclConfig = field(default_factory=AmclConfig)
    costmap: CostmapConfig = field(default_factory=CostmapConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    follower: FollowerConfig = field(default_factory=FollowerConfig)
    approach: ApproachConfig = field(default_factory=ApproachConfig)
    nudge: NudgeConfig = field(default_factory=NudgeConfig)
    anchor: AnchorConfig = field(default_factory=AnchorConfig)
    navigator: NavigatorConfig = field(default_factory=NavigatorConfig)
    frontier: FrontierConfig = field(default_factory=FrontierConfig)
    explore: ExploreConfig = field(default_factory=ExploreConfig)
    odom_jump: OdomJumpConfig = field(default_factory=OdomJumpConfig)
    objects: ObjectLayerConfig = field(default_factory=ObjectLayerConfig)
