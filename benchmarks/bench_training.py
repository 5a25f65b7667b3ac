"""PPO training throughput: agent transitions/s, SuperSuit vectorisation vs the batched VecEnv.

The same PPO (n_steps 128, batch 512, 10 epochs, Deep Sets extractor, torch 1 thread) on the
same env (``lab-3m-4`` formation, PHD observations: 4 robots) through:

- ``supersuit-2proc``: :func:`agents.sb3.adapter.make_vec_env`, 4 copies in 2 worker processes
  (the configuration of the results page's training-throughput row);
- ``supersuit``: the same, 4 copies in this process;
- ``batched-K``: :class:`agents.sb3.batched.BatchedSwarmVecEnv`, K copies sharing one localizer
  call per step;
- ``batched-KxW``: the same K copies split across W worker processes
  (:class:`agents.sb3.batched_subproc.SubprocBatchedVecEnv`, each worker one localizer call);
- ``sectors-K``: the same with 16 lidar sectors in the observation (``lidar_sectors=16``);
- ``residual-K``: the same plus the residual mode (``residual="scripted:formation"``: one
  scripted controller per copy runs every step, :mod:`agents.sb3.residual`).

Every variant runs its kernels on one thread (the cores go to PPO and the env), in this
process and in every worker.

Each variant trains for ``--rollouts`` PPO iterations after one warm-up iteration (kernels
compiled / loaded, workers started) and reports transitions/s over the timed ones, with the
env-stepping and the update share of the wall time. Ratios within one run are what to compare.

    .venv/bin/python benchmarks/bench_training.py [--rollouts 3] [--variants ...] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import time

from swarm_core.atomic_files import write_json_atomically

ENV_KWARGS = {"preset": "lab-3m-4", "task": "formation", "observation": "phd"}
PPO_KWARGS = {"n_steps": 128, "batch_size": 512, "n_epochs": 10, "learning_rate": 3e-4}


def make_venv(variant: str, seed: int = 0):
    if variant.startswith("supersuit"):
        from agents.sb3.adapter import make_vec_env

        num_cpus = 2 if variant == "supersuit-2proc" else 0
        return make_vec_env(ENV_KWARGS, n_copies=4, num_cpus=num_cpus, seed=seed)
    from agents.sb3.batched import make_batched_vec_env

    kind, copies = variant.split("-")
    copies, _, workers = copies.partition("x")
    kwargs = ENV_KWARGS if kind == "batched" else {**ENV_KWARGS, "lidar_sectors": 16}
    residual = "scripted:formation" if kind == "residual" else None
    return make_batched_vec_env(
        kwargs, n_copies=int(copies), seed=seed, residual=residual, n_workers=int(workers or 0)
    )


def make_ppo(venv):
    """The benchmarked PPO (``PPO_KWARGS``, Deep Sets extractor, 128-128 heads) on ``venv``."""
    from stable_baselines3 import PPO

    from agents.sb3.features import NeighbourSetExtractor

    return PPO(
        "MlpPolicy",
        venv,
        seed=0,
        device="cpu",
        verbose=0,
        policy_kwargs={
            "net_arch": {"pi": [128, 128], "vf": [128, 128]},
            "features_extractor_class": NeighbourSetExtractor,
            "features_extractor_kwargs": {"top_k": 16},
        },
        **PPO_KWARGS,
    )


def measure(variant: str, rollouts: int) -> dict:
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)
    # One kernel thread: the cores go to PPO and the env (SuperSuit's workers set their own).
    from swarm_core.threads import set_kernel_threads

    set_kernel_threads(1)
    venv = make_venv(variant)
    marks: list[tuple[str, float]] = []

    class Clock(BaseCallback):
        def _on_rollout_start(self) -> None:
            marks.append(("rollout", time.perf_counter()))

        def _on_rollout_end(self) -> None:
            marks.append(("update", time.perf_counter()))

        def _on_step(self) -> bool:
            return True

    model = make_ppo(venv)
    per_rollout = venv.num_envs * PPO_KWARGS["n_steps"]
    model.learn(total_timesteps=per_rollout * (rollouts + 1), callback=Clock())
    end = time.perf_counter()
    venv.close()
    starts = [t for kind, t in marks if kind == "rollout"]
    collected = [t for kind, t in marks if kind == "update"]
    # Timed: from the start of rollout 2 to the end of the last update.
    wall = end - starts[1]
    env_time = sum(c - s for s, c in zip(starts[1:], collected[1:], strict=False))
    transitions = per_rollout * rollouts
    return {
        "variant": variant,
        "entries": venv.num_envs,
        "transitions": transitions,
        "wall_s": wall,
        "transitions_per_s": transitions / wall,
        "env_share": env_time / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=3)
    parser.add_argument(
        "--variants",
        default="supersuit-2proc,supersuit,batched-4,batched-16,batched-16x2,batched-32x2",
        help="comma list",
    )
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    variants = args.variants.split(",")
    results = [measure(v, args.rollouts) for v in variants]
    base = results[0]["transitions_per_s"]
    print(f"bench_training: {ENV_KWARGS}, PPO {PPO_KWARGS}, {os.cpu_count()} cores")
    print("  | variant | VecEnv entries | transitions/s | vs first | env share of wall |")
    print("  |---|---:|---:|---:|---:|")
    for r in results:
        print(
            f"  | {r['variant']} | {r['entries']} | {r['transitions_per_s']:.0f} | "
            f"{r['transitions_per_s'] / base:.2f}x | {100 * r['env_share']:.0f} % |"
        )
    if args.json:
        write_json_atomically(args.json, results)


if __name__ == "__main__":
    main()
