"""Perception: object detection, per-object point clouds, grasp poses by the height-map
method, object memory and drawer handles (paper Section 4). Algorithms live in plain
modules; ``node.py`` wires them to Zenoh."""
