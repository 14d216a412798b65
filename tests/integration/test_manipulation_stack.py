"""Issue 5 acceptance over the real stack: sim, locomotion and manipulation as processes.

One stack (``quadmanip.testbench.stack.StackRun``: a private router, ``quadmanip service sim
--lockstep`` on a scenario file, ``quadmanip service locomotion``, ``quadmanip service
manipulation``) on scenario ``paper-2`` with the robot starting in the kitchen in front of
the cabinet. The test plays navigation (velocity commands from the ground-truth base
pose) and perception (grasp poses from ground-truth object poses, ``grasp_from_poses``);
the manipulation service does everything else through the sim's actuator layer (arm,
gripper) and locomotion's body-pose interface (moveCOM, crouch). Success is judged from
ground truth. In order, as the paper does (Section 7.2, drawers first):

1. open the top drawer >= 15 cm;
2. table grasp (tomato soup can on the kitchen table), lifted >= 10 cm;
3. carry it to the deposit table and place it into the tray (the judge says in place);
4. floor grasp (padlock), lifted >= 10 cm and held for 3 s.
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.common.rotations import quat_to_mat
from quadmanip.sim.scenarios import get_scenario
from quadmanip.sim.world.house import load_house
from quadmanip.sim.world.objects import load_catalogue
from quadmanip.testbench.manipulation_scenes import TABLE_HEIGHT, grasp_from_poses
from quadmanip.testbench.stack import ActionOutcome, StackRun

# Slow (``make test-all``, ~2 min): its steps run in the default suite elsewhere - drawers in
# test_manipulation_physics.py, table and floor grasps and the tray place in
# test_manipulation_acceptance.py and the tidy-up over the full stack (test_tidyup.py).
pytestmark = [pytest.mark.integration, pytest.mark.slow]

# in front of the top drawer: handle (9.46, 1.5) minus arm mount (0.06) minus 0.44 m
START = (8.96, 1.5, 0.0)


def must(out: ActionOutcome, what: str) -> ActionOutcome:
    assert out.ok, f"{what}: {out.status} {out.reason}"
    return out


class Stack(StackRun):
    """StackRun with a grasp from ground truth."""

    def grasp(self, name: str, surface_z: float) -> float:
        """Grasp ``name`` with a pose from ground truth; returns its resting height."""
        p, q = self.pose(name)
        bp, br, _ = self.base_frame()
        gs = grasp_from_poses(load_catalogue(), name, p, quat_to_mat(q), bp, br, surface_z)
        goal = m.GraspGoal(
            stamp=self.now(),
            position=gs.position_base,
            yaw=gs.yaw,
            approach=gs.approach,
            width=gs.width,
            object_name=name,
            mass=load_catalogue().objects[name].mass,
            hang=gs.hang,
        )
        must(self.act("grasp", goal), f"grasp {name}")
        return float(p[2])

    def mark(self, what: str) -> None:
        print(f"{what}: {self.elapsed()}")


def test_drawer_table_grasp_place_floor_grasp_over_the_stack(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "egl")
    scenario = dataclasses.replace(get_scenario("paper-2"), robot_start=START)
    with Stack(scenario, sys.stdout) as s:
        _run(s)


def _run(s: Stack) -> None:
    s.mark("stack up")

    # 1. the top drawer, >= 15 cm (paper: drawers first)
    h0, _ = s.pose("top", s.drawers)
    s.face(h0[:2], 0.0, 0.51, tol=0.012)  # square to the drawer, handle ~0.45 m ahead of the arm
    _, br, _ = s.base_frame()
    out = s.act(
        "open_drawer",
        m.DrawerGoal(
            stamp=s.now(),
            handle_position=s.to_base(h0),
            pull_direction=br.T @ np.array([-1.0, 0.0, 0.0]),
            distance=0.15,
        ),
    )
    must(out, "open_drawer")
    s.wait_sim(s.now() + 1.0)
    opened = float(h0[0] - s.pose("top", s.drawers)[0][0])
    s.mark(f"drawer opened {opened:.3f} m")
    assert opened >= 0.15, f"top drawer opened only {opened:.3f} m"

    # 2. table grasp: the tomato soup can, from the kitchen table's north side
    must(s.posture("stow"), "stow")
    can = "tomato_soup_can"
    cp, _ = s.pose(can)
    s.walk([(8.0, 2.6, math.pi)])  # round the table's north-east corner
    # the table edge 0.26 m ahead; tight: at 0.414 m the can is out of a vertical grasp's reach
    s.face(cp[:2], -math.pi / 2, 0.39, tol=0.012)
    z0 = s.grasp(can, TABLE_HEIGHT)
    lift = s.min_height(can, 1.0) - z0
    s.mark(f"table grasp {can}: lifted {lift:.3f} m")
    assert lift >= 0.10, f"{can} only {lift:.3f} m above the table"

    # 3. carry it to the tray on the deposit table and place it there
    must(s.posture("carry"), "carry")
    tray = next(c for c in load_house().containers if c.name == "tray")
    ix, iy = tray.size[1] / 2 - tray.wall, tray.size[0] / 2 - tray.wall  # robot faces +y
    s.face(tray.center, math.pi / 2, 0.55)
    target = np.array([tray.center[0], tray.center[1] - 0.6 * ix, TABLE_HEIGHT + tray.size[2]])
    # a task steps closer when the goal is out of reach (the walk stops within 3 cm)
    out, steps = s.place_within_reach(target)
    must(out, f"place after {steps} steps")
    assert s.in_place(can), f"the judge does not see {can} in the tray: {s.pose(can)[0]}"
    end, _ = s.pose(can)
    s.mark(f"placed {can} at {np.round(end, 3)}")
    assert abs(end[0] - tray.center[0]) < iy and abs(end[1] - tray.center[1]) < ix, end

    # 4. floor grasp: the padlock, lifted 10 cm and held for 3 s
    lock = "padlock"
    lp, _ = s.pose(lock)
    s.face(lp[:2], math.pi / 2, 0.36)
    z0 = s.grasp(lock, 0.0)
    lift = s.min_height(lock, 3.0) - z0
    s.mark(f"floor grasp {lock}: lifted {lift:.3f} m for 3 s")
    assert lift >= 0.10, f"{lock} only {lift:.3f} m above the floor"
