"""Marginal association probabilities of a track-oriented PMB update.

Problem (Williams 2015, Williams & Lau 2014): ``N`` tracks and ``M`` measurements. Track ``i``
takes one hypothesis ``a_i in {0 (missed / not there), 1..M}``, each measurement is used by at
most one track, and a measurement no track uses is a new target or clutter. The weight of a
joint association is

    prod_i w_i(a_i) * prod_{j unused} c_j,

with ``w_i(0) = 1 - r_i P_d,i`` (missed or not there), ``w_i(j) = r_i P_d,i g_ij`` (``g``: the
measurement likelihood) and ``c_j = kappa + e_j`` (clutter plus the Poisson intensity's
likelihood ``e_j``). Dividing by ``prod_i w_i(0) prod_j c_j`` leaves one number per pair,

    psi_ij = w_i(j) / (w_i(0) c_j)   (shape (N, M)),

and the joint weight ``prod_{i: a_i > 0} psi_{i a_i}``. :func:`lbp_marginals` approximates the
marginals ``P(a_i = j)`` and ``P(measurement j unused)`` by loopy belief propagation on the
bipartite track / measurement graph (Williams & Lau 2014, eqs. 30-31):

    mu_{i->j} = psi_ij / (1 + sum_{j' != j} psi_ij' nu_{j'->i})
    nu_{j->i} = 1 / (1 + sum_{i' != i} mu_{i'->j})

starting from ``nu = 1``, then

    P(a_i = j) = psi_ij nu_{j->i} / (1 + sum_j' psi_ij' nu_{j'->i}),   P(a_i = 0) = 1 / (same)
    P(j unused) = 1 / (1 + sum_i mu_{i->j}).

On a graph without cycles (e.g. one track, or one measurement, or tracks with disjoint gates)
this is exact. The "sum over all but one" is computed as an exclusive prefix sum plus an
exclusive suffix sum (sequential ``cumsum``), never as ``total - own`` (which cancels when one
message dominates) and in the same order as the compiled kernel.

:func:`exact_marginals` enumerates every joint association: the reference for tests (small
problems only).
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["lbp_marginals", "exact_marginals", "exclusive_sums"]


def exclusive_sums(a: np.ndarray) -> np.ndarray:
    """``out[i, j] = sum_{j' != j} a[i, j']`` for ``a`` of shape ``(N, M)``, without cancellation.

    Prefix sums of the entries left of ``j`` plus suffix sums of those right of it, each
    accumulated sequentially (as the compiled kernel does).
    """
    n, m = a.shape
    out = np.zeros((n, m))
    if m > 1:
        out[:, 1:] = np.cumsum(a[:, :-1], axis=1)
        out[:, :-1] += np.cumsum(a[:, :0:-1], axis=1)[:, ::-1]
    return out


def lbp_marginals(
    psi: np.ndarray, max_iterations: int = 100, tolerance: float = 1e-12
) -> tuple[np.ndarray, np.ndarray, int]:
    """Association marginals by loopy belief propagation (Williams & Lau 2014).

    Parameters
    ----------
    psi : ndarray, shape (N, M)
        Normalised pair weights ``w_i(j) / (w_i(0) c_j)``, finite and >= 0 (0: gated out).
    max_iterations : int
        Cap on the sweeps.
    tolerance : float
        Stop when ``max |nu_new - nu| <= tolerance`` over the pairs with ``psi > 0`` (``nu`` is
        in ``(0, 1]``; the other messages multiply ``psi = 0`` and change nothing).

    Returns
    -------
    p_track : ndarray, shape (N, M + 1)
        ``p_track[i, 0] = P(a_i = 0)``, ``p_track[i, 1 + j] = P(a_i = j)``; rows sum to 1.
    p_unused : ndarray, shape (M,)
        ``P(measurement j is not used by any track)``: new target or clutter.
    iterations : int
        Sweeps run.
    """
    n, m = psi.shape
    nu = np.ones((n, m))
    iterations = 0
    gated_in = psi > 0.0
    if gated_in.any():
        for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported
            mu = psi / (1.0 + exclusive_sums(psi * nu))
            nu_new = 1.0 / (1.0 + exclusive_sums(mu.T).T)
            # Only messages on gated-in pairs matter (elsewhere they multiply psi = 0).
            delta = np.max(np.abs(nu_new - nu)[gated_in])
            nu = nu_new
            if delta <= tolerance:
                break
    a = psi * nu
    mu = psi / (1.0 + exclusive_sums(a))
    p_track = np.empty((n, m + 1))
    p_track[:, 0] = 1.0
    p_track[:, 1:] = a
    p_track /= (1.0 + a.sum(axis=1))[:, None]
    p_unused = 1.0 / (1.0 + mu.sum(axis=0))
    return p_track, p_unused, iterations


def exact_marginals(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact marginals by enumerating every joint association (test reference, small N, M).

    Same inputs and outputs as :func:`lbp_marginals` (without the iteration count).
    """
    n, m = psi.shape
    p_track = np.zeros((n, m + 1))
    p_unused = np.zeros(m)
    total = 0.0
    for assign in itertools.product(range(m + 1), repeat=n):
        used = [a for a in assign if a]
        if len(used) != len(set(used)):
            continue
        weight = 1.0
        for i, a in enumerate(assign):
            if a:
                weight *= psi[i, a - 1]
        total += weight
        for i, a in enumerate(assign):
            p_track[i, a] += weight
        for j in range(m):
            if j + 1 not in used:
                p_unused[j] += weight
    return p_track / total, p_unused / total
