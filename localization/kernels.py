"""Compiled GM-PHD steps for many robots at once: the engine behind :class:`~localization.PHDBank`.

A swarm env makes ~100 filter calls per 0.1 s step (20 robots x odometry, lidar and camera at
their own rates), each on ~20 components. At that size numpy's per-call overhead, not the
arithmetic, sets the cost, so the bank hands a whole step's calls to :func:`apply_calls`, one
numba-compiled function that runs each robot's calls in order on its own slice of the padded
``(6, R, C)`` table.

The math is, formula for formula, that of the pure-numpy reference
(:mod:`localization.gaussian`, :mod:`localization.detection`, :mod:`localization.phd`,
:mod:`localization.reducer`, orchestrated by :class:`~localization.RobotCentricPHD`), written as
scalar loops over components and measurements; ``tests/localization/test_bank.py`` checks that
every robot of a bank ends each call with the components its own ``RobotCentricPHD`` holds
(to 1e-10) on random call sequences for every model option. Where the reference's docstrings
derive a formula or explain a guard, they are not repeated here.

Encoding of a batch of ``Q`` calls (all arrays, built by :class:`~localization.PHDBank`):

* ``robots (Q,)``, ``kinds (Q,)`` (:data:`PREDICT`, :data:`LIDAR`, :data:`CAMERA`) and
  ``index (Q,)``, the call's rank among the calls of its kind; each robot's calls are
  **contiguous** and run in array order; robots are independent and run in parallel threads
  (``NUMBA_NUM_THREADS``), each writing only its own robot's slice of the state;
* predict ``j``: ``odometry[j]``, ``[dx_m, dy_m, dpsi_rad]``;
* lidar ``j``: rows ``lidar_start[j]:lidar_stop[j]`` of ``points (P, 2)`` (m, robot frame)
  and ``null_start[j]:null_stop[j]`` of ``nulls (B,)`` (zero-intensity return bearings, rad);
* camera ``j``: rows ``camera_start[j]:camera_stop[j]`` of ``bearings (M,)`` (rad);
* ``lidar_pose (L, 3)`` / ``camera_pose (C, 3)`` with flags ``lidar_has_pose (L,)`` /
  ``camera_has_pose (C,)``: the sensor pose ``(x_m, y_m, psi_rad)`` in the filter's frame of
  a measurement taken away from it (:mod:`localization.frames`; flag 0: taken in it);
* advance ``j`` (:data:`ADVANCE`): ``stamps[j]``, the time (s) the robot's clock moves to,
  adding the process noise that accrued since (``time_update == "measurement"``);
* ``profiles (L, N_BINS)`` with flags ``lidar_has_profile (L,)``: lidar call ``j``'s scan
  profile (:mod:`localization.scan_memory`), which becomes the robot's scan memory (with
  its wide objects, :mod:`localization.object_clutter`); a batch for a bank that does not
  read scans (``PHDConfig.reads_scans``) may carry ``(0, N_BINS)`` and all flags 0 (the
  profiles are read only where the flag is set).

Model parameters travel as one float vector ``fparams`` and one int vector ``iparams``
indexed by the ``F_*`` and ``I_*`` constants below, each declared once with its transform of
the config (``_Slots``; :func:`pack_params` packs them).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .config import CAMERA_BIRTH_RADIAL_STD_FRACTION, PROCESS_CLOCK_RESET_S, PHDConfig
from .detection import (
    RAMP_MIN_STD_RAD,
    RAMP_MIN_WIDTH_RAD,
    blind_sector_first_beams,
    blind_sector_geometry,
)
from .mixture import N_ROWS
from .object_clutter import clutter_density_into, wide_objects_into
from .phd import GH_NODES, GH_WEIGHTS
from .scan_memory import WIDE_OBJECTS_AT, move_scan_pose_in_place

__all__ = [
    "PREDICT",
    "LIDAR",
    "CAMERA",
    "ADVANCE",
    "pack_params",
    "apply_calls",
    "reduce_table",
]

PREDICT, LIDAR, CAMERA, ADVANCE = 0, 1, 2, 3
# Positions of the arrays in an encoded batch (module docstring).
(
    _ROBOTS,
    _KINDS,
    _INDEX,
    _ODOMETRY,
    _LIDAR_START,
    _LIDAR_STOP,
    _POINTS,
    _NULL_START,
    _NULL_STOP,
    _NULLS,
    _CAMERA_START,
    _CAMERA_STOP,
    _BEARINGS,
    _LIDAR_POSE,
    _LIDAR_HAS_POSE,
    _CAMERA_POSE,
    _CAMERA_HAS_POSE,
    _STAMPS,
    _PROFILES,
    _LIDAR_HAS_PROFILE,
) = range(20)


class _Slots:
    """One declarative table of kernel parameters: each slot is written once, as
    ``F_NAME = _F.slot(transform)`` with ``transform(config) -> value``. The slot index is a
    plain module-level int (numba freezes it as a compile-time constant, so indexing costs
    what a literal would) and :func:`pack_params` fills the vector from the same table."""

    def __init__(self, dtype: type) -> None:
        self.dtype = dtype
        self.transforms: list = []

    def slot(self, transform) -> int:
        self.transforms.append(transform)
        return len(self.transforms) - 1

    def pack(self, config: PHDConfig) -> np.ndarray:
        return np.array([t(config) for t in self.transforms], dtype=self.dtype)


def _inv_var_deg(std_deg: float) -> float:
    return 1.0 / math.radians(std_deg) ** 2


_F = _Slots(np.float64)  # fparams
F_PROCESS_VAR = _F.slot(lambda c: c.prediction.process_noise_std_m**2)
F_PROCESS_INTERVAL = _F.slot(lambda c: c.prediction.process_noise_interval_s)
F_PS_OFFSET = _F.slot(lambda c: c.prediction.survival_offset)
F_PS_SLOPE = _F.slot(lambda c: c.prediction.survival_slope_per_m)
F_PS_RANGE = _F.slot(lambda c: c.prediction.survival_range_m)
F_PS_CONST = _F.slot(lambda c: c.prediction.survival_probability)
F_BIRTH_W = _F.slot(lambda c: c.births.weight)
F_BIRTH_X = _F.slot(lambda c: c.births.mean_m[0])
F_BIRTH_Y = _F.slot(lambda c: c.births.mean_m[1])
F_BIRTH_VAR = _F.slot(lambda c: c.births.std_m**2)
F_MBIRTH_W = _F.slot(lambda c: c.births.measurement_weight)
F_MBIRTH_VAR = _F.slot(lambda c: c.births.measurement_cov_scale * c.lidar.noise_var_m2)
F_MBIRTH_MAX_EXPLAINED = _F.slot(lambda c: c.births.measurement_max_explained)
F_LIDAR_VAR = _F.slot(lambda c: c.lidar.noise_var_m2)
F_LPD_OFFSET = _F.slot(lambda c: c.lidar.pd_offset)
F_LPD_SLOPE = _F.slot(lambda c: c.lidar.pd_slope_per_m)
F_LPD_MID = _F.slot(lambda c: c.lidar.pd_midpoint_m)
F_LPD_CONST = _F.slot(lambda c: c.lidar.detection_probability)
F_LIDAR_RANGE = _F.slot(lambda c: c.lidar.range_m)
F_OCC_INV_VAR = _F.slot(lambda c: _inv_var_deg(c.lidar.occlusion_std_deg))
F_OCC_SEPARATION = _F.slot(lambda c: c.lidar.occlusion_min_separation_m)
F_INT_DEPTH = _F.slot(lambda c: c.lidar.interference_depth)
F_INT_INV_VAR = _F.slot(lambda c: _inv_var_deg(c.lidar.interference_std_deg))
F_KAPPA_L = _F.slot(lambda c: c.lidar.clutter_intensity)
F_CAMERA_VAR = _F.slot(lambda c: c.camera.noise_var_rad2)
F_CAMERA_WIDTH_FRACTION = _F.slot(lambda c: c.camera.noise_width_fraction)
F_CAMERA_TARGET_RADIUS = _F.slot(lambda c: c.camera.target_radius_m)
F_CPD_OFFSET = _F.slot(lambda c: c.camera.pd_offset)
F_CPD_SLOPE = _F.slot(lambda c: c.camera.pd_slope_per_m)
F_CPD_MID = _F.slot(lambda c: c.camera.pd_midpoint_m)
# false blobs + untracked teammates (PHDConfig.camera_clutter_total_per_rad)
F_KAPPA_C = _F.slot(lambda c: c.camera_clutter_total_per_rad)
# the same less the wide objects' share where they are modelled
# (PHDConfig.camera_clutter_uniform_per_rad)
F_KAPPA_C_UNIFORM = _F.slot(lambda c: c.camera_clutter_uniform_per_rad)
F_PRUNE = _F.slot(lambda c: c.reduction.prune_threshold)
F_MERGE = _F.slot(lambda c: c.reduction.merge_threshold)
F_MIN_RANGE = _F.slot(lambda c: c.reduction.min_range_m)
F_CBIRTH_W = _F.slot(lambda c: c.births.camera_weight)
F_CBIRTH_MIN_RANGE = _F.slot(lambda c: c.births.camera_min_range_m)
F_CBIRTH_MAX_RANGE = _F.slot(lambda c: c.births.camera_max_range_m)
F_CBIRTH_MAX_EXPLAINED = _F.slot(lambda c: c.births.camera_max_explained)
F_CBIRTH_RADIAL_FRACTION = _F.slot(lambda c: CAMERA_BIRTH_RADIAL_STD_FRACTION)
F_TARGET_RADIUS = _F.slot(lambda c: c.lidar.target_radius_m)
F_BEAM_FOOTPRINT = _F.slot(lambda c: math.radians(c.lidar.beam_footprint_deg))
F_WIDE_CLUTTER = _F.slot(lambda c: c.camera.clutter_per_wide_object * c.models_wide_objects)
F_WIDE_STD_FRACTION = _F.slot(lambda c: c.camera.wide_object_std_fraction)
F_BEAM_SPACING = _F.slot(lambda c: math.radians(c.lidar.beam_spacing_deg))
F_MIN_RETURNS = _F.slot(lambda c: float(c.lidar.min_returns))
F_EDGE_RAMP = _F.slot(lambda c: blind_sector_first_beams(c)[1])
N_FPARAMS = len(_F.transforms)

_I = _Slots(np.int64)  # iparams (flags are 0 / 1)
I_MAX_COMPONENTS = _I.slot(lambda c: c.reduction.max_components)
I_SURVIVAL_CONSTANT = _I.slot(lambda c: c.prediction.survival_model == "constant")
I_BIRTH_FIXED = _I.slot(lambda c: c.births.model == "fixed")
I_BIRTH_MEASUREMENT = _I.slot(lambda c: c.births.model == "measurement")
I_LIDAR_PD_CONSTANT = _I.slot(lambda c: c.lidar.pd_model == "constant")
I_LIDAR_ONLY = _I.slot(lambda c: c.mode == "lidar-only")
I_CAMERA_BIRTH = _I.slot(lambda c: c.births.camera == "ray")
I_TIME_UPDATE_MEASUREMENT = _I.slot(lambda c: c.prediction.time_update == "measurement")
I_CBIRTH_COMPONENTS = _I.slot(lambda c: c.births.camera_components)
I_MISSED_BERNOULLI = _I.slot(lambda c: c.missed_detection == "bernoulli")
I_LIDAR_MISSED_MOMENTS = _I.slot(lambda c: c.lidar.missed_moments and c.lidar.pd_model == "seed")
I_BLIND_VISIBLE_WIDTH = _I.slot(lambda c: c.lidar.blind_sector_model == "visible-width")
N_IPARAMS = len(_I.transforms)

_TINY = 1e-300  # as localization.gaussian.TINY: floor of every divisor
_WEIGHT_FLOOR = 1e-150  # as localization.reducer: cluster weights never 0/0
_MAX_EXP = 700.0  # as localization.detection: no exp overflow for absurd ranges
# 1 - x == 1.0 exactly in float64 for 0 <= x < 2^-54 ~ 5.6e-17, and exp(-38) ~ 3.1e-17: a
# bump factor with an exponent below this is skipped without changing a single bit.
_NEGLIGIBLE_EXPONENT = -38.0
_DROP_FRACTION = 1e-20  # see _negligible_exponent (or the prune threshold, if lower)
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI
_INV_SQRT_TWO_PI = 1.0 / math.sqrt(_TWO_PI)
_INV_SQRT_TWO = 1.0 / math.sqrt(2.0)


def pack_params(config: PHDConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(fparams, iparams, sector_scaled (S, 2), sector_params (S, 3))`` of ``config``.

    The blind sectors are given as unit centre directions scaled by ``1 / sigma^2``
    (``sigma = width / 2``), as :class:`~localization.detection.DetectionModel` keeps them,
    and per sector ``[1 / sigma^2, first beam past the + edge, first beam past the - edge]``
    (rad, :func:`~localization.detection.blind_sector_first_beams`). ``sigma`` is also the
    sector's half-width, which the ``"visible-width"`` model reads from the same arrays.
    """
    directions, inv_var = blind_sector_geometry(config)
    first_beams, _ = blind_sector_first_beams(config)
    sector_params = np.concatenate((inv_var[:, None], first_beams), axis=1).reshape(-1, 3)
    return _F.pack(config), _I.pack(config), directions * inv_var[:, None], sector_params


# ---------------------------------------------------------------------- detection factors
@njit(cache=True)
def _wrap(angle):
    """:func:`swarm_core.geometry.wrap_angle` of one angle: ``[-pi, pi)``."""
    wrapped = (angle + math.pi) % _TWO_PI - math.pi
    # the modulo can round a tiny negative input up to exactly 2 pi, which would give +pi
    return wrapped - _TWO_PI if wrapped >= math.pi else wrapped


@njit(cache=True)
def _inverse_sigmoid(range_m, offset, slope, midpoint):
    return 1.0 / (math.exp(min(range_m * slope - slope * midpoint, _MAX_EXP)) + offset)


@njit(cache=True)
def _units(tab, n, min_range):
    """Ranges ``(n,)`` and unit bearing vectors ``(2, n)`` (zero vector at the origin)."""
    ranges = np.empty(n)
    units = np.empty((2, n))
    for i in range(n):
        x, y = tab[1, i], tab[2, i]
        r = math.hypot(x, y)
        ranges[i] = r
        d = max(r, min_range)
        units[0, i] = x / d
        units[1, i] = y / d
    return ranges, units


@njit(cache=True)
def _apply_occlusion(pd, tab, n, ranges, units, inv_var, separation):
    """``pd[i] *= prod_j (1 - min(w_j, 1) bump(i, j))`` over components ``j`` nearer than ``i``."""
    for i in range(n):
        uxi = units[0, i] * inv_var
        uyi = units[1, i] * inv_var
        limit = ranges[i] - separation
        factor = 1.0
        for j in range(n):
            if ranges[j] < limit:
                exponent = uxi * units[0, j] + uyi * units[1, j] - inv_var
                if exponent > _NEGLIGIBLE_EXPONENT:
                    factor *= 1.0 - math.exp(exponent) * min(tab[0, j], 1.0)
        pd[i] *= factor


@njit(cache=True)
def _ramp_g(x, std):
    """``E[max(Y, 0)]`` for ``Y ~ N(x, std^2)``."""
    z = x / std
    return (
        x * 0.5 * math.erfc(-z * _INV_SQRT_TWO) + std * math.exp(-0.5 * z * z) * _INV_SQRT_TWO_PI
    )


@njit(cache=True)
def _expected_ramp(mean, std, start, width):
    """:func:`localization.detection.expected_ramp` of scalars."""
    std = max(std, RAMP_MIN_STD_RAD)
    x = mean - start
    if width < RAMP_MIN_WIDTH_RAD:
        return 0.5 * math.erfc(-x / std * _INV_SQRT_TWO)
    value = (_ramp_g(x, std) - _ramp_g(x - width, std)) / width
    return min(max(value, 0.0), 1.0)


@njit(cache=True)
def _visible_width_blind(ux, uy, r, d, pxx, pxy, pyy, fp, sector_scaled, sector_params):
    """Product over sectors of :func:`localization.detection.visible_width_factor` for the
    component with unit bearing ``(ux, uy)`` (``m / d``), range ``r`` and covariance ``P``."""
    std = math.sqrt(max(uy * uy * pxx - 2.0 * ux * uy * pxy + ux * ux * pyy, 0.0)) / d
    half_angle = math.asin(min(fp[F_TARGET_RADIUS] / max(r, 1e-12), 1.0))
    # start of each side's step or ramp, less the first beam past the edge
    lead = (
        -half_angle + 0.5 * fp[F_BEAM_FOOTPRINT] + (fp[F_MIN_RETURNS] - 1.0) * fp[F_BEAM_SPACING]
    )
    ramp = fp[F_EDGE_RAMP]
    reach = 9.0 * max(std, RAMP_MIN_STD_RAD)  # Phi(-9) ~ 1e-19: beyond it a ramp is 0 or 1
    blind = 1.0
    for k in range(sector_params.shape[0]):
        inv_var = sector_params[k, 0]
        half_width = 1.0 / math.sqrt(inv_var)  # sigma = width / 2 (pack_params)
        dx = sector_scaled[k, 0] / inv_var
        dy = sector_scaled[k, 1] / inv_var
        offset = math.atan2(dx * uy - dy * ux, dx * ux + dy * uy)
        clear = half_width + half_angle - 0.5 * fp[F_BEAM_FOOTPRINT]
        if abs(offset) - clear > reach:
            continue  # 9 sigmas clear of the sector: its side's ramp is 1, the factor 1
        start_plus = sector_params[k, 1] + lead
        start_minus = sector_params[k, 2] + lead
        plus = _expected_ramp(
            offset, std, min(start_plus, clear), min(max(clear - start_plus, 0.0), ramp)
        )
        minus = _expected_ramp(
            -offset, std, min(start_minus, clear), min(max(clear - start_minus, 0.0), ramp)
        )
        blind *= min(plus + minus, 1.0)  # the average of the larger side (reference)
    return blind


@njit(cache=True)
def _lidar_pd(tab, n, nulls, fp, ip, sector_scaled, sector_params):
    pd = np.empty(n)
    if ip[I_LIDAR_PD_CONSTANT]:
        for i in range(n):
            inside = math.hypot(tab[1, i], tab[2, i]) <= fp[F_LIDAR_RANGE]
            pd[i] = fp[F_LPD_CONST] if inside else 0.0
        return pd
    ranges, units = _units(tab, n, fp[F_MIN_RANGE])
    n_sectors = sector_params.shape[0]
    depth = fp[F_INT_DEPTH]
    int_inv_var = fp[F_INT_INV_VAR]
    for i in range(n):
        p = _inverse_sigmoid(ranges[i], fp[F_LPD_OFFSET], fp[F_LPD_SLOPE], fp[F_LPD_MID])
        if n_sectors and ip[I_BLIND_VISIBLE_WIDTH]:
            p *= _visible_width_blind(
                units[0, i],
                units[1, i],
                ranges[i],
                max(ranges[i], fp[F_MIN_RANGE]),
                tab[3, i],
                tab[4, i],
                tab[5, i],
                fp,
                sector_scaled,
                sector_params,
            )
        elif n_sectors:
            blind = 1.0
            for k in range(n_sectors):
                exponent = (
                    sector_scaled[k, 0] * units[0, i]
                    + sector_scaled[k, 1] * units[1, i]
                    - sector_params[k, 0]
                )
                if exponent > _NEGLIGIBLE_EXPONENT:
                    blind *= 1.0 - math.exp(exponent)
            p *= blind
        pd[i] = p
    if n > 1:
        _apply_occlusion(pd, tab, n, ranges, units, fp[F_OCC_INV_VAR], fp[F_OCC_SEPARATION])
    if nulls.shape[0]:
        cos_b = np.cos(nulls) * int_inv_var
        sin_b = np.sin(nulls) * int_inv_var
        for i in range(n):
            factor = 1.0
            for b in range(nulls.shape[0]):
                exponent = cos_b[b] * units[0, i] + sin_b[b] * units[1, i] - int_inv_var
                if exponent > _NEGLIGIBLE_EXPONENT:  # depth <= 1
                    factor *= 1.0 - depth * math.exp(exponent)
            pd[i] *= factor
    return pd


@njit(cache=True)
def _camera_pd(tab, n, fp):
    min_range = fp[F_MIN_RANGE]
    ranges, units = _units(tab, n, min_range)
    pd = np.empty(n)
    for i in range(n):
        p = _inverse_sigmoid(ranges[i], fp[F_CPD_OFFSET], fp[F_CPD_SLOPE], fp[F_CPD_MID])
        # bearing undefined inside our own body
        pd[i] = p if ranges[i] >= min_range else 0.0
    if n > 1:
        _apply_occlusion(pd, tab, n, ranges, units, fp[F_OCC_INV_VAR], fp[F_OCC_SEPARATION])
    return pd


# ---------------------------------------------------------------------- time update
@njit(cache=True)
def frame_change(out, total, n_survive, odo, q, fp, ip):
    """The time update of ``out``'s first ``total`` columns, in place: weights (or existences)
    times ``P_s`` (columns ``>= n_survive`` are new births: 1), and the ego-motion
    ``m' = R(dpsi)^T (m - d)``, ``P' = R^T P R + q I`` (localization.gaussian.frame_change_matrix;
    ``q`` from :func:`predict_process_var`). Shared by the GM-PHD and the PMB kernels."""
    dx, dy, dpsi = odo[0], odo[1], odo[2]
    c, s = math.cos(dpsi), math.sin(dpsi)
    cc, ss, cs = c * c, s * s, c * s
    off_x = -(c * dx + s * dy)
    off_y = s * dx - c * dy
    constant = ip[I_SURVIVAL_CONSTANT]
    for i in range(total):
        x, y = out[1, i], out[2, i]
        pxx, pxy, pyy = out[3, i], out[4, i], out[5, i]
        if i >= n_survive:
            ps = 1.0
        elif constant:
            ps = fp[F_PS_CONST]
        else:
            ps = _inverse_sigmoid(
                math.hypot(x, y), fp[F_PS_OFFSET], fp[F_PS_SLOPE], fp[F_PS_RANGE]
            )
        out[0, i] *= ps
        out[1, i] = c * x + s * y + off_x
        out[2, i] = -s * x + c * y + off_y
        out[3, i] = cc * pxx + 2.0 * cs * pxy + ss * pyy + q
        out[4, i] = -cs * pxx + (cc - ss) * pxy + cs * pyy
        out[5, i] = ss * pxx - 2.0 * cs * pxy + cc * pyy + q


@njit(cache=True)
def advance_clock(clock, r, stamp, fp, ip):
    """Robot ``r``'s clock to ``stamp`` (s); returns the process variance (m^2) that accrued
    since its previous stamp (0 for the first stamp, a stamp out of order, or
    ``time_update == "odometry"``). ``clock[r] = (last stamp or nan, advanced since the last
    predict)``; as :meth:`localization.RobotCentricPHD.advance`."""
    if not ip[I_TIME_UPDATE_MEASUREMENT]:
        return 0.0
    last = clock[r, 0]
    if math.isnan(last):
        clock[r, 0] = stamp
        clock[r, 1] = 1.0
        return 0.0
    if stamp < last - PROCESS_CLOCK_RESET_S:  # the clock was reset: restart it
        clock[r, 0] = stamp
        clock[r, 1] = 0.0
        return 0.0
    clock[r, 1] = 1.0
    if stamp <= last:
        return 0.0
    clock[r, 0] = stamp
    return fp[F_PROCESS_VAR] * (stamp - last) / fp[F_PROCESS_INTERVAL]


@njit(cache=True)
def predict_process_var(clock, r, fp, ip):
    """The ``Q`` variance of robot ``r``'s next predict: none if its clock was advanced since
    the last one (the noise went in at each stamp), else all of it (Perera 2021; unstamped calls).
    Marks the clock as not advanced."""
    advanced = ip[I_TIME_UPDATE_MEASUREMENT] and clock[r, 1] != 0.0
    clock[r, 1] = 0.0
    return 0.0 if advanced else fp[F_PROCESS_VAR]


@njit(cache=True)
def diffuse(tab, n, var):
    """``P += var I`` on the first ``n`` columns of ``tab``, in place (a random walk's share)."""
    for i in range(n):
        tab[3, i] += var
        tab[5, i] += var


@njit(cache=True)
def set_round_gaussian(out, col, w, x, y, var):
    """Column ``col`` of ``out`` becomes the component ``(w, [x, y], var I)`` (a birth)."""
    out[0, col] = w
    out[1, col] = x
    out[2, col] = y
    out[3, col] = var
    out[4, col] = 0.0
    out[5, col] = var


@njit(cache=True)
def _set_posterior_column(out, col, w, x, y, post_covs, i):
    """Column ``col`` of ``out`` becomes the component ``(w, [x, y], P_i)``, ``P_i`` the
    shared posterior covariance ``post_covs[:, i]`` (xx, xy, yy) of prior ``i``."""
    out[0, col] = w
    out[1, col] = x
    out[2, col] = y
    out[3, col] = post_covs[0, i]
    out[4, col] = post_covs[1, i]
    out[5, col] = post_covs[2, i]


@njit(cache=True)
def set_fixed_birth(out, col, fp):
    """Column ``col`` of ``out`` becomes the Perera 2021 study's fixed birth component
    (``birth == "fixed"``), which joins the prior of every lidar update."""
    set_round_gaussian(out, col, fp[F_BIRTH_W], fp[F_BIRTH_X], fp[F_BIRTH_Y], fp[F_BIRTH_VAR])


@njit(cache=True)
def predict_with_births(tab, n, births, n_births, odo, q, fp, ip):
    """Frame change + Q + survival of ``tab``'s first ``n`` columns; the ``n_births`` pending
    ``births (B, 2)`` join with ``P_s = 1``; reduced past ``max_components``. Returns (table,
    k). The GM-PHD's time update, and the PMB's of its Poisson intensity."""
    total = n + n_births
    out = np.empty((N_ROWS, total))
    out[:, :n] = tab[:, :n]
    for b in range(n_births):
        set_round_gaussian(
            out, n + b, fp[F_MBIRTH_W], births[b, 0], births[b, 1], fp[F_MBIRTH_VAR]
        )
    frame_change(out, total, n, odo, q, fp, ip)
    if total > ip[I_MAX_COMPONENTS]:
        return reduce_table(out, total, fp[F_PRUNE], fp[F_MERGE], ip[I_MAX_COMPONENTS])
    return out, total


# ---------------------------------------------------------------------- measurement updates
@njit(cache=True)
def _negligible_exponent(pd_w, norm, kappa, prune):
    """Likelihood exponent below which a (component, measurement) pair is dropped.

    A dropped pair's term ``P_d w N`` is below ``f kappa`` with ``f = min(1e-20, prune)``
    (``norm`` is ``N``'s peak), so it changes no normaliser (``kappa + sum >= kappa``) beyond
    round-off, and its copy's weight (``< f``) is pruned anyway. With ``kappa = 0`` nothing is
    dropped; with ``P_d w = 0`` every term is 0.
    """
    if pd_w <= 0.0:
        return np.inf
    if kappa <= 0.0:
        return -np.inf
    return math.log(min(_DROP_FRACTION, prune) * kappa / (pd_w * norm))


@njit(cache=True)
def _posterior(
    tab,
    n,
    pd,
    detected,
    post_means,
    post_covs,
    kappa,
    prune,
    dropped_missed,
    bernoulli,
    missed_tab,
    missed_pd,
):
    """GM-PHD weights (Vo & Ma Table I), pruned: the kept missed copies, then the kept
    detected copies in component-major order (the reference's column order, minus the pruned).

    ``kappa (M,)`` is each measurement's clutter intensity; ``detected (n, M)`` holds
    ``P_d w N`` per pair, ``post_means (2, n, M)`` (read only where ``detected > 0``),
    ``post_covs (3, n)``; ``dropped_missed`` is a component whose missed copy is not kept
    (-1: none); ``bernoulli``: missed copies get
    :func:`localization.phd.missed_weights`; the missed copies take their ``P_d`` from
    ``missed_pd`` and their means and covariances from ``missed_tab`` (``pd`` and ``tab``, or
    :func:`_missed_moments`'). Returns the ``(6, k)`` table, ``k`` and ``explained (M,)``.
    """
    m = detected.shape[1]
    sums = np.zeros(m)
    for i in range(n):
        for h in range(m):
            sums[h] += detected[i, h]
    explained = np.empty(m)
    inv_denom = np.empty(m)
    for h in range(m):
        # Guard: zero clutter and underflowed likelihoods give weights 0, not 0/0.
        inv_denom[h] = 1.0 / max(sums[h] + kappa[h], _TINY)
        explained[h] = sums[h] * inv_denom[h]
    weights = np.empty(n + n * m)
    k = 0
    for i in range(n):
        w = tab[0, i] - missed_pd[i] * tab[0, i]  # (1 - P_d) w
        if bernoulli:
            evidence = 0.0  # w_i Lambda_i
            for h in range(m):
                others = max(sums[h] - detected[i, h], 0.0) + kappa[h]
                evidence += detected[i, h] / max(others, _TINY)
            w = _bernoulli_missed(tab[0, i], missed_pd[i], evidence)
        weights[i] = 0.0 if i == dropped_missed else w
        k += weights[i] >= prune
        for h in range(m):
            w = detected[i, h] * inv_denom[h]
            weights[n + i * m + h] = w
            k += w >= prune
    out = np.empty((N_ROWS, k))
    col = _kept_missed(out, weights, missed_tab, n, prune)
    for i in range(n):
        for h in range(m):
            w = weights[n + i * m + h]
            if w >= prune:
                _set_posterior_column(
                    out, col, w, post_means[0, i, h], post_means[1, i, h], post_covs, i
                )
                col += 1
    return out, k, explained


@njit(cache=True)
def _kept_missed(out, weights, missed_tab, n, prune):
    """The first columns of a posterior table ``out``: the missed copies whose weight
    ``weights[i]`` (``i < n``) is at least ``prune``, with ``missed_tab``'s means and
    covariances, in order. Returns how many."""
    col = 0
    for i in range(n):
        if weights[i] >= prune:
            out[0, col] = weights[i]
            for r in range(1, N_ROWS):
                out[r, col] = missed_tab[r, i]
            col += 1
    return col


@njit(cache=True)
def _bernoulli_missed(w, pd, evidence):
    """:func:`localization.phd.missed_weights` of one component."""
    scale = 1.0 / max(math.ceil(w), 1.0)  # r / w = 1 / n
    denom = 1.0 - (w * scale) * pd + scale * evidence
    return (w - w * pd) / max(denom, _TINY)


@njit(cache=True)
def _missed_only(tab, n, pd, prune, bernoulli, missed_tab):
    """An update without measurements: ``w *= 1 - P_d`` (or the Bernoulli missed weight),
    means and covariances from ``missed_tab`` (``tab``, or :func:`_missed_moments`'), pruned.
    Returns (table, k)."""
    out = missed_tab[:, :n].copy()
    for i in range(n):
        out[0, i] = tab[0, i]
        if bernoulli:
            out[0, i] = _bernoulli_missed(out[0, i], pd[i], 0.0)
        else:
            out[0, i] *= 1.0 - pd[i]
    return _prune(out, n, prune)


@njit(cache=True)
def _missed_moments(tab, n, pd, fp):
    """:func:`localization.phd.missed_moments` (the lidar's missed copies moment-matched to
    ``(1 - P_d(x)) N(x; m, P)``), scalar loops. Returns ``(missed_pd (n,), missed_tab (6, n))``."""
    missed_pd = np.empty(n)
    out = tab[:, :n].copy()
    k_nodes = GH_NODES.shape[0]
    for i in range(n):
        mx, my = tab[1, i], tab[2, i]
        pxx, pxy, pyy = tab[3, i], tab[4, i], tab[5, i]
        r = math.hypot(mx, my)
        inv_r = 1.0 / max(r, fp[F_MIN_RANGE])
        ux, uy = mx * inv_r, my * inv_r
        pu_x = pxx * ux + pxy * uy
        pu_y = pxy * ux + pyy * uy
        s2 = ux * pu_x + uy * pu_y
        s = math.sqrt(max(s2, 0.0))
        f_mean = _inverse_sigmoid(r, fp[F_LPD_OFFSET], fp[F_LPD_SLOPE], fp[F_LPD_MID])
        g = pd[i] / f_mean if f_mean > 1e-12 else 0.0
        z = 0.0
        z1 = 0.0
        z2 = 0.0
        for q in range(k_nodes):
            f = _inverse_sigmoid(
                r + s * GH_NODES[q], fp[F_LPD_OFFSET], fp[F_LPD_SLOPE], fp[F_LPD_MID]
            )
            miss = 1.0 - g * f
            z += GH_WEIGHTS[q] * miss
            z1 += GH_WEIGHTS[q] * GH_NODES[q] * miss
            z2 += GH_WEIGHTS[q] * GH_NODES[q] * GH_NODES[q] * miss
        if not (z > _TINY and s2 > _TINY and f_mean > 1e-12):
            missed_pd[i] = pd[i]
            continue
        missed_pd[i] = 1.0 - z
        mu = s * z1 / z
        v = s2 * z2 / z - mu * mu
        shift = mu / s2
        shrink = (v - s2) / (s2 * s2)
        out[1, i] = mx + pu_x * shift
        out[2, i] = my + pu_y * shift
        out[3, i] = pxx + pu_x * pu_x * shrink
        out[4, i] = pxy + pu_x * pu_y * shrink
        out[5, i] = pyy + pu_y * pu_y * shrink
    return missed_pd, out


@njit(cache=True)
def lidar_component(tab, i, r, post_covs):
    """The lidar (``H = I``, noise ``r I``) update of component ``i`` of ``tab``: writes its
    posterior covariance ``[Pxx, Pxy, Pyy]`` into ``post_covs[:, i]`` and returns ``(mx, my,
    h_xx, h_xy, h_yy, norm)``: its mean, ``-S^-1 / 2`` and the peak ``1 / (2 pi sqrt|S|)``
    of its likelihood (:func:`lidar_exponent`; see ``gaussian.position_update``). Shared by
    the GM-PHD and the PMB kernels."""
    pxx, pxy, pyy = tab[3, i], tab[4, i], tab[5, i]
    pxy2 = pxy * pxy
    det_p = pxx * pyy - pxy2
    inv_det_s = 1.0 / max((pxx + r) * (pyy + r) - pxy2, _TINY)
    # -S^-1 / 2 (see gaussian.position_update)
    h_xx = (pyy + r) * (-0.5 * inv_det_s)
    h_xy = pxy * (0.5 * inv_det_s)
    h_yy = (pxx + r) * (-0.5 * inv_det_s)
    # Joseph form reduced to r S^-1 P: all terms non-negative
    scale = r * inv_det_s
    post_covs[0, i] = (pxx * r + det_p) * scale
    post_covs[1, i] = (pxy * r) * scale
    post_covs[2, i] = (pyy * r + det_p) * scale
    return tab[1, i], tab[2, i], h_xx, h_xy, h_yy, math.sqrt(inv_det_s) * _INV_TWO_PI


@njit(cache=True)
def lidar_exponent(pts, h, mx, my, h_xx, h_xy, h_yy):
    """``(-q / 2, e0, e1)`` of point ``pts[h]`` against the component of
    :func:`lidar_component`: ``q`` its squared Mahalanobis distance, ``e = -S^-1 d / 2``
    (the posterior mean is ``pts[h] + 2 r e``)."""
    d0 = pts[h, 0] - mx
    d1 = pts[h, 1] - my
    e0 = h_xx * d0 + h_xy * d1
    e1 = h_xy * d0 + h_yy * d1
    return d0 * e0 + d1 * e1, e0, e1


@njit(cache=True)
def _lidar_update(tab, n, pts, nulls, fp, ip, sector_scaled, sector_params):
    """Lidar GM-PHD update (H = I), pruned. Returns (table, k, explained (M,))."""
    m = pts.shape[0]
    prune = fp[F_PRUNE]
    if m == 0:
        pd = _lidar_pd(tab, n, nulls, fp, ip, sector_scaled, sector_params)
        if ip[I_LIDAR_MISSED_MOMENTS]:
            missed_pd, missed_tab = _missed_moments(tab, n, pd, fp)
        else:
            missed_pd, missed_tab = pd, tab
        out, k = _missed_only(tab, n, missed_pd, prune, ip[I_MISSED_BERNOULLI], missed_tab)
        return out, k, np.empty(0)
    fixed_birth = ip[I_BIRTH_FIXED]
    n1 = n + 1 if fixed_birth else n
    prior = np.empty((N_ROWS, n1))
    prior[:, :n] = tab[:, :n]
    if fixed_birth:
        set_fixed_birth(prior, n, fp)
    pd = _lidar_pd(prior, n1, nulls, fp, ip, sector_scaled, sector_params)
    r = fp[F_LIDAR_VAR]
    kappa = fp[F_KAPPA_L]
    detected = np.empty((n1, m))
    post_means = np.empty((2, n1, m))
    post_covs = np.empty((3, n1))
    for i in range(n1):
        mx, my, h_xx, h_xy, h_yy, norm = lidar_component(prior, i, r, post_covs)
        pd_w = pd[i] * prior[0, i]
        floor = _negligible_exponent(pd_w, norm, kappa, prune)
        for h in range(m):
            # exponent <= 0: far pairs underflow to exactly 0
            exponent, e0, e1 = lidar_exponent(pts, h, mx, my, h_xx, h_xy, h_yy)
            if exponent < floor:
                detected[i, h] = 0.0
                continue
            detected[i, h] = math.exp(exponent) * norm * pd_w
            post_means[0, i, h] = pts[h, 0] + (2.0 * r) * e0
            post_means[1, i, h] = pts[h, 1] + (2.0 * r) * e1
    if ip[I_LIDAR_MISSED_MOMENTS]:
        missed_pd, missed_tab = _missed_moments(prior, n1, pd, fp)
    else:
        missed_pd, missed_tab = pd, prior
    # the fixed birth's missed copy is dropped (see RobotCentricPHD.update_lidar)
    out, k, explained = _posterior(
        prior,
        n1,
        pd,
        detected,
        post_means,
        post_covs,
        np.full(m, kappa),
        prune,
        n if fixed_birth else -1,
        ip[I_MISSED_BERNOULLI],
        missed_tab,
        missed_pd,
    )
    return out, k, explained


@njit(cache=True)
def camera_bearing_var(range_m, fp):
    """``R_C(r)`` (rad^2) at range ``range_m`` (m), as
    :meth:`localization.PHDConfig.camera_bearing_var`."""
    r = max(range_m, fp[F_MIN_RANGE])
    width = 2.0 * math.asin(min(1.0, fp[F_CAMERA_TARGET_RADIUS] / r))
    spread = fp[F_CAMERA_WIDTH_FRACTION] * width
    return fp[F_CAMERA_VAR] + spread * spread


@njit(cache=True)
def camera_clutter(brg, memory, ox, oy, fp):
    """The camera clutter intensity (1/rad) at each bearing ``brg (M,)`` seen from ``(ox, oy)``:
    the uniform ``kappa_C`` plus the blobs of the scan ``memory``'s wide objects
    (:func:`localization.object_clutter.clutter_density`). Without a scan the objects are
    unknown, and the uniform part is the whole. Shared by the GM-PHD and the PMB banks."""
    kappas = np.full(brg.shape[0], fp[F_KAPPA_C_UNIFORM] if memory[0] != 0.0 else fp[F_KAPPA_C])
    if fp[F_WIDE_CLUTTER] > 0.0:
        clutter_density_into(
            kappas,
            brg,
            memory,
            ox,
            oy,
            fp[F_WIDE_CLUTTER],
            fp[F_WIDE_STD_FRACTION],
            fp[F_CAMERA_VAR],
        )
    return kappas


@njit(cache=True)
def camera_gate(tab, i, fp, min_r2):
    """The camera's bearing model at component ``i`` of ``tab`` (seen from the camera): its
    Jacobian ``(j0, j1)``, ``u = P J^T``, ``1 / S``, the noise ``R_C``, the predicted bearing,
    the likelihood's peak ``1 / sqrt(2 pi S)`` and ``-1 / (2 S)``: what gating a bearing
    needs, before :func:`camera_posterior_cov`."""
    x, y = tab[1, i], tab[2, i]
    pxx, pxy, pyy = tab[3, i], tab[4, i], tab[5, i]
    noise = camera_bearing_var(math.hypot(x, y), fp)
    # Guard: ||m||^2 floored so the atan2 Jacobian [-y, x] / r^2 stays finite.
    inv_r2 = 1.0 / max(x * x + y * y, min_r2)
    j0, j1 = -y * inv_r2, x * inv_r2
    u0 = pxx * j0 + pxy * j1
    u1 = pxy * j0 + pyy * j1
    inv_s = 1.0 / (j0 * u0 + j1 * u1 + noise)  # S >= R_C > 0
    predicted = math.atan2(y, x)
    norm = math.sqrt(inv_s) * _INV_SQRT_TWO_PI
    return j0, j1, u0, u1, inv_s, noise, predicted, norm, -0.5 * inv_s


@njit(cache=True)
def camera_posterior_cov(tab, i, j0, j1, u0, u1, inv_s, noise, post_covs):
    """The EKF bearing update's posterior covariance of component ``i`` (Joseph form) from
    :func:`camera_gate`'s terms, written into ``post_covs[:, i]``; returns the gain
    ``(g0, g1)``."""
    pxx, pxy, pyy = tab[3, i], tab[4, i], tab[5, i]
    g0, g1 = u0 * inv_s, u1 * inv_s
    # Joseph form (I - K H) P (I - K H)^T + K R K^T: a sum of PSD terms.
    b00, b01 = 1.0 - g0 * j0, -g0 * j1
    b10, b11 = -g1 * j0, 1.0 - g1 * j1
    bp00 = b00 * pxx + b01 * pxy
    bp01 = b00 * pxy + b01 * pyy
    bp10 = b10 * pxx + b11 * pxy
    bp11 = b10 * pxy + b11 * pyy
    post_covs[0, i] = bp00 * b00 + bp01 * b01 + g0 * noise * g0
    post_covs[1, i] = bp00 * b10 + bp01 * b11 + g0 * noise * g1
    post_covs[2, i] = bp10 * b10 + bp11 * b11 + g1 * noise * g1
    return g0, g1


@njit(cache=True)
def camera_component(tab, i, fp, min_r2, post_covs):
    """The camera's EKF bearing update of component ``i`` of ``tab`` (seen from the camera):
    writes its posterior covariance ``[Pxx, Pxy, Pyy]`` (Joseph form) into ``post_covs[:, i]``
    and returns ``(x, y, g0, g1, predicted, norm, half_inv_s)``: its mean, the gain, the
    predicted bearing, the likelihood's peak ``1 / sqrt(2 pi S)`` and ``-1 / (2 S)``
    (:func:`camera_gate` then :func:`camera_posterior_cov`). Used by the PMB kernels."""
    j0, j1, u0, u1, inv_s, noise, predicted, norm, half_inv_s = camera_gate(tab, i, fp, min_r2)
    g0, g1 = camera_posterior_cov(tab, i, j0, j1, u0, u1, inv_s, noise, post_covs)
    return tab[1, i], tab[2, i], g0, g1, predicted, norm, half_inv_s


@njit(cache=True)
def _camera_update(tab, n, brg, fp, ip, memory, ox, oy):
    """Camera EKF bearing GM-PHD update (+ ray births), pruned. Returns (table, k).

    ``tab`` is seen from the camera: the filter's frame shifted by ``(-ox, -oy)``, which is
    how the scan memory's pose is read (its wide objects' clutter).

    Sparse: of the ``n x M`` (component, bearing) pairs only those above the component's
    :func:`_negligible_exponent` are kept (in component-major order, bearings ascending:
    ``first (n + 1,)`` bounds each component's run), and a component's posterior covariance
    is made only when it has one. Every kept value is computed by the same operations in the
    same order as the dense update over all pairs (``_camera_update_dense`` in
    ``tests/localization/test_camera_sparse.py``), and a dropped pair adds exactly 0 to every
    sum, so the result is the same to the bit."""
    m = brg.shape[0]
    prune = fp[F_PRUNE]
    pd = _camera_pd(tab, n, fp)
    if m == 0:
        return _missed_only(tab, n, pd, prune, ip[I_MISSED_BERNOULLI], tab)
    # The uniform part alone bounds the pairs dropped below (kappa_h >= kappa_C).
    kappa = fp[F_KAPPA_C_UNIFORM] if memory[0] != 0.0 else fp[F_KAPPA_C]
    kappas = camera_clutter(brg, memory, ox, oy, fp)
    min_r2 = fp[F_MIN_RANGE] * fp[F_MIN_RANGE]
    # Per kept pair: its bearing, P_d w N and the posterior mean (the exponent and the
    # innovation wait in pair_w / pair_x until the component's gain is known).
    pair_h = np.empty(n * m, dtype=np.int64)
    pair_w = np.empty(n * m)
    pair_x = np.empty(n * m)
    pair_y = np.empty(n * m)
    first = np.empty(n + 1, dtype=np.int64)
    post_covs = np.empty((3, n))
    p = 0
    for i in range(n):
        first[i] = p
        j0, j1, u0, u1, inv_s, noise, predicted, norm, half_inv_s = camera_gate(tab, i, fp, min_r2)
        pd_w = pd[i] * tab[0, i]
        floor = _negligible_exponent(pd_w, norm, kappa, prune)
        for h in range(m):
            innov = brg[h] - predicted
            if innov >= math.pi or innov < -math.pi:  # wrapped to [-pi, pi)
                innov = _wrap(innov)
            exponent = (innov * innov) * half_inv_s
            if exponent < floor:
                continue
            pair_h[p] = h
            pair_w[p] = exponent
            pair_x[p] = innov
            p += 1
        if p == first[i]:
            continue
        g0, g1 = camera_posterior_cov(tab, i, j0, j1, u0, u1, inv_s, noise, post_covs)
        x, y = tab[1, i], tab[2, i]
        for q in range(first[i], p):
            innov = pair_x[q]
            pair_w[q] = math.exp(pair_w[q]) * norm * pd_w
            pair_x[q] = x + g0 * innov
            pair_y[q] = y + g1 * innov
    first[n] = p
    out, k, explained = _camera_posterior(
        tab, n, pd, pair_h, pair_w, pair_x, pair_y, first, post_covs, kappas, prune,
        ip[I_MISSED_BERNOULLI],
    )  # fmt: skip
    if ip[I_CAMERA_BIRTH]:
        return _with_ray_births(out, k, brg, explained, fp, ip)
    return out, k


@njit(cache=True)
def _camera_posterior(
    tab, n, missed_pd, pair_h, pair_w, pair_x, pair_y, first, post_covs, kappa, prune, bernoulli
):
    """:func:`_posterior` of the camera's kept pairs (:func:`_camera_update`): the same
    weights from the same sums, the kept missed copies (means and covariances of ``tab``,
    ``P_d`` of ``missed_pd``) then the kept detected copies, component-major. Overwrites
    ``pair_w`` with the detected weights. Returns the ``(6, k)`` table, ``k`` and
    ``explained (M,)``."""
    m = kappa.shape[0]
    sums = np.zeros(m)
    for p in range(first[n]):  # per bearing, components in increasing order
        sums[pair_h[p]] += pair_w[p]
    explained = np.empty(m)
    inv_denom = np.empty(m)
    for h in range(m):
        # Guard: zero clutter and underflowed likelihoods give weights 0, not 0/0.
        inv_denom[h] = 1.0 / max(sums[h] + kappa[h], _TINY)
        explained[h] = sums[h] * inv_denom[h]
    missed = np.empty(n)
    k = 0
    for i in range(n):
        w = tab[0, i] - missed_pd[i] * tab[0, i]  # (1 - P_d) w
        if bernoulli:
            evidence = 0.0  # w_i Lambda_i
            for p in range(first[i], first[i + 1]):
                h = pair_h[p]
                others = max(sums[h] - pair_w[p], 0.0) + kappa[h]
                evidence += pair_w[p] / max(others, _TINY)
            w = _bernoulli_missed(tab[0, i], missed_pd[i], evidence)
        missed[i] = w
        k += w >= prune
    for p in range(first[n]):
        pair_w[p] *= inv_denom[pair_h[p]]
        k += pair_w[p] >= prune
    out = np.empty((N_ROWS, k))
    col = _kept_missed(out, missed, tab, n, prune)
    for i in range(n):
        for p in range(first[i], first[i + 1]):
            if pair_w[p] >= prune:
                _set_posterior_column(out, col, pair_w[p], pair_x[p], pair_y[p], post_covs, i)
                col += 1
    return out, k, explained


@njit(cache=True)
def _with_ray_births(tab, n, brg, explained, fp, ip):
    """``tab`` plus :func:`localization.phd.ray_births` of the bearings explained less than
    ``births.camera_max_explained``, those above the prune threshold. Returns (table, k)."""
    n_cells = ip[I_CBIRTH_COMPONENTS]
    r_min = fp[F_CBIRTH_MIN_RANGE]
    step = (fp[F_CBIRTH_MAX_RANGE] - r_min) / n_cells
    ranges = np.empty(n_cells)
    share = np.empty(n_cells)
    total = 0.0
    for c in range(n_cells):
        r = r_min + (c + 0.5) * step
        ranges[c] = r
        share[c] = r * _inverse_sigmoid(r, fp[F_CPD_OFFSET], fp[F_CPD_SLOPE], fp[F_CPD_MID])
        total += share[c]
    scale = fp[F_CBIRTH_W] / total
    prune = fp[F_PRUNE]
    n_kept = 0
    for c in range(n_cells):
        share[c] *= scale  # now the cell's weight
        n_kept += share[c] >= prune
    threshold = fp[F_CBIRTH_MAX_EXPLAINED]
    n_rays = 0
    for h in range(brg.shape[0]):
        n_rays += explained[h] < threshold
    if n_rays == 0 or n_kept == 0:
        return tab, n
    radial_var = (fp[F_CBIRTH_RADIAL_FRACTION] * step) ** 2
    out = np.empty((N_ROWS, n + n_rays * n_kept))
    out[:, :n] = tab[:, :n]
    cells = np.empty((N_ROWS, n_cells))
    col = n
    for h in range(brg.shape[0]):
        if explained[h] >= threshold:
            continue
        co, si = math.cos(brg[h]), math.sin(brg[h])
        for c in range(n_cells):
            r = ranges[c]
            cross_var = r * r * camera_bearing_var(r, fp)
            cells[0, c] = share[c]
            cells[1, c] = r * co
            cells[2, c] = r * si
            cells[3, c] = radial_var * (co * co) + cross_var * (si * si)
            cells[4, c] = (radial_var - cross_var) * (co * si)
            cells[5, c] = radial_var * (si * si) + cross_var * (co * co)
        for c in range(n_cells):
            if cells[0, c] < prune:
                continue
            out[:, col] = cells[:, c]
            col += 1
    return out, col


# ---------------------------------------------------------------------- reduction
@njit(cache=True)
def _prune(tab, n, threshold):
    """The components with ``w >= threshold``, in order (a new array). Returns (table, k)."""
    k = 0
    for i in range(n):
        k += tab[0, i] >= threshold
    out = np.empty((N_ROWS, k))
    col = 0
    for i in range(n):
        if tab[0, i] >= threshold:
            out[:, col] = tab[:, i]
            col += 1
    return out, k


@njit(cache=True)
def _merge_cap(tab, n, merge_threshold, max_components):
    """Greedy merge then cap of a pruned table. Returns (table, k)."""
    cur, k = _merge(tab, n, merge_threshold)
    if k <= max_components:
        return cur, k
    # cap: the max_components heaviest (ties: lower index), in their original order
    order = np.argsort(-cur[0, :k], kind="mergesort")
    kept = np.sort(order[:max_components])
    return cur[:, kept].copy(), max_components


@njit(cache=True)
def reduce_table(tab, n, prune_threshold, merge_threshold, max_components):
    """Prune, greedy merge (Vo & Ma Table II), cap: :func:`localization.reducer.reduce`.

    Parameters
    ----------
    tab : ndarray, shape (6, >= n)
        Component table; only the first ``n`` columns are read.
    n : int
    prune_threshold, merge_threshold : float
    max_components : int

    Returns
    -------
    table : ndarray, shape (6, n')
        A new array, ``n' <= max_components``.
    n' : int
    """
    cur, k = _prune(tab, n, prune_threshold)
    return _merge_cap(cur, k, merge_threshold, max_components)


@njit(cache=True)
def _merge(tab, n, threshold):
    if n < 2:
        return tab, n
    # inverse covariances of the candidates (Vo & Ma's gate uses the candidate's P)
    a_xx = np.empty(n)
    a_xy = np.empty(n)
    a_yy = np.empty(n)
    for i in range(n):
        # Guard: a singular covariance gets a tiny positive determinant.
        inv_det = 1.0 / max(tab[3, i] * tab[5, i] - tab[4, i] * tab[4, i], _TINY)
        a_xx[i] = tab[5, i] * inv_det
        a_xy[i] = -tab[4, i] * inv_det
        a_yy[i] = tab[3, i] * inv_det
    # Leaders in decreasing weight (ties: lower index): a stable sort once, then each round
    # takes the first unassigned one and scans only the still-unassigned candidates.
    order = np.argsort(-tab[0, :n], kind="mergesort")
    labels = np.full(n, -1)
    remaining = np.arange(n)
    n_remaining = n
    n_clusters = 0
    for leader in order:
        if labels[leader] >= 0:
            continue
        n_clusters += 1
        lx, ly = tab[1, leader], tab[2, leader]
        labels[leader] = leader
        kept = 0
        for t in range(n_remaining):
            i = remaining[t]
            if i == leader:
                continue
            dx = tab[1, i] - lx
            dy = tab[2, i] - ly
            if a_xx[i] * dx * dx + 2.0 * a_xy[i] * dx * dy + a_yy[i] * dy * dy <= threshold:
                labels[i] = leader
            else:
                remaining[kept] = i
                kept += 1
        n_remaining = kept
    if n_clusters == n:
        return tab, n
    # Moments about the heaviest mean (no cancellation far from the origin), clusters in
    # increasing leader index, as reducer.merge.
    heaviest = order[0]
    rx, ry = tab[1, heaviest], tab[2, heaviest]
    out = np.empty((N_ROWS, n_clusters))
    slot = np.full(n, -1)
    k = 0
    for i in range(n):
        if labels[i] == i:
            slot[i] = k
            k += 1
    sums = np.zeros((N_ROWS, n_clusters))
    for i in range(n):
        s = slot[labels[i]]
        # Guard: floored weights, so an all-zero cluster still has a defined mean.
        w = max(tab[0, i], _WEIGHT_FLOOR)
        dx, dy = tab[1, i] - rx, tab[2, i] - ry
        sums[0, s] += w
        sums[1, s] += w * dx
        sums[2, s] += w * dy
        sums[3, s] += w * (tab[3, i] + dx * dx)
        sums[4, s] += w * (tab[4, i] + dx * dy)
        sums[5, s] += w * (tab[5, i] + dy * dy)
    for s in range(n_clusters):
        inv_total = 1.0 / sums[0, s]
        mx, my = sums[1, s] * inv_total, sums[2, s] * inv_total
        out[0, s] = sums[0, s]
        out[1, s] = mx + rx
        out[2, s] = my + ry
        out[3, s] = sums[3, s] * inv_total - mx * mx
        out[4, s] = sums[4, s] * inv_total - my * mx
        out[5, s] = sums[5, s] * inv_total - my * my
    return out, n_clusters


# ---------------------------------------------------------------------- driver
@njit(cache=True)
def _remember_scan(memory, profiles, has_profile, poses, has_pose, j):
    """Lidar call ``j``'s scan becomes the robot's scan memory: its profile, and the pose it
    was taken from (the filter's origin without one). A call without a profile leaves no
    scan (an older one would be judged from the wrong place and time)."""
    if not has_profile[j]:
        memory[:] = 0.0
        return
    memory[0] = 1.0
    for k in range(3):
        memory[1 + k] = poses[j, k] if has_pose[j] else 0.0
    memory[4:WIDE_OBJECTS_AT] = profiles[j]
    memory[WIDE_OBJECTS_AT:] = 0.0  # no wide objects until object_clutter extracts them


@njit(cache=True)
def _to_filter_frame(points, bearings, pose):
    """:mod:`localization.frames`: points moved rigidly, bearings rotated (new arrays)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty((points.shape[0], 2))
    for h in range(points.shape[0]):
        out[h, 0] = c * points[h, 0] - s * points[h, 1] + pose[0]
        out[h, 1] = s * points[h, 0] + c * points[h, 1] + pose[1]
    rotated = np.empty(bearings.shape[0])
    for h in range(bearings.shape[0]):
        rotated[h] = _wrap(bearings[h] + pose[2])
    return out, rotated


@njit(cache=True)
def shift_means(tab, n, dx, dy):
    """A copy of ``tab``'s first ``n`` columns with the means moved by ``(dx, dy)``; the
    table itself when the shift is zero (a sensor pose with no translation)."""
    if dx == 0.0 and dy == 0.0:
        return tab
    out = tab[:, :n].copy()
    shift_means_in_place(out, n, dx, dy)
    return out


@njit(cache=True)
def shift_means_in_place(tab, n, dx, dy):
    if dx == 0.0 and dy == 0.0:
        return
    for i in range(n):
        tab[1, i] += dx
        tab[2, i] += dy


@njit(cache=True)
def robot_runs(robots):
    """Runs of equal robot indices in the call order ``robots (Q,)`` (each robot's calls are
    contiguous): ``starts (G + 1,)`` with run ``g`` = calls ``starts[g]:starts[g + 1]``, and
    ``G``. Shared by the GM-PHD and PMB banks' drivers."""
    n_calls = robots.shape[0]
    starts = np.empty(n_calls + 1, dtype=np.int64)
    n_groups = 0
    for q in range(n_calls):
        if q == 0 or robots[q] != robots[q - 1]:
            starts[n_groups] = q
            n_groups += 1
    starts[n_groups] = n_calls
    return starts, n_groups


@njit(cache=True)
def lidar_call_inputs(calls, j, memory, keep_scan, fp):
    """Lidar call ``j``'s detections ``(M, 2)`` and null bearings ``(B,)``, moved into the
    filter's frame when it has a sensor pose. With ``keep_scan`` its scan becomes the robot's
    scan ``memory`` (:func:`_remember_scan`), with its wide objects where the camera clutter
    reads them. Shared by the GM-PHD and the PMB drivers."""
    pts = calls[_POINTS][calls[_LIDAR_START][j] : calls[_LIDAR_STOP][j]]
    nul = calls[_NULLS][calls[_NULL_START][j] : calls[_NULL_STOP][j]]
    if calls[_LIDAR_HAS_POSE][j]:
        pts, nul = _to_filter_frame(pts, nul, calls[_LIDAR_POSE][j])
    if keep_scan:  # else no 720-float copy
        _remember_scan(
            memory,
            calls[_PROFILES],
            calls[_LIDAR_HAS_PROFILE],
            calls[_LIDAR_POSE],
            calls[_LIDAR_HAS_POSE],
            j,
        )
        if fp[F_WIDE_CLUTTER] > 0.0 and memory[0] != 0.0:
            wide_objects_into(memory)
    return pts, nul


@njit(cache=True)
def camera_call_inputs(calls, j):
    """Camera call ``j``'s bearings ``(M,)``, rotated into the filter's frame when it has a
    sensor pose, and the camera's position ``(x_m, y_m)`` in that frame (``0, 0`` without
    one): the bearing model is read from there. Shared by the GM-PHD and the PMB drivers."""
    brg = calls[_BEARINGS][calls[_CAMERA_START][j] : calls[_CAMERA_STOP][j]]
    if not calls[_CAMERA_HAS_POSE][j]:
        return brg, 0.0, 0.0
    pose = calls[_CAMERA_POSE][j]
    _, brg = _to_filter_frame(np.empty((0, 2)), brg, pose)
    return brg, pose[0], pose[1]


@njit(cache=True)
def after_predict(pending_counts, r, memory, odo):
    """After robot ``r``'s time update: its pending births are spent and its scan memory's
    pose moves with the frame. Shared by the GM-PHD and the PMB drivers."""
    pending_counts[r] = 0
    if memory[0] != 0.0:
        move_scan_pose_in_place(memory, odo)


@njit(cache=True)
def keep_measurement_births(pending, pending_counts, r, pts, explained, fp):
    """Robot ``r``'s detections explained below ``measurement_birth_max_explained`` wait, as
    its pending births, for the next time update. Shared by the GM-PHD and the PMB drivers."""
    b = 0
    for h in range(explained.shape[0]):
        if explained[h] < fp[F_MBIRTH_MAX_EXPLAINED]:
            pending[r, b, 0] = pts[h, 0]
            pending[r, b, 1] = pts[h, 1]
            b += 1
    pending_counts[r] = b


@njit(cache=True)
def store_table(table, counts, r, out, n_out):
    """Robot ``r``'s slice of the padded ``table`` becomes ``out``'s first ``n_out`` columns
    (the rest zero)."""
    table[:, r, :n_out] = out[:, :n_out]
    table[:, r, n_out:] = 0.0
    counts[r] = n_out


@njit(cache=True)
def _apply_call(q, state, calls, params):
    """Call ``q`` of :func:`apply_calls` on its robot's slice of the state."""
    table, counts, pending, pending_counts, clock, scan_memory = state
    fp, ip, sector_scaled, sector_params = params
    r = calls[_ROBOTS][q]
    kind = calls[_KINDS][q]
    j = calls[_INDEX][q]
    n = counts[r]
    tab = table[:, r, :n]
    memory = scan_memory[r]
    if kind == ADVANCE:
        diffuse(tab, n, advance_clock(clock, r, calls[_STAMPS][j], fp, ip))
        return
    if kind == PREDICT:
        odo = calls[_ODOMETRY][j]
        q_var = predict_process_var(clock, r, fp, ip)
        out, n_out = predict_with_births(tab, n, pending[r], pending_counts[r], odo, q_var, fp, ip)
        after_predict(pending_counts, r, memory, odo)
    elif kind == LIDAR:
        keep_scan = fp[F_WIDE_CLUTTER] > 0.0
        pts, nul = lidar_call_inputs(calls, j, memory, keep_scan, fp)
        cand, n_cand, explained = _lidar_update(
            tab, n, pts, nul, fp, ip, sector_scaled, sector_params
        )
        if ip[I_BIRTH_MEASUREMENT]:
            keep_measurement_births(pending, pending_counts, r, pts, explained, fp)
        out, n_out = _merge_cap(cand, n_cand, fp[F_MERGE], ip[I_MAX_COMPONENTS])
    else:
        if ip[I_LIDAR_ONLY]:
            return
        # The bearing model from the camera's position (RobotCentricPHD.update_camera).
        brg, sx, sy = camera_call_inputs(calls, j)
        seen = shift_means(tab, n, -sx, -sy)
        cand, n_cand = _camera_update(seen, n, brg, fp, ip, memory, sx, sy)
        shift_means_in_place(cand, n_cand, sx, sy)
        out, n_out = _merge_cap(cand, n_cand, fp[F_MERGE], ip[I_MAX_COMPONENTS])
    store_table(table, counts, r, out, n_out)


@njit(cache=True, parallel=True)
def apply_calls(state, calls, params):
    """Run ``Q`` encoded calls (module docstring) on the bank state, in place.

    Parameters
    ----------
    state : tuple of ndarray
        ``(table, counts, pending, pending_counts, clock, scan_memory)``: ``table (6, R, C)``
        with rows ``w, x, y, Pxx, Pxy, Pyy`` (robot ``r`` uses columns ``[:counts[r]]``, the
        rest is kept at 0; ``C = max_components``), ``counts (R,)``; ``pending (R, Pmax, 2)``
        the measurement births awaiting the next time update (``birth == "measurement"``;
        ``Pmax`` at least the largest lidar call's point count) and ``pending_counts (R,)``;
        ``clock (R, 2)`` per robot its last stamp (s, nan before the first) and whether it
        was advanced since the last predict (:func:`advance_clock`); ``scan_memory (R,
        MEMORY_LEN)`` per robot its last scan (:mod:`localization.scan_memory`),
        ``[has_scan, x_m, y_m, psi_rad, profile, wide objects]``, the pose in the filter's
        frame: written by lidar calls (where the scans are read; a call without a profile
        clears it), moved by predicts.
    calls : tuple of ndarray
        ``robots, kinds, index, odometry, lidar_start, lidar_stop, points, null_start,
        null_stop, nulls, camera_start, camera_stop, bearings, lidar_pose, lidar_has_pose,
        camera_pose, camera_has_pose, stamps, profiles, lidar_has_profile`` (module docstring).
    params : tuple of ndarray
        :func:`pack_params`.
    """
    # Robots are independent: each thread takes whole robots, and runs their calls in order.
    starts, n_groups = robot_runs(calls[_ROBOTS])
    for g in prange(n_groups):
        for q in range(starts[g], starts[g + 1]):
            _apply_call(q, state, calls, params)
