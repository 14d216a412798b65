"""Frontiers: where known free space meets the unknown, the places to look next when
exploring (Yamauchi 1997). Independent of the planner: ranking takes a cost-to-go grid
(e.g. a Dijkstra wavefront from the robot) or any callable that prices goal points."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.grid import GridGeometry
from scipy import ndimage

__all__ = ["Frontier", "FrontierConfig", "find_frontiers", "rank_frontiers"]


@dataclass(frozen=True)
class FrontierConfig:
    """What counts as free, which frontiers are big enough, how size trades against cost."""

    free_max_percent: int = 49
    """cells with 0 <= occupancy <= this count as free: seen empty more often than not (one
    pass-through leaves a cell at 40 %, so the grid's 35 % free threshold found no frontier
    before the robot had moved)"""
    min_cells: int = 6
    """smaller clusters are dropped: 6 cells of 5 cm, narrower than the robot can pass"""
    size_bonus: float = 0.1
    """score = path cost (m) - size_bonus * frontier length (m): nearer first, bigger
    frontiers win ties"""


@dataclass(frozen=True)
class Frontier:
    """One frontier: its cells (K, 2) as (row, col), their centroid (m), the cell count,
    ``goal_xy``, the frontier cell nearest the centroid (a free cell, a place to walk to;
    the centroid of a curved frontier may lie in an obstacle), and ``length`` = size x
    resolution (m), the size in the units of path cost."""

    cells: np.ndarray
    centroid_xy: np.ndarray
    size: int
    goal_xy: np.ndarray
    length: float


_FOUR = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=bool)


def find_frontiers(
    occupancy: np.ndarray, geometry: GridGeometry, config: FrontierConfig | None = None
) -> list[Frontier]:
    """Free cells 4-adjacent to unknown cells, clustered with 8-connectivity, largest
    first. Off the grid counts as neither free nor unknown."""
    cfg = config or FrontierConfig()
    occ = np.asarray(occupancy)
    if occ.shape != geometry.shape:
        raise ValueError(f"occupancy shape {occ.shape} != grid shape {geometry.shape}")
    free = (occ >= 0) & (occ <= cfg.free_max_percent)
    unknown = occ < 0
    near_unknown = ndimage.binary_dilation(unknown, structure=_FOUR, border_value=0)
    frontier = free & near_unknown
    labels, n = ndimage.label(frontier, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return []
    out: list[Frontier] = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        rr, cc = np.nonzero(labels[sl] == k)
        if len(rr) < cfg.min_cells:
            continue
        rows = rr + sl[0].start
        cols = cc + sl[1].start
        xy = geometry.cell_center(rows, cols)
        centroid = xy.mean(axis=0)
        goal = xy[int(np.argmin(np.sum((xy - centroid) ** 2, axis=1)))]
        out.append(
            Frontier(
                np.stack([rows, cols], axis=1),
                centroid,
                len(rows),
                goal,
                len(rows) * geometry.resolution,
            )
        )
    out.sort(key=lambda f: -f.size)
    return out


def rank_frontiers(
    frontiers: list[Frontier],
    cost_to_go: Callable[[np.ndarray], np.ndarray] | np.ndarray,
    geometry: GridGeometry | None = None,
    config: FrontierConfig | None = None,
) -> list[tuple[Frontier, float]]:
    """(frontier, path cost) best first; unreachable ones (inf or NaN cost) are dropped.
    ``cost_to_go`` is either a callable mapping goal points (K, 2) to costs (K,) or a
    cost-to-go grid on ``geometry`` (goals off the grid are unreachable)."""
    cfg = config or FrontierConfig()
    if not frontiers:
        return []
    goals = np.stack([f.goal_xy for f in frontiers])
    if callable(cost_to_go):
        costs = np.asarray(cost_to_go(goals), dtype=float).reshape(-1)
    else:
        if geometry is None:
            raise ValueError("a cost-to-go grid needs its geometry")
        grid = np.asarray(cost_to_go, dtype=float)
        if grid.shape != geometry.shape:
            raise ValueError(f"cost grid shape {grid.shape} != grid shape {geometry.shape}")
        rows, cols = geometry.to_cell(goals)
        inside = geometry.inside(rows, cols)
        costs = np.full(len(goals), np.inf)
        costs[inside] = grid[rows[inside], cols[inside]]
    if len(costs) != len(frontiers):
        raise ValueError("cost_to_go returned a cost per goal of a different count")
    ranked = [
        (f, float(c), float(c) - cfg.size_bonus * f.length)
        for f, c in zip(frontiers, costs, strict=True)
        if np.isfinite(c)
    ]
    ranked.sort(key=lambda t: t[2])
    return [(f, c) for f, c, _ in ranked]
