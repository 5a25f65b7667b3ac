"""Survival and detection probabilities of the GM-PHD (Perera 2021 eqs. 10, 18-23, 29-30).

All factors are evaluated at the component means of the *prior* mixture, vectorised over
components (and over component pairs for occlusion, components x null returns for
interference). Angular bumps are written with unit bearing vectors: for two bearings whose
difference is ``d``, ``u_i . u_j = cos d``, and the bump

    ``bump(d; sigma) = exp((cos d - 1) / sigma^2)``

has peak 1 at ``d = 0``, is periodic (no angle wrapping needed) and equals the Gaussian
``exp(-d^2 / (2 sigma^2))`` up to a relative error of order ``d^4 / (24 sigma^2)`` in the
exponent, i.e. identical for the few-degree widths used here. It costs one small matrix
product instead of ``atan2`` plus wrapping.

Corrections to Perera 2021 (see ``docs/concepts/localizers.md``):

* eq. 20 (blind sectors) and eq. 22 (occlusion) are written as *sums* of factors; a product
  is what the text describes (each sector / each nearer robot removes detection), so we
  multiply. Perera 2021's ``N(theta; alpha, beta/2)`` is replaced by a bump of peak 1 with
  ``sigma = beta/2``, so that ``P_d -> 0`` at the sector centre.
* eq. 23 (interference) is also written as a sum; we use the product over null-return
  bearings ``b`` of ``1 - depth * bump(theta - b; c)``.
* Each occlusion factor ``1 - w_j bump`` is clipped at 0: merged weights can exceed 1.
* The blind sectors' bump is the Perera 2021 study's; ``blind_sector_model="visible-width"``
  replaces it with the notch that the scanner's beam geometry gives (:func:`visible_width_factor`).

References
----------
.. [1] Perera 2021, chapter 3.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

from swarm_core.geometry import wrap_angle

from .config import PHDConfig
from .mixture import ROW_PXX, ROW_PXY, ROW_PYY, ROW_W, ROW_X, ROW_Y

__all__ = [
    "inverse_sigmoid",
    "unit_bearings",
    "angular_bump",
    "blind_sector_factor",
    "blind_sector_geometry",
    "expected_ramp",
    "visible_width_factor",
    "blind_sector_first_beams",
    "occlusion_factor",
    "interference_factor",
    "DetectionModel",
]

_INV_SQRT_TWO_PI = 1.0 / math.sqrt(2.0 * math.pi)
# exp(x) overflows above ~709; clip the sigmoid exponent (far components get P ~ 0 either way).
_MAX_EXP = 700.0
# expected_ramp: a ramp narrower than this (rad) is a step, and stds are floored at this (rad),
# so the ramp's difference quotient never divides a rounding error by a vanishing width.
RAMP_MIN_WIDTH_RAD = 1e-6
RAMP_MIN_STD_RAD = 1e-12


def inverse_sigmoid(
    range_m: np.ndarray, offset: float, slope_per_m: float, midpoint_m: float
) -> np.ndarray:
    """``1 / (offset + exp(slope * (range - midpoint)))`` (Perera 2021 eqs. 10, 19, 30).

    Parameters
    ----------
    range_m : ndarray, shape (N,)
        Ranges (m).
    offset, slope_per_m, midpoint_m : float
        Sigmoid parameters; ``offset >= 1`` keeps the result in ``[0, 1]``.

    Returns
    -------
    ndarray, shape (N,)
    """
    # Guard: clipped exponent, so no overflow warning for absurdly far components.
    exponent = np.minimum(range_m * slope_per_m - slope_per_m * midpoint_m, _MAX_EXP)
    return 1.0 / (np.exp(exponent) + offset)


def unit_bearings(means: np.ndarray, min_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Ranges and unit bearing vectors of the component means.

    Parameters
    ----------
    means : ndarray, shape (2, N)
        Component means (m).
    min_range_m : float
        Floor on the range used for the division; a component at the origin gets the zero
        vector (it then neither occludes nor is affected by angular factors).

    Returns
    -------
    ranges : ndarray, shape (N,)
        ``||m||`` (m), unfloored.
    units : ndarray, shape (2, N)
        ``m / max(||m||, min_range_m)``.
    """
    ranges = np.hypot(means[0], means[1])
    # Guard: floor the divisor so a mean at the origin gives a zero vector, not NaN.
    return ranges, means / np.maximum(ranges, min_range_m)


def angular_bump(units: np.ndarray, directions: np.ndarray, inv_var: np.ndarray) -> np.ndarray:
    """``exp((cos d - 1) / sigma^2)`` between bearings and reference directions.

    Parameters
    ----------
    units : ndarray, shape (2, N)
        Unit bearing vectors.
    directions : ndarray, shape (K, 2)
        Unit reference directions.
    inv_var : ndarray, shape (K, 1)
        ``1 / sigma_k^2`` per direction (rad^-2).

    Returns
    -------
    ndarray, shape (K, N)
        Bump values in ``[0, 1]``, 1 where the bearing equals the direction.
    """
    return np.exp((directions * inv_var).dot(units) - inv_var)


def _scaled_bump(scaled_dirs: np.ndarray, units: np.ndarray, inv_var: np.ndarray) -> np.ndarray:
    """:func:`angular_bump` with ``directions * inv_var`` precomputed."""
    return np.exp(scaled_dirs.dot(units) - inv_var)


def blind_sector_factor(
    units: np.ndarray,
    sector_dirs: np.ndarray,
    sector_inv_var: np.ndarray,
    _scaled_dirs: np.ndarray | None = None,
) -> np.ndarray:
    """Product over blind sectors of ``1 - bump(theta - alpha_k; sigma_k)``.

    Parameters
    ----------
    units : ndarray, shape (2, N)
        Unit bearing vectors of the components.
    sector_dirs : ndarray, shape (K, 2)
        Unit vectors of the sector centres ``alpha_k``.
    sector_inv_var : ndarray, shape (K, 1)
        ``1 / sigma_k^2`` with ``sigma_k = beta_k / 2`` (rad^-2).

    Returns
    -------
    ndarray, shape (N,)
        Factor in ``[0, 1]``; 0 at a sector centre.
    """
    if _scaled_dirs is None:
        bump = angular_bump(units, sector_dirs, sector_inv_var)
    else:
        bump = _scaled_bump(_scaled_dirs, units, sector_inv_var)
    return np.multiply.reduce(1.0 - bump, axis=0)


def expected_ramp(
    mean: np.ndarray, std: np.ndarray, start: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """``E[clip((X - start) / width, 0, 1)]`` for ``X ~ N(mean, std^2)``, elementwise.

    With ``G(m) = E[max(Y, 0)] = m Phi(m / std) + std phi(m / std)`` for ``Y ~ N(m, std^2)``,
    the ramp is ``(max(x, 0) - max(x - width, 0)) / width`` of ``x = X - start``, so its
    expectation is ``(G(mean - start) - G(mean - start - width)) / width``. A ramp narrower
    than ``RAMP_MIN_WIDTH_RAD`` is a step: ``Phi((mean - start) / std)``. ``std`` is floored
    at ``RAMP_MIN_STD_RAD`` (``std -> 0`` evaluates the ramp at ``mean``). Arguments broadcast;
    angles in rad.
    """
    std = np.maximum(std, RAMP_MIN_STD_RAD)
    x = np.asarray(mean - start, dtype=float)
    is_step = width < RAMP_MIN_WIDTH_RAD
    safe_width = np.where(is_step, 1.0, width)
    z0 = x / std
    z1 = (x - safe_width) / std
    g0 = x * ndtr(z0) + std * np.exp(-0.5 * z0 * z0) * _INV_SQRT_TWO_PI
    g1 = (x - safe_width) * ndtr(z1) + std * np.exp(-0.5 * z1 * z1) * _INV_SQRT_TWO_PI
    return np.clip(np.where(is_step, ndtr(z0), (g0 - g1) / safe_width), 0.0, 1.0)


def visible_width_factor(
    offsets_rad: np.ndarray,
    ranges_m: np.ndarray,
    bearing_std_rad: np.ndarray,
    half_widths_rad: np.ndarray,
    first_beams_rad: tuple[np.ndarray, np.ndarray],
    edge_ramp_rad: float,
    target_radius_m: float,
    footprint_rad: float,
    spacing_rad: float,
    min_returns: int,
) -> np.ndarray:
    """The ``"visible-width"`` blind-sector factor of one sector: the probability that a
    housing at signed bearing ``offsets_rad`` from the sector's centre still gives
    ``min_returns`` returns, given that it would in full view. Arguments broadcast.

    Derivation (the X4 of ``swarm_env.sensors.lidar``; ``f`` the footprint, ``Delta`` the beam
    spacing, ``n`` the minimum returns, ``h`` the sector's half-width). A housing of radius
    ``R`` at range ``r`` spans ``+/- a``, ``a = asin(R / r)``, about its bearing ``s``; a beam
    returns from it when its whole footprint is on it, i.e. its centre is within
    ``[s - a + f/2, s + a - f/2]``, and when that centre is outside the sector ``[-h, h]``.
    Beyond ``+h`` the beams that can return start at ``e`` (``first_beams_rad[0]``) and come
    every ``Delta``: at least ``n`` of them fall on the housing when
    ``s + a - f/2 >= e + (n - 1) Delta``, a step at ``s0 = e - a + f/2 + (n - 1) Delta``. With
    fixed beams ``e`` is the first beam past the edge (``edge_ramp_rad`` = 0). With drifting
    beams ``e`` is uniform on ``(h, h + Delta]``, which turns the step into the ramp
    ``clip((s - s0) / Delta, 0, 1)`` with ``e = h`` (``edge_ramp_rad`` = ``Delta``). Once the
    housing clears the sector (``s1 = h + a - f/2``) the count is the full view's, which the
    filter's range factor carries: the factor is 1 from ``s1`` on, so the step or ramp is cut
    there (a housing that gives fewer than ``n`` returns even in full view has a step at
    ``s1``). The side beyond ``-h`` is the mirror image (``-s``, ``first_beams_rad[1]``). At
    a given bearing the factor is the larger side; the two are both non-zero only where a
    housing wider than the sector shows on both sides, and then both are 1 (the null returns
    of the blind beams split the cluster, so the sides do not add up). It is averaged over
    the component's bearing, ``s ~ N(offset, bearing_std^2)``: the notch's edges (``<=
    Delta`` = 0.5 deg) are narrower than a typical component's bearing uncertainty. The
    average of the larger side is the sum of the sides' averages (:func:`expected_ramp`)
    where they do not overlap, capped at 1 where they do: ``min(E[plus] + E[minus], 1)``.

    Parameters
    ----------
    offsets_rad : ndarray
        Component bearing minus the sector centre, wrapped to ``(-pi, pi]`` (rad).
    ranges_m : ndarray
        Component ranges (m).
    bearing_std_rad : ndarray
        Component bearing standard deviations (rad; 0 evaluates at the mean).
    half_widths_rad : ndarray
        Sector half-widths ``h`` (rad).
    first_beams_rad : (ndarray, ndarray)
        ``e`` beyond ``+h`` and beyond ``-h`` (rad, both positive; see
        :func:`blind_sector_first_beams`).
    edge_ramp_rad : float
        Width of the edge's ramp: ``Delta`` (drifting beams) or 0 (fixed beams).
    target_radius_m, footprint_rad, spacing_rad, min_returns
        ``R`` (m), ``f``, ``Delta`` (rad) and ``n``.

    Returns
    -------
    ndarray
        Factor in ``[0, 1]``, broadcast shape of the arguments.
    """
    ratio = np.minimum(target_radius_m / np.maximum(ranges_m, 1e-12), 1.0)
    half_angle = np.arcsin(ratio)
    clear = half_widths_rad + half_angle - 0.5 * footprint_rad
    sides = []
    for sign, first in ((1.0, first_beams_rad[0]), (-1.0, first_beams_rad[1])):
        start = first - half_angle + 0.5 * footprint_rad + (min_returns - 1) * spacing_rad
        width = np.clip(clear - start, 0.0, edge_ramp_rad)
        sides.append(
            expected_ramp(sign * offsets_rad, bearing_std_rad, np.minimum(start, clear), width)
        )
    return np.minimum(sides[0] + sides[1], 1.0)


def blind_sector_first_beams(config: PHDConfig) -> tuple[np.ndarray, float]:
    """``(first_beams (K, 2), edge_ramp_rad)`` of ``config``'s blind sectors for
    :func:`visible_width_factor`: per sector, the offsets from its centre (rad, positive) of
    the first beams that can return beyond its ``+`` and ``-`` edges, and the edges' ramp.

    Fixed beams (``lidar_beam_phase == "fixed"``) sit at ``-pi + k 2 pi / B``,
    ``B = round(360 / lidar_beam_spacing_deg)``, and a beam is blind within half a width of a
    centre, edges included: the simulator's rule (``swarm_core.perception.blind_sectors``),
    evaluated here with its expressions so both sides of an edge round alike. Drifting beams
    start at the edge itself, with a ramp one spacing wide.
    """
    centres = np.radians(np.asarray(config.lidar.blind_sector_centers_deg, dtype=float))
    halves = 0.5 * np.radians(np.asarray(config.lidar.blind_sector_widths_deg, dtype=float))
    spacing = math.radians(config.lidar.beam_spacing_deg)
    if config.lidar.beam_phase == "drifting":
        return np.stack((halves, halves), axis=1).reshape(-1, 2), spacing
    n_beams = round(360.0 / config.lidar.beam_spacing_deg)
    angles = -np.pi + np.arange(n_beams) * (2.0 * np.pi / n_beams)
    offsets = wrap_angle(angles[:, None] - centres)  # (B, K)
    visible = ~(np.abs(offsets) <= halves)
    plus = np.where(visible & (offsets > 0.0), offsets, np.inf).min(axis=0)
    minus = np.where(visible & (offsets < 0.0), -offsets, np.inf).min(axis=0)
    return np.stack((plus, minus), axis=1).reshape(-1, 2), 0.0


def occlusion_factor(
    units: np.ndarray,
    ranges: np.ndarray,
    weights: np.ndarray,
    inv_var: float,
    min_separation_m: float,
) -> np.ndarray:
    """Perera 2021 eqs. 21-22 as a product over nearer components ``j`` of ``1 - w_j bump``.

    Parameters
    ----------
    units : ndarray, shape (2, N)
        Unit bearing vectors.
    ranges : ndarray, shape (N,)
        Component ranges (m).
    weights : ndarray, shape (N,)
        Component weights.
    inv_var : float
        ``1 / sigma^2`` of the occlusion bump (rad^-2).
    min_separation_m : float
        Component ``j`` occludes ``i`` only if ``r_j < r_i - min_separation_m``.

    Returns
    -------
    ndarray, shape (N,)
        Factor in ``[0, 1]``.
    """
    bump = np.exp((units.T * inv_var).dot(units) - inv_var)  # (N, N) [i, j], symmetric
    nearer = ranges[None, :] < (ranges - min_separation_m)[:, None]  # [i, j]: j nearer
    # Guard: weights clipped at 1 so each factor 1 - w_j bump stays >= 0 (merged weights
    # can exceed 1).
    blockers = nearer * np.minimum(weights, 1.0)[None, :]
    return np.multiply.reduce(1.0 - bump * blockers, axis=-1)


def interference_factor(
    units: np.ndarray,
    null_bearings_rad: np.ndarray,
    inv_var: float,
    depth: float,
) -> np.ndarray:
    """Perera 2021 eq. 23 as a product over null-return bearings ``b`` of ``1 - depth * bump``.

    Parameters
    ----------
    units : ndarray, shape (2, N)
        Unit bearing vectors.
    null_bearings_rad : ndarray, shape (B,)
        Bearings of zero-intensity returns (rad, robot frame).
    inv_var : float
        ``1 / c^2`` (rad^-2).
    depth : float
        Notch depth in ``[0, 1]`` (seed: 0.6).

    Returns
    -------
    ndarray, shape (N,)
        Product of per-null factors, each in ``[1 - depth, 1]``.
    """
    dirs = np.empty((null_bearings_rad.shape[0], 2))
    dirs[:, 0] = np.cos(null_bearings_rad)
    dirs[:, 1] = np.sin(null_bearings_rad)
    bump = np.exp((dirs * inv_var).dot(units) - inv_var)  # (B, N)
    return np.multiply.reduce(1.0 - depth * bump, axis=0)


def blind_sector_geometry(config: PHDConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(directions, inv_var)`` of ``config``'s lidar blind sectors: the unit vectors of their
    centres ``alpha_k``, shape (K, 2), and ``1 / sigma_k^2`` with ``sigma_k = beta_k / 2``
    (rad^-2), shape (K,)."""
    centres = np.radians(np.asarray(config.lidar.blind_sector_centers_deg, dtype=float))
    sigmas = 0.5 * np.radians(np.asarray(config.lidar.blind_sector_widths_deg, dtype=float))
    return np.stack((np.cos(centres), np.sin(centres)), axis=1).reshape(-1, 2), 1.0 / sigmas**2


class DetectionModel:
    """Survival, lidar and camera detection probabilities built from a :class:`PHDConfig`.

    Derived constants (sector unit vectors, inverse variances) are computed once here so
    the per-call functions are a handful of numpy operations.

    Parameters
    ----------
    config : PHDConfig
        Filter configuration.
    """

    __slots__ = (
        "config",
        "_sector_dirs",
        "_sector_inv_var",
        "_sector_scaled",
        "_sector_half_widths",
        "_sector_first_beams",
        "_sector_edge_ramp",
        "_occlusion_inv_var",
        "_interference_inv_var",
    )

    def __init__(self, config: PHDConfig) -> None:
        self.config = config
        self._sector_dirs, inv_var = blind_sector_geometry(config)  # (K, 2), (K,)
        self._sector_inv_var = inv_var[:, None]  # (K, 1)
        self._sector_scaled = self._sector_dirs * self._sector_inv_var
        # sigma = width / 2 is the half-width, read back as the compiled kernel reads it
        self._sector_half_widths = 1.0 / np.sqrt(self._sector_inv_var)  # (K, 1)
        first_beams, self._sector_edge_ramp = blind_sector_first_beams(config)
        self._sector_first_beams = (first_beams[:, :1], first_beams[:, 1:])  # (K, 1) each
        self._occlusion_inv_var = 1.0 / math.radians(config.lidar.occlusion_std_deg) ** 2
        self._interference_inv_var = 1.0 / math.radians(config.lidar.interference_std_deg) ** 2

    def __getstate__(self) -> PHDConfig:
        return self.config

    def __setstate__(self, config: PHDConfig) -> None:
        self.__init__(config)  # type: ignore[misc]

    def survival(self, table: np.ndarray) -> np.ndarray:
        """``P_s`` per component (Perera 2021 eq. 10 or constant), shape (N,), of a ``(6, N)``
        table."""
        cfg = self.config
        if cfg.prediction.survival_model == "constant":
            return np.full(table.shape[1:], cfg.prediction.survival_probability)
        return inverse_sigmoid(
            np.hypot(table[ROW_X], table[ROW_Y]),
            cfg.prediction.survival_offset,
            cfg.prediction.survival_slope_per_m,
            cfg.prediction.survival_range_m,
        )

    def lidar(self, table: np.ndarray, null_bearings_rad: np.ndarray | None) -> np.ndarray:
        """Lidar ``P_d`` per component (Perera 2021 eq. 18 or constant), in ``[0, 1]``.

        Parameters
        ----------
        table : ndarray, shape (6, N)
            Prior component table.
        null_bearings_rad : ndarray, shape (B,), or None
            Bearings of zero-intensity returns (interference factor); ``None`` or empty
            disables the factor.

        Returns
        -------
        ndarray, shape (N,)
        """
        cfg = self.config
        if cfg.lidar.pd_model == "constant":
            return self.lidar_range_factor(np.hypot(table[ROW_X], table[ROW_Y]))
        ranges, units = unit_bearings(table[ROW_X : ROW_Y + 1], cfg.reduction.min_range_m)
        pd = self.lidar_range_factor(ranges)
        if self._sector_dirs.shape[0]:
            if cfg.lidar.blind_sector_model == "seed":
                pd *= blind_sector_factor(
                    units, self._sector_dirs, self._sector_inv_var, self._sector_scaled
                )
            else:
                # u_perp' P u_perp / d^2 with u = m / d, d = max(||m||, min_range_m)
                bearing_var = (
                    units[1] ** 2 * table[ROW_PXX]
                    - 2.0 * units[0] * units[1] * table[ROW_PXY]
                    + units[0] ** 2 * table[ROW_PYY]
                ) / np.maximum(ranges, cfg.reduction.min_range_m) ** 2
                pd *= self._visible_width_factor(
                    units, ranges, np.sqrt(np.maximum(bearing_var, 0.0))
                )
        if table.shape[1] > 1:
            pd *= occlusion_factor(
                units,
                ranges,
                table[ROW_W],
                self._occlusion_inv_var,
                cfg.lidar.occlusion_min_separation_m,
            )
        if null_bearings_rad is not None and null_bearings_rad.shape[0]:
            pd *= interference_factor(
                units, null_bearings_rad, self._interference_inv_var, cfg.lidar.interference_depth
            )
        # Every factor is in [0, 1] by construction, so the product needs no final clip.
        return pd

    def lidar_range_factor(self, ranges_m: np.ndarray) -> np.ndarray:
        """The range part of :meth:`lidar`'s ``P_d`` at ``ranges_m`` (N,) (m), shape (N,): seed
        eq. 19's sigmoid, or the constant model's ``P_d`` within ``lidar_range_m`` (0 beyond)."""
        cfg = self.config
        ranges_m = np.asarray(ranges_m, dtype=float)
        if cfg.lidar.pd_model == "constant":
            return (ranges_m <= cfg.lidar.range_m) * cfg.lidar.detection_probability
        return inverse_sigmoid(
            ranges_m, cfg.lidar.pd_offset, cfg.lidar.pd_slope_per_m, cfg.lidar.pd_midpoint_m
        )

    def lidar_blind_sector_factor(
        self,
        bearings_rad: np.ndarray,
        ranges_m: np.ndarray,
        bearing_std_rad: np.ndarray | float = 0.0,
    ) -> np.ndarray:
        """The blind-sector part of :meth:`lidar`'s ``P_d`` for components at body-frame
        ``bearings_rad`` (N,) and ``ranges_m`` (N,) (m) with bearing stds ``bearing_std_rad``
        (rad; 0: the factor at the bearing itself), shape (N,): 1 in the lidar's view, 0 at a
        sector's centre. The ``"seed"`` bump ignores range and std. The constant model has no
        sectors (1 everywhere), as in :meth:`lidar`."""
        bearings_rad = np.asarray(bearings_rad, dtype=float)
        if self.config.lidar.pd_model == "constant" or not self._sector_dirs.shape[0]:
            return np.ones(bearings_rad.shape)
        units = np.stack((np.cos(bearings_rad), np.sin(bearings_rad)))
        if self.config.lidar.blind_sector_model == "seed":
            return blind_sector_factor(
                units, self._sector_dirs, self._sector_inv_var, self._sector_scaled
            )
        return self._visible_width_factor(
            units,
            np.broadcast_to(np.asarray(ranges_m, dtype=float), bearings_rad.shape),
            np.broadcast_to(np.asarray(bearing_std_rad, dtype=float), bearings_rad.shape),
        )

    def _visible_width_factor(
        self, units: np.ndarray, ranges_m: np.ndarray, bearing_std_rad: np.ndarray
    ) -> np.ndarray:
        """Product over sectors of :func:`visible_width_factor` for unit bearings (2, N)."""
        cfg = self.config
        dirs = self._sector_dirs  # (K, 2)
        # signed angle from each sector centre to each bearing, (K, N)
        offsets = np.arctan2(
            dirs[:, :1] * units[1] - dirs[:, 1:] * units[0],
            dirs[:, :1] * units[0] + dirs[:, 1:] * units[1],
        )
        factors = visible_width_factor(
            offsets,
            ranges_m,
            bearing_std_rad,
            self._sector_half_widths,
            self._sector_first_beams,
            self._sector_edge_ramp,
            cfg.lidar.target_radius_m,
            math.radians(cfg.lidar.beam_footprint_deg),
            math.radians(cfg.lidar.beam_spacing_deg),
            cfg.lidar.min_returns,
        )
        return np.multiply.reduce(factors, axis=0)

    def camera(self, table: np.ndarray) -> np.ndarray:
        """Camera ``P_d`` per component (Perera 2021 eqs. 29-30), in ``[0, 1]``.

        ``table`` is ``(6, N)``; the result has shape ``(N,)``. Components closer than
        ``min_range_m`` get 0: their bearing is undefined.
        """
        cfg = self.config
        ranges, units = unit_bearings(table[ROW_X : ROW_Y + 1], cfg.reduction.min_range_m)
        pd = inverse_sigmoid(
            ranges, cfg.camera.pd_offset, cfg.camera.pd_slope_per_m, cfg.camera.pd_midpoint_m
        )
        pd *= ranges >= cfg.reduction.min_range_m
        if table.shape[-1] > 1:
            pd *= occlusion_factor(
                units,
                ranges,
                table[ROW_W],
                self._occlusion_inv_var,
                cfg.lidar.occlusion_min_separation_m,
            )
        return pd
