"""How leg commands reach the robot side (sim or hardware adapter), per status window:
the age of the command applied at each control tick and the ticks without a new one.
Both publish it as ``RobotStatus`` on ``sim/status`` for locomotion's deadline monitor."""

from __future__ import annotations

import statistics
from typing import Any

from quadmanip.common import messages as msg

__all__ = ["LinkStats"]


class LinkStats:
    """How leg commands arrive, per status window: the age (ticks) of the command applied
    at each tick and the ticks that got no new command (the last one is reused)."""

    def __init__(self) -> None:
        self._ages: list[int] = []
        self._stale = 0
        self._ticks = 0
        self._last: msg.LegCommand | None = None

    def record(self, tick: int, cmd: msg.LegCommand | None) -> None:
        """Tick ``tick`` is about to be stepped with ``cmd`` (None: no new command)."""
        self._ticks += 1
        if cmd is None:
            self._stale += 1
            cmd = self._last
        self._last = cmd
        if cmd is not None:
            self._ages.append(max(0, tick - int(cmd.tick)))

    def flush(self, **fields: Any) -> msg.RobotStatus:
        """The window's RobotStatus (``fields`` fill the rest); starts a new window."""
        ages = self._ages
        status = msg.RobotStatus(
            ticks=self._ticks,
            stale_ticks=self._stale,
            cmd_age_p50=float(statistics.median(ages)) if ages else 0.0,
            cmd_age_max=max(ages, default=0),
            **fields,
        )
        self._ages, self._stale, self._ticks = [], 0, 0
        return status
