"""``quadmanip sim snapshot --scenario S --out DIR``: PNGs of a scenario's initial state.

Writes the robot's front and gripper cameras, an overview of the house and one view per
room, so a person can check the house, the objects and the robot at a glance. Rendering is
offscreen (set ``MUJOCO_GL=egl`` on a headless machine).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["main", "render_views"]


def render_views(
    scenario: str, out: Path, width: int = 640, height: int = 480, robot: bool = True
) -> list[Path]:
    """Render every snapshot view of ``scenario`` into ``out``; return the PNG paths."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import cv2
    import mujoco
    from quadmanip.common import robot_description as rd
    from quadmanip.sim.scenarios import get_scenario
    from quadmanip.sim.world import build_world

    world = build_world(get_scenario(scenario), robot=robot)
    data = world.initial_data()
    model = world.model
    views = list(world.cameras)
    if robot:
        views = [rd.FRONT_CAMERA, rd.GRIPPER_CAMERA, *views]
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    with mujoco.Renderer(model, height=height, width=width) as renderer:
        for cam in views:
            renderer.update_scene(data, camera=cam)
            rgb = renderer.render()
            path = out / f"{cam.replace('/', '_')}.png"
            if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                raise OSError(f"could not write {path}")
            paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (``quadmanip sim snapshot``)."""
    parser = argparse.ArgumentParser(prog="quadmanip sim snapshot", description=__doc__)
    parser.add_argument("--scenario", default="paper-1", help="paper-1..5 or a seed")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--no-robot", action="store_true", help="house and objects only")
    args = parser.parse_args(argv)
    if args.width > 1280 or args.height > 960 or args.width < 16 or args.height < 16:
        parser.error("size must be between 16x16 and 1280x960")
    paths = render_views(args.scenario, args.out, args.width, args.height, not args.no_robot)
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
