"""Two 180-deg fisheye cameras (front + back = 360 deg) detecting red colour blobs: bearings only.

Model (Perera 2021, "Camera measurements"): every robot carries a red strip on its camera holder;
the colour-blob detector reports the bearing of each red blob in the robot frame, without
identity. A red circle ``t`` (a robot's strip or a red decoy) is *visible* to observer ``k`` when

* it is not the observer's own strip,
* its centre is at least ``range_min_m`` away and no farther than the range at which a fully
  lit band of its radius can still pass the blob-area test (``detectable_range_m``, capped at
  ``range_max_m``),
* the straight line between the two centres crosses no wall/box segment and passes outside
  every camera-occluding circle except the observer's own and the target's own.

Blob detection (physical, Perera 2021 "Camera measurements": 1920x1080 fisheyes covering 180 deg,
red colour threshold, blobs). A red strip of radius R and height ``strip_height_m`` at range d
covers ``A(d) = f^2 x 2 asin(R / d) x strip_height_m / d`` pixels, ``f = pixels_per_rad``
(equidistant fisheye). In each frame a fraction ``u ~ U(fill_min, 1)`` of it passes the colour
threshold, as one contiguous sub-arc at a uniform position within the strip (the lit part of a
curved strip). The blob is detected when ``u A(d) >= min_blob_area_px`` and it is not lost
(``miss_probability``), so the detection probability falls with range:
``P_d(d) = (1 - miss) clip((1 - min_area / A(d)) / (1 - fill_min), 0, 1)``
(:meth:`CameraSensor.detection_probability`; 0.95 to 3.3 m, 0.5 at 4.1 m, 0 from 4.7 m for a
robot's 5 cm strip). The bearing is the blob centroid's: the true bearing plus the sub-arc's
offset ``(s - 1/2)(1 - u) x 2 asin(R / d)``, ``s ~ U(0, 1)`` (a few tenths of a degree at 1 m,
more when closer), plus pixel quantisation ``U(-1/2, 1/2) / f``, plus optional Gaussian
``bearing_noise_std_deg``. Each frame also has ``Poisson(false_positive_rate)`` clutter
bearings, uniform on the circle; red decoys are detected like strips (false positives). Bearings
of a frame are sorted, so their order says nothing about which robot produced them.

Simplified: no partial occlusion, no lens distortion (the fisheye is equidistant and the strip
is seen side-on at the horizon), no seam between the two fisheyes, all of a frame's blobs are
seen at one instant, every red circle is one blob, and the fill fractions are independent per
frame (real lighting is correlated over time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from swarm_core.validation import check_number_fields
from swarm_env.sensors.kernels import segment_distance2, stable_order, wrap
from swarm_env.sensors.noise import table_indices
from swarm_env.sensors.scene import Scene
from swarm_env.sensors.spatial_index import build_grid, gather

#: ``observe(indexed=None)`` uses the grid from this many (observer, red circle) pairs on: a
#: 20-robot step (60 frames x ~100 red circles) is faster brute force, 100 robots (300 x 510)
#: already 1.4x faster with the grid.
INDEX_MIN_PAIRS = 50_000


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """Fisheye pair + colour-blob detector.

    Attributes
    ----------
    rate_hz : float
        Frame rate (seed: 30 fps).
    range_max_m : float
        Blobs farther than this are not tested at all: a computational bound, beyond the
        range where the area test can pass (4.7 m for a 5 cm strip, 5.2 m for a 6 cm red decoy
        at full fill). The detection probability itself falls with range through the area test.
    range_min_m : float
        Nearer blobs are out of the fisheyes' view (below the lens).
    pixels_per_rad : float
        Equidistant fisheye scale: 1920 px across 180 deg (seed: 1920x1080, 180-deg lens).
    strip_height_m : float
        Height of the red strip (and of a red decoy's red band). The seed does not give it:
        15 mm (a roll of tape), our choice, which puts the 50 % detection range at 4.1 m,
        matching the Perera 2021 study's "~3-4 m" camera range.
    min_blob_area_px : float
        Smallest blob the detector keeps, in pixels (OpenCV ``SimpleBlobDetector``'s default
        ``minArea`` = 25).
    fill_min : float
        The fraction of a strip's pixels that pass the colour threshold in a frame is uniform
        in ``[fill_min, 1]`` (shading of the curved strip, lighting; our choice 0.5). 1 gives
        ideal blobs: centroid at the strip's centre, detected wherever the area suffices.
    bearing_noise_std_deg : float
        Extra Gaussian bearing noise beyond the centroid and quantisation terms (lens
        calibration, timing). Default 0: the simulated lens is ideal. Perera 2021's hardware
        reports R_C = "25 deg" (5 deg std read as a variance), which includes such errors.
    miss_probability : float
        Chance a blob that passes the area test is still lost in a frame (motion blur,
        glare); our choice.
    false_positive_rate : float
        Mean number of clutter bearings per frame (Poisson), uniform on the circle.
    """

    rate_hz: float = 30.0
    range_max_m: float = 5.5
    range_min_m: float = 0.1
    pixels_per_rad: float = 1920.0 / math.pi
    strip_height_m: float = 0.015
    min_blob_area_px: float = 25.0
    fill_min: float = 0.5
    bearing_noise_std_deg: float = 0.0
    miss_probability: float = 0.05
    false_positive_rate: float = 0.1

    def __post_init__(self) -> None:
        check_number_fields(self)
        if not self.rate_hz > 0.0:
            raise ValueError(f"CameraConfig.rate_hz must be > 0, got {self.rate_hz!r}")
        # > 0: the robot's own red strip is at range 0 (0 took > 20 s for three steps).
        if not self.range_min_m > 0.0:
            raise ValueError(f"CameraConfig.range_min_m must be > 0, got {self.range_min_m!r}")
        if not self.range_max_m > self.range_min_m:
            raise ValueError(
                f"CameraConfig.range_max_m must exceed range_min_m={self.range_min_m}, got "
                f"{self.range_max_m!r}"
            )
        if not (math.isfinite(self.range_max_m) and self.range_max_m <= 100.0):
            raise ValueError(
                f"CameraConfig.range_max_m must be finite and <= 100 m, got {self.range_max_m!r}"
            )
        # <= 180: beyond a half turn a bearing carries no information (1e300 put bearings of
        # 1e298 rad into the filters, which refuse them).
        if not 0.0 <= self.bearing_noise_std_deg <= 180.0:
            raise ValueError(
                "CameraConfig.bearing_noise_std_deg must be in [0, 180], got "
                f"{self.bearing_noise_std_deg!r}"
            )
        for name in ("pixels_per_rad", "strip_height_m", "min_blob_area_px"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"CameraConfig.{name} must be finite and > 0, got {value!r}")
        if not 0.0 <= self.fill_min <= 1.0:
            raise ValueError(f"CameraConfig.fill_min must be in [0, 1], got {self.fill_min!r}")
        if not 0.0 <= self.miss_probability <= 1.0:
            raise ValueError(
                f"CameraConfig.miss_probability must be in [0, 1], got {self.miss_probability!r}"
            )
        # Cost guard: every false blob is drawn, stored and filtered each frame (1e7 per
        # frame grew memory without bound).
        if not 0.0 <= self.false_positive_rate <= 1000.0:
            raise ValueError(
                "CameraConfig.false_positive_rate must be in [0, 1000] blobs per frame, got "
                f"{self.false_positive_rate!r}"
            )


@dataclass(frozen=True, slots=True)
class CameraBatch:
    """One frame for each of K observers.

    Attributes
    ----------
    robots : ndarray, shape (K,), int
        Observing robots.
    bearings : list of ndarray
        K arrays of shape (M_k,): detected bearings in the observer's frame, ``[-pi, pi)``,
        sorted.
    sources : list of ndarray
        K int arrays aligned with ``bearings``: the scene circle index of the red blob behind
        each bearing, -1 for clutter (ground truth, for diagnostics and tests).
    visible : ndarray, shape (K, N), bool
        Robot j's strip had line of sight and was within its detectable range
        (``CameraSensor.detectable_range_m``) from observer k (before fill, miss and noise).
        N = number of circle owners (``scene.n_robots``, or more if sensorless robots such as an
        intruder own circles).
    target_index : ndarray, shape (T,), int
        Scene circle index of every red circle.
    pair_bounds : ndarray, shape (K + 1,), int
        The visible (observer, red circle) pairs, row-major: frame k's are
        ``pair_target[pair_bounds[k]:pair_bounds[k + 1]]``.
    pair_target : ndarray, shape (V,), int
        Column (index into ``target_index``) of each visible pair, ascending within a frame.
    """

    robots: np.ndarray
    bearings: list[np.ndarray]
    sources: list[np.ndarray]
    visible: np.ndarray
    target_index: np.ndarray
    pair_bounds: np.ndarray
    pair_target: np.ndarray

    @property
    def target_visible(self) -> np.ndarray:
        """(K, T) bool: same as ``visible`` per red circle, including red decoys (owner -1).

        Built from the pairs on each access (K x T grows as N^2 with the swarm; the
        simulator never needs it)."""
        out = np.zeros((self.robots.size, self.target_index.size), dtype=bool)
        rows = np.repeat(np.arange(self.robots.size), np.diff(self.pair_bounds))
        out[rows, self.pair_target] = True
        return out


class CameraSensor:
    """Camera model for a whole swarm: one vectorised :meth:`observe` for many observers.

    Parameters
    ----------
    config : CameraConfig, optional
    """

    def __init__(self, config: CameraConfig | None = None) -> None:
        self.config = config if config is not None else CameraConfig()
        self._reach_cache: tuple[bytes | None, np.ndarray] = (None, np.empty(0))

    def blob_area_px(self, range_m: np.ndarray | float, radius_m: np.ndarray | float):
        """Pixels of a fully lit red band of radius ``radius_m`` at ``range_m`` (broadcast)."""
        cfg = self.config
        d = np.asarray(range_m, dtype=np.float64)
        width = 2.0 * np.arcsin(np.minimum(np.asarray(radius_m, dtype=np.float64) / d, 1.0))
        return cfg.pixels_per_rad**2 * width * (cfg.strip_height_m / d)

    def detectable_range_m(self, radius_m: np.ndarray | float) -> np.ndarray:
        """Range beyond which a red band of radius ``radius_m`` cannot pass the area test (even
        fully lit), capped at ``range_max_m``: the visibility test's reach, m.

        An upper bound of the exact root of ``A(d) = min_blob_area_px``: with
        ``d0 = f sqrt(2 R h / min_area)`` (the small-angle root) and ``asin(x) <= x /
        sqrt(1 - x^2)``, ``A(d0 (1 - (R / d0)^2)^(-1/4)) <= min_area``.
        """
        cfg = self.config
        radius = np.asarray(radius_m, dtype=np.float64)
        d0 = cfg.pixels_per_rad * np.sqrt(2.0 * radius * cfg.strip_height_m / cfg.min_blob_area_px)
        x2 = np.minimum((radius / np.maximum(d0, 1e-12)) ** 2, 0.99)
        bound = np.where(x2 < 0.5, d0 / (1.0 - x2) ** 0.25 * (1.0 + 1e-9), np.inf)
        return np.minimum(bound, cfg.range_max_m)

    def detection_probability(self, range_m: np.ndarray | float, radius_m: np.ndarray | float):
        """Probability that a visible red band of radius ``radius_m`` at ``range_m`` (m,
        broadcast) is detected in a frame: ``(1 - miss) P(u A >= min_area)``, ``u ~
        U(fill_min, 1)``. The analytic curve the simulated detections follow."""
        cfg = self.config
        need = cfg.min_blob_area_px / self.blob_area_px(range_m, radius_m)
        if cfg.fill_min == 1.0:
            passed = (need <= 1.0).astype(np.float64)
        else:
            passed = np.clip((1.0 - need) / (1.0 - cfg.fill_min), 0.0, 1.0)
        return (1.0 - cfg.miss_probability) * passed

    def visibility(
        self, scene: Scene, robots: np.ndarray, time_index: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which red circles each observer can see, and their true bearings.

        Parameters
        ----------
        scene : Scene
        robots : ndarray, shape (K,), int
        time_index : ndarray, shape (K,), int, optional
            Instant of each frame in a time-stacked scene (see :class:`Scene`).

        Returns
        -------
        target_index : ndarray, shape (T,), int
            Scene circle indices of the red circles.
        visible : ndarray, shape (K, T), bool
        bearing_rad : ndarray, shape (K, T)
            True bearing of each red circle in each observer's frame, also where not visible
            (in a time-stacked scene: for the circles of the frame's own instant and the static
            ones; 0 for other instants' circles).
        """
        return self._geometry(scene, robots, time_index)[:3]

    def _geometry(self, scene, robots, time_index):
        """:meth:`visibility` plus the (K, T) observer-to-circle distances, m (valid where
        visible)."""
        cfg = self.config
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        when, n_instants, frame_time = _instants(scene, robots.size, time_index)
        if time_index is not None:
            time_index = np.asarray(time_index, dtype=np.intp).reshape(-1)
        target = np.flatnonzero(np.asarray(scene.circle_red, dtype=bool))
        # Occluders grouped by instant: static ones first, then instant 0, 1, ...
        occ = np.flatnonzero(np.asarray(scene.circle_camera_occluder, dtype=bool))
        occ = occ[np.argsort(when[occ], kind="stable")]
        groups = np.searchsorted(when[occ], np.arange(-1, n_instants + 1))
        origin, yaw = scene.observer_poses(robots, time_index)
        visible = np.empty((robots.size, target.size), dtype=bool)
        bearing = np.empty((robots.size, target.size))
        dist = np.empty((robots.size, target.size))
        _visibility_kernel(
            np.ascontiguousarray(origin, dtype=np.float64),
            np.ascontiguousarray(yaw, dtype=np.float64),
            robots,
            frame_time,
            np.ascontiguousarray(scene.circle_xy, dtype=np.float64),
            np.asarray(scene.circle_radius_m, dtype=np.float64),
            np.asarray(scene.circle_owner, dtype=np.intp),
            when,
            target,
            occ,
            groups,
            np.ascontiguousarray(scene.segment_a, dtype=np.float64).reshape(-1, 2),
            np.ascontiguousarray(scene.segment_b, dtype=np.float64).reshape(-1, 2),
            cfg.range_min_m**2,
            self._reach2(np.asarray(scene.circle_radius_m, dtype=np.float64)[target]),
            visible,
            bearing,
            dist,
        )
        return target, visible, bearing, dist

    def _reach2(self, radius: np.ndarray) -> np.ndarray:
        """Squared :meth:`detectable_range_m` of ``radius``; the radii of a layout do not
        change from call to call, so the last answer is kept."""
        key = radius.tobytes()
        if self._reach_cache[0] != key:
            self._reach_cache = (key, self.detectable_range_m(radius) ** 2)
        return self._reach_cache[1]

    def observe(
        self,
        scene: Scene,
        robots: np.ndarray,
        rng: np.random.Generator,
        time_index: np.ndarray | None = None,
        indexed: bool | None = None,
    ) -> CameraBatch:
        """One frame for each observer in ``robots``.

        Parameters
        ----------
        scene : Scene
            World snapshot (not modified).
        robots : ndarray, shape (K,), int
            Observers (indices into ``scene.robot_xy``).
        rng : numpy.random.Generator
            Draws, in this order: 4 V 16-bit uniforms (``noise.table_indices``: fill fraction,
            sub-arc position, pixel quantisation, miss) and, if ``bearing_noise_std_deg > 0``,
            V bearing normals, for the V visible (observer, target) pairs in row-major order;
            K Poisson clutter counts, then the clutter bearings.
        time_index : ndarray, shape (K,), int, optional
            Instant of each frame in a time-stacked scene (see :class:`Scene`).
        indexed : bool, optional
            ``True``: test only the red circles, occluders and segments near each observer,
            through a uniform grid (:mod:`swarm_env.sensors.spatial_index`). ``False``: the
            brute-force :meth:`visibility` over every (observer, red circle) pair, the
            reference (bit-identical, O(K x T) in time and memory). ``None`` (default): the
            grid from :data:`INDEX_MIN_PAIRS` (observer, red circle) pairs on.

        Returns
        -------
        CameraBatch
        """
        cfg = self.config
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        if robots.size and (robots.min() < 0 or robots.max() >= scene.n_robots):
            raise ValueError(
                f"observe: robots must index the scene's {scene.n_robots} robots, got "
                f"{robots.tolist()}"
            )
        n_obs = robots.size
        if time_index is not None:
            time_index = np.asarray(time_index, dtype=np.intp).reshape(-1)
        if indexed is None:
            n_red = int(np.count_nonzero(scene.circle_red))
            indexed = n_obs * n_red >= INDEX_MIN_PAIRS
        if indexed:
            target, bounds, pair_target, pair_bearing, pair_dist = self._pairs(
                scene, robots, time_index
            )
        else:
            target, visible, bearing, dist = self._geometry(scene, robots, time_index)
            rows, pair_target = np.nonzero(visible)  # row-major, as the indexed pairs
            bounds = np.searchsorted(rows, np.arange(n_obs + 1)).astype(np.intp)
            pair_bearing, pair_dist = bearing[rows, pair_target], dist[rows, pair_target]

        # Draws only for the visible (observer, target) pairs, in row-major order.
        n_visible = int(pair_target.size)
        # 16-bit uniforms, four per raw 64-bit draw (noise.table_indices): ~4x cheaper than
        # Generator.random and fine enough for a fill fraction, a position and a miss.
        draws = table_indices(rng, 4 * n_visible).reshape(4, n_visible)
        if cfg.bearing_noise_std_deg > 0.0:
            extra = rng.standard_normal(n_visible) * np.deg2rad(cfg.bearing_noise_std_deg)
        else:
            extra = np.zeros(n_visible)  # no draws: the ideal lens costs nothing
        n_clutter = rng.poisson(cfg.false_positive_rate, size=n_obs)
        clutter = rng.uniform(-np.pi, np.pi, size=int(n_clutter.sum()))

        owner = np.asarray(scene.circle_owner, dtype=np.intp)
        n_owners = max(scene.n_robots, int(owner.max()) + 1 if owner.size else 0)
        values, source, frame_bounds, robot_visible = _frames_kernel(
            bounds,
            pair_target,
            pair_bearing,
            target,
            owner,
            pair_dist,
            np.asarray(scene.circle_radius_m, dtype=np.float64),
            draws,
            extra,
            cfg.pixels_per_rad,
            cfg.strip_height_m,
            cfg.min_blob_area_px,
            cfg.fill_min,
            cfg.miss_probability,
            n_clutter.astype(np.intp),
            clutter,
            n_owners,
        )
        values.setflags(write=False)  # the per-frame slices become read-only views
        cuts = frame_bounds.tolist()
        return CameraBatch(
            robots=robots,
            # Slicing, not np.split: np.split costs ~3 us per piece.
            bearings=[values[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True)],
            sources=[source[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True)],
            visible=robot_visible,
            target_index=target,
            pair_bounds=bounds,
            pair_target=pair_target,
        )

    def _pairs(self, scene, robots, time_index):
        """The visible (observer, red circle) pairs through the grid index, row-major.

        Returns ``target`` (T,) scene circle indices of the red circles, ``bounds`` (K + 1,),
        and per visible pair its column ``pair_target`` (V,) in ``target``, true bearing
        ``pair_bearing`` (V,) rad and distance ``pair_dist`` (V,) m: exactly the non-zero
        entries of :meth:`_geometry`'s (K, T) arrays, without building them.
        """
        when, _, frame_time = _instants(scene, robots.size, time_index)
        xy = np.ascontiguousarray(scene.circle_xy, dtype=np.float64)
        radius = np.asarray(scene.circle_radius_m, dtype=np.float64)
        target = np.flatnonzero(np.asarray(scene.circle_red, dtype=bool))
        occ = np.flatnonzero(np.asarray(scene.circle_camera_occluder, dtype=bool))
        reach2 = self._reach2(radius[target])
        max_reach = float(np.sqrt(reach2.max(initial=0.0)))
        n_slots = int(when.max(initial=-1)) + 2  # slot 0: static, t + 1: instant t
        targets = build_grid(xy[target], radius[target], when[target] + 1, n_slots)
        occluders = build_grid(xy[occ], radius[occ], when[occ] + 1, n_slots)
        # Grid items index `target` / `occ`; the kernel wants scene indices for occluders.
        occluders = (occluders[0], occ[occluders[1]], *occluders[2:])
        seg_a = np.ascontiguousarray(scene.segment_a, dtype=np.float64).reshape(-1, 2)
        seg_b = np.ascontiguousarray(scene.segment_b, dtype=np.float64).reshape(-1, 2)
        segments = build_grid(0.5 * (seg_a + seg_b), 0.5 * np.hypot(*(seg_b - seg_a).T))
        origin, yaw = scene.observer_poses(robots, time_index)
        bounds, pair_target, pair_bearing, pair_dist = _pairs_kernel(
            np.ascontiguousarray(origin, dtype=np.float64),
            np.ascontiguousarray(yaw, dtype=np.float64),
            robots,
            frame_time,
            (xy, radius, np.asarray(scene.circle_owner, dtype=np.intp), when),
            target,
            (targets, occluders, segments, n_slots, max_reach),
            seg_a,
            seg_b,
            self.config.range_min_m**2,
            reach2,
        )
        return target, bounds, pair_target, pair_bearing, pair_dist


@njit(cache=True)
def _frames_kernel(
    pair_bounds,
    pair_target,
    pair_bearing,
    target,
    circle_owner,
    pair_dist,
    circle_radius,
    draws,
    extra,
    pixels_per_rad,
    strip_height,
    min_area,
    fill_min,
    miss,
    n_clutter,
    clutter,
    n_owners,
):
    """Assemble K frames from the geometry and the draws.

    The V visible (observer, red circle) pairs, row-major: frame k's are
    ``pair_bounds[k]:pair_bounds[k + 1]`` (``pair_bounds`` (K + 1,)), with their column
    ``pair_target`` (V,) in ``target`` (T,) (circle indices), true bearing ``pair_bearing``
    (V,) rad and distance ``pair_dist`` (V,) m; ``circle_radius`` (C,) m; ``draws`` (4, V)
    uint16 levels of uniforms ``(i + 1/2) / 2^16`` (fill, sub-arc
    position, pixel rounding, miss) and
    ``extra`` (V,) rad Gaussian noise for the V visible pairs in row-major order; the blob
    model's scalars (see :class:`CameraConfig`);
    ``n_clutter`` (K,) and ``clutter`` (sum,) rad. Returns the bearings (M,) rad and their
    sources (M,) (circle index, -1 for clutter), sorted by bearing within each frame,
    ``bounds`` (K + 1,) of the frames, and ``robot_visible`` (K, n_owners).
    """
    n_obs = pair_bounds.shape[0] - 1
    n_visible = draws.shape[1]
    # Blob-area test and centroid offset per visible pair, in row-major order.
    hit = np.empty(n_visible, dtype=np.bool_)
    noise = np.empty(n_visible)
    f2h = pixels_per_rad * pixels_per_rad * strip_height
    level = 1.0 / 65536.0
    total = n_clutter.sum()
    for k in range(n_obs):
        for v in range(pair_bounds[k], pair_bounds[k + 1]):
            j = pair_target[v]
            d = pair_dist[v]
            width = 2.0 * math.asin(min(circle_radius[target[j]] / d, 1.0))  # strip's extent
            u_fill, u_pos, u_pix, u_miss = (
                (draws[0, v] + 0.5) * level,
                (draws[1, v] + 0.5) * level,
                (draws[2, v] + 0.5) * level,
                (draws[3, v] + 0.5) * level,
            )
            fill = fill_min + (1.0 - fill_min) * u_fill
            hit[v] = fill * f2h * width / d >= min_area and u_miss >= miss
            # Centroid of the lit sub-arc (fraction `fill`, uniform position), to a pixel.
            noise[v] = (u_pos - 0.5) * (1.0 - fill) * width
            noise[v] += (u_pix - 0.5) / pixels_per_rad + extra[v]
            total += hit[v]
    values = np.empty(total)
    source = np.empty(total, dtype=np.intp)
    bounds = np.empty(n_obs + 1, dtype=np.intp)
    robot_visible = np.zeros((n_obs, n_owners), dtype=np.bool_)
    c = pos = 0
    for k in range(n_obs):
        start = bounds[k] = pos
        for v in range(pair_bounds[k], pair_bounds[k + 1]):
            j = pair_target[v]
            owner = circle_owner[target[j]]
            if owner >= 0:
                robot_visible[k, owner] = True
            if hit[v]:
                values[pos] = wrap(pair_bearing[v] + noise[v])
                source[pos] = target[j]
                pos += 1
        for _ in range(n_clutter[k]):
            values[pos] = clutter[c]
            source[pos] = -1
            pos += 1
            c += 1
        # Bearings in order, so their order says nothing about identities (stable sort).
        order = stable_order(values[start:pos])
        values[start:pos] = values[start:pos][order]
        source[start:pos] = source[start:pos][order]
    bounds[n_obs] = pos
    return values, source, bounds, robot_visible


@njit(cache=True, parallel=True)
def _visibility_kernel(
    origin,
    yaw,
    robots,
    frame_time,
    circle_xy,
    circle_radius,
    circle_owner,
    circle_time,
    target,
    occ,
    groups,
    seg_a,
    seg_b,
    range_min2,
    reach2,
    visible,
    bearing,
    dist,
):
    """Line of sight from K observers to T red circles.

    ``origin`` (K, 2) m, ``yaw`` (K,) rad, ``robots`` (K,) and ``frame_time`` (K,) (-1: every
    circle is present) describe the frames; ``circle_*`` (C,) the scene; ``target`` (T,) and
    ``occ`` (O,) are circle indices, ``occ`` sorted by instant with ``groups`` (instants + 2,)
    its bounds: static occluders ``groups[0]:groups[1]``, instant t's
    ``groups[t + 1]:groups[t + 2]``. ``seg_a``, ``seg_b`` (S, 2) m. ``reach2`` (T,) m^2: each
    target's squared detectable range. Writes ``visible`` (K, T), ``bearing`` (K, T) rad (0 for
    targets absent at the frame's instant) and ``dist`` (K, T) m (set where present).

    A line is blocked when it properly crosses a segment, or passes closer than a circle's
    radius to its centre (closest point of the line segment) for a circle other than the
    observer's own and the target's own (the target circle, and every circle of the same robot).
    """
    n_obs, n_targets = visible.shape
    n_seg = seg_a.shape[0]
    # Segment lines as p . q = pa, with p = perp(b - a): cross(b - a, q - a) = p . q - pa.
    seg_px = seg_a[:, 1] - seg_b[:, 1]
    seg_py = seg_b[:, 0] - seg_a[:, 0]
    seg_pa = seg_px * seg_a[:, 0] + seg_py * seg_a[:, 1]
    # Frames are independent (each writes only its own output rows): parallel threads.
    for k in prange(n_obs):
        side_o = np.empty(n_seg)
        ox, oy = origin[k, 0], origin[k, 1]
        me, when = robots[k], frame_time[k]
        for s in range(n_seg):
            side_o[s] = seg_px[s] * ox + seg_py[s] * oy - seg_pa[s]  # observer's side, per frame
        for j in range(n_targets):
            c = target[j]
            if circle_time[c] >= 0 and circle_time[c] != when:
                visible[k, j] = False
                bearing[k, j] = 0.0
                continue
            dx, dy = circle_xy[c, 0] - ox, circle_xy[c, 1] - oy
            bearing[k, j] = wrap(math.atan2(dy, dx) - yaw[k])
            d2 = dx * dx + dy * dy
            dist[k, j] = math.sqrt(d2)
            t_owner = circle_owner[c]
            if t_owner == me or d2 < range_min2 or d2 > reach2[j]:
                visible[k, j] = False
                continue
            tx, ty = circle_xy[c, 0], circle_xy[c, 1]
            blocked = False
            do = -dy * ox + dx * oy
            for s in range(n_seg):
                if _wall_blocks(
                    s, s, tx, ty, dx, dy, do, side_o, seg_px, seg_py, seg_pa, seg_a, seg_b
                ):
                    blocked = True
                    break
            # Static occluders, then the moving ones of the frame's own instant.
            if not blocked:
                blocked = _circles_block(
                    occ, groups[0], groups[1], c, me, t_owner, ox, oy, dx, dy,
                    circle_xy, circle_radius, circle_owner,
                )  # fmt: skip
            if not blocked and when >= 0:
                blocked = _circles_block(
                    occ, groups[when + 1], groups[when + 2], c, me, t_owner, ox, oy, dx, dy,
                    circle_xy, circle_radius, circle_owner,
                )  # fmt: skip
            visible[k, j] = not blocked


@njit(cache=True, parallel=True)
def _pairs_kernel(
    origin, yaw, robots, frame_time, circles, target, index, seg_a, seg_b, range_min2, reach2
):
    """The visible (observer, red circle) pairs of K frames, through grid indices.

    Same inputs and tests as :func:`_visibility_kernel` (``circles`` = ``(circle_xy,
    circle_radius, circle_owner, circle_time)``), and ``index`` = ``(targets, occluders,
    segments, n_slots, max_reach)``: grids (:func:`~swarm_env.sensors.spatial_index.build_grid`)
    of the red circles (items: columns of ``target``) and of the camera occluders (items: scene
    circle indices), both in slot ``instant + 1``, of the segments, and the largest detectable
    range, m. A frame tests only the red circles, occluders and segments of the cells within
    ``max_reach``: a target farther away fails its range test, and an occluder or segment
    that blocks a sight line of length <= ``max_reach`` lies within it. The tests are the
    reference's own expressions, so the pairs are exactly its non-zero entries.

    Returns ``bounds`` (K + 1,) and per visible pair, row-major (targets ascending within a
    frame), ``pair_target`` (V,), ``pair_bearing`` (V,) rad and ``pair_dist`` (V,) m.
    """
    circle_xy, circle_radius, circle_owner, circle_time = circles
    targets, occluders, segments, n_slots, max_reach = index
    n_obs = origin.shape[0]
    # Pass 1: candidate counts (an upper bound of each frame's visible pairs).
    cap = np.empty(n_obs + 1, dtype=np.intp)
    cap[0] = 0
    for k in prange(n_obs):
        cand = np.empty(targets[1].shape[0], dtype=np.intp)
        cap[k + 1] = _gather_slots(targets, n_slots, frame_time[k], origin[k], max_reach, cand)
    offset = np.cumsum(cap)
    n_pairs = np.zeros(n_obs, dtype=np.intp)
    slot_target = np.empty(offset[n_obs], dtype=np.intp)
    slot_bearing = np.empty(offset[n_obs])
    slot_dist = np.empty(offset[n_obs])
    # Pass 2: the tests, each frame writing its visible pairs at the start of its own slice.
    for k in prange(n_obs):
        ox, oy = origin[k, 0], origin[k, 1]
        me, when = robots[k], frame_time[k]
        cand = np.empty(targets[1].shape[0], dtype=np.intp)
        n_cand = _gather_slots(targets, n_slots, when, origin[k], max_reach, cand)
        cand = np.sort(cand[:n_cand])  # row-major: targets ascending
        occ = np.empty(occluders[1].shape[0], dtype=np.intp)
        n_occ = _gather_slots(occluders, n_slots, when, origin[k], max_reach, occ)
        # The local occluders, contiguous and nearest first (by |w| - r, w = centre - origin):
        # one that blocks a sight line of length L has |w| - r < L, so a target's scan over
        # them stops at the first beyond it.
        near = np.empty(n_occ)
        for g in range(n_occ):
            o = occ[g]
            wx, wy = circle_xy[o, 0] - ox, circle_xy[o, 1] - oy
            near[g] = math.sqrt(wx * wx + wy * wy) - circle_radius[o]
        order = np.argsort(near)
        occ_near = near[order]
        occ_id = occ[:n_occ][order]
        occ_wx = np.empty(n_occ)
        occ_wy = np.empty(n_occ)
        occ_r2 = np.empty(n_occ)
        occ_owner = np.empty(n_occ, dtype=np.intp)
        for g in range(n_occ):
            o = occ_id[g]
            occ_wx[g] = circle_xy[o, 0] - ox
            occ_wy[g] = circle_xy[o, 1] - oy
            occ_r2[g] = circle_radius[o] * circle_radius[o]
            occ_owner[g] = circle_owner[o]
        seg = np.empty(segments[1].shape[0], dtype=np.intp)
        n_seg = gather(segments, 0, ox, oy, max_reach, seg, 0)
        # Segment lines as p . q = pa (as _visibility_kernel), for the local segments.
        seg_px = np.empty(n_seg)
        seg_py = np.empty(n_seg)
        seg_pa = np.empty(n_seg)
        side_o = np.empty(n_seg)
        for q in range(n_seg):
            s = seg[q]
            seg_px[q] = seg_a[s, 1] - seg_b[s, 1]
            seg_py[q] = seg_b[s, 0] - seg_a[s, 0]
            seg_pa[q] = seg_px[q] * seg_a[s, 0] + seg_py[q] * seg_a[s, 1]
            side_o[q] = seg_px[q] * ox + seg_py[q] * oy - seg_pa[q]
        m = offset[k]
        for q in range(n_cand):
            j = cand[q]
            c = target[j]
            if circle_time[c] >= 0 and circle_time[c] != when:
                continue
            dx, dy = circle_xy[c, 0] - ox, circle_xy[c, 1] - oy
            d2 = dx * dx + dy * dy
            t_owner = circle_owner[c]
            if t_owner == me or d2 < range_min2 or d2 > reach2[j]:
                continue
            tx, ty = circle_xy[c, 0], circle_xy[c, 1]
            blocked = False
            do = -dy * ox + dx * oy
            for g in range(n_seg):
                s = seg[g]
                if _wall_blocks(
                    g, s, tx, ty, dx, dy, do, side_o, seg_px, seg_py, seg_pa, seg_a, seg_b
                ):
                    blocked = True
                    break
            if not blocked:
                # As _circles_block, over the occluders nearer than the target (the margin
                # covers the rounding of |w| - r and of the length).
                length = math.sqrt(d2)
                stop = length * (1.0 + 1e-9) + 1e-9
                d_len2 = dx * dx + dy * dy
                for g in range(n_occ):
                    if occ_near[g] > stop:
                        break
                    o_owner = occ_owner[g]
                    if occ_id[g] == c or o_owner == me or (t_owner >= 0 and o_owner == t_owner):
                        continue
                    wx, wy = occ_wx[g], occ_wy[g]
                    cross = wx * dy - wy * dx
                    if cross * cross >= occ_r2[g] * d_len2:
                        continue
                    if segment_distance2(wx, wy, dx, dy) < occ_r2[g]:
                        blocked = True
                        break
            if not blocked:
                slot_target[m] = j
                slot_bearing[m] = wrap(math.atan2(dy, dx) - yaw[k])
                slot_dist[m] = math.sqrt(d2)
                m += 1
        n_pairs[k] = m - offset[k]
    # Pass 3: the frames' pairs, contiguous.
    bounds = np.empty(n_obs + 1, dtype=np.intp)
    bounds[0] = 0
    for k in range(n_obs):
        bounds[k + 1] = bounds[k] + n_pairs[k]
    pair_target = np.empty(bounds[n_obs], dtype=np.intp)
    pair_bearing = np.empty(bounds[n_obs])
    pair_dist = np.empty(bounds[n_obs])
    for k in range(n_obs):
        src, dst = offset[k], bounds[k]
        for v in range(n_pairs[k]):
            pair_target[dst + v] = slot_target[src + v]
            pair_bearing[dst + v] = slot_bearing[src + v]
            pair_dist[dst + v] = slot_dist[src + v]
    return bounds, pair_target, pair_bearing, pair_dist


@njit(cache=True, inline="always")
def _gather_slots(grid, n_slots, when, origin, radius, out):
    """The grid's shapes near ``origin`` (2,) that exist at instant ``when`` (-1: at every
    instant): the static slot 0 and slot ``when + 1`` (every slot if ``when`` < 0)."""
    n = gather(grid, 0, origin[0], origin[1], radius, out, 0)
    for slot in range(1, n_slots):
        if when < 0 or slot == when + 1:
            n = gather(grid, slot, origin[0], origin[1], radius, out, n)
    return n


@njit(cache=True, inline="always")
def _wall_blocks(g, s, tx, ty, dx, dy, do, side_o, seg_px, seg_py, seg_pa, seg_a, seg_b):
    """Whether wall segment ``s`` (row ``g`` of the per-observer line tests ``side_o``,
    ``seg_px``, ``seg_py``, ``seg_pa``) blocks the sight line ``o -> t`` to the target
    ``t = (tx, ty)``, with ``d = t - o`` and ``do = d x o`` (m^2)."""
    # Observer and target strictly on opposite sides of the segment's line ...
    if side_o[g] * (seg_px[g] * tx + seg_py[g] * ty - seg_pa[g]) >= 0.0:
        return False
    # ... and the segment's end points strictly on opposite sides of the sight line.
    side_a = -dy * seg_a[s, 0] + dx * seg_a[s, 1] - do
    side_b = -dy * seg_b[s, 0] + dx * seg_b[s, 1] - do
    return side_a * side_b < 0.0


@njit(cache=True, inline="always")
def _circles_block(
    occ, lo, hi, c, me, t_owner, ox, oy, dx, dy, circle_xy, circle_radius, circle_owner
):
    """Whether occluders ``occ[lo:hi]`` block the sight line ``o -> o + d`` to circle ``c``."""
    for g in range(lo, hi):
        o = occ[g]
        o_owner = circle_owner[o]
        if o == c or o_owner == me or (t_owner >= 0 and o_owner == t_owner):
            continue
        r2 = circle_radius[o] * circle_radius[o]
        wx, wy = circle_xy[o, 0] - ox, circle_xy[o, 1] - oy
        # Cheap reject first: the line itself passes at least r away (cross^2 >= r^2 |d|^2).
        cross = wx * dy - wy * dx
        if cross * cross >= r2 * (dx * dx + dy * dy):
            continue
        if segment_distance2(wx, wy, dx, dy) < r2:
            return True
    return False


def _instants(scene: Scene, n_frames: int, time_index) -> tuple[np.ndarray, int, np.ndarray]:
    """``(when (C,), n_instants, frame_time (n_frames,))``: each circle's instant and each
    frame's, in a time-stacked scene; without one, every circle exists at every instant
    (``when = frame_time = -1``, the observers' poses are at instant 0)."""
    if scene.circle_time is not None and time_index is not None:
        time_index = np.asarray(time_index, dtype=np.intp).reshape(-1)
        when = np.asarray(scene.circle_time, dtype=np.intp)
        n_instants = (
            scene.robot_xy.shape[0] if scene.robot_xy.ndim == 3 else int(when.max(initial=0)) + 1
        )
        _check_instants(n_instants, time_index)
        return when, n_instants, time_index
    n_circles = scene.circle_xy.shape[0]
    return (
        np.full(n_circles, -1, dtype=np.intp),
        0,
        np.full(n_frames, -1, dtype=np.intp),
    )


def _check_instants(n_instants: int, time_index: np.ndarray) -> None:
    if time_index.size and (time_index.min() < 0 or time_index.max() >= n_instants):
        raise ValueError(
            f"time_index must be in [0, {n_instants}) (the scene's instants), got "
            f"{time_index.tolist()}"
        )
