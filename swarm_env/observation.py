"""Observation encoders: what each agent sees, as one flat float32 vector.

Layout (``observation="phd"`` and ``"truth"``)::

    [ K rows x (w, x_m, y_m, sxx_m2, sxy_m2, syy_m2, valid) | v_mps, omega_radps | task features ]

- ``phd``: the agent's own PHD components, largest weight first (``w`` = component weight).
- ``truth``: the true neighbours within ``localization_range_m``, nearest first, ``w = 1`` and zero
  covariance (the upper bound a perfect localizer would give).

Layout (``observation="measurements"``)::

    [ K rows x (x_m, y_m, valid) lidar detections of the last scan, nearest first
    | K rows x (cos b, sin b, valid) camera bearings of the last frame
    | v_mps, omega_radps | task features ]

Positions are in the agent's body frame (REP-103). Unused rows are zeros. Every entry is clipped to
the observation space's bounds so that ``space.contains(obs)`` always holds.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

PHD_COLUMNS = ("w", "x_m", "y_m", "sxx_m2", "sxy_m2", "syy_m2", "valid")
MAX_POSITION_M = 20.0
MAX_WEIGHT = 10.0
MAX_VARIANCE_M2 = 25.0


def table_bounds(top_k: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the K x 7 neighbour table, flattened."""
    low = np.array([0.0, -MAX_POSITION_M, -MAX_POSITION_M, 0.0, -MAX_VARIANCE_M2, 0.0, 0.0])
    high = np.array(
        [
            MAX_WEIGHT,
            MAX_POSITION_M,
            MAX_POSITION_M,
            MAX_VARIANCE_M2,
            MAX_VARIANCE_M2,
            MAX_VARIANCE_M2,
            1.0,
        ]
    )
    return np.tile(low, top_k), np.tile(high, top_k)


def measurement_bounds(top_k: int) -> tuple[np.ndarray, np.ndarray]:
    lidar_low = np.tile([-MAX_POSITION_M, -MAX_POSITION_M, 0.0], top_k)
    lidar_high = np.tile([MAX_POSITION_M, MAX_POSITION_M, 1.0], top_k)
    cam_low, cam_high = np.tile([-1.0, -1.0, 0.0], top_k), np.tile([1.0, 1.0, 1.0], top_k)
    return np.r_[lidar_low, cam_low], np.r_[lidar_high, cam_high]


def build_space(
    mode: str,
    top_k: int,
    max_speed_mps: float,
    max_turn_rate_radps: float,
    feature_low: np.ndarray,
    feature_high: np.ndarray,
) -> spaces.Box:
    """The observation space shared by all agents."""
    low, high = table_bounds(top_k) if mode != "measurements" else measurement_bounds(top_k)
    low = np.concatenate([low, [-max_speed_mps, -max_turn_rate_radps], feature_low])
    high = np.concatenate([high, [max_speed_mps, max_turn_rate_radps], feature_high])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def phd_table(weights: np.ndarray, means: np.ndarray, covs: np.ndarray, top_k: int) -> np.ndarray:
    """Top-K components by weight as rows ``[w, x, y, sxx, sxy, syy, 1]``, zero-padded, (K, 7)."""
    table = np.zeros((top_k, 7))
    order = np.argsort(-weights, kind="stable")[:top_k]
    n = order.size
    table[:n, 0] = weights[order]
    table[:n, 1:3] = means[order]
    table[:n, 3] = covs[order, 0, 0]
    table[:n, 4] = covs[order, 0, 1]
    table[:n, 5] = covs[order, 1, 1]
    table[:n, 6] = 1.0
    return table


def phd_tables(tables: np.ndarray, counts: np.ndarray, top_k: int) -> np.ndarray:
    """:func:`phd_table` for R robots at once, from padded component tables.

    Parameters
    ----------
    tables : ndarray, shape (6, R, N)
        Rows ``w, x, y, pxx, pxy, pyy``; robot r's columns past ``counts[r]`` are padding.
    counts : ndarray, shape (R,)

    Returns
    -------
    ndarray, shape (R, top_k, 7)
        Same rows and order as :func:`phd_table` gives robot by robot.
    """
    n_robots, width = tables.shape[1], tables.shape[2]
    valid = np.arange(width)[None, :] < counts[:, None]
    # Padding sorts last; a stable sort keeps equal weights in table order, as phd_table does.
    keys = np.where(valid, -tables[0], np.inf)
    order = np.argsort(keys, axis=1, kind="stable")[:, :top_k]
    rows = np.take_along_axis(tables, order[None], axis=2)  # (6, R, k)
    kept = np.take_along_axis(valid, order, axis=1)
    out = np.zeros((n_robots, top_k, 7))
    k = order.shape[1]
    out[:, :k, :6] = np.where(kept[None], rows, 0.0).transpose(1, 2, 0)
    out[:, :k, 6] = kept
    return out


def truth_table(neighbours_xy: np.ndarray, top_k: int) -> np.ndarray:
    """True neighbours (M, 2), nearest first, as rows ``[1, x, y, 0, 0, 0, 1]``, (K, 7)."""
    table = np.zeros((top_k, 7))
    order = np.argsort(np.hypot(neighbours_xy[:, 0], neighbours_xy[:, 1]), kind="stable")[:top_k]
    n = order.size
    table[:n, 0] = 1.0
    table[:n, 1:3] = neighbours_xy[order]
    table[:n, 6] = 1.0
    return table


def measurement_table(detections: np.ndarray, bearings: np.ndarray, top_k: int) -> np.ndarray:
    """Lidar detections (M, 2) nearest first and camera bearings (B,), padded, (2K*3,)."""
    lidar = np.zeros((top_k, 3))
    order = np.argsort(np.hypot(detections[:, 0], detections[:, 1]), kind="stable")[:top_k]
    lidar[: order.size, 0:2] = detections[order]
    lidar[: order.size, 2] = 1.0
    cam = np.zeros((top_k, 3))
    b = np.sort(bearings)[:top_k]
    cam[: b.size, 0], cam[: b.size, 1], cam[: b.size, 2] = np.cos(b), np.sin(b), 1.0
    return np.concatenate([lidar.ravel(), cam.ravel()])


def assemble(
    space: spaces.Box, table: np.ndarray, velocity: np.ndarray, features: np.ndarray
) -> np.ndarray:
    """Concatenate and clip into ``space``; returns float32 of ``space.shape``."""
    obs = np.concatenate([table.ravel(), velocity, features]).astype(np.float32)
    return np.minimum(np.maximum(obs, space.low, out=obs), space.high, out=obs)
