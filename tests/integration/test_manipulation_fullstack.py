"""Full stack over Zenoh: sim, locomotion and manipulation processes; a floor grasp.

The test plays navigation and perception from ground truth (test code only): it walks the
robot (velocity commands to locomotion) until the nearest simple floor object of the
scenario lies ~36 cm ahead, then sends a GraspGoal computed from the object's true pose.
The manipulation service moves the arm through the sim's actuator layer and the body
through locomotion's body-pose interface (moveCOM / crouch). Success is judged from
ground truth: the object 10 cm above its resting height for 3 s.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from quadmanip.common import messages as m
from quadmanip.sim.world.objects import load_catalogue

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SIM_ARGS = (
    "-m", "quadmanip.cli", "service", "sim", "--lockstep", "--scenario", "paper-1",
    "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
    "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
)  # fmt: skip
LOCO_ARGS = ("-m", "quadmanip.cli", "service", "locomotion", "--set", "node.start_mode=stand")
MANIP_ARGS = ("-m", "quadmanip.cli", "service", "manipulation")
SIMPLE = ("box", "cylinder", "sphere")


def _yaw(q) -> float:
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def test_floor_grasp_through_the_whole_stack(zenoh_router, spawn, bus_factory):
    ep = zenoh_router
    procs = [
        spawn(*SIM_ARGS, endpoint=ep, env={"MUJOCO_GL": "egl"}),
        spawn(*LOCO_ARGS, endpoint=ep),
        spawn(*MANIP_ARGS, endpoint=ep),
    ]
    bus = bus_factory(ep)
    objs = bus.latest("sim/gt/objects", m.GroundTruthPoses)
    base = bus.latest("sim/gt/base", m.GroundTruthPoses)
    clock = bus.latest("sim/clock", m.Clock)
    vel = bus.publisher("locomotion/cmd_vel", m.BodyVelocityCommand)
    grasp = bus.action_client("manipulation", "grasp")
    cat = load_catalogue()

    def now() -> float:
        c = clock.get()
        return -1.0 if c is None else float(c.stamp)

    def logs() -> str:
        return "\n".join("\n".join(p.lines[-10:]) for p in procs)

    def wait_sim(t: float, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while now() < t:
            assert time.monotonic() < deadline, logs()
            time.sleep(0.02)

    def poses() -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for cache in (objs, base):
            msg = cache.get()
            assert msg is not None
            for n, p, q in zip(msg.names, msg.positions, msg.orientations, strict=True):
                out[n] = (np.asarray(p), np.asarray(q))
        return out

    wait_sim(3.0, 180.0)
    deadline = time.monotonic() + 60
    while "manipulation" not in bus.alive_services(0.5):
        assert time.monotonic() < deadline, logs()
    ps = poses()
    base_p, _ = ps["base"]
    # boxes (one side fits the fingers), small cylinders and balls
    cands = [
        n
        for n in ps
        if n != "base"
        and cat.objects[n].shape in SIMPLE
        and (cat.objects[n].shape == "box" or max(cat.objects[n].size[:2]) < 0.09)
    ]
    cands = [n for n in cands if ps[n][0][2] < 0.15]  # on the floor
    assert cands, "no simple floor object in the scenario"
    target = min(cands, key=lambda n: np.linalg.norm(ps[n][0][:2] - base_p[:2]))
    spec = cat.objects[target]

    # walk until the object is 0.36 m ahead, on the body axis (test plays navigation)
    t_end = now() + 90.0
    while True:
        ps = poses()
        bp, bq = ps["base"]
        yaw = _yaw(bq)
        d = ps[target][0][:2] - bp[:2]
        px = math.cos(yaw) * d[0] + math.sin(yaw) * d[1]
        py = -math.sin(yaw) * d[0] + math.cos(yaw) * d[1]
        if abs(px - 0.36) < 0.03 and abs(py) < 0.025:
            break
        assert now() < t_end, f"could not reach {target}: {px:.2f}, {py:.2f}\n{logs()}"
        far = math.hypot(px, py) > 0.8
        wz = float(np.clip(1.5 * math.atan2(py, px), -0.8, 0.8)) if far or abs(py) > 0.1 else 0.0
        vx = float(np.clip(0.8 * (px - 0.36), -0.3, 0.4))
        vy = 0.0 if far else float(np.clip(1.0 * py, -0.15, 0.15))
        vel.publish(m.BodyVelocityCommand(stamp=now(), vx=vx, vy=vy, wz=wz))
        time.sleep(0.05)
    for _ in range(20):
        vel.publish(m.BodyVelocityCommand(stamp=now(), vx=0.0, vy=0.0, wz=0.0))
        time.sleep(0.02)
    wait_sim(now() + 2.0)

    # grasp pose from ground truth (test plays perception)
    ps = poses()
    bp, bq = ps["base"]
    yaw_b = _yaw(bq)
    op, oq = ps[target]
    rot = np.array(
        [[math.cos(yaw_b), -math.sin(yaw_b), 0], [math.sin(yaw_b), math.cos(yaw_b), 0], [0, 0, 1]]
    )
    top = op[2] + spec.size[2] / 2
    pt = op.copy()
    pt[2] = max(0.021, top - 0.03)
    p_base = rot.T @ (pt - bp)
    p_base[2] = pt[2] - bp[2]
    oyaw = _yaw(oq) - yaw_b
    if spec.size[1] <= 0.085 and (spec.size[1] <= spec.size[0] or spec.size[0] > 0.085):
        gyaw, width = oyaw, spec.size[1]
    else:
        gyaw, width = oyaw + math.pi / 2, spec.size[0]
    z0 = op[2]
    goal = m.GraspGoal(
        stamp=now(), position=p_base, yaw=gyaw, approach="vertical", width=width, object_name=target
    )
    h = grasp.send_goal(goal, timeout=5.0)
    assert h.accepted, h.reason
    res = h.result(timeout=400.0)
    assert res is not None and res.status == "succeeded", f"{res}\n{logs()}"
    t = now()
    low = np.inf
    while now() < t + 3.0:
        low = min(low, poses()[target][0][2] - z0)
        time.sleep(0.05)
    print(f"grasped {target}: lift {low:.3f} m")
    assert low >= 0.10, f"{target} only {low:.3f} m above its start"
