"""``encirclement``: enclose a moving intruder in a circle (Lee 2012, particle-filter swarms).

The intruder is one extra robot that is not an agent: same chassis, lidar housing and red strip,
so every lidar and camera sees it like any teammate (it shows up in the PHD like one), but it has
no sensors and moves on a scripted path:

- ``path="circle"``: a loop of radius ``path_radius_m`` around the arena centre at
  ``intruder_speed_mps`` (it first drives onto the loop from where it spawned);
- ``path="static"``: it stands still.

Its driver sees only its own world position (from the ground truth of the simulator): heading is
estimated from its displacement, so it behaves like an open-loop target with position feedback.

Reward (per agent i, per step; ``q`` intruder position, ``d_i = ||p_i - q||``, ``G`` the largest
angular gap between the agents as seen from ``q``, N agents)::

    r_i = -| d_i - r |  -  gap_weight * max(0, G - 2 pi / N) / pi

The first term brings every agent onto the circle of radius ``r`` around the intruder, the second
(shared) spreads them around it. The intruder is *enclosed* when ``G < pi`` (it lies inside the
agents' convex hull).

Termination: never. Truncation: ``max_steps`` of the config.

Task features (per agent): ``[r]``, and with ``beacon=True`` (default)
``[r, valid, cos b, sin b, rho]``: the intruder's bearing ``b`` (rad) and range ``rho`` (m) in the
agent's frame with Gaussian noise, and ``valid`` = 1.0 when this reading exists. It is 0.0 (and
``cos b, sin b, rho`` are 0) when the beacon cannot be computed: the beacon is simulated from
the ground truth, so a real swarm without motion capture (``truth is None``) or a world without
the intruder has none, and a bare ``rho = 0`` would read as "the intruder is right here". This
models the Lee 2012 study's setting, where every robot ranges the intruder by radio (Lee 2012:
"range (and bearing) to others by wireless"): a real intruder carrying no beacon could not be
told apart from a teammate by anonymous lidar/camera detections, so without the beacon the PHD
alone does not say which component to enclose. With ``beacon=False`` only ``[r]`` is given.

Where the intruder's position comes from (``intruder_source``, Lee 2012; the scripted
controller :class:`agents.scripted.EncirclementPolicy` reads the same parameter):

- ``"beacon"`` (the ablation, default): a fresh reading every step, simulated from the ground
  truth; the controller encloses that reading (refined by the nearest PHD component).
- ``"particle"``: the same kind of reading, but only at ``reading_rate_hz`` with probability
  ``reading_dropout`` of losing each (Lee 2012's radio ranging; ``valid`` = 1 only on the
  step a reading arrives). Each robot's controller runs Lee 2012's particle filter
  (:class:`localization.baselines.particle.ParticleFilterTracker`) on them with its own
  odometry, and encloses the filter's estimate.
  With ``intruder_sensing="range"`` (``"particle"`` only) a reading carries the range only,
  with the same rate, loss and range noise: its ``cos b, sin b`` are both 0 (no unit vector
  is, so ``(0, 0)`` with ``valid`` = 1 means "no bearing"). The filters then weight by range
  alone, and with ``particle_start="trilateration"`` start from a trilateration fix of the
  robot's own positions at >= 3 readings (:mod:`localization.baselines.particle`); before
  that the robot random-walks, which is what gives it the baseline.
- ``"estimate"``: one reading at reset (the intruder pointed out once), none after; the
  controller then follows the intruder in its own PHD estimate (the env's localizer output),
  the component nearest its odometry-propagated last position.

What the features carry (``intruder_features``):

- ``"reading"`` (default): the raw reading of the step, as above (``valid`` = 1 only when one
  arrives). The scripted controller runs its own filter on them; a memoryless learned policy
  sees a reading on 2 steps in 10 (``particle``) or once (``estimate``).
- ``"filter"`` (``intruder_source="particle"`` only): the task runs Lee 2012's particle
  filter for every robot itself and the features are the filter's estimate every step (``valid``
  = 1 from the first reading on; range-only with ``particle_start="trilateration"``, from the
  fix on), so a learned policy observes what the scripted one encloses.
  Each robot's filter is predicted with the arc of that robot's own clipped command ``[v, omega]``
  over the control period (the task sees the commands, not the wheel odometry) and updated with
  each reading. Commands are what the robot knows without ground truth; they miss wheel slip and
  contact, which the reading updates correct.

The task reports the enclosing error and the escape figures for whichever source drives the
controller (``metrics()``: ``escape_fraction`` = share of the steps after the first enclosure
in which the intruder is outside the agents' hull, ``escapes_per_min`` = enclosed -> not
enclosed transitions per minute).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_core.world import GroundTruth
from swarm_env.tasks.base import Task
from swarm_env.tasks.common import check_choice, check_param, max_angular_gap

PATHS = ("circle", "static")
INTRUDER_SOURCES = ("beacon", "particle", "estimate")
INTRUDER_FEATURES = ("reading", "filter")
INTRUDER_SENSING = ("range-bearing", "range")
PARTICLE_STARTS = ("uniform", "trilateration")
_MAX_RANGE_M = 20.0


class EncirclementTask(Task):
    """Enclose a scripted intruder on a circle of radius ``radius_m``.

    Parameters
    ----------
    radius_m : float
        Enclosing circle radius, default 0.6 m.
    gap_weight : float
        Weight of the spread term, default 0.5.
    path : {"circle", "static"}
    intruder_speed_mps : float
        Default 0.05 m/s; must be 0 for ``path="static"``.
    path_radius_m : float or None
        Loop radius; default ``0.25 * min(arena width, height)``.
    beacon : bool
        Give every agent the intruder's noisy range and bearing, with a validity flag (default
        True): features ``[r, valid, cos b, sin b, rho]`` instead of ``[r]``.
    beacon_range_std_m, beacon_bearing_std_deg : float
        Beacon noise (default 0.05 m, 5 deg).
    intruder_source : {"beacon", "particle", "estimate"}
        Where the controller's intruder position comes from (module docstring); needs
        ``beacon=True`` unless ``"beacon"``.
    reading_rate_hz, reading_dropout : float
        ``"particle"`` only: readings per second per robot (default 2 Hz) and the probability
        of losing each (default 0.2). Lee 2012 gives neither: stated assumptions.
    intruder_features : {"reading", "filter"}
        What the features carry (module docstring): the raw reading (default) or, with
        ``intruder_source="particle"``, the estimate of a particle filter the task runs per robot.
    n_particles : int
        ``"filter"`` only: particles per robot's filter (default 300, as the scripted controller).
    intruder_sensing : {"range-bearing", "range"}
        ``"particle"`` only for ``"range"``: what a reading carries (module docstring). Default
        ``"range-bearing"``.
    particle_start : {"uniform", "trilateration"}
        How the particle filters (the task's under ``"filter"``, the scripted controller's)
        start a track (:mod:`localization.baselines.particle`): uniform cloud (default) or the
        triangulation / trilateration fix.
    """

    name = "encirclement"
    n_extra_robots = 1

    def __init__(
        self,
        radius_m: float = 0.6,
        gap_weight: float = 0.5,
        path: str = "circle",
        intruder_speed_mps: float | None = None,
        path_radius_m: float | None = None,
        beacon: bool = True,
        beacon_range_std_m: float = 0.05,
        beacon_bearing_std_deg: float = 5.0,
        intruder_source: str = "beacon",
        reading_rate_hz: float = 2.0,
        reading_dropout: float = 0.2,
        intruder_features: str = "reading",
        n_particles: int = 300,
        intruder_sensing: str = "range-bearing",
        particle_start: str = "uniform",
        **params: Any,
    ) -> None:
        super().__init__(**params)
        self.radius_m = check_param(self.name, "radius_m", radius_m, 0.0, 20.0, low_open=True)
        self.gap_weight = check_param(self.name, "gap_weight", gap_weight, 0.0, 10.0)
        self.path = check_choice(self.name, "path", path, PATHS)
        if intruder_speed_mps is None:
            intruder_speed_mps = 0.05 if path == "circle" else 0.0
        self.intruder_speed_mps = check_param(
            self.name, "intruder_speed_mps", intruder_speed_mps, 0.0, 2.0
        )
        if path == "static" and (self.intruder_speed_mps > 0 or path_radius_m is not None):
            raise ValueError(
                f"task {self.name!r}: path='static' takes no intruder_speed_mps > 0 "
                "or path_radius_m"
            )
        if path == "circle" and self.intruder_speed_mps == 0:
            raise ValueError(
                f"task {self.name!r}: path='circle' needs intruder_speed_mps > 0 "
                "(use path='static' for a standing intruder)"
            )
        self.path_radius_m = (
            None
            if path_radius_m is None
            else check_param(self.name, "path_radius_m", path_radius_m, 0.0, 50.0, low_open=True)
        )
        if not isinstance(beacon, bool):
            raise ValueError(f"task {self.name!r}: beacon must be True or False, got {beacon!r}")
        self.beacon = beacon
        self.beacon_range_std_m = check_param(
            self.name, "beacon_range_std_m", beacon_range_std_m, 0.0, 5.0
        )
        self.beacon_bearing_std_rad = math.radians(
            check_param(self.name, "beacon_bearing_std_deg", beacon_bearing_std_deg, 0.0, 180.0)
        )
        self.intruder_source = check_choice(
            self.name, "intruder_source", intruder_source, INTRUDER_SOURCES
        )
        if intruder_source != "beacon" and not beacon:
            raise ValueError(
                f"task {self.name!r}: intruder_source={intruder_source!r} needs beacon=True "
                "(its readings are the beacon features)"
            )
        self.reading_rate_hz = check_param(
            self.name, "reading_rate_hz", reading_rate_hz, 0.0, 100.0, low_open=True
        )
        self.reading_dropout = check_param(self.name, "reading_dropout", reading_dropout, 0.0, 1.0)
        self.intruder_features = check_choice(
            self.name, "intruder_features", intruder_features, INTRUDER_FEATURES
        )
        if intruder_features == "filter":
            self._check_particle_source("intruder_features='filter'", intruder_source)
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)):
            raise ValueError(
                f"task {self.name!r}: n_particles must be an int, got {n_particles!r}"
            )
        if not 10 <= n_particles <= 100_000:
            raise ValueError(
                f"task {self.name!r}: n_particles must be in [10, 100000], got {n_particles!r}"
            )
        self.n_particles = int(n_particles)
        self.intruder_sensing = check_choice(
            self.name, "intruder_sensing", intruder_sensing, INTRUDER_SENSING
        )
        if intruder_sensing == "range":
            self._check_particle_source(
                "intruder_sensing='range'",
                intruder_source,
                "the other sources use the reading's bearing",
            )
        self.particle_start = check_choice(
            self.name, "particle_start", particle_start, PARTICLE_STARTS
        )
        self._filters: list[Any] = []  # "filter": one ParticleFilterTracker (or None) per agent
        self._dt_s = 0.1
        self._time_s = 0.0
        self._next_reading_s = np.zeros(0)
        self._cued = False
        self._rng = np.random.default_rng(0)
        self._features = np.zeros((0, self.n_features))
        self._loop_radius_m = 1.0
        self._heading = 0.0
        self._prev_xy: np.ndarray | None = None
        self._last_omega = 0.0
        self._errors: list[float] = []
        self._gaps: list[float] = []

    def _check_particle_source(self, option: str, intruder_source: str, why: str = "") -> None:
        """Refuse ``option`` (e.g. ``"intruder_features='filter'"``) unless the intruder source
        is the particle filter; ``why`` is said in brackets."""
        if intruder_source != "particle":
            because = f" ({why})" if why else ""
            raise ValueError(
                f"task {self.name!r}: {option} needs intruder_source='particle'{because}, "
                f"got {intruder_source!r}"
            )

    @property
    def n_features(self) -> int:
        """``[r]`` (1), or ``[r, valid, cos b, sin b, rho]`` (5) with the beacon."""
        return 5 if self.beacon else 1

    # -- observation ----------------------------------------------------------------------
    def feature_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.beacon:
            return np.zeros(1), np.array([self.radius_m])
        return (
            np.array([0.0, 0.0, -1.0, -1.0, 0.0]),
            np.array([self.radius_m, 1.0, 1.0, 1.0, _MAX_RANGE_M]),
        )

    def features(self, n_agents: int) -> np.ndarray:
        """Task features, shape (N, F): ``[r]`` or ``[r, valid, cos b, sin b, rho]`` (m, -, -, -,
        m). Without a current beacon reading, ``valid`` and the beacon values are 0."""
        if len(self._features) != n_agents:
            out = np.zeros((n_agents, self.n_features))
            out[:, 0] = self.radius_m
            return out
        return self._features.copy()

    def _update_features(
        self, truth: GroundTruth | None, commands: np.ndarray | None = None
    ) -> None:
        if truth is None:
            # No ground truth, no beacon: drop the last reading so that features() reports
            # it invalid instead of repeating a stale intruder position.
            self._features = np.zeros((0, self.n_features))
            return
        n = len(truth.poses)
        out = np.zeros((n, self.n_features))
        out[:, 0] = self.radius_m
        if self.beacon and len(truth.extra_xy):
            arrives = self._arrivals(n)
            rel = intruder_in_agent_frames(truth.poses, truth.extra_xy[0])
            rho = np.hypot(rel[:, 0], rel[:, 1]) + self._rng.normal(
                0.0, self.beacon_range_std_m, n
            )
            bearing = np.arctan2(rel[:, 1], rel[:, 0]) + self._rng.normal(
                0.0, self.beacon_bearing_std_rad, n
            )
            out[:, 1] = 1.0
            out[:, 2], out[:, 3] = np.cos(bearing), np.sin(bearing)
            if self.intruder_sensing == "range":
                out[:, 2:4] = 0.0  # range only: (cos b, sin b) = (0, 0) is "no bearing"
            out[:, 4] = np.clip(rho, 0.0, _MAX_RANGE_M)
            out[~arrives, 1:] = 0.0  # no reading this step: flagged invalid, values zeroed
            if self.intruder_features == "filter":
                self._filter_features(out, commands)
        self._features = out

    def _filter_features(self, out: np.ndarray, commands: np.ndarray | None) -> None:
        """Replace ``out``'s readings (N, 5) by each robot's particle-filter estimate, in place:
        predict with the robot's command arc (not on the reset step, ``commands is None``),
        update with the reading if one arrived, report the estimate once the filter started."""
        from localization.baselines.particle import ParticleFilterTracker

        n = len(out)
        if len(self._filters) != n:
            self._filters = [None] * n
        for i in range(n):  # a loop over the robots; each filter is vectorised over particles
            pf = self._filters[i]
            if pf is not None and commands is not None:
                pf.predict(command_arc(commands[i], self._dt_s))
            if out[i, 1] >= 0.5:
                if pf is None:
                    pf = self._filters[i] = ParticleFilterTracker(
                        n_particles=self.n_particles,
                        range_std_m=max(self.beacon_range_std_m, 1e-3),
                        bearing_std_rad=max(self.beacon_bearing_std_rad, 1e-3),
                        period_s=self._dt_s,
                        seed=int(self._rng.integers(2**31)),
                        start=self.particle_start,
                    )
                bearing = (
                    math.atan2(out[i, 3], out[i, 2])
                    if self.intruder_sensing == "range-bearing"
                    else math.nan
                )
                pf.update({0: np.array([out[i, 4], bearing])})
            if pf is None or 0 not in pf.ids:  # no filter, or range-only and not fixed yet
                out[i, 1:] = 0.0
                continue
            q = pf.estimate()[0]
            b = math.atan2(q[1], q[0])
            out[i, 1:] = (1.0, math.cos(b), math.sin(b), min(math.hypot(*q), _MAX_RANGE_M))

    def intruder_estimates(self) -> list[np.ndarray | None]:
        """``"filter"`` only: each robot's filter estimate of the intruder (2,) in its body frame
        (m), or ``None`` before its first reading; empty otherwise."""
        return [None if pf is None or not pf.ids else pf.estimate()[0] for pf in self._filters]

    def _arrivals(self, n: int) -> np.ndarray:
        """Which agents get an intruder reading this step (N,) bool, per ``intruder_source``.
        Draws nothing for ``"beacon"`` (its random stream is the one it always had)."""
        if self.intruder_source == "beacon":
            return np.ones(n, dtype=bool)
        if self.intruder_source == "estimate":
            first = not self._cued
            self._cued = True
            return np.full(n, first)
        if len(self._next_reading_s) != n:  # first reading of each robot within one period
            self._next_reading_s = self._time_s + self._rng.uniform(
                0.0, 1.0 / self.reading_rate_hz, n
            )
        due = self._next_reading_s <= self._time_s + 1e-9
        self._next_reading_s[due] += 1.0 / self.reading_rate_hz
        return due & (self._rng.random(n) >= self.reading_dropout)

    # -- episode --------------------------------------------------------------------------
    def check_arena(self, arena: Any) -> None:
        half_side = 0.5 * min(arena.width_m, arena.height_m)
        for name, value in (("radius_m", self.radius_m), ("path_radius_m", self.path_radius_m)):
            if value is not None and value >= half_side:  # a circle wider than the arena
                raise ValueError(
                    f"task {self.name!r}: {name}={value} does not fit a "
                    f"{arena.width_m} m x {arena.height_m} m arena"
                )

    def start(self, truth: GroundTruth | None) -> None:
        self._loop_radius_m = (
            self.path_radius_m
            if self.path_radius_m is not None
            else 0.25 * min(self._arena.width_m, self._arena.height_m)
        )
        self._heading = 0.0
        self._prev_xy = None
        self._last_omega = 0.0
        self._errors, self._gaps = [], []
        self._time_s = 0.0
        self._next_reading_s = np.zeros(0)
        self._cued = False
        self._filters = []
        self._update_features(truth)

    def extra_commands(self, truth: GroundTruth | None, dt_s: float) -> np.ndarray | None:
        self._time_s += dt_s  # the env calls this once per step: the readings' clock
        self._dt_s = dt_s
        if truth is None or self.path == "static" or not len(truth.extra_xy):
            return np.zeros((self.n_extra_robots, 2))
        q = truth.extra_xy[0]
        # Heading from the displacement since the last command (no skid on a differential
        # drive); while barely moving, integrate the commanded turn rate instead.
        self._heading += self._last_omega * dt_s
        if self._prev_xy is not None:
            step = q - self._prev_xy
            if np.hypot(*step) > 2e-3:
                self._heading = math.atan2(step[1], step[0])
        self._prev_xy = q.copy()
        # Carrot on the loop, 0.6 rad ahead (counter-clockwise) of the intruder's polar angle.
        theta = math.atan2(q[1], q[0]) + 0.6
        target = self._loop_radius_m * np.array([math.cos(theta), math.sin(theta)])
        desired = math.atan2(target[1] - q[1], target[0] - q[0])
        err = math.atan2(math.sin(desired - self._heading), math.cos(desired - self._heading))
        omega = float(np.clip(2.0 * err, -1.0, 1.0))
        v = self.intruder_speed_mps * max(0.3, math.cos(err))
        self._last_omega = omega
        return np.array([[v, omega]])

    def errors(self, xy: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
        """Per-agent radius error (N,) and the largest angular gap around ``q`` (rad)."""
        return np.abs(np.linalg.norm(xy - q, axis=1) - self.radius_m), max_angular_gap(q, xy)

    def rewards(self, truth: GroundTruth | None, actions: np.ndarray) -> np.ndarray:
        if truth is None or not len(truth.extra_xy):
            self._update_features(truth)  # beacon flagged invalid, not left stale
            return np.zeros(len(actions))
        xy = truth.poses[:, :2]
        radius_err, gap = self.errors(xy, truth.extra_xy[0])
        self._errors.append(float(radius_err.mean()))
        self._gaps.append(gap)
        self._update_features(truth, actions)
        spread = max(0.0, gap - 2 * math.pi / len(xy)) / math.pi
        return -(radius_err + self.gap_weight * spread)

    def metrics(self) -> dict[str, float]:
        if not self._errors:
            return {}
        tail = max(1, len(self._errors) // 5)
        gaps = np.asarray(self._gaps)
        enclosed = gaps < math.pi
        after = enclosed[int(np.argmax(enclosed)) :] if enclosed.any() else enclosed[:0]
        escapes = int(np.count_nonzero(after[:-1] & ~after[1:]))
        minutes = self._time_s / 60.0
        return {
            "radius_error_m": float(np.mean(self._errors)),
            "final_radius_error_m": float(np.mean(self._errors[-tail:])),
            "enclosed_fraction": float(np.mean(gaps < math.pi)),
            "final_enclosed_fraction": float(np.mean(gaps[-tail:] < math.pi)),
            "mean_max_gap_deg": float(np.degrees(gaps.mean())),
            "ever_enclosed": float(enclosed.any()),
            "escape_fraction": float(np.mean(~after)) if len(after) else 1.0,
            "escapes_per_min": escapes / minutes if minutes > 0 else 0.0,
        }


def command_arc(command: np.ndarray, dt_s: float) -> np.ndarray:
    """Own motion ``(dx_m, dy_m, dpsi_rad)`` over ``dt_s`` of a unicycle holding ``[v, omega]``
    (m/s, rad/s): an arc, the straight line as ``omega -> 0``."""
    v, w = float(command[0]), float(command[1])
    if abs(w) < 1e-9:
        return np.array([v * dt_s, 0.0, 0.0])
    return np.array([v * math.sin(w * dt_s) / w, v * (1.0 - math.cos(w * dt_s)) / w, w * dt_s])


def intruder_in_agent_frames(poses: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The intruder's world position ``q`` (2,) in each agent's body frame, shape (N, 2)."""
    d = q[None, :] - poses[:, :2]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)
