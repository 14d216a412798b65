"""``quadmanip bench robustness --json FILE``: does the robot stay up when the computer is
busy, does it notice a fall, and does it get up again (issue 12)?

Over the real processes (a private router, ``quadmanip service sim`` and ``quadmanip
service locomotion``); this process plays the operator and scores from ground truth
(``sim/gt/base``), which no service reads.

1. **Load** (sim in ``realtime`` mode with its cameras and LiDAR on, as in a trial):
   ``--busy`` processes that spin on the CPU (default 4, on this 2-core machine a load
   average of about 6) for ``--load-s`` seconds while the robot stands, then again while
   it trots back and forth at 0.3 m/s. A fall is roll or pitch beyond 10° or the trunk
   below 0.25 m at any sample. Recorded: the minimum trunk height, the maximum tilt, the
   sim's leg-command timeouts and command age, the health states locomotion published
   (``degraded`` must be said if it was needed) and its missed ticks.
2. **Falls** (sim in lockstep, so the trials do not depend on the load of the machine):
   ``--falls`` pushes per side through the TEST-ONLY disturbance channel, strong enough
   to topple it. Scored per trial: the sim time from ground truth crossing the safety
   limit (roll or pitch) to the ``tripped`` health message (``fall_detect_s``; negative
   when another check, e.g. a knee stretched beyond its range, tripped first), whether the
   phase went to ``safe`` (legs damped), and, after a ``recover`` command once the robot
   lies still, whether it stands (trunk above 0.25 m, tilt below 10°, phase ``balance``)
   within 10 s.

``--schedule fifo|nice|normal`` sets both services' ``scheduling.policy`` (the default is
the configs', i.e. SCHED_FIFO where permitted): run it with ``normal`` to see what the
real-time priority buys. The seeds pick the sensor noise and the push variations.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.bus import Bus
from quadmanip.common.rotations import quat_to_mat, rpy_from_mat, yaw_from_quat
from quadmanip.launcher import Launcher, free_endpoint
from quadmanip.services.locomotion.controller import load_locomotion_config
from quadmanip.services.locomotion.self_righting import gravity_in_base, tilt_angle
from quadmanip.sim.scenarios import Scenario, save_scenario_file
from quadmanip.testbench.self_righting_trials import toppling_push
from quadmanip.testbench.stack import harness_bus

FALL_TILT_DEG = 10.0  # the "no fall": roll and pitch within 10°...
FALL_HEIGHT_M = 0.25  # ... and the trunk above 0.25 m
TROT_SPEED = 0.3  # m/s
TROT_LEG_S = 5.0  # s forward, then as long backward (stays in the living room)
RIGHT_WITHIN_S = 10.0  # the issue: stands within 10 s of the reset
# The load runs start in the middle of the living room, facing +x: 1.5 m of trotting each
# way stays clear of the furniture (configs/house.toml).
LOAD_START = (1.6, 1.8, 0.0)
SPIN = "while True:\n    pass\n"


def _say(text: str) -> None:
    print(f"[bench robustness] {text}", flush=True)


def tilt_deg(quat: np.ndarray) -> float:
    """Angle between the trunk's z axis and the vertical (deg; covers roll and pitch)."""
    return math.degrees(tilt_angle(gravity_in_base(quat)))


@contextlib.contextmanager
def busy_processes(n: int) -> Iterator[list[subprocess.Popen]]:
    """``n`` processes spinning on the CPU at normal priority (the load of a busy stack)."""
    procs = [
        subprocess.Popen([sys.executable, "-c", SPIN], stdin=subprocess.DEVNULL) for _ in range(n)
    ]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


class RobotStack:
    """Router + sim + locomotion, and this process's view of them over Zenoh."""

    def __init__(self, sim_args: list[str], loco_args: list[str], log: io.TextIOBase) -> None:
        self.sim_args = sim_args
        self.loco_args = loco_args
        self.log = log
        self.lock = threading.Lock()
        self.gt: list[tuple[float, np.ndarray, np.ndarray]] = []  # stamp, position, quat
        self.health: list[m.LocomotionHealth] = []
        self.status: list[m.RobotStatus] = []
        self.launcher: Launcher | None = None
        self.bus: Bus | None = None

    def __enter__(self) -> RobotStack:
        endpoint = free_endpoint()
        self.launcher = Launcher(
            listen=endpoint,
            services=["sim", "locomotion"],
            service_args={"sim": self.sim_args, "locomotion": self.loco_args},
            out=self.log,  # type: ignore[arg-type]
        )
        self.launcher.start()
        self.bus = harness_bus(self.launcher.connect or endpoint)
        self.clock = self.bus.latest("sim/clock")
        self.bus.subscribe("sim/gt/base", self._on_gt)
        self.bus.subscribe("locomotion/health", self._on_health)
        self.bus.subscribe("sim/status", self._on_status)
        self.pub_mode = self.bus.publisher("locomotion/mode")
        self.pub_vel = self.bus.publisher("locomotion/cmd_vel")
        self.pub_push = self.bus.publisher("sim/test/disturbance")
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bus is not None:
            self.bus.close()
        if self.launcher is not None:
            self.launcher.stop()

    def _on_gt(self, msg: m.GroundTruthPoses) -> None:
        with self.lock:
            self.gt.append((float(msg.stamp), np.array(msg.positions[0]),
                            np.array(msg.orientations[0])))  # fmt: skip

    def _on_health(self, msg: m.LocomotionHealth) -> None:
        with self.lock:
            self.health.append(msg)

    def _on_status(self, msg: m.RobotStatus) -> None:
        with self.lock:
            self.status.append(msg)

    def now(self) -> float:
        c = self.clock.get()
        return -1.0 if c is None else float(c.stamp)

    def alive(self) -> None:
        assert self.launcher is not None
        dead = self.launcher.dead_child()
        if dead is not None:
            raise RuntimeError(f"{dead.name} exited")

    def wait_sim(self, t: float, timeout_s: float = 300.0, every: Any = None) -> None:
        deadline = time.monotonic() + timeout_s
        while self.now() < t:
            self.alive()
            if time.monotonic() > deadline:
                raise TimeoutError(f"sim time {self.now():.2f} did not reach {t:.2f}")
            if every is not None:
                every()
            time.sleep(0.02)

    def last_health(self) -> m.LocomotionHealth | None:
        with self.lock:
            return self.health[-1] if self.health else None

    def base(self) -> tuple[float, np.ndarray, np.ndarray] | None:
        with self.lock:
            return self.gt[-1] if self.gt else None

    def standing(self) -> bool:
        b, h = self.base(), self.last_health()
        return (
            b is not None
            and h is not None
            and b[1][2] > FALL_HEIGHT_M
            and tilt_deg(b[2]) < FALL_TILT_DEG
            and h.phase == "balance"
        )

    def wait_standing(self, timeout_s: float = 120.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.standing():
            self.alive()
            if time.monotonic() > deadline:
                raise TimeoutError("the robot did not stand up")
            time.sleep(0.05)
        self.wait_sim(self.now() + 2.0)

    def mode(self, mode: str) -> None:
        self.pub_mode.publish(m.LocomotionMode(stamp=max(self.now(), 0.0), mode=mode))

    def window(self, t0: float, t1: float) -> list[tuple[float, np.ndarray, np.ndarray]]:
        with self.lock:
            return [g for g in self.gt if t0 <= g[0] <= t1]


# --------------------------------------------------------------------------- load
def _sim_load_args(scenario_file: Path, seed: int, schedule: str | None) -> list[str]:
    args = ["--realtime", "--scenario", str(scenario_file), "--set", f"seed={seed}",
            "--set", f"sensors.seed={seed}", "--set", "ground_truth.poses_rate=100",
            "--set", "ground_truth.contacts_rate=0"]  # fmt: skip
    return args + (["--set", f"scheduling.policy={schedule}"] if schedule else [])


def _loco_args(schedule: str | None) -> list[str]:
    args = ["--set", "node.start_mode=stand"]
    return args + (["--set", f"scheduling.policy={schedule}"] if schedule else [])


def run_load(seed: int, busy: int, load_s: float, schedule: str | None, log: Any) -> dict:
    """Stand, then trot, each ``load_s`` with ``busy`` spinning processes (module doc)."""
    tmp = tempfile.TemporaryDirectory(prefix="qm-robust-")
    scn = save_scenario_file(
        Scenario(name="robustness", seed=seed, objects=(), robot_start=LOAD_START),
        Path(tmp.name) / "scenario.toml",
    )
    out: dict[str, Any] = {"seed": seed, "busy": busy, "load_s": load_s}
    with RobotStack(_sim_load_args(scn, seed, schedule), _loco_args(schedule), log) as st:
        st.wait_standing()
        h = st.last_health()
        out["scheduling"] = h.scheduling if h else ""
        for kind in ("stand", "trot"):
            st.wait_sim(st.now() + 1.0)
            with st.lock:
                n_health, n_status = len(st.health), len(st.status)
            t0 = st.now()
            w0 = time.monotonic()
            load0 = os.getloadavg()[0]
            state = {"sign": 1.0, "flip": t0 + TROT_LEG_S}

            def steer(kind: str = kind, state: dict = state) -> None:
                if kind != "trot":
                    return
                now = st.now()
                if now >= state["flip"]:
                    state["sign"] *= -1.0
                    state["flip"] = now + TROT_LEG_S
                st.pub_vel.publish(m.BodyVelocityCommand(
                    stamp=max(now, 0.0), vx=state["sign"] * TROT_SPEED, vy=0.0, wz=0.0))  # fmt: skip

            with busy_processes(busy):
                end_wall = time.monotonic() + load_s
                while time.monotonic() < end_wall:
                    st.alive()
                    steer()
                    time.sleep(0.05)
                load1 = os.getloadavg()[0]
            t1 = st.now()
            # Stop trotting and let it settle before scoring the tail of the run.
            st.wait_sim(t1 + 2.0)
            samples = st.window(t0, t1 + 2.0)
            heights = [g[1][2] for g in samples]
            xy = np.array([g[1][:2] for g in samples]) if samples else np.zeros((0, 2))
            path_m = (
                float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) if len(xy) > 1 else 0.0
            )
            tilts = [tilt_deg(g[2]) for g in samples]
            with st.lock:
                health = st.health[n_health:]
                status = st.status[n_status:]
            fell = bool(samples and (min(heights) < FALL_HEIGHT_M or max(tilts) > FALL_TILT_DEG))
            states = sorted({h.state for h in health})
            first_h = st.health[n_health - 1] if n_health else None
            last_h = health[-1] if health else None
            out[kind] = {
                "fell": fell,
                "min_height_m": min(heights) if heights else None,
                "max_tilt_deg": max(tilts) if tilts else None,
                "sim_s": t1 - t0,
                "wall_s": time.monotonic() - w0,
                "rtf": (t1 - t0) / max(time.monotonic() - w0, 1e-9),
                "load_average_1min": [load0, load1],
                "leg_timeouts": (status[-1].leg_timeouts - status[0].leg_timeouts)
                if len(status) > 1 else 0,
                "cmd_age_ticks_p50": statistics.median([s.cmd_age_p50 for s in status])
                if status else None,
                "cmd_age_ticks_max": max((s.cmd_age_max for s in status), default=None),
                "health_states": states,
                "degraded_reasons": sorted({h.reason for h in health if h.state == "degraded"})[:5],
                "missed_ticks": (last_h.missed_ticks - (first_h.missed_ticks if first_h else 0))
                if last_h else None,
                "late_answers": (last_h.late_answers - (first_h.late_answers if first_h else 0))
                if last_h else None,
                "answer_ms_p99_max": max((h.answer_ms_p99 for h in health), default=None),
                "path_m": path_m,  # ground-truth distance walked (trot: ~0.3 m/s x time)
                "rejected_commands": (last_h.rejected_commands
                                      - (first_h.rejected_commands if first_h else 0))
                if last_h else None,
            }  # fmt: skip
            _say(f"seed {seed} {kind} under {busy} busy: fell={fell} "
                 f"min z {out[kind]['min_height_m']:.3f} m, max tilt "
                 f"{out[kind]['max_tilt_deg']:.1f}°, timeouts {out[kind]['leg_timeouts']}, "
                 f"health {states}, walked {path_m:.1f} m, rtf {out[kind]['rtf']:.2f}")  # fmt: skip
            if fell:
                break  # the trot cannot start from the floor
    tmp.cleanup()
    return out


# --------------------------------------------------------------------------- falls
def run_falls(seed: int, per_side: int, log: Any) -> list[dict]:
    """``per_side`` push → detect → recover trials to each side (module doc)."""
    sim_args = ["--lockstep", "--scenario", "empty", "--set", "allow_test_disturbance=true",
                "--set", f"seed={seed}", "--set", f"sensors.seed={seed}",
                "--set", "sensors.front_camera.rate=0", "--set", "sensors.gripper_camera.rate=0",
                "--set", "sensors.lidar.rate=0", "--set", "ground_truth.contacts_rate=0",
                "--set", "ground_truth.poses_rate=500"]  # fmt: skip
    limits = load_locomotion_config().safety
    rng = np.random.default_rng(seed)
    trials: list[dict] = []
    sides = [s for _ in range(per_side) for s in ("left", "right")]
    stack: RobotStack | None = None
    try:
        for k, side in enumerate(sides):
            if stack is None:
                stack = RobotStack(sim_args, _loco_args(None), log).__enter__()
                stack.wait_standing()
            trial = _fall_trial(stack, side, rng, limits)
            trials.append(trial)
            _say(f"fall {k + 1}/{len(sides)} to the {side}: detect "
                 f"{trial['fall_detect_s']} s, safe {trial['safe']}, righted "
                 f"{trial['righted']} in {trial['right_s']} s ({trial['note']})")  # fmt: skip
            if not trial["righted"]:
                stack.__exit__()
                stack = None
    finally:
        if stack is not None:
            stack.__exit__()
    return trials


def _fall_trial(st: RobotStack, side: str, rng: np.random.Generator, limits: Any) -> dict:
    with st.lock:
        n_health = len(st.health)
    t_push = st.now()
    b = st.base()
    assert b is not None
    # The test aims its push with the true heading (self_righting_trials.py's pushes,
    # varied per trial); the robot never sees it.
    push = toppling_push(side, rng, yaw=yaw_from_quat(b[2]), stamp=t_push)
    st.pub_push.publish(push)
    trial: dict[str, Any] = {"side": side, "push_force": push.force.tolist(),
                             "push_torque": push.torque.tolist(), "duration": push.duration,
                             "fall_detect_s": None, "safe": False, "righted": False,
                             "right_s": None, "note": ""}  # fmt: skip
    # Wait for the trip (or 3 s: it did not fall / was not detected).
    t_trip = None
    deadline = t_push + 3.0
    while st.now() < deadline and t_trip is None:
        st.alive()
        with st.lock:
            trip = next((h for h in st.health[n_health:] if h.state == "tripped"), None)
        if trip is not None:
            t_trip = float(trip.stamp)
            trial["safe"] = trip.phase == "safe"
            trial["trip_reason"] = trip.reason
        time.sleep(0.01)
    # Let it come to rest (ground truth only times the operator), then look for the
    # crossing of the tilt limit over the whole fall: another check (a joint beyond its
    # range) may trip before the trunk gets there, which gives a negative detection time.
    st.wait_sim(st.now() + 2.0)
    samples = st.window(t_push, st.now())
    cross = next((g[0] for g in samples
                  if np.max(np.abs(rpy_from_mat(quat_to_mat(g[2]))[:2]))
                  > min(limits.max_roll, limits.max_pitch)),
                 None)  # fmt: skip
    trial["t_cross"] = None if cross is None else cross - t_push
    if t_trip is None:
        trial["note"] = "no trip" if cross is not None else "did not fall"
        return trial
    trial["fall_detect_s"] = None if cross is None else round(t_trip - cross, 4)
    b = st.base()
    assert b is not None
    trial["lying_tilt_deg"] = tilt_deg(b[2])
    t_reset = st.now()
    st.mode("recover")
    deadline = t_reset + RIGHT_WITHIN_S + 3.0
    while st.now() < deadline:
        st.alive()
        if st.standing():
            trial["righted"] = st.now() - t_reset <= RIGHT_WITHIN_S
            trial["right_s"] = round(st.now() - t_reset, 3)
            break
        time.sleep(0.02)
    h = st.last_health()
    trial["note"] = (
        "" if trial["righted"] else f"phase {h.phase if h else '?'}: {h.reason if h else ''}"
    )
    if trial["righted"]:
        st.wait_sim(st.now() + 1.0)
    return trial


# --------------------------------------------------------------------------- main
def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip bench robustness", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--json", required=True, help="output JSON file")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="scenario/noise seeds")
    ap.add_argument("--busy", type=int, default=4, help="spinning processes during the load")
    ap.add_argument("--load-s", type=float, default=60.0, help="wall seconds of load per part")
    ap.add_argument("--falls", type=int, default=10, help="push trials per side")
    ap.add_argument(
        "--schedule",
        choices=("fifo", "nice", "normal"),
        help="scheduling.policy of sim and locomotion (default: the configs')",
    )
    ap.add_argument("--parts", nargs="+", choices=("load", "falls"), default=["load", "falls"])
    ap.add_argument("--log", help="services' output (default: a temporary file)")
    args = ap.parse_args(argv)
    if args.busy < 0 or args.load_s <= 0 or args.falls < 0:
        ap.error("--busy and --falls must be >= 0 and --load-s > 0")
    log_path = (
        Path(args.log)
        if args.log
        else Path(tempfile.mkstemp(prefix="qm-robust-", suffix=".log")[1])
    )
    _say(f"services' output: {log_path}")
    result: dict[str, Any] = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
                              "args": vars(args)}  # fmt: skip
    loads: list[dict] = []
    trials: list[dict] = []
    with log_path.open("w") as log:
        for seed in args.seeds:
            if "load" in args.parts:
                _say(f"seed {seed}: load, {args.busy} busy processes, {args.load_s:g} s standing "
                     "then trotting")  # fmt: skip
                loads.append(run_load(seed, args.busy, args.load_s, args.schedule, log))
            if "falls" in args.parts and args.falls > 0:
                _say(f"seed {seed}: {args.falls} falls per side")
                for t in run_falls(seed, args.falls, log):
                    trials.append({"seed": seed, **t})
    parts = [r[k] for r in loads for k in ("stand", "trot") if k in r]
    detects = [t["fall_detect_s"] for t in trials if t["fall_detect_s"] is not None]
    righted = {s: [t for t in trials if t["side"] == s] for s in ("left", "right")}
    summary: dict[str, Any] = {
        "load_falls": sum(p["fell"] for p in parts) if parts else None,
        "load_runs": len(parts),
        "load_min_height_m": min((p["min_height_m"] for p in parts), default=None),
        "load_max_tilt_deg": max((p["max_tilt_deg"] for p in parts), default=None),
        "leg_timeouts_under_load": sum(p["leg_timeouts"] for p in parts) if parts else None,
        "load_degraded": any("degraded" in p["health_states"] for p in parts) if parts else None,
        "load_trot_path_m": [r["trot"]["path_m"] for r in loads if "trot" in r],
        "load_scheduling": sorted({r.get("scheduling", "") for r in loads}),
        "fall_detect_s_p50": statistics.median(detects) if detects else None,
        "fall_detect_s_max": max(detects) if detects else None,
        "falls_detected": f"{sum('trip_reason' in t for t in trials)}/{len(trials)}",
        "safe_engaged": sum(t["safe"] for t in trials),
        "self_right_success": sum(t["righted"] for t in trials),
        "self_right_trials": len(trials),
        "self_right_by_side": {s: f"{sum(t['righted'] for t in v)}/{len(v)}" for s, v in righted.items()},
        "self_right_s_p50": statistics.median([t["right_s"] for t in trials if t["righted"]])
        if any(t["righted"] for t in trials) else None,
    }  # fmt: skip
    result.update(summary=summary, load=loads, falls=trials)
    Path(args.json).write_text(json.dumps(result, indent=2, default=float))
    _say(f"wrote {args.json}")
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
