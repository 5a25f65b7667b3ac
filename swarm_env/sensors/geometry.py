"""Vectorised planar geometry shared by the sensor models.

Everything here is pure numpy on stacked arrays: no Python loop over rays, shapes or robots.
Rays start at the origin of the frame they are expressed in (the sensor models first move the
shapes into the sensor's body frame, so one precomputed table of beam directions serves every
scan). Misses are reported as ``+inf`` distances so results reduce with ``np.minimum``.
"""

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


def to_body_frame(
    points_xy: np.ndarray, origin_xy: np.ndarray, yaw_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Express world points in several body frames at once.

    Parameters
    ----------
    points_xy : ndarray, shape (P, 2)
        World points, metres.
    origin_xy : ndarray, shape (K, 2)
        Frame origins, metres.
    yaw_rad : ndarray, shape (K,)
        Frame headings, rad.

    Returns
    -------
    x, y : ndarray, shape (K, P)
        ``R(yaw_k)^T (p - o_k)`` for every frame k and point p.
    """
    dx = points_xy[None, :, 0] - origin_xy[:, None, 0]
    dy = points_xy[None, :, 1] - origin_xy[:, None, 1]
    c = np.cos(yaw_rad)[:, None]
    s = np.sin(yaw_rad)[:, None]
    return c * dx + s * dy, c * dy - s * dx


def expand_intervals(start: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Expand integer intervals ``[start_i, start_i + count_i)`` into flat index lists.

    Parameters
    ----------
    start : ndarray, shape (P,), int
    count : ndarray, shape (P,), int, >= 0

    Returns
    -------
    owner : ndarray, shape (sum(count),), int
        Which interval each element came from.
    value : ndarray, shape (sum(count),), int
        ``start[owner] + position within the interval``.
    """
    count = np.maximum(count, 0)
    total = int(count.sum())
    owner = np.repeat(np.arange(count.size), count)
    first = np.cumsum(count) - count
    value = np.arange(total) - first[owner] + start[owner]
    return owner, value


def ray_circle_distance(
    ux: np.ndarray, uy: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Distance from the origin along unit rays to the first crossing of circles.

    Parameters
    ----------
    ux, uy : ndarray, shape (E,)
        Unit ray directions.
    cx, cy, radius : ndarray, shape (E,)
        Circle centres and radii in the same frame, metres.

    Returns
    -------
    ndarray, shape (E,)
        Distance ``t > 0`` to the near intersection, ``inf`` for a miss (including a ray
        starting inside its circle: a sensor never sees the inside of a shape).
    """
    t_closest = ux * cx + uy * cy
    disc = radius * radius - (cx * cx + cy * cy - t_closest * t_closest)
    t = t_closest - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0.0) & (t > 0.0), t, np.inf)


def ray_segment_distance(
    ux: np.ndarray,
    uy: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    bx: np.ndarray,
    by: np.ndarray,
) -> np.ndarray:
    """Distance from the origin along unit rays to segments ``a -> b``.

    Solves ``t u = a + s (b - a)`` with ``t > 0``, ``0 <= s <= 1``; parallel rays miss.

    Parameters
    ----------
    ux, uy : ndarray, shape (E,)
        Unit ray directions.
    ax, ay, bx, by : ndarray, shape (E,)
        Segment end points in the same frame, metres.

    Returns
    -------
    ndarray, shape (E,)
        Distance to the hit, ``inf`` for a miss.
    """
    ex = bx - ax
    ey = by - ay
    denom = ux * ey - uy * ex
    safe = np.where(denom == 0.0, 1.0, denom)
    t = (ax * ey - ay * ex) / safe
    s = (ax * uy - ay * ux) / safe
    hit = (denom != 0.0) & (s >= 0.0) & (s <= 1.0) & (t > 0.0)
    return np.where(hit, t, np.inf)


def point_segment_distance(
    px: np.ndarray, py: np.ndarray, ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray
) -> np.ndarray:
    """Euclidean distance from points to segments (broadcasting).

    Parameters
    ----------
    px, py : ndarray
        Points, metres.
    ax, ay, bx, by : ndarray
        Segment end points, metres, broadcastable against the points.

    Returns
    -------
    ndarray
        Broadcast shape, metres.
    """
    ex = bx - ax
    ey = by - ay
    length2 = ex * ex + ey * ey
    s = ((px - ax) * ex + (py - ay) * ey) / np.where(length2 > 0.0, length2, 1.0)
    s = np.clip(s, 0.0, 1.0)
    return np.hypot(px - ax - s * ex, py - ay - s * ey)


def sight_lines_blocked(
    origins_xy: np.ndarray,
    targets_xy: np.ndarray,
    segment_a: np.ndarray,
    segment_b: np.ndarray,
    circle_xy: np.ndarray,
    circle_radius_m: np.ndarray,
    circle_applies: np.ndarray | None = None,
) -> np.ndarray:
    """Whether each straight sight line ``origin_p -> target_p`` is blocked.

    A line is blocked when it properly crosses a segment, or passes closer than a circle's
    radius to its centre. Every (line, shape) test is evaluated at once; the bilinear terms are
    written as (P, 2) x (2, shapes) matrix products, so the work is a few GEMMs plus a handful
    of elementwise passes over (P, shapes) arrays.

    Parameters
    ----------
    origins_xy, targets_xy : ndarray, shape (P, 2)
        Line end points, metres (e.g. observer and target centres of P pairs).
    segment_a, segment_b : ndarray, shape (S, 2)
    circle_xy : ndarray, shape (C, 2)
    circle_radius_m : ndarray, shape (C,)
    circle_applies : ndarray, shape (P, C), bool, optional
        Which circles may block which line (e.g. not the observer's or the target's own).
        Default: all.

    Returns
    -------
    ndarray, shape (P,), bool
    """
    blocked = np.zeros(origins_xy.shape[0], dtype=bool)
    if not origins_xy.shape[0]:
        return blocked
    if segment_a.shape[0]:
        blocked |= _lines_cross_segments(origins_xy, targets_xy, segment_a, segment_b)
    if circle_xy.shape[0]:
        blocked |= _lines_hit_circles(
            origins_xy, targets_xy, circle_xy, circle_radius_m, circle_applies
        )
    return blocked


def _lines_cross_segments(
    o: np.ndarray, t: np.ndarray, a: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """Proper crossings of lines ``o -> t`` (P) and segments ``a -> b`` (S): (P,) any."""
    d = t - o  # (P, 2)
    e = b - a  # (S, 2)
    # Both end points of the segment strictly on opposite sides of the line:
    # cross(d, a - o) = d x a - d x o, a (P, 2) @ (2, S) product minus a per-line constant.
    d_perp = np.stack((-d[:, 1], d[:, 0]), axis=1)  # d x q = d_perp . q
    d_cross_o = np.einsum("pj,pj->p", d_perp, o)[:, None]
    side_a = d_perp @ a.T
    side_a -= d_cross_o
    side_b = d_perp @ b.T
    side_b -= d_cross_o
    side_a *= side_b
    # ... and both end points of the line strictly on opposite sides of the segment.
    e_perp = np.stack((-e[:, 1], e[:, 0]), axis=1)  # (S, 2)
    e_cross_a = np.einsum("sj,sj->s", e_perp, a)[None, :]
    side_o = o @ e_perp.T
    side_o -= e_cross_a
    side_t = t @ e_perp.T
    side_t -= e_cross_a
    side_o *= side_t
    crosses = side_a < 0.0
    crosses &= side_o < 0.0
    return crosses.any(axis=1)


def _lines_hit_circles(
    o: np.ndarray,
    t: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    applies: np.ndarray | None,
) -> np.ndarray:
    """Lines ``o -> t`` (P) passing closer than ``radius`` to circle centres (C): (P,) any."""
    d = t - o
    length2 = np.einsum("pj,pj->p", d, d)[:, None]
    # w = c - o; w.d = d.c - d.o and |w|^2 = |c|^2 - 2 o.c + |o|^2, as (P, C) products.
    wd = d @ centre.T
    wd -= np.einsum("pj,pj->p", d, o)[:, None]
    w2 = o @ centre.T
    w2 *= -2.0
    w2 += np.einsum("cj,cj->c", centre, centre)[None, :]
    w2 += np.einsum("pj,pj->p", o, o)[:, None]
    # Closest point of the line segment: s = clip(w.d / L^2, 0, 1);
    # dist^2 = |w - s d|^2 = |w|^2 + s (s L^2 - 2 w.d).
    s = np.divide(wd, np.where(length2 > 0.0, length2, 1.0))
    np.clip(s, 0.0, 1.0, out=s)
    wd *= -2.0
    wd += s * length2
    wd *= s
    w2 += wd
    hits = w2 < (radius * radius)[None, :]
    if applies is not None:
        hits &= applies
    return hits.any(axis=1)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
