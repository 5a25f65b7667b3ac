"""One robot's filter on board: CPU time per second of sensor data, on one core.

Perera 2021's robots ran their filter on an Odroid-XU4 in real time. This measures what
:class:`hardware_bridge.onboard.OnBoardFilter` costs one robot: the simulator records one
robot's odometry (10 Hz), scans (7 Hz) and camera frames (30 Hz) in the Perera 2021 study's arena
(``sim-6m-20``, 20 robots wandering), then a fresh one-robot filter is stepped over those
records alone, timed, numba on one thread and the process pinned to one core. Recording is not
timed. The lidar feature extraction runs inside the step (it is part of the robot's work).

Usage::

    python benchmarks/bench_onboard_filter.py --duration 60 --robot 3 --localizer phd-lc,pmb-lc

Prints, per family, the CPU seconds per second of data (``< 1``: real time on this core) and
the median and 99th-percentile step time. The first step (kernel loading) is not counted.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before numba is imported

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def record(preset: str, duration_s: float, robot: int, seed: int):
    from swarm_env import parallel_env

    env = parallel_env(preset, localize=False, observation="measurements", max_steps=10**7)
    env.reset(seed=seed)
    agent = env.possible_agents[robot]
    rng = np.random.default_rng(seed)
    steps = [(env.last_world_step.time_s, env.last_world_step.measurements[agent])]
    while env.last_world_step.time_s < duration_s:
        env.step({a: rng.uniform(-1, 1, 2) * [0.3, 1.5] for a in env.agents})
        steps.append((env.last_world_step.time_s, env.last_world_step.measurements[agent]))
    config = env.config
    env.close()
    return agent, config, steps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="sim-6m-20")
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--robot", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--localizer", default="phd-lc,pmb-lc")
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from hardware_bridge.messages import s_to_ns
    from hardware_bridge.onboard import OnBoardFilter

    agent, config, steps = record(args.preset, args.duration, args.robot, args.seed)
    data_s = steps[-1][0] - steps[0][0]
    counts = {
        kind: sum(len(getattr(m, kind)) for _, m in steps)
        for kind in ("odometry", "lidar", "camera")
    }
    print(
        f"{args.preset}, {agent}, {data_s:.1f} s of data: "
        + ", ".join(f"{v} {k} records" for k, v in counts.items())
    )
    for family in args.localizer.split(","):
        onboard = OnBoardFilter(agent, config, family)
        onboard.step_records(steps[0][1], s_to_ns(max(steps[0][0], 1e-9)))  # load kernels
        times = []
        cpu0 = time.process_time()
        for t, records in steps[1:]:
            start = time.perf_counter()
            onboard.step_records(records, s_to_ns(t))
            times.append(time.perf_counter() - start)
        cpu = time.process_time() - cpu0
        p99 = float(np.percentile(times, 99))
        print(
            f"  {family}: {cpu / data_s:.4f} CPU s per s of data "
            f"({1e3 * cpu / data_s:.1f} ms/s), step median {1e3 * statistics.median(times):.2f} "
            f"ms, p99 {1e3 * p99:.2f} ms over {len(times)} steps"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
