"""Which of the robot's services are running, and when one went away and came back.

The launcher restarts a service that dies (``[restart]`` of ``configs/launch.toml``), so a
SIGKILLed navigation, perception, manipulation or locomotion is gone for a few seconds and
then runs again from scratch: its action goals, its memory and (for locomotion) the
standing robot are lost. The task must learn of it at once: a goal sent to a service that
vanished is never answered (the new process does not know it), and it would otherwise
wait out the whole ``action_timeout``.

:class:`ServiceWatch` is fed with what the node observes, with wall times (it reads no
clock of its own, so tests drive it with numbers):

* liveliness: every service declares ``<service>/alive``; the token vanishes with the
  process (a SIGKILL closes its sockets, so at once) and reappears when it starts again;
* heartbeats (``<service>/heartbeat``, 1 Hz): ``state`` says when a new process has
  finished its setup (``running``; its action servers exist only from then on), ``seq``
  restarts at 0 in a new process (a restart even if both token changes were missed);
* silence: no heartbeat for ``heartbeat_timeout`` counts as gone too (a hung process).

A service is *running* when its token is present and a heartbeat of this life said it
runs. Every time a service that had been seen stops running is one *outage*
(:meth:`ServiceWatch.outages`): the task compares these counts to notice restarts, and the
node cuts short the goals in flight to it.

No transport here: the node (``node.py``) wires the watch to the bus.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["RUNNING_STATES", "ServiceWatch", "Transition", "stand_command"]

#: Heartbeat states of a process that has finished its setup and serves.
RUNNING_STATES = frozenset({"running", "degraded"})


@dataclass(frozen=True)
class Transition:
    """One change of a service's state, for the log: ``went_away`` or ``back``."""

    service: str
    what: str
    why: str
    t: float


@dataclass
class _Life:
    """What is known of one service right now."""

    token: bool = False  # its liveliness token is present
    running: bool = False  # token present and a heartbeat of this life said it runs
    seen: bool = False  # it has run at least once (only then can it go away)
    seq: int | None = None  # last heartbeat seq of this life
    t_beat: float = -math.inf  # wall time of the last heartbeat (or of the token)
    t_running: float = -math.inf  # wall time this life started to run
    outages: int = 0


class ServiceWatch:
    """Running / gone / back of a set of services (see the module docstring).

    Thread-safe: liveliness and heartbeat callbacks arrive on the bus's threads while the
    task asks from its own.
    """

    def __init__(self, services: Iterable[str], heartbeat_timeout: float = 15.0) -> None:
        self.heartbeat_timeout = float(heartbeat_timeout)
        self._lives = {s: _Life() for s in services}
        self._lock = threading.Lock()
        self._transitions: list[Transition] = []

    @property
    def services(self) -> tuple[str, ...]:
        return tuple(self._lives)

    # ------------------------------------------------------------------ observations
    def liveliness(self, service: str, alive: bool, now: float) -> None:
        """The token ``<service>/alive`` appeared (``alive``) or vanished."""
        with self._lock:
            life = self._lives.get(service)
            if life is None:
                return
            if alive:
                if not life.token:
                    # a new life: its heartbeats from now on say when it runs
                    life.token, life.seq, life.t_beat = True, None, now
            else:
                life.token = False
                self._gone(service, life, "its liveliness token vanished", now)

    def heartbeat(self, service: str, seq: int, state: str, now: float) -> None:
        """A heartbeat of ``service`` with its sequence number and lifecycle state."""
        with self._lock:
            life = self._lives.get(service)
            if life is None or not life.token:
                # before the token (or after it vanished): cannot tell which life it is
                return
            if life.seq is not None and seq < life.seq:
                # counting started again: a new process, though the token never blinked
                self._gone(service, life, "its heartbeat sequence restarted", now)
            life.seq, life.t_beat = int(seq), now
            running = state in RUNNING_STATES
            if running and not life.running:
                life.running, life.seen, life.t_running = True, True, now
                self._transitions.append(Transition(service, "back", state, now))
            elif not running and life.running:
                self._gone(service, life, f"its state is {state!r}", now)

    def tick(self, now: float) -> None:
        """Check for silence: a running service whose heartbeats stopped is gone."""
        if self.heartbeat_timeout <= 0:
            return
        with self._lock:
            for service, life in self._lives.items():
                if life.running and now - life.t_beat > self.heartbeat_timeout:
                    self._gone(service, life, f"no heartbeat for {now - life.t_beat:.1f} s", now)
                    life.seq = None  # a heartbeat that comes back starts a new life

    def _gone(self, service: str, life: _Life, why: str, now: float) -> None:
        """(Under the lock.) It stopped running: one more outage if it had been running."""
        if life.running:
            life.outages += 1
            self._transitions.append(Transition(service, "went_away", why, now))
        life.running = False

    # ------------------------------------------------------------------ queries
    def running(self, service: str) -> bool:
        """It runs now (token present, its heartbeat says running)."""
        with self._lock:
            life = self._lives.get(service)
            return life is not None and life.running

    def away(self) -> set[str]:
        """The watched services that have run once and do not run now."""
        with self._lock:
            return {s for s, life in self._lives.items() if life.seen and not life.running}

    def not_running(self) -> set[str]:
        """The watched services that do not run now (never seen included)."""
        with self._lock:
            return {s for s, life in self._lives.items() if not life.running}

    def outages(self) -> dict[str, int]:
        """Per service, how many times it stopped running since it was first seen."""
        with self._lock:
            return {s: life.outages for s, life in self._lives.items()}

    def running_since(self, service: str) -> float:
        """Wall time its current life started to run (-inf when it does not run)."""
        with self._lock:
            life = self._lives.get(service)
            if life is None or not life.running:
                return -math.inf
            return life.t_running

    def drain(self) -> list[Transition]:
        """The transitions since the last call (the node logs them)."""
        with self._lock:
            out, self._transitions = self._transitions, []
        return out


def stand_command(state: str, phase: str, upright: bool) -> str | None:
    """The mode to ask locomotion for to get the robot standing (None: nothing to ask).

    Locomotion refuses ``stand`` while tripped (its latched safe mode) or lying on a side:
    ``recover`` is the explicit reset that rights the robot and stands it up. A robot
    lying damped (locomotion starts damped, and the actuators damp the legs when commands
    stop) or sitting upright is asked to ``stand``. Standing up, righting itself or
    standing already: nothing.
    """
    if state == "tripped" and phase == "safe":
        return "recover"
    if phase in ("damp", "sit"):
        return "stand" if upright else "recover"
    return None
