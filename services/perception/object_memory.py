"""What the robot has seen where: object tracks in the odom frame (paper Section 4).

The detector reports, per camera frame, objects as (class, score, centroid, extent) in the
odom frame. :class:`ObjectMemory` fuses them over time and cameras into tracks:

- Association: per class, observations are matched one-to-one to tracks by distance
  (Hungarian assignment), within a gate that grows with the object's size; unmatched
  observations start new tracks. Centroid and extent are running means whose newest-sample
  weight never falls below ``smoothing`` (so a nudged object is followed).
- Confirmation: a track is tentative until ``confirm_hits`` observations; a spurious
  single detection therefore never reaches ``tracks(confirmed_only=True)``, and one not seen
  again within ``tentative_ttl`` is forgotten.
- Negative evidence: a track that this frame's camera should have seen (in front of it,
  inside the image, within the detector's range, and not hidden: the depth at its pixel is
  not much closer than the track) but that was not detected, misses; its confidence decays
  and after ``max_misses`` consecutive misses (a confirmed one: and ``miss_time`` since
  it was last detected) it is removed. A track out of view, or hidden
  behind something, keeps its state: the robot simply did not look. No depth return at
  the track's pixel is no evidence either way (not a miss); a view without a depth image
  is judged on geometry alone.
- Two tracks of one class that drift within each other's gate (two cameras' slightly
  different estimates) are merged, unless both were detected in the same frame.
- One object, two classes: the detector may call one object a mug from one side and a
  coffee can from another. An observation no track of its class takes, within
  ``class_radius`` of a track of another class, is that track's; tracks of different
  classes that come within ``class_radius`` of each other are merged. A track keeps a
  score-weighted vote per class and is named by the largest: the task then sees one
  object, not a real one and a phantom, and a one-off misreading does not rename it.
  (Two different objects' centroids lie farther apart than ``class_radius``: their
  half-sizes separate them.)

- Cut-off views: a box at the image's edge (``Observation.partial``, set by the node)
  may show part of an object, or of furniture (table legs at the edge of walking views
  were filed as "sugar boxes" in most tidy-up trials). Such an observation keeps the
  track it matches alive and votes at ``partial_vote``, but starts no track and moves
  none: objects are placed from whole views.

``confidence = mean score x (1 - exp(-observations / evidence_scale)) x miss_decay^misses``.

Call :meth:`ObjectMemory.update` for every processed frame, also when nothing was detected
(that is what removes objects that are gone). Not thread-safe; the node owns one instance.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from quadmanip.common.rotations import quat_to_mat, rot_z
from scipy.optimize import linear_sum_assignment

__all__ = ["CameraView", "MemoryConfig", "ObjectMemory", "Observation", "Track"]


@dataclass(frozen=True)
class MemoryConfig:
    """Parameters of :class:`ObjectMemory` (``[memory]`` of configs/perception.toml).

    Lengths in metres, times in seconds (robot time, the stamps given to ``update``).
    """

    # Association gate: gate_scale x half the diagonal of the larger extent (track or
    # observation), clipped to [min_gate, max_gate].
    gate_scale: float = 1.0
    min_gate: float = 0.08
    max_gate: float = 0.40
    # Detections scoring below this are ignored.
    min_score: float = 0.0
    # Weight of a partial observation's class vote (Observation.partial), x its score.
    partial_vote: float = 0.25
    # Observations and tracks of different classes this near are one object (module doc).
    class_radius: float = 0.06
    # Observations before a track is confirmed.
    confirm_hits: int = 3
    # Consecutive in-view misses that remove a confirmed / a tentative track.
    max_misses: int = 3
    tentative_max_misses: int = 1
    # s (robot time): a confirmed track goes only once it has not been detected for this
    # long as well (0: the misses' count alone). Three frames pass in a fraction of a
    # second: paper-5 (2026-12-08) lost a coffee can seen 43 times to three gripper-camera
    # misses as the arm moved to carry a clamp beside it, 0.83 m away; 100 s later a walk's
    # goal, chosen clear of the floor objects the memory held, stood on the can, and the
    # robot kicked it out of the room's search zone.
    miss_time: float = 0.0
    # A tentative track not observed for this long is dropped.
    tentative_ttl: float = 30.0
    # Lowest weight of a new sample in the centroid/extent running mean (1/n before).
    smoothing: float = 0.2
    # The score is a running mean over about this many detections.
    score_window: int = 10
    # Evidence term of the confidence, 1 - exp(-observations / evidence_scale).
    evidence_scale: float = 2.0
    # Confidence factor per consecutive miss.
    miss_decay: float = 0.6
    # Distance from the camera (m) at which the detector finds objects; a CameraView may
    # override it per camera.
    min_range: float = 0.15
    max_range: float = 3.0
    # m from the camera, per class: farther, a track of that class in view and not
    # detected is no miss (the detector does not find it that far). Measured with
    # ``python -m quadmanip.testbench.detection_range``: the front camera found a Lego in
    # every view to 2 m and in none at 2.5 m (a padlock: 1.25 m, none at 2 m), and the
    # memory missed them out to max_range: a Lego confirmed four times was dropped each
    # time before the task came to it (paper-1, 2026-12-07). Classes not named: the camera's
    # range (max_range) alone.
    miss_ranges: dict[str, float] = field(default_factory=dict)
    # The centroid must project at least this many pixels inside the image border.
    image_margin: float = 8.0
    # Hidden when the depth at the track's pixel is closer than the centroid by more than
    # occlusion_tolerance + half the track's largest size.
    occlusion_tolerance: float = 0.05
    # Half-size (pixels of the given depth image) of the window sampled at the pixel: the
    # furthest valid depth in it counts, so a thin occluder edge does not hide the track.
    depth_window: int = 1

    def __post_init__(self) -> None:
        for name in (
            "gate_scale",
            "min_gate",
            "max_gate",
            "tentative_ttl",
            "evidence_scale",
            "max_range",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"MemoryConfig.{name} must be finite and > 0, got {v}")
        if not (math.isfinite(self.class_radius) and self.class_radius >= 0.0):
            raise ValueError(f"MemoryConfig.class_radius must be >= 0, got {self.class_radius}")
        if self.min_gate > self.max_gate:
            raise ValueError("MemoryConfig: min_gate must not exceed max_gate")
        if not 0.0 <= self.min_range < self.max_range:
            raise ValueError("MemoryConfig: need 0 <= min_range < max_range")
        bad = {k: v for k, v in self.miss_ranges.items() if not (math.isfinite(v) and v > 0.0)}
        if bad:
            raise ValueError(f"MemoryConfig.miss_ranges must be finite and > 0, got {bad}")
        if not (math.isfinite(self.miss_time) and self.miss_time >= 0.0):
            raise ValueError(
                f"MemoryConfig.miss_time must be finite and >= 0, got {self.miss_time}"
            )
        if self.confirm_hits < 1 or self.max_misses < 1 or self.tentative_max_misses < 1:
            raise ValueError("MemoryConfig: confirm_hits, max_misses, tentative_max_misses >= 1")
        if not 0.0 < self.smoothing <= 1.0 or not 0.0 < self.miss_decay <= 1.0:
            raise ValueError("MemoryConfig: smoothing and miss_decay must be in (0, 1]")
        if self.score_window < 1 or self.depth_window < 0:
            raise ValueError("MemoryConfig: score_window >= 1, depth_window >= 0")
        if not 0.0 <= self.partial_vote <= 1.0:
            raise ValueError(
                f"MemoryConfig.partial_vote must be in [0, 1], got {self.partial_vote}"
            )
        if self.image_margin < 0.0 or self.occlusion_tolerance < 0.0 or self.min_score < 0.0:
            raise ValueError("MemoryConfig: image_margin, occlusion_tolerance, min_score >= 0")


@dataclass(frozen=True)
class Observation:
    """One detection: ``centroid`` (odom, m) and axis-aligned ``extent`` (odom, m, size
    along x, y, z), detector ``score`` in [0, 1], the ``camera`` that saw it."""

    class_name: str
    score: float
    centroid: np.ndarray
    extent: np.ndarray
    camera: str = ""
    # the box reaches the image's edge: the object may be cut off, so its class, centroid
    # and extent are unreliable (a table's leg at the edge of a walking view was taken for
    # a "sugar box" in most tidy-up trials, 2026-12-05). It keeps a track it matches alive
    # and votes at ``MemoryConfig.partial_vote``, but moves nothing and starts no track.
    partial: bool = False


ObservationLike = Observation | tuple[str, float, Sequence[float], Sequence[float], str]


@dataclass(frozen=True)
class CameraView:
    """The camera a frame came from: OpenCV intrinsics ``K`` of the ``width`` x ``height``
    image, its optical frame (x right, y down, z forward) in odom (``position``,
    ``orientation`` [w, x, y, z]), and optionally its depth image (m along the optical axis,
    0 = no return) at full or any reduced resolution (pixels are scaled to it)."""

    camera: str
    K: np.ndarray
    width: int
    height: int
    position: np.ndarray
    orientation: np.ndarray
    depth: np.ndarray | None = None
    # The detector's working range for this camera; None: MemoryConfig's.
    min_range: float | None = None
    max_range: float | None = None


@dataclass
class Track:
    """A remembered object (odom frame)."""

    id: int
    class_name: str
    centroid: np.ndarray
    extent: np.ndarray
    confidence: float
    score: float  # running mean of the detection scores
    observations: int
    misses: int  # consecutive frames it should have been seen and was not
    first_seen: float
    last_seen: float
    cameras: frozenset[str] = field(default_factory=frozenset)
    confirmed: bool = False
    # score-weighted detections per class; class_name is the largest
    votes: dict[str, float] = field(default_factory=dict)

    def vote(self, class_name: str, weight: float) -> None:
        """Count a detection of ``class_name``; the track takes the leading class."""
        self.votes[class_name] = self.votes.get(class_name, 0.0) + weight
        self.class_name = max(self.votes, key=lambda c: (self.votes[c], c == self.class_name))

    def copy(self) -> Track:
        return replace(
            self, centroid=self.centroid.copy(), extent=self.extent.copy(), votes=dict(self.votes)
        )


def _as_observation(o: ObservationLike) -> Observation | None:
    """A checked Observation, or None for garbage (non-finite, wrong shape, bad score)."""
    try:
        if not isinstance(o, Observation):
            cls, score, c, e, cam = o
            o = Observation(str(cls), float(score), np.asarray(c, float), np.asarray(e, float), cam)
        c = np.asarray(o.centroid, dtype=float)
        e = np.asarray(o.extent, dtype=float)
        score = float(o.score)
    except (TypeError, ValueError):
        return None
    if c.shape != (3,) or e.shape != (3,) or not (np.all(np.isfinite(c)) and math.isfinite(score)):
        return None
    if not np.all(np.isfinite(e)) or np.any(e < 0.0) or not 0.0 <= score <= 1.0:
        return None
    return Observation(o.class_name, score, c, e, str(o.camera), bool(o.partial))


def _inside(
    point: Sequence[float] | np.ndarray, sphere: tuple[Sequence[float], float] | None
) -> bool:
    """Whether ``point`` lies in ``sphere`` (centre, radius); never for None."""
    if sphere is None:
        return False
    centre, radius = sphere
    return float(np.linalg.norm(np.asarray(point, float) - np.asarray(centre, float))) < radius


def _pose_matrix(pose: np.ndarray | tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A 4x4 homogeneous matrix from itself or a (position, quaternion wxyz) pair."""
    if isinstance(pose, tuple):
        p, q = pose
        t = np.eye(4)
        t[:3, :3] = quat_to_mat(np.asarray(q, dtype=float))
        t[:3, 3] = np.asarray(p, dtype=float)
        return t
    t = np.asarray(pose, dtype=float)
    if t.shape != (4, 4):
        raise ValueError(f"map_T_odom must be 4x4 or (position, quaternion), got {t.shape}")
    return t


class ObjectMemory:
    """Object tracks in the odom frame, fused from detections over frames and cameras."""

    def __init__(self, config: MemoryConfig | None = None) -> None:
        self.config = config or MemoryConfig()
        self._tracks: dict[int, Track] = {}
        self._next_id = 1
        self._merged_into: dict[int, int] = {}  # this update's merges: dropped -> kept
        self.rejected = 0  # malformed observations dropped (for the node's counters)
        # the last update's confirmed tracks removed for misses, with their distance (m)
        # from the camera: said in the node's log, so a trial's log tells where an object
        # found once went from the memory (paper-1, 2026-12-07: a Lego confirmed four
        # times, gone each time before the task came to it, never taken up)
        self.missed_out: list[tuple[Track, float]] = []

    # ------------------------------------------------------------------ queries
    def __len__(self) -> int:
        return len(self._tracks)

    def move_frame(self, se2: np.ndarray) -> None:
        """Re-expresses every track in a frame the planar transform ``se2`` (3x3: a
        rotation about z and a translation) takes the old one into: the node's way to
        keep objects where they lie in the world while the odometry drifts under them."""
        m = np.asarray(se2, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise ValueError(f"move_frame: a finite 3x3 planar transform, got {m.shape}")
        for t in self._tracks.values():
            c = np.asarray(t.centroid, dtype=float).copy()
            c[:2] = m[:2, :2] @ c[:2] + m[:2, 2]
            t.centroid = c

    def tracks(self, confirmed_only: bool = True) -> list[Track]:
        """Copies of the tracks (confirmed ones only by default), by id."""
        return [
            t.copy() for _, t in sorted(self._tracks.items()) if t.confirmed or not confirmed_only
        ]

    def confirmed_ids(self) -> set[int]:
        """Ids of the confirmed tracks (no copies: cheap enough for every frame)."""
        return {i for i, t in self._tracks.items() if t.confirmed}

    def get(self, track_id: int) -> Track | None:
        t = self._tracks.get(track_id)
        return None if t is None else t.copy()

    def to_map(
        self,
        map_T_odom: np.ndarray | tuple[np.ndarray, np.ndarray],  # noqa: N803 - frame notation
        confirmed_only: bool = True,
    ) -> list[Track]:
        """The tracks with centroids in the map frame (``map_T_odom``: a 4x4 matrix or a
        (position, quaternion wxyz) pair); extents become the axis-aligned box around the
        rotated box."""
        t = _pose_matrix(map_T_odom)
        r = t[:3, :3]
        out = []
        for tr in self.tracks(confirmed_only):
            tr.centroid = r @ tr.centroid + t[:3, 3]
            tr.extent = np.abs(r) @ tr.extent
            out.append(tr)
        return out

    # ------------------------------------------------------------------ edits
    def remove(self, track_id: int) -> bool:
        """Forget a track (the task picked the object up); False if there was none."""
        return self._tracks.pop(track_id, None) is not None

    def clear(self) -> None:
        self._tracks.clear()

    def update(
        self,
        observations: Iterable[ObservationLike],
        view: CameraView | None,
        stamp: float,
        blind: tuple[Sequence[float], float] | None = None,
    ) -> list[int]:
        """Fuse one frame's detections (all from ``view``'s camera; may be empty); returns
        the ids of the tracks they updated or created, in the observations' order
        (malformed, low-score, unmatched partial and blind observations are skipped and
        get no id).

        ``blind``: a sphere (odom centre, radius) the memory neither learns nor unlearns
        from: observations inside are dropped and tracks inside do not miss. The node
        passes the gripper's: what it holds moves with it, and is not an object lying
        where the cameras saw it (the held can was filed as a floor object and walked
        back to in a paper-5 trial, 2026-12-07)."""
        cfg = self.config
        self.missed_out = []
        obs: list[Observation] = []
        for raw in observations:
            o = _as_observation(raw)
            if o is None:
                self.rejected += 1
            elif o.score >= cfg.min_score and not _inside(o.centroid, blind):
                obs.append(o)
        # tentative tracks not seen again in time were noise
        for tid in [
            i
            for i, t in self._tracks.items()
            if not t.confirmed and stamp - t.last_seen > cfg.tentative_ttl
        ]:
            del self._tracks[tid]

        before = set(self._tracks)
        matched: dict[int, int] = self._associate(obs)  # observation index -> track id
        ids: list[int] = []
        seen: set[int] = set()
        for k, o in enumerate(obs):
            tid = matched.get(k)
            if tid is None and o.partial:
                continue  # a cut-off view starts nothing
            if tid is None:
                tid = self._new_track(o, stamp)
            else:
                self._absorb(self._tracks[tid], o, stamp)
            ids.append(tid)
            seen.add(tid)
        if view is not None:
            unseen = [
                i
                for i in before
                if i not in seen
                and i in self._tracks
                and not _inside(self._tracks[i].centroid, blind)
            ]
            self._count_misses(unseen, view, stamp)
        self._merge(seen)
        for t in self._tracks.values():
            t.confidence = self._confidence(t)
        return [self._resolve(i) for i in ids]

    def _resolve(self, tid: int) -> int:
        """The track id ``tid`` lives on as after this update's merges."""
        while tid not in self._tracks and tid in self._merged_into:
            tid = self._merged_into[tid]
        return tid

    # ------------------------------------------------------------------ internals
    def _gate(self, ext_a: np.ndarray, ext_b: np.ndarray) -> np.ndarray:
        """Gate radii for broadcast extents (..., 3)."""
        cfg = self.config
        half_diag = 0.5 * np.linalg.norm(np.maximum(ext_a, ext_b), axis=-1)
        return np.clip(cfg.gate_scale * half_diag, cfg.min_gate, cfg.max_gate)

    def _associate(self, obs: list[Observation]) -> dict[int, int]:
        out: dict[int, int] = {}
        for cls in {o.class_name for o in obs}:
            oi = [k for k, o in enumerate(obs) if o.class_name == cls]
            ti = [i for i, t in self._tracks.items() if t.class_name == cls]
            if not ti:
                continue
            oc = np.array([obs[k].centroid for k in oi])
            oe = np.array([obs[k].extent for k in oi])
            tc = np.array([self._tracks[i].centroid for i in ti])
            te = np.array([self._tracks[i].extent for i in ti])
            dist = np.linalg.norm(oc[:, None, :] - tc[None, :, :], axis=-1)
            ok = dist <= self._gate(oe[:, None, :], te[None, :, :])
            # pairs outside the gate cost more than any feasible set of pairs together
            cost = np.where(ok, dist, 1e6)
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows, cols, strict=True):
                if ok[r, c]:
                    out[oi[r]] = ti[c]
        # what no track of its class took: a track of another class right there (one
        # object the detector names two ways), the nearest, one observation each
        taken = set(out.values())
        for k, o in enumerate(obs):
            if k in out:
                continue
            best, best_d = None, self.config.class_radius
            for i, t in self._tracks.items():
                if i in taken or t.class_name == o.class_name:
                    continue
                d = float(np.linalg.norm(t.centroid - o.centroid))
                if d <= best_d:
                    best, best_d = i, d
            if best is not None:
                out[k] = best
                taken.add(best)
        return out

    def _new_track(self, o: Observation, stamp: float) -> int:
        tid = self._next_id
        self._next_id += 1
        self._tracks[tid] = Track(
            id=tid,
            class_name=o.class_name,
            centroid=o.centroid.copy(),
            extent=o.extent.copy(),
            confidence=0.0,
            score=o.score,
            observations=1,
            misses=0,
            first_seen=stamp,
            last_seen=stamp,
            cameras=frozenset({o.camera}) if o.camera else frozenset(),
            confirmed=self.config.confirm_hits <= 1,
            votes={o.class_name: o.score},
        )
        return tid

    def _absorb(self, t: Track, o: Observation, stamp: float) -> None:
        cfg = self.config
        if o.partial:  # seen, not measured (Observation.partial)
            t.misses = 0
            t.last_seen = max(t.last_seen, stamp)
            t.vote(o.class_name, cfg.partial_vote * o.score)
            return
        t.observations += 1
        a = max(1.0 / t.observations, cfg.smoothing)
        t.centroid = (1.0 - a) * t.centroid + a * o.centroid
        t.extent = (1.0 - a) * t.extent + a * o.extent
        b = 1.0 / min(t.observations, cfg.score_window)
        t.score += b * (o.score - t.score)
        t.misses = 0
        t.last_seen = max(t.last_seen, stamp)
        t.vote(o.class_name, o.score)
        if o.camera:
            t.cameras = t.cameras | {o.camera}
        t.confirmed = t.confirmed or t.observations >= cfg.confirm_hits

    def _confidence(self, t: Track) -> float:
        cfg = self.config
        evidence = 1.0 - math.exp(-t.observations / cfg.evidence_scale)
        return float(t.score * evidence * cfg.miss_decay**t.misses)

    def visible(self, points: np.ndarray, sizes: np.ndarray, view: CameraView) -> np.ndarray:
        """Which odom ``points`` (N, 3) of largest size ``sizes`` (N,) ``view``'s camera
        should see: in front, in the image, in the detector's range, not hidden."""
        cfg = self.config
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        r = quat_to_mat(np.asarray(view.orientation, dtype=float))
        pc = (pts - np.asarray(view.position, dtype=float)) @ r  # = r.T @ (p - t), per row
        z = pc[:, 2]
        rng = np.linalg.norm(pc, axis=1)
        lo = cfg.min_range if view.min_range is None else view.min_range
        hi = cfg.max_range if view.max_range is None else view.max_range
        vis = (z > 1e-6) & (rng >= lo) & (rng <= hi)
        K = np.asarray(view.K, dtype=float)
        zs = np.where(vis, z, 1.0)
        u = (K[0, 0] * pc[:, 0] + K[0, 1] * pc[:, 1]) / zs + K[0, 2]
        v = K[1, 1] * pc[:, 1] / zs + K[1, 2]
        m = cfg.image_margin
        vis &= (u >= m) & (u <= view.width - 1 - m) & (v >= m) & (v <= view.height - 1 - m)
        if view.depth is None or not np.any(vis):
            return vis
        depth = np.asarray(view.depth, dtype=float)
        dh, dw = depth.shape
        # pixel centres scale with the resolution (a downsampled copy of the image)
        du = np.clip(((u + 0.5) * dw / view.width - 0.5).round().astype(int), 0, dw - 1)
        dv = np.clip(((v + 0.5) * dh / view.height - 0.5).round().astype(int), 0, dh - 1)
        w = np.arange(-cfg.depth_window, cfg.depth_window + 1)
        cols = np.clip(du[:, None, None] + w[None, None, :], 0, dw - 1)
        rows = np.clip(dv[:, None, None] + w[None, :, None], 0, dh - 1)
        win = depth[rows, cols].reshape(len(pts), -1)
        win = np.where(np.isfinite(win) & (win > 0.0), win, -np.inf)
        far = win.max(axis=1)
        known = np.isfinite(far)
        # no return anywhere at the pixel: no evidence either way, so not a miss
        hidden = ~known | (far < z - cfg.occlusion_tolerance - 0.5 * np.asarray(sizes))
        return vis & ~hidden

    def _count_misses(self, ids: list[int], view: CameraView, stamp: float) -> None:
        if not ids:
            return
        cfg = self.config
        pts = np.array([self._tracks[i].centroid for i in ids])
        sizes = np.array([float(np.max(self._tracks[i].extent)) for i in ids])
        far = np.linalg.norm(pts - np.asarray(view.position, dtype=float), axis=1)
        reach = np.array([cfg.miss_ranges.get(self._tracks[i].class_name, math.inf) for i in ids])
        seen = self.visible(pts, sizes, view) & (far <= reach)
        for i, vis, dist in zip(ids, seen, far, strict=True):
            if not vis:
                continue
            t = self._tracks[i]
            t.misses += 1
            if t.confirmed and stamp - t.last_seen < cfg.miss_time:
                continue
            if t.misses >= (cfg.max_misses if t.confirmed else cfg.tentative_max_misses):
                if t.confirmed:
                    self.missed_out.append((t, float(dist)))
                del self._tracks[i]

    def _merge(self, seen_now: set[int]) -> None:
        """Merge same-class tracks within each other's gate (not two seen in this frame),
        and tracks of different classes within ``class_radius`` (one object named two ways:
        the detector may name it both ways in one frame too)."""
        self._merged_into = {}
        ids = sorted(self._tracks)
        if len(ids) < 2:
            return
        c = np.array([self._tracks[i].centroid for i in ids])
        e = np.array([self._tracks[i].extent for i in ids])
        cls = np.array([self._tracks[i].class_name for i in ids])
        dist = np.linalg.norm(c[:, None] - c[None], axis=-1)
        same = cls[:, None] == cls[None]
        close = (dist <= self._gate(e[:, None], e[None])) & same
        close |= (dist <= self.config.class_radius) & ~same
        close &= np.triu(np.ones_like(close), k=1).astype(bool)
        for a, b in zip(*np.nonzero(close), strict=True):
            ia, ib = ids[a], ids[b]
            both_now = ia in seen_now and ib in seen_now
            if (both_now and same[a, b]) or ia not in self._tracks:
                continue
            if ib not in self._tracks:
                continue
            keep, drop = ia, ib
            ta, tb = self._tracks[keep], self._tracks[drop]
            if tb.observations > ta.observations:
                keep, drop, ta, tb = drop, keep, tb, ta
            n = ta.observations + tb.observations
            wa = ta.observations / n
            ta.centroid = wa * ta.centroid + (1.0 - wa) * tb.centroid
            ta.extent = wa * ta.extent + (1.0 - wa) * tb.extent
            ta.score = wa * ta.score + (1.0 - wa) * tb.score
            ta.observations = n
            ta.misses = min(ta.misses, tb.misses)
            ta.first_seen = min(ta.first_seen, tb.first_seen)
            ta.last_seen = max(ta.last_seen, tb.last_seen)
            ta.cameras = ta.cameras | tb.cameras
            for name, w in tb.votes.items():
                ta.vote(name, w)
            ta.confirmed = ta.confirmed or tb.confirmed or n >= self.config.confirm_hits
            del self._tracks[drop]
            self._merged_into[drop] = keep


def planar_pose_matrix(x: float, y: float, yaw: float) -> np.ndarray:
    """The 3x3 homogeneous matrix of a planar pose."""
    m = rot_z(yaw)  # its last row and column are those of a planar pose already
    m[:2, 2] = (x, y)
    return m


class MapAnchor:
    """Keeps odom-frame tracks where they lie in the map while the odometry drifts.

    Tracks are kept in ``odom``, the frame of the observations; navigation's map->odom
    correction changes as it takes out the odometry's drift (about 1 % of the distance
    walked, docs/locomotion.md), and a track left in odom drifts with it. In random
    tidy-up trials objects seen long before were approached 0.10-0.23 m beside where they
    lay (seed-106: three grasps refused as ``lateral_out_of_range``), and the track, missed
    where it was believed to be, was forgotten just before the probe (12-23 probes per
    trial asked for an unknown track). :meth:`step` gives the transform that moves the
    tracks with each change of the correction (also the jump of a restarted odometry)."""

    def __init__(self) -> None:
        self.last: np.ndarray | None = None  # the correction the tracks are kept under

    def step(self, map_to_odom: Sequence[float] | None) -> np.ndarray | None:
        """The planar transform for :meth:`ObjectMemory.move_frame` after navigation's
        correction became ``map_to_odom`` (x, y, yaw; None: not localised, nothing
        moves); None when nothing changed."""
        if map_to_odom is None:
            return None
        now = planar_pose_matrix(*(float(v) for v in map_to_odom))
        last, self.last = self.last, now
        if last is None or np.allclose(now, last, rtol=0.0, atol=1e-9):
            return None
        # a track at odom p lies at map last @ p; in the new odom frame at inv(now) @ that
        return np.linalg.inv(now) @ last
