"""Tasks, one small file each, chosen with ``task=`` (see :func:`make_task`)."""

from __future__ import annotations

from typing import Any

from swarm_env.tasks.base import Task
from swarm_env.tasks.encirclement import EncirclementTask
from swarm_env.tasks.exploration import ExplorationTask
from swarm_env.tasks.formation import FormationTask
from swarm_env.tasks.wander import WanderTask

TASKS: dict[str, type[Task]] = {
    WanderTask.name: WanderTask,
    FormationTask.name: FormationTask,
    ExplorationTask.name: ExplorationTask,
    EncirclementTask.name: EncirclementTask,
}


def make_task(name: str | Task, **params: Any) -> Task:
    """A task instance by name; unknown names or parameters raise ``ValueError``."""
    if isinstance(name, Task):
        if params:
            raise ValueError("task parameters go to the task's constructor, not with an instance")
        return name
    if name not in TASKS:
        raise ValueError(f"task must be one of {sorted(TASKS)}, got {name!r}")
    return TASKS[name](**params)


def task_needs_estimates(name: str | Task, params: dict[str, Any] | None = None) -> bool:
    """Whether task ``name`` with ``params`` scores the robots' own estimates (a localization
    term ``localization_term="estimate"``), so its env must run the filters (``localize``)
    even for a policy that ignores the observation."""
    task = name if isinstance(name, Task) else make_task(name, **(params or {}))
    return task.needs_estimates


__all__ = ["TASKS", "Task", "make_task", "task_needs_estimates"]
