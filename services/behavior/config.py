"""Configuration of the behavior service (``configs/behavior.toml``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from quadmanip.services.behavior.coverage import SearchConfig
from quadmanip.services.behavior.tidy_task import DepositSpec, DrawerConfig, TaskConfig

__all__ = ["BehaviorConfig", "NodeConfig"]


@dataclass(frozen=True)
class NodeConfig:
    """How the node runs: the places file, when the task starts, what it waits for."""

    places_file: str = "maps/house.places.toml"  # a path, or a name under configs/
    # Start a tidy-up at launch (as if a tidy_up goal with no filter had come): the robot,
    # started in a house it has mapped, tidies it. Otherwise the task waits for a goal.
    start_on_launch: bool = True
    # Before a task starts: these services are alive, and locomotion stands (the task asks
    # it to stand up when it lies damped) in one of these phases; within start_timeout.
    required_services: tuple[str, ...] = ("locomotion", "manipulation", "navigation", "perception")
    standing_phases: tuple[str, ...] = ("balance", "walk")
    start_timeout: float = 300.0  # s (wall)
    progress_period: float = 1.0  # s (wall) between progress messages (and at every step)
    goal_timeout: float = 5.0  # s (wall) for a service to accept or reject a request
    # s (wall) a request may run: lockstep can run at a fifth of real time on 2 cores, and
    # a walk across the house takes a minute of robot time
    action_timeout: float = 900.0
    nav_tolerance_xy: float = 0.10  # m: navigate_to goals (the approach is the precise one)
    nav_tolerance_yaw: float = 0.15  # rad
    # a walk an approach follows (``navigate_to(lead_in=True)``) ends once within this of
    # its goal, facing any way and still under way (``NavigateGoal.pass_through``):
    # navigation's approach takes the robot on at its speed (its velocity model starts
    # from odometry's) and turns it, where the walk braked to a stop, turned to its goal's
    # yaw and the approach started again from standing
    lead_in_tolerance_xy: float = 0.25  # m
    # m, rad: a probe's (and a drawer's, a side grasp's step in) stance. 2.5 cm and 0.05
    # rad were 0.65 s faster per approach (16 full-stack approaches, median 4.38 ->
    # 3.73 s) but two side grasps of a can near the kitchen table's corner then ended
    # arm_blocked in a two-object run (2026-12-07), cause not found: kept tight
    approach_tolerance_xy: float = 0.015
    approach_tolerance_yaw: float = 0.03
    # a place's stand: the place plans from the pose the robot stands at, so +-1.5 cm
    # buys nothing there, and near a box the approach sometimes never settled to it
    stand_tolerance_xy: float = 0.03  # m
    stand_tolerance_yaw: float = 0.06  # rad
    holding_min_mass: float = 0.005  # kg: a payload above this means the gripper holds something
    # Restarts (service_watch.py): a required service whose heartbeats stop for this long
    # (wall s) counts as gone, as one whose liveliness token vanished; 0: tokens only.
    # Generous: a loaded machine delays heartbeats, and a false alarm cuts requests short.
    heartbeat_timeout: float = 15.0
    # A restart of these services ends every request in flight, not only their own: when
    # locomotion dies the legs are damped and the robot lies down, whatever it was doing.
    interrupt_all_on: tuple[str, ...] = ("locomotion",)
    # s (wall) for locomotion to stand the robot up again after a restart (righting itself
    # from a side included); lockstep on 2 cores runs at a fifth of real time
    stand_timeout: float = 120.0


@dataclass(frozen=True)
class BehaviorConfig:
    """All of ``configs/behavior.toml``."""

    node: NodeConfig = field(default_factory=NodeConfig)
    task: TaskConfig = field(default_factory=TaskConfig)
    drawers: DrawerConfig = field(default_factory=DrawerConfig)
    # how each kind of search zone (the places file's kinds) is searched
    search: dict[str, SearchConfig] = field(default_factory=dict)
    # how objects go into each deposit place, by the catalogue's place name
    deposits: dict[str, DepositSpec] = field(default_factory=dict)
