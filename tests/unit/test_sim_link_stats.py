"""The sim node's view of the control link (common/link_stats.py LinkStats → sim/status)."""

from __future__ import annotations

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.link_stats import LinkStats


def _cmd(tick: int) -> m.LegCommand:
    z = np.zeros(12)
    return m.LegCommand(stamp=tick * 0.002, tick=tick, q_des=z, dq_des=z, kp=z, kd=z, tau_ff=z)


def test_ages_and_stale_ticks_per_window():
    link = LinkStats()
    link.record(10, None)  # no command yet: stale, no age
    link.record(11, _cmd(11))  # answered at once
    link.record(12, None)  # nothing new: the tick-11 command again, 1 tick old
    link.record(13, _cmd(10))  # a late answer to an old tick: 3 ticks old
    st = link.flush(stamp=0.026, leg_timeouts=2, leg_mode="active", rtf=0.9, mode="realtime")
    assert st.ticks == 4 and st.stale_ticks == 2
    assert st.cmd_age_max == 3 and st.cmd_age_p50 == 1.0
    assert st.leg_timeouts == 2 and st.mode == "realtime"
    # A new window starts empty; the last command carries over.
    link.record(14, None)
    st2 = link.flush(stamp=0.03, leg_timeouts=2, leg_mode="active", rtf=1.0, mode="realtime")
    assert st2.ticks == 1 and st2.stale_ticks == 1 and st2.cmd_age_max == 4
