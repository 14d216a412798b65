"""Self-righting trials in-process: stand, push over, damp, right, stand up again.

One trial (:func:`run_trial`) on the locomotion plant (:class:`SimPlant`, the sim engine
with the robot alone on a floor):

1. the locomotion controller stands the robot up from the lying keyframe and balances;
2. a lateral push through the sim's test-only disturbance channel topples it towards the
   asked side (force, direction, duration and roll torque drawn per trial from its seed);
3. the controller sees the fall on its IMU (tilt past ``FALL_TILT``) and goes limp
   (``damp``; a controller with a safety checker has latched its safe mode, limp too, a
   little earlier) until the robot is at rest (gyro quiet);
4. :func:`lying_side` reads the IMU; from a side, :class:`SelfRighting` drives the legs
   from the measured state until it is done (or gives up);
5. a fresh controller stands up (``stand``: 1.2 s joint-space stand-up, then the MPC).

Verdict from ground truth: the trial succeeds when, within ``STAND_DEADLINE`` s of sim
time from the start of the self-righting, the base is above ``STAND_HEIGHT`` with roll
and pitch under ``STAND_TILT`` while the controller balances, and still is ``HOLD`` s
later. Only the verdict reads ground truth; every decision uses encoders and the IMU.

Measured with the default pushes and ``RecoveryParams()`` (seeds 0-9 per side): 10/10
left, 10/10 right, standing 4.33 s (median) after the start of the self-righting.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.common.joint_layout import LEG_SLICE, N_LEG_JOINTS
from quadmanip.common.rotations import quat_to_mat, rpy_from_mat
from quadmanip.services.locomotion.controller import (
    LegOutput,
    LocomotionConfig,
    LocomotionController,
    load_locomotion_config,
)
from quadmanip.services.locomotion.self_righting import (
    RecoveryParams,
    SelfRighting,
    gravity_in_base,
    lying_side,
    tilt_angle,
)
from quadmanip.testbench.locomotion_plant import SimPlant, controller_step

__all__ = [
    "PushSpec",
    "draw_push",
    "push_disturbance",
    "run_trial",
    "run_trials",
    "summarize",
    "toppling_push",
]

STAND_TIME = 2.0  # s of standing before the push (stand-up 1.2 s + balance)
FALL_TILT = 0.7  # rad (40 deg): the controller calls this a fall and goes limp
REST_GYRO = 0.05  # rad/s: at rest below this ...
REST_TIME = 0.3  # ... for this long (s)
REST_MIN = 1.0  # s of damping at least after the fall
REST_MAX = 3.0  # s of damping at most
NO_FALL_WAIT = 2.0  # s after the push without a fall: the push did not topple it
STAND_DEADLINE = 10.0  # s from the start of the self-righting (the acceptance)
STAND_HEIGHT = 0.25  # m
STAND_TILT = math.radians(10.0)
HOLD = 1.0  # s it must keep standing


@dataclass(frozen=True)
class PushSpec:
    """A push on the base: lateral force (N) for a duration (s) and a roll torque (N m).

    ``side`` is where it topples the robot: "left" pushes towards the base's +y.
    ``heading`` turns the force in the floor plane from the base's lateral axis (rad).
    """

    side: str
    force: float
    duration: float
    heading: float = 0.0
    roll_torque: float = 0.0


# Pushes that topple the standing robot onto a side: a lateral force at the trunk's centre
# for a quarter second, with a small roll torque the same way, drawn uniformly from these
# ranges (an impulse of 34-43 N s). Measured: 32 of 32 draws came to rest on the asked
# side, rolled 113-132 deg (leaning back on the arm). Below ~32 N s the robot often stays
# propped on its legs at 45 deg; above ~45 N s it tumbles over its back onto the other side.
PUSH_FORCE = (140.0, 160.0)  # N
PUSH_DURATION = (0.24, 0.27)  # s
PUSH_HEADING = (-0.1, 0.1)  # rad (+-6 deg) from the base's lateral axis
PUSH_ROLL_TORQUE = (2.0, 6.0)  # N m


def draw_push(side: str, rng: np.random.Generator) -> PushSpec:
    """A push that topples the robot towards ``side``, drawn from the validated ranges."""
    return PushSpec(
        side=side,
        force=float(rng.uniform(*PUSH_FORCE)),
        duration=float(rng.uniform(*PUSH_DURATION)),
        heading=float(rng.uniform(*PUSH_HEADING)),
        roll_torque=float(rng.uniform(*PUSH_ROLL_TORQUE)),
    )


def push_disturbance(push: PushSpec, yaw: float = 0.0, stamp: float = 0.0) -> msg.Disturbance:
    """``push`` as the sim's disturbance message (world frame) for a base heading ``yaw``."""
    s = 1.0 if push.side == "left" else -1.0
    lateral = yaw + s * math.pi / 2.0 + push.heading
    force = push.force * np.array([math.cos(lateral), math.sin(lateral), 0.0])
    # Toppling to the left is a rotation about the base's -x axis.
    axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    torque = -s * push.roll_torque * axis
    return msg.Disturbance(
        stamp=stamp, force=force, torque=torque, duration=push.duration, body="base"
    )


def toppling_push(
    side: str, rng: np.random.Generator, yaw: float = 0.0, stamp: float = 0.0
) -> msg.Disturbance:
    """A push drawn like :func:`draw_push` that topples a robot heading ``yaw`` onto
    ``side``, as the disturbance message to send (over the bus or to the engine)."""
    return push_disturbance(draw_push(side, rng), yaw, stamp)


def _apply_push(plant: SimPlant, push: PushSpec) -> None:
    """Send the push through the disturbance channel, in the base's current heading."""
    # The test aims its push with the true heading; the robot never sees it.
    d = push_disturbance(push, plant.true_yaw(), plant.time)
    if not plant.engine.apply_disturbance(d):
        raise RuntimeError("disturbance refused")


def _standing(plant: SimPlant) -> bool:
    """Ground truth: base high enough with small roll and pitch."""
    rpy = rpy_from_mat(quat_to_mat(plant.data.qpos[3:7]))
    return bool(
        plant.data.qpos[2] > STAND_HEIGHT and abs(rpy[0]) < STAND_TILT and abs(rpy[1]) < STAND_TILT
    )


def run_trial(
    side: str,
    seed: int,
    params: RecoveryParams | None = None,
    push: PushSpec | None = None,
    observer: Any = None,
    config: LocomotionConfig | None = None,
    floor_friction: float = 1.0,
) -> dict[str, Any]:
    """One trial (module doc); ``push`` defaults to one drawn from ``seed``.

    ``params`` default to ``RecoveryParams()``, ``config`` (the locomotion controller's)
    to configs/locomotion.toml; ``seed`` also seeds the IMU noise.
    ``observer(plant, stage)`` is called every tick, if given (films, debugging).
    Returns a dict: ``success``, ``outcome`` ("stood"; "no_fall": the push left it
    standing; "back": it lies on its back, the sequence is not started; "righting_failed";
    "not_standing": righted but not standing in time), the push, ``fell_to`` (what
    ``lying_side`` measured at rest: "left", "right" or "upright", which goes straight to
    the stand-up) and ``rest_roll_deg`` (signed: negative rolled onto the left),
    ``t_righted`` and ``t_standing`` (s from the start of the self-righting), ``attempts``,
    ``reason`` (SelfRighting's when it failed) and ``wall_s``.
    """
    wall0 = time.perf_counter()
    params = params or RecoveryParams()
    config = config or load_locomotion_config()
    rng = np.random.default_rng([seed, 0 if side == "left" else 1])
    push = push or draw_push(side, rng)
    plant = SimPlant(seed=seed, floor_friction=floor_friction)
    ctl = LocomotionController(config)
    q_lying = rd.lying_joint_positions(plant.model)[LEG_SLICE]
    result: dict[str, Any] = {
        "side": side,
        "seed": seed,
        "push_force": push.force,
        "push_duration": push.duration,
        "push_heading": push.heading,
        "push_roll_torque": push.roll_torque,
        "floor_friction": floor_friction,
        "success": False,
        "outcome": "",
        "fell_to": "",
        "rest_roll_deg": math.nan,
        "t_righted": math.nan,
        "t_standing": math.nan,
        "attempts": 0,
        "reason": "",
    }

    def tick(out: object, stage: str) -> msg.LowState:
        ls = plant.step(out)
        if observer is not None:
            observer(plant, stage)
        return ls

    # 1. Stand.
    ls = plant.lowstate
    ctl.set_mode("stand")
    while plant.time < STAND_TIME:
        ls = tick(controller_step(ctl, ls), "stand")
    # 2-3. Push; damp on the fall; wait for rest.
    _apply_push(plant, push)
    t_push = plant.time
    t_fall = math.nan
    t_quiet = plant.time
    while True:
        out = controller_step(ctl, ls)
        ls = tick(out, "fall")
        g = gravity_in_base(ls.imu.orientation)
        if math.isnan(t_fall):
            if tilt_angle(g) > FALL_TILT:
                ctl.set_mode("damp")
                t_fall = plant.time
            elif plant.time - t_push > NO_FALL_WAIT:
                result["outcome"] = "no_fall"
                break
            continue
        if np.linalg.norm(ls.imu.angular_velocity) > REST_GYRO:
            t_quiet = plant.time
        rested = plant.time - t_quiet >= REST_TIME and plant.time - t_fall >= REST_MIN
        if rested or plant.time - t_fall >= REST_MAX:
            break
    if result["outcome"]:
        result["wall_s"] = time.perf_counter() - wall0
        return result
    # 4. Self-righting from the measured state.
    g = gravity_in_base(ls.imu.orientation)
    lay = lying_side(g, params)
    result["fell_to"] = lay
    result["rest_roll_deg"] = math.degrees(math.atan2(g[1], g[2]))
    if lay == "back":
        result["outcome"] = "back"  # needs help: the controller reports it
        result["wall_s"] = time.perf_counter() - wall0
        return result
    t0 = plant.time
    if lay in ("left", "right"):
        sr = SelfRighting(params, lay, ls.joints.q[LEG_SLICE], q_lying)
        zero = np.zeros(N_LEG_JOINTS)
        while not (sr.done or sr.failed) and plant.time - t0 < STAND_DEADLINE:
            q_des, dq_des, kp, kd = sr.command(
                plant.time - t0,
                ls.joints.q[LEG_SLICE],
                ls.joints.dq[LEG_SLICE],
                gravity_in_base(ls.imu.orientation),
            )
            ls = tick(LegOutput(q_des, dq_des, kp, kd, zero), "righting")
        result["attempts"] = sr.attempts
        if not sr.done:
            result["outcome"] = "righting_failed"
            result["reason"] = sr.reason or "deadline"
            result["wall_s"] = time.perf_counter() - wall0
            return result
        result["t_righted"] = plant.time - t0
    # 5. Stand up with a fresh locomotion controller (the one that fell has latched its
    # fall); one limp tick first gives it the measured state and the time.
    ctl = LocomotionController(config)
    ls = tick(controller_step(ctl, ls), "stand_up")
    ctl.set_mode("stand")
    t_stand = math.nan
    while plant.time - t0 < STAND_DEADLINE + HOLD:
        ls = tick(controller_step(ctl, ls), "stand_up")
        if ctl.phase != "balance":
            continue
        if math.isnan(t_stand):
            if _standing(plant):
                if plant.time - t0 > STAND_DEADLINE:
                    break
                t_stand = plant.time
        elif not _standing(plant):
            t_stand = math.nan  # fell again: not standing
            break
        elif plant.time - t_stand >= HOLD:
            break
    if not math.isnan(t_stand) and plant.time - t_stand >= HOLD - 1e-9:
        result["success"] = True
        result["outcome"] = "stood"
        result["t_standing"] = t_stand - t0
    else:
        result["outcome"] = "not_standing"
    result["wall_s"] = time.perf_counter() - wall0
    return result


def run_trials(
    side: str,
    n: int,
    seed0: int = 0,
    params: RecoveryParams | None = None,
    config: LocomotionConfig | None = None,
) -> list[dict[str, Any]]:
    """``n`` trials toppling towards ``side``, seeds ``seed0 .. seed0 + n - 1``."""
    config = config or load_locomotion_config()
    return [run_trial(side, seed0 + k, params, config=config) for k in range(n)]


def summarize(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Success count and median time to standing of a list of trial results."""
    ok = [r for r in results if r["success"]]
    times = [r["t_standing"] for r in ok]
    return {
        "trials": len(results),
        "success": len(ok),
        "median_t_standing": float(np.median(times)) if times else math.nan,
        "max_t_standing": float(np.max(times)) if times else math.nan,
        "outcomes": sorted({r["outcome"] for r in results}),
    }


if __name__ == "__main__":  # python -m quadmanip.testbench.self_righting_trials [n]
    import json
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    for s in ("left", "right"):
        res = run_trials(s, n)
        for r in res:
            print(
                json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()})
            )
        print(s, json.dumps(summarize(res)), flush=True)
