"""The robot's joint layout: joint names, their wire order, counts and slices.

One definition for everyone: the messages (array shapes), the actuator layer, the
controllers and the tools. Names are those of the robot description
(`configs/robot/quadmanip_dog.xml`; :mod:`quadmanip.common.robot_description` re-exports
them and resolves them in the model, and a unit test checks that the MJCF has exactly these
joints and actuators in this order). Plain Python, no MuJoCo: importing it is free.

Wire order of a joint array of :data:`N_JOINTS` (``JointState.q``): the legs FL, FR, RL,
RR, each (abad, hip, knee), then the arm ``arm_j1..arm_j4``. Leg arrays
(``LegCommand``) hold the first :data:`N_LEG_JOINTS`, arm arrays (``ArmTrajectory``) the
last :data:`N_ARM_JOINTS`. Actuators (:data:`ACTUATORS`): those joints, then the gripper.
"""

from __future__ import annotations

__all__ = [
    "ACTUATORS",
    "ARM_JOINTS",
    "ARM_SLICE",
    "GRIPPER_ACTUATOR",
    "JOINTS",
    "JOINTS_PER_LEG",
    "LEG_JOINTS",
    "LEG_JOINT_KINDS",
    "LEG_NAMES",
    "LEG_SLICE",
    "N_ARM_JOINTS",
    "N_JOINTS",
    "N_LEGS",
    "N_LEG_JOINTS",
    "leg_slice",
]

LEG_NAMES: tuple[str, ...] = ("FL", "FR", "RL", "RR")
"""Legs in wire order: front left, front right, rear left, rear right."""
LEG_JOINT_KINDS: tuple[str, ...] = ("abad", "hip", "knee")
"""Joints of one leg, from the trunk outwards."""
LEG_JOINTS: tuple[str, ...] = tuple(f"{leg}_{k}" for leg in LEG_NAMES for k in LEG_JOINT_KINDS)
"""The 12 leg joints in wire order."""
ARM_JOINTS: tuple[str, ...] = ("arm_j1", "arm_j2", "arm_j3", "arm_j4")
"""The 4 arm joints in wire order (shoulder, elbow, wrist pitch, wrist roll)."""
JOINTS: tuple[str, ...] = LEG_JOINTS + ARM_JOINTS
"""The 16 actuated revolute joints in the fixed wire order."""
GRIPPER_ACTUATOR = "gripper"
ACTUATORS: tuple[str, ...] = JOINTS + (GRIPPER_ACTUATOR,)
"""Actuator names (motors named like their joints) in actuator-index order."""

N_LEGS = len(LEG_NAMES)
JOINTS_PER_LEG = len(LEG_JOINT_KINDS)
N_LEG_JOINTS = len(LEG_JOINTS)
N_ARM_JOINTS = len(ARM_JOINTS)
N_JOINTS = len(JOINTS)

LEG_SLICE = slice(0, N_LEG_JOINTS)
"""The legs in a wire-order joint array (``q[LEG_SLICE]``)."""
ARM_SLICE = slice(N_LEG_JOINTS, N_JOINTS)
"""The arm in a wire-order joint array (``q[ARM_SLICE]``)."""


def leg_slice(leg: int) -> slice:
    """The joints of leg number ``leg`` (0..3, :data:`LEG_NAMES` order) in a leg array."""
    if not 0 <= leg < N_LEGS:
        raise IndexError(f"leg {leg} not in 0..{N_LEGS - 1}")
    return slice(JOINTS_PER_LEG * leg, JOINTS_PER_LEG * (leg + 1))
