"""Fine-tune the recurrent residual student by PPO on the task's reward, from the command line.

Question: how much does the task's own reward (and a localization term) improve on the DAgger
student that imitates the controller on the truth? The training is the library's
:func:`agents.sb3.recurrent_ppo.finetune` (its module doc describes the actor, the critic, the
rollouts, the update and the files); this script only reads its settings from flags.
Reproduce the fine-tuned student::

    python -m experiments.recurrent_ppo --student runs/recurrent/student_best.pt \\
        --task-params '{"progress_weight": 10}' --out runs/recurrent_ppo

(``--base scripted:NAME --env-from runs/x/student.pt`` starts from a zero correction on that
base instead.) Its figure is ``runs/recurrent_ppo/train_log.png``; score the result with
``swarm-phd evaluate --policy runs/recurrent_ppo/student.pt``. Exit codes: 0, 2 for bad flags
(one line naming the flag), 130 / 143 after SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse

from agents.interrupts import add_max_wall_argument, max_wall_seconds
from agents.sb3.recurrent_ppo import FinetuneConfig, prepare_finetune, run_finetune
from experiments.recurrent_student import parse_phases
from swarm_core import inputs
from swarm_core.inputs import parse_json_object, parse_seeds

DEFAULTS = FinetuneConfig(student="-")  # the library's defaults, shown in --help


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.recurrent_ppo",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    start = parser.add_mutually_exclusive_group(required=True)
    start.add_argument("--student", help="the student.pt to start from")
    start.add_argument(
        "--base",
        help="start from a zero correction on this residual base (scripted:NAME): the base's "
        "own motion, in --env-from's env",
    )
    parser.add_argument(
        "--env-from",
        default=None,
        help="with --base: a student (.pt) or model (.zip) whose env the new student acts in",
    )
    parser.add_argument("--out", required=True, help="directory for the students and the log")
    inputs.add_overwrite_argument(parser)
    parser.add_argument(
        "--task-params", default=None, help="the training reward's task parameters (JSON)"
    )
    d = DEFAULTS
    parser.add_argument("--iterations", type=int, default=d.iterations)
    parser.add_argument("--n-copies", type=int, default=d.n_copies, help="episodes per iteration")
    parser.add_argument(
        "--num-cpus",
        type=int,
        default=d.num_cpus,
        help="worker processes stepping the copies (0: in this process); the same rollouts",
    )
    parser.add_argument("--train-seeds-start", type=int, default=d.train_seeds_start)
    parser.add_argument("--val-seeds", default="200-209")
    parser.add_argument(
        "--eval-every", type=int, default=d.eval_every, help="iterations between scores"
    )
    parser.add_argument(
        "--phases",
        default=",".join(map(str, d.phases)),
        help="comma-separated first steps of the scored phases",
    )
    parser.add_argument(
        "--critic-warmup", type=int, default=d.critic_warmup, help="critic-only iterations"
    )
    parser.add_argument("--epochs", type=int, default=d.epochs)
    parser.add_argument("--batch-sequences", type=int, default=d.batch_sequences)
    parser.add_argument("--learning-rate", type=float, default=d.learning_rate, help="the actor's")
    parser.add_argument("--critic-learning-rate", type=float, default=d.critic_learning_rate)
    parser.add_argument("--clip-range", type=float, default=d.clip_range)
    parser.add_argument("--target-kl", type=float, default=d.target_kl)
    parser.add_argument("--gamma", type=float, default=d.gamma)
    parser.add_argument("--gae-lambda", type=float, default=d.gae_lambda)
    parser.add_argument("--log-std", type=float, default=d.log_std, help="initial, unit scale")
    parser.add_argument(
        "--fit-seed", type=int, default=d.fit_seed, help="torch, noise and minibatches"
    )
    parser.add_argument("--torch-threads", type=int, default=d.torch_threads)
    add_max_wall_argument(parser, "after the iteration in which")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        config = FinetuneConfig(
            student=args.student,
            base=args.base,
            env_from=args.env_from,
            task_params=parse_json_object(args.task_params, "--task-params"),
            iterations=args.iterations,
            n_copies=args.n_copies,
            num_cpus=args.num_cpus,
            train_seeds_start=args.train_seeds_start,
            val_seeds=tuple(parse_seeds(args.val_seeds, "--val-seeds")),
            eval_every=args.eval_every,
            phases=tuple(parse_phases(parser, args.phases)),
            critic_warmup=args.critic_warmup,
            epochs=args.epochs,
            batch_sequences=args.batch_sequences,
            learning_rate=args.learning_rate,
            critic_learning_rate=args.critic_learning_rate,
            clip_range=args.clip_range,
            target_kl=args.target_kl,
            gamma=args.gamma,
            gae_lambda=args.gae_lambda,
            log_std=args.log_std,
            fit_seed=args.fit_seed,
            torch_threads=args.torch_threads,
            max_wall_s=max_wall_seconds(args.max_wall_minutes),
        )
        start = prepare_finetune(config, args.out, overwrite=args.overwrite)
    except ValueError as err:
        parser.error(str(err))
    return run_finetune(start)


if __name__ == "__main__":
    raise SystemExit(main())
