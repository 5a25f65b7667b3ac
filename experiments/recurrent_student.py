"""Distil the recurrent residual student by DAgger, from the command line.

Question: how close does a GRU over the robot's own estimate come to the formation controller
that reads the truth, when it is distilled from that teacher on the states it reaches itself?
The training is the library's :func:`agents.sb3.recurrent_student.distill` (its module doc
describes the rounds, the files and the stops); this script only reads its settings from
flags. Reproduce the student the fine-tuning starts from::

    python -m experiments.recurrent_student --preset lab-3m-4 --lidar-sectors 16 \\
        --base scripted:formation-known-n-fast \\
        --teacher privileged:formation-known-n-fast@truth \\
        --round-seeds 0-199 1000-1099 --val-seeds 200-209 --out runs/recurrent

then score it with ``swarm-phd evaluate --policy runs/recurrent/student_best.pt`` or
``python -m experiments.report --env-from runs/recurrent/student_best.pt ...``; its figure is
``runs/recurrent/train_log.png``. Exit codes: 0, 2 for bad flags (one line naming the flag),
130 / 143 after SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse

from agents.evaluation import DEFAULT_PHASES
from agents.evaluation import parse_phases as parse_phases_of
from agents.interrupts import add_max_wall_argument, max_wall_seconds
from agents.sb3.recurrent_student import DistillConfig, distill, student_space
from agents.sb3.train import add_env_arguments, env_kwargs_from_args
from swarm_core.inputs import parse_seeds


def distillation_parser(description: str) -> argparse.ArgumentParser:
    """A parser with the env's flags, ``--base``, ``--teacher`` and ``--phases``: what the
    distillation studies share."""
    parser = argparse.ArgumentParser(description=description)
    add_env_arguments(parser)
    parser.add_argument("--base", required=True, help="the residual's base, scripted:NAME")
    parser.add_argument(
        "--teacher", required=True, help="scripted:NAME, privileged:NAME or privileged:NAME@truth"
    )
    parser.add_argument(
        "--phases",
        default=",".join(map(str, DEFAULT_PHASES)),
        help="comma-separated first steps of the scored phases",
    )
    return parser


def parse_phases(parser: argparse.ArgumentParser, text: str) -> list[int]:
    """``--phases`` as step numbers (:func:`agents.evaluation.parse_phases`), or the parser's
    error (before any rollout, which takes minutes)."""
    try:
        return parse_phases_of(text)
    except ValueError as err:
        parser.error(str(err))


def main(argv: list[str] | None = None) -> int:
    parser = distillation_parser(__doc__.split("\n\n")[0])
    parser.add_argument(
        "--round-seeds",
        nargs="+",
        default=["0-199", "1000-1099"],
        help="one seed range per round: the first with the base driving, the rest DAgger",
    )
    parser.add_argument("--val-seeds", default="200-209", help="closed-loop score per round")
    parser.add_argument("--epochs", type=int, default=30, help="round 1's passes")
    parser.add_argument("--dagger-epochs", type=int, default=10, help="later rounds' passes")
    parser.add_argument("--fit-seed", type=int, default=0, help="torch and minibatch seed")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--out", required=True, help="directory for the students and data")
    add_max_wall_argument(parser, "after the round in which")
    args = parser.parse_args(argv)
    try:
        config = DistillConfig(
            env_kwargs=env_kwargs_from_args(args),
            base=args.base,
            teacher=args.teacher,
            round_seeds=tuple(tuple(parse_seeds(s, "--round-seeds")) for s in args.round_seeds),
            val_seeds=tuple(parse_seeds(args.val_seeds, "--val-seeds")),
            phases=tuple(parse_phases(parser, args.phases)),
            epochs=args.epochs,
            dagger_epochs=args.dagger_epochs,
            fit_seed=args.fit_seed,
            torch_threads=args.torch_threads,
            max_wall_s=max_wall_seconds(args.max_wall_minutes),
        )
        student_space(config)  # a bad teacher is named before any rollout
    except ValueError as err:
        parser.error(str(err))
    return distill(config, args.out)


if __name__ == "__main__":
    raise SystemExit(main())
