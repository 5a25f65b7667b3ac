"""Env keyword arguments shared by the tests: the formation task in the lab preset."""

from __future__ import annotations

from typing import Any


def formation_env(
    max_steps: int,
    *,
    observation: str | None = None,
    task_params: dict[str, Any] | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """``parallel_env`` keyword arguments of the formation task in the ``lab-3m-4`` preset:
    ``preset``, ``task``, then ``task_params`` and ``observation`` when given, ``max_steps``
    (env steps per episode), then ``overrides`` (e.g. ``lidar_sectors``, ``n_robots``), in that
    order. A fresh dict each call, so a test may extend or change its own copy."""
    kwargs: dict[str, Any] = {"preset": "lab-3m-4", "task": "formation"}
    if task_params is not None:
        kwargs["task_params"] = dict(task_params)
    if observation is not None:
        kwargs["observation"] = observation
    kwargs["max_steps"] = max_steps
    kwargs.update(overrides)
    return kwargs
