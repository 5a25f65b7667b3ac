"""ID-PHD: the robot-centric filter whose components carry teammate identities (see the
package docstring for the model)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_core.validation import as_float_array

from ..config import config_with_overrides
from ..detection import DetectionModel
from ..mixture import N_ROWS, ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y, GaussianMixture
from .config import UNTAGGED, IDPHDConfig
from .motion import compose_relative, split_untagged
from .reducer import reduce_tagged
from .update import lidar_update_3d


# ---------------------------------------------------------------------- the filter
class IDPHD:
    """Robot-centric ID-PHD: teammate positions, headings and identities in the observer frame.

    Parameters
    ----------
    config : IDPHDConfig, optional
    **overrides
        Field values replacing those of ``config``; unknown names raise ``ValueError``.

    Examples
    --------
    >>> import numpy as np
    >>> f = IDPHD()
    >>> f.update_lidar(np.array([[1.0, 0.5]]))  # an unexplained detection: a pending birth
    >>> f.predict(np.zeros(3), {3: np.array([0.02, 0.0, 0.0])})  # split over {3, static}
    >>> f.update_lidar(np.array([[1.02, 0.5]]))
    >>> poses = f.estimate()  # {3: array([x, y, psi])}, maybe {-2: ...}

    Notes
    -----
    Bounds (``docs/concepts/localizers.md``, "Bounds on weight and cardinality"), ``W`` the total
    weight over every tag: ``predict`` gives ``W' <= survival_probability (W + birth_weight
    B)`` (``B``: detections of the last scan; the split shares a weight among its copies);
    ``update_lidar`` with ``M`` detections ``W' <= sum_i (1 - P_d,i) w_i + M``. At most
    ``max_components`` components; tags are teammate IDs that sent odometry, ``-1`` or ``-2``.
    An identity's weight (:meth:`identity_weights`) is an expected count, not a probability:
    it is bounded by ``W`` only.
    """

    __slots__ = (
        "config",
        "_model",
        "_w",
        "_m",
        "_p",
        "_tags",
        "_known",
        "_pending",
        "_mixture",
    )

    def __init__(self, config: IDPHDConfig | None = None, **overrides: Any) -> None:
        self.config = config = config_with_overrides(config, IDPHDConfig, overrides)
        self._model = DetectionModel(config.detection)
        self.reset()

    def reset(self) -> None:
        """Forget everything (components, known robots and pending births)."""
        self._w = np.empty(0)
        self._m = np.empty((0, 3))
        self._p = np.empty((0, 3, 3))
        self._tags = np.empty(0, dtype=np.int64)
        self._known: set[int] = set()
        self._pending = np.empty((0, 2))
        self._mixture: GaussianMixture | None = None

    # ------------------------------------------------------------------ views
    @property
    def weights(self) -> np.ndarray:
        return _readonly(self._w)

    @property
    def means(self) -> np.ndarray:
        """``(N, 3)``: ``(x_m, y_m, psi_rad)`` per component (read-only)."""
        return _readonly(self._m)

    @property
    def covs(self) -> np.ndarray:
        """``(N, 3, 3)`` covariances (read-only)."""
        return _readonly(self._p)

    @property
    def tags(self) -> np.ndarray:
        """``(N,)`` int tags: ``-1`` untagged, ``-2`` static, ``i >= 0`` robot ``i``."""
        return _readonly(self._tags)

    @property
    def known_ids(self) -> tuple[int, ...]:
        """Robots whose odometry has been received so far (sorted)."""
        return tuple(sorted(self._known))

    @property
    def mixture(self) -> GaussianMixture:
        """The ``(x, y)`` marginal of every component, as a read-only :class:`GaussianMixture`."""
        if self._mixture is None:
            self._mixture = GaussianMixture(
                self._w.copy(), self._m[:, :2].copy(), self._p[:, :2, :2].copy()
            )
        return self._mixture

    @property
    def total_weight(self) -> float:
        return float(self._w.sum())

    def __len__(self) -> int:
        return int(self._w.shape[0])

    def __repr__(self) -> str:
        return (
            f"IDPHD(components={len(self)}, known={len(self._known)}, "
            f"total_weight={self.total_weight:.3f})"
        )

    # ------------------------------------------------------------------ steps
    def predict(
        self, own_odometry: np.ndarray, teammate_odometry: dict[int, np.ndarray] | None = None
    ) -> None:
        """Time update: split untagged components, then compose each component's odometry.

        Parameters
        ----------
        own_odometry : array_like, shape (3,)
            ``[dx_m, dy_m, dpsi_rad]`` of the observer, in its frame at the start of the
            interval.
        teammate_odometry : dict int -> array_like (3,), optional
            Each teammate's increment over the same interval, in *its* frame at the start.
            A known robot missing from the dict is propagated with a null increment.

        Raises
        ------
        ValueError
            If an argument has the wrong shape, a non-finite value or a negative ID (nothing
            changes then).
        """
        own = _checked_delta(own_odometry, "own_odometry")
        team: dict[int, np.ndarray] = {}
        for key, value in (teammate_odometry or {}).items():
            if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
                raise ValueError(f"teammate_odometry keys must be robot IDs >= 0, got {key!r}")
            team[int(key)] = _checked_delta(value, f"teammate_odometry[{key}]")
        cfg = self.config
        known = self._known | set(team)
        w, m, p, tags = self._w, self._m, self._p, self._tags
        if self._pending.shape[0]:
            b = self._pending.shape[0]
            bm = np.zeros((b, 3))
            bm[:, :2] = self._pending
            bp = np.zeros((b, 3, 3))
            bp[:, 0, 0] = bp[:, 1, 1] = cfg.birth_std_m**2
            bp[:, 2, 2] = cfg.birth_heading_std_rad**2
            w = np.concatenate((w, np.full(b, cfg.birth_weight)))
            m = np.concatenate((m, bm))
            p = np.concatenate((p, bp))
            tags = np.concatenate((tags, np.full(b, UNTAGGED, dtype=np.int64)))
        if (tags == UNTAGGED).any():
            recovered = {
                i for i in known if self._w[self._tags == i].sum() >= cfg.recovered_weight
            }
            candidates = np.array(sorted(known - recovered), dtype=np.int64)
            w, m, p, tags = split_untagged(w, m, p, tags, candidates, cfg.birth_heading_hypotheses)
        # Per-component teammate increment and noise (one lookup table over tags).
        ids = np.array(sorted(known), dtype=np.int64)
        table = np.zeros((ids.shape[0] + 1, 3))  # last row: static / unknown -> null odometry
        for row, i in enumerate(ids.tolist()):
            if i in team:
                table[row] = team[i]
        index = np.searchsorted(ids, tags)
        is_robot = tags >= 0
        index[~is_robot] = ids.shape[0]
        delta = table[index]
        tvar = np.where(
            is_robot[:, None],
            np.array([cfg.teammate_odometry_std_m**2] * 2 + [cfg.teammate_odometry_std_rad**2]),
            np.array([cfg.static_process_std_m**2] * 2 + [0.0]),
        )
        ovar = np.array([cfg.own_odometry_std_m**2] * 2 + [cfg.own_odometry_std_rad**2])
        m, p = compose_relative(m, p, delta, own, tvar, ovar)
        w = w * cfg.survival_probability
        if w.shape[0] > cfg.max_components:
            w, m, p, tags = self._reduce(w, m, p, tags)
        self._w, self._m, self._p, self._tags = w, m, p, tags
        self._known = known
        self._pending = np.empty((0, 2))
        self._mixture = None

    def update_lidar(self, points: np.ndarray, null_bearings: np.ndarray | None = None) -> None:
        """GM-PHD update on ``(x, y)`` with anonymous lidar detections, then reduce.

        Unexplained detections (explained fraction < ``birth_max_explained``) become untagged
        births at the next :meth:`predict`.

        Parameters
        ----------
        points : array_like, shape (M, 2)
            Detections ``[x_m, y_m]`` in the observer frame (``M = 0`` is a valid scan).
        null_bearings : array_like, shape (B,), optional
            Bearings of zero-intensity returns (interference ``P_d`` factor).
        """
        pts = _checked_points(points)
        nulls = None if null_bearings is None else _checked_angles(null_bearings, "null_bearings")
        cfg = self.config
        w, m, p, tags = self._w, self._m, self._p, self._tags
        table = np.empty((N_ROWS, w.shape[0]))
        table[ROW_W] = w
        table[ROW_X : ROW_Y + 1] = m[:, :2].T
        table[ROW_PXX], table[ROW_PXY], table[ROW_PYY] = p[:, 0, 0], p[:, 0, 1], p[:, 1, 1]
        pd = self._model.lidar(table, nulls) if w.shape[0] else np.empty(0)
        if pts.shape[0] == 0:
            w = w * (1.0 - pd)
            explained = np.empty(0)
        else:
            w, m, p, source, explained = lidar_update_3d(
                w, m, p, pts, pd, cfg.lidar_noise_var_m2, cfg.lidar_clutter_intensity_per_m2
            )
            tags = tags[source]
        self._w, self._m, self._p, self._tags = self._reduce(w, m, p, tags)
        births = pts[explained < cfg.birth_max_explained]
        if births.shape[0] and cfg.birth_min_detection_prob > 0.0:
            probe = np.zeros((N_ROWS, births.shape[0]))
            probe[ROW_X : ROW_Y + 1] = births.T
            probe[ROW_PXX] = probe[ROW_PYY] = cfg.birth_std_m**2
            births = births[self._model.lidar(probe, nulls) >= cfg.birth_min_detection_prob]
        self._pending = births
        self._mixture = None

    def estimate(self, min_weight: float = 0.0) -> dict[int, np.ndarray]:
        """Per identity, the mean ``(x_m, y_m, psi_rad)`` of its highest-weight component.

        Parameters
        ----------
        min_weight : float
            Only identities whose best component has at least this weight are reported.

        Returns
        -------
        dict int -> ndarray (3,)
            Robot IDs ``>= 0`` and, if present, the static class ``-2``.
        """
        return {i: pose for i, (pose, _, _) in self.best_components(min_weight).items()}

    def best_components(self, min_weight: float = 0.0) -> dict[int, tuple]:
        """Per identity: ``(mean (3,), weight, cov (3, 3))`` of its highest-weight component."""
        min_weight = float(min_weight)
        if not math.isfinite(min_weight):
            raise ValueError(f"min_weight must be finite, got {min_weight!r}")
        w, tags = self._w, self._tags
        if not w.shape[0]:
            return {}
        order = np.lexsort((-w, tags))  # by tag, heaviest first
        first = np.ones(order.shape[0], dtype=bool)
        first[1:] = tags[order][1:] != tags[order][:-1]
        best = order[first]
        best = best[(w[best] >= min_weight) & (tags[best] != UNTAGGED)]
        return {int(tags[k]): (self._m[k].copy(), float(w[k]), self._p[k].copy()) for k in best}

    def identity_weights(self) -> dict[int, float]:
        """Total weight per tag (expected number of objects with that identity)."""
        out: dict[int, float] = {}
        if self._w.shape[0]:
            uniq, inverse = np.unique(self._tags, return_inverse=True)
            sums = np.bincount(inverse, weights=self._w)
            out = {int(t): float(s) for t, s in zip(uniq, sums, strict=True)}
        return out

    def _reduce(self, w, m, p, tags):
        cfg = self.config
        return reduce_tagged(
            w, m, p, tags, cfg.prune_threshold, cfg.merge_threshold, cfg.max_components
        )


# ---------------------------------------------------------------------- input checks
def _readonly(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


def _checked_delta(value: Any, name: str) -> np.ndarray:
    arr = as_float_array(value, name)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) [dx_m, dy_m, dpsi_rad], got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _checked_points(value: Any, name: str = "points") -> np.ndarray:
    pts = as_float_array(value, name)
    if pts.size == 0:
        return np.empty((0, 2))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (M, 2), got shape {pts.shape}")
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if bad.size:
        raise ValueError(f"{name} must be finite, got {name}[{bad[0]}] = {pts[bad[0]].tolist()}")
    return pts


def _checked_angles(value: Any, name: str) -> np.ndarray:
    arr = as_float_array(value, name)
    if arr.size == 0:
        return np.empty(0)
    if arr.ndim != 1:
        raise ValueError(f"{name} must have shape (M,), got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(f"{name} must be finite, got {name}[{bad[0]}] = {arr[bad[0]]!r}")
    return arr
