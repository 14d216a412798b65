"""The ``quadmanip`` command line: router, services, launcher, demo, benchmarks, tools.

Sub-commands that belong to other modules (router, bench targets, sim snapshot) are
imported lazily, so ``quadmanip --help`` is instant and a module that is not installed yet
gives a clear message instead of a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from quadmanip import services_registry
from quadmanip.common import keys

# Dispatch targets named in the shared contracts: sub-command -> "module:function".
BENCH_TARGETS: dict[str, str] = {
    "bus": "quadmanip.testbench.bench_bus:main",
    "sim": "quadmanip.testbench.bench_sim:main",
    "locomotion": "quadmanip.testbench.bench_locomotion:main",
    "manipulation": "quadmanip.testbench.bench_manipulation:main",
    "robustness": "quadmanip.testbench.bench_robustness:main",
    "navigation": "quadmanip.testbench.bench_navigation:main",
    "perception": "quadmanip.testbench.bench_perception:main",
    "tidyup": "quadmanip.testbench.bench_tidyup:main",
}
ROUTER_TARGET = "quadmanip.common.router:main"
SIM_TOOLS: dict[str, str] = {"snapshot": "quadmanip.sim.snapshot:main"}
MAP_TARGET = "quadmanip.testbench.map_house:main"
PERCEPTION_TOOLS: dict[str, str] = {
    "dataset": "quadmanip.testbench.perception_dataset:main",
    "train": "quadmanip.services.perception.train:main",
    "evaluate": "quadmanip.testbench.detection_eval:main",
    "replay": "quadmanip.services.perception.rejections:main",
}

EXIT_UNAVAILABLE = 3


class Unavailable(RuntimeError):
    """A dispatch target's module is not installed (yet)."""


def _resolve(target: str) -> Callable[[list[str]], int]:
    module_name, _, func_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        # Only "this very module is missing" means not installed; a missing dependency
        # inside it is a real error and should surface with its traceback.
        if exc.name and module_name.startswith(exc.name):
            raise Unavailable(f"{module_name} is not installed yet") from exc
        raise
    func = getattr(module, func_name, None)
    if not callable(func):
        raise Unavailable(f"{target} is not callable")
    return func


def _dispatch(target: str, argv: Sequence[str], what: str) -> int:
    try:
        func = _resolve(target)
    except Unavailable as exc:
        print(f"quadmanip {what}: not available: {exc}", file=sys.stderr)
        if "-h" in argv or "--help" in argv:
            return 0
        return EXIT_UNAVAILABLE
    return int(func(list(argv)) or 0)


def _die_with_parent() -> None:
    """Children of ``quadmanip up`` ask the kernel for SIGTERM when the launcher dies.

    The launcher sets ``QM_PARENT_PID``; if the parent is already gone (the race between
    fork and prctl) exit at once. Linux only; elsewhere a no-op.
    """
    parent = os.environ.pop("QM_PARENT_PID", None)
    if parent is None or not sys.platform.startswith("linux"):
        return
    import ctypes

    pr_set_pdeathsig = 1
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(pr_set_pdeathsig, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:
        sys.exit(EXIT_UNAVAILABLE)


# ------------------------------------------------------------------------------ commands


def _cmd_router(args: argparse.Namespace, extra: list[str]) -> int:
    return _dispatch(ROUTER_TARGET, [*args.args, *extra], "router")


def _cmd_service(args: argparse.Namespace, extra: list[str]) -> int:
    try:
        func = services_registry.load(args.name)
    except services_registry.ServiceUnavailable as exc:
        print(f"quadmanip service: {exc}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    argv: list[str] = []
    if args.config:
        argv += ["--config", args.config]
    if args.robot:
        argv += ["--robot", args.robot]
    if args.connect:
        argv += ["--connect", args.connect]
        os.environ["QM_ZENOH_CONNECT"] = args.connect
    return int(func(argv + extra) or 0)


def _cmd_up(args: argparse.Namespace, extra: list[str]) -> int:
    from quadmanip.launcher import up

    return up(
        services=args.services,
        router=args.router,
        listen=args.listen,
        connect=args.connect,
        robot=args.robot,
        config=args.config,
        profile=args.profile,
        restart=args.restart,
    )


def _cmd_demo(args: argparse.Namespace, extra: list[str]) -> int:
    from quadmanip import demo

    return demo.main([*args.args, *extra])


def _cmd_tidyup(args: argparse.Namespace, extra: list[str]) -> int:
    from quadmanip import tidyup

    return tidyup.main([*args.args, *extra])


def _cmd_bench(args: argparse.Namespace, extra: list[str]) -> int:
    return _dispatch(BENCH_TARGETS[args.target], [*args.args, *extra], f"bench {args.target}")


def _cmd_map(args: argparse.Namespace, extra: list[str]) -> int:
    return _dispatch(MAP_TARGET, [*args.args, *extra], "map")


def _cmd_perception(args: argparse.Namespace, extra: list[str]) -> int:
    target = PERCEPTION_TOOLS[args.tool]
    return _dispatch(target, [*args.args, *extra], f"perception {args.tool}")


def _cmd_sim(args: argparse.Namespace, extra: list[str]) -> int:
    return _dispatch(SIM_TOOLS[args.tool], [*args.args, *extra], f"sim {args.tool}")


def _cmd_keys(args: argparse.Namespace, extra: list[str]) -> int:
    try:
        keys.validate_robot_name(args.robot)
    except ValueError as exc:
        print(f"quadmanip keys: {exc}", file=sys.stderr)
        return 2
    if args.readme:
        return _update_readme(Path(args.readme), keys.render_key_table_markdown())
    print(keys.render_key_table_markdown(args.robot), end="")
    return 0


README_KEYS_START = "<!-- keys:start"
README_KEYS_END = "<!-- keys:end -->"


def readme_key_block(text: str) -> tuple[int, int]:
    """(start, end) offsets of the generated key table inside the README's markers."""
    start = text.find(README_KEYS_START)
    end = text.find(README_KEYS_END)
    if start < 0 or end < start:
        raise ValueError(f"no '{README_KEYS_START} ... {README_KEYS_END}' block")
    return text.index("\n", start) + 1, end


def _update_readme(path: Path, table: str) -> int:
    text = path.read_text()
    try:
        start, end = readme_key_block(text)
    except ValueError as exc:
        print(f"quadmanip keys: {path}: {exc}", file=sys.stderr)
        return 2
    if text[start:end] != table:
        path.write_text(text[:start] + table + text[end:])
        print(f"updated the key table in {path}")
    else:
        print(f"key table in {path} is current")
    return 0


def _cmd_services(args: argparse.Namespace, extra: list[str]) -> int:
    table = services_registry.available()
    if not table:
        print("no services registered yet")
    for name, problem in table.items():
        target = services_registry.SERVICES[name]
        print(f"{name:<14} {target:<50} {'ok' if problem is None else problem}")
    return 0


# -------------------------------------------------------------------------------- parser

NO_EXTRA = {"up", "keys", "services"}


def build_parser() -> argparse.ArgumentParser:
    """The full argparse tree (also used by tests to check compose.yaml's commands)."""
    parser = argparse.ArgumentParser(
        prog="quadmanip",
        description="Quadruped robot with an arm that tidies a house: Zenoh services and tools.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "router",
        help="run a Zenoh router",
        description="Run a Zenoh router (arguments go to quadmanip.common.router).",
        add_help=False,
    )
    p.set_defaults(func=_cmd_router, args=[])

    names = services_registry.names()
    p = sub.add_parser(
        "service",
        help="run one service from the registry",
        description="Run one service in this process. Registered: "
        + (", ".join(names) or "none yet")
        + ". Extra arguments are passed to the service.",
    )
    p.add_argument("name", metavar="NAME", help="service name (see `quadmanip services`)")
    p.add_argument("--config", metavar="FILE", help="service config (TOML name or path)")
    p.add_argument(
        "--robot", metavar="NAME", help=f"robot name in the keys (default {keys.DEFAULT_ROBOT})"
    )
    p.add_argument(
        "--connect",
        metavar="EP",
        help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447 (sets QM_ZENOH_CONNECT)",
    )
    p.set_defaults(func=_cmd_service)

    p = sub.add_parser(
        "up",
        help="router + configured services as child processes",
        description="Start a Zenoh router and the services of configs/launch.toml as child "
        "processes with prefixed logs. Ctrl-C/SIGTERM stops all. A child that fails (non-zero "
        "exit or a signal) is restarted with a growing backoff ([restart] of launch.toml); "
        "one that fails too often, or any that dies under --restart no, stops the rest and "
        "the exit code is 1.",
    )
    p.add_argument("--services", metavar="A,B", help="comma-separated services (overrides config)")
    p.add_argument(
        "--router",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="start a router child (default from launch.toml)",
    )
    p.add_argument("--listen", metavar="EP", help="router listen endpoint (e.g. tcp/0.0.0.0:7447)")
    p.add_argument("--connect", metavar="EP", help="with --no-router: an existing router")
    p.add_argument("--robot", metavar="NAME", help="robot name passed to every service")
    p.add_argument("--config", default="launch", metavar="FILE", help="launch config (TOML)")
    p.add_argument(
        "--profile",
        metavar="NAME",
        help="a [profiles.NAME] of the launch config: its services replace the list, its "
        "service_args add to the base ones (e.g. unitree-sim: Unitree adapter + simulated robot)",
    )
    p.add_argument(
        "--restart",
        choices=("no", "on-failure"),
        default=None,
        help="restart policy of every child, overriding launch.toml's [restart] "
        "(on-failure: restart a child that exits non-zero or by a signal; no: any exit "
        "stops everything)",
    )
    p.set_defaults(func=_cmd_up)

    p = sub.add_parser(
        "demo",
        help="start the stack that exists and show it working",
        description="Run the demo (arguments go to quadmanip.demo; try `demo --help`).",
        add_help=False,
    )
    p.set_defaults(func=_cmd_demo, args=[])

    p = sub.add_parser(
        "tidyup",
        help="run the tidy-up task on a simulated stack and report it",
        description="Run the tidy-up (arguments go to quadmanip.tidyup; try `tidyup --help`).",
        add_help=False,
    )
    p.set_defaults(func=_cmd_tidyup, args=[])

    p = sub.add_parser(
        "bench",
        help="benchmarks with JSON output",
        description="Run a benchmark; arguments (--json FILE, ...) go to the benchmark module.",
    )
    p.add_argument("target", choices=sorted(BENCH_TARGETS), help="what to benchmark")
    p.add_argument("args", nargs=argparse.REMAINDER, help="benchmark arguments (try --help)")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser(
        "map",
        help="map the house: explore with navigation, save the map",
        description="The robot explores the house (sim, locomotion, navigation in mapping "
        "mode) and the map is saved in the map_server format (try --help after 'map').",
    )
    p.add_argument("args", nargs=argparse.REMAINDER, help="mapping arguments (try --help)")
    p.set_defaults(func=_cmd_map)

    p = sub.add_parser(
        "perception",
        help="detector tools: render a labelled dataset, train, evaluate, replay rejections",
        description="Perception tools: `dataset` renders labelled camera frames (COCO), "
        "`train` trains the detector (resumable), `evaluate` scores it, `replay` re-runs "
        "rejected grasp estimates saved by the node (try --help after each).",
    )
    p.add_argument("tool", choices=sorted(PERCEPTION_TOOLS), help="tool to run")
    p.add_argument("args", nargs=argparse.REMAINDER, help="tool arguments (try --help)")
    p.set_defaults(func=_cmd_perception)

    p = sub.add_parser("sim", help="simulator tools", description="Simulator tools.")
    p.add_argument("tool", choices=sorted(SIM_TOOLS), help="tool to run")
    p.add_argument("args", nargs=argparse.REMAINDER, help="tool arguments (try --help)")
    p.set_defaults(func=_cmd_sim)

    p = sub.add_parser(
        "keys", help="print the key table", description="Print the key table (Markdown)."
    )
    p.add_argument(
        "--robot",
        default=keys.DEFAULT_ROBOT,
        metavar="NAME",
        help=f"robot name (default {keys.DEFAULT_ROBOT})",
    )
    p.add_argument(
        "--readme", metavar="FILE", help="rewrite the generated table inside FILE's markers"
    )
    p.set_defaults(func=_cmd_keys)

    p = sub.add_parser(
        "services",
        help="list registered services",
        description="List the service registry and whether each entry point is importable.",
    )
    p.set_defaults(func=_cmd_services)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point ``quadmanip``."""
    _die_with_parent()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "map":  # every option after `map` is the mapping tool's own
        return _dispatch(MAP_TARGET, argv[1:], "map")
    if len(argv) >= 3 and argv[0] == "service" and not argv[1].startswith("-"):
        if {"-h", "--help"} & set(argv[2:]):
            # `service NAME --help` shows the service's own options, not ours.
            return _cmd_service(
                argparse.Namespace(name=argv[1], config=None, robot=None, connect=None), ["--help"]
            )
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and args.command in NO_EXTRA:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return int(args.func(args, extra))


if __name__ == "__main__":
    sys.exit(main())
