"""The seen grid: which cells of floor and table top the cameras have shown."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from quadmanip.common import robot_description as rd
from quadmanip.common.messages import SEEN_FLOOR, SEEN_TABLE
from quadmanip.services.perception.node import seen_grid
from quadmanip.services.perception.seen_area import SeenArea, SeenConfig

pytestmark = pytest.mark.unit


def test_floor_and_table_returns_mark_their_cells_and_nothing_else():
    area = SeenArea(SeenConfig(resolution=0.1, min_views=1))
    pts = np.array(
        [
            [1.05, 2.05, 0.01],  # floor
            [3.05, -0.95, 0.42],  # a table top
            [5.0, 5.0, 0.20],  # an object's side, a chair: neither
            [np.nan, 0.0, 0.0],  # a bad return
        ]
    )
    assert area.mark(pts) == 2
    q = np.array([[1.01, 2.09], [1.11, 2.05], [3.0, -0.99], [5.0, 5.0], [-40.0, 0.0]])
    assert seen_grid(area, 0.0).seen(q, SEEN_FLOOR).tolist() == [True, False, False, False, False]
    assert seen_grid(area, 0.0).seen(q, SEEN_TABLE).tolist() == [False, False, True, False, False]
    # seen again adds nothing; a table top over a seen floor cell counts
    assert area.mark(pts) == 0
    assert area.mark(np.array([[1.05, 2.05, 0.45]])) == 1
    assert seen_grid(area, 0.0).seen(q[:1], SEEN_TABLE).tolist() == [True]


def test_a_cell_counts_seen_after_min_views_frames_each_counted_once():
    # walking past, a cell in one frame: an object there would not have been confirmed
    area = SeenArea(SeenConfig(resolution=0.1, min_views=3))
    q = np.array([[1.05, 2.05]])
    frame = np.array([[1.05, 2.05, 0.0], [1.06, 2.04, 0.0], [1.04, 2.06, 0.01]])
    assert area.mark(frame) == 0  # three returns in one frame are one view
    assert area.mark(frame) == 0
    assert not seen_grid(area, 0.0).seen(q, SEEN_FLOOR)[0]
    assert area.mark(frame) == 1
    assert seen_grid(area, 0.0).seen(q, SEEN_FLOOR)[0]


def test_the_grid_grows_to_hold_every_mark_and_keeps_the_old_ones():
    area = SeenArea(SeenConfig(resolution=0.1, min_views=1))
    area.mark(np.array([[0.05, 0.05, 0.0]]))
    shape0 = area.views.shape[1:]
    area.mark(np.array([[9.95, -3.05, 0.0], [-2.05, 4.05, 0.0]]))
    assert area.views.shape[1] > shape0[0] and area.views.shape[2] > shape0[1]
    q = np.array([[0.05, 0.05], [9.95, -3.05], [-2.05, 4.05]])
    assert seen_grid(area, 0.0).seen(q, SEEN_FLOOR).all()
    assert int(np.count_nonzero(area.views)) == 3
    # the origin is the corner of cell (0, 0): a mark's cell is where the origin says
    r, c = np.argwhere(area.views[0])[0]
    x0, y0 = area.origin
    assert seen_grid(area, 0.0).seen(
        np.array([[x0 + (c + 0.5) * 0.1, y0 + (r + 0.5) * 0.1]]), SEEN_FLOOR
    )[0]


def test_bad_configs_are_refused():
    with pytest.raises(ValueError):
        SeenConfig(resolution=0.0)
    with pytest.raises(ValueError):
        SeenConfig(stride=0)
    with pytest.raises(ValueError):
        SeenConfig(table_z=(0.6, 0.3))
    with pytest.raises(ValueError):
        SeenConfig(min_views=0)


def _floor_depth(height: float, tilt: float, w: int = 320, h: int = 240, f: float = 250.0):
    """A pinhole camera ``height`` m over a flat floor, looking along +x and ``tilt`` rad
    down: its depth image (0 where a ray misses the floor), K and pose (quaternion)."""
    from quadmanip.common.rotations import mat_to_quat

    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    c, s = np.cos(tilt), np.sin(tilt)
    x_opt, z_opt = np.array([0.0, -1.0, 0.0]), np.array([c, 0.0, -s])
    R = np.column_stack([x_opt, np.cross(z_opt, x_opt), z_opt])
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([(u - w / 2) / f, (v - h / 2) / f, np.ones((h, w))], axis=-1) @ R.T
    down = rays[..., 2]
    depth = np.where(down < -1e-6, height / np.maximum(-down, 1e-6), 0.0).astype(np.float32)
    return depth, K, np.array([0.0, 0.0, height]), mat_to_quat(R)


def test_a_frame_marks_the_floor_it_shows_within_reach_in_the_grid_frame():
    depth, K, pos, quat = _floor_depth(0.5, 0.5)
    area = SeenArea(SeenConfig(resolution=0.1, stride=2, min_views=1))
    # the grid's frame: odom turned a quarter turn and moved (map->odom's matrix)
    to_grid = np.array([[0.0, -1.0, 3.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    assert area.mark_frame(depth, K, pos, quat, 2.0, to_grid, np.array([-0.3, 0.0])) > 20
    # odom points ahead on the camera's axis (x) -> grid (3 - y, 1 + x)
    ahead = np.array([[1.0, 0.0], [1.6, 0.0]])
    far = np.array([[2.6, 0.0]])  # beyond the reach along the optical axis
    behind = np.array([[-0.5, 0.0]])
    g = lambda p: p @ to_grid[:2, :2].T + to_grid[:2, 2]  # noqa: E731
    assert seen_grid(area, 0.0).seen(g(ahead), SEEN_FLOOR).all()
    assert not seen_grid(area, 0.0).seen(g(far), SEEN_FLOOR).any()
    assert not seen_grid(area, 0.0).seen(g(behind), SEEN_FLOOR).any()
    assert not seen_grid(area, 0.0).seen(g(ahead), SEEN_TABLE).any()


def test_a_reader_asks_what_was_seen_since_a_time():
    # an object fell at t = 10: only views from then on say where it does not lie
    area = SeenArea(SeenConfig(resolution=0.1, min_views=1))
    area.mark(np.array([[1.05, 2.05, 0.0], [3.05, 2.05, 0.0]]), stamp=4.0)
    area.mark(np.array([[3.05, 2.05, 0.0]]), stamp=12.0)
    grid = seen_grid(area, 12.0)
    q = np.array([[1.05, 2.05], [3.05, 2.05]])
    assert grid.seen(q, SEEN_FLOOR).tolist() == [True, True]
    assert grid.seen(q, SEEN_FLOOR, since=10.0).tolist() == [False, True]
    assert not grid.seen(q, SEEN_TABLE, since=0.0).any()


def test_a_table_top_counts_seen_only_from_a_camera_above_it():
    # the front camera (0.33 m up) sees a 0.40 m table's underside at 0.385 m
    area = SeenArea(SeenConfig(resolution=0.1, min_views=1))
    under = np.array([[3.05, 1.05, 0.385], [3.15, 1.05, 0.385]])
    assert area.mark(under, camera_z=0.33) == 0
    assert area.mark(under, camera_z=0.50) == 0  # level with it: a grazing look at best
    assert area.mark(under, camera_z=0.83) == 2  # the gripper camera over the table
    assert area.mark(np.array([[5.05, 1.05, 0.0]]), camera_z=0.33) == 1  # the floor: always


def _table_cells_marked(posture: str, camera: str, back: float) -> int:
    """Kitchen-table cells (of 54) one rendered frame marks, the robot in ``posture``
    facing the table's south edge from ``back`` m, reach as the node's config."""
    import mujoco
    from quadmanip.common.config import load_config
    from quadmanip.services.perception.config import PerceptionConfig
    from quadmanip.services.perception.seen_area import TABLE
    from quadmanip.sim.scenarios import Placement, Scenario
    from quadmanip.sim.world.builder import build_world
    from quadmanip.testbench.probe_views import _postures, _stand, render_object

    cfg = load_config(PerceptionConfig, "perception").seen
    # the kitchen table: centre (7.2, 1.9), 0.9 x 0.6 m; a ball far off for the renderer
    ball = Placement("baseball", "floor", (4.0, 1.0, 0.04), (1.0, 0.0, 0.0, 0.0))
    world = build_world(Scenario("seen", 0, (ball,), (7.2, 1.6 - back, 90.0)))
    data = world.initial_data()
    _stand(world, data, *_postures()[posture])
    frame, _ = render_object(world, data, camera, "baseball")
    site = world.model.site(rd.CAMERA_OPTICAL_SITES[camera]).id
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    area = SeenArea(replace(cfg, min_views=1))
    reach = cfg.front_range if camera == rd.FRONT_CAMERA else cfg.gripper_range
    base = np.array([7.2, 1.6 - back])
    area.mark_frame(frame.depth, frame.K, data.site_xpos[site], quat, reach, np.eye(3), base)
    rows, cols = np.nonzero(area.seen(TABLE))
    x = (cols + area.col0 + 0.5) * cfg.resolution
    y = (rows + area.row0 + 0.5) * cfg.resolution
    return int(np.count_nonzero((abs(x - 7.2) < 0.45) & (abs(y - 1.9) < 0.3)))


def test_the_front_camera_below_a_table_top_marks_none_of_it_the_gripper_camera_over_it_does():
    # before: the front camera marked 11-12 of the 54 cells from 0.9-1.3 m, from below
    for back in (0.6, 0.9, 1.3):
        assert _table_cells_marked("floor_search", rd.FRONT_CAMERA, back) == 0
    assert _table_cells_marked("table_search", rd.GRIPPER_CAMERA, 0.6) > 40
