"""Odometry over the last second, looked up at a scan's own stamp.

A scan is matched against the map with the odometry of the instant it was taken. The
node steps at 20 Hz and takes the newest odometry, which is up to a step newer than the
newest scan: at 0.5 m/s and 1 rad/s a 50 ms gap puts the scan 2.5 cm and 3 degrees away
from where the robot was, and the localiser pulled the map->odom transform by that much
on every update (ROS's amcl and slam_toolbox look odometry up at the scan's stamp through
tf for the same reason). :class:`PoseHistory` keeps the recent poses and interpolates.
"""

from __future__ import annotations

import bisect
import threading
from collections import deque

from quadmanip.services.navigation.grid import Pose2, wrap

__all__ = ["PoseHistory", "interpolate_pose"]


def interpolate_pose(a: Pose2, b: Pose2, w: float) -> Pose2:
    """The pose a fraction ``w`` (0..1) of the way from ``a`` to ``b`` (yaw the short way)."""
    return (
        a[0] + w * (b[0] - a[0]),
        a[1] + w * (b[1] - a[1]),
        float(wrap(a[2] + w * float(wrap(b[2] - a[2])))),
    )


class PoseHistory:
    """Stamped poses (newest last) over ``span`` seconds; thread-safe (filled from a
    subscriber's thread, read from the control loop)."""

    def __init__(self, span: float = 1.0, max_gap: float = 0.2) -> None:
        if span <= 0 or max_gap <= 0:
            raise ValueError(f"span and max_gap must be > 0, got {span}, {max_gap}")
        self.span = span
        self.max_gap = max_gap  # s: no interpolation across a longer hole in the stream
        self._stamps: deque[float] = deque()
        self._poses: deque[Pose2] = deque()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp: float, pose: Pose2) -> None:
        """Append a pose; a stamp older than the newest (a restarted clock or publisher)
        starts the history again, a repeated stamp replaces the newest."""
        with self._lock:
            if self._stamps and stamp < self._stamps[-1]:
                self._stamps.clear()
                self._poses.clear()
            if self._stamps and stamp == self._stamps[-1]:
                self._poses[-1] = pose
                return
            self._stamps.append(stamp)
            self._poses.append(pose)
            while self._stamps and self._stamps[0] < stamp - self.span:
                self._stamps.popleft()
                self._poses.popleft()

    def clear(self) -> None:
        """Forget every pose (odometry went on in a new frame)."""
        with self._lock:
            self._stamps.clear()
            self._poses.clear()

    def at(self, stamp: float) -> Pose2 | None:
        """The pose at ``stamp``, linear between the two around it; None when the history
        does not cover it (older than kept, newer than the newest, or across a gap)."""
        with self._lock:
            t = list(self._stamps)
            if not t or stamp < t[0] or stamp > t[-1]:
                return None
            k = bisect.bisect_left(t, stamp)
            if t[k] == stamp:
                return self._poses[k]
            if t[k] - t[k - 1] > self.max_gap:
                return None
            w = (stamp - t[k - 1]) / (t[k] - t[k - 1])
            return interpolate_pose(self._poses[k - 1], self._poses[k], w)
