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


def test_a_places_signed_distance_is_positive_outside_and_negative_inside():
    table = Place(
        "kitchen_table", "search_table", (7.2, 2.62, -1.5708), (7.2, 1.9, 0.4), (0.9, 0.6)
    )
    # area x 6.75-7.65, y 1.6-2.2
    assert table.outside_by((6.716, 1.869)) == pytest.approx(0.034)  # west of its end
    assert table.outside_by((7.2, 2.5)) == pytest.approx(0.3)  # north of its edge
    assert table.outside_by((8.05, 2.5)) == pytest.approx(0.5)  # off its corner (0.4, 0.3)
    assert table.outside_by((6.79, 2.02)) == pytest.approx(-0.04)  # 4 cm in from the end
    assert table.outside_by((7.2, 1.9)) == pytest.approx(-0.3)  # its middle


@pytest.mark.parametrize(
    ("flag", "place", "area"),
    [
        ("keepout", Place("kitchen_table", "search_table", (7.2, 2.62, -1.5708),
                          (7.2, 1.9, 0.4), (0.9, 0.6), keepout=True), (6.75, 1.6, 7.65, 2.2)),
        ("moves", Place("cabinet", "cabinet", (8.56, 1.5, 0.0), (9.46, 1.5, 0.0), (0.6, 0.72),
                        moves=True), (9.16, 1.14, 9.76, 1.86)),
    ],
)  # fmt: skip
def test_area_flags_load_save_and_refuse_an_area_without_a_size(tmp_path, flag, place, area):
    from quadmanip.common.places import PlacesError, load_places, save_places

    path = save_places(tmp_path / "a.places.toml", [place])
    assert f"{flag} = true" in path.read_text()
    back = load_places(path)[place.name]
    assert back.area == pytest.approx(area)
    assert {f: getattr(back, f) for f in ("keepout", "moves")} == {
        f: f == flag for f in ("keepout", "moves")
    }
    bad = tmp_path / "b.places.toml"
    head = f'[places.t]\nkind = "{place.kind}"\nstand = [0, 0, 0]\ntarget = [1, 1, 0.4]\n'
    bad.write_text(head + f"{flag} = true\n")
    with pytest.raises(PlacesError, match=f"{flag} needs the area's 'size'"):
        load_places(bad)
    bad.write_text(head + f'size = [1, 1]\n{flag} = "yes"\n')
    with pytest.raises(PlacesError, match=f"{flag}: want true or false"):
        load_places(bad)
    bad.write_text('[places.c]\nkind = "cabinet"\nstand = [0, 0, 0]\ntarget = [1, 1, 0]\n'
                   'size = [1, 1]\nmoves = 1\n')  # fmt: skip
    with pytest.raises(PlacesError, match="moves: want true or false"):
        load_places(bad)
