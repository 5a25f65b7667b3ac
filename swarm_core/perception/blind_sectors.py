"""Lidar beams hidden by the camera pillars (Perera 2021's four blind sectors, eq. 20)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from swarm_core.geometry import wrap_angle


class BlindSectors(Protocol):
    """Anything that names blind sectors: ``LidarConfig``, ``PHDConfig``, ..."""

    blind_sector_centers_deg: tuple[float, ...]
    blind_sector_widths_deg: tuple[float, ...]


def blind_mask(angles_rad: np.ndarray, sectors: BlindSectors) -> np.ndarray:
    """Beams inside the blind sectors of ``sectors``, shape like ``angles_rad`` (bool).

    A beam is blind when its bearing is within half a width of a sector centre (edges
    included). Shared by the simulator and the hardware bridge, so a beam's side of a sector
    edge is the same everywhere: their null returns are not interference (the filter has a
    blind-sector factor instead).

    Parameters
    ----------
    angles_rad : ndarray, any shape
        Beam bearings in the robot frame, rad.
    sectors : object with ``blind_sector_centers_deg`` and ``blind_sector_widths_deg``
    """
    centers = np.deg2rad(np.asarray(sectors.blind_sector_centers_deg, dtype=np.float64))
    half = 0.5 * np.deg2rad(np.asarray(sectors.blind_sector_widths_deg, dtype=np.float64))
    if centers.size == 0:
        return np.zeros(np.shape(angles_rad), dtype=bool)
    offset = np.abs(wrap_angle(np.asarray(angles_rad)[..., None] - centers))
    return (offset <= half).any(axis=-1)
