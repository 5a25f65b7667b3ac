"""YDLidar X4 model: vectorised ray casting over a :class:`~swarm_env.world.scene.Scene`.

One call to :meth:`LidarSensor.scan` casts every beam of K scans at once. It never builds the
dense (scans x beams x shapes) product: for each (scan, shape) pair it computes the bearing
interval the shape subtends from the sensor, expands the interval into the beam indices it
covers, intersects only those rays, and keeps the nearest hit per beam with
``np.minimum.at``. Walls subtend wide intervals, but in a closed arena their intervals tile
the circle about once, so the total work stays ~ (K x B + small shapes' beams).

Model (seed 000, section "Lidar"; defaults from the YDLidar X4 data sheet the seed quotes):

* 720 beams per revolution (0.5 deg), beam k at robot-frame angle ``-pi + k 2 pi / B``;
  7 Hz; returns between ``range_min_m`` and ``range_max_m``, else range 0 ("no return").
* Additive Gaussian range noise on valid returns; the return is dropped (range 0) if the noisy
  range falls outside ``[range_min_m, range_max_m]``.
* Intensity = surface intensity x ``1 / (1 + (r / intensity_falloff_m)^2)`` x log-normal noise,
  so a valid return always has intensity > 0 and range 0 + intensity 0 marks a null.
* Four blind sectors where the camera pillars sit inside ``range_min_m``: range 0, intensity 0.
* Interference (seed's eq. 23 phenomenon): beam k of robot i is fired at
  ``stamp_i - 1/rate_i + (k / B) / rate_i``; if it hits robot j's housing while j's spinning
  head points back at i (within ``interference_tolerance_deg``, and not into j's own blind
  sector), the beam returns a null. Each head spins at ``rate_hz`` plus a per-robot offset, so
  the nulls come and go pseudo-periodically as the heads drift in and out of phase.

Simplification: the Scene is one snapshot, so the robots' motion during a revolution
(~0.14 s, i.e. < 4 cm at the robot's top speed) is ignored; only the beam *times* are used, for
the interference phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm_env.sensors.geometry import (
    TWO_PI,
    expand_intervals,
    point_segment_distance,
    to_body_frame,
    wrap_angle,
)
from swarm_env.sensors.noise import TabulatedNormal
from swarm_env.world.scene import Scene

# Bearing intervals are widened by this much so rounding never loses a beam through an end point.
_EDGE_RAD = 1e-9

#: ``hit_kind`` codes.
HIT_NONE = 0
HIT_CIRCLE = 1
HIT_SEGMENT = 2


@dataclass(frozen=True, slots=True)
class LidarConfig:
    """YDLidar X4 parameters (seed 000; defaults are the seed's values where it gives them).

    Attributes
    ----------
    rate_hz : float
        Nominal head rotation rate = scan rate (seed: 7 Hz).
    n_beams : int
        Beams per revolution (seed: 720, i.e. 0.5 deg).
    range_max_m, range_min_m : float
        Valid return interval (X4 data sheet: 0.12 m - 10 m).
    range_noise_std_m : float
        Standard deviation of the additive Gaussian range noise (X4: ~1 % at short range; we
        use a flat 1 cm, which matches the seed filter's R_L = diag(0.0025) being dominated by
        the centre-estimate error, not the range noise).
    intensity_noise_std : float
        Sigma of the multiplicative log-normal intensity noise (dimensionless).
    intensity_falloff_m : float
        Range at which the return intensity halves.
    blind_sector_centers_deg, blind_sector_widths_deg : tuple of float
        Camera-pillar blind sectors in the robot frame (seed eq. 20: "determined
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
    intensity_noise_std: float = 0.05
    intensity_falloff_m: float = 4.0
    blind_sector_centers_deg: tuple[float, ...] = (45.0, 135.0, -135.0, -45.0)
    blind_sector_widths_deg: tuple[float, ...] = (10.0, 10.0, 10.0, 10.0)
    interference_tolerance_deg: float = 6.0
    head_rate_jitter_hz: float = 0.05

    def __post_init__(self) -> None:
        _positive("rate_hz", self.rate_hz)
        if not isinstance(self.n_beams, (int, np.integer)) or self.n_beams < 1:
            raise ValueError(f"LidarConfig.n_beams must be a positive int, got {self.n_beams!r}")
        _non_negative("range_min_m", self.range_min_m)
        if not self.range_max_m > self.range_min_m:
            raise ValueError(
                f"LidarConfig.range_max_m must exceed range_min_m={self.range_min_m}, "
                f"got {self.range_max_m!r}"
            )
        _non_negative("range_noise_std_m", self.range_noise_std_m)
        _non_negative("intensity_noise_std", self.intensity_noise_std)
        _positive("intensity_falloff_m", self.intensity_falloff_m)
        if len(self.blind_sector_centers_deg) != len(self.blind_sector_widths_deg):
            raise ValueError(
                "LidarConfig.blind_sector_widths_deg must have one width per centre, got "
                f"{self.blind_sector_widths_deg!r} for centres {self.blind_sector_centers_deg!r}"
            )
        for width in self.blind_sector_widths_deg:
            if not 0.0 <= width < 360.0:
                raise ValueError(
                    f"LidarConfig.blind_sector_widths_deg must be in [0, 360), got {width!r}"
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
        hit = self.hit_owner >= 0
        if after_interference:
            hit &= ~self.interfered
        rows, cols = np.nonzero(hit)
        flat = rows * n_robots + self.hit_owner[rows, cols]
        counts = np.bincount(flat, minlength=self.n_scans * n_robots)
        return counts.reshape(self.n_scans, n_robots)


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
        self._range_noise = TabulatedNormal("normal", cfg.range_noise_std_m)
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
        rates = self.rates_hz
        # End of revolution: phase + 2 pi rate t = -pi (mod 2 pi)  =>  t = t0 + n / rate.
        t0 = np.mod(-np.pi - self.head_phase_rad, TWO_PI) / (TWO_PI * rates)
        n_first = np.floor((t_start_s - t0) * rates) + 1.0
        n_last = np.floor((t_end_s - t0) * rates)
        counts = np.maximum(n_last - n_first + 1.0, 0.0).astype(np.intp)
        robots, n = expand_intervals(n_first.astype(np.intp), counts)
        stamps = t0[robots] + n / rates[robots]
        # Guard the floor() boundaries against rounding.
        keep = (stamps > t_start_s) & (stamps <= t_end_s)
        robots, stamps = robots[keep], stamps[keep]
        order = np.lexsort((robots, stamps))
        return robots[order], stamps[order]

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

        flat, dist, code = self._cast(scene, origin, yaw, robots, time_index)
        best = np.full(n_scans * n_beams, np.inf)
        np.minimum.at(best, flat, dist)
        winner = dist == best[flat]
        hit_code = np.full(n_scans * n_beams, -1, dtype=np.intp)
        hit_code[flat[winner]] = code[winner]

        ranges = best + self._range_noise.draw(rng, n_scans * n_beams)  # inf (no hit) stays inf
        valid = np.tile(~self.blind_mask, n_scans)
        valid &= ranges >= cfg.range_min_m
        valid &= ranges <= cfg.range_max_m
        hit_code[~valid] = -1
        # Per-surface tables over [circles, segments, "no hit"]: code -1 reads the sentinel.
        n_circles, n_segments = scene.circle_xy.shape[0], scene.segment_a.shape[0]
        table_kind = np.concatenate(
            (np.full(n_circles, HIT_CIRCLE), np.full(n_segments, HIT_SEGMENT), [HIT_NONE])
        ).astype(np.int8)
        table_index = np.concatenate((np.arange(n_circles), np.arange(n_segments), [-1]))
        table_owner = np.concatenate(
            (np.asarray(scene.circle_owner, dtype=np.intp), np.full(n_segments + 1, -1))
        )
        table_intensity = np.concatenate(
            (
                np.asarray(scene.circle_intensity, dtype=np.float64),
                np.asarray(scene.segment_intensity, dtype=np.float64),
                [0.0],
            )
        )
        shape = (n_scans, n_beams)
        hit_kind = table_kind[hit_code].reshape(shape)
        hit_index = table_index[hit_code].reshape(shape)
        hit_owner = table_owner[hit_code].reshape(shape)
        falloff = 1.0 / (1.0 + np.square(ranges * (1.0 / cfg.intensity_falloff_m)))
        intensities = (
            table_intensity[hit_code]
            * falloff
            * self._intensity_noise.draw(rng, n_scans * n_beams)
        )

        interfered = self._interference(scene, robots, stamps, hit_owner, hit_index, time_index)
        valid &= ~interfered.reshape(-1)
        ranges = np.where(valid, ranges, 0.0).reshape(shape)
        intensities = np.where(valid, intensities, 0.0).reshape(shape)
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

    # -- internals -----------------------------------------------------------------------

    def _cast(
        self,
        scene: Scene,
        origin: np.ndarray,
        yaw: np.ndarray,
        robots: np.ndarray,
        time_index: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate hits ``(flat beam index k*B + b, distance, surface code)``.

        Surface code: circle index, or ``C + segment index``. Only the beams inside each
        shape's subtended bearing interval are intersected. Inside that interval a beam is
        known to hit the shape, so each candidate costs a handful of flops: for a circle the
        near root of the ray-circle quadratic, for a segment ``p / cos(theta - alpha)`` with
        ``(p, alpha)`` the normal form of its line. The interval is widened by ``_EDGE_RAD`` so
        a beam exactly through an end point (e.g. a corner) is never lost to rounding.
        """
        cfg = self.config
        n_beams = cfg.n_beams
        inv_spacing = 1.0 / cfg.beam_spacing_rad
        # Shapes whose nearest point is beyond this cannot return (noise margin included).
        reach = cfg.range_max_m + 6.0 * cfg.range_noise_std_m
        flats, dists, codes = [], [], []

        lidar_idx = np.flatnonzero(np.asarray(scene.circle_lidar, dtype=bool))
        if lidar_idx.size and robots.size:
            radius = np.asarray(scene.circle_radius_m, dtype=np.float64)[lidar_idx]
            owner = np.asarray(scene.circle_owner, dtype=np.intp)[lidar_idx]
            cx, cy = to_body_frame(scene.circle_xy[lidar_idx], origin, yaw)  # (K, C)
            d2 = cx * cx + cy * cy
            near = (
                (owner[None, :] != robots[:, None])
                & (d2 > radius * radius)
                & (d2 < (reach + radius) ** 2)
            )
            present = scene.circles_present(lidar_idx, time_index, robots.size)
            if present is not None:
                near &= present
            scan_i, circ_i = np.nonzero(near)
            px, py, r = cx[scan_i, circ_i], cy[scan_i, circ_i], radius[circ_i]
            dd = d2[scan_i, circ_i]
            half = np.arcsin(r / np.sqrt(dd)) + _EDGE_RAD
            bearing = np.arctan2(py, px) + np.pi
            lo = np.ceil((bearing - half) * inv_spacing).astype(np.intp)
            hi = np.floor((bearing + half) * inv_spacing).astype(np.intp)
            count, beam = _expand(lo, hi, n_beams)
            ux, uy = self._beam_ux[beam], self._beam_uy[beam]
            t_closest = ux * np.repeat(px, count) + uy * np.repeat(py, count)
            disc = t_closest * t_closest + np.repeat(r * r - dd, count)
            # Within the tangent bearings disc >= 0 up to rounding: clamp (a grazing hit).
            flats.append(np.repeat(scan_i * n_beams, count) + beam)
            dists.append(t_closest - np.sqrt(np.maximum(disc, 0.0)))
            codes.append(np.repeat(lidar_idx[circ_i], count))

        if scene.segment_a.shape[0] and robots.size:
            ax, ay = to_body_frame(scene.segment_a, origin, yaw)  # (K, S)
            bx, by = to_body_frame(scene.segment_b, origin, yaw)
            ex, ey = bx - ax, by - ay
            length = np.hypot(ex, ey)
            # Normal form of the supporting line: n . x = p, with p >= 0.
            nx = ey / np.where(length > 0.0, length, 1.0)
            ny = -ex / np.where(length > 0.0, length, 1.0)
            p = nx * ax + ny * ay
            flip = p < 0.0
            nx, ny, p = np.where(flip, -nx, nx), np.where(flip, -ny, ny), np.abs(p)
            # A sensor on the line sees the segment edge-on: no return.
            near = (p > 1e-9) & (point_segment_distance(0.0, 0.0, ax, ay, bx, by) < reach)
            scan_i, seg_i = np.nonzero(near)
            phi_a = np.arctan2(ay[scan_i, seg_i], ax[scan_i, seg_i])
            sweep = wrap_angle(np.arctan2(by[scan_i, seg_i], bx[scan_i, seg_i]) - phi_a)
            # The segment subtends the shorter arc between its end-point bearings.
            start = np.where(sweep >= 0.0, phi_a, phi_a + sweep) + np.pi
            lo = np.ceil((start - _EDGE_RAD) * inv_spacing).astype(np.intp)
            hi = np.floor((start + np.abs(sweep) + _EDGE_RAD) * inv_spacing).astype(np.intp)
            count, beam = _expand(lo, hi, n_beams)
            cos_rel = self._beam_ux[beam] * np.repeat(nx[scan_i, seg_i], count)
            cos_rel += self._beam_uy[beam] * np.repeat(ny[scan_i, seg_i], count)
            t = np.repeat(p[scan_i, seg_i], count) / np.maximum(cos_rel, 1e-12)
            flats.append(np.repeat(scan_i * n_beams, count) + beam)
            dists.append(t)
            codes.append(np.repeat(scene.circle_xy.shape[0] + seg_i, count))

        if not flats:
            empty = np.zeros(0, dtype=np.intp)
            return empty, np.zeros(0), empty
        return np.concatenate(flats), np.concatenate(dists), np.concatenate(codes)

    def _interference(
        self,
        scene: Scene,
        robots: np.ndarray,
        stamps: np.ndarray,
        hit_owner: np.ndarray,
        hit_index: np.ndarray,
        time_index: np.ndarray | None = None,
    ) -> np.ndarray:
        """Beams hitting robot j's housing while j's head points back at the scanner.

        Only owners with a modelled head (index < both ``n_robots`` and ``scene.n_robots``)
        interfere: circles of sensorless robots (e.g. an intruder) never null a beam.
        """
        cfg = self.config
        interfered = np.zeros(hit_owner.shape, dtype=bool)
        if cfg.interference_tolerance_deg <= 0.0:
            return interfered
        n_heads = min(self.n_robots, scene.n_robots)
        scan_i, beam = np.nonzero((hit_owner >= 0) & (hit_owner < n_heads))
        if not scan_i.size:
            return interfered
        other = hit_owner[scan_i, beam]
        me = robots[scan_i]
        rate = self.rates_hz[me]
        beam_time = stamps[scan_i] - 1.0 / rate + (beam / cfg.n_beams) / rate
        head_body = self.head_angle_rad(other, beam_time)
        when = None if time_index is None else time_index[scan_i]
        my_xy, _ = scene.observer_poses(me, when)
        _, other_yaw = scene.observer_poses(other, when)
        head_world = other_yaw + head_body
        # The head sits at the centre of the housing the beam hit.
        to_me = my_xy - scene.circle_xy[hit_index[scan_i, beam]]
        bearing_to_me = np.arctan2(to_me[:, 1], to_me[:, 0])
        tolerance = np.deg2rad(cfg.interference_tolerance_deg)
        aligned = np.abs(wrap_angle(head_world - bearing_to_me)) <= tolerance
        # A head pointing into its own pillar emits nothing towards us.
        head_beam = np.rint((head_body + np.pi) / cfg.beam_spacing_rad).astype(np.intp)
        aligned &= ~self.blind_mask[head_beam % cfg.n_beams]
        interfered[scan_i, beam] = aligned
        return interfered


def blind_mask(angles_rad: np.ndarray, config: LidarConfig) -> np.ndarray:
    """Beams inside the camera-pillar blind sectors of ``config``, shape like ``angles_rad``.

    Shared by the simulator and the hardware bridge, so that a beam's side of a sector edge is
    the same everywhere (their null returns are not interference: the filter has a blind factor).
    """
    centers = np.deg2rad(np.asarray(config.blind_sector_centers_deg, dtype=np.float64))
    half = 0.5 * np.deg2rad(np.asarray(config.blind_sector_widths_deg, dtype=np.float64))
    if centers.size == 0:
        return np.zeros(np.shape(angles_rad), dtype=bool)
    offset = np.abs(wrap_angle(np.asarray(angles_rad)[..., None] - centers))
    return (offset <= half).any(axis=-1)


def _expand(lo: np.ndarray, hi: np.ndarray, n_beams: int) -> tuple[np.ndarray, np.ndarray]:
    """Beam indices ``lo..hi`` of every interval, wrapped to ``[0, n_beams)``; and the counts."""
    count = np.maximum(hi - lo + 1, 0)
    total = int(count.sum())
    # Element e of interval i is lo_i + (e - first_i); np.repeat beats fancy indexing here.
    first = np.cumsum(count) - count
    beam = np.repeat(lo - first, count) + np.arange(total)
    return count, beam % n_beams


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
