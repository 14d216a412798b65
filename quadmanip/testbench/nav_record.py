"""Record what navigation sees and what really happened, scan by scan (TOOLING: reads gt).

At each LiDAR scan: the scan's ranges, the newest odometry (position, quaternion), the
true base pose, navigation's newest map pose and the true pose at that map pose's own
stamp. The map pose is published each control step at the odometry's stamp, up to a step
behind the scan; at 0.5 m/s a 50 ms gap alone is 2.5 cm, so localisation is scored
against the truth interpolated at the estimate's stamp (``gt_at_nav``), not the newest. Saved as one ``.npz``; the navigation benchmark
scores localisation from it, and the unit tests replay such recordings through the
algorithms (``tests/data``).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.bus import Bus
from quadmanip.common.rotations import wrap_angle, yaw_from_quat

__all__ = ["NavRecorder"]


class NavRecorder:
    """Subscribes on ``bus``; :meth:`save` writes ``stamp``, ``ranges`` (N, rays),
    ``odom`` (N, 8: x y z qw qx qy qz stamp), ``gt`` (N, 4: x y yaw stamp) and ``nav``
    (N, 4: x y yaw stamp, NaN before navigation's first pose) and ``cmd`` (N, 4: the newest
    body velocity command vx vy wz stamp) and ``gt_at_nav`` (N, 4: the true x y yaw at
    ``nav``'s stamp, NaN where the truth does not cover it)."""

    def __init__(self, bus: Bus) -> None:
        self.lock = threading.Lock()
        self.rows: list[tuple[np.ndarray, ...]] = []
        self.odom = bus.latest("locomotion/odometry")
        self.gt = bus.latest("sim/gt/base")
        self.nav = bus.latest("navigation/pose")
        self.cmd = bus.latest("locomotion/cmd_vel")
        self.truth: list[tuple[float, float, float, float]] = []  # every true pose
        bus.subscribe("sim/gt/base", self._on_gt)
        self.angle_min = 0.0
        self.angle_increment = 0.0
        bus.subscribe("sim/scan", self._on_scan)

    def _on_gt(self, gt: m.GroundTruthPoses) -> None:
        i = list(gt.names).index("base")
        with self.lock:
            self.truth.append((float(gt.stamp), float(gt.positions[i][0]),
                               float(gt.positions[i][1]), yaw_from_quat(gt.orientations[i])))  # fmt: skip

    def truth_at(self, stamps: np.ndarray) -> np.ndarray:
        """The true (x, y, yaw, stamp) at each of ``stamps``, linear between the true poses
        around it; NaN outside the recorded truth."""
        with self.lock:
            tr = np.array(self.truth, dtype=float).reshape(-1, 4)
        out = np.full((len(stamps), 4), np.nan)
        if len(tr) < 2:
            return out
        inside = (stamps >= tr[0, 0]) & (stamps <= tr[-1, 0])
        t = stamps[inside]
        yaw = np.unwrap(tr[:, 3])
        out[inside, 0] = np.interp(t, tr[:, 0], tr[:, 1])
        out[inside, 1] = np.interp(t, tr[:, 0], tr[:, 2])
        out[inside, 2] = wrap_angle(np.interp(t, tr[:, 0], yaw))
        out[inside, 3] = t
        return out

    def _on_scan(self, s: m.LaserScan) -> None:
        od, gt, nv = self.odom.get(), self.gt.get(), self.nav.get()
        if od is None or gt is None:
            return
        i = list(gt.names).index("base")
        g = np.array([gt.positions[i][0], gt.positions[i][1], yaw_from_quat(gt.orientations[i]),
                      gt.stamp])  # fmt: skip
        o = np.array([*od.position, *od.orientation, od.stamp])
        n = np.full(4, np.nan) if nv is None else np.array([nv.x, nv.y, nv.yaw, nv.stamp])
        c = self.cmd.get()
        cv = np.full(4, np.nan) if c is None else np.array([c.vx, c.vy, c.wz, c.stamp])
        with self.lock:
            self.angle_min, self.angle_increment = float(s.angle_min), float(s.angle_increment)
            self.rows.append((np.float64(s.stamp), np.asarray(s.ranges, np.float32), o, g, n, cv))

    def __len__(self) -> int:
        return len(self.rows)

    def arrays(self) -> dict[str, np.ndarray]:
        """The recording so far as arrays."""
        with self.lock:
            rows = list(self.rows)
        if not rows:
            return {}
        return {
            "stamp": np.array([r[0] for r in rows]),
            "ranges": np.stack([r[1] for r in rows]),
            "odom": np.stack([r[2] for r in rows]),
            "gt": np.stack([r[3] for r in rows]),
            "nav": np.stack([r[4] for r in rows]),
            "cmd": np.stack([r[5] for r in rows]),
            "gt_at_nav": self.truth_at(np.array([r[4][3] for r in rows])),
            "angles": np.array([self.angle_min, self.angle_increment]),
        }

    def save(self, path: str | Path) -> Path:
        """Write the recording (compressed)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **self.arrays())
        return path
