"""`quadmanip up`'s restart policy: the pure decision logic and the launcher acting on it.

No process is started: the launcher's children get fake ``Popen`` objects, and spawning and
signalling are replaced, so the supervision pass is driven with an explicit clock.
"""

from __future__ import annotations

import io
import itertools
import signal
import textwrap
import threading

import pytest
from quadmanip import cli, launcher
from quadmanip.common.config import ConfigError
from quadmanip.launcher import (
    EXIT_CHILD_DIED,
    EXIT_OK,
    Child,
    Launcher,
    RestartConfig,
    RestartOverride,
    RestartPolicy,
    RestartTracker,
)

pytestmark = pytest.mark.unit

SIGKILLED = -int(signal.SIGKILL)


# ------------------------------------------------------------------------------ policy


def test_backoff_doubles_from_backoff_s_up_to_the_cap():
    policy = RestartPolicy(backoff_s=0.5, backoff_max_s=5.0)
    assert [policy.backoff(n) for n in range(1, 8)] == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0, 5.0]
    assert policy.backoff(10_000) == 5.0  # no overflow for a long-running crash loop
    with pytest.raises(ValueError):
        policy.backoff(0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"policy": "always"},
        {"max_restarts": -1},
        {"window_s": 0.0},
        {"backoff_s": -0.1},
        {"backoff_s": 2.0, "backoff_max_s": 1.0},
    ],
)
def test_policy_rejects_nonsense(kwargs):
    with pytest.raises(ValueError):
        RestartPolicy(**kwargs)


def test_failures_are_restarted_with_growing_backoff_then_given_up():
    tracker = RestartTracker(RestartPolicy(max_restarts=5, window_s=60.0))
    decisions = [tracker.on_exit(SIGKILLED if i % 2 else 3, now=float(i)) for i in range(5)]
    assert [d.action for d in decisions] == ["restart"] * 5
    assert [d.attempt for d in decisions] == [1, 2, 3, 4, 5]
    assert [d.delay_s for d in decisions] == [0.5, 1.0, 2.0, 4.0, 5.0]
    assert "restart 1 of 5 within 60 s" in decisions[0].reason
    assert tracker.total == 5
    # The sixth failure within the window is a crash loop: give up, saying why.
    last = tracker.on_exit(1, now=10.0)
    assert last.action == "give-up"
    assert "5 restarts within 60 s" in last.reason and "max_restarts 5" in last.reason
    assert tracker.total == 5


def test_restarts_older_than_the_window_do_not_count():
    tracker = RestartTracker(RestartPolicy(max_restarts=2, window_s=10.0))
    assert tracker.on_exit(1, now=0.0).attempt == 1
    assert tracker.on_exit(1, now=4.0).attempt == 2
    assert tracker.recent(9.9) == 2
    # At t=10 the restart of t=0 leaves the window: one slot again, and the backoff of
    # the second restart in the window (not the third in all).
    again = tracker.on_exit(1, now=10.0)
    assert (again.action, again.attempt, again.delay_s) == ("restart", 2, 1.0)
    assert tracker.on_exit(1, now=11.0).action == "give-up"
    # A long quiet spell empties the window: the backoff starts over.
    fresh = tracker.on_exit(1, now=100.0)
    assert (fresh.action, fresh.attempt, fresh.delay_s) == ("restart", 1, 0.5)
    assert tracker.total == 4


def test_a_clean_exit_is_left_alone_under_on_failure():
    tracker = RestartTracker(RestartPolicy(max_restarts=1))
    decision = tracker.on_exit(0, now=0.0)
    assert decision.action == "leave" and "clean exit" in decision.reason
    assert tracker.total == 0 and tracker.recent(0.0) == 0  # not counted as a restart
    assert tracker.on_exit(2, now=1.0).action == "restart"


@pytest.mark.parametrize("code", [0, 1, SIGKILLED])
def test_policy_no_gives_up_on_any_exit(code):
    decision = RestartTracker(RestartPolicy(policy="no")).on_exit(code, now=0.0)
    assert decision.action == "give-up" and "'no'" in decision.reason


def test_max_restarts_zero_gives_up_on_the_first_failure():
    tracker = RestartTracker(RestartPolicy(max_restarts=0))
    assert tracker.on_exit(0, now=0.0).action == "leave"
    assert tracker.on_exit(-int(signal.SIGSEGV), now=0.0).action == "give-up"


# ------------------------------------------------------------------------------ config


def test_launch_toml_sets_the_documented_defaults():
    restart = launcher.load_launch_config().restart
    assert isinstance(restart, RestartConfig)
    assert (restart.policy, restart.max_restarts, restart.window_s) == ("on-failure", 5, 60.0)
    assert (restart.backoff_s, restart.backoff_max_s) == (0.5, 5.0)


def test_per_service_overrides_merge_over_the_base(tmp_path):
    path = tmp_path / "launch.toml"
    path.write_text(
        textwrap.dedent(
            """
            services = ["sim", "viz"]
            [restart]
            policy = "on-failure"
            max_restarts = 3
            window_s = 30.0
            backoff_s = 0.25
            backoff_max_s = 2.0
            [restart.services.viz]
            policy = "no"
            [restart.services.router]
            max_restarts = 10
            """
        )
    )
    restart = launcher.load_launch_config(str(path)).restart
    assert restart.for_child("sim") == RestartPolicy("on-failure", 3, 30.0, 0.25, 2.0)
    assert restart.for_child("viz") == RestartPolicy("no", 3, 30.0, 0.25, 2.0)
    assert restart.for_child("router") == RestartPolicy("on-failure", 10, 30.0, 0.25, 2.0)
    # --restart beats the file, per-service policies included; their limits stay.
    forced = restart.with_policy("on-failure")
    assert forced.for_child("viz").policy == "on-failure"
    assert forced.for_child("router").max_restarts == 10
    assert restart.with_policy("no").for_child("sim").policy == "no"


@pytest.mark.parametrize(
    "table",
    [
        '[restart]\npolicy = "always"\n',
        "[restart]\nretries = 3\n",
        "[restart.services.viz]\nx = 1\n",
    ],
)
def test_restart_table_is_loaded_strictly(tmp_path, table):
    path = tmp_path / "launch.toml"
    path.write_text(table)
    with pytest.raises(ConfigError):
        launcher.load_launch_config(str(path))


# ----------------------------------------------------------------- the launcher acting


class FakeProc:
    """Just what the supervision pass reads of a ``Popen``."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        return self.returncode


@pytest.fixture
def fake(monkeypatch):
    """A launcher with children ``router`` and ``sim`` on fake processes."""
    out = io.StringIO()
    lau = Launcher(
        listen=None,
        connect="tcp/127.0.0.1:7447",
        services=["sim"],
        out=out,
        restart=RestartConfig(max_restarts=2, services={"router": RestartOverride(max_restarts=1)}),
    )
    pids = itertools.count(1000)
    spawned: list[tuple[str, int]] = []
    swept: list[tuple[str, int, signal.Signals]] = []

    def spawn(child: Child) -> None:
        child.proc = FakeProc(next(pids))  # type: ignore[assignment]
        spawned.append((child.name, child.proc.pid))

    # Never signal real process groups with fake pids.
    monkeypatch.setattr(lau, "_spawn", spawn)
    monkeypatch.setattr(lau, "_signal_group", lambda c, sig: swept.append((c.name, c.pid, sig)))
    for name, pid in (("router", 10), ("sim", 20)):
        lau.children.append(Child(name, ["python", "-m", "x", name], {}, proc=FakeProc(pid)))
    return lau, out, spawned, swept


def _child(lau: Launcher, name: str) -> Child:
    return next(c for c in lau.children if c.name == name)


def test_a_killed_child_is_restarted_after_its_backoff(fake):
    lau, out, spawned, swept = fake
    assert lau.supervise(0.0) is None and spawned == []  # all running: nothing to do
    _child(lau, "sim").proc.returncode = SIGKILLED
    assert lau.supervise(1.0) is None
    assert "sim (pid 20) killed by SIGKILL; restarting in 0.5 s (restart 1 of 2" in out.getvalue()
    assert swept == [("sim", 20, signal.SIGKILL)]  # leftovers of the old group go first
    assert lau.supervise(1.4) is None and spawned == []  # still backing off
    assert lau.supervise(1.5) is None and spawned == [("sim", 1000)]
    assert _child(lau, "sim").pid == 1000 and len(lau.children) == 2
    # A second failure waits twice as long; the third in the window gives up.
    _child(lau, "sim").proc.returncode = 1
    assert lau.supervise(2.0) is None
    assert "sim (pid 1000) exited with code 1; restarting in 1 s (restart 2 of 2" in out.getvalue()
    assert lau.supervise(2.9) is None and len(spawned) == 1
    assert lau.supervise(3.0) is None and spawned[-1] == ("sim", 1001)
    _child(lau, "sim").proc.returncode = SIGKILLED
    assert lau.supervise(4.0) == (EXIT_CHILD_DIED, "sim died after 2 restarts")
    assert "error: sim (pid 1001) killed by SIGKILL; giving up: 2 restarts" in out.getvalue()


def test_the_router_is_restarted_with_its_own_limits(fake):
    lau, out, spawned, _ = fake
    _child(lau, "router").proc.returncode = SIGKILLED
    assert lau.supervise(0.0) is None
    assert lau.supervise(0.5) is None and spawned == [("router", 1000)]
    _child(lau, "router").proc.returncode = SIGKILLED
    # max_restarts 1 for the router (its override), 2 for the rest.
    assert lau.supervise(1.0) == (EXIT_CHILD_DIED, "router died after 1 restart")


def test_a_clean_exit_stays_stopped_and_the_rest_keep_running(fake):
    lau, out, spawned, _ = fake
    _child(lau, "sim").proc.returncode = 0
    assert lau.supervise(0.0) is None
    assert "sim (pid 20) exited with code 0; not restarted" in out.getvalue()
    for t in (1.0, 10.0):
        assert lau.supervise(t) is None
    assert spawned == []
    # Once every child has exited cleanly there is nothing left to supervise.
    _child(lau, "router").proc.returncode = 0
    assert lau.supervise(11.0) == (EXIT_OK, "every child exited cleanly")


def test_policy_no_stops_everything_on_the_first_exit(fake):
    lau, out, spawned, _ = fake
    lau.restart = lau.restart.with_policy("no")
    _child(lau, "sim").proc.returncode = SIGKILLED
    assert lau.supervise(0.0) == (EXIT_CHILD_DIED, "sim died")
    assert "error: sim (pid 20) killed by SIGKILL; not restarted (restart policy 'no')" in (
        out.getvalue()
    )
    assert spawned == []


def test_no_restart_while_stopping(fake):
    lau, _, spawned, _ = fake
    _child(lau, "sim").proc.returncode = SIGKILLED
    lau.supervise(0.0)
    lau._stopping = True  # stop() sets it; a pending restart must not fire afterwards
    assert lau.supervise(10.0) is None and spawned == []


def test_a_restart_that_cannot_spawn_stops_the_launcher(fake, monkeypatch):
    lau, out, _, _ = fake

    def broken_spawn(child: Child) -> None:
        raise OSError("Resource temporarily unavailable")

    _child(lau, "sim").proc.returncode = 1
    assert lau.supervise(0.0) is None
    monkeypatch.setattr(lau, "_spawn", broken_spawn)
    assert lau.supervise(1.0) == (EXIT_CHILD_DIED, "sim could not be restarted")
    assert "error: cannot restart sim: Resource temporarily unavailable" in out.getvalue()


@pytest.mark.parametrize("policy", ["no", "on-failure"])
def test_run_reports_why_it_stopped(fake, monkeypatch, policy):
    lau, out, _, _ = fake
    lau.restart = lau.restart.with_policy(policy)
    stops: list[bool] = []
    monkeypatch.setattr(lau, "start", lambda: None)  # the fake children are already "up"
    monkeypatch.setattr(lau, "stop", lambda: stops.append(True))
    _child(lau, "sim").proc.returncode = 0
    _child(lau, "router").proc.returncode = 0
    code = lau.run(threading.Event())
    assert stops == [True]
    if policy == "no":  # any exit stops everything, as before restart policies existed
        assert code == EXIT_CHILD_DIED
        assert "stopped; exit 1 because router died" in out.getvalue()
    else:
        assert code == EXIT_OK
        assert "stopped cleanly (every child exited cleanly)" in out.getvalue()


# ---------------------------------------------------------------------------- the CLI


def test_an_unknown_restart_mode_is_a_usage_error():
    out = io.StringIO()
    assert launcher.up(restart="always", out=out) == launcher.EXIT_USAGE
    assert "--restart must be one of no, on-failure" in out.getvalue()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # nothing was started


def test_cli_passes_restart_to_up(up_calls, capsys):
    seen = up_calls
    assert cli.main(["up", "--restart", "no"]) == 0
    assert seen["restart"] == "no"
    assert cli.main(["up"]) == 0
    assert seen["restart"] is None
    with pytest.raises(SystemExit):
        cli.main(["up", "--restart", "always"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        cli.main(["up", "--help"])
    assert "--restart" in capsys.readouterr().out
