"""The per-robot PMB localizer: :class:`RobotCentricPMB` (numpy reference).

A track-oriented Poisson multi-Bernoulli filter (Williams 2015) in the observer's body frame:

* a **Poisson intensity** for teammates never detected (or forgotten): a Gaussian mixture, the
  ``(6, K)`` component table of :mod:`localization.mixture` (rows ``w, x, y, Pxx, Pxy, Pyy``);
* **Bernoulli tracks**, one per potential teammate: a ``(6, N)`` table with the existence
  probability ``r`` in the weight row and one Gaussian each.

Each step::

    predict:       P_s (r and w) -> frame change + Q (GM-PHD's phd.predict, both tables)
                   (+ pending measurement births into the Poisson)
    update_lidar:  (+ fixed birth into the Poisson prior) -> P_d on the PMB's first moment
                   -> Kalman likelihoods, gate -> LBP marginals -> moment-matched Bernoullis,
                   one new Bernoulli per measurement from the Poisson, Poisson missed copies
                   -> recycle r < threshold into the Poisson -> reduce the Poisson
    update_camera: the same with the GM-PHD's EKF bearing update and camera P_d, and the
                   clutter of each bearing from the last scan's wide objects (as the GM-PHD's)
    estimate:      tracks with r >= threshold

Every public method validates all of its inputs before touching any state. The derivation is in
``docs/concepts/localizers.md`` ("Poisson multi-Bernoulli (PMB) localizer").

References
----------
.. [1] J. L. Williams, "Marginal multi-Bernoulli filters: RFS derivation of MHT, JIPDA and
   association-based MeMBer", IEEE TAES 51(3), 2015.
.. [2] J. L. Williams and R. A. Lau, "Approximate evaluation of marginal association
   probabilities with belief propagation", IEEE TAES 50(4), 2014.
.. [3] J. L. Williams, "Hybrid Poisson and multi-Bernoulli filters", FUSION 2012.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import object_clutter, phd
from ..detection import DetectionModel
from ..filter import (
    RobotCentricFilter,
    _checked_angles,
    _checked_odometry,
    _shifted,
    checked_pose,
    lidar_inputs,
    ranked_above,
    read_only,
    scan_memory_of,
)
from ..frames import bearings_to_filter_frame
from ..gaussian import bearing_update, position_update
from ..mixture import (
    N_ROWS,
    ROW_PXX,
    ROW_PXY,
    ROW_PYY,
    ROW_W,
    ROW_X,
    ROW_Y,
    GaussianMixture,
    arrays_from_table,
    empty_table,
)
from ..reducer import reduce
from ..scan_memory import MEMORY_LEN
from .association import lbp_marginals
from .config import pmb_config

__all__ = ["RobotCentricPMB", "Tracks", "FLOOR"]

#: Floor of the missed-hypothesis weight ``1 - r P_d`` and of ``c_j = kappa + e_j`` before they
#: divide (both can be exactly 0: ``r = P_d = 1``; ``kappa = 0`` and no Poisson mass). With both
#: floors, ``psi <= g * 1e200`` stays finite for any likelihood ``g`` below 1e108.
FLOOR = 1e-100
_TINY = 1e-300
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class Tracks:
    """Read-only snapshot of the Bernoulli tracks.

    Attributes
    ----------
    r : ndarray, shape (N,)
        Existence probabilities in ``[0, 1]``.
    means : ndarray, shape (N, 2)
        Means ``[x_m, y_m]`` in the robot frame.
    covs : ndarray, shape (N, 2, 2)
        Covariances (m^2).
    """

    r: np.ndarray
    means: np.ndarray
    covs: np.ndarray


class RobotCentricPMB(RobotCentricFilter):
    """Robot-centric track-oriented PMB filter for teammate positions in the observer's frame.

    Parameters
    ----------
    config : PMBConfig or PHDConfig, optional
        A ``PHDConfig`` gives the shared models with the PMB defaults.
    **overrides
        PMB or PHD field values replacing those of ``config``
        (``RobotCentricPMB(mode="lidar-only", max_tracks=16)``). Unknown names raise.

    Notes
    -----
    Read access: ``.mixture`` (a :class:`GaussianMixture` whose weights are the tracks'
    existence probabilities, what the project's metrics read), ``.tracks``, ``.poisson``
    (the undetected intensity), ``.table`` (tracks as a ``(6, N)`` table).

    Bounds (``docs/concepts/localizers.md``, "Bounds on weight and cardinality"), with ``n = sum r
    +
    sum w`` (tracks plus Poisson, the expected number of teammates): ``predict`` gives
    ``n' <= P_s,max n + measurement_birth_weight B`` (``B``: detections of the last scan);
    an update with ``M`` measurements ``n' <= sum r + sum_k (1 - P_d,k) w_k + M`` (each
    measurement goes to one track or to new-or-clutter; recycling moves mass, pruning and the
    cap only remove it). Every existence is in ``[0, 1]`` (and ``>= recycle_threshold`` after
    an update), at most ``max_tracks`` tracks and ``phd.reduction.max_components`` Poisson
    components.
    """

    __slots__ = (
        "config",
        "_model",
        "_tracks",
        "_poisson",
        "_pending_births",
        "_fixed_birth",
        "_mixture",
        "_clock",
        "_scan",
    )
    TABLES = ("tracks", "poisson")

    def __init__(self, config: Any = None, **overrides: Any) -> None:
        self.config = config = pmb_config(config, overrides)
        self._model = DetectionModel(config.phd)
        self._fixed_birth = phd.birth_components(
            np.asarray([config.phd.births.mean_m], dtype=float),
            config.phd.births.std_m**2,
            config.phd.births.weight,
        )
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the empty prior: no tracks, empty Poisson intensity, no pending births."""
        self._tracks = empty_table()
        self._poisson = empty_table()
        self._pending_births = np.empty((0, 2))
        self._mixture: GaussianMixture | None = None
        self._clock = phd.ProcessClock()
        # The last lidar scan with its wide objects (localization.object_clutter), kept only
        # where the camera clutter reads them (PHDConfig.models_wide_objects).
        self._scan = np.zeros(MEMORY_LEN)

    def set_state(self, tracks: GaussianMixture, poisson: GaussianMixture | None = None) -> None:
        """Load tracks (weights = existence probabilities in ``[0, 1]``) and optionally a Poisson
        intensity (weights >= 0); clears pending births.

        Raises
        ------
        ValueError
            Non-finite values, ``r`` outside ``[0, 1]``, negative weights, non-SPD covariances,
            more than ``max_tracks`` tracks (the filter is left unchanged).
        """
        tables = []
        for name, mix in (("tracks", tracks), ("poisson", poisson)):
            if mix is None:
                tables.append(empty_table())
                continue
            if not isinstance(mix, GaussianMixture):
                raise ValueError(f"{name} must be a GaussianMixture, got {type(mix).__name__}")
            table = mix.to_table()
            w = table[ROW_W]
            if not np.isfinite(table).all():
                raise ValueError(f"{name} must be finite")
            if (w < 0).any() or (name == "tracks" and (w > 1).any()):
                raise ValueError(f"{name} weights out of range, got {w.tolist()}")
            pxx, pxy, pyy = table[ROW_PXX], table[ROW_PXY], table[ROW_PYY]
            if ((pxx <= 0) | (pxx * pyy - pxy * pxy <= 0)).any():
                raise ValueError(f"{name} covariances must be positive definite")
            tables.append(table)
        if tables[0].shape[1] > self.config.max_tracks:
            raise ValueError(
                f"tracks has {tables[0].shape[1]} tracks, more than max_tracks "
                f"{self.config.max_tracks}"
            )
        self._tracks, self._poisson = tables
        self._pending_births = np.empty((0, 2))
        self._mixture = None

    @property
    def tracks(self) -> Tracks:
        """The Bernoulli tracks: ``r (N,)``, ``means (N, 2)``, ``covs (N, 2, 2)`` (copies)."""
        r, means, covs = arrays_from_table(self._tracks)
        return Tracks(r, means, covs)

    @property
    def poisson(self) -> GaussianMixture:
        """The Poisson intensity of undetected teammates (a read-only snapshot)."""
        return GaussianMixture.from_table(self._poisson)

    @property
    def table(self) -> np.ndarray:
        """Tracks as a read-only ``(6, N)`` table, rows ``r, x, y, Pxx, Pxy, Pyy``."""
        return read_only(self._tracks)

    @property
    def poisson_table(self) -> np.ndarray:
        """Poisson intensity as a read-only ``(6, K)`` table."""
        return read_only(self._poisson)

    def __repr__(self) -> str:
        return (
            f"RobotCentricPMB(mode={self.config.phd.mode!r}, tracks={len(self)}, "
            f"sum_r={self.total_weight:.3f}, poisson={self._poisson.shape[1]})"
        )

    # ------------------------------------------------------------------ steps
    def predict(self, odometry: Any) -> None:
        """Time update with the observer's own motion (the GM-PHD's, :func:`phd.predict`).

        ``m <- R(dpsi)^T (m - d)``, ``P <- R^T P R + Q``; ``r`` and the Poisson weights are
        multiplied by ``P_s`` at the prior means. Pending measurement births join the Poisson
        intensity (``P_s = 1``, moved with the frame).

        Parameters
        ----------
        odometry : array_like, shape (3,)
            ``[dx_m, dy_m, dpsi_rad]``, in the robot frame at the start of the interval.
        """
        odo = _checked_odometry(odometry)
        cfg = self.config.phd
        q = self._predict_clock(cfg)
        tracks = phd.predict(self._tracks, odo, self._model.survival(self._tracks), q)
        self._poisson = self._predicted_with_births(self._poisson, odo, q, cfg)
        self._tracks = tracks
        self._after_predict(odo)

    def advance(self, stamp_s: float) -> None:
        """The process noise that accrued up to ``stamp_s`` (s), on the tracks and the Poisson
        intensity alike (as :meth:`localization.RobotCentricPHD.advance`)."""
        var = self._advance_clock(stamp_s, self.config.phd)
        if var > 0.0:
            self._tracks = phd.diffuse(self._tracks, var)
            self._poisson = phd.diffuse(self._poisson, var)
            self._mixture = None

    def update_lidar(
        self,
        points: Any,
        null_bearings: Any = None,
        sensor_pose: Any = None,
        scan_profile: Any = None,
    ) -> None:
        """PMB update with lidar detections (position measurements, ``H = I``).

        Parameters
        ----------
        points : array_like, shape (M, 2)
            Detections ``[x_m, y_m]``; ``M = 0`` is a scan with no detection.
        null_bearings : array_like, shape (B,), optional
            Bearings (rad) of zero-intensity returns (interference factor of ``P_d``).
        sensor_pose : array_like, shape (3,), optional
            ``[x_m, y_m, psi_rad]`` in the filter's frame the scan was taken from; points and
            null bearings are moved into the filter's frame (:mod:`localization.frames`).
        scan_profile : array_like, shape (N_BINS,), optional
            The scan's :func:`~localization.scan_memory.scan_profile` (m, 0 = unknown).
            Where the camera clutter models the wide objects
            (``PHDConfig.models_wide_objects``) it becomes the filter's scan memory with its
            wide objects, from which later camera frames take their clutter; without one
            the filter has no scan until the next.
        """
        pts, nulls, pose, profile = lidar_inputs(points, null_bearings, sensor_pose, scan_profile)
        if self.config.phd.models_wide_objects:  # the memory is kept only where it is used
            self._scan = scan_memory_of(profile, pose, True)
        cfg = self.config.phd
        poisson = self._poisson
        fixed = cfg.births.model == "fixed" and pts.shape[0] > 0
        if fixed:
            # As the GM-PHD: the Perera 2021 study's birth joins the prior of every lidar update
            # with detections; only its detected part is kept (its missed part is dropped below).
            poisson = np.concatenate((poisson, self._fixed_birth), axis=1)
        union = np.concatenate((self._tracks, poisson), axis=1)
        pd = self._model.lidar(union, nulls)
        var = cfg.lidar.noise_var_m2
        post_means, post_covs, lik = position_update(
            union[ROW_X : ROW_Y + 1], union[ROW_PXX:], pts.T, var
        )
        # Gate: q > G  <=>  N(z; m, S) * 2 pi sqrt(det S) < exp(-G / 2).
        det_s = (union[ROW_PXX] + var) * (union[ROW_PYY] + var) - union[ROW_PXY] ** 2
        scale = _TWO_PI * np.sqrt(np.maximum(det_s, _TINY))
        explained = self._update(
            union, poisson, pd, post_means, post_covs, lik, scale, cfg.lidar.clutter_intensity
        )
        if cfg.births.model == "measurement":
            self._pending_births = pts[explained < cfg.births.measurement_max_explained]

    def update_camera(self, bearings: Any, sensor_pose: Any = None) -> None:
        """PMB update with camera bearings: the GM-PHD's EKF bearing update per hypothesis.

        A no-op (after validation) in ``mode="lidar-only"``. New tracks from bearings come
        only from the Poisson intensity's own mass (see the module docs); no position is
        invented along the ray. With ``PHDConfig.births.camera="ray"`` bearings start no
        track at all: what the Poisson part explains stays in it, and the bearings nothing
        explains add their ray (``phd.ray_births``) to it, so a teammate only the camera sees
        is held as undetected mass until a lidar detection confirms it.

        Parameters
        ----------
        bearings : array_like, shape (M,)
            Bearings (rad); ``M = 0`` is a frame with no detection.
        sensor_pose : array_like, shape (3,), optional
            Pose the frame was taken from, in the filter's frame; bearings are rotated by its
            heading (:func:`localization.frames.bearings_to_filter_frame`) and the bearing
            model is evaluated from its position (the parallax, as
            :meth:`localization.RobotCentricPHD.update_camera`'s ``sensor_xy``).
        """
        brg = _checked_angles(bearings, "bearings")
        pose = checked_pose(sensor_pose)
        cfg = self.config.phd
        if cfg.mode == "lidar-only":
            return
        if pose is None or not pose[:2].any():
            if pose is not None:
                brg = bearings_to_filter_frame(brg, pose)
            self._camera_update(brg, np.zeros(2))
            return
        brg = bearings_to_filter_frame(brg, pose)
        # Seen from the camera: shift the whole state, update, shift back (the update is
        # translation-equivariant but for the sensor's own position).
        self._tracks = _shifted(self._tracks, -pose[:2])
        self._poisson = _shifted(self._poisson, -pose[:2])
        try:
            self._camera_update(brg, pose[:2])
        finally:
            self._tracks = _shifted(self._tracks, pose[:2])
            self._poisson = _shifted(self._poisson, pose[:2])
            self._mixture = None

    def _camera_update(self, brg: np.ndarray, offset: np.ndarray) -> None:
        """The update of the tracks and the Poisson intensity, whose frame is the filter's
        shifted by ``-offset`` (2,) (the camera's view; the scan memory's pose is read alike)."""
        cfg = self.config.phd
        union = np.concatenate((self._tracks, self._poisson), axis=1)
        pd = self._model.camera(union)
        means = union[ROW_X : ROW_Y + 1]
        var = cfg.camera_bearing_var(np.hypot(means[0], means[1]))  # R_C at each prior mean
        post_means, post_covs, lik = bearing_update(
            means, union[ROW_PXX:], brg, var, cfg.reduction.min_range_m
        )
        # Gate: q > G  <=>  N(nu; 0, S) * sqrt(2 pi S) < exp(-G / 2), S = H P H^T + R_C.
        inv_r2 = 1.0 / np.maximum(means[0] ** 2 + means[1] ** 2, cfg.reduction.min_range_m**2)
        j0, j1 = -means[1] * inv_r2, means[0] * inv_r2
        s = j0 * j0 * union[ROW_PXX] + 2.0 * j0 * j1 * union[ROW_PXY] + j1 * j1 * union[ROW_PYY]
        scale = np.sqrt(_TWO_PI * (s + var))
        to_poisson = cfg.births.camera == "ray"
        explained = self._update(
            union,
            self._poisson,
            pd,
            post_means,
            post_covs,
            lik,
            scale,
            object_clutter.camera_clutter(cfg, brg, self._scan, offset),  # per bearing
            births_to_poisson=to_poisson,
        )
        if to_poisson:
            # Bearings nothing explains: a teammate somewhere along the ray, undetected so
            # far. Its mass joins the Poisson part (the range prior over the camera's reach,
            # phd.ray_births); a track is born only when a lidar detection falls on it.
            unexplained = brg[explained < cfg.births.camera_max_explained]
            if unexplained.shape[0]:
                births = phd.camera_ray_births(cfg, unexplained)
                births = births[:, births[ROW_W] >= cfg.reduction.prune_threshold]
                if births.shape[1]:
                    self._poisson = reduce(
                        np.concatenate((self._poisson, births), axis=1),
                        cfg.reduction.prune_threshold,
                        cfg.reduction.merge_threshold,
                        cfg.reduction.max_components,
                    )

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Tracks with ``r >= threshold``, by decreasing ``r`` (each Bernoulli is at most one
        teammate), in the form every localizer's ``estimate`` has.

        Returns
        -------
        means : ndarray, shape (K, 2)
            Positions ``[x_m, y_m]`` in the robot frame.
        existences : ndarray, shape (K,)
            Their ``r`` (their covariances: :attr:`tracks`).
        """
        return estimate_table(self._tracks, threshold)

    # ------------------------------------------------------------------ internals
    def _update(
        self,
        union: np.ndarray,
        poisson: np.ndarray,
        pd: np.ndarray,
        post_means: np.ndarray,
        post_covs: np.ndarray,
        lik: np.ndarray,
        scale: np.ndarray,
        kappa: float | np.ndarray,
        births_to_poisson: bool = False,
    ) -> np.ndarray:
        """Track-oriented PMB update from per-component likelihoods; returns ``explained (M,)``.

        ``births_to_poisson``: the Bernoullis a measurement would start from the Poisson part
        stay in it as Poisson components, one per (component, measurement) pair, unmatched (a
        bearing says a teammate is on its ray, not where: the camera's births, with
        ``PHDConfig.births.camera="ray"``).

        ``union`` is ``[tracks | poisson]`` ``(6, N + K)`` (``poisson`` may end with the fixed
        birth, whose missed part is dropped), ``pd (N + K,)``, ``post_means (2, N + K, M)``,
        ``post_covs (3, N + K)``, ``lik (N + K, M)``, ``scale (N + K,)``: ``lik * scale`` is
        ``exp(-q / 2)`` for the gate; ``kappa`` the clutter intensity, one or per measurement
        ``(M,)``.
        """
        cfg = self.config
        n = self._tracks.shape[1]
        gate = math.exp(-0.5 * cfg.gate_mahalanobis2)
        lik = np.where(lik * scale[:, None] < gate, 0.0, lik)
        w = union[ROW_W]
        pd_w = pd * w
        # --- Poisson part: e_j, and the missed copies (1 - P_d) w.
        ew = lik[n:] * pd_w[n:, None]  # (K, M)
        e = ew.sum(axis=0)
        c = kappa + e
        # --- tracks: w_i(0) = 1 - r P_d, w_i(j) = r P_d g_ij, psi = w_i(j) / (w_i(0) c_j).
        miss = np.maximum(1.0 - pd_w[:n], FLOOR)
        psi = lik[:n] * (pd_w[:n] / miss)[:, None] / np.maximum(c, FLOOR)[None, :]
        p_track, p_unused, _ = lbp_marginals(psi, cfg.bp_max_iterations, cfg.bp_tolerance)
        # Missed: r0 = r (1 - P_d) / (1 - r P_d), density unchanged; detected: r = 1, updated.
        hyp_w = p_track.copy()
        hyp_w[:, 0] *= (w[:n] - pd_w[:n]) / miss
        hyp_means = np.concatenate((union[ROW_X : ROW_Y + 1, :n, None], post_means[:, :n]), axis=2)
        updated = _moment_match(hyp_w, hyp_means, union[ROW_PXX:, :n], post_covs[:, :n])
        # Guard: the marginals sum to 1 up to round-off, so r can exceed 1 by an ulp.
        np.minimum(updated[ROW_W], 1.0, out=updated[ROW_W])
        # --- new tracks: measurement j unused by the tracks, explained by the Poisson part.
        born = np.flatnonzero(e > 0.0)
        new = _moment_match(
            ew[:, born].T,
            post_means[:, n:, born].transpose(0, 2, 1),
            None,
            post_covs[:, n:],
        )
        new[ROW_W] = p_unused[born] * e[born] / c[born]
        # --- Poisson: missed copies; the fixed birth (beyond the stored ones) has none.
        k_stored = self._poisson.shape[1]
        missed = poisson[:, :k_stored].copy()
        missed[ROW_W] -= pd_w[n : n + k_stored]
        if births_to_poisson:
            # Each Poisson component's copy updated by each measurement it explains, weighted
            # by its share of that measurement's new Bernoulli (measurement-major): the
            # mixture is kept, not moment-matched, so a ray's range cells stay apart.
            jj, kk = np.nonzero(ew[:, born].T > 0.0)
            j = born[jj]
            det = np.empty((N_ROWS, j.size))
            det[ROW_W] = p_unused[j] * ew[kk, j] / c[j]
            det[ROW_X] = post_means[0, n + kk, j]
            det[ROW_Y] = post_means[1, n + kk, j]
            det[ROW_PXX:] = post_covs[:, n + kk]
            self._finish(updated, np.concatenate((missed, det), axis=1))
        else:
            self._finish(np.concatenate((updated, new), axis=1), missed)
        new_frac = e / np.maximum(c, _TINY)
        return 1.0 - p_unused + p_unused * new_frac

    def _finish(self, tracks: np.ndarray, poisson: np.ndarray) -> None:
        """Recycle tracks with ``r < recycle_threshold`` (and beyond ``max_tracks``) into the
        Poisson intensity, then prune / merge / cap the Poisson intensity."""
        cfg = self.config
        keep = tracks[ROW_W] >= cfg.recycle_threshold
        if np.count_nonzero(keep) > cfg.max_tracks:
            # the max_tracks largest r (ties: lower index), as reducer.cap
            order = np.argsort(-np.where(keep, tracks[ROW_W], -1.0), kind="stable")
            keep = np.zeros_like(keep)
            keep[order[: cfg.max_tracks]] = True
        poisson = np.concatenate((poisson, tracks[:, ~keep]), axis=1)
        p = cfg.phd
        self._poisson = reduce(
            poisson,
            p.reduction.prune_threshold,
            p.reduction.merge_threshold,
            p.reduction.max_components,
        )
        self._tracks = tracks[:, keep]
        self._mixture = None


def _moment_match(
    weights: np.ndarray, means: np.ndarray, first_covs: np.ndarray | None, covs: np.ndarray
) -> np.ndarray:
    """One Gaussian per row of a mixture, by moment matching (two passes, no cancellation).

    Parameters
    ----------
    weights : ndarray, shape (A, H)
        Hypothesis weights (row sums may be < 1; the output weight row is the sum).
    means : ndarray, shape (2, A, H)
    first_covs : ndarray, shape (3, A), or None
        Covariance of hypothesis 0 of each row when it differs from the others (a track's
        missed hypothesis keeps the prior); None: ``covs`` is per hypothesis.
    covs : ndarray, shape (3, A) or (3, H)
        Covariance of hypotheses 1.. of each row (tracks: the updated covariance of the
        track), or of each hypothesis (new tracks: ``(3, H)``, one per Poisson component).

    Returns
    -------
    ndarray, shape (6, A)
        Weight ``W = sum_h w``, mean ``sum_h w m_h / W``,
        covariance ``sum_h w (P_h + (m_h - mean)(m_h - mean)^T) / W``.
    """
    a = weights.shape[0]
    out = np.empty((N_ROWS, a))
    total = weights.sum(axis=1)
    out[ROW_W] = total
    inv = 1.0 / np.maximum(total, _TINY)  # an all-zero row gets a zero mean (r = 0: dropped)
    mean = (weights * means).sum(axis=2) * inv
    out[ROW_X : ROW_Y + 1] = mean
    d = means - mean[:, :, None]
    spread = np.stack((d[0] * d[0], d[0] * d[1], d[1] * d[1]))  # (3, A, H)
    if first_covs is None:
        cov = (weights * (spread + covs[:, None, :])).sum(axis=2)
    else:
        cov = (weights * spread).sum(axis=2)
        cov += weights[:, 0] * first_covs + weights[:, 1:].sum(axis=1) * covs
    out[ROW_PXX:] = cov * inv
    return out


def estimate_table(table: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """``(means (K, 2), existences (K,))`` of the tracks of ``table`` with ``r >= threshold``,
    by decreasing ``r`` (ties: lower index). Each Bernoulli is at most one teammate."""
    keep = ranked_above(table[ROW_W], threshold)
    existences, means, _ = arrays_from_table(table[:, keep])
    return means, existences
