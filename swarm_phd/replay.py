"""``swarm-phd replay BAG``: rerun localization and the metrics offline on a recorded bag, through
the same env API (a :class:`~hardware_bridge.bag.ReplayWorld` behind ``SwarmEnv``)."""

from __future__ import annotations

import argparse
import json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="bag directory written by the bridge or export-bag")
    parser.add_argument(
        "--mode",
        choices=("lidar-camera", "lidar-only"),
        default=None,
        help="rerun with another filter mode than the recorded config",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    from hardware_bridge.bag import replay_env
    from swarm_phd.episode import format_metrics, run_episode

    overrides = {}
    if args.mode is not None:
        overrides["phd"] = {"mode": args.mode}
    env = replay_env(args.bag, **overrides)
    try:
        world = env.world
        episodes = []
        for episode in range(world.n_episodes):
            n_steps = world.n_steps(episode)
            result = run_episode(env, None, n_steps, seed=None)
            episodes.append(
                {
                    "episode": episode,
                    "steps": result.steps,
                    "metrics": result.metrics,
                    "stale_steps": result.stale_steps,
                }
            )
        rejected = world.counters.snapshot()
    finally:
        env.close()
    if args.json:
        print(
            json.dumps(
                {
                    "bag": args.bag,
                    "robots": list(env.possible_agents),
                    "episodes": episodes,
                    "rejected": rejected,
                },
                indent=2,
                default=float,
            )
        )
        return 0
    print(
        f"replayed {args.bag}: robots {env.possible_agents}, source "
        f"{world.meta.get('source')}, {len(episodes)} episode(s)"
    )
    for ep in episodes:
        print(f"episode {ep['episode']}: {ep['steps']} steps")
        print(format_metrics(ep["metrics"]))
        if ep["stale_steps"]:
            print("  stale sensor-steps:", ep["stale_steps"])
    if rejected:
        print("rejected messages:", rejected)
    return 0
