"""Where the scripted formation controller's error comes from: its centroid estimate.

``scripted:formation`` steers each robot to the circle around the swarm's centroid *as the
robot estimates it* (:func:`agents.scripted.estimated_centroid` over the confident components
of its own PHD table). This tool runs that controller on the PHD observation and, for every
robot and step from ``--from-step`` on (the settled formation), compares:

- each true teammate's position with the nearest confident component (how well the robot
  localizes its teammates);
- the controller's centroid estimate with the true centroid (both in the robot's body frame);
- the same estimate from only the components that sit on a true teammate (within
  ``--match-m``; an oracle no robot has), with the controller's weights and with weight 1;
- every confident component that sits on no teammate, by what it sits on
  (:func:`classify_components`): a decoy post, a red decoy, a wall, or nothing known.

    python -m agents.formation_diagnosis --preset lab-3m-4 --seeds 200-204 --from-step 150

Figures of ``docs/results.md`` (round 3); a JSON summary with ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.scripted import estimated_centroid, estimated_neighbours, split_observation
from swarm_core.world import relative_positions

KINDS = ("post", "red_decoy", "wall", "other")


def classify_components(
    world_xy: np.ndarray,
    teammates_xy: np.ndarray,
    layout: Any,
    arena_half_m: tuple[float, float],
    match_m: float = 0.15,
    object_m: float = 0.2,
) -> np.ndarray:
    """What each estimated component sits on, shape (M,) of strings.

    ``"teammate"`` within ``match_m`` of a true teammate (``teammates_xy`` (K, 2)); else
    ``"post"`` / ``"red_decoy"`` within ``object_m`` of one (``layout.posts_xy``,
    ``layout.red_decoys_xy``); else ``"wall"`` within ``object_m`` of the arena's walls
    (``|x| = arena_half_m[0]`` or ``|y| = arena_half_m[1]``); else ``"other"``. World frame,
    metres; ``world_xy`` (M, 2)."""
    world_xy = np.asarray(world_xy, dtype=float).reshape(-1, 2)

    def near(points: np.ndarray, radius: float) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if not len(points):
            return np.zeros(len(world_xy), dtype=bool)
        d = np.linalg.norm(world_xy[:, None, :] - points[None, :, :], axis=2)
        return d.min(axis=1) <= radius

    wall_gap = np.min(np.asarray(arena_half_m) - np.abs(world_xy), axis=1)
    kind = np.full(len(world_xy), "other", dtype=object)
    kind[wall_gap <= object_m] = "wall"
    kind[near(layout.red_decoys_xy, object_m)] = "red_decoy"
    kind[near(layout.posts_xy, object_m)] = "post"
    kind[near(teammates_xy, match_m)] = "teammate"
    return kind


def diagnose(
    preset: str,
    seeds: list[int],
    from_step: int,
    max_steps: int = 300,
    match_m: float = 0.15,
    observation: str = "phd",
    env_overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run ``scripted:formation`` on ``observation`` (``"phd"``, or ``"truth"`` as a check:
    every component is then a teammate) for ``seeds``, in ``preset`` with ``env_overrides``
    (``parallel_env`` keywords); the module doc's figures (medians and means in metres, counts
    per observer-step)."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    if not 0 <= from_step < max_steps:
        raise ValueError(f"--from-step must be in [0, {max_steps}), got {from_step}")
    fixed = {"preset", "task", "observation", "max_steps"} & set(env_overrides or {})
    if fixed:
        raise ValueError(
            f"--env-overrides may not set {sorted(fixed)}: the diagnosis sets them (use --preset, "
            "--observation, --max-steps)"
        )
    env = parallel_env(
        preset=preset,
        task="formation",
        observation=observation,
        max_steps=max_steps,
        **(env_overrides or {}),
    )
    policy = load_policy("scripted:formation", env)
    arena = env.config.arena
    half = (0.5 * arena.width_m, 0.5 * arena.height_m)
    errors: dict[str, list[float]] = {"controller": [], "oracle": [], "oracle_weight_1": []}
    teammate_errors: list[np.ndarray] = []
    counts = dict.fromkeys(KINDS, 0)
    formation: list[float] = []
    observer_steps = 0
    for seed in seeds:
        policy.reset(seed)
        obs, infos = env.reset(seed=seed)
        layout = env.unwrapped.world.layout
        for t in range(max_steps):
            actions = policy(obs, infos)
            if t >= from_step:
                truth = env.last_world_step.truth
                poses = truth.poses[: len(env.possible_agents)]
                centroid = relative_positions(poses, poses[:, :2].mean(axis=0, keepdims=True))
                formation.append(float(env.task.errors(poses[:, :2])[0].mean()))
                for i, agent in enumerate(env.possible_agents):
                    observer_steps += 1
                    table = split_observation(obs[agent], policy.top_k, policy.n_sectors)[0]
                    pts, w = estimated_neighbours(
                        table, policy.min_weight, reference_variance_m2=0.02
                    )
                    c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
                    world = poses[i, :2] + pts @ np.array([[c, s], [-s, c]])
                    others = np.delete(poses[:, :2], i, axis=0)
                    kind = classify_components(world, others, layout, half, match_m)
                    for k in KINDS:
                        counts[k] += int((kind == k).sum())
                    if len(world):
                        gap = np.linalg.norm(others[:, None, :] - world[None, :, :], axis=2)
                        teammate_errors.append(gap.min(axis=1))
                    mate = kind == "teammate"
                    true_c = centroid[i, 0]
                    for name, value in (
                        ("controller", estimated_centroid(pts, w)),
                        ("oracle", estimated_centroid(pts[mate], w[mate])),
                        ("oracle_weight_1", estimated_centroid(pts[mate], np.ones(mate.sum()))),
                    ):
                        errors[name].append(float(np.linalg.norm(value - true_c)))
            obs, _, _, _, infos = env.step(actions)
    env.close()
    spurious = sum(counts.values())
    return {
        "preset": preset,
        "seeds": seeds,
        "from_step": from_step,
        "formation_error_m": float(np.mean(formation)),
        "teammate_error_m": {
            "median": float(np.median(np.concatenate(teammate_errors or [np.zeros(0)]))),
            "mean": float(np.mean(np.concatenate(teammate_errors or [np.zeros(0)]))),
        },
        "centroid_error_m": {
            name: {"median": float(np.median(v)), "mean": float(np.mean(v))}
            for name, v in errors.items()
        },
        "spurious_per_observer_step": spurious / max(1, observer_steps),
        "spurious_share": {k: counts[k] / max(1, spurious) for k in KINDS},
        "observer_steps": observer_steps,
    }


def main(argv: list[str] | None = None) -> int:
    from swarm_phd.sweep import parse_json_object, parse_seeds

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="lab-3m-4")
    parser.add_argument("--seeds", default="200-204")
    parser.add_argument("--from-step", type=int, default=150, help="first step scored")
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--match-m", type=float, default=0.15, help="'on a teammate' radius")
    parser.add_argument("--observation", default="phd", choices=["phd", "truth"])
    parser.add_argument(
        "--env-overrides",
        default=None,
        help='env keywords as JSON, e.g. \'{"phd": {"scan_evidence": true}}\'',
    )
    parser.add_argument("--out", default=None, help="JSON summary file")
    args = parser.parse_args(argv)
    summary = diagnose(
        args.preset,
        parse_seeds(args.seeds),
        args.from_step,
        args.max_steps,
        args.match_m,
        args.observation,
        parse_json_object(args.env_overrides, "--env-overrides"),
    )
    print(json.dumps(summary, indent=2))
    if args.out:
        from swarm_core.atomic_files import write_json_atomically

        write_json_atomically(Path(args.out), summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
