"""The UAV supervisor's configuration (Stegagno 2013: an AscTec Pelican over Khepera III UGVs)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from swarm_core.validation import check_non_negative, check_number_fields, check_positive
from swarm_env.sensors.downward_camera import DownwardCameraConfig

VELOCITY_FRAMES = ("body", "world")


@dataclass(frozen=True, slots=True)
class UAVConfig:
    """A kinematic quadrotor above the arena (it never collides: it flies above everything).

    Attributes
    ----------
    max_speed_mps : float
        Limit on the planar speed ``||(vx, vy)||`` (the action is scaled down to it).
    max_yaw_rate_radps, max_climb_rate_mps : float
        Limits on the yaw rate and on the altitude rate.
    yaw_control, altitude_control : bool
        Whether the action has a yaw-rate and an altitude-rate entry (else they are 0).
    velocity_frame : str
        ``"body"``: ``(vx, vy)`` along the UAV's x (forward) and y (left) axes; ``"world"``:
        along the world's axes.
    min_altitude_m, max_altitude_m, start_altitude_m : float
        Altitude range (the action saturates at its ends) and the altitude at reset.
    start_x_m, start_y_m, start_yaw_rad : float
        Pose at reset (world frame; the arena is centred on the origin).
    geofence_margin_m : float
        The UAV's projection stays within the arena grown by this margin.
    odometry_std_mps, odometry_std_radps : float
        Noise of the UAV's own motion estimate (Stegagno 2013: optical flow + IMU), per axis, as
        white velocity noise: the increment over ``dt`` has std ``sigma * dt``.
    camera : DownwardCameraConfig
    """

    max_speed_mps: float = 1.0
    max_yaw_rate_radps: float = 1.0
    max_climb_rate_mps: float = 0.5
    yaw_control: bool = True
    altitude_control: bool = True
    velocity_frame: str = "body"
    min_altitude_m: float = 1.0
    max_altitude_m: float = 6.0
    start_altitude_m: float = 2.8
    start_x_m: float = 0.0
    start_y_m: float = 0.0
    start_yaw_rad: float = 0.0
    geofence_margin_m: float = 1.0
    odometry_std_mps: float = 0.02
    odometry_std_radps: float = 0.01
    camera: DownwardCameraConfig = field(default_factory=DownwardCameraConfig)

    def __post_init__(self) -> None:
        check_number_fields(self, "uav")
        for name in ("yaw_control", "altitude_control"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"uav.{name} must be a bool, got {getattr(self, name)!r}")
        if self.velocity_frame not in VELOCITY_FRAMES:
            raise ValueError(
                f"uav.velocity_frame must be one of {VELOCITY_FRAMES}, got {self.velocity_frame!r}"
            )
        for name in (
            "max_speed_mps",
            "max_yaw_rate_radps",
            "max_climb_rate_mps",
            "min_altitude_m",
        ):
            check_positive(f"uav.{name}", getattr(self, name))
        for name in ("geofence_margin_m", "odometry_std_mps", "odometry_std_radps"):
            check_non_negative(f"uav.{name}", getattr(self, name))
        if self.max_speed_mps > 20.0:
            raise ValueError(f"uav.max_speed_mps must be <= 20 m/s, got {self.max_speed_mps!r}")
        if not self.min_altitude_m < self.max_altitude_m <= 100.0:
            raise ValueError(
                f"uav.max_altitude_m must be in (min_altitude_m={self.min_altitude_m}, 100], got "
                f"{self.max_altitude_m!r}"
            )
        if not self.min_altitude_m <= self.start_altitude_m <= self.max_altitude_m:
            raise ValueError(
                f"uav.start_altitude_m must be in [{self.min_altitude_m}, {self.max_altitude_m}], "
                f"got {self.start_altitude_m!r}"
            )
        if abs(self.start_yaw_rad) > 4.0 * math.pi:
            raise ValueError(
                f"uav.start_yaw_rad must be in [-4 pi, 4 pi], got {self.start_yaw_rad!r}"
            )
        if not isinstance(self.camera, DownwardCameraConfig):
            raise ValueError(f"uav.camera must be a DownwardCameraConfig, got {self.camera!r}")

    @property
    def action_size(self) -> int:
        return 2 + int(self.yaw_control) + int(self.altitude_control)
