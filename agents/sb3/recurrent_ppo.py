"""PPO fine-tuning of a recurrent residual student (:mod:`agents.sb3.recurrent_student`).

    from agents.sb3.recurrent_ppo import FinetuneConfig, finetune

    finetune(FinetuneConfig(student="runs/recurrent/student_best.pt",
                            task_params={"progress_weight": 10}), "runs/recurrent_ppo")

(``python -m experiments.recurrent_ppo`` reads the same settings from flags; the flags below
are :class:`FinetuneConfig`'s fields.)

A DAgger student imitates its teacher; this lets the task's reward (and a localization term,
``task_params={"localization_weight": 2, "localization_term": "estimate"}``) move it.
Without a DAgger student, ``base="scripted:NAME", env_from="runs/x/student.pt"`` starts from a
zero correction on that base (:func:`zero_student`, the base's own motion) in that file's env.
SB3 has no recurrent policy of its own and sb3-contrib's ``RecurrentPPO`` trains its own LSTM
actor-critic, so the student (a GRU over the Deep Sets code of the estimate and the base's
command) is trained by this short PPO loop:

- **actor**: the student's correction ``c(o_t, b_t, h_t)`` (unit scale) is the mean of a
  Gaussian, ``sigma = exp(log_std)`` per axis, learnt from ``--log-std``; the env composes
  ``clip(b + clip(a, -1, 1) * high)`` (:func:`agents.sb3.residual.compose`). Each agent's GRU
  state starts at zero with the episode, as when it is deployed.
- **critic** (training only): the agent's true state (:mod:`agents.sb3.central_critic`'s
  block: its teammates' true positions and the task's critic features), its own Deep Sets
  code of the observation, the base's command and the fraction of the episode left;
  feed-forward (asymmetric actor-critic: the truth makes it close to Markov).
- **rollouts**: ``--n-copies`` copies of the student's env in one
  :class:`~agents.sb3.batched.BatchedSwarmVecEnv` (one filter call per step; with
  ``--num-cpus N``, split across N worker processes, the same rollouts bit for bit), K fresh
  episodes per iteration, seeds ``--train-seeds-start + iteration * K + k``.
- **advantages**: GAE(``--gamma``, ``--gae-lambda``) over the whole episode, whose end is
  terminal: the critic reads the fraction of the episode left, so the horizon is part of its
  state and the value after the last step is 0 (Pardo et al. 2018, "Time Limits in
  Reinforcement Learning").
- **update**: the first ``--critic-warmup`` iterations train the critic alone; then
  ``--epochs`` passes of clipped PPO (``--clip-range``) over minibatches of
  ``--batch-sequences`` whole agent-episodes, the GRU unrolled from the episode's start (the
  rollout's own computation), Adam at ``--learning-rate``; as in SB3, the actor's update
  stops at the first minibatch whose approximate KL passes 1.5 ``--target-kl`` (the critic's
  passes go on).
- every ``--eval-every`` iterations, and before the first, the student (its mean: the
  deployed policy) is saved (``student_it<k>.pt``) and scored in closed loop on
  ``--val-seeds``; the last iteration's is also ``student.pt``. ``train_log.json`` holds
  every iteration's return, formation error, KL, clip fraction and wall time, drawn with
  the validation scores in ``train_log.png`` (several runs: :func:`plot_ppo_logs`).
  Ctrl-C or SIGTERM saves the current student as ``student.pt`` and exits 130 / 143;
  ``--max-wall-minutes`` stops after the iteration in which the budget passes, saving
  ``student.pt`` (that iteration's; scored only if it is an ``--eval-every`` iteration) and
  the log as a finished run does (exit 0).
  ``train_log.json``'s ``"stopped"`` says why a run stopped early (the signal,
  ``"max-wall-minutes"``) or is null.

The saved student keeps its own env (the reward's task parameters do not change its
observation), so it is scored on the task's own reward and metrics; the training reward's
parameters are recorded in it as ``reward_task_params``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import DEFAULT_PHASES
from swarm_core import inputs
from swarm_core.atomic_files import atomic_write
from swarm_core.inputs import format_seeds

__all__ = [
    "FinetuneConfig",
    "FinetuneStart",
    "finetune",
    "gae",
    "new_critic",
    "plot_ppo_logs",
    "ppo_update",
    "prepare_finetune",
    "rollout",
    "run_finetune",
    "start_metadata",
    "zero_student",
]


def gae(
    rewards: np.ndarray, values: np.ndarray, last_values: np.ndarray, gamma: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimates of whole episodes.

    ``rewards`` and ``values`` (T, B); ``last_values`` (B,) the value of the state after the
    last step (0 at a terminal state; the critic's value where the episode was cut short).
    Returns the advantages and the value targets (advantages + values), (T, B) float64 each."""
    t_max = rewards.shape[0]
    adv = np.zeros(rewards.shape, np.float64)
    running = np.zeros(rewards.shape[1], np.float64)
    for t in range(t_max - 1, -1, -1):  # a recursion over time: T steps, vectorised over B
        following = last_values if t == t_max - 1 else values[t + 1]
        delta = rewards[t] + gamma * following - values[t]
        running = delta + gamma * lam * running
        adv[t] = running
    return adv, adv + values


def _critic_class():
    import torch
    from torch import nn

    from agents.sb3.features import NeighbourSetExtractor

    class Critic(nn.Module):
        """V(s) of one agent (module doc). ``obs`` (..., D), ``base`` (..., 2), ``state``
        (..., P), ``left`` (...) the fraction of the episode still to come -> (...)."""

        def __init__(self, observation_space: Any, critic_dims: int, hidden: int = 64):
            super().__init__()
            self.encoder = NeighbourSetExtractor(observation_space)
            self.state = nn.Sequential(nn.Linear(critic_dims + 3, hidden), nn.Tanh())
            self.head = nn.Sequential(
                nn.Linear(self.encoder.features_dim + hidden, hidden),
                nn.Tanh(),
                nn.Linear(hidden, 1),
            )

        def forward(self, obs, base, state, left):
            lead = left.shape  # any leading shape: the encoder takes rows
            # Positions in m, halved as the central critic does: the lab's ranges are ~0-3 m.
            s = self.state(torch.cat([state / 2.0, base, left.unsqueeze(-1)], -1))
            code = self.encoder(obs.reshape(-1, obs.shape[-1])).reshape(*lead, -1)
            return self.head(torch.cat([code, s], -1)).squeeze(-1)

    return Critic


def new_critic(observation_space: Any, critic_dims: int, hidden: int = 64) -> Any:
    """The critic (module doc), a torch module; torch is imported only when one is built."""
    return _critic_class()(observation_space, critic_dims, hidden)


def rollout(vec: Any, model: Any, log_std: Any, seeds: list[int], generator: Any) -> dict:
    """K episodes, one per copy of ``vec`` (seeds ``seeds``), the student sampling around its
    mean. Returns per step t and VecEnv entry b: ``obs`` (T, B, D + 2 + P) float32 (the env's
    observation, the base's command in unit scale, the critic block), ``actions`` (T, B, 2),
    ``logp`` (T, B) and ``rewards`` (T, B). Every copy's episode must end at the same step, its
    time limit: the critic's time input counts down to it."""
    import torch

    obs = vec.reset(copy_seeds=seeds)
    hidden = None
    dim = model.encoder_obs_dim
    std = log_std.exp().detach()
    rows: dict[str, list] = {"obs": [], "actions": [], "logp": [], "rewards": []}
    while True:
        o = torch.as_tensor(obs)
        with torch.no_grad():
            mean, hidden = model.step(o[:, :dim], o[:, dim : dim + 2], hidden)
            noise = torch.randn(mean.shape, generator=generator)
            action = mean + std * noise
            logp = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
        vec.step_async(action.numpy())
        obs, rewards, dones, infos = vec.step_wait()
        rows["obs"].append(o.numpy())
        rows["actions"].append(action.numpy())
        rows["logp"].append(logp.numpy())
        rows["rewards"].append(rewards.astype(np.float64))
        if dones.any():
            step = len(rows["rewards"])
            if not dones.all():
                ended = sorted({b // vec.agents_per_copy for b in np.flatnonzero(dones)})
                raise ValueError(
                    f"copies {ended} ended at step {step} before the others: recurrent PPO "
                    "needs every copy's episode to end together"
                )
            if not all(info.get("TimeLimit.truncated", False) for info in infos):
                raise ValueError(
                    f"the task terminated the episode at step {step}: recurrent PPO's critic "
                    "counts the time left down to the episode's time limit"
                )
            break
    return {k: np.stack(v) for k, v in rows.items()}


def _split(obs: Any, dim: int) -> tuple:
    """A rollout row's parts: the env's observation, the base's command, the critic block."""
    return obs[..., :dim], obs[..., dim : dim + 2], obs[..., dim + 2 :]


def _time_left(t_max: int) -> np.ndarray:
    """The fraction of a ``t_max``-step episode still to come at each step, (T,): 1 .. 1/T."""
    return (t_max - np.arange(t_max)) / t_max


def ppo_update(
    model: Any,
    log_std: Any,
    critic: Any,
    actor_optim: Any | None,
    critic_optim: Any,
    batch: dict[str, Any],
    epochs: int,
    batch_sequences: int,
    clip_range: float,
    target_kl: float,
    rng: np.random.Generator,
    max_grad_norm: float = 0.5,
) -> dict[str, float]:
    """One iteration's update on ``batch`` (torch tensors, sequences first: ``obs`` (B, T, F),
    ``actions`` (B, T, 2), ``logp`` (B, T), ``advantages`` (B, T) normalised, ``returns``
    (B, T), ``left`` (B, T)). ``actor_optim`` ``None``: the critic alone (warm-up). Returns
    the critic's loss of the last pass, the actor's mean KL, clip fraction and loss of the
    last pass it took part in, the passes made and the actor's optimizer steps.

    Like SB3's PPO, the actor's update stops at the first minibatch whose approximate KL
    from the policy that acted, measured before its step, passes 1.5 ``target_kl``: a GRU
    unrolled over 300 steps can move its mean at a few states by far more than the average
    state (one Adam step at 3e-5 moved the round-18 student's mean by 0.008 on average and by
    0.7 at one state), so a pass's end is too late a check."""
    import torch

    dim = model.encoder_obs_dim
    n_seq, t_max = batch["logp"].shape
    stats = {"approx_kl": 0.0, "clip_fraction": 0.0, "policy_loss": 0.0, "value_loss": 0.0}
    passes = actor_steps = 0
    stopped = False
    for _ in range(epochs):
        order = rng.permutation(n_seq)
        kls, clips, p_losses, v_losses = [], [], [], []
        for start in range(0, n_seq, batch_sequences):
            idx = torch.as_tensor(order[start : start + batch_sequences])
            o, b, state = _split(batch["obs"][idx], dim)
            value = critic(o, b, state, batch["left"][idx])
            v_loss = ((value - batch["returns"][idx]) ** 2).mean()
            critic_optim.zero_grad()
            v_loss.backward()
            torch.nn.utils.clip_grad_norm_(critic.parameters(), max_grad_norm)
            critic_optim.step()
            v_losses.append(float(v_loss.detach()))
            if actor_optim is None or stopped:
                continue
            mean = model(o, b, torch.zeros(len(idx), t_max))
            dist = torch.distributions.Normal(mean, log_std.exp())
            logp = dist.log_prob(batch["actions"][idx]).sum(-1)
            log_ratio = logp - batch["logp"][idx]
            ratio = log_ratio.exp()
            with torch.no_grad():
                kls.append(float(((ratio - 1) - log_ratio).mean()))
                clips.append(float(((ratio - 1).abs() > clip_range).float().mean()))
            if kls[-1] > 1.5 * target_kl:
                stopped = True
                continue
            adv = batch["advantages"][idx]
            p_loss = -torch.min(
                ratio * adv, ratio.clamp(1 - clip_range, 1 + clip_range) * adv
            ).mean()
            actor_optim.zero_grad()
            p_loss.backward()
            torch.nn.utils.clip_grad_norm_([*model.parameters(), log_std], max_grad_norm)
            actor_optim.step()
            actor_steps += 1
            p_losses.append(float(p_loss.detach()))
        passes += 1
        stats["value_loss"] = float(np.mean(v_losses))
        if kls:  # the actor's figures of the last pass it took part in
            stats.update(
                approx_kl=float(np.mean(kls)),
                clip_fraction=float(np.mean(clips)),
                policy_loss=float(np.mean(p_losses)) if p_losses else 0.0,
            )
    return stats | {"passes": passes, "actor_steps": actor_steps}


def _batch(data: dict[str, np.ndarray], values: np.ndarray, last_values: np.ndarray, config):
    """The rollout as sequence-first torch tensors with its advantages and value targets."""
    import torch

    adv, returns = gae(data["rewards"], values, last_values, config.gamma, config.gae_lambda)
    norm = (adv - adv.mean()) / (adv.std() + 1e-8)
    t_max = data["rewards"].shape[0]
    left = np.repeat(_time_left(t_max)[:, None], values.shape[1], axis=1)

    def seq(a: np.ndarray) -> Any:
        return torch.as_tensor(np.swapaxes(a, 0, 1).copy(), dtype=torch.float32)

    return {
        "obs": seq(data["obs"]),
        "actions": seq(data["actions"]),
        "logp": seq(data["logp"]),
        "advantages": seq(norm),
        "returns": seq(returns),
        "left": seq(left),
    }


def _values(critic: Any, data: dict[str, np.ndarray], dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The critic's values of every rollout state (T, B), and the values after the last step
    (B,): 0, the episode's end being terminal (module doc)."""
    import torch

    t_max, n = data["rewards"].shape
    left = torch.as_tensor(_time_left(t_max), dtype=torch.float32)[:, None].expand(t_max, n)
    with torch.no_grad():
        values = critic(*_split(torch.as_tensor(data["obs"]), dim), left)
    return values.numpy().astype(np.float64), np.zeros(n)


def plot_ppo_logs(logs: list[str | Path], figure: str | Path) -> None:
    """Draw each run's learning curves (``train_log.json`` files) to ``figure`` (PNG): the
    training return per agent-episode and the training episodes' formation error (with the
    exploration noise) per iteration, and the closed-loop validation score of the scored
    students, with the base's as a dashed line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4), squeeze=False)
    for path in logs:
        log = json.loads(Path(path).read_text())
        settings = log.get("config") or log["args"]  # "args": logs of the earlier command
        label = f"{Path(path).parent.name} (fit seed {settings['fit_seed']})"
        its = [it["iteration"] for it in log["iterations"]]
        line = axes[0, 0].plot(its, [it["return_per_agent"] for it in log["iterations"]])[0]
        color = line.get_color()
        line.set_label(label)
        axes[0, 1].plot(its, [it["formation_error_m"] for it in log["iterations"]], color=color)
        val = log["val"]
        axes[0, 2].plot(
            [v["iteration"] for v in val],
            [v["formation_error_m"] for v in val],
            "o-",
            color=color,
            label=label,
        )
        axes[0, 2].axhline(log["base_val"]["formation_error_m"], ls="--", color=color, alpha=0.5)
    titles = (
        ("return per agent-episode", "training episodes (with exploration noise)"),
        ("formation error (m)", "training episodes (with exploration noise)"),
        ("formation error (m)", "validation seeds, the mean; dashed: the base"),
    )
    for ax, (ylabel, title) in zip(axes[0], titles, strict=True):
        ax.set_xlabel("PPO iteration")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    atomic_write(figure, lambda tmp: fig.savefig(tmp, dpi=110))  # a Ctrl-C mid-write: old file
    plt.close(fig)


@dataclass(frozen=True)
class FinetuneConfig:
    """A PPO fine-tuning of a recurrent student (:func:`finetune`; module doc).

    The start: ``student`` (a ``student.pt``), or a zero correction on ``base`` (a scripted
    residual base) in the env of ``env_from`` (a ``.pt`` student or ``.zip`` model).
    ``task_params``: the training reward's task parameters (they may not change what the
    student observes). Each of ``iterations`` rolls out ``n_copies`` fresh episodes (seeds
    from ``train_seeds_start`` on; with ``num_cpus`` worker processes, the same rollouts),
    the first ``critic_warmup`` train the critic alone; every ``eval_every`` iterations the
    student is scored on ``val_seeds`` (none of them a training seed) over ``phases``. The
    rest are PPO's settings, and ``max_wall_s`` a wall-time budget (None: none). Checked on
    construction: ``ValueError`` naming the command-line flag and the value.
    """

    student: str | None = None
    base: str | None = None
    env_from: str | None = None
    task_params: dict[str, Any] = field(default_factory=dict)
    iterations: int = 40
    n_copies: int = 16
    num_cpus: int = 0
    train_seeds_start: int = 5000
    val_seeds: tuple[int, ...] = tuple(range(200, 210))
    eval_every: int = 10
    phases: tuple[int, ...] = DEFAULT_PHASES
    critic_warmup: int = 3
    epochs: int = 5
    batch_sequences: int = 8
    # The actor's step, set by the KL it makes: from a DAgger student, 1e-4 reached an
    # approximate KL of 0.21 in one pass (10x target_kl), 1e-5 0.0006 per iteration, 3e-5
    # 0.002-0.03.
    learning_rate: float = 3e-5
    critic_learning_rate: float = 1e-3
    clip_range: float = 0.1
    target_kl: float = 0.02
    gamma: float = 0.99
    gae_lambda: float = 0.95
    log_std: float = -2.5
    fit_seed: int = 0
    torch_threads: int = 1
    max_wall_s: float | None = None

    def __post_init__(self) -> None:
        from agents.evaluation import parse_phases
        from swarm_core.validation import check_number

        object.__setattr__(self, "val_seeds", tuple(int(s) for s in self.val_seeds))
        object.__setattr__(self, "phases", tuple(parse_phases(self.phases)))
        if (self.student is None) == (self.base is None):
            raise ValueError("one of --student and --base is required, not both")
        if self.student is not None and self.env_from is not None:
            raise ValueError("--env-from goes with --base; a --student acts in its own env")
        if self.base is not None and self.env_from is None:
            raise ValueError(
                "--base needs --env-from: the student's env (a .pt or .zip trained there)"
            )
        for flag, value, low in (
            ("--iterations", self.iterations, 1),
            ("--n-copies", self.n_copies, 1),
            ("--num-cpus", self.num_cpus, 0),
            ("--eval-every", self.eval_every, 1),
            ("--critic-warmup", self.critic_warmup, 0),
            ("--epochs", self.epochs, 1),
            ("--batch-sequences", self.batch_sequences, 1),
            ("--torch-threads", self.torch_threads, 1),
            ("--fit-seed", self.fit_seed, 0),
            ("--train-seeds-start", self.train_seeds_start, 0),
        ):
            check_number(flag, value, integer=True, low=low)
        if self.num_cpus > self.n_copies:
            raise ValueError(
                f"--num-cpus {self.num_cpus} exceeds --n-copies {self.n_copies}: each worker "
                "steps at least one copy"
            )
        for flag, value in (
            ("--learning-rate", self.learning_rate),
            ("--critic-learning-rate", self.critic_learning_rate),
            ("--clip-range", self.clip_range),
            ("--target-kl", self.target_kl),
        ):
            check_number(flag, value, low=0, above=True)
        check_number("--gamma", self.gamma, low=0, high=1)
        check_number("--gae-lambda", self.gae_lambda, low=0, high=1)
        check_number("--log-std", self.log_std)
        check_number("--max-wall-minutes", self.max_wall_s, low=0, above=True, optional=True)
        if not isinstance(self.task_params, dict):
            raise ValueError(f"--task-params must be a JSON object, got {self.task_params!r}")
        train_end = self.train_seeds_start + self.iterations * self.n_copies
        overlap = sorted(set(self.val_seeds) & set(range(self.train_seeds_start, train_end)))
        if overlap:
            raise ValueError(f"--val-seeds share seeds with the training episodes: {overlap}")


@dataclass
class FinetuneStart:
    """A checked fine-tuning, ready to run (:func:`prepare_finetune`): the start's metadata,
    its env and the training env's kwargs, the starting model and its observation space."""

    config: FinetuneConfig
    out: Path
    meta: dict[str, Any]
    env_kwargs: dict[str, Any]
    train_kwargs: dict[str, Any]
    model: Any
    space: Any


def prepare_finetune(config: FinetuneConfig, out: str | Path, overwrite: bool = False):
    """Check everything a fine-tuning needs before any rollout or worker (``ValueError``
    naming the flag): the start (:func:`start_metadata`), ``out`` (new or empty unless
    ``overwrite``, and not the directory the start is read from), a formation task, and a
    training env whose ``task_params`` leave the student's observation unchanged. Builds the
    starting model; returns a :class:`FinetuneStart` for :func:`run_finetune`."""
    import torch

    from agents.sb3.recurrent_student import load_student
    from swarm_env import parallel_env

    meta = start_metadata(config)
    for flag, read in (("--student", config.student), ("--env-from", config.env_from)):
        if read and Path(out).resolve() == Path(read).resolve().parent:
            raise ValueError(
                f"--out {str(out)!r} holds {flag} {read!r}: its student.pt and "
                "train_log.json would be overwritten; give another directory"
            )
    inputs.run_dir("--out", out, overwrite=overwrite)
    env_kwargs = dict(meta["env_kwargs"])
    if env_kwargs.get("task") != "formation":  # its log and scores are formation's
        raise ValueError(
            f"{_start_flag(config)} acts on task {env_kwargs.get('task')!r}; recurrent "
            "PPO trains formation students"
        )
    reward_params = config.task_params
    train_kwargs = {
        **env_kwargs,
        "task_params": {**env_kwargs.get("task_params", {}), **reward_params},
    }
    probe = parallel_env(**env_kwargs)
    try:
        space = probe.observation_space(probe.possible_agents[0])
        features = probe.task.features(len(probe.possible_agents))
        torch.manual_seed(config.fit_seed)  # the zero student's hidden layers
        if config.student is not None:  # refuses a mismatched observation
            model = load_student(config.student, probe).model
        else:
            model = zero_student(space)
    finally:
        probe.close()
    torch.set_num_threads(config.torch_threads)  # loading a student set it to 1
    torch.manual_seed(config.fit_seed)
    try:  # a bad task_params fails here, before any rollout or worker
        trained = parallel_env(**train_kwargs)
    except ValueError as err:
        raise ValueError(
            f"the training env with --task-params {json.dumps(reward_params)}: {err}"
        ) from err
    try:
        same = trained.observation_space(
            trained.possible_agents[0]
        ).shape == space.shape and np.array_equal(
            trained.task.features(len(trained.possible_agents)), features
        )
    finally:
        trained.close()
    if not same:
        raise ValueError(
            f"--task-params {json.dumps(reward_params)} changes what the student observes (its "
            "task's features or the observation's size); only the reward's terms may change"
        )
    return FinetuneStart(config, Path(out), meta, env_kwargs, train_kwargs, model, space)


def finetune(config: FinetuneConfig, out: str | Path, overwrite: bool = False) -> int:
    """Fine-tune a recurrent student by PPO into ``out`` (module doc): every check first
    (:func:`prepare_finetune`), then :func:`run_finetune`. Returns the exit code: 0, or
    130 / 143 after SIGINT / SIGTERM (``student.pt`` saved)."""
    return run_finetune(prepare_finetune(config, out, overwrite))


def start_metadata(config: FinetuneConfig) -> dict[str, Any]:
    """The starting student's metadata (``env_kwargs``, ``base``, ...): ``student``'s, or for
    ``base`` that base in ``env_from``'s env (ValueError on a bad file or base)."""
    from agents.sb3.recurrent_student import read_student_metadata

    if config.student is not None:
        return read_student_metadata(config.student)
    from agents.policies import model_env_kwargs
    from agents.sb3.recurrent_student import check_student_env
    from agents.sb3.residual import check_residual

    check_residual(config.base, "--base")
    try:
        env_kwargs = model_env_kwargs(config.env_from)
    except ValueError as err:
        raise ValueError(f"--env-from: {err}") from err
    if env_kwargs is None:
        raise ValueError(
            f"--env-from must be a .pt student or a .zip model, got {config.env_from!r}"
        )
    check_student_env(env_kwargs, "--env-from")
    return {"env_kwargs": env_kwargs, "base": config.base}


def _start_flag(config: FinetuneConfig) -> str:
    if config.student:
        return f"--student {config.student!r}"
    return f"--env-from {config.env_from!r}"


def zero_student(space: Any, hidden: int = 64) -> Any:
    """A student whose correction is zero everywhere (its output layer zeroed), so that it
    drives exactly as its base: PPO's start when there is no DAgger student. The rest keeps
    its random initialisation, through which the output layer's first gradients flow."""
    import torch

    from agents.sb3.recurrent_student import new_student

    model = new_student(space, hidden=hidden)
    with torch.no_grad():
        model.head[-1].weight.zero_()
        model.head[-1].bias.zero_()
    return model.eval()


def run_finetune(start: FinetuneStart) -> int:
    """The PPO iterations of a prepared fine-tuning (:func:`prepare_finetune`; module doc),
    stopped by a signal or the wall-time budget; returns the exit code."""
    import torch

    from agents.evaluation import score
    from agents.interrupts import EXIT_CODES, Interrupts, WallBudget, stop_reason
    from agents.sb3.batched import batched_vec_env
    from agents.sb3.recurrent_student import save_student
    from swarm_core.atomic_files import write_json_atomically

    config, meta, model, space = start.config, start.meta, start.model, start.space
    env_kwargs, train_kwargs = start.env_kwargs, start.train_kwargs
    val_seeds, phases = list(config.val_seeds), list(config.phases)
    val_text = format_seeds(config.val_seeds)
    vec_kwargs = {
        "residual": meta["base"],
        "residual_observes_base": True,
        "critic_state": True,
    }
    vec = batched_vec_env(
        train_kwargs, config.n_copies, None, n_workers=config.num_cpus, **vec_kwargs
    )
    try:  # the workers end with the run, whatever ends it
        out = start.out
        out.mkdir(parents=True, exist_ok=True)
        log_std = torch.nn.Parameter(torch.full((2,), float(config.log_std)))
        critic = new_critic(space, vec.critic_dims)
        actor_optim = torch.optim.Adam([*model.parameters(), log_std], lr=config.learning_rate)
        critic_optim = torch.optim.Adam(critic.parameters(), lr=config.critic_learning_rate)
        generator = torch.Generator().manual_seed(config.fit_seed)
        rng = np.random.default_rng(config.fit_seed)
        extra = {
            "teacher": meta.get("teacher"),
            "start_student": str(config.student) if config.student else f"zero:{config.base}",
            "reward_task_params": config.task_params,
            "fit_seed": config.fit_seed,
        }
        budget = WallBudget(config.max_wall_s)  # as in every trainer, the base's scoring counts
        log: dict[str, Any] = {
            "config": dataclasses.asdict(config),
            "env_kwargs": env_kwargs,
            "train_task_params": train_kwargs["task_params"],
            "base": meta["base"],
            "val_seeds": val_seeds,
            "phases": phases,
            "base_val": score(meta["base"], env_kwargs, val_seeds, phases=phases)["mean"],
            "iterations": [],
            "val": [],
        }

        def save_and_score(iteration: int) -> None:
            path = out / f"student_it{iteration}.pt"
            save_student(path, model, env_kwargs, meta["base"], iteration=iteration, **extra)
            val = score(str(path), env_kwargs, val_seeds, phases=phases)["mean"]
            torch.set_num_threads(config.torch_threads)
            log["val"].append({"iteration": iteration, **val})
            if log["iterations"]:
                write_json_atomically(out / "train_log.json", log, indent=1)
                plot_ppo_logs([out / "train_log.json"], out / "train_log.png")
            print(
                f"iteration {iteration}: on {val_text} {val['formation_error_m']:.4f} m "
                f"(base {log['base_val']['formation_error_m']:.4f} m)",
                flush=True,
            )

        iteration = completed = 0
        start = time.perf_counter()
        with Interrupts() as interrupts:
            with interrupts.caught():
                save_and_score(0)
                for iteration in range(1, config.iterations + 1):
                    if interrupts.received:  # a signal that landed in a C callback was dropped
                        raise KeyboardInterrupt
                    t0 = time.perf_counter()
                    first = config.train_seeds_start + (iteration - 1) * config.n_copies
                    seeds = list(range(first, first + config.n_copies))
                    model.eval()
                    data = rollout(vec, model, log_std, seeds, generator)
                    t1 = time.perf_counter()
                    values, last_values = _values(critic, data, model.encoder_obs_dim)
                    batch = _batch(data, values, last_values, config)
                    warm = iteration <= config.critic_warmup
                    model.train()
                    stats = ppo_update(
                        model,
                        log_std,
                        critic,
                        None if warm else actor_optim,
                        critic_optim,
                        batch,
                        config.epochs,
                        config.batch_sequences,
                        config.clip_range,
                        config.target_kl,
                        rng,
                    )
                    model.eval()
                    # The critic block's first task feature is each agent's true shape error.
                    n = vec.agents_per_copy
                    shape_error = data["obs"][..., model.encoder_obs_dim + 2 + 2 * (n - 1)]
                    log["iterations"].append(
                        {
                            "iteration": iteration,
                            "seeds": seeds,
                            "critic_only": warm,
                            "return_per_agent": float(data["rewards"].sum(0).mean()),
                            "formation_error_m": float(shape_error.mean()),
                            "log_std": log_std.detach().tolist(),
                            "rollout_s": t1 - t0,
                            "update_s": time.perf_counter() - t1,
                            **stats,
                        }
                    )
                    completed = iteration
                    write_json_atomically(out / "train_log.json", log, indent=1)
                    if iteration % config.eval_every == 0 or iteration == config.iterations:
                        save_and_score(iteration)
                    if iteration < config.iterations and budget.passed():
                        break
            interrupted = interrupts.received
            with Interrupts(ignore=True):  # a second signal must not leave a half-written file
                model.eval()
                # After an interrupt the weights are those of the last completed iteration plus
                # whatever part of the next one's update ran (``interrupted_in``).
                stopped = {"interrupted_in": iteration} if interrupted else {}
                save_student(
                    out / "student.pt",
                    model,
                    env_kwargs,
                    meta["base"],
                    iteration=completed,
                    **stopped,
                    **extra,
                )
                log["wall_s"] = time.perf_counter() - start
                log["interrupted"] = interrupted
                log["stopped"] = stop_reason(interrupted, budget)
                write_json_atomically(out / "train_log.json", log, indent=1)
        if interrupted:
            print(
                f"recurrent_ppo: {interrupted} in iteration {iteration} ({completed} completed): "
                f"saved {out / 'student.pt'}",
                file=sys.stderr,
            )
            return EXIT_CODES[interrupted]
        why = " (wall-time budget)" if budget.reached else ""
        print(f"{completed} iterations in {log['wall_s']:.0f} s{why} -> {out / 'student.pt'}")
        return 0
    finally:
        with Interrupts(ignore=True):  # a second signal must not leave workers behind
            vec.close()
