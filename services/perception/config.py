"""Configuration of the perception service (``configs/perception.toml``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from quadmanip.services.perception.detector import DetectorConfig
from quadmanip.services.perception.frames import FrameConfig
from quadmanip.services.perception.grasp_pose import GraspConfig
from quadmanip.services.perception.handle_locator import HandleConfig
from quadmanip.services.perception.object_memory import MemoryConfig
from quadmanip.services.perception.seen_area import SeenConfig

__all__ = ["NodeConfig", "PerceptionConfig"]


@dataclass(frozen=True)
class NodeConfig:
    """How the node runs: input timeouts, publication period, what a grasp request
    waits for and accepts."""

    frame_timeout: float = 1.0  # s (wall) without a frame: the camera is reported silent
    objects_period: float = 0.5  # s (wall) between object-memory publications
    odom_max_skew: float = 0.1  # s: odometry further than this from a frame is not used
    grasp_timeout: float = 3.0  # s (wall) an action waits for a fresh frame, arm still
    arm_still: float = 0.05  # rad/s: every arm joint slower than this counts as still
    max_reach: float = 0.75  # m from the base: a farther target is "too far" ...
    # ... but the front camera probes from farther back: it sits below a table top, so it
    # sees a table object from about 1 m (the task steps in to grasp)
    max_side_probe: float = 1.3
    track_gate: float = 0.2  # m: a detection this near a requested track is that track
    # rad: the gripper camera's frames feed the object memory only while it looks at least
    # this far down: floor search (77 deg), probing (80 deg), carrying (70 deg). Walking
    # with the arm stowed it looks ahead along the trunk (20 deg down), a view the detector
    # was not trained on, where it took the trunk's orange front corners for toy guns: the
    # memory filed them as tracks flat on the floor a step ahead (`make demo`, eight
    # phantom "toy guns"). The front camera covers that view.
    gripper_min_look_down: float = 0.8
    # A detection whose extent is longer than extent_ratio x its class's longest side (the
    # object catalogue) + extent_margin is not remembered (frames.plausible_extent); what
    # a probe measures taller than that above its surface is refused as not that object
    # (frames.implausible_grasp)
    extent_ratio: float = 1.5
    extent_margin: float = 0.05
    # ... and what it measures lower than flat_ratio x the class's thinnest side is refused
    # the same way (a bare patch of floor or table top: nothing stands out of it)
    flat_ratio: float = 0.5
    view_frames: int = 5  # fresh frames per camera a grasp request looks at for its target
    # a grasp request for a class takes its box from every candidate; a reported box of
    # another class over it, scoring this much more, names the object instead (the close
    # view decides; frames.close_view_class)
    relabel_margin: float = 0.2
    # px: a box this near the image's border may show a cut-off object; the memory takes
    # it as a partial observation (object_memory.Observation.partial)
    edge_px: float = 4.0
    # m: a sphere about the gripper's tool centre (placed from the newest gripper camera
    # frame's pose) that the object memory neither learns nor unlearns from: what the
    # gripper holds moves with it (object_memory.ObjectMemory.update's ``blind``)
    held_radius: float = 0.15
    # s: a gripper pose further than this (robot time) from the frame places no sphere
    held_pose_max_age: float = 0.3
    # a folder: each rejected grasp estimate's inputs (depth, colour, box, K, camera pose,
    # label, surface) are written there as .npz (``quadmanip perception replay`` reads
    # them back), so a rejection seen live can be studied offline; "" writes nothing
    save_rejected: str = ""


@dataclass(frozen=True)
class PerceptionConfig:
    """All of ``configs/perception.toml``."""

    node: NodeConfig = field(default_factory=NodeConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    frames: FrameConfig = field(default_factory=FrameConfig)
    grasp: GraspConfig = field(default_factory=GraspConfig)
    handle: HandleConfig = field(default_factory=HandleConfig)
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    seen: SeenConfig = field(default_factory=SeenConfig)
