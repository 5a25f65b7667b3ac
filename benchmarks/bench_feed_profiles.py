"""The feed's packing cost with and without the lidar scans' profiles (issue 13).

``SwarmFeed.packed(scan_profiles)`` bins every lidar scan into a 720-bin profile only for a bank
that reads them (``PHDConfig.reads_scans``). This measures the CPU time of packing one env
step, with and without the profiles, on the same recorded steps, alternated in one process.

    .venv/bin/python benchmarks/bench_feed_profiles.py --sizes 20,1000
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scaling import random_motion  # noqa: E402  (the scaling benchmark's envs)

from localization.feed import SwarmFeed  # noqa: E402


def measure(n_robots: int, n_steps: int = 8, repeats: int = 4) -> dict[bool, list[float]]:
    """CPU ms per step of ``SwarmFeed.packed(flag)`` for both flags, ``repeats`` times each,
    on ``n_steps`` recorded steps of random motion (seed 0) after 5 warm-up steps."""
    env, step = random_motion(n_robots)
    for _ in range(5):
        step()
    steps = [step() for _ in range(n_steps)]
    ids = env.possible_agents
    env.close()
    out: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(repeats):
        for flag in (True, False):
            feeds = [SwarmFeed.from_world_step(s, ids) for s in steps]
            t = time.process_time()
            for feed in feeds:
                feed.packed(flag)
            out[flag].append(1e3 * (time.process_time() - t) / n_steps)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="20,1000", help="swarm sizes (bench_scaling presets)")
    args = parser.parse_args()
    for n in (int(s) for s in args.sizes.split(",")):
        res = measure(n)
        print(
            f"{n} robots: packing CPU ms/step with profiles "
            f"{[round(x, 2) for x in res[True]]}, without {[round(x, 2) for x in res[False]]}; "
            f"load {os.getloadavg()[0]:.1f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
