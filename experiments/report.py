"""Score policies on a task and draw learning curves: the learning results.

Question: does a learned policy do its task better than the scripted and random baselines,
on held-out seeds, paired by seed? (The statistics: :mod:`agents.evaluation`.) The results
page's learning rows (``experiments/results/formation_phd.json``, ``exploration.json``, ...)
are its tables::

    python -m experiments.report --runs runs/formation_phd runs/formation_truth \\
        --baselines random scripted:formation --seeds 100-109 --out runs/report

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

from agents.evaluation import (
    higher_is_better,
    markdown_table,
    paired_differences,
    paired_table,
    parse_phases,
    phase_key,
    phase_spans,
    pooled,
    score,
)
from swarm_core.atomic_files import atomic_write
from swarm_core.inputs import parse_json_object, parse_seeds


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
    parser.add_argument("--out", default="runs/report")
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
            phases = parse_phases(args.phases)
        except ValueError as err:
            parser.error(str(err))
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
