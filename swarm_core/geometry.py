"""Planar geometry shared by the sensor models (numpy; the compiled kernels' scalar helpers are
in :mod:`swarm_env.sensors.kernels`)."""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray:
    """Wrap angles to ``[-pi, pi)``.

    Parameters
    ----------
    angle_rad : array_like
        Angles in radians, any shape.

    Returns
    -------
    ndarray
        Same shape, in ``[-pi, pi)``.
    """
    wrapped = np.mod(np.asarray(angle_rad, dtype=np.float64) + np.pi, TWO_PI) - np.pi
    # np.mod can round a tiny negative input up to exactly 2*pi, which would give +pi.
    return np.where(wrapped >= np.pi, wrapped - TWO_PI, wrapped)
