"""Mixture reduction: prune, merge, cap (Vo & Ma 2006, Table II), on component tables.

* :func:`prune` drops components below a weight threshold. **It loses mass**: the total weight
  falls by exactly the pruned weights (we do not redistribute them as Stone Soup does: a
  pruned component is evidence we chose to forget, not evidence for the survivors).
* :func:`merge` is Vo & Ma's greedy merge. Take the heaviest remaining component ``j``;
  every remaining ``i`` with ``(m_i - m_j)^T P_i^-1 (m_i - m_j) <= U`` joins its cluster; the
  cluster becomes one moment-matched component. **It preserves the total weight** (each
  cluster's weight is the sum of its members') and the first two moments of every cluster.
* :func:`cap` keeps the ``max_components`` heaviest components (loses the rest's mass).

How the greedy merge is computed (see :func:`greedy_clusters`): a component is a cluster
leader iff no heavier *leader* has it in its gate, and it joins the heaviest leader whose
gate holds it, which is exactly the cluster the sequential "pop the heaviest, absorb its
gate" loop gives it. All pairwise gate distances come from one matrix product. In the common
case (every component's heaviest coverer is a leader) the labels follow from one argmax.
Otherwise the sequential loop runs once per output cluster on Python-int bitsets of the
rank-ordered gate rows (next leader = lowest set bit, absorb = one AND-NOT), with no numpy
call inside the loop.
Moment matching is one matrix product of per-component moments with the cluster weights.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
"""

from __future__ import annotations

import numpy as np

from .gaussian import sym_inverse
from .mixture import N_ROWS, ROW_PXX, ROW_W, ROW_X, ROW_Y

_WEIGHT_FLOOR = 1e-150

__all__ = [
    "prune",
    "merge",
    "cap",
    "reduce",
    "greedy_clusters",
    "gate_distances",
]


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
    """Keep the ``max_components`` largest-weight components, in their original order.

    Among equal weights at the boundary the lower index is kept, so the result is defined
    exactly (the compiled bank keeps the same components).

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
    keep = np.sort(np.argsort(-table[ROW_W], kind="stable")[:max_components])
    return table[:, keep]


def gate_distances(means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """Pairwise merge distances ``q[j, i] = (m_i - m_j)^T P_i^-1 (m_i - m_j)``.

    Computed as one matrix product of the expansion
    ``q[j, i] = m_i^T A_i m_i - 2 m_j^T A_i m_i + m_j^T A_i m_j`` (``A_i = P_i^-1``) instead of
    ~10 elementwise passes over the ``(N, N)`` array. The expansion's absolute round-off is
    ~1e-15 ``|m|^2 / sigma^2``, i.e. < 1e-9 for a 1 cm component 100 m away, negligible
    against merge gates of order 1.

    Parameters
    ----------
    means : ndarray, shape (2, N)
    covs : ndarray, shape (3, N)

    Returns
    -------
    ndarray, shape (N, N)
        ``q[j, i]`` uses the covariance of the *candidate* ``i`` (Vo & Ma 2006, Table II).
    """
    n = means.shape[1]
    x = means[0]
    inv, _ = sym_inverse(covs)  # rows A_xx, A_xy, A_yy
    lhs = np.empty((6, n))  # terms of m_j
    np.multiply(means, x, out=lhs[0:2])  # x_j^2, x_j y_j
    lhs[1] *= 2.0
    np.multiply(means[1], means[1], out=lhs[2])
    np.multiply(means, -2.0, out=lhs[3:5])
    lhs[5] = 1.0
    rhs = np.empty((6, n))  # terms of candidate i
    rhs[0:3] = inv
    v = rhs[3:5]
    np.multiply(inv[0:2], x, out=v)  # A_i m_i
    v += inv[1:3] * means[1]
    mv = means * v
    np.add(mv[0], mv[1], out=rhs[5])  # m_i^T A_i m_i
    # Guard: the expansion leaves ~1e-13 round-off on the diagonal, which is exactly 0.
    q = lhs.T.dot(rhs)
    q.flat[:: n + 1] = 0.0
    return q


def greedy_clusters(close: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Cluster labels of Vo & Ma's greedy merge from a gate matrix.

    Components are ranked by decreasing weight (ties: lower index first). Component ``i`` is
    a *leader* iff no higher-ranked leader ``j`` has ``close[j, i]``; every component joins
    the highest-ranked leader whose gate holds it. This is exactly what the sequential
    "pop the heaviest, absorb its gate" loop produces.

    Parameters
    ----------
    close : ndarray of bool, shape (N, N)
        ``close[j, i]``: component ``i`` is inside component ``j``'s merge gate.
        ``close[i, i]`` must be True.
    weights : ndarray, shape (N,)
        Component weights (>= 0).

    Returns
    -------
    ndarray of int, shape (N,)
        ``labels[i]``: index of the leader of ``i``'s cluster (``labels[j] == j`` for leaders).
    """
    n = close.shape[0]
    index = np.arange(n)
    order = np.lexsort((index, -weights))  # rank order, ties: lower index first
    # Score = n - rank (> 0): any coverer beats a non-coverer (0) and the highest-ranked one
    # wins. (Not ``weight + 1``: below ~1e-16 every weight + 1 rounds to 1.0, and the lowest
    # index would win instead of the heaviest.)
    rank_score = np.empty(n)
    rank_score[order] = np.arange(n, 0, -1)
    score = close * rank_score[:, None]  # [j, i]
    best = score.argmax(axis=0)  # highest-ranked component whose gate holds i (maybe i)
    certain = best == index  # nobody ranked above covers it: certainly a leader
    certain_best = certain[best]
    if np.count_nonzero(certain_best) == n:
        # Every best coverer is a leader, so every component's cluster is known: done.
        return best
    # General case (covering chains: i's best coverer is itself absorbed by someone else).
    # Run the sequential greedy itself, once per output cluster, on Python-int bitsets: with
    # the gate matrix in rank order, the next leader is the lowest set bit of the remaining
    # set, and absorbing its gate is one AND-NOT. The rows are packed to bytes once; a row
    # becomes an int only for a leader.
    packed = np.packbits(close[np.ix_(order, order)], axis=1, bitorder="little")
    row_bytes = packed.shape[1]
    buf = packed.tobytes()
    from_bytes = int.from_bytes
    remaining = (1 << n) - 1
    leaders = []
    while remaining:
        j = (remaining & -remaining).bit_length() - 1  # highest-ranked remaining component
        leaders.append(j)
        start = j * row_bytes
        remaining &= ~from_bytes(buf[start : start + row_bytes], "little")
    # Each component joins the highest-ranked leader whose gate holds it.
    lead = order[leaders]
    return lead[score[lead].argmax(axis=0)]


def merge(table: np.ndarray, threshold: float) -> np.ndarray:
    """Vo & Ma greedy merge with moment matching.

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Component table; weights must be >= 0.
    threshold : float
        ``U``: squared Mahalanobis distance ``(m_i - m_j)^T P_i^-1 (m_i - m_j)`` at or below
        which component ``i`` joins the cluster of the heavier component ``j``.

    Returns
    -------
    ndarray, shape (6, L)
        One component per cluster: weight ``W = sum w_i`` (so the total weight is preserved),
        mean ``sum w_i m_i / W``, covariance ``sum w_i (P_i + (m - m_i)(m - m_i)^T) / W``.
        Returns the input table itself when nothing merges.
    """
    n = table.shape[1]
    if n < 2:
        return table
    w = table[ROW_W]
    means = table[ROW_X : ROW_Y + 1]
    covs = table[ROW_PXX:]
    labels = greedy_clusters(gate_distances(means, covs) <= threshold, w)
    is_leader = labels == np.arange(n)
    leaders = is_leader.nonzero()[0]
    n_out = leaders.shape[0]
    if n_out == n:
        return table
    # Guard: weights floored at 1e-150 (far above underflow), so an all-zero cluster still
    # gets a well-defined (unweighted) mean and covariance instead of 0/0. Cluster weights
    # are then exact sums up to that floor.
    member_w = (labels == leaders[:, None]) * np.maximum(w, _WEIGHT_FLOOR)  # (L, N)
    return _moment_match(means, covs, member_w, means[:, w.argmax()][:, None])


def _moment_match(
    means: np.ndarray, covs: np.ndarray, member_w: np.ndarray, ref: np.ndarray
) -> np.ndarray:
    """Moment-matched cluster components from per-cluster member weights.

    Parameters
    ----------
    means : ndarray, shape (2, N)
    covs : ndarray, shape (3, N)
    member_w : ndarray, shape (L, N)
        ``member_w[l, i]``: weight of component ``i`` in cluster ``l`` (0 if not a member).
        Every cluster must have a positive total.
    ref : ndarray, shape (2, 1)
        Reference point (the heaviest mean): moments are taken about it, so no cancellation
        even for a mixture far from the origin.

    Returns
    -------
    ndarray, shape (6, L)
        Weight ``W = sum w_i``, mean ``sum w_i m_i / W``, covariance
        ``sum w_i (P_i + (m - m_i)(m - m_i)^T) / W``.
    """
    # Weighted sums per cluster of [1, d, P + d d^T], d = m - ref.
    rows = np.empty((N_ROWS, means.shape[1]))
    rows[0] = 1.0
    d = rows[1:3]
    np.subtract(means, ref, out=d)
    np.multiply(d, d[0], out=rows[3:5])
    np.multiply(d[1], d[1], out=rows[5])
    rows[3:] += covs
    sums = rows.dot(member_w.T)  # (6, L)
    inv_total = 1.0 / sums[0]
    out = np.empty(sums.shape)
    out[ROW_W] = sums[0]
    mean = out[ROW_X : ROW_Y + 1]
    np.multiply(sums[1:3], inv_total, out=mean)
    cov = out[ROW_PXX:]
    np.multiply(sums[3:], inv_total, out=cov)  # E[P + d d^T] - E[d] E[d]^T
    cov[0:2] -= mean * mean[0]
    cov[2] -= mean[1] * mean[1]
    mean += ref
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
