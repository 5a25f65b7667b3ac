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


def integrate_body_delta(poses: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Dead reckoning: poses after body-frame increments.

    Parameters
    ----------
    poses : ndarray, shape (..., 3)
        ``[x_m, y_m, yaw_rad]`` in some fixed frame (e.g. the odometry frame of the robot's start).
    deltas : ndarray, shape (..., 3)
        ``[dx_m, dy_m, dpsi_rad]`` in the body frame at the start of each increment (the
        :class:`~swarm_core.records.OdometryRecord` convention).

    Returns
    -------
    ndarray, shape (..., 3)
        The new poses, yaw wrapped to ``[-pi, pi)``.
    """
    poses = np.asarray(poses, dtype=np.float64)
    deltas = np.asarray(deltas, dtype=np.float64)
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    out = np.empty(np.broadcast_shapes(poses.shape, deltas.shape))
    out[..., 0] = poses[..., 0] + c * deltas[..., 0] - s * deltas[..., 1]
    out[..., 1] = poses[..., 1] + s * deltas[..., 0] + c * deltas[..., 1]
    out[..., 2] = wrap_angle(poses[..., 2] + deltas[..., 2])
    return out
