"""Scripted swarm controllers that use only what a real robot has: its own lidar scan, its own
odometry and its own PHD estimate (never ground truth).

Every policy maps ``(observations, infos) -> actions`` for all live agents at once, so the same
object drives the simulator and the hardware bridge.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from localization.config import PHDConfig
from localization.detection import DetectionModel
from swarm_core.geometry import wrap_angle
from swarm_core.validation import check_number, check_positive
from swarm_env.observation import ESTIMATE_COLUMNS


class ScriptedPolicy:
    """Base class: per-agent state is kept in dicts keyed by agent name.

    ``max_speed_mps`` (m/s) and ``max_turn_rate_radps`` (rad/s) are the robot's command limits
    (``for_env`` takes them from ``env.config.robot``); the subclasses take them as keywords,
    beside their own parameters."""

    name = "scripted"
    #: The agents whose command of the last call was the Perera 2021 study's random walk (drawn
    #: from the controller's own generator, so two instances disagree there). Set by every call.
    wandering: frozenset[str] | set[str] = frozenset()

    def __init__(self, max_speed_mps: float = 0.3, max_turn_rate_radps: float = 1.5) -> None:
        self.max_speed_mps = max_speed_mps
        self.max_turn_rate_radps = max_turn_rate_radps

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any) -> ScriptedPolicy:
        robot = env.config.robot
        return cls(
            max_speed_mps=robot.max_speed_mps,
            max_turn_rate_radps=robot.max_turn_rate_radps,
            **kwargs,
        )

    def reset(self, seed: int | None = None) -> None:
        """Forget per-agent state; reseed any randomness."""

    def __call__(
        self, observations: dict[str, np.ndarray], infos: dict[str, dict[str, Any]]
    ) -> dict[str, np.ndarray]:
        raise NotImplementedError


def latest_scan(info: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(angles_rad (B,), ranges_m (B,))`` of the newest lidar scan in ``info``, or ``None``."""
    scans = info.get("measurements", {}).get("lidar", [])
    if not scans:
        return None
    return scans[-1]["angles_rad"], scans[-1]["ranges_m"]


class WanderPolicy(ScriptedPolicy):
    """Perera 2021's pseudo-random motion with lidar obstacle avoidance.

    Each robot cruises at ``cruise_fraction * v_max`` with a turn rate that follows an
    Ornstein-Uhlenbeck process (smooth random heading changes). When the nearest valid lidar return
    in the front sector (+/- ``front_half_angle_deg``) is closer than ``avoid_distance_m``, the
    robot slows down and turns towards the side with more free space until the front is clear.
    Teammates and obstacles are avoided alike: the lidar cannot tell them apart.
    """

    name = "wander"

    def __init__(
        self,
        *,
        cruise_fraction: float = 0.6,
        avoid_distance_m: float = 0.45,
        front_half_angle_deg: float = 50.0,
        turn_noise: float = 0.6,
        seed: int | None = 0,
        **limits: float,
    ) -> None:
        super().__init__(**limits)
        self.cruise_mps = cruise_fraction * self.max_speed_mps
        self.avoid_distance_m = avoid_distance_m
        self.front_half_angle_rad = np.deg2rad(front_half_angle_deg)
        self.turn_noise = turn_noise
        self._seed = seed
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(self._seed if seed is None else seed)
        self._turn: dict[str, float] = {}
        self._scan: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._avoid_sign: dict[str, float] = {}

    def __call__(self, observations, infos):
        actions = {}
        for agent in observations:
            scan = latest_scan(infos.get(agent, {}))
            if scan is not None:
                self._scan[agent] = scan
            actions[agent] = self._act(agent)
        self.wandering = set(observations)
        return actions

    def _act(self, agent: str) -> np.ndarray:
        # Ornstein-Uhlenbeck turn rate: mean-reverting, so paths curve but do not spin.
        turn = self._turn.get(agent, 0.0)
        turn += -0.2 * turn + self.turn_noise * self._rng.standard_normal() * 0.3
        self._turn[agent] = float(np.clip(turn, -0.5, 0.5) * self.max_turn_rate_radps)
        v, omega = self.cruise_mps, self._turn[agent]
        scan = self._scan.get(agent)
        if scan is not None:
            angles, ranges = scan
            valid = ranges > 0
            front = valid & (np.abs(angles) < self.front_half_angle_rad)
            nearest = ranges[front].min() if front.any() else np.inf
            if nearest < self.avoid_distance_m:
                if agent not in self._avoid_sign:
                    # Turn towards the side whose nearest return is further away; keep that
                    # choice until clear so the robot does not dither between sides.
                    left = valid & (angles > 0) & (angles < np.pi / 2)
                    right = valid & (angles < 0) & (angles > -np.pi / 2)
                    free_left = ranges[left].min() if left.any() else np.inf
                    free_right = ranges[right].min() if right.any() else np.inf
                    self._avoid_sign[agent] = 1.0 if free_left >= free_right else -1.0
                v = self.cruise_mps * max(0.0, (nearest - 0.25) / self.avoid_distance_m) - 0.05
                omega = self._avoid_sign[agent] * self.max_turn_rate_radps
            else:
                self._avoid_sign.pop(agent, None)
        return np.array([v, omega], dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# Controllers on the agent's own PHD estimate (the observation table), lidar and odometry.
# ---------------------------------------------------------------------------------------------

TABLE_COLUMNS = len(ESTIMATE_COLUMNS)  # [w, x, y, sxx, sxy, syy, valid]
_W, _X, _Y, _SXX, _SXY, _SYY, _VALID = (ESTIMATE_COLUMNS.index(c) for c in ESTIMATE_COLUMNS)


def split_observation(
    obs: np.ndarray, top_k: int, n_sectors: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(table (K, 7), odometry [v, omega] (2,), task features (F,))`` of one observation in
    the ``"phd"``/``"truth"`` layout; ``n_sectors``: the lidar sector table between the table
    and the odometry (``SwarmConfig.lidar_sectors``), skipped here (the controllers read the
    full scan from ``infos``)."""
    n_table = TABLE_COLUMNS * top_k
    start = n_table + n_sectors
    obs = np.asarray(obs, dtype=np.float64)
    return (
        obs[:n_table].reshape(top_k, TABLE_COLUMNS),
        obs[start : start + 2],
        obs[start + 2 :],
    )


def estimated_neighbours(
    table: np.ndarray,
    min_weight: float = 0.5,
    max_variance_m2: float = 0.5,
    reference_variance_m2: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (M, 2) and weights (M,) of the confident components of a PHD table.

    Kept: valid rows with weight >= ``min_weight`` whose position variance is below
    ``max_variance_m2`` (this drops the broad birth component at the origin). With
    ``reference_variance_m2`` the returned weights are discounted by the component's spread,
    ``w / (1 + (sxx + syy) / reference_variance_m2)``: a camera-only track (bearing known, range
    drifting) then counts little next to a lidar-confirmed one.
    """
    keep = confident_rows(table, min_weight, max_variance_m2)
    weights = table[keep, _W].copy()
    if reference_variance_m2 is not None:
        weights /= 1.0 + (table[keep, _SXX] + table[keep, _SYY]) / reference_variance_m2
    return table[keep][:, [_X, _Y]], weights


def confident_rows(
    table: np.ndarray, min_weight: float = 0.5, max_variance_m2: float = 0.5
) -> np.ndarray:
    """Which rows (K,) of a PHD table :func:`estimated_neighbours` keeps (bool)."""
    return (
        (table[:, _VALID] > 0.5)
        & (table[:, _W] >= min_weight)
        & (np.maximum(table[:, _SXX], table[:, _SYY]) <= max_variance_m2)
    )


def bearing_std(rows: np.ndarray) -> np.ndarray:
    """Bearing standard deviations (M,) (rad) of PHD table rows (M, 7):
    ``sqrt(u_perp' P u_perp) / r`` with ``u`` the unit bearing (ranges floored at 1 cm)."""
    ranges = np.maximum(np.hypot(rows[:, _X], rows[:, _Y]), 0.01)
    ux, uy = rows[:, _X] / ranges, rows[:, _Y] / ranges
    var = uy * uy * rows[:, _SXX] - 2.0 * ux * uy * rows[:, _SXY] + ux * ux * rows[:, _SYY]
    return np.sqrt(np.maximum(var, 0.0)) / ranges


def estimated_centroid(
    points: np.ndarray, weights: np.ndarray, swarm_size: int | None = None
) -> np.ndarray:
    """The swarm's centroid as a robot sees it, in its body frame (2,): its confident
    components ``points`` (M, 2) with ``weights`` (M,), plus itself (weight 1 at the origin),
    ``sum_k w_k m_k / (1 + sum_k w_k)``. With the swarm size ``swarm_size`` = N known, once
    M >= N - 1 and the weights sum to less than N - 1 they are first scaled to sum to N - 1
    (everyone is in sight; see :class:`FormationPolicy`). With more than N - 1 components a
    spurious one (a decoy post's) is scaled up with the rest."""
    total = weights.sum()
    if swarm_size is not None and len(weights) >= swarm_size - 1 and 0.0 < total < swarm_size - 1:
        weights, total = weights * ((swarm_size - 1) / total), swarm_size - 1
    return (weights[:, None] * points).sum(axis=0) / (1.0 + total)


#: Candidate turns of :meth:`VectorFieldPolicy.sensing_turn`, 1 deg apart (rad).
_SENSING_TURNS_RAD = np.radians(np.arange(-90.0, 90.5, 1.0))
_SENSING_NO_TURN = int(np.argmin(np.abs(_SENSING_TURNS_RAD)))


def expected_lidar_detections(
    points: np.ndarray,
    weights: np.ndarray,
    turns_rad: np.ndarray,
    detection: DetectionModel,
    bearing_std_rad: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Expected lidar detections per scan of the estimated teammates ``points`` (K, 2) (body
    frame, m) with ``weights`` (K,) and bearing stds ``bearing_std_rad`` (K,) (rad), if the
    robot turned in place by each of ``turns_rad`` (D,) (rad, counter-clockwise: a bearing
    ``beta`` becomes ``beta - turn``), shape (D,):
    ``sum_k w_k P_range(r_k) P_blind(beta_k - turn)``.

    ``P_range`` and ``P_blind`` are the filter's own range and blind-sector factors
    (``detection``, the filter's :class:`~localization.detection.DetectionModel`; Perera 2021
    eq. 18 without the occlusion and interference factors, which a turn does not change). Under the
    constant ``P_d`` model the filter has no blind sectors, so no turn gains anything."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    weights = np.asarray(weights, dtype=float)
    turns_rad = np.asarray(turns_rad, dtype=float)
    if weights.shape != (len(points),):
        raise ValueError(f"weights must have shape ({len(points)},), got {weights.shape}")
    ranges = np.hypot(points[:, 0], points[:, 1])
    in_range = detection.lidar_range_factor(ranges)
    bearings = np.arctan2(points[:, 1], points[:, 0])[None, :] - turns_rad[:, None]
    blind = detection.lidar_blind_sector_factor(
        bearings.ravel(),
        np.broadcast_to(ranges, bearings.shape).ravel(),
        np.broadcast_to(bearing_std_rad, bearings.shape).ravel(),
    ).reshape(bearings.shape)
    return (blind * (weights * in_range)[None, :]).sum(axis=1)


def lidar_points(scan: tuple[np.ndarray, np.ndarray] | None, max_range_m: float) -> np.ndarray:
    """Valid lidar returns closer than ``max_range_m`` as body-frame points (P, 2)."""
    if scan is None:
        return np.zeros((0, 2))
    angles, ranges = scan
    keep = (ranges > 0) & (ranges < max_range_m)
    return np.stack(
        [ranges[keep] * np.cos(angles[keep]), ranges[keep] * np.sin(angles[keep])], axis=-1
    )


class VectorFieldPolicy(ScriptedPolicy):
    """Base of the PHD-driven controllers: each computes a desired planar velocity ``u`` in its
    own body frame; this class adds lidar repulsion and turns ``u`` into ``[v, omega]`` for the
    differential drive (driving backwards when ``u`` points behind, so no U-turns are needed).

    Parameters
    ----------
    top_k : int
        Rows of the observation table (``env.config.top_k``).
    min_weight : float
        PHD components below this weight are ignored.
    avoid_distance_m : float
        Lidar returns closer than this push the robot away (obstacles and teammates alike).
    avoid_gain : float
        Strength of that push (m/s at contact).
    heading_gain : float
        ``omega = heading_gain * heading error``.
    deadband_mps : float
        ``|u|`` below this is treated as "arrived": the robot stops (no dithering on noise).
    sensing_model : PHDConfig or None
        With a filter config (``for_env(..., sensing_turn=True)`` passes ``env.config.phd``),
        an arrived robot turns in place (:meth:`sensing_turn`) so that its lidar's blind
        sectors, as that config models them, cover the fewest of its estimated teammates.
        ``None`` (default): it stands still.
    sensing_margin : float
        The turn must gain at least this many expected lidar detections per scan over the
        current heading (>= 0; hysteresis: no turning back and forth on noise).
    restart_mps : float or None
        Arrival hysteresis: a robot that has stopped (``|u|`` below ``deadband_mps``) moves
        again only once its desired velocity's ``|u|`` reaches this (> ``deadband_mps``), or
        as soon as the lidar pushes it away from something (avoidance is never held).
        ``None`` (default): it moves again at ``deadband_mps``. Why: a correction just above
        the deadband that points sideways turns a differential drive at up to
        ``max_turn_rate_radps``, so a robot that chases its centroid estimate's noise keeps
        turning, and its lidar's blind sectors sweep over its teammates (measured with
        ``experiments/formation_diagnosis.py``). The stopped state is the controller's own
        history: a residual policy on top
        of it does not see it.
    """

    observation_modes = ("phd", "truth")
    #: The task a subclass is written for: :meth:`for_env` refuses an env with another one.
    task: str | None = None

    def __init__(
        self,
        *,
        top_k: int = 16,
        min_weight: float = 0.5,
        avoid_distance_m: float = 0.3,
        avoid_gain: float = 0.3,
        heading_gain: float = 2.0,
        deadband_mps: float = 0.02,
        seed: int | None = 0,
        n_sectors: int = 0,
        sensing_model: PHDConfig | None = None,
        sensing_margin: float = 0.2,
        restart_mps: float | None = None,
        **limits: float,
    ) -> None:
        if sensing_model is not None and not isinstance(sensing_model, PHDConfig):
            raise TypeError(
                f"sensing_model must be a PHDConfig or None, got {type(sensing_model).__name__}"
            )
        if not (np.isfinite(sensing_margin) and sensing_margin >= 0.0):
            raise ValueError(f"sensing_margin must be finite and >= 0, got {sensing_margin}")
        if restart_mps is not None and not (
            isinstance(restart_mps, (int, float))
            and not isinstance(restart_mps, bool)
            and np.isfinite(restart_mps)
            and deadband_mps < restart_mps
        ):
            raise ValueError(
                f"restart_mps must be None or a finite number > deadband_mps={deadband_mps}, "
                f"got {restart_mps!r}"
            )
        self.restart_mps = restart_mps
        super().__init__(**limits)
        self.sensing_model = sensing_model
        self.sensing_margin = sensing_margin
        self._sensing_detection = None if sensing_model is None else DetectionModel(sensing_model)
        self.top_k = top_k
        self.n_sectors = n_sectors  # lidar sector table in the observation (skipped)
        self.min_weight = min_weight
        self.avoid_distance_m = avoid_distance_m
        self.avoid_gain = avoid_gain
        self.heading_gain = heading_gain
        self.deadband_mps = deadband_mps
        self._seed = seed
        self.reset(seed)

    @classmethod
    def for_env(cls, env: Any, sensing_turn: bool = False, **kwargs: Any) -> ScriptedPolicy:
        """The controller for ``env``; ``sensing_turn``: arrived robots turn their lidar's
        blind sectors off their teammates, as ``env.config.phd`` models them."""
        if cls.task is not None and env.task.name != cls.task:
            raise ValueError(f"scripted:{cls.name} needs task={cls.task!r}, got {env.task.name!r}")
        if sensing_turn:
            kwargs.setdefault("sensing_model", env.config.phd)
        mode = env.config.observation
        if mode not in cls.observation_modes:
            raise ValueError(
                f"scripted:{cls.name} reads the PHD table: it needs "
                f"observation='phd' (or 'truth'), the env has {mode!r}"
            )
        kwargs.setdefault("n_sectors", env.config.lidar_sectors)
        return super().for_env(env, top_k=env.config.top_k, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        seed = self._seed if seed is None else seed
        self._rng = np.random.default_rng(seed)
        self._scan: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._wander = WanderPolicy(
            max_speed_mps=self.max_speed_mps,
            max_turn_rate_radps=self.max_turn_rate_radps,
            seed=seed,
        )
        self.wandering = set()
        self._stopped: set[str] = set()  # agents that arrived and have not moved since

    def __call__(self, observations, infos):
        actions = {}
        self.wandering = set()
        for agent, obs in observations.items():
            scan = latest_scan(infos.get(agent, {}) if infos else {})
            if scan is not None:
                self._scan[agent] = scan
                self._wander._scan[agent] = scan
            table, odometry, features = split_observation(obs, self.top_k, self.n_sectors)
            u = self.desired_velocity(agent, table, odometry, features)
            if u is None:  # nothing to act on: search (Perera 2021's random walk)
                actions[agent] = self._wander._act(agent)
                self.wandering.add(agent)
                self._stopped.discard(agent)
                continue
            push = self.avoidance(self._scan.get(agent))
            holding = (
                self.restart_mps is not None
                and agent in self._stopped
                and np.linalg.norm(u) < self.restart_mps
                and not push.any()  # obstacle avoidance is never held back
            )
            u = u + push
            actions[agent] = np.zeros(2, dtype=np.float32) if holding else self.to_unicycle(u)
            if actions[agent].any():
                self._stopped.discard(agent)
            else:
                self._stopped.add(agent)
            if self.sensing_model is not None and not actions[agent].any():
                actions[agent] = self.sensing_turn(table)
        return actions

    def sensing_turn(self, table: np.ndarray) -> np.ndarray:
        """``[0, omega]`` turning in place towards the heading, within +-90 deg, at which the
        lidar would detect the most estimated teammates per scan
        (:func:`expected_lidar_detections`), if it gains ``sensing_margin`` detections over the
        current heading; else ``[0, 0]``. +-90 deg reaches every heading of a sector layout
        that repeats every 180 deg (the Perera 2021 study's +-45, +-135 deg); an asymmetric layout
        can have its best heading beyond it.

        Why: the lidar is blind behind the four camera pillars (+-45, +-135 deg), exactly where
        a robot that drove radially into a square formation sees its two neighbours; it then
        holds them by bearing alone, and loses them (``experiments/formation_diagnosis.py``)."""
        rows = table[confident_rows(table, self.min_weight)]
        stop = np.zeros(2, dtype=np.float32)
        if not len(rows):
            return stop
        # Each teammate's own bearing uncertainty: a turn that leaves it just past a notch
        # edge it may really be inside gains less than one that clears it.
        gain = expected_lidar_detections(
            rows[:, [_X, _Y]],
            rows[:, _W],
            _SENSING_TURNS_RAD,
            self._sensing_detection,
            bearing_std(rows),
        )
        # Prefer the smallest turn among near-equal ones (0.01 detections per radian).
        best = int(np.argmax(gain - 0.01 * np.abs(_SENSING_TURNS_RAD)))
        if gain[best] - gain[_SENSING_NO_TURN] < self.sensing_margin:
            return stop
        omega = self.heading_gain * _SENSING_TURNS_RAD[best]
        return np.array(
            [0.0, np.clip(omega, -self.max_turn_rate_radps, self.max_turn_rate_radps)],
            dtype=np.float32,
        )

    def desired_velocity(
        self, agent: str, table: np.ndarray, odometry: np.ndarray, features: np.ndarray
    ) -> np.ndarray | None:
        """Desired body-frame velocity (2,), or ``None`` to random-walk (e.g. nobody seen)."""
        raise NotImplementedError

    def avoidance(self, scan: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        """Sum of pushes away from lidar returns closer than ``avoid_distance_m``, (2,)."""
        pts = lidar_points(scan, self.avoid_distance_m)
        if not len(pts):
            return np.zeros(2)
        d = np.linalg.norm(pts, axis=1)
        push = (self.avoid_distance_m - d) / self.avoid_distance_m
        # Average over returns (one obstacle gives many beams), scaled by the closest one.
        direction = -(pts / d[:, None] * push[:, None]).sum(axis=0)
        norm = np.linalg.norm(direction)
        return np.zeros(2) if norm < 1e-9 else self.avoid_gain * push.max() * direction / norm

    def to_unicycle(self, u: np.ndarray) -> np.ndarray:
        """Body-frame velocity ``u`` -> ``[v, omega]``: drive along ``u`` projected on the
        heading, turn the nearer end (front or back) towards ``u``."""
        speed = float(np.linalg.norm(u))
        if speed < self.deadband_mps:
            return np.zeros(2, dtype=np.float32)
        angle = float(np.arctan2(u[1], u[0]))
        turn = angle if abs(angle) <= np.pi / 2 else float(wrap_angle(angle - np.pi))
        v = np.clip(u[0], -self.max_speed_mps, self.max_speed_mps)
        omega = np.clip(
            self.heading_gain * turn, -self.max_turn_rate_radps, self.max_turn_rate_radps
        )
        return np.array([v, omega], dtype=np.float32)

    def _clip_speed(self, u: np.ndarray) -> np.ndarray:
        speed = np.linalg.norm(u)
        return u if speed <= self.max_speed_mps else u * (self.max_speed_mps / speed)


class FormationPolicy(VectorFieldPolicy):
    """Formation from the robot's own PHD estimate (task ``formation``).

    Circle (the Stegagno 2013 study's T4): the centroid of the swarm as this robot sees it is
    ``c = sum_k w_k m_k / (1 + sum_k w_k)`` over its confident components ``(w_k, m_k)`` plus
    itself (weight 1 at its origin); ``w_k`` is discounted by the component's spread (see
    :func:`estimated_neighbours`, reference variance 0.02 m^2) so that a camera-only track with
    a drifting range does not drag the centroid. The robot heads for the closest point of the
    circle of radius ``r`` around ``c`` (``c + r (-c) / ||c||``, gain ``k_p``) and is pushed
    away from estimated neighbours closer than the even-spread chord ``s*`` (gain ``k_s``).
    With ``pull_far`` it is also pulled towards those farther than the diameter ``2 r``. That
    rule is off by default: the components beyond the lidar's ~2 m are camera-only, and since
    the lidar extractor rejects red decoys (``LidarFeatureConfig.extent_test``) a red decoy's
    camera track sits along its ray at 2-4 m as often as a far teammate does. Measured with
    ``experiments/formation_diagnosis.py``: on ``lab-3m-4`` validation seeds the pull raised the
    formation error from 0.086 to 0.162 m.
    With ``swarm_size_centroid`` the swarm size N (from the features, below) rescales the
    weights: once at least N - 1 confident components are in sight and their weights sum to
    less than N - 1, they are scaled to sum to N - 1, so ``c = (N - 1) / N`` times their
    weighted mean. Why: a PHD weight is not an existence probability of 1 for a teammate the
    robot has in sight; measured on the validation seeds, three confident components' weights
    sum to 2.4 after the spread discount, which shrinks ``c`` towards the robot by about 6 % and
    parks it about 4 cm outside the circle (``experiments/formation_diagnosis.py``). The rescale
    keeps the
    weights' relative say (a camera-only track still counts less than a lidar-confirmed one).
    Off by default, so that the registered ``scripted:formation`` keeps its measured behaviour;
    the ``*-known-n`` controllers turn it on.
    Lattice: a spring to every estimated neighbour within ``1.5 d`` (and to the nearest one):
    ``u = k_p sum_k (||m_k|| - d) m_k / ||m_k||``.

    ``r``, ``s*`` (circle) and ``d`` (lattice) come from the task features in the observation,
    the shape from the mission (``shape=``). The chord also encodes the swarm size N; while the
    robot estimates fewer than N - 1 teammates its centroid is only a local one, so it first
    closes in on it (up to ``r / 2``). With fewer than ``min_neighbours`` estimated the robot
    random-walks (the Perera 2021 study's wander) until it finds the swarm.
    """

    name = "formation"
    task = "formation"

    def __init__(
        self,
        *,
        shape: str = "circle",
        k_p: float = 0.8,
        k_s: float = 0.6,
        min_neighbours: int = 1,
        pull_far: bool = False,
        swarm_size_centroid: bool = False,
        **kwargs: Any,
    ) -> None:
        if shape not in ("circle", "lattice"):
            raise ValueError(f"shape must be 'circle' or 'lattice', got {shape!r}")
        self.shape = shape
        self.pull_far = pull_far
        if not isinstance(swarm_size_centroid, bool):
            raise TypeError(f"swarm_size_centroid must be a bool, got {swarm_size_centroid!r}")
        self.swarm_size_centroid = swarm_size_centroid
        self.k_p = k_p
        self.k_s = k_s
        self.min_neighbours = min_neighbours
        super().__init__(**kwargs)

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any) -> ScriptedPolicy:
        if env.task.name == cls.task:
            kwargs.setdefault("shape", env.task.shape)
        return super().for_env(env, **kwargs)

    def centroid(
        self, points: np.ndarray, weights: np.ndarray, features: np.ndarray
    ) -> np.ndarray:
        """The centroid (2,) this controller steers around (circle): :func:`estimated_centroid`
        of the confident components ``points`` (M, 2), ``weights`` (M,), with the swarm size
        from the circle ``features`` ``[r, s*]`` if ``swarm_size_centroid``."""
        if not self.swarm_size_centroid:
            return estimated_centroid(points, weights)
        n_swarm = expected_count(float(features[0]), float(features[1]))
        return estimated_centroid(points, weights, n_swarm)

    def desired_velocity(self, agent, table, odometry, features):
        pts, w = estimated_neighbours(table, self.min_weight, reference_variance_m2=0.02)
        if len(pts) < self.min_neighbours:
            return None
        d = np.linalg.norm(pts, axis=1)
        if self.shape == "circle":
            radius, chord = float(features[0]), float(features[1])
            c = self.centroid(pts, w, features)
            dc = np.linalg.norm(c)
            if len(pts) + 1 < expected_count(radius, chord) and dc > 0.5 * radius:
                # Not everyone in sight: this centroid is only a local one. Close in first.
                return self._clip_speed(self.k_p * c)
            away = -c / dc if dc > 1e-6 else np.array([1.0, 0.0])
            u = self.k_p * (c + radius * away)
            close = (d < chord) & (d > 1e-6)
            push = (chord - d[close]) / d[close]
            u -= self.k_s * (push[:, None] * pts[close]).sum(axis=0)
            if self.pull_far:
                # Nobody on the circle is farther than its diameter: pull towards anyone beyond
                # it, whatever the centroid estimate is (but a camera ghost pulls too).
                far = d > 2.0 * radius
                pull = (d[far] - 2.0 * radius) / d[far]
                u += self.k_s * (pull[:, None] * pts[far]).sum(axis=0)
        else:
            spacing = float(features[0])
            near = d < 1.5 * spacing
            near[np.argmin(d)] = True
            u = self.k_p * (
                ((d[near] - spacing) / np.maximum(d[near], 1e-6))[:, None] * pts[near]
            ).sum(axis=0)
        return self._clip_speed(u)


class DispersionPolicy(VectorFieldPolicy):
    """Exploration by dispersion from the robot's own PHD estimate (task ``exploration``).

    Potential-field deployment (Howard, Mataric & Sukhatme 2002): each confident neighbour
    estimate ``(w_k, m_k)`` closer than ``spread_m`` pushes the robot away,
    ``u = cruise [1, 0] - k_s sum_k w_k (spread - d_k) / spread * m_k / d_k``, with ``w_k``
    discounted by the component's spread as in :class:`FormationPolicy`. The cruise term keeps
    a spread-out swarm sweeping new cells; the lidar pushes it off walls and obstacles (the base
    class). With nobody estimated within ``spread_m`` it random-walks (the Perera 2021 study's
    wander), which is what a lone robot can do without a map. The robot never needs its own global
    position.
    """

    name = "exploration"
    task = "exploration"

    def __init__(
        self,
        *,
        spread_m: float = 1.5,
        k_s: float = 0.4,
        cruise_fraction: float = 0.6,
        **kwargs: Any,
    ) -> None:
        check_positive("spread_m", spread_m)
        check_positive("k_s", k_s)
        check_number("cruise_fraction", cruise_fraction, low=0, high=1)
        self.spread_m = float(spread_m)
        self.k_s = float(k_s)
        self.cruise_fraction = float(cruise_fraction)
        super().__init__(**kwargs)

    def desired_velocity(self, agent, table, odometry, features):
        pts, w = estimated_neighbours(table, self.min_weight, reference_variance_m2=0.02)
        d = np.linalg.norm(pts, axis=1) if len(pts) else np.zeros(0)
        near = (d < self.spread_m) & (d > 1e-6)
        if not near.any():
            return None
        push = w[near] * (self.spread_m - d[near]) / self.spread_m
        u = np.array([self.cruise_fraction * self.max_speed_mps, 0.0])
        u -= self.k_s * ((push / d[near])[:, None] * pts[near]).sum(axis=0)
        return self._clip_speed(u)


def expected_count(radius_m: float, chord_m: float) -> int:
    """Swarm size N implied by the circle features ``[r, s* = 2 r sin(pi / N)]``."""
    ratio = chord_m / (2.0 * radius_m) if radius_m > 0 else 0.0
    if not 0.0 < ratio <= 1.0:
        return 1
    return int(round(np.pi / np.arcsin(ratio)))


class EncirclementPolicy(VectorFieldPolicy):
    """Enclose the intruder (task ``encirclement``) on a circle of radius ``r``, evenly spread.

    Where the intruder's position ``q`` (body frame) comes from is the task's
    ``intruder_source`` (Lee 2012; :mod:`swarm_env.tasks.encirclement`):

    - ``"beacon"`` (ablation): the beacon features ``[r, valid, cos b, sin b, rho]`` of this
      step, refined by the nearest confident PHD component within ``gate_m`` (the PHD is more
      precise; the beacon says which component is the intruder). While ``valid`` is 0 (no
      reading, e.g. real robots without motion capture) nothing says where the intruder is: the
      robot random-walks, as with nobody in sight.
    - ``"particle"``: the Lee 2012 study's particle filter
      (:class:`localization.baselines.particle.ParticleFilterTracker`, one per robot, in its body
      frame), predicted every step with the robot's own odometry ``[v, omega]`` and updated with
      each range-bearing reading when one arrives (``valid`` = 1); ``q`` is its estimate. The
      filter starts at the first reading (the Lee 2012 study's uniform cloud weighted by it), or
      with ``particle_start="trilateration"`` (the task's) at its polar fix; a range-only reading
      (``cos b = sin b = 0``) has a NaN bearing, and a trilateration start waits for >= 3
      spread readings (random walk until then). With the
      task's ``intruder_features="filter"`` the features already are such a filter's estimate
      (the task runs it): ``q`` is read from them (``task_filter=True``), as a learned policy
      reads it.
    - ``"estimate"``: the robot's own PHD estimate. The first reading (the task gives one, at
      reset) picks the component; after that ``q`` is propagated with the robot's odometry and
      snapped to the nearest confident component within ``gate_m``; after ``lost_after_s``
      without one the track is dropped and the robot random-walks.

    Radial term: ``k_p (||q|| - r) q / ||q||``. Tangential term: with ``g+``/``g-`` the angular
    gaps (seen from ``q``) to the nearest estimated teammates counter-clockwise and clockwise,
    ``k_t r (g+ - g-) / 2`` along the counter-clockwise tangent, which evens the gaps out (the
    classic cyclic spreading law). Teammates are the confident PHD components, less the one
    within ``gate_m`` of ``q`` (the intruder).
    """

    name = "encirclement"
    task = "encirclement"
    sources = ("beacon", "particle", "estimate")

    def __init__(
        self,
        *,
        k_p: float = 0.8,
        k_t: float = 0.4,
        gate_m: float = 0.4,
        intruder_source: str = "beacon",
        control_period_s: float = 0.1,
        reading_range_std_m: float = 0.05,
        reading_bearing_std_rad: float = float(np.radians(5.0)),
        n_particles: int = 300,
        lost_after_s: float = 3.0,
        task_filter: bool = False,
        particle_start: str = "uniform",
        **kwargs: Any,
    ) -> None:
        if intruder_source not in self.sources:
            raise ValueError(
                f"intruder_source must be one of {self.sources}, got {intruder_source!r}"
            )
        if not (np.isfinite(control_period_s) and control_period_s > 0):
            raise ValueError(f"control_period_s must be > 0, got {control_period_s!r}")
        self.k_p = k_p
        self.k_t = k_t
        self.gate_m = gate_m
        self.intruder_source = intruder_source
        self.control_period_s = float(control_period_s)
        self.reading_range_std_m = reading_range_std_m
        self.reading_bearing_std_rad = reading_bearing_std_rad
        self.n_particles = n_particles
        self.lost_after_s = lost_after_s
        self.task_filter = bool(task_filter)
        if particle_start not in ("uniform", "trilateration"):
            raise ValueError(
                f"particle_start must be 'uniform' or 'trilateration', got {particle_start!r}"
            )
        self.particle_start = particle_start
        super().__init__(**kwargs)

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any) -> ScriptedPolicy:
        task = env.task
        if task.name != "encirclement" or not task.beacon:
            raise ValueError(
                "scripted:encirclement needs task='encirclement' with beacon=True "
                "(anonymous detections alone do not say which robot is the "
                "intruder)"
            )
        kwargs.setdefault("intruder_source", getattr(task, "intruder_source", "beacon"))
        kwargs.setdefault("control_period_s", env.config.control_period_s)
        kwargs.setdefault("reading_range_std_m", max(task.beacon_range_std_m, 1e-3))
        kwargs.setdefault("reading_bearing_std_rad", max(task.beacon_bearing_std_rad, 1e-3))
        kwargs.setdefault("task_filter", getattr(task, "intruder_features", "reading") == "filter")
        kwargs.setdefault("particle_start", getattr(task, "particle_start", "uniform"))
        return super().for_env(env, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._episode_seed = int((self._seed if seed is None else seed) or 0)
        self._filters: dict[str, Any] = {}  # "particle": agent -> ParticleFilterTracker
        self._track: dict[str, np.ndarray] = {}  # "estimate": agent -> q (2,)
        self._unseen_s: dict[str, float] = {}

    def intruder_estimate(self, agent: str) -> np.ndarray | None:
        """The intruder's position (2,) in ``agent``'s body frame the controller last used for
        ``"particle"`` / ``"estimate"``, or ``None`` (no track)."""
        if self.intruder_source == "particle" and self.task_filter:
            return None  # the task's filter: read it from the task (intruder_estimates)
        if self.intruder_source == "particle":
            pf = self._filters.get(agent)
            return None if pf is None or not pf.ids else pf.estimate()[0]
        q = self._track.get(agent)
        return None if q is None else q.copy()

    def _increment(self, odometry: np.ndarray) -> np.ndarray:
        """Own motion ``(dx, dy, dpsi)`` over one control period from ``[v, omega]`` (an arc)."""
        v, w = float(odometry[0]), float(odometry[1])
        dt = self.control_period_s
        if abs(w) < 1e-9:
            return np.array([v * dt, 0.0, 0.0])
        return np.array([v * np.sin(w * dt) / w, v * (1.0 - np.cos(w * dt)) / w, w * dt])

    def _particle_q(self, agent: str, odometry, valid: bool, reading) -> np.ndarray | None:
        from localization.baselines.particle import ParticleFilterTracker

        pf = self._filters.get(agent)
        if pf is None:
            if not valid:
                return None  # no reading yet: nothing to start the filter from
            seed = abs(self._episode_seed) * 1000 + len(self._filters)  # one stream per robot
            pf = self._filters[agent] = ParticleFilterTracker(
                n_particles=self.n_particles,
                range_std_m=self.reading_range_std_m,
                bearing_std_rad=self.reading_bearing_std_rad,
                period_s=self.control_period_s,
                seed=seed,
                start=self.particle_start,
            )
        else:
            pf.predict(self._increment(odometry))
        if valid:
            pf.update({0: reading})
        return pf.estimate()[0] if pf.ids else None  # range-only: no fix yet

    def _nearest_in_gate(self, pts: np.ndarray, q: np.ndarray) -> int | None:
        """Row of ``pts`` (K, 2) m nearest to ``q`` (2,) m if nearer than ``gate_m``, else None."""
        if not len(pts):
            return None
        gap = np.linalg.norm(pts - q, axis=1)
        k = int(np.argmin(gap))
        return k if gap[k] < self.gate_m else None

    def _estimate_q(self, agent: str, odometry, valid: bool, q_cue, pts) -> np.ndarray | None:
        q = self._track.get(agent)
        if valid:
            q = q_cue
        elif q is not None:
            inc = self._increment(odometry)
            c, s = np.cos(inc[2]), np.sin(inc[2])
            d = q - inc[:2]
            q = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
        if q is None:
            return None
        k = self._nearest_in_gate(pts, q)
        if k is not None:
            self._unseen_s[agent] = 0.0
            self._track[agent] = pts[k].copy()
            return pts[k].copy()
        self._unseen_s[agent] = self._unseen_s.get(agent, 0.0) + self.control_period_s
        if self._unseen_s[agent] > self.lost_after_s:
            self._track.pop(agent, None)
            return None
        self._track[agent] = q
        return q

    def desired_velocity(self, agent, table, odometry, features):
        radius, valid, cos_b, sin_b, rho = (float(x) for x in features[:5])
        has_reading = valid >= 0.5
        pts, w = estimated_neighbours(table, self.min_weight)
        if self.intruder_source == "particle" and self.task_filter:
            q = rho * np.array([cos_b, sin_b]) if has_reading else None  # the task's filter
        elif self.intruder_source == "particle":
            # (cos b, sin b) = (0, 0): a range-only reading (intruder_sensing="range")
            bearing = np.nan if cos_b == 0.0 and sin_b == 0.0 else np.arctan2(sin_b, cos_b)
            q = self._particle_q(agent, odometry, has_reading, (rho, bearing))
        elif self.intruder_source == "estimate":
            q = self._estimate_q(agent, odometry, has_reading, rho * np.array([cos_b, sin_b]), pts)
        else:
            # no beacon reading: rho = 0 would put the intruder on this robot
            q = rho * np.array([cos_b, sin_b]) if has_reading else None
        if q is None:
            return None
        k = self._nearest_in_gate(pts, q)
        if k is not None:
            if self.intruder_source == "beacon":
                q = pts[k]
            pts = np.delete(pts, k, axis=0)
        dq = float(np.linalg.norm(q))
        if dq < 1e-6:
            return np.zeros(2)
        u = self.k_p * (dq - radius) * q / dq
        if len(pts):
            own = np.arctan2(-q[1], -q[0])
            rel = np.arctan2(pts[:, 1] - q[1], pts[:, 0] - q[0])
            ahead = np.mod(rel - own, 2 * np.pi)  # counter-clockwise angle to each teammate
            ahead = ahead[(ahead > 1e-3) & (ahead < 2 * np.pi - 1e-3)]
            if len(ahead):
                g_ccw, g_cw = float(ahead.min()), float(2 * np.pi - ahead.max())
                tangent = np.array([q[1], -q[0]]) / dq  # ccw tangent at our position around q
                u = u + self.k_t * radius * 0.5 * (g_ccw - g_cw) * tangent
        return self._clip_speed(u)


def symmetry_metric(points: np.ndarray, phis: np.ndarray) -> np.ndarray:
    """The thesis' symmetry metric ``gamma_Z(phi) = sum_z min_z'' ||z - z''||^2`` with ``z''`` in
    Z rotated by ``phi`` about its centroid (Stegagno 2012, chapter 12), for every ``phi``."""
    c = points.mean(axis=0)
    z = points - c
    cos, sin = np.cos(phis), np.sin(phis)
    rot = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)  # (A, 2, 2)
    rotated = np.einsum("aij,nj->ani", rot, z)  # (A, n, 2)
    d2 = ((z[None, :, None, :] - rotated[:, None, :, :]) ** 2).sum(-1)  # (A, n, n)
    return d2.min(axis=2).sum(axis=1)


def internal_minimum(points: np.ndarray, n_angles: int = 360) -> tuple[float, float]:
    """``(phi_bar, gamma_min)``: the minimiser and value of ``gamma_Z`` between its first rise
    and its final fall (Proposition 6); ``gamma_min = 0`` iff Z is rotationally symmetric."""
    phis = np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False)
    gamma = symmetry_metric(points, phis)
    i1 = 1
    while i1 < n_angles - 1 and gamma[i1 + 1] >= gamma[i1]:
        i1 += 1
    i2 = n_angles - 1
    while i2 > i1 and gamma[i2 - 1] >= gamma[i2]:
        i2 -= 1
    k = i1 + int(np.argmin(gamma[i1 : i2 + 1]))
    return float(phis[k]), float(gamma[k])


class AntiSymmetryPolicy(VectorFieldPolicy):
    """The anti-symmetry control law (Stegagno 2012, chapter 12, eq. 46), robot-centric.

    Each robot takes ``Z`` = its confident PHD components plus itself (the origin), finds the
    rotation ``phi_bar`` about the centroid that minimises ``gamma_Z`` inside
    ``[phi_1, phi_2]``, and moves at ``alpha`` m/s away from ``z_bar``, its closest point in
    ``Z`` rotated by ``phi_bar`` (which raises ``gamma_Z(phi_bar)``: the formation moves away from
    rotational symmetry, the configuration in which anonymous measurements are ambiguous). When
    ``z_bar`` coincides with the robot (the law is undefined) it moves in a random direction.
    Once ``gamma_min / |Z|`` exceeds ``gamma_stop_m2`` the robot stops (symmetry broken enough);
    ``None`` never stops. With fewer than two neighbours estimated it waits.
    """

    name = "anti-symmetry"

    def __init__(
        self,
        *,
        alpha_mps: float = 0.1,
        gamma_stop_m2: float | None = 0.04,
        n_angles: int = 180,
        **kwargs: Any,
    ) -> None:
        self.alpha_mps = alpha_mps
        self.gamma_stop_m2 = gamma_stop_m2
        self.n_angles = n_angles
        super().__init__(**kwargs)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._random_dir: dict[str, np.ndarray] = {}

    def desired_velocity(self, agent, table, odometry, features):
        pts, _ = estimated_neighbours(table, self.min_weight)
        if len(pts) < 2:
            return np.zeros(2)
        z = np.vstack([np.zeros((1, 2)), pts])
        phi, gamma_min = internal_minimum(z, self.n_angles)
        if self.gamma_stop_m2 is not None and gamma_min / len(z) >= self.gamma_stop_m2:
            return np.zeros(2)
        c = z.mean(axis=0)
        rot = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
        rotated = (z - c) @ rot.T + c
        z_bar = rotated[np.argmin(np.linalg.norm(rotated, axis=1))]
        dist = float(np.linalg.norm(z_bar))
        if dist < 1e-3:
            if agent not in self._random_dir:
                a = self._rng.uniform(-np.pi, np.pi)
                self._random_dir[agent] = np.array([np.cos(a), np.sin(a)])
            return self.alpha_mps * self._random_dir[agent]
        self._random_dir.pop(agent, None)
        return -self.alpha_mps * z_bar / dist
