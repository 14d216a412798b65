"""Gripper commands and grasp detection from finger gap and effort.

A real parallel gripper reports only its finger opening and its motor effort. With a
force-limited position loop (what the actuator layer implements) closing on an object
stalls the fingers at the object's width with the effort saturated at the commanded force
limit; closing on nothing drives the gap to the closed stop with the effort falling back
to ~0. So after a close command, once the gap has settled:

* ``HOLDING``: gap above ``empty_gap`` and effort at least ``hold_min_effort``. An absolute
  threshold, not a fraction of the force limit: a position loop closing on a thin object
  (a 1.2 mm cup wall) stalls before its force saturates;
* ``EMPTY``: gap at or below ``empty_gap`` (fingers met), or no effort;

and while carrying, ``LOST`` when the gap closes to ``empty_gap`` (the fingers met: the
object slid out) or the effort stays below ``lost_min_effort`` for ``lost_debounce``
seconds. A gap that shrinks by more than ``slip_gap`` and settles again with the force
still on is an object that turned or slid *within* the grip (a spoon pinched across its
width rolling onto its 14 mm thickness while the robot walks): still ``HOLDING``, at the
new width, counted in ``shifts``. Treating every such shift as lost made the task drop
objects it was still carrying.

A (re)started service does not know what its fingers hold: the actuator layer keeps the
last gripper command of the process that died, so fingers that were squeezing an object
still squeeze it. Until its first gripper command the monitor therefore infers the grip
from the readings (``infer_at_start``): once the gap has settled, a gap above
``empty_gap`` with at least ``hold_min_effort`` is ``HOLDING`` (``inferred``: an object of
unknown class and mass); anything else stays ``OPEN`` (the start state).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = ["GripState", "GripperConfig", "GraspMonitor"]


@dataclass(frozen=True)
class GripperConfig:
    """Gripper thresholds (section ``[gripper]`` of configs/manipulation.toml)."""

    # 0 = the description's maximum finger gap (filled in by load_manipulation_config).
    open_gap: float = 0.0
    close_gap: float = 0.0
    max_force: float = 25.0
    empty_gap: float = 0.0015
    settle_speed: float = 0.005
    settle_time: float = 0.15
    close_timeout: float = 2.0
    # An open command has arrived once the gap is this close to the commanded one (m).
    open_tolerance: float = 0.001
    hold_min_effort: float = 2.0
    lost_min_effort: float = 1.0
    slip_gap: float = 0.006
    lost_debounce: float = 0.1
    # kg announced to locomotion for a held object whose mass the grasp goal left unknown
    # (about the catalogue's mean object, 0.16 kg)
    default_payload_mass: float = 0.15
    # Heavier objects are squeezed harder: force = force_per_kg x mass, at least max_force
    # and at most the description's rated gripper force (filled in by the config: 0 = that).
    # Silicone on a 0.41 kg steel can (mu 0.55, a few mm of contact patch) twisted or
    # slipped out of a 30 N horizontal grasp in the full-stack trials; at 40 N it held.
    force_per_kg: float = 100.0
    rated_force: float = 0.0
    # Until the first gripper command, infer HOLDING from settled readings (a restart
    # while an object is in the fingers: see the module docstring).
    infer_at_start: bool = True


class GripState(StrEnum):
    """What the gripper believes about its contents."""

    OPEN = "open"
    CLOSING = "closing"
    HOLDING = "holding"
    EMPTY = "empty"
    LOST = "lost"


class GraspMonitor:
    """Classifies holding / empty / lost from ``(time, gap, effort)`` samples."""

    def __init__(self, config: GripperConfig) -> None:
        self.cfg = config
        self.state = GripState.OPEN
        self.max_force = config.max_force
        self.grasp_gap: float | None = None
        self._t_cmd = 0.0
        self._last: tuple[float, float] | None = None
        self._settled_since: float | None = None
        self._weak_since: float | None = None
        self.shifts = 0
        self._inferring = config.infer_at_start
        self.inferred = False
        """HOLDING was inferred from the readings at start, not seen after a close."""

    def command_open(self, t: float) -> tuple[float, float]:
        """Returns the ``(gap, max_force)`` of an open command and resets detection."""
        self.state = GripState.OPEN
        self.grasp_gap = None
        self._t_cmd = t
        self._inferring = self.inferred = False
        return self.cfg.open_gap, self.cfg.max_force

    def command_close(self, t: float, max_force: float | None = None) -> tuple[float, float]:
        """Returns the ``(gap, max_force)`` of a force-limited close command."""
        self.max_force = self.cfg.max_force if max_force is None else float(max_force)
        self.state = GripState.CLOSING
        self.grasp_gap = None
        self._t_cmd = t
        self._settled_since = None
        self._weak_since = None
        self._inferring = self.inferred = False
        return self.cfg.close_gap, self.max_force

    def update(self, t: float, gap: float, effort: float) -> GripState:
        """Feeds one sample; returns the (possibly new) state."""
        cfg = self.cfg
        speed = 0.0
        if self._last is not None and t > self._last[0]:
            speed = abs(gap - self._last[1]) / (t - self._last[0])
        self._last = (t, gap)
        eff = abs(effort)
        if self.state is GripState.OPEN and self._inferring:
            self._infer(t, gap, eff, speed)
        elif self.state is GripState.CLOSING:
            if speed < cfg.settle_speed:
                if self._settled_since is None:
                    self._settled_since = t
            else:
                self._settled_since = None
            settled = self._settled_since is not None and t - self._settled_since >= cfg.settle_time
            if settled or t - self._t_cmd >= cfg.close_timeout:
                if gap > cfg.empty_gap and eff >= cfg.hold_min_effort:
                    self.state = GripState.HOLDING
                    self.grasp_gap = gap
                else:
                    self.state = GripState.EMPTY
        elif self.state is GripState.HOLDING:
            assert self.grasp_gap is not None
            if gap <= cfg.empty_gap:
                self.state = GripState.LOST
            elif eff < cfg.lost_min_effort:
                if self._weak_since is None:
                    self._weak_since = t
                if t - self._weak_since >= cfg.lost_debounce:
                    self.state = GripState.LOST
            else:
                self._weak_since = None
                if gap < self.grasp_gap - cfg.slip_gap and speed < cfg.settle_speed:
                    self.grasp_gap = gap  # shifted in the grip, still squeezed
                    self.shifts += 1
        return self.state

    def _infer(self, t: float, gap: float, eff: float, speed: float) -> None:
        """Before the first command: settled fingers closed on something are HOLDING."""
        cfg = self.cfg
        if speed >= cfg.settle_speed:
            self._settled_since = None
            return
        if self._settled_since is None:
            self._settled_since = t
        if t - self._settled_since < cfg.settle_time:
            return
        if gap > cfg.empty_gap and eff >= cfg.hold_min_effort:
            self.state = GripState.HOLDING
            self.grasp_gap = gap
            self.inferred = True
            self._inferring = False
            self._weak_since = None

    @property
    def holding(self) -> bool:
        """True while an object is detected between the fingers."""
        return self.state is GripState.HOLDING


def grasp_force(cfg: GripperConfig, mass: float) -> float:
    """The squeeze force (N) for an object of ``mass`` kg (0: unknown -> ``max_force``)."""
    want = max(cfg.max_force, cfg.force_per_kg * max(mass, 0.0))
    return float(min(want, cfg.rated_force)) if cfg.rated_force > 0.0 else float(want)
