"""Perception's grasp pipeline on rendered probing views against the harness's ground truth.

One object of every catalogue category, on the floor and on a table (seed 0 of the
full-stack grasp trials' scenes), seen in its probing posture (paper Fig. 5): the gripper
camera looking down, or the front camera for a tall table object. The box is cut from the
ground-truth segmentation (a perfect detector), so the test measures the grasp pipeline
alone. The estimate must agree with ``grasp_from_poses`` (the harness's stand-in for
perception): same approach, grasp point within 1.5 cm, yaw within 15 deg modulo the
object's symmetry, width within 1.5 cm, hang within 1 cm, and the bowl's tilt.

Known, documented disagreements are not tested here (docs/perception_grasp.md): the marker
is grasped at its middle (the harness takes the centre of its longer part, 15.5 mm off)
and the padlock across its body's 47 mm side, clear of the shackle (the harness closes
across the 40 mm side, one finger landing on the shackle).
"""

from __future__ import annotations

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from quadmanip.services.perception.grasp_pose import estimate_grasp_from_depth  # noqa: E402
from quadmanip.sim.world.objects import load_catalogue  # noqa: E402
from quadmanip.testbench.probe_accuracy import yaw_period  # noqa: E402
from quadmanip.testbench.probe_views import render_probe_view  # noqa: E402

pytestmark = pytest.mark.unit

POS_TOL = 0.015  # m
YAW_TOL = math.radians(15.0)
WIDTH_TOL = 0.015  # m
HANG_TOL = 0.01  # m

# (object, category): one per catalogue category, plus the bowl for the wall pinch
OBJECTS = [
    "brick",  # shape
    "sugar_box",  # food: vertical on the floor, horizontal (front camera) on a table
    "screwdriver",  # tool
    "spoon",  # orientation
    "toy_gun",  # task
    "mug",  # kitchen
    "bowl",  # kitchen: a flared wall, pinched with the tool tilted
]


@pytest.fixture(scope="module")
def cat():
    return load_catalogue()


def test_objects_cover_every_category(cat):
    assert {cat.objects[n].category for n in OBJECTS} == set(cat.categories)


@pytest.mark.parametrize("where", ["floor", "table"])
@pytest.mark.parametrize("name", OBJECTS)
def test_grasp_matches_ground_truth(cat, name, where):
    view = render_probe_view(name, where, 0, catalogue=cat)
    assert view.box is not None, "object not in view"
    est = estimate_grasp_from_depth(
        view.depth,
        view.box,
        view.K,
        view.cam_position,
        view.cam_orientation,
        name,
        cat,
        view.probing,
        where,
    )
    gt = view.gt
    assert est.ok, est.reason
    assert est.approach == gt.approach
    err = np.linalg.norm(est.position - gt.position_base)
    assert err < POS_TOL, f"grasp point {err * 1000:.1f} mm off"
    period = yaw_period(cat.objects[name]) if gt.approach == "vertical" else math.pi
    if period is not None:
        dyaw = abs((est.yaw - gt.yaw + period / 2) % period - period / 2)
        assert dyaw < YAW_TOL, f"yaw {math.degrees(dyaw):.1f} deg off"
    assert est.width == pytest.approx(gt.width, abs=WIDTH_TOL)
    assert est.hang == pytest.approx(gt.hang, abs=HANG_TOL)
    assert est.tilt == pytest.approx(gt.tilt, abs=0.1)  # 0 except the bowl's 0.64 rad
    assert est.mass == pytest.approx(cat.objects[name].mass)
    # the object's middle, which a place puts where it is asked (the spoon's grasp point,
    # at its bowl, is 6.5 cm from it): its footprint's middle, as the catalogue's origin
    middle = view.base_rotation.T @ (view.obj_position - view.base_position)
    off = np.linalg.norm(est.center[:2] - middle[:2])
    print(f"{name} {where}: middle {off * 1000:.1f} mm off, grasp point "
          f"{np.linalg.norm(est.position[:2] - middle[:2]) * 1000:.1f} mm from it")  # fmt: skip
    assert off < POS_TOL, f"the object's middle {off * 1000:.1f} mm off"


@pytest.mark.parametrize("turn_deg", [50.0, -70.0])
def test_a_cracker_box_turned_off_the_front_camera_is_refused_with_the_turn_to_its_end(
    cat, turn_deg
):
    # seed-120: the cracker box on the kitchen table, turned 68 deg off the view; seen so
    # its 16 cm face is wider than the fingers open, and a grasp at its near corner closes
    # on nothing (physics harness). Rendered: the refusal names the turn to its end face
    from quadmanip.common.reasons import parse_narrow_side

    view = render_probe_view("cracker_box", "table", 0, catalogue=cat, turn=math.radians(turn_deg))
    assert view.probing == "horizontal" and view.box is not None
    args = (view.depth, view.box, view.K, view.cam_position, view.cam_orientation)
    est = estimate_grasp_from_depth(*args, "cracker_box", cat, "horizontal", "table")
    assert not est.ok and est.reason == "long side turned off the view"
    turn = parse_narrow_side(est.detail)
    assert turn is not None and abs(math.degrees(turn) - turn_deg) < 5.0
    # seen along it (the task's next stance), it is grasped across its 6 cm
    view = render_probe_view("cracker_box", "table", 0, catalogue=cat, turn=math.radians(4.0))
    args = (view.depth, view.box, view.K, view.cam_position, view.cam_orientation)
    est = estimate_grasp_from_depth(*args, "cracker_box", cat, "horizontal", "table")
    assert est.ok and est.width == pytest.approx(0.06, abs=0.01)
