"""Configuration of the robot-centric GM-PHD filter (and of the PMB, which shares it).

:class:`PHDConfig` is the filter's model, one small frozen dataclass per component:

* :class:`PredictionModel` (``prediction``): process noise, when it goes in, survival;
* :class:`LidarModel` (``lidar``): the lidar's noise, its ``P_d`` and that ``P_d``'s factors
  (range, blind sectors, occlusion, interference), its clutter;
* :class:`CameraModel` (``camera``): the camera's bearing noise, ``P_d``, clutter, the
  untracked teammates' density and the wide objects' clutter;
* :class:`BirthModel` (``births``): where new components come from;
* :class:`Reduction` (``reduction``): pruning, merging, the component cap and the minimum range;

plus the sensor set ``mode`` and the ``missed_detection`` rule both sensors' updates use.

The defaults, ``PHDConfig()``, are the model every simulator preset runs: each sensor number
measured on the simulated sensors (each field's description says where), the rest the
Perera 2021 study's. :meth:`PHDConfig.perera2021` is that study's own model (its hardware,
chapter 3): each field's description gives the study's value and equation. Units are in the
field names (``_m``, ``_deg``, ``_per_m``, ``_per_m2``, ``_per_rad``, ``_s``).

>>> from localization.config import LidarModel, PHDConfig
>>> PHDConfig(lidar=LidarModel(noise_std_m=0.04)).lidar.noise_std_m
0.04
>>> PHDConfig().replace(camera={"noise_std_deg": 1.0}).camera.noise_std_deg
1.0

References
----------
.. [1] B.-N. Vo and W.-K. Ma, "The Gaussian Mixture Probability Hypothesis Density Filter",
   IEEE Trans. Signal Processing, 54(11):4091-4104, 2006.
.. [2] Perera 2021, "PHD-filter based relative localization for robot swarms with lidar and
   camera", chapter 3, eqs. (7)-(30).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np

from swarm_core.perception.lidar_features import LidarFeatureConfig
from swarm_core.validation import (
    check_blind_sectors,
    check_non_negative,
    check_number,
    check_number_fields,
    check_positive,
)

__all__ = [
    "PHDConfig",
    "PredictionModel",
    "LidarModel",
    "CameraModel",
    "BirthModel",
    "Reduction",
    "config_with_overrides",
    "replace_fields",
    "nest_flat_phd",
    "MODES",
    "BIRTH_MODELS",
    "LIDAR_PD_MODELS",
    "BLIND_SECTOR_MODELS",
    "LIDAR_BEAM_PHASES",
    "SURVIVAL_MODELS",
    "CAMERA_BIRTH_MODELS",
    "MISSED_DETECTION_MODELS",
    "CAMERA_BIRTH_RADIAL_STD_FRACTION",
]

#: Sensor sets: lidar and camera (LC), or lidar only (LO: camera updates are no-ops).
MODES = ("lidar-camera", "lidar-only")
#: ``"fixed"``: Perera 2021 eq. (11), one wide component per time update. ``"measurement"``:
#: adaptive births from lidar detections that the current mixture does not explain.
BIRTH_MODELS = ("fixed", "measurement")
#: ``"seed"``: product of range x blind sectors x occlusion x interference (eq. 18).
#: ``"constant"``: ``lidar.detection_probability`` inside ``lidar.range_m``, 0 outside.
LIDAR_PD_MODELS = ("seed", "constant")
#: The lidar's blind-sector factor (``lidar.pd_model == "seed"``). ``"seed"``: eq. 20, a bump
#: ``1 - bump(theta - alpha; sigma = width / 2)`` per sector. ``"visible-width"``: the
#: probability that the part of a teammate's housing outside the sector still gives
#: ``lidar.min_returns`` whole-footprint returns, from the scanner's beam geometry, averaged
#: over the component's bearing uncertainty (``localization.detection.visible_width_factor``).
BLIND_SECTOR_MODELS = ("seed", "visible-width")
#: Where the lidar's beams fall from one turn to the next. ``"drifting"``: anywhere (a real
#: X4's sample angles drift with its motor speed), so the first beam past a sector edge is
#: uniform within a spacing of it. ``"fixed"``: at the same body-frame bearings
#: ``-pi + k * lidar.beam_spacing_deg`` every turn (the simulated X4).
LIDAR_BEAM_PHASES = ("drifting", "fixed")
#: ``"seed"``: inverse sigmoid of range (eq. 10). ``"constant"``: ``survival_probability``.
SURVIVAL_MODELS = ("seed", "constant")
#: ``"none"``: only the lidar starts tracks (Perera 2021). ``"ray"``: an unexplained camera
#: bearing spawns components along its ray (bearing-only measurement-driven birth).
CAMERA_BIRTH_MODELS = ("none", "ray")
#: ``"phd"``: missed copy ``(1 - P_d) w`` (Vo & Ma, Perera 2021). ``"bernoulli"``: each
#: component's missed copy gets the exact Bernoulli missed-detection weight (see ``PHDConfig``).
MISSED_DETECTION_MODELS = ("phd", "bernoulli")
#: ``"odometry"``: all of ``Q`` at each odometry time update. ``"measurement"``: up to each
#: measurement's stamp (see ``PredictionModel.time_update``).
TIME_UPDATE_MODELS = ("odometry", "measurement")
#: A stamp this far (s) behind a robot's latest one means its clock was reset (a ROS ``/clock``
#: restart, a bag looping): the process-noise clock restarts there instead of waiting for time
#: to pass the old maximum with no noise added.
PROCESS_CLOCK_RESET_S = 1.0
#: Radial standard deviation of a ray-birth component, as a fraction of the spacing ``d``
#: between component centres: below ``1 / sqrt(merge_threshold) = 0.5`` so that neighbours
#: stay apart under the default merge gate (``d^2 / sigma^2 = 4.9 > 4``), and close to it so
#: the sum of the components is flat along the ray (ripple ``+- 2 exp(-2 pi^2 0.45^2) = 3.7 %``).
CAMERA_BIRTH_RADIAL_STD_FRACTION = 0.45


# ------------------------------------------------------------------------------ checks
class _Checks:
    """The field checks of the components: every error names ``<component>.<field>`` (the
    component's ``PREFIX``) and the value."""

    __slots__ = ()
    PREFIX: ClassVar[str] = ""

    def _name(self, name: str) -> str:
        return f"{self.PREFIX}.{name}"

    def _numbers(self) -> None:
        check_number_fields(self, self.PREFIX)

    def _choice(self, name: str, choices: tuple[str, ...]) -> None:
        value = getattr(self, name)
        if value not in choices:
            raise ValueError(f"{self._name(name)} must be one of {choices}, got {value!r}")

    def _positive(self, *names: str) -> None:
        for name in names:
            check_positive(self._name(name), getattr(self, name))

    def _non_negative(self, *names: str) -> None:
        for name in names:
            check_non_negative(self._name(name), getattr(self, name))

    def _within(self, name: str, low: float, high: float) -> None:
        check_number(self._name(name), getattr(self, name), low=low, high=high)

    def _sigmoid_offset(self, *names: str) -> None:
        # Sigmoid offsets >= 1 keep P_s and P_d inside [0, 1] without clipping.
        for name in names:
            check_number(self._name(name), getattr(self, name), low=1)

    def _int_within(self, name: str, low: int, high: int) -> None:
        check_number(self._name(name), getattr(self, name), integer=True, low=low, high=high)


# ------------------------------------------------------------------------------ components
@dataclass(frozen=True, slots=True)
class PredictionModel(_Checks):
    """The time update: process noise and survival (``PHDConfig.prediction``).

    Attributes
    ----------
    process_noise_std_m : float
        Standard deviation of the random-walk process noise added per **time update**,
        ``Q = process_noise_std_m**2 * I``. The Perera 2021 study does not give Q. 0.03 m: a
        teammate moving at 0.2-0.3 m/s covers 0.02-0.03 m per 10 Hz odometry step, and the
        observer's own odometry error adds a little. Scale it with your time-update period.
    time_update : str
        When the process noise is added. ``"odometry"`` (Perera 2021): all of ``Q`` at each
        odometry time update. ``"measurement"`` (default): the random walk is continuous,
        variance rate ``Q / process_noise_interval_s``, and each lidar scan, camera frame and
        odometry sample first adds the share that accrued since the robot's previous one (the
        ``("advance", stamp_s)`` calls :func:`~localization.feed.localizer_calls` emits). The
        simulated camera frames arrive three times per odometry sample: under ``"odometry"`` a
        teammate keeps moving between them while its covariance stands still (1 cm of motion at
        0.5 m is 1.2 sigma of the simulated camera's bearing noise there, per frame). Calls
        without stamps get the Perera 2021 study's behaviour.
    process_noise_interval_s : float
        The interval over which ``process_noise_std_m`` accrues (the odometry period, 0.1 s).
    survival_model : str
        ``"seed"`` (Perera 2021 eq. 10) or ``"constant"``.
    survival_offset, survival_slope_per_m, survival_range_m : float
        ``P_s(m) = 1 / (offset + exp(slope * (||m|| - range)))`` with those three values,
        evaluated at the component mean *before* the time update. Perera 2021 eq. 10: 1.05, 4
        /m, 4 m.
    survival_probability : float
        Constant ``P_s`` when ``survival_model == "constant"``.
    """

    PREFIX: ClassVar[str] = "prediction"

    process_noise_std_m: float = 0.03
    time_update: str = "measurement"
    process_noise_interval_s: float = 0.1
    survival_model: str = "seed"
    survival_offset: float = 1.05
    survival_slope_per_m: float = 4.0
    survival_range_m: float = 4.0
    survival_probability: float = 0.99

    def __post_init__(self) -> None:
        self._numbers()
        self._choice("time_update", TIME_UPDATE_MODELS)
        self._choice("survival_model", SURVIVAL_MODELS)
        self._positive("process_noise_std_m", "process_noise_interval_s", "survival_slope_per_m")
        self._non_negative("survival_range_m")
        # Plausibility: a std beyond this is no motion model (1e300 squares to inf).
        self._within("process_noise_std_m", 0.0, 100.0)
        self._within("process_noise_interval_s", 1e-3, 3600.0)
        self._sigmoid_offset("survival_offset")
        self._within("survival_probability", 0.0, 1.0)


@dataclass(frozen=True, slots=True)
class LidarModel(_Checks):
    """The lidar's measurement model (``PHDConfig.lidar``): its noise, its detection
    probability ``P_d`` (range x blind sectors x occlusion x interference, Perera 2021 eq. 18)
    and its clutter. Defaults: the simulated X4.

    Attributes
    ----------
    noise_std_m : float
        Position noise, ``R_L = noise_std_m**2 * I``. Perera 2021 eq. 17: 0.05 m (0.0025 m^2).
    pd_model : str
        ``"seed"`` (the product of the factors below, eq. 18) or ``"constant"``
        (``detection_probability`` inside ``range_m``; see ``LIDAR_PD_MODELS``).
    pd_offset, pd_slope_per_m, pd_midpoint_m : float
        Range factor ``1 / (offset + exp(slope * (||m|| - midpoint)))``. Default 1.0, 8.78 /m,
        2.14 m: fitted to the simulated lidar's measured detection curve
        (``benchmarks/bench_detection_curves.py``; ``docs/concepts/sensors.md``, "Detection
        curves"): the probability that the feature extractor reports a teammate's housing at
        range r, in free space, outside the blind sectors, without interference (1500 pairs per
        range, RMS residual 0.017 on 0.25-5.5 m). It follows from the geometry: a 65 mm housing
        gives ``2 asin(0.0325 / r) / 0.5 deg - 1`` clean returns and a cluster needs 3, so
        ``P_d`` is 1 up to 1.86 m, 0.73 at 2 m and 0 from 2.48 m. Perera 2021 eq. 19: 1.02, 8
        /m, 1.5 m (``P_d`` = 0.5 at 1.5 m, 0.05 at 1.9 m), its real X4, which fades about 0.6 m
        sooner; with that factor the filter inflates the weight of every simulated teammate at
        1.5-2 m towards ``1 / P_d``.
    detection_probability : float
        Constant ``P_d`` of ``pd_model == "constant"``.
    range_m : float
        Detection range of the ``"constant"`` model (the effective tracking range, 2 m).
    blind_sector_centers_deg, blind_sector_widths_deg : tuple of float
        Blind sectors caused by the camera pillars, robot frame, degrees: a beam whose bearing
        is within half a width of a centre returns nothing. Must match the lidar. Perera 2021
        eq. 20: four 10 deg sectors at +-45 deg and +-135 deg.
    blind_sector_model : str
        How a sector removes detections (see ``BLIND_SECTOR_MODELS``). ``"seed"`` (Perera 2021
        eq. 20): each sector multiplies ``P_d`` by ``1 - bump(bearing - centre; sigma = width /
        2)`` with a bump of peak 1, so ``P_d -> 0`` at the sector centre. ``"visible-width"``
        (default): a teammate is detected when the beams outside the sector that fall wholly on
        its housing (radius ``target_radius_m``, footprint ``beam_footprint_deg``, spacing
        ``beam_spacing_deg``) number at least ``min_returns``. That is a notch with edges
        ``<= 0.5 deg`` wide, ending where enough of the housing clears the sector (the X4 at
        1 m: 4.9 deg from the centre of a 10 deg sector). The Perera 2021 bump (sigma 5 deg) is
        wrong for the simulated X4: measured 0.04 at 2-4 deg from a centre against the bump's
        0.17, and 0.93 at 6-8 deg against 0.62 (``benchmarks/RESULTS.md``, "Sensor detection
        curves").
    beam_spacing_deg : float
        Angle between consecutive beams: the X4's 720 per turn, 0.5 deg (the simulated
        ``LidarConfig.n_beams``).
    min_returns : int
        Returns the feature extractor needs for a teammate (``LidarFeatureConfig.min_beams``:
        3).
    beam_phase : str
        ``"drifting"`` (a real X4) or ``"fixed"`` (default: the simulated X4; see
        ``LIDAR_BEAM_PHASES``): with fixed beams the ``"visible-width"`` notch's edges are
        steps at the first beams past each sector's edges; with drifting beams, ramps one
        spacing wide.
    target_radius_m : float
        Radius of what the lidar sees of a teammate: the X4's 65 mm housing
        (``RobotConfig.housing_radius_m``), for the ``"visible-width"`` blind sectors.
    beam_footprint_deg : float
        Angular width of one beam's sample (the X4, as the simulated
        ``LidarConfig.beam_footprint_deg``: 0.5 deg), for the ``"visible-width"`` blind
        sectors: only beams whose whole footprint lies on the housing count.
    occlusion_std_deg : float
        Angular std of the occlusion bump (Perera 2021 eqs. 21-22: 3 deg).
    occlusion_min_separation_m : float
        A component only occludes components at least this much farther away (a teammate
        cannot hide one that is at the same range). 0 reproduces Perera 2021 literally.
    interference_depth : float
        Depth of the interference notch (Perera 2021 eq. 23: 0.6).
    interference_std_deg : float
        Angular std ``c`` of each null-return notch (Perera 2021 eq. 23 leaves ``c``
        unspecified).
    clutter_intensity : float
        Clutter intensity ``kappa_L`` per m^2 (Poisson false detections per unit area). The
        Perera 2021 study uses 0; 0 is allowed but then every unexplained detection is taken as
        a target. Default 0.05 /m^2, about 0.6 false detections per scan in the 2 m disc.
    missed_moments : bool
        The missed-detection copy of a lidar update under a range-dependent ``P_d``: its
        posterior is ``(1 - P_d(x)) N(x; m, P)``, not the prior reweighted by ``1 - P_d(m)``.
        With ``True`` (default; Perera 2021: False) it is moment-matched along the component's
        range direction (9-point Gauss-Hermite over the linearised range, the angular factors at
        the mean): the weight uses the expected ``P_d`` and the mean moves towards where the
        lidar would not have seen it. A track left at the edge of the lidar's range by a
        teammate that moved beyond it then drifts outwards with each missed scan instead of
        being confirmed in place by the camera. ``pd_model="seed"`` only; the GM-PHD engines
        only (the PMB ignores it).
    """

    PREFIX: ClassVar[str] = "lidar"

    noise_std_m: float = 0.05
    pd_model: str = "seed"
    pd_offset: float = 1.0
    pd_slope_per_m: float = 8.78
    pd_midpoint_m: float = 2.14
    detection_probability: float = 0.9
    range_m: float = 2.0
    blind_sector_centers_deg: tuple[float, ...] = (45.0, 135.0, -135.0, -45.0)
    blind_sector_widths_deg: tuple[float, ...] = (10.0, 10.0, 10.0, 10.0)
    blind_sector_model: str = "visible-width"
    beam_spacing_deg: float = 0.5
    min_returns: int = LidarFeatureConfig().min_beams
    beam_phase: str = "fixed"
    target_radius_m: float = 0.0325
    beam_footprint_deg: float = 0.5
    occlusion_std_deg: float = 3.0
    occlusion_min_separation_m: float = 0.1
    interference_depth: float = 0.6
    interference_std_deg: float = 1.0
    clutter_intensity: float = 0.05
    missed_moments: bool = True

    def __post_init__(self) -> None:
        self._numbers()
        self._choice("pd_model", LIDAR_PD_MODELS)
        self._choice("blind_sector_model", BLIND_SECTOR_MODELS)
        self._choice("beam_phase", LIDAR_BEAM_PHASES)
        self._positive(
            "noise_std_m", "pd_slope_per_m", "range_m", "occlusion_std_deg", "interference_std_deg"
        )
        self._non_negative("pd_midpoint_m", "occlusion_min_separation_m", "clutter_intensity")
        # Plausibility: a std beyond these is no sensor (and 1e300 squares to inf inside the
        # kernels); the angular stds the P_d bumps divide by need a floor.
        for name, low, high in (
            ("noise_std_m", 0.0, 100.0),
            ("range_m", 0.0, 1000.0),
            ("occlusion_std_deg", 1e-3, 180.0),
            ("interference_std_deg", 1e-3, 180.0),
            ("target_radius_m", 1e-3, 10.0),
            ("beam_footprint_deg", 0.0, 10.0),
            ("beam_spacing_deg", 1e-3, 10.0),
            ("detection_probability", 0.0, 1.0),
            ("interference_depth", 0.0, 1.0),
        ):
            self._within(name, low, high)
        self._sigmoid_offset("pd_offset")
        self._int_within("min_returns", 1, 100)
        if self.beam_phase == "fixed":
            turns = 360.0 / self.beam_spacing_deg
            if abs(turns - round(turns)) > 1e-9 * turns:
                raise ValueError(
                    "lidar.beam_spacing_deg must divide 360 with fixed beams "
                    f"(lidar.beam_phase='fixed'), got {self.beam_spacing_deg!r}"
                )
        # One rule for the lidar, the filter and the bridge (swarm_core.validation).
        check_blind_sectors("lidar", self.blind_sector_centers_deg, self.blind_sector_widths_deg)

    @property
    def noise_var_m2(self) -> float:
        """Noise variance ``R_L[0, 0]`` in m^2."""
        return self.noise_std_m**2


@dataclass(frozen=True, slots=True)
class CameraModel(_Checks):
    """The camera's bearing model (``PHDConfig.camera``): noise, ``P_d``, clutter. Defaults:
    the simulated cameras.

    Attributes
    ----------
    noise_std_deg : float
        Constant part of the bearing noise, ``R_C = radians(noise_std_deg)**2`` (plus the
        width term below). Default 0.027 deg, the pixel rounding (1 px / sqrt(12)) of the
        simulated blobs: least squares on their measured RMS error per range where ``P_d >=
        0.9`` gives an ``s0`` below what the fit resolves. Perera 2021 (eq. 29, "25 deg" read as
        a variance of 25 deg^2): 5 deg.
    noise_width_fraction, target_radius_m : float
        Range-dependent part of the bearing noise: a blob's centroid wanders within the
        target's angular width ``W(r) = 2 asin(R / r)`` (``R`` = ``target_radius_m``, the red
        strip's radius: ``RobotConfig.camera_holder_radius_m``, 0.05 m), so ``R_C(r) =
        radians(noise_std_deg)**2 + (noise_width_fraction W(r))**2``, evaluated at each
        component's range (and at each ray birth's). Default 0.0845: the same least squares on
        the simulated blobs' RMS error (0.96 deg at 0.5 m, 0.48 at 1 m, 0.23 at 2 m, 0.16 at
        3 m; the blob model's own ``(1 - fill_min) / 6`` = 0.0833, a centroid offset uniform
        within the unlit part of the strip). Over all of ``sim-6m-20``'s frames the RMS error is
        0.45 deg, which a constant model would use at every range: 4x too tight at 0.3 m.
        Perera 2021: 0 (a constant 5 deg).
    pd_offset, pd_slope_per_m, pd_midpoint_m : float
        Range factor ``1 / (offset + exp(slope * (||m|| - midpoint)))``. Default 1.050, 3.84
        /m, 4.08 m: fitted as the lidar's to the simulated cameras' measured curve (a
        teammate's 5 cm strip with free line of sight; RMS residual 0.023): 0.95 up to 3 m, 0.56
        at 4 m, 0.18 at 4.5 m, 0 from 4.75 m. Perera 2021 eq. 30: 1.1, 5 /m, 4 m.
    clutter_intensity : float
        Clutter intensity ``kappa_C`` per radian of bearing. Besides false red blobs it must
        account for the bearings of teammates the camera sees but the filter does not track
        (the camera sees to ~4 m, the lidar-initialised mixture only holds teammates within
        ~2 m); without it those bearings inflate the weights of tracked components at similar
        bearings. Default 1.22 /rad, measured per ``sim-6m-20`` frame: 1.29 bearings from the
        arena's red decoys, 0.10 random false blobs (0.22 /rad together), and 6.3 bearings of
        teammates beyond the lidar's 50 % range (2.1 m, 1.00 /rad). Perera 2021 gives none; its
        model here uses 0.5 /rad (about 3 such bearings per frame). This is the part that does
        not depend on the tracked disc; :attr:`PHDConfig.camera_clutter_total_per_rad` adds the
        untracked-teammate term below.
    untracked_density_per_m2 : float
        Density ``rho`` of teammates the filter does not track (per m^2), counted from
        ``untracked_min_range_m`` outwards. Their bearings are Poisson clutter of intensity
        ``rho * integral_{r_in}^{inf} P_dC(r) r dr`` per radian (a ring of radius ``r``, width
        ``dr`` and angle ``dtheta`` holds ``rho r dr dtheta`` teammates, each reported with the
        camera's range factor ``P_dC(r)``), added to ``clutter_intensity``. Default 0 (the
        measured ``clutter_intensity`` already counts them). Leave it 0 with
        ``births.camera="ray"``: the camera then tracks those teammates itself.
    untracked_min_range_m : float
        Inner radius ``r_in`` of the untracked band (m): the tracked disc (the lidar's 2 m).
    clutter_per_wide_object : float
        Camera blobs per frame that are not teammates, per compact object wider than a housing
        in the last scan (:mod:`localization.object_clutter`): the camera clutter intensity
        rises on those objects' bearings by this many blobs, spread as their measured blobs
        are. Needs the scan (:attr:`PHDConfig.reads_scans`). Default 0.878, measured in
        ``sim-6m-20`` (``benchmarks/bench_detection_curves.py``): a scan shows 0.94 compact
        objects wider than a housing and at most 0.12 m wide (mostly red decoys); each brings
        0.878 blobs per frame that are not teammates (and 0.014 of teammates). 0 turns it off
        (the Perera 2021 study's uniform clutter). The GM-PHD and the PMB engines.
    wide_object_std_fraction : float
        Std of those blobs' bearings about the object's centre, in the object's angular
        half-widths (added in quadrature to the camera's constant bearing variance). Measured
        as above: 0.280.
    clutter_wide_object_share_per_rad : float
        The part of ``clutter_intensity`` (1/rad) that the wide objects account for: where they
        are modelled (``clutter_per_wide_object`` > 0) the uniform part is
        ``clutter_intensity`` minus this (:attr:`PHDConfig.camera_clutter_uniform_per_rad`);
        before a filter's first scan the objects are unknown and it keeps the whole. At most
        ``clutter_intensity``. Measured as above: the objects explain 67 % of the decoys'
        blobs, 0.131 /rad (1.22 -> 1.09 /rad where they are modelled).
    """

    PREFIX: ClassVar[str] = "camera"

    noise_std_deg: float = 0.027
    noise_width_fraction: float = 0.0845
    target_radius_m: float = 0.05
    pd_offset: float = 1.050
    pd_slope_per_m: float = 3.84
    pd_midpoint_m: float = 4.08
    clutter_intensity: float = 1.22
    untracked_density_per_m2: float = 0.0
    untracked_min_range_m: float = 2.0
    clutter_per_wide_object: float = 0.878
    wide_object_std_fraction: float = 0.280
    clutter_wide_object_share_per_rad: float = 0.131

    def __post_init__(self) -> None:
        self._numbers()
        self._positive("noise_std_deg", "target_radius_m", "pd_slope_per_m")
        self._non_negative(
            "pd_midpoint_m",
            "clutter_intensity",
            "untracked_density_per_m2",
            "untracked_min_range_m",
            "noise_width_fraction",
            "clutter_per_wide_object",
            "clutter_wide_object_share_per_rad",
        )
        for name, low, high in (
            ("noise_std_deg", 0.0, 180.0),
            ("noise_width_fraction", 0.0, 10.0),
            ("target_radius_m", 0.0, 10.0),
            ("wide_object_std_fraction", 0.0, 10.0),
        ):
            self._within(name, low, high)
        self._sigmoid_offset("pd_offset")
        if self.clutter_wide_object_share_per_rad > self.clutter_intensity:
            raise ValueError(
                "camera.clutter_wide_object_share_per_rad must be at most "
                f"camera.clutter_intensity ({self.clutter_intensity!r}), got "
                f"{self.clutter_wide_object_share_per_rad!r}"
            )

    @property
    def noise_var_rad2(self) -> float:
        """The constant part of the bearing noise variance ``R_C`` in rad^2 (all of it when
        ``noise_width_fraction == 0``, Perera 2021)."""
        return math.radians(self.noise_std_deg) ** 2

    @property
    def clutter_total_per_rad(self) -> float:
        """Clutter ``kappa_C`` used by the update (1/rad): false blobs plus untracked
        teammates, ``clutter_intensity + rho * int_{r_in}^inf P_dC(r) r dr``."""
        rho = self.untracked_density_per_m2
        if rho == 0.0:
            return float(self.clutter_intensity)
        moment = _range_moment(
            self.untracked_min_range_m, self.pd_offset, self.pd_slope_per_m, self.pd_midpoint_m
        )
        return float(self.clutter_intensity + rho * moment)


@dataclass(frozen=True, slots=True)
class BirthModel(_Checks):
    """Where new components come from (``PHDConfig.births``).

    Attributes
    ----------
    model : str
        ``"measurement"`` (default: adaptive births, below) or ``"fixed"`` (Perera 2021 eq. 11).
        Measured in ``sim-6m-20`` (wander, 20 robots): teammates enter an observer's 2 m disc
        0.085 times per lidar scan, and the Perera 2021 study's fixed birth (weight 0.001
        spread over ``N(0, 4 I)``) gives a first detection a weight of ~5e-4, so a newcomer
        needs two or three more scans (0.3-0.4 s) to pass 0.1; adaptive births confirm it at
        the next time update. The fixed birth component joins the prior of every *lidar*
        update (the only sensor that can initialise a position) and only its detected copies
        are kept, as in Stone Soup; Perera 2021 adds it at every time update, where its
        lingering missed-detection copies get merged into tracks and inflate their
        covariances.
    weight : float
        Weight of the fixed birth component (expected births per lidar scan). Perera 2021
        eq. 11: 0.001.
    mean_m : tuple of float
        Mean ``(x, y)`` of the fixed birth component in the robot frame. Perera 2021 eq. 11:
        (0, 0).
    std_m : float
        Standard deviation of the fixed birth component, ``cov = std_m**2 * I``. Perera 2021
        eq. 11: 2 m (``cov = diag(4, 4)``).
    measurement_weight : float
        Weight of each adaptive birth component (``model == "measurement"``): the expected
        number of new teammates behind one unexplained detection (not in Perera 2021).
        0.25, measured in ``sim-6m-20``: of the detections that spawn a birth, 22 % lie at a
        teammate with lidar + camera (the camera removes the decoy-post tracks, whose
        detections then spawn births again at every scan) and 63 % with the lidar only.
    measurement_cov_scale : float
        Adaptive birth covariance is ``measurement_cov_scale * R_L``.
    measurement_max_explained : float
        A lidar detection spawns a birth when the fraction of it explained by the current
        components, ``sum_i P_d w N / (kappa + sum_i P_d w N)``, is below this value.
        The birth enters the mixture at the next time update (Ristic et al. 2012 style).
    camera : str
        ``"none"`` (default; Perera 2021: only lidar detections start tracks) or ``"ray"``: a
        bearing whose explained fraction ``sum_i P_d w_i g_i / (kappa_C + sum_i ...)`` after
        the camera update is below ``camera_max_explained`` adds ``camera_components``
        components along its ray, at the centres ``r_k`` of equal range cells over
        ``[camera_min_range_m, camera_max_range_m]``, radial std
        ``CAMERA_BIRTH_RADIAL_STD_FRACTION`` x the cell width, cross-range std ``r_k`` x the
        bearing noise, weights ``camera_weight * r_k P_dC(r_k) / sum_j r_j P_dC(r_j)`` (a
        bearing from a uniform teammate density comes from range ``r`` with a probability
        proportional to ``r P_dC(r)``). They join the posterior of the frame that spawned them
        (it is their own update, so it is not applied twice) and the next frames and lidar
        scans confirm them: the lidar removes the near part of the ray where it sees nothing
        and parallax from the observer's motion sharpens the range. Off by default: measured,
        they put ghost components along the rays that the formation controller follows (final
        error 0.05 -> 0.44 m, ``lab-3m-4``, seed 0); the bearings of teammates the lidar does
        not reach are clutter instead (``camera.clutter_intensity`` counts them).
    camera_weight : float
        Total weight of one ray birth: the expected number of new teammates behind one
        unexplained bearing. 0.25, as ``measurement_weight``.
    camera_components : int
        Components per ray birth (6: 0.62 m cells over 0.3-4 m).
    camera_min_range_m, camera_max_range_m : float
        Range band of a ray birth (m): 0.3 (two robot radii: nearer than that is our own body)
        and 4 (the camera's range, Perera 2021 eq. 30's midpoint).
    camera_max_explained : float
        Threshold on a bearing's explained fraction below which it spawns a ray (as
        ``measurement_max_explained`` for the lidar).
    """

    PREFIX: ClassVar[str] = "births"

    model: str = "measurement"
    weight: float = 0.001
    mean_m: tuple[float, float] = (0.0, 0.0)
    std_m: float = 2.0
    measurement_weight: float = 0.25
    measurement_cov_scale: float = 4.0
    measurement_max_explained: float = 0.5
    camera: str = "none"
    camera_weight: float = 0.25
    camera_components: int = 6
    camera_min_range_m: float = 0.3
    camera_max_range_m: float = 4.0
    camera_max_explained: float = 0.5

    def __post_init__(self) -> None:
        self._numbers()
        self._choice("model", BIRTH_MODELS)
        self._choice("camera", CAMERA_BIRTH_MODELS)
        self._positive("std_m", "measurement_cov_scale", "camera_min_range_m")
        self._within("std_m", 0.0, 100.0)
        self._within("measurement_cov_scale", 0.0, 1e6)
        for name in ("measurement_max_explained", "camera_max_explained"):
            self._within(name, 0.0, 1.0)
        for name in ("weight", "measurement_weight", "camera_weight"):
            check_number(self._name(name), getattr(self, name), low=0, high=1e3, below=True)
        self._int_within("camera_components", 1, 64)
        if not self.camera_max_range_m > self.camera_min_range_m:
            raise ValueError(
                "births.camera_max_range_m must be > births.camera_min_range_m "
                f"({self.camera_min_range_m!r}), got {self.camera_max_range_m!r}"
            )
        value = self.mean_m
        ok = (
            isinstance(value, tuple)
            and len(value) == 2
            and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in value
            )
        )
        if not ok:
            raise ValueError(f"births.mean_m must be a tuple of 2 finite numbers, got {value!r}")


@dataclass(frozen=True, slots=True)
class Reduction(_Checks):
    """Mixture reduction after each update (``PHDConfig.reduction``; Vo & Ma's pruning and
    merging).

    Attributes
    ----------
    prune_threshold : float
        Components with a lower weight are dropped after each update (mass is lost).
        Must be > 0 (zero-weight components are always dropped).
    merge_threshold : float
        Squared Mahalanobis distance below which components merge (Vo & Ma's ``U``).
    max_components : int
        Cap on the number of components kept after reduction (largest weights survive).
    min_range_m : float
        Floor on ``||m||`` for the bearing Jacobian and unit bearing vectors; components closer
        than this (inside our own body) get camera ``P_d = 0`` because their bearing is undefined.
    """

    PREFIX: ClassVar[str] = "reduction"

    prune_threshold: float = 1e-4
    merge_threshold: float = 4.0
    max_components: int = 64
    min_range_m: float = 0.1

    def __post_init__(self) -> None:
        self._numbers()
        self._positive("merge_threshold", "min_range_m")
        check_number(
            self._name("prune_threshold"),
            self.prune_threshold,
            low=0,
            high=1,
            above=True,
            below=True,
        )
        # Cost guard: the banks allocate (6, R, max_components) and merge in O(C^2).
        self._int_within("max_components", 1, 10_000)


_COMPONENTS: dict[str, type] = {
    "prediction": PredictionModel,
    "lidar": LidarModel,
    "camera": CameraModel,
    "births": BirthModel,
    "reduction": Reduction,
}


@dataclass(frozen=True, slots=True)
class PHDConfig:
    """Parameters of :class:`~localization.RobotCentricPHD` and of every bank and family built
    on it. ``PHDConfig()`` is the model the simulator presets run (sensor models measured on
    the simulated sensors); :meth:`perera2021` is the Perera 2021 study's.

    Attributes
    ----------
    mode : str
        ``"lidar-camera"`` (LC) or ``"lidar-only"`` (LO; ``update_camera`` does nothing).
    missed_detection : str
        ``"bernoulli"`` (default) or ``"phd"`` (Vo & Ma, Perera 2021): under ``"phd"`` a
        component's missed-detection copy keeps ``(1 - P_d) w``. ``"bernoulli"``: it keeps the
        exact Bernoulli filter's missed posterior ``w (1 - P_d) / (1 - r P_d + r Lambda)``, the
        component read as ``n = max(1, ceil(w))`` targets of existence ``r = w / n``, and
        ``Lambda = sum_h P_d g_h / (kappa + sum_{j != i} P_d w_j g_jh)``, the evidence that
        the component was detected, against clutter plus every other component. The PHD's
        ``(1 - P_d) w`` is its first-order (Poisson) approximation, exact only for ``r << 1``;
        at ``r ~ 1`` it takes an established track to ``1 - P_d`` after one missed frame
        (0.09 with the Perera 2021 study's camera), while the exact missed posterior of a target
        that was certainly there is still ``r (1 - P_d) / (1 - r P_d)`` (0.64 after a time update
        with ``P_s = 0.95``): one dropped blob does not kill the track, three in a row do. With a
        gated measurement ``Lambda`` is large and the missed copy vanishes, so a detected
        track is not inflated towards ``1 / P_d``. Detected copies keep the PHD weights.
    prediction : PredictionModel
        The time update: process noise and survival.
    lidar : LidarModel
        The lidar's noise, detection probability and clutter.
    camera : CameraModel
        The camera's bearing noise, detection probability and clutter.
    births : BirthModel
        Where new components come from.
    reduction : Reduction
        Pruning, merging, the component cap and the minimum range.
    """

    mode: str = "lidar-camera"
    missed_detection: str = "bernoulli"
    prediction: PredictionModel = field(default_factory=PredictionModel)
    lidar: LidarModel = field(default_factory=LidarModel)
    camera: CameraModel = field(default_factory=CameraModel)
    births: BirthModel = field(default_factory=BirthModel)
    reduction: Reduction = field(default_factory=Reduction)

    def __post_init__(self) -> None:
        for name, kind in _COMPONENTS.items():
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"PHDConfig.{name} must be a {kind.__name__} (as an override, a dict of "
                    f"its fields also), got {getattr(self, name)!r}"
                )
        if self.mode not in MODES:
            raise ValueError(f"PHDConfig.mode must be one of {MODES}, got {self.mode!r}")
        if self.missed_detection not in MISSED_DETECTION_MODELS:
            raise ValueError(
                f"PHDConfig.missed_detection must be one of {MISSED_DETECTION_MODELS}, got "
                f"{self.missed_detection!r}"
            )

    @classmethod
    def perera2021(cls) -> PHDConfig:
        """The Perera 2021 study's model (its hardware: chapter 3, eqs. 10-30), with the
        choices the study leaves open as in ``PHDConfig()`` (process noise, clutter, pruning,
        merging, guards). Its fixed birth (eq. 11), lidar range factor (eq. 19), bump-shaped
        blind sectors (eq. 20), camera range factor (eq. 30) and 5 deg bearing noise, the PHD's
        missed-detection copies and all of ``Q`` at each odometry update."""
        return cls(
            missed_detection="phd",
            prediction=PredictionModel(time_update="odometry"),
            lidar=LidarModel(
                pd_offset=1.02,
                pd_slope_per_m=8.0,
                pd_midpoint_m=1.5,
                blind_sector_model="seed",
                beam_phase="drifting",
                missed_moments=False,
            ),
            camera=CameraModel(
                noise_std_deg=5.0,
                noise_width_fraction=0.0,
                pd_offset=1.1,
                pd_slope_per_m=5.0,
                pd_midpoint_m=4.0,
                clutter_intensity=0.5,
                clutter_per_wide_object=0.0,
                wide_object_std_fraction=0.28,
                clutter_wide_object_share_per_rad=0.0,
            ),
            births=BirthModel(model="fixed"),
        )

    def replace(self, **changes: Any) -> PHDConfig:
        """A copy with ``changes`` applied: a component takes a component or a dict of its
        fields (``replace(lidar={"noise_std_m": 0.04})``); a field that moved into a
        component is refused with its new place."""
        return replace_fields(self, changes)

    def camera_bearing_var(self, range_m: np.ndarray | float) -> np.ndarray:
        """``R_C(r)`` in rad^2 at ranges ``range_m`` (m, any shape; floored at
        ``reduction.min_range_m``): the constant part plus ``(camera.noise_width_fraction
        W(r))^2``, ``W(r) = 2 asin(min(1, camera.target_radius_m / r))``."""
        camera = self.camera
        r = np.maximum(np.asarray(range_m, dtype=float), self.reduction.min_range_m)
        width = 2.0 * np.arcsin(np.minimum(1.0, camera.target_radius_m / r))
        return camera.noise_var_rad2 + (camera.noise_width_fraction * width) ** 2

    @property
    def camera_clutter_total_per_rad(self) -> float:
        """:attr:`CameraModel.clutter_total_per_rad` (1/rad)."""
        return self.camera.clutter_total_per_rad

    @property
    def camera_clutter_uniform_per_rad(self) -> float:
        """The uniform camera clutter of a filter that models the wide objects (1/rad):
        :attr:`camera_clutter_total_per_rad` less the objects' share, when they are on."""
        total = self.camera_clutter_total_per_rad
        if self.models_wide_objects:
            return total - self.camera.clutter_wide_object_share_per_rad
        return total

    @property
    def models_wide_objects(self) -> bool:
        """Whether camera updates use the wide objects' clutter (a rate > 0, and a camera)."""
        return self.camera.clutter_per_wide_object > 0.0 and self.mode != "lidar-only"

    @property
    def reads_scans(self) -> bool:
        """Whether the filter keeps each lidar call's scan profile (for
        :attr:`models_wide_objects`)."""
        return self.models_wide_objects


#: The flat field names of earlier releases and where each lives now (an override that uses
#: one is refused with its new place; :func:`nest_flat_phd` converts stored flat configs).
MOVED_FIELDS: dict[str, str] = {
    **{
        name: f"prediction.{name}"
        for name in (
            "process_noise_std_m",
            "time_update",
            "process_noise_interval_s",
            "survival_model",
            "survival_offset",
            "survival_slope_per_m",
            "survival_range_m",
            "survival_probability",
        )
    },
    "birth": "births.model",
    "birth_weight": "births.weight",
    "birth_mean_m": "births.mean_m",
    "birth_std_m": "births.std_m",
    "measurement_birth_weight": "births.measurement_weight",
    "measurement_birth_cov_scale": "births.measurement_cov_scale",
    "measurement_birth_max_explained": "births.measurement_max_explained",
    "camera_birth": "births.camera",
    "camera_birth_weight": "births.camera_weight",
    "camera_birth_components": "births.camera_components",
    "camera_birth_min_range_m": "births.camera_min_range_m",
    "camera_birth_max_range_m": "births.camera_max_range_m",
    "camera_birth_max_explained": "births.camera_max_explained",
    "lidar_noise_std_m": "lidar.noise_std_m",
    "lidar_pd_model": "lidar.pd_model",
    "lidar_pd_offset": "lidar.pd_offset",
    "lidar_pd_slope_per_m": "lidar.pd_slope_per_m",
    "lidar_pd_midpoint_m": "lidar.pd_midpoint_m",
    "lidar_detection_probability": "lidar.detection_probability",
    "lidar_range_m": "lidar.range_m",
    "blind_sector_centers_deg": "lidar.blind_sector_centers_deg",
    "blind_sector_widths_deg": "lidar.blind_sector_widths_deg",
    "blind_sector_model": "lidar.blind_sector_model",
    "lidar_beam_spacing_deg": "lidar.beam_spacing_deg",
    "lidar_min_returns": "lidar.min_returns",
    "lidar_beam_phase": "lidar.beam_phase",
    "occlusion_std_deg": "lidar.occlusion_std_deg",
    "occlusion_min_separation_m": "lidar.occlusion_min_separation_m",
    "interference_depth": "lidar.interference_depth",
    "interference_std_deg": "lidar.interference_std_deg",
    "lidar_clutter_intensity": "lidar.clutter_intensity",
    "lidar_missed_moments": "lidar.missed_moments",
    "scan_target_radius_m": "lidar.target_radius_m",
    "scan_beam_footprint_deg": "lidar.beam_footprint_deg",
    **{
        f"camera_{name}": f"camera.{name}"
        for name in (
            "noise_std_deg",
            "noise_width_fraction",
            "target_radius_m",
            "pd_offset",
            "pd_slope_per_m",
            "pd_midpoint_m",
            "clutter_intensity",
            "untracked_density_per_m2",
            "untracked_min_range_m",
            "clutter_per_wide_object",
            "wide_object_std_fraction",
            "clutter_wide_object_share_per_rad",
        )
    },
    **{
        name: f"reduction.{name}"
        for name in ("prune_threshold", "merge_threshold", "max_components", "min_range_m")
    },
}
#: Flat fields of earlier releases that no longer exist: the scan's free-space and visibility
#: evidence (measured worse than the filter without it) and its parameters.
REMOVED_FIELDS = (
    "scan_evidence",
    "scan_range_noise_std_m",
    "scan_range_noise_quadratic_per_m",
    "scan_margin_sigmas",
)


def nest_flat_phd(flat: dict[str, Any]) -> dict[str, Any]:
    """A flat config dict of an earlier release (one key per field, e.g. from a recorded bag's
    metadata) as the nested dict :class:`PHDConfig` takes. Nested keys pass through; the
    removed scan-evidence fields are dropped when the evidence was off.

    Raises
    ------
    ValueError
        If the dict switches the removed scan evidence on, or names no known field.
    """
    nested: dict[str, Any] = {}
    for key, value in flat.items():
        if key in REMOVED_FIELDS:
            if key == "scan_evidence" and value:
                raise ValueError(
                    "scan_evidence=True: the scan's free-space evidence was removed from the "
                    "filter (this config cannot be reproduced)"
                )
            continue
        if key in MOVED_FIELDS:
            component, name = MOVED_FIELDS[key].split(".")
            nested.setdefault(component, {})[name] = value
        elif key in _COMPONENTS and isinstance(value, dict):
            nested.setdefault(key, {}).update(value)
        else:
            nested[key] = value
    return nested


def replace_fields(obj: Any, overrides: dict[str, Any], prefix: str = "") -> Any:
    """The dataclass ``obj`` with ``overrides`` applied, recursively: a nested dataclass field
    takes a dataclass or a dict of its fields. A PHDConfig field that moved into a component
    is refused with its new place (``camera_noise_std_deg is now camera.noise_std_deg``).

    Raises
    ------
    ValueError
        If a key names no field (``prefix`` + the key, and the valid keys), before anything
        is built; the dataclasses' own checks then check the values.
    """
    names = {f.name for f in dataclasses.fields(obj)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in names:
            if isinstance(obj, PHDConfig) and key in MOVED_FIELDS:
                raise ValueError(f"{prefix}{key} is now {prefix}{MOVED_FIELDS[key]}")
            if isinstance(obj, PHDConfig) and key in REMOVED_FIELDS:
                raise ValueError(
                    f"{prefix}{key} was removed (the scan's free-space evidence, measured "
                    "worse than the filter without it)"
                )
            raise ValueError(f"unknown config key {prefix + key!r}; valid keys: {sorted(names)}")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            value = replace_fields(current, value, prefix=f"{prefix}{key}.")
        elif isinstance(value, np.generic):  # np.int64(4) from a sweep: stored as 4
            value = value.item()
        changes[key] = value
    return dataclasses.replace(obj, **changes) if changes else obj


@functools.lru_cache(maxsize=64)
def _range_moment(r_in: float, offset: float, slope: float, mid: float) -> float:
    """``int_{r_in}^inf r / (offset + exp(slope (r - mid))) dr`` (m^2): the trapezoidal rule
    with 0.5 mm steps up to where the integrand is below ``exp(-40)`` of its peak."""
    r_out = max(r_in, mid + 40.0 / slope)
    n = max(2, int(math.ceil((r_out - r_in) / 5e-4)) + 1)
    r = np.linspace(r_in, r_out, n)
    f = r / (offset + np.exp(np.minimum(slope * (r - mid), 700.0)))
    return float((r[1] - r[0]) * (f.sum() - 0.5 * (f[0] + f[-1])))


_Config = TypeVar("_Config")


def config_with_overrides(config: Any, cls: type[_Config], overrides: dict[str, Any]) -> _Config:
    """``config`` (default: ``cls()``) with the fields in ``overrides`` replaced
    (:func:`replace_fields`: a component takes a dict of its fields).

    The constructor idiom of every filter here: ``Filter(config=None, **overrides)``.

    Raises
    ------
    ValueError
        If ``config`` is not a ``cls``, or ``overrides`` names a field ``cls`` lacks (the
        dataclass's own validation then checks the values).
    """
    if config is None:
        config = cls()
    elif not isinstance(config, cls):
        raise ValueError(f"config must be a {cls.__name__}, got {type(config).__name__}")
    return replace_fields(config, overrides) if overrides else config
