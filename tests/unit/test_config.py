"""Strict TOML → frozen dataclass loading (issue 2, item 4)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import pytest
from quadmanip.common.bus import BusConfig, apply_env, load_bus_config
from quadmanip.common.config import (
    ConfigError,
    config_path,
    from_dict,
    load_config,
    to_dict,
)
from quadmanip.paths import CONFIG_DIR

pytestmark = pytest.mark.unit


@dataclasses.dataclass(frozen=True)
class Gains:
    kp: float
    kd: float = 1.0


@dataclasses.dataclass(frozen=True)
class Ctrl:
    name: str
    rate_hz: int
    gains: Gains
    legs: tuple[str, ...] = ("FL", "FR", "RL", "RR")
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mode: Literal["walk", "stand"] = "stand"
    limits: list[float] = dataclasses.field(default_factory=lambda: (1.0,))
    note: str | None = None
    table: dict[str, float] = dataclasses.field(default_factory=dict)


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "ctrl.toml"
    p.write_text(text)
    return p


GOOD = """
name = "mpc"
rate_hz = 500
legs = ["FL", "FR"]
offset = [0, 0.5, 1]
mode = "walk"
limits = [1, 2.5]
[gains]
kp = 20
[table]
a = 1.5
"""


def test_loads_nested_tuples_literals_and_converts_ints_to_floats(tmp_path):
    cfg = load_config(Ctrl, write(tmp_path, GOOD))
    assert cfg == Ctrl(
        name="mpc",
        rate_hz=500,
        gains=Gains(kp=20.0, kd=1.0),
        legs=("FL", "FR"),
        offset=(0.0, 0.5, 1.0),
        mode="walk",
        limits=(1.0, 2.5),
        table={"a": 1.5},
    )
    assert isinstance(cfg.gains.kp, float) and isinstance(cfg.limits, tuple)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.rate_hz = 1  # type: ignore[misc]
    assert from_dict(Ctrl, to_dict(cfg)) == cfg


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("rate_hzz = 3\n" + GOOD, "unknown key 'rate_hzz'"),
        (GOOD.replace("kp = 20", "kp = 20\nki = 1"), "unknown key 'gains.ki'"),
        (GOOD.replace("rate_hz = 500", 'rate_hz = "500"'), "key 'rate_hz': expected int"),
        (GOOD.replace("rate_hz = 500", "rate_hz = 500.0"), "key 'rate_hz': expected int"),
        (GOOD.replace("rate_hz = 500", "rate_hz = true"), "key 'rate_hz': expected int"),
        (GOOD.replace("kp = 20", "kp = nan"), "key 'gains.kp': must be finite"),
        (GOOD.replace("kp = 20", "kp = true"), "key 'gains.kp': expected float"),
        (GOOD.replace('mode = "walk"', 'mode = "run"'), "key 'mode': expected one of"),
        (GOOD.replace("offset = [0, 0.5, 1]", "offset = [0, 1]"), "expected 3 items"),
        (GOOD.replace('legs = ["FL", "FR"]', "legs = [1]"), "key 'legs[0]': expected str"),
        (GOOD.replace("[gains]\nkp = 20", "gains = 3"), "expected a table for Gains"),
        (GOOD.replace("[gains]\nkp = 20", "[gains]\nkd = 2"), "key 'gains.kp': missing"),
        (GOOD.replace('name = "mpc"', ""), "key 'name': missing"),
        ("name = [", "invalid TOML"),
    ],
)
def test_bad_files_raise_config_error_naming_file_and_key(tmp_path, text, needle):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load_config(Ctrl, path)
    assert needle in str(exc.value)
    assert str(path) in str(exc.value)


def test_overrides_dotted_and_nested_are_validated(tmp_path):
    path = write(tmp_path, GOOD)
    cfg = load_config(Ctrl, path, {"gains.kd": 3, "rate_hz": 250, "note": "x"})
    assert (cfg.gains.kd, cfg.gains.kp, cfg.rate_hz, cfg.note) == (3.0, 20.0, 250, "x")
    cfg = load_config(Ctrl, path, {"gains": {"kp": 5}})
    assert cfg.gains == Gains(kp=5.0, kd=1.0)
    with pytest.raises(ConfigError, match="unknown key 'gains.kx'"):
        load_config(Ctrl, path, {"gains.kx": 1})


def test_section_and_names_resolve_under_config_dir(tmp_path):
    path = tmp_path / "multi.toml"
    path.write_text("[gains]\nkp = 2\n[other]\nx = 1\n")
    assert load_config(Gains, path, section="gains") == Gains(kp=2.0)
    with pytest.raises(ConfigError, match=r"no table \[missing\]"):
        load_config(Gains, path, section="missing")
    assert config_path("bus") == CONFIG_DIR / "bus.toml"
    assert config_path("robot/x") == CONFIG_DIR / "robot" / "x.toml"
    assert config_path(path) == path
    with pytest.raises(ConfigError, match="not found"):
        load_config(Gains, "no_such_config_name")


def test_dataclass_validation_errors_become_config_errors(tmp_path):
    path = tmp_path / "bus.toml"
    path.write_text('mode = "bogus"\n')
    with pytest.raises(ConfigError, match="(mode|expected one of)"):
        load_config(BusConfig, path)
    path.write_text("close_timeout_s = 0\n")
    with pytest.raises(ConfigError, match="close_timeout_s"):
        load_config(BusConfig, path)


def test_bus_toml_loads_and_environment_overrides_connect(monkeypatch):
    monkeypatch.delenv("QM_ZENOH_CONNECT", raising=False)
    monkeypatch.delenv("QM_ZENOH_MODE", raising=False)
    monkeypatch.delenv("QM_ZENOH_LISTEN", raising=False)
    base = load_bus_config()
    assert base.mode == "peer" and base.multicast_scouting is False
    assert base.connect == ("tcp/127.0.0.1:7447",)
    assert base.close_timeout_s <= 2.0
    monkeypatch.setenv("QM_ZENOH_CONNECT", "tcp/router:7447, tcp/10.0.0.2:7447")
    monkeypatch.setenv("QM_ZENOH_MODE", "client")
    cfg = load_bus_config()
    assert cfg.connect == ("tcp/router:7447", "tcp/10.0.0.2:7447")
    assert cfg.mode == "client"
    pinned = dataclasses.replace(base, env_override=False)
    assert apply_env(pinned) == pinned
    assert apply_env(base, {"QM_ZENOH_LISTEN": "tcp/0.0.0.0:0"}).listen == ("tcp/0.0.0.0:0",)
