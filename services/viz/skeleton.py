"""A stick figure of the robot from measured joint angles (forward kinematics, no transport).

The viz draws the robot as line segments between body origins of the robot description
(the same MJCF every controller loads), computed by MuJoCo's forward kinematics with the
base at the origin: the result is in the ``base`` frame and hangs under
``world/odom/base`` in the recording. Cheap (one ``mj_kinematics`` on a ~25-body model, a
few microseconds) and a single Rerun log per frame.
"""

from __future__ import annotations

import mujoco
import numpy as np
from quadmanip.common import robot_description as rd

__all__ = ["RobotSkeleton", "SkeletonPose"]


class SkeletonPose:
    """Segments (N×2×3), foot centres (4×3) and the gripper TCP (3,), base frame."""

    def __init__(self, segments: np.ndarray, feet: np.ndarray, tcp: np.ndarray) -> None:
        self.segments = segments
        self.feet = feet
        self.tcp = tcp


class RobotSkeleton:
    """Forward kinematics of the robot description for drawing."""

    def __init__(self, model: mujoco.MjModel | None = None) -> None:
        self.model = rd.load_mujoco_model() if model is None else model
        self.data = mujoco.MjData(self.model)
        md = self.model
        self._qadr = rd.joint_qpos_indices(md, rd.JOINTS)
        self._grip = rd.joint_qpos_indices(md, rd.GRIPPER_JOINTS)
        self._grip_max = float(md.jnt_range[md.joint(rd.GRIPPER_JOINTS[0]).id][1])
        free = rd.free_joint_qpos_index(md)
        self.data.qpos[free : free + 7] = [0, 0, 0, 1, 0, 0, 0]  # base = origin: base frame
        base = md.body(rd.BASE_BODY).id
        # Bodies below the base, each drawn from its parent's origin to its own.
        self._bodies = np.array(
            [b for b in range(md.nbody) if b != base and self._descends(b, base)], dtype=int
        )
        self._parents = md.body_parentid[self._bodies]
        self._foot_sites = np.array([md.site(s).id for s in rd.FOOT_SITES], dtype=int)
        self._calves = np.array([md.body(b).id for b in rd.CALF_BODIES], dtype=int)
        self._fingers = np.array([md.body(b).id for b in rd.FINGER_BODIES], dtype=int)
        self._pads = np.array([md.geom(g).id for g in rd.FINGER_PAD_GEOMS], dtype=int)
        self._tcp = md.site(rd.GRIPPER_TCP_SITE).id
        self._tcp_body = md.site_bodyid[self._tcp]
        trunk = md.geom(rd.TRUNK_GEOM)
        self.trunk_half_size = md.geom_size[trunk.id].copy()
        self.trunk_center = md.geom_pos[trunk.id].copy()

    def _descends(self, body: int, ancestor: int) -> bool:
        while body != 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return False

    def pose(self, q: np.ndarray, gripper_gap: float = 0.0) -> SkeletonPose:
        """Stick figure for joint angles ``q`` (16, wire order) and finger gap (m)."""
        d = self.data
        d.qpos[self._qadr] = q
        # The gap is the sum of the two finger slides (the description's gap tendon).
        d.qpos[self._grip] = np.clip(0.5 * gripper_gap, 0.0, self._grip_max)
        mujoco.mj_kinematics(self.model, d)
        xpos = d.xpos
        segs = [np.stack([xpos[self._parents], xpos[self._bodies]], axis=1)]
        feet = d.site_xpos[self._foot_sites].copy()
        segs.append(np.stack([xpos[self._calves], feet], axis=1))
        segs.append(np.stack([xpos[self._fingers], d.geom_xpos[self._pads]], axis=1))
        tcp = d.site_xpos[self._tcp].copy()
        segs.append(np.stack([xpos[self._tcp_body], tcp])[None])
        segments = np.concatenate(segs, axis=0)
        # Zero-length segments (bodies sharing an origin) add nothing to the drawing.
        keep = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) > 1e-6
        return SkeletonPose(segments[keep], feet, tcp)
