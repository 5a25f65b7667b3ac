"""Pure Kalman / EKF building blocks for 2-D Gaussians, vectorised over stacked components.

Every function takes arrays and returns **new** arrays; inputs are never modified.
Covariances are passed as their three distinct entries ``(pxx, pxy, pyy)``, each of shape
``(N,)`` (the rows of a component table, see :mod:`localization.mixture`), and every 2x2
inverse/determinant is written in closed form: with N ~ 20 components a call to
``np.linalg`` per update would cost more than the whole update.

Numerical guards used here (each one is also commented where it happens):

* Joseph-form covariance updates, ``(I - K H) P (I - K H)^T + K R K^T``: a sum of two
  positive semi-definite products, so round-off in ``K`` cannot make ``P`` indefinite.
* Symmetry by construction: only ``pxx, pxy, pyy`` are stored and computed.
* Determinants floored at a tiny positive value before division.
* The bearing Jacobian uses ``max(||m||^2, min_range^2)`` so components near the origin
  do not produce infinite gains.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
.. [2] Perera 2021, seed ``000`` of this project, eqs. (13)-(16) and (25)-(28).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "TINY",
    "wrap_angle",
    "sym_inverse",
    "frame_change_matrix",
    "kalman_update_position",
    "position_likelihood",
    "bearing_ekf_update",
]

#: Smallest positive value used as a floor for determinants and normalisers.
TINY = 1e-300
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return (angle + math.pi) % _TWO_PI - math.pi


def sym_inverse(
    pxx: np.ndarray, pxy: np.ndarray, pyy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form inverse of stacked symmetric 2x2 matrices.

    Parameters
    ----------
    pxx, pxy, pyy : ndarray, shape (N,)
        Entries of the matrices ``[[pxx, pxy], [pxy, pyy]]``.

    Returns
    -------
    ixx, ixy, iyy : ndarray, shape (N,)
        Entries of the inverses.
    det : ndarray, shape (N,)
        Determinants, floored at :data:`TINY`.
    """
    # Guard: a singular or (by round-off) slightly indefinite matrix gets a tiny positive
    # determinant instead of a division by zero / negative variance.
    det = np.maximum(pxx * pyy - pxy * pxy, TINY)
    inv_det = 1.0 / det
    return pyy * inv_det, -pxy * inv_det, pxx * inv_det, det


def frame_change_matrix(dx: float, dy: float, dpsi: float, process_var: float) -> np.ndarray:
    """Affine map of a component table for an observer displacement ``(dx, dy, dpsi)``.

    A point ``p`` fixed in the world, seen from a robot that moves by ``d = (dx, dy)`` and
    turns by ``dpsi`` (both in the robot frame at the start of the move), is at
    ``p' = R(dpsi)^T (p - d)`` afterwards: the frame rotates by ``+dpsi``, so points rotate by
    ``-dpsi`` (the seed's eq. 7 writes ``R(dpsi)``, which is the inverse). Covariances map as
    ``P' = R^T P R + Q`` with ``Q = process_var * I`` (isotropic, so the seed's ``R Q R^T``
    equals ``Q``).

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
        ``A`` such that ``table' = A[:, :6] @ table + A[:, 6:]`` for a ``(6, N)`` table with rows
        ``w, x, y, Pxx, Pxy, Pyy`` (the weight row is copied unchanged).
    """
    c = math.cos(dpsi)
    s = math.sin(dpsi)
    cc, ss, cs = c * c, s * s, c * s
    # Means: R^T = [[c, s], [-s, c]]; offset -R^T d.
    # Covariances: entries of R^T P R as a linear map of (Pxx, Pxy, Pyy).
    return np.array(
        [
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, c, s, 0.0, 0.0, 0.0, -(c * dx + s * dy)],
            [0.0, -s, c, 0.0, 0.0, 0.0, s * dx - c * dy],
            [0.0, 0.0, 0.0, cc, 2.0 * cs, ss, process_var],
            [0.0, 0.0, 0.0, -cs, cc - ss, cs, 0.0],
            [0.0, 0.0, 0.0, ss, -2.0 * cs, cc, process_var],
        ]
    )


def kalman_update_position(
    pxx: np.ndarray, pxy: np.ndarray, pyy: np.ndarray, noise_var: float
) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], tuple[np.ndarray, ...], np.ndarray]:
    """Kalman gain and posterior covariance for a position measurement ``z = m + v``.

    ``H = I``, ``R = noise_var * I``. The gain and the posterior covariance do not depend on
    the measured value, so they are computed once per component.

    Parameters
    ----------
    pxx, pxy, pyy : ndarray, shape (N,)
        Prior covariances (m^2).
    noise_var : float
        Measurement noise variance (m^2).

    Returns
    -------
    gain : tuple of 3 ndarray, shape (N,)
        ``(kxx, kxy, kyy)``; with ``H = I`` and isotropic ``R``, ``K = P S^-1`` is symmetric.
    post : tuple of 3 ndarray, shape (N,)
        Posterior covariance ``(pxx, pxy, pyy)`` in Joseph form.
    innov_inv : tuple of 3 ndarray, shape (N,)
        Inverse innovation covariance ``S^-1 = (P + R)^-1``.
    innov_det : ndarray, shape (N,)
        ``det S`` (m^4).
    """
    r = noise_var
    sxx = pxx + r
    syy = pyy + r
    ixx, ixy, iyy, det = sym_inverse(sxx, pxy, syy)
    # I - K = I - P S^-1 = R S^-1 = r S^-1 (exact for H = I); K = I - r S^-1.
    axx = r * ixx
    axy = r * ixy
    ayy = r * iyy
    kxx = 1.0 - axx
    kxy = -axy
    kyy = 1.0 - ayy
    # Joseph form: (I - K) P (I - K)^T + K R K^T, both terms PSD (guard against round-off).
    txx = axx * pxx + axy * pxy
    txy = axx * pxy + axy * pyy
    tyx = axy * pxx + ayy * pxy
    tyy = axy * pxy + ayy * pyy
    kxy2 = kxy * kxy
    qxx = txx * axx + txy * axy + r * (kxx * kxx + kxy2)
    qxy = txx * axy + txy * ayy + r * kxy * (kxx + kyy)
    qyy = tyx * axy + tyy * ayy + r * (kxy2 + kyy * kyy)
    return (kxx, kxy, kyy), (qxx, qxy, qyy), (ixx, ixy, iyy), det


def position_likelihood(
    dx: np.ndarray,
    dy: np.ndarray,
    innov_inv: tuple[np.ndarray, np.ndarray, np.ndarray],
    innov_det: np.ndarray,
) -> np.ndarray:
    """Gaussian likelihood ``N(z; m, S)`` for all component x measurement pairs.

    Parameters
    ----------
    dx, dy : ndarray, shape (N, M)
        Innovations ``z - m`` (m).
    innov_inv : tuple of 3 ndarray, shape (N,)
        ``S^-1`` entries per component.
    innov_det : ndarray, shape (N,)
        ``det S`` per component (m^4).

    Returns
    -------
    ndarray, shape (N, M)
        Densities (1/m^2). Far pairs underflow to exactly 0 (never NaN).
    """
    ixx, ixy, iyy = innov_inv
    maha = ixx[:, None] * (dx * dx) + (2.0 * ixy)[:, None] * (dx * dy) + iyy[:, None] * (dy * dy)
    return np.exp(-0.5 * maha) * (_INV_TWO_PI / np.sqrt(innov_det))[:, None]


def bearing_ekf_update(
    x: np.ndarray,
    y: np.ndarray,
    pxx: np.ndarray,
    pxy: np.ndarray,
    pyy: np.ndarray,
    noise_var: float,
    min_range: float,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray], tuple[np.ndarray, ...]]:
    """EKF terms for a bearing measurement ``theta = atan2(y, x) + v``.

    Jacobian ``H = [-y, x] / ||m||^2`` (the derivative of ``atan2``; the seed's eq. 28 divides
    by ``||m||``, which is wrong by a factor ``||m||``).

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        Prior means (m).
    pxx, pxy, pyy : ndarray, shape (N,)
        Prior covariances (m^2).
    noise_var : float
        Bearing noise variance (rad^2).
    min_range : float
        Floor on ``||m||`` (m) used in the Jacobian.

    Returns
    -------
    predicted : ndarray, shape (N,)
        Predicted bearings ``atan2(y, x)`` (rad).
    innov_var : ndarray, shape (N,)
        ``S = H P H^T + R`` (rad^2).
    gain : tuple of 2 ndarray, shape (N,)
        ``(kx, ky)`` (m/rad).
    post : tuple of 3 ndarray, shape (N,)
        Joseph-form posterior covariance ``(pxx, pxy, pyy)``.
    """
    # Guard: ||m||^2 floored so the Jacobian stays finite for components at the origin.
    r2 = np.maximum(x * x + y * y, min_range * min_range)
    inv_r2 = 1.0 / r2
    hx = -y * inv_r2
    hy = x * inv_r2
    ux = pxx * hx + pxy * hy  # P H^T
    uy = pxy * hx + pyy * hy
    s = hx * ux + hy * uy + noise_var  # >= noise_var > 0
    inv_s = 1.0 / s
    kx = ux * inv_s
    ky = uy * inv_s
    # Joseph form with B = I - K H: B P B^T + K R K^T (sum of PSD terms; round-off guard).
    bxx = 1.0 - kx * hx
    bxy = -kx * hy
    byx = -ky * hx
    byy = 1.0 - ky * hy
    txx = bxx * pxx + bxy * pxy
    txy = bxx * pxy + bxy * pyy
    tyx = byx * pxx + byy * pxy
    tyy = byx * pxy + byy * pyy
    rkx = noise_var * kx
    qxx = txx * bxx + txy * bxy + rkx * kx
    qxy = txx * byx + txy * byy + rkx * ky
    qyy = tyx * byx + tyy * byy + noise_var * ky * ky
    return np.arctan2(y, x), s, (kx, ky), (qxx, qxy, qyy)
