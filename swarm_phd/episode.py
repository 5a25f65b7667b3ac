"""Run an episode through the env API and score the robots' own localization against ground
truth (motion capture on robots, the simulator's truth otherwise), with the project's metrics
(:class:`localization.metrics.LocalizationScorer`). Shared by ``swarm-phd bridge`` and
``swarm-phd replay`` and the end-to-end tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm_core import progress


@dataclass
class EpisodeResult:
    steps: int = 0
    scored_steps: int = 0
    stale_steps: dict[str, int] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    # Per step, per agent: (weights (N,), means (N, 2)) of the agent's PHD, if traced.
    trace: list[dict[str, tuple[np.ndarray, np.ndarray]]] = field(default_factory=list)


def snapshot_mixtures(env) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {
        a: (env.localizers[i].mixture.weights.copy(), env.localizers[i].mixture.means.copy())
        for i, a in enumerate(env.possible_agents)
    }


def run_episode(
    env,
    policy: Callable[[dict, dict], dict] | None,
    n_steps: int,
    *,
    seed: int | None = 0,
    trace: bool = False,
    on_step: Callable[[int, dict], None] | None = None,
) -> EpisodeResult:
    """Reset ``env`` (and ``policy``, if it has a ``reset``, with the same ``seed``; not for
    ``seed=None``), run ``policy`` (``None``: zero commands) for up to ``n_steps`` steps and
    score every step that has ground truth. Stops early at the end of the episode."""
    from localization.metrics import LocalizationScorer

    n = len(env.possible_agents)
    range_m = env.config.localization_range_m
    # Per observer, as ``swarm-phd evaluate`` scores the simulator.
    scorer = LocalizationScorer(n, cardinality_range_m=range_m)
    result = EpisodeResult()
    if seed is not None and hasattr(policy, "reset"):  # e.g. a recurrent student's state
        policy.reset(seed)
    obs, infos = env.reset(seed=seed)
    if trace:
        result.trace.append(snapshot_mixtures(env))
    for k in progress.sim_steps(n_steps, env.config.control_period_s, "episode", leave=False):
        if not env.agents:
            break
        actions = (
            policy(obs, infos)
            if policy is not None
            else {a: np.zeros(2, dtype=np.float32) for a in env.agents}
        )
        obs, _, _, _, infos = env.step(actions)
        result.steps += 1
        if trace:
            result.trace.append(snapshot_mixtures(env))
        scored = False
        for i, agent in enumerate(env.possible_agents):
            info = infos.get(agent)
            if info is None:
                continue
            for sensor in info.get("stale", ()):
                result.stale_steps[sensor] = result.stale_steps.get(sensor, 0) + 1
            truth = info.get("truth")
            if truth is None:
                continue
            mask = np.asarray(truth["in_range"]["lidar"], dtype=bool)
            scorer.add(i, truth["neighbours_xy"][mask], env.localizers[i].mixture, range_m=range_m)
            scored = True
        result.scored_steps += int(scored)
        if on_step is not None:
            on_step(k, infos)
    if result.scored_steps:
        result.metrics = scorer.summary()
    return result


def format_metrics(metrics: dict[str, Any]) -> str:
    if not metrics:
        return "  no ground truth (no motion capture): localization not scored"
    lines = []
    for key, value in metrics.items():
        if isinstance(value, dict):
            inner = ", ".join(f"{k}={_fmt(v)}" for k, v in value.items() if k != "per_robot")
            lines.append(f"  {key}: {inner}")
        else:
            lines.append(f"  {key}: {_fmt(value)}")
    return "\n".join(lines)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)
