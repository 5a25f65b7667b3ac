"""The P-MultiBeaReg system of one observer (Stegagno 2012 chapter 10, Fig. 33).

As :class:`~localization.mutual.pmultireg.PMultiRegLocalizer`, with bearings instead of
positions: every ``update_period_s`` the observer's bearings and those of the teammates whose set
is within ``max_skew_s`` of its own go to :func:`~localization.mutual.beareg.bearing_solutions`;
each teammate's distinct bearing-orientations ``xi = (bearing, theta)`` pass the fitness test
(eq. 18 at the scale that maximises it, :meth:`TeammateParticles.scale_search`; relative drop
and an absolute gate, as in P-MultiReg) and update its particle filter (eq. 19). The filter is
the same (motion from both robots' odometry); its first particles lie on the hypotheses' rays at
ranges uniform in ``range_m``, re-seeded ones at eq. 18's scale, and the range becomes
observable as the robots move (the thesis's "circular sectors", Fig. 35).

The bearings are the camera's (default): the observer's newest frame and each teammate's newest
broadcast frame (``Broadcast.bearings_rad``), red blobs of teammates' strips and red decoys,
with misses and false blobs. The camera sits at the body origin (no mount parallax); its frames
(30 Hz) fall between odometry samples, so each set's rotation to the filters' instants is taken
from the odometry track interpolated at the frame's stamp; the translation over that gap is not
compensated (the scale is unknown at registration) and is part of the model's 2 deg time-gap
term. ``features="lidar"`` uses the lidar detections' bearings instead (the thesis's
experiment made its bearing detector that way; this project's first figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm_core.geometry import wrap_angle
from swarm_core.records import RobotMeasurements

from .beareg import bearing_solutions
from .particles import MotionNoise, TeammateParticles
from .pmultireg import _ScheduledRegistrar, check_registrar_config

__all__ = ["PMultiBeaRegConfig", "PMultiBeaRegLocalizer"]


#: Per feature source, the noise the measurement model and the triangle test assume (deg) and
#: the ranges a teammate can be seen at (m), from the sensors' measured statistics
#: (docs/concepts/sensors.md, RESULTS "Sensor detection curves"). Each bearing's std is the
#: sensor's
#: bearing noise plus 2 deg for the sets' time gap (the radio's latency and the sensors'
#: periods; the rotation is compensated, the translation cannot be: 1.5 cm at 1 m is 0.9 deg);
#: the orientation combines two bearings (sqrt 2 x); the triangle tolerance is 2 x the bearing
#: std (a sum of three differences of such bearings, at about 1.2 sigma).
#: lidar: a detection's centre error 0.03 m is 1.7 deg at 1 m; robot detections to 2.5 m.
#: camera: the red-blob bearing RMS 0.45 deg (all ranges; 0.96 deg at 0.5 m); a 5 cm strip
#: is detected to 4.7 m.
FEATURE_MODELS: dict[str, dict[str, object]] = {
    "lidar": {
        "triangle_tol_deg": 6.0,
        "bearing_std_deg": 3.0,
        "orientation_std_deg": 4.0,
        "range_m": (0.2, 2.5),
    },
    "camera": {
        "triangle_tol_deg": 5.0,
        "bearing_std_deg": 2.5,
        "orientation_std_deg": 3.5,
        "range_m": (0.2, 4.7),
    },
}


@dataclass(frozen=True, slots=True)
class PMultiBeaRegConfig:
    """Parameters of the bearing-only system.

    Attributes
    ----------
    n_particles : int
        Per teammate (the thesis ran 500).
    features : str
        ``"camera"`` (default): the red-blob bearings of the observer's camera frames and of
        the teammates' broadcast frames (``Broadcast.bearings_rad``). ``"lidar"``: the bearings
        of the lidar detections, own and broadcast (how the thesis's experiment built its
        bearing detector, and this project's first figures).
    scale_search : bool
        Eq. 18 with each hypothesis's scale chosen to maximise it (the thesis's, default), used
        in the fitness test and to place re-seeded particles; ``False``: the scale-free test and
        re-seeded ranges drawn from the belief (the first figures: ``features="lidar",
        scale_search=False`` reproduces them).
    triangle_tol_deg : float, optional
        Tolerance on the triangles' angle sum and on the 3-intersections; ``None``: the
        feature source's (:data:`FEATURE_MODELS`).
    bearing_std_deg, orientation_std_deg : float, optional
        Measurement model (eq. 19); ``None``: the feature source's.
    range_m : tuple of 2 floats, optional
        Ranges of the first particles along a ray and the scale search's span (the sensor's
        robot-detection range); ``None``: the feature source's.
    """

    n_particles: int = 500
    update_period_s: float = 0.5
    max_skew_s: float = 0.3
    reseed_fraction: float = 0.05
    features: str = "camera"
    scale_search: bool = True
    triangle_tol_deg: float | None = None
    bearing_std_deg: float | None = None
    orientation_std_deg: float | None = None
    range_m: tuple[float, float] | None = None
    gate_mahalanobis2: float = 25.0
    lost_after: int = 6
    log_fitness_drop: float = math.log(100.0)
    motion_noise: MotionNoise = field(default_factory=MotionNoise)

    def __post_init__(self) -> None:
        if self.features not in FEATURE_MODELS:
            raise ValueError(
                f"features must be one of {sorted(FEATURE_MODELS)}, got {self.features!r}"
            )
        if not isinstance(self.scale_search, bool):
            raise ValueError(f"scale_search must be a bool, got {self.scale_search!r}")
        for name, value in FEATURE_MODELS[self.features].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        check_registrar_config(
            self,
            ("triangle_tol_deg", "bearing_std_deg", "orientation_std_deg", "log_fitness_drop"),
        )
        r = self.range_m
        if not (
            isinstance(r, (tuple, list))
            and len(r) == 2
            and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in r
            )
            and 0.0 < r[0] < r[1]
        ):
            raise ValueError(f"range_m must be 2 finite numbers 0 < low < high, got {r!r}")
        n_scales = scale_grid(r, math.radians(self.bearing_std_deg)).shape[0]
        if self.scale_search and n_scales > MAX_SCALES:
            # Eq. 18's search holds particles x hypotheses x scales values at once.
            raise ValueError(
                f"bearing_std_deg={self.bearing_std_deg} over range_m={r!r} needs {n_scales} "
                f"scales for eq. 18's search, more than {MAX_SCALES}: widen the bearing noise"
            )


#: Most scales eq. 18's search may test (a bearing std of ~0.36 deg over 0.2-4.7 m; the
#: camera's model needs ~150).
MAX_SCALES = 1000


def scale_grid(range_m: tuple[float, float], bearing_std_rad: float) -> np.ndarray:
    """Eq. 18's scale grid (m): geometric, half the model's relative spread ``s_b`` apart (a
    bearing's position std at range ``r`` is ``r s_b``), over ``range_m``."""
    step = 1.0 + 0.5 * bearing_std_rad
    n_grid = int(math.ceil(math.log(range_m[1] / range_m[0]) / math.log(step))) + 1
    return range_m[0] * step ** np.arange(n_grid)


class PMultiBeaRegLocalizer(_ScheduledRegistrar):
    """P-MultiBeaReg plus one particle filter per teammate, for one observer."""

    name = "p-multibeareg"
    config_type = PMultiBeaRegConfig

    def _init_filters(self) -> None:
        cfg = self.config
        self.filters = {
            t: TeammateParticles(
                cfg.n_particles, cfg.motion_noise, np.full(3, 1e-3), cfg.reseed_fraction, self.rng
            )
            for t in self.teammates
        }
        self._rejections = {t: 0 for t in self.teammates}
        self._own = np.zeros(0)
        self._std = np.radians([cfg.bearing_std_deg, cfg.orientation_std_deg])
        self._scales = scale_grid(cfg.range_m, float(self._std[0]))
        self.last_hypotheses: dict[str, np.ndarray] = {}
        self.n_registrations = 0

    def _own_set(self, detections: np.ndarray) -> np.ndarray:
        """What the registration uses of the observer's latest detections (M, 2): bearings (M,)."""
        return np.arctan2(detections[:, 1], detections[:, 0])

    def _absorb_own(self, measurements: RobotMeasurements) -> None:
        """Keep the observer's latest bearing set and its stamp: its newest camera frame (the
        camera sits at the body origin, so its bearings are body-frame ones), or its newest
        scan's detections' bearings with ``features="lidar"``."""
        if self.config.features == "camera":
            if measurements.camera:
                frame = measurements.camera[-1]
                self._own = np.array(frame.bearings_rad)
                self._own_stamp = frame.stamp_s
        elif measurements.lidar:
            self._own = self._own_set(measurements.lidar[-1].detections)
            self._own_stamp = measurements.lidar[-1].stamp_s

    def _mate_set(self, t: str) -> tuple[np.ndarray, float]:
        """Teammate ``t``'s latest broadcast bearing set (M,) and its stamp (s)."""
        link = self.links[t]
        if self.config.features == "camera":
            return link.bearings, link.bearings_stamp_s
        det = link.detections
        return np.arctan2(det[:, 1], det[:, 0]), link.detections_stamp_s

    def _turns(self, t: str) -> tuple[float, float]:
        """The observer's and the teammate's heading change from their sets' instants (frame or
        scan, interpolated on the odometry tracks) to the filters' instants (rad)."""
        link = self.links[t]
        p_scan, p_now = self.own_track.at(self._own_stamp), self.own_track.latest
        v_scan, v_last = link.track.at(self._mate_set(t)[1]), link.track.latest
        own = 0.0 if p_scan is None else float(wrap_angle(p_now[2] - p_scan[2]))
        mate = 0.0 if v_scan is None else float(wrap_angle(v_last[2] - v_scan[2]))
        return own, mate

    def _register(self) -> None:
        cfg = self.config
        labels, sets = {}, {0: self._own}
        for k, t in enumerate(self.teammates, start=1):
            bearings, stamp = self._mate_set(t)
            if abs(stamp - self._own_stamp) <= cfg.max_skew_s:
                labels[k] = t
                sets[k] = bearings
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
            scales = None
            if cfg.scale_search:
                searched = f.scale_search(xis, self._std, self._scales)
                lf = None if searched is None else searched[0]
                scales = None if searched is None else searched[1]
            else:
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
                scales = None if scales is None else scales[ok]
            self._rejections[t] = 0
            f.update_bearing(xis, self._std, cfg.range_m, scales)
            self.last_hypotheses[t] = xis
