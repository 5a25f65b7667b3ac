"""P-MultiReg: probabilistic multiple registration (Stegagno 2012 section 6.1, Algorithm 1).

The observer ``i`` registers its observation ``Z_i`` (detections plus its origin, labelled ``i``)
with every teammate's ``Z_j`` (same, in ``j``'s frame, origin labelled ``j``). Each iteration:

1. binary registrations (:func:`~localization.mutual.registration.register_pair`) of the current
   aggregate set against every teammate's set not registered yet;
2. the teammate whose registration has the most inliers is taken; its best-scoring solutions are
   mutually *irreconcilable* (the same robot on different features);
3. the fitness test against the current belief (eq. 11, ``int p(x_hat | x) bel(x) dx``, given by
   ``log_fitness``) keeps the solutions within ``log_fitness_drop`` of the best one and drops
   those the caller rates ``-inf`` (outside its belief's gate); an uninformed belief keeps all.
   When no solution survives, the branch goes on without that teammate's set;
4. each kept solution expands the aggregate (matched points averaged, new points added, ``j``'s
   origin labelled), re-tunes the poses already estimated on the new aggregate, and continues as
   its own **branch** when there is more than one.

A branch ends when no remaining set registers. The final pruning keeps the branches that
registered the most teammates with the most inliers; every teammate's hypotheses are the distinct
poses it has in them. In a rotationally symmetric scene the branches are the formations that
Proposition 4 counts (e.g. 6 for four robots on a square).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from swarm_core.geometry import wrap_angle

from .registration import UNLABELLED, _fit, register_pair, registration_covariance

__all__ = ["Branch", "MultiRegConfig", "MultiRegResult", "multi_register"]


@dataclass(frozen=True, slots=True)
class MultiRegConfig:
    """P-MultiReg's parameters.

    Attributes
    ----------
    gate_m : float
        Inlier distance of a correspondence (m). 0.1: about 3 x the measured lidar detection
        noise (robust std 0.015 m per axis in ``lab-3m-4``) on both sets.
    sigma_m : float
        Point noise for the registration covariance (m): the detections' measured overall std
        (0.03 m, tails included).
    min_inliers : int
        Correspondences a registration needs (origins included).
    max_samples : int
        RANSAC budget per binary registration.
    log_fitness_drop : float
        Fitness test: solutions whose log-fitness is more than this below the best one's are
        pruned (ln 100: a hundred times less compatible with the belief).
    max_branches : int
        Cap on the finished branches (factorial in the ambiguous worst case, Corollary 1).
    """

    gate_m: float = 0.1
    sigma_m: float = 0.03
    min_inliers: int = 3
    max_samples: int = 20000
    log_fitness_drop: float = math.log(100.0)
    max_branches: int = 1000

    def __post_init__(self) -> None:
        for name in ("gate_m", "sigma_m", "log_fitness_drop"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"multireg.{name} must be a finite number > 0, got {v!r}")
        for name, low in (("min_inliers", 2), ("max_samples", 1), ("max_branches", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"multireg.{name} must be an integer >= {low}, got {v!r}")


@dataclass
class Branch:
    """A partial (or, when finished, complete) solution of the multiple registration."""

    points: np.ndarray  # (A, 2) aggregate, observer frame
    labels: np.ndarray  # (A,) robot label or -1
    counts: np.ndarray  # (A,) observations averaged into each point
    poses: dict[int, np.ndarray] = field(default_factory=dict)  # label -> (3,)
    pairs: dict[int, np.ndarray] = field(default_factory=dict)  # label -> (K, 2)
    covariances: dict[int, np.ndarray] = field(default_factory=dict)
    inliers: int = 0
    sources: dict[int, np.ndarray] = field(default_factory=dict)  # label -> its observation


@dataclass(frozen=True, slots=True)
class MultiRegResult:
    """What P-MultiReg found.

    Attributes
    ----------
    hypotheses : dict
        ``label -> (poses (H, 3), covariances (H, 3, 3))``, distinct poses over the kept branches.
    branches : list of Branch
        The kept complete solutions (formations).
    n_branches : int
        Finished branches before the final pruning.
    truncated : bool
        ``max_branches`` was reached.
    """

    hypotheses: dict[int, tuple[np.ndarray, np.ndarray]]
    branches: list[Branch]
    n_branches: int
    truncated: bool


def _expand(branch: Branch, label: int, source: np.ndarray, reg, sigma_m: float) -> Branch:
    """The aggregate with ``source`` (registered as ``reg``) merged in, poses re-tuned."""
    c, s = math.cos(reg.pose[2]), math.sin(reg.pose[2])
    moved = source @ np.array([[c, s], [-s, c]]) + reg.pose[:2]
    points, labels, counts = branch.points.copy(), branch.labels.copy(), branch.counts.copy()
    matched = dict((int(a), int(b)) for a, b in reg.pairs)
    pairs = []
    for k in range(len(source)):  # the teammate's few points
        if k in matched:
            t = matched[k]
            points[t] = (points[t] * counts[t] + moved[k]) / (counts[t] + 1)
            counts[t] += 1
            if k == 0:
                labels[t] = label
        else:
            t = len(points)
            points = np.vstack([points, moved[k]])
            labels = np.append(labels, label if k == 0 else UNLABELLED)
            counts = np.append(counts, 1)
        pairs.append((k, t))
    out = Branch(
        points,
        labels,
        counts,
        dict(branch.poses),
        dict(branch.pairs),
        dict(branch.covariances),
        branch.inliers + reg.n_inliers,
        {**branch.sources, label: source},
    )
    out.pairs[label] = np.array(pairs, dtype=np.int64)
    out.poses[label] = reg.pose.copy()
    out.covariances[label] = reg.covariance
    # Tune every pose already estimated on the updated aggregate (same correspondences).
    for lab, prs in out.pairs.items():
        src = out.sources[lab]
        pose = _fit(src, points, prs)
        out.poses[lab] = pose
        out.covariances[lab] = registration_covariance(src, prs, pose[2], sigma_m)
    return out


def multi_register(
    observer: np.ndarray,
    teammates: dict[int, np.ndarray],
    log_fitness: Callable[[int, np.ndarray, np.ndarray], np.ndarray | None] | None = None,
    config: MultiRegConfig | None = None,
    rng: np.random.Generator | None = None,
) -> MultiRegResult:
    """Algorithm 1.

    Parameters
    ----------
    observer : ndarray, shape (M, 2)
        The observer's detections in its body frame (its origin is added, labelled 0).
    teammates : dict
        ``label (int >= 1) -> detections (K, 2)`` in that teammate's body frame.
    log_fitness : callable, optional
        ``(label, poses (H, 3), covariances (H, 3, 3)) -> (H,)`` log of eq. 11 under the current
        belief (``-inf``: rejected outright), or ``None`` when the belief about ``label`` is
        uninformed.
    """
    cfg = config or MultiRegConfig()
    obs = np.asarray(observer, dtype=np.float64).reshape(-1, 2)
    sets = {
        int(k): np.vstack([np.zeros((1, 2)), np.asarray(v, dtype=np.float64).reshape(-1, 2)])
        for k, v in teammates.items()
    }
    if any(k < 1 for k in sets):
        raise ValueError(f"teammate labels must be >= 1 (0 is the observer), got {sorted(sets)}")
    root = Branch(
        np.vstack([np.zeros((1, 2)), obs]),
        np.array([0] + [UNLABELLED] * len(obs), dtype=np.int64),
        np.ones(len(obs) + 1, dtype=np.int64),
    )
    finished: list[Branch] = []
    stack = [(root, tuple(sorted(sets)))]
    truncated = False
    while stack:
        branch, remaining = stack.pop()
        if len(finished) >= cfg.max_branches:
            truncated = True
            break
        best_label, best_regs = None, []
        for lab in remaining:
            src = sets[lab]
            regs = register_pair(
                branch.points,
                branch.labels,
                src,
                np.array([lab] + [UNLABELLED] * (len(src) - 1), dtype=np.int64),
                gate_m=cfg.gate_m,
                min_inliers=cfg.min_inliers,
                max_samples=cfg.max_samples,
                sigma_m=cfg.sigma_m,
                rng=rng,
            )
            if regs and (not best_regs or regs[0].n_inliers > best_regs[0].n_inliers):
                best_label, best_regs = lab, regs
        if best_label is None:
            finished.append(branch)
            continue
        if log_fitness is not None:
            lf = log_fitness(
                best_label,
                np.array([r.pose for r in best_regs]),
                np.array([r.covariance for r in best_regs]),
            )
            if lf is not None:
                lf = np.asarray(lf, dtype=np.float64)
                top = lf.max()
                best_regs = [
                    r
                    for r, v in zip(best_regs, lf, strict=True)
                    if np.isfinite(v) and v >= top - cfg.log_fitness_drop
                ]
        rest = tuple(k for k in remaining if k != best_label)
        if not best_regs:  # every solution contradicts the belief: go on without this set
            stack.append((branch, rest))
            continue
        for reg in reversed(best_regs):  # depth first, best solution explored first
            stack.append((_expand(branch, best_label, sets[best_label], reg, cfg.sigma_m), rest))
    n_finished = len(finished)
    if not finished:
        return MultiRegResult({}, [], 0, truncated)
    key = [(len(b.poses), b.inliers) for b in finished]
    top = max(key)
    kept = [b for b, k in zip(finished, key, strict=True) if k == top]
    hyps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for lab in sets:
        poses, covs = [], []
        for b in kept:
            if lab not in b.poses:
                continue
            p = b.poses[lab]
            if any(
                np.hypot(*(q[:2] - p[:2])) < 2 * cfg.gate_m
                and abs(float(wrap_angle(q[2] - p[2]))) < math.radians(10.0)
                for q in poses
            ):
                continue
            poses.append(p)
            covs.append(b.covariances[lab])
        if poses:
            hyps[lab] = (np.array(poses), np.array(covs))
    return MultiRegResult(hyps, kept, n_finished, truncated)
