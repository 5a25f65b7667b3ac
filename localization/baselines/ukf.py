"""The IR-UKF study's tracking baseline: one UKF per identified teammate, range-bearing updates.

The IR-UKF study (a low-cost swarm with IR range-bearing sensing that carries identities) tracks
every robot with its own unscented Kalman filter: a differential-drive motion model, and the
range-bearing landmark model of Labbe's FilterPy book with a **wrapped angle residual**. It
runs them on a central computer in a global frame. Here the same filters run on the observer,
in its body frame (the robot-centric setting of this project):

* state per teammate ``(x_m, y_m, psi_rad)`` in the observer frame;
* motion: the teammate's communicated differential-drive increment ``u_i`` composed with the
  observer's own increment ``u_0`` (the map of :func:`localization.id_phd.compose_relative`),
  passed through the sigma points; additive noise
  ``Q = diag(s_t^2 + s_t0^2 + s_r0^2 |p|^2, same, s_r^2 + s_r0^2)``;
* measurement ``h(x) = (||p||, atan2(y, x))``, ``R = diag(range_std_m^2, bearing_std_rad^2)``;
  innovation and sigma-point spreads of the bearing are wrapped to ``[-pi, pi)``, headings
  are averaged about the central sigma point;
* Van der Merwe scaled sigma points (``2n + 1 = 7``; ``alpha``, ``beta``, ``kappa`` in the
  config).

A track starts at its first measurement (position from range and bearing, heading unknown:
``psi = 0`` with std ``init_heading_std_rad``, the heading is then learnt from the odometry
composition), and is dropped when its position std exceeds ``drop_position_std_m``. All
teammates are advanced at once (arrays over tracks x sigma points; no Python loop over tracks).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from localization.gaussian import wrap_angle
from localization.mixture import GaussianMixture
from swarm_core.validation import check_non_negative, check_number

from ..config import config_with_overrides
from ._common import (
    checked_odometry,
    checked_range_bearing,
    compose_poses,
    extract,
    track_mixture,
)

__all__ = ["UKFConfig", "UKFTracker"]


@dataclass(frozen=True, slots=True)
class UKFConfig:
    """UKF tracker parameters (units in the names), validated on construction."""

    own_odometry_std_m: float = 0.005
    own_odometry_std_rad: float = 0.01
    teammate_odometry_std_m: float = 0.005
    teammate_odometry_std_rad: float = 0.01
    range_std_m: float = 0.05
    bearing_std_rad: float = 0.05
    init_position_std_m: float = 0.1
    init_heading_std_rad: float = math.pi
    drop_position_std_m: float = 1.0
    alpha: float = 0.5
    beta: float = 2.0
    kappa: float = 0.0
    state_dim: int = 3

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name == "state_dim":
                check_number(f.name, self.state_dim, integer=True, low=3)
                if self.state_dim != 3:
                    raise ValueError(f"state_dim must be 3, got {self.state_dim!r}")
            elif f.name in ("beta", "kappa"):
                check_non_negative(f.name, getattr(self, f.name))
            else:  # odometry noise may be 0; every other std and alpha must be > 0
                check_number(f.name, getattr(self, f.name), low=0, above="odometry" not in f.name)


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """Van der Merwe's scaled sigma-point weights ``(Wm, Wc)`` and ``lambda``."""
    lam = alpha * alpha * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1.0 - alpha * alpha + beta
    return wm, wc, lam


def sigma_points(means: np.ndarray, covs: np.ndarray, lam: float) -> np.ndarray:
    """``(T, 2n + 1, n)`` sigma points: ``x``, ``x +- cols of sqrt((n + lambda) P)``."""
    n = means.shape[-1]
    root = np.linalg.cholesky((n + lam) * covs)  # (T, n, n), lower: columns are the offsets
    offsets = root.transpose(0, 2, 1)  # rows = columns of the root
    return np.concatenate(
        (means[:, None, :], means[:, None, :] + offsets, means[:, None, :] - offsets), axis=1
    )


def _pose_mean(points: np.ndarray, wm: np.ndarray) -> np.ndarray:
    """Weighted mean of ``(T, S, 3)`` poses; the heading averaged about the central point."""
    mean = np.einsum("s,tsk->tk", wm, points)
    ref = points[:, 0, 2]
    mean[:, 2] = wrap_angle(
        ref + np.einsum("s,ts->t", wm, wrap_angle(points[:, :, 2] - ref[:, None]))
    )
    return mean


def _psd(covs: np.ndarray, floor: float = 1e-12) -> np.ndarray:
    """Symmetrise and floor the eigenvalues (guards the Cholesky of the next sigma points)."""
    covs = 0.5 * (covs + covs.transpose(0, 2, 1))
    vals, vecs = np.linalg.eigh(covs)
    if (vals > floor).all():
        return covs
    vals = np.maximum(vals, floor)
    return np.einsum("tij,tj,tkj->tik", vecs, vals, vecs)


class UKFTracker:
    """One UKF per identified teammate, in the observer's body frame (IR-UKF study).

    ``predict(own_odometry, teammate_odometry)``, ``update(measurements)`` with
    ``{id: (range_m, bearing_rad)}``, ``estimate() -> {id: (x, y, psi)}``, ``mixture``.

    Bounds: one unit-weight component per track, so weight = count = the number of distinct
    IDs measured and not yet dropped (``drop_position_std_m``); ``update`` adds exactly the new
    IDs, ``predict`` can only drop. With the oracle of :mod:`localization.registry` the IDs are
    teammates: at most ``n_robots - 1``.
    """

    def __init__(self, config: UKFConfig | None = None, **overrides: Any) -> None:
        self.config = config = config_with_overrides(config, UKFConfig, overrides)
        self._wm, self._wc, self._lam = merwe_weights(3, config.alpha, config.beta, config.kappa)
        self.reset()

    def reset(self) -> None:
        self._ids = np.empty(0, dtype=np.int64)
        self._x = np.empty((0, 3))
        self._p = np.empty((0, 3, 3))
        self._mixture: GaussianMixture | None = None

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(int(i) for i in self._ids)

    @property
    def covs(self) -> np.ndarray:
        return self._p.copy()

    def predict(
        self, own_odometry: np.ndarray, teammate_odometry: dict[int, np.ndarray] | None = None
    ) -> None:
        """Unscented time update of every track (a missing teammate increment counts as 0)."""
        own, team = checked_odometry(own_odometry, teammate_odometry)
        cfg = self.config
        if not self._ids.shape[0]:
            return
        delta = np.array([team.get(int(i), np.zeros(3)) for i in self._ids])
        pts = sigma_points(self._x, self._p, self._lam)  # (T, 7, 3)
        moved = compose_poses(pts, delta[:, None, :], own)
        mean = _pose_mean(moved, self._wm)
        d = moved - mean[:, None, :]
        d[..., 2] = wrap_angle(d[..., 2])
        cov = np.einsum("s,tsi,tsj->tij", self._wc, d, d)
        r2 = mean[:, 0] ** 2 + mean[:, 1] ** 2
        q_xy = (
            cfg.teammate_odometry_std_m**2
            + cfg.own_odometry_std_m**2
            + cfg.own_odometry_std_rad**2 * r2
        )
        cov[:, 0, 0] += q_xy
        cov[:, 1, 1] += q_xy
        cov[:, 2, 2] += cfg.teammate_odometry_std_rad**2 + cfg.own_odometry_std_rad**2
        self._x, self._p = mean, _psd(cov)
        alive = np.sqrt(0.5 * (self._p[:, 0, 0] + self._p[:, 1, 1])) <= cfg.drop_position_std_m
        if not alive.all():
            self._ids, self._x, self._p = self._ids[alive], self._x[alive], self._p[alive]
        self._mixture = None

    def update(self, measurements: dict[int, np.ndarray] | None) -> None:
        """Range-bearing update of the measured tracks; unknown IDs start new tracks."""
        meas = checked_range_bearing(measurements)
        cfg = self.config
        if not meas:
            return
        ids = np.array(sorted(meas), dtype=np.int64)
        z = np.array([meas[int(i)] for i in ids])  # (K, 2)
        known = np.isin(ids, self._ids)
        if known.any():
            order = np.argsort(self._ids)
            rows = order[np.searchsorted(self._ids[order], ids[known])]
            x, p = self._x[rows], self._p[rows]
            pts = sigma_points(x, p, self._lam)
            zs = np.stack(
                (np.hypot(pts[..., 0], pts[..., 1]), np.arctan2(pts[..., 1], pts[..., 0])), -1
            )
            zhat = np.einsum("s,tsk->tk", self._wm, zs)
            ref = zs[:, 0, 1]
            zhat[:, 1] = wrap_angle(
                ref + np.einsum("s,ts->t", self._wm, wrap_angle(zs[..., 1] - ref[:, None]))
            )
            dz = zs - zhat[:, None, :]
            dz[..., 1] = wrap_angle(dz[..., 1])
            dx = pts - x[:, None, :]
            dx[..., 2] = wrap_angle(dx[..., 2])
            s = np.einsum("s,tsi,tsj->tij", self._wc, dz, dz)
            s[:, 0, 0] += cfg.range_std_m**2
            s[:, 1, 1] += cfg.bearing_std_rad**2
            pxz = np.einsum("s,tsi,tsj->tij", self._wc, dx, dz)
            gain = np.linalg.solve(s, pxz.transpose(0, 2, 1)).transpose(0, 2, 1)  # P_xz S^-1
            innov = z[known] - zhat
            innov[:, 1] = wrap_angle(innov[:, 1])
            x = x + np.einsum("tij,tj->ti", gain, innov)
            x[:, 2] = wrap_angle(x[:, 2])
            p = p - np.einsum("tij,tjk,tlk->til", gain, s, gain)
            self._x[rows], self._p[rows] = x, _psd(p)
        if (~known).any():
            zn = z[~known]
            n = zn.shape[0]
            x = np.zeros((n, 3))
            x[:, 0] = zn[:, 0] * np.cos(zn[:, 1])
            x[:, 1] = zn[:, 0] * np.sin(zn[:, 1])
            p = np.zeros((n, 3, 3))
            p[:, 0, 0] = p[:, 1, 1] = cfg.init_position_std_m**2
            p[:, 2, 2] = cfg.init_heading_std_rad**2
            self._ids = np.concatenate((self._ids, ids[~known]))
            self._x = np.concatenate((self._x, x))
            self._p = np.concatenate((self._p, p))
        self._mixture = None

    def estimate(self) -> dict[int, np.ndarray]:
        """``{id: (x_m, y_m, psi_rad)}`` of every live track."""
        return {int(i): self._x[k].copy() for k, i in enumerate(self._ids)}

    @property
    def mixture(self) -> GaussianMixture:
        """One unit-weight component per track (position marginal)."""
        if self._mixture is None:
            self._mixture = track_mixture(self._x[:, :2].copy(), self._p[:, :2, :2].copy())
        return self._mixture

    def extract(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return extract(self.mixture, threshold)
