"""Score policies on a task and draw learning curves (the figures of ``docs/results.md``).

    python -m agents.sb3.report --runs runs/formation_phd runs/formation_truth \\
        --baselines random scripted:formation --seeds 100-109 --out docs/results

``--warm-start`` also scores each run's ``warm_start.zip`` (the behaviour-cloned actor before
PPO); ``--name`` prefixes the outputs (``results_<name>.json``, ``results_<name>_learning_curve
.png``); ``--metric`` is the task metric of the tables and the checkpoint panel (default
``formation_error_m``; ``coverage`` for exploration, whose per-step coverage curves are also
recorded and drawn). A markdown table (mean +- std over the held-out seeds, and pooled over the
runs) is printed and written to ``results_<name>.md``, with a second one that pairs every
learned group and baseline with every baseline, and every learned group with every earlier
group, by seed (:func:`paired_differences`: the mean difference, its standard error and on
how many seeds the policy is better; ``--group tuned=... --group start=...`` gives what the
fine-tuning added).
``--group NAME=A,B`` scores more policies (models, recurrent students: each in its own env,
with ``--baseline-overrides``) pooled as one learned group; without ``--runs``, ``--env-from
MODEL`` gives the baselines' env. ``--phases 0,150`` also scores
the metric over phases of the episode (steps 0-149 and 150 to
the end: ``formation_error_m@0-150``, ``formation_error_m@150-``, from the task's per-step
series), with a paired table per phase.

Every policy runs on the same held-out seeds (not used in training: training seeds its copies
from 0..n_copies-1 and continues their generators), in the env its model was trained in, for one
episode (``max_steps``). Scripted policies get the model's env with ``observation="phd"``
(``scripted:formation@truth`` for ground-truth neighbours); ``random`` ignores the observation.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from swarm_core.atomic_files import atomic_write
from swarm_phd.sweep import parse_json_object, parse_seeds

METRICS = ("formation_error_m", "final_formation_error_m", "spacing_error_m")


#: Task metrics where more is better (the rest are errors and rates: less is better).
HIGHER_IS_BETTER = (
    "coverage",
    "episode_return",
    "enclosed_fraction",
    "final_enclosed_fraction",
    "ever_enclosed",
)


def higher_is_better(metric: str) -> bool:
    """Whether more of ``metric`` (or of its phase, ``NAME@LO-HI``) is better."""
    return metric.split("@", 1)[0] in HIGHER_IS_BETTER


def phase_key(name: str, lo: int, hi: int | None) -> str:
    """``formation_error_m@150-300``; the last, open-ended phase ``formation_error_m@150-``."""
    return f"{name}@{lo}-{'' if hi is None else hi}"


def phase_spans(phases: Any) -> list[tuple[int, int | None]]:
    """First steps ``[0, 150]`` -> spans ``[(0, 150), (150, None)]`` (the last open-ended);
    ValueError unless they are increasing integers >= 0."""
    bounds = [int(p) for p in phases]
    if not bounds or bounds != sorted(set(bounds)) or bounds[0] < 0:
        raise ValueError(f"phases must be increasing step numbers >= 0, got {list(phases)!r}")
    return list(zip(bounds, [*bounds[1:], None], strict=True))


def phase_metrics(series: dict[str, np.ndarray], phases: list[int]) -> dict[str, float]:
    """Each per-step series (``Task.step_series``, index t: the step t + 1 ends) averaged over
    the phases ``[phases[i], phases[i + 1])`` (the last open-ended), keyed by
    :func:`phase_key`; NaN for a phase the episode did not reach."""
    spans = phase_spans(phases)
    out = {}
    for name, values in series.items():
        for lo, hi in spans:
            part = np.asarray(values, dtype=float)[lo:hi]
            out[phase_key(name, lo, hi)] = float(part.mean()) if part.size else float("nan")
    return out


def score(
    policy_spec: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    n_steps: int | None = None,
    phases: list[int] | None = None,
) -> dict[str, Any]:
    """Mean/std over seeds of the task metrics and of the per-agent episode return; with
    ``phases`` (first steps), also of each per-step task series over each phase
    (:func:`phase_metrics`, e.g. ``formation_error_m@150-``)."""
    from agents.policies import load_policy
    from swarm_env import parallel_env
    from swarm_env.tasks import task_needs_estimates

    kwargs = dict(env_kwargs)
    spec = policy_spec
    # A localization term on the estimate needs the filters whatever the policy reads.
    needs = task_needs_estimates(kwargs.get("task", "wander"), kwargs.get("task_params"))
    # scripted:NAME@truth runs in an env on the truth; privileged:NAME@truth reads the truth
    # from its infos, in an env on the estimate (the next branch).
    if spec.startswith("scripted:") and spec.endswith("@truth"):
        spec = spec[: -len("@truth")]
        kwargs.update(observation="truth", localize=needs)
    elif not spec.endswith(".zip"):
        from agents.policies import policy_observation

        mode = policy_observation(spec)
        kwargs.update(observation=mode or "measurements", localize=mode == "phd" or needs)
    env = parallel_env(**kwargs)
    policy = load_policy(spec, env)
    n_steps = n_steps or env.config.max_steps
    per_seed: list[dict[str, float]] = []
    curves: list[list[float]] = []  # per seed, the task's coverage after every step
    for seed in seeds:
        if hasattr(policy, "reset"):
            policy.reset(seed)
        obs, infos = env.reset(seed=seed)
        total = 0.0
        curve = []
        for _ in range(n_steps):
            if not env.agents:
                break
            obs, rewards, _, _, infos = env.step(policy(obs, infos))
            total += float(np.mean(list(rewards.values()))) if rewards else 0.0
            if hasattr(env.task, "coverage"):
                curve.append(float(env.task.coverage))
        by_phase = phase_metrics(env.task.step_series(), phases) if phases else {}
        per_seed.append({**env.task.metrics(), **by_phase, "episode_return": total})
        if curve:  # an episode ended early at the target: coverage stays where it was
            curves.append(curve + [curve[-1]] * (n_steps - len(curve)))
    env.close()
    keys = per_seed[0].keys()
    out = {
        "policy": policy_spec,
        "seeds": seeds,
        "mean": {k: float(np.mean([d[k] for d in per_seed])) for k in keys},
        "std": {k: float(np.std([d[k] for d in per_seed])) for k in keys},
        "per_seed": per_seed,
    }
    out["control_period_s"] = env.config.control_period_s
    if curves:
        out["coverage_curve_mean"] = np.mean(curves, axis=0).tolist()
    return out


def pooled(results: list[dict[str, Any]], metric: str) -> dict[str, float]:
    """Several runs (training seeds) scored on the same held-out seeds: the mean and std over
    all (run, seed) episodes, and the std of the runs' means (the training-seed spread)."""
    values = np.array([[d[metric] for d in r["per_seed"]] for r in results])
    return {
        "mean": float(values.mean()),
        "std": float(values.std()),
        "std_of_run_means": float(values.mean(axis=1).std()),
        "n_runs": len(results),
    }


def paired_differences(
    policies: dict[str, Any],
    groups: dict[str, list[str]],
    baselines: list[str],
    metric: str,
) -> list[dict[str, Any]]:
    """Every learned group (its runs' per-seed mean) and every later baseline against every
    baseline, and every learned group against every earlier one (a fine-tuned group against
    the group it started from: what the fine-tuning added), paired by held-out seed: the mean
    difference ``a - b`` in ``metric``, its
    standard error (``std(ddof=1) / sqrt(n)`` over the seeds), and on how many seeds ``a`` is
    better (lower, or higher for :data:`HIGHER_IS_BETTER`).

    Paired by seed, the spread that the layouts share cancels: on 20 formation seeds the
    per-policy std is ~0.06 m, the SE of a paired difference ~0.004 m. ``verdict`` is
    ``"better"`` / ``"worse"`` beyond 2 SE, else ``"within 2 SE"``, or
    :data:`NO_SE_VERDICT` / :data:`NO_PAIR_VERDICT` with under 2 / no seeds scored by both
    (each pair's statistic: :func:`paired_difference`). The SE is over the held-out
    seeds only: it judges these trained models, not the recipe (the runs' spread, the pooled
    row's "run means ±", is not in it). Every policy must have been scored on the same seeds.
    """

    seed_lists = {s: policies[s].get("seeds") for specs in groups.values() for s in specs}
    seed_lists.update({b: policies[b].get("seeds") for b in baselines})
    if len({tuple(v) for v in seed_lists.values() if v is not None}) > 1:
        raise ValueError(f"paired_differences needs the same seeds for every policy: {seed_lists}")

    def per_seed(specs: list[str]) -> np.ndarray:
        return np.mean([[d[metric] for d in policies[s]["per_seed"]] for s in specs], axis=0)

    # (contender, its specs, the references it is paired with, each with its specs): each
    # learned group against every baseline and every earlier group, and each pair of
    # baselines once (the later one against the earlier).
    learned = [(name, specs) for name, specs in groups.items() if specs]
    singles = [(b, [b]) for b in baselines]
    pairs = [(name, specs, singles + learned[:j]) for j, (name, specs) in enumerate(learned)]
    pairs += [(b, [b], singles[:j]) for j, b in enumerate(baselines)]
    return [
        {
            "policy": name,
            "baseline": base,
            **paired_difference(per_seed(specs), per_seed(base_specs), metric),
        }
        for name, specs, references in pairs
        for base, base_specs in references
    ]


#: :func:`paired_difference`'s verdict when there is no standard error (fewer than 2 seeds).
NO_SE_VERDICT = "SE needs at least 2 seeds"
#: ... and when no seed has a value on both sides.
NO_PAIR_VERDICT = "no seed scored by both"


def paired_difference(values: Any, reference: Any, metric: str) -> dict[str, Any]:
    """One policy's per-seed ``values`` of ``metric`` against a ``reference``'s on the same
    seeds, in the same order (a seed where either is not finite is left out, and not counted
    in ``n_seeds``): the mean of the differences ``values - reference``, its standard
    error (``std(ddof=1) / sqrt(n)``; NaN for one seed), on how many seeds the policy is better
    (lower, or higher for :data:`HIGHER_IS_BETTER`; a tie is not), and ``verdict``:
    ``"better"`` / ``"worse"`` beyond 2 SE, else ``"within 2 SE"`` (:data:`NO_SE_VERDICT`
    with one seed, :data:`NO_PAIR_VERDICT` with none). The one paired statistic of
    :func:`paired_differences`, ``agents.sb3.localization_table`` and ``swarm-phd evaluate
    --compare``."""
    a = np.asarray(values, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(
            f"paired_difference needs one value per seed on the same seeds, got {a.shape} "
            f"values and {b.shape} reference values of {metric}"
        )
    diff = a - b
    diff = diff[np.isfinite(diff)]  # a seed either side has no value of (nothing in range)
    n = len(diff)
    if n == 0:
        return {
            "mean_difference": float("nan"),
            "standard_error": float("nan"),
            "seeds_better": 0,
            "n_seeds": 0,
            "verdict": NO_PAIR_VERDICT,
        }
    sign = 1.0 if higher_is_better(metric) else -1.0  # positive sign * diff = better
    se = float(diff.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    mean = float(diff.mean())
    if n < 2:
        verdict = NO_SE_VERDICT
    elif sign * mean > 2.0 * se:
        verdict = "better"
    elif -sign * mean > 2.0 * se:
        verdict = "worse"
    else:
        verdict = "within 2 SE"
    return {
        "mean_difference": mean,
        "standard_error": se,
        "seeds_better": int((sign * diff > 0).sum()),
        "n_seeds": n,
        "verdict": verdict,
    }


def paired_table(rows: list[dict[str, Any]], metric: str) -> str:
    """:func:`paired_differences` as markdown."""
    lines = [
        f"| policy − baseline, paired by seed | mean difference in {metric} | SE | "
        "seeds better | verdict |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['policy']} − {r['baseline']} | {r['mean_difference']:+.4f} | "
            f"{_se_cell(r['standard_error'], '.4f')} | {r['seeds_better']} of {r['n_seeds']} | "
            f"{r['verdict']} |"
        )
    return "\n".join(lines) + "\n"


def _se_cell(se: float, spec: str) -> str:
    """A standard error for a table: ``spec``-formatted, or "-" without one (one seed)."""
    return format(se, spec) if np.isfinite(se) else "-"


def markdown_table(results: dict[str, Any], metric: str, groups: dict[str, list[str]]) -> str:
    """Rows ``policy | metric mean +- std | return mean +- std`` plus one pooled row per group."""
    lines = [f"| policy | {metric} | episode return / agent |", "|---|---|---|"]
    for spec, r in results.items():
        m, s = r["mean"], r["std"]
        lines.append(
            f"| {spec} | {m[metric]:.3f} ± {s[metric]:.3f} | "
            f"{m['episode_return']:.1f} ± {s['episode_return']:.1f} |"
        )
    for name, specs in groups.items():
        if len(specs) < 2:
            continue
        p, ret = (
            pooled([results[s] for s in specs], metric),
            pooled([results[s] for s in specs], "episode_return"),
        )
        lines.append(
            f"| **{name}** ({p['n_runs']} training seeds, pooled) | "
            f"**{p['mean']:.3f} ± {p['std']:.3f}** (run means ± {p['std_of_run_means']:.3f}) | "
            f"{ret['mean']:.1f} ± {ret['std']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def monitor_curve(run_dir: Path, window: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """(agent timesteps, moving-average episode return) from ``monitor.csv``."""
    with open(run_dir / "monitor.csv") as f:
        lines = [line for line in f if not line.startswith("#")]
    rows = list(csv.DictReader(lines))
    returns = np.array([float(r["r"]) for r in rows])
    lengths = np.array([float(r["l"]) for r in rows])
    steps = np.cumsum(lengths)  # each row is one agent-episode of l transitions
    if len(returns) == 0:
        return np.zeros(0), np.zeros(0)
    w = min(window, len(returns))
    smooth = np.convolve(returns, np.ones(w) / w, mode="valid")
    return steps[w - 1 :], smooth


def run_models(run_dir: Path) -> list[tuple[int, Path]]:
    """A run's models as ``(PPO agent transitions, path)`` in training order: its warm start
    (``warm_start.zip``, at 0), its checkpoints and its final ``model.zip`` (a final model
    saved at a checkpoint's step replaces it)."""
    models = {
        int(re.findall(r"\d+", p.stem)[0]): p
        for p in (run_dir / "checkpoints").glob("model_*_steps.zip")
    }
    if (run_dir / "warm_start.zip").is_file():
        models[0] = run_dir / "warm_start.zip"
    summary = run_dir / "train_summary.json"
    if summary.is_file() and (run_dir / "model.zip").is_file():
        models[int(json.loads(summary.read_text())["timesteps"])] = run_dir / "model.zip"
    return sorted(models.items())


def checkpoint_scores(run_dir: Path, seeds: list[int]) -> list[tuple[int, dict[str, Any]]]:
    from agents.sb3.policy import read_metadata

    return [
        (steps, score(str(path), read_metadata(path)["env_kwargs"], seeds))
        for steps, path in run_models(run_dir)
        if path.parent.name == "checkpoints"
    ]


def select_model(run_dir: Path, seeds: list[int], metric: str) -> tuple[Path, list[dict]]:
    """The run's model (warm start, checkpoint or final) with the best mean ``metric`` on the
    validation ``seeds``, and every candidate's score (``{"steps", "model", "mean"}``); ties go
    to the earlier model."""
    from agents.sb3.policy import read_metadata

    sign = -1.0 if higher_is_better(metric) else 1.0
    scored = []
    for steps, path in run_models(run_dir):
        result = score(str(path), read_metadata(path)["env_kwargs"], seeds)
        if metric not in result["mean"]:
            raise ValueError(
                f"--metric {metric!r} is not a metric of {str(path)!r}'s task; it has "
                f"{sorted(result['mean'])}"
            )
        scored.append({"steps": steps, "model": str(path), "mean": result["mean"][metric]})
    if not scored:
        raise ValueError(f"run {str(run_dir)!r} has no model.zip and no checkpoints")
    best = min(scored, key=lambda c: sign * c["mean"])
    return Path(best["model"]), scored


def policy_kind(meta: dict[str, Any]) -> str:
    """A trained model's label in tables, from its ``swarm_phd.json`` ``meta``: ``"PPO"``, or
    ``"residual PPO (scripted:NAME + learned correction)"`` (``x learned gain`` for a
    ``--residual-mode gain`` model)."""
    residual = meta.get("residual")
    if not residual:
        return "PPO"
    how = "x learned gain" if meta.get("residual_mode") == "gain" else "+ learned correction"
    return f"residual PPO ({residual} {how})"


def phase_means_table(
    results: dict[str, Any], keys: list[str], groups: dict[str, list[str]]
) -> str:
    """Rows ``policy | mean +- std`` of each phase metric in ``keys``, plus one pooled row per
    group of several runs."""
    lines = ["| policy | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    for spec, r in results.items():
        cells = [f"{r['mean'][k]:.3f} ± {r['std'][k]:.3f}" for k in keys]
        lines.append(f"| {spec} | " + " | ".join(cells) + " |")
    for name, specs in groups.items():
        if len(specs) < 2:
            continue
        cells = []
        for k in keys:
            p = pooled([results[s] for s in specs], k)
            cells.append(f"**{p['mean']:.3f} ± {p['std']:.3f}**")
        lines.append(
            f"| **{name}** ({len(specs)} training seeds, pooled) | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", nargs="*", default=[], help="training run directories")
    parser.add_argument(
        "--env-from",
        default=None,
        help="without --runs: the model (.zip) or recurrent student (.pt) whose env the "
        "baselines are scored in",
    )
    parser.add_argument(
        "--baselines",
        nargs="*",
        default=["random", "scripted:formation", "scripted:formation@truth"],
    )
    parser.add_argument(
        "--group",
        nargs="+",
        action="extend",
        default=[],
        metavar="NAME=SPEC,SPEC",
        help="policies scored and pooled as one learned group, like the runs of one recipe "
        "(e.g. recurrent students of several fit seeds: 'students=a.pt,b.pt,c.pt'); each in "
        "its own env (a model's or a student's) with --baseline-overrides; each group is "
        "paired by seed with the baselines and with every earlier group",
    )
    parser.add_argument("--seeds", default="100-109")
    parser.add_argument("--out", default="docs/results")
    parser.add_argument(
        "--checkpoints", action="store_true", help="also score every checkpoint (slower)"
    )
    parser.add_argument("--checkpoint-seeds", default="100-104")
    parser.add_argument(
        "--select-on",
        default=None,
        metavar="SEEDS",
        help="validation seeds, disjoint from --seeds: each run is scored with its model (warm "
        "start, checkpoint or final) that did best on them; a chosen warm start is labelled so",
    )
    parser.add_argument(
        "--warm-start", action="store_true", help="also score each run's warm_start.zip"
    )
    parser.add_argument("--name", default="formation", help="output file prefix")
    parser.add_argument("--metric", default="formation_error_m", help="task metric of the table")
    parser.add_argument(
        "--phases",
        default=None,
        metavar="STEPS",
        help="comma-separated first steps of phases of the episode, e.g. 0,150: also score "
        "--metric over each phase (from the task's per-step series, e.g. "
        "formation_error_m@150-), with a paired table per phase",
    )
    parser.add_argument(
        "--baseline-overrides",
        default="{}",
        metavar="JSON",
        help="SwarmConfig overrides for the baselines' and the --group members' env, e.g. "
        '\'{"localizer": "id-phd"}\' (the --runs models always run in their own env)',
    )
    parser.add_argument(
        "--curves-only",
        action="store_true",
        help="only draw the runs' training curves (results_<name>_learning_curve.png), no scoring",
    )
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if args.curves_only:
        fig, ax = plt.subplots(figsize=(6.5, 4.2))
        for run in map(Path, args.runs):
            x, y = monitor_curve(run)
            ax.plot(x, y, label=run.name)
        ax.set_xlabel("agent transitions")
        ax.set_ylabel("episode return per agent (moving avg. of 200)")
        ax.set_title(f"{args.name}: training episodes")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        figure = Path(args.out) / f"results_{args.name}_learning_curve.png"
        atomic_write(figure, lambda tmp: fig.savefig(tmp, dpi=110))
        print(f"wrote {figure}")
        return 0

    from agents.sb3.policy import read_metadata

    seeds = parse_seeds(args.seeds)
    phases = None
    if args.phases is not None:
        try:
            phases = [int(p) for p in args.phases.split(",")]
            phase_spans(phases)
        except ValueError:
            parser.error(f"--phases must be increasing integers >= 0, got {args.phases!r}")
    validation = None if args.select_on is None else parse_seeds(args.select_on, "--select-on")
    if validation is not None and set(validation) & set(seeds):
        raise ValueError(
            f"--select-on {args.select_on} shares seeds with --seeds {args.seeds}: selecting "
            "a checkpoint on the seeds it is scored on would flatter it"
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [Path(r) for r in args.runs]
    extra_groups: dict[str, list[str]] = {}
    for item in args.group:
        name, _, specs = item.partition("=")
        members = [x for x in specs.split(",") if x]
        if not name or not members or name in extra_groups:
            parser.error(f"--group must be NAME=SPEC[,SPEC...] with distinct names, got {item!r}")
        missing = [m for m in members if m.endswith((".zip", ".pt")) and not Path(m).is_file()]
        if missing:  # before any scoring, which takes minutes
            parser.error(f"--group {name}: no such file {missing}")
        extra_groups[name] = members
    if runs and args.env_from is not None:
        parser.error("--env-from is for reports without --runs (the first run gives the env)")
    overrides = parse_json_object(args.baseline_overrides, "--baseline-overrides")
    if runs:
        env_kwargs = read_metadata(runs[0] / "model.zip")["env_kwargs"]
    elif args.env_from is None:
        parser.error("give --runs, or --env-from MODEL: the env the baselines are scored in")
    elif args.env_from.endswith(".pt"):
        from agents.sb3.recurrent_student import read_student_metadata

        env_kwargs = read_student_metadata(args.env_from)["env_kwargs"]
    else:
        env_kwargs = read_metadata(args.env_from)["env_kwargs"]
    env_kwargs = {k: v for k, v in env_kwargs.items() if k not in ("observation", "localize")}
    env_kwargs.update(overrides)
    results: dict[str, Any] = {"seeds": seeds, "env_kwargs": env_kwargs, "policies": {}}
    # Runs named <group>_s<seed> (one per training seed) are pooled per group.
    groups: dict[str, list[str]] = {}
    for spec in args.baselines:
        results["policies"][spec] = score(spec, env_kwargs, seeds, phases=phases)
        print(spec, results["policies"][spec]["mean"])
    curves = {}
    for run in runs:
        spec = str(run / "model.zip")
        if validation is not None:
            chosen, candidates = select_model(run, validation, args.metric)
            results.setdefault("selection", {})[run.name] = {
                "seeds": validation,
                "chosen": str(chosen),
                "candidates": candidates,
            }
            print(f"{run.name}: selected {chosen} on seeds {args.select_on}")
            spec = str(chosen)
        results["policies"][spec] = score(
            spec, read_metadata(spec)["env_kwargs"], seeds, phases=phases
        )
        print(spec, results["policies"][spec]["mean"])
        group = re.sub(r"_s\d+$", "", run.name)
        meta = read_metadata(spec)
        kind = policy_kind(meta)
        clone = run / "warm_start.zip"
        if Path(spec) == clone:  # selection chose the warm start itself: label it so
            kind = "warm start only"
        groups.setdefault(f"{kind} {group}", []).append(spec)
        if args.warm_start and clone.is_file() and Path(spec) != clone:
            results["policies"][str(clone)] = score(
                str(clone), read_metadata(clone)["env_kwargs"], seeds, phases=phases
            )
            groups.setdefault(f"warm start only {group}", []).append(str(clone))
            print(clone, results["policies"][str(clone)]["mean"])
        label = "residual PPO " if meta.get("residual") else "PPO "
        curves[label + run.name] = monitor_curve(run)
        if args.checkpoints:
            results.setdefault("checkpoints", {})[run.name] = [
                (s, r["mean"])
                for s, r in checkpoint_scores(run, parse_seeds(args.checkpoint_seeds))
            ]
            final_spec = str(run / "model.zip")
            final = score(
                final_spec,
                read_metadata(final_spec)["env_kwargs"],
                parse_seeds(args.checkpoint_seeds),
            )
            results["checkpoints"][run.name].append(
                (
                    int(json.loads((run / "train_summary.json").read_text())["timesteps"]),
                    final["mean"],
                )
            )
    from agents.policies import model_env_kwargs

    for name, specs in extra_groups.items():
        for spec in specs:
            if spec not in results["policies"]:
                own = model_env_kwargs(spec)  # a model's or a student's own env, else None
                kwargs = env_kwargs if own is None else {**own, **overrides}
                results["policies"][spec] = score(spec, kwargs, seeds, phases=phases)
                print(spec, results["policies"][spec]["mean"])
        groups[name] = specs
    results["pooled"] = {
        name: pooled([results["policies"][s] for s in specs], args.metric)
        for name, specs in groups.items()
        if specs
    }
    results["groups"] = groups
    results["paired"] = paired_differences(
        results["policies"], groups, list(args.baselines), args.metric
    )
    table = markdown_table(results["policies"], args.metric, groups)
    if results["paired"]:
        table += "\n" + paired_table(results["paired"], args.metric)
    if phases:
        keys = [phase_key(args.metric, lo, hi) for lo, hi in phase_spans(phases)]
        missing = [
            k
            for k in keys
            if k not in results["policies"][next(iter(results["policies"]))]["mean"]
        ]
        if missing:
            raise ValueError(
                f"--phases: the task has no per-step series for --metric {args.metric!r} "
                f"(Task.step_series); missing {missing}"
            )
        results["paired_by_phase"] = {
            k: paired_differences(results["policies"], groups, list(args.baselines), k)
            for k in keys
        }
        table += "\n" + phase_means_table(results["policies"], keys, groups)
        for k, rows in results["paired_by_phase"].items():
            if rows:
                table += "\n" + paired_table(rows, k)
    (out / f"results_{args.name}.json").write_text(json.dumps(results, indent=2))
    (out / f"results_{args.name}.md").write_text(table)
    print(table)

    coverage = {
        spec: r["coverage_curve_mean"]
        for spec, r in results["policies"].items()
        if "coverage_curve_mean" in r
    }
    n_panels = 1 + bool(args.checkpoints) + bool(coverage)
    fig, axes = plt.subplots(1, n_panels, figsize=(6.5 * n_panels, 4.2), squeeze=False)
    ax = axes[0, 0]
    colors = {
        "random": "tab:gray",
        "scripted:formation": "tab:green",
        "scripted:formation@truth": "tab:olive",
    }
    for name, (x, y) in curves.items():
        ax.plot(x, y, label=f"{name} (training episodes)")
    for spec in args.baselines:
        ax.axhline(
            results["policies"][spec]["mean"]["episode_return"],
            ls="--",
            color=colors.get(spec),
            label=spec,
        )
    ax.set_xlabel("agent transitions")
    ax.set_ylabel("episode return per agent (moving avg.)")
    ax.set_title(f"{args.name}, PPO with parameter sharing")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    if args.checkpoints:
        ax = axes[0, 1]
        for name, pts in results["checkpoints"].items():
            ax.plot(
                [s for s, _ in pts],
                [m[args.metric] for _, m in pts],
                "o-",
                label=name,
            )
        for spec in args.baselines:
            base = score(spec, env_kwargs, parse_seeds(args.checkpoint_seeds))
            ax.axhline(base["mean"][args.metric], ls="--", color=colors.get(spec), label=spec)
        ax.set_xlabel("agent transitions")
        ax.set_ylabel(f"{args.metric}, held-out seeds")
        ax.set_title("checkpoints on held-out seeds")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    if coverage:
        ax = axes[0, n_panels - 1]
        for spec, curve in coverage.items():
            dt = results["policies"][spec]["control_period_s"]
            label = spec if not spec.endswith(".zip") else f"PPO {Path(spec).parent.name}"
            ax.plot(dt * np.arange(1, len(curve) + 1), 100 * np.asarray(curve), label=label)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("coverage (%), mean over held-out seeds")
        ax.set_title("coverage over time")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    figure = out / f"results_{args.name}_learning_curve.png"
    atomic_write(figure, lambda tmp: fig.savefig(tmp, dpi=110))
    print(f"wrote {figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
