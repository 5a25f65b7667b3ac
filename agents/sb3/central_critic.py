"""A centralised critic: the value function also reads the true state; the policy never does.

Asymmetric actor-critic (Pinto et al. 2018, "Asymmetric Actor Critic for Image-Based Robot
Learning"; MAPPO's centralised value function, Yu et al. 2022): in simulation the critic may use
information no robot has, because only the actor is deployed. PPO's advantages are then computed
against a value function that knows where the teammates truly are, instead of one that has to
guess the return from the robot's own noisy estimate (measured: a value
function on the PHD observation explained 0.2-0.6 of the return's variance).

Training (``swarm-phd train --critic-state``, batched VecEnv only) appends a critic block to
each agent's observation, after the actor's part::

    [ actor observation (D) | critic state (P) ]
    critic state = [ teammates' true body-frame xy (N - 1, 2), nearest first  (metres)
                   | task.critic_features(truth) (F) ]                 P = 2 (N - 1) + F

:class:`CentralCriticPolicy`'s actor reads the first ``D`` entries only (its extractor drops the
tail, so its output cannot depend on it: ``tests/agents/test_central_critic.py``); the critic
reads both. A deployed policy (:class:`agents.sb3.policy.SB3Policy`) pads the observation with
``P`` zeros, which the actor ignores; no ground truth is needed on a real robot.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, MlpExtractor
from torch import nn

from agents.sb3.features import NeighbourSetExtractor
from swarm_core.world import GroundTruth

__all__ = ["CentralCriticPolicy", "critic_state", "critic_state_dims"]


def critic_state_dims(n_agents: int, task: Any) -> int:
    """``P``: the critic block's width for ``n_agents`` robots and ``task``."""
    return 2 * (n_agents - 1) + int(task.n_critic_features)


def critic_state(truth: GroundTruth, task: Any, n_agents: int) -> np.ndarray:
    """The critic block of every agent, shape (n_agents, P) float32 (module doc).

    Teammates are the other agents (a task's extra robots, e.g. an intruder, are not listed),
    sorted by true distance so that the block does not depend on the robots' names."""
    rel = truth.relative_xy[:n_agents, :n_agents]  # (N, N, 2), rel[i, j] in i's frame
    dist = np.hypot(rel[..., 0], rel[..., 1])
    np.fill_diagonal(dist, np.inf)  # self last, then dropped
    order = np.argsort(dist, axis=1, kind="stable")[:, : n_agents - 1]
    teammates = np.take_along_axis(rel, order[..., None], axis=1).reshape(n_agents, -1)
    task_part = np.asarray(task.critic_features(truth), dtype=np.float64)[:n_agents]
    return np.concatenate([teammates, task_part], axis=1).astype(np.float32)


class CriticStateExtractor(BaseFeaturesExtractor):
    """The critic's features: the actor's Deep Sets features of the first ``D`` entries,
    concatenated with an MLP code of the ``P``-wide critic block (positions / 2 m)."""

    def __init__(self, observation_space, top_k: int, critic_dims: int, hidden: int = 64):
        sets = NeighbourSetExtractor(observation_space, top_k=top_k, critic_dims=critic_dims)
        super().__init__(observation_space, features_dim=sets.features_dim + hidden)
        self.sets = sets
        self.critic_dims = critic_dims
        self.state_net = nn.Sequential(
            nn.Linear(critic_dims, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        state = obs[:, -self.critic_dims :] / 2.0
        return torch.cat([self.sets(obs), self.state_net(state)], dim=1)


class SplitMlpExtractor(nn.Module):
    """SB3's ``MlpExtractor`` contract (``forward_actor``, ``forward_critic``, latent
    sizes) for an actor and a critic whose feature vectors differ in width."""

    def __init__(self, pi_dim: int, vf_dim: int, net_arch: Any, activation_fn, device):
        super().__init__()
        arch = net_arch if isinstance(net_arch, dict) else {"pi": net_arch, "vf": net_arch}
        actor = MlpExtractor(pi_dim, {"pi": arch["pi"], "vf": []}, activation_fn, device)
        critic = MlpExtractor(vf_dim, {"pi": [], "vf": arch["vf"]}, activation_fn, device)
        self.policy_net = actor.policy_net
        self.value_net = critic.value_net
        self.latent_dim_pi = actor.latent_dim_pi
        self.latent_dim_vf = critic.latent_dim_vf

    def forward(self, features):  # pragma: no cover - separate extractors never call it
        raise RuntimeError("the actor and the critic read different features")

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class CentralCriticPolicy(ActorCriticPolicy):
    """SB3 actor-critic whose actor reads the robot's observation (Deep Sets over its
    estimate table) and whose critic also reads the trailing ``critic_dims`` entries
    (module doc). Extractors are never shared."""

    def __init__(
        self,
        observation_space,
        action_space,
        lr_schedule,
        critic_dims: int,
        top_k: int = 16,
        **kwargs: Any,
    ) -> None:
        if isinstance(critic_dims, bool) or not isinstance(critic_dims, int) or critic_dims < 1:
            raise ValueError(f"critic_dims must be an int >= 1, got {critic_dims!r}")
        self.critic_dims = critic_dims
        self.top_k = top_k
        kwargs.update(
            share_features_extractor=False,
            features_extractor_class=NeighbourSetExtractor,
            features_extractor_kwargs={"top_k": top_k, "critic_dims": critic_dims},
        )
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        # Called by ActorCriticPolicy._build before the heads, the initialisation and the
        # optimizer, so the critic's extractor is initialised and trained like SB3's own.
        self.vf_features_extractor = CriticStateExtractor(
            self.observation_space, self.top_k, self.critic_dims
        )
        self.mlp_extractor = SplitMlpExtractor(
            self.pi_features_extractor.features_dim,
            self.vf_features_extractor.features_dim,
            self.net_arch,
            self.activation_fn,
            self.device,
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(critic_dims=self.critic_dims, top_k=self.top_k)
        data.pop("features_extractor_class", None)
        data.pop("features_extractor_kwargs", None)
        return data
