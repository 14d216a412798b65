"""The odometry history navigation looks a scan's pose up in."""

from __future__ import annotations

import math

import pytest
from quadmanip.services.navigation.pose_history import PoseHistory, interpolate_pose


def test_a_pose_between_two_stamps_is_interpolated():
    h = PoseHistory()
    h.add(1.00, (0.0, 0.0, 0.0))
    h.add(1.02, (0.01, 0.002, 0.02))
    x, y, yaw = h.at(1.015)
    assert x == pytest.approx(0.0075) and y == pytest.approx(0.0015) and yaw == pytest.approx(0.015)
    assert h.at(1.02) == (0.01, 0.002, 0.02)


def test_yaw_is_interpolated_the_short_way_across_pi():
    p = interpolate_pose((0.0, 0.0, math.pi - 0.1), (0.0, 0.0, -math.pi + 0.1), 0.5)
    assert abs(abs(p[2]) - math.pi) < 1e-9


def test_stamps_it_does_not_cover_give_none():
    h = PoseHistory(span=0.5, max_gap=0.1)
    for k in range(20):
        h.add(k * 0.05, (k * 0.01, 0.0, 0.0))
    assert h.at(0.0) is None  # older than the span kept
    assert h.at(0.96) is None  # newer than the newest
    assert h.at(0.7) == pytest.approx((0.14, 0.0, 0.0))
    h.add(1.2, (0.5, 0.0, 0.0))  # a 0.25 s hole
    assert h.at(1.1) is None


def test_a_clock_that_starts_again_starts_the_history_again():
    h = PoseHistory()
    h.add(5.0, (1.0, 0.0, 0.0))
    h.add(5.1, (1.1, 0.0, 0.0))
    h.add(0.1, (0.0, 0.0, 0.0))
    assert len(h) == 1 and h.at(5.05) is None
    h.clear()
    assert h.at(0.1) is None


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        PoseHistory(span=0.0)
