"""Episodes as sequences, and the recurrent regressors fitted to them: the recurrent student's
training data and network.

:func:`collect_sequences` rolls out a scripted base (or a student driving on it) and records,
per agent-episode, the observation, the base's command and a teacher's correction (the warm
start's labels, :func:`agents.sb3.warm_start.correction_labels`); :func:`regressor` builds the
networks that map them to corrections (the student's encoder,
:class:`agents.sb3.features.NeighbourSetExtractor`, with an optional GRU over the episode);
:func:`train_sequences` fits one by masked MSE. :mod:`agents.sb3.recurrent_student` distils
its student with them; ``experiments/history_fit.py`` compares the regressors.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["collect_sequences", "regressor", "sequence_tensors", "train_sequences"]


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


#: The regressors: ``frame`` (an MLP on the current observation and the base's command),
#: ``frame+age`` (the same plus the step number) and ``history`` (the same plus a GRU over the
#: episode's sequence of those inputs: the recurrent student's).
KINDS = ("frame", "frame+age", "history")
#: Steps per unit of the ``frame+age`` regressor's age input (100 steps: 10 s).
AGE_SCALE_STEPS = 100.0


def regressor(observation_space: Any, kind: str, hidden: int = 64) -> Any:
    """A ``kind`` regressor (:data:`KINDS`), torch, mapping ``obs`` (B, T, D),
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
    """Fit ``model`` (a :func:`regressor`) in place to :func:`sequence_tensors`: masked MSE
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
