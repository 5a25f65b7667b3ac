"""The P-MultiReg mutual localization system of one observer (Stegagno 2012 chapter 6, Fig. 16).

Per env step the observer absorbs its own wheel odometry (motion update of every teammate's
particle filter, eq. 13), the teammates' broadcasts (their communicated odometry pose gives each
teammate's motion update, eq. 15; their anonymous detections are kept), and its own latest lidar
detections. Every ``update_period_s`` (the thesis lowers the measurement rate below the motion
rate so that successive measurements are nearly independent) it runs P-MultiReg
(:func:`~localization.mutual.multireg.multi_register`) on its own detections and those of the
teammates whose latest scan is within ``max_skew_s`` of its own, with the particle filters'
fitness (eq. 11) as the belief test, and feeds each teammate's hypotheses to its filter (eq. 17).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm_core.records import Broadcast, RobotMeasurements
from swarm_core.validation import check_number, check_positive

from .links import ObserverLocalizer, absorb_broadcasts, next_due, to_filter_instant
from .multireg import MultiRegConfig, MultiRegResult, multi_register
from .particles import MotionNoise, TeammateParticles

__all__ = ["PMultiRegConfig", "PMultiRegLocalizer"]


@dataclass(frozen=True, slots=True)
class PMultiRegConfig:
    """Parameters of the P-MultiReg system.

    Attributes
    ----------
    n_particles : int
        Per teammate (the thesis ran 400).
    update_period_s : float
        Time between registrations / measurement updates (s).
    max_skew_s : float
        A teammate's scan enters a registration only if stamped within this of the observer's.
    reseed_fraction : float
        Particles redrawn from the hypotheses at each measurement update (kidnapping).
    gate_mahalanobis2 : float
        The fitness test's absolute part: a registration whose position is further than this
        squared Mahalanobis distance (5 sigma) from every particle's contradicts the belief and
        is dropped. Without it a single wrong registration (a missed detection makes one
        possible) is swallowed. Position only: a teammate's heading drifts with wheel slip
        (10 % of its odometry steps err by > 0.02 rad in ``lab-3m-4``).
    lost_after : int
        After this many registrations in a row whose solutions for a teammate were all dropped
        by the gate, the next ones pass ungated: the teammate was kidnapped (or the belief is
        wrong), and the filter restarts from them.
    measurement_floor : tuple of 3 floats
        Std ``[m, m, rad]`` added to each hypothesis: the two scans are up to a scan period
        (1/7 s) apart, 0.02 m at 0.15 m/s, and 2 deg of heading at the robots' turn rates.
    motion_noise : MotionNoise
    multireg : MultiRegConfig
    """

    n_particles: int = 400
    update_period_s: float = 0.5
    max_skew_s: float = 0.3
    reseed_fraction: float = 0.05
    gate_mahalanobis2: float = 25.0
    lost_after: int = 6
    measurement_floor: tuple[float, float, float] = (0.02, 0.02, math.radians(2.0))
    motion_noise: MotionNoise = field(default_factory=MotionNoise)
    multireg: MultiRegConfig = field(default_factory=MultiRegConfig)

    def __post_init__(self) -> None:
        check_registrar_config(self)
        floor = np.asarray(self.measurement_floor, dtype=np.float64)
        if floor.shape != (3,) or not (np.isfinite(floor).all() and (floor > 0).all()):
            raise ValueError(
                f"measurement_floor must be 3 finite numbers > 0, got {self.measurement_floor!r}"
            )
        if not isinstance(self.multireg, MultiRegConfig):
            raise ValueError(f"multireg must be a MultiRegConfig, got {self.multireg!r}")


def check_registrar_config(config: object, positive: tuple[str, ...] = ()) -> None:
    """The fields P-MultiReg's and P-MultiBeaReg's configs share, and their other ``positive``
    ones: ``ValueError`` naming the field and the value."""
    check_number("n_particles", config.n_particles, integer=True, low=2)
    for name in ("update_period_s", "max_skew_s", "gate_mahalanobis2", *positive):
        check_positive(name, getattr(config, name))
    # A share of the particles redrawn per update: all of them would leave the filter no memory.
    check_number("reseed_fraction", config.reseed_fraction, low=0, high=1, below=True)
    check_number("lost_after", config.lost_after, integer=True, low=1)
    if not isinstance(config.motion_noise, MotionNoise):
        raise ValueError(f"motion_noise must be a MotionNoise, got {config.motion_noise!r}")


class _ScheduledRegistrar(ObserverLocalizer):
    """The step shared by P-MultiReg and P-MultiBeaReg: motion updates from the observer's and
    the teammates' odometry, keep the latest own scan, register every ``update_period_s``.

    Subclasses set ``filters`` and ``_own`` and define ``_own_set`` and ``_register``."""

    def step(
        self, time_s: float, measurements: RobotMeasurements, broadcasts: list[Broadcast]
    ) -> None:
        """Absorb one env step's records and broadcasts; register when due."""
        for odo in measurements.odometry:
            self.own_track.integrate(odo.stamp_s, odo.delta)
            for f in self.filters.values():
                f.predict_own(odo.delta)
        for sender, delta in absorb_broadcasts(self.links, broadcasts):
            self.filters[sender].predict_teammate(delta)
        self._absorb_own(measurements)
        if time_s + 1e-9 >= self._next_update_s and np.isfinite(self._own_stamp):
            self._next_update_s = next_due(
                self._next_update_s, time_s, self.config.update_period_s
            )
            self._register()

    def estimates(self) -> dict[str, np.ndarray | None]:
        """Each teammate's relative pose ``[x_m, y_m, theta_rad]`` (particle mean) or ``None``."""
        return {t: f.mean() for t, f in self.filters.items()}

    def moments(self) -> dict[str, tuple[np.ndarray, np.ndarray] | None]:
        """Each teammate's pose mean (3,) and covariance (3, 3) over its particles, or ``None``
        while uninformed (what :class:`~localization.mutual.localizer.MutualLocalizer` reports)."""
        return {t: f.moments() for t, f in self.filters.items()}

    def _absorb_own(self, measurements: RobotMeasurements) -> None:
        """Keep the observer's latest feature set and its stamp (here: the lidar scan's)."""
        if measurements.lidar:
            self._own = self._own_set(measurements.lidar[-1].detections)
            self._own_stamp = measurements.lidar[-1].stamp_s


class PMultiRegLocalizer(_ScheduledRegistrar):
    """P-MultiReg plus one particle filter per teammate, for one observer.

    Parameters
    ----------
    observer : str
        The observer's robot id.
    teammates : sequence of str
        Every other robot id it may hear.
    config : PMultiRegConfig
    rng : numpy Generator
        The filters' own stream.
    """

    name = "p-multireg"
    config_type = PMultiRegConfig

    def _init_filters(self) -> None:
        cfg = self.config
        self.filters = {
            t: TeammateParticles(
                cfg.n_particles,
                cfg.motion_noise,
                np.asarray(cfg.measurement_floor),
                cfg.reseed_fraction,
                self.rng,
            )
            for t in self.teammates
        }
        self._rejections = {t: 0 for t in self.teammates}
        self._own = np.zeros((0, 2))
        self.last_result: MultiRegResult | None = None
        self.last_hypotheses: dict[str, np.ndarray] = {}
        self.n_registrations = 0

    def _own_set(self, detections: np.ndarray) -> np.ndarray:
        """What the registration uses of the observer's latest detections (M, 2): all of them."""
        return np.array(detections)

    def _register(self) -> None:
        labels = {}
        sets = {}
        for k, t in enumerate(self.teammates, start=1):
            link = self.links[t]
            if abs(link.detections_stamp_s - self._own_stamp) <= self.config.max_skew_s:
                labels[k] = t
                sets[k] = link.detections
        self.last_hypotheses = {}
        if not sets:
            return

        gated: set[str] = set()

        def fitness(label, poses, covs):
            t = labels[label]
            f = self.filters[t]
            poses, covs = to_filter_instant(
                poses, covs, self.own_track, self._own_stamp, self.links[t]
            )
            lf = f.log_fitness(poses, covs)
            if lf is None or self._rejections[t] >= self.config.lost_after:
                return lf
            out = np.where(
                f.min_mahalanobis2(poses, covs) <= self.config.gate_mahalanobis2, lf, -np.inf
            )
            if not np.isfinite(out).any():
                gated.add(t)
            return out

        result = multi_register(self._own, sets, fitness, self.config.multireg, self.rng)
        self.last_result = result
        self.n_registrations += 1
        for t in labels.values():
            if t in gated and t not in {labels[k] for k in result.hypotheses}:
                self._rejections[t] += 1
            else:
                self._rejections[t] = 0
        for label, (poses, covs) in result.hypotheses.items():
            t = labels[label]
            moved, covs = to_filter_instant(
                poses, covs, self.own_track, self._own_stamp, self.links[t]
            )
            self.filters[t].update(moved, covs)
            self.last_hypotheses[t] = moved
