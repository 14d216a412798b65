"""Where to look from to cover a search zone (paper Section 5.3, Figure 12).

A search zone of the places file is an axis-aligned rectangle (``target`` its centre,
``size`` its extent) with a ``stand`` pose at its edge, facing in. The searching camera
sees a band of the floor (or of a table top) from ``view_near`` to ``view_far`` ahead of
the base and ``view_half_width`` to either side. Candidate viewpoints:

* along the stand's heading, every half band (``view_far - view_near``) up to the zone's
  far side less ``view_near`` (floors, ``advance``); a table is seen from its stand line
  only (nobody walks into a table);
* at each, turned by multiples of ``turn`` up to a quarter turn either way (``cover =
  "turn"``: turning in place is what a quadruped does cheaply), or stepped sideways by
  multiples of ``shift`` across the zone (``"shift"``: the front camera looks straight
  ahead along a table).

The stand pose comes first; then, greedily, the candidate that sees most of what is not
yet seen (points ``sample`` m apart over the zone) until no candidate adds anything, and
the chosen ones are visited nearest the stand first. The robot thus walks into floor it
has already looked at (and cleared: the task picks up what it finds before it moves on).
A viewpoint whose points (:func:`view_samples`) perception's cameras have all but shown
already, on the way or from other zones, is skipped by the task.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from quadmanip.services.behavior.frames import Pose2, wrap

__all__ = ["SearchConfig", "sees", "view_samples", "zone_viewpoints"]


@dataclass(frozen=True)
class SearchConfig:
    """How one kind of zone (``search_floor``, ``search_table``) is searched."""

    posture: str = "floor_search"  # manipulation's posture while looking (Fig. 12)
    camera: str = "gripper_camera"  # the camera that posture looks with (for the record)
    view_near: float = 0.4  # m ahead of the base where the camera's band begins
    view_far: float = 1.4  # ... and where it ends
    view_half_width: float = 0.6  # m either side of the body axis
    advance: bool = True  # walk into the zone (floors) or look from the stand line (tables)
    cover: Literal["turn", "shift"] = "turn"  # how a zone wider than the band is covered
    turn: float = 0.6  # rad between headings ("turn")
    shift: float = 0.4  # m between side steps ("shift")
    sample: float = 0.2  # m between the zone's points that must be seen
    # s (robot time) looking from each viewpoint: the cameras give 10 frames a second and a
    # track confirms in 3; the search posture also looks while walking between viewpoints
    dwell: float = 1.0


def sees(viewpoint: Pose2, point: tuple[float, float], cfg: SearchConfig) -> bool:
    """Whether the camera's band from ``viewpoint`` holds ``point``."""
    dx, dy = point[0] - viewpoint[0], point[1] - viewpoint[1]
    c, s = math.cos(viewpoint[2]), math.sin(viewpoint[2])
    along, across = c * dx + s * dy, -s * dx + c * dy
    return cfg.view_near <= along <= cfg.view_far and abs(across) <= cfg.view_half_width


def _samples(centre: tuple[float, float], size: tuple[float, float], step: float) -> list:
    """Points at most ``step`` apart over the zone, its edges included."""
    nx = max(int(math.ceil(size[0] / step)), 1)
    ny = max(int(math.ceil(size[1] / step)), 1)
    return [
        (centre[0] + (i / nx - 0.5) * size[0], centre[1] + (j / ny - 0.5) * size[1])
        for i in range(nx + 1)
        for j in range(ny + 1)
    ]


def _candidates(
    stand: Pose2, centre: tuple[float, float], size: tuple[float, float], cfg: SearchConfig
) -> list[tuple[float, int, Pose2]]:
    """(distance along, order of the side offset, pose) of every candidate viewpoint."""
    c, s = math.cos(stand[2]), math.sin(stand[2])
    along, across = [], []
    for dx in (-0.5, 0.5):
        for dy in (-0.5, 0.5):
            px, py = centre[0] + dx * size[0] - stand[0], centre[1] + dy * size[1] - stand[1]
            along.append(c * px + s * py)
            across.append(-s * px + c * py)
    steps = [0.0]
    if cfg.advance:  # every half band, and as far in as the near edge allows
        half = max(cfg.view_far - cfg.view_near, 0.2) / 2
        limit = max(along) - cfg.view_near
        while steps[-1] + half < limit:
            steps.append(steps[-1] + half)
        if limit > steps[-1] + 0.05:
            steps.append(limit)
    if cfg.cover == "turn":
        n = int(math.floor((math.pi / 2) / max(cfg.turn, 1e-3)))
    else:
        n = int(math.ceil(max(abs(a) for a in across) / max(cfg.shift, 1e-3)))
    out = []
    for d in steps:
        x, y = stand[0] + c * d, stand[1] + s * d
        for rank, k in enumerate(k for j in range(n + 1) for k in ((j, -j) if j else (0,))):
            if cfg.cover == "turn":
                pose = (x, y, wrap(stand[2] + k * cfg.turn))
            else:
                pose = (x - s * k * cfg.shift, y + c * k * cfg.shift, stand[2])
            out.append((d, rank, pose))
    return out


def zone_viewpoints(
    stand: Pose2, centre: tuple[float, float], size: tuple[float, float], cfg: SearchConfig
) -> list[Pose2]:
    """The poses (map frame) to look from; the stand pose first (module docstring)."""
    todo = _samples(centre, size, cfg.sample)
    cands = _candidates(stand, centre, size, cfg)
    chosen = [cands[0]]  # the stand pose
    todo = [p for p in todo if not sees(cands[0][2], p, cfg)]
    while todo:
        gains = [sum(sees(v[2], p, cfg) for p in todo) for v in cands]
        best = max(range(len(cands)), key=lambda i: gains[i])
        if gains[best] == 0:
            break  # what is left no candidate sees (too near the stand, or beyond reach)
        chosen.append(cands[best])
        todo = [p for p in todo if not sees(cands[best][2], p, cfg)]
    chosen.sort(key=lambda v: (v[0], v[1]))
    return [v[2] for v in chosen]


def view_samples(
    viewpoint: Pose2, centre: tuple[float, float], size: tuple[float, float], cfg: SearchConfig
) -> list[tuple[float, float]]:
    """The zone's points (``sample`` m apart) the camera's band from ``viewpoint`` holds."""
    return [p for p in _samples(centre, size, cfg.sample) if sees(viewpoint, p, cfg)]
