"""Configuration of the robot-centric GM-PHD filter.

One frozen dataclass, :class:`PHDConfig`, holds every model parameter. Defaults are the
Perera 2021 thesis' values (chapter 3, its hardware) wherever the thesis gives one; the
places where we had to choose (process noise, clutter, pruning, merging, guards) say so in the
field description. The simulator's presets use :data:`swarm_env.config.SIMULATOR_PHD`, the
same model with the birth and the lidar range factor matched to the simulated sensors.
Units are in the field names (``_m``, ``_deg``, ``_per_m``, ``_per_m2``, ``_per_rad``).

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
from dataclasses import dataclass, fields
from typing import Any, TypeVar

import numpy as np

from swarm_core.validation import check_blind_sectors, check_number_fields

__all__ = [
    "PHDConfig",
    "config_with_overrides",
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
#: ``"constant"``: ``lidar_detection_probability`` inside ``lidar_range_m``, 0 outside.
LIDAR_PD_MODELS = ("seed", "constant")
#: The lidar's blind-sector factor (``lidar_pd_model == "seed"``). ``"seed"``: eq. 20, a bump
#: ``1 - bump(theta - alpha; sigma = width / 2)`` per sector. ``"visible-width"``: the
#: probability that the part of a teammate's housing outside the sector still gives
#: ``lidar_min_returns`` whole-footprint returns, from the scanner's beam geometry, averaged
#: over the component's bearing uncertainty (``localization.detection.visible_width_factor``).
BLIND_SECTOR_MODELS = ("seed", "visible-width")
#: Where the lidar's beams fall from one turn to the next. ``"drifting"``: anywhere (a real
#: X4's sample angles drift with its motor speed), so the first beam past a sector edge is
#: uniform within a spacing of it. ``"fixed"``: at the same body-frame bearings
#: ``-pi + k * lidar_beam_spacing_deg`` every turn (the simulated X4).
LIDAR_BEAM_PHASES = ("drifting", "fixed")
#: ``"seed"``: inverse sigmoid of range (eq. 10). ``"constant"``: ``survival_probability``.
SURVIVAL_MODELS = ("seed", "constant")
#: ``"none"``: only the lidar starts tracks (Perera 2021). ``"ray"``: an unexplained camera
#: bearing spawns components along its ray (bearing-only measurement-driven birth).
CAMERA_BIRTH_MODELS = ("none", "ray")
#: ``"phd"``: missed copy ``(1 - P_d) w`` (Vo & Ma, Perera 2021). ``"bernoulli"``: each
#: component's missed copy gets the exact Bernoulli missed-detection weight (see ``PHDConfig``).
MISSED_DETECTION_MODELS = ("phd", "bernoulli")
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


@dataclass(frozen=True, slots=True)
class PHDConfig:
    """Parameters of :class:`~localization.RobotCentricPHD` (defaults: the Perera 2021 study's).

    Attributes
    ----------
    mode : str
        ``"lidar-camera"`` (LC) or ``"lidar-only"`` (LO; ``update_camera`` does nothing).
    process_noise_std_m : float
        Standard deviation of the random-walk process noise added per **time update**,
        ``Q = process_noise_std_m**2 * I``. The seed does not give Q. Default 0.03 m: a teammate
        moving at 0.2-0.3 m/s covers 0.02-0.03 m per 10 Hz odometry step, and the observer's own
        odometry error adds a little. Scale it with your time-update period.
    time_update : str
        When the process noise is added. ``"odometry"`` (Perera 2021): all of ``Q`` at each
        odometry time update. ``"measurement"``: the random walk is continuous, variance rate
        ``Q / process_noise_interval_s``, and each lidar scan, camera frame and odometry sample
        first adds the share that accrued since the robot's previous one (the ``("advance",
        stamp_s)`` calls :func:`~localization.feed.localizer_calls` emits). Camera frames
        arrive three times per odometry sample: under ``"odometry"`` a teammate keeps moving
        between them while its covariance stands still (1 cm of motion at 0.5 m is 1.2 sigma of
        the simulated camera's bearing noise there, per frame). Calls without stamps get
        the Perera 2021 study's behaviour.
    process_noise_interval_s : float
        The interval over which ``process_noise_std_m`` accrues (the odometry period, 0.1 s).
    survival_model : str
        ``"seed"`` (eq. 10) or ``"constant"``.
    survival_offset, survival_slope_per_m, survival_range_m : float
        ``P_s(m) = 1 / (offset + exp(slope * (||m|| - range)))`` with those three values,
        evaluated at the component mean *before* the time update. Seed: 1.05, 4, 4.
    survival_probability : float
        Constant ``P_s`` when ``survival_model == "constant"``.
    birth : str
        ``"fixed"`` (default, Perera 2021 eq. 11) or ``"measurement"`` (adaptive births, below).
        Measured in ``seed-sim`` (wander, 20 robots): teammates enter an observer's 2 m disc
        0.085 times per lidar scan, and the Perera 2021 study's fixed birth (weight 0.001 spread
        over ``N(0, 4 I)``) gives a first detection a weight of ~5e-4, so a newcomer needs two or
        three more scans (0.3-0.4 s) to pass 0.1; adaptive births confirm it at the next
        time update (the simulator presets use them).
        The fixed birth component joins the prior of every *lidar* update (the only sensor
        that can initialise a position) and only its detected copies are kept, as in Stone
        Soup; Perera 2021 adds it at every time update, where its lingering missed-detection
        copies get merged into tracks and inflate their covariances.
    birth_weight : float
        Weight of the fixed birth component (expected births per lidar scan). Seed: 0.001.
    birth_mean_m : tuple of float
        Mean ``(x, y)`` of the fixed birth component in the robot frame. Seed: (0, 0).
    birth_std_m : float
        Standard deviation of the fixed birth component, ``cov = birth_std_m**2 * I``.
        Seed: 2 m (``cov = diag(4, 4)``).
    measurement_birth_weight : float
        Weight of each adaptive birth component (``birth == "measurement"``): the expected
        number of new teammates behind one unexplained detection (not in Perera 2021). Default
        0.25, measured in
        ``seed-sim``: of the detections that spawn a birth, 22 % lie at a teammate with lidar +
        camera (the camera removes the decoy-post tracks, whose detections then spawn births
        again at every scan) and 63 % with the lidar only.
    measurement_birth_cov_scale : float
        Adaptive birth covariance is ``measurement_birth_cov_scale * R_L``.
    measurement_birth_max_explained : float
        A lidar detection spawns a birth when the fraction of it explained by the current
        components, ``sum_i P_d w N / (kappa + sum_i P_d w N)``, is below this value.
        The birth enters the mixture at the next time update (Ristic et al. 2012 style).
    lidar_noise_std_m : float
        Lidar position noise, ``R_L = lidar_noise_std_m**2 * I``. Perera 2021 eq. 17: 0.05
        (0.0025 m^2).
    lidar_pd_model : str
        ``"seed"`` or ``"constant"`` (see ``LIDAR_PD_MODELS``).
    lidar_pd_offset, lidar_pd_slope_per_m, lidar_pd_midpoint_m : float
        Range factor ``1 / (offset + exp(slope * (||m|| - midpoint)))``. Perera 2021 eq. 19
        (1.02, 8, 1.5: ``P_d`` = 0.5 at 1.5 m, 0.05 at 1.9 m) describes that study's hardware. The
        simulator presets use the fit to the simulated X4's measured curve, 1.0, 8.78, 2.14
        (``swarm_env.config.SIM_LIDAR_PD_*``: 1 up to 1.86 m, 0.73 at 2 m, 0 from 2.48 m).
        With the Perera 2021 study's factor the filter inflates the weight of every teammate at
        1.5-2 m towards ``1/P_d``.
    lidar_detection_probability : float
        Constant ``P_d`` used by ``lidar_pd_model == "constant"``.
    lidar_range_m : float
        Detection range of the ``"constant"`` model (seed: effective tracking range 2 m).
    blind_sector_centers_deg, blind_sector_widths_deg : tuple of float
        Lidar blind sectors caused by the camera pillars, robot frame, degrees: a beam whose
        bearing is within half a width of a centre returns nothing. Must match the lidar.
    blind_sector_model : str
        How a sector removes detections (see ``BLIND_SECTOR_MODELS``). ``"seed"``: each
        sector multiplies ``P_d`` by ``1 - bump(bearing - centre; sigma = width / 2)`` with a
        bump of peak 1, so ``P_d -> 0`` at the sector centre. ``"visible-width"``: a teammate
        is detected when the beams outside the sector that fall wholly on its housing
        (radius ``scan_target_radius_m``, footprint ``scan_beam_footprint_deg``, spacing
        ``lidar_beam_spacing_deg``) number at least ``lidar_min_returns``. That is a notch
        with edges ``<= 0.5 deg`` wide, ending where enough of the housing clears the sector
        (the X4 at 1 m: 4.9 deg from the centre of a 10 deg sector). The
        Perera 2021 bump (sigma 5 deg) is wrong for the simulated X4: measured 0.04 at 2-4 deg
        from a centre against the bump's 0.17, and 0.93 at 6-8 deg against 0.62
        (``docs/concepts/localizers.md``, "The blind sectors' notch").
    lidar_beam_spacing_deg : float
        Angle between consecutive lidar beams (the X4: 720 per turn, 0.5 deg).
    lidar_min_returns : int
        Returns the feature extractor needs for a teammate
        (``LidarFeatureConfig.min_beams``: 3).
    lidar_beam_phase : str
        ``"drifting"`` or ``"fixed"`` (see ``LIDAR_BEAM_PHASES``): with fixed beams the
        ``"visible-width"`` notch's edges are steps at the first beams past each sector's
        edges; with drifting beams, ramps one spacing wide.
    occlusion_std_deg : float
        Angular std of the occlusion bump (Perera 2021 eqs. 21-22: 3 deg).
    occlusion_min_separation_m : float
        A component only occludes components at least this much farther away (a teammate
        cannot hide one that is at the same range). 0 reproduces Perera 2021 literally.
    interference_depth : float
        Depth of the interference notch (Perera 2021 eq. 23: 0.6).
    interference_std_deg : float
        Angular std ``c`` of each null-return notch (Perera 2021 leaves ``c`` unspecified).
    lidar_clutter_intensity : float
        Lidar clutter intensity ``kappa_L`` per m^2 (Poisson false detections per unit area).
        The seed uses 0; 0 is allowed but then every unexplained detection is taken as a
        target. Default 0.05 /m^2, about 0.6 false detections per scan in the 2 m disc.
    camera_noise_std_deg : float
        Camera bearing noise, ``R_C = radians(camera_noise_std_deg)**2``. Seed: "25 deg" read
        as a variance of 25 deg^2, i.e. 5 deg std.
    camera_noise_width_fraction, camera_target_radius_m : float
        Range-dependent part of the bearing noise: a blob's centroid wanders within the
        target's angular width ``W(r) = 2 asin(R / r)`` (``R`` = ``camera_target_radius_m``,
        the red strip's radius), so ``R_C(r) = radians(camera_noise_std_deg)**2 +
        (camera_noise_width_fraction W(r))**2``, evaluated at each component's range (and at
        each ray birth's). The seed has 0 (a constant 5 deg); the simulator's is measured
        (``swarm_env.config.SIM_CAMERA_NOISE_WIDTH_FRACTION``): 0.96 deg at 0.5 m, 0.24 deg
        at 2 m, where a constant would be 4x too tight close in or too loose far out.
    camera_pd_offset, camera_pd_slope_per_m, camera_pd_midpoint_m : float
        Camera range factor (Perera 2021 eq. 30: 1.1, 5, 4).
    camera_clutter_intensity : float
        Camera clutter intensity ``kappa_C`` per radian of bearing. Besides false red blobs it
        must account for the bearings of teammates the camera sees but the filter does not
        track (the camera sees to ~4 m, the lidar-initialised mixture only holds teammates
        within ~2 m); without it those bearings inflate the weights of tracked components at
        similar bearings. Default 0.5 /rad (about 3 such bearings per frame). This is the part
        that does not depend on the tracked disc; :attr:`camera_clutter_total_per_rad` adds
        the untracked-teammate term below.
    camera_untracked_density_per_m2 : float
        Density ``rho`` of teammates the filter does not track (per m^2), counted from
        ``camera_untracked_min_range_m`` outwards. Their bearings are Poisson clutter of
        intensity ``rho * integral_{r_in}^{inf} P_dC(r) r dr`` per radian (a ring of radius
        ``r``, width ``dr`` and angle ``dtheta`` holds ``rho r dr dtheta`` teammates, each
        reported with the camera's range factor ``P_dC(r)``), added to
        ``camera_clutter_intensity``. Default 0 (the Perera 2021 study's model). Leave it 0 with
        ``camera_birth="ray"``: the camera then tracks those teammates itself.
    camera_untracked_min_range_m : float
        Inner radius ``r_in`` of the untracked band (m): the tracked disc (the lidar's 2 m).
    camera_birth : str
        ``"none"`` (Perera 2021: only lidar detections start tracks) or ``"ray"``: a bearing
        whose explained fraction ``sum_i P_d w_i g_i / (kappa_C + sum_i ...)`` after the
        camera update is below ``camera_birth_max_explained`` adds
        ``camera_birth_components`` components along its ray, at the centres ``r_k`` of equal
        range cells over ``[camera_birth_min_range_m, camera_birth_max_range_m]``, radial std
        ``CAMERA_BIRTH_RADIAL_STD_FRACTION`` x the cell width, cross-range std ``r_k`` x the
        bearing noise, weights ``camera_birth_weight * r_k P_dC(r_k) / sum_j r_j P_dC(r_j)``
        (a bearing from a uniform teammate density comes from range ``r`` with a probability
        proportional to ``r P_dC(r)``). They join the posterior of the frame that spawned them
        (it is their own update, so it is not applied twice) and the next frames and lidar
        scans confirm them: the lidar removes the near part of the ray where it sees nothing
        and parallax from the observer's motion sharpens the range.
    camera_birth_weight : float
        Total weight of one ray birth: the expected number of new teammates behind one
        unexplained bearing. Default 0.25, as ``measurement_birth_weight``.
    camera_birth_components : int
        Components per ray birth (default 6: 0.62 m cells over 0.3-4 m).
    camera_birth_min_range_m, camera_birth_max_range_m : float
        Range band of a ray birth (m). Defaults 0.3 (two robot radii: nearer than that is
        our own body) and 4 (the camera's range, Perera 2021 eq. 30's midpoint).
    camera_birth_max_explained : float
        Threshold on a bearing's explained fraction below which it spawns a ray (as
        ``measurement_birth_max_explained`` for the lidar).
    lidar_missed_moments : bool
        The missed-detection copy of a lidar update under a range-dependent ``P_d``: its
        posterior is ``(1 - P_d(x)) N(x; m, P)``, not the prior reweighted by ``1 - P_d(m)``.
        With ``True`` it is moment-matched along the component's range direction (9-point
        Gauss-Hermite over the linearised range, the angular factors at the mean): the weight
        uses the expected ``P_d`` and the mean moves towards where the lidar would not have seen
        it. A track left at the edge of the lidar's range by a teammate that moved beyond it
        then drifts outwards with each missed scan instead of only losing weight (which the
        camera restores). ``lidar_pd_model="seed"`` only; the GM-PHD engines only (the PMB
        ignores it).
    missed_detection : str
        ``"phd"`` (Vo & Ma, Perera 2021): a component's missed-detection copy keeps
        ``(1 - P_d) w``. ``"bernoulli"``: it keeps the exact Bernoulli filter's missed
        posterior ``w (1 - P_d) / (1 - r P_d + r Lambda)``, the component read as
        ``n = max(1, ceil(w))`` targets of existence ``r = w / n``, and
        ``Lambda = sum_h P_d g_h / (kappa + sum_{j != i} P_d w_j g_jh)``, the evidence that
        the component was detected, against clutter plus every other component. The PHD's
        ``(1 - P_d) w`` is its first-order (Poisson) approximation, exact only for ``r << 1``;
        at ``r ~ 1`` it takes an established track to ``1 - P_d`` after one missed frame
        (0.09 with the Perera 2021 study's camera), while the exact missed posterior of a target
        that was certainly there is still ``r (1 - P_d) / (1 - r P_d)`` (0.64 after a time update
        with ``P_s = 0.95``): one dropped blob does not kill the track, three in a row do. With a
        gated measurement ``Lambda`` is large and the missed copy vanishes, so a detected
        track is not inflated towards ``1 / P_d``. Detected copies keep the PHD weights.
    scan_evidence : bool
        Use the lidar scan's raw ranges (:mod:`localization.scan_evidence`): a component in the
        free space the beams crossed loses weight (``1 - P_free``), and one behind the scan's
        first surface is hidden from both sensors (``P_d`` times the visibility). Needs the
        scan in the lidar calls (a :class:`~localization.feed.SwarmFeed` packs it for a bank
        whose ``reads_scans`` is True, with this on or ``camera_clutter_per_wide_object`` > 0;
        its call tuples always carry it).
        Default False: Perera 2021's filter. The GM-PHD engines only (the PMB ignores it).
    camera_clutter_per_wide_object : float
        Camera blobs per frame that are not teammates, per compact object wider than a housing
        in the last scan (:mod:`localization.object_clutter`): the camera clutter intensity
        rises on those objects' bearings by this many blobs, spread as their measured blobs
        are. Needs the scan, as ``scan_evidence`` does (:attr:`reads_scans`). Default 0 (off,
        the Perera 2021 study's uniform clutter); the simulator's is measured
        (``swarm_env.config.SIM_CAMERA_CLUTTER_PER_WIDE_OBJECT``). The GM-PHD and the PMB
        engines.
    camera_wide_object_std_fraction : float
        Std of those blobs' bearings about the object's centre, in the object's angular
        half-widths (added in quadrature to the camera's constant bearing variance).
    camera_clutter_wide_object_share_per_rad : float
        The part of ``camera_clutter_intensity`` (1/rad) that the wide objects account for:
        where they are modelled (``camera_clutter_per_wide_object`` > 0) the uniform part
        is ``camera_clutter_intensity`` minus this (:attr:`camera_clutter_uniform_per_rad`);
        before a filter's first scan the objects are unknown and it keeps the whole. At most
        ``camera_clutter_intensity``.
    scan_target_radius_m : float
        Radius of what the lidar sees of a teammate (Perera 2021: the X4's 65 mm housing); the
        scan evidence and the ``"visible-width"`` blind sectors.
    scan_range_noise_std_m, scan_range_noise_quadratic_per_m : float
        The scanner's range noise std ``a + b d^2`` at range ``d`` (the X4's, as
        ``swarm_env.sensors.lidar.LidarConfig``: 1 cm + 0.0025 /m).
    scan_beam_footprint_deg : float
        Angular width of one beam's sample (the X4: 0.5 deg), for the scan evidence and the
        ``"visible-width"`` blind sectors; only bins whose whole footprint
        lies on the housing can refute it.
    scan_margin_sigmas : float
        Margin ``k`` of the visibility and free-space tests: a housing is hidden only ``k`` of
        the scanner's range sigmas behind the first surface; free space refutes a component
        only ``k`` sigmas (its own and the scanner's, radially, and ``k`` tangential sigmas
        in bearing) in front of the returns. A teammate on the scan keeps ``P_free <=
        Phi(-k)`` (``k = 3``: 0.13 %); its ``V`` is at least ``Phi(k sigma_r / s)``, near
        ``Phi(k)`` for a well-localised one (module :mod:`localization.scan_evidence`).
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

    mode: str = "lidar-camera"
    process_noise_std_m: float = 0.03
    time_update: str = "odometry"
    process_noise_interval_s: float = 0.1
    survival_model: str = "seed"
    survival_offset: float = 1.05
    survival_slope_per_m: float = 4.0
    survival_range_m: float = 4.0
    survival_probability: float = 0.99
    birth: str = "fixed"
    birth_weight: float = 0.001
    birth_mean_m: tuple[float, float] = (0.0, 0.0)
    birth_std_m: float = 2.0
    measurement_birth_weight: float = 0.25
    measurement_birth_cov_scale: float = 4.0
    measurement_birth_max_explained: float = 0.5
    lidar_noise_std_m: float = 0.05
    lidar_pd_model: str = "seed"
    lidar_pd_offset: float = 1.02
    lidar_pd_slope_per_m: float = 8.0
    lidar_pd_midpoint_m: float = 1.5
    lidar_detection_probability: float = 0.9
    lidar_range_m: float = 2.0
    blind_sector_centers_deg: tuple[float, ...] = (45.0, 135.0, -135.0, -45.0)
    blind_sector_widths_deg: tuple[float, ...] = (10.0, 10.0, 10.0, 10.0)
    blind_sector_model: str = "seed"
    lidar_beam_spacing_deg: float = 0.5
    lidar_min_returns: int = 3
    lidar_beam_phase: str = "drifting"
    occlusion_std_deg: float = 3.0
    occlusion_min_separation_m: float = 0.1
    interference_depth: float = 0.6
    interference_std_deg: float = 1.0
    lidar_clutter_intensity: float = 0.05
    camera_noise_std_deg: float = 5.0
    camera_noise_width_fraction: float = 0.0
    camera_target_radius_m: float = 0.05
    camera_pd_offset: float = 1.1
    camera_pd_slope_per_m: float = 5.0
    camera_pd_midpoint_m: float = 4.0
    camera_clutter_intensity: float = 0.5
    camera_untracked_density_per_m2: float = 0.0
    camera_untracked_min_range_m: float = 2.0
    camera_birth: str = "none"
    camera_birth_weight: float = 0.25
    camera_birth_components: int = 6
    camera_birth_min_range_m: float = 0.3
    camera_birth_max_range_m: float = 4.0
    camera_birth_max_explained: float = 0.5
    missed_detection: str = "phd"
    lidar_missed_moments: bool = False
    scan_evidence: bool = False
    camera_clutter_per_wide_object: float = 0.0
    camera_wide_object_std_fraction: float = 0.28
    camera_clutter_wide_object_share_per_rad: float = 0.0
    scan_target_radius_m: float = 0.0325
    scan_range_noise_std_m: float = 0.01
    scan_range_noise_quadratic_per_m: float = 0.0025
    scan_beam_footprint_deg: float = 0.5
    scan_margin_sigmas: float = 3.0
    prune_threshold: float = 1e-4
    merge_threshold: float = 4.0
    max_components: int = 64
    min_range_m: float = 0.1

    @classmethod
    def perera2021(cls) -> PHDConfig:
        """The Perera 2021 study's filter: its eqs. 10-30 with its stated constants."""
        return cls()

    def __post_init__(self) -> None:
        check_number_fields(self)
        _check_choice("mode", self.mode, MODES)
        _check_choice("survival_model", self.survival_model, SURVIVAL_MODELS)
        _check_choice("birth", self.birth, BIRTH_MODELS)
        _check_choice("lidar_pd_model", self.lidar_pd_model, LIDAR_PD_MODELS)
        _check_choice("blind_sector_model", self.blind_sector_model, BLIND_SECTOR_MODELS)
        _check_choice("lidar_beam_phase", self.lidar_beam_phase, LIDAR_BEAM_PHASES)
        _check_choice("camera_birth", self.camera_birth, CAMERA_BIRTH_MODELS)
        _check_choice("missed_detection", self.missed_detection, MISSED_DETECTION_MODELS)
        _check_choice("time_update", self.time_update, TIME_UPDATE_MODELS)
        # Every float field must be a finite real number (bool is rejected: it is an int).
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("float", float):
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ValueError(f"PHDConfig.{f.name} must be a number, got {value!r}")
                if not math.isfinite(value):
                    raise ValueError(f"PHDConfig.{f.name} must be finite, got {value!r}")
        for name in (
            "process_noise_std_m",
            "process_noise_interval_s",
            "survival_slope_per_m",
            "birth_std_m",
            "measurement_birth_cov_scale",
            "lidar_noise_std_m",
            "lidar_pd_slope_per_m",
            "lidar_range_m",
            "occlusion_std_deg",
            "interference_std_deg",
            "camera_noise_std_deg",
            "camera_target_radius_m",
            "camera_pd_slope_per_m",
            "merge_threshold",
            "min_range_m",
            "camera_birth_min_range_m",
        ):
            _check_positive(name, getattr(self, name))
        for name in (
            "survival_range_m",
            "lidar_pd_midpoint_m",
            "camera_pd_midpoint_m",
            "occlusion_min_separation_m",
            "lidar_clutter_intensity",
            "camera_clutter_intensity",
            "camera_untracked_density_per_m2",
            "camera_untracked_min_range_m",
            "camera_noise_width_fraction",
            "camera_clutter_per_wide_object",
            "camera_clutter_wide_object_share_per_rad",
        ):
            if getattr(self, name) < 0.0:
                raise ValueError(f"PHDConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        # Plausibility: a std beyond these is no sensor (and 1e300 squares to inf inside the
        # kernels); the angular stds the P_d bumps divide by need a floor.
        for name, low, high in (
            ("process_noise_std_m", 0.0, 100.0),
            ("birth_std_m", 0.0, 100.0),
            ("lidar_noise_std_m", 0.0, 100.0),
            ("lidar_range_m", 0.0, 1000.0),
            ("camera_noise_std_deg", 0.0, 180.0),
            ("occlusion_std_deg", 1e-3, 180.0),
            ("interference_std_deg", 1e-3, 180.0),
            ("process_noise_interval_s", 1e-3, 3600.0),
            ("measurement_birth_cov_scale", 0.0, 1e6),
            ("camera_noise_width_fraction", 0.0, 10.0),
            ("camera_target_radius_m", 0.0, 10.0),
            ("scan_target_radius_m", 1e-3, 10.0),
            ("scan_range_noise_std_m", 0.0, 10.0),
            ("scan_range_noise_quadratic_per_m", 0.0, 10.0),
            ("scan_beam_footprint_deg", 0.0, 10.0),
            ("lidar_beam_spacing_deg", 1e-3, 10.0),
            ("scan_margin_sigmas", 0.0, 10.0),
            ("camera_wide_object_std_fraction", 0.0, 10.0),
        ):
            value = getattr(self, name)
            if not low <= value <= high:
                raise ValueError(f"PHDConfig.{name} must be in [{low}, {high}], got {value!r}")
        # Sigmoid offsets >= 1 keep P_s and P_d inside [0, 1] without clipping.
        for name in ("survival_offset", "lidar_pd_offset", "camera_pd_offset"):
            if getattr(self, name) < 1.0:
                raise ValueError(f"PHDConfig.{name} must be >= 1, got {getattr(self, name)!r}")
        for name in (
            "survival_probability",
            "lidar_detection_probability",
            "interference_depth",
            "measurement_birth_max_explained",
            "camera_birth_max_explained",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"PHDConfig.{name} must be in [0, 1], got {value!r}")
        for name in ("birth_weight", "measurement_birth_weight", "camera_birth_weight"):
            value = getattr(self, name)
            if not 0.0 <= value < 1e3:
                raise ValueError(f"PHDConfig.{name} must be in [0, 1000), got {value!r}")
        if self.camera_clutter_wide_object_share_per_rad > self.camera_clutter_intensity:
            raise ValueError(
                "PHDConfig.camera_clutter_wide_object_share_per_rad must be at most "
                f"camera_clutter_intensity ({self.camera_clutter_intensity!r}), got "
                f"{self.camera_clutter_wide_object_share_per_rad!r}"
            )
        if not 0.0 < self.prune_threshold < 1.0:
            raise ValueError(
                f"PHDConfig.prune_threshold must be in (0, 1), got {self.prune_threshold!r}"
            )
        if (
            isinstance(self.max_components, bool)
            or not isinstance(self.max_components, int)
            or not 1 <= self.max_components <= 10_000
        ):
            # Cost guard: the banks allocate (6, R, max_components) and merge in O(C^2).
            raise ValueError(
                "PHDConfig.max_components must be an int in [1, 10000], got "
                f"{self.max_components!r}"
            )
        if self.lidar_beam_phase == "fixed":
            turns = 360.0 / self.lidar_beam_spacing_deg
            if abs(turns - round(turns)) > 1e-9 * turns:
                raise ValueError(
                    "PHDConfig.lidar_beam_spacing_deg must divide 360 with fixed beams "
                    f"(lidar_beam_phase='fixed'), got {self.lidar_beam_spacing_deg!r}"
                )
        value = self.lidar_min_returns
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 100:
            raise ValueError(
                f"PHDConfig.lidar_min_returns must be an int in [1, 100], got {value!r}"
            )
        value = self.camera_birth_components
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 64:
            raise ValueError(
                f"PHDConfig.camera_birth_components must be an int in [1, 64], got {value!r}"
            )
        if not self.camera_birth_max_range_m > self.camera_birth_min_range_m:
            raise ValueError(
                "PHDConfig.camera_birth_max_range_m must be > camera_birth_min_range_m "
                f"({self.camera_birth_min_range_m!r}), got {self.camera_birth_max_range_m!r}"
            )
        _check_pair("birth_mean_m", self.birth_mean_m)
        # One rule for the lidar, the filter and the bridge (swarm_core.validation).
        check_blind_sectors(
            "PHDConfig", self.blind_sector_centers_deg, self.blind_sector_widths_deg
        )

    @property
    def lidar_noise_var_m2(self) -> float:
        """Lidar noise variance ``R_L[0, 0]`` in m^2."""
        return self.lidar_noise_std_m**2

    @property
    def camera_noise_var_rad2(self) -> float:
        """The constant part of the camera bearing noise variance ``R_C`` in rad^2 (all of it
        when ``camera_noise_width_fraction == 0``, Perera 2021)."""
        return math.radians(self.camera_noise_std_deg) ** 2

    def camera_bearing_var(self, range_m: np.ndarray | float) -> np.ndarray:
        """``R_C(r)`` in rad^2 at ranges ``range_m`` (m, any shape; floored at
        ``min_range_m``): the constant part plus ``(camera_noise_width_fraction W(r))^2``,
        ``W(r) = 2 asin(min(1, camera_target_radius_m / r))``."""
        r = np.maximum(np.asarray(range_m, dtype=float), self.min_range_m)
        width = 2.0 * np.arcsin(np.minimum(1.0, self.camera_target_radius_m / r))
        return self.camera_noise_var_rad2 + (self.camera_noise_width_fraction * width) ** 2

    @property
    def camera_clutter_uniform_per_rad(self) -> float:
        """The uniform camera clutter of a filter that models the wide objects (1/rad):
        :attr:`camera_clutter_total_per_rad` less the objects' share, when they are on."""
        total = self.camera_clutter_total_per_rad
        if self.models_wide_objects:
            return total - self.camera_clutter_wide_object_share_per_rad
        return total

    @property
    def models_wide_objects(self) -> bool:
        """Whether camera updates use the wide objects' clutter (a rate > 0, and a camera)."""
        return self.camera_clutter_per_wide_object > 0.0 and self.mode != "lidar-only"

    @property
    def reads_scans(self) -> bool:
        """Whether the filter keeps each lidar call's scan profile (``scan_evidence``, or
        :attr:`models_wide_objects`)."""
        return bool(self.scan_evidence) or self.models_wide_objects

    @property
    def camera_clutter_total_per_rad(self) -> float:
        """Camera clutter ``kappa_C`` used by the update (1/rad): false blobs plus untracked
        teammates, ``camera_clutter_intensity + rho * int_{r_in}^inf P_dC(r) r dr``."""
        rho = self.camera_untracked_density_per_m2
        if rho == 0.0:
            return float(self.camera_clutter_intensity)
        moment = _range_moment(
            self.camera_untracked_min_range_m,
            self.camera_pd_offset,
            self.camera_pd_slope_per_m,
            self.camera_pd_midpoint_m,
        )
        return float(self.camera_clutter_intensity + rho * moment)


@functools.lru_cache(maxsize=64)
def _range_moment(r_in: float, offset: float, slope: float, mid: float) -> float:
    """``int_{r_in}^inf r / (offset + exp(slope (r - mid))) dr`` (m^2): the trapezoidal rule
    with 0.5 mm steps up to where the integrand is below ``exp(-40)`` of its peak."""
    r_out = max(r_in, mid + 40.0 / slope)
    n = max(2, int(math.ceil((r_out - r_in) / 5e-4)) + 1)
    r = np.linspace(r_in, r_out, n)
    f = r / (offset + np.exp(np.minimum(slope * (r - mid), 700.0)))
    return float((r[1] - r[0]) * (f.sum() - 0.5 * (f[0] + f[-1])))


def _check_choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"PHDConfig.{name} must be one of {choices}, got {value!r}")


def _check_positive(name: str, value: float) -> None:
    if not value > 0.0:
        raise ValueError(f"PHDConfig.{name} must be > 0, got {value!r}")


def _check_pair(name: str, value: object) -> None:
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in value
        )
    )
    if not ok:
        raise ValueError(f"PHDConfig.{name} must be a tuple of 2 finite numbers, got {value!r}")


def _check_angles(name: str, value: object) -> None:
    ok = isinstance(value, tuple) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
    )
    if not ok:
        raise ValueError(f"PHDConfig.{name} must be a tuple of finite numbers, got {value!r}")


_Config = TypeVar("_Config")


def config_with_overrides(config: Any, cls: type[_Config], overrides: dict[str, Any]) -> _Config:
    """``config`` (default: ``cls()``) with the fields in ``overrides`` replaced.

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
    if overrides:
        unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ValueError(f"unknown {cls.__name__} field(s) {unknown}")
        config = dataclasses.replace(config, **overrides)
    return config
