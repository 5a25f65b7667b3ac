"""``swarm-phd replay BAG``: rerun localization and the metrics offline on a recorded bag, through
the same env API (a :class:`~hardware_bridge.bag.ReplayWorld` behind ``SwarmEnv``)."""

from __future__ import annotations

import argparse
import json

from swarm_core import progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="bag directory written by the bridge or export-bag")
    parser.add_argument(
        "--mode",
        choices=("lidar-camera", "lidar-only"),
        default=None,
        help="rerun with another filter mode than the recorded config",
    )
    parser.add_argument(
        "--localizer",
        default=None,
        help="rerun with another filter family than the recorded config (`swarm-phd list`), "
        "e.g. pmb-lc",
    )
    parser.add_argument(
        "--overrides",
        default=None,
        metavar="JSON",
        help="SwarmConfig overrides of the recorded config, e.g. "
        '\'{"lidar_features": {"extent_test": false}}\' to re-extract the lidar detections '
        "from the recorded scans with another rule",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    """Replay, or one line on stderr naming the bag and the problem (exit status 2); never a
    traceback. Damage that leaves a replayable part is reported as skipped."""
    import sys

    try:
        return _run(args)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # noqa: BLE001 - a corrupt bag must never show a traceback
        from hardware_bridge.bag import BagError

        text = (
            str(exc) if isinstance(exc, BagError) else f"{args.bag}: {type(exc).__name__}: {exc}"
        )
        print(f"swarm-phd replay: error: {' '.join(text.split())[:500]}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    import sys

    from hardware_bridge.bag import SKIP_REASONS, BagError, replay_env
    from swarm_core.inputs import parse_json_object
    from swarm_phd.episode import format_metrics, run_episode

    overrides = parse_json_object(args.overrides, "--overrides")
    if args.mode is not None:
        overrides["phd"] = {"mode": args.mode}
    if args.localizer is not None:
        overrides["localizer"] = args.localizer
    env = replay_env(args.bag, **overrides)
    try:
        world = env.world
        missing = dict(world.missing)
        without_odometry = sorted(r for r, gone in missing.items() if "odometry" in gone)
        without_truth = sorted(r for r, gone in missing.items() if "mocap" in gone)
        if without_odometry or without_truth:
            why = (
                f"no odometry at all from {without_odometry}: a robot's filter cannot follow "
                "its own motion without it"
                if without_odometry
                else f"no motion capture at all from {without_truth}: the ground truth needs "
                "every robot's pose, so no step could be scored"
            )
            raise BagError(
                args.bag,
                f"{why}; refused rather than scored wrongly (sensors absent from the bag: "
                f"{_missing_text(missing)})",
            )
        if missing:
            print(
                f"swarm-phd replay: {args.bag}: warning: sensors absent from the whole bag, "
                f"reported stale at every step and never fed: {_missing_text(missing)}",
                file=sys.stderr,
            )
        episodes = []
        for episode in progress.over(range(world.n_episodes), "replay", unit="episode"):
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
        skipped = world.skipped()
    finally:
        env.close()
    if skipped:
        parts = ", ".join(
            f"{n} {SKIP_REASONS.get(k, k.replace('.invalid', ' messages failing validation'))}"
            for k, n in skipped.items()
        )
        print(f"swarm-phd replay: {args.bag}: skipped {parts}", file=sys.stderr)
    if args.json:
        print(
            json.dumps(
                {
                    "bag": args.bag,
                    "robots": list(env.possible_agents),
                    "episodes": episodes,
                    "rejected": rejected,
                    "skipped": skipped,
                    "missing": {r: list(g) for r, g in missing.items()},
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


def _missing_text(missing: dict[str, tuple[str, ...]]) -> str:
    return "; ".join(f"{robot}: {', '.join(gone)}" for robot, gone in sorted(missing.items()))
