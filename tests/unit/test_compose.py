"""compose.yaml stays in step with the service registry, and every command parses."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from quadmanip import services_registry
from quadmanip.cli import build_parser

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


@pytest.fixture(scope="module")
def compose() -> dict:
    with (ROOT / "compose.yaml").open() as fh:
        return yaml.load(fh, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass


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
            # `quadmanip service NAME` for exactly this service, and nothing unparsed.
            assert args.command == "service", name
            assert args.name == name
            assert extra == []


def test_services_reach_the_router_from_the_environment(compose):
    router_port = compose["services"]["router"]["command"][-1].rsplit(":", 1)[1]
    for name, svc in compose["services"].items():
        if name == "router":
            continue
        assert svc["environment"]["QM_ZENOH_CONNECT"] == f"tcp/router:{router_port}", name
        assert "router" in svc["depends_on"], name
        assert svc["image"] == compose["services"]["router"]["image"], name


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
