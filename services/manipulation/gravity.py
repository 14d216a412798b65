"""Static gravity torques of the arm, sent as feed-forward with every trajectory knot.

A pure PD servo sags by ``G(q) / kp`` under the arm's own weight: about 1 cm at the tool
with the arm stretched out, enough to push a light cup instead of pinching its rim. Like a
real arm's controller, the manipulation service therefore sends the static gravity torque
``G(q)`` of every planned knot as the knot's feed-forward torque (``ArmTrajectory.tau_ff``);
the actuator layer interpolates it along the trajectory and adds it to the PD torque, so the
servos hold the planned joints with no position error to make up for the weight.

``G`` is computed with pinocchio on the robot description, trunk level and body at rest.
The load in the gripper is not modelled (a 0.35 kg can adds ~2 mm of sag at the tool).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from quadmanip.common import robot_description as rd

__all__ = ["GravityCompensator"]


class GravityCompensator:
    """Static arm gravity torques from the robot description."""

    def __init__(self) -> None:
        self.model, self.data = rd.load_pinocchio_model()
        self._q = pin.neutral(self.model)
        arm = rd.ARM_JOINTS
        self._iq = [self.model.joints[self.model.getJointId(n)].idx_q for n in arm]
        self._iv = [self.model.joints[self.model.getJointId(n)].idx_v for n in arm]
        self._q[:] = rd.mujoco_qpos_to_pinocchio(rd.home_qpos())
        # trunk level at the origin: only its orientation matters for gravity
        self._q[:3] = 0.0
        self._q[3:7] = (0.0, 0.0, 0.0, 1.0)

    def torque(self, q_arm: Sequence[float]) -> np.ndarray:
        """Joint torques (N m) that hold the arm still at ``q_arm`` against gravity."""
        self._q[self._iq] = np.asarray(q_arm, dtype=float)
        g = pin.computeGeneralizedGravity(self.model, self.data, self._q)
        return np.asarray(g[self._iv], dtype=float)

    def feed_forward(self, q_knots: np.ndarray) -> np.ndarray:
        """Feed-forward torques ``G(q)`` for every knot of ``q_knots`` (N, 4) -> (N, 4)."""
        q = np.asarray(q_knots, dtype=float).reshape(-1, len(self._iq))
        return np.array([self.torque(row) for row in q]).reshape(q.shape)
