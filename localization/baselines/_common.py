"""Input checks and small helpers shared by the identified-measurement baselines."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from localization.gaussian import wrap_angle
from localization.mixture import GaussianMixture


def checked_vector(value: Any, name: str, size: int) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def checked_id(key: Any, name: str) -> int:
    if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
        raise ValueError(f"{name} keys must be robot IDs >= 0, got {key!r}")
    return int(key)


def checked_odometry(
    own_odometry: Any, teammate_odometry: dict | None
) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    own = checked_vector(own_odometry, "own_odometry", 3)
    team = {}
    for key, value in (teammate_odometry or {}).items():
        team[checked_id(key, "teammate_odometry")] = checked_vector(
            value, f"teammate_odometry[{key}]", 3
        )
    return own, team


def checked_range_bearing(measurements: dict | None) -> dict[int, np.ndarray]:
    """``{id: (range_m, bearing_rad)}``, validated (range >= 0, both finite)."""
    out = {}
    for key, value in (measurements or {}).items():
        ident = checked_id(key, "measurements")
        rb = checked_vector(value, f"measurements[{key}]", 2)
        if rb[0] < 0:
            raise ValueError(f"measurements[{key}] range must be >= 0 m, got {rb[0]!r}")
        out[ident] = rb
    return out


def frame_change(xy: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Points ``(..., 2)`` fixed in the world, seen after the observer moves by ``own``:
    ``R(dpsi)^T (p - d)``."""
    c, s = math.cos(own[2]), math.sin(own[2])
    d = xy - own[:2]
    return np.stack((c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]), axis=-1)


def compose_poses(means: np.ndarray, teammate: np.ndarray, own: np.ndarray) -> np.ndarray:
    """Mean part of :func:`localization.id_phd.compose_relative` for ``(..., 3)`` poses and
    per-pose teammate increments ``(..., 3)`` (broadcast)."""
    psi = means[..., 2]
    c, s = np.cos(psi), np.sin(psi)
    rd = np.stack(
        (c * teammate[..., 0] - s * teammate[..., 1], s * teammate[..., 0] + c * teammate[..., 1]),
        axis=-1,
    )
    out = np.empty(np.broadcast_shapes(means.shape, teammate.shape))
    out[..., :2] = frame_change(means[..., :2] + rd, own)
    out[..., 2] = wrap_angle(psi + teammate[..., 2] - own[2])
    return out


def track_mixture(positions: np.ndarray, covs: np.ndarray) -> GaussianMixture:
    """One unit-weight component per tracked teammate (read-only snapshot)."""
    n = positions.shape[0]
    return GaussianMixture(np.ones(n), positions.reshape(n, 2), covs.reshape(n, 2, 2))


def extract(mixture: GaussianMixture, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    keep = mixture.weights >= threshold
    return mixture.means[keep].copy(), mixture.weights[keep].copy()
