"""Manipulation service: 4-DOF arm kinematics, trajectories, gripper logic and grasp primitives."""
