"""The tidy-up's contact sheet: one frame per stage of the task, captioned."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from quadmanip.common import robot_description as rd  # noqa: E402
from quadmanip.sim.scenarios import get_scenario  # noqa: E402
from quadmanip.testbench.tidyup_film import TILE, TidyFilm, stage_of  # noqa: E402

pytestmark = pytest.mark.unit


def test_a_stage_is_the_step_without_its_numbers():
    assert stage_of("approach: mug#12") == stage_of("approach: mug#40") == "approach: mug"
    assert stage_of("go_to_viewpoint: living_floor view 2/8") == "go_to_viewpoint: living_floor"
    assert (
        stage_of("open_drawers: drawer_top: pulling 0.19 m") == "open_drawers: drawer_top: pulling"
    )
    assert stage_of("carry: mug#3 to small_box") != stage_of("carry: mug#3")


class _Latest:
    def __init__(self, msg: object) -> None:
        self.msg = msg

    def get(self) -> object:
        return self.msg


class _Bus:
    def __init__(self, topics: dict[str, object]) -> None:
        self.topics = topics

    def latest(self, key: str) -> _Latest:
        return _Latest(self.topics.get(key))


def test_each_new_stage_is_kept_once_and_drawn_on_a_captioned_sheet(tmp_path):
    scn = get_scenario("short-20")
    ball = scn.objects[0]
    base = SimpleNamespace(
        names=["base"],
        positions=[np.array([0.9, 1.2, 0.3])],
        orientations=[np.array([1.0, 0, 0, 0])],
    )
    objs = SimpleNamespace(
        names=[ball.name],
        positions=[np.asarray(ball.position)],
        orientations=[np.asarray(ball.quat)],
    )
    low = SimpleNamespace(joints=SimpleNamespace(q=rd.home_joint_positions(), gripper_gap=0.05))
    film = TidyFilm(scn, tmp_path / "film")
    steps = [
        "getting ready",  # quiet
        "go_to_viewpoint: living_floor view 1/8",
        "go_to_viewpoint: living_floor view 1/8",  # the same stage
        "look: living_floor view 1/8",  # quiet
        "approach: tennis_ball#9",
        "probe: tennis_ball#9",
        "grasp: tennis_ball#9",
        "carry: tennis_ball#9 to green_box",
    ]
    film.attach(_Bus({"sim/lowstate": low, "sim/gt/base": base, "sim/gt/objects": objs}))
    kept = [film.on_step(2.0 * k, s) for k, s in enumerate(steps)]
    assert kept == [False, True, False, False, True, True, True, True]
    # the robot walks between stages: each frame shows where the wire said it was
    base.positions[0] = np.array([2.0, 1.4, 0.3])
    assert film.on_step(20.0, "place: tennis_ball#9")
    assert film.captions[0].split() == ["2", "s", "go_to_viewpoint:", "living_floor", "view", "1/8"]
    sheet = film.save()
    assert sheet is not None and sheet.exists()
    from PIL import Image

    img = Image.open(sheet)
    assert img.size == (6 * TILE[0], 1 * TILE[1])  # six stages in a row
    frames = sorted((tmp_path / "film").glob("frame_*.png"))
    assert len(frames) == 6
    a, b = (np.asarray(Image.open(frames[i]), dtype=int) for i in (-2, -1))
    assert np.mean(np.abs(a - b)) > 0.5  # the robot moved between the last two


def test_no_state_yet_keeps_nothing(tmp_path):
    film = TidyFilm(get_scenario("short-20"), tmp_path / "film")
    film.attach(_Bus({}))
    assert not film.on_step(1.0, "approach: mug#1")
    assert film.save() is None
