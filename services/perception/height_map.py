"""Height maps of an object's point cloud (paper Section 4.4, Algorithm 1) and the way back
from a height-map cell to 3-D (Section 4.5.4, Algorithm 4).

Algorithm 1 maps the cloud onto a grid: for vertical probing the grid's axes come from the
points' x and y and the height from z (``z - criteria_height``, criteria = min z); for
horizontal probing the axes come from y and z and the height from x
(``criteria_height - x``, criteria = max x: the part nearest the camera is "highest").
Each cell holds the mean height of its points (``height_map_sum / height_map_num``).

We keep that structure in a general *map frame* (three orthonormal base-frame axes: ``u``
along the fingers' closing direction, ``v`` along the finger pads, ``h`` the height
direction), which covers both probing directions and the Section 4.6 rotation:

* vertical: ``h`` = up (the supporting plane's normal, so a tilted stance does not tilt the
  map), ``u`` turned about ``h`` by the object's axis angle (4.6);
* horizontal: ``h`` = towards the camera (``-x`` levelled), ``u`` = the base y axis levelled,
  ``v`` = up: Algorithm 1's (y, z) -> x mapping.

Deviations from Algorithm 1, and why:

* **Metric cells.** Algorithm 1 bins by *rank* among the unique coordinates
  (``x_unit = x_coords.size / HEIGHT_MAP_SIZE``), so cells hold equal numbers of distinct
  coordinates, not equal lengths; Algorithm 2 then needs the gripper's width in cells,
  which only means a fixed width in metres if cells have a fixed size. We bin at a fixed
  ``cell`` (m) over the object's extent plus a margin wide enough for the fingertips.
  (Algorithm 1 also pairs ``height_map_x`` with the y rank but compares it with
  ``x_unit``, a swap that a square map hides.)
* **Criteria height = the supporting surface** when it is known (outlier filter's RANSAC
  plane), not the lowest object point: heights are then heights above the table, empty
  cells are honestly "surface level" (0), and Algorithm 4 gives heights above the table.
* **Max or mean.** ``reduce="max"`` (default) keeps the highest point of a cell: a cell
  straddling an edge then reports the edge's top, which is what a fingertip would hit;
  ``"mean"`` is the paper's.
* **Hole filling** (:func:`fill_holes`) for the grasp search: a fingertip descends outside
  the object, so what lies inside a closed rim (a cup's cavity, a spoon's bowl) does not
  matter; grey-level reconstruction by erosion fills every depression not connected to the
  map's border up to its rim.

OCR corrections: Algorithm 4 line 2 reads ``grasp_pos_3d.x <- creteria_height
height_map(...)``: the minus sign was lost, it is ``criteria_height - height_map(...)``,
the inverse of Algorithm 1 line 15 (``point_height <- criteria_height - x``); its line 4-5
``ond if`` / ``end if`` is one ``end if``; ``creteria`` is ``criteria`` throughout.

Everything is vectorised: binning is one ``np.maximum.at`` (or ``bincount``) pass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage

__all__ = [
    "HeightMap",
    "HeightMapConfig",
    "build_height_map",
    "fill_holes",
    "horizontal_axes",
    "vertical_axes",
]


@dataclass(frozen=True)
class HeightMapConfig:
    """Parameters of the height map (``[grasp.height_map]``)."""

    cell: float = 0.004  # m: cell side (Algorithm 1's 1 / HEIGHT_MAP_SIZE, made metric)
    pixels_per_cell: float = 1.5  # a cell spans at least this many pixels' footprints
    margin: float = 0.075  # m: grid border around the object (>= half the fingertip span)
    max_cells: int = 200  # per side: caps the grid (cells grow if the object is larger)
    reduce: Literal["max", "mean"] = "max"  # cell height: highest point or the mean (paper)
    empty_depth: float = 0.05  # m below the object's back: empty cells of a horizontal map


@dataclass(frozen=True)
class HeightMap:
    """A height map in a map frame; ``heights[i, j]`` is the cell at u index i, v index j.

    ``axes`` rows are the map frame's unit axes (u, v, h) in the base frame; a base-frame
    point p has map coordinates ``axes @ p``. Cell (i, j) covers
    ``u in [u0 + i cell, u0 + (i+1) cell)``, likewise v. ``heights`` are measured from
    ``reference`` along h; empty cells (``counts == 0``) hold ``empty``.
    """

    heights: np.ndarray  # (nu, nv) float
    counts: np.ndarray  # (nu, nv) int: points per cell
    axes: np.ndarray  # (3, 3) rows u, v, h
    u0: float
    v0: float
    cell: float
    reference: float  # criteria height (along h)
    empty: float  # height given to empty cells

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape  # type: ignore[return-value]

    @property
    def occupied(self) -> np.ndarray:
        return self.counts > 0

    def map_coords(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) base-frame points → (N, 3) map coordinates (u, v, height above reference)."""
        c = np.asarray(points, dtype=float) @ self.axes.T
        c[:, 2] -= self.reference
        return c

    def cell_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices (i, j) of base-frame points (may lie outside the grid)."""
        c = np.asarray(points, dtype=float) @ self.axes.T
        i = np.floor((c[:, 0] - self.u0) / self.cell).astype(int)
        j = np.floor((c[:, 1] - self.v0) / self.cell).astype(int)
        return i, j

    def cell_centre(self, i: float, j: float) -> tuple[float, float]:
        """Map coordinates (u, v) of the centre of cell (i, j) (fractional indices allowed)."""
        return self.u0 + (i + 0.5) * self.cell, self.v0 + (j + 0.5) * self.cell

    def to_base(self, u: float, v: float, height: float) -> np.ndarray:
        """Algorithm 4: map coordinates (u, v, height above reference) → base-frame point."""
        return self.axes.T @ np.array([u, v, height + self.reference])

    def cell_to_base(self, i: int, j: int, height: float | None = None) -> np.ndarray:
        """Algorithm 4 for a cell: its centre at its own height (or ``height``)."""
        u, v = self.cell_centre(i, j)
        return self.to_base(u, v, float(self.heights[i, j]) if height is None else height)


def vertical_axes(up: np.ndarray, angle: float) -> np.ndarray:
    """Map axes for vertical probing: ``u`` at ``angle`` (rad, from the base x axis about
    up; Section 4.6's rotation), ``v = h x u``, ``h = up``."""
    h = np.asarray(up, dtype=float)
    h = h / np.linalg.norm(h)
    d = np.array([np.cos(angle), np.sin(angle), 0.0])
    u = d - (d @ h) * h
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(h, u), h])


def horizontal_axes(up: np.ndarray) -> np.ndarray:
    """Map axes for horizontal probing (Algorithm 1's (y, z) → x): ``u`` = base y and
    ``v`` = up, levelled; ``h = v x u`` points back towards the robot (-x), so the part
    nearest the camera is the highest (Algorithm 1's ``criteria_height - x``)."""
    v = np.asarray(up, dtype=float)
    v = v / np.linalg.norm(v)
    y = np.array([0.0, 1.0, 0.0])
    u = y - (y @ v) * v
    u /= np.linalg.norm(u)
    return np.stack([u, v, np.cross(v, u)])


def build_height_map(
    points: np.ndarray,
    axes: np.ndarray,
    reference: float | None,
    cfg: HeightMapConfig | None = None,
    empty: float = 0.0,
    cell: float | None = None,
    margin: float | None = None,
) -> HeightMap:
    """Algorithm 1 (vectorised, metric cells) on base-frame points.

    ``reference`` is the criteria height along ``axes[2]`` (None: the lowest point's, the
    paper's ``min z``); ``empty`` is the height of cells without points (0 = the reference
    level, e.g. the table top). ``cell``/``margin`` override the config's.
    """
    cfg = cfg or HeightMapConfig()
    pts = np.asarray(points, dtype=float)
    if pts.shape[0] == 0:
        raise ValueError("no points for a height map")
    c = pts @ np.asarray(axes, dtype=float).T
    ref = float(c[:, 2].min()) if reference is None else float(reference)
    hgt = c[:, 2] - ref
    size = cfg.cell if cell is None else cell
    pad = cfg.margin if margin is None else margin
    lo = c[:, :2].min(axis=0) - pad
    hi = c[:, :2].max(axis=0) + pad
    size = max(size, float((hi - lo).max()) / cfg.max_cells)
    n = np.floor((hi - lo) / size).astype(int) + 1  # the farthest point gets its own cell
    i = np.clip(((c[:, 0] - lo[0]) / size).astype(int), 0, n[0] - 1)
    j = np.clip(((c[:, 1] - lo[1]) / size).astype(int), 0, n[1] - 1)
    flat = i * n[1] + j
    counts = np.bincount(flat, minlength=n[0] * n[1])
    if cfg.reduce == "mean":
        sums = np.bincount(flat, weights=hgt, minlength=n[0] * n[1])
        with np.errstate(invalid="ignore", divide="ignore"):
            heights = np.where(counts > 0, sums / np.maximum(counts, 1), empty)
    else:
        heights = np.full(n[0] * n[1], -np.inf)
        np.maximum.at(heights, flat, hgt)
        heights[counts == 0] = empty
    return HeightMap(
        heights=heights.reshape(n[0], n[1]),
        counts=counts.reshape(n[0], n[1]),
        axes=np.asarray(axes, dtype=float),
        u0=float(lo[0]),
        v0=float(lo[1]),
        cell=float(size),
        reference=ref,
        empty=float(empty),
    )


def fill_holes(heights: np.ndarray, closing: int = 5, max_iter: int = 400) -> np.ndarray:
    """Grey-level hole filling (morphological reconstruction by erosion, 8-connected).

    Every depression not connected to the map's border rises to the lowest rim around it;
    everything else is unchanged: start from the maximum inside and the map on the border,
    erode repeatedly, never below the map, ``F <- max(H, erode(F))`` until stable.

    The fill level is taken on the map after a ``closing`` x ``closing`` grey closing: a
    thin rim sampled with a gap, or with a cell that caught only the inner wall, would
    otherwise let the fill leak out or stop low, leaving the rim as a ridge above a
    half-filled cavity. Only the cells that the fill raises take the new value.
    """
    h = np.asarray(heights, dtype=float)
    if min(h.shape) < 3:
        return h.copy()
    c = ndimage.grey_closing(h, size=(closing, closing)) if closing > 1 else h
    # marker: the maximum only where a hole can be (the raised cells and what they
    # enclose); everywhere else the map already is its own fill. Same fixed point as the
    # textbook marker (max inside, map on the border), in as many iterations as the
    # object is wide in cells instead of the map.
    raised = ndimage.binary_fill_holes(c > c.min())
    f = np.where(raised, c.max(), c)
    f[0, :], f[-1, :], f[:, 0], f[:, -1] = c[0, :], c[-1, :], c[:, 0], c[:, -1]
    for _ in range(max_iter):
        nxt = np.maximum(c, ndimage.grey_erosion(f, size=(3, 3)))
        if np.array_equal(nxt, f):
            break
        f = nxt
    return np.where(f > c, f, h)
