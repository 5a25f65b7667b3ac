"""The Deep Sets extractor's pooling, torch ops against the fused kernels: alone and in PPO.

Two timings, each alternating :func:`agents.sb3.set_pooling.pool_reference` (the torch
formula) and :func:`agents.sb3.set_pooling.relu_masked_pool` (the compiled one)
``--repeats`` times on one torch thread, reported as medians and their ratio:

- ``extractor``: one PPO minibatch's worth of real observations (512 ``lab-3m-4`` PHD tables
  of 16 rows, from random motion) through
  :class:`agents.sb3.features.NeighbourSetExtractor`, forward and backward (ms);
- ``update``: PPO's update alone (``model.train()``, ``benchmarks/bench_training.py``'s PPO),
  on one rollout of 16 batched copies (8192 agent transitions), in us per transition.

    .venv/bin/python benchmarks/bench_set_pooling.py [--repeats 5] [--json PATH]
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import numpy as np

from swarm_core.atomic_files import write_json_atomically


def real_tables(n: int = 512, seed: int = 0):
    """``n`` observations (n, D) of ``lab-3m-4`` formation copies under random actions, and
    their observation space."""
    from agents.sb3.batched import BatchedSwarmVecEnv

    vec = BatchedSwarmVecEnv({"preset": "lab-3m-4", "task": "formation"}, 4, seed=seed)
    rng = np.random.default_rng(seed)
    batches = [vec.reset()]
    while sum(len(b) for b in batches) < n:
        batches.append(vec.step(rng.uniform(-1, 1, (vec.num_envs, 2)).astype(np.float32))[0])
    space = vec.observation_space
    vec.close()
    return np.concatenate(batches)[:n], space


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=40, help="passes per timing")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    import torch

    import agents.sb3.features as features
    from agents.sb3.set_pooling import pool_reference, relu_masked_pool
    from swarm_core.threads import set_kernel_threads

    torch.set_num_threads(1)
    set_kernel_threads(1)
    obs_np, space = real_tables()
    obs = torch.as_tensor(obs_np)
    torch.manual_seed(0)
    extractor = features.NeighbourSetExtractor(space, top_k=16)
    upstream = torch.randn(len(obs), extractor.features_dim)

    def extractor_ms() -> float:
        for _ in range(3):  # warm-up (and the kernels' first load)
            (extractor(obs) * upstream).sum().backward()
        start = time.perf_counter()
        for _ in range(args.iterations):
            extractor.zero_grad()
            (extractor(obs) * upstream).sum().backward()
        return (time.perf_counter() - start) / args.iterations * 1e3

    model = _model_with_a_rollout()
    transitions = model.rollout_buffer.size() * model.n_envs

    def update_us() -> float:
        start = time.perf_counter()
        model.train()
        return (time.perf_counter() - start) / transitions * 1e6

    update_us()  # warm-up
    poolings = {"torch_ops": pool_reference, "fused": relu_masked_pool}
    timings = {"extractor": (extractor_ms, "ms"), "update": (update_us, "us per transition")}
    result = {}
    for name, (timed, unit) in timings.items():
        runs = {"torch_ops": [], "fused": []}
        for _ in range(args.repeats):
            for label, pool in poolings.items():  # the extractor looks the pooling up per call
                with mock.patch.object(features, "relu_masked_pool", pool):
                    runs[label].append(timed())
        medians = {k: float(np.median(v)) for k, v in runs.items()}
        speedup = medians["torch_ops"] / medians["fused"]
        result[name] = {**medians, "speedup": speedup, "unit": unit, "all": runs}
        print(
            f"{name}: torch ops {medians['torch_ops']:.2f}, fused {medians['fused']:.2f} "
            f"{unit} ({speedup:.2f}x)"
        )
    if args.json:
        write_json_atomically(args.json, result)


def _model_with_a_rollout():
    """``bench_training``'s PPO on 16 batched copies, its rollout buffer full (one rollout)."""
    from bench_training import make_ppo, make_venv
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.utils import configure_logger

    class Nothing(BaseCallback):
        def _on_step(self) -> bool:
            return True

    model = make_ppo(make_venv("batched-16"))
    model._setup_learn(model.n_steps * model.n_envs, None)  # SB3's own preamble to learn()
    model._logger = configure_logger(0, None, "", False)
    callback = Nothing()
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)
    model.env.close()
    return model


if __name__ == "__main__":
    main()
