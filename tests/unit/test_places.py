"""A place's area: the rectangle ``size`` around its target, grown by a margin."""

from __future__ import annotations

import pytest
from quadmanip.common.places import Place

pytestmark = pytest.mark.unit


def test_a_place_covers_its_rectangle_and_the_margin_around_it():
    floor = Place("living_floor", "search_floor", (0.95, 1.65, 0.0), (2.95, 1.65, 0.0), (3.1, 2.1))
    assert floor.covers((1.41, 0.61)) and floor.covers((4.49, 2.69, 0.05))  # near the corners
    assert not floor.covers((1.39, 1.0)) and not floor.covers((3.0, 2.71))
    assert floor.covers((1.15, 1.0), margin=0.3) and not floor.covers((1.05, 1.0), margin=0.3)
    deposit = Place("tray", "deposit", (7.0, 3.22, 1.57), (7.0, 3.65, 0.425))  # no size
    assert deposit.covers((7.0, 3.65)) and not deposit.covers((7.01, 3.65))
