"""How much of a teacher's correction one frame of the estimate carries, and how much a history.

Question: is there more in the estimate's past than in its present for a residual student to
learn? (It is why the recurrent student, :mod:`agents.sb3.recurrent_student`, is recurrent.)
The tables are printed and written to ``--out``::

    python -m experiments.history_fit --preset lab-3m-4 --lidar-sectors 16 \
        --base scripted:formation-known-n-fast \
        --teacher privileged:formation-known-n-fast@truth \
        --train-seeds 0-99 --test-seeds 200-209 --out fit.json

A residual student distilled from a teacher that sees more than the estimate (the formation
controller on the true table) can only carry the part of the teacher's correction that its
input predicts. This measures that part offline, by supervised regression, before anyone
trains a policy on it:

- the base (``--base``) drives the robots on every seed, so both regressors are asked about the
  same states (the ones the base reaches, as in ``experiments/distill_fit.py``);
- the labels are the warm start's (:func:`agents.sb3.warm_start.correction_labels`, unit
  scale); steps where the teacher random-walks are left out of the loss and the scores;
- ``frame``: the student's own encoder (:class:`agents.sb3.features.NeighbourSetExtractor`) on
  the current observation, with the base's command appended as ``--residual-observes-base``
  does, then an MLP (64, 64, tanh; SB3's policy head): what a feed-forward residual can carry;
- ``frame+age``: ``frame`` plus the step number (``step / 100``, tens of seconds): the one thing
  a GRU run from the episode's start knows for free, how old the estimate is;
- ``history``: the same as ``frame``, plus a GRU over the episode's sequence of those inputs
  (causal: step t reads steps 0..t), read by the same head: what a recurrent residual could
  carry (it sees everything ``frame`` sees);
- all are trained on the same sequences, in the same order, for the same epochs, and scored
  on the held-out ``--test-seeds`` per phase of the episode with
  :func:`experiments.distill_fit.phase_table` (``R^2`` against answering 0, the base itself,
  and ``R^2`` beyond a straight line in the base's command).

If ``history`` beats ``frame`` on the held-out seeds well beyond the gap between two seeds of the
same regressor (``--fit-seeds``), and beyond ``frame+age``, a recurrent student has more to
learn from the estimate's past; if not, with this much data, it does not show. These are fits
of one architecture to a finite set of
episodes: lower bounds on what the input carries, not upper ones.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents.sb3.sequences import (
    KINDS,
    collect_sequences,
    regressor,
    sequence_tensors,
    train_sequences,
)
from experiments.distill_fit import phase_table
from experiments.recurrent_student import distillation_parser, parse_phases
from swarm_core.inputs import parse_seeds


def fit_regressors(
    train: dict[str, np.ndarray],
    test: dict[str, np.ndarray],
    observation_space: Any,
    epochs: int = 30,
    batch_sequences: int = 8,
    learning_rate: float = 1e-3,
    seed: int = 0,
    kinds: tuple[str, ...] = KINDS,
) -> dict[str, dict[str, np.ndarray]]:
    """Train the ``kinds`` regressors on ``train``'s sequences (masked MSE over the valid,
    non-wandering steps; Adam; the same shuffled minibatches of ``batch_sequences`` sequences
    for all) and return each one's predicted corrections
    ``{"frame": {"train": (S, T, 2), "test": (S', T, 2)}, ...}``."""
    import torch

    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise ValueError(f"regressors must be some of {KINDS}, got {list(kinds)!r}")
    torch.manual_seed(seed)
    models = {name: regressor(observation_space, name) for name in kinds}
    tensors = {part: sequence_tensors(d) for part, d in (("train", train), ("test", test))}
    for model in models.values():  # the same minibatches for all: one generator each
        train_sequences(model, tensors["train"], epochs, batch_sequences, learning_rate, seed)
    out: dict[str, dict[str, np.ndarray]] = {}
    with torch.no_grad():  # in chunks of sequences: the encoder's activations are large
        for name, model in models.items():  # train_sequences left each in eval mode
            out[name] = {
                part: np.concatenate(
                    [
                        model(
                            t["obs"][i : i + 16], t["base"][i : i + 16], t["step"][i : i + 16]
                        ).numpy()
                        for i in range(0, t["obs"].shape[0], 16)
                    ]
                ).astype(np.float64)
                for part, t in tensors.items()
            }
    return out


def fit_rows(data: dict[str, np.ndarray], prediction: np.ndarray) -> dict[str, np.ndarray]:
    """``data`` and a regressor's ``prediction`` (S, T, 2) as :func:`phase_table`'s rows (the
    valid steps, flattened)."""
    valid = data["valid"]
    return {
        "step": data["step"][valid],
        "label": data["label"][valid].astype(np.float64),
        "correction": prediction[valid],
        "base": data["base"][valid].astype(np.float64),
        "wandering": data["wandering"][valid],
    }


def main(argv: list[str] | None = None) -> int:
    from agents.sb3.train import env_kwargs_from_args

    parser = distillation_parser(__doc__.split("\n\n")[0])
    parser.add_argument("--train-seeds", default="0-99")
    parser.add_argument("--test-seeds", default="200-209")
    parser.add_argument("--epochs", type=int, default=30, help="passes over the sequences")
    parser.add_argument(
        "--regressors",
        default=",".join(KINDS),
        help=f"comma-separated, some of {', '.join(KINDS)}",
    )
    parser.add_argument(
        "--fit-seeds",
        default="0",
        help="torch seeds of the regressors: two or more show the fits' own spread",
    )
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--out", default=None, help="also write the tables as JSON here")
    args = parser.parse_args(argv)
    try:
        train_seeds = parse_seeds(args.train_seeds, "--train-seeds")
        test_seeds = parse_seeds(args.test_seeds, "--test-seeds")
        fit_seeds = parse_seeds(args.fit_seeds, "--fit-seeds")
    except ValueError as err:
        parser.error(str(err))
    shared = sorted(set(train_seeds) & set(test_seeds))
    if shared:
        parser.error(f"--train-seeds and --test-seeds share seeds {shared}")
    if args.epochs < 1:
        parser.error(f"--epochs must be >= 1, got {args.epochs}")
    phases = parse_phases(parser, args.phases)
    kinds = tuple(k.strip() for k in args.regressors.split(",") if k.strip())
    if not kinds or any(k not in KINDS for k in kinds):
        parser.error(f"--regressors must be some of {','.join(KINDS)}, got {args.regressors!r}")
    import torch

    from experiments.distill_fit import markdown
    from swarm_env import parallel_env

    torch.set_num_threads(args.torch_threads)
    env_kwargs = env_kwargs_from_args(args)
    t0 = time.perf_counter()
    train = collect_sequences(env_kwargs, args.base, args.teacher, train_seeds)
    test = collect_sequences(env_kwargs, args.base, args.teacher, test_seeds)
    collect_s = time.perf_counter() - t0
    probe = parallel_env(**env_kwargs)
    space = probe.observation_space(probe.possible_agents[0])
    probe.close()
    results: dict[str, Any] = {}
    for fit_seed in fit_seeds:
        t1 = time.perf_counter()
        preds = fit_regressors(train, test, space, epochs=args.epochs, seed=fit_seed, kinds=kinds)
        fit_s = time.perf_counter() - t1
        for name, pred in preds.items():
            for part, data in (("train", train), ("test", test)):
                rows = phase_table(fit_rows(data, pred[part]), phases)
                results.setdefault(f"{name}/fit_seed{fit_seed}", {})[part] = rows
                if part == "test":
                    print(f"{name} (fit seed {fit_seed}), held-out seeds {args.test_seeds}:")
                    print(markdown(rows))
        print(f"fit seed {fit_seed}: {fit_s:.0f} s")
    print(f"collected {len(train_seeds)} + {len(test_seeds)} episodes in {collect_s:.0f} s")
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {
                    "env_kwargs": env_kwargs,
                    "base": args.base,
                    "teacher": args.teacher,
                    "train_seeds": train_seeds,
                    "test_seeds": test_seeds,
                    "epochs": args.epochs,
                    "regressors": list(kinds),
                    "fits": results,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
