"""Mixture reduction: prune, merge, cap (Vo & Ma 2006, Table II), on component tables.

* :func:`prune` drops components below a weight threshold. **It loses mass**: the total weight
  falls by exactly the pruned weights (we do not redistribute them as Stone Soup does: a
  pruned component is evidence we chose to forget, not evidence for the survivors).
* :func:`merge` is Vo & Ma's greedy merge. Take the heaviest remaining component ``j``;
  every remaining ``i`` with ``(m_i - m_j)^T P_i^-1 (m_i - m_j) <= U`` joins its cluster; the
  cluster becomes one moment-matched component. **It preserves the total weight** (each
  cluster's weight is the sum of its members') and the first two moments of every cluster.
* :func:`cap` keeps the ``max_components`` heaviest components (loses the rest's mass).

The greedy merge is computed without a Python loop over components (see
:func:`greedy_clusters`): a component is a cluster leader iff no heavier *leader* has it in
its gate, and it joins the heaviest leader whose gate holds it. That is exactly the cluster
the sequential "pop the heaviest, absorb its gate" loop gives it.

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
"""

from __future__ import annotations

import numpy as np

from .gaussian import sym_inverse
from .mixture import N_ROWS, ROW_PXX, ROW_W, ROW_X, ROW_Y

#: Up to this many chain members are resolved one by one; beyond, by whole-array passes.
_MAX_SEQUENTIAL = 16
_WEIGHT_FLOOR = 1e-150

__all__ = ["prune", "merge", "cap", "reduce", "greedy_clusters", "gate_distances"]


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
    q = lhs.T.dot(rhs)
    # Guard: the expansion leaves ~1e-13 round-off on the diagonal, which is exactly 0.
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
    # weight + 1 > 0 keeps the weight order and makes any coverer beat a non-coverer (0);
    # argmax breaks ties towards the lower index, which is our rank tie-break.
    score = close * (weights + 1.0)[:, None]  # [j, i]
    best = score.argmax(axis=0)  # highest-ranked component whose gate holds i (maybe i)
    certain = best == index  # nobody ranked above covers it: certainly a leader
    certain_best = certain[best]
    if np.count_nonzero(certain_best) == n:
        # Every best coverer is a leader, so every component's cluster is known: done.
        return best
    # General case: covering chains. Resolve the components whose best coverer is not a
    # certain leader ("uncertain") by the recursion
    #     leader[i] = no leader ranked above i has i in its gate.
    # In column i of `masked` (leaders' scores plus i's own), the argmax is i exactly when no
    # leader above covers i, and otherwise it is the highest-ranked leader covering i, i.e.
    # i's cluster. Components certainly absorbed keep `best` (a certain leader).
    diagonal = (index, index)
    own = score[diagonal]
    uncertain = (~certain_best).nonzero()[0]
    if uncertain.shape[0] <= _MAX_SEQUENTIAL:
        # Few uncertain components (the usual case): decide them one by one in rank order;
        # every leader ranked above i is known by the time i is decided.
        uncertain = uncertain[np.lexsort((uncertain, -weights[uncertain]))]
        labels = best.copy()
        leader = certain.copy()
        for i in uncertain.tolist():
            column = score[:, i] * leader
            column[i] = own[i]
            top = int(column.argmax())
            labels[i] = top
            leader[i] = top == i
        return labels
    # Many uncertain components: iterate the recursion on all of them at once to its fixed
    # point (it has one solution; each pass fixes at least one more rank). Start from "not
    # certainly absorbed", which is exact for chains of depth 2.
    leader = certain | ~certain_best
    while True:
        masked = score * leader[:, None]
        masked[diagonal] = own
        labels = masked.argmax(axis=0)
        new_leader = labels == index
        if np.count_nonzero(new_leader != leader) == 0:
            return labels
        leader = new_leader


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
    member = labels == leaders[:, None]  # (L, N) cluster membership
    # Guard: weights floored at 1e-150 (far above underflow) for the moments, so an all-zero
    # cluster still gets a well-defined (unweighted) mean and covariance instead of 0/0.
    floored = np.maximum(w, _WEIGHT_FLOOR)
    member_w = member * floored
    # Weighted sums per cluster of [1, d, P, d d^T] with d = m - m_leader: moments about
    # each cluster's leader, so no cancellation even far from the origin.
    rows = np.empty((9, n))
    rows[0] = 1.0
    d = rows[1:3]
    np.subtract(means, means[:, labels], out=d)
    rows[3:6] = covs
    np.multiply(d, d[0], out=rows[6:8])
    np.multiply(d[1], d[1], out=rows[8])
    sums = rows.dot(member_w.T)  # (9, L)
    inv_total = 1.0 / sums[0]
    shift = sums[1:3] * inv_total
    out = np.empty((N_ROWS, n_out))
    # Cluster weights are the plain sums of member weights (total weight preserved); the
    # floored sums differ only if some weight was below the floor.
    out[ROW_W] = sums[0] if w.min() >= _WEIGHT_FLOOR else member.dot(w)
    np.add(means[:, leaders], shift, out=out[ROW_X : ROW_Y + 1])
    cov = out[ROW_PXX:]
    np.multiply(sums[3:6] + sums[6:9], inv_total, out=cov)
    cov[0:2] -= shift * shift[0]
    cov[2] -= shift[1] * shift[1]
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
