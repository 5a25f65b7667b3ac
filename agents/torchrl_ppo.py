"""MAPPO / IPPO on the swarm with TorchRL's own parts (the recipe of TorchRL's multi-agent PPO
tutorial): one policy shared by every robot (``MultiAgentMLP``, a Tanh-normal over the
velocity box), a critic that sees all robots' observations (MAPPO, ``centralised=True``) or
only its own (IPPO), GAE and the clipped PPO loss.

>>> from agents.torchrl_env import make_torchrl_env
>>> from agents.torchrl_ppo import train_ppo
>>> env = make_torchrl_env(preset="lab-3m-4", task="formation", max_steps=200, seed=0)
>>> result = train_ppo(env, total_frames=20_000, frames_per_batch=1_000, mappo=True)
>>> result.log[-1]["episode_reward_mean"]

TorchRL's collector closes the env it collected from once the budget is spent: run the trained
``result.policy`` (a TorchRL module) in a new env, ``make_torchrl_env(...).rollout(200,
policy=result.policy)`` (its mean action under ``torchrl.envs.utils.set_exploration_type(
ExplorationType.DETERMINISTIC)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agents.torchrl_env import GROUP
from swarm_core.validation import check_number


@dataclass
class PPOResult:
    """What :func:`train_ppo` returns: the trained ``policy`` (a ``ProbabilisticActor``),
    its ``critic`` and one log row per collected batch (frames so far, mean reward per agent
    and step, mean return of the episodes finished in the batch, losses)."""

    policy: Any
    critic: Any
    log: list[dict[str, float]] = field(default_factory=list)


def build_modules(env: Any, *, mappo: bool = True, hidden: int = 64, depth: int = 2):
    """The shared actor (observation -> Tanh-normal action within the env's action bounds)
    and the critic (centralised for MAPPO) of group :data:`GROUP` of ``env``."""
    import torch
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal

    n_agents = len(env.group_map[GROUP])
    obs_dim = env.observation_spec[GROUP, "observation"].shape[-1]
    action_spec = env.full_action_spec_unbatched[GROUP, "action"]
    act_dim = action_spec.shape[-1]
    device = env.device
    actor_net = torch.nn.Sequential(
        MultiAgentMLP(
            n_agent_inputs=obs_dim,
            n_agent_outputs=2 * act_dim,
            n_agents=n_agents,
            centralised=False,  # each robot acts on its own observation
            share_params=True,
            device=device,
            depth=depth,
            num_cells=hidden,
            activation_class=torch.nn.Tanh,
        ),
        NormalParamExtractor(),
    )
    actor = ProbabilisticActor(
        module=TensorDictModule(
            actor_net,
            in_keys=[(GROUP, "observation")],
            out_keys=[(GROUP, "loc"), (GROUP, "scale")],
        ),
        spec=action_spec,
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        return_log_prob=True,
    )
    critic_net = MultiAgentMLP(
        n_agent_inputs=obs_dim,
        n_agent_outputs=1,
        n_agents=n_agents,
        centralised=mappo,
        share_params=True,
        device=device,
        depth=depth,
        num_cells=hidden,
        activation_class=torch.nn.Tanh,
    )
    critic = TensorDictModule(
        critic_net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")]
    )
    return actor, critic


def train_ppo(
    env: Any,
    *,
    total_frames: int = 20_000,
    frames_per_batch: int = 1_000,
    minibatch_size: int = 250,
    epochs: int = 4,
    mappo: bool = True,
    lr: float = 3e-4,
    gamma: float = 0.99,
    lmbda: float = 0.95,
    clip_epsilon: float = 0.2,
    entropy_coef: float = 1e-3,
    max_grad_norm: float = 1.0,
    seed: int = 0,
) -> PPOResult:
    """Train MAPPO (``mappo=True``) or IPPO on a :func:`~agents.torchrl_env.make_torchrl_env`
    env for ``total_frames`` env steps, in batches of ``frames_per_batch`` (each reused for
    ``epochs`` passes of minibatches of ``minibatch_size`` steps). The collector closes ``env``
    at the end. ValueError for a budget that does not make one batch or a minibatch that does
    not divide it."""
    import torch
    from tensordict import TensorDict
    from torchrl.collectors import Collector
    from torchrl.data.replay_buffers import ReplayBuffer
    from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
    from torchrl.data.replay_buffers.storages import LazyTensorStorage
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    for name, value in (
        ("total_frames", total_frames),
        ("frames_per_batch", frames_per_batch),
        ("minibatch_size", minibatch_size),
        ("epochs", epochs),
    ):
        check_number(name, value, integer=True, low=1)
    if total_frames < frames_per_batch:
        raise ValueError(
            f"total_frames ({total_frames}) must be at least frames_per_batch ({frames_per_batch})"
        )
    if frames_per_batch % minibatch_size:
        raise ValueError(
            f"minibatch_size ({minibatch_size}) must divide frames_per_batch ({frames_per_batch})"
        )
    torch.manual_seed(seed)
    actor, critic = build_modules(env, mappo=mappo)
    collector = Collector(
        env,
        actor,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        device=env.device,
        storing_device=env.device,
    )
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames_per_batch, device=env.device),
        sampler=SamplerWithoutReplacement(),
        batch_size=minibatch_size,
    )
    loss = ClipPPOLoss(
        actor_network=actor,
        critic_network=critic,
        clip_epsilon=clip_epsilon,
        entropy_coeff=entropy_coef,
        normalize_advantage=False,
    )
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=(GROUP, "action"),
        value=(GROUP, "state_value"),
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=gamma, lmbda=lmbda)
    optimizer = torch.optim.Adam(loss.parameters(), lr)
    result = PPOResult(actor, critic)
    frames = 0
    returns = torch.zeros(len(env.group_map[GROUP]))
    try:
        for batch in collector:
            frames += batch.numel()
            with torch.no_grad():
                loss.value_estimator(
                    batch,
                    params=loss.critic_network_params,
                    target_params=loss.target_critic_network_params,
                )
            buffer.extend(batch.reshape(-1))
            totals: dict[str, float] = {}
            n_updates = 0
            for _ in range(epochs):
                for _ in range(frames_per_batch // minibatch_size):
                    parts: TensorDict = loss(buffer.sample())
                    total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                    total.backward()
                    torch.nn.utils.clip_grad_norm_(loss.parameters(), max_grad_norm)
                    optimizer.step()
                    optimizer.zero_grad()
                    for key in ("loss_objective", "loss_critic", "loss_entropy"):
                        totals[key] = totals.get(key, 0.0) + float(parts[key].detach())
                    n_updates += 1
            collector.update_policy_weights_()
            reward = batch["next", GROUP, "reward"]  # (T, agents, 1)
            done = batch["next", "done"].squeeze(-1)  # (T,)
            finished = []
            for t in range(reward.shape[0]):
                returns += reward[t, :, 0]
                if bool(done[t]):
                    finished.append(float(returns.mean()))
                    returns.zero_()
            row = {
                "frames": float(frames),
                "reward_mean": float(reward.mean()),
                "episode_reward_mean": (
                    sum(finished) / len(finished) if finished else float("nan")
                ),
                **{k: v / n_updates for k, v in totals.items()},
            }
            result.log.append(row)
    finally:
        collector.shutdown(close_env=False)  # the env stays the caller's
    return result
