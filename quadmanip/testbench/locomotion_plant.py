"""In-process plant for locomotion tests and the benchmark (never used by the node).

It wraps the sim's own engine (`quadmanip.sim.engine.SimEngine`: 1 kHz physics, the actuator
layer, the IMU model, the test-only disturbance channel) around the robot on a flat floor
(`robot_description.robot_only_with_floor`), without Zenoh, so the controller can be
exercised quickly in lockstep. The controller sees only the LowState (encoders + IMU).
Ground truth (`true_*`) is for the test's judgement only.
"""

from __future__ import annotations

from types import SimpleNamespace

import mujoco
import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.sim.engine import PhysicsConfig, SimConfig, SimEngine


class SimPlant:
    """The sim engine with the robot alone on a floor, starting from a keyframe."""

    def __init__(
        self,
        key: str = rd.LYING_KEY,
        seed: int = 0,
        model: mujoco.MjModel | None = None,
        floor_friction: float = 1.0,
    ) -> None:
        if model is None:
            model = rd.robot_only_with_floor(floor_friction=floor_friction)
        data = mujoco.MjData(model)
        if key is not None:
            mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
        world = SimpleNamespace(model=model, data=data, object_names=[])
        # Island sleeping only matters for resting objects; the robot alone has none.
        cfg = SimConfig(seed=seed, allow_test_disturbance=True, physics=PhysicsConfig(sleep=False))
        self.engine = SimEngine(
            world, cfg, data=data, cameras=False, lidar=False, ground_truth=False
        )
        self.model, self.data = model, data
        self._base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "base")
        self._hold_cmd: msg.LegCommand | None = None
        self.lowstate = self.engine.low_state()

    @property
    def time(self) -> float:
        """Sim time since the start (s)."""
        return self.engine.time

    def step(self, out: object) -> msg.LowState:
        """Send the controller's leg command (answering the last tick) and advance a tick."""
        cmd = msg.LegCommand(
            stamp=self.lowstate.stamp,
            tick=self.lowstate.tick,
            q_des=out.q_des,  # type: ignore[attr-defined]
            dq_des=out.dq_des,  # type: ignore[attr-defined]
            kp=out.kp,  # type: ignore[attr-defined]
            kd=out.kd,  # type: ignore[attr-defined]
            tau_ff=out.tau_ff,  # type: ignore[attr-defined]
        )
        self.lowstate = self.engine.step_tick(cmd).lowstate
        return self.lowstate

    def push(self, force: np.ndarray, duration: float) -> None:
        """TEST-ONLY: a force on the base through the sim's disturbance channel."""
        d = msg.Disturbance(
            stamp=self.time, force=np.asarray(force, float), torque=np.zeros(3), duration=duration
        )
        if not self.engine.apply_disturbance(d):
            raise RuntimeError("disturbance refused")

    # Ground truth for the test's judgement only.
    def true_position(self) -> np.ndarray:
        """Base position (world)."""
        return self.data.qpos[0:3].copy()

    def true_velocity_body(self) -> np.ndarray:
        """Base linear velocity in the base frame and yaw rate: (vx, vy, wz)."""
        d = self.data
        rot = d.xmat[self._base].reshape(3, 3)
        v_b = rot.T @ d.qvel[0:3]
        w_w = rot @ d.qvel[3:6]  # free joint angular velocity is in the body frame
        return np.array([v_b[0], v_b[1], w_w[2]])

    def true_yaw(self) -> float:
        """Base yaw (world)."""
        return yaw_from_quat(self.data.qpos[3:7])

    def fallen(self) -> bool:
        """Trunk low or tipped over."""
        rot = self.data.xmat[self._base].reshape(3, 3)
        return bool(self.data.qpos[2] < 0.12 or rot[2, 2] < 0.5)


def controller_step(ctl: object, ls: msg.LowState) -> object:
    """Feed a LowState to a LocomotionController (what the node does per message)."""
    return ctl.step(  # type: ignore[attr-defined]
        ls.stamp,
        ls.joints.q,
        ls.joints.dq,
        ls.imu.orientation,
        ls.imu.angular_velocity,
        ls.imu.linear_acceleration,
    )
