"""Configuration: one frozen dataclass per subsystem, seed values as defaults, named presets.

``SwarmConfig`` gathers everything a simulated swarm needs. Presets reproduce the seed's setups
(Perera 2021): ``seed-sim`` is the 6 m x 6 m Gazebo arena with 20 UGVs, ``seed-lab`` the 3 m x 3 m
real testing area with 4 UGVs. :func:`make_config` applies keyword overrides to a preset and
rejects unknown keys, so a typo never passes silently.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from localization import PHDConfig
from swarm_core.validation import (
    check_int_range,
    check_non_negative,
    check_positive,
)
from swarm_env.sensors.camera import CameraConfig
from swarm_env.sensors.lidar import LidarConfig
from swarm_env.sensors.lidar_features import LidarFeatureConfig
from swarm_env.sensors.odometry import OdometryConfig

MAX_ROBOTS = 200
OBSERVATION_MODES = ("phd", "truth", "measurements")


@dataclass(frozen=True, slots=True)
class RobotConfig:
    """A DFRobot Cherokey UGV with the seed's sensor tower.

    Attributes
    ----------
    length_m, width_m : float
        Chassis footprint (0.225 m x 0.175 m).
    housing_radius_m : float
        Lidar housing cylinder at the robot centre: what other robots' lidars see (65 mm dia.).
    camera_holder_radius_m : float
        Camera holder with the red strip, above the lidar: what cameras see and what blocks them.
    wheel_radius_m, axle_width_m : float
        Differential-drive geometry (Cherokey: 65 mm wheels, ~150 mm track).
    max_speed_mps, max_turn_rate_radps : float
        Velocity limits; actions are clipped to them.
    max_accel_mps2, max_turn_accel_radps2 : float
        Acceleration limits applied by the motor controller on every physics substep.
    mass_kg : float
    """

    length_m: float = 0.225
    width_m: float = 0.175
    housing_radius_m: float = 0.0325
    camera_holder_radius_m: float = 0.05
    wheel_radius_m: float = 0.0325
    axle_width_m: float = 0.15
    max_speed_mps: float = 0.3
    max_turn_rate_radps: float = 1.5
    max_accel_mps2: float = 0.6
    max_turn_accel_radps2: float = 6.0
    mass_kg: float = 1.6

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_positive(f"robot.{f.name}", getattr(self, f.name))
        if self.max_speed_mps > 2.0:
            raise ValueError(f"robot.max_speed_mps must be <= 2.0 m/s, got {self.max_speed_mps!r}")
        if self.housing_radius_m > 0.5 * self.width_m:
            raise ValueError(
                f"robot.housing_radius_m must fit the chassis (<= {0.5 * self.width_m} m), "
                f"got {self.housing_radius_m!r}"
            )

    @property
    def footprint_radius_m(self) -> float:
        """Radius of the circle that encloses the chassis (used for spawning clearance)."""
        return 0.5 * math.hypot(self.length_m, self.width_m)


@dataclass(frozen=True, slots=True)
class ArenaConfig:
    """A walled rectangular arena centred on the world origin, with seeded random obstacles.

    Attributes
    ----------
    width_m, height_m : float
        Inner size along world x and y.
    wall_thickness_m : float
    n_decoy_posts : int
        Robot-sized posts (radius ``decoy_post_radius_m`` <= 32.5 mm): lidar false positives.
    n_red_decoys : int
        Red objects (radius ``red_decoy_radius_m``): camera false positives; too wide to pass the
        lidar feature extractor.
    n_boxes : int
        Box obstacles, sides drawn in ``box_size_range_m``: they occlude lidar and camera.
    """

    width_m: float = 6.0
    height_m: float = 6.0
    wall_thickness_m: float = 0.1
    n_decoy_posts: int = 4
    decoy_post_radius_m: float = 0.03
    n_red_decoys: int = 2
    red_decoy_radius_m: float = 0.06
    n_boxes: int = 2
    box_size_range_m: tuple[float, float] = (0.3, 0.6)

    def __post_init__(self) -> None:
        for name in (
            "width_m",
            "height_m",
            "wall_thickness_m",
            "decoy_post_radius_m",
            "red_decoy_radius_m",
        ):
            check_positive(f"arena.{name}", getattr(self, name))
        for name in ("n_decoy_posts", "n_red_decoys", "n_boxes"):
            check_int_range(f"arena.{name}", getattr(self, name), 0, 100)
        if self.width_m > 100 or self.height_m > 100:
            raise ValueError(f"arena size must be <= 100 m, got {self.width_m} x {self.height_m}")
        low, high = self.box_size_range_m
        if not 0 < low <= high:
            raise ValueError(
                f"arena.box_size_range_m must be 0 < low <= high, got {(low, high)!r}"
            )

    @property
    def area_m2(self) -> float:
        return self.width_m * self.height_m


#: The robots' filter in the simulator: the seed's GM-PHD (``PHDConfig()``, which describes the
#: seed's hardware) with two models matched to the simulated sensors, each from a measurement
#: in ``seed-sim`` (``docs/localization.md``, "Accuracy in the seed experiment"):
#:
#: * the lidar range factor ``1 / (1 + exp(20 (r - 2)))``: the simulated lidar does not fade
#:   with range and its feature extractor cuts at ``tracking_range_m`` = 2 m (the seed's
#:   ``1.02, 8, 1.5 m`` makes a lidar-only filter's weight sum 2.3x the truth; this, 1.06x);
#: * measurement-driven births of weight 0.25: teammates enter a robot's 2 m disc 0.085 times
#:   per scan, and the seed's fixed birth needs 2-3 extra scans per newcomer.
#:
#: Real robots (:func:`hardware_bridge.real_env`) keep the seed's values unless overridden.
SIMULATOR_PHD = PHDConfig(
    birth="measurement",
    measurement_birth_weight=0.25,
    lidar_pd_offset=1.0,
    lidar_pd_slope_per_m=20.0,
    lidar_pd_midpoint_m=2.0,
)


@dataclass(frozen=True, slots=True)
class SwarmConfig:
    """Everything one simulated swarm needs.

    Attributes
    ----------
    n_robots : int
        Number of agents (``ugv_0`` ... ``ugv_{n-1}``).
    control_period_s : float
        Duration of one env step.
    physics_substeps : int
        pymunk steps per control period; sensors fire on substep boundaries.
    max_steps : int
        Episode truncation (3000 steps = the seed's 300 s at 0.1 s).
    observation : str
        ``"phd"`` (default: the agent's own PHD estimate), ``"truth"`` (true neighbours in range,
        same layout; an upper bound for ablations) or ``"measurements"`` (padded raw detections).
    top_k : int
        Rows of the observation's neighbour table.
    localization_range_m : float
        "In range" for ground truth and metrics: the lidar's effective tracking range (seed: 2 m).
    localize : bool
        Run every robot's PHD filter. Required by ``observation="phd"``; switch it off to train
        faster on ``"truth"`` or ``"measurements"`` when localization metrics are not wanted.
    sensor_stats : bool
        Count each sensor's detections, false positives and misses against the truth at the
        instant of every reading (``SimWorld.stats``; the demo prints them). Costs time.
    phd : PHDConfig
        Every robot's filter (default :data:`SIMULATOR_PHD`).
    """

    n_robots: int = 20
    arena: ArenaConfig = field(default_factory=ArenaConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    lidar_features: LidarFeatureConfig = field(default_factory=LidarFeatureConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    phd: PHDConfig = SIMULATOR_PHD
    control_period_s: float = 0.1
    physics_substeps: int = 5
    max_steps: int = 3000
    observation: str = "phd"
    top_k: int = 16
    localization_range_m: float = 2.0
    spawn_clearance_m: float = 0.05
    localize: bool = True
    sensor_stats: bool = False

    def __post_init__(self) -> None:
        check_int_range("n_robots", self.n_robots, 1, MAX_ROBOTS)
        check_positive("control_period_s", self.control_period_s)
        if self.control_period_s > 1.0:
            raise ValueError(f"control_period_s must be <= 1.0 s, got {self.control_period_s!r}")
        check_int_range("physics_substeps", self.physics_substeps, 1, 100)
        check_int_range("max_steps", self.max_steps, 1, 10_000_000)
        check_int_range("top_k", self.top_k, 1, 256)
        check_positive("localization_range_m", self.localization_range_m)
        check_non_negative("spawn_clearance_m", self.spawn_clearance_m)
        if self.observation not in OBSERVATION_MODES:
            raise ValueError(
                f"observation must be one of {OBSERVATION_MODES}, got {self.observation!r}"
            )
        if self.observation == "phd" and not self.localize:
            raise ValueError('observation="phd" needs localize=True')
        substep_m = self.robot.max_speed_mps * self.physics_dt_s
        if substep_m > 0.5 * self.arena.wall_thickness_m:
            raise ValueError(
                f"physics_substeps={self.physics_substeps} lets a robot move {substep_m:.3f} m "
                "per substep, more than half the wall thickness: raise physics_substeps"
            )
        # Sensors fire on substep boundaries, at most once per substep each.
        substep_hz = 1.0 / self.physics_dt_s
        for name in ("lidar", "camera", "odometry"):
            rate = getattr(self, name).rate_hz
            if rate > substep_hz + 1e-9:
                raise ValueError(
                    f"{name}.rate_hz={rate} exceeds the physics substep rate {substep_hz:g} Hz "
                    f"(control_period_s / physics_substeps): raise physics_substeps"
                )
        # Rough packing bound: robots' enclosing discs must cover < 35 % of the free area.
        disc = math.pi * (self.robot.footprint_radius_m + self.spawn_clearance_m) ** 2
        if self.n_robots * disc > 0.35 * self.arena.area_m2:
            raise ValueError(
                f"n_robots={self.n_robots} do not fit a {self.arena.width_m} m x "
                f"{self.arena.height_m} m arena (at most "
                f"{int(0.35 * self.arena.area_m2 / disc)} robots)"
            )

    @property
    def physics_dt_s(self) -> float:
        return self.control_period_s / self.physics_substeps


PRESETS: dict[str, SwarmConfig] = {
    "seed-sim": SwarmConfig(),
    "seed-lab": SwarmConfig(
        n_robots=4,
        arena=ArenaConfig(width_m=3.0, height_m=3.0, n_decoy_posts=2, n_red_decoys=1, n_boxes=0),
    ),
}


def make_config(preset: str = "seed-sim", config: SwarmConfig | None = None, **overrides: Any):
    """A preset (or ``config``) with keyword overrides applied.

    Top-level fields are overridden directly (``n_robots=10``). Nested sub-configs take a dataclass
    or a dict of their fields (``lidar={"rate_hz": 10.0}``). Unknown keys raise ``ValueError``.
    """
    if config is None:
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
        config = PRESETS[preset]
    return _replace_strict(config, overrides, prefix="")


def _replace_strict(obj: Any, overrides: dict[str, Any], prefix: str) -> Any:
    names = {f.name: f for f in dataclasses.fields(obj)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in names:
            raise ValueError(f"unknown config key {prefix + key!r}; valid keys: {sorted(names)}")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            value = _replace_strict(current, value, prefix=f"{prefix}{key}.")
        changes[key] = value
    return dataclasses.replace(obj, **changes) if changes else obj
