"""The IR-UKF study's direct estimation: every robot's pose from identified range-bearing readings,
with no initial state, by SLSQP; and the Kabsch alignment used to report its errors.

The IR-UKF study (Sec. III-A, eq. 2): with ``p_i``, ``psi_i`` robot ``i``'s global position and
heading and ``z_ij = rho_ij (cos b_ij, sin b_ij)`` robot ``j`` as ``i`` measures it in ``i``'s
body frame, minimise over all poses::

    J = sum_i sum_{j in S_i} || (p_j - p_i) - R(psi_i) z_ij ||^2

with ``scipy.optimize.minimize(method="SLSQP")``. The swarm's global rotation and translation
are free (3 DOF): the gauge is fixed by holding robot ``anchor`` at the origin with heading 0,
so ``3 (N - 1)`` unknowns remain, and each reading gives 2 equations; the IR-UKF study's eq. 3
needs ``2 |readings| >= 3 N - 3``. ``J`` and its gradient are one vectorised expression over
readings.

The problem is not convex (headings): the first start composes the readings along a spanning tree
from the anchor (position of ``j`` from ``i``'s reading; ``j``'s heading from ``j``'s own reading
of ``i`` when there is one), the others are random; the lowest ``J`` wins.

:func:`kabsch` (Kabsch 1976, proper rotation, ``det R = +1``) fits the estimate onto ground
truth (centroids aligned, then the best rotation) for error reporting, as the study does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from swarm_core.geometry import wrap_angle

__all__ = [
    "DirectResult",
    "align_poses",
    "direct_estimate",
    "direct_objective",
    "kabsch",
    "pose_errors",
]


def _checked_readings(observer, target, range_m, bearing_rad, n_robots: int):
    if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)) or n_robots < 2:
        raise ValueError(f"n_robots must be an integer >= 2, got {n_robots!r}")
    obs = np.asarray(observer)
    tgt = np.asarray(target)
    rho = np.asarray(range_m, dtype=np.float64)
    brg = np.asarray(bearing_rad, dtype=np.float64)
    k = obs.shape[0] if obs.ndim == 1 else -1
    for name, arr in (("observer", obs), ("target", tgt), ("range_m", rho), ("bearing_rad", brg)):
        if arr.ndim != 1 or arr.shape[0] != k:
            raise ValueError(
                f"{name} must be a 1-D array of the readings' length, got {arr.shape}"
            )
    if not (np.isfinite(rho).all() and np.isfinite(brg).all()) or (rho < 0).any():
        raise ValueError("range_m must be finite and >= 0, bearing_rad finite")
    for name, arr in (("observer", obs), ("target", tgt)):
        if k and (
            not np.issubdtype(arr.dtype, np.integer) or arr.min() < 0 or arr.max() >= n_robots
        ):
            raise ValueError(f"{name} must hold robot indices in [0, {n_robots}), got {arr!r}")
    if k and (obs == tgt).any():
        raise ValueError("a reading's observer and target must differ")
    z = np.stack((rho * np.cos(brg), rho * np.sin(brg)), axis=-1)
    return obs.astype(np.int64), tgt.astype(np.int64), z


def direct_objective(
    poses: np.ndarray, observer: np.ndarray, target: np.ndarray, z: np.ndarray
) -> tuple[float, np.ndarray]:
    """``J`` (m^2) and its gradient (N, 3) at ``poses`` (N, 3) for readings ``z`` (K, 2)."""
    psi = poses[observer, 2]
    c, s = np.cos(psi), np.sin(psi)
    rz = np.stack((c * z[:, 0] - s * z[:, 1], s * z[:, 0] + c * z[:, 1]), axis=-1)
    e = poses[target, :2] - poses[observer, :2] - rz  # (K, 2)
    n = poses.shape[0]
    grad = np.zeros((n, 3))
    for axis in (0, 1):
        grad[:, axis] = 2.0 * (
            np.bincount(target, e[:, axis], n) - np.bincount(observer, e[:, axis], n)
        )
    # d(R z)/dpsi = R(psi + pi/2) z = (-rz_y, rz_x)
    grad[:, 2] = -2.0 * np.bincount(observer, e[:, 0] * -rz[:, 1] + e[:, 1] * rz[:, 0], n)
    return float((e * e).sum()), grad


@dataclass(frozen=True, slots=True)
class DirectResult:
    """``poses`` (N, 3) in the gauge frame (``anchor`` at the origin, heading 0); ``cost`` the
    final ``J`` (m^2); ``rms_residual_m`` = sqrt(J / K); ``observable`` (N,) bool: robots linked
    to the anchor by readings; ``heading_observable`` (N,): robots that made a reading (the
    others' headings are not in ``J``); ``enough_readings``: the IR-UKF study's eq. 3."""

    poses: np.ndarray
    cost: float
    rms_residual_m: float
    observable: np.ndarray
    heading_observable: np.ndarray
    enough_readings: bool
    n_starts: int
    success: bool


def _tree_init(n: int, anchor: int, obs, tgt, z, rng) -> tuple[np.ndarray, np.ndarray]:
    """Compose readings along a breadth-first spanning tree from the anchor."""
    poses = np.zeros((n, 3))
    known = np.zeros(n, dtype=bool)
    known[anchor] = True
    heading_known = known.copy()
    poses[:, 2] = rng.uniform(-math.pi, math.pi, n)
    poses[anchor, 2] = 0.0
    frontier = [anchor]
    while frontier:
        nxt = []
        for i in frontier:
            for k in np.flatnonzero(((obs == i) & ~known[tgt]) | ((tgt == i) & ~known[obs])):
                if obs[k] == i:  # i sees j: j = p_i + R(psi_i) z
                    j = int(tgt[k])
                    c, s = math.cos(poses[i, 2]), math.sin(poses[i, 2])
                    poses[j, :2] = poses[i, :2] + (
                        c * z[k, 0] - s * z[k, 1],
                        s * z[k, 0] + c * z[k, 1],
                    )
                else:  # j sees i: heading from the direction of i, then p_j = p_i - R z
                    j = int(obs[k])
                    rho = math.hypot(*z[k])
                    # j's heading is still a random guess: place j consistently with it
                    ang = poses[j, 2] + math.atan2(z[k, 1], z[k, 0])
                    poses[j, :2] = poses[i, :2] - rho * np.array([math.cos(ang), math.sin(ang)])
                known[j] = True
                nxt.append(j)
        frontier = nxt
    # Headings of robots with a reading of a placed robot: psi_j = dir(p_t - p_j) - bearing.
    for k in range(obs.shape[0]):
        j, t = int(obs[k]), int(tgt[k])
        if j != anchor and known[t] and not heading_known[j]:
            d = poses[t, :2] - poses[j, :2]
            poses[j, 2] = math.atan2(d[1], d[0]) - math.atan2(z[k, 1], z[k, 0])
            heading_known[j] = True
    return poses, known


def direct_estimate(
    observer,
    target,
    range_m,
    bearing_rad,
    n_robots: int,
    anchor: int = 0,
    n_starts: int = 8,
    seed: int = 0,
    x0: np.ndarray | None = None,
    ftol: float = 1e-14,
    maxiter: int = 500,
) -> DirectResult:
    """Minimise the IR-UKF study's eq. 2 by SLSQP, robot ``anchor`` held at the origin, heading 0.

    Parameters
    ----------
    observer, target : int arrays (K,)
        Who measured whom (identities, the IR-UKF study's IR modulation).
    range_m, bearing_rad : arrays (K,)
        The readings in the observer's body frame (REP-103).
    n_robots : int
    x0 : (N, 3), optional
        An extra start (e.g. the previous solution), re-expressed in the anchor's gauge.
    n_starts : int
        Starts in all: the spanning-tree composition, ``x0`` if given, then random ones.

    Returns
    -------
    DirectResult
    """
    obs, tgt, z = _checked_readings(observer, target, range_m, bearing_rad, n_robots)
    n = int(n_robots)
    if (
        isinstance(anchor, bool)
        or not isinstance(anchor, (int, np.integer))
        or not 0 <= anchor < n
    ):
        raise ValueError(f"anchor must be a robot index in [0, {n}), got {anchor!r}")
    if isinstance(n_starts, bool) or not isinstance(n_starts, int) or n_starts < 1:
        raise ValueError(f"n_starts must be an integer >= 1, got {n_starts!r}")
    rng = np.random.default_rng(seed)
    free = np.arange(n) != anchor

    def unpack(x: np.ndarray) -> np.ndarray:
        poses = np.zeros((n, 3))
        poses[free] = x.reshape(n - 1, 3)
        return poses

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        f, g = direct_objective(unpack(x), obs, tgt, z)
        return f, g[free].ravel()

    tree, linked = _tree_init(n, anchor, obs, tgt, z, rng)
    starts = [tree]
    if x0 is not None:
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (n, 3) or not np.isfinite(x0).all():
            raise ValueError(f"x0 must be finite of shape ({n}, 3), got {x0.shape}")
        starts.append(_to_gauge(x0, anchor))
    scale = max(1.0, float(np.abs(z).max(initial=1.0))) * math.sqrt(n)
    while len(starts) < n_starts:
        p = np.zeros((n, 3))
        p[:, :2] = rng.uniform(-scale, scale, (n, 2))
        p[:, 2] = rng.uniform(-math.pi, math.pi, n)
        starts.append(_to_gauge(p, anchor))
    best = None
    for start in starts:
        res = minimize(
            fun,
            start[free].ravel(),
            jac=True,
            method="SLSQP",
            options={"ftol": ftol, "maxiter": maxiter},
        )
        if best is None or res.fun < best.fun:
            best = res
    poses = unpack(best.x)
    poses[:, 2] = wrap_angle(poses[:, 2])
    k = obs.shape[0]
    heading_obs = np.zeros(n, dtype=bool)
    heading_obs[obs] = True
    heading_obs[anchor] = True
    return DirectResult(
        poses=poses,
        cost=float(best.fun),
        rms_residual_m=math.sqrt(max(best.fun, 0.0) / k) if k else 0.0,
        observable=linked,
        heading_observable=heading_obs,
        enough_readings=2 * k >= 3 * n - 3,
        n_starts=len(starts),
        success=bool(best.success),
    )


def _to_gauge(poses: np.ndarray, anchor: int) -> np.ndarray:
    """Poses re-expressed with ``anchor`` at the origin, heading 0."""
    a = poses[anchor]
    c, s = math.cos(a[2]), math.sin(a[2])
    d = poses[:, :2] - a[:2]
    out = np.empty_like(poses)
    out[:, 0] = c * d[:, 0] + s * d[:, 1]
    out[:, 1] = -s * d[:, 0] + c * d[:, 1]
    out[:, 2] = wrap_angle(poses[:, 2] - a[2])
    return out


def kabsch(estimate_xy: np.ndarray, truth_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The proper rotation ``R`` (2, 2), ``det R = +1``, and translation ``t`` (2,) minimising
    ``sum_k || R e_k + t - q_k ||^2`` (Kabsch 1976): centroids aligned, ``R`` from the SVD of the
    cross-covariance with the reflection removed."""
    e = np.asarray(estimate_xy, dtype=np.float64)
    q = np.asarray(truth_xy, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 2 or e.shape != q.shape or e.shape[0] < 1:
        raise ValueError(
            f"estimate_xy and truth_xy must both be (K >= 1, 2), got {e.shape} and {q.shape}"
        )
    if not (np.isfinite(e).all() and np.isfinite(q).all()):
        raise ValueError("estimate_xy and truth_xy must be finite")
    ce, cq = e.mean(axis=0), q.mean(axis=0)
    h = (e - ce).T @ (q - cq)
    u, _, vt = np.linalg.svd(h)
    d = 1.0 if np.linalg.det(vt.T @ u.T) >= 0 else -1.0
    rot = vt.T @ np.diag([1.0, d]) @ u.T
    return rot, cq - rot @ ce


def align_poses(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None):
    """``estimate`` poses (N, 3) moved by the Kabsch fit of their positions onto ``truth``'s
    (over ``mask`` if given): positions ``R p + t``, headings ``+ angle(R)``."""
    estimate = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    sel = slice(None) if mask is None else np.asarray(mask, dtype=bool)
    rot, t = kabsch(estimate[sel, :2], truth[sel, :2])
    out = estimate.copy()
    out[:, :2] = estimate[:, :2] @ rot.T + t
    out[:, 2] = wrap_angle(estimate[:, 2] + math.atan2(rot[1, 0], rot[0, 0]))
    return out


def pose_errors(aligned: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-robot position error (m) and wrapped heading error (rad), each (N,)."""
    return (
        np.hypot(*(aligned[:, :2] - truth[:, :2]).T),
        np.abs(wrap_angle(aligned[:, 2] - truth[:, 2])),
    )
