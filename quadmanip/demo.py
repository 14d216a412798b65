"""`quadmanip demo` (`make demo`): start the stack that exists and show it working.

Until the task (behavior) service exists, the demo is a live look at the bus: it starts a
router and every registered service (the sim in ``lockstep`` mode when a leg controller is
registered, else ``realtime``), plays the operator (stand up, trot forward, trot on a curve,
stop: :mod:`quadmanip.demo_operator`), listens to every key
under ``qm/**`` like a real robot's operator console would, prints a table of what arrives
(key, message type, rate, last stamp), writes the camera frames it sees as PNGs, and stops
everything cleanly. With no service registered yet it still exercises the real thing: an
echo process answers joint commands through the router and the table shows the round trip.

The demo starts the services ``quadmanip up`` starts (configs/launch.toml) that are in
``quadmanip.services_registry`` and importable; it never
reads ground truth for anything but display (``.../sim/gt/**`` keys are listed like any
other traffic).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
from quadmanip import services_registry
from quadmanip.common import keys
from quadmanip.demo_operator import DemoOperator
from quadmanip.launcher import (
    Launcher,
    free_endpoint,
    install_stop_signals,
    load_launch_config,
)

# Extra arguments per service when the demo runs it. With a leg controller the sim runs in
# lockstep (it waits for every leg command, so a slow machine slows the demo down instead of
# making the robot stumble); without one it free-runs in real time.
DEMO_SERVICE_ARGS: dict[str, list[str]] = {
    "sim": ["--realtime"],
    # the demo's operator drives the robot: the task must not start on its own
    "behavior": ["--set", "node.start_on_launch=false"],
}
LOCKSTEP_SIM_ARGS = ["--lockstep"]
# The robot must really walk in the demo: at least this far (ground truth, display only).
MIN_WALK_M = 0.3
SUMMARY_EVERY_S = 5.0  # table period when stdout is not a terminal


@dataclass
class KeyTraffic:
    """What arrived on one key."""

    type_name: str = "?"
    count: int = 0
    errors: int = 0
    nbytes: int = 0
    last_stamp: float = float("nan")
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=4096))

    def rate(self, now: float, window_s: float = 2.0) -> float:
        # A copy: the bus thread appends while the terminal thread counts (iterating the
        # deque itself raised "deque mutated during iteration" in a demo run).
        n = sum(1 for t in tuple(self.arrivals) if now - t <= window_s)
        return n / window_s


class BusMonitor:
    """Counts and decodes everything on ``qm/**`` (a raw wildcard subscriber)."""

    def __init__(self, bus: object) -> None:
        from quadmanip.common import messages as _messages  # noqa: F401  (registers types)
        from quadmanip.common.schema import MessageError, decode

        self._decode = decode
        self._error = MessageError
        self.lock = threading.Lock()
        self.keys: dict[str, KeyTraffic] = {}
        self.frames: dict[str, object] = {}  # key -> latest RgbdImage
        self.detections: dict[str, object] = {}  # camera -> perception's latest Detections
        self.alive: set[str] = set()
        self._sub = bus.session.declare_subscriber("qm/**", self._on_sample)  # type: ignore[attr-defined]
        self._live = bus.watch_liveliness(self._on_alive)  # type: ignore[attr-defined]

    def _on_alive(self, service: str, alive: bool) -> None:
        with self.lock:
            (self.alive.add if alive else self.alive.discard)(service)

    def _on_sample(self, sample: object) -> None:
        key = str(sample.key_expr)  # type: ignore[attr-defined]
        data = sample.payload.to_bytes()  # type: ignore[attr-defined]
        now = time.monotonic()
        try:
            msg = self._decode(data)
        except self._error:
            msg = None
        with self.lock:
            t = self.keys.setdefault(key, KeyTraffic())
            t.count += 1
            t.nbytes = len(data)
            t.arrivals.append(now)
            if msg is None:
                t.errors += 1
                return
            t.type_name = type(msg).__name__
            t.last_stamp = float(msg.stamp)
            if t.type_name == "RgbdImage":
                self.frames[key] = msg
            elif t.type_name == "Detections":
                self.detections[msg.camera] = msg  # type: ignore[attr-defined]

    def undeclare(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - best effort at shutdown
            pass

    def render(self, elapsed: float, extra: list[str]) -> str:
        now = time.monotonic()
        with self.lock:
            rows = sorted(self.keys.items())
            alive = sorted(self.alive)
        width = max([len(k) for k, _ in rows] + [20])
        lines = [
            f"quadmanip demo: {elapsed:5.1f} s   alive services: {', '.join(alive) or '-'}",
            f"{'key':<{width}}  {'message':<18} {'count':>7} {'rate Hz':>8} {'last stamp':>11}"
            f" {'bytes':>8}",
        ]
        for key, t in rows:
            stamp = "-" if np.isnan(t.last_stamp) else f"{t.last_stamp:11.3f}"
            err = f"  ({t.errors} undecodable)" if t.errors else ""
            lines.append(
                f"{key:<{width}}  {t.type_name:<18} {t.count:>7} {t.rate(now):>8.1f} "
                f"{stamp:>11} {t.nbytes:>8}{err}"
            )
        if not rows:
            lines.append("(nothing received yet)")
        return "\n".join(lines + extra)


class FrameWriter:
    """Saves the latest RGB-D frame per camera every ``every_s`` seconds as PNGs."""

    def __init__(self, out_dir: Path, every_s: float) -> None:
        self.out_dir = out_dir
        self.every_s = every_s
        self.last_saved: dict[str, float] = {}
        self.written: list[Path] = []

    def poll(self, monitor: BusMonitor) -> None:
        import cv2

        with monitor.lock:
            frames = dict(monitor.frames)
            detections = dict(monitor.detections)
        now = time.monotonic()
        for key, msg in frames.items():
            if now - self.last_saved.get(key, -1e9) < self.every_s:
                continue
            self.last_saved[key] = now
            camera = key.rsplit("/", 1)[-1]
            stem = self.out_dir / f"{camera}_{msg.stamp:09.3f}"  # type: ignore[attr-defined]
            rgb = np.asarray(msg.rgb)  # type: ignore[attr-defined]
            if rgb.size:
                path = stem.with_name(stem.name + "_rgb.png")
                bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
                cv2.imwrite(str(path), bgr)
                self.written.append(path)
                det = detections.get(msg.camera)  # type: ignore[attr-defined]
                if det is not None and len(det.labels):  # type: ignore[attr-defined]
                    # perception's newest boxes for this camera (from a frame < 0.1 s older
                    # or newer, so they may sit a little off a moving object)
                    for lab, sc, b in zip(det.labels, det.scores, det.boxes, strict=True):  # type: ignore[attr-defined]
                        x0, y0, x1, y1 = (int(round(float(v))) for v in b)
                        cv2.rectangle(bgr, (x0, y0), (x1, y1), (0, 255, 0), 1)
                        cv2.putText(bgr, f"{lab} {sc:.2f}", (x0, max(8, y0 - 2)),
                                    cv2.FONT_HERSHEY_SIMPLEX, 0.3, (0, 255, 0), 1)  # fmt: skip
                    path = stem.with_name(stem.name + "_detections.png")
                    cv2.imwrite(str(path), bgr)
                    self.written.append(path)
            depth = np.asarray(msg.depth)  # type: ignore[attr-defined]
            if depth.size:
                valid = depth > 0
                far = float(depth[valid].max()) if valid.any() else 1.0
                gray = np.where(valid, 255.0 * (1.0 - depth / max(far, 1e-6)), 0.0)
                color = cv2.applyColorMap(gray.astype(np.uint8), cv2.COLORMAP_TURBO)
                color[~valid] = 0
                path = stem.with_name(stem.name + "_depth.png")
                cv2.imwrite(str(path), color)
                self.written.append(path)


class RoundTrip:
    """Joint commands through the router to an echo process and back, at ``rate_hz``."""

    def __init__(self, bus: object, connect: str, rate_hz: float = 100.0) -> None:
        from quadmanip.common.messages import LegCommand
        from quadmanip.testbench import bench_bus as bb

        self._bb = bb
        self.echo = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "quadmanip.testbench.bench_bus",
                "--echo",
                "--mode",
                "client",
                "--connect",
                connect,
            ],
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        prefix = f"qm/{bb.ROBOT}/"
        self.pp = bb.PingPong(bus, prefix + bb.K_PING_CMD, prefix + bb.K_PONG_CMD, LegCommand)  # type: ignore[arg-type]
        self.period = 1.0 / rate_hz
        self.rtts: deque[float] = deque(maxlen=1000)
        self.sent = 0
        self.lost = 0
        self.ready = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="roundtrip", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.ready = self.pp.wait_ready(self._bb.leg_command, 20.0)
        i = 0
        while self.ready and not self._stop.wait(self.period):
            rtts, lost = self.pp.run([self._bb.leg_command(i)], "demo", report=False)
            self.rtts.extend(rtts)
            self.sent += 1
            self.lost += lost
            i += 1

    def lines(self) -> list[str]:
        if not self.ready:
            return ["", "round trip (joint command → echo process → back): waiting for echo"]
        a = np.asarray(self.rtts) * 1e3
        if not a.size:
            return ["", "round trip: no answers yet"]
        return [
            "",
            f"round trip through the router (LegCommand → echo process → back): {self.sent} "
            f"sent, {self.lost} lost, p50 {np.percentile(a, 50):.3f} ms, "
            f"p99 {np.percentile(a, 99):.3f} ms",
        ]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        if self.echo.poll() is None:
            self.echo.terminate()
            try:
                self.echo.wait(timeout=3.0)
            except subprocess.TimeoutExpired:
                self.echo.kill()
                self.echo.wait()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadmanip demo",
        description="Start a router and every registered service, show the live traffic, "
        "save camera frames as PNGs, then stop everything.",
    )
    p.add_argument("--duration", type=float, default=25.0, help="seconds to run (default 25)")
    p.add_argument("--out", default="demo-output", help="folder for PNGs and the stack log")
    p.add_argument(
        "--robot", default=keys.DEFAULT_ROBOT, help=f"robot name (default {keys.DEFAULT_ROBOT})"
    )
    p.add_argument("--listen", help="router endpoint (default: a free loopback port)")
    p.add_argument("--frames-every", type=float, default=2.0, help="s between saved frames")
    p.add_argument(
        "--roundtrip",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="run the joint-command round trip (default: only when no service is registered)",
    )
    return p


def run(args: argparse.Namespace, out: TextIO) -> int:
    """The demo proper; returns the exit code."""
    from quadmanip.common.bus import Bus, BusConfig

    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in [*out_dir.glob("*.png"), *out_dir.glob("*.rrd")]:
        old.unlink()
    # what `quadmanip up` starts (configs/launch.toml), of what is registered and importable:
    # the registry also holds the hardware adapter and its test robot, which take the sim's
    # place and must not run beside it
    registry = services_registry.available()
    listed = load_launch_config().services
    names = [n for n in listed if registry.get(n, "not registered") is None]
    for n in listed:
        problem = registry.get(n, "not registered yet")
        if problem:
            print(f"demo: skipping {n}: {problem}", file=out)
    listen = args.listen or free_endpoint()
    log_path = out_dir / "stack.log"
    roundtrip_on = (not names) if args.roundtrip is None else args.roundtrip
    print(
        f"demo: router on {listen}, services: {', '.join(names) or 'none registered yet'}; "
        f"their logs go to {log_path}",
        file=out,
        flush=True,
    )
    service_args = {k: list(v) for k, v in DEMO_SERVICE_ARGS.items()}
    drive = "sim" in names and "locomotion" in names
    if drive:
        service_args["sim"] = list(LOCKSTEP_SIM_ARGS)
    if "viz" in names:
        # The Rerun recording goes next to the pictures (`rerun FILE.rrd` replays it).
        rrd = json.dumps(str(out_dir / "quadmanip_{time}.rrd"))
        service_args.setdefault("viz", []).extend(["--set", f"output={rrd}"])
    stop = threading.Event()
    install_stop_signals(stop)
    tty = out.isatty()
    with log_path.open("w") as log_file:
        launcher = Launcher(
            listen=listen,
            services=names,
            service_args=service_args,
            robot=args.robot,
            out=log_file,
        )
        try:
            launcher.start()
        except RuntimeError as exc:
            print(f"demo: {exc} (see {log_path})", file=out)
            return 1
        bus = monitor = roundtrip = operator = None
        walked: float | None = None
        died = None
        try:
            # The round trip's echo keys are the bus benchmark's, beside the product's.
            from quadmanip.testbench.bench_bus import TABLE as bench_table

            bus = Bus(
                BusConfig(mode="client", connect=(launcher.connect or listen,)),
                args.robot,
                table=bench_table,
            )
            monitor = BusMonitor(bus)
            writer = FrameWriter(out_dir, args.frames_every)
            roundtrip = RoundTrip(bus, launcher.connect or listen) if roundtrip_on else None
            operator = DemoOperator(bus) if drive else None
            t0 = time.monotonic()
            last_print = -1e9
            while not stop.wait(0.2):
                elapsed = time.monotonic() - t0
                writer.poll(monitor)
                died = launcher.dead_child()
                if died is not None or elapsed >= args.duration:
                    break
                period = 1.0 if tty else SUMMARY_EVERY_S
                if time.monotonic() - last_print >= period:
                    last_print = time.monotonic()
                    table = monitor.render(elapsed, _extra_lines(roundtrip, operator))
                    print(("\x1b[H\x1b[J" if tty else "\n") + table, file=out, flush=True)
            final = monitor.render(time.monotonic() - t0, _extra_lines(roundtrip, operator))
            walked = operator.walked_m() if operator is not None else None
        finally:
            if operator is not None:
                operator.stop()
            if roundtrip is not None:
                roundtrip.stop()
            if monitor is not None:
                monitor.undeclare()
            if bus is not None:
                bus.close()
            launcher.stop()
    print("\n" + final, file=out)
    code = _verdict(out, names, monitor, roundtrip, died, writer, log_path, args.robot)
    if drive:
        if walked is None or walked < MIN_WALK_M:
            print(
                f"demo: FAILED: the robot did not walk (moved {walked} m); see {log_path}", file=out
            )
            code = 1
        else:
            print(f"demo: the robot stood up and walked {walked:.2f} m (ground truth)", file=out)
    return code


def _extra_lines(roundtrip: RoundTrip | None, operator: DemoOperator | None) -> list[str]:
    return (roundtrip.lines() if roundtrip else []) + (operator.lines() if operator else [])


def _verdict(
    out: TextIO,
    names: list[str],
    monitor: BusMonitor,
    roundtrip: RoundTrip | None,
    died: object,
    writer: FrameWriter,
    log_path: Path,
    robot: str,
) -> int:
    """Print where things are and decide the exit code: did the stack really work?"""
    code = 0
    if died is not None:
        print(f"demo: FAILED: {died.name} died; see {log_path}", file=out)  # type: ignore[attr-defined]
        code = 1
    with monitor.lock:
        heard = {k.split("/")[2] for k in monitor.keys if k.startswith(f"qm/{robot}/")}
    silent = [n for n in names if n not in heard]
    if silent:
        print(f"demo: FAILED: nothing received from {', '.join(silent)}; see {log_path}", file=out)
        code = 1
    if roundtrip is not None and not roundtrip.rtts:
        print("demo: FAILED: no joint-command round trip completed", file=out)
        code = 1
    if writer.written:
        print(f"demo: {len(writer.written)} camera images in {writer.out_dir.resolve()}/", file=out)
    elif any(n == "sim" for n in names):
        print("demo: no camera frames arrived", file=out)
    for rrd in sorted(writer.out_dir.glob("*.rrd")):
        print(f"demo: Rerun recording {rrd.resolve()} (view it with `rerun {rrd}`)", file=out)
    print(f"demo: service logs in {log_path.resolve()}", file=out)
    print("demo: stopped cleanly" if code == 0 else "demo: finished with errors", file=out)
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``quadmanip demo``."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    if args.duration <= 0 or args.frames_every <= 0:
        print("demo: --duration and --frames-every must be positive", file=sys.stderr)
        return 2
    return run(args, sys.stdout)


if __name__ == "__main__":
    sys.exit(main())
