"""Grasp detection on synthetic finger gap / effort signals shaped like a force-limited loop."""

import numpy as np
import pytest
from quadmanip.services.manipulation.gripper import GraspMonitor, GripperConfig, GripState

pytestmark = pytest.mark.unit

CFG = GripperConfig()
DT = 0.002


def _close_on(width: float, force: float, t_end: float = 1.0):
    """First-order finger closing from open_gap to `width`; effort saturates on contact."""
    t = np.arange(0.0, t_end, DT)
    gap = np.maximum(width, CFG.open_gap - 0.2 * t)  # 0.2 m/s closing speed
    effort = np.where(gap > width + 1e-9, 0.3 * force, force if width > 0 else 0.0)
    return t, gap, effort


def test_close_on_object_is_holding_with_measured_width():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.05, CFG.max_force)
    states = [mon.update(ti, g, e) for ti, g, e in zip(t, gap, eff, strict=True)]
    assert states[-1] is GripState.HOLDING
    assert mon.grasp_gap == pytest.approx(0.05, abs=1e-6)
    # no decision while the fingers still move (3 cm at 0.2 m/s = 0.15 s of travel)
    first = states.index(GripState.HOLDING)
    assert t[first] >= (CFG.open_gap - 0.05) / 0.2 + CFG.settle_time - 1e-9


def test_close_on_nothing_is_empty():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.0, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    assert mon.state is GripState.EMPTY


def test_stalled_without_effort_is_not_holding():
    """Fingers stopped at 3 cm with (almost) no effort: not a grasp."""
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    for ti in np.arange(0.0, 1.0, DT):
        mon.update(ti, 0.03, 0.5 * CFG.hold_min_effort)
    assert mon.state is GripState.EMPTY


def test_slip_during_carry_is_lost():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.04, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    assert mon.holding
    # object slides out: fingers close further to the stop
    t2 = np.arange(1.0, 1.3, DT)
    g2 = np.maximum(0.0, 0.04 - 0.2 * (t2 - 1.0))
    seen = [mon.update(ti, g, CFG.max_force) for ti, g in zip(t2, g2, strict=True)]
    assert seen[-1] is GripState.LOST
    lost_at = t2[seen.index(GripState.LOST)]
    # lost as soon as the gap shrank by slip_gap (0.2 m/s -> 30 ms)
    assert lost_at - 1.0 == pytest.approx(CFG.slip_gap / 0.2, abs=2 * DT)


def test_effort_drop_is_lost_only_after_debounce():
    mon = GraspMonitor(CFG)
    mon.command_close(0.0)
    t, gap, eff = _close_on(0.04, CFG.max_force)
    for ti, g, e in zip(t, gap, eff, strict=True):
        mon.update(ti, g, e)
    # a 50 ms effort dip (shorter than the debounce) keeps holding
    for ti in np.arange(1.0, 1.05, DT):
        mon.update(ti, 0.04, 0.0)
    for ti in np.arange(1.05, 1.2, DT):
        mon.update(ti, 0.04, CFG.max_force)
    assert mon.holding
    for ti in np.arange(1.2, 1.2 + CFG.lost_debounce + 4 * DT, DT):
        mon.update(ti, 0.04, 0.0)
    assert mon.state is GripState.LOST


def test_open_resets():
    mon = GraspMonitor(CFG)
    gap, force = mon.command_open(0.0)
    assert gap == CFG.open_gap and force == CFG.max_force
    assert mon.state is GripState.OPEN
    gap, force = mon.command_close(0.1, max_force=10.0)
    assert gap == CFG.close_gap and force == 10.0
