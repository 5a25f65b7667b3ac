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

from dataclasses import dataclass

import numpy as np

from swarm_env.sensors.geometry import sight_lines_blocked, to_body_frame, wrap_angle
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
                "CameraConfig.false_positive_rate must be >= 0, got "
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
        self, scene: Scene, robots: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which red circles each observer can see, and their true bearings.

        Parameters
        ----------
        scene : Scene
        robots : ndarray, shape (K,), int

        Returns
        -------
        target_index : ndarray, shape (T,), int
            Scene circle indices of the red circles.
        visible : ndarray, shape (K, T), bool
        bearing_rad : ndarray, shape (K, T)
            True bearing of each red circle in each observer's frame (also where not visible).
        """
        cfg = self.config
        robots = np.asarray(robots, dtype=np.intp).reshape(-1)
        owner = np.asarray(scene.circle_owner, dtype=np.intp)
        target = np.flatnonzero(np.asarray(scene.circle_red, dtype=bool))
        origin = scene.robot_xy[robots]
        tx, ty = to_body_frame(scene.circle_xy[target], origin, scene.robot_yaw[robots])
        dist2 = tx * tx + ty * ty
        t_owner = owner[target]
        visible = (t_owner[None, :] != robots[:, None]) & (dist2 >= cfg.range_min_m**2)
        visible &= dist2 <= cfg.range_max_m**2

        # Line-of-sight tests only for the (observer, target) pairs still in play.
        pair_k, pair_t = np.nonzero(visible)
        occ = np.flatnonzero(np.asarray(scene.circle_camera_occluder, dtype=bool))
        o_owner = owner[occ]
        p_owner = t_owner[pair_t]
        # A circle may block a sight line unless it belongs to the observer or to the target
        # (its own strip, or any circle of the same robot; a static target excludes only itself).
        applies = o_owner[None, :] != robots[pair_k][:, None]
        applies &= occ[None, :] != target[pair_t][:, None]
        applies &= (o_owner[None, :] != p_owner[:, None]) | (p_owner[:, None] < 0)
        blocked = sight_lines_blocked(
            origin[pair_k],
            scene.circle_xy[target[pair_t]],
            scene.segment_a,
            scene.segment_b,
            scene.circle_xy[occ],
            np.asarray(scene.circle_radius_m, dtype=np.float64)[occ],
            applies,
        )
        visible[pair_k[blocked], pair_t[blocked]] = False
        return target, visible, np.arctan2(ty, tx)

    def observe(self, scene: Scene, robots: np.ndarray, rng: np.random.Generator) -> CameraBatch:
        """One frame for each observer in ``robots``.

        Parameters
        ----------
        scene : Scene
            World snapshot (not modified).
        robots : ndarray, shape (K,), int
            Observers (indices into ``scene.robot_xy``).
        rng : numpy.random.Generator
            Draws, in this order: K*T miss uniforms, K*T bearing normals, K Poisson clutter
            counts, then the clutter bearings.

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
        target, visible, bearing = self.visibility(scene, robots)
        n_targets = target.size

        miss = rng.random((n_obs, n_targets)) < cfg.miss_probability
        noise = rng.standard_normal((n_obs, n_targets)) * np.deg2rad(cfg.bearing_noise_std_deg)
        n_clutter = rng.poisson(cfg.false_positive_rate, size=n_obs)
        clutter = rng.uniform(-np.pi, np.pi, size=int(n_clutter.sum()))

        det_obs, det_t = np.nonzero(visible & ~miss)
        obs_index = np.concatenate((det_obs, np.repeat(np.arange(n_obs), n_clutter)))
        values = wrap_angle(
            np.concatenate((bearing[det_obs, det_t] + noise[det_obs, det_t], clutter))
        )
        source = np.concatenate((target[det_t], np.full(clutter.size, -1, dtype=np.intp)))
        order = np.lexsort((values, obs_index))
        bounds = np.searchsorted(obs_index[order], np.arange(n_obs + 1)).tolist()
        values, source = values[order], source[order]

        owner = np.asarray(scene.circle_owner, dtype=np.intp)
        n_owners = max(scene.n_robots, int(owner.max()) + 1 if owner.size else 0)
        robot_visible = np.zeros((n_obs, n_owners), dtype=bool)
        vis_obs, vis_t = np.nonzero(visible)
        t_owner = owner[target[vis_t]]
        is_robot = t_owner >= 0
        robot_visible[vis_obs[is_robot], t_owner[is_robot]] = True
        return CameraBatch(
            robots=robots,
            # Slicing, not np.split: np.split costs ~3 us per piece.
            bearings=[values[a:b] for a, b in zip(bounds[:-1], bounds[1:])],
            sources=[source[a:b] for a, b in zip(bounds[:-1], bounds[1:])],
            visible=robot_visible,
            target_index=target,
            target_visible=visible,
        )

