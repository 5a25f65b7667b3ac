"""Env-runner sampling throughput of the RLlib engine: N runners vs 1, on this machine.

``python benchmarks/bench_rllib.py --runners plain,0,1,2`` builds the same PPO config as
``swarm-phd train --engine rllib`` (shared module, kernels pre-warmed, one kernel thread per
runner) for each N, samples once to warm up (module weights, first episode), then times
``--env-steps`` env steps per runner, all runners in parallel. N = 0 is the driver's own local
runner; ``plain`` is the env alone in a plain loop, no RLlib (the reference). Prints and
optionally writes (``--json``) env steps/s and agent steps/s. Only sampling is timed: the PPO
update (the learner) is not part of these figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any


def sample_rate(
    env_kwargs: dict[str, Any], num_env_runners: int, env_steps: int, seed: int = 0
) -> dict[str, Any]:
    """Env steps/s of ``num_env_runners`` runners sampling ``env_steps`` each, in parallel."""
    from agents.rllib.train import build_config

    config = build_config(
        env_kwargs,
        seed=seed,
        num_env_runners=num_env_runners,
        ppo={"rollout_fragment_length": 64, "minibatch_size": 64},
    )
    algo = config.build_algo()
    try:
        local = num_env_runners == 0

        def sample(n: int):
            def fn(runner: Any) -> tuple[int, int, float]:
                cpu0 = time.process_time()  # this runner process's CPU time, all its threads
                episodes = runner.sample(num_timesteps=n)
                env_total = sum(e.env_steps() for e in episodes)
                agent_total = sum(e.agent_steps() for e in episodes)
                return env_total, agent_total, time.process_time() - cpu0

            return algo.env_runner_group.foreach_env_runner(fn, local_env_runner=local)

        sample(64)  # warm-up: weights synced, envs reset, kernels loaded in every runner
        start = time.perf_counter()
        counts = sample(env_steps)
        elapsed = time.perf_counter() - start
    finally:
        algo.stop()
    env_total = sum(c[0] for c in counts)
    agent_total = sum(c[1] for c in counts)
    cpu = sum(c[2] for c in counts)
    return {
        "num_env_runners": num_env_runners,
        "env_steps": env_total,
        "agent_steps": agent_total,
        "seconds": elapsed,
        "env_steps_per_s": env_total / elapsed,
        "agent_steps_per_s": agent_total / elapsed,
        # Contention-free cost: on a shared machine the wall rate depends on other jobs, the
        # CPU seconds per env step much less. N idle cores give about N x this rate.
        "runner_cpu_s": cpu,
        "env_steps_per_cpu_s": env_total / cpu,
    }


def plain_rate(env_kwargs: dict[str, Any], env_steps: int, seed: int = 0) -> dict[str, Any]:
    """The reference: the same env stepped in a plain loop in this process, one kernel thread,
    random unit actions (what one runner would do with no RLlib around it)."""
    import numpy as np

    from agents.sb3.adapter import TrainingWrapper
    from swarm_core.threads import set_kernel_threads
    from swarm_env import parallel_env

    previous = set_kernel_threads(None)
    set_kernel_threads(1)
    rng = np.random.default_rng(seed)
    env = TrainingWrapper(parallel_env(**env_kwargs))
    try:
        env.reset(seed=seed)
        done = agent_total = 0
        start, cpu0 = time.perf_counter(), time.process_time()
        while done < env_steps:
            if not env.agents:
                env.reset()
            agents = env.agents
            actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in agents}
            env.step(actions)
            done += 1
            agent_total += len(agents)
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu0
    finally:
        env.close()
        set_kernel_threads(previous)
    return {
        "num_env_runners": "plain loop",
        "env_steps": done,
        "agent_steps": agent_total,
        "seconds": elapsed,
        "env_steps_per_s": done / elapsed,
        "agent_steps_per_s": agent_total / elapsed,
        "runner_cpu_s": cpu,
        "env_steps_per_cpu_s": done / cpu,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/bench_rllib.py", description=__doc__)
    parser.add_argument("--preset", default="sim-6m-20")
    parser.add_argument("--task", default="formation")
    parser.add_argument("--observation", default="phd", choices=["phd", "truth", "measurements"])
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument(
        "--runners",
        default="plain,1,2",
        help="comma-separated runner counts; 'plain': the env alone in a loop, no RLlib",
    )
    parser.add_argument("--env-steps", type=int, default=1000, help="per runner")
    parser.add_argument("--ray-num-cpus", type=int, default=None)
    parser.add_argument("--json", default=None, help="write the figures here")
    args = parser.parse_args(argv)

    import ray

    from agents.rllib.env import prewarm_kernels
    from agents.rllib.train import start_ray

    env_kwargs = {
        "preset": args.preset,
        "task": args.task,
        "observation": args.observation,
        "max_steps": args.max_steps,
    }
    prewarm_kernels()
    import torch

    torch.set_num_threads(1)  # as the train command's default: the local runner's inference
    started = start_ray(None, args.ray_num_cpus)
    rows = []
    try:
        for name in args.runners.split(","):
            if name.strip() == "plain":
                row = plain_rate(env_kwargs, args.env_steps)
            else:
                row = sample_rate(env_kwargs, int(name), args.env_steps)
            rows.append(row)
            print(
                f"runners={row['num_env_runners']}: {row['env_steps']} env steps in "
                f"{row['seconds']:.1f} s = "
                f"{row['env_steps_per_s']:.1f} env steps/s, "
                f"{row['agent_steps_per_s']:.0f} agent steps/s; "
                f"{row['env_steps_per_cpu_s']:.1f} env steps per runner CPU-second",
                flush=True,
            )
    finally:
        if started:
            ray.shutdown()
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(
            json.dumps(
                {
                    "env_kwargs": env_kwargs,
                    "rows": rows,
                    "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
                    "date": time.strftime("%Y-%m-%d"),
                    # The machine is shared: other jobs' load makes these figures lower bounds.
                    "load_average_1_5_15min": list(os.getloadavg()),
                },
                indent=2,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
