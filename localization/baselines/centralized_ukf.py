"""The IR-UKF study's centralized tracker: one UKF per robot, all in one global frame.

The IR-UKF study (Sec. III-B): a central controller runs a UKF per robot, state ``(x, y, psi)``
in a global frame (the frame of the direct estimate that initialises it):

- *predict*: differential-drive motion from the robot's own odometry increment
  ``(dx, dy, dpsi)`` (body frame at the interval's start, :class:`swarm_core.records.
  OdometryRecord`): ``p' = p + R(psi) (dx, dy)``, ``psi' = psi + dpsi``, pushed through the
  unscented transform, plus diagonal process noise. The study's noise: sigma 0.1 cm in position and
  0.02 rad in heading per 1/30 s predict step (it predicted at 30 Hz), scaled here to the actual
  interval as a random walk (variance proportional to time).
- *update*: robot ``i`` measures robots ``S_i``; the others' current estimates are treated as
  known landmarks (the IR-UKF study's "landmark measurement model", eq. 4):
  ``rho = ||m_j - p_i||``, ``b = atan2`` of ``m_j - p_i`` in ``i``'s frame, with the bearing
  residual wrapped to ``[-pi, pi)``. The study zeroes the residual of robots not seen in a
  sweep; here they are removed exactly (their rows have no sigma spread and no residual, so the
  gain ignores them). Where the study treats the landmark as exact, its position variance is added
  to the reading's (range: ``+ tr(P_j) / 2``, bearing: ``+ tr(P_j) / (2 rho^2)``), so that an
  uncertain teammate does not pull hard.
- sigma points: Van der Merwe's scaled set, ``2n + 1 = 7`` points (``alpha``, ``beta``,
  ``kappa`` as the study/FilterPy).

Every robot's filter is one slice of ``(N, ...)`` arrays: no Python loop over robots or sigma
points. Readings of one batch update every observer at once from the prior estimates.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from localization.gaussian import wrap_angle
from swarm_core.validation import check_non_negative, check_positive

from ..config import config_with_overrides
from .ukf import _pose_mean, _psd, merwe_weights, sigma_points

__all__ = ["CentralizedUKF", "CentralizedUKFConfig"]


@dataclass(frozen=True, slots=True)
class CentralizedUKFConfig:
    """Parameters (units in the names). Defaults: the IR-UKF study's choices (Sec. II-B): range
    sigma 18.6 cm (the outlier-skewed value it adopted), bearing sigma 5 deg ("a few degrees";
    the text we have lost its figure), motion sigma 0.1 cm and 0.02 rad per 1/30 s step."""

    range_std_m: float = 0.186
    bearing_std_rad: float = math.radians(5.0)
    motion_std_m: float = 0.001
    motion_std_rad: float = 0.02
    motion_period_s: float = 1.0 / 30.0
    init_position_std_m: float = 0.1
    init_heading_std_rad: float = 0.2
    alpha: float = 0.1
    beta: float = 2.0
    kappa: float = 0.0
    landmark_uncertainty: bool = True

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "landmark_uncertainty":
                if not isinstance(value, bool):
                    raise ValueError(f"landmark_uncertainty must be True or False, got {value!r}")
            elif f.name in ("beta", "kappa", "motion_std_m", "motion_std_rad"):
                check_non_negative(f.name, value)
            else:
                check_positive(f.name, value)


class CentralizedUKF:
    """One UKF per robot in a shared global frame (IR-UKF study).

    ``initialize(poses)``, ``predict(deltas, dt_s)``, ``update(observer, target, range_m,
    bearing_rad)``; ``poses`` (N, 3) and ``covs`` (N, 3, 3) are the current estimate.
    """

    def __init__(self, config: CentralizedUKFConfig | None = None, **overrides: Any) -> None:
        self.config = config_with_overrides(config, CentralizedUKFConfig, overrides)
        cfg = self.config
        self._wm, self._wc, self._lam = merwe_weights(3, cfg.alpha, cfg.beta, cfg.kappa)
        self._x = np.zeros((0, 3))
        self._p = np.zeros((0, 3, 3))

    @property
    def n_robots(self) -> int:
        return int(self._x.shape[0])

    @property
    def poses(self) -> np.ndarray:
        return self._x.copy()

    @property
    def covs(self) -> np.ndarray:
        return self._p.copy()

    def initialize(self, poses: np.ndarray, covs: np.ndarray | None = None) -> None:
        """Start every filter at ``poses`` (N, 3) (e.g. the direct estimate) with ``covs``
        (N, 3, 3), default diagonal from ``init_position_std_m`` / ``init_heading_std_rad``."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3 or not np.isfinite(poses).all():
            raise ValueError(f"poses must be finite of shape (N, 3), got {poses.shape}")
        n = poses.shape[0]
        if covs is None:
            cfg = self.config
            d = [cfg.init_position_std_m**2] * 2 + [cfg.init_heading_std_rad**2]
            covs = np.broadcast_to(np.diag(d), (n, 3, 3))
        covs = np.asarray(covs, dtype=np.float64)
        if covs.shape != (n, 3, 3) or not np.isfinite(covs).all():
            raise ValueError(f"covs must be finite of shape ({n}, 3, 3), got {covs.shape}")
        if (np.linalg.eigvalsh(0.5 * (covs + covs.transpose(0, 2, 1))) <= 0).any():
            raise ValueError("covs must be positive definite")
        self._x = poses.copy()
        self._x[:, 2] = wrap_angle(self._x[:, 2])
        self._p = covs.copy()

    def _check_ready(self) -> None:
        if not self.n_robots:
            raise RuntimeError("CentralizedUKF used before initialize()")

    def predict(self, deltas: np.ndarray, dt_s: float) -> None:
        """Move every robot by its odometry increment ``deltas`` (N, 3) ``[dx_m, dy_m,
        dpsi_rad]`` (body frame at the start), over ``dt_s`` seconds (scales the noise)."""
        self._check_ready()
        deltas = np.asarray(deltas, dtype=np.float64)
        if deltas.shape != (self.n_robots, 3) or not np.isfinite(deltas).all():
            raise ValueError(
                f"deltas must be finite of shape ({self.n_robots}, 3), got {deltas.shape}"
            )
        if isinstance(dt_s, bool) or not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a finite number > 0, got {dt_s!r}")
        cfg = self.config
        pts = sigma_points(self._x, self._p, self._lam)  # (N, 7, 3)
        c, s = np.cos(pts[..., 2]), np.sin(pts[..., 2])
        dx, dy = deltas[:, None, 0], deltas[:, None, 1]
        moved = np.empty_like(pts)
        moved[..., 0] = pts[..., 0] + c * dx - s * dy
        moved[..., 1] = pts[..., 1] + s * dx + c * dy
        moved[..., 2] = wrap_angle(pts[..., 2] + deltas[:, None, 2])
        mean = _pose_mean(moved, self._wm)
        d = moved - mean[:, None, :]
        d[..., 2] = wrap_angle(d[..., 2])
        scale = dt_s / cfg.motion_period_s
        q = np.diag([cfg.motion_std_m**2, cfg.motion_std_m**2, cfg.motion_std_rad**2]) * scale
        self._x = mean
        self._p = _psd(np.einsum("s,nsi,nsj->nij", self._wc, d, d) + q)

    def update(self, observer, target, range_m, bearing_rad) -> None:
        """Fuse identified readings (K,) each: robot ``observer`` saw robot ``target`` at
        ``range_m``, ``bearing_rad`` (its body frame). Each reading updates its observer's
        filter, the target's current estimate standing in as a landmark. A pair given twice
        keeps its last reading."""
        self._check_ready()
        n = self.n_robots
        obs = np.asarray(observer)
        tgt = np.asarray(target)
        rho = np.asarray(range_m, dtype=np.float64)
        brg = np.asarray(bearing_rad, dtype=np.float64)
        k = obs.shape[0] if obs.ndim == 1 else -1
        for name, arr in (
            ("observer", obs),
            ("target", tgt),
            ("range_m", rho),
            ("bearing_rad", brg),
        ):
            if arr.ndim != 1 or arr.shape[0] != k:
                raise ValueError(f"{name} must be 1-D of the readings' length, got {arr.shape}")
        if not k:
            return
        for name, arr in (("observer", obs), ("target", tgt)):
            if not np.issubdtype(arr.dtype, np.integer) or arr.min() < 0 or arr.max() >= n:
                raise ValueError(f"{name} must hold robot indices in [0, {n}), got {arr!r}")
        if (obs == tgt).any():
            raise ValueError("a reading's observer and target must differ")
        if not (np.isfinite(rho).all() and np.isfinite(brg).all()) or (rho < 0).any():
            raise ValueError("range_m must be finite and >= 0, bearing_rad finite")
        cfg = self.config
        rows = np.unique(obs)  # observers updated, (M,)
        row_of = np.full(n, -1)
        row_of[rows] = np.arange(rows.shape[0])
        m = rows.shape[0]
        mask = np.zeros((m, n), dtype=bool)
        z = np.zeros((m, n, 2))
        mask[row_of[obs], tgt] = True
        z[row_of[obs], tgt, 0] = rho
        z[row_of[obs], tgt, 1] = brg

        x, p = self._x[rows], self._p[rows]
        pts = sigma_points(x, p, self._lam)  # (M, S, 3)
        lm = self._x[:, :2]  # landmarks: every robot's prior position (N, 2)
        d = lm[None, None, :, :] - pts[:, :, None, :2]  # (M, S, N, 2)
        c, s = np.cos(pts[..., 2])[..., None], np.sin(pts[..., 2])[..., None]
        bx, by = c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]
        hz = np.stack((np.hypot(bx, by), np.arctan2(by, bx)), axis=-1)  # (M, S, N, 2)
        # Unseen targets: constant prediction (no spread, no residual) -> zero gain.
        hz = np.where(mask[:, None, :, None], hz, 0.0)
        zmean = np.einsum("s,msnk->mnk", self._wm, hz)
        ref = hz[:, 0, :, 1]
        zmean[..., 1] = wrap_angle(
            ref + np.einsum("s,msn->mn", self._wm, wrap_angle(hz[..., 1] - ref[:, None, :]))
        )
        dz = hz - zmean[:, None]
        dz[..., 1] = wrap_angle(dz[..., 1])
        dz = dz.reshape(m, -1, 2 * n)  # (M, S, 2N): [rho_0, b_0, rho_1, b_1, ...]
        dxs = pts - x[:, None, :]
        dxs[..., 2] = wrap_angle(dxs[..., 2])

        r_var = np.full((m, n), cfg.range_std_m**2)
        b_var = np.full((m, n), cfg.bearing_std_rad**2)
        if cfg.landmark_uncertainty:
            lm_var = 0.5 * (self._p[:, 0, 0] + self._p[:, 1, 1])  # (N,)
            r_var = r_var + lm_var[None, :]
            b_var = b_var + lm_var[None, :] / np.maximum(zmean[..., 0], 0.05) ** 2
        rdiag = np.stack((np.where(mask, r_var, 1.0), np.where(mask, b_var, 1.0)), -1)
        pzz = np.einsum("s,msi,msj->mij", self._wc, dz, dz)
        pzz[:, np.arange(2 * n), np.arange(2 * n)] += rdiag.reshape(m, 2 * n)
        pxz = np.einsum("s,msi,msj->mij", self._wc, dxs, dz)  # (M, 3, 2N)
        resid = z - zmean
        resid[..., 1] = wrap_angle(resid[..., 1])
        resid = np.where(mask[..., None], resid, 0.0).reshape(m, 2 * n)
        gain = np.linalg.solve(pzz, pxz.transpose(0, 2, 1)).transpose(0, 2, 1)  # (M, 3, 2N)
        x_new = x + np.einsum("mij,mj->mi", gain, resid)
        x_new[:, 2] = wrap_angle(x_new[:, 2])
        p_new = p - np.einsum("mij,mjk,mlk->mil", gain, pzz, gain)
        self._x[rows] = x_new
        self._p[rows] = _psd(p_new)
