"""What the tidy-up task records and reports: per object, per drawer, per trial, and
the snapshots the operator sees."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from quadmanip.services.behavior.frames import Point3

__all__ = [
    "DrawerRecord",
    "Failure",
    "ObjectRecord",
    "ObjectSummary",
    "Progress",
    "TaskReport",
]


@dataclass(frozen=True)
class Failure:
    """One failure: in which step, why, when (robot time)."""

    step: str
    reason: str
    t: float


@dataclass
class ObjectRecord:
    """Everything the task did with one object."""

    label: str
    track_id: int
    place: str
    position: Point3
    t_found: float
    grasped: bool = False
    placed: bool = False
    given_up: bool = False
    dropped: bool = False
    release_seen: bool = False  # a track of the class was seen at the release point
    attempts: int = 0  # failures that count against the give-up rule
    restarts: int = 0  # times a service's restart interrupted the work on it
    unseen: int = 0  # probes from its probing area that detected no such object
    estimated: bool = False  # perception planned a grasp of it from close by at least once
    side_probe: bool = False  # perception asked for a look from the side (4.3: not level)
    # a tall class whose side probe found nothing to grasp while its track lies low on the
    # table (knocked onto its side): probed from above
    top_probe: bool = False
    # rad: on a table, the heading it is stood at once its square stance met a leg (one of
    # the task's ``table_slants``); None: square to the table
    table_heading: float | None = None
    # perception saw it (a long box) turned off the view: stood at along its long side
    # once (``table_heading``), ``end_walk`` while the walk there is still due
    end_on: bool = False
    end_walk: bool = False
    # the class the detector gave it from close by, in the probing view, when that was not
    # the class of its track: the memory's votes from afar no longer rename it
    close_label: str = ""
    # s (robot time): not taken up again before this (its walk goals were all blocked)
    wait_until: float = -math.inf
    slot: int = -1  # the deposit slot it was (last) to be released at; -1: none yet
    # (x0, y0, x1, y1) map: the walk it fell from the fingers on, from where it was picked
    # up to where the robot noticed (it may lie anywhere along it); empty: not dropped
    dropped_along: tuple[float, ...] = ()
    # the deposit place it slipped from the fingers at (the robot stood at it): it lies
    # beside that place's box, on its table or the floor before it; empty: not there
    dropped_by: str = ""
    time_spent: float = 0.0  # s of robot time spent on it (approach to let go)
    failures: list[Failure] = field(default_factory=list)
    first_position: Point3 = (math.nan, math.nan, math.nan)  # where it was first seen
    # which life of perception's memory track_id belongs to: a restarted perception (or a
    # restarted odom frame) numbers its tracks afresh, so an old id names nothing now
    track_epoch: int = 0

    def __post_init__(self) -> None:
        if math.isnan(self.first_position[0]):
            self.first_position = tuple(self.position)  # type: ignore[assignment]

    @property
    def name(self) -> str:
        return f"{self.label}#{self.track_id}"

    @property
    def finished(self) -> bool:
        return self.placed or self.given_up


@dataclass
class DrawerRecord:
    """What the task did with one drawer."""

    place: str
    opened: float = 0.0  # m pulled (what the pulls that succeeded asked for)
    ok: bool = False
    failures: list[Failure] = field(default_factory=list)


@dataclass
class TaskReport:
    """The task's account of a trial (the judge's verdict is separate)."""

    outcome: Literal["running", "done", "budget", "canceled", "failed"] = "running"
    reason: str = ""
    t_start: float = 0.0
    t_end: float = 0.0
    step: str = ""
    drawers: list[DrawerRecord] = field(default_factory=list)
    objects: list[ObjectRecord] = field(default_factory=list)
    zones_searched: list[str] = field(default_factory=list)
    zones_total: int = 0
    trips: int = 0  # times locomotion's safety tripped (the robot got up again)


@dataclass(frozen=True)
class ObjectSummary:
    """One object's record as it stands (a copy: the task goes on changing its own)."""

    label: str
    track_id: int
    t_found: float
    grasped: bool
    placed: bool
    given_up: bool
    time_spent: float
    attempts: int
    failures: tuple[str, ...]  # "step: reason"
    first_position: Point3 = (0.0, 0.0, 0.0)  # map frame, where it was first seen


@dataclass(frozen=True)
class Progress:
    """A snapshot of the task for the operator: state, step, clock, per-object records."""

    state: str
    reason: str
    step: str
    current_object: str
    elapsed: float
    budget: float
    drawers_opened: tuple[str, ...]
    zones_searched: tuple[str, ...]
    zones_total: int
    objects: tuple[ObjectSummary, ...]
    taken_tracks: tuple[int, ...] = ()  # the track each grasp took up (TaskProgress)

    @property
    def placed(self) -> int:
        return sum(o.placed for o in self.objects)

    @property
    def given_up(self) -> int:
        return sum(o.given_up for o in self.objects)
