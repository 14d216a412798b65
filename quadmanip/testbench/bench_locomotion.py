"""``quadmanip bench locomotion --json FILE [--plot PNG] [--quick]``: how well and how fast it walks.

Three parts, all on this machine:

1. **MPC timing**: 1500 MPC problems recorded from a real trot (so the contact schedules and
   states are realistic) are solved again with each PIQP backend; p50/p99 of the solver
   alone and of the whole MPC step (matrix construction + solve). The whole-step numbers
   inside the controller come from the same runs.
2. **Tracking in-process** (the sim's engine as the plant, no transport), for the `tuned`
   and the `paper` profile: the scripted command sequence of issue 4 (forward 0.5 m/s,
   backward 0.3, lateral ±0.3, yaw ±1.0 rad/s and a combination), each 3 s with 1 s of
   settling, RMSE of the true base velocity; falls. A PNG plot of commanded vs true
   velocity and the MPC's vertical foot forces is written for the tuned run.
3. **Over Zenoh** (router + `sim --lockstep` + `locomotion` processes): the same command
   sequence steered by this process, then a 30 N / 0.2 s lateral push while trotting in
   place; velocity RMSE from ground truth, odometry drift per distance walked, push
   recovery, leg-command loop period and jitter (wall clock, as seen on the bus), and the
   achieved real-time factor (sim time over wall time).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common.rotations import yaw_from_quat
from quadmanip.services.locomotion.controller import LocomotionController, load_locomotion_config
from quadmanip.services.locomotion.convex_mpc import ConvexMpc
from quadmanip.testbench.unitree_sim_robot import SMALL_MACHINE_RTF

SEQUENCE: list[tuple[float, float, float]] = [
    (0.5, 0.0, 0.0),
    (-0.3, 0.0, 0.0),
    (0.0, 0.3, 0.0),
    (0.0, -0.3, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
    (0.3, 0.2, 0.5),
]
SEGMENT_S = 3.0
SETTLE_S = 1.0


def _say(text: str) -> None:
    print(f"[bench locomotion] {text}", flush=True)


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


# --------------------------------------------------------------------------- in-process
def run_in_process(profile: str, record: bool = False, segment_s: float = SEGMENT_S) -> dict:
    """Stand up, then the command sequence; returns RMSEs, falls, MPC timings, traces."""
    from quadmanip.testbench.locomotion_plant import SimPlant, controller_step

    ctl = LocomotionController(load_locomotion_config(profile=profile))
    plant = SimPlant()
    ls = plant.lowstate
    ctl.set_mode("stand")
    falls = 0
    fallen = False
    problems: list[tuple] = []
    mpc_step: list[float] = []
    mpc_cpu: list[float] = []
    solver: list[float] = []
    tick_ms: list[float] = []
    trace: list[list[float]] = []
    seg_err: list[list[np.ndarray]] = [[] for _ in SEQUENCE]
    orig_solve = ctl.mpc.solve

    def recording_solve(*args: Any) -> Any:
        sol = orig_solve(*args)
        if record and len(problems) < 1500:
            problems.append(tuple(np.copy(a) if isinstance(a, np.ndarray) else a for a in args))
        return sol

    ctl.mpc.solve = recording_solve  # type: ignore[method-assign]
    t_walk = 2.5
    t_end = t_walk + len(SEQUENCE) * (segment_s + 0.5)
    last_mpc = 0
    wall0 = time.perf_counter()
    while plant.time < t_end:
        t = ls.stamp
        cmd = np.zeros(3)
        seg = -1
        if t >= t_walk:
            k = int((t - t_walk) // (segment_s + 0.5))
            into = (t - t_walk) - k * (segment_s + 0.5)
            if k < len(SEQUENCE) and into < segment_s:
                seg, cmd = k, np.asarray(SEQUENCE[k], dtype=float)
                # a fall latches the safety checker's safe mode (legs damped): the rest of
                # the sequence counts as tracking error, as it would on the robot
                if round(t / 0.002) % 10 == 0 and ctl.phase != "safe":
                    ctl.set_velocity(*cmd, now=t)
                if into >= SETTLE_S:
                    seg_err[k].append(plant.true_velocity_body() - cmd)
        c0 = time.perf_counter()
        out = controller_step(ctl, ls)
        tick_ms.append((time.perf_counter() - c0) * 1e3)
        if ctl.mpc_tick != last_mpc:
            last_mpc = ctl.mpc_tick
            mpc_step.append(ctl.debug.mpc_step_s * 1e3)
            mpc_cpu.append(ctl.debug.mpc_step_cpu_s * 1e3)
            solver.append(ctl.debug.mpc_solver_s * 1e3)
        ls = plant.step(out)
        if ctl.phase in ("balance", "walk", "stopping"):
            now_fallen = plant.fallen()
            if now_fallen and not fallen:
                falls += 1
            fallen = now_fallen
        if record and ls.tick % 5 == 0:
            tv = plant.true_velocity_body()
            trace.append([t, *cmd, *tv, *ctl.debug.foot_forces[:, 2], float(seg)])
    wall = time.perf_counter() - wall0
    if ctl.trip_reason and not fallen:
        falls += 1  # the safety checker damped the legs before the body hit the ground
    segs = []
    all_err = np.concatenate([np.array(e) for e in seg_err if e])
    for v, e in zip(SEQUENCE, seg_err, strict=True):
        e = np.array(e)
        segs.append(
            {
                "command": list(v),
                "vel_rmse_mps": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
                "yaw_rate_rmse_radps": float(np.sqrt(np.mean(e[:, 2] ** 2))),
            }
        )
    return {
        "profile": profile,
        "vel_rmse_mps": float(np.sqrt(np.mean(np.sum(all_err[:, :2] ** 2, axis=1)))),
        "yaw_rate_rmse_radps": float(np.sqrt(np.mean(all_err[:, 2] ** 2))),
        "worst_segment_vel_rmse_mps": max(s["vel_rmse_mps"] for s in segs),
        "worst_segment_yaw_rmse_radps": max(s["yaw_rate_rmse_radps"] for s in segs),
        "segments": segs,
        "falls": falls,
        "safe_mode_reason": ctl.trip_reason,  # "" unless the safety checker latched
        "in_process_rtf": plant.time / wall,
        "controller_tick_ms_p50": _pct(tick_ms, 50),
        "controller_tick_ms_p99": _pct(tick_ms, 99),
        "mpc_step_ms_p50": _pct(mpc_step, 50),
        "mpc_step_ms_p99": _pct(mpc_step, 99),
        "mpc_step_cpu_ms_p50": _pct(mpc_cpu, 50),
        "mpc_step_cpu_ms_p99": _pct(mpc_cpu, 99),
        "solver_ms_p50": _pct(solver, 50),
        "solver_ms_p99": _pct(solver, 99),
        "_problems": problems,
        "_trace": trace,
    }


def bench_backends(problems: list[tuple]) -> dict[str, Any]:
    """Re-solve recorded MPC problems with the dense and the sparse PIQP backend."""
    cfg = load_locomotion_config()
    weights = cfg.profiles[cfg.profile].weights
    out: dict[str, Any] = {}
    for backend in ("dense", "sparse"):
        mpc = ConvexMpc(replace(cfg.mpc, weights=weights, backend=backend))
        step, solve, cpu = [], [], []
        for args in problems:
            c0 = time.thread_time()
            sol = mpc.solve(*args)
            cpu.append((time.thread_time() - c0) * 1e3)
            step.append(sol.step_time_s * 1e3)
            solve.append(sol.solver_time_s * 1e3)
        out[backend] = {
            "mpc_step_ms_p50": _pct(step, 50),
            "mpc_step_ms_p99": _pct(step, 99),
            "solver_ms_p50": _pct(solve, 50),
            "solver_ms_p99": _pct(solve, 99),
            # CPU time of this thread: what the step costs without other processes' load.
            "mpc_step_cpu_ms_p50": _pct(cpu, 50),
            "mpc_step_cpu_ms_p99": _pct(cpu, 99),
            "n": len(problems),
        }
    return out


# --------------------------------------------------------------------------- plot (OpenCV)
def write_plot(trace: list[list[float]], path: Path) -> None:
    """Commanded vs true vx, vy, ωz and the MPC's vertical foot forces, as a PNG."""
    import cv2

    a = np.asarray(trace)
    t = a[:, 0]
    w, h_row, margin = 1400, 220, 70
    rows = [
        ("vx (m/s)", a[:, 1], a[:, 4], (-0.6, 0.7)),
        ("vy (m/s)", a[:, 2], a[:, 5], (-0.5, 0.5)),
        ("wz (rad/s)", a[:, 3], a[:, 6], (-1.4, 1.4)),
        ("foot fz (N)", None, a[:, 7:11], (0.0, 160.0)),
    ]
    img = np.full((h_row * len(rows) + 40, w, 3), 255, np.uint8)
    x_of = lambda tt: (margin + (tt - t[0]) / (t[-1] - t[0]) * (w - margin - 20)).astype(np.int32)  # noqa: E731
    colors = [(200, 60, 0), (0, 140, 0), (0, 0, 220), (160, 0, 160)]
    for r, (label, cmd, true, (lo, hi)) in enumerate(rows):
        top = 20 + r * h_row
        bot = top + h_row - 30

        def y_of(v: np.ndarray, top: int = top, bot: int = bot, lo: float = lo, hi: float = hi):
            return (bot - (np.clip(v, lo, hi) - lo) / (hi - lo) * (bot - top)).astype(np.int32)

        cv2.rectangle(img, (margin, top), (w - 20, bot), (180, 180, 180), 1)
        cv2.putText(img, label, (5, top + 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
        for val in (lo, 0.0, hi):
            yy = int(y_of(np.array([val]))[0])
            cv2.putText(
                img, f"{val:g}", (5, yy + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (90, 90, 90), 1
            )
            cv2.line(img, (margin, yy), (w - 20, yy), (225, 225, 225), 1)
        xs = x_of(t)
        if cmd is not None:
            pts = np.stack([xs, y_of(cmd)], axis=1)
            cv2.polylines(img, [pts], False, (0, 0, 0), 2)
            pts = np.stack([xs, y_of(true)], axis=1)
            cv2.polylines(img, [pts], False, (0, 90, 255), 1)
        else:
            for i in range(4):
                pts = np.stack([xs, y_of(true[:, i])], axis=1)
                cv2.polylines(img, [pts], False, colors[i], 1)
    legend = "black: commanded, orange: true (ground truth); forces: FL blue, FR green, RL red, RR purple"
    cv2.putText(img, legend, (margin, h_row * len(rows) + 30), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (0, 0, 0), 1)  # fmt: skip
    cv2.imwrite(str(path), img)


# --------------------------------------------------------------------------- over Zenoh
def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_zenoh(segment_s: float = SEGMENT_S) -> dict[str, Any]:
    """Router + sim (lockstep) + locomotion processes; this process commands and judges."""
    from quadmanip.common import messages as m
    from quadmanip.common.bus import Bus, BusConfig

    ep = f"tcp/127.0.0.1:{_free_port()}"
    env = {**os.environ, "QM_ZENOH_CONNECT": ep, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    logs = tempfile.TemporaryDirectory(prefix="qm-bench-loco-")
    procs: list[subprocess.Popen] = []

    def start(name: str, *args: str) -> None:
        fh = open(os.path.join(logs.name, f"{name}.log"), "w")  # noqa: SIM115
        procs.append(
            subprocess.Popen([sys.executable, *args], env=env, stdout=fh, stderr=subprocess.STDOUT)
        )

    def tail(name: str) -> str:
        with open(os.path.join(logs.name, f"{name}.log")) as fh:
            return fh.read()[-1500:]

    gt: list[tuple[float, np.ndarray, float]] = []
    leg_wall: list[float] = []
    clock_wall: list[tuple[float, float]] = []
    lock = threading.Lock()
    try:
        start("router", "-m", "quadmanip.common.router", "--listen", ep)
        time.sleep(1.0)
        start(
            "sim", "-m", "quadmanip.cli", "service", "sim", "--lockstep", "--scenario", "paper-1",
            "--set", "allow_test_disturbance=true", "--set", "sensors.front_camera.rate=0",
            "--set", "sensors.gripper_camera.rate=0", "--set", "sensors.lidar.rate=0",
            "--set", "ground_truth.contacts_rate=0",
        )  # fmt: skip
        start("locomotion", "-m", "quadmanip.cli", "service", "locomotion")
        cfg = BusConfig(mode="peer", connect=(ep,), listen=("tcp/127.0.0.1:0",), env_override=False)
        with Bus(cfg) as bus:

            def on_gt(msg: m.GroundTruthPoses) -> None:
                with lock:
                    gt.append(
                        (msg.stamp, np.array(msg.positions[0]), yaw_from_quat(msg.orientations[0]))
                    )

            def on_leg(_msg: m.LegCommand) -> None:
                with lock:
                    leg_wall.append(time.perf_counter())

            def on_clock(msg: m.Clock) -> None:
                with lock:
                    clock_wall.append((time.perf_counter(), msg.stamp))

            bus.subscribe("sim/gt/base", on_gt)
            bus.subscribe("sim/leg_command", on_leg)
            bus.subscribe("sim/clock", on_clock)
            odom = bus.latest("locomotion/odometry")
            pub_mode = bus.publisher("locomotion/mode")
            pub_vel = bus.publisher("locomotion/cmd_vel")
            pub_push = bus.publisher("sim/test/disturbance")

            def now() -> float:
                with lock:
                    return clock_wall[-1][1] if clock_wall else -1.0

            def wait_until(t: float, every: Any = None, timeout: float = 300.0) -> None:
                deadline = time.monotonic() + timeout
                while now() < t:
                    if time.monotonic() > deadline:
                        raise TimeoutError(
                            f"sim stuck at {now():.2f}\n{tail('sim')}\n{tail('locomotion')}"
                        )
                    if every is not None:
                        every()
                    time.sleep(0.02)

            deadline = time.monotonic() + 90
            while odom.get() is None:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no odometry\n{tail('sim')}\n{tail('locomotion')}")
                pub_mode.publish(m.LocomotionMode(stamp=max(now(), 0.0), mode="stand"))
                time.sleep(0.2)
            wait_until(now() + 1.0)
            with lock:
                p_start = gt[-1][1].copy()
            odo_start = odom.get().position.copy()  # type: ignore[union-attr]
            w_walk0 = time.perf_counter()
            s_walk0 = now()
            segs = []
            for v in SEQUENCE_ZENOH:
                t0 = now()
                wait_until(
                    t0 + segment_s,
                    every=lambda v=v: pub_vel.publish(
                        m.BodyVelocityCommand(stamp=now(), vx=v[0], vy=v[1], wz=v[2])
                    ),
                )
                with lock:
                    samples = [g for g in gt if t0 + SETTLE_S <= g[0] <= t0 + segment_s]
                segs.append((v, _body_velocity_errors(samples, v)))
                wait_until(now() + 0.7)
            w_walk1 = time.perf_counter()
            s_walk1 = now()
            with lock:
                p_end = gt[-1][1].copy()
                path = [g[1] for g in gt if s_walk0 <= g[0] <= s_walk1]
            odo_end = odom.get().position.copy()  # type: ignore[union-attr]
            walked = float(
                sum(np.linalg.norm(b[:2] - a[:2]) for a, b in zip(path, path[1:], strict=False))
            )
            drift = float(np.linalg.norm((odo_end - odo_start)[:2] - (p_end - p_start)[:2]))
            # Push while trotting in place.
            pub_mode.publish(m.LocomotionMode(stamp=now(), mode="walk"))
            wait_until(now() + 1.5)
            t_push = now()
            pub_push.publish(
                m.Disturbance(
                    stamp=t_push, force=np.array([0.0, 30.0, 0.0]), torque=np.zeros(3), duration=0.2
                )  # fmt: skip
            )
            wait_until(t_push + 3.0)
            with lock:
                after = [g for g in gt if t_push + 2.5 <= g[0] <= t_push + 3.0]
                during = [g for g in gt if t_push <= g[0] <= t_push + 3.0]
                legs = np.diff(np.asarray(leg_wall[-3000:])) * 1e3
            fell = any(g[1][2] < 0.15 for g in during) or any(
                g[1][2] < 0.15 for g in gt if g[0] >= s_walk0
            )
            v_after = np.abs(_body_velocity_errors(after, (0.0, 0.0, 0.0))[:, :2]).mean()
            recovered = (not fell) and bool(v_after < 0.1)
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs[::-1]:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        logs.cleanup()
    return {
        **_sequence_rmse(segs),
        "walked_m": walked,
        "odom_drift_m": drift,
        "odom_drift_pct": 100.0 * drift / max(walked, 1e-9),
        "push_recovered": recovered,
        "falls": int(fell),
        "rtf": (s_walk1 - s_walk0) / (w_walk1 - w_walk0),
        "leg_cmd_period_ms_p50": _pct(list(legs), 50),
        "leg_cmd_period_ms_p99": _pct(list(legs), 99),
        "leg_cmd_jitter_ms_std": float(np.std(legs)),
    }


def run_adapter(
    segment_s: float = SEGMENT_S,
    robot_rtf: float = SMALL_MACHINE_RTF,
    locomotion_args: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Router + the simulated Unitree robot (DDS) + the adapter + locomotion processes;
    this process commands and judges from the robot's ground truth (docs/hardware.md).

    The simulated robot runs free in real time (at ``robot_rtf``, the real-time factor
    this machine can hold for the three processes), so there is no push and no lockstep.
    Ground-truth samples are windowed by the robot time at which they arrive here and
    differentiated with their own stamps (the physics clock)."""
    import random

    from quadmanip.common import messages as m
    from quadmanip.common.bus import Bus, BusConfig

    ep = f"tcp/127.0.0.1:{_free_port()}"
    domain = str(random.randint(100, 200))  # a private DDS domain for this run
    env = {**os.environ, "QM_ZENOH_CONNECT": ep, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    logs = tempfile.TemporaryDirectory(prefix="qm-bench-loco-hw-")
    procs: list[subprocess.Popen] = []

    def start(name: str, *args: str) -> None:
        fh = open(os.path.join(logs.name, f"{name}.log"), "w")  # noqa: SIM115
        procs.append(
            subprocess.Popen([sys.executable, *args], env=env, stdout=fh, stderr=subprocess.STDOUT)
        )

    def tail(name: str) -> str:
        with open(os.path.join(logs.name, f"{name}.log")) as fh:
            return fh.read()[-1500:]

    gt: list[tuple[float, float, np.ndarray, float]] = []  # (arrival, stamp, pos, yaw)
    clock: list[float] = []
    status: list[Any] = []
    health: list[Any] = []
    lock = threading.Lock()
    try:
        start("router", "-m", "quadmanip.common.router", "--listen", ep)
        time.sleep(1.0)
        start(
            "robot", "-m", "quadmanip.cli", "service", "unitree-sim-robot", "--domain", domain,
            "--scenario", "paper-1", "--realtime-factor", str(robot_rtf),
        )  # fmt: skip
        start("adapter", "-m", "quadmanip.cli", "service", "unitree-adapter", "--domain", domain)
        start("locomotion", "-m", "quadmanip.cli", "service", "locomotion", *locomotion_args)
        cfg = BusConfig(mode="peer", connect=(ep,), listen=("tcp/127.0.0.1:0",), env_override=False)
        with Bus(cfg) as bus:

            def now() -> float:
                with lock:
                    return clock[-1] if clock else -1.0

            def on_gt(msg: m.GroundTruthPoses) -> None:
                arrival = now()
                with lock:
                    gt.append(
                        (arrival, msg.stamp, np.array(msg.positions[0]),
                         yaw_from_quat(msg.orientations[0]))
                    )  # fmt: skip

            def on_clock(msg: m.Clock) -> None:
                with lock:
                    clock.append(msg.stamp)

            bus.subscribe("sim/gt/base", on_gt)
            bus.subscribe("sim/clock", on_clock)
            bus.subscribe("sim/status", status.append)
            bus.subscribe("locomotion/health", health.append)
            odom = bus.latest("locomotion/odometry")
            pub_mode = bus.publisher("locomotion/mode")
            pub_vel = bus.publisher("locomotion/cmd_vel")

            def wait_until(t: float, every: Any = None, timeout: float = 300.0) -> None:
                deadline = time.monotonic() + timeout
                while now() < t:
                    if time.monotonic() > deadline:
                        raise TimeoutError(
                            f"robot clock stuck at {now():.2f}\n{tail('robot')}\n"
                            f"{tail('adapter')}\n{tail('locomotion')}"
                        )
                    if every is not None:
                        every()
                    time.sleep(0.02)

            deadline = time.monotonic() + 120
            while odom.get() is None or now() < 0:
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"no odometry\n{tail('robot')}\n{tail('adapter')}\n{tail('locomotion')}"
                    )
                pub_mode.publish(m.LocomotionMode(stamp=max(now(), 0.0), mode="stand"))
                time.sleep(0.2)
            wait_until(now() + 2.0)
            w_walk0, s_walk0 = time.perf_counter(), now()
            segs = []
            for v in SEQUENCE_ZENOH:
                t0 = now()
                wait_until(
                    t0 + segment_s,
                    every=lambda v=v: pub_vel.publish(
                        m.BodyVelocityCommand(stamp=now(), vx=v[0], vy=v[1], wz=v[2])
                    ),
                )
                with lock:
                    samples = [
                        (g[1], g[2], g[3]) for g in gt if t0 + SETTLE_S <= g[0] <= t0 + segment_s
                    ]
                segs.append((v, _body_velocity_errors(samples, v)))
                wait_until(now() + 0.7)
            w_walk1, s_walk1 = time.perf_counter(), now()
            with lock:
                walk = [g for g in gt if g[0] >= s_walk0]
            fell = any(g[2][2] < 0.15 for g in walk)
            walked = float(
                sum(
                    np.linalg.norm(b[2][:2] - a[2][:2])
                    for a, b in zip(walk, walk[1:], strict=False)
                )
            )
            stats = [s for s in status if s.ticks > 0]
            degraded = sum(1 for h in health if h.state != "ok")
            reasons: dict[str, int] = {}
            for h in health:
                if h.state != "ok":
                    key = h.reason.split("(")[0].split(":")[-1].strip()[:60]
                    reasons[key] = reasons.get(key, 0) + 1
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs[::-1]:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        logs.cleanup()
    return {
        **_sequence_rmse(segs),
        "walked_m": walked,
        "falls": int(fell),
        "robot_rtf_cap": robot_rtf,
        "rtf": (s_walk1 - s_walk0) / (w_walk1 - w_walk0),
        "stale_tick_fraction": sum(s.stale_ticks for s in stats)
        / max(1, sum(s.ticks for s in stats)),
        "cmd_age_ticks_p50": _pct([s.cmd_age_p50 for s in stats], 50),
        "leg_timeouts": max((s.leg_timeouts for s in stats), default=0),
        "health_not_ok_fraction": degraded / max(1, len(health)),
        "health_reasons": dict(sorted(reasons.items(), key=lambda kv: -kv[1])[:6]),
    }


# Ordered so that the robot stays clear of the house's walls and the paper-1 objects.
SEQUENCE_ZENOH: list[tuple[float, float, float]] = [
    (0.0, 0.3, 0.0),
    (0.0, -0.3, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
    (0.5, 0.0, 0.0),
    (-0.3, 0.0, 0.0),
    (0.3, 0.2, 0.5),
]


def _rmse(err: np.ndarray) -> dict[str, float]:
    """Planar velocity and yaw-rate RMSE of body-velocity errors (N, 3)."""
    return {
        "vel_rmse_mps": float(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1)))),
        "yaw_rate_rmse_radps": float(np.sqrt(np.mean(err[:, 2] ** 2))),
    }


def _sequence_rmse(segs: list) -> dict[str, Any]:
    """The sequence's RMSE overall and per (command, errors) segment."""
    return {
        **_rmse(np.concatenate([e for _, e in segs])),
        "segments": [{"command": list(v), **_rmse(e)} for v, e in segs],
    }


def _body_velocity_errors(samples: list, v: tuple[float, float, float]) -> np.ndarray:
    out = []
    for (t0, p0, y0), (t1, p1, y1) in zip(samples, samples[1:], strict=False):
        dt = t1 - t0
        if dt <= 1e-6:
            continue
        vw = (p1 - p0) / dt
        dyaw = (y1 - y0 + math.pi) % (2 * math.pi) - math.pi
        yaw = y0 + 0.5 * dyaw
        c, s = math.cos(yaw), math.sin(yaw)
        out.append([c * vw[0] + s * vw[1] - v[0], -s * vw[0] + c * vw[1] - v[1], dyaw / dt - v[2]])
    return np.asarray(out).reshape(-1, 3)


# --------------------------------------------------------------------------- main
def main(argv: list[str]) -> int:
    """Run the benchmark and write the JSON (and a PNG plot)."""
    ap = argparse.ArgumentParser(prog="quadmanip bench locomotion")
    ap.add_argument("--json", required=True, help="output JSON file")
    ap.add_argument("--plot", help="PNG plot (default: next to the JSON)")
    ap.add_argument("--quick", action="store_true", help="1.5 s segments (smoke run)")
    ap.add_argument("--no-zenoh", action="store_true", help="skip the multi-process part")
    ap.add_argument(
        "--over",
        choices=("sim", "unitree-sim"),
        default="sim",
        help="unitree-sim: the sequence over the Unitree adapter and a simulated DDS robot, "
        "beside the same sequence over the sim directly (docs/hardware.md)",
    )
    ap.add_argument(
        "--robot-rtf",
        type=float,
        default=SMALL_MACHINE_RTF,
        help=f"real-time factor of the simulated robot (default {SMALL_MACHINE_RTF}, what "
        "2 cores hold for it, the adapter and locomotion)",
    )
    args = ap.parse_args(argv)
    seg = 1.5 if args.quick else SEGMENT_S
    if args.over == "unitree-sim":
        return _main_adapter(args, seg)
    _say("in-process run, tuned profile")
    tuned = run_in_process("tuned", record=True, segment_s=seg)
    _say(f"tuned: vel RMSE {tuned['vel_rmse_mps']:.3f} m/s, falls {tuned['falls']}")
    _say("in-process run, paper profile")
    paper = run_in_process("paper", segment_s=seg)
    _say(f"paper: vel RMSE {paper['vel_rmse_mps']:.3f} m/s, falls {paper['falls']}")
    _say("PIQP backends on the recorded problems")
    backends = bench_backends(tuned.pop("_problems"))
    plot = Path(args.plot) if args.plot else Path(args.json).with_suffix(".png")
    write_plot(tuned.pop("_trace"), plot)
    paper.pop("_problems")
    paper.pop("_trace")
    zen: dict[str, Any] | None = None
    if not args.no_zenoh:
        _say("over Zenoh: router + sim (lockstep) + locomotion")
        zen = run_zenoh(segment_s=seg)
        _say(f"zenoh: vel RMSE {zen['vel_rmse_mps']:.3f}, rtf {zen['rtf']:.2f}")
    src = zen if zen is not None else tuned
    summary = {
        "mpc_step_ms_p50": tuned["mpc_step_ms_p50"],
        "mpc_step_ms_p99": tuned["mpc_step_ms_p99"],
        "solver_ms_p50": tuned["solver_ms_p50"],
        "solver_ms_p99": tuned["solver_ms_p99"],
        "mpc_step_cpu_ms_p50": tuned["mpc_step_cpu_ms_p50"],
        "mpc_step_cpu_ms_p99": tuned["mpc_step_cpu_ms_p99"],
        "load_average_1min": os.getloadavg()[0],
        "vel_rmse_mps": src["vel_rmse_mps"],
        "yaw_rate_rmse_radps": src["yaw_rate_rmse_radps"],
        "falls": tuned["falls"] + (zen["falls"] if zen else 0),
        "odom_drift_pct": zen["odom_drift_pct"] if zen else None,
        "push_recovered": zen["push_recovered"] if zen else None,
        "rtf": zen["rtf"] if zen else tuned["in_process_rtf"],
        "leg_cmd_period_ms_p50": zen["leg_cmd_period_ms_p50"] if zen else None,
        "leg_cmd_jitter_ms_std": zen["leg_cmd_jitter_ms_std"] if zen else None,
        "paper_profile_vel_rmse_mps": paper["vel_rmse_mps"],
        "paper_profile_falls": paper["falls"],
    }
    result = {
        "summary": summary,
        "in_process": {"tuned": tuned, "paper": paper},
        "piqp_backends": backends,
        "zenoh": zen,
        "plot": str(plot),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "segment_s": seg,
    }
    Path(args.json).write_text(json.dumps(result, indent=2))
    _say(f"wrote {args.json} and {plot}")
    print(json.dumps(summary, indent=2))
    return 0


def _main_adapter(args: argparse.Namespace, seg: float) -> int:
    """``--over unitree-sim``: the sequence over the sim directly, then over the adapter."""
    _say("over Zenoh: router + sim (lockstep) + locomotion")
    direct = run_zenoh(segment_s=seg)
    _say(f"sim directly: vel RMSE {direct['vel_rmse_mps']:.3f} m/s, falls {direct['falls']}")
    _say(f"over the Unitree adapter: simulated DDS robot at rtf {args.robot_rtf}")
    hw = run_adapter(segment_s=seg, robot_rtf=args.robot_rtf)
    ratio = hw["vel_rmse_mps"] / max(direct["vel_rmse_mps"], 1e-9)
    _say(f"adapter: vel RMSE {hw['vel_rmse_mps']:.3f} m/s ({ratio:.2f} x), falls {hw['falls']}")
    summary = {
        "vel_rmse_mps": hw["vel_rmse_mps"],
        "yaw_rate_rmse_radps": hw["yaw_rate_rmse_radps"],
        "sim_vel_rmse_mps": direct["vel_rmse_mps"],
        "sim_yaw_rate_rmse_radps": direct["yaw_rate_rmse_radps"],
        "vel_rmse_ratio": ratio,
        "within_25_pct": bool(ratio <= 1.25),
        "falls": hw["falls"] + direct["falls"],
        "robot_rtf": hw["rtf"],
        "stale_tick_fraction": hw["stale_tick_fraction"],
        "leg_timeouts": hw["leg_timeouts"],
        "load_average_1min": os.getloadavg()[0],
    }
    result = {
        "summary": summary,
        "over": "unitree-sim",
        "adapter": hw,
        "sim_direct": direct,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "segment_s": seg,
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=2))
    _say(f"wrote {args.json}")
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
