"""Robot-centric FastSLAM with Monte-Carlo data association (Stegagno 2012 chapter 5).

The thesis's baseline for mutual localization from anonymous measurements. Each of ``P``
particles is one hypothesis of the whole scene in the observer's body frame (the observer's own
state is null in every particle):

- every teammate ``j`` is an EKF over its pose ``(x, y, theta)``, propagated with ``j``'s
  communicated odometry (``x_j <- x_j (+) u_j``, linearised: eq. 15 as an EKF);
- every other robot-like feature (a decoy post) is a 2-D EKF;
- the observer's own odometry moves every landmark (``x <- x (-) u_i``), with a noisy ``u_i``
  sampled per particle (the particle is the observer's path, as in FastSLAM).

A lidar detection is associated, per particle, by sampling (Monte-Carlo data association,
Montemerlo et al.) among the landmarks it may come from and "new", with probabilities
proportional to their likelihoods; the particle's weight is multiplied by the sum (the
detection's marginal likelihood). "New" starts an uninitialised teammate or a feature. A new
teammate's orientation is unknown: the particles take it from a regular **bank** of ``B``
orientations (``2 pi k / B``, std ``pi / B``), because an EKF started far from the true
orientation never recovers (the thesis's Figs. 7-8); the bank spreads the orientations over the
particles. Teammates' broadcast detections re-weight the particles only (using them in the EKFs
would break FastSLAM's factorisation, eq. 8): each particle predicts what ``j`` sees from its
estimate of ``j``'s pose and is scored against it. Estimates are the weighted means over the
particles (the thesis's criterion). Everything is vectorised over particles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp

from swarm_core.geometry import wrap_angle
from swarm_core.records import Broadcast, RobotMeasurements
from swarm_core.validation import check_number, check_positive

from .links import ObserverLocalizer, TeammateLink, absorb_broadcasts, next_due
from .particles import MotionNoise, odometry_noise, weighted_moments
from .se2 import compose, inverse_compose, rotation

__all__ = ["FastSLAMConfig", "FastSLAMLocalizer"]


@dataclass(frozen=True, slots=True)
class FastSLAMConfig:
    """Parameters of the FastSLAM-MC baseline.

    Attributes
    ----------
    n_particles : int
        The thesis ran 10, 100 and 1000 (eq. 9 asks ``(2n + m)!``).
    n_orientations : int
        ``B``, the orientations of the bank a new teammate's EKF starts from.
    max_features : int
        Static-feature EKFs per particle (decoy posts).
    detection_std_m : float
        Lidar detection noise (measured: 0.03 m overall std in ``lab-3m-4``).
    new_density_per_m2 : float
        Likelihood of "new landmark / clutter" for a detection: one over the lidar's tracking
        disc (2 m radius).
    teammate_range_m : float
        A teammate is expected to see the landmarks within this range (its lidar's).
    update_period_s, max_skew_s : float
        When and which teammate scans re-weight the particles (as :class:`PMultiRegConfig`).
    motion_noise : MotionNoise
    """

    n_particles: int = 1000
    n_orientations: int = 8
    max_features: int = 6
    detection_std_m: float = 0.03
    new_density_per_m2: float = 1.0 / (math.pi * 2.0**2)
    teammate_range_m: float = 2.0
    update_period_s: float = 0.5
    max_skew_s: float = 0.3
    motion_noise: MotionNoise = field(default_factory=MotionNoise)

    def __post_init__(self) -> None:
        for name, low in (("n_particles", 2), ("n_orientations", 1), ("max_features", 0)):
            check_number(f"fastslam.{name}", getattr(self, name), integer=True, low=low)
        for name in (
            "detection_std_m",
            "new_density_per_m2",
            "teammate_range_m",
            "update_period_s",
            "max_skew_s",
        ):
            check_positive(f"fastslam.{name}", getattr(self, name))
        if not isinstance(self.motion_noise, MotionNoise):
            raise ValueError(
                f"fastslam.motion_noise must be a MotionNoise, got {self.motion_noise!r}"
            )


class FastSLAMLocalizer(ObserverLocalizer):
    """FastSLAM-MC for one observer (same interface as :class:`PMultiRegLocalizer`).

    Parameters
    ----------
    observer : str
    teammates : sequence of str
    config : FastSLAMConfig
    rng : numpy Generator
    """

    name = "fastslam"
    config_type = FastSLAMConfig

    def _init_filters(self) -> None:
        cfg = self.config
        p, r, f = cfg.n_particles, len(self.teammates), cfg.max_features
        self.mu_r = np.zeros((p, r, 3))
        self.cov_r = np.tile(np.eye(3), (p, r, 1, 1))
        self.init_r = np.zeros((p, r), dtype=bool)
        self.mu_f = np.zeros((p, f, 2))
        self.cov_f = np.tile(np.eye(2), (p, f, 1, 1))
        self.active_f = np.zeros((p, f), dtype=bool)
        self.logw = np.full(p, -math.log(p))
        self._r_meas = cfg.detection_std_m**2 * np.eye(2)

    # ------------------------------------------------------------------ motion
    def _predict_own(self, delta: np.ndarray) -> None:
        """Every landmark of every particle moves by the inverse of a sampled own increment."""
        u = odometry_noise(delta, self.config.motion_noise, len(self.logw), self.rng)  # (P, 3)
        rt = rotation(-u[:, 2])  # (P, 2, 2): R(-dtheta)
        for mu, cov, dim in ((self.mu_r, self.cov_r, 3), (self.mu_f, self.cov_f, 2)):
            d = mu[..., :2] - u[:, None, :2]
            mu[..., :2] = np.einsum("pij,plj->pli", rt, d)
            if dim == 3:
                mu[..., 2] = wrap_angle(mu[..., 2] - u[:, None, 2])
                g = np.tile(np.eye(3), (len(u), 1, 1))
                g[:, :2, :2] = rt
            else:
                g = rt
            cov[:] = np.einsum("pij,pljk,pmk->plim", g, cov, g)

    def _predict_teammate(self, r: int, delta: np.ndarray) -> None:
        """EKF prediction of teammate ``r``'s pose in every particle: ``x <- x (+) u``."""
        n = self.config.motion_noise
        d = math.hypot(delta[0], delta[1])
        s_t = n.trans_per_m * d + n.trans_floor_m
        s_r = n.rot_per_m * d + n.rot_per_rad * abs(delta[2]) + n.rot_floor_rad
        q = np.diag([s_t**2, s_t**2, s_r**2])
        mu, cov = self.mu_r[:, r], self.cov_r[:, r]
        th = mu[:, 2]
        c, s = np.cos(th), np.sin(th)
        fj = np.tile(np.eye(3), (len(th), 1, 1))
        fj[:, 0, 2] = -s * delta[0] - c * delta[1]
        fj[:, 1, 2] = c * delta[0] - s * delta[1]
        gj = np.tile(np.eye(3), (len(th), 1, 1))
        gj[:, :2, :2] = rotation(th)
        mu[:, 0] += c * delta[0] - s * delta[1]
        mu[:, 1] += s * delta[0] + c * delta[1]
        mu[:, 2] = wrap_angle(th + delta[2])
        cov[:] = fj @ cov @ fj.transpose(0, 2, 1) + gj @ q @ gj.transpose(0, 2, 1)

    # ------------------------------------------------------------------ own detections
    def _update_detection(self, z: np.ndarray, used: np.ndarray) -> None:
        """One detection (2,), Monte-Carlo associated per particle; ``used`` (P, R + F) marks
        landmarks already taken by this scan (one detection per landmark)."""
        cfg = self.config
        p, r = self.init_r.shape
        pos = np.concatenate([self.mu_r[..., :2], self.mu_f], axis=1)  # (P, L, 2)
        cov = np.concatenate([self.cov_r[..., :2, :2], self.cov_f], axis=1)  # (P, L, 2, 2)
        exists = np.concatenate([self.init_r, self.active_f], axis=1) & ~used
        s = cov + self._r_meas  # (P, L, 2, 2), symmetric
        sxx, sxy, syy = s[..., 0, 0], s[..., 0, 1], s[..., 1, 1]
        det = sxx * syy - sxy * sxy
        ex, ey = z[0] - pos[..., 0], z[1] - pos[..., 1]
        maha = (syy * ex * ex - 2.0 * sxy * ex * ey + sxx * ey * ey) / det  # e' S^-1 e
        ll = np.where(exists, -0.5 * maha - np.log(2 * math.pi * np.sqrt(det)), -np.inf)
        opts = np.empty((p, ll.shape[1] + 1))
        opts[:, :-1] = ll
        opts[:, -1] = math.log(cfg.new_density_per_m2)
        # Row-wise log-sum-exp; the finite "new" option bounds every row's maximum from below.
        top = opts.max(axis=1)
        total = top + np.log(np.exp(opts - top[:, None]).sum(axis=1))  # (P,)
        self.logw += total
        prob = np.exp(opts - total[:, None])
        cdf = np.cumsum(prob, axis=1)
        choice = (self.rng.random(p)[:, None] > cdf).sum(axis=1)  # (P,) in [0, L]
        choice = np.minimum(choice, opts.shape[1] - 1)
        n_land = opts.shape[1] - 1
        rows = np.arange(p)
        # EKF update of the chosen landmark (position part; teammates' theta via the cross term).
        hit = choice < n_land
        idx = choice[hit]
        ph = rows[hit]
        used[ph, idx] = True
        is_r = idx < r
        for sel, mu, cv, dim, off in (
            (is_r, self.mu_r, self.cov_r, 3, 0),
            (~is_r, self.mu_f, self.cov_f, 2, r),
        ):
            pp, li = ph[sel], idx[sel] - off
            if len(pp) == 0:
                continue
            m, c = mu[pp, li], cv[pp, li]  # (K, dim), (K, dim, dim)
            sk = c[:, :2, :2] + self._r_meas
            k_gain = c[:, :, :2] @ np.linalg.inv(sk)  # (K, dim, 2)
            innov = z - m[:, :2]
            m = m + np.einsum("kij,kj->ki", k_gain, innov)
            if dim == 3:
                m[:, 2] = wrap_angle(m[:, 2])
            c = c - k_gain @ c[:, :2, :]
            mu[pp, li] = m
            cv[pp, li] = 0.5 * (c + c.transpose(0, 2, 1))
        # "New": an uninitialised teammate (its orientation from the bank) or a new feature.
        new = rows[~hit]
        if len(new) == 0:
            return
        uninit = ~self.init_r[new]  # (K, R)
        n_un = uninit.sum(axis=1)
        as_robot = self.rng.random(len(new)) < n_un / (n_un + 1.0)
        pr = new[as_robot]
        if len(pr):
            # A random uninitialised teammate per particle.
            u = uninit[as_robot].astype(float)
            u /= u.sum(axis=1, keepdims=True)
            j = (self.rng.random(len(pr))[:, None] > np.cumsum(u, axis=1)).sum(axis=1)
            b = cfg.n_orientations
            k = self.rng.integers(0, b, len(pr))
            self.mu_r[pr, j] = np.column_stack(
                [np.full(len(pr), z[0]), np.full(len(pr), z[1]), wrap_angle(2 * np.pi * k / b)]
            )
            c0 = np.zeros((len(pr), 3, 3))
            c0[:, :2, :2] = self._r_meas
            c0[:, 2, 2] = (math.pi / b) ** 2
            self.cov_r[pr, j] = c0
            self.init_r[pr, j] = True
            used[pr, j] = True
        pf = new[~as_robot]
        if len(pf) and self.active_f.shape[1]:
            free = ~self.active_f[pf]
            has = free.any(axis=1)
            pf = pf[has]
            slot = np.argmax(free[has], axis=1)
            self.mu_f[pf, slot] = z
            self.cov_f[pf, slot] = self._r_meas
            self.active_f[pf, slot] = True
            used[pf, r + slot] = True

    # ------------------------------------------------------------------ teammates' detections
    def _reweight_teammate(self, r: int, link: TeammateLink) -> None:
        """Score every particle's prediction of what teammate ``r`` sees against what it said.

        The prediction is made at ``r``'s scan instant: ``r`` moved back along its own odometry
        from its latest broadcast, the observer's origin where it was then."""
        detections = link.detections
        if len(detections) == 0:
            return
        cfg = self.config
        ok = self.init_r[:, r]
        if not ok.any():
            return
        xj = self.mu_r[:, r]  # (P, 3), at r's latest broadcast
        v_scan, v_last = link.track.at(link.detections_stamp_s), link.track.latest
        if v_scan is not None and v_last is not None:
            xj = compose(xj, inverse_compose(v_scan, v_last))
        me = np.zeros((1, 2))
        p_then, p_now = self.own_track.at(link.detections_stamp_s), self.own_track.latest
        if p_then is not None and p_now is not None:
            me = inverse_compose(p_then, p_now)[None, :2]
        others = np.concatenate(
            [
                np.broadcast_to(me, (len(xj), 1, 2)),
                np.delete(self.mu_r[..., :2], r, axis=1),
                self.mu_f,
            ],
            axis=1,
        )  # (P, L', 2): the observer itself, the other teammates, the features
        valid = np.concatenate(
            [np.ones((len(xj), 1), bool), np.delete(self.init_r, r, axis=1), self.active_f], axis=1
        )
        rt = rotation(-xj[:, 2])
        pred = np.einsum("pij,plj->pli", rt, others - xj[:, None, :2])  # in r's frame
        valid &= np.hypot(pred[..., 0], pred[..., 1]) <= cfg.teammate_range_m
        # Covariance of each predicted point in r's frame: both detections' noise, r's position
        # uncertainty turned into r's frame, and r's heading uncertainty along the tangent
        # (a wrong heading swings the points about r: it spreads them sideways, not in range).
        cov_xy = np.einsum(
            "pji,pjk,pkl->pil", rotation(xj[:, 2]), self.cov_r[:, r, :2, :2], rotation(xj[:, 2])
        )
        tangent = np.stack([-pred[..., 1], pred[..., 0]], axis=-1)  # (P, L', 2)
        cov = (
            2 * cfg.detection_std_m**2 * np.eye(2)
            + cov_xy[:, None]
            + self.cov_r[:, r, 2, 2][:, None, None, None]
            * tangent[..., :, None]
            * tangent[..., None, :]
        )  # (P, L', 2, 2)
        det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] * cov[..., 1, 0]
        e = detections[None, :, None, :] - pred[:, None, :, :]  # (P, M, L', 2)
        maha = (
            e[..., 0] ** 2 * cov[:, None, :, 1, 1]
            - 2 * e[..., 0] * e[..., 1] * cov[:, None, :, 0, 1]
            + e[..., 1] ** 2 * cov[:, None, :, 0, 0]
        ) / det[:, None, :]
        lg = -0.5 * maha - np.log(2 * math.pi * np.sqrt(det))[:, None, :]
        lg = np.where(valid[:, None, :], lg, -np.inf)
        per = np.logaddexp(
            logsumexp(lg, axis=2) - np.log(np.maximum(valid.sum(1), 1))[:, None],
            math.log(cfg.new_density_per_m2),
        )  # (P, M): a detection is one of the predicted landmarks, or clutter
        self.logw += np.where(ok, per.sum(axis=1), per.sum(axis=1)[ok].mean())

    # ------------------------------------------------------------------ resampling
    def _normalise_and_resample(self) -> None:
        self.logw -= logsumexp(self.logw, axis=0)
        w = np.exp(self.logw)
        n = len(w)
        if 1.0 / float((w**2).sum()) >= 0.5 * n:
            return
        u = (self.rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(w), u), n - 1)
        for name in ("mu_r", "cov_r", "init_r", "mu_f", "cov_f", "active_f"):
            setattr(self, name, getattr(self, name)[idx].copy())
        self.logw[:] = -math.log(n)

    # ------------------------------------------------------------------ public
    def step(
        self, time_s: float, measurements: RobotMeasurements, broadcasts: list[Broadcast]
    ) -> None:
        """Absorb one env step's records and broadcasts."""
        for sender, delta in absorb_broadcasts(self.links, broadcasts):
            self._predict_teammate(self.teammates.index(sender), delta)
        # Own odometry and own scans in time order (a scan sees the world of its instant).
        events = [(o.stamp_s, 0, o) for o in measurements.odometry]
        events += [(li.stamp_s, 1, li) for li in measurements.lidar]
        for _, kind, rec in sorted(events, key=lambda e: (e[0], e[1])):
            if kind == 0:
                self.own_track.integrate(rec.stamp_s, rec.delta)
                self._predict_own(np.asarray(rec.delta))
                continue
            used = np.zeros(
                (len(self.logw), len(self.teammates) + self.config.max_features), dtype=bool
            )
            for z in rec.detections:  # a handful of detections; each vectorised over particles
                self._update_detection(np.asarray(z), used)
            self._own_stamp = rec.stamp_s
            self._normalise_and_resample()
        if time_s + 1e-9 >= self._next_update_s and np.isfinite(self._own_stamp):
            self._next_update_s = next_due(
                self._next_update_s, time_s, self.config.update_period_s
            )
            for r, t in enumerate(self.teammates):
                link = self.links[t]
                if abs(link.detections_stamp_s - self._own_stamp) <= self.config.max_skew_s:
                    self._reweight_teammate(r, link)
            self._normalise_and_resample()

    def moments(self) -> dict[str, tuple[np.ndarray, np.ndarray] | None]:
        """Each teammate's pose mean (3,) and covariance (3, 3): the moments of the mixture of
        its EKFs over the particles that hold it (weighted mean of the EKF covariances plus the
        spread of their means), or ``None`` if no particle holds it. The mean is
        :meth:`estimates`'."""
        w = np.exp(self.logw - self.logw.max())
        out: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
        for r, t in enumerate(self.teammates):  # a loop over teammates, vectorised over particles
            ok = self.init_r[:, r]
            if not ok.any():
                out[t] = None
                continue
            wr = w[ok] / w[ok].sum()
            mean, spread = weighted_moments(self.mu_r[ok, r], wr)
            out[t] = (mean, spread + np.einsum("p,pij->ij", wr, self.cov_r[ok, r]))
        return out

    def estimates(self) -> dict[str, np.ndarray | None]:
        """Each teammate's relative pose: the weighted mean over the particles that hold it."""
        w = np.exp(self.logw - self.logw.max())
        out: dict[str, np.ndarray | None] = {}
        for r, t in enumerate(self.teammates):
            ok = self.init_r[:, r]
            if not ok.any():
                out[t] = None
                continue
            wr = w[ok] / w[ok].sum()
            mu = self.mu_r[ok, r]
            th = math.atan2(float(wr @ np.sin(mu[:, 2])), float(wr @ np.cos(mu[:, 2])))
            out[t] = np.array([float(wr @ mu[:, 0]), float(wr @ mu[:, 1]), th])
        return out
