"""The tasks' optional localization term: a per-robot penalty for teammates it does not localize.

``r_i -= localization_weight * u_i``, ``u_i`` in [0, 1], with ``localization_term``:

- ``"unseen"`` (default): the fraction of i's teammates that its lidar and camera did not both
  detect at their last tick (:func:`~swarm_env.tasks.common.unseen_fraction`). A proxy: it needs
  only the simulator's visibility masks.
- ``"estimate"``: the fraction of i's teammates that i's *own estimate* misplaces: no component
  of weight > 0.1 within 0.30 m of the teammate's true position (:func:`mislocalized_fraction`).
  That is the per-pair error of the Perera 2021 study's scoring
  (:class:`localization.metrics.SeedScorer`, the "% of pair-steps above 0.30 m" of
  ``swarm-phd evaluate``), over every teammate rather than those within 2 m, so that leaving a
  teammate's range does not lower the penalty. It reads the env's localizer after this step's
  update (simulation only: it needs ground truth).

The episode mean of ``u`` goes to the task metrics as ``unseen_fraction`` or
``mislocalized_fraction``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from localization.metrics import (
    LARGE_ERROR_M,
    MIN_COMPONENT_WEIGHT,
    closest_component_errors_padded,
    weights_means_from_table,
)
from swarm_core.world import relative_positions
from swarm_env.tasks.common import check_choice, check_param, unseen_fraction

LOCALIZATION_TERMS = ("unseen", "estimate")


def mislocalized_fraction(
    truth: Any,
    table: np.ndarray,
    counts: np.ndarray,
    threshold_m: float = LARGE_ERROR_M,
    min_weight: float = MIN_COMPONENT_WEIGHT,
) -> np.ndarray:
    """Per robot i: the fraction of its R - 1 teammates with no component of weight
    ``> min_weight`` within ``threshold_m`` of their true position, shape (R,), in [0, 1]
    (0 for a lone robot).

    ``table`` (6, R, C) and ``counts`` (R,) are the localizer's ``padded_tables()`` (robot i's
    components in its body frame); ``truth.poses`` holds the R robots first (extra task robots,
    such as an intruder, after them are not teammates).
    """
    n = len(counts)
    if n < 2:
        return np.zeros(n)
    poses = truth.poses[:n]
    rel = relative_positions(poses, poses[:, :2])  # (R, R, 2): j in i's frame
    weights, means = weights_means_from_table(table, counts)
    err = closest_component_errors_padded(rel, weights, means, min_weight)
    lost = (err > threshold_m) & ~np.eye(n, dtype=bool)
    return lost.sum(axis=1) / (n - 1)


class LocalizationTerm:
    """One task's localization term (see the module doc): checks its parameters, computes the
    weighted penalty per step and keeps its episode mean."""

    def __init__(self, task: str, weight: float, kind: str) -> None:
        self.weight = check_param(task, "localization_weight", weight, 0.0, 1e3)
        self.kind = check_choice(task, "localization_term", kind, LOCALIZATION_TERMS)
        self._values: list[float] = []
        self._tables: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def needs_estimates(self) -> bool:
        """Whether the env must hand over its localizer's tables before every reward."""
        return bool(self.weight) and self.kind == "estimate"

    def observe_estimates(self, table: np.ndarray, counts: np.ndarray) -> None:
        """This step's ``padded_tables()`` of the env's localizer, read by :meth:`penalty`."""
        self._tables = (table, counts)

    def reset(self) -> None:
        self._values = []
        self._tables = None

    def penalty(self, truth: Any) -> np.ndarray | float:
        """``weight * u`` per robot (N,), or 0.0 when the term is off."""
        if not self.weight:
            return 0.0
        if self.kind == "unseen":
            u = unseen_fraction(truth)
        else:
            if self._tables is None:
                raise RuntimeError(
                    "localization_term='estimate' needs the localizer's tables before every "
                    "reward (the env passes them when localize=True)"
                )
            u = mislocalized_fraction(truth, *self._tables)
            self._tables = None  # never score a stale estimate
        self._values.append(float(u.mean()))
        return self.weight * u

    def metrics(self) -> dict[str, float]:
        if not self._values:
            return {}
        key = "unseen_fraction" if self.kind == "unseen" else "mislocalized_fraction"
        return {key: float(np.mean(self._values))}
