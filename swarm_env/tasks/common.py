"""Geometry and parameter checks shared by the tasks (pure numpy, no env state)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_core.validation import check_number

if TYPE_CHECKING:
    from swarm_env.world.arena import Layout


def check_param(
    task: str, name: str, value: Any, low: float, high: float, *, low_open: bool = False
) -> float:
    """``value`` as a float in ``[low, high]`` (``(low, high]`` with ``low_open``), else a
    ``ValueError`` naming the task and the parameter."""
    check_number(f"task {task!r}: {name}", value, low=low, high=high, above=low_open)
    return float(value)


def check_choice(task: str, name: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"task {task!r}: {name} must be one of {choices}, got {value!r}")
    return value


def pairwise_distances(xy: np.ndarray) -> np.ndarray:
    """Distances between all points, shape (N, N), ``inf`` on the diagonal."""
    d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d


def obstacle_distances(xy: np.ndarray, layout: Layout, arena: Any) -> np.ndarray:
    """Signed distance from every point to the surface of every obstacle of ``layout``.

    Parameters
    ----------
    xy : ndarray, shape (N, 2)
        World positions, metres.
    layout : Layout
        The episode's obstacles (``SimWorld.layout``): boxes ``[cx, cy, size_x, size_y, yaw]``
        (rectangles rotated by ``yaw``), decoy posts and red decoys (circles).
    arena : ArenaConfig
        For the circle radii (``decoy_post_radius_m``, ``red_decoy_radius_m``), which the layout
        does not store.

    Returns
    -------
    ndarray, shape (N, B + P + D)
        Metres, negative inside an obstacle; columns are the boxes, then the posts, then the red
        decoys, in layout order.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    boxes = layout.boxes
    # Boxes: each point in each box's own frame (rotate by -yaw), then the rectangle's signed
    # distance: outside, the distance to the nearest point of the rectangle; inside, minus the
    # distance to the nearest side.
    d = xy[:, None, :] - boxes[None, :, 0:2]  # (N, B, 2)
    c, s = np.cos(boxes[:, 4]), np.sin(boxes[:, 4])
    local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
    q = np.abs(local) - 0.5 * boxes[None, :, 2:4]
    box_d = np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
    # Circles: centre distance minus radius.
    centres = np.concatenate([layout.posts_xy, layout.red_decoys_xy]).reshape(-1, 2)
    radii = np.concatenate(
        [
            np.full(len(layout.posts_xy), arena.decoy_post_radius_m),
            np.full(len(layout.red_decoys_xy), arena.red_decoy_radius_m),
        ]
    )
    circle_d = np.linalg.norm(xy[:, None, :] - centres[None, :, :], axis=-1) - radii[None, :]
    return np.concatenate([box_d, circle_d], axis=1)


def collisions(
    xy: np.ndarray,
    min_distance_m: float,
    arena: Any | None = None,
    wall_margin_m: float = 0.0,
    layout: Layout | None = None,
) -> np.ndarray:
    """Per robot: touching another robot, a wall or an obstacle. Shape (N,) bool.

    A robot collides when its centre is closer than ``min_distance_m`` to another robot's centre,
    or closer than ``wall_margin_m`` to a wall of ``arena`` (an ``ArenaConfig``) or, given the
    episode's ``layout``, to the surface of a box, decoy post or red decoy (see
    :func:`obstacle_distances`). Walls and obstacles share the margin: both are rigid surfaces
    the chassis stops against, so the same centre distance means the same contact.
    """
    hit = (
        (pairwise_distances(xy) < min_distance_m).any(axis=1)
        if len(xy) > 1
        else np.zeros(len(xy), dtype=bool)
    )
    if arena is not None and wall_margin_m > 0:
        hx, hy = 0.5 * arena.width_m, 0.5 * arena.height_m
        hit |= (np.abs(xy[:, 0]) > hx - wall_margin_m) | (np.abs(xy[:, 1]) > hy - wall_margin_m)
        if layout is not None:
            hit |= (obstacle_distances(xy, layout, arena) < wall_margin_m).any(axis=1)
    return hit


#: Sensors whose joint detection of a teammate localizes it well: the lidar gives its range, the
#: camera its bearing (and the red-strip identity of a robot rather than an obstacle).
LOCALIZING_SENSORS = ("lidar", "camera")


def unseen_fraction(truth: Any, sensors: tuple[str, ...] = LOCALIZING_SENSORS) -> np.ndarray:
    """Per robot i: the fraction of its N - 1 teammates that not every sensor in ``sensors``
    detected at that sensor's last tick, shape (N,), in [0, 1] (0 for a lone robot).

    Detection is the simulator's ``truth.visible[sensor][i, j]`` (in range, line of sight,
    outside blind sectors, not interfered); a World that reports no ``visible`` mask for a sensor
    (motion capture) falls back to its nominal ``in_range`` mask. A robot's filter can only keep
    an accurate estimate of a teammate it measures, and the range-bearing pair of lidar and
    camera pins it down best, so this is the localization term of the tasks
    (``localization_weight``)::

        r_i -= localization_weight * unseen_fraction(truth)[i]
    """
    n = len(truth.poses)
    if n < 2:
        return np.zeros(n)
    seen = ~np.eye(n, dtype=bool)
    for name in sensors:
        mask = truth.visible.get(name)
        if mask is None:
            mask = truth.in_range.get(name)
        if mask is None:
            raise ValueError(f"ground truth has no visibility or range mask for sensor {name!r}")
        seen &= np.asarray(mask, dtype=bool)[:, :n]
    return 1.0 - seen.sum(axis=1) / (n - 1)


def max_angular_gap(center: np.ndarray, xy: np.ndarray) -> float:
    """Largest angle (rad) between consecutive directions from ``center`` to the points.

    ``2 pi`` for zero or one point. The center lies strictly inside the points' convex hull iff
    this gap is below ``pi`` (the points "enclose" it).
    """
    if len(xy) < 2:
        return 2 * math.pi
    angles = np.sort(np.arctan2(xy[:, 1] - center[1], xy[:, 0] - center[0]))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * math.pi])
    return float(gaps.max())
