"""TorchRL's door: the swarm as a TorchRL env through ``torchrl.envs.PettingZooWrapper``.

>>> from agents.torchrl_env import make_torchrl_env
>>> env = make_torchrl_env(preset="lab-3m-4", task="formation", max_steps=200, seed=0)
>>> env.group_map
{'ugv': ['ugv_0', 'ugv_1', 'ugv_2', 'ugv_3']}
>>> td = env.rollout(10)          # td["ugv", "observation"]: (10, 4, obs_dim)

All robots share one group (``"ugv"``): their tensors are stacked along an agent dimension, what
TorchRL's multi-agent modules (``MultiAgentMLP``) and losses expect. Actions are continuous
``[v_mps, omega_radps]`` per robot (``full_action_spec["ugv", "action"]``, the env's bounds);
``"state"`` is the env's global ground-truth state (:meth:`SwarmEnv.state`) for centralised
critics. The episode ends for all robots at once (truncation at ``max_steps``, or the task's
termination), so no agent mask is needed.

TorchRL stacks every ``info`` entry into a tensor of fixed shape; the env's infos also carry
nested records of variable length (measurements, truth), so :class:`NumericInfos` passes only
the numeric scalars (``time_s``) on. Needs the ``marl`` extra (``pip install
"swarm-phd[marl]"``: torchrl and tensordict).
"""

from __future__ import annotations

import numbers
from typing import Any

from pettingzoo.utils.wrappers import BaseParallelWrapper

#: The one agent group every robot belongs to.
GROUP = "ugv"


class NumericInfos(BaseParallelWrapper):
    """A parallel env whose per-agent infos keep only their numeric scalar entries (``time_s``
    for :class:`~swarm_env.env.SwarmEnv`), which TorchRL can stack into tensors."""

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        self.metadata = env.metadata
        self.possible_agents = list(env.possible_agents)

    @property
    def agents(self) -> list[str]:  # type: ignore[override]
        return self.env.agents

    @property
    def render_mode(self) -> str | None:  # type: ignore[override]
        return self.env.render_mode

    @property
    def state_space(self) -> Any:
        return self.env.state_space

    @staticmethod
    def _numeric(infos: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        return {
            agent: {
                k: v
                for k, v in info.items()
                if isinstance(v, numbers.Real) and not isinstance(v, bool)
            }
            for agent, info in infos.items()
        }

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs, self._numeric(infos)

    def step(self, actions: dict[str, Any]):
        obs, rewards, terms, truncs, infos = self.env.step(actions)
        return obs, rewards, terms, truncs, self._numeric(infos)


def make_torchrl_env(
    preset: str = "lab-3m-4",
    task: str = "formation",
    *,
    seed: int | None = None,
    device: str = "cpu",
    return_state: bool = True,
    **env_kwargs: Any,
):
    """The swarm (:func:`swarm_env.parallel_env` of ``preset`` and ``task`` with
    ``env_kwargs``: ``max_steps``, ``task_params``, ``localizer``, config overrides) wrapped
    by TorchRL's ``PettingZooWrapper``, every robot in group :data:`GROUP`. ``seed`` seeds its
    first reset (TorchRL reseeds later resets from its own generator)."""
    try:
        from torchrl.envs import PettingZooWrapper
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError(
            'the TorchRL adapter needs torchrl: pip install "swarm-phd[marl]"'
        ) from exc
    import warnings

    from swarm_env import parallel_env

    env = NumericInfos(parallel_env(preset, task=task, **env_kwargs))
    with warnings.catch_warnings():
        # TorchRL warns that it was tested with another PettingZoo release; this adapter's
        # tests run it on the installed one.
        warnings.filterwarnings("ignore", message="PettingZoo in TorchRL is tested")
        return PettingZooWrapper(
            env,
            return_state=return_state,
            group_map={GROUP: list(env.possible_agents)},
            use_mask=False,
            categorical_actions=False,
            seed=seed,
            done_on_any=True,
            device=device,
        )
