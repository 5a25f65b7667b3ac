"""swarm_env: a PettingZoo parallel env of a UGV swarm with embedded GM-PHD relative localization.

>>> from swarm_env import parallel_env
>>> env = parallel_env(preset="lab-3m-4")

Importing it also registers the single-agent Gymnasium view (one controlled robot among
scripted teammates, :mod:`swarm_env.single_agent`): ``gymnasium.make("SwarmPHD-v0", ...)``.
"""

from __future__ import annotations

from typing import Any

from swarm_env.config import PRESETS, SwarmConfig, make_config
from swarm_env.env import SwarmEnv


def parallel_env(preset: str = "sim-6m-20", **kwargs: Any) -> SwarmEnv:
    """A :class:`SwarmEnv` for ``preset`` with keyword overrides (see its docstring)."""
    return SwarmEnv(preset, **kwargs)


def _register() -> None:
    import gymnasium

    if "SwarmPHD-v0" not in gymnasium.registry:
        # No TimeLimit wrapper: the env truncates at its own ``max_steps``.
        gymnasium.register(id="SwarmPHD-v0", entry_point="swarm_env.single_agent:SingleAgentEnv")


_register()

__all__ = ["PRESETS", "SwarmConfig", "SwarmEnv", "make_config", "parallel_env"]
