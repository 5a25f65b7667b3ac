"""What ``swarm-phd train`` says and writes about learning, for both engines.

- :func:`rollout_plan`: the budget trained: ``--timesteps`` rounded up to whole rollouts (PPO
  trains on whole rollouts), and the line that says so when it is rounded;
- :class:`LearningLog`: one line per rollout (or per ~10 % of the budget when there are many)
  with the mean episode return so far, and the rows of ``learning_curve.csv``;
- :func:`final_evaluation`: the trained policy, its saved checkpoints, the task's scripted
  controller and ``random`` on held-out seeds (:func:`agents.evaluation.score`), each against
  the trained policy paired by seed (:func:`agents.evaluation.paired_difference`, the statistic
  of ``swarm-phd evaluate --compare``); :func:`print_verdict` prints the table and
  :func:`write_learning_curve` draws ``learning_curve.png``.

The held-out seeds are :data:`HELD_OUT_SEED` onwards: the training envs draw their layouts from
``--seed`` and its generators, never from these.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path
from typing import Any

#: Default ``--eval-seeds``: episodes per policy in the final evaluation.
DEFAULT_EVAL_SEEDS = 5
#: The first held-out evaluation seed.
HELD_OUT_SEED = 100_000
#: At most this many learning lines per run (one per rollout when there are fewer rollouts).
MAX_LINES = 10


def add_eval_arguments(parser: argparse.ArgumentParser) -> None:
    """``--eval-seeds``: the final evaluation's budget (both engines)."""
    parser.add_argument(
        "--eval-seeds",
        type=int,
        default=DEFAULT_EVAL_SEEDS,
        help="after training, score the policy, its checkpoints, the task's scripted "
        f"controller and random on this many held-out seeds ({HELD_OUT_SEED} on), print the "
        "verdict table and draw learning_curve.png (0: skip)",
    )


def eval_seeds(n: Any) -> list[int]:
    """The held-out seeds of ``--eval-seeds n`` (ValueError naming the flag unless n >= 0)."""
    from swarm_core.validation import check_number

    check_number("--eval-seeds", n, integer=True, low=0)
    return list(range(HELD_OUT_SEED, HELD_OUT_SEED + int(n)))


def rollout_plan(timesteps: int, rollout: int, detail: str) -> tuple[int, str | None]:
    """The agent steps a run of ``timesteps`` trains (whole rollouts of ``rollout`` agent
    steps), and the line saying so when that is more than asked (``detail``: what makes a
    rollout, e.g. ``"n_steps 128 x 4 copies x 4 agents"``)."""
    n = max(1, math.ceil(timesteps / rollout))
    total = n * rollout
    if total == timesteps:
        return total, None
    return total, (
        f"--timesteps {timesteps} rounds up to {total} = {n} rollout{'s' * (n > 1)} of "
        f"{rollout} agent steps ({detail})"
    )


def say(line: str, bar: Any = None) -> None:
    """A status line on stdout, above a tqdm bar if there is one; nothing when quiet."""
    from swarm_core import progress

    if progress.is_quiet():
        return
    write = getattr(bar, "write", None)
    if callable(write):
        write(line, file=sys.stdout)
    else:
        print(line, flush=True)


class LearningLog:
    """The learning curve as it is trained: :meth:`add` one point per rollout (agent steps,
    mean episode return per agent over the last finished episodes, NaN before the first);
    a line is printed for the first rollout, every ~``1/MAX_LINES`` of ``total`` and the last."""

    def __init__(self, total: int, engine: str) -> None:
        self.total = max(1, int(total))
        self.engine = engine
        self.rows: list[dict[str, float]] = []
        self._next_line = 0.0

    def add(
        self,
        agent_steps: int,
        episode_return: float,
        episodes: int,
        bar: Any = None,
        task_metric: tuple[str, float, int] | None = None,
    ):
        """One rollout's point; ``task_metric``: ``(name, mean, episodes)`` of the task's
        first metric over the last finished training episodes, when the VecEnv reports it."""
        row: dict[str, Any] = {
            "agent_steps": int(agent_steps),
            "episode_return_mean": float(episode_return),
            "episodes": int(episodes),
        }
        if task_metric is not None:
            row["task_metric"], row["task_metric_mean"], row["task_metric_episodes"] = task_metric
        self.rows.append(row)
        if agent_steps >= self._next_line or agent_steps >= self.total:
            self._next_line = agent_steps + self.total / MAX_LINES
            ret = (
                f"mean episode return per agent {episode_return:.2f} (last {episodes} episodes)"
                if math.isfinite(episode_return)
                else "no episode finished yet (an episode is --max-steps env steps)"
            )
            if task_metric is not None and task_metric[2]:
                name, value, n = task_metric
                ret += f"; {name} {value:.3f} (last {n} copy-episodes)"
            pct = 100.0 * agent_steps / self.total
            say(f"train: {agent_steps}/{self.total} agent steps ({pct:.0f} %): {ret}", bar)

    def write_csv(self, path: Path) -> None:
        if not self.rows:
            return
        with path.open("w", newline="") as f:
            fields = list(dict.fromkeys(k for row in self.rows for k in row))
            writer = csv.DictWriter(f, fieldnames=fields)
            writer.writeheader()
            writer.writerows(self.rows)


def baselines_for(task: str) -> list[str]:
    """The task's scripted controller (if it has one) and ``random``."""
    from agents.policies import SCRIPTED

    return ([f"scripted:{task}"] if task in SCRIPTED else []) + ["random"]


def final_evaluation(
    policy: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    checkpoints: list[tuple[int, str]] = (),
    baselines: list[str] | None = None,
) -> dict[str, Any]:
    """Score ``policy`` (the final model), each of ``checkpoints`` (``(agent steps, spec)``)
    and ``baselines`` (default: the task's, :func:`baselines_for`) on ``seeds``; pair the
    policy against each baseline by seed on the headline task metric and the episode return.
    Returns the report written to ``final_evaluation.json``."""
    from agents.evaluation import paired_difference, score
    from swarm_core import progress

    task = env_kwargs.get("task", "wander")
    specs = [policy, *(baselines_for(task) if baselines is None else baselines)]
    scores: dict[str, Any] = {}
    for spec in progress.over(specs, "final evaluation", unit="policy"):
        scores[spec] = score(spec, env_kwargs, seeds)
    metrics = [k for k in scores[policy]["mean"] if k != "episode_return"]
    metric = metrics[0] if metrics else None
    checkpoint_scores = []
    for steps, spec in progress.over(checkpoints, "checkpoints", unit="checkpoint"):
        s = score(spec, env_kwargs, seeds)
        checkpoint_scores.append({"agent_steps": int(steps), "mean": s["mean"]})
    rows = []
    for key in [k for k in (metric, "episode_return") if k is not None]:
        for base in specs[1:]:
            values = [d[key] for d in scores[policy]["per_seed"]]
            reference = [d[key] for d in scores[base]["per_seed"]]
            rows.append(
                {
                    "metric": key,
                    "policy": policy,
                    "baseline": base,
                    "policy_mean": float(sum(values) / len(values)),
                    "baseline_mean": float(sum(reference) / len(reference)),
                    **paired_difference(values, reference, key),
                }
            )
            if rows[-1]["verdict"] in ("better", "worse"):
                rows[-1]["verdict"] += " by > 2 SE"  # as swarm-phd evaluate --compare says it
    return {
        "seeds": list(seeds),
        "metric": metric,
        "scores": {
            spec: {"mean": s["mean"], "per_seed": s["per_seed"]} for spec, s in scores.items()
        },
        "checkpoints": checkpoint_scores,
        "paired": rows,
    }


def print_verdict(report: dict[str, Any], label: str = "trained") -> None:
    """The trained policy against each baseline, paired by held-out seed (markdown)."""
    seeds = report["seeds"]
    print(
        f"trained policy vs baselines on {len(seeds)} held-out seeds ({seeds[0]}-{seeds[-1]}), "
        "paired by seed: the mean difference trained − baseline, its standard error, the seeds "
        "on which the trained policy is better, the verdict at 2 SE"
    )
    print(
        "| metric | trained | baseline | baseline's | difference | SE | seeds better | verdict |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in report["paired"]:
        se = r["standard_error"]
        se_cell = f"{se:.3f}" if se is not None and math.isfinite(se) else "-"
        better = "higher" if _higher(r["metric"]) else "lower"
        print(
            f"| {r['metric']} ({better} is better) | {r['policy_mean']:.3f} | {r['baseline']} | "
            f"{r['baseline_mean']:.3f} | {r['mean_difference']:+.3f} | {se_cell} | "
            f"{r['seeds_better']} of {r['n_seeds']} | {r['verdict']} |"
        )


def _higher(metric: str) -> bool:
    from agents.evaluation import higher_is_better

    return higher_is_better(metric)


def write_learning_curve(
    path: Path, rows: list[dict[str, float]], report: dict[str, Any] | None, title: str
) -> dict[str, list[str]]:
    """``learning_curve.png``: the mean episode return per agent against agent steps (from
    training), and the task metric of each checkpoint and the final policy on the held-out
    seeds, each with the baselines' held-out values as horizontal lines. Returns each panel's
    y quantity with the labels of its lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    metric = report.get("metric") if report else None
    n_panels = 2 if metric else 1
    fig, axes = plt.subplots(1, n_panels, figsize=(5.5 * n_panels, 3.8), squeeze=False)
    axes = axes[0]
    steps = [r["agent_steps"] for r in rows]
    returns = [r["episode_return_mean"] for r in rows]
    axes[0].plot(
        steps, returns, marker="o", ms=3, color="tab:blue", label="trained (training episodes)"
    )
    panels = [(axes[0], "episode_return", "mean episode return per agent")]
    if report:  # the final policy's deterministic return on the held-out seeds
        final = report["scores"][next(iter(report["scores"]))]["mean"]["episode_return"]
        axes[0].plot(
            [steps[-1] if steps else 0],
            [final],
            marker="*",
            ms=11,
            ls="none",
            color="tab:red",
            label="trained (final, held-out seeds)",
        )
    if metric:
        points = [
            (c["agent_steps"], c["mean"].get(metric, math.nan)) for c in report["checkpoints"]
        ]
        final_steps = steps[-1] if steps else 0
        points.append(
            (final_steps, report["scores"][next(iter(report["scores"]))]["mean"][metric])
        )
        points.sort()
        axes[1].plot(
            [p[0] for p in points],
            [p[1] for p in points],
            marker="o",
            color="tab:blue",
            label="trained (checkpoints, held-out seeds)",
        )
        panels.append((axes[1], metric, metric.replace("_", " ")))
        training = [
            (r["agent_steps"], r["task_metric_mean"])
            for r in rows
            if r.get("task_metric") == metric and r.get("task_metric_episodes")
        ]
        if training:
            axes[1].plot(
                [p[0] for p in training],
                [p[1] for p in training],
                color="tab:blue",
                alpha=0.4,
                lw=1,
                label="trained (training episodes)",
            )
    colours = {"random": "tab:gray"}
    if report:
        baselines = list(report["scores"])[1:]
        for ax, key, _ in panels:
            for base in baselines:
                value = report["scores"][base]["mean"].get(key)
                if value is None or not math.isfinite(value):
                    continue
                ax.axhline(
                    value,
                    linestyle="--",
                    color=colours.get(base, "tab:green"),
                    label=f"{base} (held-out seeds)",
                )
    thousands = matplotlib.ticker.FuncFormatter(lambda x, _: f"{x / 1000:g}k")
    for ax, _, ylabel in panels:
        if steps and steps[-1] >= 10_000:
            ax.xaxis.set_major_formatter(thousands)
        ax.set_xlabel("agent steps")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    drawn = {key: [line.get_label() for line in ax.get_lines()] for ax, key, _ in panels}
    plt.close(fig)
    return drawn


def finish(
    out: Path,
    log: LearningLog,
    policy: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    checkpoints: list[tuple[int, str]],
    title: str,
) -> dict[str, Any] | None:
    """After training: ``learning_curve.csv``, the final evaluation (unless no seeds) with its
    ``final_evaluation.json`` and verdict table, and ``learning_curve.png``."""
    from swarm_core.atomic_files import write_json_atomically

    log.write_csv(out / "learning_curve.csv")
    report = None
    if seeds:
        report = final_evaluation(policy, env_kwargs, seeds, checkpoints)
        write_json_atomically(out / "final_evaluation.json", report)
        print_verdict(report)
    write_learning_curve(out / "learning_curve.png", log.rows, report, title)
    say(f"learning curve: {out / 'learning_curve.png'}")
    return report
