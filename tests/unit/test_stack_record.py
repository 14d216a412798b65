"""The full-stack film replays wire samples on its own copy of the world."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from quadmanip.common import robot_description as rd  # noqa: E402
from quadmanip.testbench import stack_trials as st  # noqa: E402
from quadmanip.testbench.stack_record import HEIGHT, WIDTH, StackFilm, _Sample  # noqa: E402

pytestmark = pytest.mark.unit


def test_film_draws_each_sample_where_the_wire_said(tmp_path):
    scn = st.grasp_scenario("mug", "floor", 0)
    film = StackFilm(scn, tmp_path / "run")
    (mug,) = scn.objects
    x, y, _ = scn.robot_start
    q = rd.home_joint_positions()
    for k, gap in enumerate((0.0, 0.1)):
        film.samples.append(
            _Sample(
                t=0.25 * k,
                q=q,
                gap=gap,
                base=(np.array([x, y, 0.3]), np.array([1.0, 0.0, 0.0, 0.0])),
                objects={"mug": (np.asarray(mug.position) + [0, 0, 0.1 * k], np.asarray(mug.quat))},
                drawers={},
            )
        )
    frames = film.render()
    assert len(frames) == 2 and frames[0].shape == (HEIGHT, WIDTH, 3)
    # the lifted mug and the opened fingers change the picture
    assert np.mean(np.abs(frames[0].astype(int) - frames[1].astype(int))) > 0.5
    assert film.save(tmp_path / "docs" / "sheet.png") == 2
    assert (tmp_path / "run" / "frame_001.png").exists()
    assert (tmp_path / "run" / "sheet.png").exists() and (tmp_path / "docs" / "sheet.png").exists()


def test_a_camera_behind_a_wall_turns_to_where_the_robot_shows():
    import math

    from quadmanip.sim.scenarios import get_scenario
    from quadmanip.testbench.stack_record import render_states

    # by the west wall, facing so that the default bearing puts the camera behind the wall
    yaw = math.radians(-125.0)
    quat = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    smp = _Sample(0.0, rd.home_joint_positions(), 0.05, (np.array([0.4, 2.0, 0.3]), quat), {}, {})
    scn = get_scenario("short-20")
    (blocked,) = render_states(scn, [smp], 125.0)
    (seen,) = render_states(scn, [smp], 125.0, unblocked=True)

    def trunk_pixels(img: np.ndarray) -> int:  # the trunk's orange
        r, g, b = (img[..., k].astype(int) for k in range(3))
        return int(((r > 180) & (g > 90) & (g < 190) & (b < 90)).sum())

    assert trunk_pixels(blocked) == 0  # the wall hides it
    assert trunk_pixels(seen) > 1000
