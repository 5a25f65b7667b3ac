"""ID-PHD configuration and the component tags."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from swarm_core.validation import check_non_negative, check_number, check_positive

from ..config import PHDConfig

#: Tag of a component not yet associated to any robot.
UNTAGGED = -1
#: Tag of a static false positive (null odometry).
STATIC = -2

_WEIGHT_FLOOR = 1e-150


@dataclass(frozen=True, slots=True)
class IDPHDConfig:
    """ID-PHD parameters (units in the names). Validated on construction.

    Attributes
    ----------
    own_odometry_std_m, own_odometry_std_rad : float
        ``C_0``: std of the observer's own odometry increment per time update (per axis).
    teammate_odometry_std_m, teammate_odometry_std_rad : float
        ``C_i``: std of a teammate's communicated increment per time update.
    static_process_std_m : float
        Extra position noise per time update of the static class (``-2``).
    survival_probability : float
        Constant ``P_s`` per time update (identities are tracked out of sensor range too).
    lidar_noise_std_m, lidar_clutter_intensity_per_m2 : float
        ``R_L = s^2 I`` and ``kappa_L``.
    birth_weight : float
        Weight of an untagged birth (before the split).
    birth_std_m, birth_heading_std_rad : float
        Birth position std and (before the heading split) heading std.
    birth_heading_hypotheses : int
        Number of evenly spaced heading hypotheses per robot copy at the split.
    birth_max_explained : float
        A detection whose explained fraction is below this becomes a birth.
    birth_min_detection_prob : float
        ...if the lidar ``P_d`` at the detection is at least this (a teammate where ``P_d ~ 0``
        cannot be tracked, and its births would be split and dropped at every scan).
    recovered_weight : float
        A robot whose tag weight reaches this is no longer a split candidate (``inf``: never).
    prune_threshold, merge_threshold : float
        Prune weight and squared 3-D Mahalanobis merge gate.
    max_components : int
        Cap after every reduction.
    detection : PHDConfig
        Supplies the lidar ``P_d`` model (range, blind sectors, occlusion, interference).
    """

    own_odometry_std_m: float = 0.005
    own_odometry_std_rad: float = 0.01
    teammate_odometry_std_m: float = 0.005
    teammate_odometry_std_rad: float = 0.01
    static_process_std_m: float = 0.002
    survival_probability: float = 0.999
    lidar_noise_std_m: float = 0.05
    lidar_clutter_intensity_per_m2: float = 0.05
    birth_weight: float = 0.1
    birth_std_m: float = 0.1
    birth_heading_std_rad: float = math.pi
    birth_heading_hypotheses: int = 8
    birth_max_explained: float = 0.5
    birth_min_detection_prob: float = 0.3
    recovered_weight: float = 0.8
    prune_threshold: float = 1e-5
    merge_threshold: float = 4.0
    max_components: int = 400
    detection: PHDConfig = field(default_factory=PHDConfig)

    def __post_init__(self) -> None:
        for name in (
            "own_odometry_std_m",
            "own_odometry_std_rad",
            "teammate_odometry_std_m",
            "teammate_odometry_std_rad",
            "static_process_std_m",
            "lidar_clutter_intensity_per_m2",
        ):
            check_non_negative(name, getattr(self, name))
        for name in ("lidar_noise_std_m", "birth_std_m", "birth_heading_std_rad"):
            check_positive(name, getattr(self, name))
        for name in (
            "survival_probability",
            "birth_weight",
            "birth_max_explained",
            "birth_min_detection_prob",
        ):
            check_number(name, getattr(self, name), low=0, high=1)
        check_number("prune_threshold", self.prune_threshold, low=0, above=True, high=1)
        check_non_negative("merge_threshold", self.merge_threshold)
        value = self.recovered_weight
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise ValueError(f"recovered_weight must be a number > 0 (or inf), got {value!r}")
        for name in ("birth_heading_hypotheses", "max_components"):
            check_number(name, getattr(self, name), integer=True, low=1)
        if not isinstance(self.detection, PHDConfig):
            raise ValueError(f"detection must be a PHDConfig, got {self.detection!r}")

    @property
    def lidar_noise_var_m2(self) -> float:
        return self.lidar_noise_std_m**2


# ---------------------------------------------------------------------- pure functions
