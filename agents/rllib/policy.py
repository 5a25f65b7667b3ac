"""A policy trained by ``swarm-phd train --engine rllib``, as a plain callable.

RLlib saves the shared module under ``<out>/checkpoint/learner_group/learner/rl_module/shared``.
:func:`load_policy` loads it (torch, no Ray runtime needed) and acts deterministically: the mean
of the diagonal Gaussian the module outputs (its ``action_dist_inputs`` are ``[mean, log_std]``
per action dimension), clipped to ``[-1, 1]`` and scaled to ``[v_max, omega_max]`` by
:func:`agents.sb3.adapter.scale_actions`, as during training.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.rllib.env import SHARED_POLICY

#: Where the shared module sits inside an Algorithm checkpoint.
MODULE_SUBDIR = Path("learner_group") / "learner" / "rl_module" / SHARED_POLICY


def module_path(checkpoint: str | Path) -> Path:
    """The shared module's directory of an Algorithm checkpoint (or the module dir itself)."""
    path = Path(checkpoint)
    if (path / MODULE_SUBDIR).is_dir():
        return path / MODULE_SUBDIR
    if (path / "module_state.pkl").exists() or (path / "module_state.pt").exists():
        return path
    raise ValueError(f"checkpoint has no RLlib module '{MODULE_SUBDIR}': {str(path)!r}")


class RLlibPolicy:
    """``policy(observations) -> actions``, both ``{agent: array}``; one batched forward pass
    per call for all agents.

    Parameters
    ----------
    checkpoint : path
        ``<out>/checkpoint`` of a run (or the module directory).
    action_high : array_like, shape (2,)
        ``[v_max_mps, omega_max_radps]`` of the env the actions go to.
    """

    def __init__(self, checkpoint: str | Path, action_high: Any) -> None:
        from ray.rllib.core.rl_module.rl_module import RLModule

        self.module = RLModule.from_checkpoint(str(module_path(checkpoint).resolve()))
        self.high = np.asarray(action_high, dtype=np.float64).reshape(2)
        self.obs_dim = int(np.prod(self.module.observation_space.shape))

    def __call__(self, observations: dict[str, np.ndarray], infos: Any = None) -> dict:
        import torch

        from agents.sb3.adapter import scale_actions

        agents = list(observations)
        if not agents:
            return {}
        obs = np.stack([np.asarray(observations[a], dtype=np.float32) for a in agents])
        if obs.shape[1:] != (self.obs_dim,):
            raise ValueError(
                f"observations must have {self.obs_dim} values per agent, got {obs.shape[1:]}"
            )
        with torch.no_grad():
            out = self.module.forward_inference({"obs": torch.from_numpy(obs)})
        mean = out["action_dist_inputs"].numpy()[:, : self.high.size]  # [mean, log_std]
        return {a: scale_actions(mean[k], self.high) for k, a in enumerate(agents)}


def load_policy(checkpoint: str | Path, env: Any) -> RLlibPolicy:
    """:class:`RLlibPolicy` for ``env`` (a SwarmEnv: its action bounds scale the actions)."""
    agent = env.possible_agents[0]
    return RLlibPolicy(checkpoint, env.action_space(agent).high)
