"""Pure Kalman / EKF building blocks for 2-D Gaussians, vectorised over stacked components.

Every function takes arrays and returns **new** arrays; inputs are never modified.

Layout (the rows of a component table, see :mod:`localization.mixture`):

* ``means`` : shape ``(2, N)``, rows ``x, y`` (m);
* ``covs`` : shape ``(3, N)``, rows ``Pxx, Pxy, Pyy`` (m^2), the three distinct entries of
  each symmetric 2x2 covariance (so every covariance is symmetric by construction);
* measurements are stacked along a trailing axis: ``(2, N, M)`` posterior means,
  ``(N, M)`` likelihoods, component-major.

Every 2x2 inverse/determinant is written in closed form: at N ~ 20 components one
``np.linalg`` call per component would cost more than the whole update. The functions are
written to minimise the number of numpy calls (each costs ~0.5-1 us at these sizes, far more
than the arithmetic), which is why some products are spelled out row by row.

Numerical guards (each is also commented where it happens):

* posterior covariances are computed as sums/products of positive semi-definite terms
  (Joseph form for the bearing update; its exact closed form ``R S^-1 P`` for the position
  update), never as ``P - (...)`` differences that round-off can make indefinite;
* determinants and squared ranges are floored before division;
* likelihoods are evaluated as ``exp(-q/2)`` of a non-negative ``q``: far pairs underflow to
  exactly 0, never to NaN.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
.. [2] Perera 2021, eqs. (13)-(16) and (25)-(28).
.. [3] R. S. Bucy and P. D. Joseph, "Filtering for Stochastic Processes with Applications to
   Guidance", 1968 (the Joseph stabilised covariance update).
"""

from __future__ import annotations

import math

import numpy as np

# The project's one wrap_angle (re-exported here for localization's modules).
from swarm_core.geometry import wrap_angle

__all__ = [
    "TINY",
    "wrap_angle",
    "sym_inverse",
    "frame_change_matrix",
    "position_update",
    "bearing_update",
    "joseph_update",
]

#: Floor for determinants and normalisers (smallest value we divide by).
TINY = 1e-300
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI
_INV_SQRT_TWO_PI = 1.0 / math.sqrt(_TWO_PI)
# Constant helper columns (never written to).
_EYE3 = np.array([[1.0], [0.0], [1.0]])  # identity in (xx, xy, yy) layout
_INV_SIGN3 = np.array([[1.0], [-1.0], [1.0]])  # adj([[a, b], [b, c]]) = [c, -b, a]
_JAC_SIGN = np.array([[-1.0], [1.0]])  # d atan2(y, x) / d(x, y) = [-y, x] / r^2
_EYE22 = np.eye(2)[:, :, None]
_FULL_FROM_SYM = np.array([0, 1, 1, 2])  # (xx, xy, yy) -> (xx, xy, yx, yy)
_SYM_FROM_FULL = np.array([0, 1, 3])
_FRAME_TEMPLATE = np.zeros((6, 7))
_FRAME_TEMPLATE[0, 0] = 1.0


def sym_inverse(covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form inverse of stacked symmetric 2x2 matrices.

    Parameters
    ----------
    covs : ndarray, shape (3, N)
        Rows ``Pxx, Pxy, Pyy``.

    Returns
    -------
    inverse : ndarray, shape (3, N)
        Rows of ``P^-1`` in the same layout.
    det : ndarray, shape (N,)
        ``det P``, floored at :data:`TINY`.
    """
    # Guard: a singular or (by round-off) indefinite matrix gets a tiny positive determinant
    # instead of a division by zero.
    det = np.maximum(covs[0] * covs[2] - covs[1] * covs[1], TINY)
    return covs[::-1] * (_INV_SIGN3 / det), det


def frame_change_matrix(dx: float, dy: float, dpsi: float, process_var: float) -> np.ndarray:
    """Affine map of a component table for an observer displacement ``(dx, dy, dpsi)``.

    A point ``p`` fixed in the world, seen from a robot that moves by ``d = (dx, dy)`` and
    turns by ``dpsi`` (both in the robot frame at the start of the move), is at
    ``p' = R(dpsi)^T (p - d)`` afterwards: the frame rotates by ``+dpsi``, so points rotate by
    ``-dpsi`` (the Perera 2021 study's eq. 7 writes ``R(dpsi)``, which is the inverse). Covariances
    map with the same matrix, ``P' = R^T P R + Q``, ``Q = process_var * I`` (isotropic, so the
    study's ``R Q R^T`` is just ``Q``).

    Parameters
    ----------
    dx, dy : float
        Observer translation (m) in its frame at the start of the interval.
    dpsi : float
        Observer rotation (rad, counter-clockwise).
    process_var : float
        Process-noise variance (m^2) added to ``Pxx`` and ``Pyy``.

    Returns
    -------
    ndarray, shape (6, 7)
        ``A`` with ``table' = A[:, :6] @ table + A[:, 6:]`` for a ``(6, N)`` table with rows
        ``w, x, y, Pxx, Pxy, Pyy`` (the weight row is copied unchanged).
    """
    c = math.cos(dpsi)
    s = math.sin(dpsi)
    a = _FRAME_TEMPLATE.copy()
    cc, ss, cs = c * c, s * s, c * s
    # Means: R^T = [[c, s], [-s, c]], offset -R^T d.
    a[..., 1, 1] = c
    a[..., 1, 2] = s
    a[..., 1, 6] = -(c * dx + s * dy)
    a[..., 2, 1] = -s
    a[..., 2, 2] = c
    a[..., 2, 6] = s * dx - c * dy
    # Covariances: (Pxx, Pxy, Pyy) of R^T P R, a linear map of (Pxx, Pxy, Pyy).
    a[..., 3, 3] = cc
    a[..., 3, 4] = 2.0 * cs
    a[..., 3, 5] = ss
    a[..., 3, 6] = process_var
    a[..., 4, 3] = -cs
    a[..., 4, 4] = cc - ss
    a[..., 4, 5] = cs
    a[..., 5, 3] = ss
    a[..., 5, 4] = -2.0 * cs
    a[..., 5, 5] = cc
    a[..., 5, 6] = process_var
    return a


def position_update(
    means: np.ndarray, covs: np.ndarray, points: np.ndarray, noise_var: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kalman update of every component with every position measurement ``z = m + v``.

    ``H = I``, ``R = noise_var * I``, ``S = P + R``, ``K = P S^-1``.

    Parameters
    ----------
    means : ndarray, shape (2, N)
        Prior means (m).
    covs : ndarray, shape (3, N)
        Prior covariances (m^2).
    points : ndarray, shape (2, M)
        Measurements as columns (m).
    noise_var : float
        Measurement noise variance ``r`` (m^2).

    Returns
    -------
    post_means : ndarray, shape (2, N, M)
        ``m + K (z - m)``, written as ``z - r S^-1 (z - m)`` (the same thing: ``I - K = r S^-1``).
    post_covs : ndarray, shape (3, N)
        Posterior covariance (independent of ``z``). The Joseph form
        ``(I - K) P (I - K)^T + K R K^T`` reduces exactly, for ``H = I`` and ``R = r I``, to
        ``r S^-1 P = r (det(P) I + r P) / det(S)``; we evaluate that expression, whose terms are
        all non-negative, so it keeps Joseph's guarantee (no cancellation, PSD under
        round-off) at a fraction of the cost (tested against the explicit Joseph product).
    likelihood : ndarray, shape (N, M)
        ``N(z; m, S)`` (1/m^2); far pairs underflow to exactly 0.
    """
    eye3, sign3 = _EYE3, _INV_SIGN3
    r = noise_var
    pxx, pxy, pyy = covs
    pxy2 = pxy * pxy
    det_p = pxx * pyy - pxy2
    s = covs + r * eye3
    # det S >= r^2 > 0 for PSD P; the floor only guards a corrupted input.
    inv_det_s = 1.0 / np.maximum(s[0] * s[2] - pxy2, TINY)
    # -S^-1 / 2, rows xx, xy, yy (the -1/2 of the exponent folded in once per component).
    half_inv = s[::-1] * (sign3 * (-0.5 * inv_det_s))
    post_covs = (covs * r + eye3 * det_p) * (r * inv_det_s)
    pts = points[:, None, :]
    diff = pts - means[:, :, None]  # (2, N, M): z - m
    # e = -S^-1 (z - m) / 2, row by row.
    e = half_inv[0:2, :, None] * diff[0] + half_inv[1:3, :, None] * diff[1]
    likelihood = np.exp(diff[0] * e[0] + diff[1] * e[1])
    likelihood *= (np.sqrt(inv_det_s) * _INV_TWO_PI)[:, None]
    post_means = pts + (2.0 * r) * e  # z - r S^-1 (z - m)
    return post_means, post_covs, likelihood


def joseph_update(covs: np.ndarray, gain: np.ndarray, jac: np.ndarray, noise: np.ndarray):
    """Joseph-form covariance update ``(I - K H) P (I - K H)^T + K R K^T`` for 2-D states.

    Reference implementation for scalar measurements and for tests.

    Parameters
    ----------
    covs : ndarray, shape (3, N)
        Prior covariances.
    gain : ndarray, shape (2, N)
        Kalman gains ``K`` (one column per component, scalar measurement).
    jac : ndarray, shape (2, N)
        Measurement Jacobians ``H`` (row vectors, one per component).
    noise : float or ndarray, shape (N,)
        Measurement noise variance ``R``.

    Returns
    -------
    ndarray, shape (3, N)
        Posterior covariances. Symmetric by construction: only the upper off-diagonal of the
        product is kept.
    """
    full = covs[_FULL_FROM_SYM].reshape(2, 2, -1)  # P as (2, 2, N)
    b = _EYE22 - gain[:, None, :] * jac[None, :, :]  # I - K H, (2, 2, N)
    bp = b[:, 0:1] * full[0:1] + b[:, 1:2] * full[1:2]  # (B P)[a, c]
    bpb = bp[:, None, 0] * b[None, :, 0] + bp[:, None, 1] * b[None, :, 1]  # B P B^T
    krk = (gain * noise)[:, None] * gain[None]  # K R K^T
    return (bpb + krk).reshape(4, -1)[_SYM_FROM_FULL]


def bearing_update(
    means: np.ndarray,
    covs: np.ndarray,
    bearings: np.ndarray,
    noise_var: float,
    min_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EKF update of every component with every bearing ``theta = atan2(y, x) + v``.

    Jacobian ``H = [-y, x] / ||m||^2`` (the derivative of ``atan2``; the Perera 2021 study's eq. 28
    divides by ``||m||``, which is wrong by a factor ``||m||``). Innovations are wrapped to
    ``[-pi, pi)``.

    Parameters
    ----------
    means : ndarray, shape (2, N)
        Prior means (m).
    covs : ndarray, shape (3, N)
        Prior covariances (m^2).
    bearings : ndarray, shape (M,)
        Measured bearings (rad).
    noise_var : float or ndarray, shape (N,)
        Bearing noise variance ``R_C`` (rad^2), per component if an array (a range-dependent
        model evaluated at each prior mean).
    min_range : float
        Floor on ``||m||`` (m) used in the Jacobian.

    Returns
    -------
    post_means : ndarray, shape (2, N, M)
        ``m + K * wrap(theta - atan2(y, x))``.
    post_covs : ndarray, shape (3, N)
        Joseph-form posterior covariance (independent of the measured value).
    likelihood : ndarray, shape (N, M)
        ``N(innovation; 0, S)`` with ``S = H P H^T + R_C`` (1/rad).
    """
    # Guard: ||m||^2 floored so the Jacobian stays finite for components at the origin.
    sq = means * means
    inv_r2 = 1.0 / np.maximum(sq[0] + sq[1], min_range * min_range)
    jac = means[::-1] * (_JAC_SIGN * inv_r2)  # (2, N): [-y, x] / r^2
    u = covs[0:2] * jac[0] + covs[1:3] * jac[1]  # P H^T
    hu = jac * u
    inv_s = 1.0 / (hu[0] + hu[1] + noise_var)  # S >= R_C > 0
    gain = u * inv_s
    # Joseph form: a sum of two PSD products (round-off cannot make it indefinite).
    post_covs = joseph_update(covs, gain, jac, noise_var)
    innov = wrap_angle(bearings[None, :] - np.arctan2(means[1], means[0])[:, None])  # (N, M)
    post_means = means[:, :, None] + gain[:, :, None] * innov
    likelihood = np.exp((innov * innov) * (-0.5 * inv_s)[:, None])
    likelihood *= (np.sqrt(inv_s) * _INV_SQRT_TWO_PI)[:, None]
    return post_means, post_covs, likelihood
