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
.. [2] Perera 2021, seed ``000`` of this project, eqs. (7)-(30).
"""

from __future__ import annotations

import math

import numpy as np

from .gaussian import (
    TINY,
    bearing_ekf_update,
    frame_change_matrix,
    kalman_update_position,
    position_likelihood,
    wrap_angle,
)
from .mixture import N_ROWS, ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y

__all__ = [
    "predict",
    "birth_components",
    "lidar_update",
    "camera_update",
]

_INV_SQRT_TWO_PI = 1.0 / math.sqrt(2.0 * math.pi)


def predict(
    table: np.ndarray, odometry: np.ndarray, survival: np.ndarray, process_var: float
) -> np.ndarray:
    """GM-PHD time update with the observer's own odometry (seed eqs. 7-9).

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
    out = affine[:, :N_ROWS] @ table
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


def _assemble(
    table: np.ndarray,
    missed_weights: np.ndarray,
    detected_weights: np.ndarray,
    x_post: np.ndarray,
    y_post: np.ndarray,
    cov_post: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """Stack missed copies ``(6, N)`` and detected copies ``(6, N*M)`` into one table."""
    n, m = detected_weights.shape
    out = np.empty((N_ROWS, n + n * m))
    out[ROW_W, :n] = missed_weights
    out[ROW_X:, :n] = table[ROW_X:]
    detected = out[:, n:].reshape(N_ROWS, n, m)  # a view: component-major blocks
    detected[ROW_W] = detected_weights
    detected[ROW_X] = x_post
    detected[ROW_Y] = y_post
    detected[ROW_PXX] = cov_post[0][:, None]
    detected[ROW_PXY] = cov_post[1][:, None]
    detected[ROW_PYY] = cov_post[2][:, None]
    return out


def _normalise(weighted_likelihood: np.ndarray, clutter: float) -> tuple[np.ndarray, np.ndarray]:
    """Divide each measurement column by ``clutter + sum_i``; return weights and the sums."""
    sums = weighted_likelihood.sum(axis=0)
    # Guard: with zero clutter and every likelihood underflowed, 0/0 would give NaN;
    # the floor turns it into weights of exactly 0 (nothing explains that measurement).
    denom = np.maximum(sums + clutter, TINY)
    return weighted_likelihood / denom, sums / denom


def lidar_update(
    table: np.ndarray,
    points: np.ndarray,
    detection_prob: np.ndarray,
    noise_var: float,
    clutter_intensity: float,
) -> tuple[np.ndarray, np.ndarray]:
    """GM-PHD update with lidar position measurements (seed eqs. 12-17, ``H = I``).

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Prior component table.
    points : ndarray, shape (M, 2)
        Detections ``[x_m, y_m]`` in the robot frame.
    detection_prob : ndarray, shape (N,)
        Lidar ``P_d`` per prior component, in ``[0, 1]``.
    noise_var : float
        ``R_L = noise_var * I`` (m^2).
    clutter_intensity : float
        ``kappa_L`` (1/m^2).

    Returns
    -------
    table : ndarray, shape (6, N + N*M)
        Posterior table: missed copies with weight ``(1 - P_d) w``, then detected copies
        ``P_d w N(z; m, P + R) / (kappa + sum_i P_d w_i N(z; m_i, P_i + R))``.
    explained : ndarray, shape (M,)
        Fraction of each measurement explained by the components,
        ``sum_i / (kappa + sum_i)`` in ``[0, 1]``.
    """
    w, x, y, pxx, pxy, pyy = table
    gain, cov_post, innov_inv, innov_det = kalman_update_position(pxx, pxy, pyy, noise_var)
    dx = points[:, 0] - x[:, None]  # (N, M) innovations
    dy = points[:, 1] - y[:, None]
    likelihood = position_likelihood(dx, dy, innov_inv, innov_det)
    weights, explained = _normalise((detection_prob * w)[:, None] * likelihood, clutter_intensity)
    kxx, kxy, kyy = gain
    x_post = x[:, None] + kxx[:, None] * dx + kxy[:, None] * dy
    y_post = y[:, None] + kxy[:, None] * dx + kyy[:, None] * dy
    out = _assemble(table, (1.0 - detection_prob) * w, weights, x_post, y_post, cov_post)
    return out, explained


def camera_update(
    table: np.ndarray,
    bearings: np.ndarray,
    detection_prob: np.ndarray,
    noise_var: float,
    clutter_intensity: float,
    min_range_m: float,
) -> np.ndarray:
    """GM-PHD update with camera bearings, one EKF step per component (seed eqs. 24-30).

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
    clutter_intensity : float
        ``kappa_C`` (1/rad).
    min_range_m : float
        Floor on ``||m||`` for the bearing Jacobian (m).

    Returns
    -------
    ndarray, shape (6, N + N*M)
        Posterior table (layout as :func:`lidar_update`); the innovation is wrapped to
        ``[-pi, pi)`` and the weight factor is ``N(innovation; 0, H P H^T + R_C)``.
    """
    w, x, y, pxx, pxy, pyy = table
    predicted, innov_var, (kx, ky), cov_post = bearing_ekf_update(
        x, y, pxx, pxy, pyy, noise_var, min_range_m
    )
    innov = wrap_angle(bearings - predicted[:, None])  # (N, M)
    inv_var = 1.0 / innov_var
    likelihood = np.exp((innov * innov) * (-0.5 * inv_var)[:, None])
    coeff = detection_prob * w * (_INV_SQRT_TWO_PI * np.sqrt(inv_var))
    weights, _ = _normalise(coeff[:, None] * likelihood, clutter_intensity)
    x_post = x[:, None] + kx[:, None] * innov
    y_post = y[:, None] + ky[:, None] * innov
    return _assemble(table, (1.0 - detection_prob) * w, weights, x_post, y_post, cov_post)
