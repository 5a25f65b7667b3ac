"""The Deep Sets extractor's forward and backward, torch-op pooling against the fused kernels.

One PPO minibatch's worth of real observations (512 ``lab-3m-4`` PHD tables of 16 rows, from
random motion) through :class:`agents.sb3.features.NeighbourSetExtractor`, forward and
backward, on one torch thread: once with :func:`agents.sb3.set_pooling.pool_reference` (the
torch formula) and once with :func:`agents.sb3.set_pooling.relu_masked_pool` (the compiled
one), alternated ``--repeats`` times. Reports the median ms of each and their ratio.

    .venv/bin/python benchmarks/bench_set_pooling.py [--repeats 5] [--json PATH]
"""

from __future__ import annotations

import argparse
import time

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

    def timed(pool) -> float:
        features.relu_masked_pool = pool
        try:
            for _ in range(3):  # warm-up (and the kernels' first load)
                (extractor(obs) * upstream).sum().backward()
            start = time.perf_counter()
            for _ in range(args.iterations):
                extractor.zero_grad()
                (extractor(obs) * upstream).sum().backward()
            return (time.perf_counter() - start) / args.iterations * 1e3
        finally:
            features.relu_masked_pool = relu_masked_pool

    ms = {"torch_ops": [], "fused": []}
    for _ in range(args.repeats):
        ms["torch_ops"].append(timed(pool_reference))
        ms["fused"].append(timed(relu_masked_pool))
    result = {name: float(np.median(v)) for name, v in ms.items()}
    result["speedup"] = result["torch_ops"] / result["fused"]
    result["all_ms"] = ms
    print(
        f"extractor forward+backward, 512 tables: torch ops {result['torch_ops']:.2f} ms, "
        f"fused {result['fused']:.2f} ms ({result['speedup']:.2f}x)"
    )
    if args.json:
        write_json_atomically(args.json, result)


if __name__ == "__main__":
    main()
