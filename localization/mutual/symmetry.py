"""Rotational symmetry of an observation set: Stegagno 2012 chapter 4 (Lemma 1, Propositions 1-4).

With anonymous position measurements and a complete measuring graph, the formation is uniquely
recoverable from the robots' observation sets iff the observer's set ``Z_1`` (its detections
plus the origin) is **not** rotationally symmetric (Proposition 1). Proposition 2 tests it: with
``c`` the centroid of ``Z_1`` and ``n = |Z_1|`` (``n - 1`` if ``c`` is in ``Z_1``), ``Z_1`` is
symmetric iff ``Z_1 = Z_1(2 pi / m)`` for some prime factor ``m`` of ``n``. The order ``l`` of its
proper symmetry group ``G_l`` then fixes the number of solutions of the static problem
(Proposition 4): ``(l-1)! (l!)^(n/l - 1)`` if ``c`` is not in ``Z_1``, ``(l!)^((n-1)/l)`` if it is.

With noisy measurements "equal" means equal within ``tol_m``: a one-to-one matching pairs each
point of the rotated set with a distinct point of ``Z_1`` within ``tol_m``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from .se2 import rotation

__all__ = [
    "centroid_in_set",
    "is_rotationally_symmetric",
    "number_of_solutions",
    "prime_factors",
    "symmetry_order",
    "symmetric_partition",
]


def _points(z: np.ndarray, name: str = "points") -> np.ndarray:
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 2 or z.shape[1] != 2 or len(z) < 1 or not np.isfinite(z).all():
        raise ValueError(f"{name} must be a finite (n >= 1, 2) array, got shape {z.shape}")
    return z


def prime_factors(n: int) -> list[int]:
    """The distinct prime factors of ``n >= 1``, ascending (``[]`` for 1)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    out, k, n = [], 2, int(n)
    while k * k <= n:
        if n % k == 0:
            out.append(k)
            while n % k == 0:
                n //= k
        k += 1
    if n > 1:
        out.append(n)
    return out


def centroid_in_set(z: np.ndarray, tol_m: float = 1e-6) -> bool:
    """Whether a point of ``z`` (n, 2) lies on its centroid (within ``tol_m``)."""
    z = _points(z)
    return bool((np.linalg.norm(z - z.mean(axis=0), axis=1) <= tol_m).any())


def _invariant(z: np.ndarray, phi: float, tol_m: float) -> bool:
    """``Z = Z(phi)`` within ``tol_m``: a one-to-one matching of the rotated points to the points
    with every pair within ``tol_m``. An assignment (``linear_sum_assignment``) on the 0/1 cost
    "pair further than ``tol_m``" has cost 0 iff such a perfect matching exists (a min-sum on the
    distances themselves could trade one long pair for shorter ones and miss it)."""
    c = z.mean(axis=0)
    rotated = (z - c) @ rotation(phi).T + c
    d = np.linalg.norm(z[:, None, :] - rotated[None, :, :], axis=-1)
    far = (d > tol_m).astype(np.float64)
    rows, cols = linear_sum_assignment(far)
    return bool(far[rows, cols].sum() == 0.0)


def symmetry_order(z: np.ndarray, tol_m: float = 1e-6) -> int:
    """``l``, the order of the proper symmetry group ``G_l`` of ``z`` (n, 2).

    The candidates are the divisors of ``n`` (or ``n - 1`` with a point on the centroid, Lemma 1);
    the largest ``l`` with ``Z = Z(2 pi / l)`` is the order (``G_l`` contains ``G_m`` for m | l).
    """
    z = _points(z)
    if not (tol_m >= 0):
        raise ValueError(f"tol_m must be >= 0, got {tol_m!r}")
    n = len(z) - (1 if centroid_in_set(z, tol_m) else 0)
    if n < 2:
        return 1 if len(z) == 1 else max(1, n)
    for order in range(n, 1, -1):
        if n % order == 0 and _invariant(z, 2.0 * math.pi / order, tol_m):
            return order
    return 1


def is_rotationally_symmetric(z: np.ndarray, tol_m: float = 1e-6) -> bool:
    """Proposition 2's test: ``Z != Z(2 pi / m)`` for every prime factor ``m`` of ``n`` (``n - 1``
    with a point on the centroid) means **not** symmetric, i.e. a unique solution. ``O(n pi(n))``
    rotations checked."""
    z = _points(z)
    n = len(z) - (1 if centroid_in_set(z, tol_m) else 0)
    if n < 2:
        return False
    return any(_invariant(z, 2.0 * math.pi / m, tol_m) for m in prime_factors(n))


def symmetric_partition(z: np.ndarray, tol_m: float = 1e-6) -> list[np.ndarray]:
    """Lemma 1's partition ``E_Z``: index arrays of the orbits of ``z`` under ``G_l`` (each of
    size ``l``, plus the singleton centroid if it is a point of ``z``)."""
    z = _points(z)
    order = symmetry_order(z, tol_m)
    c = z.mean(axis=0)
    left = set(range(len(z)))
    out = []
    while left:
        k = min(left)
        orbit = {k}
        for m in range(1, order):
            p = rotation(2.0 * math.pi * m / order) @ (z[k] - c) + c
            orbit.add(int(np.argmin(np.linalg.norm(z - p, axis=1))))
        left -= orbit
        out.append(np.array(sorted(orbit)))
    return out


def number_of_solutions(z: np.ndarray, tol_m: float = 1e-6) -> int:
    """Proposition 4: how many formations explain the observations of a complete measuring
    graph whose observer set (detections plus origin) is ``z``."""
    z = _points(z)
    order = symmetry_order(z, tol_m)
    n = len(z)
    if centroid_in_set(z, tol_m) and n > 1:
        return math.factorial(order) ** ((n - 1) // order)
    return math.factorial(order - 1) * math.factorial(order) ** (n // order - 1)
