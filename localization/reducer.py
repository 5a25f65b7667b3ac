"""Mixture reduction: prune, merge, cap (Vo & Ma 2006, Table II), on component tables.

* :func:`prune` drops components below a weight threshold. **It loses mass**: the total weight
  falls by exactly the pruned weights (we do not redistribute them as Stone Soup does: a
  pruned component is evidence we chose to forget, not evidence for the survivors).
* :func:`merge` is Vo & Ma's greedy merge. Take the heaviest remaining component ``j``;
  every remaining ``i`` with ``(m_i - m_j)^T P_i^-1 (m_i - m_j) <= U`` joins its cluster; the
  cluster becomes one moment-matched component. **It preserves the total weight** (each
  cluster's weight is the sum of its members') and the first two moments of every cluster.
* :func:`cap` keeps the ``max_components`` heaviest components (loses the rest's mass).

The greedy merge is computed without a Python loop over components: with components sorted
by decreasing weight and ``close[j, i]`` the gate test, component ``i`` is a cluster leader iff
no earlier *leader* ``j < i`` has ``close[j, i]``. That recursion has a unique solution, and
iterating ``leader <- not any_j<i (leader[j] & close[j, i])`` reaches it in at most "depth of
the longest covering chain" sweeps (1-2 in practice), each a few array operations. Each
component then joins the first leader (heaviest) whose gate holds it, which is exactly the
cluster the sequential algorithm gives it.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
"""

from __future__ import annotations

import numpy as np

from .gaussian import sym_inverse
from .mixture import N_ROWS, ROW_PXX, ROW_PYY, ROW_W, ROW_X, ROW_Y

__all__ = ["prune", "merge", "cap", "reduce", "greedy_clusters"]


def prune(table: np.ndarray, threshold: float) -> np.ndarray:
    """Drop components with weight below ``threshold``.

    Parameters
    ----------
    table : ndarray, shape (6, N)
    threshold : float

    Returns
    -------
    ndarray, shape (6, N')
        The kept components, in their original order (total weight decreases by the sum of
        the pruned weights).
    """
    keep = table[ROW_W] >= threshold
    return table[:, keep]


def cap(table: np.ndarray, max_components: int) -> np.ndarray:
    """Keep the ``max_components`` largest-weight components (original order is not kept).

    Parameters
    ----------
    table : ndarray, shape (6, N)
    max_components : int

    Returns
    -------
    ndarray, shape (6, min(N, max_components))
    """
    n = table.shape[1]
    if n <= max_components:
        return table
    keep = np.argpartition(table[ROW_W], n - max_components)[n - max_components :]
    return table[:, keep]


def greedy_clusters(close: np.ndarray) -> np.ndarray:
    """Cluster labels of Vo & Ma's greedy merge from a gate matrix.

    Parameters
    ----------
    close : ndarray of bool, shape (N, N)
        ``close[j, i]``: component ``i`` is inside component ``j``'s merge gate. Components
        are assumed sorted by decreasing weight, and ``close[i, i]`` must be True.

    Returns
    -------
    ndarray of int, shape (N,)
        ``labels[i]`` is the index of the leader of ``i``'s cluster (``labels[j] == j`` for
        leaders).
    """
    n = close.shape[0]
    index = np.arange(n)
    # First (heaviest) component whose gate holds i; close[i, i] guarantees first[i] <= i.
    first = close.argmax(axis=0)
    if (first[first] == first).all():
        # Every first-coverer leads itself: those are exactly the greedy leaders.
        return first
    earlier = close & (index[:, None] < index)  # strictly earlier coverers only
    leader = first == index  # never covered by anyone earlier: certainly a leader
    while True:
        new_leader = ~(earlier & leader[:, None]).any(axis=0)
        if (new_leader == leader).all():
            break
        leader = new_leader
    return (close & leader[:, None]).argmax(axis=0)


def merge(table: np.ndarray, threshold: float) -> np.ndarray:
    """Vo & Ma greedy merge with moment matching.

    Parameters
    ----------
    table : ndarray, shape (6, N)
    threshold : float
        ``U``: squared Mahalanobis distance ``(m_i - m_j)^T P_i^-1 (m_i - m_j)`` at or below
        which component ``i`` joins the cluster of the heavier component ``j``.

    Returns
    -------
    ndarray, shape (6, L)
        One component per cluster, sorted by decreasing weight: weight ``sum w_i``, mean
        ``sum w_i m_i / W``, covariance ``sum w_i (P_i + (m - m_i)(m - m_i)^T) / W``.
    """
    n = table.shape[1]
    if n < 2:
        return table
    table = table[:, np.argsort(-table[ROW_W], kind="stable")]
    w, x, y, pxx, pxy, pyy = table
    ixx, ixy, iyy, _ = sym_inverse(pxx, pxy, pyy)
    dx = x - x[:, None]  # [j, i] = x_i - x_j
    dy = y - y[:, None]
    maha = ixx * (dx * dx) + (2.0 * ixy) * (dx * dy) + iyy * (dy * dy)  # with P_i^-1
    labels = greedy_clusters(maha <= threshold)
    leaders = np.flatnonzero(labels == np.arange(n))
    n_out = leaders.shape[0]
    if n_out == n:
        return table
    # Cluster id 0..L-1 of every component (leaders are in decreasing-weight order).
    cluster = np.cumsum(labels == np.arange(n))[labels] - 1
    flat = cluster + n_out * np.arange(3)[:, None]  # offsets to bincount 3 rows at once
    total = np.bincount(cluster, weights=w, minlength=n_out)
    # Moment matching. Guard: weights are >= 0; a cluster of all-zero weights would divide
    # 0 by 0, so its leader's own moments are used instead (floor on the divisor).
    wsafe = np.where(total > 0.0, total, 1.0)
    means = np.bincount(flat[:2].ravel(), weights=(w * table[ROW_X : ROW_Y + 1]).ravel(),
                        minlength=2 * n_out).reshape(2, n_out) / wsafe
    zero = total <= 0.0
    if zero.any():
        means[:, zero] = table[ROW_X : ROW_Y + 1, leaders[zero]]
        w = np.where(zero[cluster], 1.0, w)
        wsafe = np.where(zero, np.bincount(cluster, minlength=n_out), wsafe)
    ex = x - means[0, cluster]
    ey = y - means[1, cluster]
    spread = np.stack((pxx + ex * ex, pxy + ex * ey, pyy + ey * ey)) * w
    covs = np.bincount(flat.ravel(), weights=spread.ravel(), minlength=3 * n_out)
    out = np.empty((N_ROWS, n_out))
    out[ROW_W] = total
    out[ROW_X : ROW_Y + 1] = means
    out[ROW_PXX : ROW_PYY + 1] = covs.reshape(3, n_out) / wsafe
    return out


def reduce(
    table: np.ndarray, prune_threshold: float, merge_threshold: float, max_components: int
) -> np.ndarray:
    """Prune, then merge, then cap (Vo & Ma 2006, Table II).

    Parameters
    ----------
    table : ndarray, shape (6, N)
    prune_threshold, merge_threshold : float
    max_components : int

    Returns
    -------
    ndarray, shape (6, N'), ``N' <= max_components``
    """
    table = prune(table, prune_threshold)
    table = merge(table, merge_threshold)
    return cap(table, max_components)
