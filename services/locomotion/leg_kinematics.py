"""Leg kinematics and whole-body inertia from the robot description, with pinocchio.

Loads the MJCF (the single source of truth, `pin.buildModelFromMJCF`) and, for the measured
joint angles, gives per leg the foot position and the 3×3 foot Jacobian in the base frame,
and the composite rigid-body inertia of the whole robot — trunk, legs, arm in its current
pose and an optional held object at the gripper — that the convex MPC uses.

The base is placed at the identity, so every quantity is in the base frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from quadmanip.common import robot_description as rd
from quadmanip.common.robot_description import (
    ARM_JOINTS,
    ARM_SLICE,
    FOOT_SITES,
    JOINTS_PER_LEG,
    LEG_JOINTS,
    LEG_SLICE,
    N_JOINTS,
    N_LEG_JOINTS,
)


@dataclass
class BodyInertia:
    """Whole-robot mass (kg), COM (base frame, m) and inertia about the COM (base frame)."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray


def default_mjcf() -> Path:
    """Path of the robot description MJCF."""
    return Path(rd.ROBOT_XML)


class LegKinematics:
    """Foot kinematics and composite inertia for the 16 measured joints (see module doc)."""

    def __init__(self, mjcf: str | Path | None = None, tcp_frame: str = "gripper_tcp") -> None:
        path = Path(mjcf) if mjcf is not None else default_mjcf()
        self.model = pin.buildModelFromMJCF(str(path))
        self.data = self.model.createData()
        m = self.model
        if m.joints[1].shortname() != "JointModelFreeFlyer":
            raise ValueError("robot description must have a free-floating base")
        self._leg_q = np.array([m.idx_qs[m.getJointId(n)] for n in LEG_JOINTS])
        self._leg_v = np.array([m.idx_vs[m.getJointId(n)] for n in LEG_JOINTS])
        self._arm_q = np.array([m.idx_qs[m.getJointId(n)] for n in ARM_JOINTS])
        missing = [n for n in LEG_JOINTS + ARM_JOINTS if not m.existJointName(n)]
        if missing:
            raise ValueError(f"joints missing from the description: {missing}")
        self._foot_ids = [m.getFrameId(n) for n in FOOT_SITES]
        self._tcp_id = m.getFrameId(tcp_frame) if m.existFrame(tcp_frame) else None
        self.q = pin.neutral(m)
        self.foot_pos = np.zeros((4, 3))
        self.foot_jac = np.zeros((4, 3, 3))
        self.foot_jac_ang = np.zeros((4, 3, 3))  # calf angular velocity per joint rate
        self.hip_pos = self._hip_positions()
        self.update(np.zeros(N_JOINTS))
        self.straight_leg_feet = self.foot_pos.copy()  # feet of straight legs (neutral pose)

    def _hip_positions(self) -> np.ndarray:
        """Abduction joint origins in the base frame (at the neutral pose)."""
        pin.forwardKinematics(self.model, self.data, pin.neutral(self.model))
        ids = [self.model.getJointId(n) for n in LEG_JOINTS[::JOINTS_PER_LEG]]  # abad joints
        return np.array([self.data.oMi[i].translation.copy() for i in ids])

    def update(self, q16: np.ndarray) -> None:
        """Forward kinematics and foot Jacobians for joint angles q16 (legs then arm)."""
        q16 = np.asarray(q16, dtype=float)
        self.q[self._leg_q] = q16[LEG_SLICE]
        self.q[self._arm_q] = q16[ARM_SLICE]
        m, d = self.model, self.data
        pin.computeJointJacobians(m, d, self.q)
        pin.updateFramePlacements(m, d)
        for i, fid in enumerate(self._foot_ids):
            self.foot_pos[i] = d.oMf[fid].translation
            jac = pin.getFrameJacobian(m, d, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            self.foot_jac[i] = jac[:3, self._leg_v[3 * i : 3 * i + 3]]
            self.foot_jac_ang[i] = jac[3:, self._leg_v[3 * i : 3 * i + 3]]

    def rolling_velocities(
        self, dq12: np.ndarray, omega_body: np.ndarray, up_body: np.ndarray, radius: float
    ) -> np.ndarray:
        """Velocity of each foot sphere's centre (base frame) when it rolls without slipping.

        A round foot in stance does not keep its centre still: the centre moves by
        ω_calf × (radius · up) as the calf turns over the contact point (≈ 7 % of the walking
        speed for a 2 cm foot at a 0.3 m stance height if ignored).
        """
        dq = np.asarray(dq12, dtype=float).reshape(4, 3)
        w_calf = np.asarray(omega_body)[None, :] + np.einsum("fij,fj->fi", self.foot_jac_ang, dq)
        return np.cross(w_calf, radius * np.asarray(up_body)[None, :])

    def foot_velocities(self, dq12: np.ndarray) -> np.ndarray:
        """J q̇ per foot (4, 3), base frame (relative to the base)."""
        dq = np.asarray(dq12, dtype=float).reshape(4, 3)
        return np.einsum("fij,fj->fi", self.foot_jac, dq)

    def leg_torques(self, forces_base: np.ndarray) -> np.ndarray:
        """Joint torques (12,) that make each foot push with the given force on the robot.

        A force f that the ground exerts on the robot at the foot is balanced by the leg's
        motors when τ = −Jᵀ f (virtual work: the ground's force maps to Jᵀ f on the joints).
        """
        f = np.asarray(forces_base, dtype=float).reshape(4, 3)
        return -np.einsum("fji,fj->fi", self.foot_jac, f).reshape(N_LEG_JOINTS)

    def cartesian_torques(self, forces_on_foot: np.ndarray) -> np.ndarray:
        """τ = Jᵀ F for a force F to apply *to the foot* (swing-leg Cartesian PD)."""
        f = np.asarray(forces_on_foot, dtype=float).reshape(4, 3)
        return np.einsum("fji,fj->fi", self.foot_jac, f).reshape(N_LEG_JOINTS)

    def body_inertia(self, held_mass: float = 0.0) -> BodyInertia:
        """Composite inertia of the whole robot in the current pose (call update() first).

        Uses pinocchio's composite rigid-body algorithm: the root subtree's spatial inertia
        is the whole robot's. A held object is a point mass at the gripper's TCP.
        """
        m, d = self.model, self.data
        pin.crba(m, d, self.q)
        total = pin.Inertia(d.Ycrb[1])
        if held_mass > 0.0 and self._tcp_id is not None:
            pos = d.oMf[self._tcp_id].translation
            total = total + pin.Inertia(held_mass, pos, np.zeros((3, 3)))
        return BodyInertia(
            mass=float(total.mass), com=np.array(total.lever), inertia=np.array(total.inertia)
        )
