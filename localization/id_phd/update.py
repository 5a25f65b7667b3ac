"""ID-PHD measurement update: GM-PHD on the ``(x, y)`` part of ``(x, y, psi)`` components
(Stegagno 2013 eqs. 20-21), the heading row following from the same gain."""

from __future__ import annotations

import numpy as np

from .. import phd
from ..gaussian import wrap_angle
from ..mixture import N_ROWS, ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y


def lidar_update_3d(
    weights: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    points: np.ndarray,
    detection_prob: np.ndarray,
    noise_var: float,
    clutter_intensity: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """GM-PHD update of ``(x, y, psi)`` components with ``(x, y)`` detections (``H = [I 0]``).

    The weights, position means and position covariances are those of
    :func:`localization.phd.lidar_update` on the ``(x, y)`` marginal. The heading follows from
    the same gain ``K_psi = P_psi,xy S^-1``: ``psi+ = psi + P_psi,xy (z - m+) / r`` (because
    ``m+ = z - r S^-1 (z - m)``), cross-covariance ``P+_xy,psi = r S^-1 P_xy,psi`` and
    ``P+_psi = P_psi - P_psi,xy S^-1 P_xy,psi`` (floored at 1e-12 rad^2).

    Returns
    -------
    weights (N + N M,), means (N + N M, 3), covs (N + N M, 3, 3), source (N + N M,) int
    (the prior component of each output), explained (M,)
    """
    n, m = means.shape[0], points.shape[0]
    table = np.empty((N_ROWS, n))
    table[ROW_W] = weights
    table[ROW_X : ROW_Y + 1] = means[:, :2].T
    table[ROW_PXX] = covs[:, 0, 0]
    table[ROW_PXY] = covs[:, 0, 1]
    table[ROW_PYY] = covs[:, 1, 1]
    out, explained = phd.lidar_update(table, points, detection_prob, noise_var, clutter_intensity)
    # S^-1 per component (closed form), for the heading rows.
    sxx, sxy, syy = covs[:, 0, 0] + noise_var, covs[:, 0, 1], covs[:, 1, 1] + noise_var
    inv_det = 1.0 / np.maximum(sxx * syy - sxy * sxy, 1e-300)
    s_inv = np.empty((n, 2, 2))
    s_inv[:, 0, 0] = syy * inv_det
    s_inv[:, 1, 1] = sxx * inv_det
    s_inv[:, 0, 1] = s_inv[:, 1, 0] = -sxy * inv_det
    c = covs[:, :2, 2]  # P_xy,psi, (N, 2)
    new_means = np.empty((n + n * m, 3))
    new_means[:, :2] = out[ROW_X : ROW_Y + 1].T
    new_means[:n, 2] = means[:, 2]
    innov_scaled = (points[None, :, :] - out[ROW_X : ROW_Y + 1, n:].T.reshape(n, m, 2)) / noise_var
    psi = means[:, 2][:, None] + np.einsum("nk,nmk->nm", c, innov_scaled)
    new_means[n:, 2] = wrap_angle(psi).reshape(-1)
    post = np.empty((n, 3, 3))
    post[:, 0, 0] = out[ROW_PXX, n : n + n * m : m] if m else covs[:, 0, 0]
    post[:, 0, 1] = post[:, 1, 0] = out[ROW_PXY, n : n + n * m : m] if m else covs[:, 0, 1]
    post[:, 1, 1] = out[ROW_PYY, n : n + n * m : m] if m else covs[:, 1, 1]
    s_c = np.einsum("nij,nj->ni", s_inv, c)  # S^-1 P_xy,psi
    post[:, :2, 2] = post[:, 2, :2] = noise_var * s_c
    post[:, 2, 2] = np.maximum(covs[:, 2, 2] - np.einsum("ni,ni->n", c, s_c), 1e-12)
    new_covs = np.concatenate((covs, np.repeat(post, m, axis=0)))
    source = np.concatenate((np.arange(n), np.repeat(np.arange(n), m)))
    return out[ROW_W], new_means, new_covs, source, explained
