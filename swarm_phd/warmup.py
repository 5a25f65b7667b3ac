"""``swarm-phd warmup``: compile (or load) every numba kernel ahead of time, with progress
(the work: :mod:`swarm_env.warmup`)."""

from __future__ import annotations

import argparse

from swarm_env.warmup import warmup


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        default="lab-3m-4",
        help="env preset to step (kernels do not depend on its size: the small one is quickest)",
    )


def run(args: argparse.Namespace) -> int:
    result = warmup(args.preset)
    if result["compiled"]:
        head = f"{result['kernels']} of {result['kernels_found']} kernels compiled"
    else:
        head = f"{result['kernels_found']} kernels loaded from the cache"
    print(
        f"{head} in {result['seconds']:.1f} s; {result['cached_on_disk']} of "
        f"{result['kernels_found']} cached in {result['cache']}"
    )
    return 0
