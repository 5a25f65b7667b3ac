"""The ``swarm-phd`` command line. Each subcommand lives in the module that does the work; this
file only parses arguments and dispatches."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

Command = Callable[[argparse.Namespace], int]
_REGISTRY: list[tuple[str, str, Callable[[argparse.ArgumentParser], None], str]] = []


def _add(name: str, help_text: str, module: str):
    """Register a subcommand implemented by ``module.add_arguments`` and ``module.run``."""

    def configure(parser: argparse.ArgumentParser) -> None:
        import importlib

        importlib.import_module(module).add_arguments(parser)

    _REGISTRY.append((name, help_text, configure, module))


_add("demo", "run the seed's swarm for 60 s and show sensors and localization", "swarm_phd.demo")
_add("bench", "measure env throughput (steps/s, real-time factor, lidar cost)", "swarm_phd.bench")
_add(
    "evaluate",
    "reproduce the seed's localization experiment / evaluate a policy",
    "swarm_phd.evaluate",
)
_add(
    "bridge",
    "drive robots (or --loopback simulated ones) over rosbridge",
    "swarm_phd.bridge",
)
_add(
    "replay",
    "rerun localization and metrics offline on a recorded bag",
    "swarm_phd.replay",
)
_add("export-bag", "write a simulated episode as a ROS 2 bag", "swarm_phd.export_bag")
_add(
    "train",
    "train a PPO policy shared by all agents on a task (stable-baselines3)",
    "agents.sb3.train",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm-phd",
        description="UGV swarm simulator with embedded robot-centric GM-PHD localization.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help_text, configure, module in _REGISTRY:
        p = sub.add_parser(name, help=help_text, description=help_text)
        configure(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    import importlib

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except ValueError as exc:  # bad input: a clear message, no traceback
        print(f"swarm-phd {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
