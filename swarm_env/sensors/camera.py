"""Two 180-deg fisheye cameras (front + back = 360 deg) detecting red colour blobs: bearings only.

Model (seed 000, "Camera measurements"): every robot carries a red strip on its camera holder;
the colour-blob detector reports the bearing of each red blob in the robot frame, without
identity. A red circle ``t`` (a robot's strip or a red decoy) is *visible* to observer ``k`` when

* it is not the observer's own strip,
* its centre is within ``[range_min_m, range_max_m]`` (seed: ~3-4 m),
* the straight line between the two centres crosses no wall/box segment and passes outside
  every camera-occluding circle except the observer's own and the target's own.

A visible blob is detected with probability ``1 - miss_probability`` and reported at its true
bearing plus Gaussian noise (sigma 5 deg: the seed's "25 deg" R_C read as a variance). Each frame
also has ``Poisson(false_positive_rate)`` clutter bearings, uniform on the circle. Bearings of a
frame are sorted, so their order says nothing about which robot produced them.

Simplified: blobs are points (no partial occlusion, no size-dependent detection, no lens
distortion or seam between the two fisheyes), all of a frame's blobs are seen at one instant,
and every red circle is one blob.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from swarm_env.sensors.kernels import segment_distance2, stable_order, wrap
from swarm_env.world.scene import Scene


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """Fisheye pair + colour-blob detector.

    Attributes
    ----------
    rate_hz : float
        Frame rate (seed: 30 fps).
    range_max_m : float
        Farthest detectable blob (seed: "~3-4 m").
    range_min_m : float
        Nearer blobs are out of the fisheyes' view (below the lens).
    bearing_noise_std_deg : float
        Gaussian bearing noise (seed: R_C = 25 deg^2).
    miss_probability : float
        Chance a visible blob is not detected in a frame.
    false_positive_rate : float
        Mean number of clutter bearings per frame (Poisson), uniform on the circle.
    """

    rate_hz: float = 30.0
    range_max_m: float = 4.0
    range_min_m: float = 0.1
    bearing_noise_std_deg: float = 5.0
    miss_probability: float = 0.05
    false_positive_rate: float = 0.1

    def __post_init__(self) -> None:
        if not self.rate_hz > 0.0:
            raise ValueError(f"CameraConfig.rate_hz must be > 0, got {self.rate_hz!r}")
        if not self.range_min_m >= 0.0:
            raise ValueError(f"CameraConfig.range_min_m must be >= 0, got {self.range_min_m!r}")
        if not self.range_max_m > self.range_min_m:
            raise ValueError(
                f"CameraConfig.range_max_m must exceed range_min_m={self.range_min_m}, got "
                f"{self.range_max_m!r}"
            )
        if not self.bearing_noise_std_deg >= 0.0:
            raise ValueError(
                "CameraConfig.bearing_noise_std_deg must be >= 0, got "
                f"{self.bearing_noise_std_deg!r}"
            )
        if not 0.0 <= self.miss_probability <= 1.0:
            raise ValueError(
                f"CameraConfig.miss_probability must be in [0, 1], got {self.miss_probability!r}"
            )
        if not self.false_positive_rate >= 0.0:
            raise ValueError(
                f"CameraConfig.false_positive_rate must be >= 0, got {self.false_positive_rate!r}"
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
        Robot j's strip had line of sight and range from observer k (before miss and noise).
        N = number of circle owners (``scene.n_robots``, or more if sensorless robots such as an
        intruder own circles).
    target_index : ndarray, shape (T,), int
        Scene circle index of every red circle.
    target_visible : ndarray, shape (K, T), bool
        Same as ``visible`` per red circle, including red decoys (owner -1).
    """

    robots: np.ndarray
    bearings: list[np.ndarray]
    sources: list[np.ndarray]
    visible: np.ndarray
    target_index: np.ndarray
    target_visible: np.ndarray


class CameraSensor:
    """Camera model for a whole swarm: one vectorised :meth:`observe` for many observers.

    Parameters
    ----------
    config : CameraConfig, optional
    """

    def __init__(self, config: CameraConfig | None = None) -> None:
        self.config = config if config is not None else CameraConfig()

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
        cfg = self.config
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        n_circles = scene.circle_xy.shape[0]
        if scene.circle_time is not None and time_index is not None:
            time_index = np.asarray(time_index, dtype=np.intp).reshape(-1)
            when = np.asarray(scene.circle_time, dtype=np.intp)
            n_instants = (
                scene.robot_xy.shape[0]
                if scene.robot_xy.ndim == 3
                else int(when.max(initial=0)) + 1
            )
            _check_instants(n_instants, time_index)
            frame_time = time_index
        else:
            # Every circle exists at every instant (the observers' poses are at instant 0).
            when = np.full(n_circles, -1, dtype=np.intp)
            n_instants, frame_time = 0, np.full(robots.size, -1, dtype=np.intp)
        target = np.flatnonzero(np.asarray(scene.circle_red, dtype=bool))
        # Occluders grouped by instant: static ones first, then instant 0, 1, ...
        occ = np.flatnonzero(np.asarray(scene.circle_camera_occluder, dtype=bool))
        occ = occ[np.argsort(when[occ], kind="stable")]
        groups = np.searchsorted(when[occ], np.arange(-1, n_instants + 1))
        origin, yaw = scene.observer_poses(robots, time_index)
        visible = np.empty((robots.size, target.size), dtype=bool)
        bearing = np.empty((robots.size, target.size))
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
            cfg.range_max_m**2,
            visible,
            bearing,
        )
        return target, visible, bearing

    def observe(
        self,
        scene: Scene,
        robots: np.ndarray,
        rng: np.random.Generator,
        time_index: np.ndarray | None = None,
    ) -> CameraBatch:
        """One frame for each observer in ``robots``.

        Parameters
        ----------
        scene : Scene
            World snapshot (not modified).
        robots : ndarray, shape (K,), int
            Observers (indices into ``scene.robot_xy``).
        rng : numpy.random.Generator
            Draws, in this order: V miss uniforms and V bearing normals for the V visible
            (observer, target) pairs in row-major order, K Poisson clutter counts, then the
            clutter bearings.
        time_index : ndarray, shape (K,), int, optional
            Instant of each frame in a time-stacked scene (see :class:`Scene`).

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
        target, visible, bearing = self.visibility(scene, robots, time_index)

        # Draws only for the visible (observer, target) pairs, in row-major order.
        n_visible = int(np.count_nonzero(visible))
        hit = rng.random(n_visible) >= cfg.miss_probability
        noise = rng.standard_normal(n_visible) * np.deg2rad(cfg.bearing_noise_std_deg)
        n_clutter = rng.poisson(cfg.false_positive_rate, size=n_obs)
        clutter = rng.uniform(-np.pi, np.pi, size=int(n_clutter.sum()))

        owner = np.asarray(scene.circle_owner, dtype=np.intp)
        n_owners = max(scene.n_robots, int(owner.max()) + 1 if owner.size else 0)
        values, source, bounds, robot_visible = _frames_kernel(
            visible,
            bearing,
            target,
            owner,
            hit,
            noise,
            n_clutter.astype(np.intp),
            clutter,
            n_owners,
        )
        values.setflags(write=False)  # the per-frame slices become read-only views
        bounds = bounds.tolist()
        return CameraBatch(
            robots=robots,
            # Slicing, not np.split: np.split costs ~3 us per piece.
            bearings=[values[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)],
            sources=[source[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)],
            visible=robot_visible,
            target_index=target,
            target_visible=visible,
        )


@njit(cache=True)
def _frames_kernel(
    visible, bearing, target, circle_owner, hit, noise, n_clutter, clutter, n_owners
):
    """Assemble K frames from the geometry and the draws.

    ``visible``, ``bearing`` (K, T) from :meth:`CameraSensor.visibility`; ``target`` (T,)
    circle indices; ``hit``, ``noise`` (V,) rad for the V visible pairs in row-major order;
    ``n_clutter`` (K,) and ``clutter`` (sum,) rad. Returns the bearings (M,) rad and their
    sources (M,) (circle index, -1 for clutter), sorted by bearing within each frame,
    ``bounds`` (K + 1,) of the frames, and ``robot_visible`` (K, n_owners).
    """
    n_obs, n_targets = visible.shape
    total = n_clutter.sum()
    for v in range(hit.shape[0]):
        total += hit[v]
    values = np.empty(total)
    source = np.empty(total, dtype=np.intp)
    bounds = np.empty(n_obs + 1, dtype=np.intp)
    robot_visible = np.zeros((n_obs, n_owners), dtype=np.bool_)
    v = c = pos = 0
    for k in range(n_obs):
        start = bounds[k] = pos
        for j in range(n_targets):
            if not visible[k, j]:
                continue
            owner = circle_owner[target[j]]
            if owner >= 0:
                robot_visible[k, owner] = True
            if hit[v]:
                values[pos] = wrap(bearing[k, j] + noise[v])
                source[pos] = target[j]
                pos += 1
            v += 1
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
    range_max2,
    visible,
    bearing,
):
    """Line of sight from K observers to T red circles.

    ``origin`` (K, 2) m, ``yaw`` (K,) rad, ``robots`` (K,) and ``frame_time`` (K,) (-1: every
    circle is present) describe the frames; ``circle_*`` (C,) the scene; ``target`` (T,) and
    ``occ`` (O,) are circle indices, ``occ`` sorted by instant with ``groups`` (instants + 2,)
    its bounds: static occluders ``groups[0]:groups[1]``, instant t's
    ``groups[t + 1]:groups[t + 2]``. ``seg_a``, ``seg_b`` (S, 2) m. Writes ``visible`` (K, T)
    and ``bearing`` (K, T) rad (0 for targets absent at the frame's instant).

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
            t_owner = circle_owner[c]
            if t_owner == me or d2 < range_min2 or d2 > range_max2:
                visible[k, j] = False
                continue
            tx, ty = circle_xy[c, 0], circle_xy[c, 1]
            blocked = False
            do = -dy * ox + dx * oy
            for s in range(n_seg):
                # Observer and target strictly on opposite sides of the segment's line ...
                if side_o[s] * (seg_px[s] * tx + seg_py[s] * ty - seg_pa[s]) >= 0.0:
                    continue
                # ... and the segment's end points strictly on opposite sides of the sight line.
                side_a = -dy * seg_a[s, 0] + dx * seg_a[s, 1] - do
                side_b = -dy * seg_b[s, 0] + dx * seg_b[s, 1] - do
                if side_a * side_b < 0.0:
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


def _check_instants(n_instants: int, time_index: np.ndarray) -> None:
    if time_index.size and (time_index.min() < 0 or time_index.max() >= n_instants):
        raise ValueError(
            f"time_index must be in [0, {n_instants}) (the scene's instants), got "
            f"{time_index.tolist()}"
        )
