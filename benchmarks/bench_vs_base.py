"""Env speed of this checkout against another (a git worktree of older code), alternated in one run.

The machine is shared and its speed drifts by up to ~2.5x within an hour, so absolute rates taken
at different times do not compare; rates of two checkouts taken in alternation do. Each round runs,
per case, one process in each checkout (the order flips every round), each timing
:func:`swarm_phd.bench.measure` (random actions, after a 20-step warm-up) ``--repeats`` times;
printed: per case the median steps/s of each checkout, the per-round ratios new / base and their
median, and each process's peak memory.

    git worktree add /tmp/base <commit>
    .venv/bin/python benchmarks/bench_vs_base.py --base /tmp/base [--preset sim-6m-20]
        [--localizers off,phd-lc,pmb-lc] [--duration 20] [--rounds 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

_CHILD = """
import json, resource, sys
from swarm_phd.bench import measure
preset, duration, localizer, repeats = sys.argv[1], float(sys.argv[2]), sys.argv[3], int(sys.argv[4])
runs = [measure(preset, duration, 0, None if localizer == "off" else localizer)
        for _ in range(repeats)]
print(json.dumps({"steps_per_s": [r["steps_per_s"] for r in runs],
                  "real_time_factor": [r["real_time_factor"] for r in runs],
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_case(tree: Path, args: argparse.Namespace, localizer: str) -> dict:
    """One process in checkout ``tree``: ``--repeats`` timed runs of one case."""
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_NUM_THREADS=str(args.threads))
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, args.preset, str(args.duration), localizer,
         str(args.repeats)],
        cwd=tree, env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if out.returncode != 0:
        raise SystemExit(f"{tree} ({localizer}) failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the other checkout (a directory)")
    parser.add_argument("--new", default=str(Path(__file__).resolve().parents[1]))
    parser.add_argument("--preset", default="sim-6m-20")
    parser.add_argument("--localizers", default="off,phd-lc,pmb-lc")
    parser.add_argument("--duration", type=float, default=20.0, help="simulated s per run")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs per process")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="NUMBA_NUM_THREADS")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    trees = {"base": Path(args.base).resolve(), "new": Path(args.new).resolve()}
    for name, tree in trees.items():
        if not (tree / "swarm_phd" / "bench.py").is_file():
            raise SystemExit(f"--{name} must be a checkout of this project, got {tree}")
    cases = [c.strip() for c in args.localizers.split(",") if c.strip()]
    results = {c: {"base": [], "new": [], "ratio": [], "rss": {"base": 0.0, "new": 0.0}}
               for c in cases}  # fmt: skip
    loads = []
    for rnd in range(args.rounds):
        for case in cases:
            order = ("base", "new") if rnd % 2 == 0 else ("new", "base")
            rates = {}
            for name in order:
                r = run_case(trees[name], args, case)
                rates[name] = float(np.median(r["steps_per_s"]))
                results[case][name].append(rates[name])
                results[case]["rss"][name] = max(results[case]["rss"][name], r["peak_rss_mib"])
            results[case]["ratio"].append(rates["new"] / rates["base"])
            loads.append(os.getloadavg()[0])
            print(
                f"round {rnd + 1} {case}: base {rates['base']:.0f}, new {rates['new']:.0f} "
                f"steps/s, new / base {rates['new'] / rates['base']:.2f} "
                f"(load {loads[-1]:.1f})",
                flush=True,
            )
    print(
        f"\nbench_vs_base: {args.preset}, {args.duration:.0f} s simulated per run, "
        f"{args.repeats} runs per process, {args.rounds} rounds, NUMBA_NUM_THREADS="
        f"{args.threads}, {platform.machine()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"load {min(loads):.1f}-{max(loads):.1f}"
    )
    print("| case | base steps/s | new steps/s | new / base per round | median | peak RSS MiB |")
    print("|---|---:|---:|---|---:|---:|")
    for case, r in results.items():
        print(
            f"| {case} | {np.median(r['base']):.0f} | {np.median(r['new']):.0f} | "
            f"{', '.join(f'{x:.2f}' for x in r['ratio'])} | {np.median(r['ratio']):.2f} | "
            f"{r['rss']['base']:.0f} / {r['rss']['new']:.0f} |"
        )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
