"""A short seeded rollout, pinned bit for bit: observations, every robot's filter table, poses.

A refactor must leave these hashes unchanged (the data-flow spine was checked this way
against the code before it, on these four configurations). A change of the physics, a sensor
model or a filter's math changes them on purpose: then update the constants in the same
commit and say why in its message.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from swarm_env import parallel_env


def rollout_hash(steps: int = 60, seed: int = 3, **kwargs) -> str:
    env = parallel_env("lab-3m-4", max_steps=steps + 5, **kwargs)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    h = hashlib.sha256()
    for _ in range(steps):
        obs, *_ = env.step({a: rng.uniform(-1, 1, 2) * [0.3, 1.5] for a in env.agents})
        for agent in sorted(obs):
            h.update(obs[agent].tobytes())
        if env.config.localize:
            table, counts = env.localizer.padded_tables()
            for r in range(len(counts)):
                h.update(np.ascontiguousarray(table[:, r, : counts[r]]).tobytes())
        h.update(env.last_world_step.truth.poses.tobytes())
    env.close()
    return h.hexdigest()[:16]


PINNED = {
    "phd-lc": ({"localizer": "phd-lc"}, "50fca56a0405e160"),
    "phd-lo": ({"localizer": "phd-lo"}, "8ce198e4164ddd71"),
    "pmb-lc": ({"localizer": "pmb-lc"}, "3c9ac5d521ea2cd4"),
    "measurements": ({"observation": "measurements", "localize": False}, "a5183c8ff2ac8d00"),
}


@pytest.mark.parametrize("case", sorted(PINNED))
def test_rollout_is_pinned(case):
    kwargs, expected = PINNED[case]
    assert rollout_hash(**kwargs) == expected
