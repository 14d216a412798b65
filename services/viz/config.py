"""Parameters of the viz service (``configs/viz.toml``)."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class VizConfig:
    """Where the recording goes and how much of each stream is kept.

    Rates are in Hz of ROBOT time (message stamps), so a lockstep run faster than real time
    gives the same recording density as a real-time one; 0 keeps every message.
    """

    # .rrd file written while the service runs ("" = none). "{time}" → UTC start time
    # (YYYYmmdd_HHMMSS); missing parent folders are created.
    output: str = "recordings/quadmanip_{time}.rrd"
    # Stream to a running viewer too (e.g. "rerun+http://127.0.0.1:9876/proxy"; "" = no).
    connect_url: str = ""
    # Host a gRPC server on this port that viewers connect to (`rerun --connect`); 0 = no.
    serve_port: int = 0
    application_id: str = "quadmanip"

    joints_rate: float = 50.0  # LowState → joint/IMU/gripper plots
    odometry_rate: float = 50.0  # base transform + velocity plots
    trail_rate: float = 5.0  # odometry / ground-truth trajectory lines
    trail_max_points: int = 5000
    trail_min_spacing: float = 0.01  # m between kept trail points
    debug_rate: float = 0.0  # locomotion debug (MPC runs at ~33 Hz)
    command_rate: float = 0.0  # locomotion/cmd_vel
    gt_rate: float = 10.0  # ground-truth base/objects/contacts
    image_every: int = 2  # log every Nth frame of each camera (1 = all)
    rgb: bool = True
    depth: bool = True
    jpeg_quality: int = 0  # 1..100: JPEG-compress RGB (smaller files); 0 = raw
    scan_every: int = 1  # log every Nth LiDAR scan
    # perception/detections: boxes on the camera images + located centroids. A detection
    # whose camera frame was logged (image_every) is always kept, so its boxes sit on their
    # own picture; the others at most detections_rate per camera (they overlay the last
    # logged frame, up to image_every - 1 frames older).
    detections: bool = True
    detections_rate: float = 5.0
    objects: bool = True  # perception/objects: the object memory as 3-D boxes
    objects_rate: float = 4.0  # published at 2 Hz and on every change: caps the bursts

    skeleton: bool = True  # draw the robot (stick figure from joint angles) at joints_rate
    force_scale: float = 0.002  # m of arrow per N of foot force

    # Place the odom frame in the world from the first odometry/ground-truth pair (display
    # only; the estimator starts at the odom origin, the robot does not start at the world's).
    align_odom: bool = True
    align_max_dt: float = 0.05  # s: largest stamp gap of the pair used

    # base_T_lidar; empty = read the `lidar` site from the robot description.
    lidar_position: tuple[float, ...] = ()
    lidar_orientation: tuple[float, ...] = ()  # [w, x, y, z]

    stats_period: float = 5.0  # s (wall) between dropped/decimated counter reports
    flush_timeout: float = 1.0  # s allowed to flush the recording at stop (budget is 2 s)

    def __post_init__(self) -> None:
        for name in (
            "joints_rate",
            "odometry_rate",
            "trail_rate",
            "debug_rate",
            "gt_rate",
            "command_rate",
            "detections_rate",
            "objects_rate",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"viz.{name} must be >= 0")
        if self.image_every < 1 or self.scan_every < 1:
            raise ValueError("viz.image_every and viz.scan_every must be >= 1")
        if not 0 <= self.jpeg_quality <= 100:
            raise ValueError("viz.jpeg_quality must be in 0..100")
        if self.force_scale < 0:
            raise ValueError("viz.force_scale must be >= 0")
        if self.trail_max_points < 2:
            raise ValueError("viz.trail_max_points must be >= 2")
        if self.lidar_position and len(self.lidar_position) != 3:
            raise ValueError("viz.lidar_position needs 3 values (or none)")
        if self.lidar_orientation and len(self.lidar_orientation) != 4:
            raise ValueError("viz.lidar_orientation needs 4 values [w, x, y, z] (or none)")
        if not 0.0 < self.flush_timeout <= 1.5:
            raise ValueError("viz.flush_timeout must be in (0, 1.5] (the stop budget is 2 s)")
        if not 0 <= self.serve_port <= 65535:
            raise ValueError("viz.serve_port must be a port number (0 = off)")
        if not (self.output or self.connect_url or self.serve_port):
            # Without a sink Rerun buffers everything in memory until the process dies.
            raise ValueError("viz needs an output file, a connect_url or a serve_port")
