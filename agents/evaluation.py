"""``swarm-phd evaluate``: the seed's localization experiment, under scripted or learned motion.

Every robot runs its own filter, for each requested localizer at once (``phd-lc``: Lidar+Camera,
``phd-lo``: Lidar-Only), fed with the same records, so the comparison is paired: same motion,
same measurements. The motion comes from ``--policy`` (default ``scripted:wander``, the seed's
pseudo-random motion with obstacle avoidance; or ``random``, or a trained ``model.zip``).

Metrics (see :mod:`localization.metrics` and ``docs/localization.md``), per observer robot, over
every (step, neighbour within ``localization_range_m``) pair:

- ``pct_time_err_gt_30cm``: % of those pairs where the distance from the neighbour to the closest
  component with weight > 0.1 exceeds 0.30 m (the seed's Fig. 7);
- ``pct_time_within_10cm``: % within 0.10 m (the seed's ``001`` tables);
- ``gospa_mean``: mean GOSPA (c = 1 m, p = 2, alpha = 2) between the neighbours in range and the
  extracted estimates (weight >= 0.5) within the same range;
- ``cardinality_mae``: mean |sum of weights within range - true count in range| (Fig. 8).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from localization import PHDBank
from localization.metrics import LocalizationScorer
from swarm_env import parallel_env
from swarm_env.env import SwarmEnv, localizer_calls

LOCALIZERS = {"phd-lc": "lidar-camera", "phd-lo": "lidar-only"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset", default=None, help="default: the model's preset for a model.zip, else seed-sim"
    )
    parser.add_argument("--duration", type=float, default=300.0, help="simulated seconds")
    parser.add_argument(
        "--localizer", default="phd-lc,phd-lo", help=f"comma-separated, from {sorted(LOCALIZERS)}"
    )
    parser.add_argument("--seeds", default="0", help="comma-separated integers")
    parser.add_argument(
        "--policy",
        default="scripted:wander",
        help="'scripted:NAME', 'random' or a trained model.zip",
    )
    parser.add_argument(
        "--task", default=None, help="default: the model's task for a model.zip, else 'wander'"
    )
    parser.add_argument(
        "--task-params",
        default=None,
        help="JSON dict of task parameters (default: the model's, else {})",
    )
    parser.add_argument(
        "--compare",
        default=None,
        help="a second policy run on the same env and seeds, reported side by "
        "side (e.g. --policy runs/X/model.zip --compare scripted:formation)",
    )
    parser.add_argument("--out", default=None, help="write metrics.json and figures here")


def run(args: argparse.Namespace) -> int:
    localizers = [s.strip() for s in args.localizer.split(",") if s.strip()]
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError as exc:
        raise ValueError(f"--seeds must be comma-separated integers, got {args.seeds!r}") from exc
    overrides: dict[str, Any] = {}
    if args.task_params is not None:
        try:
            overrides["task_params"] = json.loads(args.task_params)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--task-params must be a JSON object: {exc}") from exc
    out_dir = Path(args.out) if args.out else None
    results = evaluate_localization(
        args.preset,
        args.duration,
        localizers,
        seeds,
        policy=args.policy,
        task=args.task,
        out_dir=out_dir,
        **overrides,
    )
    print_table(results)
    if args.compare:
        shared = shared_env_kwargs(args.policy, args.preset, args.task, **overrides)
        other = evaluate_localization(
            shared.pop("preset"),
            args.duration,
            localizers,
            seeds,
            policy=args.compare,
            task=shared.pop("task"),
            out_dir=out_dir / "compare" if out_dir else None,
            **shared,
        )
        print_table(other)
        print_comparison([results, other])
        if out_dir is not None:
            (out_dir / "comparison.json").write_text(
                json.dumps(comparison_rows([results, other]), indent=2)
            )
    return 0


def shared_env_kwargs(
    policy: str, preset: str | None, task: str | None, **overrides: Any
) -> dict[str, Any]:
    """Preset, task, task parameters and config overrides of ``policy``'s evaluation env, minus
    the observation mode (each policy brings its own): what a ``--compare`` run must share."""
    kwargs: dict[str, Any] = {}
    if policy.endswith(".zip"):
        from agents.sb3.policy import read_metadata

        kwargs = dict(read_metadata(policy)["env_kwargs"])
    if task is not None and task != kwargs.get("task", task):
        kwargs.pop("task_params", None)  # the model's parameters belong to its own task
    kwargs.update(overrides)
    for key in ("observation", "localize"):
        kwargs.pop(key, None)
    kwargs["preset"] = preset or kwargs.get("preset") or "seed-sim"
    kwargs["task"] = task or kwargs.get("task") or "wander"
    return kwargs


def _make_env(preset: str | None, task: str | None, policy: str, **overrides: Any) -> SwarmEnv:
    if policy.endswith(".zip"):
        from agents.sb3.policy import read_metadata

        model = dict(read_metadata(policy)["env_kwargs"])
        model_preset = model.pop("preset", None)
        model_task = model.pop("task", "wander")
        model_params = model.pop("task_params", {})
        if task is None or task == model_task:  # the model's observation includes its task
            task = model_task
            model["task_params"] = model_params
        overrides = {**model, **overrides}
        preset = preset or model_preset
    else:
        from agents.policies import policy_observation

        observation = policy_observation(policy)
        if observation is None:
            # Policies that ignore the observation: skip the env's own filters, the evaluation
            # runs its own banks of filters below.
            overrides.setdefault("observation", "measurements")
            overrides.setdefault("localize", False)
        else:  # e.g. scripted:formation acts on the robot's own PHD estimate
            overrides.setdefault("observation", observation)
    return parallel_env(preset or "seed-sim", task=task or "wander", **overrides)


def evaluate_localization(
    preset: str,
    duration_s: float,
    localizers: list[str],
    seeds: list[int],
    policy: str = "scripted:wander",
    task: str = "wander",
    out_dir: Path | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Run the experiment; return (and optionally write) the metrics per localizer.

    Returns
    -------
    dict
        ``{"config": ..., "localizers": {name: {"pct_time_err_gt_30cm": {"per_robot": [...],
        "median": m, "max": M}, "pct_time_within_10cm": ..., "gospa_mean": g,
        "cardinality_mae": c}}, "task": {...}, "wall_time_s": ...}``
    """
    from agents.policies import load_policy

    unknown = [name for name in localizers if name not in LOCALIZERS]
    if unknown or not localizers:
        raise ValueError(f"--localizer must name some of {sorted(LOCALIZERS)}, got {localizers}")
    if duration_s <= 0:
        raise ValueError(f"duration must be > 0 s, got {duration_s}")
    start = time.perf_counter()
    env = _make_env(preset, task, policy, **overrides)
    n_steps = int(round(duration_s / env.config.control_period_s))
    base_phd = env.config.phd
    n_agents = len(env.possible_agents)
    scorers = {name: LocalizationScorer(env.config.n_robots) for name in localizers}
    trace = {
        name: {"time_s": [], "weight_sum": [], "true_count": [], "gospa": []}
        for name in localizers
    }
    paths: list[np.ndarray] = []
    estimates: dict[str, list[np.ndarray]] = {name: [] for name in localizers}
    task_metrics: list[dict[str, float]] = []
    for seed in seeds:
        # One filter per robot and localizer, fed the same records (a paired comparison).
        banks = {
            name: PHDBank(dataclasses.replace(base_phd, mode=LOCALIZERS[name]), n_agents)
            for name in localizers
        }
        act = load_policy(policy, env)
        if hasattr(act, "reset"):
            act.reset(seed)
        obs, infos = env.reset(seed=seed)
        for _ in range(n_steps):
            if not env.agents:
                break
            obs, _, _, _, infos = env.step(act(obs, infos))
            step = env.last_world_step
            truth = step.truth
            calls = [
                localizer_calls(step.measurements[agent], step.stale.get(agent, ()))
                for agent in env.possible_agents
            ]
            for name in localizers:
                banks[name].apply(calls)
                views = banks[name].views
                for i in range(n_agents):
                    mask = truth.in_range["lidar"][i]
                    scorers[name].add(
                        i,
                        truth.relative_xy[i][mask],
                        views[i].mixture,
                        range_m=env.config.localization_range_m,
                    )
                if seed == seeds[0]:
                    _trace_step(trace[name], step, views, env.config.localization_range_m)
                    estimates[name].append(_world_estimates(views[0], truth.poses[0]))
            if seed == seeds[0]:
                paths.append(truth.poses[:, :2].copy())
        task_metrics.append(env.task.metrics())
    preset = preset or ("seed-sim" if not policy.endswith(".zip") else _model_preset(policy))
    task = env.task.name
    results = {
        "config": {
            "preset": preset,
            "duration_s": duration_s,
            "seeds": seeds,
            "policy": policy,
            "task": task,
            "n_robots": env.config.n_robots,
            "localization_range_m": env.config.localization_range_m,
        },
        "localizers": {name: scorers[name].summary() for name in localizers},
        "task": _mean_dicts(task_metrics),
        "wall_time_s": time.perf_counter() - start,
    }
    env.close()
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "metrics.json").write_text(json.dumps(results, indent=2))
        from agents.figures import write_localization_figures

        write_localization_figures(out_dir, results, trace, np.array(paths), estimates)
    return results


def _model_preset(policy: str) -> str:
    from agents.sb3.policy import read_metadata

    return read_metadata(policy)["env_kwargs"].get("preset", "seed-sim")


def comparison_rows(all_results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per policy: its task metrics and each localizer's headline metrics."""
    rows = []
    for res in all_results:
        row: dict[str, Any] = {"policy": res["config"]["policy"], **res.get("task", {})}
        for name, m in res["localizers"].items():
            row[f"{name} % err>30cm (median)"] = m["pct_time_err_gt_30cm"]["median"]
            row[f"{name} GOSPA"] = m["gospa_mean"]
            row[f"{name} card. MAE"] = m["cardinality_mae"]
        rows.append(row)
    return rows


def print_comparison(all_results: list[dict[str, Any]]) -> None:
    """Task and localization metrics of several policies, side by side (markdown)."""
    rows = comparison_rows(all_results)
    keys = list(dict.fromkeys(k for row in rows for k in row if k != "policy"))
    print("  | metric | " + " | ".join(str(r["policy"]) for r in rows) + " |")
    print("  |---|" + "---|" * len(rows))
    for key in keys:
        cells = [
            f"{r[key]:.3f}" if isinstance(r.get(key), float) else str(r.get(key, "-"))
            for r in rows
        ]
        print(f"  | {key} | " + " | ".join(cells) + " |")


def _trace_step(trace: dict[str, list], step, bank, range_m: float):
    """Fig. 8 / GOSPA-over-time data for observer ugv_0."""
    from localization.metrics import gospa

    truth = step.truth
    mask = truth.in_range["lidar"][0]
    mixture = bank[0].mixture
    near = np.hypot(mixture.means[:, 0], mixture.means[:, 1]) <= range_m
    est, _ = bank[0].estimate(threshold=0.5)
    est = est[np.hypot(est[:, 0], est[:, 1]) <= range_m] if len(est) else est
    trace["time_s"].append(step.time_s)
    trace["weight_sum"].append(float(mixture.weights[near].sum()))
    trace["true_count"].append(int(mask.sum()))
    trace["gospa"].append(float(gospa(truth.relative_xy[0][mask], est).distance))


def _world_estimates(localizer, pose: np.ndarray) -> np.ndarray:
    est, _ = localizer.estimate(threshold=0.5)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return est @ np.array([[c, s], [-s, c]]) + pose[:2] if len(est) else np.zeros((0, 2))


def _mean_dicts(items: list[dict[str, float]]) -> dict[str, float]:
    keys = {k for d in items for k in d}
    return {k: float(np.mean([d[k] for d in items if k in d])) for k in sorted(keys)}


def print_table(results: dict[str, Any]) -> None:
    cfg = results["config"]
    print(
        f"  {cfg['preset']}, {cfg['n_robots']} robots, {cfg['duration_s']:.0f} s x "
        f"{len(cfg['seeds'])} seed(s), policy {cfg['policy']}, in range = "
        f"{cfg['localization_range_m']:.1f} m"
    )
    print(
        "  | localizer | % time err > 30 cm (median robot) | worst robot | robots > 25 % | "
        "% time < 10 cm | GOSPA mean | cardinality MAE |"
    )
    print("  |---|---|---|---|---|---|---|")
    for name, m in results["localizers"].items():
        per_robot = np.asarray(m["pct_time_err_gt_30cm"]["per_robot"], dtype=float)
        print(
            f"  | {name} | {m['pct_time_err_gt_30cm']['median']:.1f} | "
            f"{m['pct_time_err_gt_30cm']['max']:.1f} | {int((per_robot > 25).sum())} | "
            f"{m['pct_time_within_10cm']['median']:.1f} | {m['gospa_mean']:.3f} | "
            f"{m['cardinality_mae']:.2f} |"
        )
    if results.get("task"):
        print("  task: " + ", ".join(f"{k} = {v:.3f}" for k, v in results["task"].items()))
    print(f"  wall time {results['wall_time_s']:.1f} s")
