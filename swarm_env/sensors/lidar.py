"""YDLidar X4 model: compiled ray casting over a :class:`~swarm_env.sensors.scene.Scene`.

One call to :meth:`LidarSensor.scan` casts every beam of K scans at once in one numba kernel
(``_scan_kernel``). It never tests every (beam, shape) pair: for each (scan, shape) pair it
computes the bearing interval the shape subtends from the sensor, intersects only the beams in
that interval, and keeps the nearest hit per beam in place. Walls subtend wide intervals, but in
a closed arena their intervals tile the circle about once, so the work stays
~ (K x B + small shapes' beams).

Model (Perera 2021, section "Lidar"; defaults from the YDLidar X4 data sheet the study quotes):

* 720 beams per revolution (0.5 deg), beam k at robot-frame angle ``-pi + k 2 pi / B``;
  7 Hz; returns between ``range_min_m`` and ``range_max_m``, else range 0 ("no return").
* Each sample integrates over ``beam_footprint_deg`` (the head sweeps one beam spacing while it
  measures): a beam returns from a small round target (housing, post) only when its whole
  footprint is on it; a footprint straddling the edge is a mixed return that the cluster
  extractor splits off, modelled as passing to whatever is behind. A 65 mm housing at range r
  thus gives ``2 asin(0.0325 / r) / 0.5 deg - 1`` returns (6.4 at 1 m, 2.7 at 2 m).
* Additive Gaussian range noise ``sigma(r) = range_noise_std_m + range_noise_quadratic_per_m
  r^2`` (triangulation) on valid returns; the return is dropped (range 0) if the noisy range
  falls outside ``[range_min_m, range_max_m]``.
* Intensity = surface intensity x ``1 / (1 + (r / intensity_falloff_m)^2)`` x log-normal noise,
  so a valid return always has intensity > 0 and range 0 + intensity 0 marks a null.
* Four blind sectors where the camera pillars sit inside ``range_min_m``: range 0, intensity 0.
* Interference (Perera 2021's eq. 23 phenomenon): beam k of robot i is fired at
  ``stamp_i - 1/rate_i + (k / B) / rate_i``; if it hits robot j's housing while j's spinning
  head points back at i (within ``interference_tolerance_deg``, and not into j's own blind
  sector), the beam returns a null. Each head spins at ``rate_hz`` plus a per-robot offset, so
  the nulls come and go pseudo-periodically as the heads drift in and out of phase.

Simplification: the Scene is one snapshot, so the robots' motion during a revolution
(~0.14 s, i.e. < 4 cm at the robot's top speed) is ignored; only the beam *times* are used, for
the interference phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from swarm_core.geometry import TWO_PI, wrap_angle
from swarm_core.perception.blind_sectors import blind_mask
from swarm_core.validation import check_blind_sectors, check_number_fields
from swarm_env.sensors.kernels import segment_distance2, stable_order, wrap
from swarm_env.sensors.noise import TabulatedNormal, table_indices, tabulated
from swarm_env.sensors.scene import Scene
from swarm_env.sensors.spatial_index import build_grid, gather

# Grid cell of the scans' spatial index, m: a scan reaches 11.6 m (10 m + 6 sigma of noise),
# i.e. ~150 cells of 2 m per slot (~550 of 1 m; 2 m measured ~1.5x faster at 1000 robots).
_CELL_M = 2.0
#: ``scan(indexed=None)`` uses the grid from this many lidar circles in the scene on (a
#: time-stacked 20-robot scene has ~110, where building the grid costs more than it saves).
INDEX_MIN_CIRCLES = 400
# Bearing intervals are widened by this much so rounding never loses a beam through an end point.
_EDGE_RAD = 1e-9

#: ``hit_kind`` codes.
HIT_NONE = 0
HIT_CIRCLE = 1
HIT_SEGMENT = 2


#: Cost and plausibility guards of :class:`LidarConfig`.
MAX_BEAMS = 20_000
MAX_RANGE_M = 100.0


@dataclass(frozen=True, slots=True)
class LidarConfig:
    """YDLidar X4 parameters (Perera 2021; defaults are the study's values where it gives them).

    Attributes
    ----------
    rate_hz : float
        Nominal head rotation rate = scan rate (seed: 7 Hz).
    n_beams : int
        Beams per revolution (seed: 720, i.e. 0.5 deg).
    range_max_m, range_min_m : float
        Valid return interval (X4 data sheet: 0.12 m - 10 m).
    range_noise_std_m : float
        Range-independent part of the Gaussian range noise standard deviation (1 cm: our
        choice, X4 data sheet order of magnitude).
    range_noise_quadratic_per_m : float
        The X4 is a triangulation lidar: its depth error grows as r^2 (a fixed error in the
        laser spot's position on the sensor maps to ``r^2 / (focal x baseline)``). The noise
        standard deviation is ``range_noise_std_m + range_noise_quadratic_per_m * r^2``; the
        default 0.0025 /m gives 1.25 cm at 1 m, 2 cm at 2 m (1 % of the distance, the data
        sheet's figure from 2 m on) and 5 cm at 4 m.
    beam_footprint_deg : float
        Angular width of one sample on a target: the head turns ``360 rate_hz / 5000 Hz`` =
        0.50 deg during each of the X4's 5 kHz samples (the laser spot's own divergence is not
        in the data sheet and is left out). A beam whose footprint reaches past the edge of a
        circle does not return from it (mixed pixel, see the module notes). 0 gives ideal thin
        beams. Segments (walls, boxes) are not affected.
    intensity_noise_std : float
        Sigma of the multiplicative log-normal intensity noise (dimensionless).
    intensity_falloff_m : float
        Range at which the return intensity halves.
    blind_sector_centers_deg, blind_sector_widths_deg : tuple of float
        Camera-pillar blind sectors in the robot frame (Perera 2021 eq. 20: "determined
        experimentally"; the values here are the pillar geometry of the Cherokey build).
    interference_tolerance_deg : float
        Half-angle within which another robot's head must point back at the scanner for a beam
        that hits its housing to be nulled. 0 disables interference.
    head_rate_jitter_hz : float
        Each head spins at ``rate_hz + U(-jitter, jitter)``, drawn once per reset.
    """

    rate_hz: float = 7.0
    n_beams: int = 720
    range_max_m: float = 10.0
    range_min_m: float = 0.12
    range_noise_std_m: float = 0.01
    range_noise_quadratic_per_m: float = 0.0025
    beam_footprint_deg: float = 0.5
    intensity_noise_std: float = 0.05
    intensity_falloff_m: float = 4.0
    blind_sector_centers_deg: tuple[float, ...] = (45.0, 135.0, -135.0, -45.0)
    blind_sector_widths_deg: tuple[float, ...] = (10.0, 10.0, 10.0, 10.0)
    interference_tolerance_deg: float = 6.0
    head_rate_jitter_hz: float = 0.05

    def __post_init__(self) -> None:
        check_number_fields(self)
        _positive("rate_hz", self.rate_hz)
        # Cost guard: every beam is cast every scan; 20 000 beams (0.018 deg) already costs
        # ~30x the X4's 720, and 10**7 took 54 s per step.
        if (
            isinstance(self.n_beams, bool)
            or not isinstance(self.n_beams, (int, np.integer))
            or not 8 <= self.n_beams <= MAX_BEAMS
        ):
            raise ValueError(
                f"LidarConfig.n_beams must be an int in [8, {MAX_BEAMS}], got {self.n_beams!r}"
            )
        _non_negative("range_min_m", self.range_min_m)
        if not (math.isfinite(self.range_max_m) and self.range_max_m <= MAX_RANGE_M):
            raise ValueError(
                f"LidarConfig.range_max_m must be finite and <= {MAX_RANGE_M} m (a planar "
                f"lidar), got {self.range_max_m!r}"
            )
        if not self.range_max_m > self.range_min_m:
            raise ValueError(
                f"LidarConfig.range_max_m must exceed range_min_m={self.range_min_m}, "
                f"got {self.range_max_m!r}"
            )
        _non_negative("range_noise_std_m", self.range_noise_std_m)
        _non_negative("range_noise_quadratic_per_m", self.range_noise_quadratic_per_m)
        if not 0.0 <= self.beam_footprint_deg < 10.0:
            raise ValueError(
                "LidarConfig.beam_footprint_deg must be in [0, 10), got "
                f"{self.beam_footprint_deg!r}"
            )
        _non_negative("intensity_noise_std", self.intensity_noise_std)
        _positive("intensity_falloff_m", self.intensity_falloff_m)
        check_blind_sectors(
            "LidarConfig", self.blind_sector_centers_deg, self.blind_sector_widths_deg
        )
        if not 0.0 <= self.interference_tolerance_deg <= 180.0:
            raise ValueError(
                "LidarConfig.interference_tolerance_deg must be in [0, 180], got "
                f"{self.interference_tolerance_deg!r}"
            )
        if not 0.0 <= self.head_rate_jitter_hz < self.rate_hz:
            raise ValueError(
                f"LidarConfig.head_rate_jitter_hz must be in [0, rate_hz={self.rate_hz}), got "
                f"{self.head_rate_jitter_hz!r}"
            )

    @property
    def beam_spacing_rad(self) -> float:
        """Angle between consecutive beams, rad."""
        return TWO_PI / self.n_beams

    def range_noise_std_at(self, range_m: np.ndarray | float) -> np.ndarray:
        """Range noise standard deviation at ``range_m`` (any shape), metres."""
        r = np.asarray(range_m, dtype=np.float64)
        return self.range_noise_std_m + self.range_noise_quadratic_per_m * r * r


@dataclass(frozen=True, slots=True)
class LidarScanBatch:
    """K lidar revolutions cast in one call.

    Attributes
    ----------
    robots : ndarray, shape (K,), int
        Scanning robot of each scan.
    stamps_s : ndarray, shape (K,)
        End of each revolution, seconds.
    angles_rad : ndarray, shape (B,)
        Beam bearings in the robot frame, ``-pi + k 2 pi / B``.
    ranges_m : ndarray, shape (K, B)
        Measured ranges; 0 = no valid return (nothing in range, blind sector or null).
    intensities : ndarray, shape (K, B)
        Return intensities; > 0 for every valid return, 0 otherwise.
    hit_owner : ndarray, shape (K, B), int
        Robot whose housing produced the return, -1 otherwise. Computed *before* interference
        nulling (ground truth for "this beam saw robot j").
    hit_kind : ndarray, shape (K, B), int8
        ``HIT_NONE``, ``HIT_CIRCLE`` or ``HIT_SEGMENT`` for the surface of the (pre-nulling)
        return.
    hit_index : ndarray, shape (K, B), int
        Index of that surface in ``scene.circle_*`` or ``scene.segment_*``, -1 for none.
    interfered : ndarray, shape (K, B), bool
        Beams nulled by interference (their range and intensity are 0).
    """

    robots: np.ndarray
    stamps_s: np.ndarray
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    intensities: np.ndarray
    hit_owner: np.ndarray
    hit_kind: np.ndarray
    hit_index: np.ndarray
    interfered: np.ndarray

    @property
    def n_scans(self) -> int:
        """Number of scans K in the batch."""
        return int(self.robots.shape[0])

    def owner_beam_counts(self, n_robots: int, after_interference: bool = True) -> np.ndarray:
        """Valid beams returned by each robot's housing, per scan.

        Parameters
        ----------
        n_robots : int
        after_interference : bool
            Count only beams that survived interference nulling (what the extractor sees).

        Returns
        -------
        ndarray, shape (K, n_robots), int
            ``counts[k, j]`` beams of scan k hit robot j. ``counts > 0`` is a ground-truth
            "visible to the lidar" (before clustering).
        """
        return _owner_counts(self.hit_owner, self.interfered, n_robots, after_interference)


class LidarSensor:
    """Lidars of a whole swarm: per-robot head phases and rates, vectorised scans.

    Parameters
    ----------
    config : LidarConfig, optional
    n_robots : int
        Number of robots whose heads are modelled (robots index ``scene.robot_xy``).

    Notes
    -----
    Robot j's head points at robot-frame angle ``phase_j + 2 pi rate_j t`` (mod 2 pi), world
    angle ``yaw_j`` plus that. A revolution ends (its stamp) when the head comes back to -pi,
    which is what :meth:`scan_stamps` enumerates. Call :meth:`reset` to draw phases and rates;
    before that, all phases are 0 and all rates nominal.
    """

    def __init__(self, config: LidarConfig | None = None, n_robots: int = 1) -> None:
        self.config = config if config is not None else LidarConfig()
        if n_robots < 0:
            raise ValueError(f"LidarSensor.n_robots must be >= 0, got {n_robots!r}")
        cfg = self.config
        n_beams = cfg.n_beams
        angles = -np.pi + np.arange(n_beams) * cfg.beam_spacing_rad
        self.angles_rad = _readonly(angles)
        self._beam_ux = np.cos(angles)
        self._beam_uy = np.sin(angles)
        self.blind_mask = _readonly(blind_mask(angles, cfg))
        # Per-beam noise as table lookups (see noise.py): range offsets and intensity factors.
        # Unit normals: the kernel scales them by the range-dependent sigma.
        self._range_noise = TabulatedNormal("normal", 1.0)
        self._intensity_noise = TabulatedNormal("lognormal", cfg.intensity_noise_std)
        self.head_phase_rad = np.zeros(n_robots)
        self.rate_offset_hz = np.zeros(n_robots)

    @property
    def n_robots(self) -> int:
        """Number of modelled heads N."""
        return int(self.head_phase_rad.shape[0])

    @property
    def rates_hz(self) -> np.ndarray:
        """Per-robot head rates, shape (N,), Hz."""
        return self.config.rate_hz + self.rate_offset_hz

    def reset(self, rng: np.random.Generator, n_robots: int | None = None) -> None:
        """Draw every head's phase ``U(0, 2 pi)`` and rate offset ``U(-jitter, jitter)``.

        Parameters
        ----------
        rng : numpy.random.Generator
        n_robots : int, optional
            New swarm size (default: keep the current one).
        """
        n = self.n_robots if n_robots is None else int(n_robots)
        if n < 0:
            raise ValueError(f"LidarSensor.reset n_robots must be >= 0, got {n_robots!r}")
        jitter = self.config.head_rate_jitter_hz
        self.head_phase_rad = rng.uniform(0.0, TWO_PI, size=n)
        self.rate_offset_hz = rng.uniform(-jitter, jitter, size=n)

    def scan_stamps(self, t_start_s: float, t_end_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Revolutions that end in ``(t_start_s, t_end_s]``, consistent with the head phases.

        Returns
        -------
        robots : ndarray, shape (K,), int
        stamps_s : ndarray, shape (K,)
            Sorted by stamp (ties by robot index).
        """
        return _scan_stamps(self.head_phase_rad, self.rates_hz, float(t_start_s), float(t_end_s))

    def head_angle_rad(self, robots: np.ndarray, times_s: np.ndarray) -> np.ndarray:
        """Robot-frame head angles of ``robots`` at ``times_s`` (broadcast), wrapped."""
        robots = np.asarray(robots, dtype=np.intp)
        revolutions = self.rates_hz[robots] * np.asarray(times_s, dtype=np.float64)
        # Keep only the fractional turn so the angle stays exact over long runs.
        frac = revolutions - np.floor(revolutions)
        return wrap_angle(self.head_phase_rad[robots] + TWO_PI * frac)

    def scan(
        self,
        scene: Scene,
        robots: np.ndarray,
        stamps_s: np.ndarray,
        rng: np.random.Generator,
        time_index: np.ndarray | None = None,
        indexed: bool | None = None,
    ) -> LidarScanBatch:
        """Cast K full revolutions at once.

        Parameters
        ----------
        scene : Scene
            World snapshot (not modified).
        robots : ndarray, shape (K,), int
            Scanning robots (indices into ``scene.robot_xy``; repeats allowed).
        stamps_s : ndarray, shape (K,)
            End time of each revolution, seconds.
        rng : numpy.random.Generator
            Source of the range and intensity noise. Always draws ``2 K B`` tabulated normals
            (:class:`~swarm_env.sensors.noise.TabulatedNormal`), so the stream advances the
            same way whatever the scene.
        time_index : ndarray, shape (K,), int, optional
            Instant of each scan in a time-stacked scene (see :class:`Scene`).
        indexed : bool, optional
            ``True``: visit only the shapes near each scanner through a uniform grid
            (:mod:`swarm_env.sensors.spatial_index`). ``False``: test every shape, the
            brute-force reference (bit-identical results at O(scans x shapes) cost).
            ``None`` (default): the grid from :data:`INDEX_MIN_CIRCLES` lidar circles on,
            where it pays for building it.

        Returns
        -------
        LidarScanBatch
        """
        cfg = self.config
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        stamps = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
        if robots.shape != stamps.shape:
            raise ValueError(
                f"scan: robots {robots.shape} and stamps_s {stamps.shape} must have one entry "
                "per scan"
            )
        n_scene = scene.n_robots
        if robots.size and (robots.min() < 0 or robots.max() >= min(n_scene, self.n_robots)):
            raise ValueError(
                f"scan: robots must index the scene ({n_scene} robots) and the sensor "
                f"({self.n_robots} heads), got {robots.tolist()}"
            )
        n_scans, n_beams = robots.size, cfg.n_beams
        if time_index is not None:
            time_index = np.asarray(time_index, dtype=np.intp).reshape(-1)
        origin, yaw = scene.observer_poses(robots, time_index)
        origin = np.ascontiguousarray(origin, dtype=np.float64)
        yaw = np.ascontiguousarray(yaw, dtype=np.float64)

        # Circles with their instants (-1: static, or every circle present).
        n_circles = scene.circle_xy.shape[0]
        if scene.circle_time is None or time_index is None:
            c_time = np.full(n_circles, -1, dtype=np.intp)
            scan_time = np.full(n_scans, -1, dtype=np.intp)
        else:
            c_time = np.asarray(scene.circle_time, dtype=np.intp)
            scan_time = time_index
        # Interference reads the other robot's heading at the scan's instant.
        robot_yaw = np.asarray(scene.robot_yaw, dtype=np.float64)
        if robot_yaw.ndim == 1:
            robot_yaw = robot_yaw[None]
        pose_time = np.zeros(n_scans, dtype=np.intp) if time_index is None else time_index
        n_heads = min(self.n_robots, n_scene)
        if cfg.interference_tolerance_deg <= 0.0:
            n_heads = 0
        reach = float(cfg.range_max_m + 6.0 * float(cfg.range_noise_std_at(cfg.range_max_m)))
        circle_xy = np.ascontiguousarray(scene.circle_xy, dtype=np.float64)
        circle_radius = np.asarray(scene.circle_radius_m, dtype=np.float64)
        circle_lidar = np.asarray(scene.circle_lidar, dtype=np.bool_)
        seg_a = np.ascontiguousarray(scene.segment_a, dtype=np.float64).reshape(-1, 2)
        seg_b = np.ascontiguousarray(scene.segment_b, dtype=np.float64).reshape(-1, 2)
        if indexed is None:
            indexed = int(np.count_nonzero(circle_lidar)) >= INDEX_MIN_CIRCLES
        index = _lidar_index(indexed, circle_xy, circle_radius, circle_lidar, c_time, seg_a, seg_b)
        shape = (n_scans, n_beams)
        ranges = np.empty(shape)
        intensities = np.empty(shape)
        hit_owner = np.empty(shape, dtype=np.intp)
        hit_kind = np.empty(shape, dtype=np.int8)
        hit_index = np.empty(shape, dtype=np.intp)
        interfered = np.empty(shape, dtype=bool)
        _scan_kernel(
            (origin, yaw, robots, scan_time, pose_time, stamps),
            (
                circle_xy,
                circle_radius,
                np.asarray(scene.circle_owner, dtype=np.intp),
                c_time,
                circle_lidar,
                np.asarray(scene.circle_intensity, dtype=np.float64),
            ),
            (seg_a, seg_b, np.asarray(scene.segment_intensity, dtype=np.float64).reshape(-1)),
            (self._beam_ux, self._beam_uy, self.blind_mask),
            (
                float(cfg.range_min_m),
                float(cfg.range_max_m),
                reach,
                float(cfg.range_noise_std_m),
                float(cfg.range_noise_quadratic_per_m),
                float(0.5 * np.deg2rad(cfg.beam_footprint_deg)),
                float(1.0 / cfg.intensity_falloff_m),
                float(np.deg2rad(cfg.interference_tolerance_deg)),
            ),
            (
                table_indices(rng, 2 * n_scans * n_beams),
                self._range_noise.table,
                self._intensity_noise.table,
            ),
            (robot_yaw, n_heads, self.rates_hz, self.head_phase_rad),
            index,
            (ranges, intensities, hit_owner, hit_kind, hit_index, interfered),
        )
        return LidarScanBatch(
            robots=robots,
            stamps_s=stamps,
            angles_rad=self.angles_rad,
            ranges_m=ranges,
            intensities=intensities,
            hit_owner=hit_owner,
            hit_kind=hit_kind,
            hit_index=hit_index,
            interfered=interfered,
        )


def _lidar_index(indexed, circle_xy, circle_radius, circle_lidar, c_time, seg_a, seg_b):
    """The kernel's ``index`` argument: ``(indexed, circle grid, segment grid, n_slots)``.

    The circle grid holds the lidar circles by centre and radius, in slot ``instant + 1`` (0:
    static); the segment grid the segments by midpoint and half length (walls, longer than a
    cell, are visited by every scan). Not ``indexed``: two empty grids, never read.
    """
    if not indexed:
        empty = build_grid(np.zeros((0, 2)), np.zeros(0))
        return False, empty, empty, 1
    lidar = np.flatnonzero(circle_lidar)
    slots = c_time[lidar] + 1  # -1 (static or every instant) -> 0
    n_slots = int(slots.max(initial=0)) + 1
    circles = build_grid(circle_xy[lidar], circle_radius[lidar], slots, n_slots, _CELL_M)
    # Grid items index the lidar circles: map them back to scene circle indices.
    circles = (circles[0], lidar[circles[1]], *circles[2:])
    half = 0.5 * np.hypot(*(seg_b - seg_a).T)
    segments = build_grid(0.5 * (seg_a + seg_b), half, cell_m=_CELL_M)
    return True, circles, segments, n_slots


@njit(cache=True, parallel=True)
def _scan_kernel(scans, circles, segments, beams, model, noise, interference, index, out):
    """K full revolutions: ray casting, noise, range limits, blind sectors and interference.

    Shapes: K scans, B beams, C circles (``c_*``; only ``c_lidar`` ones are seen), S segments.
    ``origin`` (K, 2) m and ``yaw`` (K,) rad are the scanners' poses; ``scan_time`` (K,) is
    each scan's instant (-1: every circle is present), ``c_time`` (C',) each circle's (-1:
    static); ``pose_time`` (K,) indexes ``robot_yaw`` (T, N). ``noise_index`` (2 K B,) uint16:
    the range-noise indices of beam (k, b) at ``k B + b``, the intensity-noise ones after
    them.
    Writes the (K, B) outputs of :class:`LidarScanBatch`.

    Per (scan, shape) pair only the beams inside the shape's subtended bearing interval are
    intersected, and there a closed form without a validity test is exact (the beam is known to
    hit); the nearest hit is kept in place, so the cost is ~K x (B + small shapes' beams).
    With ``index = (True, circle grid, segment grid, n_slots)`` (:func:`_lidar_index`) a scan
    visits only the shapes of the grid cells within its reach (the rest fail the reach test
    anyway), in cell order; the nearest hit is order-free (ties: the highest shape code, as
    the brute-force pass in index order with ``<=`` gives), so both paths agree bit for bit.

    The arguments travel as tuples grouped by role (a new option is added to one group at the
    call and unpacked once here): ``scans``, ``circles``, ``segments``, ``beams``, the float
    ``model`` constants, the ``noise`` tables, the ``interference`` state and the ``out``puts.
    """
    origin, yaw, robots, scan_time, pose_time, stamps = scans
    c_xy, c_radius, c_owner, c_time, c_lidar, c_intensity = circles
    seg_a, seg_b, seg_intensity = segments
    beam_ux, beam_uy, blind = beams
    (range_min, range_max, reach, noise_std, noise_quadratic, footprint_half, inv_falloff,
     tolerance) = model  # fmt: skip
    noise_index, range_table, intensity_table = noise
    robot_yaw, n_heads, rates, phases = interference
    indexed, circle_grid, segment_grid, n_slots = index
    ranges, intensities, hit_owner, hit_kind, hit_index, interfered = out
    n_scans, n_beams = ranges.shape
    spacing = TWO_PI / n_beams
    too_far = math.sin(footprint_half) ** 2 * (1.0 - 1e-9)  # (r / d)^2 below it: no return
    inv_spacing = 1.0 / spacing
    n_c, n_s = c_xy.shape[0], seg_a.shape[0]
    # Scans are independent (each writes only its own output rows): parallel threads.
    for k in prange(n_scans):
        best = np.full(n_beams, np.inf)
        code = np.full(n_beams, -1, dtype=np.intp)
        ox, oy = origin[k, 0], origin[k, 1]
        cos_y, sin_y = math.cos(yaw[k]), math.sin(yaw[k])
        me, when = robots[k], scan_time[k]
        # The shapes to test: all of them, or those of the cells within reach.
        n_visit_c, n_visit_s = n_c, n_s
        visit_c = np.empty(circle_grid[1].shape[0], dtype=np.intp)
        visit_s = np.empty(segment_grid[1].shape[0], dtype=np.intp)
        if indexed:
            n_visit_c = gather(circle_grid, 0, ox, oy, reach, visit_c, 0)
            for slot in range(1, n_slots):
                if when < 0 or slot == when + 1:
                    n_visit_c = gather(circle_grid, slot, ox, oy, reach, visit_c, n_visit_c)
            n_visit_s = gather(segment_grid, 0, ox, oy, reach, visit_s, 0)
        for q in range(n_visit_c):
            i = visit_c[q] if indexed else q
            if not c_lidar[i] or c_owner[i] == me:
                continue
            if c_time[i] >= 0 and when >= 0 and c_time[i] != when:
                continue
            dx, dy = c_xy[i, 0] - ox, c_xy[i, 1] - oy
            px, py = cos_y * dx + sin_y * dy, cos_y * dy - sin_y * dx
            r = c_radius[i]
            d2 = px * px + py * py
            # Inside the circle (no outer surface) or out of reach.
            if not (d2 > r * r and d2 < (reach + r) * (reach + r)):
                continue
            # Far enough that r / d < sin(footprint_half) by a margin: asin() < footprint_half
            # for sure, so the test below would skip it (half the circles of a big arena).
            if r * r < d2 * too_far:
                continue
            # Beams whose whole footprint lies on the circle (none: the circle returns nothing).
            half = math.asin(r / math.sqrt(d2)) - footprint_half
            if half < 0.0:
                continue
            half += _EDGE_RAD
            bearing = math.atan2(py, px) + math.pi
            lo = int(math.ceil((bearing - half) * inv_spacing))
            hi = int(math.floor((bearing + half) * inv_spacing))
            rr_dd = r * r - d2
            # The interval as two runs of beam indices (one may be empty): no modulo per beam.
            runs = _runs(lo, hi, n_beams)
            for part in range(2):
                for b in range(runs[2 * part], runs[2 * part + 1] + 1):
                    t_closest = beam_ux[b] * px + beam_uy[b] * py
                    # Within the tangent bearings disc >= 0 up to rounding: clamp (grazing hit).
                    disc = max(t_closest * t_closest + rr_dd, 0.0)
                    t = t_closest - math.sqrt(disc)
                    # Ties: the later shape wins (as np.minimum.at did), in any visit order.
                    if t < best[b] or (t == best[b] and i > code[b]):
                        best[b] = t
                        code[b] = i
        for q in range(n_visit_s):
            s = visit_s[q] if indexed else q
            dx, dy = seg_a[s, 0] - ox, seg_a[s, 1] - oy
            ax, ay = cos_y * dx + sin_y * dy, cos_y * dy - sin_y * dx
            dx, dy = seg_b[s, 0] - ox, seg_b[s, 1] - oy
            bx, by = cos_y * dx + sin_y * dy, cos_y * dy - sin_y * dx
            ex, ey = bx - ax, by - ay
            length = math.hypot(ex, ey)
            # Normal form of the supporting line: n . x = p, with p >= 0.
            inv_len = 1.0 / length if length > 0.0 else 1.0
            nx, ny = ey * inv_len, -ex * inv_len
            p = nx * ax + ny * ay
            if p < 0.0:
                nx, ny, p = -nx, -ny, -p
            # A sensor on the line sees the segment edge-on: no return.
            if not p > 1e-9 or segment_distance2(-ax, -ay, ex, ey) >= reach * reach:
                continue
            phi_a = math.atan2(ay, ax)
            sweep = wrap(math.atan2(by, bx) - phi_a)
            # The segment subtends the shorter arc between its end-point bearings.
            start = (phi_a if sweep >= 0.0 else phi_a + sweep) + math.pi
            lo = int(math.ceil((start - _EDGE_RAD) * inv_spacing))
            hi = int(math.floor((start + abs(sweep) + _EDGE_RAD) * inv_spacing))
            runs = _runs(lo, hi, n_beams)
            for part in range(2):
                for b in range(runs[2 * part], runs[2 * part + 1] + 1):
                    cos_rel = beam_ux[b] * nx + beam_uy[b] * ny
                    t = p / max(cos_rel, 1e-12)
                    if t < best[b] or (t == best[b] and n_c + s > code[b]):
                        best[b] = t
                        code[b] = n_c + s

        rate_me = rates[me]
        base = k * n_beams
        # Bearing from the last housing hit to the scanner (consecutive beams share it).
        to_me, to_me_c = 0.0, -1
        for b in range(n_beams):
            d = best[b]
            r = d  # no hit: inf stays inf
            if d < np.inf:
                # sigma(d) = noise_std + noise_quadratic d^2 (triangulation).
                sigma = noise_std + noise_quadratic * d * d
                r += sigma * tabulated(range_table, noise_index[base + b])
            c = code[b]
            if blind[b] or not (r >= range_min and r <= range_max) or c < 0:
                ranges[k, b] = 0.0
                intensities[k, b] = 0.0
                hit_owner[k, b] = -1
                hit_kind[k, b] = HIT_NONE
                hit_index[k, b] = -1
                interfered[k, b] = False
                continue
            if c < n_c:
                owner, kind, index, surface = c_owner[c], HIT_CIRCLE, c, c_intensity[c]
            else:
                owner, kind, index = -1, HIT_SEGMENT, c - n_c
                surface = seg_intensity[index]
            hit_owner[k, b] = owner
            hit_kind[k, b] = kind
            hit_index[k, b] = index
            nulled = False
            if 0 <= owner < n_heads:
                # Beam b is fired at this time; robot `owner`'s head sits at its housing centre.
                beam_time = stamps[k] - 1.0 / rate_me + (b / n_beams) / rate_me
                turns = rates[owner] * beam_time
                head_body = wrap(phases[owner] + TWO_PI * (turns - math.floor(turns)))
                head_world = robot_yaw[pose_time[k], owner] + head_body
                if to_me_c != c:  # one atan2 per run of beams on a housing, not per beam
                    to_me = math.atan2(oy - c_xy[c, 1], ox - c_xy[c, 0])
                    to_me_c = c
                if abs(wrap(head_world - to_me)) <= tolerance:
                    # A head pointing into its own pillar emits nothing towards us.
                    head_beam = int(np.rint((head_body + math.pi) / spacing)) % n_beams
                    nulled = not blind[head_beam]
            interfered[k, b] = nulled
            if nulled:
                ranges[k, b] = 0.0
                intensities[k, b] = 0.0
                continue
            ranges[k, b] = r
            scaled = r * inv_falloff
            falloff = 1.0 / (1.0 + scaled * scaled)
            factor = tabulated(intensity_table, noise_index[(n_scans + k) * n_beams + b])
            intensities[k, b] = surface * falloff * factor


@njit(cache=True)
def _scan_stamps(phase, rates, t_start, t_end):
    """Revolution ends in ``(t_start, t_end]`` s of heads with ``phase`` (N,) rad and ``rates``
    (N,) Hz: ``robots`` (K,) and ``stamps`` (K,) s, sorted by stamp, ties by robot."""
    n = phase.shape[0]
    t0 = np.empty(n)
    first = np.empty(n)
    last = np.empty(n)
    total = 0
    for i in range(n):
        # End of revolution: phase + 2 pi rate t = -pi (mod 2 pi)  =>  t = t0 + n / rate.
        t0[i] = ((-math.pi - phase[i]) % TWO_PI) / (TWO_PI * rates[i])
        first[i] = math.floor((t_start - t0[i]) * rates[i]) + 1.0
        last[i] = math.floor((t_end - t0[i]) * rates[i])
        total += max(int(last[i] - first[i]) + 1, 0)
    robots = np.empty(total, dtype=np.intp)
    stamps = np.empty(total)
    k = 0
    for i in range(n):
        m = first[i]
        while m <= last[i]:
            stamp = t0[i] + m / rates[i]
            if t_start < stamp <= t_end:  # guard the floor() boundaries against rounding
                robots[k] = i
                stamps[k] = stamp
                k += 1
            m += 1.0
    order = stable_order(stamps[:k])  # equal stamps keep robot order
    return robots[:k][order], stamps[:k][order]


@njit(cache=True)
def _owner_counts(hit_owner, interfered, n_robots, after_interference):
    """(K, n_robots) counts of the beams of ``hit_owner`` (K, B) per owner (owners outside
    ``[0, n_robots)`` are not counted), optionally skipping the ``interfered`` (K, B) ones."""
    n_scans, n_beams = hit_owner.shape
    counts = np.zeros((n_scans, n_robots), dtype=np.intp)
    for k in range(n_scans):
        for b in range(n_beams):
            j = hit_owner[k, b]
            if 0 <= j < n_robots and not (after_interference and interfered[k, b]):
                counts[k, j] += 1
    return counts


@njit(cache=True, inline="always")
def _runs(lo, hi, n_beams):
    """Beam indices ``lo..hi`` (an interval narrower than the circle, ``lo`` in
    ``[-n_beams, n_beams]``) wrapped to ``[0, n_beams)`` as two runs ``(a0, z0, a1, z1)``, each
    inclusive and possibly empty: the hot loops then index beams without a modulo."""
    if lo < 0:
        return lo + n_beams, n_beams - 1, 0, hi
    if hi >= n_beams:
        return lo, n_beams - 1, 0, hi - n_beams
    return lo, hi, 0, -1


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


def _positive(name: str, value: float) -> None:
    if not value > 0.0:
        raise ValueError(f"LidarConfig.{name} must be > 0, got {value!r}")


def _non_negative(name: str, value: float) -> None:
    if not value >= 0.0:
        raise ValueError(f"LidarConfig.{name} must be >= 0, got {value!r}")
