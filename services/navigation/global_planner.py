"""The global planner: a cost-weighted shortest path over the costmap, shortened and
resampled for the path follower (paper Section 5.2: move_base's global planner, NavFn).

- Search: Dijkstra on the 8-connected grid of cells whose centre the robot may occupy
  (cost < 253), an edge weighing its length times ``1 + cost_weight * cost / 252`` so
  paths keep off the walls. The graph is a CSR matrix built with numpy and cached on the
  costmap's version; the search is scipy's compiled Dijkstra (a pure-Python A* over a
  house-sized grid costs far more than the whole graph search in C).
- A start in the inscribed zone (the robot after a grasp, standing close to furniture)
  escapes by a straight, obstacle-free step to the nearest traversable cell; a goal must
  be traversable.
- Shortening: greedy line-of-sight shortcuts (from each anchor, the farthest later path
  point whose straight segment stays under ``shortcut_cost`` or under the worst cost the
  grid path itself met between them), then resampling every ``spacing`` metres.
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.costmap import INFLATED_MAX, INSCRIBED, LETHAL, UNKNOWN, Costmap
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

__all__ = [
    "START_IN_OBSTACLE",
    "PlanResult",
    "PlannerConfig",
    "plan_path",
    "path_headings",
    "resample_path",
]

#: The reason of a plan whose start lies in an obstacle with no free cell in a straight
#: step (the walk may still step out: Navigator.start).
START_IN_OBSTACLE = "start in an obstacle"


@dataclass(frozen=True)
class PlannerConfig:
    """Global planner parameters."""

    cost_weight: float = 3.0  # edge weight factor at cost 252 is 1 + cost_weight
    unknown_cost: int = 200  # cost of unknown cells when the costmap lets them be crossed
    escape_radius: float = 0.6  # m: how far a start in the inscribed zone may step out
    shortcut_cost: int = 100  # shortcuts may cross cells up to this cost (~0.37 m clear)
    shortcut_max_cells: int = 240  # farthest look for a shortcut, in path points
    spacing: float = 0.05  # m: resampled path spacing


@dataclass(frozen=True)
class PlanResult:
    """A plan: ``path`` (N, 2) in the map frame from start to goal (None when there is no
    plan), ``headings`` (N,) of its segments, its ``length`` (m), ``reason`` ("ok" or why
    not) and the planning time ``ms``."""

    path: np.ndarray | None
    length: float
    reason: str
    ms: float
    headings: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether a path was found."""
        return self.path is not None


_OFFSETS = [(0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)]
_graph_cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _edge_costs(costmap: Costmap, config: PlannerConfig) -> tuple[np.ndarray, np.ndarray]:
    """(traversable mask, per-cell cost factor) for the graph."""
    c = costmap.cost
    passable = c < INSCRIBED
    cost = c.astype(float)
    if not costmap.config.unknown_is_lethal:
        unk = c == UNKNOWN
        passable |= unk
        cost[unk] = config.unknown_cost
    factor = 1.0 + config.cost_weight * np.minimum(cost, INFLATED_MAX) / INFLATED_MAX
    return passable, factor


def path_cost(costmap: Costmap, path: np.ndarray, config: PlannerConfig) -> float:
    """What the planner minimises, for a given polyline (N, 2) on ``costmap``: each
    segment's length times the mean of its ends' cost factors (``_edge_costs``). Lets a
    navigator compare the path it follows with a fresh plan on the same terms."""
    if len(path) < 2:
        return 0.0
    step = 0.5 * costmap.geometry.resolution
    seg = np.diff(path, axis=0)
    n = np.maximum(np.ceil(np.hypot(*seg.T) / step).astype(np.int64), 1)
    # sample each segment every half cell so that a short cut through a costly zone counts
    k = np.repeat(np.arange(len(seg)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[k]
    pts = path[:-1][k] + seg[k] * t[:, None]
    _, factor = _cached_edge_costs(costmap, config)
    rows, cols = costmap.geometry.to_cell(pts)
    h, w = costmap.geometry.shape
    f = factor[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)]
    return float(np.sum(np.hypot(*seg[k].T) / n[k] * f))


def _cache_key(costmap: Costmap, config: PlannerConfig) -> tuple[int, float, int]:
    return (costmap.version, config.cost_weight, config.unknown_cost)


def _cached_edge_costs(costmap: Costmap, config: PlannerConfig) -> tuple[np.ndarray, np.ndarray]:
    """``_edge_costs`` of the graph last built for this costmap, if it is still current."""
    hit = _graph_cache.get(costmap)
    if hit is not None and hit[0] == _cache_key(costmap, config):
        return hit[2], hit[3]
    return _edge_costs(costmap, config)


def _graph(costmap: Costmap, config: PlannerConfig) -> tuple[csr_matrix, np.ndarray]:
    """The cached CSR graph of the costmap (rebuilt when the costmap's version moves)."""
    key = _cache_key(costmap, config)
    hit = _graph_cache.get(costmap)
    if hit is not None and hit[0] == key:
        return hit[1], hit[2]
    h, w = costmap.geometry.shape
    passable, factor = _edge_costs(costmap, config)
    idx = np.arange(h * w).reshape(h, w)
    src, dst, wt = [], [], []
    for dr, dc in _OFFSETS:
        a = (slice(max(-dr, 0), h - max(dr, 0)), slice(max(-dc, 0), w - max(dc, 0)))
        b = (slice(max(dr, 0), h + min(dr, 0)), slice(max(dc, 0), w + min(dc, 0)))
        ok = passable[a] & passable[b]
        if dr and dc:  # no corner cutting between two blocked cells
            ok &= passable[a[0], b[1]] & passable[b[0], a[1]]
        step = math.hypot(dr, dc) * costmap.geometry.resolution
        src.append(idx[a][ok])
        dst.append(idx[b][ok])
        wt.append(step * 0.5 * (factor[a][ok] + factor[b][ok]))
    graph = csr_matrix(
        (np.concatenate(wt), (np.concatenate(src), np.concatenate(dst))), shape=(h * w, h * w)
    )
    _graph_cache[costmap] = (key, graph, passable, factor)
    return graph, passable


def _segment_costs(costmap: Costmap, a: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Worst cost along straight segments from point a to each of ends (M, 2), counted
    from where a segment first drops below the inscribed cost (a start in the inscribed
    zone escapes; it may not skim along inside it). Lethal anywhere reads lethal."""
    step = 0.5 * costmap.geometry.resolution
    d = ends - a
    n = np.floor(np.hypot(d[:, 0], d[:, 1]) / step).astype(np.int64) + 2
    seg = np.repeat(np.arange(len(ends)), n)
    first = np.cumsum(n) - n
    k = np.arange(int(n.sum())) - np.repeat(first, n)
    t = k / (n[seg] - 1)
    c = costmap.cost_at(a + d[seg] * t[:, None]).astype(np.int64)
    below = np.cumsum(c < INSCRIBED)
    out_of_zone = below - np.repeat(np.r_[0, below][first], n) > 0
    worst = np.zeros(len(ends), dtype=np.int64)
    np.maximum.at(worst, seg[out_of_zone], c[out_of_zone])
    lethal = np.zeros(len(ends), dtype=bool)
    np.logical_or.at(lethal, seg, c == LETHAL)
    worst[lethal] = LETHAL
    return worst


def _escape(costmap: Costmap, xy: np.ndarray, radius: float, passable: np.ndarray) -> int | None:
    """Flat index of the nearest passable cell within ``radius`` reachable from xy by a
    straight step that crosses no lethal cell outside xy's own cell."""
    geo = costmap.geometry
    (r,), (c,) = geo.to_cell(xy)
    n = int(math.ceil(radius / geo.resolution))
    r0, r1, c0, c1 = (
        max(r - n, 0),
        min(r + n + 1, geo.height),
        max(c - n, 0),
        min(c + n + 1, geo.width),
    )
    rr, cc = np.nonzero(passable[r0:r1, c0:c1])
    if not len(rr):
        return None
    rr, cc = rr + r0, cc + c0
    centres = geo.cell_center(rr, cc)
    dist = np.hypot(*(centres - xy).T)
    order = np.argsort(dist)
    order = order[dist[order] <= radius][:32]
    for i in order:
        seg = np.linspace(xy, centres[i], max(int(dist[i] / (0.5 * geo.resolution)) + 2, 2))
        sr, sc = geo.to_cell(seg)
        away = (sr != r) | (sc != c)
        if not np.any(costmap.cost_at(seg)[away] == LETHAL):
            return int(rr[i] * geo.width + cc[i])
    return None


def _shortcut(costmap: Costmap, pts: np.ndarray, config: PlannerConfig) -> np.ndarray:
    """Greedy line-of-sight shortening of a grid path (N, 2)."""
    costs = costmap.cost_at(pts).astype(np.int64)
    costs[costs == UNKNOWN] = (
        config.unknown_cost if not costmap.config.unknown_is_lethal else LETHAL
    )
    out = [pts[0]]
    i, n = 0, len(pts)
    while i < n - 1:
        j_hi = min(n - 1, i + config.shortcut_max_cells)
        cand = np.arange(i + 1, j_hi + 1)
        seen = np.minimum(costs[i : j_hi + 1], INFLATED_MAX)  # the escape does not count
        allowed = np.maximum(config.shortcut_cost, np.maximum.accumulate(seen)[1:])
        worst = _segment_costs(costmap, pts[i], pts[cand])
        ok = np.nonzero(worst <= allowed)[0]
        j = int(cand[ok[-1]]) if len(ok) else i + 1
        out.append(pts[j])
        i = j
    return np.asarray(out)


def resample_path(points: np.ndarray, spacing: float) -> np.ndarray:
    """A polyline (N, 2) resampled every ``spacing`` metres, both ends kept."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(pts) < 2:
        return pts.copy()
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    if s[-1] <= 1e-9:
        return pts[:1].copy()
    m = max(int(math.ceil(s[-1] / spacing)), 1)
    t = np.linspace(0.0, s[-1], m + 1)
    return np.stack([np.interp(t, s, pts[:, 0]), np.interp(t, s, pts[:, 1])], axis=1)


def path_headings(path: np.ndarray) -> np.ndarray:
    """Heading (rad) of each point's outgoing segment (the last point repeats the last)."""
    p = np.asarray(path, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return np.zeros(len(p))
    d = np.diff(p, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.r_[h, h[-1]]


def plan_path(
    costmap: Costmap,
    start_xy: tuple[float, float] | np.ndarray,
    goal_xy: tuple[float, float] | np.ndarray,
    config: PlannerConfig | None = None,
) -> PlanResult:
    """A shortened, resampled, cost-aware path from start to goal on the costmap."""
    cfg = config or PlannerConfig()
    t0 = time.perf_counter()
    geo = costmap.geometry
    start = np.asarray(start_xy, dtype=float).reshape(2)
    goal = np.asarray(goal_xy, dtype=float).reshape(2)

    def fail(reason: str) -> PlanResult:
        return PlanResult(None, 0.0, reason, (time.perf_counter() - t0) * 1e3)

    if not geo.contains(*goal):
        return fail("goal off the map")
    if not geo.contains(*start):
        return fail("start off the map")
    gc = int(costmap.cost_at(goal[None])[0])
    if gc == LETHAL:
        return fail("goal in an obstacle")
    if gc == UNKNOWN and costmap.config.unknown_is_lethal:
        return fail("goal in unknown space")
    if gc == INSCRIBED:
        return fail("goal too close to an obstacle")
    graph, passable = _graph(costmap, cfg)
    (sr,), (sc,) = geo.to_cell(start[None])
    (gr,), (gcol,) = geo.to_cell(goal[None])
    s_node = int(sr * geo.width + sc)
    g_node = int(gr * geo.width + gcol)
    if not passable[sr, sc]:
        esc = _escape(costmap, start, cfg.escape_radius, passable)
        if esc is None:
            return fail(START_IN_OBSTACLE)
        s_node = esc
    dist, pred = dijkstra(graph, directed=True, indices=s_node, return_predecessors=True)
    if not np.isfinite(dist[g_node]):
        return fail("no path")
    nodes = [g_node]
    while nodes[-1] != s_node:
        nodes.append(int(pred[nodes[-1]]))
    nodes = np.asarray(nodes[::-1])
    cells = geo.cell_center(nodes // geo.width, nodes % geo.width)
    # the start's and goal's own cell centres would be a back-step: the points replace them
    inner = cells[1:-1] if passable[sr, sc] else cells[:-1]
    pts = np.vstack([start, inner.reshape(-1, 2), goal])
    keep = np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-9]
    pts = pts[keep]
    short = _shortcut(costmap, pts, cfg)
    path = resample_path(short, cfg.spacing)
    length = float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if len(path) > 1 else 0.0
    return PlanResult(path, length, "ok", (time.perf_counter() - t0) * 1e3, path_headings(path))
