"""The manipulation service: arm and gripper primitives as Zenoh actions.

Actions (``manipulation/action/<name>``): ``move_to_posture`` (PostureGoal), ``grasp``
(GraspGoal, Algorithm 6), ``place`` (PlaceGoal), ``open_drawer`` (DrawerGoal). Each goal is
planned when it arrives - an unreachable or invalid goal is rejected with the planner's
reason before anything moves - then executed by a transport-free primitive that this node
steps at ``loop_period`` with the newest LowState. Commands go to the sim (or a hardware
adapter) as time-stamped ``ArmTrajectory`` (gravity-compensated servo targets, see
``gravity.py``) and ``GripperCommand``, and body moves to locomotion as
``BodyPoseCommand`` (Algorithm 6's moveCOM and crouch). Cancel stops the arm at once with a
one-knot hold trajectory at the measured joints. One goal runs at a time (others: "busy").

``approach = "auto"`` on a grasp picks vertical when the vertical grasp is reachable, else
horizontal. The held object's hang below the tool centre (needed to place it from above)
comes with the grasp goal (``GraspGoal.hang``, from perception's model of the object); when
the goal leaves it 0 it is measured at grasp time as the grasp point's height above the
floor for a vertical grasp below table height (the standing height comes from the
description), else taken as 5 cm.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common import robot_description as rd
from quadmanip.common.bus import ActionCanceled, ActionFailed, GoalHandle
from quadmanip.common.service import Input, Output, Service, run_service
from quadmanip.services.manipulation.arm_kinematics import ArmGeometry
from quadmanip.services.manipulation.config import ManipulationConfig
from quadmanip.services.manipulation.drawer import DrawerPrimitive, plan_drawer
from quadmanip.services.manipulation.grasp import GraspPrimitive, GraspRejected, plan_grasp
from quadmanip.services.manipulation.gravity import GravityCompensator
from quadmanip.services.manipulation.gripper import GraspMonitor, GripState
from quadmanip.services.manipulation.place import PlacePrimitive, plan_place
from quadmanip.services.manipulation.postures import resolve_postures
from quadmanip.services.manipulation.primitive import (
    ArmCommand,
    BodyPoseRequest,
    Command,
    GripperCmd,
    Observation,
    PostureMove,
    Primitive,
    Status,
)
from quadmanip.services.manipulation.trajectory import TrajectoryError

__all__ = ["ManipulationNode", "main"]

DEFAULT_HANG = 0.05
# A vertical grasp point lower than this above the floor is taken as a floor grasp (the
# house's tables are 40 cm high; the tallest object, the cracker box, is 21 cm).
FLOOR_GRASP_MAX_Z = 0.30
PAYLOAD_PERIOD_S = 1.0  # repeat the payload this often while holding
ARM = slice(12, 16)
ODOM_MAX_AGE = 0.5  # s: older odometry is not used for the body-drift correction


class ManipulationNode(Service):
    """Serves the manipulation actions; owns the arm joints and the gripper."""

    name = "manipulation"
    config_type = ManipulationConfig
    inputs = (
        Input("sim/lowstate", m.LowState, latest_only=True, doc="joint encoders, gripper"),
        Input("locomotion/odometry", m.Odometry, latest_only=True, doc="body drift while working"),
    )
    outputs = (
        Output("sim/arm_trajectory", m.ArmTrajectory, doc="time-stamped arm trajectory"),
        Output("sim/gripper_command", m.GripperCommand, doc="finger gap + force limit"),
        Output("locomotion/body_pose", m.BodyPoseCommand, doc="moveCOM / crouch requests"),
        Output("locomotion/payload", m.Payload, doc="mass held in the gripper"),
    )
    actions = ("move_to_posture", "grasp", "place", "open_drawer")
    loop_period = 0.005

    def setup(self) -> None:
        """Loads the description, postures and publishers; declares the action servers."""
        cfg: ManipulationConfig = self.config
        self.geom = ArmGeometry.from_description()
        self.postures = resolve_postures(self.geom, cfg)
        self.gravity = GravityCompensator()
        self.monitor = GraspMonitor(cfg.gripper)
        self.body = BodyPoseRequest()
        self.hang = DEFAULT_HANG
        self._grip_state = self.monitor.state
        self.floor_z = -float(rd.home_qpos()[2])  # floor height in the body frame, standing
        self.pub_arm = self.publisher("sim/arm_trajectory")
        self.pub_grip = self.publisher("sim/gripper_command")
        self.pub_body = self.publisher("locomotion/body_pose")
        self.pub_payload = self.publisher("locomotion/payload")
        self.payload = m.Payload(stamp=0.0)  # what locomotion is told the gripper holds
        self._grasp_payload = m.Payload(stamp=0.0)  # the current grasp goal's object
        self.state_cache = self.latest("sim/lowstate")
        self.odom_cache = self.latest("locomotion/odometry")
        self._lock = threading.Lock()
        self.active: Primitive | None = None
        self._cancel_req = False
        bus = self.bus
        bus.action_server(
            self.name, "move_to_posture", m.PostureGoal, self._exec, accept=self._accept
        )
        bus.action_server(self.name, "grasp", m.GraspGoal, self._exec, accept=self._accept)
        bus.action_server(self.name, "place", m.PlaceGoal, self._exec, accept=self._accept)
        bus.action_server(self.name, "open_drawer", m.DrawerGoal, self._exec, accept=self._accept)
        self.set_state("running")

    # ------------------------------------------------------------------ planning
    def _observation(self) -> Observation | None:
        st = self.state_cache.get()
        if st is None:
            return None
        j = st.joints
        base = None
        od = self.odom_cache.get()
        if od is not None and abs(float(od.stamp) - float(st.stamp)) < ODOM_MAX_AGE:
            w, x, y, z = (float(v) for v in od.orientation)
            yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            p = od.position
            base = (float(p[0]), float(p[1]), float(p[2]), yaw)
        return Observation(
            t=float(st.stamp),
            q_arm=np.asarray(j.q[ARM], dtype=float),
            dq_arm=np.asarray(j.dq[ARM], dtype=float),
            gripper_gap=float(j.gripper_gap),
            gripper_effort=float(j.gripper_effort),
            base=base,
        )

    def _make(self, goal: m.Message, obs: Observation) -> Primitive:
        """Plans a primitive for ``goal``; raises GraspRejected/ValueError with a reason."""
        cfg: ManipulationConfig = self.config
        kw = {"monitor": self.monitor, "body": self.body}
        if isinstance(goal, m.PostureGoal):
            if goal.posture not in self.postures:
                known = ", ".join(sorted(self.postures))
                raise GraspRejected("unknown_posture", f"{goal.posture!r} (known: {known})")
            held_across = cfg.postures[goal.posture].held_across
            return PostureMove(self.geom, cfg, self.postures[goal.posture], held_across, **kw)
        if isinstance(goal, m.GraspGoal):
            mass = float(goal.mass) if goal.mass > 0.0 else cfg.gripper.default_payload_mass
            self._grasp_payload = m.Payload(stamp=0.0, mass=mass, object_name=goal.object_name)
            pos = np.asarray(goal.position, dtype=float)
            approaches = ("vertical", "horizontal") if goal.approach == "auto" else (goal.approach,)
            err: GraspRejected | None = None
            for ap in approaches:
                try:
                    plan = plan_grasp(
                        self.geom, cfg, pos, ap, goal.yaw, goal.width, self.body, tilt=goal.tilt
                    )
                except GraspRejected as exc:
                    err = err or exc
                    continue
                return GraspPrimitive(self.geom, cfg, plan, **kw)
            assert err is not None
            raise err
        if isinstance(goal, m.PlaceGoal):
            if not self.monitor.holding:
                raise GraspRejected("not_holding", "the gripper holds nothing to place")
            yaw = float(goal.yaw) if goal.turn else None
            plan = plan_place(
                self.geom, cfg, goal.position, obs.q_arm, self.hang, self.body, yaw=yaw
            )
            return PlacePrimitive(self.geom, cfg, plan, **kw)
        if isinstance(goal, m.DrawerGoal):
            plan = plan_drawer(
                self.geom, cfg, goal.handle_position, goal.pull_direction, goal.distance, self.body
            )
            return DrawerPrimitive(self.geom, cfg, plan, **kw)
        raise GraspRejected("invalid_goal", f"unsupported goal {type(goal).__name__}")

    def _accept(self, goal: m.Message) -> tuple[bool, str]:
        obs = self._observation()
        if obs is None:
            return False, "no_joint_state: no LowState received yet"
        if self.active is not None and not self.active.done:
            return False, f"busy: {self.active.name} running"
        try:
            self._make(goal, obs)
        except (GraspRejected, TrajectoryError) as exc:
            return False, str(exc)
        return True, ""

    # ----------------------------------------------------------------- execution
    def _exec(self, handle: GoalHandle) -> m.Message | None:
        obs = self._observation()
        if obs is None:
            raise ActionFailed("no_joint_state")
        try:
            prim = self._make(handle.goal, obs)
        except (GraspRejected, TrajectoryError) as exc:
            raise ActionFailed(str(exc)) from exc
        with self._lock:
            self.active = prim
            self._cancel_req = False
        last_fb = ""
        while not prim.done:
            if handle.cancel_requested:
                with self._lock:
                    self._cancel_req = True
                while not prim.done:
                    time.sleep(0.005)
                raise ActionCanceled("canceled: arm holds its measured position")
            if prim.progress.text != last_fb:
                last_fb = prim.progress.text
                handle.feedback(float(prim.progress.value), last_fb)
            time.sleep(0.01)
        self.body = prim.body
        if isinstance(prim, GraspPrimitive) and prim.status is Status.SUCCEEDED:
            goal = handle.goal
            above_floor = float(goal.position[2]) - self.floor_z
            if goal.hang > 0.0:
                self.hang = float(goal.hang)
            elif prim.plan.approach == "vertical" and above_floor < FLOOR_GRASP_MAX_Z:
                self.hang = max(0.01, above_floor)
            else:
                self.hang = DEFAULT_HANG
        if prim.status is Status.SUCCEEDED:
            return None
        if prim.status is Status.CANCELED:
            raise ActionCanceled(prim.reason)
        raise ActionFailed(prim.reason or "failed")

    def _send(self, cmds: list[Command], stamp: float) -> None:
        cfg: ManipulationConfig = self.config
        for c in cmds:
            if isinstance(c, ArmCommand):
                q_cmd = self.gravity.offset_knots(c.traj, cfg.motion.kp)
                self.pub_arm.publish(
                    m.ArmTrajectory(
                        stamp=stamp,
                        t=c.traj.t,
                        q=q_cmd,
                        dq=c.traj.dq,
                        kp=np.asarray(cfg.motion.kp),
                        kd=np.asarray(cfg.motion.kd),
                    )
                )
            elif isinstance(c, GripperCmd):
                self.pub_grip.publish(
                    m.GripperCommand(stamp=stamp, gap=c.gap, max_force=c.max_force)
                )
            elif isinstance(c, BodyPoseRequest):
                self.pub_body.publish(
                    m.BodyPoseCommand(
                        stamp=stamp, x_offset=c.x_offset, y_offset=c.y_offset, z_offset=c.z_offset
                    )
                )

    def _announce_payload(self, t: float, payload: m.Payload) -> None:
        """Tell locomotion's balance model what the gripper holds (mass at the tool)."""
        self.payload = m.Payload(stamp=t, mass=payload.mass, object_name=payload.object_name)
        self.pub_payload.publish(self.payload)

    def step(self) -> None:
        """Feeds the newest joint state to the running primitive, sends its commands."""
        prim = self.active
        obs = self._observation()
        if obs is None:
            return
        if self.monitor.state is not self._grip_state:  # log every grip verdict once
            self._grip_state = self.monitor.state
            self.log.info(
                "grip",
                state=self._grip_state.value,
                gap=round(obs.gripper_gap, 4),
                effort=round(obs.gripper_effort, 2),
            )
            held = self._grip_state is GripState.HOLDING
            self._announce_payload(obs.t, self._grasp_payload if held else m.Payload(stamp=0.0))
        elif self.payload.mass > 0.0 and obs.t - self.payload.stamp >= PAYLOAD_PERIOD_S:
            self._announce_payload(obs.t, self.payload)  # for a locomotion started later
        if prim is None or prim.done:
            # keep watching the grip while carrying between actions (holding -> lost)
            self.monitor.update(obs.t, obs.gripper_gap, obs.gripper_effort)
            return
        with self._lock:
            cancel = self._cancel_req
        cmds = prim.cancel(obs) if cancel else prim.step(obs)
        self._send(cmds, obs.t)

    def teardown(self) -> None:
        """Holds the arm where it is when the service stops mid-motion."""
        prim = self.active
        obs = self._observation()
        if prim is not None and not prim.done and obs is not None:
            self._send(prim.cancel(obs), obs.t)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip service manipulation``."""
    return run_service(ManipulationNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())
