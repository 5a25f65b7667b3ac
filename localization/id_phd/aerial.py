"""ID-PHD on an aerial observer: the Stegagno 2013 study's own setting (a UAV over the UGVs).

The state of each component is a UGV's pose ``(x, y, psi)`` in the UAV's level frame ``H_0``
(origin under the UAV, x along its yaw; Stegagno 2013 Problem 3). The time update is the ground
mode's (:meth:`IDPHD.predict`: the UGV's broadcast odometry increment composed with the UAV's own
planar increment, eq. 18-19). What differs is the measurement: the downward camera's anonymous
positions, whose

- detection probability is ``P_d`` for a component whose mean lies inside the camera's footprint
  and 0 outside (Stegagno 2013: "the probability of detection p_D^h of each component can be
  computed by considering whether or not its mean falls in the field of view"),
- noise std grows with altitude (``noise_per_altitude * h``),
- clutter is ``clutter_per_frame`` false positives spread uniformly over the footprint, i.e. an
  intensity of ``clutter_per_frame / footprint area`` per m^2.

All three come from the camera's *measured* statistics
(:func:`swarm_env.sensors.downward_camera.measure_camera`), passed in as a :class:`CameraModel`.
The ground mode (``update_lidar``) is untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_core.validation import check_positive

from .filter import IDPHD, _checked_points
from .update import lidar_update_3d


@dataclass(frozen=True, slots=True)
class CameraModel:
    """The aerial filter's camera parameters (from measurements).

    Attributes
    ----------
    detection_probability : float
        ``P_d`` inside the footprint.
    noise_per_altitude : float
        Detection std per axis divided by altitude (m / m).
    clutter_per_frame : float
        Mean false positives per frame (uniform over the footprint).
    min_noise_std_m : float
        Floor on the noise std (keeps ``R`` positive definite for a noiseless camera).
    """

    detection_probability: float
    noise_per_altitude: float
    clutter_per_frame: float
    min_noise_std_m: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("detection_probability", "noise_per_altitude", "clutter_per_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"camera_model.{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"camera_model.{name} must be finite and >= 0, got {value!r}")
        if not 0.0 < self.detection_probability <= 1.0:
            raise ValueError(
                f"camera_model.detection_probability must be in (0, 1], got "
                f"{self.detection_probability!r}"
            )
        if not (math.isfinite(self.min_noise_std_m) and self.min_noise_std_m > 0.0):
            raise ValueError(
                f"camera_model.min_noise_std_m must be > 0, got {self.min_noise_std_m!r}"
            )

    def noise_var_m2(self, altitude_m: float) -> float:
        return max(self.noise_per_altitude * altitude_m, self.min_noise_std_m) ** 2


class AerialIDPHD(IDPHD):
    """ID-PHD whose measurements are a downward camera's anonymous ground positions.

    Parameters
    ----------
    camera : CameraModel
    config : IDPHDConfig, optional
        As for :class:`IDPHD` (its lidar fields are not used by :meth:`update_camera`).
    **overrides
        Field values replacing those of ``config``.
    """

    __slots__ = ("camera",)

    def __init__(self, camera: CameraModel, config: Any = None, **overrides: Any) -> None:
        if not isinstance(camera, CameraModel):
            raise ValueError(f"camera must be a CameraModel, got {camera!r}")
        self.camera = camera
        super().__init__(config, **overrides)

    def update_camera(
        self, points: np.ndarray, altitude_m: float, half_extents_m: np.ndarray
    ) -> None:
        """GM-PHD update on ``(x, y)`` with one frame of the downward camera, then reduce.

        Parameters
        ----------
        points : array_like, shape (M, 2)
            Anonymous detections ``[x_m, y_m]`` in the UAV's level frame (``M = 0`` is valid).
        altitude_m : float
            Altitude of the frame (m, > 0): sets the noise.
        half_extents_m : array_like, shape (2,)
            Footprint half extents along the UAV's x and y (m, > 0): sets ``P_d`` and clutter.

        Raises
        ------
        ValueError
            On a bad argument, before anything changes.
        """
        pts = _checked_points(points)
        check_positive("altitude_m", altitude_m)  # refuses None, strings, nan, inf, <= 0
        altitude = float(altitude_m)
        half = np.asarray(half_extents_m, dtype=np.float64)
        if half.shape != (2,) or not (np.isfinite(half).all() and (half > 0).all()):
            raise ValueError(f"half_extents_m must be 2 finite values > 0, got {half_extents_m!r}")
        cam, cfg = self.camera, self.config
        w, m, p, tags = self._w, self._m, self._p, self._tags
        inside = (np.abs(m[:, :2]) <= half).all(axis=1)
        pd = np.where(inside, cam.detection_probability, 0.0)
        if pts.shape[0] == 0:
            w = w * (1.0 - pd)
            explained = np.empty(0)
        else:
            clutter = cam.clutter_per_frame / (4.0 * half[0] * half[1])
            w, m, p, source, explained = lidar_update_3d(
                w, m, p, pts, pd, cam.noise_var_m2(altitude), clutter
            )
            tags = tags[source]
        self._w, self._m, self._p, self._tags = self._reduce(w, m, p, tags)
        self._pending = pts[explained < cfg.birth_max_explained]
        self._mixture = None
