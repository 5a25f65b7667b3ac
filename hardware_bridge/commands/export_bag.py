"""``swarm-phd export-bag --out PATH --duration S``: write a simulated episode (scripted wander
policy) as a ROS 2 bag, laid out exactly as the bridge records robots, so ``swarm-phd replay``
is exercised on data the simulator wrote."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="new bag directory (must not exist)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    parser.add_argument("--preset", default="seed-lab")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hardware_bridge.bag import export_sim_episode

    if Path(args.out).exists():
        raise ValueError(f"--out {args.out} exists already; bags are never overwritten")
    summary = export_sim_episode(
        args.out, preset=args.preset, duration_s=args.duration, seed=args.seed
    )
    print(
        f"wrote {summary['path']}: {summary['steps']} steps, {summary['messages']} messages, "
        f"robots {summary['robots']}"
    )
    return 0
