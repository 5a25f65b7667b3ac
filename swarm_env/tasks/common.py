"""Geometry and parameter checks shared by the tasks (pure numpy, no env state)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def check_param(
    task: str, name: str, value: Any, low: float, high: float, *, low_open: bool = False
) -> float:
    """``value`` as a float in ``[low, high]`` (``(low, high]`` with ``low_open``), else a
    ``ValueError`` naming the task and the parameter."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"task {task!r}: {name} must be a finite number, got {value!r}")
    too_low = value <= low if low_open else value < low
    if too_low or value > high:
        bracket = "(" if low_open else "["
        raise ValueError(
            f"task {task!r}: {name} must be in {bracket}{low}, {high}], got {value!r}"
        )
    return float(value)


def check_choice(task: str, name: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"task {task!r}: {name} must be one of {choices}, got {value!r}")
    return value


def pairwise_distances(xy: np.ndarray) -> np.ndarray:
    """Distances between all points, shape (N, N), ``inf`` on the diagonal."""
    d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d


def collisions(
    xy: np.ndarray, min_distance_m: float, arena: Any | None = None, wall_margin_m: float = 0.0
) -> np.ndarray:
    """Per robot: touching (centre distance < ``min_distance_m``) another robot, or closer than
    ``wall_margin_m`` to a wall of ``arena`` (an ``ArenaConfig``). Shape (N,) bool."""
    hit = (
        (pairwise_distances(xy) < min_distance_m).any(axis=1)
        if len(xy) > 1
        else np.zeros(len(xy), dtype=bool)
    )
    if arena is not None and wall_margin_m > 0:
        hx, hy = 0.5 * arena.width_m, 0.5 * arena.height_m
        hit |= (np.abs(xy[:, 0]) > hx - wall_margin_m) | (np.abs(xy[:, 1]) > hy - wall_margin_m)
    return hit


def max_angular_gap(center: np.ndarray, xy: np.ndarray) -> float:
    """Largest angle (rad) between consecutive directions from ``center`` to the points.

    ``2 pi`` for zero or one point. The center lies strictly inside the points' convex hull iff
    this gap is below ``pi`` (the points "enclose" it).
    """
    if len(xy) < 2:
        return 2 * math.pi
    angles = np.sort(np.arctan2(xy[:, 1] - center[1], xy[:, 0] - center[0]))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * math.pi])
    return float(gaps.max())
