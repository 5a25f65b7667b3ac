"""Binary registration of two anonymous feature sets (Stegagno 2012 section 6.1, Fig. 17).

A *registration* of a source set ``S`` (a teammate ``j``'s observation: its detections plus its
own origin, in ``j``'s body frame) onto a target set ``T`` (the observer's observation, or the
aggregate of several registered ones, in the observer's frame) is a pose ``x_j`` (``j``'s frame
in the target frame) and a one-to-one correspondence between points of ``S`` and ``T`` with
``x_j (+) s ~ t``. Origins are labelled (the robot that observed the set sits there): a labelled
point may only correspond to an unlabelled one or to one with the same label.

RANSAC over minimal samples: a sample is two source points and two target points whose mutual
distances agree within ``gate_m``; it fixes a pose. When there are fewer distance-consistent
samples than ``max_samples`` they are all scored (exhaustive; the sets here hold tens of points),
otherwise ``max_samples`` are drawn at random. A pose scores its inliers (source points with a
compatible target point within ``gate_m``). Every pose with the best score (``>= min_inliers``)
is refined by least squares (closed-form Kabsch, :func:`localization.baselines.direct.kabsch`) on
its one-to-one correspondences, twice, and the distinct refined poses are returned: in a
rotationally symmetric scene there are several, as Propositions 3-4 predict.

Covariance of a refined pose (hand-derived, small-noise): with ``K`` correspondences, point noise
``sigma`` on both sides (``2 sigma^2`` per difference) and source spread
``S = sum |s_k - s_bar|^2``,
the rotation has variance ``2 sigma^2 / S``; the origin ``t = q_bar - R s_bar`` has
``2 sigma^2 / K I + var_theta (J R s_bar)(J R s_bar)^T`` and covariance
``-var_theta J R s_bar`` with the angle (``J`` the rotation by +90 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from localization.baselines.direct import kabsch
from swarm_core.geometry import wrap_angle

__all__ = ["Registration", "register_pair", "registration_covariance"]

UNLABELLED = -1


@dataclass(frozen=True, slots=True)
class Registration:
    """One solution of a binary registration.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        ``[x_m, y_m, theta_rad]`` of the source frame in the target frame.
    pairs : ndarray, shape (K, 2), int
        ``(source index, target index)`` correspondences.
    rms_m : float
        RMS distance between ``pose (+) s`` and ``t`` over the pairs (m).
    covariance : ndarray, shape (3, 3)
        Of ``pose`` (m^2, m rad, rad^2), see the module docstring.
    """

    pose: np.ndarray
    pairs: np.ndarray
    rms_m: float
    covariance: np.ndarray

    @property
    def n_inliers(self) -> int:
        return len(self.pairs)


def registration_covariance(
    source: np.ndarray, pairs: np.ndarray, theta: float, sigma_m: float
) -> np.ndarray:
    """Covariance (3, 3) of a least-squares pose fitted on ``pairs`` of ``source`` (N, 2) points
    with point noise ``sigma_m`` on both sets (module docstring)."""
    s = source[pairs[:, 0]]
    k = len(s)
    s_bar = s.mean(axis=0)
    spread = float(((s - s_bar) ** 2).sum())
    var_d = 2.0 * sigma_m**2
    var_th = var_d / max(spread, 1e-6)
    c, sn = math.cos(theta), math.sin(theta)
    rs = np.array([c * s_bar[0] - sn * s_bar[1], sn * s_bar[0] + c * s_bar[1]])
    jrs = np.array([-rs[1], rs[0]])
    cov = np.zeros((3, 3))
    cov[:2, :2] = var_d / k * np.eye(2) + var_th * np.outer(jrs, jrs)
    cov[:2, 2] = cov[2, :2] = -var_th * jrs
    cov[2, 2] = var_th
    return cov


def _compatible(source_labels: np.ndarray, target_labels: np.ndarray) -> np.ndarray:
    """(Ms, Mt) bool: labelled points match only unlabelled ones or their own label."""
    s = source_labels[:, None]
    t = target_labels[None, :]
    return (s == UNLABELLED) | (t == UNLABELLED) | (s == t)


def _transform(poses: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """poses (H, 3), pts (M, 2) -> (H, M, 2)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + c * pts[None, :, 0] - s * pts[None, :, 1]
    y = poses[:, 1:2] + s * pts[None, :, 0] + c * pts[None, :, 1]
    return np.stack([x, y], axis=-1)


def _match(moved: np.ndarray, target: np.ndarray, compat: np.ndarray, gate_m: float) -> np.ndarray:
    """Greedy one-to-one correspondences (nearest first) within ``gate_m``: (K, 2) int."""
    d = np.linalg.norm(moved[:, None, :] - target[None, :, :], axis=-1)
    d = np.where(compat, d, np.inf)
    si, ti = np.nonzero(d <= gate_m)
    order = np.argsort(d[si, ti], kind="stable")
    used_s, used_t, out = set(), set(), []
    for k in order:  # a handful of candidate pairs, not particles
        a, b = int(si[k]), int(ti[k])
        if a not in used_s and b not in used_t:
            used_s.add(a)
            used_t.add(b)
            out.append((a, b))
    return np.array(sorted(out), dtype=np.int64).reshape(-1, 2)


def _fit(source: np.ndarray, target: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    rot, t = kabsch(source[pairs[:, 0]], target[pairs[:, 1]])
    return np.array([t[0], t[1], math.atan2(rot[1, 0], rot[0, 0])])


def register_pair(
    target: np.ndarray,
    target_labels: np.ndarray,
    source: np.ndarray,
    source_labels: np.ndarray,
    *,
    gate_m: float = 0.1,
    min_inliers: int = 3,
    max_samples: int = 20000,
    sigma_m: float = 0.03,
    distinct_m: float | None = None,
    distinct_rad: float = math.radians(10.0),
    rng: np.random.Generator | None = None,
) -> list[Registration]:
    """All best-scoring distinct registrations of ``source`` onto ``target``.

    Parameters
    ----------
    target : ndarray, shape (Mt, 2)
        Target points (m).
    target_labels : ndarray, shape (Mt,), int
        Robot label of each target point, ``-1`` if unlabelled.
    source : ndarray, shape (Ms, 2)
        Source points in the source frame (m).
    source_labels : ndarray, shape (Ms,), int
        As ``target_labels``.
    gate_m : float
        Inlier distance and the tolerance of the minimal samples' distance check (m).
    min_inliers : int
        A registration needs at least this many correspondences (two always fit; the third is
        the evidence).
    max_samples : int
        RANSAC budget: above it, this many minimal samples are drawn at random (``rng``).
    sigma_m : float
        Point noise for the covariance (m).
    distinct_m, distinct_rad : float
        Refined poses closer than this (default ``2 gate_m``) and ``distinct_rad`` are one
        solution.

    Returns
    -------
    list of Registration
        Best inlier count first, then lowest RMS; empty if none reaches ``min_inliers``.
    """
    target = np.asarray(target, dtype=np.float64).reshape(-1, 2)
    source = np.asarray(source, dtype=np.float64).reshape(-1, 2)
    tl = np.asarray(target_labels, dtype=np.int64).reshape(-1)
    sl = np.asarray(source_labels, dtype=np.int64).reshape(-1)
    if len(tl) != len(target) or len(sl) != len(source):
        raise ValueError(
            f"labels must match the points: target {len(target)} vs {len(tl)}, "
            f"source {len(source)} vs {len(sl)}"
        )
    if not (gate_m > 0):
        raise ValueError(f"gate_m must be > 0, got {gate_m!r}")
    if isinstance(min_inliers, bool) or int(min_inliers) < 2:
        raise ValueError(f"min_inliers must be an integer >= 2, got {min_inliers!r}")
    distinct_m = 2.0 * gate_m if distinct_m is None else distinct_m
    ms, mt = len(source), len(target)
    if ms < 2 or mt < 2:
        return []
    compat = _compatible(sl, tl)
    # Minimal samples: unordered source pairs (a < b) x ordered target pairs (c != d).
    a, b = np.triu_indices(ms, 1)
    c, d = np.nonzero(~np.eye(mt, dtype=bool))
    ds = np.linalg.norm(source[a] - source[b], axis=1)
    dt = np.linalg.norm(target[c] - target[d], axis=1)
    ok = np.abs(ds[:, None] - dt[None, :]) <= gate_m
    ok &= compat[a][:, c] & compat[b][:, d]
    ok &= (ds[:, None] > gate_m) & (dt[None, :] > gate_m)  # degenerate samples fix no angle
    ip, jp = np.nonzero(ok)
    if len(ip) == 0:
        return []
    if len(ip) > max_samples:
        rng = np.random.default_rng(0) if rng is None else rng
        pick = rng.choice(len(ip), size=max_samples, replace=False)
        ip, jp = ip[pick], jp[pick]
    sa, sb, tc, td = source[a[ip]], source[b[ip]], target[c[jp]], target[d[jp]]
    theta = np.arctan2(td[:, 1] - tc[:, 1], td[:, 0] - tc[:, 0]) - np.arctan2(
        sb[:, 1] - sa[:, 1], sb[:, 0] - sa[:, 0]
    )
    cos, sin = np.cos(theta), np.sin(theta)
    # Translation from the sample's midpoints (least squares for two pairs, given theta).
    ms_ = 0.5 * (sa + sb)
    mt_ = 0.5 * (tc + td)
    tx = mt_[:, 0] - (cos * ms_[:, 0] - sin * ms_[:, 1])
    ty = mt_[:, 1] - (sin * ms_[:, 0] + cos * ms_[:, 1])
    poses = np.stack([tx, ty, wrap_angle(theta)], axis=1)
    moved = _transform(poses, source)  # (H, Ms, 2)
    dist = np.linalg.norm(moved[:, :, None, :] - target[None, None, :, :], axis=-1)
    close = (dist <= gate_m) & compat[None]
    # Inliers, one-to-one in the count: min(#source points matched, #target points matched).
    score = np.minimum(close.any(axis=2).sum(axis=1), close.any(axis=1).sum(axis=1))
    best = int(score.max())
    if best < min_inliers:
        return []
    out: list[Registration] = []
    for h in np.flatnonzero(score == best):  # the best samples' poses: few, refined one by one
        pose = poses[h]
        pairs = _match(moved[h], target, compat, gate_m)
        for _ in range(2):
            if len(pairs) < 2:
                break
            pose = _fit(source, target, pairs)
            pairs = _match(_transform(pose[None], source)[0], target, compat, gate_m)
        if len(pairs) < min_inliers or len(pairs) < best:
            continue
        pose[2] = float(wrap_angle(pose[2]))
        dup = False
        for r in out:
            if (
                np.hypot(*(r.pose[:2] - pose[:2])) < distinct_m
                and abs(float(wrap_angle(r.pose[2] - pose[2]))) < distinct_rad
            ):
                dup = True
                break
        if dup:
            continue
        res = _transform(pose[None], source[pairs[:, 0]])[0] - target[pairs[:, 1]]
        rms = float(np.sqrt((res**2).sum(axis=1).mean()))
        out.append(
            Registration(
                pose, pairs, rms, registration_covariance(source, pairs, pose[2], sigma_m)
            )
        )
    out.sort(key=lambda r: (-r.n_inliers, r.rms_m))
    return out
