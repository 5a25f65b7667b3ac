"""How much return a change of a scripted base's gains is worth, against the return's noise.

    python -m experiments.paired_returns --base scripted:formation-known-n --speed-gains 2 1 \\
        --preset lab-3m-4 --seeds 300-339 --task-params '{"progress_weight": 10}'

For every seed two copies of the env run the same episode (same seed: the same layout, start
poses and random draws until the two closed loops part) under the base controller, one with
its speed and turn-rate commands scaled by gains A, the other by gains B (the
``--residual-mode gain`` composition, :func:`agents.sb3.residual.compose`, so ``A = 2`` is
what a gain residual with correction 0.5 would send). These are common random numbers: what
the two arms share cancels in their difference. Reported, on the per-agent training reward
summed over the episode (what PPO's returns are made of, undiscounted):

- each arm's mean per-agent return, and the paired difference A − B with its SE over seeds;
- ``agent_return_sd``: the spread of a per-agent return (the noise one agent-episode carries,
  pooled over both arms), and ``agent_return_correlation`` between the arms' per-agent
  returns (0: pairing removes nothing; 1: the arms move together);
- ``episode_return_sd`` and ``episode_return_correlation``: the same for the episode's mean
  over its agents, the level the SE and the episode counts below are taken at (a paired
  difference's variance is ``2 (1 - rho)`` times one arm's, with this ``rho``);
- ``episodes_for_2se_paired`` / ``_unpaired``: the episodes (per arm) for the difference of
  episode means to reach 2 SE, with and without the pairing. A policy gradient sees a smaller
  change than A vs B (its exploration noise), with less pairing than this.

Question: can PPO see this change at this budget? Answered before a training run; the figures
are printed (``--out`` writes them as JSON).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import paired_difference
from agents.sb3.residual import GAIN_RANGE
from swarm_core.inputs import parse_seeds

__all__ = ["paired_returns", "summarise_pairs"]

#: Seeds run side by side (2 copies each) in one batched filter call.
_SEEDS_PER_CALL = 4


def paired_returns(
    env_kwargs: dict[str, Any],
    base: str,
    gains_a: tuple[float, float],
    gains_b: tuple[float, float],
    seeds: list[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Per-agent episode returns (seeds, agents) of arms A and B (module doc).

    ``gains_*``: ``(speed gain, turn-rate gain)``, each in [1/4, 4]; ``base``:
    ``"scripted:NAME"``; ``env_kwargs``: :func:`swarm_env.parallel_env` arguments."""
    from agents.sb3.batched import BatchedSwarmVecEnv
    from agents.sb3.residual import check_residual

    check_residual(base, field="base")
    corrections = [
        _gain_corrections(f"gains_{arm}", g) for arm, g in (("a", gains_a), ("b", gains_b))
    ]
    seeds = list(seeds)
    if len(seeds) < 2 or not all(
        isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0 for s in seeds
    ):
        raise ValueError(f"seeds must be at least 2 ints >= 0, got {seeds!r}")
    n_pairs = min(_SEEDS_PER_CALL, len(seeds))
    venv = BatchedSwarmVecEnv(
        env_kwargs, 2 * n_pairs, seed=None, residual=base, residual_mode="gain"
    )
    n = venv.agents_per_copy
    # Copy 2j runs arm A and copy 2j + 1 arm B of the chunk's j-th seed.
    actions = np.tile(np.repeat(np.stack(corrections), n, axis=0), (n_pairs, 1)).astype(np.float32)
    returns = np.zeros((len(seeds), 2, n))
    try:
        for start in range(0, len(seeds), n_pairs):
            chunk = seeds[start : start + n_pairs]
            padded = chunk + [chunk[0]] * (n_pairs - len(chunk))  # a short last chunk
            venv.reset(copy_seeds=[s for s in padded for _ in range(2)])
            total = np.zeros(venv.num_envs)
            running = np.ones(venv.num_envs, bool)
            while running.any():
                _, rewards, dones, _ = venv.step(actions)
                total += np.where(running, rewards, 0.0)
                running &= ~dones  # the copy's auto-reset episode is not counted
            returns[start : start + len(chunk)] = total.reshape(n_pairs, 2, n)[: len(chunk)]
    finally:
        venv.close()
    return returns[:, 0], returns[:, 1]


def summarise_pairs(returns_a: np.ndarray, returns_b: np.ndarray) -> dict[str, float]:
    """The module doc's statistics from per-agent returns (seeds, agents) of both arms."""
    a, b = np.asarray(returns_a, np.float64), np.asarray(returns_b, np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[0] < 2:
        raise ValueError(
            f"need (seeds >= 2, agents) returns of one shape, got {a.shape} and {b.shape}"
        )
    # Per seed, over its agents; the difference and its SE as every comparison takes them.
    paired = paired_difference(a.mean(axis=1), b.mean(axis=1), "episode_return")
    delta = paired["mean_difference"]
    sd_paired = paired["standard_error"] * math.sqrt(paired["n_seeds"])
    sd_episode = float(np.sqrt(0.5 * (a.mean(axis=1).var(ddof=1) + b.mean(axis=1).var(ddof=1))))

    def episodes(sd: float) -> float:  # n with sd / sqrt(n) = |delta| / 2
        return math.inf if delta == 0 else (2.0 * sd / abs(delta)) ** 2

    return {
        "pairs": int(a.shape[0]),
        "return_a": float(a.mean()),
        "return_b": float(b.mean()),
        "difference": delta,
        "difference_se": paired["standard_error"],
        "agent_return_sd": float(np.sqrt(0.5 * (a.var(ddof=1) + b.var(ddof=1)))),
        "agent_return_correlation": float(np.corrcoef(a.ravel(), b.ravel())[0, 1]),
        "episode_return_sd": sd_episode,
        "episode_return_correlation": float(np.corrcoef(a.mean(axis=1), b.mean(axis=1))[0, 1]),
        "episodes_for_2se_paired": episodes(sd_paired),
        # Two independent arms: the difference's variance is twice one arm's.
        "episodes_for_2se_unpaired": episodes(math.sqrt(2.0) * sd_episode),
    }


def _gain_corrections(name: str, gains: tuple[float, float]) -> np.ndarray:
    """The gain residual's correction ``log_4(gain)`` per command; refuses what it cannot send."""
    try:
        g = np.asarray(gains, dtype=np.float64)
    except (TypeError, ValueError):
        g = np.full(1, np.nan)  # not numbers: refused below with the field's name
    if (
        g.shape != (2,)
        or not np.all(np.isfinite(g))
        or np.any(g < 1 / GAIN_RANGE)
        or np.any(g > GAIN_RANGE)
    ):
        raise ValueError(
            f"{name} must be (speed gain, turn-rate gain), each in [1/{GAIN_RANGE:g}, "
            f"{GAIN_RANGE:g}], got {gains!r}"
        )
    return np.log(g) / math.log(GAIN_RANGE)


def main(argv: list[str] | None = None) -> int:
    from agents.sb3.train import add_env_arguments, env_kwargs_from_args

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_env_arguments(parser)
    parser.add_argument("--base", required=True, help="scripted:NAME, the controller scaled")
    parser.add_argument(
        "--speed-gains", type=float, nargs=2, default=(2.0, 1.0), metavar=("A", "B")
    )
    parser.add_argument(
        "--turn-gains", type=float, nargs=2, default=(1.0, 1.0), metavar=("A", "B")
    )
    parser.add_argument("--seeds", default="300-339", help="episodes, one pair each")
    parser.add_argument("--out", default=None, help="write the summary as JSON here")
    args = parser.parse_args(argv)
    env_kwargs = env_kwargs_from_args(args)
    gains_a = (args.speed_gains[0], args.turn_gains[0])
    gains_b = (args.speed_gains[1], args.turn_gains[1])
    seeds = parse_seeds(args.seeds)
    summary = summarise_pairs(*paired_returns(env_kwargs, args.base, gains_a, gains_b, seeds))
    print(
        f"{args.base} x gains {gains_a} - x gains {gains_b}, {len(seeds)} seeds: per-agent return "
        f"{summary['difference']:+.2f} (SE {summary['difference_se']:.2f}); one agent-episode's "
        f"sd {summary['agent_return_sd']:.1f}; arms' correlation "
        f"{summary['agent_return_correlation']:.2f} per agent, "
        f"{summary['episode_return_correlation']:.2f} per episode; episodes for 2 SE: "
        f"{summary['episodes_for_2se_paired']:.0f} paired, "
        f"{summary['episodes_for_2se_unpaired']:.0f} unpaired",
        flush=True,
    )
    if args.out:
        record = {
            "base": args.base,
            "gains_a": gains_a,
            "gains_b": gains_b,
            "seeds": seeds,
            "env_kwargs": env_kwargs,
            **summary,
        }
        Path(args.out).write_text(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
