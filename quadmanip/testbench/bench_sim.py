"""``quadmanip bench sim --json FILE``: how fast the simulator is on this machine.

Measures, in the house of scenario ``paper-1``:

* ``physics_rtf``: physics + actuator layer only (robot standing, PD holding the home
  pose, no sensors, no transport), sim seconds per wall second.
* ``render_ms_320x240`` / ``render_ms_640x480``: median ms per RGB-D frame (colour and
  depth from one render pass) per camera; the summary holds the mean over both cameras.
* ``full_sensors_rtf``: the real node in its own process in ``lockstep`` mode with every
  sensor and ground-truth stream on, answered by a trivial responder process
  (``python -m quadmanip.testbench.bench_sim responder``) over a real local Zenoh router; the RTF is
  sim time over wall time seen on ``sim/clock`` by this process.

Targets on the 2-core dev machine (issue 3): physics >= 5x, full sensors >= 1.5x.

The responder is also what the sim's integration tests use as "a controller": it echoes
each LowState's tick in a LegCommand that holds the joint angles of the first state it saw
(PD only), which is the smallest honest lockstep partner.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from quadmanip.common import messages as msg
from quadmanip.common import robot_description as rd
from quadmanip.common.config import load_config
from quadmanip.sim.engine import standing_data

SCENARIO = "paper-1"


def _say(text: str) -> None:
    print(f"[bench sim] {text}", flush=True)


# --------------------------------------------------------------------------- parts


def bench_physics(sim_seconds: float = 5.0) -> dict[str, Any]:
    from quadmanip.sim.engine import SimConfig, SimEngine
    from quadmanip.sim.node import load_world

    world = load_world(SCENARIO)
    eng = SimEngine(
        world,
        load_config(SimConfig, "sim"),
        data=standing_data(world),
        cameras=False,
        lidar=False,
        ground_truth=False,
    )
    n = rd.N_LEG_JOINTS
    q0 = rd.home_joint_positions()[rd.LEG_SLICE]
    kp, kd, zero = np.full(n, 150.0), np.full(n, 3.0), np.zeros(n)
    act = eng.actuators
    d = eng.data
    steps = 0
    t0, c0 = time.perf_counter(), time.process_time()
    while eng.time < sim_seconds:
        act.set_leg_command(float(d.time), q0, zero, kp, kd, zero)
        for _ in range(eng.substeps):
            eng.physics_step()
        steps += eng.substeps
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    base_z = float(d.xpos[eng.base][2])
    return {
        "physics_rtf": eng.time / wall,
        "physics_steps_per_s": steps / wall,
        "physics_rtf_cpu": eng.time / cpu,
        "sim_seconds": eng.time,
        "wall_seconds": wall,
        "timestep": eng.model.opt.timestep,
        "base_height_end": base_z,
    }


def bench_render(frames: int = 20) -> dict[str, Any]:
    from quadmanip.sim.engine import SimConfig
    from quadmanip.sim.node import load_world
    from quadmanip.sim.sensors import CameraConfig, RgbdRenderer

    world = load_world(SCENARIO)
    d = standing_data(world)
    out: dict[str, Any] = {}
    for w, h in ((320, 240), (640, 480)):
        cams = {c: CameraConfig(width=w, height=h) for c in rd.CAMERAS}
        r = RgbdRenderer(world.model, cams, render=load_config(SimConfig, "sim").sensors.render)
        per_cam = {}
        for cam in rd.CAMERAS:
            r.render(d, cam)  # warm-up (shader compile, buffers)
            ms, cpu = [], []
            for _ in range(frames):
                t0, c0 = time.perf_counter(), time.process_time()
                r.render(d, cam)
                ms.append((time.perf_counter() - t0) * 1e3)
                cpu.append((time.process_time() - c0) * 1e3)
            per_cam[cam] = {
                "median_ms": statistics.median(ms),
                "min_ms": min(ms),
                # CPU time of this process (GL driver threads included): less sensitive to
                # other load on a shared machine than wall time.
                "median_cpu_ms": statistics.median(cpu),
            }
        r.close()
        out[f"{w}x{h}"] = per_cam
        _say(
            f"render {w}x{h}: "
            + ", ".join(f"{c} {v['median_ms']:.1f} ms" for c, v in per_cam.items())
        )
    return out


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_full(wall_seconds: float = 20.0, warmup_s: float = 3.0) -> dict[str, Any]:
    """Node (lockstep, every sensor) + responder + router, RTF from sim/clock."""
    from quadmanip.common.bus import Bus, BusConfig

    port = _free_port()
    ep = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "QM_ZENOH_CONNECT": ep, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    py = sys.executable
    procs: list[subprocess.Popen] = []
    logs = tempfile.TemporaryDirectory(prefix="qm-bench-sim-")

    def start(name: str, *args: str) -> subprocess.Popen:
        # Logs go to files: an unread pipe would block a chatty child.
        log_file = open(os.path.join(logs.name, f"{name}.log"), "w")  # noqa: SIM115
        p = subprocess.Popen(
            [py, *args], env=env, stdout=subprocess.DEVNULL, stderr=log_file, text=True
        )
        procs.append(p)
        return p

    def node_log() -> str:
        with open(os.path.join(logs.name, "node.log")) as fh:
            return fh.read()[-2000:]

    try:
        start("router", "-m", "quadmanip.common.router", "--listen", ep)
        time.sleep(1.0)
        start("responder", "-m", "quadmanip.testbench.bench_sim", "responder")
        node = start("node", "-m", "quadmanip.sim.node", "--lockstep", "--scenario", SCENARIO)
        cfg = BusConfig(mode="peer", connect=(ep,), listen=("tcp/127.0.0.1:0",), env_override=False)
        stamps: list[tuple[float, float]] = []
        counts = {"lowstate": 0, "front": 0, "gripper": 0, "scan": 0}
        lock = threading.Lock()

        def on_clock(c: msg.Clock) -> None:
            with lock:
                stamps.append((time.monotonic(), c.stamp))

        def counter(name: str) -> Any:
            def cb(_m: Any) -> None:
                counts[name] += 1

            return cb

        with Bus(cfg) as bus:
            bus.subscribe("sim/clock", on_clock)
            bus.subscribe("sim/camera/front", counter("front"), latest_only=True)
            bus.subscribe("sim/camera/gripper", counter("gripper"), latest_only=True)
            bus.subscribe("sim/scan", counter("scan"))
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not stamps:
                if node.poll() is not None:
                    raise RuntimeError(f"sim node exited: {node_log()}")
                time.sleep(0.2)
            if not stamps:
                raise RuntimeError(f"no sim/clock within 60 s: {node_log()}")
            _say("node running; warming up")
            time.sleep(warmup_s)
            with lock:
                w0, s0 = stamps[-1]
                c0 = dict(counts)
            time.sleep(wall_seconds)
            with lock:
                w1, s1 = stamps[-1]
                c1 = dict(counts)
        rtf = (s1 - s0) / (w1 - w0)
        sim = s1 - s0
        return {
            "full_sensors_rtf": rtf,
            "sim_seconds": sim,
            "wall_seconds": w1 - w0,
            "rates_hz_sim": {k: (c1[k] - c0[k]) / sim for k in ("front", "gripper", "scan")},
        }
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        logs.cleanup()


# --------------------------------------------------------------------------- responder


def responder_main(argv: list[str]) -> int:
    """A trivial lockstep partner: answer every LowState with a PD hold of the first
    state's leg angles (``--home``: of the standing keyframe), echoing its tick."""
    from quadmanip.common.bus import Bus, apply_env, load_bus_config
    from quadmanip.common.log import configure_logging, get_logger

    p = argparse.ArgumentParser(prog="quadmanip.testbench.bench_sim responder")
    p.add_argument("--home", action="store_true", help="hold the home pose instead")
    p.add_argument("--kp", type=float, default=60.0)
    p.add_argument("--kd", type=float, default=2.0)
    args = p.parse_args(argv)
    configure_logging("responder")
    log = get_logger("responder")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    hold: list[np.ndarray] = []
    if args.home:
        hold.append(rd.home_joint_positions()[rd.LEG_SLICE])
    n_leg = rd.N_LEG_JOINTS
    kp, kd, zero = np.full(n_leg, args.kp), np.full(n_leg, args.kd), np.zeros(n_leg)
    with Bus(apply_env(load_bus_config())) as bus:
        pub = bus.publisher("sim/leg_command")
        n = [0]

        def on_state(s: msg.LowState) -> None:
            if not hold:
                hold.append(np.array(s.joints.q[rd.LEG_SLICE]))
            pub.publish(
                msg.LegCommand(
                    stamp=s.stamp,
                    tick=s.tick,
                    q_des=hold[0],
                    dq_des=zero,
                    kp=kp,
                    kd=kd,
                    tau_ff=zero,
                )
            )
            n[0] += 1

        bus.subscribe("sim/lowstate", on_state)
        log.info("responder ready")
        while not stop.wait(0.5):
            pass
        log.info("responder stopped", answered=n[0])
    return 0


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    """``quadmanip bench sim [--json FILE] [--quick]``; ``responder`` runs the partner."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "responder":
        return responder_main(argv[1:])
    p = argparse.ArgumentParser(prog="quadmanip bench sim", description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, help="write the results here")
    p.add_argument("--quick", action="store_true", help="shorter runs (smoke test)")
    args = p.parse_args(argv)
    load0 = list(os.getloadavg())
    os.environ.setdefault("MUJOCO_GL", "egl")
    quick = args.quick
    _say("physics (robot standing in the house, no sensors)")
    phys = bench_physics(1.0 if quick else 5.0)
    _say(f"physics_rtf {phys['physics_rtf']:.2f} ({phys['physics_steps_per_s']:.0f} steps/s)")
    _say("rendering")
    rend = bench_render(5 if quick else 20)
    _say("full sensor set, lockstep node + responder over Zenoh")
    full = bench_full(wall_seconds=4.0 if quick else 20.0, warmup_s=2.0 if quick else 3.0)
    _say(f"full_sensors_rtf {full['full_sensors_rtf']:.2f}")

    def mean_ms(size: str) -> float:
        return float(np.mean([v["median_ms"] for v in rend[size].values()]))

    result = {
        "summary": {
            "physics_rtf": phys["physics_rtf"],
            "render_ms_320x240": mean_ms("320x240"),
            "render_ms_640x480": mean_ms("640x480"),
            "full_sensors_rtf": full["full_sensors_rtf"],
        },
        "targets": {"physics_rtf": 5.0, "full_sensors_rtf": 1.5},
        "physics": phys,
        "render": rend,
        "full_sensors": full,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "mujoco": mujoco.__version__,
            "gl": os.environ.get("MUJOCO_GL", ""),
            "loadavg_start": load0,
            "loadavg_end": list(os.getloadavg()),
        },
        "scenario": SCENARIO,
    }
    text = json.dumps(result, indent=2)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
        _say(f"wrote {args.json}")
    print(json.dumps(result["summary"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
