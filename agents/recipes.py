"""The best known training recipe of each task, as one call (``swarm-phd train --recipe NAME``).

    from agents.recipes import run_recipe

    run_recipe("formation", "runs/formation_recipe")

A recipe runs its stages end to end with the settings that worked best for its task, then scores
the final policy on held-out seeds against the task's best scripted controller and ``random``
(:mod:`agents.train_report`: ``final_evaluation.json``, the verdict table,
``learning_curve.png``). Its run directory holds each stage's own directory and files (the
final policy is the last stage's: ``ppo/student.pt`` or ``ppo/model.zip``, loadable wherever
a policy is accepted) and ``recipe.json`` (the recipe, its stages' settings, the training and
held-out seeds, the commit, the held-out scores, the wall time).

The recipes (the budgets are for this project's 2-core machine, one thread):

- ``formation``: a recurrent residual student on ``scripted:formation-known-n-fast``,
  distilled by DAgger from the same controller reading the truth
  (:func:`agents.sb3.recurrent_student.distill`, 3 rounds over 400 episodes), then
  fine-tuned by PPO on the task's reward (:func:`agents.sb3.recurrent_ppo.finetune`, 40
  iterations of 16 episodes); about an hour.
- ``exploration`` and ``encirclement``: a residual policy on the task's scripted controller
  (the correction starts at zero, so the policy starts as the controller) trained by PPO on the
  task's reward (:func:`agents.sb3.train.train`, 150,000 agent steps, 8 batched copies); 10-20
  minutes each.

``scale`` (``--recipe-scale``) multiplies every stage's budget (episodes, iterations, agent
steps; at least one of each): a quick smoke run, not a recipe result.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm_core import inputs
from swarm_core.atomic_files import write_json_atomically
from swarm_core.inputs import format_seeds
from swarm_core.provenance import source_commit

__all__ = ["RECIPES", "Recipe", "run_recipe", "recipe_names", "check_recipe"]

#: Every recipe's env: the lab preset, four robots, the task's own reward; the robots read
#: their own estimate (``observation="phd"``) with the lidar summarised in 16 sectors.
_LAB = {"preset": "lab-3m-4", "observation": "phd", "lidar_sectors": 16, "max_steps": 300}
#: The held-out seeds of a recipe's final evaluation start here (no stage trains or
#: validates on them; :data:`agents.train_report.HELD_OUT_SEED`).
DEFAULT_RECIPE_EVAL_SEEDS = 20


@dataclass(frozen=True)
class Recipe:
    """One task's recipe: its env, the baselines its final policy is scored against, and the
    function that runs its stages into a directory and returns the final policy's path
    (``run(out, seed, scale, max_wall_s, progress_bar) -> (policy path, learning-curve rows,
    stages)``)."""

    name: str
    task: str
    summary: str
    env_kwargs: dict[str, Any]
    baselines: tuple[str, ...]
    run: Callable[..., tuple[Path, list[dict[str, float]], list[dict[str, Any]]]]


def _scaled(n: int, scale: float) -> int:
    return max(1, int(round(n * scale)))


def _formation(
    out: Path, seed: int, scale: float, max_wall_s: float | None, progress_bar: bool = True
):
    """DAgger rounds into a recurrent student, then PPO on the task's reward."""
    from agents.sb3.recurrent_ppo import FinetuneConfig, prepare_finetune, run_finetune
    from agents.sb3.recurrent_student import DistillConfig, distill

    env_kwargs = {**_LAB, "task": "formation"}
    blocks = [(0, 200), (1000, 1100), (1100, 1200)]
    rounds = tuple(tuple(range(a, a + _scaled(b - a, scale))) for a, b in blocks)
    val = tuple(range(200, 200 + _scaled(10, scale)))
    started = time.monotonic()
    distill_config = DistillConfig(
        env_kwargs,
        base="scripted:formation-known-n-fast",
        teacher="privileged:formation-known-n-fast@truth",
        round_seeds=rounds,
        val_seeds=val,
        epochs=_scaled(30, scale),
        dagger_epochs=_scaled(10, scale),
        fit_seed=seed,
        max_wall_s=max_wall_s,
    )
    code = distill(distill_config, out / "dagger")
    if code:
        raise _Stopped(code)
    left = None if max_wall_s is None else max(1.0, max_wall_s - (time.monotonic() - started))
    iterations = _scaled(40, scale)
    n_copies = _scaled(16, scale)
    finetune_config = FinetuneConfig(
        student=str(out / "dagger" / "student_best.pt"),
        task_params={"progress_weight": 10},
        iterations=iterations,
        n_copies=n_copies,
        val_seeds=val,
        eval_every=max(1, iterations // 4),
        critic_warmup=min(3, iterations - 1),
        log_std=-1.5,
        fit_seed=seed,
        max_wall_s=left,
    )
    code = run_finetune(prepare_finetune(finetune_config, out / "ppo", overwrite=True))
    if code:
        raise _Stopped(code)
    log = json.loads((out / "ppo" / "train_log.json").read_text())
    n_agents = 4
    steps_per_iteration = n_copies * env_kwargs["max_steps"] * n_agents
    rows = [
        {
            "agent_steps": (i + 1) * steps_per_iteration,
            "episode_return_mean": float(it.get("return_per_agent", math.nan)),
            "episodes": n_copies * n_agents,
            "task_metric": "formation_error_m",
            "task_metric_mean": float(it.get("formation_error_m", math.nan)),
            "task_metric_episodes": n_copies,
        }
        for i, it in enumerate(log["iterations"])
    ]
    stages = [
        {
            "stage": "DAgger distillation (agents.sb3.recurrent_student.distill)",
            "dir": "dagger",
            "base": distill_config.base,
            "teacher": distill_config.teacher,
            "round_seeds": [format_seeds(r) for r in rounds],
            "val_seeds": format_seeds(val),
            "epochs": distill_config.epochs,
            "dagger_epochs": distill_config.dagger_epochs,
        },
        {
            "stage": "PPO fine-tuning (agents.sb3.recurrent_ppo.finetune)",
            "dir": "ppo",
            "start": "dagger/student_best.pt",
            "reward_task_params": finetune_config.task_params,
            "iterations": iterations,
            "n_copies": n_copies,
            "train_seeds": format_seeds(
                range(
                    finetune_config.train_seeds_start,
                    finetune_config.train_seeds_start + iterations * n_copies,
                )
            ),
            "log_std": finetune_config.log_std,
        },
    ]
    return out / "ppo" / "student.pt", rows, stages


def _residual_ppo(task: str):
    """PPO of a residual policy on ``scripted:<task>`` (the correction starts at zero)."""

    def run(
        out: Path, seed: int, scale: float, max_wall_s: float | None, progress_bar: bool = True
    ):
        from agents.sb3.train import _train

        env_kwargs = {**_LAB, "task": task}
        timesteps = _scaled(150_000, scale)
        n_copies = 8
        options = {
            "seed": seed,
            "overwrite": True,
            "n_copies": n_copies,
            "vec": "batched",
            "checkpoint_every": max(1, timesteps // 5),
            "residual": f"scripted:{task}",
            "residual_log_std": -2.5,
            "critic_warmup": 5 if scale >= 1 else 0,
            "ppo_kwargs": {
                "learning_rate": 1e-4,
                "clip_range": 0.1,
                "target_kl": 0.02,
                "n_epochs": 5,
                "n_steps": 128 if scale >= 1 else 16,
            },
            "max_wall_s": max_wall_s,
            "eval_seeds": 0,
            "progress_bar": progress_bar,
        }
        model, interrupted = _train(env_kwargs, timesteps, out / "ppo", **options)
        if interrupted:
            from agents.interrupts import EXIT_CODES

            raise _Stopped(EXIT_CODES[interrupted])
        rows = _curve_rows(out / "ppo" / "learning_curve.csv")
        stages = [
            {
                "stage": "residual PPO (agents.sb3.train.train)",
                "dir": "ppo",
                "residual": options["residual"],
                "timesteps": timesteps,
                "seed": seed,
                **{k: v for k, v in options.items() if k in ("n_copies", "residual_log_std")},
                "ppo_kwargs": options["ppo_kwargs"],
            }
        ]
        return model, rows, stages

    return run


def _curve_rows(path: Path) -> list[dict[str, Any]]:
    import csv

    if not path.is_file():
        return []
    rows = []
    with path.open() as f:
        for row in csv.DictReader(f):
            parsed: dict[str, Any] = {}
            for key, value in row.items():
                if key == "task_metric":
                    parsed[key] = value
                elif value not in ("", None):
                    parsed[key] = float(value)
            rows.append(parsed)
    return rows


class _Stopped(Exception):
    """A stage ended by a signal (the exit code it returned)."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


RECIPES: dict[str, Recipe] = {
    "formation": Recipe(
        "formation",
        "formation",
        "recurrent residual student on scripted:formation-known-n-fast: DAgger from the "
        "controller on the truth, then PPO (about an hour)",
        {**_LAB, "task": "formation"},
        ("scripted:formation-known-n-fast", "scripted:formation", "random"),
        _formation,
    ),
    "exploration": Recipe(
        "exploration",
        "exploration",
        "residual PPO on scripted:exploration, 150k agent steps (10-20 minutes)",
        {**_LAB, "task": "exploration"},
        ("scripted:exploration", "random"),
        _residual_ppo("exploration"),
    ),
    "encirclement": Recipe(
        "encirclement",
        "encirclement",
        "residual PPO on scripted:encirclement, 150k agent steps (10-20 minutes)",
        {**_LAB, "task": "encirclement"},
        ("scripted:encirclement", "random"),
        _residual_ppo("encirclement"),
    ),
}


def recipe_names() -> list[str]:
    return list(RECIPES)


def check_recipe(name: Any, flag: str = "--recipe") -> Recipe:
    """The recipe called ``name``, or ``ValueError`` naming ``flag`` and listing the known."""
    if not isinstance(name, str) or name not in RECIPES:
        raise ValueError(f"{flag}: unknown recipe {name!r}; known: {', '.join(RECIPES)}")
    return RECIPES[name]


def run_recipe(
    name: str,
    out: str | Path,
    *,
    seed: int = 0,
    eval_seeds: int = DEFAULT_RECIPE_EVAL_SEEDS,
    scale: float = 1.0,
    overwrite: bool = False,
    max_wall_s: float | None = None,
    progress_bar: bool = True,
) -> int:
    """Run recipe ``name`` into ``out`` (module doc); returns the exit code (0, or 130 / 143
    after SIGINT / SIGTERM, the stage's files kept). Every argument is checked before
    anything is written (``ValueError`` naming the flag)."""
    from agents import train_report
    from swarm_core.validation import check_number

    recipe = check_recipe(name)
    check_number("--seed", seed, integer=True, low=0, high=2**32 - 1)
    check_number("--recipe-scale", scale, low=0, above=True, high=1)
    check_number("--max-wall-minutes", max_wall_s, low=0, above=True, optional=True)
    seeds = train_report.eval_seeds(eval_seeds)
    out = Path(out)
    inputs.run_dir("--out", out, overwrite=overwrite)
    if overwrite and out.is_dir():
        for stage in ("dagger", "ppo"):
            shutil.rmtree(out / stage, ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    print(f"recipe {name}: {recipe.summary}" + (f" (budgets x {scale:g})" if scale < 1 else ""))
    try:
        policy, rows, stages = recipe.run(out, seed, scale, max_wall_s, progress_bar)
    except _Stopped as stop:
        print(f"recipe {name}: stopped; the stage's files are in {out}")
        return stop.code
    final = policy
    report = None
    if seeds:
        report = train_report.final_evaluation(
            str(final), recipe.env_kwargs, seeds, baselines=list(recipe.baselines)
        )
        write_json_atomically(out / "final_evaluation.json", report)
        train_report.print_verdict(report)
    train_report.write_learning_curve(
        out / "learning_curve.png", rows, report, f"recipe {name} ({recipe.task}, lab-3m-4)"
    )
    summary = {
        "recipe": name,
        "task": recipe.task,
        "summary": recipe.summary,
        "env_kwargs": recipe.env_kwargs,
        "scale": scale,
        "seed": seed,
        "stages": stages,
        "policy": str(final.relative_to(out)),
        "commit": source_commit(),
        "held_out_seeds": format_seeds(seeds) if seeds else None,
        "held_out": (
            {spec: s["mean"] for spec, s in report["scores"].items()} if report else None
        ),
        "paired": report["paired"] if report else None,
        "wall_s": round(time.monotonic() - started, 1),
    }
    write_json_atomically(out / "recipe.json", summary, indent=1)
    print(f"recipe {name}: the policy is {final}; learning curve {out / 'learning_curve.png'}")
    return 0
