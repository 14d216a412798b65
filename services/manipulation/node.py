"""The manipulation service: arm and gripper primitives as Zenoh actions.

Actions (``manipulation/action/<name>``): ``move_to_posture`` (PostureGoal), ``grasp``
(GraspGoal, Algorithm 6), ``place`` (PlaceGoal), ``open_drawer`` (DrawerGoal). This node
only wires them: it converts goal messages into the executive's requests and the
executive's outputs into messages. Goal arbitration (one goal at a time across the four
actions; others are rejected ``busy: ...``), planning (once, at accept: an unreachable or
invalid goal is rejected with the planner's reason before anything moves) and policy (grasp
approach, the held object's hang) live in :mod:`.executive`.

Every ``loop_period`` the newest LowState (and odometry, for the body-drift correction) is
handed to the executive, whose outputs go to the sim (or a hardware adapter) as
time-stamped ``ArmTrajectory`` with the arm's gravity torque as per-knot feed-forward
(see ``gravity.py``) and ``GripperCommand``; to locomotion as ``BodyPoseCommand``
(Algorithm 6's moveCOM and crouch) and ``Payload`` (the mass in the gripper). Cancel stops
the arm at once with a one-knot hold trajectory at the measured joints.
"""

from __future__ import annotations

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.actions import ActionCanceled, ActionFailed, GoalHandle
from quadmanip.common.joint_layout import ARM_SLICE
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.manipulation.config import ManipulationConfig
from quadmanip.services.manipulation.executive import (
    ArmServo,
    DrawerRequest,
    Executive,
    GraspRequest,
    PayloadUpdate,
    PlaceRequest,
    PostureRequest,
    Request,
)
from quadmanip.services.manipulation.executive import (
    Output as ExecOutput,
)
from quadmanip.services.manipulation.primitive import (
    BodyPoseRequest,
    GripperCmd,
    Observation,
    Status,
)

__all__ = ["ManipulationNode", "main", "to_request"]


def _xyz(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def to_request(goal: m.Message) -> Request | None:
    """The executive's request for a goal message (None for another message type)."""
    if isinstance(goal, m.PostureGoal):
        return PostureRequest(goal.posture)
    if isinstance(goal, m.GraspGoal):
        return GraspRequest(
            position=_xyz(goal.position),
            yaw=float(goal.yaw),
            approach=goal.approach,
            width=float(goal.width),
            object_name=goal.object_name,
            tilt=float(goal.tilt),
            mass=float(goal.mass),
            hang=float(goal.hang),
            center=_xyz(goal.center) if len(goal.center) == 3 else None,
        )
    if isinstance(goal, m.PlaceGoal):
        return PlaceRequest(_xyz(goal.position), float(goal.yaw) if goal.turn else None)
    if isinstance(goal, m.DrawerGoal):
        return DrawerRequest(
            _xyz(goal.handle_position), _xyz(goal.pull_direction), float(goal.distance)
        )
    return None


class ManipulationNode(Service):
    """Serves the manipulation actions; owns the arm joints and the gripper."""

    name = "manipulation"
    config_type = ManipulationConfig
    inputs = (
        Input("sim/lowstate", latest_only=True, doc="joint encoders, gripper"),
        Input("locomotion/odometry", latest_only=True, doc="body drift while working"),
        Input("locomotion/health", latest_only=True, doc="tripped: stop and hold the arm"),
    )
    outputs = (
        Output("sim/arm_trajectory", doc="time-stamped arm trajectory + gravity feed-forward"),
        Output("sim/gripper_command", doc="finger gap + force limit"),
        Output("locomotion/body_pose", doc="moveCOM / crouch requests"),
        Output("locomotion/payload", doc="mass held in the gripper"),
    )
    actions = ("move_to_posture", "grasp", "place", "open_drawer")
    loop_period = 0.005

    def setup(self) -> None:
        """Builds the executive and the publishers; serves the four actions."""
        self.executive = Executive.from_description(self.config)
        self.pub_arm = self.publisher("sim/arm_trajectory")
        self.pub_grip = self.publisher("sim/gripper_command")
        self.pub_body = self.publisher("locomotion/body_pose")
        self.pub_payload = self.publisher("locomotion/payload")
        self.state_cache = self.latest("sim/lowstate")
        self.odom_cache = self.latest("locomotion/odometry")
        self.health_cache = self.latest("locomotion/health")
        for action in self.actions:
            # the executive arbitrates across the four actions: no per-server "busy"
            self.action_server(action, self._execute, accept=self._accept, policy="parallel")
        self.set_state("running")

    # ------------------------------------------------------------------ messages in
    def _observation(self) -> Observation | None:
        st = self.state_cache.get()
        if st is None:
            return None
        j = st.joints
        base = None
        od = self.odom_cache.get()
        max_age = self.config.executive.odom_max_age
        if od is not None and abs(float(od.stamp) - float(st.stamp)) < max_age:
            base = (*_xyz(od.position), yaw_from_quat(od.orientation))
        return Observation(
            t=float(st.stamp),
            q_arm=np.asarray(j.q[ARM_SLICE], dtype=float),
            dq_arm=np.asarray(j.dq[ARM_SLICE], dtype=float),
            gripper_gap=float(j.gripper_gap),
            gripper_effort=float(j.gripper_effort),
            base=base,
        )

    def _robot_down(self) -> str:
        """Why the arm must not move now ("" when it may): locomotion tripped (fallen,
        overloaded) or is righting itself. The arm then holds where it is."""
        h = self.health_cache.get()
        if h is not None and h.state == "tripped":
            return f"robot_down: locomotion tripped ({h.reason})"
        return ""

    def _accept(self, goal: m.Message) -> tuple[bool, str]:
        down = self._robot_down()
        if down:
            return False, down
        request = to_request(goal)
        if request is None:
            return False, f"invalid_goal: unsupported goal {type(goal).__name__}"
        verdict = self.executive.accept(request, self._observation(), token=goal)
        return verdict.accepted, verdict.reason

    def _execute(self, handle: GoalHandle) -> m.Message | None:
        down: list[str] = []

        def stop_now() -> bool:
            if not down and (why := self._robot_down()):
                down.append(why)
                self.log.warning("stopping the action: the robot is down", reason=why)
            return handle.cancel_requested or bool(down)

        outcome = self.executive.execute(handle.goal, cancel_requested=stop_now,
                                         feedback=handle.feedback)  # fmt: skip
        if outcome.plan:
            self.log.info("planned", goal=type(handle.goal).__name__, plan=outcome.plan)
        # what the goal left in the fingers goes out before its result (the loop thread
        # sends it too, but may do so just after this thread answers)
        held = self.executive.payload
        obs = self._observation()
        stamp = obs.t if obs is not None else 0.0
        self.pub_payload.publish(
            m.Payload(stamp=stamp, mass=held.mass, object_name=held.object_name)
        )
        if outcome.status is Status.SUCCEEDED:
            return None
        if outcome.status is Status.CANCELED:
            if down and not handle.cancel_requested:
                raise ActionFailed(down[0])
            raise ActionCanceled(outcome.reason)
        raise ActionFailed(outcome.reason or "failed")

    # ----------------------------------------------------------------- messages out
    def _send(self, outputs: list[ExecOutput], stamp: float) -> None:
        for c in outputs:
            if isinstance(c, ArmServo):
                self.pub_arm.publish(
                    m.ArmTrajectory(
                        stamp=stamp, t=c.t, q=c.q, dq=c.dq, kp=c.kp, kd=c.kd, tau_ff=c.tau_ff
                    )
                )
            elif isinstance(c, GripperCmd):
                self.pub_grip.publish(
                    m.GripperCommand(stamp=stamp, gap=c.gap, max_force=c.max_force)
                )
            elif isinstance(c, BodyPoseRequest):
                self.pub_body.publish(
                    m.BodyPoseCommand(
                        stamp=stamp,
                        x_offset=c.x_offset,
                        y_offset=c.y_offset,
                        z_offset=c.z_offset,
                        pitch=c.pitch,
                    )
                )
            elif isinstance(c, PayloadUpdate):
                if c.grip is not None:  # log every grip verdict once
                    self.log.info("grip", state=c.grip.value, gap=round(c.gap, 4),
                                  effort=round(c.effort, 2),
                                  inferred=self.executive.monitor.inferred)  # fmt: skip
                self.pub_payload.publish(
                    m.Payload(stamp=stamp, mass=c.mass, object_name=c.object_name)
                )

    # ----------------------------------------------------------------- loop
    def step(self) -> None:
        """Feeds the newest joint state to the executive and sends what it answers."""
        obs = self._observation()
        if obs is not None:
            self._send(self.executive.step(obs), obs.t)

    def teardown(self) -> None:
        """Holds the arm where it is when the service stops mid-motion."""
        executive = getattr(self, "executive", None)
        if executive is None:  # setup did not get that far
            return
        obs = self._observation()
        out = executive.stop(obs)
        if obs is not None:
            self._send(out, obs.t)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service manipulation``."""
    return run_service(ManipulationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
