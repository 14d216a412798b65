"""compose.yaml stays in step with the registry and launch.toml; every command parses.

compose.unitree-sim.yaml (the override that runs the stack on the Unitree adapter) only
switches ``sim`` off. Docker is not needed: the files are checked as YAML.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

import pytest
import yaml
from quadmanip import services_registry
from quadmanip.cli import build_parser
from quadmanip.launcher import load_launch_config

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]


class _StrictLoader(yaml.SafeLoader):
    """PyYAML keeps the last of two equal keys silently; a duplicated service must fail."""

    def construct_mapping(self, node, deep=False):
        keys = [k.value for k, _ in node.value if k.tag != "tag:yaml.org,2002:merge"]
        dup = {k for k in keys if keys.count(k) > 1}
        if dup:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate keys {sorted(dup)}", node.start_mark
            )
        return super().construct_mapping(node, deep=deep)


UNITREE_SERVICES = ("unitree-sim-robot", "unitree-adapter")


def _load(name: str) -> dict:
    with (ROOT / name).open() as fh:
        return yaml.load(fh, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass


@pytest.fixture(scope="module")
def compose() -> dict:
    return _load("compose.yaml")


@pytest.fixture(scope="module")
def override() -> dict:
    return _load("compose.unitree-sim.yaml")


def _service_parser(name: str) -> argparse.ArgumentParser:
    """The parser of service ``name``'s own arguments (what `quadmanip service` passes on)."""
    from quadmanip.common.service import Service
    from quadmanip.common.service import build_parser as service_parser

    module = importlib.import_module(services_registry.entry_point(name).module)
    if callable(getattr(module, "build_parser", None)):
        return module.build_parser()  # a tool that is not a Service (unitree-sim-robot)
    # The Service defined there (its .name may differ: unitree-adapter plays "sim").
    found = [
        v
        for v in vars(module).values()
        if isinstance(v, type) and issubclass(v, Service) and v.__module__ == module.__name__
    ]
    assert len(found) == 1, f"{name}: want one Service class in {module.__name__}, got {found}"
    return service_parser(found[0])


def test_strict_loader_rejects_duplicate_keys():
    with pytest.raises(yaml.constructor.ConstructorError, match="duplicate"):
        yaml.load("services:\n  a: 1\n  a: 2\n", Loader=_StrictLoader)  # noqa: S506


def test_services_match_registry(compose):
    assert set(compose["services"]) == {"router", *services_registry.names()}


def test_every_command_parses_with_the_cli(compose):
    parser = build_parser()
    for name, svc in compose["services"].items():
        command = svc["command"]
        assert isinstance(command, list) and all(isinstance(a, str) for a in command), name
        args, extra = parser.parse_known_args(command)
        if name == "router":
            assert args.command == "router"
            assert "--listen" in [*args.args, *extra]
        else:
            # `quadmanip service NAME` for exactly this service; what the CLI leaves
            # unparsed goes to the service, whose own parser must accept all of it.
            assert args.command == "service", name
            assert args.name == name
            if extra:
                try:
                    _service_parser(name).parse_args(extra)
                except SystemExit:
                    pytest.fail(f"{name}: the service rejects {extra}")


def test_services_reach_the_router_from_the_environment(compose):
    router_port = compose["services"]["router"]["command"][-1].rsplit(":", 1)[1]
    for name, svc in compose["services"].items():
        if name == "router":
            continue
        assert svc["environment"]["QM_ZENOH_CONNECT"] == f"tcp/router:{router_port}", name
        assert "router" in svc["depends_on"], name
        assert svc["image"] == compose["services"]["router"]["image"], name


def test_restart_policy_matches_the_launcher(compose):
    # Containers and `quadmanip up` recover from a crashed service (or router) the same way:
    # restart on failure, leave a clean exit alone.
    policy = load_launch_config().restart.policy
    assert policy == "on-failure"
    for name, svc in compose["services"].items():
        assert svc["restart"] == policy, name


def test_unitree_services_are_only_in_the_unitree_sim_profile(compose):
    for name, svc in compose["services"].items():
        if name in UNITREE_SERVICES:
            assert svc["profiles"] == ["unitree-sim"], name
        else:
            assert "profiles" not in svc, name  # a plain `docker compose up` starts it


def test_unitree_adapter_talks_to_the_sim_robot(compose):
    robot = compose["services"]["unitree-sim-robot"]
    adapter = compose["services"]["unitree-adapter"]
    # One DDS domain for both, and one network namespace for DDS on loopback.
    assert robot["command"][-2:] == adapter["command"][-2:] == ["--domain", "1"]
    assert adapter["network_mode"] == "service:unitree-sim-robot"
    assert "unitree-sim-robot" in adapter["depends_on"]
    assert "network_mode" not in robot and "ports" not in adapter
    # Real-time loops, like sim's.
    for svc in (robot, adapter):
        assert svc["cap_add"] == compose["services"]["sim"]["cap_add"]
        assert svc["ulimits"] == compose["services"]["sim"]["ulimits"]


def test_override_file_disables_sim_only(compose, override):
    assert set(override) == {"services"}
    assert override["services"] == {"sim": {"profiles": ["sim-off"]}}
    # With the override and --profile unitree-sim, a service starts when it has no profiles
    # or the unitree-sim one; the override's keys replace compose.yaml's.
    merged = {n: {**s, **override["services"].get(n, {})} for n, s in compose["services"].items()}
    started = {n for n, s in merged.items() if "unitree-sim" in s.get("profiles", ["unitree-sim"])}
    assert started == set(compose["services"]) - {"sim"}
    assert set(UNITREE_SERVICES) <= started


def test_registered_entry_points_exist():
    # A registry entry must name a module that is really there (no placeholders).
    assert {n: p for n, p in services_registry.available().items() if p} == {}


def test_dockerfile_has_headless_rendering_and_pins():
    text = (ROOT / "Dockerfile").read_text()
    assert text.startswith("#") and "FROM python:3.11-slim" in text
    for lib in ("libegl1", "libgl1", "libgles2", "libosmesa6"):
        assert lib in text
    assert "MUJOCO_GL=egl" in text
    assert "torch==2.13.0" in text
    assert 'ENTRYPOINT ["quadmanip"]' in text
