"""A single-agent Gymnasium view: one controlled robot among scripted teammates.

>>> import gymnasium as gym
>>> import swarm_env  # registers "SwarmPHD-v0"
>>> env = gym.make("SwarmPHD-v0", preset="lab-3m-4", max_steps=200)
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

The controlled robot (``agent``, default ``ugv_0``) sees exactly its own observation of the
multi-agent :class:`~swarm_env.env.SwarmEnv` (its GM-PHD table, odometry speed, task features)
and gets its own reward. The other robots are driven by ``teammates``: any callable with the
project's policy signature ``teammates(observations, infos) -> {agent: action}`` over the other
live agents, with an optional ``reset(seed)``; or ``make_teammates(swarm_env) -> policy`` for a
policy built on the inner SwarmEnv, e.g. ``make_teammates=WanderPolicy.for_env`` from
``agents.scripted`` (lidar obstacle avoidance; swarm_env itself never imports ``agents``). The
default, :class:`RandomWalkTeammates`, is a seeded random walk. Every other keyword goes to
:class:`SwarmEnv` (``task``, ``observation``, config overrides). ``terminated`` /
``truncated`` are the controlled robot's own.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from swarm_env.env import SwarmEnv

TeammatePolicy = Callable[[dict[str, np.ndarray], dict[str, dict[str, Any]]], dict[str, Any]]


class RandomWalkTeammates:
    """Each teammate holds a command ``[v, omega]`` and redraws it with probability
    ``switch_prob`` per step: ``v ~ U(0, v_frac * v_max)`` (m/s, forward only),
    ``omega ~ U(-w_frac * w_max, w_frac * w_max)`` (rad/s). Seeded by ``reset(seed)``."""

    def __init__(
        self, high: np.ndarray, switch_prob: float = 0.1, v_frac: float = 0.5, w_frac: float = 0.5
    ) -> None:
        if not 0.0 <= switch_prob <= 1.0:
            raise ValueError(f"switch_prob must be in [0, 1], got {switch_prob!r}")
        self.high = np.asarray(high, dtype=np.float64)
        self.switch_prob = switch_prob
        self.scale = np.array([v_frac, w_frac]) * self.high
        self._commands: dict[str, np.ndarray] = {}
        self.reset(None)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)
        self._commands = {}

    def _draw(self) -> np.ndarray:
        u = self._rng.uniform([0.0, -1.0], [1.0, 1.0])
        return (u * self.scale).astype(np.float32)

    def __call__(self, observations, infos) -> dict[str, np.ndarray]:
        actions = {}
        for agent in sorted(observations):  # a fixed draw order: reproducible
            if agent not in self._commands or self._rng.random() < self.switch_prob:
                self._commands[agent] = self._draw()
            actions[agent] = self._commands[agent]
        return actions


class SingleAgentEnv(gym.Env):
    """See the module docstring. Spaces are the controlled agent's spaces in the SwarmEnv."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        preset: str = "lab-3m-4",
        agent: str = "ugv_0",
        teammates: TeammatePolicy | None = None,
        render_mode: str | None = None,
        make_teammates: Callable[[SwarmEnv], TeammatePolicy] | None = None,
        **env_kwargs: Any,
    ) -> None:
        super().__init__()
        from swarm_env import parallel_env

        self.env: SwarmEnv = parallel_env(
            preset, render_mode=render_mode, render_agent=agent, **env_kwargs
        )
        if agent not in self.env.possible_agents:
            raise ValueError(f"agent must be one of {self.env.possible_agents}, got {agent!r}")
        self.agent = agent
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": self.env.metadata["render_fps"]}
        self.observation_space = self.env.observation_space(agent)
        self.action_space = self.env.action_space(agent)
        high = np.asarray(self.action_space.high, dtype=np.float64)
        if teammates is not None and make_teammates is not None:
            raise ValueError("pass teammates or make_teammates, not both")
        if make_teammates is not None:
            teammates = make_teammates(self.env)
        self.teammates = RandomWalkTeammates(high) if teammates is None else teammates
        if not callable(self.teammates):
            raise ValueError(f"teammates must be callable, got {type(teammates).__name__}")
        self._obs: dict[str, np.ndarray] = {}
        self._infos: dict[str, dict[str, Any]] = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        # One generator (gymnasium's np_random) seeds the swarm and the teammates: same seed,
        # same episode; later unseeded resets continue it.
        env_seed, mate_seed = (int(s) for s in self.np_random.integers(0, 2**31 - 1, size=2))
        self._obs, self._infos = self.env.reset(seed=env_seed, options=options)
        if hasattr(self.teammates, "reset"):
            self.teammates.reset(mate_seed)
        return self._obs[self.agent], self._infos[self.agent]

    def step(self, action):
        if self.agent not in self.env.agents:
            raise ValueError(f"{self.agent} is done: call reset() before step()")
        others = [a for a in self.env.agents if a != self.agent]
        actions = dict(
            self.teammates(
                {a: self._obs[a] for a in others}, {a: self._infos.get(a, {}) for a in others}
            )
            if others
            else {}
        )
        actions = {a: actions[a] for a in others if a in actions}
        missing = [a for a in others if a not in actions]
        if missing:
            raise ValueError(f"teammates returned no action for {missing}")
        actions[self.agent] = action
        obs, rewards, terms, truncs, infos = self.env.step(actions)
        self._obs, self._infos = obs, infos
        return (
            obs[self.agent],
            float(rewards[self.agent]),
            bool(terms[self.agent]),
            bool(truncs[self.agent]),
            infos[self.agent],
        )

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()
