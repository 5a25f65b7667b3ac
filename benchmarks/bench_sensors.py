"""Micro-benchmark of the sensor models on the Perera 2021 study's arena (6 m x 6 m,
20 robots).

Run from the repository root::

    .venv/bin/python benchmarks/bench_sensors.py [--reps 300] [--scenes 5]

Times, as the median over ``reps`` calls cycling through ``scenes`` random arenas
(20 robots, 10 decoy posts, 5 red decoys, 4 boxes):

* ``LidarSensor.scan`` for K = 14 scans (a 0.1 s env step of 20 robots at 7 Hz needs ~14),
* ``extract_clusters`` on that batch,
* ``CameraSensor.observe`` for 20 observers.

Targets: lidar batch of 14 < 3 ms, camera for 20 observers < 0.5 ms. The ``faults`` column is
minor page faults per call: on glibc, freed heap tops go back to the OS and large temporaries
fault back in, which can dominate on VMs (see docs/concepts/sensors.md, "Speed").
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from swarm_core.perception.lidar_features import extract_clusters  # noqa: E402
from swarm_env.sensors.camera import CameraSensor  # noqa: E402
from swarm_env.sensors.lidar import LidarSensor  # noqa: E402
from swarm_env.sensors.scene_builder import make_arena_scene  # noqa: E402

TARGETS_US = {"lidar scan": 3000.0, "camera observe": 500.0}


def _time(fn, args_cycle, reps: int) -> tuple[float, float]:
    """Median microseconds per call and minor page faults per call."""
    for args in args_cycle:  # warm-up: one pass over every scene
        fn(*args)
    samples = np.empty(reps)
    faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for i in range(reps):
        args = args_cycle[i % len(args_cycle)]
        t0 = time.perf_counter()
        fn(*args)
        samples[i] = time.perf_counter() - t0
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0) / reps
    return float(np.median(samples) * 1e6), faults


def run(reps: int = 300, n_scenes: int = 5, seed: int = 0) -> list[dict]:
    """Benchmark rows: name, per-call and per-item microseconds, items, faults, target."""
    rng = np.random.default_rng(seed)
    scenes = [
        make_arena_scene(rng, n_robots=20, n_posts=10, n_red_decoys=5, n_boxes=4)
        for _ in range(n_scenes)
    ]
    lidar = LidarSensor(n_robots=20)
    lidar.reset(rng)
    camera = CameraSensor()
    scan_robots = np.arange(14)
    stamps = np.full(14, 12.3)
    noise = np.random.default_rng(seed + 1)
    batches = [lidar.scan(s, scan_robots, stamps, noise) for s in scenes]

    rows = []
    us, faults = _time(
        lambda s: lidar.scan(s, scan_robots, stamps, noise), [(s,) for s in scenes], reps
    )
    rows.append(dict(name="lidar scan", items=14, unit="scan", us=us, faults=faults))
    us, faults = _time(
        lambda b: extract_clusters(b.angles_rad, b.ranges_m), [(b,) for b in batches], reps
    )
    rows.append(dict(name="lidar features", items=14, unit="scan", us=us, faults=faults))
    observers = np.arange(20)
    us, faults = _time(lambda s: camera.observe(s, observers, noise), [(s,) for s in scenes], reps)
    rows.append(dict(name="camera observe", items=20, unit="observer", us=us, faults=faults))
    for row in rows:
        row["per_item_us"] = row["us"] / row["items"]
        row["target_us"] = TARGETS_US.get(row["name"])
    return rows


def format_table(rows: list[dict]) -> str:
    lines = [
        f"{'operation':<16} {'K':>3} {'us/call':>9} {'us/item':>9} {'faults':>7} {'target':>8}",
        "-" * 57,
    ]
    for r in rows:
        target = "" if r["target_us"] is None else f"<{r['target_us']:.0f}"
        flag = "" if r["target_us"] is None else (" ok" if r["us"] < r["target_us"] else " SLOW")
        lines.append(
            f"{r['name']:<16} {r['items']:>3} {r['us']:>9.0f} {r['per_item_us']:>9.1f} "
            f"{r['faults']:>7.1f} {target:>8}{flag}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=300)
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(format_table(run(args.reps, args.scenes, args.seed)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
