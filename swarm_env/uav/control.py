"""Scripted UAV controllers and the per-type views used to train one agent type at a time.

Parameter sharing in :class:`~swarm_env.uav.env.SupervisedSwarmEnv` is per agent type: the UGVs
are interchangeable (same spaces, same role), the UAV is not. Libraries that share one policy
across all agents of a ParallelEnv (SB3 through SuperSuit, this project's ``agents.sb3``) need
agents with one space, so :class:`UGVView` hides the UAV behind a scripted controller (hover or
:func:`centroid_command`) and exposes the UGVs only; the UAV's own policy is trained separately
(or stays scripted). Multi-policy libraries (RLlib) can use the full env with a policy mapping
``agent -> "ugv" if agent.startswith("ugv") else "uav"``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv

from swarm_core.aerial import AerialFrame


def hover_command(frame: AerialFrame | None) -> np.ndarray:
    """Hold position (Stegagno 2013's simulation: the UAV hovers for the whole run)."""
    return np.zeros(2)


def centroid_command(frame: AerialFrame | None, gain_per_s: float = 0.5) -> np.ndarray:
    """Body velocity ``gain * centroid`` towards the centroid of the frame's detections
    (Stegagno 2013's visual-servoing task T1: keep the UGVs' centroid at the image centre)."""
    if frame is None or frame.detections.shape[0] == 0:
        return np.zeros(2)
    return gain_per_s * frame.detections.mean(axis=0)


#: ``name -> controller(frame) -> (vx, vy)`` in the UAV's body frame.
UAV_CONTROLLERS: dict[str, Callable[[AerialFrame | None], np.ndarray]] = {
    "hover": hover_command,
    "centroid": centroid_command,
}


def uav_action(env: Any, controller: str = "hover") -> np.ndarray:
    """The UAV's action for ``env`` (a ``SupervisedSwarmEnv``) from a scripted controller:
    planar velocity from the controller, yaw and altitude rates 0."""
    if controller not in UAV_CONTROLLERS:
        raise ValueError(
            f"controller must be one of {sorted(UAV_CONTROLLERS)}, got {controller!r}"
        )
    v = UAV_CONTROLLERS[controller](env.last_frame)
    out = np.zeros(env.uav_config.action_size, dtype=np.float32)
    out[:2] = v
    return out


class UGVView(ParallelEnv):
    """The UGVs of a :class:`SupervisedSwarmEnv` as a ParallelEnv, the UAV scripted.

    Every agent has the same spaces, so one shared policy fits (SB3 / SuperSuit). The UAV's
    observation, reward and info are dropped; ``self.env`` is the full env.
    """

    def __init__(self, env: Any, controller: str = "hover") -> None:
        from swarm_env.uav.env import UAV_ID

        if controller not in UAV_CONTROLLERS:
            raise ValueError(
                f"controller must be one of {sorted(UAV_CONTROLLERS)}, got {controller!r}"
            )
        self.env = env
        self.controller = controller
        self._uav = UAV_ID
        self.possible_agents = list(env.ugv_agents)
        self.agents: list[str] = []
        self.metadata = {**env.metadata, "name": "swarm_uav_ugv_view_v0"}

    def observation_space(self, agent: str):
        return self.env.observation_space(agent)

    def action_space(self, agent: str):
        return self.env.action_space(agent)

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = [a for a in self.env.agents if a != self._uav]
        return self._drop(obs), self._drop(infos)

    def step(self, actions: dict[str, Any]):
        actions = dict(actions)
        if self._uav in self.env.agents:
            actions[self._uav] = uav_action(self.env, self.controller)
        out = self.env.step(actions)
        self.agents = [a for a in self.env.agents if a != self._uav]
        return tuple(self._drop(part) for part in out)

    def state(self) -> np.ndarray:
        return self.env.state()

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()

    def _drop(self, d: dict) -> dict:
        return {k: v for k, v in d.items() if k != self._uav}
