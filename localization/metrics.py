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
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

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
    "extract_estimates",
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

    def as_dict(self) -> dict[str, float]:
        """The fields as a dict; ``"total"`` is an alias of ``"distance"``."""
        return {
            "total": self.distance,
            "distance": self.distance,
            "localisation": self.localisation,
            "missed": self.missed,
            "false": self.false,
            "missed_cost": self.missed_cost,
            "false_cost": self.false_cost,
        }

    def __getitem__(self, key: str) -> float:
        """Mapping-style access: ``result["total"]`` (= ``distance``), ``result["missed"]``..."""
        try:
            return self.as_dict()[key]
        except KeyError:
            raise KeyError(f"GospaResult has no field {key!r}") from None


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


def extract_estimates(
    mixture: GaussianMixture, threshold: float = 0.5, range_m: float | None = None
) -> np.ndarray:
    """Vo & Ma extraction from a mixture (as ``RobotCentricPHD.estimate``), optionally in range.

    Parameters
    ----------
    mixture : GaussianMixture
    threshold : float
        Components with weight ``>= threshold`` are reported ``max(1, floor(w + 0.5))`` times.
    range_m : float or None
        Keep only estimates within this distance of the observer.

    Returns
    -------
    ndarray, shape (K, 2)
    """
    w = mixture.weights
    keep = w >= threshold
    if range_m is not None:
        keep &= np.hypot(mixture.means[:, 0], mixture.means[:, 1]) <= range_m
    counts = np.maximum(np.floor(w[keep] + 0.5), 1.0).astype(np.intp)
    return np.repeat(mixture.means[keep], counts, axis=0)


@dataclass
class LocalizationScorer:
    """Accumulate the seed's localization statistics over time.

    Two ways to feed it, each once per evaluation step:

    * ``update(truth, ids, mixture)``: one observer, the true positions (observer frame) of the
      neighbours in range and their ids. Statistics are kept **per neighbour id** (the seed's
      fig. 7: % of time each UGV's error exceeds 0.30 m).
    * ``add(observer, truth, mixture, range_m=None)``: a swarm of observers, each with its own
      filter. Statistics are kept **per observer** (pooled over its neighbours in range).

    Either way, each call also records the mixture's weight sum within range against the true
    count (seed fig. 8) and the GOSPA between the truth and the extracted estimates
    (weight >= ``extraction_threshold``) within range. "In range" is decided by the caller
    (pass only the neighbours in range; see :func:`in_range_mask`); the weight-sum and
    estimate range is ``range_m`` (``add``) or ``cardinality_range_m``.

    Parameters
    ----------
    n_observers : int or None
        Number of observers for ``add`` (per-observer lists then have this length, NaN for an
        observer never scored). Optional.
    error_threshold_m : float
        "Large error" threshold (m), seed fig. 7: 0.30.
    accurate_threshold_m : float
        "Accurate" threshold (m), seed ``001``: 0.1.
    min_weight : float
        Components with weight ``<= min_weight`` are ignored for the error (seed: 0.1).
    cardinality_range_m : float or None
        Range (m) for the weight sum and the GOSPA estimates; ``None`` takes everything.
    extraction_threshold : float
        Weight threshold of the estimates used for GOSPA (0.5).
    gospa_c : float
        GOSPA cut-off (m); ``p = 2``, ``alpha = 2``.

    Examples
    --------
    >>> scorer = LocalizationScorer()
    >>> # each step: scorer.update(rel_positions_in_range, ids_in_range, f.mixture)
    >>> # then: scorer.summary()
    """

    n_observers: int | None = None
    _: KW_ONLY
    error_threshold_m: float = 0.30
    accurate_threshold_m: float = 0.10
    min_weight: float = 0.1
    cardinality_range_m: float | None = DEFAULT_RANGE_M
    extraction_threshold: float = 0.5
    gospa_c: float = 1.0
    steps: int = field(default=0, init=False)
    in_range_steps: dict[int, int] = field(default_factory=dict, init=False)
    large_error_steps: dict[int, int] = field(default_factory=dict, init=False)
    accurate_steps: dict[int, int] = field(default_factory=dict, init=False)
    weight_sums: list[float] = field(default_factory=list, init=False)
    true_counts: list[int] = field(default_factory=list, init=False)
    errors: list[float] = field(default_factory=list, init=False)
    gospas: list[float] = field(default_factory=list, init=False)

    def update(
        self, truth: np.ndarray, ids: np.ndarray | list[int], mixture: GaussianMixture
    ) -> np.ndarray:
        """Add one time step of one observer, keyed by neighbour id.

        Parameters
        ----------
        truth : array_like, shape (K, 2)
            True positions (observer frame, m) of the neighbours in range at this step.
        ids : array_like of int, shape (K,)
            Their identities (any ints), to accumulate per neighbour.
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
            self._count(ident, err)
        self._record_step(pts, errors, mixture, self.cardinality_range_m)
        return errors

    def add(
        self,
        observer: int,
        truth: np.ndarray,
        mixture: GaussianMixture,
        range_m: float | None = None,
    ) -> np.ndarray:
        """Add one time step of observer ``observer``, keyed by observer.

        Parameters
        ----------
        observer : int
            Index of the observing robot.
        truth : array_like, shape (K, 2)
            True positions (its frame, m) of its neighbours in range at this step.
        mixture : GaussianMixture
            Its PHD at this step.
        range_m : float or None
            Range for its weight sum and GOSPA estimates (default ``cardinality_range_m``).

        Returns
        -------
        ndarray, shape (K,)
            This step's per-neighbour errors (m).
        """
        pts = _points(truth, "truth")
        errors = closest_component_errors(pts, mixture, self.min_weight)
        observer = int(observer)
        for err in errors.tolist():
            self._count(observer, err)
        self._record_step(
            pts, errors, mixture, self.cardinality_range_m if range_m is None else range_m
        )
        return errors

    def _count(self, key: int, err: float) -> None:
        self.in_range_steps[key] = self.in_range_steps.get(key, 0) + 1
        if not err <= self.error_threshold_m:  # inf counts as large
            self.large_error_steps[key] = self.large_error_steps.get(key, 0) + 1
        if err <= self.accurate_threshold_m:
            self.accurate_steps[key] = self.accurate_steps.get(key, 0) + 1

    def _record_step(
        self,
        pts: np.ndarray,
        errors: np.ndarray,
        mixture: GaussianMixture,
        range_m: float | None,
    ) -> None:
        self.errors.extend(errors.tolist())
        weights = mixture.weights
        if range_m is not None:
            ranges = np.hypot(mixture.means[:, 0], mixture.means[:, 1])
            weights = weights[ranges <= range_m]
        self.weight_sums.append(float(weights.sum()))
        self.true_counts.append(pts.shape[0])
        estimates = extract_estimates(mixture, self.extraction_threshold, range_m)
        self.gospas.append(gospa(pts, estimates, c=self.gospa_c).distance)
        self.steps += 1

    def percent_large_error(self) -> dict[int, float]:
        """Per key (neighbour id or observer): % of in-range steps with a large error."""
        return {
            i: 100.0 * self.large_error_steps.get(i, 0) / n for i, n in self.in_range_steps.items()
        }

    def percent_accurate(self) -> dict[int, float]:
        """Per key (neighbour id or observer): % of in-range steps within the accurate range."""
        return {
            i: 100.0 * self.accurate_steps.get(i, 0) / n for i, n in self.in_range_steps.items()
        }

    def cardinality_mae(self) -> float:
        """Mean absolute difference between the weight sum and the true count per step."""
        if not self.steps:
            return float("nan")
        return float(np.mean(np.abs(np.subtract(self.weight_sums, self.true_counts))))

    def _per_key(self, values: dict[int, float]) -> dict[str, Any]:
        if self.n_observers is not None:
            keys = list(range(self.n_observers))
        else:
            keys = sorted(values)
        per = [values.get(k, float("nan")) for k in keys]
        finite = [v for v in per if math.isfinite(v)]
        return {
            "per_robot": per,
            "median": float(np.median(finite)) if finite else float("nan"),
            "max": float(max(finite)) if finite else float("nan"),
        }

    def summary(self) -> dict[str, Any]:
        """Pooled and per-key figures.

        Returns
        -------
        dict
            ``percent_large_error``, ``percent_accurate`` (pooled over neighbour-steps),
            ``robots_over_25pct`` (keys with > 25 % large-error time, the seed's headline
            count), ``cardinality_mae``, ``mean_weight_sum``, ``mean_true_count``,
            ``median_error_m`` (finite errors only), ``gospa_mean``, ``scored_observations``
            (one per ``update``/``add`` call: observer-steps), and the per-key
            distributions ``pct_time_err_gt_30cm`` and ``pct_time_within_10cm``, each
            ``{"per_robot": [...], "median": m, "max": M}`` (per neighbour id for ``update``,
            per observer for ``add``; the names assume the default thresholds).
        """
        total = sum(self.in_range_steps.values())
        large = sum(self.large_error_steps.values())
        accurate = sum(self.accurate_steps.values())
        finite = [e for e in self.errors if math.isfinite(e)]
        per_key = self.percent_large_error()
        nan = float("nan")
        return {
            "percent_large_error": 100.0 * large / total if total else nan,
            "percent_accurate": 100.0 * accurate / total if total else nan,
            "robots_over_25pct": float(sum(v > 25.0 for v in per_key.values())),
            "cardinality_mae": self.cardinality_mae(),
            "mean_weight_sum": float(np.mean(self.weight_sums)) if self.steps else nan,
            "mean_true_count": float(np.mean(self.true_counts)) if self.steps else nan,
            "median_error_m": float(np.median(finite)) if finite else nan,
            "gospa_mean": float(np.mean(self.gospas)) if self.steps else nan,
            "scored_observations": float(self.steps),
            "pct_time_err_gt_30cm": self._per_key(per_key),
            "pct_time_within_10cm": self._per_key(self.percent_accurate()),
        }
