"""ID-PHD time update: a teammate's communicated odometry composed with the observer's own
(Stegagno 2013 eqs. 14-19), and the split of untagged components over the candidate robots."""

from __future__ import annotations

import math

import numpy as np

from ..gaussian import wrap_angle
from .config import STATIC, UNTAGGED


# ---------------------------------------------------------------------- pure functions
def compose_relative(
    means: np.ndarray,
    covs: np.ndarray,
    teammate_delta: np.ndarray,
    own_delta: np.ndarray,
    teammate_var: np.ndarray,
    own_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Time update of teammate poses in a moving observer frame (Stegagno 2013 eqs. 18-19).

    Parameters
    ----------
    means : ndarray, shape (N, 3)
        ``(x_m, y_m, psi_rad)`` of each teammate in the observer frame at the start.
    covs : ndarray, shape (N, 3, 3)
    teammate_delta : ndarray, shape (N, 3)
        Each component's teammate increment ``(dx_m, dy_m, dpsi_rad)``, in the teammate's own
        frame at the start of the interval (zeros for a static object).
    own_delta : ndarray, shape (3,)
        The observer's increment, in its frame at the start of the interval.
    teammate_var : ndarray, shape (N, 3)
        Diagonal of ``C_i`` per component (m^2, m^2, rad^2).
    own_var : ndarray, shape (3,)
        Diagonal of ``C_0``.

    Returns
    -------
    means : ndarray, shape (N, 3)
        ``p' = R(dpsi_0)^T (p + R(psi) d_i - d_0)``, ``psi' = wrap(psi + dpsi_i - dpsi_0)``.
    covs : ndarray, shape (N, 3, 3)
        ``F P F^T + J_i C_i J_i^T + J_0 C_0 J_0^T``, symmetrised.
    """
    c0, s0 = math.cos(own_delta[2]), math.sin(own_delta[2])
    rt0 = np.array([[c0, s0], [-s0, c0]])  # R(dpsi_0)^T
    psi = means[:, 2]
    c, s = np.cos(psi), np.sin(psi)
    dx, dy = teammate_delta[:, 0], teammate_delta[:, 1]
    rd = np.stack((c * dx - s * dy, s * dx + c * dy), axis=1)  # R(psi) d_i
    a = means[:, :2] + rd - own_delta[:2]
    out = np.empty_like(means)
    out[:, :2] = a @ rt0.T
    out[:, 2] = wrap_angle(psi + teammate_delta[:, 2] - own_delta[2])
    n = means.shape[0]
    # F = d x' / d x: [[R0^T, R0^T dR(psi)/dpsi d_i], [0, 0, 1]]; dR/dpsi d = [-rd_y, rd_x].
    f = np.zeros((n, 3, 3))
    f[:, :2, :2] = rt0
    f[:, :2, 2] = np.stack((-rd[:, 1], rd[:, 0]), axis=1) @ rt0.T
    f[:, 2, 2] = 1.0
    # J_i = d x' / d u_i: [[R0^T R(psi), 0], [0, 0, 1]].
    ji = np.zeros((n, 3, 3))
    rpsi = np.stack((np.stack((c, -s), -1), np.stack((s, c), -1)), axis=1)  # (N, 2, 2)
    ji[:, :2, :2] = rt0 @ rpsi
    ji[:, 2, 2] = 1.0
    # J_0 = d x' / d u_0: [[-R0^T, (p'_y, -p'_x)^T], [0, 0, -1]].
    j0 = np.zeros((n, 3, 3))
    j0[:, :2, :2] = -rt0
    j0[:, 0, 2] = out[:, 1]
    j0[:, 1, 2] = -out[:, 0]
    j0[:, 2, 2] = -1.0
    new = f @ covs @ f.transpose(0, 2, 1)
    new += (ji * teammate_var[:, None, :]) @ ji.transpose(0, 2, 1)
    new += (j0 * own_var) @ j0.transpose(0, 2, 1)
    new = 0.5 * (new + new.transpose(0, 2, 1))
    return out, new


def split_untagged(
    weights: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    tags: np.ndarray,
    candidates: np.ndarray,
    heading_hypotheses: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split every untagged component over the candidate robots and the static class.

    Each untagged component of weight ``w`` becomes ``len(candidates) + 1`` identity copies of
    weight ``w / (len(candidates) + 1)`` (Stegagno 2013 eq. 15, the static class ``-2`` counts as
    one identity). A robot copy is further split into ``heading_hypotheses`` copies with
    headings ``psi_0 + 2 pi k / H`` and heading variance ``min(P_psi, (pi / H)^2)``, each of
    weight ``w / ((len(candidates) + 1) H)``; the static copy keeps the original component.
    Tagged components are returned unchanged, first, in their order.

    Returns
    -------
    weights (N',), means (N', 3), covs (N', 3, 3), tags (N',)
    """
    untagged = tags == UNTAGGED
    if not untagged.any():
        return weights, means, covs, tags
    keep = ~untagged
    uw, um, uc = weights[untagged], means[untagged], covs[untagged]
    b = uw.shape[0]
    n_ids = candidates.shape[0] + 1
    h = heading_hypotheses if candidates.shape[0] else 0
    share = uw / n_ids
    # Robot copies, ordered (birth, candidate, heading).
    offsets = 2.0 * math.pi * np.arange(h) / max(h, 1)
    rw = np.repeat(share / max(h, 1), candidates.shape[0] * h)
    rm = np.repeat(um, candidates.shape[0] * h, axis=0)
    rm[:, 2] = wrap_angle(rm[:, 2] + np.tile(offsets, b * candidates.shape[0]))
    rc = np.repeat(uc, candidates.shape[0] * h, axis=0)
    if h:
        heading_var = min(math.pi / h, math.pi) ** 2
        scale = np.sqrt(np.minimum(heading_var, rc[:, 2, 2]) / rc[:, 2, 2])
        rc[:, 2, :] *= scale[:, None]
        rc[:, :, 2] *= scale[:, None]
    rt = np.tile(np.repeat(candidates, h), b)
    return (
        np.concatenate((weights[keep], rw, share)),
        np.concatenate((means[keep], rm, um)),
        np.concatenate((covs[keep], rc, uc)),
        np.concatenate((tags[keep], rt, np.full(b, STATIC))).astype(np.int64),
    )
