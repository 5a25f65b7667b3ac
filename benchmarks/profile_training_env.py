"""Where the batched training env's time goes: cProfile of its steps (no PPO).

    python benchmarks/profile_training_env.py --copies 16 --steps 200

The env is ``bench_training.py``'s (``lab-3m-4`` formation on PHD observations), stepped with
zero actions on one kernel thread after a 20-step warm-up; prints the env-only rate and the
profile's top functions by cumulative time (benchmarks/RESULTS.md, "Against the issue's own
code and command").
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--copies", type=int, default=16)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--top", type=int, default=30, help="functions printed")
    args = parser.parse_args()

    from bench_training import make_venv  # the very env the training benchmark steps

    from swarm_core.threads import set_kernel_threads

    set_kernel_threads(1)
    venv = make_venv(f"batched-{args.copies}")
    venv.reset()
    actions = np.zeros((venv.num_envs, 2), dtype=np.float32)
    for _ in range(20):
        venv.step(actions)
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    for _ in range(args.steps):
        venv.step(actions)
    profile.disable()
    elapsed = time.perf_counter() - start
    transitions = args.steps * venv.num_envs
    print(
        f"{transitions / elapsed:.0f} agent transitions/s, env only, under the profiler "
        f"({elapsed / transitions * 1e6:.0f} us each)"
    )
    pstats.Stats(profile).sort_stats("cumulative").print_stats(args.top)
    venv.close()


if __name__ == "__main__":
    main()
