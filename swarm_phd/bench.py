"""``swarm-phd bench``: env throughput on the ``sim-6m-20`` preset (by default), one process.

20 robots, all sensors at the Perera 2021 study's rates, random actions. Reported with localization
off (the simulator alone) and with Lidar+Camera GM-PHD on every robot: env steps per second, the
real-time factor (simulated seconds per wall second) and the lidar cost per scan (ray casting +
feature extraction). Each case runs ``--repeats`` times (the machine is a shared VM whose speed
drifts): the table gives the median run and the range of the real-time factor.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from agents.policies import random_policy
from swarm_core import inputs, progress
from swarm_env import parallel_env
from swarm_phd import presets
from swarm_phd.runner import rollout


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", default="sim-6m-20")
    inputs.add_duration_argument(parser, 60.0, "simulated seconds per case")
    inputs.add_seed_argument(parser)
    parser.add_argument("--repeats", type=int, default=3, help="runs per case (median shown)")
    parser.add_argument(
        "--localizer",
        default="phd-lc",
        help="comma-separated localizers to time (each beside the simulator alone; "
        "`swarm-phd list` names them)",
    )
    parser.add_argument("--json", default=None, help="also write the figures to this file")


def measure(preset: str, duration_s: float, seed: int, localizer: str | None) -> dict[str, float]:
    """One timed run: the simulator alone (``localizer=None``, raw-measurement observations)
    or with every robot's ``localizer`` and the estimate observations."""
    localize = localizer is not None
    observation = "phd" if localize else "measurements"
    env = parallel_env(
        preset, observation=observation, localize=localize, localizer=localizer or "phd"
    )
    n_steps = int(round(duration_s / env.config.control_period_s))
    rollout(env, random_policy(env), 20, seed=seed)  # warm-up (imports, caches)
    for key in env.world.timing:
        env.world.timing[key] = 0
    result = rollout(env, random_policy(env), n_steps, seed=seed)
    timing = env.world.timing
    scans = max(timing["lidar_scans"], 1)
    return {
        "localization": localizer or "off",
        "n_robots": env.config.n_robots,
        "steps": result.steps,
        "steps_per_s": result.steps_per_s,
        "real_time_factor": result.real_time_factor,
        "lidar_ms_per_scan": 1e3 * timing["lidar_s"] / scans,
        "lidar_share": timing["lidar_s"] / result.wall_time_s,
        "camera_share": timing["camera_s"] / result.wall_time_s,
        "physics_share": timing["physics_s"] / result.wall_time_s,
    }


def median_of_runs(
    preset: str, duration_s: float, seed: int, localizer: str | None, repeats: int, bar=None
):
    """:func:`measure` ``repeats`` times: the median run, with the real-time factor's range.

    ``bar`` (a :func:`swarm_core.progress.bar`) advances once per run; the runs themselves carry
    no per-step bar, so the throughput measured is the env's alone.
    """
    runs = []
    for _ in range(max(repeats, 1)):
        runs.append(measure(preset, duration_s, seed, localizer))
        if bar is not None:
            bar.update(1)
    runs.sort(key=lambda r: r["real_time_factor"])
    row = dict(runs[len(runs) // 2])
    row["rtf_min"], row["rtf_max"] = runs[0]["real_time_factor"], runs[-1]["real_time_factor"]
    row["repeats"] = len(runs)
    return row


def run(args: argparse.Namespace) -> int:
    period = presets.control_period_s(args.preset)  # an unknown preset is refused here too
    inputs.duration("--duration", args.duration, period)
    inputs.integer("--repeats", args.repeats, minimum=1)
    inputs.seed("--seed", args.seed)
    if args.json:
        inputs.output_file("--json", args.json)
    from localization.registry import LOCALIZERS

    names = [n.strip() for n in args.localizer.split(",") if n.strip()]
    unknown = [n for n in names if n not in LOCALIZERS]
    if unknown:
        raise ValueError(f"--localizer must name some of {sorted(LOCALIZERS)}, got {unknown}")
    cases: list[str | None] = [None, *names]
    with progress.bar(len(cases) * args.repeats, "bench", unit="run") as bar:
        rows = [
            median_of_runs(args.preset, args.duration, args.seed, name, args.repeats, bar)
            for name in cases
        ]
    print(
        f"swarm-phd bench: {args.preset}, {args.duration:.0f} s simulated per case, "
        f"median of {args.repeats} runs, "
        f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}"
    )
    print(
        "| localization | robots | env steps/s | real-time factor (range) | lidar ms/scan | "
        "lidar | camera | physics |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['localization']} | {r['n_robots']} | {r['steps_per_s']:.0f} | "
            f"{r['real_time_factor']:.1f}x ({r['rtf_min']:.1f}-{r['rtf_max']:.1f}) | "
            f"{r['lidar_ms_per_scan']:.3f} | "
            f"{r['lidar_share']:.0%} | {r['camera_share']:.0%} | {r['physics_share']:.0%} |"
        )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0
