"""How much of a teacher's correction one frame of the estimate carries, and how much a history.

    python -m agents.sb3.history_fit --preset lab-3m-4 --lidar-sectors 16 \
        --base scripted:formation-known-n-fast \
        --teacher privileged:formation-known-n-fast@truth \
        --train-seeds 0-99 --test-seeds 200-209 --out fit.json

A residual student distilled from a teacher that sees more than the estimate (round 16's
controller on the true table) can only carry the part of the teacher's correction that its
input predicts. This measures that part offline, by supervised regression, before anyone
trains a policy on it:

- the base (``--base``) drives the robots on every seed, so both regressors are asked about the
  same states (the ones the base reaches, as in :mod:`agents.sb3.distill_fit`);
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
  :func:`agents.sb3.distill_fit.phase_table` (``R^2`` against answering 0, the base itself,
  and ``R^2`` beyond a straight line in the base's command).

If ``history`` beats ``frame`` on the held-out seeds well beyond the gap between two seeds of the
same regressor (``--fit-seeds``), and beyond ``frame+age``, a recurrent student has more to
learn from the estimate's past; if not, with this much data, it does not show
(``docs/results.md``, round 17). These are fits of one architecture to a finite set of
episodes: lower bounds on what the input carries, not upper ones.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents.sb3.distill_fit import DEFAULT_PHASES, phase_table
from swarm_phd.sweep import parse_seeds

__all__ = ["collect_sequences", "fit_regressors", "main"]


def collect_sequences(
    env_kwargs: dict[str, Any],
    base: str,
    teacher: str,
    seeds: list[int],
    student: Any = None,
) -> dict[str, np.ndarray]:
    """Roll out ``base`` on ``seeds`` and record, per agent-episode (S sequences of up to T
    steps, padded): ``obs`` (S, T, D) float32 the env's observation, ``base`` (S, T, 2) the
    base's command and ``label`` (S, T, 2) the teacher's correction, unit scale (``[v, omega]
    / high``, clipped), ``step`` (S, T) int, ``valid`` (S, T) bool (False on padding) and
    ``wandering`` (S, T) bool (the teacher random-walks), plus ``seed`` (S,).

    With a ``student`` (:class:`agents.sb3.recurrent_student.RecurrentStudentPolicy`), the
    student drives instead, on the same base commands (``student.correct``): DAgger's states,
    with the teacher's labels still taken against the base."""
    from agents.sb3.privileged import load_teacher
    from agents.sb3.residual import ResidualBase, base_in_unit_scale
    from agents.sb3.warm_start import correction_labels
    from swarm_env import parallel_env

    env = parallel_env(**env_kwargs)
    episodes: list[dict[str, list]] = []
    try:
        scripted = ResidualBase(base, env)
        tutor = load_teacher(teacher, env)
        high = scripted.high
        for seed in seeds:
            scripted.reset(seed)
            tutor.reset(seed)
            if student is not None:
                student.reset(seed)
            obs, infos = env.reset(seed=seed)
            rows: dict[str, dict[str, list]] = {
                a: {"obs": [], "base": [], "label": [], "wandering": []} for a in env.agents
            }
            while env.agents:
                commands = scripted(obs, infos)
                taught = tutor(obs, infos)
                agents = list(obs)
                labels = correction_labels(taught, commands, tutor.wandering, agents, high)
                for i, a in enumerate(agents):
                    r = rows[a]
                    r["obs"].append(np.asarray(obs[a], np.float32))
                    r["base"].append(base_in_unit_scale(commands[a], high))
                    r["label"].append(labels[i])
                    r["wandering"].append(a in tutor.wandering)
                drive = commands if student is None else student.correct(obs, commands)
                obs, _, _, _, infos = env.step(drive)
            for r in rows.values():
                episodes.append({**r, "seed": seed})
    finally:
        env.close()
    n_seq, t_max = len(episodes), max(len(e["obs"]) for e in episodes)
    dim = episodes[0]["obs"][0].shape[0]
    out = {
        "obs": np.zeros((n_seq, t_max, dim), np.float32),
        "base": np.zeros((n_seq, t_max, 2), np.float32),
        "label": np.zeros((n_seq, t_max, 2), np.float32),
        "step": np.tile(np.arange(t_max), (n_seq, 1)),
        "valid": np.zeros((n_seq, t_max), bool),
        "wandering": np.zeros((n_seq, t_max), bool),
        "seed": np.array([e["seed"] for e in episodes]),
    }
    for s, e in enumerate(episodes):
        t = len(e["obs"])
        out["obs"][s, :t] = np.stack(e["obs"])
        out["base"][s, :t] = np.stack(e["base"])
        out["label"][s, :t] = np.stack(e["label"])
        out["valid"][s, :t] = True
        out["wandering"][s, :t] = e["wandering"]
    return out


#: The regressors (module doc).
KINDS = ("frame", "frame+age", "history")
#: Steps per unit of the ``frame+age`` regressor's age input (100 steps: 10 s).
AGE_SCALE_STEPS = 100.0


def _regressor(observation_space: Any, kind: str, hidden: int = 64) -> Any:
    """A ``kind`` regressor (:data:`KINDS`, module doc), torch, mapping ``obs`` (B, T, D),
    ``base`` (B, T, 2) and ``step`` (B, T) to corrections (B, T, 2)."""
    import torch
    from torch import nn

    from agents.sb3.features import NeighbourSetExtractor

    class Regressor(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = NeighbourSetExtractor(observation_space)
            width = self.encoder.features_dim + 2
            self.gru = nn.GRU(width, hidden, batch_first=True) if kind == "history" else None
            self.age = kind == "frame+age"
            head_in = width + (hidden if self.gru is not None else 0) + int(self.age)
            self.head = nn.Sequential(
                nn.Linear(head_in, hidden),
                nn.Tanh(),
                nn.Linear(hidden, hidden),
                nn.Tanh(),
                nn.Linear(hidden, 2),
            )

        def step(
            self, obs: torch.Tensor, base: torch.Tensor, hidden: torch.Tensor | None
        ) -> tuple[torch.Tensor, torch.Tensor]:
            """One step of a ``history`` regressor for B sequences at once: ``obs`` (B, D),
            ``base`` (B, 2), ``hidden`` (1, B, H) the GRU's state (None at a sequence's start)
            -> corrections (B, 2) and the next state; equals :meth:`forward` step by step."""
            if self.gru is None:
                raise ValueError(f"only a 'history' regressor is stepped, this is {kind!r}")
            z = torch.cat([self.encoder(obs), base], -1)
            out, hidden = self.gru(z.unsqueeze(1), hidden)
            return self.head(torch.cat([z, out[:, 0]], -1)), hidden

        def forward(
            self, obs: torch.Tensor, base: torch.Tensor, step: torch.Tensor
        ) -> torch.Tensor:
            b, t, d = obs.shape
            z = torch.cat([self.encoder(obs.reshape(b * t, d)).reshape(b, t, -1), base], -1)
            if self.gru is not None:
                z = torch.cat([z, self.gru(z)[0]], -1)  # one-directional: causal
            if self.age:
                z = torch.cat([z, (step / AGE_SCALE_STEPS).unsqueeze(-1)], -1)
            return self.head(z)

    return Regressor()


def sequence_tensors(data: dict[str, np.ndarray]) -> dict[str, Any]:
    """:func:`collect_sequences`' arrays as the torch tensors a regressor trains on; ``mask``
    (S, T) is 1 on the valid steps where the teacher does not random-walk."""
    import torch

    return {k: torch.as_tensor(data[k]) for k in ("obs", "base", "label")} | {
        "step": torch.as_tensor(data["step"], dtype=torch.float32),
        "mask": torch.as_tensor(data["valid"] & ~data["wandering"], dtype=torch.float32),
    }


def train_sequences(
    model: Any,
    tensors: dict[str, Any],
    epochs: int,
    batch_sequences: int = 8,
    learning_rate: float = 1e-3,
    seed: int = 0,
) -> list[float]:
    """Fit ``model`` (a :func:`_regressor`) in place to :func:`sequence_tensors`: masked MSE
    over the valid, non-wandering steps, Adam, ``epochs`` passes in minibatches of
    ``batch_sequences`` whole sequences shuffled by ``default_rng(seed)``. Returns each
    epoch's mean minibatch loss."""
    import torch

    rng = np.random.default_rng(seed)
    optim = torch.optim.Adam(model.parameters(), lr=learning_rate)
    n_seq = tensors["obs"].shape[0]
    model.train()
    losses = []
    for _ in range(epochs):
        order = rng.permutation(n_seq)
        total, batches = 0.0, 0
        for start in range(0, n_seq, batch_sequences):
            idx = torch.as_tensor(order[start : start + batch_sequences])
            mask = tensors["mask"][idx]
            pred = model(tensors["obs"][idx], tensors["base"][idx], tensors["step"][idx])
            err = ((pred - tensors["label"][idx]) ** 2).sum(-1)
            loss = (err * mask).sum() / mask.sum().clamp(min=1.0)
            optim.zero_grad()
            loss.backward()
            optim.step()
            total, batches = total + float(loss.detach()), batches + 1
        losses.append(total / batches)
    model.eval()
    return losses


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
    models = {name: _regressor(observation_space, name) for name in kinds}
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


def distillation_parser(description: str) -> argparse.ArgumentParser:
    """A parser with the env's flags, ``--base``, ``--teacher`` and ``--phases`` (checked by
    :func:`parse_phases`): what the distillation tools share."""
    from agents.sb3.train import add_env_arguments

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
    """``--phases`` as step numbers, or the parser's error (called before any rollout, which
    takes minutes)."""
    from agents.sb3.report import phase_spans

    try:
        phases = [int(p) for p in text.split(",")]
        phase_spans(phases)
    except ValueError:
        parser.error(f"--phases must be increasing integers >= 0, got {text!r}")
    return phases


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

    from agents.sb3.distill_fit import markdown
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
