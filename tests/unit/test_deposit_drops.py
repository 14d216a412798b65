"""The tray's release slots against MuJoCo physics (``quadmanip.testbench.deposit_drops``):
a third food object goes beside the first two, not onto them."""

from __future__ import annotations

import pytest
from quadmanip.testbench.deposit_drops import drop_into

pytestmark = pytest.mark.unit


def test_a_third_food_object_released_into_the_tray_stays_in_with_the_first_two() -> None:
    # the coffee can is the widest (0.102 m); on the near row alone it landed on the first
    # object and one of the three ended on the table (0 of 96 drops kept all three)
    where = drop_into("tray", ["cracker_box", "tomato_soup_can", "coffee_can"], seed=0)
    assert where == {"cracker_box": "in_place", "tomato_soup_can": "in_place",
                     "coffee_can": "in_place"}  # fmt: skip
