"""Grasp candidates on a height map and the choice among them (paper Sections 4.5.1-4.5.3
and 4.6, Algorithms 2 and 3, Algorithm 6 lines 6-9).

**Algorithm 2** (:func:`find_candidates`): the gripper's two fingertips stand
``gripper_width_half`` cells either side of a centre cell ``i`` along the closing axis (the
map's first index); the centre is a candidate when it is higher than *both* tips by
``GRASPABLE_HEIGHT`` and, scanning from each tip towards the centre, a step of at least
``GRASPABLE_HEIGHT_VAR`` is found on each side: the wall a finger pad closes on (the
*contact*). A gentle slope gives no such step: the finger would slide up it.

Corrections of the OCR text of Algorithm 2 (the listing's tail is garbled):

* line 7 ``if left_tip_diff or right_tip_diff > GRASPABLE_HEIGHT``: read as *and*, both
  differences above the margin, which is what Section 4.5.1's text says ("the height of
  the coordinate situated at the center of the gripper exceeds the height of the locations
  where the gripper's tips are positioned by a predefined margin"); with *or* a cell on a
  slope beside a wall would pass with one tip resting on top of the object;
* line 14 tests ``right_height_slope`` again inside the loop over ``l``: it must test
  ``left_height_slope`` (computed on line 13 and otherwise unused);
* lines 23-27 (OCR ``If grusp_pos_journu then / Dieuk / 25. end for / 20. end if``, line
  27 missing) are ``23: if grasp_pos_found then / 24: break / 25: end if / 26: end for /
  27: end if``: stop scanning ``k`` once a pair of contacts is found, close the ``k`` loop,
  close line 7's test; lines 28-29 (``end for`` x2) close the ``j`` and ``i`` loops, which
  is the only nesting the indentation of lines 9-22 allows.

One deliberate change: line 12 scans ``l`` from the centre outwards (``i + 1`` to
``left_tip_pos``), so the left contact is the *innermost* step while the right one (line 9,
from the tip inwards) is the *outermost*. We scan both sides from their tip inwards, as a
closing finger meets the walls: on a cup the two contacts are then the outer walls on both
sides, not the outer wall on one side and the inner wall of the cavity on the other.

**Algorithm 3** (:func:`contact_inclination`): for each contact cell, the contacts within
``VICINITY_RANGE`` cells span ``dx`` cells along the closing axis and ``dy`` along the
pads; ``atan2(dy, dx)`` is 90 degrees for a contact edge parallel to the pads and small for
an edge slanted to them, where the object would slip or turn. (The listing's
``VICINE_RANGE`` is ``VICINITY_RANGE``.)

**Selection** (4.5.3, :func:`select_candidate`): drop candidates whose contacts have a low
inclination; take the one closest to the centre, ties to the narrowest area. Improvements:

* the centre is the *volume centroid* of the height map (the object's mass centre, seen
  from above) rather than the map's geometric centre, which for a screwdriver is on the
  thin shaft and for a clamp in the empty space between its jaws;
* a grasp lies midway between its contacts (the two fingers close symmetrically: an
  off-centre candidate would push the object); contacts and widths are measured on the
  points of the candidate's row, not on the cells (:class:`RowIndex`);
* :func:`climb_to_widest` then moves along the pads while the cross-section between the
  contacts grows smoothly, so a round body is grasped across its diameter and a spoon
  across the widest part of its bowl (a jump is another part: a clamp's jaw);
* :func:`plateau_middle` centres the grasp along the pads on the run of rows of the same
  width: a box across its middle, a screwdriver in the middle of its handle, a clamp's bar
  midway between its jaws.

**4.6 and Algorithm 6's roll**: the paper turns a floor object's cloud about z by the angle
of a line-fitting RANSAC (:func:`line_ransac`) and rolls the gripper by that line's normal,
or towards the grasp point when it lies far from the centroid (:func:`gripper_roll`). On a
filled footprint, line RANSAC finds the longest chord, the diagonal of a box (20 degrees
off for the cracker box); a square (Rubik's cube) has no preferred line at all. We orient
the first pass with the minimum-area rectangle of the footprint (:func:`object_axis`) and
then close across the *narrowest cross-section through the chosen grasp point*
(:func:`narrowest_direction`), which is exact for boxes and puts a mug's fingers across
its handle's axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

__all__ = [
    "CandidateConfig",
    "Candidates",
    "Grip",
    "RowIndex",
    "climb_to_widest",
    "contact_inclination",
    "find_candidates",
    "gripper_roll",
    "line_ransac",
    "min_area_rect",
    "narrowest_direction",
    "object_axis",
    "plateau_middle",
    "select_candidate",
]


@dataclass(frozen=True)
class CandidateConfig:
    """Parameters of the candidate search and selection (``[grasp.candidates]``)."""

    finger_span: float = 0.12  # m: fingertip spacing when open (Alg. 2: 2 gripper_width_half)
    graspable_height: float = 0.010  # m: GRASPABLE_HEIGHT, centre above both tips
    wall_slope: float = 1.0  # GRASPABLE_HEIGHT_VAR = wall_slope * cell (1.0: 45 deg walls)
    vicinity: int = 2  # cells: VICINITY_RANGE of Algorithm 3
    min_inclination: float = 1.05  # rad (60 deg): contacts slanted more are dropped (4.5.3)
    tie_cells: float = 0.5  # cells: distances to the centre this close are a tie (4.5.3)
    width_weight: float = 0.0  # 4.5.3 cost = distance + this x width (0: the paper's ties)
    climb_gain: float = 0.0005  # m: a row at least this much wider is "wider" (climb) ...
    climb_max_step: float = 0.01  # m: ... and at most this much (more: another part)
    plateau_tolerance: float = 0.002  # m: rows this close in width are one part (centring)
    plateau_reach: float = 0.06  # m: centring looks at most this far either way
    pad_half_length: float = 0.02  # m: half the finger pad's length along the pads
    fan_steps: int = 36  # directions tried for the narrowest cross-section (5 deg apart)
    fan_flat: float = 0.002  # m: widths this close to the narrowest count as equally narrow
    fan_half_width: float = 0.008  # m: the fan measures a strip this wide either side
    fan_round: float = 0.1  # widths all within this share of the narrowest: round, any way
    roll_threshold: float = 0.02  # m: Algorithm 6's ROLL_THRESHOLD
    axis_method: Literal["minrect", "pca", "ransac"] = "minrect"  # first-pass object axis
    line_tolerance: float = 0.004  # m: line RANSAC inlier band
    line_iterations: int = 128  # line RANSAC hypotheses


@dataclass(frozen=True)
class Candidates:
    """Algorithm 2's output, one entry per candidate (cell indices of the height map).

    ``right``/``left`` are the outermost object cells the two fingers touch (the low-u and
    the high-u side): the object spans ``right..left`` between the fingers.
    """

    i: np.ndarray
    j: np.ndarray
    right: np.ndarray
    left: np.ndarray

    def __len__(self) -> int:
        return int(self.i.size)

    @property
    def width_cells(self) -> np.ndarray:
        return self.left - self.right + 1

    @property
    def middle(self) -> np.ndarray:
        """Midpoint of the contacts along the closing axis (cell index, fractional)."""
        return 0.5 * (self.right + self.left)

    def take(self, keep: np.ndarray) -> Candidates:
        return Candidates(self.i[keep], self.j[keep], self.right[keep], self.left[keep])


def find_candidates(
    heights: np.ndarray,
    half_span: int,
    graspable_height: float,
    step: float,
    outside: float = 0.0,
    on_object: np.ndarray | None = None,
    no_tip: np.ndarray | None = None,
) -> Candidates:
    """Algorithm 2, vectorised over the whole map (closing axis = first index).

    ``half_span``: fingertip offset in cells; ``step``: GRASPABLE_HEIGHT_VAR (m per cell);
    ``outside``: height beyond the map's ends; ``on_object``: cells a centre may be on
    (default: all); ``no_tip``: cells a fingertip may not land on (a cavity that hole
    filling closed: the finger would go into the cup). Returns every candidate with its
    two contacts.
    """
    h = np.asarray(heights, dtype=float)
    nu, nv = h.shape
    w = max(int(half_span), 1)
    p = np.pad(h, ((w + 1, w + 1), (0, 0)), constant_values=outside)
    n = p.shape[0]
    idx = np.arange(n)[:, None]
    rise = np.zeros(p.shape, bool)  # rise[k]: p[k+1] - p[k] >= step
    rise[:-1] = (p[1:] - p[:-1]) >= step
    fall = np.zeros(p.shape, bool)  # fall[l]: p[l-1] - p[l] >= step
    fall[1:] = (p[:-1] - p[1:]) >= step
    # first rise at or after k, last fall at or before l: the inward scans of lines 9 and 12
    next_rise = np.minimum.accumulate(np.where(rise, idx, n + 1)[::-1], axis=0)[::-1]
    prev_fall = np.maximum.accumulate(np.where(fall, idx, -1), axis=0)
    ip = np.arange(nu) + w + 1
    centre = p[ip]
    ok = (centre - p[ip - w] > graspable_height) & (centre - p[ip + w] > graspable_height)
    k = next_rise[ip - w]
    ell = prev_fall[ip + w]
    ok &= (k <= ip[:, None] - 1) & (ell >= ip[:, None] + 1)
    if on_object is not None:
        ok &= on_object
    if no_tip is not None:
        nt = np.pad(np.asarray(no_tip, bool), ((w + 1, w + 1), (0, 0)))
        ok &= ~nt[ip - w] & ~nt[ip + w]
    ii, jj = np.nonzero(ok)
    # outermost object cells touched: k + 1 (right) and l - 1 (left), unpadded
    right = k[ii, jj] + 1 - (w + 1)
    left = ell[ii, jj] - 1 - (w + 1)
    return Candidates(ii, jj, np.clip(right, 0, nu - 1), np.clip(left, 0, nu - 1))


def contact_inclination(
    cands: Candidates, shape: tuple[int, int], vicinity: int
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 3: inclination (rad, 0..pi/2) of each candidate's right and left contact.

    For each side, the contact cells of all candidates within ``vicinity`` cells of a
    contact span ``di`` cells along the closing axis and ``dj`` along the pads;
    the inclination is ``atan2(dj, di)``.
    """
    size = 2 * int(vicinity) + 1
    ii, jj = np.indices(shape)
    out = []
    for side in (cands.right, cands.left):
        mask = np.zeros(shape, bool)
        mask[side, cands.j] = True
        big = float(max(shape) + 1)
        rng = []
        for grid in (ii, jj):
            g = grid.astype(float)
            hi = ndimage.maximum_filter(
                np.where(mask, g, -big), size=size, mode="constant", cval=-big
            )
            lo = ndimage.minimum_filter(
                np.where(mask, g, big), size=size, mode="constant", cval=big
            )
            rng.append(hi - lo)
        incl = np.arctan2(rng[1], rng[0])
        out.append(incl[side, cands.j])
    return out[0], out[1]


def select_candidate(
    cands: Candidates,
    inclination: np.ndarray,
    centre: tuple[float, float],
    cfg: CandidateConfig,
) -> int | None:
    """Section 4.5.3: the index of the chosen candidate, or None.

    Candidates whose contact inclination is below ``min_inclination`` are dropped; of the
    rest the one whose contact midpoint is closest to ``centre`` (cell coordinates) wins,
    ties (within ``tie_cells``) to the narrowest.

    With ``width_weight`` > 0 the narrowness weighs in before the tie: the cost is the
    distance plus ``width_weight`` times the width (both in cells). Off by default: it
    makes a mug's handle (12 mm, 45 mm from the centroid) beat its body (80 mm, at the
    centroid), a poor grasp for the torque.
    """
    keep = np.flatnonzero(inclination >= cfg.min_inclination)
    if keep.size == 0:
        return None
    d = np.hypot(cands.middle[keep] - centre[0], cands.j[keep] - centre[1])
    d = d + cfg.width_weight * cands.width_cells[keep]
    tie = np.floor(d / max(cfg.tie_cells, 1e-9))
    order = np.lexsort((cands.width_cells[keep], tie))  # distance first, then narrowest
    return int(keep[order[0]])


def row_extent(
    coords: np.ndarray, v_lo: float, v_hi: float, u_lo: float, u_hi: float, min_height: float
) -> tuple[float, float, float] | None:
    """(u_min, u_max, top) of the object points (map coordinates) with ``v`` in
    [v_lo, v_hi), ``u`` in [u_lo, u_hi] and height above ``min_height``; None if none."""
    sel = (
        (coords[:, 1] >= v_lo)
        & (coords[:, 1] < v_hi)
        & (coords[:, 0] >= u_lo)
        & (coords[:, 0] <= u_hi)
        & (coords[:, 2] > min_height)
    )
    if not sel.any():
        return None
    u = coords[sel, 0]
    return float(u.min()), float(u.max()), float(coords[sel, 2].max())


@dataclass(frozen=True)
class Grip:
    """A chosen grasp in map coordinates: the contacts' span along u, the row, the top."""

    j: int
    u_min: float
    u_max: float
    top: float  # highest object point between the contacts in the row (above reference)

    @property
    def width(self) -> float:
        return self.u_max - self.u_min

    @property
    def u_mid(self) -> float:
        return 0.5 * (self.u_min + self.u_max)


class RowIndex:
    """The candidates and the object's points of one height map, grouped by row (the
    pads' axis), for the climb and the centring: each candidate's grip is measured once,
    on the points of its own row only.

    ``coords``: object points in map coordinates (u, v, height above the reference);
    points at or below ``min_height`` are ignored.
    """

    def __init__(
        self,
        cands: Candidates,
        coords: np.ndarray,
        u0: float,
        v0: float,
        cell: float,
        min_height: float,
    ) -> None:
        self.cands, self.u0, self.v0, self.cell = cands, u0, v0, cell
        c = np.asarray(coords, dtype=float)
        c = c[c[:, 2] > min_height]
        j = np.floor((c[:, 1] - v0) / cell).astype(int)
        order = np.argsort(j, kind="stable")
        self._pts = c[order]
        rows, first, count = np.unique(j[order], return_index=True, return_counts=True)
        self._span = {
            int(r): (int(f), int(f + n)) for r, f, n in zip(rows, first, count, strict=True)
        }
        # one representative candidate per distinct (row, right, left): the climb and the
        # centring only care about the contacts, not where in the band the centre was
        key = np.stack([cands.j, cands.right, cands.left], axis=1)
        _, rep = np.unique(key, axis=0, return_index=True)
        self._by_row: dict[int, np.ndarray] = {}
        for r in np.unique(cands.j[rep]):
            self._by_row[int(r)] = rep[cands.j[rep] == r]
        self._grips: dict[int, Grip | None] = {}

    def grip(self, k: int) -> Grip | None:
        """Candidate ``k``'s grip measured on the points of its row (contacts +- 1 cell)."""
        if k in self._grips:
            return self._grips[k]
        cd = self.cands
        j = int(cd.j[k])
        g = None
        if j in self._span:
            a, b = self._span[j]
            p = self._pts[a:b]
            u_lo = self.u0 + (int(cd.right[k]) - 1) * self.cell
            u_hi = self.u0 + (int(cd.left[k]) + 2) * self.cell
            sel = (p[:, 0] >= u_lo) & (p[:, 0] <= u_hi)
            if sel.any():
                u = p[sel, 0]
                g = Grip(j, float(u.min()), float(u.max()), float(p[sel, 2].max()))
        self._grips[k] = g
        return g

    def neighbours(self, k: int, dj: int) -> np.ndarray:
        """Candidates in row ``j + dj`` whose contacts overlap candidate ``k``'s (the same
        part of the object, one row along the pads), one per distinct contact pair."""
        cd = self.cands
        nb = self._by_row.get(int(cd.j[k]) + dj)
        if nb is None:
            return np.zeros(0, int)
        return nb[(cd.right[nb] <= cd.left[k]) & (cd.left[nb] >= cd.right[k])]

    def ahead(self, k: int, dj: int) -> list[int]:
        """Neighbours one row on and two rows on (a single row cut short by the pixel
        grid must not stop a walk along the pads)."""
        one = [int(x) for x in self.neighbours(k, dj)]
        return one + [int(x) for k1 in one for x in self.neighbours(k1, dj)]

    def points_between(self, j_lo: int, j_hi: int, u_lo: float, u_hi: float) -> np.ndarray:
        """Points (map coordinates) of rows j_lo..j_hi with u in [u_lo, u_hi]."""
        spans = [self._span[j] for j in range(j_lo, j_hi + 1) if j in self._span]
        if not spans:
            return np.zeros((0, 3))
        p = self._pts[spans[0][0] : spans[-1][1]]
        return p[(p[:, 0] >= u_lo) & (p[:, 0] <= u_hi)]


def climb_to_widest(
    rows: RowIndex, chosen: int, gain: float, max_step: float = np.inf, max_steps: int = 40
) -> tuple[Grip, int] | None:
    """From the chosen candidate, move row by row along the pads while the cross-section
    between the contacts (measured on the points, not the cells) gets wider by ``gain``,
    but by no more than ``max_step`` at a time: a round body's chords grow smoothly, a
    jump is another part (a clamp's jaw beside its bar).

    Only candidates whose contacts overlap the current ones are neighbours, so the climb
    stays on one part of the object. Returns the final grip and its candidate index
    (None: no points in the chosen row).
    """
    cur = rows.grip(chosen)
    if cur is None:
        return None
    c = chosen
    for _ in range(max_steps):
        best: tuple[Grip, int] | None = None
        for dj in (-1, 1):
            for k in rows.ahead(c, dj):
                g = rows.grip(k)
                if g is not None and cur.width + gain < g.width <= cur.width + max_step:
                    if best is None or g.width > best[0].width:
                        best = (g, k)
        if best is None:
            break
        cur, c = best
    return cur, c


def plateau_middle(
    rows: RowIndex, chosen: int, tolerance: float, reach: float
) -> tuple[float, float, float, float] | None:
    """Centre the grasp along the pads on the part it holds: from the chosen candidate,
    follow the rows whose cross-section stays within ``tolerance`` of its width (at most
    ``reach`` either way) and return (v_mid, u_min, u_max, top) over that plateau, v_mid
    being the middle of the plateau's points along the pads.

    A box is then held across its middle, a screwdriver in the middle of its handle, a
    round body across its diameter (the plateau of near-maximal chords is symmetric).
    """
    g0 = rows.grip(chosen)
    if g0 is None:
        return None
    cd = rows.cands
    found = [g0]
    max_rows = max(1, int(reach / rows.cell))
    for dj in (-1, 1):
        c = chosen
        while abs(int(cd.j[c]) - int(cd.j[chosen])) < max_rows:
            nxt: tuple[int, Grip] | None = None
            for k in rows.ahead(c, dj):
                g = rows.grip(k)
                if g is None or abs(g.width - g0.width) > tolerance:
                    continue
                if nxt is None or abs(int(cd.j[k]) - int(cd.j[c])) < abs(
                    int(cd.j[nxt[0]]) - int(cd.j[c])
                ):
                    nxt = (k, g)
            if nxt is None:
                break
            found.append(nxt[1])
            c = nxt[0]
    u_lo = min(g.u_min for g in found) - rows.cell
    u_hi = max(g.u_max for g in found) + rows.cell
    pts = rows.points_between(min(g.j for g in found), max(g.j for g in found), u_lo, u_hi)
    v_mid = 0.5 * (float(pts[:, 1].min()) + float(pts[:, 1].max()))
    # the grip itself: the rows' median contacts (one row could be cut by a pixel row)
    u_min = float(np.median([g.u_min for g in found]))
    u_max = float(np.median([g.u_max for g in found]))
    return v_mid, u_min, u_max, max(g.top for g in found)


def gripper_roll(
    centroid_xy: np.ndarray,
    grasp_xy: np.ndarray,
    line_normal_angle: float,
    roll_threshold: float,
) -> float:
    """Algorithm 6 lines 6-9: the closing direction (rad, base frame, mod pi).

    Far from the centroid (>= ROLL_THRESHOLD) the fingers close along the centroid → grasp
    direction (across a vessel's wall); otherwise along the line-fitting RANSAC normal.
    """
    diff = np.asarray(grasp_xy, dtype=float) - np.asarray(centroid_xy, dtype=float)
    if float(np.hypot(diff[0], diff[1])) >= roll_threshold:
        return math.atan2(float(diff[1]), float(diff[0]))
    return float(line_normal_angle)


def line_ransac(
    xy: np.ndarray, tolerance: float, iterations: int, rng: np.random.Generator
) -> tuple[float, np.ndarray]:
    """Line-fitting RANSAC (Section 4.6) on 2-D points: (direction angle mod pi, inliers).

    Hypotheses from random point pairs, all scored at once; the best line is refined by
    the principal axis of its inliers."""
    p = np.asarray(xy, dtype=float)
    if p.shape[0] < 2:
        return 0.0, np.ones(p.shape[0], bool)
    a = p[rng.integers(0, p.shape[0], iterations)]
    b = p[rng.integers(0, p.shape[0], iterations)]
    d = b - a
    norm = np.linalg.norm(d, axis=1)
    good = norm > 1e-9
    if not good.any():
        return 0.0, np.ones(p.shape[0], bool)
    a, d = a[good], d[good] / norm[good, None]
    nrm = np.stack([-d[:, 1], d[:, 0]], axis=1)
    off = np.einsum("ij,ij->i", nrm, a)
    counts = (np.abs(p @ nrm.T - off) <= tolerance).sum(axis=0)
    best = int(np.argmax(counts))
    inl = np.abs(p @ nrm[best] - off[best]) <= tolerance
    q = p[inl] - p[inl].mean(axis=0)
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    return math.atan2(float(vt[0, 1]), float(vt[0, 0])) % math.pi, inl


def min_area_rect(xy: np.ndarray) -> tuple[float, float, float]:
    """Minimum-area bounding rectangle of 2-D points: (angle of its long side mod pi,
    long side, short side). Rotating calipers over the convex hull's edges."""
    p = np.asarray(xy, dtype=float)
    try:
        hull = p[ConvexHull(p).vertices]
    except (QhullError, ValueError):
        q = p - p.mean(axis=0)
        _, s, vt = np.linalg.svd(q, full_matrices=False)
        return math.atan2(float(vt[0, 1]), float(vt[0, 0])) % math.pi, float(np.ptp(q @ vt[0])), 0.0
    e = np.roll(hull, -1, axis=0) - hull
    ang = np.arctan2(e[:, 1], e[:, 0])
    c, s = np.cos(ang), np.sin(ang)
    # hull points in every edge's frame at once: (E, H)
    pu = hull[:, 0][None, :] * c[:, None] + hull[:, 1][None, :] * s[:, None]
    pv = -hull[:, 0][None, :] * s[:, None] + hull[:, 1][None, :] * c[:, None]
    du, dv = np.ptp(pu, axis=1), np.ptp(pv, axis=1)
    k = int(np.argmin(du * dv))
    a, la, lb = float(ang[k]), float(du[k]), float(dv[k])
    if lb > la:
        a, la, lb = a + math.pi / 2, lb, la
    return a % math.pi, la, lb


def object_axis(
    xy: np.ndarray, cfg: CandidateConfig, rng: np.random.Generator | None = None
) -> float:
    """Angle (rad, mod pi) of the object's long axis in its footprint (Section 4.6)."""
    p = np.asarray(xy, dtype=float)
    if cfg.axis_method == "ransac":
        return line_ransac(
            p, cfg.line_tolerance, cfg.line_iterations, rng or np.random.default_rng(0)
        )[0]
    if cfg.axis_method == "pca":
        q = p - p.mean(axis=0)
        _, _, vt = np.linalg.svd(q, full_matrices=False)
        return math.atan2(float(vt[0, 1]), float(vt[0, 0])) % math.pi
    return min_area_rect(p)[0]


def narrowest_direction(
    xy: np.ndarray,
    centre: np.ndarray,
    cfg: CandidateConfig,
    reach: float,
    flat: float | None = None,
    prefer: float | None = None,
) -> tuple[float, float] | None:
    """Closing direction (rad, mod pi) across the narrowest cross-section of the footprint
    ``xy`` through ``centre``, and its width; None when every direction is as narrow
    (a round object: no preferred direction).

    For each of ``fan_steps`` directions the width is the extent, along it, of the points
    within ``fan_half_width`` of the closing line and ``reach`` of the centre (a strip
    narrower than the pads, so a neighbouring part, a clamp's jaw beside its bar, does not
    widen the cross-section of the part being held). Directions
    within ``fan_flat`` (or ``flat``) of the narrowest form arcs; the middle of the arc
    holding the narrowest width is returned, so a flat minimum (a mug's body, away from
    its handle) gives the symmetric direction. Several equally narrow arcs (a square's two
    sides) are a tie, broken towards ``prefer`` (rad).
    """
    p = np.asarray(xy, dtype=float) - np.asarray(centre, dtype=float)[:2]
    p = p[np.einsum("ij,ij->i", p, p) <= reach * reach]
    if p.shape[0] < 3:
        return None
    steps = cfg.fan_steps
    th = np.arange(steps) * (math.pi / steps)
    c, s = np.cos(th), np.sin(th)
    u = p[:, :1] * c + p[:, 1:2] * s  # (N, D) along each closing direction
    v = -p[:, :1] * s + p[:, 1:2] * c
    inside = np.abs(v) <= cfg.fan_half_width
    hi = np.where(inside, u, -np.inf).max(axis=0)
    lo = np.where(inside, u, np.inf).min(axis=0)
    width = np.where(np.isfinite(hi) & np.isfinite(lo), hi - lo, np.inf)
    best = float(width.min())
    tol = cfg.fan_flat if flat is None else flat
    near = width <= best + tol
    if not np.isfinite(best) or near.all():
        return None
    if float(width.max()) <= best + max(tol, cfg.fan_round * best):
        return None  # round (a ball seen through the pixel grid): no preferred direction
    # arcs of consecutive near directions (circular): start after a far direction
    shift = int(np.flatnonzero(~near)[0])
    order = (np.arange(steps) + shift) % steps
    nr = near[order]
    starts = np.flatnonzero(nr & ~np.concatenate([[False], nr[:-1]]))
    arcs = []
    for a in starts:
        b = a
        while b + 1 < steps and nr[b + 1]:
            b += 1
        idx = order[a : b + 1]
        mid = (th[order[a]] + 0.5 * (b - a) * math.pi / steps) % math.pi
        arcs.append((float(width[idx].min()), mid))
    top = min(w for w, _ in arcs)
    arcs = [arc for arc in arcs if arc[0] <= top + 0.5 * tol]
    if prefer is not None:
        arcs.sort(key=lambda arc: abs((arc[1] - prefer + math.pi / 2) % math.pi - math.pi / 2))
    return arcs[0][1], arcs[0][0]
