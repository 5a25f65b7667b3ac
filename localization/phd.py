"""GM-PHD time and measurement updates on component tables (pure functions).

A component table is a float64 array of shape ``(6, N)`` with rows ``w, x, y, Pxx, Pxy, Pyy``
(see :mod:`localization.mixture`). Every function returns a new table and leaves its inputs
untouched. Updates are vectorised over components x measurements: there is no Python loop
over components or measurements.

Update layout: for ``N`` prior components and ``M`` measurements the posterior table has
``N + N*M`` columns, the ``N`` missed-detection copies first, then the detected copies in
component-major order (column ``N + i*M + h`` is component ``i`` updated with measurement ``h``).

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006, Table I.
.. [2] Perera 2021, eqs. (7)-(30).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import CAMERA_BIRTH_RADIAL_STD_FRACTION, PROCESS_CLOCK_RESET_S
from .detection import inverse_sigmoid
from .gaussian import TINY, bearing_update, frame_change_matrix, position_update
from .mixture import N_ROWS, ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y

__all__ = [
    "ProcessClock",
    "predict",
    "diffuse",
    "birth_components",
    "lidar_update",
    "camera_update",
    "missed_weights",
    "ray_births",
    "camera_ray_births",
]


@dataclass(frozen=True, slots=True)
class ProcessClock:
    """When a robot's random-walk process noise went in (``PHDConfig.prediction.time_update``).

    ``time_update == "measurement"``: the noise accrues continuously at the rate
    ``process_var / interval_s``; every stamped call (``("advance", stamp_s)``) adds what
    accrued since the previous stamp, and the next predict adds none. A predict that no
    stamp preceded (unstamped calls, ``"odometry"``) adds all of ``Q``, as Perera 2021 does.

    Attributes
    ----------
    last_stamp_s : float
        The latest stamp seen (nan: none since the reset).
    advanced : bool
        Whether a stamp arrived since the last predict.

    The first stamp after a reset only starts the clock: the share of ``Q`` between the reset
    and that stamp (under one odometry period, once per episode) is not added. A stamp more
    than ``PROCESS_CLOCK_RESET_S`` behind the latest restarts the clock (the next predict then
    adds the whole ``Q``); a smaller step back adds nothing and leaves the clock where it was.
    """

    last_stamp_s: float = float("nan")
    advanced: bool = False

    def advance(self, stamp_s: float, process_var: float, interval_s: float, enabled: bool):
        """``(clock, variance to add now in m^2)`` at ``stamp_s``. The first stamp and a stamp
        out of order add nothing (a stale stamp never moves the clock back)."""
        if not enabled:
            return self, 0.0
        last = self.last_stamp_s
        if math.isnan(last):
            return ProcessClock(stamp_s, True), 0.0
        if stamp_s < last - PROCESS_CLOCK_RESET_S:
            return ProcessClock(stamp_s, False), 0.0
        if stamp_s <= last:
            return ProcessClock(last, True), 0.0
        return ProcessClock(stamp_s, True), process_var * (stamp_s - last) / interval_s

    def predict(self, process_var: float, enabled: bool):
        """``(clock, Q variance of this predict in m^2)``."""
        added = enabled and self.advanced
        return ProcessClock(self.last_stamp_s, False), 0.0 if added else process_var

    def as_array(self) -> np.ndarray:
        """``[last_stamp_s, advanced]``, the compiled banks' row of their ``clock (R, 2)``."""
        return np.array([self.last_stamp_s, float(self.advanced)])

    @classmethod
    def from_array(cls, row: np.ndarray) -> ProcessClock:
        return cls(float(row[0]), bool(row[1]))


def diffuse(table: np.ndarray, process_var: float) -> np.ndarray:
    """The table with ``process_var * I`` (m^2) added to every covariance (a new array)."""
    out = table.copy()
    out[ROW_PXX] += process_var
    out[ROW_PYY] += process_var
    return out


def predict(
    table: np.ndarray, odometry: np.ndarray, survival: np.ndarray, process_var: float
) -> np.ndarray:
    """GM-PHD time update with the observer's own odometry (Perera 2021 eqs. 7-9).

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Posterior component table at ``k-1``.
    odometry : ndarray, shape (3,)
        ``[dx_m, dy_m, dpsi_rad]``: the observer's motion over the interval, expressed in
        its frame at the start of the interval.
    survival : ndarray, shape (N,)
        ``P_s`` per component, evaluated at the prior means.
    process_var : float
        ``Q = process_var * I`` (m^2) added to every covariance.

    Returns
    -------
    ndarray, shape (6, N)
        Predicted table: ``m' = R(dpsi)^T (m - d)``, ``P' = R^T P R + Q``, ``w' = P_s w``.
    """
    affine = frame_change_matrix(
        float(odometry[0]), float(odometry[1]), float(odometry[2]), process_var
    )
    out = affine[:, :N_ROWS].dot(table)
    out += affine[:, N_ROWS:]
    out[ROW_W] *= survival
    return out


def birth_components(
    means: np.ndarray, variance_m2: float | np.ndarray, weight: float
) -> np.ndarray:
    """Birth components with isotropic covariances.

    Parameters
    ----------
    means : ndarray, shape (B, 2)
        Birth means (m, robot frame).
    variance_m2 : float
        Variance of each axis (m^2).
    weight : float
        Weight of each birth component.

    Returns
    -------
    ndarray, shape (6, B)
    """
    out = np.empty((N_ROWS, means.shape[0]))
    out[ROW_W] = weight
    out[ROW_X] = means[:, 0]
    out[ROW_Y] = means[:, 1]
    out[ROW_PXX] = variance_m2
    out[ROW_PXY] = 0.0
    out[ROW_PYY] = variance_m2
    return out


def _posterior_table(
    table: np.ndarray,
    detection_prob: np.ndarray,
    post_means: np.ndarray,
    post_covs: np.ndarray,
    likelihood: np.ndarray,
    clutter_intensity: float | np.ndarray,
    bernoulli: bool = False,
    missed: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """GM-PHD weights (Vo & Ma 2006, Table I, step 4) and the stacked posterior table.

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Prior table.
    detection_prob : ndarray, shape (N,)
        ``P_d`` per component.
    post_means : ndarray, shape (2, N, M)
        Updated means per (component, measurement).
    post_covs : ndarray, shape (3, N)
        Updated covariances per component.
    likelihood : ndarray, shape (N, M)
        Measurement likelihood per (component, measurement).
    clutter_intensity : float or ndarray, shape (M,)
        ``kappa`` in the measurement's units, or one per measurement.
    bernoulli : bool
        Missed copies with :func:`missed_weights`' Bernoulli weights instead of the PHD's.
    missed : (missed_prob (N,), missed_table (6, N)), optional
        The missed copies' ``P_d`` and shape from :func:`missed_moments` (default: ``P_d`` at
        the mean and the prior's shape).

    Returns
    -------
    table : ndarray, shape (6, N + N*M)
        Missed copies first (weight ``(1 - P_d) w``), then detected copies, component-major,
        with weight ``P_d w g / (kappa + sum_i P_d w_i g_i)``.
    explained : ndarray, shape (M,)
        ``sum_i P_d w_i g_i / (kappa + sum_i ...)`` per measurement, in ``[0, 1]``.
    """
    n, m = likelihood.shape
    weights = table[ROW_W]
    pd_w = detection_prob * weights
    detected = likelihood * pd_w[:, None]
    # column sums (a dot is cheaper than .sum(axis=0))
    sums = np.ones(n).dot(detected)
    # Guard: with zero clutter and every likelihood underflowed, 0/0 would give NaN; the
    # floor turns it into weights of exactly 0 (nothing explains that measurement).
    inv_denom = 1.0 / np.maximum(sums + clutter_intensity, TINY)
    out = np.empty((N_ROWS, n + n * m))
    missed_prob, missed_table = (detection_prob, table) if missed is None else missed
    if bernoulli:
        # Lambda_i w_i = sum_h P_d w_i g_ih / (kappa + sum_{j != i} P_d w_j g_jh)
        others = np.maximum(sums[None, :] - detected, 0.0) + clutter_intensity
        evidence = (detected / np.maximum(others, TINY)).dot(np.ones(m))
        out[ROW_W, :n] = missed_weights(weights, missed_prob, evidence)
    else:
        out[ROW_W, :n] = weights - missed_prob * weights  # (1 - P_d) w
    out[ROW_X:, :n] = missed_table[ROW_X:]
    # a view: component-major (i, h) blocks
    blocks = out[:, n:].reshape(N_ROWS, n, m)
    np.multiply(detected, inv_denom[None, :], out=blocks[ROW_W])
    blocks[ROW_X : ROW_Y + 1] = post_means
    blocks[ROW_PXX:] = post_covs[:, :, None]
    return out, sums * inv_denom


#: Probabilists' Gauss-Hermite rule (9 nodes) for expectations over N(0, 1).
GH_NODES, GH_WEIGHTS = np.polynomial.hermite_e.hermegauss(9)
GH_WEIGHTS = GH_WEIGHTS / math.sqrt(2.0 * math.pi)


def missed_moments(
    table: np.ndarray,
    detection_prob: np.ndarray,
    offset: float,
    slope_per_m: float,
    midpoint_m: float,
    min_range_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The lidar missed-detection posterior ``(1 - P_d(x)) N(x; m, P)``, moment-matched.

    ``P_d(x) = g f(r(x))``: the range factor ``f`` (Perera 2021 eq. 19's sigmoid) varies over the
    component, the angular factors ``g = P_d(m) / f(||m||)`` are taken at the mean. Along the
    range direction ``u = m / ||m||`` the range is linearised, ``r = ||m|| + s z``,
    ``s^2 = u^T P u``, ``z ~ N(0, 1)``, and 9-point Gauss-Hermite gives ``Z = E[1 - g f]``,
    ``mu = s E[z (1 - g f)] / Z`` and ``v = s^2 E[z^2 (1 - g f)] / Z - mu^2``. A likelihood of
    the projection ``u^T x`` updates the Gaussian exactly as conditioning does:
    ``m' = m + P u mu / s^2``, ``P' = P + P u u^T P (v - s^2) / s^4``.

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Prior components.
    detection_prob : ndarray, shape (N,)
        ``P_d`` at the means (every factor).
    offset, slope_per_m, midpoint_m : float
        The range factor ``1 / (offset + exp(slope (r - midpoint)))``.
    min_range_m : float
        Floor on ``||m||`` for the direction.

    Returns
    -------
    missed_prob : ndarray, shape (N,)
        ``E[P_d]`` over each component, for the missed copy's weight.
    missed_table : ndarray, shape (6, N)
        The missed copies' means and covariances (rows 1-5; row 0 is the prior's).
    """
    out = table.copy()
    mx, my = table[ROW_X], table[ROW_Y]
    r = np.hypot(mx, my)
    ux, uy = mx / np.maximum(r, min_range_m), my / np.maximum(r, min_range_m)
    pu_x = table[ROW_PXX] * ux + table[ROW_PXY] * uy  # P u
    pu_y = table[ROW_PXY] * ux + table[ROW_PYY] * uy
    s2 = ux * pu_x + uy * pu_y
    s = np.sqrt(np.maximum(s2, 0.0))
    f_mean = inverse_sigmoid(r, offset, slope_per_m, midpoint_m)
    # Angular factors; a mean far beyond the range (f underflows) keeps its own P_d.
    g = np.divide(detection_prob, f_mean, out=np.zeros_like(f_mean), where=f_mean > 1e-12)
    f_nodes = inverse_sigmoid(
        r[:, None] + s[:, None] * GH_NODES[None, :], offset, slope_per_m, midpoint_m
    )
    miss = 1.0 - g[:, None] * f_nodes  # (N, K), in [0, 1]
    z = miss.dot(GH_WEIGHTS)
    ok = (z > TINY) & (s2 > TINY) & (f_mean > 1e-12)
    missed_prob = np.where(ok, 1.0 - z, detection_prob)
    zs = np.where(ok, z, 1.0)
    mu = s * miss.dot(GH_WEIGHTS * GH_NODES) / zs
    v = s2 * miss.dot(GH_WEIGHTS * GH_NODES**2) / zs - mu * mu
    s2_safe = np.where(ok, s2, 1.0)
    shift = np.where(ok, mu / s2_safe, 0.0)
    shrink = np.where(ok, (v - s2) / (s2_safe * s2_safe), 0.0)
    out[ROW_X] = mx + pu_x * shift
    out[ROW_Y] = my + pu_y * shift
    out[ROW_PXX] = table[ROW_PXX] + pu_x * pu_x * shrink
    out[ROW_PXY] = table[ROW_PXY] + pu_x * pu_y * shrink
    out[ROW_PYY] = table[ROW_PYY] + pu_y * pu_y * shrink
    return missed_prob, out


def missed_weights(
    weights: np.ndarray, detection_prob: np.ndarray, evidence: np.ndarray | None = None
) -> np.ndarray:
    """Bernoulli missed-detection weights ``w (1 - P_d) / (1 - r P_d + r Lambda)``.

    Each component is read as ``n = max(1, ceil(w))`` Bernoulli targets of existence
    ``r = w / n`` (``r = w`` for ``w <= 1``; a merged component of weight 1.3 as two targets
    of existence 0.65, the split that claims no more certainty than the weight holds),
    updated exactly against
    a Poisson background (clutter plus every other component): the Bernoulli filter's
    missed-detection posterior (Ristic et al. 2013, "A tutorial on Bernoulli filters",
    eq. 40). The PHD's ``(1 - P_d) w`` is its limit for ``r -> 0``.

    Parameters
    ----------
    weights : ndarray, shape (N,)
    detection_prob : ndarray, shape (N,)
        ``P_d`` per component.
    evidence : ndarray, shape (N,), optional
        ``w_i Lambda_i = sum_h P_d w_i g_ih / (kappa + sum_{j != i} P_d w_j g_jh)``; omitted
        for a scan or frame without measurements (``Lambda = 0``).

    Returns
    -------
    ndarray, shape (N,)
        Missed-copy weights, ``<= w``.
    """
    scale = 1.0 / np.maximum(np.ceil(weights), 1.0)  # r / w = 1 / n
    r = weights * scale
    denom = 1.0 - r * detection_prob
    if evidence is not None:
        denom += scale * evidence
    # Guard: r = P_d = 1 and no evidence gives 0 / 0; the numerator is then 0.
    return (weights - weights * detection_prob) / np.maximum(denom, TINY)


def ray_births(
    bearings: np.ndarray,
    weight: float,
    n_components: int,
    min_range_m: float,
    max_range_m: float,
    radial_std_fraction: float,
    bearing_var: float,
    pd_offset: float,
    pd_slope_per_m: float,
    pd_midpoint_m: float,
) -> np.ndarray:
    """Bearing-only measurement-driven birth: components along each bearing's ray.

    The range band ``[min_range_m, max_range_m]`` is cut into ``K = n_components`` equal
    cells of width ``d``; cell ``k`` gets a component at range ``r_k`` (its centre) with
    radial std ``radial_std_fraction * d``, cross-range std ``r_k sqrt(bearing_var)`` and
    weight ``weight * r_k P(r_k) / sum_j r_j P(r_j)``, ``P`` the camera's range factor
    (a uniform teammate density seen through ``P``).

    Parameters
    ----------
    bearings : ndarray, shape (M,)
        Bearings (rad, robot frame).
    weight : float
        Total weight per bearing.
    n_components : int
    min_range_m, max_range_m, radial_std_fraction : float
    bearing_var : float or callable
        ``R_C`` (rad^2), or ``R_C(range_m)`` evaluated at each cell's range.
    pd_offset, pd_slope_per_m, pd_midpoint_m : float
        Camera range factor (:func:`localization.detection.inverse_sigmoid`).

    Returns
    -------
    ndarray, shape (6, M * K)
        Bearing-major: column ``h * K + k`` is cell ``k`` of bearing ``h``.
    """
    step = (max_range_m - min_range_m) / n_components
    ranges = min_range_m + (np.arange(n_components) + 0.5) * step
    share = ranges * inverse_sigmoid(ranges, pd_offset, pd_slope_per_m, pd_midpoint_m)
    weights = share * (weight / share.sum())
    radial_var = (radial_std_fraction * step) ** 2
    if callable(bearing_var):  # R_C(r), rad^2, at each cell's range
        bearing_var = bearing_var(ranges)
    cross_var = ranges * ranges * bearing_var
    c = np.cos(bearings)[:, None]
    s = np.sin(bearings)[:, None]
    out = np.empty((N_ROWS, bearings.shape[0], n_components))
    out[ROW_W] = weights
    out[ROW_X] = ranges * c
    out[ROW_Y] = ranges * s
    out[ROW_PXX] = radial_var * (c * c) + cross_var * (s * s)
    out[ROW_PXY] = (radial_var - cross_var) * (c * s)
    out[ROW_PYY] = radial_var * (s * s) + cross_var * (c * c)
    return out.reshape(N_ROWS, -1)


def camera_ray_births(config, bearings: np.ndarray) -> np.ndarray:
    """:func:`ray_births` of ``bearings`` (M,) with ``config``'s (a ``PHDConfig``) camera
    birth and camera models: ``births.camera_weight`` per bearing over
    ``[births.camera_min_range_m, births.camera_max_range_m]`` in ``births.camera_components``
    cells, the range-dependent ``R_C`` and the camera's range factor. Shape (6, M K)."""
    return ray_births(
        bearings,
        config.births.camera_weight,
        config.births.camera_components,
        config.births.camera_min_range_m,
        config.births.camera_max_range_m,
        CAMERA_BIRTH_RADIAL_STD_FRACTION,
        config.camera_bearing_var,
        config.camera.pd_offset,
        config.camera.pd_slope_per_m,
        config.camera.pd_midpoint_m,
    )


def lidar_update(
    table: np.ndarray,
    points: np.ndarray,
    detection_prob: np.ndarray,
    noise_var: float,
    clutter_intensity: float,
    bernoulli: bool = False,
    missed: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """GM-PHD update with lidar position measurements (Perera 2021 eqs. 12-17, ``H = I``).

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Prior component table.
    points : ndarray, shape (M, 2)
        Detections ``[x_m, y_m]`` in the robot frame.
    detection_prob : ndarray, shape (N,)
        Lidar ``P_d`` per prior component, in ``[0, 1]``.
    noise_var : float or ndarray, shape (N,)
        ``R_L = noise_var * I`` (m^2).
    clutter_intensity : float
        ``kappa_L`` (1/m^2).
    bernoulli : bool
        Bernoulli missed-copy weights (:func:`missed_weights`).
    missed : optional
        The missed copies' ``P_d`` and shape (:func:`missed_moments`).

    Returns
    -------
    table : ndarray, shape (6, N + N*M)
        Posterior table: missed copies with weight ``(1 - P_d) w``, then detected copies
        ``P_d w N(z; m, P + R) / (kappa + sum_i P_d w_i N(z; m_i, P_i + R))``.
    explained : ndarray, shape (M,)
        Fraction of each measurement explained by the components,
        ``sum_i / (kappa + sum_i)`` in ``[0, 1]``.
    """
    post_means, post_covs, likelihood = position_update(
        table[ROW_X : ROW_Y + 1], table[ROW_PXX:], points.T, noise_var
    )
    return _posterior_table(
        table,
        detection_prob,
        post_means,
        post_covs,
        likelihood,
        clutter_intensity,
        bernoulli,
        missed,
    )


def camera_update(
    table: np.ndarray,
    bearings: np.ndarray,
    detection_prob: np.ndarray,
    noise_var: float,
    clutter_intensity: float | np.ndarray,
    min_range_m: float,
    bernoulli: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """GM-PHD update with camera bearings, one EKF step per component (Perera 2021 eqs. 24-30).

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Prior component table.
    bearings : ndarray, shape (M,)
        Measured bearings (rad, robot frame).
    detection_prob : ndarray, shape (N,)
        Camera ``P_d`` per prior component, in ``[0, 1]``.
    noise_var : float
        ``R_C`` (rad^2).
    clutter_intensity : float or ndarray, shape (M,)
        ``kappa_C`` (1/rad), or one per bearing (the wide objects' clutter,
        :mod:`localization.object_clutter`).
    min_range_m : float
        Floor on ``||m||`` for the bearing Jacobian (m).
    bernoulli : bool
        Bernoulli missed-copy weights (:func:`missed_weights`).

    Returns
    -------
    table : ndarray, shape (6, N + N*M)
        Posterior table (layout as :func:`lidar_update`); the innovation is wrapped to
        ``[-pi, pi)`` and the weight factor is ``N(innovation; 0, H P H^T + R_C)``.
    explained : ndarray, shape (M,)
        As in :func:`lidar_update`.
    """
    post_means, post_covs, likelihood = bearing_update(
        table[ROW_X : ROW_Y + 1], table[ROW_PXX:], bearings, noise_var, min_range_m
    )
    return _posterior_table(
        table, detection_prob, post_means, post_covs, likelihood, clutter_intensity, bernoulli
    )
