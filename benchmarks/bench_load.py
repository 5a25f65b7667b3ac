"""Env speed when another process shares the cores: loaded / idle ratio of real-time factors.

The compiled kernels run robots in parallel OpenMP threads. With spinning idle workers (GNU
OpenMP's default wait policy) a busy neighbour process made the default env collapse (28x ->
2.1x real time); ``swarm_core.threads`` sets ``OMP_WAIT_POLICY=PASSIVE``. This benchmark runs
the default preset idle, then beside ``--busy`` busy-loop processes, alternating, and prints
the real-time factors and their ratio (goal: >= 0.6 with one busy core on a 2-core machine).

    .venv/bin/python benchmarks/bench_load.py [--steps 400] [--repeats 3] [--busy 1]
    OMP_WAIT_POLICY=ACTIVE .venv/bin/python benchmarks/bench_load.py   # the spinning default
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

import numpy as np

from swarm_core.atomic_files import write_json_atomically


def _spin(stop) -> None:
    while not stop.is_set():
        for _ in range(100_000):
            pass


def real_time_factor(env, steps: int, seed: int) -> float:
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    high = np.array([0.3, 1.5])
    start = time.perf_counter()
    for _ in range(steps):
        env.step({a: rng.uniform(-high, high) for a in env.agents})
    wall = time.perf_counter() - start
    return steps * env.config.control_period_s / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="sim-6m-20")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--busy", type=int, default=1, help="busy-loop processes beside the env")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from swarm_env import parallel_env

    env = parallel_env(args.preset, max_steps=args.steps + 10)
    real_time_factor(env, 30, 0)  # compile / load the kernels
    ctx = mp.get_context("spawn")
    idle, loaded = [], []
    for k in range(args.repeats):
        idle.append(real_time_factor(env, args.steps, k))
        stop = ctx.Event()
        procs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.busy)]
        for p in procs:
            p.start()
        time.sleep(0.5)
        try:
            loaded.append(real_time_factor(env, args.steps, k))
        finally:
            stop.set()
            for p in procs:
                p.join(5)
    result = {
        "preset": args.preset,
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
        "cpus": os.cpu_count(),
        "busy_processes": args.busy,
        "idle_rtf": idle,
        "loaded_rtf": loaded,
        "ratio_of_medians": float(np.median(loaded) / np.median(idle)),
    }
    print(
        f"bench_load: {args.preset}, OMP_WAIT_POLICY={result['omp_wait_policy']}, "
        f"{args.busy} busy process(es) on {result['cpus']} cores\n"
        f"  idle   real-time factor: median {np.median(idle):.1f}x  {np.round(idle, 1)}\n"
        f"  loaded real-time factor: median {np.median(loaded):.1f}x  {np.round(loaded, 1)}\n"
        f"  loaded / idle: {result['ratio_of_medians']:.2f} (goal >= 0.6)"
    )
    if args.json:
        write_json_atomically(args.json, result)


if __name__ == "__main__":
    main()
