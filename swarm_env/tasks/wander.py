"""``wander``: the Perera 2021 study's experiment. No reward, no termination: robots roam
(pseudo-random motion with obstacle avoidance comes from the scripted controller) while every robot
localises the others. Episodes end by truncation at ``max_steps``.
"""

from __future__ import annotations

from swarm_env.tasks.base import Task


class WanderTask(Task):
    """Reward ``r = 0``; termination: never; truncation: ``max_steps``."""

    name = "wander"
