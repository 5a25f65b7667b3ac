"""The gains a ``--residual-mode gain`` policy asks of its scripted base, in closed loop.

    python -m experiments.residual_gains runs/formation_gain/model.zip --seeds 200-202

Each model runs deterministically on its own env (the zip's ``env_kwargs``) for every seed,
and every agent-step's correction ``c`` gives the gains ``4 ** c`` it asks for on the scripted
command's speed and turn rate (:func:`agents.sb3.residual.compose`). Printed per model: their
arithmetic mean and 10th / 90th percentiles (1 = the base unchanged); ``--out`` also writes
them as JSON. The change actually applied is smaller where the base command is zero (a gain
cannot move it) or the result is clipped to the action bounds, and the arithmetic mean of
``4 ** c`` exceeds ``4 ** mean(c)`` by the spread (about 2.5 % at a 10th-90th percentile
range of 0.77-1.37). Question: did PPO find a gain? Answered without a 50-seed score.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.sb3.residual import GAIN_RANGE
from swarm_core.inputs import parse_seeds


def requested_gains(path: str | Path, seeds: list[int]) -> np.ndarray:
    """The gains ``4 ** c`` (agent-steps, 2) ``[speed, turn rate]`` the gain-mode residual
    ``path`` asks for over deterministic closed-loop episodes of ``seeds``."""
    from agents.sb3.policy import load_sb3_policy, read_metadata
    from swarm_env import parallel_env

    env = parallel_env(**read_metadata(check_gain_model(path))["env_kwargs"])
    gains = []
    try:
        policy = load_sb3_policy(path, env)  # once: reset() reseeds it per episode
        for seed in seeds:
            policy.reset(seed)
            obs, infos = env.reset(seed=seed)
            while env.agents:
                actions = policy(obs, infos)
                gains.extend(policy.last_correction[a] for a in obs)
                obs, _, _, _, infos = env.step(actions)
    finally:
        env.close()
    return np.power(GAIN_RANGE, np.asarray(gains, np.float64).reshape(-1, 2))


def check_gain_model(path: str | Path) -> str | Path:
    """``path`` if its zip is a ``--residual-mode gain`` residual, else ``ValueError``."""
    from agents.sb3.policy import read_metadata

    mode = read_metadata(path).get("residual_mode", "add")
    if mode != "gain":
        raise ValueError(
            f"{str(path)!r} is not a --residual-mode gain model: residual_mode {mode!r}"
        )
    return path


def summarise(gains: np.ndarray) -> dict[str, Any]:
    """Mean and 10th / 90th percentiles of each column of ``gains`` (N, 2)."""
    return {
        name: {
            "mean": float(gains[:, i].mean()),
            "p10": float(np.percentile(gains[:, i], 10)),
            "p90": float(np.percentile(gains[:, i], 90)),
        }
        for i, name in enumerate(("speed", "turn_rate"))
    } | {"agent_steps": int(len(gains))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("models", nargs="+", help="model zips of --residual-mode gain runs")
    parser.add_argument("--seeds", default="200-202")
    parser.add_argument("--out", default=None, help="write the summaries as JSON here")
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    for model in args.models:  # refuse a wrong model before any of them runs
        check_gain_model(model)
    rows = {}
    for model in args.models:
        rows[model] = row = summarise(requested_gains(model, seeds))
        speed, turn = row["speed"], row["turn_rate"]
        print(
            f"{model}: speed gain {speed['mean']:.3f} (p10 {speed['p10']:.3f}, p90 "
            f"{speed['p90']:.3f}); turn-rate gain {turn['mean']:.3f} (p10 {turn['p10']:.3f}, "
            f"p90 {turn['p90']:.3f})",
            flush=True,
        )
    if args.out:
        Path(args.out).write_text(json.dumps({"seeds": seeds, "models": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
