"""Survival and detection probabilities of the robot-centric GM-PHD (seed eqs. 10, 18-23, 29-30).

All factors are evaluated at the component means of the *prior* mixture, vectorised over
components (and over component pairs for occlusion, components x null returns for
interference). Angular bumps are written with unit bearing vectors: for two bearings whose
difference is ``d``, ``u_i . u_j = cos d``, and the bump

    ``bump(d; sigma) = exp((cos d - 1) / sigma^2)``

has peak 1 at ``d = 0``, is periodic (no angle wrapping needed) and equals the Gaussian
``exp(-d^2 / (2 sigma^2))`` up to a relative error of order ``d^4 / (24 sigma^2)`` in the
exponent, i.e. identical for the few-degree widths used here. It costs one small matrix
product instead of ``atan2`` plus wrapping.

Corrections to the seed (see ``docs/localization.md``):

* eq. 20 (blind sectors) and eq. 22 (occlusion) are written as *sums* of factors; a product
  is what the text describes (each sector / each nearer robot removes detection), so we
  multiply. The seed's ``N(theta; alpha, beta/2)`` is replaced by a bump of peak 1 with
  ``sigma = beta/2``, so that ``P_d -> 0`` at the sector centre.
* eq. 23 (interference) is also written as a sum; we use the product over null-return
  bearings ``b`` of ``1 - depth * bump(theta - b; c)``.
* Each occlusion factor ``1 - w_j bump`` is clipped at 0: merged weights can exceed 1.

References
----------
.. [1] Perera 2021, seed ``000`` of this project, chapter 3.
"""

from __future__ import annotations

import math

import numpy as np

from .config import PHDConfig
from .mixture import ROW_W, ROW_X, ROW_Y

__all__ = [
    "inverse_sigmoid",
    "unit_bearings",
    "angular_bump",
    "blind_sector_factor",
    "blind_sector_geometry",
    "occlusion_factor",
    "interference_factor",
    "DetectionModel",
]

# exp(x) overflows above ~709; clip the sigmoid exponent (far components get P ~ 0 either way).
_MAX_EXP = 700.0


def inverse_sigmoid(
    range_m: np.ndarray, offset: float, slope_per_m: float, midpoint_m: float
) -> np.ndarray:
    """``1 / (offset + exp(slope * (range - midpoint)))`` (seed eqs. 10, 19, 30).

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


def occlusion_factor(
    units: np.ndarray,
    ranges: np.ndarray,
    weights: np.ndarray,
    inv_var: float,
    min_separation_m: float,
) -> np.ndarray:
    """Seed eqs. 21-22 as a product over nearer components ``j`` of ``1 - w_j bump``.

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
    """Seed eq. 23 as a product over null-return bearings ``b`` of ``1 - depth * bump``.

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
    centres = np.radians(np.asarray(config.blind_sector_centers_deg, dtype=float))
    sigmas = 0.5 * np.radians(np.asarray(config.blind_sector_widths_deg, dtype=float))
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
        "_occlusion_inv_var",
        "_interference_inv_var",
    )

    def __init__(self, config: PHDConfig) -> None:
        self.config = config
        self._sector_dirs, inv_var = blind_sector_geometry(config)  # (K, 2), (K,)
        self._sector_inv_var = inv_var[:, None]  # (K, 1)
        self._sector_scaled = self._sector_dirs * self._sector_inv_var
        self._occlusion_inv_var = 1.0 / math.radians(config.occlusion_std_deg) ** 2
        self._interference_inv_var = 1.0 / math.radians(config.interference_std_deg) ** 2

    def __getstate__(self) -> PHDConfig:
        return self.config

    def __setstate__(self, config: PHDConfig) -> None:
        self.__init__(config)  # type: ignore[misc]

    def survival(self, table: np.ndarray) -> np.ndarray:
        """``P_s`` per component (seed eq. 10 or constant), shape (N,), of a ``(6, N)`` table."""
        cfg = self.config
        if cfg.survival_model == "constant":
            return np.full(table.shape[1:], cfg.survival_probability)
        return inverse_sigmoid(
            np.hypot(table[ROW_X], table[ROW_Y]),
            cfg.survival_offset,
            cfg.survival_slope_per_m,
            cfg.survival_range_m,
        )

    def lidar(self, table: np.ndarray, null_bearings_rad: np.ndarray | None) -> np.ndarray:
        """Lidar ``P_d`` per component (seed eq. 18 or constant), in ``[0, 1]``.

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
        if cfg.lidar_pd_model == "constant":
            return self.lidar_range_factor(np.hypot(table[ROW_X], table[ROW_Y]))
        ranges, units = unit_bearings(table[ROW_X : ROW_Y + 1], cfg.min_range_m)
        pd = self.lidar_range_factor(ranges)
        if self._sector_dirs.shape[0]:
            pd *= blind_sector_factor(
                units, self._sector_dirs, self._sector_inv_var, self._sector_scaled
            )
        if table.shape[1] > 1:
            pd *= occlusion_factor(
                units,
                ranges,
                table[ROW_W],
                self._occlusion_inv_var,
                cfg.occlusion_min_separation_m,
            )
        if null_bearings_rad is not None and null_bearings_rad.shape[0]:
            pd *= interference_factor(
                units, null_bearings_rad, self._interference_inv_var, cfg.interference_depth
            )
        # Every factor is in [0, 1] by construction, so the product needs no final clip.
        return pd

    def lidar_range_factor(self, ranges_m: np.ndarray) -> np.ndarray:
        """The range part of :meth:`lidar`'s ``P_d`` at ``ranges_m`` (N,) (m), shape (N,): seed
        eq. 19's sigmoid, or the constant model's ``P_d`` within ``lidar_range_m`` (0 beyond)."""
        cfg = self.config
        ranges_m = np.asarray(ranges_m, dtype=float)
        if cfg.lidar_pd_model == "constant":
            return (ranges_m <= cfg.lidar_range_m) * cfg.lidar_detection_probability
        return inverse_sigmoid(
            ranges_m, cfg.lidar_pd_offset, cfg.lidar_pd_slope_per_m, cfg.lidar_pd_midpoint_m
        )

    def lidar_blind_sector_factor(self, bearings_rad: np.ndarray) -> np.ndarray:
        """The blind-sector part of :meth:`lidar`'s ``P_d`` at body-frame ``bearings_rad``
        (N,), shape (N,): 0 at a sector's centre, 1 in the lidar's view. The constant model
        has no sectors (1 everywhere), as in :meth:`lidar`."""
        bearings_rad = np.asarray(bearings_rad, dtype=float)
        if self.config.lidar_pd_model == "constant" or not self._sector_dirs.shape[0]:
            return np.ones(bearings_rad.shape)
        units = np.stack((np.cos(bearings_rad), np.sin(bearings_rad)))
        return blind_sector_factor(
            units, self._sector_dirs, self._sector_inv_var, self._sector_scaled
        )

    def camera(self, table: np.ndarray) -> np.ndarray:
        """Camera ``P_d`` per component (seed eqs. 29-30), in ``[0, 1]``.

        ``table`` is ``(6, N)``; the result has shape ``(N,)``. Components closer than
        ``min_range_m`` get 0: their bearing is undefined.
        """
        cfg = self.config
        ranges, units = unit_bearings(table[ROW_X : ROW_Y + 1], cfg.min_range_m)
        pd = inverse_sigmoid(
            ranges, cfg.camera_pd_offset, cfg.camera_pd_slope_per_m, cfg.camera_pd_midpoint_m
        )
        pd *= ranges >= cfg.min_range_m
        if table.shape[-1] > 1:
            pd *= occlusion_factor(
                units,
                ranges,
                table[ROW_W],
                self._occlusion_inv_var,
                cfg.occlusion_min_separation_m,
            )
        return pd
