"""Vectorised planar geometry shared by the sensor models.

Everything here is pure numpy on stacked arrays: no Python loop over rays, shapes or robots.
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
    pair_origin: np.ndarray,
    pair_target: np.ndarray,
    segment_a: np.ndarray,
    segment_b: np.ndarray,
    circle_xy: np.ndarray,
    circle_radius_m: np.ndarray,
    circle_applies: np.ndarray | None = None,
) -> np.ndarray:
    """Whether sight lines ``origins_xy[pair_origin] -> targets_xy[pair_target]`` are blocked.

    A line is blocked when it properly crosses a segment, or passes closer than a circle's
    radius to its centre (closest point of the line *segment*). All (line, shape) tests are
    evaluated at once. Terms that depend on one end only are computed on the small (K, shapes)
    and (T, shapes) grids and gathered; the bilinear terms are (P, 2) x (2, shapes) products.

    Parameters
    ----------
    origins_xy : ndarray, shape (K, 2)
    targets_xy : ndarray, shape (T, 2)
    pair_origin, pair_target : ndarray, shape (P,), int
        The P lines to test, as indices into ``origins_xy`` and ``targets_xy``.
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
    blocked = np.zeros(pair_origin.shape[0], dtype=bool)
    if not pair_origin.shape[0]:
        return blocked
    o = origins_xy[pair_origin]
    d = targets_xy[pair_target] - o  # (P, 2) line vectors
    if segment_a.shape[0]:
        blocked |= _lines_cross_segments(
            origins_xy, targets_xy, pair_origin, pair_target, o, d, segment_a, segment_b
        )
    if circle_xy.shape[0]:
        blocked |= _lines_hit_circles(
            origins_xy, pair_origin, o, d, circle_xy, circle_radius_m, circle_applies
        )
    return blocked


# The two tests below work in (shapes, P) layout: per-line terms broadcast along the contiguous
# axis and the final reduction runs over axis 0, both several times faster than (P, shapes).


def _lines_cross_segments(origins, targets, pair_o, pair_t, o, d, a, b) -> np.ndarray:
    """Proper crossings of P lines and S segments: (P,) any."""
    # The line's end points strictly on opposite sides of the segment: cross(e, p - a).
    e_perp = np.stack((a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]), axis=1)  # cross(e, q) = e_perp.q
    e_cross_a = np.einsum("sj,sj->s", e_perp, a)[:, None]
    side_o = e_perp @ origins.T - e_cross_a  # (S, K)
    side_t = e_perp @ targets.T - e_cross_a  # (S, T)
    # Only segments with some observer and some target on opposite sides can block anything
    # (arena walls never can): test just those.
    pos_o, neg_o = (side_o > 0.0).any(axis=1), (side_o < 0.0).any(axis=1)
    pos_t, neg_t = (side_t > 0.0).any(axis=1), (side_t < 0.0).any(axis=1)
    keep = np.flatnonzero((pos_o & neg_t) | (neg_o & pos_t))
    if not keep.size:
        return np.zeros(pair_o.shape[0], dtype=bool)
    a, b = a[keep], b[keep]
    opposite = side_o[keep][:, pair_o]  # (S', P)
    opposite *= side_t[keep][:, pair_t]
    # ... and the segment's end points strictly on opposite sides of the line:
    # cross(d, q - o) = d_perp.q - d_perp.o, as (S', 2) @ (2, P) products.
    d_perp = np.stack((-d[:, 1], d[:, 0]), axis=0)  # (2, P)
    d_cross_o = np.einsum("jp,pj->p", d_perp, o)[None, :]
    side_a = a @ d_perp
    side_a -= d_cross_o
    side_b = b @ d_perp
    side_b -= d_cross_o
    side_a *= side_b
    crosses = side_a < 0.0
    crosses &= opposite < 0.0
    return crosses.any(axis=0)


def _segment_distance2(w2: np.ndarray, wd: np.ndarray, length2: np.ndarray) -> np.ndarray:
    """Squared distance from a point to the segment ``0 -> d``, from ``|w|^2``, ``w.d`` and
    ``|d|^2`` (``w``: the point relative to the segment's start; arrays broadcast).

    Closest point ``s d`` with ``s = clip(w.d / |d|^2, 0, 1)``;
    ``|w - s d|^2 = |w|^2 + s (s |d|^2 - 2 w.d)``. Overwrites ``w2`` and ``wd``.
    """
    s = wd / np.where(length2 > 0.0, length2, 1.0)
    np.clip(s, 0.0, 1.0, out=s)
    wd *= -2.0
    wd += s * length2
    wd *= s
    w2 += wd
    return w2


def _lines_hit_circles(origins, pair_o, o, d, centre, radius, applies) -> np.ndarray:
    """P lines passing closer than ``radius`` to C circle centres: (P,) any."""
    # w = c - o: |w|^2 depends on the observer only; w.d = c.d - o.d.
    w = centre[:, None, :] - origins[None, :, :]  # (C, K, 2)
    w2 = np.einsum("ckj,ckj->ck", w, w)[:, pair_o]  # (C, P)
    wd = centre @ d.T  # (C, P)
    wd -= np.einsum("pj,pj->p", d, o)[None, :]
    length2 = np.einsum("pj,pj->p", d, d)[None, :]
    hits = _segment_distance2(w2, wd, length2) < (radius * radius)[:, None]
    if applies is not None:
        hits &= applies.T
    return hits.any(axis=0)


def lines_hit_own_circles(
    vectors_xy: np.ndarray,
    centres_x: np.ndarray,
    centres_y: np.ndarray,
    radii2_m2: np.ndarray,
    applies: np.ndarray,
) -> np.ndarray:
    """P line segments ``0 -> d``, each against its own n circles: (P,) any hit.

    Coordinates are relative to each line's origin.

    Parameters
    ----------
    vectors_xy : ndarray, shape (P, 2)
        Line vectors ``d`` (origin to end point), metres.
    centres_x, centres_y : ndarray, shape (P, n)
        The circles line p is tested against (e.g. the robots at line p's own instant),
        relative to its origin. float32 is enough (and what makes it fast).
    radii2_m2 : ndarray, shape (P, n)
        Squared radii.
    applies : ndarray, shape (P, n), bool
        Which of them may block line p.

    Returns
    -------
    ndarray, shape (P,), bool
        The line passes closer than a radius to a circle centre (closest point of the segment).
    """
    # Component-wise arithmetic (einsum is slow for a length-2 contraction) in the dtype of the
    # centres: the (P, n) temporaries are the cost.
    dtype = centres_x.dtype
    dx = vectors_xy[:, 0:1].astype(dtype)
    dy = vectors_xy[:, 1:2].astype(dtype)
    wd = centres_x * dx
    wd += centres_y * dy
    w2 = np.square(centres_x)
    w2 += np.square(centres_y)
    hit = _segment_distance2(w2, wd, dx * dx + dy * dy) < radii2_m2
    hit &= applies
    return hit.any(axis=1)
