"""Odometry held to one scan: drift-free relative poses for the precise final approach.

Algorithm 5 (paper Section 5.3) walks the robot to a probing pose given relative to where
it stands. Odometry alone drifts a few centimetres over such a move (a trot in place and
slow sidesteps drift more than a straight walk): more than the ±1 cm the grasp needs.
So when an approach starts, the current scan becomes the anchor: its returns, placed in
the odom frame by the odometry of that instant, are joined into the surfaces they sample,
rasterised at 2 cm and turned into a distance field; every later scan is matched against it (:class:`.scan_matcher.ScanMatcher`,
the SLAM's matcher), which gives the base pose in that same odom frame without the drift
accumulated since. Between scans the correction is carried by the odometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.distance_field import DistanceField
from quadmanip.services.navigation.grid import (
    GridGeometry,
    Pose2,
    compose,
    invert,
    transform_points,
)
from quadmanip.services.navigation.scan_matcher import ScanMatcher, ScanMatcherConfig

__all__ = ["AnchorConfig", "ScanAnchor"]


@dataclass(frozen=True)
class AnchorConfig:
    """Raster and acceptance of the anchor's matches."""

    resolution: float = 0.02  # m: raster of the anchor scan's returns
    margin: float = 1.0  # m around the returns
    max_fit: float = 0.02  # m: mean distance of inliers to the anchor's returns
    min_inliers: float = 0.7  # fraction of returns that must lie on the anchor's
    max_correction: float = 0.1  # m: a larger jump from the odometry is refused
    min_points: int = 30
    join_gap: float = 0.15  # m: neighbouring returns closer than this lie on one surface


class ScanAnchor:
    """One scan's returns as the reference of an approach (see the module docstring)."""

    def __init__(
        self, points_base: np.ndarray, odom_pose: Pose2, config: AnchorConfig | None = None
    ) -> None:
        self.config = cfg = config or AnchorConfig()
        pts = transform_points(odom_pose, np.asarray(points_base, dtype=float))
        lo = pts.min(axis=0) - cfg.margin
        hi = pts.max(axis=0) + cfg.margin
        geo = GridGeometry.covering((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])),
                                    cfg.resolution)  # fmt: skip
        mask = np.zeros(geo.shape, dtype=bool)
        # the returns joined into the surfaces they sample: neighbouring beams 1 degree
        # apart are 7 cm apart at 4 m, so a later scan's returns fall between them
        a, b = pts[:-1], pts[1:]
        gap = np.hypot(*(b - a).T)
        join = gap < cfg.join_gap
        steps = np.ceil(gap[join] / (0.5 * cfg.resolution)).astype(int) + 1
        seg = np.repeat(np.arange(int(join.sum())), steps)
        t = (np.arange(int(steps.sum())) - np.repeat(np.cumsum(steps) - steps, steps)) / np.maximum(
            np.repeat(steps - 1, steps), 1
        )
        filled = a[join][seg] + (b[join] - a[join])[seg] * t[:, None]
        r, c = geo.to_cell(np.concatenate([pts, filled]))
        mask[r, c] = True
        self.field = DistanceField(mask, geo, max_distance=0.5)
        self.matcher = ScanMatcher(ScanMatcherConfig(surface_offset=0.0))
        self.correction: Pose2 = (0.0, 0.0, 0.0)  # odom (now) -> odom (anchor)
        self.matches = 0
        self.refused = 0

    def update(self, points_base: np.ndarray, odom_pose: Pose2) -> bool:
        """Match a scan taken at ``odom_pose``; True when the correction was updated."""
        cfg = self.config
        if len(points_base) < cfg.min_points:
            self.refused += 1
            return False
        guess = self.pose(odom_pose)
        res = self.matcher.match(points_base, self.field, guess)
        jump = math.hypot(res.pose[0] - guess[0], res.pose[1] - guess[1])
        if (
            not math.isfinite(res.fit)
            or res.fit > cfg.max_fit
            or res.inlier_fraction < cfg.min_inliers
            or jump > cfg.max_correction
        ):
            self.refused += 1
            return False
        self.correction = compose(res.pose, invert(odom_pose))
        self.matches += 1
        return True

    def pose(self, odom_pose: Pose2) -> Pose2:
        """The base pose in the anchor's odom frame, corrected for the drift since."""
        return compose(self.correction, odom_pose)
