"""The P-MultiBeaReg system of one observer (seed ``001`` chapter 10, Fig. 33).

As :class:`~localization.mutual.pmultireg.PMultiRegLocalizer`, with bearings instead of
positions: every ``update_period_s`` the observer's bearings and those of the teammates whose scan
is within ``max_skew_s`` go to :func:`~localization.mutual.beareg.bearing_solutions`; each
teammate's distinct bearing-orientations ``xi = (bearing, theta)`` pass the fitness test (eq. 18,
relative drop and an absolute gate, as in P-MultiReg) and update its particle filter (eq. 19).
The filter is the same (motion from both robots' odometry); its first particles lie on the
hypotheses' rays at ranges uniform in ``range_m``, and the range (scale) becomes observable as
the robots move (the thesis's "circular sectors", Fig. 35).

The bearings are those of the lidar detections, own and broadcast: the thesis's own experiment
(section 10.5) made its bearing detector the same way. The rotation between the scans and the
filters' instants is compensated (observer's and teammate's turns); the translation is not
(the scale is unknown at registration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm_core.geometry import wrap_angle

from .beareg import bearing_solutions
from .links import PoseTrack, TeammateLink
from .particles import MotionNoise, TeammateParticles
from .pmultireg import (
    _ScheduledRegistrar,
    check_count,
    check_fraction,
    check_localizer_args,
    check_positive_number,
)

__all__ = ["PMultiBeaRegConfig", "PMultiBeaRegLocalizer"]


@dataclass(frozen=True, slots=True)
class PMultiBeaRegConfig:
    """Parameters of the bearing-only system.

    Attributes
    ----------
    n_particles : int
        Per teammate (the thesis ran 500).
    triangle_tol_deg : float
        Tolerance on the triangles' angle sum and on the 3-intersections: about 2.5 x the
        bearing noise of a detection at 1 m (0.03 m / 1 m = 1.7 deg) combined over the sum.
    bearing_std_deg, orientation_std_deg : float
        Measurement model: one detection's bearing noise plus 2 deg for the scans' time gap; the
        orientation combines two bearings.
    range_m : tuple of 2 floats
        Ranges of the first particles along a ray (the lidar's robot-detection range).
    """

    n_particles: int = 500
    update_period_s: float = 0.5
    max_skew_s: float = 0.3
    reseed_fraction: float = 0.05
    triangle_tol_deg: float = 6.0
    bearing_std_deg: float = 3.0
    orientation_std_deg: float = 4.0
    range_m: tuple[float, float] = (0.2, 2.5)
    gate_mahalanobis2: float = 25.0
    lost_after: int = 6
    log_fitness_drop: float = math.log(100.0)
    motion_noise: MotionNoise = field(default_factory=MotionNoise)

    def __post_init__(self) -> None:
        if isinstance(self.n_particles, bool) or not isinstance(self.n_particles, int):
            raise ValueError(f"n_particles must be an integer >= 2, got {self.n_particles!r}")
        if self.n_particles < 2:
            raise ValueError(f"n_particles must be an integer >= 2, got {self.n_particles!r}")
        for name in (
            "update_period_s",
            "max_skew_s",
            "triangle_tol_deg",
            "bearing_std_deg",
            "orientation_std_deg",
            "gate_mahalanobis2",
            "log_fitness_drop",
        ):
            check_positive_number(name, getattr(self, name))
        check_fraction("reseed_fraction", self.reseed_fraction)
        check_count("lost_after", self.lost_after)
        r = self.range_m
        if not (
            isinstance(r, (tuple, list))
            and len(r) == 2
            and all(isinstance(v, (int, float)) and math.isfinite(v) for v in r)
            and 0.0 < r[0] < r[1]
        ):
            raise ValueError(f"range_m must be 2 finite numbers 0 < low < high, got {r!r}")
        if not isinstance(self.motion_noise, MotionNoise):
            raise ValueError(f"motion_noise must be a MotionNoise, got {self.motion_noise!r}")


class PMultiBeaRegLocalizer(_ScheduledRegistrar):
    """P-MultiBeaReg plus one particle filter per teammate, for one observer."""

    name = "p-multibeareg"

    def __init__(
        self,
        observer: str,
        teammates: tuple[str, ...],
        config: PMultiBeaRegConfig | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        check_localizer_args(observer, teammates, config, PMultiBeaRegConfig, rng)
        self.observer = observer
        self.teammates = tuple(t for t in teammates if t != observer)
        self.config = cfg = config or PMultiBeaRegConfig()
        self.rng = np.random.default_rng(0) if rng is None else rng
        self.filters = {
            t: TeammateParticles(
                cfg.n_particles, cfg.motion_noise, np.full(3, 1e-3), cfg.reseed_fraction, self.rng
            )
            for t in self.teammates
        }
        self.links = {t: TeammateLink() for t in self.teammates}
        self._rejections = {t: 0 for t in self.teammates}
        self.own_track = PoseTrack()
        self._own = np.zeros(0)
        self._own_stamp = math.nan
        self._next_update_s = -math.inf  # the first registration anchors the schedule
        self._std = np.radians([cfg.bearing_std_deg, cfg.orientation_std_deg])
        self.last_hypotheses: dict[str, np.ndarray] = {}
        self.n_registrations = 0

    def _own_set(self, detections: np.ndarray) -> np.ndarray:
        """What the registration uses of the observer's latest detections (M, 2): bearings (M,)."""
        return np.arctan2(detections[:, 1], detections[:, 0])

    def _turns(self, t: str) -> tuple[float, float]:
        """The observer's and the teammate's heading change from their scans to the filters'
        instants (rad)."""
        link = self.links[t]
        p_scan, p_now = self.own_track.at(self._own_stamp), self.own_track.latest
        v_scan, v_last = link.track.at(link.detections_stamp_s), link.track.latest
        own = 0.0 if p_scan is None else float(wrap_angle(p_now[2] - p_scan[2]))
        mate = 0.0 if v_scan is None else float(wrap_angle(v_last[2] - v_scan[2]))
        return own, mate

    def _register(self) -> None:
        cfg = self.config
        labels, sets = {}, {0: self._own}
        for k, t in enumerate(self.teammates, start=1):
            link = self.links[t]
            if abs(link.detections_stamp_s - self._own_stamp) <= cfg.max_skew_s:
                labels[k] = t
                det = link.detections
                sets[k] = np.arctan2(det[:, 1], det[:, 0])
        self.last_hypotheses = {}
        if not labels:
            return
        sols = bearing_solutions(sets, 0, math.radians(cfg.triangle_tol_deg))
        self.n_registrations += 1
        for k, t in labels.items():
            xis = [s[k] for s in sols if k in s]
            if not xis:
                continue
            xis = np.array(xis)
            own, mate = self._turns(t)
            xis[:, 0] = wrap_angle(xis[:, 0] - own)
            xis[:, 1] = wrap_angle(xis[:, 1] - own + mate)
            # Distinct hypotheses only (several solutions agree on this teammate).
            keep = [0]
            for h in range(1, len(xis)):
                if np.abs(wrap_angle(xis[keep] - xis[h])).max(axis=1).min() > self._std[1]:
                    keep.append(h)
            xis = xis[keep]
            f = self.filters[t]
            lf = f.log_fitness_bearing(xis, self._std)
            if lf is not None:
                ok = lf >= lf.max() - cfg.log_fitness_drop
                if self._rejections[t] < cfg.lost_after:
                    b = np.arctan2(f.x[:, 1], f.x[:, 0])
                    rb = wrap_angle(b[:, None] - xis[None, :, 0]) / self._std[0]
                    rt = wrap_angle(f.x[:, None, 2] - xis[None, :, 1]) / self._std[1]
                    ok &= (rb**2 + rt**2).min(axis=0) <= cfg.gate_mahalanobis2
                if not ok.any():
                    self._rejections[t] += 1
                    continue
                xis = xis[ok]
            self._rejections[t] = 0
            f.update_bearing(xis, self._std, cfg.range_m)
            self.last_hypotheses[t] = xis

    def estimates(self) -> dict[str, np.ndarray | None]:
        """Each teammate's relative pose ``[x_m, y_m, theta_rad]`` (particle mean) or ``None``."""
        return {t: f.mean() for t, f in self.filters.items()}
