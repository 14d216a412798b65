"""Real-time scheduling of a control process: SCHED_FIFO where permitted, else a raised nice.

A legged robot's control loop must answer every LowState within a tick (2 ms) even when the
machine is busy; under Linux's default scheduler a process competes with every other
runnable one and, on a loaded 2-core computer, waits several milliseconds for a core
(issue 12: the robot fell over with four busy processes beside it). Real robots run that
loop at real-time priority (ros2_control's real-time thread, legged_control, Unitree's
SDK examples); this module does the same for a Python service.

:func:`apply_scheduling` gives every thread of the process (Zenoh's receive threads run
the callbacks that answer LowState, so the main thread alone is not enough) the policy of a
:class:`SchedulingConfig`:

1. ``policy = "fifo"``: ``SCHED_FIFO`` at ``priority`` (1..99). Needs ``CAP_SYS_NICE``
   or ``ulimit -r`` (RLIMIT_RTPRIO) >= priority; in Docker ``cap_add: [SYS_NICE]`` and
   ``ulimits: rtprio: 99`` (compose.yaml). The kernel's RT throttling
   (``sched_rt_runtime_us``, 95 % by default) keeps a runaway loop from freezing the box.
2. Not permitted: ``nice`` = ``fallback_nice`` (negative: more CPU share and earlier
   wake-ups under the fair scheduler). Needs the same capability or RLIMIT_NICE.
3. Not permitted either: the process keeps its normal priority.

The result says which step held and why the others failed, so the service logs it at
start (a robot running without real-time priority must say so). ``cpus`` pins the
threads to those CPUs (optional). :class:`ThreadScheduler` re-applies the policy to threads
started later (Zenoh starts some lazily); services call it from their heartbeat.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["SchedulingConfig", "SchedulingResult", "ThreadScheduler", "apply_scheduling"]

Policy = Literal["fifo", "nice", "normal"]


@dataclass(frozen=True)
class SchedulingConfig:
    """How a process's threads are scheduled ([scheduling] of a service config)."""

    # "fifo": SCHED_FIFO where permitted, else the nice fallback; "nice": only the raised
    # nice; "normal": leave the process as it is
    policy: Policy = "normal"
    priority: int = 80  # SCHED_FIFO priority, 1 (low) .. 99 (high)
    fallback_nice: int = -10  # nice level when SCHED_FIFO is not permitted (0: none)
    cpus: tuple[int, ...] = ()  # CPU affinity; () = any CPU

    def __post_init__(self) -> None:
        if self.policy not in ("fifo", "nice", "normal"):
            raise ValueError(
                f"scheduling.policy must be 'fifo', 'nice' or 'normal', not {self.policy!r}"
            )
        if not 1 <= self.priority <= 99:
            raise ValueError(f"scheduling.priority must be in 1..99, not {self.priority}")
        if not -20 <= self.fallback_nice <= 19:
            raise ValueError(
                f"scheduling.fallback_nice must be in -20..19, not {self.fallback_nice}"
            )
        if any(c < 0 for c in self.cpus):
            raise ValueError(f"scheduling.cpus must be CPU numbers >= 0, not {self.cpus}")


@dataclass
class SchedulingResult:
    """What :func:`apply_scheduling` achieved: ``fifo``, ``nice`` or ``normal``."""

    applied: Literal["fifo", "nice", "normal"]
    priority: int = 0  # SCHED_FIFO priority when applied == "fifo"
    nice: int = 0  # nice level of the threads
    cpus: tuple[int, ...] = ()  # affinity set ((): unchanged)
    threads: int = 0  # threads changed
    reasons: list[str] = field(default_factory=list)  # why a stronger step did not hold

    @property
    def realtime(self) -> bool:
        return self.applied == "fifo"

    def summary(self) -> str:
        """One line for the log, e.g. ``fifo 80 on 7 threads``."""
        if self.applied == "fifo":
            text = f"SCHED_FIFO priority {self.priority} on {self.threads} threads"
        elif self.applied == "nice":
            text = f"nice {self.nice} on {self.threads} threads (no real-time priority)"
        else:
            text = "normal priority (no real-time priority, no raised nice)"
        if self.cpus:
            text += f", CPUs {list(self.cpus)}"
        return text


def _thread_ids() -> list[int]:
    """Every thread of this process (Linux); just the process elsewhere."""
    try:
        return sorted(int(t) for t in os.listdir("/proc/self/task"))
    except OSError:
        return [os.getpid()]


def _set_fifo(tids: list[int], priority: int) -> None:
    param = os.sched_param(priority)
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
        except ProcessLookupError:  # the thread ended meanwhile
            continue


def _set_nice(tids: list[int], nice: int) -> None:
    # On Linux, setpriority(PRIO_PROCESS, tid) changes that one thread.
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:
            continue


def apply_scheduling(cfg: SchedulingConfig, tids: list[int] | None = None) -> SchedulingResult:
    """Apply ``cfg`` to ``tids`` (default: every thread of this process); never raises for
    a missing permission: the result says what held and why (module doc)."""
    tids = _thread_ids() if tids is None else list(tids)
    reasons: list[str] = []
    cpus: tuple[int, ...] = ()
    if cfg.cpus:
        try:
            for tid in tids:
                os.sched_setaffinity(tid, set(cfg.cpus))
            cpus = tuple(cfg.cpus)
        except (OSError, AttributeError) as exc:
            reasons.append(f"CPU affinity {list(cfg.cpus)} not applied: {exc}")
    if cfg.policy == "normal":
        return SchedulingResult("normal", threads=0, cpus=cpus, reasons=reasons)
    if cfg.policy == "fifo":
        if not hasattr(os, "sched_setscheduler"):
            reasons.append("SCHED_FIFO: not available on this OS")
        elif _attempt(
            lambda: _set_fifo(tids, cfg.priority),
            f"SCHED_FIFO {cfg.priority}",
            f"needs CAP_SYS_NICE or `ulimit -r` >= {cfg.priority}, RLIMIT_RTPRIO is "
            f"{_rlimit('RLIMIT_RTPRIO')}",
            reasons,
        ):
            return SchedulingResult(
                "fifo", priority=cfg.priority, threads=len(tids), cpus=cpus, reasons=reasons
            )
    if cfg.fallback_nice < 0 and _attempt(
        lambda: _set_nice(tids, cfg.fallback_nice),
        f"nice {cfg.fallback_nice}",
        f"needs CAP_SYS_NICE or RLIMIT_NICE, which is {_rlimit('RLIMIT_NICE')}",
        reasons,
    ):
        return SchedulingResult(
            "nice", nice=cfg.fallback_nice, threads=len(tids), cpus=cpus, reasons=reasons
        )
    return SchedulingResult("normal", nice=_current_nice(), cpus=cpus, reasons=reasons)


def _attempt(fn: Callable[[], None], what: str, hint: str, reasons: list[str]) -> bool:
    """Run one scheduling step; on failure add why to ``reasons`` and return False."""
    try:
        fn()
        return True
    except PermissionError as exc:
        reasons.append(f"{what} not permitted ({exc.strerror}; {hint})")
    except OSError as exc:
        reasons.append(f"{what} failed: {exc}")
    return False


def _rlimit(name: str) -> str:
    try:
        import resource

        soft, _hard = resource.getrlimit(getattr(resource, name))
        return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
    except (ImportError, AttributeError, OSError):
        return "unknown"


def _current_nice() -> int:
    try:
        return os.getpriority(os.PRIO_PROCESS, 0)
    except OSError:
        return 0


def thread_policy(tid: int) -> tuple[str, int]:
    """(policy name, FIFO priority or nice) of thread ``tid``: for logs and tests."""
    policy = os.sched_getscheduler(tid)
    if policy == os.SCHED_FIFO:
        return "fifo", os.sched_getparam(tid).sched_priority
    return "normal", os.getpriority(os.PRIO_PROCESS, tid)


class ThreadScheduler:
    """Applies a policy once, then again to each thread started after the last call."""

    def __init__(self, cfg: SchedulingConfig) -> None:
        self.cfg = cfg
        self.result: SchedulingResult | None = None
        self._done: set[int] = set()

    def apply(self) -> SchedulingResult | None:
        """Schedule the threads not seen before; returns what this call achieved (None when
        there was nothing new, or the first call found it not permitted: no point retrying
        every heartbeat)."""
        if self.result is not None and self.result.applied == "normal":
            return None
        tids = [t for t in _thread_ids() if t not in self._done]
        if not tids:
            return None
        res = apply_scheduling(self.cfg, tids)
        self._done.update(tids)
        if self.result is None:
            self.result = res
        return res
