"""Warm start of a PPO policy from a scripted controller (behaviour cloning, optionally DAgger).

``swarm-phd train ... --warm-start scripted:formation --bc-steps 40000`` runs, before PPO:

1. **Demonstrations.** ``K`` env copies in one :class:`~agents.sb3.batched.BatchedSwarmVecEnv`
   (one filter call for all robots of all copies), each copy driven by its own instance of the
   teacher (the scripted controllers keep per-agent state keyed by agent name). Every agent
   transition gives a pair ``(observation, teacher action / [v_max, omega_max])``: the policy's
   own observation and the teacher's command in the policy's ``[-1, 1]^2`` action units.
2. **Fit.** The actor (its features extractor, policy MLP and ``action_net``) is fitted to the
   pairs by least squares on the Gaussian's *mean*, ``min sum ||mu(o) - a*||^2`` (the maximum
   likelihood fit of a fixed-variance Gaussian), with Adam and minibatches. The action
   log-standard-deviation is then set to ``log_std`` (small: PPO's exploration noise around
   the cloned controller, not around a random one).
3. **DAgger** (``--bc-rounds R > 1``, Ross et al. 2011): rounds ``2..R`` are driven by the
   current cloned policy (deterministic) and still labelled by the teacher, so the data covers
   the states the learner itself reaches; the actor is refitted on the aggregate.

The teacher also reads its lidar scan (obstacle avoidance) and random-walks when it sees nobody;
neither is in the policy's observation, so the clone reproduces the teacher where the PHD table
decides the action and averages over the rest. :func:`fit_report` measures how closely.

**Residual distillation** (``residual="scripted:NAME"``, ``swarm-phd train --residual ...
--warm-start TEACHER``): the copies run as a residual VecEnv, and the label is the correction
that turns the scripted base's command into the teacher's, ``clip((teacher - base) / high,
-1, 1)`` (exact while the two differ by at most ``high`` per component), and 0 where the
teacher random-walks (:attr:`~agents.scripted.ScriptedPolicy.wandering`: its random walk is
drawn from its own generator, not the base's); the fitted actor is that correction. The
action log-std after the fit is ``--bc-log-std`` (it replaces ``--residual-log-std``). With a
privileged teacher (``privileged:NAME``, :mod:`agents.sb3.privileged`, which reads ground
truth) the student learns from its own observation what the teacher knows from the truth.

Demonstration copy ``k`` of round ``r`` is seeded ``10_000 + 100 * (1000 * seed + r) + k`` (the
held-out fit episodes use ``r = 999``; each copy's later episodes continue its own generator).
For ``seed >= 0`` (numpy refuses negative seeds), ``n_copies <= 100`` and ``rounds <= 999``
(both enforced) these first-episode seeds are pairwise distinct (``k < 100`` stays inside its
round's block of 100, ``r <= 999`` inside its seed's block of 100 000) and all
``>= 10 000 + 100 000 seed``: disjoint from the held-out evaluation seeds (100-109) and from the
training copies' ``seed + k`` whenever training runs fewer than 10 000 copies.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "Demonstrations",
    "collect_demonstrations",
    "fit_actor",
    "actor_mean",
    "correction_labels",
    "fit_report",
    "warm_start",
    "DEMO_SEED_BASE",
]

DEMO_SEED_BASE = 10_000


@dataclass
class Demonstrations:
    """Teacher-labelled agent transitions.

    ``obs`` (M, D) float32: the policy's observations; ``actions`` (M, 2) float32: the teacher's
    commands divided by ``[v_max, omega_max]`` and clipped to ``[-1, 1]``.
    """

    obs: np.ndarray
    actions: np.ndarray

    def __len__(self) -> int:
        return len(self.obs)

    def __add__(self, other: Demonstrations) -> Demonstrations:
        return Demonstrations(
            np.concatenate([self.obs, other.obs]), np.concatenate([self.actions, other.actions])
        )


def collect_demonstrations(
    env_kwargs: dict[str, Any],
    teacher: str,
    n_transitions: int,
    *,
    n_copies: int = 4,
    seed: int = 0,
    learner: Any = None,
    residual: str | None = None,
    residual_observes_base: bool = False,
) -> Demonstrations:
    """Roll out ``n_copies`` batched copies for ``ceil(n_transitions / agents)`` steps.

    Parameters
    ----------
    env_kwargs : dict
        As for :func:`swarm_env.parallel_env` (the training env).
    teacher : str
        ``"scripted:NAME"`` (see :data:`agents.policies.SCRIPTED`) or ``"privileged:NAME"``
        (:data:`agents.sb3.privileged.TEACHERS`); labels every transition.
    n_transitions : int
        Agent transitions to collect (>= 1).
    learner : callable ``(obs (B, D) float32) -> actions (B, 2)`` in unit scale, optional
        Drives the copies instead of the teacher (DAgger); the teacher still labels.
    residual, residual_observes_base
        Residual distillation (module doc): the copies run with this scripted base (and its
        command in the observation); labels are corrections ``(teacher - base) / high``.

    Returns
    -------
    Demonstrations with ``ceil(n_transitions / (n_copies * n_robots)) * n_copies * n_robots``
    rows.
    """
    from agents.sb3.batched import BatchedSwarmVecEnv
    from agents.sb3.privileged import load_teacher

    if not isinstance(teacher, str) or not teacher.startswith(("scripted:", "privileged:")):
        raise ValueError(
            f"warm start teacher must be 'scripted:NAME' or 'privileged:NAME', got {teacher!r}"
        )
    if isinstance(n_transitions, bool) or not isinstance(n_transitions, int) or n_transitions < 1:
        raise ValueError(f"bc steps must be an int >= 1, got {n_transitions!r}")
    if isinstance(n_copies, bool) or not isinstance(n_copies, int) or not 1 <= n_copies <= 100:
        # More copies would run into the next round's block of seeds (module docstring).
        raise ValueError(f"warm start n_copies must be an int in [1, 100], got {n_copies!r}")
    venv = BatchedSwarmVecEnv(
        env_kwargs,
        n_copies,
        seed=DEMO_SEED_BASE + 100 * seed,
        residual=residual,
        residual_observes_base=residual_observes_base,
    )
    try:
        n = venv.agents_per_copy
        d_env = venv.envs[0].observation_space(venv.envs[0].possible_agents[0]).shape[0]
        teachers = [load_teacher(teacher, env) for env in venv.envs]
        rng = np.random.default_rng(DEMO_SEED_BASE + 100 * seed)
        for t in teachers:
            t.reset(int(rng.integers(2**31)))
        high = venv.action_high
        obs = venv.reset()
        n_steps = -(-n_transitions // venv.num_envs)
        all_obs, all_act = [], []
        for _ in range(n_steps):
            labels = np.zeros((venv.num_envs, 2), np.float32)
            for k, env in enumerate(venv.envs):
                rows = obs[k * n : (k + 1) * n, :d_env]  # the env's own observation
                act = teachers[k](dict(zip(env.agents, rows, strict=True)), venv.copy_infos(k))
                if residual is None:  # the teacher's command, in unit scale
                    unit = np.array([act[a] for a in env.agents], np.float32) / high
                    labels[k * n : (k + 1) * n] = np.clip(unit, -1.0, 1.0)
                else:
                    labels[k * n : (k + 1) * n] = correction_labels(
                        act, venv.scripted_commands(k), teachers[k].wandering, env.agents, high
                    )
            all_obs.append(obs.astype(np.float32))
            all_act.append(labels)
            drive = labels if learner is None else np.asarray(learner(obs), np.float32)
            obs, _, dones, _ = venv.step(drive)
            for k in range(len(venv.envs)):
                if dones[k * n]:  # the copy was reset: a fresh episode for its teacher
                    teachers[k].reset(int(rng.integers(2**31)))
        return Demonstrations(np.concatenate(all_obs), np.concatenate(all_act))
    finally:
        venv.close()


def correction_labels(
    teacher: dict[str, Any],
    base: dict[str, Any],
    wandering: Any,
    agents: list[str],
    high: np.ndarray,
) -> np.ndarray:
    """Residual distillation labels (A, 2) for ``agents``: the correction that turns the base's
    command into the teacher's, ``clip((teacher - base) / high, -1, 1)`` (commands
    ``[v_mps, omega_radps]``; ``high`` their bounds), and 0 for the agents in ``wandering``:
    where the teacher random-walks it draws from its own generator, not the base's, so there
    is no correction to learn."""
    # float32 before the division, as the labels of every earlier round were computed.
    out = np.array(
        [np.zeros(2) if a in wandering else np.subtract(teacher[a], base[a]) for a in agents],
        dtype=np.float32,
    ).reshape(len(agents), 2)
    return np.clip(out / high, -1.0, 1.0).astype(np.float32)


def actor_mean(policy: Any, obs: Any) -> Any:
    """The Gaussian's mean ``mu(o)`` of an SB3 ``ActorCriticPolicy`` (torch, (B, 2))."""
    from stable_baselines3.common.preprocessing import preprocess_obs

    # The actor's own extractor (shared with the critic or not: SB3's extract_features returns
    # both extractors' features when they are separate).
    x = preprocess_obs(obs, policy.observation_space, normalize_images=policy.normalize_images)
    features = policy.pi_features_extractor(x)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))


def fit_actor(
    policy: Any,
    demos: Demonstrations,
    *,
    epochs: int = 30,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    log_std: float | None = -1.5,
    obs_transform: Any = None,
    seed: int = 0,
) -> list[float]:
    """Least-squares fit of the actor's mean to ``demos``; returns the loss per epoch.

    Only the actor's parameters move (features extractor of the actor, policy MLP,
    ``action_net``); the value head is left to PPO. ``obs_transform`` maps raw observations to
    what the policy sees (VecNormalize's normalisation for the MLP extractor).
    """
    import torch

    if len(demos) == 0:
        raise ValueError("no demonstrations to fit")
    obs = demos.obs if obs_transform is None else obs_transform(demos.obs)
    x = torch.as_tensor(np.asarray(obs, np.float32))
    y = torch.as_tensor(demos.actions)
    params = _actor_parameters(policy)
    opt = torch.optim.Adam(params, lr=learning_rate)
    gen = torch.Generator().manual_seed(seed)
    losses = []
    policy.set_training_mode(True)
    for _ in range(epochs):
        order = torch.randperm(len(x), generator=gen)
        total = 0.0
        for start in range(0, len(x), batch_size):
            idx = order[start : start + batch_size]
            loss = ((actor_mean(policy, x[idx]) - y[idx]) ** 2).sum(dim=1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        losses.append(total / len(x))
    policy.set_training_mode(False)
    if log_std is not None:
        with torch.no_grad():
            policy.log_std.fill_(float(log_std))
    return losses


def _actor_parameters(policy: Any) -> list[Any]:
    """The actor's parameters (deduplicated: a shared extractor appears once)."""
    modules = [policy.pi_features_extractor, policy.mlp_extractor.policy_net, policy.action_net]
    if getattr(policy, "lstm_actor", None) is not None:  # a recurrent policy's actor memory
        modules.append(policy.lstm_actor)
    seen, params = set(), []
    for m in modules:
        for p in m.parameters():
            if id(p) not in seen:
                seen.add(id(p))
                params.append(p)
    return params


def actor_parameters(policy: Any) -> list[Any]:
    """Actor parameters plus the action log-std: what the critic warm-up freezes."""
    return [*_actor_parameters(policy), policy.log_std]


def fit_report(policy: Any, demos: Demonstrations, obs_transform: Any = None) -> dict[str, float]:
    """How closely the clone reproduces the teacher on ``demos`` (unit action scale).

    ``rmse``: per action dimension, of ``clip(mu(o)) - a*``; ``baseline_rmse``: of the best
    constant (the labels' mean), so ``r2 = 1 - (rmse / baseline_rmse)^2`` per dimension.
    """
    import torch

    obs = demos.obs if obs_transform is None else obs_transform(demos.obs)
    with torch.no_grad():
        mu = actor_mean(policy, torch.as_tensor(np.asarray(obs, np.float32))).numpy()
    err = np.clip(mu, -1.0, 1.0) - demos.actions
    rmse = np.sqrt((err**2).mean(axis=0))
    base = demos.actions.std(axis=0)
    r2 = 1.0 - (rmse / np.maximum(base, 1e-9)) ** 2
    return {
        "n": int(len(demos)),
        "rmse_v": float(rmse[0]),
        "rmse_omega": float(rmse[1]),
        "baseline_rmse_v": float(base[0]),
        "baseline_rmse_omega": float(base[1]),
        "r2_v": float(r2[0]),
        "r2_omega": float(r2[1]),
    }


def warm_start(
    policy: Any,
    env_kwargs: dict[str, Any],
    teacher: str,
    n_transitions: int,
    *,
    rounds: int = 1,
    n_copies: int = 4,
    seed: int = 0,
    epochs: int = 30,
    log_std: float = -1.5,
    obs_transform: Any = None,
    observe: Any = None,
    holdout_fraction: float = 0.1,
    residual: str | None = None,
    residual_observes_base: bool = False,
) -> dict[str, Any]:
    """Collect, fit (and, for ``rounds > 1``, DAgger); return a summary with the fit report on
    held-out demonstrations (a fresh episode set collected under the teacher).

    ``observe(obs (M, D))``, if given, sees every round's raw observations before the fit (to
    update VecNormalize's running statistics that ``obs_transform`` then applies).
    ``residual``, ``residual_observes_base``: residual distillation (module doc)."""
    import torch

    if isinstance(rounds, bool) or not isinstance(rounds, int) or not 1 <= rounds <= 999:
        # Round 999's seeds are the held-out episodes' (module docstring).
        raise ValueError(f"bc rounds must be an int in [1, 999], got {rounds!r}")
    if not 0.0 < holdout_fraction < 1.0:
        raise ValueError(f"holdout_fraction must be in (0, 1), got {holdout_fraction!r}")
    per_round = max(1, n_transitions // rounds)

    def learner(obs: np.ndarray) -> np.ndarray:
        o = obs if obs_transform is None else obs_transform(obs)
        with torch.no_grad():
            return actor_mean(policy, torch.as_tensor(np.asarray(o, np.float32))).numpy()

    data: Demonstrations | None = None
    losses: list[list[float]] = []
    for r in range(rounds):
        new = collect_demonstrations(
            env_kwargs,
            teacher,
            per_round,
            n_copies=n_copies,
            seed=seed * 1000 + r,  # each round its own episodes
            learner=None if r == 0 else learner,
            residual=residual,
            residual_observes_base=residual_observes_base,
        )
        data = new if data is None else data + new
        if observe is not None:
            observe(new.obs)
        losses.append(
            fit_actor(
                policy, data, epochs=epochs, log_std=log_std, obs_transform=obs_transform, seed=r
            )
        )
    held = collect_demonstrations(
        env_kwargs,
        teacher,
        max(1, int(holdout_fraction * n_transitions)),
        n_copies=n_copies,
        seed=seed * 1000 + 999,
        residual=residual,
        residual_observes_base=residual_observes_base,
    )
    assert data is not None
    return {
        "teacher": teacher,
        "residual": residual,
        "transitions": len(data),
        "rounds": rounds,
        "final_loss": losses[-1][-1],
        "train_fit": fit_report(policy, data, obs_transform),
        "holdout_fit": fit_report(policy, held, obs_transform),
        "log_std": log_std,
    }
