"""``swarm-phd train`` with ``--engine sb3|rllib``: the SB3 engine's options, the RLlib
engine's own (:func:`agents.rllib.train.add_engine_arguments`), and the dispatch.

Registered in the CLI in place of ``agents.sb3.train``; ``--engine sb3`` (the default) runs
:func:`agents.sb3.train.run` unchanged, ``--engine rllib`` runs :func:`agents.rllib.train.run`.
"""

from __future__ import annotations

import argparse

ENGINES = ("sb3", "rllib")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from agents.rllib.train import add_engine_arguments
    from agents.sb3.train import add_arguments as add_sb3_arguments

    add_sb3_arguments(parser)
    parser.add_argument(
        "--engine",
        default="sb3",
        choices=ENGINES,
        help="sb3: stable-baselines3 in this process (+ --num-cpus workers); rllib: Ray RLlib "
        "with --num-env-runners runner processes, local or on a cluster (--address); "
        "docs/scaling.md",
    )
    add_engine_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if args.engine == "rllib":
        from agents.rllib.train import run as run_rllib

        return run_rllib(args)
    from agents.sb3.train import run as run_sb3

    return run_sb3(args)
