"""`quadmanip tidyup`: the tidy-up task end to end, for an operator (issue 15, part 2).

Starts a private router, the sim (``lockstep`` by default: a slow machine slows the run
down instead of making the robot stumble) with the chosen scenario, and every robot
service (locomotion, manipulation, perception, navigation, behavior; viz with
``--rerun``). The behavior service runs the task on its own from the robot's sensors;
this command only watches:

- live progress on the terminal from ``behavior/progress`` (objects found / placed /
  failed, the current step, sim and wall time, real-time factor);
- at the end, the report: the behavior's own record per object (found, grasped, placed,
  time, failures with reasons) beside the sim judge's verdict (``sim/gt/judge``: the
  referee, read here to score, never fed back to the robot), as a table and a JSON file;
- timing (issue 15 part 4): the real-time factor of the whole run and the CPU cores used
  by the robot's own services (everything but the sim, viz and the router), measured
  from ``/proc`` (Linux).

The same :class:`TidyRun` serves ``quadmanip bench tidyup`` and the suite's end-to-end
test.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np
from quadmanip.common import messages as m
from quadmanip.common.bus import Bus
from quadmanip.launcher import Launcher, free_endpoint, install_stop_signals, observer_bus
from quadmanip.sim.scenarios import Scenario, get_scenario, save_scenario_file

if TYPE_CHECKING:
    from quadmanip.testbench.tidyup_film import TidyFilm

#: The robot's own services: they would share the robot's computer (CPU is measured).
ROBOT_SERVICES = ("locomotion", "manipulation", "perception", "navigation", "behavior")
#: The robot must be up and standing within this wall time, or the run fails.
START_TIMEOUT_S = 240.0
PRINT_EVERY_S = 5.0  # progress line period on a non-terminal output
FALL_TILT_DEG = 60.0  # trunk tilt that counts as a fall (scoring)
LOC_MAX_SKEW_S = 0.011  # s: a true pose this near a map pose's stamp is its truth (50 Hz)


@dataclass
class ObjectReport:
    """One scenario object: what the robot said it did and what the referee saw."""

    name: str
    category: str
    place: str  # its category's place (the catalogue)
    found: bool = False
    grasped: bool = False
    placed_by_robot: bool = False  # the behavior's own belief
    placed: bool = False  # the judge's verdict
    where: str = ""  # where the judge last saw it
    judge_note: str = ""  # why the judge says it is not placed
    time_s: float | None = None  # sim time the behavior spent on it
    failures: list[str] = field(default_factory=list)
    seen_as: list[str] = field(default_factory=list)  # the classes the robot gave it
    # where it lay at the end (m, the judge's ground truth: scoring only): the start and
    # this say whether it was moved, or knocked over (a cracker box lying flat: z 0.03)
    start_xyz: list[float] = field(default_factory=list)
    end_xyz: list[float] = field(default_factory=list)
    # the behavior's records merged into this object: where each was last believed (map
    # xy), its time and whether it was placed; a second record is a twin track
    records: list[dict[str, Any]] = field(default_factory=list)
    # each time the judge saw it leave its place after being in it: when (sim s of the
    # trial), during which task step, and where it went (seed-124: a padlock put into the
    # drawer ended on the floor in front of it, and nothing said when)
    left_place: list[str] = field(default_factory=list)


def drawer_openings(
    start: m.GroundTruthPoses | None, end: m.GroundTruthPoses | None
) -> dict[str, float]:
    """How far (m) each drawer handle moved between two ground-truth reports."""
    if start is None or end is None:
        return {}
    first = dict(zip(start.names, np.asarray(start.positions), strict=True))
    return {
        str(n): round(float(np.linalg.norm(np.asarray(p) - first[n])), 3)
        for n, p in zip(end.names, np.asarray(end.positions), strict=True)
        if n in first
    }


class PlaceWatch:
    """Follows the judge's reports during a trial: when an object judged in place is next
    judged elsewhere, and what the task was doing then."""

    #: the first transitions listed one by one; more (an object rocking in and out of the
    #: judge's "at rest", seed-124's sugar box 20 times) are summed up in one line
    shown = 2

    def __init__(self) -> None:
        self.where: dict[str, str] = {}
        self._left: dict[str, list[str]] = {}
        self._stamp = -math.inf

    def update(self, judge: m.JudgeReport | None, step: str, trial_s: float) -> None:
        """Reads one judge report (repeats of the last one are skipped)."""
        if judge is None or float(judge.stamp) <= self._stamp:
            return
        self._stamp = float(judge.stamp)
        for name, loc in zip(judge.objects, judge.locations, strict=True):
            if self.where.get(name) == "in_place" and loc != "in_place":
                self._left.setdefault(name, []).append(
                    f"left at {trial_s:.1f} s during '{step}': {loc}"
                )
            self.where[name] = loc

    @property
    def events(self) -> dict[str, list[str]]:
        """Per object, its departures from its place (the first ``shown``, then a sum)."""
        out = {}
        for name, left in self._left.items():
            out[name] = left[: self.shown]
            if len(left) > self.shown:
                out[name].append(f"{len(left) - self.shown} more times, the last {left[-1]}")
        return out


@dataclass
class TidyReport:
    """What one tidy-up run did (the JSON of ``--json``)."""

    scenario: str
    seed: int
    mode: str
    status: str = "not_started"  # done | budget | timeout | error | interrupted
    reason: str = ""
    objects: list[ObjectReport] = field(default_factory=list)
    drawers_opened: list[str] = field(default_factory=list)
    # how far each drawer's handle stands out at the end (m, ground truth: scoring only;
    # a tool released short of the tools' drawer's mouth may come from a short pull)
    drawer_openings: dict[str, float] = field(default_factory=dict)
    sim_time_s: float = 0.0
    wall_s: float = 0.0
    rtf: float = 0.0
    robot_services_cpu_cores: float = 0.0
    cpu_cores: dict[str, float] = field(default_factory=dict)
    judge_valid: bool = True
    leg_timeouts: int = 0
    restarts: dict[str, int] = field(default_factory=dict)
    faults: list[str] = field(default_factory=list)  # the faults injected (fault trials)
    falls: int = 0  # the trunk tipped over (ground truth, scoring)
    # navigation's map pose against the true pose (the saved map is in the house's frame;
    # ground truth, scoring only): over the run, and while the robot places (a place's
    # release point is as good as this)
    localisation_error_m: dict[str, float] = field(default_factory=dict)
    place_localisation_error_m: dict[str, float] = field(default_factory=dict)
    # per place step ("place: screwdriver#12"), the error of its last sample: about where
    # the robot stood as it let go (a tool released 11 cm short of the drawer's mouth in
    # paper-5, 2026-12-06, and nothing said whether the pose was off then)
    release_localisation_error_m: dict[str, float] = field(default_factory=dict)
    # how far navigation's map->odom correction moved from its first localised value: the
    # odometry's drift over the trial, which perception's odom-frame tracks must follow
    # (xy_max_m at the correction's origin, yaw_max_deg)
    odom_drift: dict[str, float] = field(default_factory=dict)
    # locomotion's own deadline counters at the end (locomotion/health; totals since its
    # last start): whether the controller kept up, above all in realtime mode, where the
    # sim does not wait for it
    controller: dict[str, float] = field(default_factory=dict)
    # the behavior's records that belong to no scenario object: what the robot went after
    # that was not there (false detections), with where first seen and why given up
    unmatched: list[dict[str, Any]] = field(default_factory=list)

    @property
    def placed(self) -> int:
        return sum(o.placed for o in self.objects)

    def summary(self) -> dict[str, Any]:
        n = len(self.objects)
        times = sorted(o.time_s for o in self.objects if o.placed and o.time_s is not None)
        return {
            "objects": n,
            "placed": self.placed,
            "success_rate": self.placed / n if n else 0.0,
            "drawers_opened": len(self.drawers_opened),
            "time_per_object_s_p50": _median(times),
            "sim_time_per_placed_object_s": self.sim_time_s / self.placed if self.placed else None,
            "trial_time_s": self.sim_time_s,
            "rtf": self.rtf,
            "robot_services_cpu_cores": self.robot_services_cpu_cores,
        }

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["summary"] = self.summary()
        return d

    def table(self) -> str:
        """A readable table, one row per object, then the totals."""
        rows = [("object", "category", "place", "found", "grasped", "placed", "time", "why not")]
        for o in self.objects:
            why = o.judge_note if not o.placed else ""
            if o.failures:
                why = "; ".join([*o.failures[-2:], why] if why else o.failures[-2:])
            if o.left_place and not o.placed:
                why = f"in place, then {o.left_place[-1]}; {why}"
            rows.append(
                (
                    o.name,
                    o.category,
                    o.place,
                    _yes(o.found),
                    _yes(o.grasped),
                    _yes(o.placed),
                    "-" if o.time_s is None else f"{o.time_s:.0f} s",
                    why[:70],
                )
            )
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
        lines.insert(1, "  ".join("-" * w for w in widths))
        s = self.summary()
        lines.append("")
        lines.append(
            f"{self.scenario}: placed {self.placed} of {len(self.objects)} "
            f"(judge), drawers opened {len(self.drawers_opened)}"
            + (
                " ("
                + ", ".join(f"{k} {v:.2f} m" for k, v in sorted(self.drawer_openings.items()))
                + ")"
                if self.drawer_openings
                else ""
            )
            + f", status {self.status}"
            + (f" ({self.reason})" if self.reason else "")
        )
        if self.faults or any(self.restarts.values()) or self.falls:
            lines.append(
                f"faults: {'; '.join(self.faults) or 'none'}; restarts: "
                + (", ".join(f"{k} {v}" for k, v in self.restarts.items() if v) or "none")
                + f"; falls: {self.falls}"
            )
        if self.unmatched:
            seen = ", ".join(
                f"{u['label']} at ({u['first_seen_xy'][0]:.1f}, {u['first_seen_xy'][1]:.1f})"
                for u in self.unmatched
            )
            lines.append(f"went after what is not in the scene ({len(self.unmatched)}): {seen}")
        if self.controller:
            c = self.controller
            lines.append(
                f"controller: {c['missed_ticks']:.0f} ticks missed, {c['late_answers']:.0f} "
                f"answers late, {c['mpc_overruns']:.0f} MPC overruns, "
                f"{c['degraded_episodes']:.0f} degraded episodes, "
                f"{c['leg_timeouts']:.0f} leg timeouts, {c.get('trips', 0):.0f} safety trips"
            )
        per = s["sim_time_per_placed_object_s"]
        lines.append(
            f"sim time {self.sim_time_s:.0f} s"
            + (f" ({per:.0f} s per placed object)" if per else "")
            + f", wall {self.wall_s:.0f} s, real-time factor {self.rtf:.2f}, "
            f"robot services {self.robot_services_cpu_cores:.2f} CPU cores"
        )
        return "\n".join(lines)


def _controller(h: m.LocomotionHealth | None) -> dict[str, float]:
    """Locomotion's deadline counters from its last health message ({} without one)."""
    if h is None:
        return {}
    return {
        "missed_ticks": h.missed_ticks,
        "late_answers": h.late_answers,
        "mpc_overruns": h.mpc_overruns,
        "answer_ms_p99_last_window": round(h.answer_ms_p99, 3),
        "cmd_age_ticks_last_window": round(h.cmd_age_ticks, 2),
        "leg_timeouts": h.leg_timeouts,
        "degraded_episodes": h.degraded_episodes,
        "trips": h.trips,
    }


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def _median(values: list[float]) -> float | None:
    if not values:
        return None
    k = len(values)
    return values[k // 2] if k % 2 else 0.5 * (values[k // 2 - 1] + values[k // 2])


def _cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of a process and its reaped children (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    tick = os.sysconf("SC_CLK_TCK")
    return sum(int(v) for v in fields[11:13]) / tick


class TidyRun:
    """A whole tidy-up on a fresh private stack: start, watch, report, stop.

    ``log`` receives every child's output (prefixed), ``say`` the progress lines.
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        log: TextIO,
        say: TextIO | None = None,
        lockstep: bool = True,
        rerun: str | None = None,
        budget_s: float | None = None,
        timeout_s: float = 3600.0,
        service_args: dict[str, list[str]] | None = None,
        stop: threading.Event | None = None,
        faults: list[tuple[str, float]] | None = None,
        film: TidyFilm | None = None,
    ) -> None:
        self.scenario = scenario
        self.film = film  # the robot at each stage, for a contact sheet (scoring tooling)
        # (service, sim seconds after the task's start): SIGKILL it then (fault trials)
        self.faults = sorted(faults or [], key=lambda f: f[1])
        for name, _ in self.faults:
            if name not in ROBOT_SERVICES:
                raise ValueError(f"fault: {name!r} is not one of {', '.join(ROBOT_SERVICES)}")
        self.stop = stop or threading.Event()  # set: stop the run (SIGINT, SIGTERM)
        self.log = log
        self.say = say
        self.lockstep = lockstep
        self.rerun = rerun
        self.budget_s = budget_s
        self.timeout_s = timeout_s
        self.extra = {k: list(v) for k, v in (service_args or {}).items()}
        self.report = TidyReport(
            scenario.name, scenario.seed, "lockstep" if lockstep else "realtime"
        )
        self.launcher: Launcher | None = None
        self.bus: Bus | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._cpu_done: dict[str, float] = {}  # CPU seconds of children's earlier lives
        self._cpu_last: dict[str, tuple[int, float]] = {}  # name -> (pid, CPU seconds)
        self._tilted = False
        self.place_watch = PlaceWatch()

    # ------------------------------------------------------------------ stack
    def _service_args(self, scenario_file: Path) -> dict[str, list[str]]:
        sim = ["--lockstep" if self.lockstep else "--realtime", "--scenario", str(scenario_file)]
        args: dict[str, list[str]] = {
            "sim": sim,
            "locomotion": [],
            "manipulation": [],
            "perception": [],
            "navigation": [],
            "behavior": [],
        }
        if self.budget_s is not None:
            args["behavior"] += ["--set", f"task.trial_budget_s={self.budget_s}"]
        if self.rerun:
            rrd = Path(self.rerun).resolve()
            rrd.parent.mkdir(parents=True, exist_ok=True)
            args["viz"] = ["--set", f"output={json.dumps(str(rrd))}"]
        for k, v in self.extra.items():
            args[k] = args.get(k, []) + v
        return args

    def _start(self) -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix="qm-tidyup-")
        scn = save_scenario_file(self.scenario, Path(self._tmp.name) / "scenario.toml")
        args = self._service_args(scn)
        endpoint = free_endpoint()
        self.launcher = Launcher(
            listen=endpoint, services=list(args), service_args=args, out=self.log
        )
        self.launcher.start()
        self.bus = observer_bus(self.launcher.connect or endpoint)

    def _stop(self) -> None:
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        if self.launcher is not None:
            self.launcher.stop()
            self.launcher = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def _cpu(self) -> dict[str, float]:
        """CPU seconds per child so far, over every life of a restarted child (the last
        reading of a dead process counts; sampled about once a second)."""
        assert self.launcher is not None
        out = {}
        for c in self.launcher.children:
            if c.proc is not None:
                pid = c.proc.pid
                last = self._cpu_last.get(c.name)
                if last is not None and last[0] != pid:  # restarted since the last reading
                    self._cpu_done[c.name] = self._cpu_done.get(c.name, 0.0) + last[1]
                    last = None
                now = _cpu_seconds(pid)
                if now is not None:
                    self._cpu_last[c.name] = (pid, now)
                elif last is not None:
                    now = last[1]
                out[c.name] = self._cpu_done.get(c.name, 0.0) + (now or 0.0)
        return out

    def _say(self, text: str) -> None:
        if self.say is not None:
            self.say.write(text + "\n")
            self.say.flush()

    # ------------------------------------------------------------------ run
    def run(self) -> TidyReport:
        """Run to the behavior's end (or the wall timeout); always stops the stack."""
        rep = self.report
        w0 = time.monotonic()
        try:
            self._start()
            self._watch(w0)
        except KeyboardInterrupt:
            rep.status, rep.reason = "interrupted", "stopped by the operator"
        except RuntimeError as exc:
            rep.status, rep.reason = "error", str(exc)
        finally:
            rep.wall_s = time.monotonic() - w0
            self._stop()
        return rep

    def _watch(self, w0: float) -> None:
        assert self.bus is not None and self.launcher is not None
        rep = self.report
        progress = self.bus.latest("behavior/progress")
        clock = self.bus.latest("sim/clock")
        judge = self.bus.latest("sim/gt/judge")
        health = self.bus.latest("locomotion/health")
        deadline = w0 + START_TIMEOUT_S
        while progress.get() is None:
            self._check_alive()
            if self.stop.is_set():
                raise KeyboardInterrupt
            if time.monotonic() > deadline:
                raise RuntimeError(f"no behavior/progress within {START_TIMEOUT_S:.0f} s")
            time.sleep(0.2)
        base = self.bus.latest("sim/gt/base")
        drawers = self.bus.latest("sim/gt/drawers")
        nav_pose = self.bus.latest("navigation/pose")
        true_xy: deque[tuple[float, float, float]] = deque(maxlen=400)  # stamp, x, y

        def on_true(gt: m.GroundTruthPoses) -> None:
            if "base" in gt.names:
                x, y, _ = gt.positions[list(gt.names).index("base")]
                true_xy.append((float(gt.stamp), float(x), float(y)))

        self.bus.subscribe("sim/gt/base", on_true)
        if self.film is not None:
            self.film.attach(self.bus)
        loc_errors: list[float] = []
        place_errors: list[float] = []
        corr0: np.ndarray | None = None
        drift_xy = drift_yaw = 0.0
        cpu0, t_cpu0 = self._cpu(), time.monotonic()
        c0 = clock.get()
        sim0 = float(c0.stamp) if c0 is not None else 0.0
        w_run0 = time.monotonic()
        last_line, last_print, last_cpu = "", 0.0, 0.0
        faults = list(self.faults)
        watch = self.place_watch = PlaceWatch()
        closed = drawers.get()  # the handles where the trial starts
        while True:
            self._check_alive()
            p = progress.get()
            c = clock.get()
            now_sim = float(c.stamp) if c is not None else 0.0
            if faults and now_sim - sim0 >= faults[0][1]:
                self._kill(faults.pop(0)[0], now_sim)
            self._count_falls(base.get())
            watch.update(judge.get(), str(p.step) if p is not None else "", now_sim - sim0)
            closed = closed if closed is not None else drawers.get()
            if self.film is not None and p is not None:
                self.film.on_step(now_sim - sim0, str(p.step))
            pose_now = nav_pose.get()
            if pose_now is not None and pose_now.status == "localized":
                corr = np.asarray(pose_now.map_to_odom, dtype=float)
                corr0 = corr if corr0 is None else corr0
                drift_xy = max(drift_xy, float(np.hypot(*(corr[:2] - corr0[:2]))))
                drift_yaw = max(drift_yaw, abs(math.remainder(corr[2] - corr0[2], math.tau)))
            err = _localisation_error(list(true_xy), pose_now)
            if err is not None:
                loc_errors.append(err)
                if p is not None and str(p.step).startswith("place"):
                    place_errors.append(err)
                    step = " ".join(str(p.step).split()[:2]).rstrip(":")  # "place: name#id"
                    rep.release_localisation_error_m[step] = round(err, 4)
            if time.monotonic() - last_cpu > 1.0:  # follow restarted children's CPU
                self._cpu()
                last_cpu = time.monotonic()
            wall = time.monotonic() - w0
            rtf = (now_sim - sim0) / max(time.monotonic() - w_run0, 1e-6)
            line = _progress_line(p)
            if line != last_line or time.monotonic() - last_print > PRINT_EVERY_S:
                self._say(f"[sim {now_sim:7.1f} s | wall {wall:6.0f} s | rtf {rtf:.2f}] {line}")
                last_line, last_print = line, time.monotonic()
            if p is not None and p.state in ("done", "failed", "budget", "canceled"):
                rep.status = "done" if p.state == "done" else p.state
                rep.reason = p.reason
                break
            if self.stop.is_set():
                rep.status, rep.reason = "interrupted", "stopped by the operator"
                break
            if wall > self.timeout_s:
                rep.status, rep.reason = "timeout", f"no end within {self.timeout_s:.0f} s wall"
                break
            time.sleep(0.25)
        cpu1, t_cpu1 = self._cpu(), time.monotonic()
        span = max(t_cpu1 - t_cpu0, 1e-6)
        rep.cpu_cores = {
            k: round((cpu1[k] - cpu0.get(k, 0.0)) / span, 3) for k in cpu1 if k in cpu0
        }
        rep.restarts = {
            c.name: c.tracker.total for c in self.launcher.children if c.tracker is not None
        }
        rep.robot_services_cpu_cores = round(
            sum(v for k, v in rep.cpu_cores.items() if k in ROBOT_SERVICES), 3
        )
        rep.controller = _controller(health.get())
        rep.localisation_error_m = _spread(loc_errors)
        rep.place_localisation_error_m = _spread(place_errors)
        if corr0 is not None:
            rep.odom_drift = {"xy_max_m": round(drift_xy, 4),
                              "yaw_max_deg": round(math.degrees(drift_yaw), 2)}  # fmt: skip
        rep.drawer_openings = drawer_openings(closed, drawers.get())
        c = clock.get()
        rep.sim_time_s = (float(c.stamp) if c is not None else 0.0) - sim0
        rep.rtf = rep.sim_time_s / max(time.monotonic() - w_run0, 1e-6)
        self._score(progress.get(), self._final_judge(judge))

    def _final_judge(self, judge: Any) -> m.JudgeReport | None:
        """The judge's report after the task's end (it publishes on its own period)."""
        first = judge.get()
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            r = judge.get()
            if r is not None and (first is None or r.stamp > first.stamp):
                return r
            time.sleep(0.1)
        return judge.get()

    def _check_alive(self) -> None:
        """The launcher's restart policy (configs/launch.toml [restart]): a child that
        dies is restarted; a crash loop (or the router dying for good) ends the run."""
        assert self.launcher is not None
        ended = self.launcher.supervise(time.monotonic())
        if ended is not None:
            raise RuntimeError(ended[1])

    def _kill(self, name: str, now_sim: float) -> None:
        """A fault: SIGKILL ``name`` (the launcher restarts it)."""
        assert self.launcher is not None
        child = next(c for c in self.launcher.children if c.name == name)
        if child.proc is not None and child.proc.poll() is None:
            os.kill(child.proc.pid, signal.SIGKILL)
            self.report.faults.append(f"{name} killed at sim {now_sim:.1f} s")
            self._say(f"fault: SIGKILL {name} (pid {child.proc.pid}) at sim {now_sim:.1f} s")

    def _count_falls(self, gt: m.GroundTruthPoses | None) -> None:
        """A fall: the trunk tipped beyond FALL_TILT_DEG (lying down level, as damped legs
        let it, is not one). Ground truth: scoring only."""
        if gt is None or "base" not in gt.names:
            return
        q = gt.orientations[list(gt.names).index("base")]  # w, x, y, z
        up_z = 1.0 - 2.0 * (float(q[1]) ** 2 + float(q[2]) ** 2)  # body z-axis . world z
        tilted = up_z < math.cos(math.radians(FALL_TILT_DEG))
        if tilted and not self._tilted:
            self.report.falls += 1
        self._tilted = tilted

    def _score(self, progress: Any, judge: m.JudgeReport | None) -> None:
        from quadmanip.sim.world.objects import load_catalogue

        rep = self.report
        cat = load_catalogue()
        records = _records_of(progress)
        if judge is not None:
            rep.judge_valid = bool(judge.valid)
            rep.leg_timeouts = int(judge.leg_timeouts)
        rep.drawers_opened = list(getattr(progress, "drawers_opened", []) or [])
        used: set[int] = set()
        for name in self.scenario.object_names:
            o = ObjectReport(name, cat.objects[name].category, cat.place_of(name))
            start = next(p for p in self.scenario.objects if p.name == name).position
            rec = _match(name, (start[0], start[1]), records)
            used.update(rec["ids"])
            o.found, o.grasped = rec["found"], rec["grasped"]
            o.placed_by_robot, o.time_s = rec["placed"], rec["time_s"]
            o.failures, o.seen_as = rec["failures"], rec["labels"]
            o.start_xyz = [round(float(v), 3) for v in start]
            o.records = [
                {
                    "xy": [round(v, 2) for v in records[i]["xy"]],
                    "time_s": None
                    if records[i]["time_s"] is None
                    else round(records[i]["time_s"], 1),
                    "placed": records[i]["placed"],
                }
                for i in rec["ids"]
            ]
            if judge is not None and name in list(judge.objects):
                i = list(judge.objects).index(name)
                o.where, o.judge_note = judge.locations[i], judge.notes[i]
                if len(judge.positions) == len(judge.objects):
                    o.end_xyz = [round(float(v), 3) for v in judge.positions[i]]
                o.placed = name in list(judge.in_place) and bool(judge.valid)
            o.left_place = list(self.place_watch.events.get(name, []))
            rep.objects.append(o)
        rep.unmatched = [
            {
                "label": r["label"],
                "first_seen_xy": [round(v, 2) for v in r["xy"]],
                "grasped": r["grasped"],
                "placed": r["placed"],
                "failures": r["failures"],
            }
            for i, r in enumerate(records)
            if i not in used
        ]


#: A behavior record belongs to a scenario object of another class (the detector took a
#: spoon for a marker) when it was first seen this near the object's starting point (m).
MATCH_RADIUS_M = 0.35
#: A record of the object's own class counts when first seen this near its start (m); a
#: track of that class elsewhere is a false detection (or another object of the class).
SAME_CLASS_RADIUS_M = 1.0


def _records_of(progress: Any) -> list[dict[str, Any]]:
    """The behavior's per-object records from a ``TaskProgress`` (parallel lists)."""
    if progress is None:
        return []
    out = []
    for i, label in enumerate(progress.objects):
        t = float(progress.object_time_s[i])
        out.append(
            {
                "label": label,
                "xy": tuple(float(v) for v in progress.object_positions[i][:2]),
                "grasped": bool(progress.object_grasped[i]),
                "placed": bool(progress.object_placed[i]),
                "time_s": None if math.isnan(t) else t,
                "failures": [f for f in progress.object_failures[i].split("\n") if f],
            }
        )
    return out


def _match(name: str, start_xy: tuple[float, float], records: list[dict[str, Any]]) -> dict:
    """Merge the records that are about scenario object ``name``: those of its class first
    seen near where it started, else any first seen right there (a misclassified object
    is still found)."""
    ids = [
        i
        for i, r in enumerate(records)
        if r["label"] == name and math.dist(r["xy"], start_xy) < SAME_CLASS_RADIUS_M
    ]
    if not ids:
        ids = [i for i, r in enumerate(records) if math.dist(r["xy"], start_xy) < MATCH_RADIUS_M]
    mine = [records[i] for i in ids]
    times = [r["time_s"] for r in mine if r["time_s"] is not None]
    return {
        "ids": ids,
        "found": bool(mine),
        "grasped": any(r["grasped"] for r in mine),
        "placed": any(r["placed"] for r in mine),
        "time_s": sum(times) if times else None,
        "failures": [f for r in mine for f in r["failures"]],
        "labels": sorted({r["label"] for r in mine}),
    }


def _localisation_error(
    truth: list[tuple[float, float, float]], nav: m.MapPose | None
) -> float | None:
    """m between navigation's localised map pose and the true base position ``truth``
    (stamp, x, y) of the same instant; None when there is none that near in time."""
    if nav is None or nav.status != "localized" or not truth:
        return None
    t = float(nav.stamp)
    stamp, x, y = min(truth, key=lambda s: abs(s[0] - t))
    if abs(stamp - t) > LOC_MAX_SKEW_S:
        return None
    return math.hypot(x - float(nav.x), y - float(nav.y))


def _spread(values: list[float]) -> dict[str, float]:
    """p50 / p95 / max and the count of ``values`` (empty: {})."""
    if not values:
        return {}
    p50, p95 = np.percentile(values, [50.0, 95.0])
    return {"p50": round(float(p50), 4), "p95": round(float(p95), 4),
            "max": round(max(values), 4), "samples": len(values)}  # fmt: skip


def _progress_line(p: Any) -> str:
    if p is None:
        return "waiting for the behavior service"
    return f"found {len(p.objects)}, placed {sum(p.object_placed)}, failed {p.failed} | {p.step}"


# --------------------------------------------------------------------------- command
def add_run_arguments(ap: argparse.ArgumentParser) -> None:
    """``--set`` and ``--kill`` (:func:`service_overrides`, :func:`parse_faults`)."""
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SERVICE.KEY=VALUE",
        help="a config override for one service, e.g. behavior.drawers.places=[] (repeatable)",
    )
    ap.add_argument(
        "--kill",
        action="append",
        default=[],
        metavar="SERVICE@SECONDS",
        help="fault trial: SIGKILL a robot service this many sim seconds into the task "
        "(the launcher restarts it), e.g. locomotion@90 (repeatable)",
    )


def parse_faults(items: list[str]) -> list[tuple[str, float]]:
    """``["locomotion@90"]`` -> ``[("locomotion", 90.0)]`` (a robot service, seconds >= 0)."""
    out = []
    for item in items:
        name, at, t = item.partition("@")
        try:
            when = float(t)
        except ValueError:
            when = -1.0
        if not at or name not in ROBOT_SERVICES or not when >= 0.0:
            raise ValueError(
                f"--kill {item!r}: expected SERVICE@SECONDS with SERVICE one of "
                f"{', '.join(ROBOT_SERVICES)}"
            )
        out.append((name, when))
    return out


def service_overrides(items: list[str]) -> dict[str, list[str]]:
    """``["behavior.task.max_attempts=3"]`` -> ``{"behavior": ["--set", "task.max_attempts=3"]}``."""
    out: dict[str, list[str]] = {}
    for item in items:
        service, dot, rest = item.partition(".")
        if not dot or "=" not in rest or service not in (*ROBOT_SERVICES, "sim", "viz"):
            raise ValueError(
                f"--set {item!r}: expected SERVICE.KEY=VALUE with SERVICE one of "
                f"{', '.join((*ROBOT_SERVICES, 'sim', 'viz'))}"
            )
        out.setdefault(service, []).extend(["--set", rest])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="quadmanip tidyup",
        description="Run the tidy-up task on a fresh simulated stack and report what it did.",
    )
    g = ap.add_mutually_exclusive_group()
    g.add_argument(
        "--scenario",
        default="short-0",
        help="paper-1..5, short-SEED[xN] (a short tidy-up), a .toml file (default short-0)",
    )
    g.add_argument("--seed", type=int, help="a random scene: ten objects from this seed")
    ap.add_argument("--json", help="report file (default: runs/tidyup-<scenario>.json)")
    ap.add_argument("--log", help="the services' output (default: next to the report)")
    ap.add_argument("--rerun", metavar="FILE.rrd", help="record the run with the viz service")
    ap.add_argument("--realtime", action="store_true", help="sim in real time, not lockstep")
    ap.add_argument("--budget-s", type=float, help="the task's time budget (sim seconds)")
    ap.add_argument("--timeout-s", type=float, default=3600.0, help="wall-clock limit")
    ap.add_argument(
        "--film",
        metavar="DIR",
        help="a contact sheet of the run: the robot at each stage (DIR/sheet.png, frames)",
    )
    add_run_arguments(ap)
    args = ap.parse_args(argv)
    try:
        overrides, faults = service_overrides(args.set), parse_faults(args.kill)
    except ValueError as exc:
        print(f"quadmanip tidyup: {exc}", file=sys.stderr)
        return 2
    try:
        scenario = get_scenario(args.seed if args.seed is not None else args.scenario)
    except (KeyError, ValueError) as exc:
        print(f"quadmanip tidyup: {exc}", file=sys.stderr)
        return 2
    out = Path(args.json or f"runs/tidyup-{scenario.name}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = Path(args.log) if args.log else out.with_suffix(".log")
    print(
        f"tidyup: {scenario.name}, {len(scenario.objects)} objects "
        f"({', '.join(scenario.object_names)}); services' output in {log_path}"
    )
    stop = threading.Event()
    install_stop_signals(stop)
    film = None
    if args.film:
        from quadmanip.testbench.tidyup_film import TidyFilm

        film = TidyFilm(scenario, Path(args.film))
    with open(log_path, "w") as log:
        run = TidyRun(
            scenario,
            log=log,
            say=sys.stdout,
            lockstep=not args.realtime,
            rerun=args.rerun,
            budget_s=args.budget_s,
            timeout_s=args.timeout_s,
            service_args=overrides,
            stop=stop,
            faults=faults,
            film=film,
        )
        rep = run.run()
    out.write_text(json.dumps(rep.to_json(), indent=2) + "\n")
    if film is not None:
        sheet = film.save()
        print(
            f"contact sheet: {sheet} ({len(film.samples)} stages)" if sheet else "no stages filmed"
        )
    print()
    print(rep.table())
    print(f"\nreport: {out}" + (f"\nrecording: {args.rerun}" if args.rerun else ""))
    if rep.status == "error":
        print(f"quadmanip tidyup: {rep.reason}", file=sys.stderr)
        return 1
    return 0 if rep.placed == len(rep.objects) else 3


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())


__all__ = [
    "ROBOT_SERVICES",
    "ObjectReport",
    "TidyReport",
    "TidyRun",
    "main",
    "parse_faults",
    "service_overrides",
]
