"""swarm_env: a PettingZoo parallel env of a UGV swarm with embedded GM-PHD relative localization.

>>> from swarm_env import parallel_env
>>> env = parallel_env(preset="seed-lab")
"""

from __future__ import annotations

from typing import Any

from swarm_env.config import PRESETS, SwarmConfig, make_config
from swarm_env.env import SwarmEnv


def parallel_env(preset: str = "seed-sim", **kwargs: Any) -> SwarmEnv:
    """A :class:`SwarmEnv` for ``preset`` with keyword overrides (see its docstring)."""
    return SwarmEnv(preset, **kwargs)


__all__ = ["PRESETS", "SwarmConfig", "SwarmEnv", "make_config", "parallel_env"]
