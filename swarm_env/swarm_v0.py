"""Versioned entry point, PettingZoo style: ``from swarm_env import swarm_v0``.

``swarm_v0.parallel_env(...)`` is the :class:`~swarm_env.env.SwarmEnv`; ``swarm_v0.env(...)``
its AEC form and ``swarm_v0.raw_env(...)`` the same (see :mod:`swarm_env.registration`).
"""

from __future__ import annotations

from swarm_env.registration import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
