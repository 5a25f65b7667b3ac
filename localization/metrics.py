"""Localization metrics: OSPA, GOSPA, the seed's per-robot error, and a time accumulator.

Definitions
-----------
* **OSPA** (Schuhmacher, Vo & Vo 2008) of order ``p`` with cut-off ``c`` between point sets
  ``X`` (``n`` points) and ``Y`` (``m`` points), ``n <= m``::

      ospa = ( (min_assignment sum d_c(x, y)^p + c^p (m - n)) / m ) ^ (1/p),  d_c = min(d, c)

  0 when both sets are empty, ``c`` when exactly one is.
* **GOSPA** (Rahmathullah, Garcia-Fernandez & Svensson 2017) with ``alpha = 2``::

      gospa^p = sum over assigned pairs (d < c) of d^p + c^p / 2 * (missed + false)

  returned with its decomposition: localisation part (sum of assigned ``d^p``), the numbers
  of missed and false targets and their cost. Pairs at distance ``>= c`` count as one
  missed plus one false target.
* **Seed per-robot error** (Perera 2021, fig. 7): for each true neighbour *in range*, the
  distance from it to the closest mixture component with weight ``> 0.1``; ``inf`` when no
  component qualifies (so it exceeds any error threshold).
* **In range** is decided by the caller (the simulator knows the truth); the default used by
  :class:`LocalizationScorer` helpers is the lidar tracking range, 2.0 m, measured from the
  observer (``in_range_mask``).

References
----------
.. [1] D. Schuhmacher, B.-T. Vo, B.-N. Vo, "A consistent metric for performance evaluation
   of multi-object filters", IEEE Trans. Signal Processing, 56(8), 2008.
.. [2] A. S. Rahmathullah, A. F. Garcia-Fernandez, L. Svensson, "Generalized optimal
   sub-pattern assignment metric", FUSION 2017.
.. [3] Perera 2021, seed ``000`` of this project, chapter 4 (figs. 7-8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from .mixture import GaussianMixture

__all__ = [
    "DEFAULT_RANGE_M",
    "GospaResult",
    "ospa",
    "gospa",
    "in_range_mask",
    "closest_component_errors",
    "LocalizationScorer",
]

#: Default "in range" radius: the lidar's effective tracking range in the seed (m).
DEFAULT_RANGE_M = 2.0


def _points(value: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.size == 0:
        return np.empty((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def _check_cp(c: float, p: float) -> None:
    if not (c > 0 and math.isfinite(c)):
        raise ValueError(f"c must be a positive finite number, got {c!r}")
    if not (p >= 1 and math.isfinite(p)):
        raise ValueError(f"p must be >= 1 and finite, got {p!r}")


def _distances(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    diff = x[:, None, :] - y[None, :, :]
    return np.hypot(diff[..., 0], diff[..., 1])


def ospa(X: np.ndarray, Y: np.ndarray, c: float = 1.0, p: float = 2) -> float:
    """OSPA distance between two 2-D point sets.

    Parameters
    ----------
    X, Y : array_like, shape (n, 2) and (m, 2)
        Point sets (either may be empty).
    c : float
        Cut-off (m).
    p : float
        Order (>= 1).

    Returns
    -------
    float
        In ``[0, c]``.
    """
    _check_cp(c, p)
    x = _points(X, "X")
    y = _points(Y, "Y")
    n, m = x.shape[0], y.shape[0]
    if n == 0 and m == 0:
        return 0.0
    if n == 0 or m == 0:
        return float(c)
    if n > m:
        x, y, n, m = y, x, m, n
    cost = np.minimum(_distances(x, y), c) ** p
    rows, cols = linear_sum_assignment(cost)
    total = cost[rows, cols].sum() + c**p * (m - n)
    return float((total / m) ** (1.0 / p))


@dataclass(frozen=True, slots=True)
class GospaResult:
    """GOSPA distance and its decomposition.

    Attributes
    ----------
    distance : float
        ``gospa`` (m).
    localisation : float
        Sum of ``d^p`` over assigned pairs (m^p).
    missed : int
        True targets not assigned (number).
    false : int
        Estimates not assigned (number).
    missed_cost, false_cost : float
        ``c^p / alpha * missed`` and ``c^p / alpha * false`` (m^p).
    """

    distance: float
    localisation: float
    missed: int
    false: int
    missed_cost: float
    false_cost: float


def gospa(
    X: np.ndarray, Y: np.ndarray, c: float = 1.0, p: float = 2, alpha: float = 2
) -> GospaResult:
    """GOSPA metric between truth ``X`` and estimates ``Y``.

    Parameters
    ----------
    X : array_like, shape (n, 2)
        True positions (either set may be empty).
    Y : array_like, shape (m, 2)
        Estimated positions.
    c : float
        Cut-off (m).
    p : float
        Order (>= 1).
    alpha : float
        In ``(0, 2]``. The distance follows the general definition
        ``(min_assignment sum d_c^p + c^p / alpha * |m - n|)^(1/p)``; the decomposition
        (localisation + missed + false costs summing to ``distance^p``) holds for
        ``alpha = 2``, the only value for which it is defined.

    Returns
    -------
    GospaResult
    """
    _check_cp(c, p)
    if not 0 < alpha <= 2:
        raise ValueError(f"alpha must be in (0, 2], got {alpha!r}")
    x = _points(X, "X")
    y = _points(Y, "Y")
    n, m = x.shape[0], y.shape[0]
    unit = c**p / alpha
    if n == 0 or m == 0:
        total = unit * (n + m)
        return GospaResult(total ** (1.0 / p), 0.0, n, m, unit * n, unit * m)
    dist = _distances(x, y)
    # Cut-off assignment: with alpha = 2 a pair at d >= c costs c^p, exactly the cost of
    # leaving both points unassigned (c^p/2 + c^p/2), so such pairs count as missed + false.
    cost = np.minimum(dist, c) ** p
    rows, cols = linear_sum_assignment(cost)
    total = float(cost[rows, cols].sum()) + unit * abs(m - n)
    assigned = dist[rows, cols] < c
    localisation = float((dist[rows, cols][assigned] ** p).sum())
    n_pairs = int(assigned.sum())
    missed = n - n_pairs
    false = m - n_pairs
    half = c**p / 2.0
    return GospaResult(
        total ** (1.0 / p), localisation, missed, false, half * missed, half * false
    )


def in_range_mask(relative_positions: np.ndarray, range_m: float = DEFAULT_RANGE_M) -> np.ndarray:
    """Which neighbours are "in range": ``||p|| <= range_m`` in the observer's frame.

    Parameters
    ----------
    relative_positions : array_like, shape (K, 2)
        True neighbour positions in the observer's frame (m).
    range_m : float
        Radius (m); default the lidar tracking range of the seed (2 m).

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    pts = _points(relative_positions, "relative_positions")
    return np.hypot(pts[:, 0], pts[:, 1]) <= range_m


def closest_component_errors(
    truth: np.ndarray, mixture: GaussianMixture, min_weight: float = 0.1
) -> np.ndarray:
    """Seed per-robot error: distance from each true neighbour to the closest component.

    Parameters
    ----------
    truth : array_like, shape (K, 2)
        True neighbour positions in the observer's frame (m).
    mixture : GaussianMixture
        The observer's PHD.
    min_weight : float
        Only components with weight ``> min_weight`` count (seed: 0.1).

    Returns
    -------
    ndarray, shape (K,)
        Distances (m); ``inf`` where no component qualifies.
    """
    pts = _points(truth, "truth")
    means = mixture.means[mixture.weights > min_weight]
    if pts.shape[0] == 0:
        return np.empty(0)
    if means.shape[0] == 0:
        return np.full(pts.shape[0], np.inf)
    return _distances(pts, means).min(axis=1)


@dataclass
class LocalizationScorer:
    """Accumulate the seed's localization statistics over time for one observer.

    Feed it once per evaluation step with the true positions of the neighbours that are in
    range (the caller decides; see :func:`in_range_mask`), their ids, and the observer's
    mixture. Per neighbour id it accumulates the fraction of in-range steps whose error
    exceeds ``error_threshold_m`` (seed fig. 7, 0.30 m) and the fraction within
    ``accurate_threshold_m`` (seed ``001`` tables, 0.1 m). Per step it records the mixture's
    weight sum against the true count (seed fig. 8) for the cardinality error.

    Parameters
    ----------
    error_threshold_m : float
        "Large error" threshold (m), seed fig. 7: 0.30.
    accurate_threshold_m : float
        "Accurate" threshold (m), seed ``001``: 0.1.
    min_weight : float
        Components with weight ``<= min_weight`` are ignored for the error (seed: 0.1).
    cardinality_range_m : float or None
        If set, the weight sum is taken over components within this range of the observer
        only (so it compares with a count of in-range neighbours); ``None`` sums all weights.

    Examples
    --------
    >>> scorer = LocalizationScorer()
    >>> # each step: scorer.update(rel_positions_in_range, ids_in_range, f.mixture)
    >>> # then: scorer.summary()
    """

    error_threshold_m: float = 0.30
    accurate_threshold_m: float = 0.10
    min_weight: float = 0.1
    cardinality_range_m: float | None = DEFAULT_RANGE_M
    steps: int = field(default=0, init=False)
    in_range_steps: dict[int, int] = field(default_factory=dict, init=False)
    large_error_steps: dict[int, int] = field(default_factory=dict, init=False)
    accurate_steps: dict[int, int] = field(default_factory=dict, init=False)
    weight_sums: list[float] = field(default_factory=list, init=False)
    true_counts: list[int] = field(default_factory=list, init=False)
    errors: list[float] = field(default_factory=list, init=False)

    def update(
        self, truth: np.ndarray, ids: np.ndarray | list[int], mixture: GaussianMixture
    ) -> np.ndarray:
        """Add one time step.

        Parameters
        ----------
        truth : array_like, shape (K, 2)
            True positions (observer frame, m) of the neighbours in range at this step.
        ids : array_like of int, shape (K,)
            Their identities (any hashable ints), to accumulate per neighbour.
        mixture : GaussianMixture
            The observer's PHD at this step.

        Returns
        -------
        ndarray, shape (K,)
            This step's per-neighbour errors (m; ``inf`` if no component has weight > 0.1).
        """
        pts = _points(truth, "truth")
        id_list = [int(i) for i in np.asarray(ids).reshape(-1)]
        if len(id_list) != pts.shape[0]:
            raise ValueError(f"ids must have {pts.shape[0]} entries, got {len(id_list)}")
        errors = closest_component_errors(pts, mixture, self.min_weight)
        for ident, err in zip(id_list, errors.tolist(), strict=True):
            self.in_range_steps[ident] = self.in_range_steps.get(ident, 0) + 1
            if not err <= self.error_threshold_m:  # inf counts as large
                self.large_error_steps[ident] = self.large_error_steps.get(ident, 0) + 1
            if err <= self.accurate_threshold_m:
                self.accurate_steps[ident] = self.accurate_steps.get(ident, 0) + 1
        self.errors.extend(errors.tolist())
        weights = mixture.weights
        if self.cardinality_range_m is not None:
            ranges = np.hypot(mixture.means[:, 0], mixture.means[:, 1])
            weights = weights[ranges <= self.cardinality_range_m]
        self.weight_sums.append(float(weights.sum()))
        self.true_counts.append(pts.shape[0])
        self.steps += 1
        return errors

    def percent_large_error(self) -> dict[int, float]:
        """Per neighbour id: % of its in-range steps with error > ``error_threshold_m``."""
        return {
            i: 100.0 * self.large_error_steps.get(i, 0) / n for i, n in self.in_range_steps.items()
        }

    def percent_accurate(self) -> dict[int, float]:
        """Per neighbour id: % of its in-range steps with error <= ``accurate_threshold_m``."""
        return {
            i: 100.0 * self.accurate_steps.get(i, 0) / n for i, n in self.in_range_steps.items()
        }

    def cardinality_mae(self) -> float:
        """Mean absolute difference between the weight sum and the true count per step."""
        if not self.steps:
            return float("nan")
        return float(np.mean(np.abs(np.subtract(self.weight_sums, self.true_counts))))

    def summary(self) -> dict[str, float]:
        """Pooled figures: % large error, % accurate (over all neighbour-steps), cardinality.

        Returns
        -------
        dict
            ``percent_large_error``, ``percent_accurate`` (pooled over neighbour-steps),
            ``robots_over_25pct`` (number of neighbours with > 25 % large-error time, the
            seed's headline count), ``cardinality_mae``, ``mean_weight_sum``,
            ``mean_true_count``, ``median_error_m`` (finite errors only), ``steps``.
        """
        total = sum(self.in_range_steps.values())
        large = sum(self.large_error_steps.values())
        accurate = sum(self.accurate_steps.values())
        finite = [e for e in self.errors if math.isfinite(e)]
        per_robot = self.percent_large_error()
        return {
            "percent_large_error": 100.0 * large / total if total else float("nan"),
            "percent_accurate": 100.0 * accurate / total if total else float("nan"),
            "robots_over_25pct": float(sum(v > 25.0 for v in per_robot.values())),
            "cardinality_mae": self.cardinality_mae(),
            "mean_weight_sum": float(np.mean(self.weight_sums)) if self.steps else float("nan"),
            "mean_true_count": float(np.mean(self.true_counts)) if self.steps else float("nan"),
            "median_error_m": float(np.median(finite)) if finite else float("nan"),
            "steps": float(self.steps),
        }
