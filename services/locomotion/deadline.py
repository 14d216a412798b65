"""Deadline awareness: is the control loop keeping up, and if not, degrade on purpose.

A balance controller that answers late is worse than a slower, more careful one: each
late answer is a stale command applied to a moving robot (issue 12: under load the robot
sank and toppled while locomotion reported nothing). The monitor measures, per window of
``window`` seconds of robot time:

* **late answers**: the oldest unanswered LowState's arrival to the LegCommand sent,
  longer than ``answer_budget``;
* **missed ticks**: LowState ticks never answered because the loop was late (it skips
  stale states to answer the newest). Ticks skipped while the answer was still on time
  are a burst from the robot side (the sim catching up after rendering a camera frame
  sends a few ticks at once), not a missed deadline: counted apart as ``coalesced``;
* **MPC overruns**: an MPC step longer than ``answer_budget`` (that tick's answer is late);
* what the robot side reports on ``sim/status``: the median age (ticks) of the leg
  command it applied and its leg-command timeouts (legs fell back to damping).

A robot side that waits for every answer (the sim's lockstep mode) has no deadline: late
answers and MPC overruns are still counted there but never degrade.

The budgets are in robot time (``answer_budget`` is 1.5 control ticks). When the robot side
runs slower than real time (a simulated robot capped at a real-time factor below 1, such
as the simulated Unitree robot on a small computer), its ticks are that much longer on the
wall clock, and so is the time an answer may take: the monitor measures the robot's pace
(robot seconds per wall second, from the states' stamps and arrival times) and divides
the wall-clock budgets by it. A real robot's pace is 1, so nothing changes there; a pace
above 1 never shortens the budgets.

Any of them beyond its limit turns the state ``degraded`` (with the reason); the
controller then accepts only ``degraded_speed_scale`` of its velocity limits (slower
steps need less precise timing, and a stop is short) and stands with joint-level
stiffness (``degraded_kp``/``degraded_kd``) that does not depend on answering in time.
When even that is too late for a trot (the window's p99 answer beyond ``no_walk_late``:
a swing leg placed 4 ticks late lands somewhere else), walking is refused altogether until
the loop is back to ``ok``; the robot stops and stands. The limit only tightens during a
degraded episode: letting it loosen window by window made the robot start and stop
trotting every quarter second (with ``nice`` instead of real-time priority), and one of
those starts ended with a knee beyond its range. ``recover_time`` of clean windows
turns it back to ``ok``. The tripped state (safety.py) is the controller's, not this.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DeadlineParams:
    """Limits of the deadline monitor ([deadline] table)."""

    answer_budget: float = 0.003  # s, LowState in to LegCommand out (1.5 control ticks)
    window: float = 0.25  # s of robot time per evaluation (a late loop topples in ~1 s)
    max_missed_fraction: float = 0.02  # of the window's ticks
    max_late_fraction: float = 0.1  # of the window's answers
    max_mpc_overruns: int = 5  # per window (about 33 MPC steps per second)
    max_cmd_age_ticks: float = 2.0  # median age of the applied command (robot side)
    recover_time: float = 5.0  # s of clean windows before degraded → ok
    degraded_speed_scale: float = 0.5  # velocity limits × this while degraded
    no_walk_late: float = 0.008  # s: answers this late (window p99) cannot carry a trot at all
    degraded_kp: float = 40.0  # N m/rad, joint-level stance stiffness while degraded
    degraded_kd: float = 1.0  # N m s/rad

    def __post_init__(self) -> None:
        if self.answer_budget <= 0.0 or self.window <= 0.0 or self.recover_time < 0.0:
            raise ValueError("deadline answer_budget and window must be > 0, recover_time >= 0")
        if not 0.0 < self.degraded_speed_scale <= 1.0:
            raise ValueError("deadline degraded_speed_scale must be in (0, 1]")


class DeadlineMonitor:
    """Counts deadline misses and decides ok / degraded (module doc)."""

    def __init__(self, params: DeadlineParams) -> None:
        self.p = params
        self.state = "ok"
        self.reason = ""
        # Totals since the start.
        self.missed_ticks = 0
        self.coalesced_ticks = 0
        self.late_answers = 0
        self.mpc_overruns = 0
        self.degraded_episodes = 0
        self.leg_timeouts = 0
        self.cmd_age_ticks = 0.0
        self.robot_waits = False  # the robot side waits for every answer (lockstep)
        self._baseline: int | None = None
        # The window.
        self._t0: float | None = None
        self._last_tick: int | None = None
        self._answers: list[float] = []
        self._w_missed = 0
        self._w_late = 0
        self._w_overruns = 0
        self._w_timeouts = 0
        self._clean_since: float | None = None
        self.answer_p99 = 0.0
        self._scale = 1.0  # the tightest speed scale of the current degraded episode
        self.pace = 1.0  # robot seconds per wall second (module doc), at most 1
        self._pace_anchor: tuple[float, float] | None = None  # (robot t, wall) of the span
        self._pace_unknown = False  # arrival times are given but no span has ended yet

    def _budget(self, seconds: float) -> float:
        """A wall-clock budget for ``seconds`` of robot time at the robot's pace."""
        return seconds / self.pace

    def tick(
        self,
        t: float,
        tick: int,
        answer_s: float,
        mpc_s: float | None = None,
        arrived: float | None = None,
    ) -> None:
        """One answered LowState: its robot time, tick number, the wall time from its
        arrival to the answer, the MPC step time if the MPC ran in it, and the wall time
        (any monotonic clock, seconds) at which it arrived, for the robot's pace."""
        if self._t0 is None:
            self._t0 = t
        if arrived is not None:
            self._measure_pace(t, arrived)
        # Until the first span has told the pace (50 ms), nothing is judged late.
        budget = math.inf if self._pace_unknown else self._budget(self.p.answer_budget)
        if self._last_tick is not None and tick > self._last_tick + 1:
            gap = tick - self._last_tick - 1
            if answer_s > budget:
                self.missed_ticks += gap
                self._w_missed += gap
            else:
                self.coalesced_ticks += gap
        if self._last_tick is None or tick > self._last_tick:
            self._last_tick = tick
        self._answers.append(answer_s)
        if answer_s > budget:
            self.late_answers += 1
            self._w_late += 1
        if mpc_s is not None and mpc_s > budget:
            self.mpc_overruns += 1
            self._w_overruns += 1

    def _measure_pace(self, t: float, wall: float) -> None:
        """Robot seconds per wall second over the last span of wall time (50 ms for the
        first, then 0.2 s); spans restart so that the pace follows a robot that speeds up
        or slows down."""
        if self._pace_anchor is None or t < self._pace_anchor[0]:
            self._pace_anchor = (t, wall)
            self._pace_unknown = True
            return
        t0, w0 = self._pace_anchor
        if wall - w0 >= (0.05 if self._pace_unknown else 0.2):
            self.pace = float(np.clip((t - t0) / (wall - w0), 0.05, 1.0))
            self._pace_anchor = (t, wall)
            self._pace_unknown = False

    def restart(self) -> None:
        """The robot side restarted (ticks went back): start counting gaps afresh."""
        self._last_tick = None
        self._pace_anchor = None

    def robot_status(self, cmd_age_p50: float, leg_timeouts: int, waits: bool = False) -> None:
        """What the robot side reported (sim/status); ``waits``: it waits for every answer."""
        self.robot_waits = bool(waits)
        self.cmd_age_ticks = float(cmd_age_p50)
        if self._baseline is None:  # timeouts before this controller listened are history
            self._baseline = int(leg_timeouts)
            self.leg_timeouts = int(leg_timeouts)
        if leg_timeouts > self.leg_timeouts:
            self._w_timeouts += leg_timeouts - self.leg_timeouts
        self.leg_timeouts = max(self.leg_timeouts, int(leg_timeouts))

    def evaluate(self, t: float) -> tuple[str, str] | None:
        """Close the window if ``window`` has passed; returns (new state, reason) on a
        change of state, else None."""
        if self._t0 is None or t - self._t0 < self.p.window:
            return None
        p = self.p
        n = max(len(self._answers), 1)
        ticks = n + self._w_missed
        self.answer_p99 = float(np.percentile(self._answers, 99)) if self._answers else 0.0
        problems = []
        if self._w_missed > p.max_missed_fraction * ticks:
            problems.append(f"{self._w_missed} of {ticks} ticks missed")
        if self._w_late > p.max_late_fraction * n and not self.robot_waits:
            problems.append(
                f"{self._w_late} of {n} answers later than "
                f"{self._budget(p.answer_budget) * 1e3:.1f} ms "
                f"(p99 {self.answer_p99 * 1e3:.1f} ms)"
            )
        if self._w_overruns > p.max_mpc_overruns and not self.robot_waits:
            problems.append(f"{self._w_overruns} MPC steps over budget")
        if self.cmd_age_ticks > p.max_cmd_age_ticks:
            problems.append(f"leg commands {self.cmd_age_ticks:.1f} ticks old at the robot")
        if self._w_timeouts > 0:
            problems.append(f"{self._w_timeouts} leg-command timeouts at the robot")
        self._t0 = t
        self._answers = []
        self._w_missed = self._w_late = self._w_overruns = self._w_timeouts = 0
        if problems:
            self._clean_since = None
            late = self.answer_p99 > self._budget(p.no_walk_late)
            self._scale = min(self._scale, 0.0 if late else p.degraded_speed_scale)
            reason = "cannot keep up: " + "; ".join(problems)
            changed = self.state != "degraded"
            if changed:
                self.degraded_episodes += 1
            self.state, self.reason = "degraded", reason
            return ("degraded", reason) if changed else None
        if self.state == "degraded":
            if self._clean_since is None:
                self._clean_since = t
            if t - self._clean_since >= p.recover_time:
                self.state, self.reason = "ok", ""
                self._clean_since = None
                self._scale = 1.0
                return ("ok", "")
        return None

    @property
    def speed_scale(self) -> float:
        """Factor on the velocity limits now: 1 when ok, ``degraded_speed_scale`` when
        degraded, 0 (no walking) once a window of this degraded episode had answers too
        late to trot."""
        return 1.0 if self.state != "degraded" else self._scale
