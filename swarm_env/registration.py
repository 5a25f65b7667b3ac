"""The swarm in PettingZoo's and Gymnasium's environment registries, and its AEC form.

Importing :mod:`swarm_env` registers, for every task of :data:`swarm_env.tasks.TASKS`:

- ``swarm_phd/<task>_v0`` in PettingZoo's ``"parallel"`` registry (a :class:`SwarmEnv`) and in
  its ``"aec"`` registry (the same env turned turn-based by :func:`env`);
- ``SwarmPHD-v0`` in Gymnasium's registry (the single-agent view,
  :mod:`swarm_env.single_agent`).

>>> import pettingzoo
>>> import swarm_env  # registers the ids
>>> par = pettingzoo.make("parallel", "swarm_phd/formation_v0", preset="lab-3m-4")
>>> aec = pettingzoo.make("aec", "swarm_phd/formation_v0", preset="lab-3m-4", max_cycles=50)

Every keyword goes to :class:`SwarmEnv` (``preset``, ``render_mode``, config overrides...),
except the task: the id fixes it (``task_params`` tune it). PettingZoo's ``max_cycles`` is the
env's episode length, ``max_steps``. PettingZoo 1.27 has no plug-in discovery: an id exists
once :mod:`swarm_env` has been imported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from swarm_env.env import SwarmEnv

#: The registry namespace: ids are ``swarm_phd/<task>_v0``.
NAMESPACE = "swarm_phd"
#: The version of every registered id (the env's ``metadata["name"]`` is ``swarm_v0``).
VERSION = 0


def env_id(task: str) -> str:
    """The registry id of ``task``, e.g. ``swarm_phd/formation_v0``."""
    return f"{NAMESPACE}/{task}_v{VERSION}"


def parallel_env(preset: str = "sim-6m-20", **kwargs: Any) -> SwarmEnv:
    """A :class:`SwarmEnv` for ``preset`` with keyword overrides (see its docstring)."""
    return SwarmEnv(preset, **kwargs)


def raw_env(preset: str = "sim-6m-20", **kwargs: Any):
    """The AEC form of :func:`parallel_env`: PettingZoo's ``parallel_to_aec`` conversion.

    The robots still move together: each agent's action is held until the last live agent of
    the cycle has acted, then the swarm steps once. ``parallel_to_aec`` already wraps the
    result in PettingZoo's ``OrderEnforcingWrapper`` (no step before reset, no attribute
    access it forbids)."""
    from pettingzoo.utils.conversions import parallel_to_aec

    return parallel_to_aec(parallel_env(preset, **kwargs))


def env(preset: str = "sim-6m-20", **kwargs: Any):
    """The AEC env, as PettingZoo's ``env()`` entry points give it: :func:`raw_env`, order
    enforced. No out-of-bounds wrapper: :class:`SwarmEnv` clips continuous actions to the motor
    limits itself and refuses non-finite ones with a ``ValueError``."""
    return raw_env(preset, **kwargs)


@dataclass(frozen=True)
class TaskEntryPoint:
    """The creator registered under one task's id: ``kind`` ``"parallel"`` or ``"aec"``."""

    task: str
    kind: Literal["parallel", "aec"]

    def __call__(self, preset: str = "sim-6m-20", **kwargs: Any):
        if "task" in kwargs:
            raise ValueError(
                f"{env_id(self.task)} is the {self.task!r} task; task={kwargs['task']!r} belongs "
                f"to another id (one of {registered_ids()}) or to swarm_env.parallel_env(task=...)"
            )
        max_cycles = kwargs.pop("max_cycles", None)
        if max_cycles is not None:
            if "max_steps" in kwargs and kwargs["max_steps"] != max_cycles:
                raise ValueError(
                    f"max_cycles={max_cycles!r} and max_steps={kwargs['max_steps']!r} both set "
                    "the episode length; pass one"
                )
            kwargs["max_steps"] = max_cycles
        build = parallel_env if self.kind == "parallel" else env
        return build(preset, task=self.task, **kwargs)


def registered_ids() -> list[str]:
    """Every task's PettingZoo id."""
    from swarm_env.tasks import TASKS

    return [env_id(task) for task in TASKS]


def register_all() -> None:
    """Register every task in PettingZoo's two registries and the single-agent view in
    Gymnasium's. Idempotent: ids already registered (a module reload) are left alone."""
    import gymnasium
    import pettingzoo

    from swarm_env.tasks import TASKS

    for task in TASKS:
        for kind, registry in (
            ("parallel", pettingzoo.parallel_registry),
            ("aec", pettingzoo.aec_registry),
        ):
            spec_id = env_id(task).replace(f"_v{VERSION}", f"-v{VERSION}")  # PettingZoo's form
            if spec_id not in registry:
                pettingzoo.register(kind, env_id(task), entry_point=TaskEntryPoint(task, kind))
    if "SwarmPHD-v0" not in gymnasium.registry:
        # No TimeLimit wrapper: the env truncates at its own ``max_steps``.
        gymnasium.register(id="SwarmPHD-v0", entry_point="swarm_env.single_agent:SingleAgentEnv")
