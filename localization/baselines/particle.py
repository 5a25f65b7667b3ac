"""The Lee 2012 study's baseline: particle-filter mutual localization from range and bearing.

Lee et al. (2012) localise each teammate with a particle filter fed with the
range and bearing its sensor measures to that (identified) teammate, cycling through:

1. *deterministic drift*: a damped constant-velocity model;
2. *weights*: the measurement likelihood of every particle;
3. *resampling*: 90 % of the particles drawn with replacement in proportion to their weights,
   the other 10 % re-seeded uniformly over the state space;
4. *diffusion*: every particle moved by a small Brownian step.

Here each particle is ``(x_m, y_m, vx_mps, vy_mps)`` of one teammate in the observer's body
frame, and the observer's own odometry moves every particle with the frame
(``p <- R(dpsi)^T (p - d)``, velocities rotated by ``R(dpsi)^T``). Lee 2012 exchanges no
odometry, so neither does this filter (``teammate_odometry`` is accepted and ignored, to share
the call shape of the other localizers). "The state space" for re-seeding is the sensing disc
(``reseed_range_m``) and the speed box ``|v| <= max_speed_mps``. The likelihood is Gaussian in
range and in the wrapped bearing residual. Steps 2-3 run only for teammates measured in that
update; the estimate is the mean of the resampled (non re-seeded) particles. All teammates'
particles are one ``(T, N, 4)`` array: no Python loop over teammates or particles.

**Range-only readings** (Lee 2012's wireless ranging): a reading ``(range_m, nan)`` (or a
1-vector ``(range_m,)``) carries no bearing; its likelihood is the range term alone.

**The start** (``start``, Lee 2012's triangulation / trilateration):

- ``"uniform"`` (default): the cloud starts uniform over the state space, weighted at once by
  the first reading (what the Lee 2012 study's filter does).
- ``"trilateration"``: with a bearing, the first reading alone fixes the teammate (one-station
  triangulation): particles drawn around the polar point with the range and bearing noise.
  Range-only readings are buffered with the observer's own position at the time (the origin of
  the body frame then, carried into the current body frame by every ``predict``'s odometry, the
  same :func:`frame_change` as the particles), and the track starts once there are ``>= 3``
  stations spread enough: the smallest singular value of the centred ``(S, 2)`` station matrix,
  divided by ``sqrt(S)`` (the RMS spread across the stations' weakest direction), must reach
  ``min_station_spread_m``. Collinear stations (a robot driving straight) give 0 and never start
  a track: a range circle through collinear centres has a mirror ambiguity. The fix is
  :func:`trilaterate` (linear least squares) refined by :func:`refine_fix` (Gauss-Newton on the
  ranges, to the Cramer-Rao bound the particles' spread assumes); the particles are drawn from
  ``N(fix, s^2 (H^T H)^-1)``, ``H`` the unit vectors from the stations to the fix (the range
  Jacobian) and ``s`` the larger of ``range_std_m`` and the fit's residual RMS (which grows when
  the teammate moved while the stations were gathered). Until then the teammate has no track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from localization.gaussian import wrap_angle
from localization.mixture import GaussianMixture
from swarm_core.validation import check_non_negative, check_number, check_positive

from ..config import config_with_overrides
from ._common import (
    checked_odometry,
    checked_range_bearing,
    extract,
    frame_change,
    track_mixture,
)

__all__ = [
    "ParticleConfig",
    "ParticleFilterTracker",
    "STARTS",
    "refine_fix",
    "station_spread",
    "trilaterate",
]

STARTS = ("uniform", "trilateration")


def station_spread(stations: np.ndarray) -> float:
    """RMS spread (m) of stations ``(S, 2)`` across their weakest direction: the smallest
    singular value of the centred station matrix over ``sqrt(S)`` (0 when collinear)."""
    stations = np.asarray(stations, dtype=float)
    if stations.shape[0] < 2:
        return 0.0
    centred = stations - stations.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[-1] / math.sqrt(stations.shape[0]))


def trilaterate(stations: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Point ``(2,)`` (m) at ``ranges`` ``(S,)`` from ``stations`` ``(S, 2)``, ``S >= 3``.

    Subtracting the first circle ``|x - s_0|^2 = r_0^2`` from the others leaves the linear
    system ``2 (s_i - s_0) . x = r_0^2 - r_i^2 + |s_i|^2 - |s_0|^2`` (i >= 1), solved by least
    squares. Exact ranges give the point exactly for non-collinear stations."""
    s = np.asarray(stations, dtype=float)
    r = np.asarray(ranges, dtype=float)
    if s.ndim != 2 or s.shape[1] != 2 or s.shape[0] < 3 or r.shape != (s.shape[0],):
        raise ValueError(
            f"stations must be (S >= 3, 2) and ranges (S,), got {s.shape} and {r.shape}"
        )
    a = 2.0 * (s[1:] - s[0])
    sq = (s**2).sum(axis=1)
    b = r[0] ** 2 - r[1:] ** 2 + sq[1:] - sq[0]
    return np.linalg.lstsq(a, b, rcond=None)[0]


def refine_fix(
    stations: np.ndarray, ranges: np.ndarray, x: np.ndarray, iterations: int = 3
) -> np.ndarray:
    """Gauss-Newton on the range residuals ``r_i - |x - s_i|`` from ``x`` (2,): the linear fix
    weights the circles by ``r_i`` and shares ``r_0``'s noise, so its error is above the
    Cramer-Rao bound ``sigma^2 (H^T H)^-1``; a few steps from it reach the bound."""
    x = np.asarray(x, dtype=float).copy()
    for _ in range(iterations):  # a 2x2 solve each, over a handful of stations
        d = x - stations
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        h = d / dist[:, None]
        x = x + np.linalg.lstsq(h, ranges - dist, rcond=None)[0]
    return x


@dataclass(frozen=True, slots=True)
class ParticleConfig:
    """Particle-filter parameters (units in the names), validated on construction."""

    n_particles: int = 500
    resample_fraction: float = 0.9
    reseed_range_m: float = 3.5
    max_speed_mps: float = 0.3
    velocity_damping: float = 0.9
    diffusion_std_m: float = 0.01
    velocity_diffusion_std_mps: float = 0.03
    range_std_m: float = 0.05
    bearing_std_rad: float = 0.05
    period_s: float = 0.1
    seed: int = 0
    start: str = "uniform"
    min_station_spread_m: float = 0.1
    max_stations: int = 20

    def __post_init__(self) -> None:
        check_number("n_particles", self.n_particles, integer=True, low=10)
        check_number("max_stations", self.max_stations, integer=True, low=3)
        if self.start not in STARTS:
            raise ValueError(f"start must be one of {STARTS}, got {self.start!r}")
        check_positive("min_station_spread_m", self.min_station_spread_m)
        check_number("seed", self.seed, integer=True, low=0)
        check_number("resample_fraction", self.resample_fraction, low=0, above=True, high=1)
        check_number("velocity_damping", self.velocity_damping, low=0, high=1)
        for name in ("reseed_range_m", "range_std_m", "bearing_std_rad", "period_s"):
            check_positive(name, getattr(self, name))
        for name in ("max_speed_mps", "diffusion_std_m", "velocity_diffusion_std_mps"):
            check_non_negative(name, getattr(self, name))

    @property
    def n_resampled(self) -> int:
        return max(1, int(round(self.resample_fraction * self.n_particles)))


class ParticleFilterTracker:
    """One particle cloud per identified teammate, in the observer frame (Lee 2012).

    Bounds: one unit-weight component per cloud, so weight = count = the number of distinct
    IDs ever measured (clouds are never dropped; ``predict`` adds none, ``update`` adds exactly
    the new IDs). With the oracle of :mod:`localization.registry` the IDs are teammates: at
    most ``n_robots - 1``.
    """

    def __init__(self, config: ParticleConfig | None = None, **overrides: Any) -> None:
        self.config = config = config_with_overrides(config, ParticleConfig, overrides)
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.config.seed)
        self._ids = np.empty(0, dtype=np.int64)
        self._particles = np.empty((0, self.config.n_particles, 4))
        self._mixture: GaussianMixture | None = None
        # "trilateration", range-only: id -> (stations (S, 2) in the current body frame, ranges)
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def pending(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Range-only teammates not started yet: ``{id: (stations (S, 2) m, ranges (S,) m)}``,
        stations in the current body frame (copies)."""
        return {k: (st.copy(), r.copy()) for k, (st, r) in self._pending.items()}

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(int(i) for i in self._ids)

    @property
    def particles(self) -> np.ndarray:
        """``(T, N, 4)`` particles ``(x, y, vx, vy)`` per track (a copy)."""
        return self._particles.copy()

    def _uniform(self, shape: tuple[int, ...]) -> np.ndarray:
        cfg = self.config
        r = cfg.reseed_range_m * np.sqrt(self._rng.random(shape))
        a = self._rng.uniform(-math.pi, math.pi, shape)
        v = self._rng.uniform(-cfg.max_speed_mps, cfg.max_speed_mps, (*shape, 2))
        return np.concatenate((np.stack((r * np.cos(a), r * np.sin(a)), -1), v), axis=-1)

    def predict(
        self,
        own_odometry: np.ndarray,
        teammate_odometry: dict[int, np.ndarray] | None = None,
        dt_s: float | None = None,
    ) -> None:
        """Drift (damped constant velocity), frame change with own odometry, diffusion."""
        own, _ = checked_odometry(own_odometry, teammate_odometry)
        cfg = self.config
        dt = cfg.period_s if dt_s is None else float(dt_s)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt_s must be a finite number > 0, got {dt_s!r}")
        for key, (stations, ranges) in self._pending.items():
            self._pending[key] = (frame_change(stations, own), ranges)
        if not self._ids.shape[0]:
            return
        p = self._particles
        xy = p[..., :2] + dt * p[..., 2:]
        v = cfg.velocity_damping * p[..., 2:]
        new = np.empty_like(p)
        new[..., :2] = frame_change(xy, own)
        new[..., 2:] = frame_change(v, np.array([0.0, 0.0, own[2]]))
        new[..., :2] += self._rng.normal(0.0, cfg.diffusion_std_m, new[..., :2].shape)
        new[..., 2:] += self._rng.normal(0.0, cfg.velocity_diffusion_std_mps, new[..., 2:].shape)
        speed = np.hypot(new[..., 2], new[..., 3])
        new[..., 2:] *= np.minimum(1.0, cfg.max_speed_mps / np.maximum(speed, 1e-12))[..., None]
        self._particles = new
        self._mixture = None

    def update(self, measurements: dict[int, np.ndarray] | None) -> None:
        """Weight, resample 90 % / re-seed 10 %, diffuse, for each measured teammate.

        ``measurements``: ``{id: (range_m, bearing_rad)}``; a NaN bearing (or a 1-vector
        ``(range_m,)``) is a range-only reading. A teammate measured for the first time starts
        per ``start`` (module docstring), weighted at once by this measurement.
        """
        meas = _checked_readings(measurements)
        cfg = self.config
        if not meas:
            return
        ids = np.array(sorted(meas), dtype=np.int64)
        new_ids = ids[~np.isin(ids, self._ids)]
        if new_ids.shape[0]:
            if cfg.start == "uniform":
                starts = self._uniform((new_ids.shape[0], cfg.n_particles))
            else:
                started = [self._fix_start(int(i), meas[int(i)]) for i in new_ids]
                keep = np.array([c is not None for c in started], dtype=bool)
                new_ids = new_ids[keep]
                starts = np.array([c for c in started if c is not None]).reshape(
                    -1, cfg.n_particles, 4
                )
                ids = ids[np.isin(ids, np.concatenate((self._ids, new_ids)))]
                if not ids.shape[0]:
                    return
            self._ids = np.concatenate((self._ids, new_ids))
            self._particles = np.concatenate((self._particles, starts))
        order = np.argsort(self._ids)
        rows = order[np.searchsorted(self._ids[order], ids)]
        z = np.array([meas[int(i)] for i in ids])  # (K, 2)
        p = self._particles[rows]  # (K, N, 4)
        rng_pred = np.hypot(p[..., 0], p[..., 1])
        brg_pred = np.arctan2(p[..., 1], p[..., 0])
        has_bearing = np.isfinite(z[:, 1:2])
        # Range-only readings drop the bearing term (np.where keeps NaN out of the sum).
        brg_term = np.where(
            has_bearing, wrap_angle(np.nan_to_num(z[:, 1:2]) - brg_pred) / cfg.bearing_std_rad, 0.0
        )
        loglik = -0.5 * (((z[:, 0:1] - rng_pred) / cfg.range_std_m) ** 2 + brg_term**2)
        # Normalised weights from log-likelihoods (no underflow to an all-zero set).
        w = np.exp(loglik - logsumexp(loglik, axis=1, keepdims=True))
        k, n = w.shape
        n_res = cfg.n_resampled
        # Multinomial resampling of every cloud at once: row offsets make one searchsorted.
        cum = np.cumsum(w, axis=1)
        cum[:, -1] = 1.0
        u = self._rng.random((k, n_res)) + np.arange(k)[:, None]
        flat = (cum + np.arange(k)[:, None]).ravel()
        idx = np.minimum(
            np.searchsorted(flat, u.ravel()).reshape(k, n_res) - np.arange(k)[:, None] * n, n - 1
        )
        resampled = np.take_along_axis(p, idx[..., None], axis=1)
        reseeded = self._uniform((k, n - n_res))
        cloud = np.concatenate((resampled, reseeded), axis=1)
        cloud[..., :2] += self._rng.normal(0.0, cfg.diffusion_std_m, cloud[..., :2].shape)
        self._particles[rows] = cloud
        self._mixture = None

    def _fix_start(self, key: int, z: np.ndarray) -> np.ndarray | None:
        """``"trilateration"``: the starting cloud ``(N, 4)`` of a new teammate, or ``None``
        while its range-only stations do not fix it yet (this reading is then buffered)."""
        cfg = self.config
        n = cfg.n_particles
        if math.isfinite(z[1]):  # one-station triangulation: the polar point of the reading
            self._pending.pop(key, None)
            v = self._rng.uniform(-cfg.max_speed_mps, cfg.max_speed_mps, (n, 2))
            r = np.maximum(z[0] + self._rng.normal(0.0, cfg.range_std_m, n), 0.0)
            b = z[1] + self._rng.normal(0.0, cfg.bearing_std_rad, n)
            return np.concatenate((np.stack((r * np.cos(b), r * np.sin(b)), -1), v), axis=-1)
        stations, ranges = self._pending.get(key, (np.empty((0, 2)), np.empty(0)))
        # The observer is at its body frame's origin when it takes this reading.
        stations = np.concatenate((stations, np.zeros((1, 2))))[-cfg.max_stations :]
        ranges = np.concatenate((ranges, z[:1]))[-cfg.max_stations :]
        self._pending[key] = (stations, ranges)
        if stations.shape[0] < 3 or station_spread(stations) < cfg.min_station_spread_m:
            return None
        del self._pending[key]
        fix = refine_fix(stations, ranges, trilaterate(stations, ranges))
        d = fix - stations
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        h = d / dist[:, None]  # (S, 2) range Jacobian at the fix
        resid = ranges - dist
        dof = max(stations.shape[0] - 2, 1)
        var = max(cfg.range_std_m**2, float(resid @ resid) / dof)
        cov = var * np.linalg.pinv(h.T @ h)
        chol = np.linalg.cholesky(cov + 1e-12 * np.eye(2))
        xy = fix + self._rng.standard_normal((n, 2)) @ chol.T
        v = self._rng.uniform(-cfg.max_speed_mps, cfg.max_speed_mps, (n, 2))
        return np.concatenate((xy, v), axis=-1)

    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        core = self._particles[:, : self.config.n_resampled, :2]
        mean = core.mean(axis=1)
        d = core - mean[:, None, :]
        cov = np.einsum("tni,tnj->tij", d, d) / core.shape[1]
        cov[:, 0, 0] += 1e-8
        cov[:, 1, 1] += 1e-8
        return mean, cov

    def estimate(self) -> dict[int, np.ndarray]:
        """``{id: (x_m, y_m)}``: the mean of each cloud's resampled particles."""
        mean, _ = self._moments()
        return {int(i): mean[k].copy() for k, i in enumerate(self._ids)}

    @property
    def mixture(self) -> GaussianMixture:
        """One unit-weight component per teammate: mean and covariance of its cloud."""
        if self._mixture is None:
            mean, cov = self._moments()
            self._mixture = track_mixture(mean, cov)
        return self._mixture

    def extract(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return extract(self.mixture, threshold)


def _checked_readings(measurements: dict | None) -> dict[int, np.ndarray]:
    """``{id: (range_m, bearing_rad)}`` validated like :func:`checked_range_bearing`, except
    that the bearing may be NaN (range-only); a 1-vector ``(range_m,)`` gets a NaN bearing."""
    out = {}
    for key, value in (measurements or {}).items():
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"measurements[{key}] must be numeric, got {value!r}") from exc
        if arr.shape == (1,) or (arr.shape == (2,) and np.isnan(arr[1])):
            ident = next(iter(checked_range_bearing({key: (arr[0], 0.0)})))
            out[ident] = np.array([arr[0], np.nan])
        else:
            out.update(checked_range_bearing({key: value}))
    return out
