"""ID-PHD: a robot-centric GM-PHD whose components carry teammate identities.

Stegagno et al. (ICRA 2013, seed ``002``) let a supervisor that sees *anonymous* positions of
its teammates recover *who is who* from the odometry each teammate broadcasts with its ID.
Here the observer is a ground robot of the swarm: it sees anonymous lidar detections in its own
body frame (as :class:`~localization.RobotCentricPHD` does) and receives, by radio, every
teammate's own odometry increment with its ID.

Each component has a **tag** (``-1`` not yet associated, ``i >= 0`` robot ``i``, ``-2`` static
false positive, whose odometry is null) and a Gaussian over the teammate's pose
``(x, y, psi)`` in the observer frame (3x3 covariance).

Time update (seed ``002`` eqs. 14-19, derived from total probability in seed ``001``, 13.2).
The teammate moves by its own increment ``u_i = (d_i, dpsi_i)`` (expressed in its frame at the
start of the interval); the observer moves by ``u_0 = (d_0, dpsi_0)`` (in its frame). In the
old observer frame the teammate ends at ``p + R(psi) d_i`` with heading ``psi + dpsi_i``; the new
observer frame has origin ``d_0`` and is turned by ``+dpsi_0``, so::

    p'   = R(dpsi_0)^T (p + R(psi) d_i - d_0)
    psi' = psi + dpsi_i - dpsi_0

(seed eq. 18). The covariance is ``F P F^T + J_i C_i J_i^T + J_0 C_0 J_0^T`` (eq. 19) with the
Jacobians of that map (:func:`compose_relative`). A static object (tag ``-2``) has ``u_i = 0``.

Untagged components (births) are split into one copy per *candidate* robot (every robot
whose odometry has been received, except those already "recovered": tag weight >=
``recovered_weight``, seed ``001`` 13.2) plus one copy for the static class, the weight divided
equally (eq. 15). Since a single position says nothing about the teammate's heading, each
robot copy is further split into ``birth_heading_hypotheses`` evenly spaced headings (sharing
that robot's share of the weight). Every copy is tagged from then on.

Measurement update: GM-PHD on the ``(x, y)`` part (eqs. 20-21). The weights, the position
posterior and the likelihoods come from :func:`localization.phd.lidar_update`; the heading row
follows from the same gain: with ``H = [I 0]``, ``S = P_xy + R``,
``psi+ = psi + P_psi,xy S^-1 (z - m)``, and ``S^-1 (z - m) = (z - m+) / r``.

Reduction: prune, Vo & Ma greedy merge **within each tag** (3-D Mahalanobis distance with the
candidate's covariance, wrapped heading difference; clusters from
:func:`localization.reducer.greedy_clusters`), cap.

Estimate: per ID, the mean of its highest-weight component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import phd
from .config import PHDConfig, config_with_overrides
from .detection import DetectionModel
from .gaussian import wrap_angle
from .mixture import N_ROWS, ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y, GaussianMixture
from .reducer import greedy_clusters

__all__ = [
    "UNTAGGED",
    "STATIC",
    "IDPHDConfig",
    "IDPHD",
    "compose_relative",
    "split_untagged",
]

#: Tag of a component not yet associated to any robot.
UNTAGGED = -1
#: Tag of a static false positive (null odometry).
STATIC = -2

_WEIGHT_FLOOR = 1e-150


@dataclass(frozen=True, slots=True)
class IDPHDConfig:
    """ID-PHD parameters (units in the names). Validated on construction.

    Attributes
    ----------
    own_odometry_std_m, own_odometry_std_rad : float
        ``C_0``: std of the observer's own odometry increment per time update (per axis).
    teammate_odometry_std_m, teammate_odometry_std_rad : float
        ``C_i``: std of a teammate's communicated increment per time update.
    static_process_std_m : float
        Extra position noise per time update of the static class (``-2``).
    survival_probability : float
        Constant ``P_s`` per time update (identities are tracked out of sensor range too).
    lidar_noise_std_m, lidar_clutter_intensity_per_m2 : float
        ``R_L = s^2 I`` and ``kappa_L``.
    birth_weight : float
        Weight of an untagged birth (before the split).
    birth_std_m, birth_heading_std_rad : float
        Birth position std and (before the heading split) heading std.
    birth_heading_hypotheses : int
        Number of evenly spaced heading hypotheses per robot copy at the split.
    birth_max_explained : float
        A detection whose explained fraction is below this becomes a birth.
    birth_min_detection_prob : float
        ...if the lidar ``P_d`` at the detection is at least this (a teammate where ``P_d ~ 0``
        cannot be tracked, and its births would be split and dropped at every scan).
    recovered_weight : float
        A robot whose tag weight reaches this is no longer a split candidate (``inf``: never).
    prune_threshold, merge_threshold : float
        Prune weight and squared 3-D Mahalanobis merge gate.
    max_components : int
        Cap after every reduction.
    detection : PHDConfig
        Supplies the lidar ``P_d`` model (range, blind sectors, occlusion, interference).
    """

    own_odometry_std_m: float = 0.005
    own_odometry_std_rad: float = 0.01
    teammate_odometry_std_m: float = 0.005
    teammate_odometry_std_rad: float = 0.01
    static_process_std_m: float = 0.002
    survival_probability: float = 0.999
    lidar_noise_std_m: float = 0.05
    lidar_clutter_intensity_per_m2: float = 0.05
    birth_weight: float = 0.1
    birth_std_m: float = 0.1
    birth_heading_std_rad: float = math.pi
    birth_heading_hypotheses: int = 8
    birth_max_explained: float = 0.5
    birth_min_detection_prob: float = 0.3
    recovered_weight: float = 0.8
    prune_threshold: float = 1e-5
    merge_threshold: float = 4.0
    max_components: int = 400
    detection: PHDConfig = field(default_factory=PHDConfig)

    def __post_init__(self) -> None:
        for name in (
            "own_odometry_std_m",
            "own_odometry_std_rad",
            "teammate_odometry_std_m",
            "teammate_odometry_std_rad",
            "static_process_std_m",
            "lidar_clutter_intensity_per_m2",
        ):
            _check_real(name, getattr(self, name), low=0.0)
        for name in ("lidar_noise_std_m", "birth_std_m", "birth_heading_std_rad"):
            _check_real(name, getattr(self, name), low=0.0, low_open=True)
        for name in (
            "survival_probability",
            "birth_weight",
            "birth_max_explained",
            "birth_min_detection_prob",
        ):
            _check_real(name, getattr(self, name), low=0.0, high=1.0)
        _check_real("prune_threshold", self.prune_threshold, low=0.0, low_open=True, high=1.0)
        _check_real("merge_threshold", self.merge_threshold, low=0.0)
        value = self.recovered_weight
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise ValueError(f"recovered_weight must be a number > 0 (or inf), got {value!r}")
        for name in ("birth_heading_hypotheses", "max_components"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if not isinstance(self.detection, PHDConfig):
            raise ValueError(f"detection must be a PHDConfig, got {self.detection!r}")

    @property
    def lidar_noise_var_m2(self) -> float:
        return self.lidar_noise_std_m**2


def _check_real(
    name: str,
    value: Any,
    low: float,
    high: float | None = None,
    low_open: bool = False,
) -> None:
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    if ok:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        bound = f"{'>' if low_open else '>='} {low}" + (f" and <= {high}" if high else "")
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")


# ---------------------------------------------------------------------- pure functions
def compose_relative(
    means: np.ndarray,
    covs: np.ndarray,
    teammate_delta: np.ndarray,
    own_delta: np.ndarray,
    teammate_var: np.ndarray,
    own_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Time update of teammate poses in a moving observer frame (seed ``002`` eqs. 18-19).

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
    weight ``w / (len(candidates) + 1)`` (seed ``002`` eq. 15, the static class ``-2`` counts as
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


def reduce_tagged(
    weights: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    tags: np.ndarray,
    prune_threshold: float,
    merge_threshold: float,
    max_components: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Prune, merge within each tag (Vo & Ma greedy, 3-D gate, wrapped heading), cap.

    Component ``i`` joins heavier component ``j`` of the same tag when
    ``d^T P_i^-1 d <= merge_threshold`` with ``d = m_i - m_j`` (heading difference wrapped) and
    the candidate's 3x3 covariance ``P_i`` (Vo & Ma's choice). Clusters come from
    :func:`localization.reducer.greedy_clusters`; each is moment-matched about its leader's
    heading. The loop runs over the distinct tags (a few tens), never over components.
    Returns components grouped by tag.
    """
    keep = weights >= prune_threshold
    weights, means, covs, tags = weights[keep], means[keep], covs[keep], tags[keep]
    if weights.shape[0] > 1:
        order = np.argsort(tags, kind="stable")
        weights, means, covs, tags = weights[order], means[order], covs[order], tags[order]
        bounds = np.flatnonzero(np.diff(tags)) + 1
        parts = [
            _merge_block(weights[a:b], means[a:b], covs[a:b], merge_threshold)
            for a, b in zip(
                np.concatenate(([0], bounds)).tolist(),
                np.concatenate((bounds, [weights.shape[0]])).tolist(),
                strict=True,
            )
        ]
        counts = [part[0].shape[0] for part in parts]
        tags = np.repeat(tags[np.concatenate(([0], bounds))], counts)
        weights = np.concatenate([part[0] for part in parts])
        means = np.concatenate([part[1] for part in parts])
        covs = np.concatenate([part[2] for part in parts])
    if weights.shape[0] > max_components:
        top = np.sort(np.argpartition(-weights, max_components - 1)[:max_components])
        weights, means, covs, tags = weights[top], means[top], covs[top], tags[top]
    return weights, means, covs, tags


def _merge_block(
    weights: np.ndarray, means: np.ndarray, covs: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy merge of components that share one tag (see :func:`reduce_tagged`)."""
    n = weights.shape[0]
    if n < 2:
        return weights, means, covs
    diff = means[None, :, :] - means[:, None, :]  # [j, i] = m_i - m_j
    diff[..., 2] = wrap_angle(diff[..., 2])
    inv = np.linalg.inv(covs)  # candidate i's inverse, (N, 3, 3)
    q = np.einsum("jik,ikl,jil->ji", diff, inv, diff, optimize=False)
    close = q <= threshold
    np.fill_diagonal(close, True)
    labels = greedy_clusters(close, weights)
    leaders = np.flatnonzero(labels == np.arange(n))
    if leaders.shape[0] == n:
        return weights, means, covs
    member_of = labels == leaders[:, None]  # (L, N)
    # Guard: floored weights, so an all-zero cluster still has a defined mean and covariance.
    member = member_of * np.maximum(weights, _WEIGHT_FLOOR)
    total = member.sum(axis=1)
    d = diff[leaders]  # (L, N, 3): m_i - m_leader, heading wrapped
    mean_d = np.einsum("ln,lnk->lk", member, d) / total[:, None]
    dd = d - mean_d[:, None, :]
    spread = np.einsum("ln,lnk,lnm->lkm", member, dd, dd)
    new_covs = (np.einsum("ln,nkm->lkm", member, covs) + spread) / total[:, None, None]
    new_means = means[leaders] + mean_d
    new_means[:, 2] = wrap_angle(new_means[:, 2])
    return (
        member_of.astype(float) @ weights,
        new_means,
        0.5 * (new_covs + new_covs.transpose(0, 2, 1)),
    )


# ---------------------------------------------------------------------- the filter
class IDPHD:
    """Robot-centric ID-PHD: teammate positions, headings and identities in the observer frame.

    Parameters
    ----------
    config : IDPHDConfig, optional
    **overrides
        Field values replacing those of ``config``; unknown names raise ``ValueError``.

    Examples
    --------
    >>> import numpy as np
    >>> f = IDPHD()
    >>> f.update_lidar(np.array([[1.0, 0.5]]))  # an unexplained detection: a pending birth
    >>> f.predict(np.zeros(3), {3: np.array([0.02, 0.0, 0.0])})  # split over {3, static}
    >>> f.update_lidar(np.array([[1.02, 0.5]]))
    >>> poses = f.estimate()  # {3: array([x, y, psi])}, maybe {-2: ...}
    """

    __slots__ = (
        "config",
        "_model",
        "_w",
        "_m",
        "_p",
        "_tags",
        "_known",
        "_pending",
        "_mixture",
    )

    def __init__(self, config: IDPHDConfig | None = None, **overrides: Any) -> None:
        self.config = config = config_with_overrides(config, IDPHDConfig, overrides)
        self._model = DetectionModel(config.detection)
        self.reset()

    def reset(self) -> None:
        """Forget everything (components, known robots and pending births)."""
        self._w = np.empty(0)
        self._m = np.empty((0, 3))
        self._p = np.empty((0, 3, 3))
        self._tags = np.empty(0, dtype=np.int64)
        self._known: set[int] = set()
        self._pending = np.empty((0, 2))
        self._mixture: GaussianMixture | None = None

    # ------------------------------------------------------------------ views
    @property
    def weights(self) -> np.ndarray:
        return _readonly(self._w)

    @property
    def means(self) -> np.ndarray:
        """``(N, 3)``: ``(x_m, y_m, psi_rad)`` per component (read-only)."""
        return _readonly(self._m)

    @property
    def covs(self) -> np.ndarray:
        """``(N, 3, 3)`` covariances (read-only)."""
        return _readonly(self._p)

    @property
    def tags(self) -> np.ndarray:
        """``(N,)`` int tags: ``-1`` untagged, ``-2`` static, ``i >= 0`` robot ``i``."""
        return _readonly(self._tags)

    @property
    def known_ids(self) -> tuple[int, ...]:
        """Robots whose odometry has been received so far (sorted)."""
        return tuple(sorted(self._known))

    @property
    def mixture(self) -> GaussianMixture:
        """The ``(x, y)`` marginal of every component, as a read-only :class:`GaussianMixture`."""
        if self._mixture is None:
            self._mixture = GaussianMixture(
                self._w.copy(), self._m[:, :2].copy(), self._p[:, :2, :2].copy()
            )
        return self._mixture

    @property
    def total_weight(self) -> float:
        return float(self._w.sum())

    def __len__(self) -> int:
        return int(self._w.shape[0])

    def __repr__(self) -> str:
        return (
            f"IDPHD(components={len(self)}, known={len(self._known)}, "
            f"total_weight={self.total_weight:.3f})"
        )

    # ------------------------------------------------------------------ steps
    def predict(
        self, own_odometry: np.ndarray, teammate_odometry: dict[int, np.ndarray] | None = None
    ) -> None:
        """Time update: split untagged components, then compose each component's odometry.

        Parameters
        ----------
        own_odometry : array_like, shape (3,)
            ``[dx_m, dy_m, dpsi_rad]`` of the observer, in its frame at the start of the
            interval.
        teammate_odometry : dict int -> array_like (3,), optional
            Each teammate's increment over the same interval, in *its* frame at the start.
            A known robot missing from the dict is propagated with a null increment.

        Raises
        ------
        ValueError
            If an argument has the wrong shape, a non-finite value or a negative ID (nothing
            changes then).
        """
        own = _checked_delta(own_odometry, "own_odometry")
        team: dict[int, np.ndarray] = {}
        for key, value in (teammate_odometry or {}).items():
            if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
                raise ValueError(f"teammate_odometry keys must be robot IDs >= 0, got {key!r}")
            team[int(key)] = _checked_delta(value, f"teammate_odometry[{key}]")
        cfg = self.config
        known = self._known | set(team)
        w, m, p, tags = self._w, self._m, self._p, self._tags
        if self._pending.shape[0]:
            b = self._pending.shape[0]
            bm = np.zeros((b, 3))
            bm[:, :2] = self._pending
            bp = np.zeros((b, 3, 3))
            bp[:, 0, 0] = bp[:, 1, 1] = cfg.birth_std_m**2
            bp[:, 2, 2] = cfg.birth_heading_std_rad**2
            w = np.concatenate((w, np.full(b, cfg.birth_weight)))
            m = np.concatenate((m, bm))
            p = np.concatenate((p, bp))
            tags = np.concatenate((tags, np.full(b, UNTAGGED, dtype=np.int64)))
        if (tags == UNTAGGED).any():
            recovered = {
                i for i in known if self._w[self._tags == i].sum() >= cfg.recovered_weight
            }
            candidates = np.array(sorted(known - recovered), dtype=np.int64)
            w, m, p, tags = split_untagged(w, m, p, tags, candidates, cfg.birth_heading_hypotheses)
        # Per-component teammate increment and noise (one lookup table over tags).
        ids = np.array(sorted(known), dtype=np.int64)
        table = np.zeros((ids.shape[0] + 1, 3))  # last row: static / unknown -> null odometry
        for row, i in enumerate(ids.tolist()):
            if i in team:
                table[row] = team[i]
        index = np.searchsorted(ids, tags)
        is_robot = tags >= 0
        index[~is_robot] = ids.shape[0]
        delta = table[index]
        tvar = np.where(
            is_robot[:, None],
            np.array([cfg.teammate_odometry_std_m**2] * 2 + [cfg.teammate_odometry_std_rad**2]),
            np.array([cfg.static_process_std_m**2] * 2 + [0.0]),
        )
        ovar = np.array([cfg.own_odometry_std_m**2] * 2 + [cfg.own_odometry_std_rad**2])
        m, p = compose_relative(m, p, delta, own, tvar, ovar)
        w = w * cfg.survival_probability
        if w.shape[0] > cfg.max_components:
            w, m, p, tags = self._reduce(w, m, p, tags)
        self._w, self._m, self._p, self._tags = w, m, p, tags
        self._known = known
        self._pending = np.empty((0, 2))
        self._mixture = None

    def update_lidar(self, points: np.ndarray, null_bearings: np.ndarray | None = None) -> None:
        """GM-PHD update on ``(x, y)`` with anonymous lidar detections, then reduce.

        Unexplained detections (explained fraction < ``birth_max_explained``) become untagged
        births at the next :meth:`predict`.

        Parameters
        ----------
        points : array_like, shape (M, 2)
            Detections ``[x_m, y_m]`` in the observer frame (``M = 0`` is a valid scan).
        null_bearings : array_like, shape (B,), optional
            Bearings of zero-intensity returns (interference ``P_d`` factor).
        """
        pts = _checked_points(points)
        nulls = None if null_bearings is None else _checked_angles(null_bearings, "null_bearings")
        cfg = self.config
        w, m, p, tags = self._w, self._m, self._p, self._tags
        table = np.empty((N_ROWS, w.shape[0]))
        table[ROW_W] = w
        table[ROW_X : ROW_Y + 1] = m[:, :2].T
        table[ROW_PXX], table[ROW_PXY], table[ROW_PYY] = p[:, 0, 0], p[:, 0, 1], p[:, 1, 1]
        pd = self._model.lidar(table, nulls) if w.shape[0] else np.empty(0)
        if pts.shape[0] == 0:
            w = w * (1.0 - pd)
            explained = np.empty(0)
        else:
            w, m, p, source, explained = lidar_update_3d(
                w, m, p, pts, pd, cfg.lidar_noise_var_m2, cfg.lidar_clutter_intensity_per_m2
            )
            tags = tags[source]
        self._w, self._m, self._p, self._tags = self._reduce(w, m, p, tags)
        births = pts[explained < cfg.birth_max_explained]
        if births.shape[0] and cfg.birth_min_detection_prob > 0.0:
            probe = np.zeros((N_ROWS, births.shape[0]))
            probe[ROW_X : ROW_Y + 1] = births.T
            probe[ROW_PXX] = probe[ROW_PYY] = cfg.birth_std_m**2
            births = births[self._model.lidar(probe, nulls) >= cfg.birth_min_detection_prob]
        self._pending = births
        self._mixture = None

    def estimate(self, min_weight: float = 0.0) -> dict[int, np.ndarray]:
        """Per identity, the mean ``(x_m, y_m, psi_rad)`` of its highest-weight component.

        Parameters
        ----------
        min_weight : float
            Only identities whose best component has at least this weight are reported.

        Returns
        -------
        dict int -> ndarray (3,)
            Robot IDs ``>= 0`` and, if present, the static class ``-2``.
        """
        return {i: pose for i, (pose, _, _) in self.best_components(min_weight).items()}

    def best_components(self, min_weight: float = 0.0) -> dict[int, tuple]:
        """Per identity: ``(mean (3,), weight, cov (3, 3))`` of its highest-weight component."""
        min_weight = float(min_weight)
        if not math.isfinite(min_weight):
            raise ValueError(f"min_weight must be finite, got {min_weight!r}")
        w, tags = self._w, self._tags
        if not w.shape[0]:
            return {}
        order = np.lexsort((-w, tags))  # by tag, heaviest first
        first = np.ones(order.shape[0], dtype=bool)
        first[1:] = tags[order][1:] != tags[order][:-1]
        best = order[first]
        best = best[(w[best] >= min_weight) & (tags[best] != UNTAGGED)]
        return {int(tags[k]): (self._m[k].copy(), float(w[k]), self._p[k].copy()) for k in best}

    def identity_weights(self) -> dict[int, float]:
        """Total weight per tag (expected number of objects with that identity)."""
        out: dict[int, float] = {}
        if self._w.shape[0]:
            uniq, inverse = np.unique(self._tags, return_inverse=True)
            sums = np.bincount(inverse, weights=self._w)
            out = {int(t): float(s) for t, s in zip(uniq, sums, strict=True)}
        return out

    def _reduce(self, w, m, p, tags):
        cfg = self.config
        return reduce_tagged(
            w, m, p, tags, cfg.prune_threshold, cfg.merge_threshold, cfg.max_components
        )


# ---------------------------------------------------------------------- input checks
def _readonly(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


def _as_float(value: Any, name: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc


def _checked_delta(value: Any, name: str) -> np.ndarray:
    arr = _as_float(value, name)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,) [dx_m, dy_m, dpsi_rad], got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _checked_points(value: Any, name: str = "points") -> np.ndarray:
    pts = _as_float(value, name)
    if pts.size == 0:
        return np.empty((0, 2))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (M, 2), got shape {pts.shape}")
    bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
    if bad.size:
        raise ValueError(f"{name} must be finite, got {name}[{bad[0]}] = {pts[bad[0]].tolist()}")
    return pts


def _checked_angles(value: Any, name: str) -> np.ndarray:
    arr = _as_float(value, name)
    if arr.size == 0:
        return np.empty(0)
    if arr.ndim != 1:
        raise ValueError(f"{name} must have shape (M,), got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(f"{name} must be finite, got {name}[{bad[0]}] = {arr[bad[0]]!r}")
    return arr
