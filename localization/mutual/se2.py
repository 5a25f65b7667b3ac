"""Planar pose algebra of the Stegagno 2012 thesis (chapter 2), vectorised over leading axes.

A pose ``x = (z, theta)`` is ``[x_m, y_m, theta_rad]`` (REP-103: yaw counter-clockwise). With
``R(phi)`` the rotation by ``phi``::

    x_a (+) x_b = (z_a + R(theta_a) z_b, theta_a + theta_b)       # compose
    x_a (-) x_b = (R(-theta_b) (z_a - z_b), theta_a - theta_b)     # x_a seen from frame x_b

``(-)`` is the thesis's *inverse composition*: ``x_b (+) (x_a (-) x_b) = x_a``. The same
operators act on points (``(..., 2)``): ``x (+) z`` maps a point from frame ``x`` to the outer
frame, ``z (-) x`` maps it into frame ``x``.
"""

from __future__ import annotations

import numpy as np

from swarm_core.geometry import integrate_body_delta, wrap_angle

__all__ = ["compose", "inverse_compose", "points_from_frame", "points_to_frame", "rotation"]


def rotation(phi: np.ndarray | float) -> np.ndarray:
    """``R(phi)``, shape ``phi.shape + (2, 2)``."""
    phi = np.asarray(phi, dtype=np.float64)
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a (+) b`` for poses ``(..., 3)`` (broadcast), angle wrapped to ``[-pi, pi)``.

    The same map as dead reckoning a body-frame increment ``b`` from pose ``a``."""
    return integrate_body_delta(a, b)


def inverse_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a (-) b``: pose ``a`` expressed in frame ``b`` (both ``(..., 3)``, broadcast)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(b[..., 2]), np.sin(b[..., 2])
    dx, dy = a[..., 0] - b[..., 0], a[..., 1] - b[..., 1]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    out[..., 2] = wrap_angle(a[..., 2] - b[..., 2])
    return out


def points_from_frame(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``x (+) z``: points ``z`` (..., K, 2) given in frame ``x`` (..., 3), in the outer frame."""
    x = np.asarray(x, dtype=np.float64)
    rot = rotation(x[..., 2])  # (..., 2, 2)
    return np.einsum("...ij,...kj->...ki", rot, np.asarray(z, dtype=np.float64)) + x[..., None, :2]


def points_to_frame(z: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``z (-) x``: points ``z`` (..., K, 2) of the outer frame, expressed in frame ``x``."""
    x = np.asarray(x, dtype=np.float64)
    rot = rotation(x[..., 2])
    d = np.asarray(z, dtype=np.float64) - x[..., None, :2]
    return np.einsum("...ji,...kj->...ki", rot, d)
