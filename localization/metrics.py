"""Localization metrics: OSPA, GOSPA, Perera 2021's per-teammate error, and time accumulators.

Two accumulators: :class:`SeedScorer` scores a whole swarm per (observer, teammate) pair, the
Perera 2021 study's Fig. 7 exactly (one bar per tracked teammate of one observer), plus the
Stegagno 2012 figures, RMSE, GOSPA with its split and cardinality (used by ``swarm-phd evaluate``);
:class:`LocalizationScorer` is the simpler per-call accumulator of the bridge and replay
episodes (pooled per key).

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
* **Seed per-teammate error** (Perera 2021, fig. 7): for each true teammate *in range*, the
  distance from it to the closest mixture component with weight ``> 0.1``; ``inf`` when no
  component qualifies (so it exceeds any error threshold). Fig. 7's bar of teammate ``j`` for
  observer ``i`` is the % of the steps with ``j`` in range where that error is ``> 0.30 m``.
* **In range** is decided by the caller (the simulator knows the truth); the default used by
  :class:`LocalizationScorer` helpers is the lidar tracking range, 2.0 m, measured from the
  observer (``in_range_mask``).

References
----------
.. [1] D. Schuhmacher, B.-T. Vo, B.-N. Vo, "A consistent metric for performance evaluation
   of multi-object filters", IEEE Trans. Signal Processing, 56(8), 2008.
.. [2] A. S. Rahmathullah, A. F. Garcia-Fernandez, L. Svensson, "Generalized optimal
   sub-pattern assignment metric", FUSION 2017.
.. [3] Perera 2021, chapter 4 (figs. 7-8).
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from swarm_core.validation import check_number, check_positive

from .mixture import GaussianMixture

__all__ = [
    "DEFAULT_RANGE_M",
    "LARGE_ERROR_M",
    "MIN_COMPONENT_WEIGHT",
    "GospaResult",
    "ospa",
    "gospa",
    "in_range_mask",
    "closest_component_errors",
    "closest_component_errors_padded",
    "extract_estimates",
    "LocalizationScorer",
    "SeedScorer",
    "pad_mixtures",
    "weights_means_from_table",
    "in_range_pairs",
    "DEFAULT_RANGE_BINS_M",
]

#: Default "in range" radius: the lidar's effective tracking range in Perera 2021 (m).
DEFAULT_RANGE_M = 2.0
#: The seeds' scoring: a teammate's error is "large" above this (m, seed fig. 7) ...
LARGE_ERROR_M = 0.30
#: ... measured to its closest component of weight (or existence) above this.
MIN_COMPONENT_WEIGHT = 0.1


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
    check_positive("c", c)
    check_number("p", p, low=1)


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
    return _gospa(_points(X, "X"), _points(Y, "Y"), float(c), float(p), float(alpha))


def _gospa(x: np.ndarray, y: np.ndarray, c: float, p: float, alpha: float) -> GospaResult:
    """:func:`gospa` on checked ``(n, 2)`` / ``(m, 2)`` float arrays (the scorers' hot path)."""
    n, m = x.shape[0], y.shape[0]
    unit = c**p / alpha
    half = c**p / 2.0
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
        Radius (m); default the lidar tracking range of Perera 2021 (2 m).

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    pts = _points(relative_positions, "relative_positions")
    return np.hypot(pts[:, 0], pts[:, 1]) <= range_m


def closest_component_errors(
    truth: np.ndarray, mixture: GaussianMixture, min_weight: float = MIN_COMPONENT_WEIGHT
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


def closest_component_errors_padded(
    points: np.ndarray,
    weights: np.ndarray,
    means: np.ndarray,
    min_weight: float = MIN_COMPONENT_WEIGHT,
) -> np.ndarray:
    """:func:`closest_component_errors` of every robot at once (the matching rule of
    :meth:`SeedScorer.update`).

    Parameters
    ----------
    points : array_like, shape (R, K, 2)
        Per robot r, K true positions in r's frame (m).
    weights, means : ndarray, shapes (R, C) and (R, C, 2)
        Every robot's zero-padded mixture in its own frame (:func:`pad_mixtures`, or
        :func:`weights_means_from_table` of a localizer's ``padded_tables()``).
    min_weight : float
        Only components with weight ``> min_weight`` count (seed: 0.1).

    Returns
    -------
    ndarray, shape (R, K)
        Distances (m) to the robot's closest qualifying component; ``inf`` where none qualifies.
    """
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 0 or weights.shape[1] == 0:
        return np.full(pts.shape[:2], np.inf)
    d2 = ((pts[:, :, None, :] - means[:, None, :, :]) ** 2).sum(axis=3)  # (R, K, C)
    return np.sqrt(np.where((weights > min_weight)[:, None, :], d2, np.inf).min(axis=2))


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
    """Accumulate the Perera 2021 study's localization statistics over time.

    Two ways to feed it, each once per evaluation step:

    * ``update(truth, ids, mixture)``: one observer, the true positions (observer frame) of the
      neighbours in range and their ids. Statistics are kept **per neighbour id** (the Perera 2021
      study's fig. 7: % of time each UGV's error exceeds 0.30 m).
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
        "Accurate" threshold (m), Stegagno 2012: 0.1.
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
    error_threshold_m: float = LARGE_ERROR_M
    accurate_threshold_m: float = 0.10
    min_weight: float = MIN_COMPONENT_WEIGHT
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
            ``robots_over_25pct`` (keys with > 25 % large-error time, the Perera 2021 study's
            headline count), ``cardinality_mae``, ``mean_weight_sum``, ``mean_true_count``,
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


# ------------------------------------------------------------- the source studies' scoring
def pad_mixtures(mixtures: list[GaussianMixture]) -> tuple[np.ndarray, np.ndarray]:
    """Stack every observer's mixture into padded arrays for :class:`SeedScorer`.

    Parameters
    ----------
    mixtures : list of GaussianMixture, length R
        Observer ``i``'s PHD (its body frame).

    Returns
    -------
    weights : ndarray, shape (R, M)
        Component weights; padding columns hold 0 (never above any weight threshold).
    means : ndarray, shape (R, M, 2)
        Component means (m); padding holds 0.
    """
    n = len(mixtures)
    m = max((len(mix.weights) for mix in mixtures), default=0)
    weights = np.zeros((n, m))
    means = np.zeros((n, m, 2))
    for i, mix in enumerate(mixtures):  # one copy per observer, not per component
        k = len(mix.weights)
        weights[i, :k] = mix.weights
        means[i, :k] = mix.means
    return weights, means


def weights_means_from_table(
    table: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:class:`SeedScorer` inputs from a localizer's ``padded_tables()``.

    Parameters
    ----------
    table : ndarray, shape (6, R, C)
        Rows ``w, x, y, Pxx, Pxy, Pyy``; robot ``r`` uses the first ``counts[r]`` columns.
    counts : ndarray of int, shape (R,)

    Returns
    -------
    weights : ndarray, shape (R, C)
        Weights, 0 past ``counts[r]`` (whatever the table holds there).
    means : ndarray, shape (R, C, 2)
        Means (m).
    """
    table = np.asarray(table, dtype=float)
    counts = np.asarray(counts)
    if table.ndim != 3 or table.shape[0] < 3 or counts.shape != (table.shape[1],):
        raise ValueError(
            f"table must be (6, R, C) and counts (R,), got {table.shape} and {counts.shape}"
        )
    used = np.arange(table.shape[2])[None, :] < counts[:, None]
    weights = np.where(used, table[0], 0.0)
    means = np.where(used[..., None], np.stack([table[1], table[2]], axis=-1), 0.0)
    return weights, means


def in_range_pairs(rel_xy: np.ndarray, range_m: float) -> np.ndarray:
    """``(R, R)`` bool: teammate ``j`` within ``range_m`` of observer ``i`` (never ``i == j``).

    Parameters
    ----------
    rel_xy : ndarray, shape (R, R, 2)
        ``rel_xy[i, j]``: teammate ``j`` in observer ``i``'s frame (m).
    range_m : float
        Sensor range (m), inclusive.
    """
    rel = np.asarray(rel_xy, dtype=float)
    if rel.ndim != 3 or rel.shape[0] != rel.shape[1] or rel.shape[2] != 2:
        raise ValueError(f"rel_xy must have shape (R, R, 2), got {rel.shape}")
    return (np.hypot(rel[..., 0], rel[..., 1]) <= range_m) & ~np.eye(rel.shape[0], dtype=bool)


#: Range bins (m) of the per-range breakdown of :class:`SeedScorer`.
DEFAULT_RANGE_BINS_M = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)


def _pct(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, 100.0 * num / np.maximum(den, 1), np.nan)


def _stats(values: np.ndarray) -> dict[str, float]:
    ok = values[np.isfinite(values)]
    nan = math.nan
    return {
        "median": float(np.median(ok)) if ok.size else nan,
        "mean": float(ok.mean()) if ok.size else nan,
        "max": float(ok.max()) if ok.size else nan,
    }


def _floats(values: np.ndarray) -> list[float]:
    # Every missing value is the one object math.nan, so that summaries of identical runs
    # compare equal with == (containers compare identical objects as equal, NaN or not).
    return [math.nan if v != v else float(v) for v in np.asarray(values, dtype=float).ravel()]


class SeedScorer:
    """The source studies' localization scoring, per (observer, teammate) pair, for a whole swarm.

    Fed once per evaluation step with the truth of every observer at once (vectorised over
    observers, teammates and components; only GOSPA's assignment loops over observers).

    **Definitions** (``docs/concepts/localizers.md``, "Metrics"):

    * *In range*: the caller's ``in_range[i, j]`` mask (the evaluation: true distance from
      observer ``i`` to teammate ``j`` <= the scoring range ``range_m``). A *tracked teammate*
      of ``i`` is a ``j`` in range at least once; only tracked teammates get a bar.
    * *Matched component* of teammate ``j`` for observer ``i``: ``i``'s closest component with
      weight ``> min_weight`` (Perera 2021: 0.1); the *error* is the distance to it, ``inf`` when
      no component qualifies.
    * *Perera 2021 Fig. 7 bar* of pair ``(i, j)``: % of the steps with ``j`` in range whose error
      is ``> error_threshold_m`` (0.30 m). ``ugv_0``'s bars are the study's figure.
    * *Pooled per observer* (the earlier ``swarm-phd evaluate`` statistic): the same % over
      all of ``i``'s (step, teammate in range) pairs together.
    * *Stegagno 2012*: % of in-range steps with error ``< accurate_threshold_m`` (0.1 m), and with
      bearing error ``< bearing_threshold_deg`` (7 deg); the bearing error is
      ``|wrap(atan2(matched mean) - atan2(truth))|``. An unmatched step fails both.
    * *RMSE* (m, deg): over in-range steps with a matched component, whatever its distance.
    * *GOSPA* (``c``, ``p``, ``alpha = 2``): per observer-step, between the teammates in range
      and the Vo & Ma estimates (weight >= ``extraction_threshold``) within ``range_m``;
      reported with its localisation / missed / false split.
    * *Cardinality*: the weight sum of the components within ``range_m`` against the true
      in-range count, and the whole mixture's weight sum against the true number of
      teammates (``R - 1``).

    Parameters
    ----------
    n_robots : int
        ``R``, the number of robots (every robot is an observer and a teammate of the others).
    range_m : float
        Scoring range (m) for the weight sum in range and the GOSPA estimates; the in-range
        mask given to :meth:`update` should be the same disc.
    trace_observer : int or None
        Observer whose per-step cardinality and GOSPA are kept in :attr:`trace` (Fig. 8)
        when :meth:`update` is given ``time_s``.
    error_threshold_m, accurate_threshold_m, bearing_threshold_deg, min_weight, over_pct :
        0.30 m, 0.10 m, 7 deg, 0.1, 25 % (the two studies' values).
    gospa_c, gospa_p, gospa_alpha, extraction_threshold :
        1 m, 2, 2, 0.5.
    range_bins_m : sequence of float
        Edges (m) of the per-range breakdown; pairs beyond the last edge fall in the last bin.
    """

    def __init__(
        self,
        n_robots: int,
        range_m: float = DEFAULT_RANGE_M,
        *,
        trace_observer: int | None = 0,
        error_threshold_m: float = LARGE_ERROR_M,
        accurate_threshold_m: float = 0.10,
        bearing_threshold_deg: float = 7.0,
        min_weight: float = MIN_COMPONENT_WEIGHT,
        over_pct: float = 25.0,
        gospa_c: float = 1.0,
        gospa_p: float = 2.0,
        gospa_alpha: float = 2.0,
        extraction_threshold: float = 0.5,
        range_bins_m: tuple[float, ...] = DEFAULT_RANGE_BINS_M,
    ) -> None:
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
            raise ValueError(f"n_robots must be an int, got {n_robots!r}")
        if n_robots < 2:
            raise ValueError(f"n_robots must be >= 2, got {n_robots}")
        if not (range_m > 0 and math.isfinite(range_m)):
            raise ValueError(f"range_m must be positive and finite, got {range_m!r}")
        _check_cp(gospa_c, gospa_p)
        if gospa_alpha != 2:
            raise ValueError(f"gospa_alpha must be 2 (the split needs it), got {gospa_alpha!r}")
        bins = np.asarray(range_bins_m, dtype=float)
        if bins.ndim != 1 or bins.size < 2 or np.any(np.diff(bins) <= 0):
            raise ValueError(f"range_bins_m must be increasing, >= 2 edges, got {range_bins_m!r}")
        if trace_observer is not None and not 0 <= trace_observer < n_robots:
            raise ValueError(f"trace_observer must be in [0, {n_robots}), got {trace_observer}")
        self.n_robots = int(n_robots)
        self.range_m = float(range_m)
        self.trace_observer = trace_observer
        self.error_threshold_m = float(error_threshold_m)
        self.accurate_threshold_m = float(accurate_threshold_m)
        self.bearing_threshold_deg = float(bearing_threshold_deg)
        self.min_weight = float(min_weight)
        self.over_pct = float(over_pct)
        self.gospa_c = float(gospa_c)
        self.gospa_p = float(gospa_p)
        self.gospa_alpha = float(gospa_alpha)
        self.extraction_threshold = float(extraction_threshold)
        self.range_bins_m = bins
        r = self.n_robots
        # Per (observer, teammate) counters, in steps.
        self.in_range_steps = np.zeros((r, r), np.int64)
        self.large_steps = np.zeros((r, r), np.int64)
        self.accurate_steps = np.zeros((r, r), np.int64)
        self.bearing_ok_steps = np.zeros((r, r), np.int64)
        self.matched_steps = np.zeros((r, r), np.int64)
        self.sq_error_m2 = np.zeros((r, r))
        self.sq_bearing_deg2 = np.zeros((r, r))
        # Large-error pair-steps by state and by range bin.
        self.cause_steps = {"low_weight": 0, "displaced": 0, "absent": 0, "not_visible": 0}
        self.bin_steps = np.zeros(bins.size - 1, np.int64)
        self.bin_large = np.zeros(bins.size - 1, np.int64)
        # Per observer-step sums: cardinality and GOSPA.
        self.observer_steps = 0
        self.card_in_range_abs = 0.0
        self.card_in_range_signed = 0.0
        self.card_total_abs = 0.0
        self.card_total_signed = 0.0
        self.weight_in_range = 0.0
        self.true_in_range = 0.0
        self.weight_total = 0.0
        self.gospa_sum = 0.0
        self.gospa_parts = {"localisation": 0.0, "missed": 0.0, "false": 0.0}
        self.gospa_counts = {"missed": 0, "false": 0, "assigned": 0}
        self.trace: dict[str, list[float]] = {
            "time_s": [],
            "weight_sum_in_range": [],
            "true_count_in_range": [],
            "weight_sum_total": [],
            "true_count_total": [],
            "gospa": [],
        }

    # ------------------------------------------------------------------------------- update
    def _check(self, rel_xy, in_range, weights, means, visible):
        r = self.n_robots
        rel = np.asarray(rel_xy, dtype=float)
        if rel.shape != (r, r, 2) or not np.isfinite(rel).all():
            raise ValueError(f"rel_xy must be finite with shape {(r, r, 2)}, got {rel.shape}")
        mask = np.asarray(in_range)
        if mask.shape != (r, r) or mask.dtype != bool:
            raise ValueError(
                f"in_range must be a bool array {(r, r)}, got {mask.dtype} {mask.shape}"
            )
        if mask.diagonal().any():
            raise ValueError(
                "in_range must be False on the diagonal (an observer is not its own teammate)"
            )
        w = np.asarray(weights, dtype=float)
        mu = np.asarray(means, dtype=float)
        if w.ndim != 2 or w.shape[0] != r or mu.shape != (*w.shape, 2):
            raise ValueError(
                f"weights (R, M) and means (R, M, 2) with R = {r}, got {w.shape} and {mu.shape}"
            )
        if not (np.isfinite(w).all() and np.isfinite(mu).all()) or (w < 0).any():
            raise ValueError("weights must be finite and >= 0, means finite")
        vis = None
        if visible is not None:
            vis = np.asarray(visible)
            if vis.shape != (r, r) or vis.dtype != bool:
                raise ValueError(f"visible must be a bool array {(r, r)}, got {vis.shape}")
        return rel, mask, w, mu, vis

    def update(
        self,
        rel_xy: np.ndarray,
        in_range: np.ndarray,
        weights: np.ndarray,
        means: np.ndarray,
        *,
        visible: np.ndarray | None = None,
        time_s: float | None = None,
    ) -> np.ndarray:
        """Score one step of every observer.

        Parameters
        ----------
        rel_xy : ndarray, shape (R, R, 2)
            ``rel_xy[i, j]``: teammate ``j``'s true position in observer ``i``'s frame (m).
        in_range : ndarray of bool, shape (R, R)
            Pairs in range this step (False on the diagonal).
        weights, means : ndarray, shapes (R, M) and (R, M, 2)
            Every observer's mixture, zero-padded (:func:`pad_mixtures`, or a bank's
            padded table), in its own frame (m).
        visible : ndarray of bool, shape (R, R), optional
            Pairs the localizer's sensors could detect at their last reading; a large error
            of a pair not visible is also counted as ``not_visible``.
        time_s : float, optional
            Step time (s); given, the trace observer's figures are appended to :attr:`trace`.

        Returns
        -------
        ndarray, shape (R, R)
            This step's errors (m) of the pairs in range: distance to the matched component,
            ``inf`` if none; NaN for pairs not in range.
        """
        rel, mask, w, mu, vis = self._check(rel_xy, in_range, weights, means, visible)
        r = self.n_robots
        # Only the P pairs in range are scored: (P, M) squared distances to every component.
        obs, mate = np.nonzero(mask)
        truth = rel[obs, mate]  # (P, 2)
        d2 = ((truth[:, None, :] - mu[obs]) ** 2).sum(axis=2)
        qualifies = w[obs] > self.min_weight  # (P, M)
        if d2.shape[1]:
            d2q = np.where(qualifies, d2, np.inf)
            idx = np.argmin(d2q, axis=1)
            err = np.sqrt(d2q[np.arange(len(obs)), idx])
            d_any = np.sqrt(d2.min(axis=1))
            matched_xy = mu[obs, idx]
        else:
            err = np.full(len(obs), np.inf)
            d_any = err
            matched_xy = np.zeros((len(obs), 2))
        matched = np.isfinite(err)
        dpsi = np.arctan2(matched_xy[:, 1], matched_xy[:, 0]) - np.arctan2(
            truth[:, 1], truth[:, 0]
        )
        bearing_err = np.degrees(np.abs((dpsi + np.pi) % (2 * np.pi) - np.pi))
        large = ~(err <= self.error_threshold_m)  # inf (unmatched) is large
        # np.nonzero gives each (observer, teammate) pair once, so fancy-index += is exact.
        self.in_range_steps[obs, mate] += 1
        self.large_steps[obs, mate] += large
        self.accurate_steps[obs, mate] += err < self.accurate_threshold_m
        self.bearing_ok_steps[obs, mate] += matched & (bearing_err < self.bearing_threshold_deg)
        self.matched_steps[obs, mate] += matched
        self.sq_error_m2[obs, mate] += np.where(matched, err, 0.0) ** 2
        self.sq_bearing_deg2[obs, mate] += np.where(matched, bearing_err, 0.0) ** 2
        # Why the large errors are large: a component near enough but too light, a matched
        # component 1-2 thresholds away, or nothing near.
        low = large & (d_any <= self.error_threshold_m)
        displaced = large & ~low & (err <= 2 * self.error_threshold_m)
        self.cause_steps["low_weight"] += int(low.sum())
        self.cause_steps["displaced"] += int(displaced.sum())
        self.cause_steps["absent"] += int((large & ~low & ~displaced).sum())
        if vis is not None:
            self.cause_steps["not_visible"] += int((large & ~vis[obs, mate]).sum())
        nb = self.bin_steps.size
        dist = np.hypot(truth[:, 0], truth[:, 1])
        bin_idx = np.clip(np.searchsorted(self.range_bins_m, dist, side="right") - 1, 0, nb - 1)
        self.bin_steps += np.bincount(bin_idx, minlength=nb)
        self.bin_large += np.bincount(bin_idx[large], minlength=nb)
        out = np.full((r, r), np.nan)
        out[obs, mate] = err
        self._cardinality_and_gospa(rel, mask, w, mu, time_s)
        return out

    def _cardinality_and_gospa(self, rel, mask, w, mu, time_s) -> None:
        r = self.n_robots
        near = np.hypot(mu[..., 0], mu[..., 1]) <= self.range_m
        w_in = np.where(near, w, 0.0).sum(axis=1)
        w_all = w.sum(axis=1)
        n_in = mask.sum(axis=1)
        n_all = r - 1
        self.observer_steps += r
        self.card_in_range_abs += float(np.abs(w_in - n_in).sum())
        self.card_in_range_signed += float((w_in - n_in).sum())
        self.card_total_abs += float(np.abs(w_all - n_all).sum())
        self.card_total_signed += float((w_all - n_all).sum())
        self.weight_in_range += float(w_in.sum())
        self.true_in_range += float(n_in.sum())
        self.weight_total += float(w_all.sum())
        keep = (w >= self.extraction_threshold) & near
        counts = np.where(keep, np.maximum(np.floor(w + 0.5), 1.0), 0.0).astype(np.intp)
        gospas = np.empty(r)
        for i in range(r):  # one small assignment problem per observer
            est = np.repeat(mu[i], counts[i], axis=0)
            g = _gospa(rel[i][mask[i]], est, self.gospa_c, self.gospa_p, 2.0)
            gospas[i] = g.distance
            self.gospa_parts["localisation"] += g.localisation
            self.gospa_parts["missed"] += g.missed_cost
            self.gospa_parts["false"] += g.false_cost
            self.gospa_counts["missed"] += g.missed
            self.gospa_counts["false"] += g.false
            self.gospa_counts["assigned"] += int(mask[i].sum()) - g.missed
        self.gospa_sum += float(gospas.sum())
        k = self.trace_observer
        if time_s is not None and k is not None:
            self.trace["time_s"].append(float(time_s))
            self.trace["weight_sum_in_range"].append(float(w_in[k]))
            self.trace["true_count_in_range"].append(int(n_in[k]))
            self.trace["weight_sum_total"].append(float(w_all[k]))
            self.trace["true_count_total"].append(n_all)
            self.trace["gospa"].append(float(gospas[k]))

    # ------------------------------------------------------------------------------ results
    def per_pair_pct_large(self) -> np.ndarray:
        """Fig. 7 bars: ``(R, R)`` % of in-range steps with error > 0.30 m; NaN if never in
        range (untracked pair, and the diagonal)."""
        return _pct(self.large_steps, self.in_range_steps)

    def observer_bars(self, observer: int) -> dict[str, Any]:
        """Perera 2021's Fig. 7 for one observer: one bar per tracked teammate."""
        if not 0 <= observer < self.n_robots:
            raise ValueError(f"observer must be in [0, {self.n_robots}), got {observer}")
        pct = self.per_pair_pct_large()[observer]
        tracked = self.in_range_steps[observer] > 0
        vals = pct[tracked]
        return {
            "observer": int(observer),
            "per_teammate": _floats(pct),  # NaN: never in range (or the observer itself)
            "in_range_steps": [int(v) for v in self.in_range_steps[observer]],
            "tracked_teammates": int(tracked.sum()),
            "teammates_above_25pct": int((vals > self.over_pct).sum()),
            **_stats(vals),
        }

    def all_observer_bars(self) -> dict[str, Any]:
        """Fig. 7 bars of every observer together: every tracked (observer, teammate) pair."""
        pct = self.per_pair_pct_large()
        tracked = self.in_range_steps > 0
        over = np.where(tracked, pct > self.over_pct, False)
        per_obs_over = over.sum(axis=1).astype(float)
        with np.errstate(invalid="ignore"):
            per_obs_median = np.array(
                [
                    np.median(pct[i][tracked[i]]) if tracked[i].any() else np.nan
                    for i in range(self.n_robots)
                ]
            )
        return {
            "per_pair": _floats(pct[tracked]),  # row-major over (observer, teammate)
            "tracked_pairs": int(tracked.sum()),
            "pairs_above_25pct": int(over.sum()),
            **_stats(pct[tracked]),
            "per_observer_teammates_above_25pct": _floats(per_obs_over),
            "median_teammates_above_25pct": float(np.median(per_obs_over)),
            "per_observer_median_teammate": _floats(per_obs_median),
        }

    def pooled_per_observer(self) -> dict[str, Any]:
        """The earlier statistic: per observer, % of all its in-range pair-steps > 0.30 m."""
        pct = _pct(self.large_steps.sum(axis=1), self.in_range_steps.sum(axis=1))
        return {"per_robot": _floats(pct), **_stats(pct)}

    def summary(self, observer: int = 0) -> dict[str, Any]:
        """Every figure, as a JSON-ready dict (keys documented in
        ``docs/concepts/localizers.md``)."""
        nan = math.nan
        pairs = float(self.in_range_steps.sum())
        matched = float(self.matched_steps.sum())
        obs_steps = self.observer_steps
        large = float(self.large_steps.sum())
        bins = self.range_bins_m
        one = self.observer_bars(observer)
        every = self.all_observer_bars()
        pooled = self.pooled_per_observer()
        gospa_mean = self.gospa_sum / obs_steps if obs_steps else nan
        card_mae = self.card_in_range_abs / obs_steps if obs_steps else nan
        return {
            # Flat numbers for tables and sweeps (each also appears below in its block).
            "headline": {
                f"ugv_{observer}_teammates_above_25pct": float(one["teammates_above_25pct"]),
                f"ugv_{observer}_tracked_teammates": float(one["tracked_teammates"]),
                f"ugv_{observer}_median_teammate_pct_err_gt_30cm": one["median"],
                "all_observers_pairs_above_25pct": float(every["pairs_above_25pct"]),
                "all_observers_median_pair_pct_err_gt_30cm": every["median"],
                "pooled_per_observer_median_pct_err_gt_30cm": pooled["median"],
                "gospa_mean_m": gospa_mean,
                "cardinality_in_range_mae": card_mae,
            },
            "definition": {
                "in_range_m": self.range_m,
                "min_weight": self.min_weight,
                "error_threshold_m": self.error_threshold_m,
                "over_pct": self.over_pct,
            },
            "seed_fig7": {f"observer_ugv_{observer}": one, "all_observers": every},
            "pooled_per_observer": pooled,
            "pct_pair_steps_err_gt_30cm": 100.0 * large / pairs if pairs else nan,
            "seed001": {
                "pct_time_position_err_lt_10cm": 100.0 * self.accurate_steps.sum() / pairs
                if pairs
                else nan,
                "pct_time_bearing_err_lt_7deg": 100.0 * self.bearing_ok_steps.sum() / pairs
                if pairs
                else nan,
                "median_teammate_position_err_lt_10cm": _stats(
                    _pct(self.accurate_steps, self.in_range_steps)[self.in_range_steps > 0]
                )["median"],
                "median_teammate_bearing_err_lt_7deg": _stats(
                    _pct(self.bearing_ok_steps, self.in_range_steps)[self.in_range_steps > 0]
                )["median"],
            },
            "rmse_m": math.sqrt(self.sq_error_m2.sum() / matched) if matched else nan,
            "rmse_bearing_deg": math.sqrt(self.sq_bearing_deg2.sum() / matched)
            if matched
            else nan,
            "pct_unmatched": 100.0 * (pairs - matched) / pairs if pairs else nan,
            "gospa": {
                "c_m": self.gospa_c,
                "p": self.gospa_p,
                "alpha": self.gospa_alpha,
                "mean_m": gospa_mean,
                **{
                    f"mean_{k}_m{self.gospa_p:g}": v / obs_steps if obs_steps else nan
                    for k, v in self.gospa_parts.items()
                },
                **{
                    f"mean_{k}_count": v / obs_steps if obs_steps else nan
                    for k, v in self.gospa_counts.items()
                },
            },
            "cardinality": {
                "in_range_mae": card_mae,
                "in_range_bias": self.card_in_range_signed / obs_steps if obs_steps else nan,
                "total_mae": self.card_total_abs / obs_steps if obs_steps else nan,
                "total_bias": self.card_total_signed / obs_steps if obs_steps else nan,
                "mean_weight_in_range": self.weight_in_range / obs_steps if obs_steps else nan,
                "mean_true_in_range": self.true_in_range / obs_steps if obs_steps else nan,
                "mean_weight_total": self.weight_total / obs_steps if obs_steps else nan,
                "true_total": float(self.n_robots - 1),
            },
            "large_error_causes_pct_of_pair_steps": {
                k: 100.0 * v / pairs if pairs else nan for k, v in self.cause_steps.items()
            },
            "by_range": {
                "edges_m": _floats(bins),
                "pair_steps": [int(v) for v in self.bin_steps],
                "pct_err_gt_30cm": _floats(_pct(self.bin_large, self.bin_steps)),
            },
            "pair_steps": int(pairs),
            "observer_steps": int(obs_steps),
            "scored_observations": float(obs_steps),  # LocalizationScorer's name for it
        }
