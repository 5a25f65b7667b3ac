"""Scaling curve: env throughput and memory from 20 to 1000 robots at the Perera 2021
study's density.

Each size runs its density-keeping preset (``sim-6m-20``, ``sim-13m-100``, ``sim-19m-200``,
``sim-30m-500``, ``sim-42m-1000``: the arena side grows as sqrt(n / 20), obstacles with the
area) with random actions, with every robot's GM-PHD filter (``phd``: estimate observations)
and without (``off``: the simulator alone, raw-measurement observations, as ``swarm-phd
bench``). Every (size, localization) pair runs in its own subprocess, so its peak resident
memory (``getrusage`` maxrss) is its own; the baseline is the RSS after importing the env,
before building it (the compiled kernels load on the first step, inside the peak).
``--brute-force`` runs the simulator's reference paths (every sensor reading
against every shape, numpy ground truth: bit-identical results, O(N^2) per step) to compare
against the default (the grid index wherever it pays) in the same run; ``--compare``
alternates both per row.

    .venv/bin/python benchmarks/bench_scaling.py                        # the whole curve
    .venv/bin/python benchmarks/bench_scaling.py --sizes 20 --compare --repeats 3
    .venv/bin/python benchmarks/bench_scaling.py --sizes 1000 --localize on --profile
    .venv/bin/python benchmarks/bench_scaling.py --sizes 20 --localize on --threads 1
    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/bench_scaling.py --feed --sizes 20,200,1000

``--feed`` times the robots' filters alone, fed the two ways the compiled bank accepts (the
per-robot call tuples, and the packed arrays of ``localization.feed.pack_calls`` the env
uses), on the same recorded steps in one process, and checks they leave the same bits.

Reports env steps/s, robot-steps/s, the real-time factor (control period 0.1 s: 1x = 10 env
steps/s), the CPU time per step (all threads; with one kernel thread the figure that other
jobs on the machine disturb least), the share of the wall time in physics, lidar, camera and
the localizer, peak memory, and the load average before and after each row (other processes
on the machine slow it).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

from swarm_core.atomic_files import write_json_atomically

PRESET_OF = {
    20: "sim-6m-20",
    100: "sim-13m-100",
    200: "sim-19m-200",
    500: "sim-30m-500",
    1000: "sim-42m-1000",
}


def measure(
    n_robots: int, localize: bool, brute_force: bool, duration_s: float, profile: bool
) -> dict:
    """One timed run in this process: warm-up steps, then steps until ``duration_s`` of wall
    time (at least 5)."""
    import numpy as np

    from swarm_env import parallel_env

    base_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    preset = PRESET_OF[n_robots]
    if localize:
        env = parallel_env(preset, max_steps=1_000_000)
    else:
        env = parallel_env(preset, observation="measurements", localize=False, max_steps=1_000_000)
    env.world.brute_force = brute_force
    t0 = time.perf_counter()
    env.reset(seed=0)
    reset_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    high = np.array([0.3, 1.5])
    agents = list(env.agents)

    def actions() -> dict:
        return dict(zip(agents, rng.uniform(-high, high, size=(len(agents), 2)), strict=True))

    localizer_s = [0.0]
    step = env.localizer.step

    def timed_step(feed):
        t = time.perf_counter()
        try:
            return step(feed)
        finally:
            localizer_s[0] += time.perf_counter() - t

    env.localizer.step = timed_step  # instance attribute: times the whole swarm's filters
    for _ in range(3):  # warm-up: kernel loading, caches, first-step allocations
        env.step(actions())
    for key in env.world.timing:
        env.world.timing[key] = 0
    localizer_s[0] = 0.0
    commands = [actions() for _ in range(20)]  # drawn outside the timed loop
    profiler = None
    if profile:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    steps, start, cpu_start = 0, time.perf_counter(), time.process_time()
    while True:
        env.step(commands[steps % len(commands)])
        steps += 1
        wall = time.perf_counter() - start
        if wall >= duration_s and steps >= 5:
            break
    cpu = time.process_time() - cpu_start  # all of this process's threads
    if profiler is not None:
        import pstats

        profiler.disable()
        pstats.Stats(profiler, stream=sys.stderr).sort_stats("tottime").print_stats(15)
    timing = env.world.timing
    period = env.config.control_period_s
    import numba

    return {
        "n_robots": n_robots,
        "kernel_threads": numba.get_num_threads(),
        "preset": preset,
        "localization": "phd" if localize else "off",
        "path": "brute-force" if brute_force else "default",
        "steps": steps,
        "wall_s": wall,
        "env_steps_per_s": steps / wall,
        "robot_steps_per_s": steps * n_robots / wall,
        "real_time_factor": steps * period / wall,
        "cpu_ms_per_step": 1e3 * cpu / steps,
        "physics_share": timing["physics_s"] / wall,
        "lidar_share": timing["lidar_s"] / wall,
        "camera_share": timing["camera_s"] / wall,
        "localizer_share": localizer_s[0] / wall,
        "reset_s": reset_s,
        "baseline_rss_mb": base_rss_mb,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def random_motion(n_robots: int) -> tuple:
    """The env of ``n_robots`` robots (:data:`PRESET_OF`, seed 0) and ``step()``, which steps
    it once with uniform random actions (seed 0) and returns its ``WorldStep``."""
    import numpy as np

    from swarm_env import parallel_env

    env = parallel_env(PRESET_OF[n_robots], max_steps=1_000_000)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    high = np.array([0.3, 1.5])

    def step():
        actions = rng.uniform(-high, high, (len(env.agents), 2))
        env.step(dict(zip(env.agents, actions, strict=True)))
        return env.last_world_step

    return env, step


def feed_paths(n_robots: int, n_steps: int, repeats: int) -> dict:
    """The filters alone, the two ways into the compiled bank, in this process: the call tuples
    (``feed.call_lists()``, re-read by the bank's batch encoder) against the packed arrays
    (``bank.step(feed)``, :func:`localization.feed.pack_calls`), on the same ``n_steps`` recorded
    steps (after 20 to fill the filters) from the same bank state, alternated ``repeats``
    times; CPU seconds per env step, and the kernel alone. Both must end in the same bits."""
    import copy

    from localization.feed import SwarmFeed

    env, step = random_motion(n_robots)
    for _ in range(20):
        step()
    start_bank = copy.deepcopy(env.localizer)
    steps = [step() for _ in range(n_steps)]
    ids = env.possible_agents
    out: dict = {"n_robots": n_robots, "steps": n_steps, "tuples_ms": [], "packed_ms": []}
    for _ in range(repeats):
        tables = []
        for key in ("tuples_ms", "packed_ms"):
            bank = copy.deepcopy(start_bank)
            feeds = [SwarmFeed.from_world_step(s, ids) for s in steps]
            t = time.process_time()
            for f in feeds:
                if key == "tuples_ms":
                    bank.apply(f.call_lists())
                else:
                    bank.step(f)
            out[key].append(1e3 * (time.process_time() - t) / n_steps)
            tables.append(bank.padded_tables()[0].tobytes())
        if tables[0] != tables[1]:
            raise AssertionError("the packed path changed the filters' output")
    # The kernel alone, then without the camera frames (the same steps with the camera marked
    # stale): how much of the filters' cost is the camera update.
    for key, drop in (("kernel_ms", ()), ("kernel_no_camera_ms", ("camera",))):
        bank = copy.deepcopy(start_bank)
        packed = []
        for s in steps:
            f = SwarmFeed.from_world_step(s, ids)
            stale = [tuple(x) + drop for x in f.stale]
            packed.append(SwarmFeed(f.time_s, f.measurements, stale).packed(bank.reads_scans))
        t = time.process_time()
        for p in packed:
            bank._run_encoded(p.encoded, p.robots)
        out[key] = 1e3 * (time.process_time() - t) / n_steps
    return out


def run_child(
    n: int, localize: bool, brute: bool, duration: float, profile: bool, threads: int | None = None
) -> dict:
    """:func:`measure` in a fresh interpreter (its own peak memory), with the load average;
    ``threads``: its ``NUMBA_NUM_THREADS`` (default: inherited, numba's: one per core)."""
    load_before = os.getloadavg()[0]
    env = dict(os.environ)
    if threads is not None:
        env["NUMBA_NUM_THREADS"] = str(threads)
    cmd = [
        sys.executable,
        __file__,
        "--child",
        str(n),
        "--localize",
        "on" if localize else "off",
        "--duration",
        str(duration),
    ]
    if brute:
        cmd.append("--brute-force")
    if profile:
        cmd.append("--profile")
    done = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True, env=env)
    row = json.loads(done.stdout.strip().splitlines()[-1])
    row["load_before"], row["load_after"] = load_before, os.getloadavg()[0]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="20,100,200,500,1000")
    parser.add_argument("--localize", choices=("both", "on", "off"), default="both")
    parser.add_argument("--duration", type=float, default=10.0, help="timed wall seconds a row")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--brute-force", action="store_true", help="the reference paths only")
    parser.add_argument(
        "--compare", action="store_true", help="indexed and brute force, alternated"
    )
    parser.add_argument("--profile", action="store_true", help="cProfile top 15 on stderr")
    parser.add_argument(
        "--threads", type=int, default=None, help="kernel threads per row (NUMBA_NUM_THREADS)"
    )
    parser.add_argument(
        "--feed",
        action="store_true",
        help="the filters alone: call tuples vs packed arrays (CPU ms per step), per size",
    )
    parser.add_argument("--json", default=None)
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.child is not None:
        row = measure(
            args.child, args.localize == "on", args.brute_force, args.duration, args.profile
        )
        print(json.dumps(row))
        return

    sizes = [int(s) for s in args.sizes.split(",")]
    for n in sizes:
        if n not in PRESET_OF:
            raise ValueError(f"--sizes: {n} has no preset; choose from {sorted(PRESET_OF)}")
    if args.feed:
        rows = []
        for n in sizes:
            n_steps = max(5, 4000 // n)  # ~4000 robot-steps a size
            row = feed_paths(n, n_steps, max(args.repeats, 3))
            row["load"] = os.getloadavg()[0]
            rows.append(row)
            print(
                f"{n:>5} robots, {n_steps} steps: filters CPU ms/step, tuples "
                f"{_fmt(row['tuples_ms'])}, packed {_fmt(row['packed_ms'])}; kernel alone "
                f"{row['kernel_ms']:.2f}, without the camera frames "
                f"{row['kernel_no_camera_ms']:.2f}; load {row['load']:.1f}",
                flush=True,
            )
        if args.json:
            write_json_atomically(args.json, rows)
        return
    modes = {"both": (False, True), "on": (True,), "off": (False,)}[args.localize]
    paths = (False, True) if args.compare else (args.brute_force,)
    print(
        f"{'robots':>6} {'filters':>7} {'path':>11} {'steps/s':>8} {'robot-steps/s':>13} "
        f"{'RTF':>7} {'CPU ms':>6} {'phys':>5} {'lidar':>5} {'cam':>5} {'filt':>5} {'peak MB':>8} "
        f"{'base MB':>7} {'reset s':>7} {'load':>9} {'thr':>3}",
        flush=True,
    )
    rows = []
    for n in sizes:
        for localize in modes:
            for _ in range(max(args.repeats, 1)):
                for brute in paths:
                    row = run_child(n, localize, brute, args.duration, args.profile, args.threads)
                    rows.append(row)
                    print(
                        f"{n:>6} {row['localization']:>7} {row['path']:>11} "
                        f"{row['env_steps_per_s']:>8.2f} {row['robot_steps_per_s']:>13,.0f} "
                        f"{row['real_time_factor']:>6.2f}x {row['cpu_ms_per_step']:>6.2f} "
                        f"{row['physics_share']:>5.2f} "
                        f"{row['lidar_share']:>5.2f} {row['camera_share']:>5.2f} "
                        f"{row['localizer_share']:>5.2f} {row['peak_rss_mb']:>8.0f} "
                        f"{row['baseline_rss_mb']:>7.0f} {row['reset_s']:>7.2f} "
                        f"{row['load_before']:>4.1f}/{row['load_after']:<4.1f} "
                        f"{row['kernel_threads']:>3}",
                        flush=True,
                    )
    if args.json:
        write_json_atomically(args.json, rows)


def _fmt(values: list[float]) -> str:
    return "/".join(f"{v:.2f}" for v in values)


if __name__ == "__main__":
    main()
