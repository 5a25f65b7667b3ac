"""Versioned entry point, PettingZoo style: ``from swarm_env import swarm_v0``."""

from __future__ import annotations

from swarm_env import SwarmEnv, parallel_env

raw_env = SwarmEnv

__all__ = ["parallel_env", "raw_env"]
