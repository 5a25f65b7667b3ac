"""Run an env with a policy and collect what the demo, the benchmark and the evaluation need."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv

Policy = Callable[[dict[str, np.ndarray], dict[str, dict[str, Any]]], dict[str, np.ndarray]]
StepHook = Callable[[SwarmEnv, int], None]


@dataclass
class RolloutResult:
    steps: int
    sim_time_s: float
    wall_time_s: float
    episode_return: dict[str, float] = field(default_factory=dict)

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / max(self.wall_time_s, 1e-9)

    @property
    def steps_per_s(self) -> float:
        return self.steps / max(self.wall_time_s, 1e-9)


def rollout(
    env: SwarmEnv,
    policy: Policy,
    n_steps: int,
    seed: int | None = 0,
    on_step: StepHook | None = None,
    progress: str | None = None,
) -> RolloutResult:
    """Reset with ``seed`` and step ``n_steps`` times (or until every agent is done).

    ``progress``: a label to show a bar over simulated time (:mod:`swarm_core.progress`; the
    bar's own cost is a few microseconds per step and is counted in ``wall_time_s``).
    """
    from swarm_core import progress as bars

    bar = (
        bars.bar(n_steps * env.config.control_period_s, progress, unit="s sim", fmt="{:.1f}")
        if progress
        else bars.NullBar()
    )
    try:
        return _rollout(env, policy, n_steps, seed, on_step, bar)
    finally:
        bar.close()


def _rollout(env, policy, n_steps, seed, on_step, bar) -> RolloutResult:
    dt = env.config.control_period_s
    total = n_steps * dt
    obs, infos = env.reset(seed=seed)
    returns = {a: 0.0 for a in env.possible_agents}
    if on_step is not None:
        on_step(env, 0)
    start = time.perf_counter()
    hook_s = 0.0  # time spent in the hook (rendering, logging) is not the env's
    steps = 0
    while steps < n_steps and env.agents:
        actions = policy(obs, infos)
        obs, rewards, _, _, infos = env.step(actions)
        for agent, r in rewards.items():
            returns[agent] += r
        steps += 1
        bar.update(min(steps * dt, total) - bar.n)  # no float drift past the total
        if on_step is not None:
            t0 = time.perf_counter()
            on_step(env, steps)
            hook_s += time.perf_counter() - t0
    wall = time.perf_counter() - start - hook_s
    return RolloutResult(steps, env.time_s, wall, returns)
