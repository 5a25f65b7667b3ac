"""Env speed of this checkout against another (a git worktree of older code), alternated.

The machine is shared and its speed drifts by up to ~2.5x within an hour, so absolute rates taken
at different times do not compare; rates of two checkouts taken in alternation do. Each round runs,
per case, one process in each checkout (the order flips every round); each builds the env as
``swarm-phd bench`` does, warms it up for 20 steps and times ``--repeats`` random-action rollouts,
in CPU time (the process's own, steadier than wall time when other jobs share the cores) and
wall time per env step. Printed: per case each checkout's median CPU ms per step, the per-round
speed-ups (base time / new time) and their medians, and each process's peak memory.

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
import json, resource, sys, time
from agents.policies import random_policy
from swarm_env import parallel_env
from swarm_phd.runner import rollout
preset, localizer = sys.argv[1], sys.argv[3]
duration, repeats = float(sys.argv[2]), int(sys.argv[4])
localize = localizer != "off"
env = parallel_env(preset, observation="phd" if localize else "measurements",
                   localize=localize, localizer=localizer if localize else "phd")
n_steps = int(round(duration / env.config.control_period_s))
rollout(env, random_policy(env), 20, seed=0)  # warm-up (imports, caches)
wall, cpu = [], []
for _ in range(repeats):
    c0 = time.process_time()
    result = rollout(env, random_policy(env), n_steps, seed=0)
    cpu.append(1e3 * (time.process_time() - c0) / result.steps)
    wall.append(1e3 * result.wall_time_s / result.steps)
print(json.dumps({"wall_ms": wall, "cpu_ms": cpu,
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
    results = {c: {"base": [], "new": [], "wall": [], "cpu": [], "rss": {}} for c in cases}
    loads = []
    for rnd in range(args.rounds):
        for case in cases:
            order = ("base", "new") if rnd % 2 == 0 else ("new", "base")
            got = {name: run_case(trees[name], args, case) for name in order}
            r = results[case]
            for name, out in got.items():
                r[name].append(out)
                r["rss"][name] = max(r["rss"].get(name, 0.0), out["peak_rss_mib"])
            for key in ("wall", "cpu"):  # speed-up: base time / new time, medians of the runs
                r[key].append(
                    float(np.median(got["base"][f"{key}_ms"]) / np.median(got["new"][f"{key}_ms"]))
                )
            loads.append(os.getloadavg()[0])
            cpu = [np.median(got[n]["cpu_ms"]) for n in ("base", "new")]
            print(
                f"round {rnd + 1} {case}: ms/step CPU base {cpu[0]:.2f}, new {cpu[1]:.2f}"
                f" (speed-up {r['cpu'][-1]:.2f}; wall {r['wall'][-1]:.2f}), load {loads[-1]:.1f}",
                flush=True,
            )
    print(
        f"\nbench_vs_base: {args.preset}, {args.duration:.0f} s simulated per run, "
        f"{args.repeats} runs per process, {args.rounds} rounds, NUMBA_NUM_THREADS="
        f"{args.threads}, {platform.machine()}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"load {min(loads):.1f}-{max(loads):.1f}"
    )
    rows = [
        ["case", "CPU ms/step base", "new", "speed-up per round (CPU)", "median (CPU)",
         "median (wall)", "peak RSS MiB base / new"],
        ["---", "---:", "---:", "---", "---:", "---:", "---:"],
    ]  # fmt: skip
    for case, r in results.items():
        cpu = {n: np.median([np.median(o["cpu_ms"]) for o in r[n]]) for n in ("base", "new")}
        rows.append(
            [case, f"{cpu['base']:.2f}", f"{cpu['new']:.2f}",
             ", ".join(f"{x:.2f}" for x in r["cpu"]), f"{np.median(r['cpu']):.2f}",
             f"{np.median(r['wall']):.2f}", f"{r['rss']['base']:.0f} / {r['rss']['new']:.0f}"]
        )  # fmt: skip
    print("\n".join("| " + " | ".join(row) + " |" for row in rows))  # fmt: skip
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
