"""One particle filter per teammate over its relative pose (Stegagno 2012 section 6.2).

State ``x_j = (z_j, theta_j)``: teammate ``j``'s pose in the observer's body frame, ``P``
particles, vectorised (no loop over particles).

- Own motion (eq. 13): ``x_j <- x_j (-) (u_i (+) n)``: the observer moved by ``u_i``.
- Teammate motion (eq. 15): ``x_j <- x_j (+) (u_j (+) n)``, with ``u_j = v_j^t (-) v_j^t'`` from
  two of ``j``'s communicated odometry poses (a gap in the radio is bridged the same way).
- Measurement (eq. 17): the registration hypotheses ``{x_hat}`` are equally likely:
  ``w <- w * sum_h N(x_hat_h - x; S_h)`` (angle residual wrapped), ``S_h`` the registration
  covariance plus a floor for what it leaves out (the two robots' scans are up to a scan period
  apart). Then systematic resampling when the effective sample size falls below half, and a few
  particles re-seeded from the hypotheses, which lets the filter survive kidnapping.
- The fitness of a candidate (eq. 11) is ``sum_p w_p N(x_hat - x_p; S)``.

Odometry noise per increment of length ``d`` and turn ``dpsi``: std ``trans_per_m * d + floor``
on x and y and ``rot_per_m * d + rot_per_rad |dpsi| + floor`` on theta (measured in ``lab-3m-4``:
translation 0.9 % of distance, heading 0.35 rad per metre, robust statistics of the wheel
odometry against ground truth; see docs/how-to/studies/stegagno2012.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from swarm_core.geometry import wrap_angle

from .se2 import compose, inverse_compose

__all__ = [
    "MotionNoise",
    "TeammateParticles",
    "gaussian_log_density",
    "odometry_noise",
    "weighted_moments",
]


@dataclass(frozen=True, slots=True)
class MotionNoise:
    """Odometry noise model (std per increment), see the module docstring."""

    trans_per_m: float = 0.01
    rot_per_m: float = 0.35
    rot_per_rad: float = 0.05
    trans_floor_m: float = 1e-4
    rot_floor_rad: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("trans_per_m", "rot_per_m", "rot_per_rad", "trans_floor_m", "rot_floor_rad"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"motion_noise.{name} must be a finite number >= 0, got {v!r}")


def odometry_noise(delta: np.ndarray, noise: MotionNoise, n: int, rng: np.random.Generator):
    """``n`` noisy copies (n, 3) of the increment ``delta`` (3,)."""
    d = math.hypot(delta[0], delta[1])
    s_t = noise.trans_per_m * d + noise.trans_floor_m
    s_r = noise.rot_per_m * d + noise.rot_per_rad * abs(delta[2]) + noise.rot_floor_rad
    out = np.empty((n, 3))
    out[:, 0:2] = delta[:2] + s_t * rng.standard_normal((n, 2))
    out[:, 2] = delta[2] + s_r * rng.standard_normal(n)
    return out


def gaussian_log_density(residual: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``log N(r; 0, S)`` for residuals (..., H, 3) and covariances (H, 3, 3): (..., H)."""
    chol = np.linalg.cholesky(covariance)  # (H, 3, 3)
    # Solve L y = r for every residual: broadcast the H triangular systems.
    r = np.moveaxis(residual, -2, 0)  # (H, ..., 3)
    shp = r.shape
    r2 = r.reshape(shp[0], -1, 3).transpose(0, 2, 1)  # (H, 3, N)
    y = np.linalg.solve(chol, r2)  # (H, 3, N)
    maha = (y**2).sum(axis=1).reshape(shp[:-1])  # (H, ...)
    logdet = 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(-1)  # (H,)
    out = -0.5 * (
        maha + logdet.reshape((-1,) + (1,) * (maha.ndim - 1)) + 3 * math.log(2 * math.pi)
    )
    return np.moveaxis(out, 0, -1)


def weighted_moments(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (3,) (circular in theta) and covariance (3, 3) (theta residuals wrapped about the
    circular mean) of pose particles ``x`` (P, 3) with normalised weights ``w`` (P,)."""
    th = math.atan2(float(w @ np.sin(x[:, 2])), float(w @ np.cos(x[:, 2])))
    mean = np.array([float(w @ x[:, 0]), float(w @ x[:, 1]), th])
    d = x - mean
    d[:, 2] = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
    return mean, (d * w[:, None]).T @ d


class TeammateParticles:
    """The particle belief about one teammate's relative pose.

    Parameters
    ----------
    n_particles : int
    motion_noise : MotionNoise
    measurement_floor : ndarray, shape (3,)
        Std added to every registration hypothesis ``[m, m, rad]``.
    reseed_fraction : float
        Share of the particles redrawn from the hypotheses at each measurement update.
    rng : numpy Generator
    """

    def __init__(
        self,
        n_particles: int,
        motion_noise: MotionNoise,
        measurement_floor: np.ndarray,
        reseed_fraction: float,
        rng: np.random.Generator,
    ) -> None:
        self.n = int(n_particles)
        self.noise = motion_noise
        self.floor = np.diag(np.asarray(measurement_floor, dtype=np.float64) ** 2)
        self.reseed_fraction = float(reseed_fraction)
        self.rng = rng
        self.x = np.zeros((self.n, 3))
        self.logw = np.full(self.n, -math.log(self.n))
        self.initialized = False

    # ------------------------------------------------------------------ motion
    def predict_own(self, delta: np.ndarray) -> None:
        """Eq. 13: the observer moved by ``delta`` (3,) in its body frame."""
        if self.initialized:
            self.x = inverse_compose(self.x, odometry_noise(delta, self.noise, self.n, self.rng))

    def predict_teammate(self, delta: np.ndarray) -> None:
        """Eq. 15: the teammate moved by ``delta`` (3,) in its own body frame."""
        if self.initialized:
            self.x = compose(self.x, odometry_noise(delta, self.noise, self.n, self.rng))

    # ------------------------------------------------------------------ measurement
    def _covs(self, covariances: np.ndarray) -> np.ndarray:
        return np.asarray(covariances, dtype=np.float64).reshape(-1, 3, 3) + self.floor

    def _sample(self, poses: np.ndarray, covs: np.ndarray, n: int) -> np.ndarray:
        h = self.rng.integers(0, len(poses), n)
        chol = np.linalg.cholesky(covs)
        x = poses[h] + np.einsum("nij,nj->ni", chol[h], self.rng.standard_normal((n, 3)))
        x[:, 2] = wrap_angle(x[:, 2])
        return x

    def initialize(self, poses: np.ndarray, covariances: np.ndarray) -> None:
        """Prior from the first hypotheses (the thesis's "first measurements")."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        self.x = self._sample(poses, self._covs(covariances), self.n)
        self.logw[:] = -math.log(self.n)
        self.initialized = True

    def log_likelihood(self, poses: np.ndarray, covariances: np.ndarray) -> np.ndarray:
        """Eq. 17 per particle (P,): ``log (1/H) sum_h N(x_hat_h - x_p; S_h)``."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        r = poses[None, :, :] - self.x[:, None, :]  # (P, H, 3)
        r[..., 2] = wrap_angle(r[..., 2])
        ll = gaussian_log_density(r, self._covs(covariances))  # (P, H)
        return logsumexp(ll, axis=1) - math.log(len(poses))

    def log_fitness(self, poses: np.ndarray, covariances: np.ndarray) -> np.ndarray | None:
        """Eq. 11 for each candidate (H,): ``log sum_p w_p N(x_hat_h - x_p; S_h)``; ``None`` while
        uninformed."""
        if not self.initialized:
            return None
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        r = poses[None, :, :] - self.x[:, None, :]
        r[..., 2] = wrap_angle(r[..., 2])
        ll = gaussian_log_density(r, self._covs(covariances))  # (P, H)
        return logsumexp(ll + self.logw[:, None], axis=0)

    def min_mahalanobis2(self, poses: np.ndarray, covariances: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance (H,) of each candidate's **position** to the nearest
        particle's, under the candidate's position covariance (the belief's gate; ``inf`` while
        uninformed). Headings are left out: a teammate's heading is what its wheel odometry gets
        most wrong (slip), so a heading mismatch alone is no reason to reject a registration."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if not self.initialized:
            return np.full(len(poses), np.inf)
        cov = self._covs(covariances)[:, :2, :2]  # (H, 2, 2)
        inv = np.linalg.inv(cov)
        r = poses[None, :, :2] - self.x[:, None, :2]  # (P, H, 2)
        return np.einsum("phi,hij,phj->ph", r, inv, r).min(axis=0)

    def update(self, poses: np.ndarray, covariances: np.ndarray) -> None:
        """Measurement update with the hypotheses, resampling, re-seeding."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(poses) == 0:
            return
        if not self.initialized:
            self.initialize(poses, covariances)
            return
        logw = self.logw + self.log_likelihood(poses, covariances)
        total = logsumexp(logw, axis=0)
        if not np.isfinite(total):  # no particle explains it: start again from the hypotheses
            self.initialize(poses, covariances)
            return
        self._reweight_resample_reseed(
            logw - total, lambda k: self._sample(poses, self._covs(covariances), k)
        )

    def _reweight_resample_reseed(self, logw: np.ndarray, draw) -> None:
        """Take the normalised log-weights ``logw`` (P,), resample (systematic) when the effective
        sample size falls below half, then redraw ``reseed_fraction`` of the particles with
        ``draw(k) -> (k, 3)`` (called after resampling and before the redrawn rows are replaced,
        so it sees the resampled belief)."""
        self.logw = logw
        w = np.exp(self.logw)
        if 1.0 / float((w**2).sum()) < 0.5 * self.n:
            self._resample(w)
        k = int(round(self.reseed_fraction * self.n))
        if k:
            idx = self.rng.choice(self.n, size=k, replace=False)
            self.x[idx] = draw(k)
            self.logw[idx] = -math.log(self.n)
            self.logw -= logsumexp(self.logw, axis=0)

    def _resample(self, w: np.ndarray) -> None:
        """Systematic resampling."""
        u = (self.rng.random() + np.arange(self.n)) / self.n
        idx = np.minimum(np.searchsorted(np.cumsum(w), u), self.n - 1)
        self.x = self.x[idx]
        self.logw[:] = -math.log(self.n)

    # ------------------------------------------------------------------ bearing-only (ch. 10.4)
    def _bearing_ll(self, xis: np.ndarray, std: np.ndarray) -> np.ndarray:
        """(P, H) ``log N(bearing(x) - beta_h; s_b) + log N(theta - theta_h; s_t)``."""
        bearing = np.arctan2(self.x[:, 1], self.x[:, 0])
        rb = wrap_angle(bearing[:, None] - xis[None, :, 0]) / std[0]
        rt = wrap_angle(self.x[:, None, 2] - xis[None, :, 1]) / std[1]
        return -0.5 * (rb**2 + rt**2) - math.log(2 * math.pi * std[0] * std[1])

    def _sample_bearing(
        self,
        xis: np.ndarray,
        std: np.ndarray,
        n: int,
        range_m,
        ranges: np.ndarray | None = None,
        scales: np.ndarray | None = None,
    ) -> np.ndarray:
        """Particles on the hypotheses' rays, range uniform in ``range_m`` (scale unknown),
        drawn from ``ranges`` (the current belief's, so that re-seeding does not bias them), or,
        with ``scales`` (H,), at each hypothesis's scale of eq. 18 with the relative spread
        ``s_b`` of :meth:`scale_search`'s model (``scales`` take precedence)."""
        h = self.rng.integers(0, len(xis), n)
        if scales is not None:
            r = np.asarray(scales, dtype=np.float64)[h] * (
                1.0 + std[0] * self.rng.standard_normal(n)
            )
            r = np.maximum(r, 1e-3)
        elif ranges is None:
            r = self.rng.uniform(range_m[0], range_m[1], n)
        else:
            r = self.rng.choice(ranges, size=n)
        b = xis[h, 0] + std[0] * self.rng.standard_normal(n)
        th = xis[h, 1] + std[1] * self.rng.standard_normal(n)
        return np.column_stack([r * np.cos(b), r * np.sin(b), wrap_angle(th)])

    def log_fitness_bearing(self, xis: np.ndarray, std: np.ndarray) -> np.ndarray | None:
        """Scale-free eq. 18 for bearing-orientation candidates (H,); ``None`` while
        uninformed."""
        if not self.initialized:
            return None
        return logsumexp(self._bearing_ll(xis, std) + self.logw[:, None], axis=0)

    def scale_search(
        self, xis: np.ndarray, std: np.ndarray, ranges_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Eq. 18 with each candidate's scale chosen to maximise it (the thesis's section 10.3).

        A bearing-orientation ``xi_h = (beta_h, theta_h)`` placed at range ``r`` is the pose
        ``x_hat(r) = (r cos beta_h, r sin beta_h, theta_h)``; its fit to the belief is
        ``P_h(r) = sum_p w_p N(x_hat(r)_xy - z_p; (r s_b)^2 I) N(theta_p - theta_h; s_t)``: the
        position error of a bearing measured with std ``s_b`` at range ``r`` is ``r s_b`` across
        the ray, and, the scale being unknown, the same along it. Evaluated on the grid
        ``ranges_m`` (G,), vectorised over particles x candidates x grid, with
        ``|x_hat(r) - z_p|^2 = r^2 - 2 r (z_p . u_h) + |z_p|^2``.

        Parameters
        ----------
        xis : ndarray, shape (H, 2)
            Candidates ``(beta, theta)`` (rad), the observer's frame.
        std : ndarray, shape (2,)
            ``(s_b, s_t)`` (rad).
        ranges_m : ndarray, shape (G,)
            Candidate scales (m), > 0.

        Returns
        -------
        (log_fit, scale) : ndarrays, shape (H,) each
            ``max_r log P_h(r)`` and the maximising ``r`` (m); ``None`` while uninformed.
        """
        if not self.initialized:
            return None
        xis = np.asarray(xis, dtype=np.float64).reshape(-1, 2)
        r = np.asarray(ranges_m, dtype=np.float64).reshape(-1)
        u = np.column_stack([np.cos(xis[:, 0]), np.sin(xis[:, 0])])  # (H, 2)
        along = self.x[:, :2] @ u.T  # (P, H): z_p . u_h
        norm2 = (self.x[:, :2] ** 2).sum(axis=1)  # (P,)
        d2 = r**2 - 2.0 * along[..., None] * r + norm2[:, None, None]  # (P, H, G)
        var = (r * std[0]) ** 2  # (G,)
        rt = wrap_angle(self.x[:, None, 2] - xis[None, :, 1]) / std[1]  # (P, H)
        # The terms that do not depend on the particle leave the sum over particles (one pass
        # over the (P, H, G) block fewer): a log-sum-exp over p of the rest.
        e = (self.logw[:, None] - 0.5 * rt**2)[..., None] - (0.5 / var) * np.maximum(d2, 0.0)
        top = e.max(axis=0)  # (H, G)
        fit = (
            top
            + np.log(np.exp(e - top).sum(axis=0))
            - np.log(2.0 * math.pi * var)
            - math.log(math.sqrt(2.0 * math.pi) * std[1])
        )  # (H, G)
        best = fit.argmax(axis=1)
        return fit[np.arange(len(xis)), best], r[best]

    def update_bearing(
        self,
        xis: np.ndarray,
        std: np.ndarray,
        range_m=(0.2, 2.5),
        scales: np.ndarray | None = None,
    ) -> None:
        """Eq. 19 with the normalised sum of Gaussians over the hypotheses ``xis`` (H, 2); the
        re-seeded particles sit at ``scales`` (H,) (eq. 18's, :meth:`scale_search`) if given,
        else at ranges drawn from the belief."""
        xis = np.asarray(xis, dtype=np.float64).reshape(-1, 2)
        std = np.asarray(std, dtype=np.float64)
        if len(xis) == 0:
            return
        if not self.initialized:
            self.x = self._sample_bearing(xis, std, self.n, range_m)
            self.logw[:] = -math.log(self.n)
            self.initialized = True
            return
        logw = self.logw + logsumexp(self._bearing_ll(xis, std), axis=1) - math.log(len(xis))
        total = logsumexp(logw, axis=0)
        if not np.isfinite(total):
            self.x = self._sample_bearing(xis, std, self.n, range_m)
            self.logw[:] = -math.log(self.n)
            return
        self._reweight_resample_reseed(
            logw - total,
            lambda k: self._sample_bearing(
                xis, std, k, range_m, np.hypot(self.x[:, 0], self.x[:, 1]), scales
            ),
        )

    # ------------------------------------------------------------------ estimate
    def moments(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Weighted mean (3,) (circular in theta, as :meth:`mean`) and covariance (3, 3) of the
        particles (theta residuals wrapped); ``None`` if uninformed."""
        if not self.initialized:
            return None
        w = np.exp(self.logw - self.logw.max())
        return weighted_moments(self.x, w / w.sum())

    def mean(self) -> np.ndarray | None:
        """Weighted mean (3,), circular for theta (the thesis's); ``None`` if uninformed."""
        if not self.initialized:
            return None
        w = np.exp(self.logw)
        w /= w.sum()
        xy = w @ self.x[:, :2]
        th = math.atan2(float(w @ np.sin(self.x[:, 2])), float(w @ np.cos(self.x[:, 2])))
        return np.array([xy[0], xy[1], th])
