"""`quadmanip bench bus --json FILE`: latency, throughput and codec cost of the quadmanip bus.

What it measures, between TWO processes on this machine (this one and an echo process it
spawns), once peer-to-peer (this process listens, the echo peer connects straight to it)
and once through a router (both are Zenoh clients of a router child process):

- round-trip time of a joint command (LegCommand, ``control`` QoS) and of a ~1 KB message
  (a LaserScan sized to 1 KB on the wire): publish → echo decodes and republishes → we
  decode; p50/p90/p99 over ``--count`` round trips after ``--warmup`` ones;
- throughput of 320×240 RGB-D frames (RgbdImage, ``sensor`` QoS, one way): the echo side
  publishes as fast as it can for ``--rgbd-seconds``; frames/s *delivered and decoded* here;
- encode+decode time (µs) of JointState, LowState, LegCommand and a 320×240 RgbdImage,
  in process.

The typed :class:`~quadmanip.common.bus.Bus` is used end to end (encode, QoS, strict
decode), so the numbers are what a service sees, not the bare transport. Targets from
issue 2 are recorded with pass/fail in the JSON; the exit code is 0 unless ``--strict``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib.metadata
import json
import os
import platform
import queue
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from quadmanip.common import keys
from quadmanip.common.bus import Bus, BusConfig
from quadmanip.common.joint_layout import N_LEG_JOINTS, N_LEGS
from quadmanip.common.messages import (
    Heartbeat,
    Imu,
    JointState,
    LaserScan,
    LegCommand,
    LowState,
    RgbdImage,
)
from quadmanip.common.schema import Message, decode, encode

ROBOT = "bench"  # keys qm/bench/bench/...: never collides with a running robot stack
K_PING_CMD, K_PONG_CMD = "bench/ping_cmd", "bench/pong_cmd"
K_PING_1K, K_PONG_1K = "bench/ping_1k", "bench/pong_1k"
K_CTL, K_CTL_REPLY, K_RGBD = "bench/ctl", "bench/ctl_reply", "bench/rgbd"
RGBD_W, RGBD_H = 320, 240
TABLE = keys.TABLE.extended(
    (
        keys.row("bench", "ping_cmd", LegCommand, "control", "in", "bus benchmark: ping"),
        keys.row("bench", "pong_cmd", LegCommand, "control", "out", "bus benchmark: pong"),
        keys.row("bench", "ping_1k", LaserScan, "control", "in", "bus benchmark: 1 kB ping"),
        keys.row("bench", "pong_1k", LaserScan, "control", "out", "bus benchmark: 1 kB pong"),
        keys.row("bench", "ctl", Heartbeat, "event", "in", "bus benchmark: echo control"),
        keys.row("bench", "ctl_reply", Heartbeat, "event", "out", "bus benchmark: echo reply"),
        keys.row("bench", "rgbd", RgbdImage, "sensor", "out", "bus benchmark: RGB-D stream"),
    )
)
"""The product's key table plus the benchmark's own keys (under robot ``bench``)."""

# Issue 2's targets: metric -> (operator, limit).
TARGETS: dict[str, tuple[str, float]] = {
    "rtt_peer_p50_ms": ("<=", 0.5),
    "codec_joint_state_us": ("<=", 20.0),
    "codec_joint_command_us": ("<=", 20.0),
    "rgbd_frames_per_s": (">=", 30.0),
}
SUMMARY_FIELDS = (
    "rtt_peer_p50_ms",
    "rtt_peer_p99_ms",
    "rtt_router_p50_ms",
    "rtt_router_p99_ms",
    "rgbd_frames_per_s",
    "codec_joint_state_us",
    "codec_joint_command_us",
    "codec_rgbd_us",
)


def progress(text: str) -> None:
    """Progress lines go to stderr so stdout stays clean for pipes."""
    print(f"[bench bus] {text}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- messages


def leg_command(i: int) -> LegCommand:
    """A realistic joint command (standing pose gains), ``tick`` = round-trip id."""
    q = np.tile([0.0, 0.8, -1.6], N_LEGS)
    return LegCommand(
        stamp=i * 0.002,
        tick=i,
        q_des=q,
        dq_des=np.zeros(N_LEG_JOINTS),
        kp=np.full(N_LEG_JOINTS, 40.0),
        kd=np.full(N_LEG_JOINTS, 1.0),
        tau_ff=np.zeros(N_LEG_JOINTS),
    )


def _scan(i: int, n: int) -> LaserScan:
    return LaserScan(
        stamp=float(i),
        angle_min=-np.pi,
        angle_increment=2 * np.pi / max(n, 1),
        range_min=0.1,
        range_max=12.0,
        ranges=np.linspace(0.5, 5.0, n, dtype=np.float32),
    )


def one_kb_message(i: int) -> LaserScan:
    """A LaserScan whose encoded size is 1024 bytes (± 3): the '1 KB message'."""
    overhead = len(encode(_scan(0, 0)))
    return _scan(i, max(0, (1024 - overhead) // 4))


def joint_state(stamp: float = 0.0) -> JointState:
    rng = np.random.default_rng(0)
    return JointState(
        stamp=stamp,
        q=rng.normal(size=16),
        dq=rng.normal(size=16),
        tau=rng.normal(size=16),
        gripper_gap=0.04,
        gripper_effort=1.0,
    )


def low_state(tick: int = 0) -> LowState:
    imu = Imu(
        stamp=0.0,
        orientation=np.array([1.0, 0.0, 0.0, 0.0]),
        angular_velocity=np.zeros(3),
        linear_acceleration=np.array([0.0, 0.0, 9.81]),
    )
    return LowState(stamp=tick * 0.002, tick=tick, joints=joint_state(), imu=imu)


def rgbd_frame(stamp: float = 0.0) -> RgbdImage:
    """A 320×240 RGB-D frame with non-trivial content (no compression shortcuts)."""
    rng = np.random.default_rng(1)
    return RgbdImage(
        stamp=stamp,
        camera="front",
        rgb=rng.integers(0, 256, size=(RGBD_H, RGBD_W, 3), dtype=np.uint8),
        depth=rng.uniform(0.3, 8.0, size=(RGBD_H, RGBD_W)).astype(np.float32),
        K=np.array([[277.0, 0.0, 160.0], [0.0, 277.0, 120.0], [0.0, 0.0, 1.0]]),
        position=np.array([0.25, 0.0, 0.05]),
        orientation=np.array([0.5, -0.5, 0.5, -0.5]),
    )


# --------------------------------------------------------------------------- statistics


def percentiles_ms(samples_s: Sequence[float]) -> dict[str, float]:
    """p50/p90/p99/min/max/mean in milliseconds of samples given in seconds."""
    if not samples_s:
        return {"n": 0}
    a = np.asarray(samples_s) * 1e3
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p90": float(np.percentile(a, 90)),
        "p99": float(np.percentile(a, 99)),
        "min": float(a.min()),
        "max": float(a.max()),
        "mean": float(a.mean()),
    }


def codec_us(msg: Message, reps: int, batches: int = 5) -> dict[str, float]:
    """encode+decode cost of ``msg`` in µs per message, median over batches.

    The headline is CPU time of this thread (``thread_time``): on a shared machine wall time
    also counts the time other processes hold the core, which is not the codec's cost.
    Wall time is recorded beside it.
    """
    cls = type(msg)
    data = encode(msg)
    decode(data, cls)  # warm
    n = max(1, reps // batches)
    cpu, wall, enc = [], [], []
    for _ in range(batches):
        w0, c0 = time.perf_counter(), time.thread_time()
        for _ in range(n):
            decode(encode(msg), cls)
        cpu.append((time.thread_time() - c0) / n * 1e6)
        wall.append((time.perf_counter() - w0) / n * 1e6)
        c0 = time.thread_time()
        for _ in range(n):
            encode(msg)
        enc.append((time.thread_time() - c0) / n * 1e6)
    return {
        "encode_decode_us": statistics.median(cpu),
        "encode_decode_wall_us": statistics.median(wall),
        "encode_us": statistics.median(enc),
        "bytes": len(data),
    }


# --------------------------------------------------------------------------- echo side


def run_echo(config: BusConfig) -> int:
    """The second process: echo pings back, stream RGB-D frames on request."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    requests: queue.SimpleQueue[Heartbeat] = queue.SimpleQueue()
    with Bus(config, robot=ROBOT, table=TABLE) as bus:
        pong_cmd = bus.publisher(K_PONG_CMD)
        pong_1k = bus.publisher(K_PONG_1K)
        reply = bus.publisher(K_CTL_REPLY)
        frames = bus.publisher(K_RGBD)
        bus.subscribe(K_PING_CMD, pong_cmd.publish)
        bus.subscribe(K_PING_1K, pong_1k.publish)
        bus.subscribe(K_CTL, requests.put)
        frame = rgbd_frame()
        while not stop.is_set():
            try:
                req = requests.get(timeout=0.1)
            except queue.Empty:
                continue
            if req.state == "quit":
                break
            if req.state == "rgbd":
                t_end = time.perf_counter() + req.seq / 1000.0
                sent = 0
                while time.perf_counter() < t_end and not stop.is_set():
                    frames.publish(frame.replace(stamp=float(sent)))
                    sent += 1
                time.sleep(0.2)  # let the last frames drain before reporting
                reply.publish(Heartbeat(stamp=0.0, service="bench-echo", seq=sent, state="done"))
    return 0


# --------------------------------------------------------------------------- main side


class PingPong:
    """Sequential round trips on one ping/pong key pair."""

    def __init__(self, bus: Bus, ping_key: str, pong_key: str, msg_type: type[Message]) -> None:
        self.pub = bus.publisher(ping_key)
        self.replies: queue.SimpleQueue[tuple[float, float]] = queue.SimpleQueue()
        self.msg_type = msg_type
        bus.subscribe(pong_key, self._on_pong)

    def _on_pong(self, msg: Message) -> None:
        self.replies.put((time.perf_counter(), msg.stamp))

    def wait_ready(self, make: Callable[[int], Message], timeout_s: float) -> bool:
        """Ping until the echo answers (subscriptions take a moment to propagate)."""
        deadline = time.monotonic() + timeout_s
        i = -1
        while time.monotonic() < deadline:
            self.pub.publish(make(i))
            try:
                self.replies.get(timeout=0.1)
                break
            except queue.Empty:
                i -= 1
        else:
            return False
        time.sleep(0.1)
        while not self.replies.empty():  # late answers to the other probes
            self.replies.get_nowait()
        return True

    def run(
        self, msgs: Sequence[Message], label: str, report: bool = True
    ) -> tuple[list[float], int]:
        """Round-trip times (s) for ``msgs`` sent one after another; returns (rtts, lost)."""
        rtts: list[float] = []
        lost = 0
        step = max(1, len(msgs) // 4)
        for k, msg in enumerate(msgs):
            t0 = time.perf_counter()
            self.pub.publish(msg)
            while True:
                try:
                    t1, stamp = self.replies.get(timeout=1.0)
                except queue.Empty:
                    lost += 1
                    break
                if stamp == msg.stamp:
                    rtts.append(t1 - t0)
                    break
            if report and (k + 1) % step == 0:
                progress(f"  {label}: {k + 1}/{len(msgs)}")
        return rtts, lost


def free_tcp_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _spawn(args: list[str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "quadmanip.testbench.bench_bus", *args],
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )


def _stop(proc: subprocess.Popen[bytes] | None, grace_s: float = 3.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=2.0)


def measure_mode(mode: str, args: argparse.Namespace) -> dict[str, Any]:
    """One topology: 'peer' (direct link) or 'router' (both clients of a router child)."""
    router = echo = None
    try:
        if mode == "peer":
            ep = free_tcp_endpoint()
            mine = BusConfig(mode="peer", connect=(), listen=(ep,))
            echo_args = ["--echo", "--mode", "peer", "--connect", ep]
        else:
            ep = free_tcp_endpoint()
            router = subprocess.Popen(
                [sys.executable, "-m", "quadmanip.cli", "router", "--listen", ep],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                start_new_session=True,
            )
            from quadmanip.launcher import wait_for_port

            if not wait_for_port(ep, 15.0, lambda: router.poll() is None):
                raise RuntimeError(f"router did not come up on {ep}")
            mine = BusConfig(mode="client", connect=(ep,))
            echo_args = ["--echo", "--mode", "client", "--connect", ep]
        with Bus(mine, robot=ROBOT, table=TABLE) as bus:
            echo = _spawn(echo_args)
            out: dict[str, Any] = {"endpoint": ep}
            cmd = PingPong(bus, K_PING_CMD, K_PONG_CMD, LegCommand)
            one_k = PingPong(bus, K_PING_1K, K_PONG_1K, LaserScan)
            if not cmd.wait_ready(leg_command, 20.0) or not one_k.wait_ready(one_kb_message, 5.0):
                raise RuntimeError(f"{mode}: echo process did not answer")
            progress(f"{mode}: echo ready on {ep}")
            for label, pp, make in (
                ("joint_command", cmd, leg_command),
                ("1kb", one_k, one_kb_message),
            ):
                pp.run([make(-1000 - i) for i in range(args.warmup)], f"{mode} {label} warmup")
                msgs = [make(i) for i in range(args.count)]
                rtts, lost = pp.run(msgs, f"{mode} {label}")
                stats = percentiles_ms(rtts)
                stats["lost"] = lost
                stats["bytes"] = len(encode(msgs[0]))
                out[f"rtt_{label}_ms"] = stats
                progress(
                    f"{mode}: {label} RTT p50 {stats.get('p50', float('nan')):.3f} ms, "
                    f"p99 {stats.get('p99', float('nan')):.3f} ms, lost {lost}"
                )
            out["rgbd"] = measure_rgbd(bus, args.rgbd_seconds, mode)
        return out
    finally:
        if echo is not None and echo.poll() is None:
            _stop(echo)
        _stop(router)


def measure_rgbd(bus: Bus, seconds: float, mode: str) -> dict[str, Any]:
    """Ask the echo side to stream frames for ``seconds``; count frames decoded here."""
    times: list[float] = []
    done: queue.SimpleQueue[Heartbeat] = queue.SimpleQueue()
    bus.subscribe(K_RGBD, lambda _m: times.append(time.perf_counter()))
    bus.subscribe(K_CTL_REPLY, done.put)
    ctl = bus.publisher(K_CTL)
    time.sleep(0.3)  # let the new subscriptions reach the echo process
    progress(f"{mode}: streaming {RGBD_W}x{RGBD_H} RGB-D frames for {seconds:.1f} s")
    ctl.publish(Heartbeat(stamp=0.0, service="bench", seq=int(seconds * 1000), state="rgbd"))
    try:
        sent = done.get(timeout=seconds + 30.0).seq
    except queue.Empty:
        sent = -1
    received = len(times)
    span = times[-1] - times[0] if received > 1 else 0.0
    fps = (received - 1) / span if span > 0 else 0.0
    progress(f"{mode}: RGB-D {fps:.1f} frames/s delivered ({received} of {sent} sent)")
    return {
        "width": RGBD_W,
        "height": RGBD_H,
        "bytes": len(encode(rgbd_frame())),
        "sent": sent,
        "received": received,
        "frames_per_s": fps,
        "megabytes_per_s": fps * len(encode(rgbd_frame())) / 1e6,
    }


def machine_info() -> dict[str, Any]:
    def version(dist: str) -> str:
        try:
            return importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return "not installed"

    return {
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15": list(os.getloadavg()),
        "python": platform.python_version(),
        "eclipse-zenoh": version("eclipse-zenoh"),
        "msgpack": version("msgpack"),
        "numpy": version("numpy"),
    }


def evaluate_targets(summary: dict[str, float]) -> dict[str, dict[str, Any]]:
    """Each issue-2 target with its measured value and pass/fail."""
    out = {}
    for metric, (op, limit) in TARGETS.items():
        value = summary.get(metric)
        ok = value is not None and (value <= limit if op == "<=" else value >= limit)
        out[metric] = {"op": op, "limit": limit, "value": value, "pass": bool(ok)}
    return out


def run_benchmark(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement; returns the JSON document."""
    t_start = time.time()
    progress("codec: encode+decode in process")
    codec = {
        "joint_state": codec_us(joint_state(), args.codec_reps),
        "low_state": codec_us(low_state(), args.codec_reps),
        "joint_command": codec_us(leg_command(0), args.codec_reps),
        "rgbd": codec_us(rgbd_frame(), max(20, args.codec_reps // 10)),
    }
    for name, c in codec.items():
        progress(f"codec: {name} {c['encode_decode_us']:.1f} us ({c['bytes']} bytes)")
    modes = {m: measure_mode(m, args) for m in args.modes}
    peer, router = modes.get("peer", {}), modes.get("router", {})

    def pick(d: dict[str, Any], *path: str) -> float | None:
        for p in path:
            if not isinstance(d, dict) or p not in d:
                return None
            d = d[p]
        return float(d)

    summary: dict[str, float | None] = {
        "rtt_peer_p50_ms": pick(peer, "rtt_joint_command_ms", "p50"),
        "rtt_peer_p99_ms": pick(peer, "rtt_joint_command_ms", "p99"),
        "rtt_router_p50_ms": pick(router, "rtt_joint_command_ms", "p50"),
        "rtt_router_p99_ms": pick(router, "rtt_joint_command_ms", "p99"),
        "rtt_peer_1kb_p50_ms": pick(peer, "rtt_1kb_ms", "p50"),
        "rtt_peer_1kb_p99_ms": pick(peer, "rtt_1kb_ms", "p99"),
        "rtt_router_1kb_p50_ms": pick(router, "rtt_1kb_ms", "p50"),
        "rtt_router_1kb_p99_ms": pick(router, "rtt_1kb_ms", "p99"),
        "rgbd_frames_per_s": pick(peer, "rgbd", "frames_per_s"),
        "rgbd_router_frames_per_s": pick(router, "rgbd", "frames_per_s"),
        "codec_joint_state_us": codec["joint_state"]["encode_decode_us"],
        "codec_low_state_us": codec["low_state"]["encode_decode_us"],
        "codec_joint_command_us": codec["joint_command"]["encode_decode_us"],
        "codec_rgbd_us": codec["rgbd"]["encode_decode_us"],
    }
    if summary["rgbd_frames_per_s"] is None:
        summary["rgbd_frames_per_s"] = summary["rgbd_router_frames_per_s"]
    targets = evaluate_targets(summary)  # type: ignore[arg-type]
    return {
        "benchmark": "bus",
        "command": "quadmanip bench bus " + " ".join(args.argv),
        "started_utc": _dt.datetime.fromtimestamp(t_start, _dt.UTC).isoformat(),
        "duration_s": round(time.time() - t_start, 3),
        "machine": machine_info(),
        "parameters": {
            "count": args.count,
            "warmup": args.warmup,
            "rgbd_seconds": args.rgbd_seconds,
            "codec_reps": args.codec_reps,
            "modes": list(args.modes),
        },
        "summary": summary,
        "targets": targets,
        "all_targets_pass": all(t["pass"] for t in targets.values()),
        "details": {"codec": codec, **modes},
    }


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadmanip bench bus",
        description="Bus latency/throughput between two processes (peer-to-peer and via a "
        "router) and message codec cost; writes a JSON report.",
    )
    p.add_argument("--json", metavar="FILE", help="write the JSON report here")
    p.add_argument("--count", type=int, default=2000, help="round trips per message type")
    p.add_argument("--warmup", type=int, default=200, help="round trips discarded first")
    p.add_argument("--rgbd-seconds", type=float, default=3.0, help="RGB-D streaming time")
    p.add_argument("--codec-reps", type=int, default=5000, help="codec repetitions")
    p.add_argument(
        "--modes",
        type=lambda s: [m for m in s.split(",") if m],
        default=["peer", "router"],
        help="comma-separated topologies: peer,router",
    )
    p.add_argument("--strict", action="store_true", help="exit 1 when a target fails")
    # Internal: the echo process.
    p.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--mode", default="peer", help=argparse.SUPPRESS)
    p.add_argument("--connect", default="", help=argparse.SUPPRESS)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip bench bus``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.echo:
        return run_echo(BusConfig(mode=args.mode, connect=(args.connect,)))
    bad = [m for m in args.modes if m not in ("peer", "router")]
    if bad or not args.modes or args.count < 1 or args.warmup < 0 or args.rgbd_seconds <= 0:
        print(
            "quadmanip bench bus: invalid --modes/--count/--warmup/--rgbd-seconds", file=sys.stderr
        )
        return 2
    args.argv = argv
    report = run_benchmark(args)
    text = json.dumps(report, indent=2)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n")
        progress(f"wrote {args.json}")
    print(json.dumps({"summary": report["summary"], "targets": report["targets"]}, indent=2))
    if args.strict and not report["all_targets_pass"]:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
