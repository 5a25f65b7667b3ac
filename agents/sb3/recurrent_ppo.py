"""PPO fine-tuning of a recurrent residual student (:mod:`agents.sb3.recurrent_student`).

    python -m agents.sb3.recurrent_ppo --student runs/recurrent/student_round3.pt \
        --task-params '{"progress_weight": 10}' --out runs/recurrent_ppo

A DAgger student imitates its teacher; this lets the task's reward (and a localization term,
``--task-params '{"localization_weight": 2, "localization_term": "estimate"}'``) move it.
Without a DAgger student, ``--base scripted:NAME --env-from runs/x/student.pt`` starts from a
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
  Reinforcement Learning"). Until round 21 it was the critic's value at a fraction left of 0,
  an input it was never trained on.
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

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm_core.atomic_files import atomic_write
from swarm_phd import inputs

__all__ = ["gae", "main", "new_critic", "plot_ppo_logs", "ppo_update", "rollout"]


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


def _batch(data: dict[str, np.ndarray], values: np.ndarray, last_values: np.ndarray, args):
    """The rollout as sequence-first torch tensors with its advantages and value targets."""
    import torch

    adv, returns = gae(data["rewards"], values, last_values, args.gamma, args.gae_lambda)
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
        label = f"{Path(path).parent.name} (fit seed {log['args']['fit_seed']})"
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


def main(argv: list[str] | None = None) -> int:
    import argparse

    from agents.interrupts import add_max_wall_argument, max_wall_seconds
    from agents.sb3.distill_fit import DEFAULT_PHASES
    from agents.sb3.history_fit import parse_phases
    from swarm_phd.inputs import parse_json_object, parse_seeds

    parser = argparse.ArgumentParser(
        prog="python -m agents.sb3.recurrent_ppo",
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
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--n-copies", type=int, default=16, help="episodes per iteration")
    parser.add_argument(
        "--num-cpus",
        type=int,
        default=0,
        help="worker processes stepping the copies (0: in this process); the same rollouts",
    )
    parser.add_argument("--train-seeds-start", type=int, default=5000)
    parser.add_argument("--val-seeds", default="200-209")
    parser.add_argument("--eval-every", type=int, default=10, help="iterations between scores")
    parser.add_argument(
        "--phases",
        default=",".join(map(str, DEFAULT_PHASES)),
        help="comma-separated first steps of the scored phases",
    )
    parser.add_argument("--critic-warmup", type=int, default=3, help="critic-only iterations")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--batch-sequences", type=int, default=8)
    # The actor's step, set by the KL it makes (docs/results.md, round 19): from the round-18
    # student, 1e-4 reached an approximate KL of 0.21 in one pass (10x --target-kl), 1e-5
    # 0.0006 per iteration, 3e-5 0.002-0.03.
    parser.add_argument("--learning-rate", type=float, default=3e-5, help="the actor's")
    parser.add_argument("--critic-learning-rate", type=float, default=1e-3)
    parser.add_argument("--clip-range", type=float, default=0.1)
    parser.add_argument("--target-kl", type=float, default=0.02)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--gae-lambda", type=float, default=0.95)
    parser.add_argument("--log-std", type=float, default=-2.5, help="initial, unit scale")
    parser.add_argument("--fit-seed", type=int, default=0, help="torch, noise and minibatches")
    parser.add_argument("--torch-threads", type=int, default=1)
    add_max_wall_argument(parser, "after the iteration in which")
    args = parser.parse_args(argv)
    checks = (
        ("--iterations", args.iterations, 1),
        ("--n-copies", args.n_copies, 1),
        ("--num-cpus", args.num_cpus, 0),
        ("--eval-every", args.eval_every, 1),
        ("--critic-warmup", args.critic_warmup, 0),
        ("--epochs", args.epochs, 1),
        ("--batch-sequences", args.batch_sequences, 1),
        ("--torch-threads", args.torch_threads, 1),
        ("--fit-seed", args.fit_seed, 0),
        ("--train-seeds-start", args.train_seeds_start, 0),
    )
    for flag, value, low in checks:
        if value < low:
            parser.error(f"{flag} must be >= {low}, got {value}")
    if args.num_cpus > args.n_copies:
        parser.error(
            f"--num-cpus {args.num_cpus} exceeds --n-copies {args.n_copies}: each worker steps "
            "at least one copy"
        )
    for flag, value in (
        ("--learning-rate", args.learning_rate),
        ("--critic-learning-rate", args.critic_learning_rate),
        ("--clip-range", args.clip_range),
        ("--target-kl", args.target_kl),
    ):
        if not np.isfinite(value) or value <= 0:
            parser.error(f"{flag} must be a finite number > 0, got {value}")
    for flag, value in (("--gamma", args.gamma), ("--gae-lambda", args.gae_lambda)):
        if not 0 <= value <= 1:
            parser.error(f"{flag} must be in [0, 1], got {value}")
    if not np.isfinite(args.log_std):
        parser.error(f"--log-std must be finite, got {args.log_std}")
    try:
        max_wall_s = max_wall_seconds(args.max_wall_minutes)
        val_seeds = parse_seeds(args.val_seeds, "--val-seeds")
        reward_params = parse_json_object(args.task_params, "--task-params")
        meta = _start_metadata(parser, args)
    except ValueError as err:
        parser.error(str(err))
    for flag, read in (("--student", args.student), ("--env-from", args.env_from)):
        if read and Path(args.out).resolve() == Path(read).resolve().parent:
            parser.error(
                f"--out {args.out!r} holds {flag} {read!r}: its student.pt and "
                "train_log.json would be overwritten; give another directory"
            )
    train_end = args.train_seeds_start + args.iterations * args.n_copies
    overlap = sorted(set(val_seeds) & set(range(args.train_seeds_start, train_end)))
    if overlap:
        parser.error(f"--val-seeds share seeds with the training episodes: {overlap}")
    phases = parse_phases(parser, args.phases)
    try:  # before any env is built
        inputs.run_dir("--out", args.out, overwrite=args.overwrite)
    except ValueError as err:
        parser.error(str(err))
    return _train(parser, args, meta, reward_params, val_seeds, phases, max_wall_s)


def _start_metadata(parser, args) -> dict[str, Any]:
    """The starting student's metadata (``env_kwargs``, ``base``, ...): ``--student``'s, or for
    ``--base`` that base in ``--env-from``'s env (ValueError on a bad file or base)."""
    from agents.sb3.recurrent_student import read_student_metadata

    if args.student is not None:
        if args.env_from is not None:
            parser.error("--env-from goes with --base; a --student acts in its own env")
        return read_student_metadata(args.student)
    if args.env_from is None:
        parser.error("--base needs --env-from: the student's env (a .pt or .zip trained there)")
    from agents.policies import model_env_kwargs
    from agents.sb3.recurrent_student import check_student_env
    from agents.sb3.residual import check_residual

    check_residual(args.base, "--base")
    try:
        env_kwargs = model_env_kwargs(args.env_from)
    except ValueError as err:
        raise ValueError(f"--env-from: {err}") from err
    if env_kwargs is None:
        raise ValueError(
            f"--env-from must be a .pt student or a .zip model, got {args.env_from!r}"
        )
    check_student_env(env_kwargs, "--env-from")
    return {"env_kwargs": env_kwargs, "base": args.base}


def _start_flag(args) -> str:
    return f"--student {args.student!r}" if args.student else f"--env-from {args.env_from!r}"


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


def _train(parser, args, meta, reward_params, val_seeds, phases, max_wall_s) -> int:
    import torch

    from agents.interrupts import EXIT_CODES, Interrupts, WallBudget, stop_reason
    from agents.sb3.batched import batched_vec_env
    from agents.sb3.recurrent_student import load_student, save_student
    from agents.sb3.report import score
    from swarm_core.atomic_files import write_json_atomically
    from swarm_env import parallel_env

    env_kwargs = dict(meta["env_kwargs"])
    if env_kwargs.get("task") != "formation":  # its log and scores are formation's
        parser.error(
            f"{_start_flag(args)} acts on task {env_kwargs.get('task')!r}; recurrent "
            "PPO trains formation students"
        )
    train_kwargs = {
        **env_kwargs,
        "task_params": {**env_kwargs.get("task_params", {}), **reward_params},
    }
    probe = parallel_env(**env_kwargs)
    try:
        space = probe.observation_space(probe.possible_agents[0])
        features = probe.task.features(len(probe.possible_agents))
        torch.manual_seed(args.fit_seed)  # the zero student's hidden layers
        if args.student is not None:  # refuses a mismatched observation
            model = load_student(args.student, probe).model
        else:
            model = zero_student(space)
    finally:
        probe.close()
    torch.set_num_threads(args.torch_threads)  # loading a student set it to 1
    torch.manual_seed(args.fit_seed)
    try:  # a bad --task-params fails here, before any rollout or worker
        trained = parallel_env(**train_kwargs)
    except ValueError as err:
        parser.error(f"the training env with --task-params {json.dumps(reward_params)}: {err}")
    try:
        same = trained.observation_space(
            trained.possible_agents[0]
        ).shape == space.shape and np.array_equal(
            trained.task.features(len(trained.possible_agents)), features
        )
    finally:
        trained.close()
    if not same:
        parser.error(
            f"--task-params {json.dumps(reward_params)} changes what the student observes (its "
            "task's features or the observation's size); only the reward's terms may change"
        )
    vec_kwargs = {
        "residual": meta["base"],
        "residual_observes_base": True,
        "critic_state": True,
    }
    vec = batched_vec_env(train_kwargs, args.n_copies, None, n_workers=args.num_cpus, **vec_kwargs)
    try:  # the workers end with the run, whatever ends it
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        log_std = torch.nn.Parameter(torch.full((2,), float(args.log_std)))
        critic = new_critic(space, vec.critic_dims)
        actor_optim = torch.optim.Adam([*model.parameters(), log_std], lr=args.learning_rate)
        critic_optim = torch.optim.Adam(critic.parameters(), lr=args.critic_learning_rate)
        generator = torch.Generator().manual_seed(args.fit_seed)
        rng = np.random.default_rng(args.fit_seed)
        extra = {
            "teacher": meta.get("teacher"),
            "start_student": str(args.student) if args.student else f"zero:{args.base}",
            "reward_task_params": reward_params,
            "fit_seed": args.fit_seed,
        }
        budget = WallBudget(max_wall_s)  # as in every trainer, the base's scoring counts
        log: dict[str, Any] = {
            "args": vars(args),
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
            torch.set_num_threads(args.torch_threads)
            log["val"].append({"iteration": iteration, **val})
            if log["iterations"]:
                write_json_atomically(out / "train_log.json", log, indent=1)
                plot_ppo_logs([out / "train_log.json"], out / "train_log.png")
            print(
                f"iteration {iteration}: on {args.val_seeds} {val['formation_error_m']:.4f} m "
                f"(base {log['base_val']['formation_error_m']:.4f} m)",
                flush=True,
            )

        iteration = completed = 0
        start = time.perf_counter()
        with Interrupts() as interrupts:
            with interrupts.caught():
                save_and_score(0)
                for iteration in range(1, args.iterations + 1):
                    if interrupts.received:  # a signal that landed in a C callback was dropped
                        raise KeyboardInterrupt
                    t0 = time.perf_counter()
                    first = args.train_seeds_start + (iteration - 1) * args.n_copies
                    seeds = list(range(first, first + args.n_copies))
                    model.eval()
                    data = rollout(vec, model, log_std, seeds, generator)
                    t1 = time.perf_counter()
                    values, last_values = _values(critic, data, model.encoder_obs_dim)
                    batch = _batch(data, values, last_values, args)
                    warm = iteration <= args.critic_warmup
                    model.train()
                    stats = ppo_update(
                        model,
                        log_std,
                        critic,
                        None if warm else actor_optim,
                        critic_optim,
                        batch,
                        args.epochs,
                        args.batch_sequences,
                        args.clip_range,
                        args.target_kl,
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
                    if iteration % args.eval_every == 0 or iteration == args.iterations:
                        save_and_score(iteration)
                    if iteration < args.iterations and budget.passed():
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


if __name__ == "__main__":
    raise SystemExit(main())
