"""Configuration: one frozen dataclass per subsystem, published values as defaults, named presets.

``SwarmConfig`` gathers everything a simulated swarm needs. Presets reproduce the Perera 2021
study's setups: ``seed-sim`` is the 6 m x 6 m Gazebo arena with 20 UGVs, ``seed-lab`` the
3 m x 3 m real testing area with 4 UGVs. :func:`make_config` applies keyword overrides to a
preset and rejects unknown keys, so a typo never passes silently.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any

from localization import PHDConfig
from localization.config import replace_fields
from swarm_core.perception.lidar_features import LidarFeatureConfig
from swarm_core.validation import (
    check_int_range,
    check_non_negative,
    check_number_fields,
    check_positive,
)
from swarm_env.comms import CommsConfig
from swarm_env.sensors.camera import CameraConfig
from swarm_env.sensors.detection_fade import RangeFade
from swarm_env.sensors.lidar import LidarConfig
from swarm_env.sensors.odometry import OdometryConfig

MAX_ROBOTS = 1000
OBSERVATION_MODES = ("phd", "truth", "measurements")


@dataclass(frozen=True, slots=True)
class RobotConfig:
    """A DFRobot Cherokey UGV with the Perera 2021 study's sensor tower.

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
        Robot mass of the physics body (sets its inertia and traction force).
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
        check_number_fields(self)
        for f in dataclasses.fields(self):
            check_positive(f"robot.{f.name}", getattr(self, f.name))
        if self.max_speed_mps > 2.0:
            raise ValueError(f"robot.max_speed_mps must be <= 2.0 m/s, got {self.max_speed_mps!r}")
        if self.housing_radius_m > 0.5 * self.width_m:
            raise ValueError(
                f"robot.housing_radius_m must fit the chassis (<= robot.width_m / 2, "
                f"robot.width_m={self.width_m!r}), got {self.housing_radius_m!r}"
            )
        # Physical plausibility of a swarm UGV: a 1e300 m axle turns 1.5 rad/s into wheel
        # speeds whose odometry overflows the filters' input bound at the first step.
        for name in (
            "length_m",
            "width_m",
            "camera_holder_radius_m",
            "wheel_radius_m",
            "axle_width_m",
        ):
            if getattr(self, name) > 2.0:
                raise ValueError(f"robot.{name} must be <= 2 m, got {getattr(self, name)!r}")
        if self.axle_width_m < 0.01:  # one encoder pulse would turn the robot by radians
            raise ValueError(f"robot.axle_width_m must be >= 0.01 m, got {self.axle_width_m!r}")

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
        Thickness of the four walls (a robot may move at most half of it per physics substep).
    n_decoy_posts : int
        Robot-sized posts (radius ``decoy_post_radius_m`` <= 32.5 mm): lidar false positives.
    decoy_post_radius_m : float
        Radius of each decoy post.
    n_red_decoys : int
        Red objects (radius ``red_decoy_radius_m``): camera false positives; too wide to pass the
        lidar feature extractor's angular extent test (``LidarFeatureConfig.extent_test``).
    red_decoy_radius_m : float
        Radius of each red decoy.
    n_boxes : int
        Box obstacles, sides drawn in ``box_size_range_m``: they occlude lidar and camera.
    box_size_range_m : (low_m, high_m)
        Range the boxes' side lengths are drawn from, uniformly.
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
        check_number_fields(self)
        for name in (
            "width_m",
            "height_m",
            "wall_thickness_m",
            "decoy_post_radius_m",
            "red_decoy_radius_m",
        ):
            check_positive(f"arena.{name}", getattr(self, name))
        # 1000: the 1000-robot preset keeps the Perera 2021 study's obstacle density (200 posts).
        for name in ("n_decoy_posts", "n_red_decoys", "n_boxes"):
            check_int_range(f"arena.{name}", getattr(self, name), 0, 1000)
        if self.width_m > 100 or self.height_m > 100:
            raise ValueError(
                f"arena.width_m and arena.height_m must be <= 100 m, got {self.width_m!r} x "
                f"{self.height_m!r}"
            )
        sizes = self.box_size_range_m
        if not (
            isinstance(sizes, tuple)
            and len(sizes) == 2
            and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in sizes
            )
        ):
            raise ValueError(
                f"arena.box_size_range_m must be a tuple (low_m, high_m) of finite numbers, "
                f"got {sizes!r}"
            )
        low, high = sizes
        if not 0 < low <= high:
            raise ValueError(
                f"arena.box_size_range_m must be 0 < low <= high, got {(low, high)!r}"
            )
        # Every obstacle must fit inside the walls (else the scene fails at reset, not here).
        half = 0.5 * min(self.width_m, self.height_m)
        for name in ("decoy_post_radius_m", "red_decoy_radius_m"):
            if getattr(self, name) >= half:
                raise ValueError(
                    f"arena.{name} must be < half the arena's smaller side (arena.width_m x "
                    f"arena.height_m = {self.width_m!r} x {self.height_m!r}), got "
                    f"{getattr(self, name)!r}"
                )
        if high >= 2 * half:
            raise ValueError(
                f"arena.box_size_range_m must fit the arena (< {2 * half} m), got {sizes!r}"
            )

    @property
    def area_m2(self) -> float:
        return self.width_m * self.height_m


#: The robots' filter in the simulator: ``PHDConfig()``, whose sensor models were measured on
#: the simulated sensors (each field's description says where; the geometry ones are checked
#: against these configs' defaults in ``tests/swarm_env/test_config_phd.py``). Real robots
#: (:func:`hardware_bridge.real_env`) run :meth:`PHDConfig.perera2021` unless overridden.
SIMULATOR_PHD = PHDConfig()


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
        Episode truncation (3000 steps = the Perera 2021 study's 300 s at 0.1 s).
    observation : str
        ``"phd"`` (default: the agent's own PHD estimate), ``"truth"`` (true neighbours in range,
        same layout; an upper bound for ablations) or ``"measurements"`` (padded raw detections).
    top_k : int
        Rows of the observation's neighbour table.
    lidar_sectors : int
        0 (default): no lidar block. S > 0: the observation also holds the robot's own last
        lidar scan as S angular sectors (min valid range per sector, body frame, sector 0
        centred straight ahead, then CCW; :func:`swarm_env.observation.lidar_sector_ranges`),
        what the scripted controllers avoid obstacles with.
    lidar_sector_max_m : float
        Sector ranges are clipped to this (and an empty sector reads it).
    localization_range_m : float
        "In range" for ground truth and metrics: the lidar's effective tracking range (seed: 2 m).
    spawn_clearance_m : float
        Minimum free gap between the objects laid out at reset (robots, decoy posts, red
        decoys, boxes) and between each of them and the walls.
    localize : bool
        Run every robot's filter. Required by ``observation="phd"``; switch it off to train
        faster on ``"truth"`` or ``"measurements"`` when localization metrics are not wanted.
    localizer : str
        The family every robot's filter belongs to, by its name in
        :data:`localization.registry.LOCALIZERS` (``swarm-phd list``): ``"phd"`` (default: the
        compiled GM-PHD bank in ``phd.mode``), ``"phd-lc"``, ``"phd-lo"``, ``"pmb-lc"``... Its
        sensor models come from ``phd``; ``observation="phd"`` is its estimate table.
    sensor_stats : bool
        Count each sensor's detections, false positives and misses against the truth at the
        instant of every reading (``SimWorld.stats``; the demo prints them). Costs time.
    phd : PHDConfig
        Every robot's filter (default ``PHDConfig()``, the model measured on the simulated
        sensors).
    comms : CommsConfig
        The robots' radio (off by default): teammates' odometry and anonymous detections, with
        loss, latency and a radius; received broadcasts are in ``infos[agent]["comms"]``.
    lidar_fade, camera_fade : RangeFade or None
        None (default): each sensor detects what its geometry lets it. A
        :class:`~swarm_env.sensors.detection_fade.RangeFade`: its detections are also kept only
        with that probability of their range (``perera2021``: the study's eqs. 19 and 30).
    """

    n_robots: int = 20
    arena: ArenaConfig = field(default_factory=ArenaConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    lidar_features: LidarFeatureConfig = field(default_factory=LidarFeatureConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    comms: CommsConfig = field(default_factory=CommsConfig)
    lidar_fade: RangeFade | None = None
    camera_fade: RangeFade | None = None
    phd: PHDConfig = SIMULATOR_PHD
    control_period_s: float = 0.1
    physics_substeps: int = 5
    max_steps: int = 3000
    observation: str = "phd"
    top_k: int = 16
    lidar_sectors: int = 0
    lidar_sector_max_m: float = 2.0
    localization_range_m: float = 2.0
    spawn_clearance_m: float = 0.05
    localize: bool = True
    localizer: str = "phd"
    sensor_stats: bool = False

    def __post_init__(self) -> None:
        for name, kind in _sub_config_types().items():  # before any of them is read
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"{name} must be a {kind.__name__} (as an override, a dict of its "
                    f"fields also), got {getattr(self, name)!r}"
                )
        for name in ("lidar_fade", "camera_fade"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, RangeFade):
                raise ValueError(f"{name} must be a RangeFade or None, got {value!r}")
        check_number_fields(self)
        check_int_range("n_robots", self.n_robots, 1, MAX_ROBOTS)
        check_positive("control_period_s", self.control_period_s)
        if self.control_period_s > 1.0:
            raise ValueError(f"control_period_s must be <= 1.0 s, got {self.control_period_s!r}")
        check_int_range("physics_substeps", self.physics_substeps, 1, 100)
        check_int_range("max_steps", self.max_steps, 1, 10_000_000)
        check_int_range("top_k", self.top_k, 1, 256)
        check_int_range("lidar_sectors", self.lidar_sectors, 0, 360)
        check_positive("lidar_sector_max_m", self.lidar_sector_max_m)
        check_positive("localization_range_m", self.localization_range_m)
        check_non_negative("spawn_clearance_m", self.spawn_clearance_m)
        if self.observation not in OBSERVATION_MODES:
            raise ValueError(
                f"observation must be one of {OBSERVATION_MODES}, got {self.observation!r}"
            )
        for name in ("localize", "sensor_stats"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        from localization.registry import LOCALIZERS

        if not isinstance(self.localizer, str) or self.localizer not in LOCALIZERS:
            raise ValueError(
                f"localizer must be one of {sorted(LOCALIZERS)}, got {self.localizer!r}"
            )
        if self.observation == "phd" and not self.localize:
            raise ValueError('observation="phd" needs localize=True')
        if self.localize and LOCALIZERS[self.localizer].needs_comms and not self.comms.enabled:
            # The Stegagno 2012 thesis's methods learn who is who from the teammates' broadcasts:
            # without the radio they would run and never know a teammate.
            raise ValueError(
                f"localizer={self.localizer!r} needs the radio: set comms={{'enabled': True}} "
                f"(comms.enabled is {self.comms.enabled})"
            )
        substep_m = self.robot.max_speed_mps * self.physics_dt_s
        if substep_m > 0.5 * self.arena.wall_thickness_m:
            raise ValueError(
                f"physics_substeps={self.physics_substeps} lets a robot move {substep_m:.3f} m "
                "per substep, more than half the wall thickness (arena.wall_thickness_m="
                f"{self.arena.wall_thickness_m!r}): raise physics_substeps"
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
        features = self.lidar_features
        if features.extent_test and features.beam_footprint_deg > self.lidar.beam_footprint_deg:
            # The extent test assumes every return's footprint is this wide: with a wider
            # assumed footprint than the scanner's it would reject the scanner's housings.
            raise ValueError(
                f"lidar_features.beam_footprint_deg={features.beam_footprint_deg!r} exceeds the "
                f"simulated scanner's lidar.beam_footprint_deg={self.lidar.beam_footprint_deg!r}: "
                "the extent test would reject housings (set them equal)"
            )
        if self.spawn_clearance_m > min(self.arena.width_m, self.arena.height_m):
            # (1e300 overflowed the packing bound below with an unnamed OverflowError.)
            raise ValueError(
                f"spawn_clearance_m must be <= the arena's smaller side, got "
                f"{self.spawn_clearance_m!r}"
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


@functools.cache
def _sub_config_types() -> dict[str, type]:
    """``SwarmConfig``'s nested config fields and their dataclass types, from its defaults."""
    out = {}
    for f in dataclasses.fields(SwarmConfig):
        default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        if dataclasses.is_dataclass(default):
            out[f.name] = type(default)
    return out


def _dense(n_robots: int) -> SwarmConfig:
    """``sim-6m-20``'s density with ``n_robots``: the arena side grows as ``sqrt(n / 20)``
    (to 0.1 m) and the posts, red decoys and boxes with the area (big-swarm presets)."""
    k = n_robots // 20
    side = round(6.0 * math.sqrt(n_robots / 20.0), 1)
    return SwarmConfig(
        n_robots=n_robots,
        arena=ArenaConfig(
            width_m=side, height_m=side, n_decoy_posts=4 * k, n_red_decoys=2 * k, n_boxes=2 * k
        ),
    )


#: The Perera 2021 study's cameras as its simulation made them ("the camera measurements were
#: generated directly using the UGV locations. A zero mean Gaussian noise was added"): every
#: teammate's strip within line of sight, its bearing plus Gaussian noise of the filter's
#: R_C (5 deg std, eq. 28), no false blobs, no lost frames, ideal blob centroids (fill 1); the
#: range fade is eq. 30's (``PERERA2021_CAMERA_FADE``).
PERERA2021_CAMERA = CameraConfig(
    bearing_noise_std_deg=PHDConfig.perera2021().camera.noise_std_deg,
    fill_min=1.0,
    miss_probability=0.0,
    false_positive_rate=0.0,
)

#: The Perera 2021 study's simulation (its section 4): 20 UGVs in a 6 m x 6 m walled arena,
#: 300 s, the lidar fading as eq. 19 and the cameras as eq. 30 (5 deg noise, no clutter), the
#: X4's four pillar blind sectors (``LidarConfig``, the filter's eq. 20 sectors), and the
#: study's own filter (``PHDConfig.perera2021()``). Its simulation names no obstacles besides
#: the walls and the robots, and generates the camera's bearings from the UGVs' positions, so
#: there are no decoy posts, red decoys or boxes (docs/how-to/studies/perera2021.md).
PERERA2021 = SwarmConfig(
    arena=ArenaConfig(n_decoy_posts=0, n_red_decoys=0, n_boxes=0),
    camera=PERERA2021_CAMERA,
    lidar_fade=RangeFade.perera2021_lidar(),
    camera_fade=RangeFade.perera2021_camera(),
    phd=PHDConfig.perera2021(),
)

PRESETS: dict[str, SwarmConfig] = {
    "sim-6m-20": SwarmConfig(),
    "perera2021": PERERA2021,
    "lab-3m-4": SwarmConfig(
        n_robots=4,
        arena=ArenaConfig(width_m=3.0, height_m=3.0, n_decoy_posts=2, n_red_decoys=1, n_boxes=0),
    ),
    # Big swarms at the Perera 2021 study's density (docs/how-to/scaling-out.md, "Big swarms").
    "sim-13m-100": _dense(100),
    "sim-19m-200": _dense(200),
    "sim-30m-500": _dense(500),
    "sim-42m-1000": _dense(1000),
    # The Stegagno 2013 study's simulation: 3 UGVs wandering under a hovering UAV (2.8 m,
    # swarm_env.uav), odometry broadcast at 10 Hz; 2.5 m x 2.5 m so the camera footprint covers it
    # (docs/how-to/studies/stegagno2013-uav.md).
    "seed-uav": SwarmConfig(
        n_robots=3,
        arena=ArenaConfig(width_m=2.5, height_m=2.5, n_decoy_posts=0, n_red_decoys=0, n_boxes=0),
        comms=CommsConfig(enabled=True, rate_hz=10.0),
    ),
}


#: The presets' names before 0.2 ("seed" = the source study), accepted for one more release.
PRESET_ALIASES: dict[str, str] = {"seed-sim": "sim-6m-20", "seed-lab": "lab-3m-4"}


def make_config(preset: str = "sim-6m-20", config: SwarmConfig | None = None, **overrides: Any):
    """A preset (or ``config``) with keyword overrides applied.

    Top-level fields are overridden directly (``n_robots=10``). Nested sub-configs take a dataclass
    or a dict of their fields (``lidar={"rate_hz": 10.0}``). Unknown keys raise ``ValueError``.
    """
    if config is None:
        preset = PRESET_ALIASES.get(preset, preset) if isinstance(preset, str) else preset
        if not isinstance(preset, str) or preset not in PRESETS:
            raise ValueError(
                f"preset must be one of {sorted(PRESETS)} (old names: {sorted(PRESET_ALIASES)}),"
                f" got {preset!r}"
            )
        config = PRESETS[preset]
    elif not isinstance(config, SwarmConfig):
        raise ValueError(
            f"config must be a SwarmConfig (or None, with keyword overrides), got {config!r}"
        )
    return replace_fields(config, overrides)
