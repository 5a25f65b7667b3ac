"""``swarm-phd train`` with ``--engine sb3|rllib`` or ``--recipe NAME``: the SB3 engine's
options, the RLlib engine's own (:func:`agents.rllib.train.add_engine_arguments`), the
recipes' (:mod:`agents.recipes`), and the dispatch.

Registered in the CLI in place of ``agents.sb3.train``; ``--engine sb3`` (the default) runs
:func:`agents.sb3.train.run` unchanged, ``--engine rllib`` runs :func:`agents.rllib.train.run`,
``--recipe NAME`` runs :func:`agents.recipes.run_recipe` (its own env, stages and budgets).
"""

from __future__ import annotations

import argparse

ENGINES = ("sb3", "rllib")
#: The flags a recipe takes; every other training flag set with ``--recipe`` is refused.
RECIPE_FLAGS = (
    "recipe",
    "recipe_scale",
    "out",
    "overwrite",
    "seed",
    "eval_seeds",
    "max_wall_minutes",
    "no_progress_bar",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from agents.recipes import RECIPES
    from agents.rllib.train import add_engine_arguments
    from agents.sb3.train import add_arguments as add_sb3_arguments

    add_sb3_arguments(parser)
    parser.add_argument(
        "--engine",
        default="sb3",
        choices=ENGINES,
        help="sb3: stable-baselines3 in this process (+ --num-cpus workers); rllib: Ray RLlib "
        "with --num-env-runners runner processes, local or on a cluster (--address); "
        "docs/scaling.md",
    )
    add_engine_arguments(parser)
    parser.add_argument(
        "--recipe",
        default=None,
        metavar="NAME",
        help="run a task's best known training recipe end to end, with its own env, stages "
        f"and budgets ({', '.join(RECIPES)}; agents.recipes); only --out, --overwrite, "
        "--seed, --eval-seeds, --max-wall-minutes and --recipe-scale go with it",
    )
    parser.add_argument(
        "--recipe-scale",
        type=float,
        default=1.0,
        help="with --recipe: multiply every stage's budget by this (0 < s <= 1): a smoke run, "
        "not the recipe's result",
    )


def _set_flags(args: argparse.Namespace) -> list[str]:
    """The training flags ``args`` sets to something other than their defaults."""
    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    defaults = {a.dest: a.default for a in parser._actions}
    return [
        "--" + dest.replace("_", "-")
        for dest, default in defaults.items()
        if dest not in RECIPE_FLAGS and hasattr(args, dest) and getattr(args, dest) != default
    ]


def run(args: argparse.Namespace) -> int:
    if args.recipe is not None:
        from agents.interrupts import max_wall_seconds
        from agents.recipes import check_recipe, run_recipe

        check_recipe(args.recipe)
        others = _set_flags(args)
        if others:
            raise ValueError(
                f"--recipe {args.recipe} runs its own env, stages and budgets: "
                f"{', '.join(others)} cannot be combined with it"
            )
        return run_recipe(
            args.recipe,
            args.out,
            seed=args.seed,
            eval_seeds=args.eval_seeds,
            scale=args.recipe_scale,
            overwrite=args.overwrite,
            max_wall_s=max_wall_seconds(args.max_wall_minutes),
            progress_bar=not (args.no_progress_bar or getattr(args, "quiet", False)),
        )
    if args.recipe_scale != 1.0:
        raise ValueError(f"--recipe-scale {args.recipe_scale} needs --recipe")
    if args.engine == "rllib":
        from agents.rllib.train import run as run_rllib

        return run_rllib(args)
    from agents.sb3.train import run as run_sb3

    return run_sb3(args)
