"""The `quadmanip` CLI: help everywhere, dispatch, service registry, launcher helpers, README."""

from __future__ import annotations

import io
import re
import signal
import sys
import textwrap
from pathlib import Path

import pytest
from quadmanip import cli, launcher, services_registry
from quadmanip.common import keys
from quadmanip.common.config import ConfigError

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]


def run_cli(argv, capsys):
    """Run the CLI in process; returns (exit code, stdout + stderr)."""
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse's --help and usage errors
        code = exc.code if isinstance(exc.code, int) else 1
    captured = capsys.readouterr()
    return code, captured.out + captured.err


HELP_COMMANDS = [
    [],
    ["router"],
    ["service"],
    ["up"],
    ["demo"],
    ["bench"],
    *[["bench", target] for target in sorted(cli.BENCH_TARGETS)],
    ["sim"],
    *[["sim", tool] for tool in sorted(cli.SIM_TOOLS)],
    ["keys"],
    ["services"],
]


@pytest.mark.parametrize("command", HELP_COMMANDS, ids=lambda c: " ".join(c) or "quadmanip")
def test_help_everywhere(command, capsys):
    code, out = run_cli([*command, "--help"], capsys)
    assert code == 0, out
    # Either argparse usage (ours or the dispatched module's) or a clear "not available yet".
    assert "usage:" in out or "not available" in out, out


def test_top_level_help_lists_every_sub_command(capsys):
    _, out = run_cli(["--help"], capsys)
    for name in ("router", "service", "up", "demo", "bench", "sim", "keys"):
        assert re.search(rf"^\s+{name}\s", out, re.M), name


def test_missing_sub_command_is_a_usage_error(capsys):
    code, out = run_cli([], capsys)
    assert code == 2 and "usage:" in out


def test_bench_of_a_module_not_installed_says_so(capsys, monkeypatch):
    monkeypatch.setitem(cli.BENCH_TARGETS, "sim", "quadmanip.no_such_module:main")
    code, out = run_cli(["bench", "sim", "--json", "x.json"], capsys)
    assert code == cli.EXIT_UNAVAILABLE
    assert "not available" in out and "quadmanip.no_such_module" in out


def test_bench_dispatch_passes_arguments_through(capsys, monkeypatch, tmp_path):
    mod = tmp_path / "qm_fake_bench.py"
    mod.write_text("SEEN = []\ndef main(argv):\n    SEEN.append(argv)\n    return 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.BENCH_TARGETS, "sim", "qm_fake_bench:main")
    code, _ = run_cli(["bench", "sim", "--json", "out.json", "--steps", "5"], capsys)
    assert code == 7
    assert sys.modules["qm_fake_bench"].SEEN == [["--json", "out.json", "--steps", "5"]]


def test_router_arguments_reach_the_router_parser():
    args, extra = cli.build_parser().parse_known_args(["router", "--listen", "tcp/0.0.0.0:7447"])
    assert args.command == "router" and [*args.args, *extra] == ["--listen", "tcp/0.0.0.0:7447"]


# ----------------------------------------------------------------------- service registry


@pytest.fixture
def fake_service(tmp_path, monkeypatch):
    mod = tmp_path / "qm_fake_service.py"
    mod.write_text(
        textwrap.dedent(
            """
            import os
            CALLS = []
            def main(argv):
                CALLS.append((argv, os.environ.get("QM_ZENOH_CONNECT")))
                return 0
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(services_registry.SERVICES, "fake", "qm_fake_service:main")
    monkeypatch.delenv("QM_ZENOH_CONNECT", raising=False)
    yield "qm_fake_service"
    sys.modules.pop("qm_fake_service", None)


def test_service_runs_the_registered_entry_point_with_its_options(fake_service, capsys):
    code, _ = run_cli(
        ["service", "fake", "--robot", "dog2", "--connect", "tcp/10.0.0.5:7447", "--x", "1"],
        capsys,
    )
    assert code == 0
    calls = sys.modules[fake_service].CALLS
    assert calls == [
        (["--robot", "dog2", "--connect", "tcp/10.0.0.5:7447", "--x", "1"], "tcp/10.0.0.5:7447")
    ]


def test_service_help_is_the_services_own(fake_service, capsys):
    code, _ = run_cli(["service", "fake", "--help"], capsys)
    assert code == 0
    assert sys.modules[fake_service].CALLS == [(["--help"], None)]


def test_unknown_service_is_reported_not_raised(capsys):
    code, out = run_cli(["service", "no_such_service"], capsys)
    assert code == cli.EXIT_UNAVAILABLE
    assert "unknown service 'no_such_service'" in out


def test_registry_reports_unimportable_and_malformed_entries(monkeypatch, fake_service):
    monkeypatch.setitem(services_registry.SERVICES, "ghost", "quadmanip.no_such.node:main")
    monkeypatch.setitem(services_registry.SERVICES, "broken", "no_colon_here")
    table = services_registry.available()
    assert table["fake"] is None
    assert "not installed" in table["ghost"] or "not importable" in table["ghost"]
    assert "bad entry" in table["broken"]
    with pytest.raises(services_registry.ServiceUnavailable, match="ghost"):
        services_registry.load("ghost")


def test_services_command_lists_the_registry(fake_service, capsys):
    code, out = run_cli(["services"], capsys)
    assert code == 0 and "fake" in out and "qm_fake_service:main" in out and "ok" in out


def test_up_refuses_unknown_services_before_starting_anything():
    out = io.StringIO()
    assert launcher.up(services="no_such_service", out=out) == launcher.EXIT_USAGE
    assert "no_such_service" in out.getvalue()
    # Nothing was started, so no signal handler was installed in this process either.
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


# ----------------------------------------------------------------------- launcher helpers


def test_endpoints():
    assert launcher.parse_endpoint("tcp/127.0.0.1:7447") == ("tcp", "127.0.0.1", 7447)
    assert launcher.parse_endpoint("tcp/[::1]:7447") == ("tcp", "::1", 7447)
    assert launcher.connect_endpoint("tcp/0.0.0.0:7447") == "tcp/127.0.0.1:7447"
    assert launcher.connect_endpoint("tcp/192.168.1.4:7000") == "tcp/192.168.1.4:7000"
    for bad in ("127.0.0.1:7447", "tcp/127.0.0.1", "tcp/host:port"):
        with pytest.raises(ValueError):
            launcher.parse_endpoint(bad)
    _, _, port = launcher.parse_endpoint(launcher.free_endpoint())
    assert 1024 <= port <= 65535


def test_describe_exit():
    assert launcher.describe_exit(-9) == "killed by SIGKILL"
    assert launcher.describe_exit(3) == "exited with code 3"


def test_launch_config_is_strict(tmp_path):
    cfg = launcher.load_launch_config()
    assert cfg.router and cfg.stop_grace_s + 0.5 <= 3.0  # up's exit budget on SIGTERM
    bad = tmp_path / "launch.toml"
    bad.write_text('router = true\nlisten = "tcp/127.0.0.1:7447"\nservice = ["sim"]\n')
    with pytest.raises(ConfigError, match="service"):
        launcher.load_launch_config(str(bad))


# ----------------------------------------------------------------------- key table / README


def test_keys_command_prints_every_topic(capsys):
    code, out = run_cli(["keys"], capsys)
    assert code == 0
    for name in keys.TOPICS:
        assert keys.key("dog1", name) in out


def test_keys_markdown_is_the_generated_table(capsys):
    code, out = run_cli(["keys", "--robot", "dog7"], capsys)
    assert code == 0 and out == keys.render_key_table_markdown("dog7")


def test_readme_key_table_is_the_generated_one():
    readme = (ROOT / "README.md").read_text()
    start, end = cli.readme_key_block(readme)
    assert readme[start:end] == keys.render_key_table_markdown(), (
        "README key table is stale: run `quadmanip keys --readme README.md`"
    )


def test_keys_readme_rewrites_only_the_marked_block(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("# x\n\n<!-- keys:start -->\n| old |\n<!-- keys:end -->\n\ntail\n")
    assert run_cli(["keys", "--readme", str(readme)], capsys)[0] == 0
    text = readme.read_text()
    assert text.startswith("# x\n\n<!-- keys:start -->\n")
    assert text.endswith("<!-- keys:end -->\n\ntail\n")
    assert keys.render_key_table_markdown() in text and "| old |" not in text
    assert "is current" in run_cli(["keys", "--readme", str(readme)], capsys)[1]
    readme.write_text("no markers\n")
    assert run_cli(["keys", "--readme", str(readme)], capsys)[0] == 2
