"""`quadmanip up --profile NAME`: profiles of configs/launch.toml (no process is started)."""

from __future__ import annotations

import io
import signal
import textwrap

import pytest
from quadmanip import cli, launcher
from quadmanip.common.config import ConfigError

pytestmark = pytest.mark.unit

CONNECT = "tcp/127.0.0.1:7447"


@pytest.fixture(scope="module")
def base() -> launcher.LaunchConfig:
    return launcher.load_launch_config()


@pytest.fixture(scope="module")
def unitree(base) -> launcher.LaunchConfig:
    return launcher.apply_profile(base, "unitree-sim")


def test_no_profile_keeps_the_configured_stack(base):
    assert launcher.apply_profile(base, None) is base
    assert "sim" in base.services and "unitree-adapter" not in base.services


def test_unitree_sim_profile_loads_from_the_real_config(base):
    profile = base.profiles["unitree-sim"]
    assert profile.services[:2] == ("unitree-sim-robot", "unitree-adapter")
    assert "sim" not in profile.services
    assert tuple(profile.service_args["unitree-sim-robot"]) == ("--domain", "1")
    assert tuple(profile.service_args["unitree-adapter"]) == ("--domain", "1")


def test_unitree_sim_profile_resolves_to_the_adapter_and_the_sim_robot(base, unitree):
    names, notes, error = launcher.resolve_services(None, unitree)
    assert error is None
    assert names[:2] == ["unitree-sim-robot", "unitree-adapter"]  # robot first, then adapter
    assert "sim" not in names
    # Everything else is the base stack minus the simulator.
    base_names, _, _ = launcher.resolve_services(None, base)
    assert names[2:] == [n for n in base_names if n != "sim"]
    # Names that are not registered are skipped with a note, as for the base list.
    for name in unitree.services:
        if name not in names:
            assert any(name in note for note in notes), name


def test_profile_service_args_reach_the_command_lines(unitree):
    names, _, _ = launcher.resolve_services(None, unitree)
    lau = launcher.Launcher(
        listen=None, connect=CONNECT, services=names, service_args=unitree.service_args
    )
    parser = cli.build_parser()
    for name in ("unitree-sim-robot", "unitree-adapter"):
        argv = lau.service_argv(name)
        assert argv[-2:] == ["--domain", "1"], argv
        args, extra = parser.parse_known_args(argv[3:])  # after `python -m quadmanip.cli`
        assert (args.command, args.name, args.connect) == ("service", name, CONNECT)
        assert extra == ["--domain", "1"]
    # The other services get no extra arguments from the profile.
    assert lau.service_argv("locomotion")[-2:] == ["--connect", CONNECT]


def test_profile_service_args_merge_over_the_base_ones(tmp_path):
    path = tmp_path / "launch.toml"
    path.write_text(
        textwrap.dedent(
            """
            services = ["sim", "locomotion"]
            [service_args]
            locomotion = ["--log-level", "DEBUG"]
            unitree-adapter = ["--domain", "0"]
            [profiles.hw]
            services = ["unitree-adapter", "locomotion"]
            [profiles.hw.service_args]
            unitree-adapter = ["--domain", "3"]
            """
        )
    )
    cfg = launcher.apply_profile(launcher.load_launch_config(str(path)), "hw")
    assert cfg.services == ("unitree-adapter", "locomotion")
    assert tuple(cfg.service_args["locomotion"]) == ("--log-level", "DEBUG")  # kept
    assert tuple(cfg.service_args["unitree-adapter"]) == ("--domain", "3")  # overridden


def test_profiles_are_loaded_strictly(tmp_path):
    path = tmp_path / "launch.toml"
    path.write_text('[profiles.hw]\nservice = ["sim"]\n')
    with pytest.raises(ConfigError, match="service"):
        launcher.load_launch_config(str(path))


def test_unknown_profile_is_a_usage_error_naming_the_known_ones():
    out = io.StringIO()
    assert launcher.up(profile="no-such-profile", out=out) == launcher.EXIT_USAGE
    text = out.getvalue()
    assert "no-such-profile" in text and "unitree-sim" in text and "known profiles" in text
    # Nothing was started, so no signal handler was installed in this process either.
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_up_help_mentions_profile(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["up", "--help"])
    assert exc.value.code == 0
    assert "--profile" in capsys.readouterr().out


def test_cli_passes_the_profile_to_up(up_calls):
    seen = up_calls
    assert cli.main(["up", "--profile", "unitree-sim"]) == 0
    assert seen["profile"] == "unitree-sim"
    assert cli.main(["up"]) == 0
    assert seen["profile"] is None
