"""``swarm-phd demo``: the seed's experiment in one minute.

20 UGVs wander in the 6 m x 6 m arena for 60 s of simulated time (pseudo-random motion with lidar
obstacle avoidance) while every robot runs its own GM-PHD filter. It prints the throughput, each
sensor's detections per scan and false-positive / missed-detection rates, writes an animation
and a snapshot to ``runs/demo/``, and finishes with a short Lidar+Camera vs Lidar-Only
localization comparison (the seed's Fig. 7 experiment, shortened).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from agents.scripted import WanderPolicy
from swarm_env import parallel_env
from swarm_phd.runner import rollout


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", default="seed-sim")
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/demo")
    parser.add_argument("--frames", type=int, default=120, help="animation frames (0: none)")
    parser.add_argument(
        "--eval-duration",
        type=float,
        default=60.0,
        help="simulated seconds of the LC vs LO comparison (0: skip)",
    )


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = parallel_env(
        args.preset, sensor_stats=True, render_mode="rgb_array" if args.frames else None
    )
    n_steps = int(round(args.duration / env.config.control_period_s))
    policy = WanderPolicy.for_env(env, seed=args.seed)
    every = max(1, n_steps // args.frames) if args.frames else 0
    frames: list[np.ndarray] = []

    def capture(e, step: int) -> None:
        if every and step % every == 0:
            frames.append(e.render())

    print(
        f"swarm-phd demo: {args.preset}, {env.config.n_robots} UGVs, "
        f"{args.duration:.0f} s simulated, seed {args.seed}"
    )
    result = rollout(env, policy, n_steps, seed=args.seed, on_step=capture)
    print(
        f"  steps {result.steps}   sim time {result.sim_time_s:.1f} s   wall time "
        f"{result.wall_time_s:.1f} s   real-time factor {result.real_time_factor:.1f}x "
        f"({result.steps_per_s:.0f} steps/s, rendering excluded)"
    )
    stats = {name: s.summary() for name, s in env.world.stats.items()}
    print("  sensor        scans   meas/scan   false-pos rate   missed rate (within range)")
    for name, s in stats.items():
        print(
            f"  {name:<10} {s['scans']:>8d}   {s['measurements_per_scan']:9.2f}   "
            f"{s['false_positive_rate']:14.1%}   {s['missed_detection_rate']:11.1%} "
            f"(<= {s['range_m']:.1f} m)"
        )
    summary = {
        "steps": result.steps,
        "sim_time_s": result.sim_time_s,
        "wall_time_s": result.wall_time_s,
        "real_time_factor": result.real_time_factor,
        "sensors": stats,
    }
    (out / "demo.json").write_text(json.dumps(summary, indent=2))
    if frames:
        _write_animation(frames, out)
        print(f"  wrote {out / 'demo.gif'} ({len(frames)} frames) and {out / 'snapshot.png'}")
    env.close()
    if args.eval_duration > 0:
        from swarm_phd.evaluate import evaluate_localization, print_table

        print(
            f"\nLocalization, Lidar+Camera (LC) vs Lidar-Only (LO), {args.eval_duration:.0f} s, "
            f"every robot running its own filter:"
        )
        results = evaluate_localization(
            args.preset,
            args.eval_duration,
            ["phd-lc", "phd-lo"],
            seeds=[args.seed],
            out_dir=out / "localization",
        )
        print_table(results)
    return 0


def _write_animation(frames: list[np.ndarray], out: Path) -> None:
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[-1].save(out / "snapshot.png")
    images[0].save(out / "demo.gif", save_all=True, append_images=images[1:], duration=100, loop=0)
