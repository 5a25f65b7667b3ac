"""swarm_env: a PettingZoo parallel env of a UGV swarm with embedded GM-PHD relative localization.

>>> from swarm_env import parallel_env
>>> env = parallel_env(preset="lab-3m-4")

The same swarm as a turn-based (AEC) env: ``swarm_env.env(preset="lab-3m-4")``. Importing the
package registers every task in PettingZoo's registries, ``pettingzoo.make("parallel" | "aec",
"swarm_phd/<task>_v0", ...)``, and the single-agent Gymnasium view (one controlled robot among
scripted teammates, :mod:`swarm_env.single_agent`): ``gymnasium.make("SwarmPHD-v0", ...)``
(see :mod:`swarm_env.registration`).
"""

from __future__ import annotations

from swarm_env.config import PRESETS, SwarmConfig, make_config
from swarm_env.env import SwarmEnv
from swarm_env.registration import env, parallel_env, raw_env, register_all

register_all()

__all__ = [
    "PRESETS",
    "SwarmConfig",
    "SwarmEnv",
    "env",
    "make_config",
    "parallel_env",
    "raw_env",
]
