"""TEST SCAFFOLDING ONLY: the sim service with the robot starting elsewhere in the house.

``python -m quadmanip.services.manipulation.stack_sim --robot-start X Y YAW_DEG [sim args]``
runs ``quadmanip service sim`` unchanged except for two test needs of the full-stack
manipulation tests (``tests/integration/test_manipulation_stack.py``):

* the robot's start pose (an initial condition, like the scenario's object poses: the house
  config's ``robot_start`` replaced before the world is built; nothing moves it afterwards),
  so a test can begin in the kitchen beside the cabinet instead of walking 9 m there;
* ground truth of the drawers: the world poses of the drawer handles on
  ``sim/gt/drawers`` (a ``GroundTruthPoses``, names ``left``/``right``/``top``), at the
  ground-truth pose rate. The sim itself publishes only the base and the objects; the test
  (playing perception) needs the handle and the judge-side opening distance.

Services never subscribe to ``sim/gt/**``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any

import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common.service import Output, run_service
from quadmanip.sim import node as sim_node
from quadmanip.sim.engine import TickOutput

__all__ = ["StackSimNode", "main"]


class StackSimNode(sim_node.SimNode):
    """``SimNode`` with ``--robot-start`` and drawer ground truth (see module doc)."""

    outputs = (*sim_node.SimNode.outputs, Output("sim/gt/drawers", msg.GroundTruthPoses, kind="gt"))

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        super().add_arguments(parser)
        parser.add_argument(
            "--robot-start",
            nargs=3,
            type=float,
            metavar=("X", "Y", "YAW_DEG"),
            help="robot start in the house (m, m, deg); default: the house config's",
        )

    def __init__(self, bus: Any, config: Any, args: argparse.Namespace | None = None) -> None:
        super().__init__(bus, config, args)
        self.robot_start = getattr(args, "robot_start", None) if args else None
        self._drawer_ids: list[tuple[str, int]] = []

    def _load_world(self, scenario: str) -> Any:
        from quadmanip.sim.scenarios import get_scenario
        from quadmanip.sim.world import build_world
        from quadmanip.sim.world.house import load_house

        house = load_house()
        if self.robot_start is not None:
            x, y, yaw = self.robot_start
            start = dataclasses.replace(house.robot_start, position=(x, y), yaw=yaw)
            house = dataclasses.replace(house, robot_start=start)
        return build_world(get_scenario(scenario), house=house)

    def setup(self) -> None:
        """The sim's setup with the world built by :meth:`_load_world`."""
        orig = sim_node.load_world
        sim_node.load_world = self._load_world
        try:
            super().setup()
        finally:
            sim_node.load_world = orig
        assert self.engine is not None
        world = self.engine.world
        model = world.model
        self._drawer_ids = [(k, model.body(b).id) for k, b in world.drawer_handles.items()]

    def _publish(self, out: TickOutput) -> None:
        super()._publish(out)
        if out.gt_poses is None or not self._drawer_ids:
            return
        assert self.engine is not None
        d = self.engine.data
        ids = [i for _, i in self._drawer_ids]
        self.pub["sim/gt/drawers"].publish(
            msg.GroundTruthPoses(
                stamp=out.gt_poses.stamp,
                names=[k for k, _ in self._drawer_ids],
                positions=np.asarray(d.xpos[ids], dtype=float),
                orientations=np.asarray(d.xquat[ids], dtype=float),
            )
        )


def main(argv: list[str] | None = None) -> int:
    """Runs the sim service with the test extensions."""
    return run_service(StackSimNode, list(sys.argv[1:] if argv is None else argv))


if __name__ == "__main__":
    raise SystemExit(main())
