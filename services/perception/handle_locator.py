"""Drawer handles from the front camera's depth image (paper Section 7.2's drawer task).

The robot knows roughly where a handle is (the map's places, within ~10 cm); this module
measures it. Steps, all vectorised numpy:

1. Project a cube of ``roi_radius`` around the expected handle into the image, lift the
   depth pixels inside it to 3-D and keep those within ``roi_radius`` (all in the camera
   frame; only the answer is turned into the caller's frame).
2. Fit the cabinet front as a near-vertical plane by RANSAC (every hypothesis scored at
   once on a random subset of the points, then a least-squares refit on the inliers).
3. Take the points standing out of the plane towards the robot by a bar's depth
   (``min_protrusion`` .. ``max_protrusion``) and cluster them by where they stand on the
   front (8-connected cells on the plane), so the bar's faces seen at a grazing angle stay
   one cluster. A cluster touching points that stand out further (the floor in front of a
   low drawer, an object before the cabinet) is part of something else and is refused.
4. The nearest plausible cluster (length, height) within ``max_offset`` of the expected
   place is the handle. Its centre is measured on the bar's front face (the points within
   ``front_tol`` of the furthest-out ones): the middle of their lateral and vertical
   extents, then half the bar's thickness back into the bar. A bar cut off by the image's
   edge is flagged ``truncated``; its visible part's middle is given (still on the bar).

The result follows the drawer action's convention (``DrawerGoal`` in common/messages.py,
``_open_drawer`` in quadmanip/testbench/stack_trials.py): ``position`` is the centre of the
handle bar, the point the gripper's tool centre closes on; ``pull_direction`` is the unit
horizontal normal of the cabinet front pointing out of it, towards the robot, i.e. the
drawer's slide axis. Both are in the frame the camera pose is given in (the base frame of
an ``RgbdImage``).

Handles are assumed to be horizontal bars standing off a flat front (the house's drawers,
and what the drawer primitive grips); a knob or a recessed handle is not found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from quadmanip.common.rotations import quat_to_mat
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = ["HandleConfig", "HandleResult", "locate_handle"]

_UP = np.array([0.0, 0.0, 1.0])
# Fields of view (deg) a depth camera can have; outside, K is taken for garbage.
_FOV_DEG = (2.0, 170.0)


@dataclass(frozen=True)
class HandleConfig:
    """Parameters of :func:`locate_handle` (``[handle]`` of configs/perception.toml).

    Lengths in metres, angles in degrees. The handle geometry defaults are the house's
    (configs/house.toml ``[cabinet]``: bar 14 mm square, 14 cm long, its centre 35 mm in
    front of the drawer's face, so its front face stands 42 mm out).
    """

    # Points farther than this from the expected handle are ignored. Covers the map's
    # error (~10 cm) plus half a handle's length, and enough cabinet front for the plane.
    roi_radius: float = 0.25
    # The handle's centre may lie this far from the expected place.
    max_offset: float = 0.12
    # Depths used (m along the optical axis); outside is treated as no return.
    min_depth: float = 0.1
    max_depth: float = 2.5
    # RANSAC: hypotheses, points each hypothesis is scored on, inlier distance.
    ransac_iterations: int = 64
    ransac_score_points: int = 1000
    plane_tol: float = 0.006
    # Drawer fronts are vertical: the plane's normal must be within this of horizontal
    # (also keeps RANSAC off the floor and table tops).
    max_plane_tilt_deg: float = 25.0
    # A plane needs this many inliers, this fraction of the region's points, and this
    # spread (m, RMS) across its narrower in-plane direction (not a line of points).
    min_plane_inliers: int = 200
    min_plane_fraction: float = 0.25
    min_plane_spread: float = 0.02
    # Points standing out of the plane by at least this are handle candidates ...
    min_protrusion: float = 0.015
    # ... and a handle stands out by no more than this (front face at 42 mm + margin).
    max_protrusion: float = 0.07
    # Thickness of the bar (front to back): the centre is half of it behind the front face.
    bar_thickness: float = 0.014
    # Points within this of the furthest-out ones are the bar's front face.
    front_tol: float = 0.005
    # Neighbour distance that links candidate points into one cluster; fewer points than
    # ``min_cluster_points`` is noise.
    cluster_radius: float = 0.012
    min_cluster_points: int = 25
    # Plausible handle size: lateral length (the front face's extent) and height.
    min_handle_length: float = 0.04
    max_handle_length: float = 0.45
    max_handle_height: float = 0.06
    # RANSAC's random generator is seeded per call: the same image gives the same answer.
    seed: int = 0

    def __post_init__(self) -> None:
        pos = (
            "roi_radius",
            "max_offset",
            "min_depth",
            "max_depth",
            "plane_tol",
            "min_plane_spread",
            "min_protrusion",
            "max_protrusion",
            "bar_thickness",
            "front_tol",
            "cluster_radius",
            "min_handle_length",
            "max_handle_length",
            "max_handle_height",
        )
        for name in pos:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"HandleConfig.{name} must be finite and > 0, got {v}")
        if self.min_depth >= self.max_depth:
            raise ValueError("HandleConfig: min_depth must be below max_depth")
        if self.min_protrusion >= self.max_protrusion:
            raise ValueError("HandleConfig: min_protrusion must be below max_protrusion")
        if self.min_handle_length >= self.max_handle_length:
            raise ValueError("HandleConfig: min_handle_length must be below max_handle_length")
        if not 0.0 < self.max_plane_tilt_deg < 90.0:
            raise ValueError("HandleConfig.max_plane_tilt_deg must be in (0, 90)")
        if self.ransac_iterations < 1 or self.ransac_score_points < 3:
            raise ValueError("HandleConfig: RANSAC needs >= 1 iteration and >= 3 points")
        if self.min_plane_inliers < 3 or self.min_cluster_points < 1:
            raise ValueError("HandleConfig: min_plane_inliers >= 3, min_cluster_points >= 1")
        if not 0.0 <= self.min_plane_fraction <= 1.0:
            raise ValueError("HandleConfig.min_plane_fraction must be in [0, 1]")


#: Rejection reasons (``HandleResult.reason``); "" when a handle was found.
REASONS = ("bad_input", "empty_depth", "not_in_view", "no_plane", "no_handle")


@dataclass(frozen=True)
class HandleResult:
    """What :func:`locate_handle` found.

    ``ok`` with ``position`` (handle bar centre) and ``pull_direction`` (unit, horizontal,
    out of the cabinet) in the camera pose's frame; otherwise ``reason`` is one of
    :data:`REASONS` and ``detail`` says why in words. ``quality`` in [0, 1] is a heuristic:
    the plane's share of the region's points times the handle cluster's support.
    """

    ok: bool
    reason: str = ""
    detail: str = ""
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pull_direction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quality: float = 0.0
    plane_normal: np.ndarray = field(default_factory=lambda: np.zeros(3))
    plane_inlier_fraction: float = 0.0
    plane_rms: float = 0.0  # m, RMS distance of the plane's inliers
    handle_points: int = 0
    handle_length: float = 0.0  # m, lateral extent of the bar's front face
    offset: float = 0.0  # m, distance of the found centre from the expected place
    # The bar runs off the image or the searched region: ``position`` is the middle of its
    # visible part (still on the bar, so still a safe grip), not its true centre.
    truncated: bool = False


def _reject(reason: str, detail: str, **kw: object) -> HandleResult:
    return HandleResult(ok=False, reason=reason, detail=detail, **kw)  # type: ignore[arg-type]


def _check_inputs(
    depth: np.ndarray, K: np.ndarray, position: np.ndarray, orientation: np.ndarray, exp: np.ndarray
) -> str:
    """'' when usable, else what is wrong."""
    if depth.ndim != 2 or depth.shape[0] < 2 or depth.shape[1] < 2:
        return f"depth must be a 2-D image, got shape {depth.shape}"
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        return "K must be a finite 3x3 matrix"
    h, w = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0.0 and fy > 0.0) or np.any(np.abs(K[2] - (0.0, 0.0, 1.0)) > 1e-9):
        return f"K is not a pinhole intrinsic matrix (fx={fx:g}, fy={fy:g}, last row {K[2]})"
    if K[1, 0] != 0.0 or abs(cx - w / 2) > w or abs(cy - h / 2) > h:
        return f"K's principal point ({cx:g}, {cy:g}) is far outside the {w}x{h} image"
    fov = np.degrees(2.0 * np.arctan2([w / 2, h / 2], [fx, fy]))
    if np.any(fov < _FOV_DEG[0]) or np.any(fov > _FOV_DEG[1]):
        return f"K gives a {fov[0]:.3g} x {fov[1]:.3g} deg field of view: not a real camera"
    if position.shape != (3,) or not np.all(np.isfinite(position)):
        return "camera position must be 3 finite numbers"
    if orientation.shape != (4,) or not np.all(np.isfinite(orientation)):
        return "camera orientation must be 4 finite numbers [w, x, y, z]"
    if abs(float(np.linalg.norm(orientation)) - 1.0) > 1e-3:
        return "camera orientation must be a unit quaternion"
    if exp.shape != (3,) or not np.all(np.isfinite(exp)):
        return "expected handle position must be 3 finite numbers"
    return ""


def _roi(
    K: np.ndarray, exp_c: np.ndarray, radius: float, shape: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """Pixel box (r0, r1, c0, c1) covering the cube of half-size ``radius`` around
    ``exp_c`` (camera frame); None when it lies wholly behind the camera or off the image."""
    h, w = shape
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    pc = exp_c + radius * signs
    front = pc[:, 2] > 1e-3
    if not np.any(front):
        return None
    if not np.all(front):
        return 0, h, 0, w  # the cube straddles the camera plane: take the whole image
    uv = pc @ K.T
    u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
    c0, c1 = max(0, math.floor(u.min())), min(w, math.ceil(u.max()) + 1)
    r0, r1 = max(0, math.floor(v.min())), min(h, math.ceil(v.max()) + 1)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1


def _ransac_plane(
    P: np.ndarray, up: np.ndarray, cfg: HandleConfig, rng: np.random.Generator
) -> tuple[np.ndarray, float, float] | None:
    """Best plane through the (3, N) points ``P`` with its normal within
    ``max_plane_tilt_deg`` of horizontal (``up`` is the vertical): unit normal n, offset d
    (n.p + d = 0) and the inliers' RMS spread across the plane's narrower direction."""
    n_pts = P.shape[1]
    max_up = math.sin(math.radians(cfg.max_plane_tilt_deg))
    k = min(n_pts, cfg.ransac_score_points)
    score = P[:, rng.integers(0, n_pts, k)] if k < n_pts else P
    idx = rng.integers(0, n_pts, size=(3, cfg.ransac_iterations))
    a, b, c = P[:, idx[0]].T, P[:, idx[1]].T, P[:, idx[2]].T
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    good = norms > 1e-9
    normals[good] /= norms[good, None]
    good &= np.abs(normals @ up) <= max_up
    if not np.any(good):
        return None
    normals, a = normals[good], a[good]
    d = -np.einsum("ij,ij->i", normals, a)
    # every hypothesis scored at once: (hypotheses, points) distances
    counts = (np.abs(normals @ score + d[:, None]) < cfg.plane_tol).sum(axis=1)
    best = int(np.argmax(counts))
    n, off = normals[best], float(d[best])
    spread = 0.0
    # least-squares refit on the inliers (twice: the first refit may gain a few)
    for _ in range(2):
        inl = np.compress(np.abs(n @ P + off) < cfg.plane_tol, P, axis=1)
        if inl.shape[1] < 3:
            return None
        centre = inl.mean(axis=1)
        q = inl - centre[:, None]
        w, v = np.linalg.eigh(q @ q.T)  # ascending: v[:, 0] is the normal
        spread = math.sqrt(max(float(w[1]), 0.0) / inl.shape[1])
        if abs(float(v[:, 0] @ up)) > max_up:
            break  # the refit tipped over (a sliver of floor?): keep the last plane
        n, off = v[:, 0], -float(v[:, 0] @ centre)
    return n, off, spread


def _clusters(x: np.ndarray, y: np.ndarray, radius: float) -> tuple[int, np.ndarray]:
    """Connected components of 2-D points on a grid of ``radius / 2`` cells, 8-connected,
    so points about ``radius`` apart join: (count, label per point). A grid rather than a
    radius graph: dense depth puts ~150 neighbours within a centimetre of each point."""
    if len(x) == 0:
        return 0, np.zeros(0, dtype=int)
    cell = 0.5 * radius
    i = ((x - x.min()) / cell).astype(int)
    j = ((y - y.min()) / cell).astype(int)
    grid = np.zeros((i.max() + 1, j.max() + 1), dtype=bool)
    grid[i, j] = True
    lab, n = ndimage.label(grid, structure=np.ones((3, 3), dtype=bool))
    return int(n), lab[i, j] - 1


def locate_handle(
    depth: np.ndarray,
    K: np.ndarray,
    camera_position: np.ndarray,
    camera_orientation: np.ndarray,
    expected: np.ndarray,
    config: HandleConfig | None = None,
) -> HandleResult:
    """Find the drawer handle near ``expected`` in a depth image; never raises on bad data.

    ``depth``: metres along the optical axis (0 = no return); ``K``: OpenCV intrinsics;
    ``camera_position``/``camera_orientation`` ([w, x, y, z]): the optical frame (x right,
    y down, z forward) in the frame of ``expected`` (the base frame of an ``RgbdImage``),
    whose z axis is taken as up.
    """
    cfg = config or HandleConfig()
    try:
        depth = np.asarray(depth, dtype=np.float32)
        K = np.asarray(K, dtype=float)
        t_bc = np.asarray(camera_position, dtype=float)
        q_bc = np.asarray(camera_orientation, dtype=float)
        exp = np.asarray(expected, dtype=float)
    except (TypeError, ValueError) as exc:
        return _reject("bad_input", f"inputs are not numeric arrays: {exc}")
    why = _check_inputs(depth, K, t_bc, q_bc, exp)
    if why:
        return _reject("bad_input", why)
    valid = np.isfinite(depth) & (depth >= cfg.min_depth) & (depth <= cfg.max_depth)
    if not np.any(valid):
        return _reject("empty_depth", "no depth return in the usable range")

    # Work in the camera frame (only the answer is rotated back): the expected place and
    # the vertical expressed there; the camera is the origin.
    r_bc = quat_to_mat(q_bc)
    exp_c = r_bc.T @ (exp - t_bc)
    up = r_bc.T @ _UP
    box = _roi(K, exp_c, cfg.roi_radius, depth.shape)
    if box is None:
        return _reject("not_in_view", "the expected handle place is outside the image")
    r0, r1, c0, c1 = box
    rows, cols = np.nonzero(valid[r0:r1, c0:c1])
    if len(rows) == 0:
        return _reject("no_plane", "no depth return near the expected handle place")
    rows, cols = rows + r0, cols + c0
    # Points as a (3, N) array: contiguous coordinate rows keep every reduction fast (and
    # clear of the multithreaded BLAS an N x 3 matmul would call, ~20 ms under load).
    zz = depth[rows, cols].astype(float)
    fx, fy, skew, cx, cy = K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]
    yn = (rows - cy) / fy
    xn = (cols - cx - skew * yn) / fx
    P = np.stack([xn * zz, yn * zz, zz])
    dp = P - exp_c[:, None]
    d2 = (dp * dp).sum(axis=0)
    keep = d2 <= cfg.roi_radius**2
    P = np.compress(keep, P, axis=1)
    # points at the image's border or the region's rim: a cluster there may be cut off
    h, w = depth.shape
    rim = (rows == 0) | (rows == h - 1) | (cols == 0) | (cols == w - 1)
    rim |= d2 >= (cfg.roi_radius - cfg.cluster_radius) ** 2
    rim = rim[keep]
    n_pts = P.shape[1]
    if n_pts < cfg.min_plane_inliers:
        uv = K @ exp_c
        seen = exp_c[2] > 0.0 and 0 <= uv[0] / uv[2] < depth.shape[1]
        seen = seen and 0 <= uv[1] / uv[2] < depth.shape[0]
        return _reject(
            "no_plane" if seen else "not_in_view",
            f"only {n_pts} depth points within {cfg.roi_radius:g} m of the expected place"
            + ("" if seen else ", which is outside the image"),
        )

    rng = np.random.default_rng(cfg.seed)
    plane = _ransac_plane(P, up, cfg, rng)
    if plane is None:
        return _reject("no_plane", "no near-vertical plane among the points")
    n, off, spread = plane
    if off < 0.0:  # n.0 + off: point the normal out of the front, towards the camera
        n, off = -n, -off
    s = n @ P + off  # signed height above the plane, towards the camera
    inl = np.abs(s) < cfg.plane_tol
    n_inl = int(inl.sum())
    frac = n_inl / n_pts
    rms = float(np.sqrt(np.mean(s[inl] ** 2))) if n_inl else 0.0
    plane_kw = {"plane_normal": r_bc @ n, "plane_inlier_fraction": frac, "plane_rms": rms}
    if n_inl < cfg.min_plane_inliers or frac < cfg.min_plane_fraction:
        return _reject(
            "no_plane",
            f"best vertical plane has {n_inl} inliers ({frac:.0%} of {n_pts} points)",
            **plane_kw,
        )
    if spread < cfg.min_plane_spread:
        return _reject(
            "no_plane", f"the points lie on a line ({spread * 100:.1f} cm wide)", **plane_kw
        )

    # In-plane axes: lateral (horizontal) and vertical; the pull is the horizontal normal.
    lat = np.cross(up, n)
    lat /= np.linalg.norm(lat)
    vert = np.cross(n, lat)
    pull = n - (n @ up) * up
    pull /= np.linalg.norm(pull)
    origin = exp_c - (exp_c @ n + off) * n  # the expected place, dropped onto the plane

    # Candidates: points a bar's depth out of the front, clustered by where they stand on
    # the front (so the bar's faces seen at a grazing angle stay one cluster). Anything
    # standing out further (the floor before a low drawer, an object) must not touch them.
    band = (s >= cfg.min_protrusion) & (s <= cfg.max_protrusion)
    cpts, cs, crim = np.compress(band, P, axis=1), s[band], rim[band]
    rel = cpts - origin[:, None]
    cl, cv = lat @ rel, vert @ rel
    n_lab, labels = _clusters(cl, cv, cfg.cluster_radius)
    # only points just beyond the band can lie within cluster_radius of one in it
    far = P[:, (s > cfg.max_protrusion) & (s <= cfg.max_protrusion + cfg.cluster_radius)]
    touching = np.zeros(cs.shape, dtype=bool)
    if far.shape[1] and cs.size:
        dist, _ = cKDTree(far.T).query(cpts.T, distance_upper_bound=cfg.cluster_radius)
        touching = np.isfinite(dist)
    best: tuple[float, HandleResult] | None = None
    refused: list[str] = []
    counts = np.bincount(labels, minlength=n_lab)
    spoiled = np.bincount(labels, weights=touching, minlength=n_lab) > 0
    cut = np.bincount(labels, weights=crim, minlength=n_lab) > 0
    for lab in np.nonzero(counts >= cfg.min_cluster_points)[0]:
        if spoiled[lab]:
            refused.append("part of something standing further out")
            continue
        m = labels == lab
        ps = cs[m]
        front = ps >= np.percentile(ps, 99) - cfg.front_tol  # the bar's front face
        fl, fv = cl[m][front], cv[m][front]
        length = float(fl.max() - fl.min())
        height = float(fv.max() - fv.min())
        if not (cfg.min_handle_length <= length <= cfg.max_handle_length):
            refused.append(f"{length * 100:.0f} cm long")
            continue
        if height > cfg.max_handle_height:
            refused.append(f"{height * 100:.0f} cm tall")
            continue
        face = float(np.median(ps[front]))
        centre = (
            origin
            + lat * 0.5 * (fl.max() + fl.min())
            + vert * 0.5 * (fv.max() + fv.min())
            + n * (face - 0.5 * cfg.bar_thickness)
        )
        dist = float(np.linalg.norm(centre - exp_c))
        if dist > cfg.max_offset:
            refused.append(f"{dist * 100:.0f} cm from the expected place")
            continue
        if best is None or dist < best[0]:
            support = min(1.0, int(counts[lab]) / (4.0 * cfg.min_cluster_points))
            support *= 0.5 if cut[lab] else 1.0
            best = (
                dist,
                HandleResult(
                    ok=True,
                    position=r_bc @ centre + t_bc,
                    pull_direction=r_bc @ pull,
                    quality=float(min(1.0, frac / 0.5) * support),
                    handle_points=int(counts[lab]),
                    handle_length=length,
                    truncated=bool(cut[lab]),
                    offset=dist,
                    **plane_kw,
                ),
            )
    if best is None:
        what = "; ".join(refused[:4]) if refused else "nothing stands out of the front"
        return _reject("no_handle", f"no handle near the expected place ({what})", **plane_kw)
    return best[1]
