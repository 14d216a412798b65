"""Filtering a box cut's outliers (paper Section 4.2): object / background split, background
removal, plane-fitting RANSAC.

The paper splits the cloud of a detection box into two parts with KNN, drops the part whose
centroid is farther from the camera (the background), then uses plane-fitting RANSAC to
filter the remaining outliers and to get plane normals for the grasp direction (4.3).

What we do, and why:

0. **Self filter**: points inside the robot's own body box are dropped first (the gripper
   camera looking down at a table sees the trunk below the table's edge).
1. **Split** (the paper's KNN step): an exact 1-D 2-means on the points' distances from the
   optical centre (:func:`two_means_split`, sorted prefix sums, no iterations, no random
   start). The cluster with the nearer centroid is the object (the paper's criterion);
   the other is the background. 1-D is enough because the criterion *is* the distance to
   the camera, and it is deterministic and O(N log N).
2. **Supporting plane** (RANSAC, :func:`fit_plane_ransac`): the floor or table top under
   the object, whose height the grasp's ``hang`` and the fingertip clearance are measured
   from. The robot's attitude gives its normal (``up``, within ``surface_max_tilt``), so
   one point makes a hypothesis. Horizontal planes are peeled off one after the other
   (sequential RANSAC, each scored with a penalty for points below it: nothing lies under
   what an object stands on). The support is, of the planes that

   * the camera is above (a row of an object's face seen from below a table is no table),
   * is a surface, not a line (its inliers spread across their main direction),
   * has the object on it (enough points above, rising at least ``surface_min_object``:
     a box's own top face and a ball's flat-looking cap have none),
   * is not enclosed by the object (a bowl's bottom is surrounded by its wall),

   the one that scores best: its inliers less a penalty for the points under it that lie
   on no other plane (a band around a ball's middle has the ball's lower half under it; a
   table has only the floor). So the table around an object wins over a strip of floor
   seen past the table's edge.
3. **Background removal**: the 2-means split alone cuts a sphere or a tall box in two (its
   lower half is as far from the camera as the floor around it), so once the supporting
   plane is known the object is every point more than ``surface_clearance`` above it
   (the paper's "remaining outliers" are the surface points left in the near cluster).
   Without a plane (a front camera below a table top sees none) the near cluster is the
   object.
4. **Object normal** (4.3's probing-direction decision): plane-fitting RANSAC on the object's
   own points; its normal (oriented towards the camera) and inlier share.

All vectorised: RANSAC scores every hypothesis against a fixed random subsample at once
(one matrix product), then refines the best plane by least squares on all its inliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = [
    "FilterConfig",
    "FilterResult",
    "Plane",
    "filter_object",
    "fit_plane_ransac",
    "two_means_split",
]


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the outlier filter (``[grasp.filter]``)."""

    min_points: int = 30  # fewer object points than this: nothing to work with
    plane_iterations: int = 96  # RANSAC hypotheses per plane fit
    plane_sample: int = 800  # points each hypothesis is scored on (a random subsample)
    plane_tolerance: float = 0.004  # m: inlier distance to a plane
    surface_max_tilt: float = 0.05  # rad: supporting plane normal vs up (3 deg)
    surface_min_inliers: int = 25  # a supporting plane needs this many inliers ...
    surface_min_share: float = 0.05  # ... and this share of the box cut's points
    max_planes: int = 3  # horizontal planes peeled off when looking for the support
    surface_min_spread: float = 0.003  # m: std of its inliers across their main direction
    footprint_cell: float = 0.004  # m: raster of the object's footprint for that test
    surface_clearance: float = 0.004  # m: object points lie this far above the surface
    surface_below_penalty: float = 2.0  # inliers a point below a support hypothesis costs
    surface_min_object: float = 0.01  # m: what stands on a support rises at least this high
    seed: int = 0  # RANSAC's random generator (deterministic results)
    # Self filter: points inside this base-frame box are the robot's own body (trunk,
    # LiDAR dome, front camera: configs/robot/quadmanip_dog.xml, trunk half-size 0.2095 x
    # 0.125 x 0.055 m, dome top 0.09 m, lens front 0.2245 m), which the gripper camera
    # sees below a table's edge. A zero-size box disables it.
    self_min: tuple[float, float, float] = (-0.30, -0.22, -0.45)
    self_max: tuple[float, float, float] = (0.235, 0.22, 0.10)
    # A box whose points lie mostly in the self box frames the robot itself: the gripper
    # camera sees the trunk's orange corners between open fingers, which detectors took
    # for cups and toy guns: 0.76-0.97 of such boxes' points lie in the self box, at most
    # 0.17 of a true detection's (353 in 200 rendered scenes). Placing its leftover floor
    # made a phantom track a step ahead of the robot wherever it walked.
    self_max_share: float = 0.5
    # Points nearer the camera than this are the robot's own gripper: the gripper camera
    # sees its palm and fingers 3-8 cm away, and a box whose edge reaches them took them
    # for a 28 cm tall object (a soup can on a table sent to side probing). Nothing the
    # robot probes is nearer than its fingertips.
    min_range: float = 0.12


@dataclass(frozen=True)
class Plane:
    """A plane ``normal . p = offset`` (unit normal) and the share of points it explains."""

    normal: np.ndarray
    offset: float
    inlier_ratio: float
    inliers: int

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of points (N, 3) along the normal."""
        return np.asarray(points, dtype=float) @ self.normal - self.offset

    def z_at(self, x: float, y: float) -> float:
        """Height of the plane at (x, y) (the plane must not be vertical)."""
        n = self.normal
        return float((self.offset - n[0] * x - n[1] * y) / n[2])


@dataclass(frozen=True)
class FilterResult:
    """The object's points and what the filter learnt about the scene (base frame)."""

    object_points: np.ndarray  # (M, 3)
    background_points: np.ndarray  # (K, 3)
    surface: Plane | None  # supporting plane, normal pointing up (None: not seen)
    object_plane: Plane | None  # the object's dominant plane, normal towards the camera
    self_share: float = 0.0  # share of the input points inside the self box


def two_means_split(values: np.ndarray) -> float:
    """Threshold of the optimal 2-means partition of 1-D ``values`` (exact).

    For sorted values the optimal two clusters are a prefix and a suffix; the split that
    minimises the within-cluster sum of squares maximises ``n1 n2 (m1 - m2)^2 / n``, which
    prefix sums give for every split at once.
    """
    v = np.sort(np.asarray(values, dtype=float).ravel())
    n = v.size
    if n < 2:
        return float(v[0]) if n else 0.0
    c = np.cumsum(v)
    n1 = np.arange(1, n)
    m1 = c[:-1] / n1
    m2 = (c[-1] - c[:-1]) / (n - n1)
    score = n1 * (n - n1) * (m1 - m2) ** 2
    k = int(np.argmax(score))
    return float(0.5 * (v[k] + v[k + 1]))


def _plane_through(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (H, 3) and offsets (H,) of the planes through point triples (H, 3, 3)."""
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    norm = np.linalg.norm(n, axis=1)
    n = n / np.maximum(norm, 1e-12)[:, None]
    n[norm < 1e-12] = 0.0  # degenerate (collinear) triples never win
    return n, np.einsum("ij,ij->i", n, p[:, 0])


def _refine(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (normal, offset) through points: smallest principal axis."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[-1]
    return n, float(n @ c)


def fit_plane_ransac(
    points: np.ndarray,
    cfg: FilterConfig,
    rng: np.random.Generator,
    up: np.ndarray | None = None,
    max_tilt: float | None = None,
    min_inliers: int = 3,
    below_penalty: float = 0.0,
) -> Plane | None:
    """Plane-fitting RANSAC (paper [18]) on points (N, 3), vectorised.

    With ``up`` and ``max_tilt`` the hypotheses are planes normal to ``up`` through single
    points, refined by least squares within ``max_tilt`` (rad) of ``up`` (a supporting
    surface, the robot's attitude being known); the returned normal then points along
    ``up``, and each point more than the tolerance *below* a hypothesis costs
    ``below_penalty`` inliers: nothing lies under what an object stands on, so a plane
    tilted through a bowl's bottom and half the floor around it loses to the floor.
    None when no plane has ``min_inliers`` inliers.
    """
    pts = np.asarray(points, dtype=float)
    n_pts = pts.shape[0]
    if n_pts < max(3, min_inliers):
        return None
    if up is not None and max_tilt is not None:
        # the normal is known up to max_tilt: one point makes a hypothesis (a plane at that
        # point's height), so a surface showing in a tenth of the cut is still sampled;
        # the least-squares refit below recovers a small tilt
        u = np.asarray(up, dtype=float) / np.linalg.norm(up)
        k = min(n_pts, cfg.plane_iterations)
        normals = np.repeat(u[None, :], k, axis=0)
        offsets = pts[rng.choice(n_pts, k, replace=False)] @ u
    else:
        idx = rng.integers(0, n_pts, size=(cfg.plane_iterations, 3))
        normals, offsets = _plane_through(pts[idx])
        valid = np.linalg.norm(normals, axis=1) > 0.5
        if not valid.any():
            return None
        normals, offsets = normals[valid], offsets[valid]
    sample = pts if n_pts <= cfg.plane_sample else pts[rng.choice(n_pts, cfg.plane_sample, False)]
    # every hypothesis against the subsample in one product: (H, S) distances
    dist = sample @ normals.T - offsets
    counts = (np.abs(dist) <= cfg.plane_tolerance).sum(axis=0).astype(float)
    if up is not None and below_penalty > 0.0:
        side = np.sign(normals @ up)  # dist is along each normal; "below" is against up
        counts -= below_penalty * ((dist * side) < -cfg.plane_tolerance).sum(axis=0)
    best = int(np.argmax(counts))
    inl = np.abs(pts @ normals[best] - offsets[best]) <= cfg.plane_tolerance
    if inl.sum() < max(3, min_inliers):
        return None
    n, d = _refine(pts[inl])
    if up is not None and max_tilt is not None and abs(float(n @ up)) < np.cos(max_tilt):
        n, d = normals[best], float(offsets[best])  # the refit tilted away: keep the sample's
    inl = np.abs(pts @ n - d) <= cfg.plane_tolerance
    if up is not None and float(n @ up) < 0.0:
        n, d = -n, -d
    return Plane(normal=n, offset=d, inlier_ratio=float(inl.mean()), inliers=int(inl.sum()))


def _enclosed(ref: np.ndarray, query: np.ndarray, cell: float) -> np.ndarray:
    """Which 2-D ``query`` points fall in a hole of the footprint of ``ref``: cells with no
    ``ref`` point that ``ref``'s cells enclose (rasterised at ``cell`` m; one-cell gaps in
    a thin rim are closed first). A bowl's bottom is enclosed by its wall; the floor
    beside a lying screwdriver is not, however close."""
    lo = ref.min(axis=0) - 2 * cell
    n = np.ceil((ref.max(axis=0) + 2 * cell - lo) / cell).astype(int) + 1
    occ = np.zeros(n, bool)
    ij = ((ref - lo) / cell).astype(int)
    occ[ij[:, 0], ij[:, 1]] = True
    holes = ndimage.binary_fill_holes(ndimage.binary_closing(occ) | occ) & ~occ
    q = np.floor((query - lo) / cell).astype(int)
    ok = np.all((q >= 0) & (q < n), axis=1)
    out = np.zeros(query.shape[0], bool)
    out[ok] = holes[q[ok, 0], q[ok, 1]]
    return out


def _support_plane(
    pts: np.ndarray,
    cam: np.ndarray,
    up: np.ndarray,
    cfg: FilterConfig,
    rng: np.random.Generator,
) -> Plane | None:
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    flat = np.stack([e1, np.cross(up, e1)], axis=1)  # levelled 2-D coordinates
    planes: list[Plane] = []
    rest = pts
    for _ in range(cfg.max_planes):
        pl = fit_plane_ransac(
            rest,
            cfg,
            rng,
            up=up,
            max_tilt=cfg.surface_max_tilt,
            min_inliers=max(cfg.surface_min_inliers, int(cfg.surface_min_share * len(pts))),
            below_penalty=cfg.surface_below_penalty,
        )
        if pl is None:
            break
        planes.append(pl)
        rest = rest[np.abs(pl.distance(rest)) > cfg.plane_tolerance]
    valid: list[Plane] = []
    for pl in planes:
        if float(pl.normal @ cam) - pl.offset <= cfg.plane_tolerance:
            continue  # the camera is below it: it cannot see a surface there (rows of a face)
        d = pl.distance(pts)
        above = d > cfg.surface_clearance
        if above.sum() < cfg.min_points or d.max() < cfg.surface_min_object:
            continue  # nothing stands on it: the object's own top (or a ball's cap)
        q = pts[np.abs(d) <= cfg.plane_tolerance] @ flat
        # what the object encloses (a bowl's or a cup's bottom, level with the floor within
        # the tolerance) is not what it stands on
        q = q[~_enclosed(pts[above] @ flat, q, cfg.footprint_cell)]
        if q.shape[0] < max(cfg.surface_min_inliers, cfg.surface_min_share * len(pts)):
            continue  # (almost) all enclosed by the object: a bowl's bottom
        if np.linalg.svd(q - q.mean(axis=0), compute_uv=False)[1] < cfg.surface_min_spread * (
            math.sqrt(q.shape[0])
        ):
            continue  # a line, not a surface: the bottom row of an object seen from the side
        valid.append(pl)
    # the best scores its (not enclosed) inliers less a penalty for the points under it
    # that lie on no other plane: a band around a ball's middle has the ball's lower half
    # under it; a table has only the floor past its edge
    best, best_score = None, -np.inf
    on_plane = {id(pl): np.abs(pl.distance(pts)) <= cfg.plane_tolerance for pl in planes}
    for pl in valid:
        others = np.zeros(len(pts), bool)
        for other in planes:
            if other is not pl:
                others |= on_plane[id(other)]
        under = int(((pl.distance(pts) < -cfg.plane_tolerance) & ~others).sum())
        score = int(on_plane[id(pl)].sum()) - cfg.surface_below_penalty * under
        if score > best_score:
            best, best_score = pl, score
    return best


def filter_object(
    points: np.ndarray,
    camera_position: np.ndarray,
    cfg: FilterConfig | None = None,
    up: np.ndarray | None = None,
) -> FilterResult:
    """Section 4.2 on a box cut's points (base frame): the object's points, the supporting
    plane and the object's own RANSAC plane. ``up`` is the gravity direction in the base
    frame (default: base z, a level stance)."""
    cfg = cfg or FilterConfig()
    rng = np.random.default_rng(cfg.seed)
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    cam = np.asarray(camera_position, dtype=float)
    up_v = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    empty = np.zeros((0, 3))
    lo, hi = np.asarray(cfg.self_min), np.asarray(cfg.self_max)
    share = 0.0
    if pts.shape[0]:
        own = np.linalg.norm(pts - cam, axis=1) < cfg.min_range
        if np.all(hi > lo):
            own |= np.all((pts >= lo) & (pts <= hi), axis=1)
        share = float(own.mean())
        pts = pts[~own]
        if share > cfg.self_max_share:  # the box framed the robot: no object in it
            return FilterResult(empty, pts, None, None, share)
    if pts.shape[0] < cfg.min_points:
        return FilterResult(pts, empty, None, None, share)
    # 1. the paper's split: the part with the nearer centroid is the object
    dist = np.linalg.norm(pts - cam, axis=1)
    near = dist <= two_means_split(dist)
    # 2. the supporting plane: horizontal planes are peeled off one by one (sequential
    # RANSAC); a plane supports the object if something stands on it
    # (a box's top face has nothing above it) and the object does not enclose most of it
    # (a bowl's bottom is enclosed by its wall). The largest such plane wins: the
    # table around the object beats a strip of floor seen beyond the table's edge, and
    # the floor beats a band of a lying screwdriver's handle at its shaft's height.
    surface = _support_plane(pts, cam, up_v, cfg, rng)
    # 3. background removal: above the surface (else the near cluster)
    is_obj = near if surface is None else surface.distance(pts) > cfg.surface_clearance
    obj = pts[is_obj]
    # 4. the object's dominant plane (4.3), normal towards the camera
    plane = fit_plane_ransac(obj, cfg, rng, min_inliers=3) if obj.shape[0] >= 3 else None
    if plane is not None and float(plane.normal @ (cam - obj.mean(axis=0))) < 0.0:
        plane = Plane(-plane.normal, -plane.offset, plane.inlier_ratio, plane.inliers)
    return FilterResult(obj, pts[~is_obj], surface, plane, share)
