"""Gravity compensation of the arm through its position servos.

The arm is commanded with PD gains only (the ArmTrajectory message has no feed-forward
torque), so a pure PD servo sags by ``G(q) / kp`` under its own weight: about 1 cm at the
tool with the arm stretched out, enough to push a light cup instead of pinching its rim.
Like the position offset a real servo's integrator settles to, every knot is sent as
``q + G(q) / kp`` where ``G`` is the arm's static gravity torque computed with pinocchio on
the robot description (trunk level, body at rest); the steady state then sits on the
planned joints. The load in the gripper is not modelled (a 0.35 kg can adds ~2 mm).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from quadmanip.common import robot_description as rd
from quadmanip.services.manipulation.trajectory import JointTrajectory

__all__ = ["GravityCompensator"]

_ARM = ("arm_j1", "arm_j2", "arm_j3", "arm_j4")


class GravityCompensator:
    """Static arm gravity torques from the description, and the servo offsets they need."""

    def __init__(self) -> None:
        self.model, self.data = rd.load_pinocchio_model()
        self._q = pin.neutral(self.model)
        self._iq = [self.model.joints[self.model.getJointId(n)].idx_q for n in _ARM]
        self._iv = [self.model.joints[self.model.getJointId(n)].idx_v for n in _ARM]
        home = rd.home_qpos()
        q_pin = rd.mujoco_qpos_to_pinocchio(home)
        self._q[:] = q_pin
        # trunk level at the origin: only its orientation matters for gravity
        self._q[:3] = 0.0
        self._q[3:7] = (0.0, 0.0, 0.0, 1.0)

    def torque(self, q_arm: Sequence[float]) -> np.ndarray:
        """Joint torques (N m) that hold the arm still at ``q_arm`` against gravity."""
        self._q[self._iq] = np.asarray(q_arm, dtype=float)
        g = pin.computeGeneralizedGravity(self.model, self.data, self._q)
        return np.asarray(g[self._iv], dtype=float)

    def offset_knots(self, traj: JointTrajectory, kp: Sequence[float]) -> np.ndarray:
        """Commanded knot positions ``q + G(q)/kp`` for a PD servo with gains ``kp``."""
        kp_a = np.asarray(kp, dtype=float)
        out = traj.q.copy()
        for i, q in enumerate(traj.q):
            out[i] = q + self.torque(q) / np.maximum(kp_a, 1e-6)
        return out
