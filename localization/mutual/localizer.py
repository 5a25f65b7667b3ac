"""The Stegagno 2012 thesis's three mutual-localization methods behind the project's
:class:`~localization.protocol.Localizer` protocol.

:class:`MutualLocalizer` holds one per-observer system (``p-multireg``:
:class:`~localization.mutual.pmultireg.PMultiRegLocalizer`, ``fastslam-mc``:
:class:`~localization.mutual.fastslam.FastSLAMLocalizer`, ``p-multibeareg``:
:class:`~localization.mutual.pmultibeareg.PMultiBeaRegLocalizer`) for every robot of the swarm
(or for ``observers`` only, the cost guard of big swarms). Each env step it hands robot ``r``
its own records of the :class:`~localization.feed.SwarmFeed` (stale sensors left out) and the
broadcasts it heard, ``feed.comms[r]``. The radio must be on for these methods to see
teammates' odometry and detections (``swarm-phd evaluate`` switches it on with
:data:`DEFAULT_RADIO`); a feed without ``comms`` is valid (nothing was heard) but leaves every
teammate unknown.

What it exposes, robot ``r``'s teammates in its body frame (REP-103):

- :meth:`identities`: ``{teammate index: (x_m, y_m, theta_rad)}``, the method's estimate (the
  weighted particle mean, the thesis's criterion), for every teammate it holds a belief about;
- :meth:`mixture` / :meth:`padded_tables`: one Gaussian per such teammate, its position's mean
  and covariance over the particles (FastSLAM-MC: over the particles' EKFs, the mixture's
  moments), teammates in index order. ``weight_meaning = "existence"``, and the weight is 1: a
  teammate is on the radio, so it exists; what the filter does not know is where, which the
  covariance carries (a P-MultiBeaReg teammate's range spreads along its ray until parallax
  fixes the scale).
- :meth:`estimate`: those positions, all of weight 1 (none if ``threshold > 1``).

Cost: every observer's system is vectorised over its particles (no Python loop over
particles); the loops are over the robots (observers), the teammates each observer holds a
filter for (motion updates, registrations' hypotheses), and, in FastSLAM-MC, the handful of
detections of one scan. ``n_particles`` (per teammate filter for P-MultiReg /
P-MultiBeaReg, per observer for FastSLAM-MC) bounds the work per observer; figures in
``benchmarks/RESULTS.md`` ("Stegagno 2012 methods behind the Localizer protocol").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from swarm_core.records import Broadcast, RobotMeasurements

from ..feed import SwarmFeed
from ..mixture import GaussianMixture
from ..protocol import LocalizerBase, tables_from_mixtures
from .fastslam import FastSLAMLocalizer
from .particles import weighted_moments
from .pmultibeareg import PMultiBeaRegLocalizer
from .pmultireg import PMultiRegLocalizer

__all__ = ["DEFAULT_RADIO", "METHODS", "MutualLocalizer", "observer_rng", "weighted_moments"]

#: Registry name -> per-observer system (its ``config_type`` names its config). The order fixes
#: each method's random streams (:func:`observer_rng`), shared with ``swarm-phd mutual``.
METHODS: dict[str, type] = {
    "p-multireg": PMultiRegLocalizer,
    "fastslam-mc": FastSLAMLocalizer,
    "p-multibeareg": PMultiBeaRegLocalizer,
}

#: The radio ``swarm-phd evaluate`` and ``swarm-phd mutual`` switch on for these methods
#: (``SwarmConfig.comms`` overrides): 10 % loss, 50 ms latency, 10 Hz, unlimited radius.
DEFAULT_RADIO: dict[str, Any] = {"enabled": True, "loss_probability": 0.1, "latency_s": 0.05}

#: Floor on a teammate's reported position variance (m^2): a particle cloud collapsed by
#: resampling must still give a positive-definite covariance.
_VAR_FLOOR_M2 = 1e-8


def observer_rng(seed: int, method_index: int, observer_index: int) -> np.random.Generator:
    """The random stream of one observer's system: ``[seed, 1001, method, observer]``."""
    return np.random.default_rng([int(seed), 1001, int(method_index), int(observer_index)])


class MutualLocalizer(LocalizerBase):
    """Every robot's mutual-localization system of one Stegagno 2012 method.

    Parameters
    ----------
    method : str
        ``"p-multireg"``, ``"fastslam-mc"`` or ``"p-multibeareg"`` (:data:`METHODS`).
    n_robots : int
        ``R``; robot ``r`` is index ``r`` of the feed.
    seed : int
        Seeds each observer's stream (:func:`observer_rng`).
    n_particles : int, optional
        Overrides the method's default particle count (400 / 1000 / 500, the thesis's).
    robot_ids : sequence of str, optional
        The robots' radio ids in index order (``Broadcast.sender``); default ``ugv_0 ..``,
        the simulator's.
    observers : sequence of int, optional
        The robots that run a system (default: all); the others report no teammates. The
        cost guard for big swarms.
    config : dataclass, optional
        The method's full config (overrides ``n_particles``' default too).
    """

    weight_meaning = "existence"
    has_identities = True
    #: The families that read ``feed.comms`` (``swarm-phd evaluate`` switches the radio on).
    needs_comms = True

    def __init__(
        self,
        method: str,
        n_robots: int,
        seed: int = 0,
        n_particles: int | None = None,
        robot_ids: Sequence[str] | None = None,
        observers: Sequence[int] | None = None,
        config: Any = None,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        if n_robots < 1:
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an int, got {seed!r}")
        self.name = method
        self.method = method
        self.n_robots = int(n_robots)
        self.seed = int(seed)
        system = METHODS[method]
        config_type = system.config_type
        if config is None:
            config = config_type(**({} if n_particles is None else {"n_particles": n_particles}))
        elif not isinstance(config, config_type):
            raise ValueError(f"config must be a {config_type.__name__}, got {config!r}")
        elif n_particles is not None:
            config = dataclasses.replace(config, n_particles=n_particles)
        self.config = config
        ids = [f"ugv_{i}" for i in range(self.n_robots)] if robot_ids is None else robot_ids
        if isinstance(ids, str) or len(ids) != self.n_robots or len(set(ids)) != len(ids):
            raise ValueError(
                f"robot_ids must be {self.n_robots} distinct robot ids, got {robot_ids!r}"
            )
        if not all(isinstance(i, str) and i for i in ids):
            raise ValueError(f"robot_ids must be non-empty strings, got {robot_ids!r}")
        self.robot_ids = tuple(ids)
        self._index = {rid: k for k, rid in enumerate(self.robot_ids)}
        self.observers = tuple(sorted(set(self._robots(observers))))
        self._system = system
        self.systems: dict[int, Any] = {}
        self.reset()

    # ------------------------------------------------------------------ protocol
    def reset(self, robots: Sequence[int] | None = None) -> None:
        """Robots ``robots``' systems rebuilt as new, on their initial random streams."""
        m = list(METHODS).index(self.method)
        for r in self._robots(robots):
            if r in self.observers:
                self.systems[r] = self._system(
                    self.robot_ids[r], self.robot_ids, self.config, observer_rng(self.seed, m, r)
                )
        self._cache: dict[int, tuple[dict[int, np.ndarray], GaussianMixture]] = {}

    def step(self, feed: SwarmFeed) -> None:
        """Hand each observer its records (stale sensors removed) and its broadcasts.

        Every record and broadcast is checked first (``ValueError`` naming robot and field,
        state untouched): the anonymous banks' checks on the records, and every sender a known
        robot id."""
        self._check_feed(feed)
        from ..registry import _check_records  # the registry builds this module lazily

        comms = feed.comms if len(feed.comms) else [()] * self.n_robots
        if len(comms) != self.n_robots:
            raise ValueError(
                f"{self.name}: feed.comms has {len(comms)} robots, the localizer {self.n_robots}"
            )
        for r in range(self.n_robots):
            _check_records(r, feed.measurements[r], feed.stale[r])
            if "camera" not in feed.stale[r]:
                for rec in feed.measurements[r].camera:
                    if not (np.isfinite(rec.stamp_s) and np.isfinite(rec.bearings_rad).all()):
                        raise ValueError(
                            f"robot {r}: camera record must have a finite stamp and finite "
                            f"bearings_rad, got stamp {rec.stamp_s!r}"
                        )
            for b in comms[r]:
                if not isinstance(b, Broadcast):
                    raise ValueError(f"robot {r}: comms must hold Broadcasts, got {b!r}")
                if b.sender not in self._index:
                    raise ValueError(
                        f"robot {r}: broadcast sender {b.sender!r} is not one of {self.robot_ids}"
                    )
                if not (
                    np.isfinite(b.odometry_pose).all()
                    and np.isfinite(b.detections).all()
                    and np.abs(b.odometry_pose[:2]).max(initial=0.0) <= 1e4
                    and np.abs(b.detections).max(initial=0.0) <= 1e4
                ):
                    raise ValueError(
                        f"robot {r}: broadcast from {b.sender} must be finite and within 1e4 m"
                    )
                if not np.isfinite(b.bearings_rad).all():
                    raise ValueError(
                        f"robot {r}: broadcast from {b.sender}: bearings_rad must be finite, "
                        f"got {b.bearings_rad!r}"
                    )
        for r, system in self.systems.items():
            records = _fresh(feed.measurements[r], feed.stale[r])
            system.step(feed.time_s, records, list(comms[r]))
        self._cache = {}

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        """``{teammate index: [x_m, y_m, theta_rad]}`` in robot ``robot``'s frame."""
        return dict(self._robot_view(self._robot(robot))[0])

    def mixture(self, robot: int) -> GaussianMixture:
        return self._robot_view(self._robot(robot))[1]

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        return tables_from_mixtures([self.mixture(r) for r in range(self.n_robots)])

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        mix = self.mixture(robot)
        keep = mix.weights >= threshold
        return mix.means[keep].copy(), mix.weights[keep].copy()

    # ------------------------------------------------------------------ internals
    def _robot_view(self, r: int) -> tuple[dict[int, np.ndarray], GaussianMixture]:
        """Robot ``r``'s identities and mixture, computed once per step."""
        if r not in self._cache:
            system = self.systems.get(r)
            moments = {} if system is None else system.moments()
            ids: dict[int, np.ndarray] = {}
            means, covs = [], []
            for t in sorted(moments, key=self._index.__getitem__):
                if moments[t] is None:
                    continue
                mean, cov = moments[t]
                ids[self._index[t]] = mean
                means.append(mean[:2])
                covs.append(cov[:2, :2] + _VAR_FLOOR_M2 * np.eye(2))
            mix = GaussianMixture(
                np.ones(len(means)),
                np.array(means).reshape(-1, 2),
                np.array(covs).reshape(-1, 2, 2),
            )
            self._cache[r] = (ids, mix)
        return self._cache[r]


def _fresh(records: RobotMeasurements, stale: tuple[str, ...]) -> RobotMeasurements:
    """``records`` without the sensors the World reports stale (P-MultiBeaReg reads the
    camera's)."""
    if not stale:
        return records
    return dataclasses.replace(
        records,
        odometry=[] if "odometry" in stale else records.odometry,
        lidar=[] if "lidar" in stale else records.lidar,
        camera=[] if "camera" in stale else records.camera,
    )
