"""A UAV's downward camera: anonymous ground positions of the UGVs under it (Stegagno 2013).

Stegagno et al. (ICRA 2013, sec. III-IV) segment marker-covered UGVs in the image
of a downward USB webcam (25 Hz) and back-projects each feature with the height sensor (eq. 2),
giving *anonymous* positions of the UGVs in the UAV's level frame ``H_0`` (x forward, y left,
the UAV's yaw; roll and pitch compensated). The output has Gaussian noise, misses (false
negatives) and false positives ("objects in the image that look like robots").

The model here produces those positions directly:

- **Footprint**: a rectangle centred under the UAV, half extents ``h tan(hfov / 2)`` along the
  UAV's x axis and ``h tan(vfov / 2)`` along its y axis (pinhole camera at altitude ``h``
  looking straight down). The seed gives no field of view; the defaults are a typical 4:3 USB
  webcam's (60 deg x 47 deg, 640 px wide).
- **Noise**: a pixel error of ``pixel_noise_std_px`` back-projected at altitude ``h`` is
  ``h * pixel_noise_std_px / f_px`` metres on the ground (``f_px = (W / 2) / tan(hfov / 2)``),
  isotropic: the noise grows linearly with altitude. Stegagno 2013's Fig. 6 reads 20 px as about
  10 cm, i.e. 5 mm/px: with ``f_px = 554`` that puts its UAV at ``h ~ 2.8 m``.
- **Misses**: each UGV inside the footprint is detected with ``detection_probability``.
- **Clutter**: ``Poisson(clutter_per_frame)`` false positives per frame, uniform over the
  footprint (ground objects that look like markers).

Detections are returned in random order (anonymous). :func:`measure_camera` runs the sensor
on known targets and measures its ``P_d``, noise-versus-altitude and clutter rate: the UAV's
filter takes its parameters from those measurements, not from the configuration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm_core.aerial import AerialFrame
from swarm_core.validation import (
    check_int_range,
    check_non_negative,
    check_number_fields,
    check_positive,
    check_probability,
)


@dataclass(frozen=True, slots=True)
class DownwardCameraConfig:
    """The UAV's downward camera and its feature extraction.

    Attributes
    ----------
    horizontal_fov_deg, vertical_fov_deg : float
        Full field-of-view angles along the UAV's x and y axes (deg, in (0, 170)).
    image_width_px : int
        Image width (pixels) along the horizontal field of view, for the focal length.
    pixel_noise_std_px : float
        Std of a feature's image position (px), per axis.
    detection_probability : float
        Probability that a UGV inside the footprint is extracted.
    clutter_per_frame : float
        Mean number of false positives per frame (Poisson), uniform over the footprint.
    rate_hz : float
        Frames per second (at most one per control period is processed).
    """

    horizontal_fov_deg: float = 60.0
    vertical_fov_deg: float = 47.0
    image_width_px: int = 640
    pixel_noise_std_px: float = 2.0
    detection_probability: float = 0.95
    clutter_per_frame: float = 0.3
    rate_hz: float = 10.0

    def __post_init__(self) -> None:
        check_number_fields(self, "uav.camera")
        for name in ("horizontal_fov_deg", "vertical_fov_deg"):
            value = getattr(self, name)
            if not 0.0 < value < 170.0:
                raise ValueError(f"uav.camera.{name} must be in (0, 170) deg, got {value!r}")
        check_int_range("uav.camera.image_width_px", self.image_width_px, 2, 100_000)
        check_non_negative("uav.camera.pixel_noise_std_px", self.pixel_noise_std_px)
        check_probability("uav.camera.detection_probability", self.detection_probability)
        check_non_negative("uav.camera.clutter_per_frame", self.clutter_per_frame)
        if self.clutter_per_frame > 100.0:
            raise ValueError(
                f"uav.camera.clutter_per_frame must be <= 100, got {self.clutter_per_frame!r}"
            )
        check_positive("uav.camera.rate_hz", self.rate_hz)

    @property
    def focal_length_px(self) -> float:
        """``f_px = (W / 2) / tan(hfov / 2)``."""
        return 0.5 * self.image_width_px / math.tan(math.radians(0.5 * self.horizontal_fov_deg))

    def half_extents_m(self, altitude_m: float) -> np.ndarray:
        """``(2,)``: footprint half extents ``[h tan(hfov/2), h tan(vfov/2)]`` (m)."""
        return altitude_m * np.array(
            [
                math.tan(math.radians(0.5 * self.horizontal_fov_deg)),
                math.tan(math.radians(0.5 * self.vertical_fov_deg)),
            ]
        )

    def noise_std_m(self, altitude_m: float) -> float:
        """Ground-plane std per axis of a detection at altitude ``h``: ``h sigma_px / f_px``."""
        return altitude_m * self.pixel_noise_std_px / self.focal_length_px


def in_footprint(points_xy: np.ndarray, half_extents_m: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: points (N, 2) in the UAV's level frame inside the footprint (edges in)."""
    return (np.abs(points_xy) <= half_extents_m).all(axis=-1)


def to_level_frame(uav_pose: np.ndarray, targets_xy: np.ndarray) -> np.ndarray:
    """World positions (N, 2) into the UAV's level frame ``H_0``: ``R(yaw)^T (p - p_uav)``."""
    c, s = math.cos(uav_pose[2]), math.sin(uav_pose[2])
    d = np.asarray(targets_xy, dtype=np.float64).reshape(-1, 2) - uav_pose[:2]
    return np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))


class DownwardCamera:
    """The sensor: :meth:`frame` turns true UGV positions into one frame of detections."""

    def __init__(self, config: DownwardCameraConfig) -> None:
        if not isinstance(config, DownwardCameraConfig):
            raise ValueError(f"config must be a DownwardCameraConfig, got {config!r}")
        self.config = config

    def frame(
        self,
        stamp_s: float,
        uav_pose: np.ndarray,
        altitude_m: float,
        targets_xy: np.ndarray,
        rng: np.random.Generator,
    ) -> AerialFrame:
        """One frame.

        Parameters
        ----------
        uav_pose : ndarray, shape (3,)
            ``[x_m, y_m, yaw_rad]`` of the UAV in the world (its projection on the ground).
        altitude_m : float
            Height of the camera above the ground (m, > 0).
        targets_xy : ndarray, shape (N, 2)
            World positions of the UGVs (m).
        rng : numpy Generator
            The camera's own stream. The number of draws depends only on ``N`` and on the
            Poisson clutter count.

        Raises
        ------
        ValueError
            If ``altitude_m`` is not a finite number > 0 (before any draw).
        """
        check_positive("altitude_m", altitude_m)
        cfg = self.config
        half = cfg.half_extents_m(altitude_m)
        rel = to_level_frame(np.asarray(uav_pose, dtype=np.float64), targets_xy)
        n = rel.shape[0]
        # Fixed-size draws for the targets (one uniform, two normals each), then the clutter.
        hit = rng.random(n) < cfg.detection_probability
        noise = rng.standard_normal((n, 2)) * cfg.noise_std_m(altitude_m)
        seen = np.flatnonzero(in_footprint(rel, half) & hit)
        n_clutter = int(rng.poisson(cfg.clutter_per_frame))
        clutter = rng.uniform(-half, half, size=(n_clutter, 2))
        points = np.concatenate((rel[seen] + noise[seen], clutter))
        source = np.concatenate((seen, np.full(n_clutter, -1))).astype(np.int64)
        order = rng.permutation(points.shape[0])  # anonymous: no order to exploit
        return AerialFrame(float(stamp_s), float(altitude_m), half, points[order], source[order])


@dataclass(frozen=True, slots=True)
class CameraStatistics:
    """The downward camera's statistics measured on the simulator (:func:`measure_camera`).

    Attributes
    ----------
    altitudes_m : ndarray (A,)
    detection_probability : ndarray (A,)
        Detected fraction of the targets inside the footprint, per altitude.
    noise_std_m : ndarray (A,)
        Std per axis of the detection error, per altitude (m).
    clutter_per_frame : ndarray (A,)
        Mean false positives per frame, per altitude.
    noise_per_altitude : float
        Least-squares slope through the origin of ``noise_std_m`` against altitude (m / m).
    """

    altitudes_m: np.ndarray
    detection_probability: np.ndarray
    noise_std_m: np.ndarray
    clutter_per_frame: np.ndarray
    noise_per_altitude: float

    @property
    def mean_detection_probability(self) -> float:
        return float(self.detection_probability.mean())

    @property
    def mean_clutter_per_frame(self) -> float:
        return float(self.clutter_per_frame.mean())

    def noise_std_at(self, altitude_m: float) -> float:
        """The fitted noise std at ``altitude_m`` (m)."""
        return self.noise_per_altitude * float(altitude_m)

    def as_dict(self) -> dict:
        return {
            "altitudes_m": self.altitudes_m.tolist(),
            "detection_probability": self.detection_probability.tolist(),
            "noise_std_m": self.noise_std_m.tolist(),
            "clutter_per_frame": self.clutter_per_frame.tolist(),
            "noise_per_altitude": self.noise_per_altitude,
        }


def measure_camera(
    config: DownwardCameraConfig,
    altitudes_m: tuple[float, ...] = (1.5, 2.0, 2.8, 4.0, 5.0),
    n_frames: int = 400,
    n_targets: int = 25,
    seed: int = 0,
) -> CameraStatistics:
    """Measure ``P_d``, noise and clutter of :class:`DownwardCamera` on known targets.

    A grid of ``n_targets`` targets fills 90 % of the footprint at each altitude; the UAV
    hovers at the origin with yaw 0. Errors come from the ``source`` of each detection (ground
    truth available only here, as in a calibration run).
    """
    check_int_range("n_frames", n_frames, 1, 10**6)
    check_int_range("n_targets", n_targets, 1, 10**4)
    camera = DownwardCamera(config)
    rng = np.random.default_rng(seed)
    side = int(math.ceil(math.sqrt(n_targets)))
    pd, std, clutter = [], [], []
    for h in altitudes_m:
        check_positive("altitudes_m", h)
        half = config.half_extents_m(h)
        gx, gy = np.meshgrid(
            np.linspace(-0.9, 0.9, side) * half[0], np.linspace(-0.9, 0.9, side) * half[1]
        )
        targets = np.column_stack((gx.ravel(), gy.ravel()))[:n_targets]
        errors, hits, n_clutter = [], 0, 0
        for _ in range(n_frames):
            f = camera.frame(0.0, np.zeros(3), h, targets, rng)
            real = f.source >= 0
            errors.append(f.detections[real] - targets[f.source[real]])
            hits += int(real.sum())
            n_clutter += int((~real).sum())
        err = np.concatenate(errors)
        pd.append(hits / (n_frames * n_targets))
        std.append(float(np.sqrt(np.mean(err**2))) if err.size else float("nan"))
        clutter.append(n_clutter / n_frames)
    alt = np.asarray(altitudes_m, dtype=np.float64)
    noise = np.asarray(std)
    slope = float(np.dot(alt, noise) / np.dot(alt, alt))
    return CameraStatistics(alt, np.asarray(pd), noise, np.asarray(clutter), slope)
