"""Service registry: which processes `quadmanip service NAME` and `quadmanip up` can start.

Only services that really exist are listed (no placeholders): a name here means a module
with a ``main(argv: list[str]) -> int`` entry point. Each service engineer adds one line when
their ``node.py`` lands. The registry is tolerant: an entry whose module is not importable is
reported with the reason instead of crashing the CLI, so one broken service never takes the
launcher, the compose check or ``--help`` down with it.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable
from dataclasses import dataclass

# name -> "module:function"; the function takes argv (list[str]) and returns an exit code.
SERVICES: dict[str, str] = {
    "sim": "quadmanip.sim.node:main",
    "locomotion": "quadmanip.services.locomotion.node:main",
    "manipulation": "quadmanip.services.manipulation.node:main",
    "perception": "quadmanip.services.perception.node:main",
    "navigation": "quadmanip.services.navigation.node:main",
    "behavior": "quadmanip.services.behavior.node:main",
    "viz": "quadmanip.services.viz.node:main",
    # The hardware adapter fills the sim's role on a Unitree SDK2 robot (docs/hardware.md),
    # and the simulated robot it is tested against (test and demo tooling).
    "unitree-adapter": "quadmanip.hardware.unitree.node:main",
    "unitree-sim-robot": "quadmanip.testbench.unitree_sim_robot:main",
}


class ServiceUnavailable(RuntimeError):
    """A service is unknown or its entry point cannot be imported."""


@dataclass(frozen=True)
class EntryPoint:
    """A parsed ``module:function`` registry entry."""

    name: str
    module: str
    function: str


def names() -> list[str]:
    """Registered service names, in registry order (which is also the start order)."""
    return list(SERVICES)


def entry_point(name: str) -> EntryPoint:
    """Parse the registry entry of ``name``; raises ServiceUnavailable if it is not registered."""
    try:
        target = SERVICES[name]
    except KeyError:
        known = ", ".join(SERVICES) or "none registered yet"
        raise ServiceUnavailable(f"unknown service {name!r} (registered: {known})") from None
    module, sep, function = target.partition(":")
    if not sep or not module or not function:
        raise ServiceUnavailable(f"service {name!r}: bad entry {target!r}, want 'module:function'")
    return EntryPoint(name, module, function)


def problem(name: str) -> str | None:
    """Why ``name`` cannot run, or None if its module can be found.

    Uses ``find_spec`` rather than importing, so checking every service stays cheap
    (a sim import pulls in MuJoCo).
    """
    try:
        ep = entry_point(name)
    except ServiceUnavailable as exc:
        return str(exc)
    try:
        spec = importlib.util.find_spec(ep.module)
    except (ImportError, ValueError) as exc:
        return f"service {name!r}: module {ep.module!r} not importable ({exc})"
    if spec is None:
        return f"service {name!r}: module {ep.module!r} is not installed"
    return None


def available() -> dict[str, str | None]:
    """Every registered service mapped to its problem (None when it looks runnable)."""
    return {name: problem(name) for name in SERVICES}


def load(name: str) -> Callable[[list[str]], int]:
    """Import and return the entry-point function of ``name``."""
    ep = entry_point(name)
    try:
        module = importlib.import_module(ep.module)
    except ImportError as exc:
        raise ServiceUnavailable(f"service {name!r}: cannot import {ep.module!r}: {exc}") from exc
    func = getattr(module, ep.function, None)
    if not callable(func):
        raise ServiceUnavailable(f"service {name!r}: {ep.module}:{ep.function} is not callable")
    return func
