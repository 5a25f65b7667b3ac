"""Scalar numba helpers shared by the compiled sensor kernels.

Every kernel is ``@njit(cache=True)``: compiled on first use and cached in ``__pycache__``, so
only the very first process pays the compile time. Helpers here are inlined into their callers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

PI = math.pi
TWO_PI = 2.0 * math.pi


@njit(cache=True, inline="always")
def wrap(angle_rad: float) -> float:
    """Wrap one angle to ``[-pi, pi)`` (as :func:`geometry.wrap_angle`, to rounding)."""
    # floor() instead of the float modulo: an instruction, not a libm fmod call.
    w = angle_rad - TWO_PI * math.floor((angle_rad + PI) * (1.0 / TWO_PI))
    # Rounding can land a hair outside the half-open interval.
    if w >= PI:
        w -= TWO_PI
    elif w < -PI:
        w += TWO_PI
    return w


@njit(cache=True, inline="always")
def segment_distance2(wx: float, wy: float, dx: float, dy: float) -> float:
    """Squared distance from the point ``w`` to the segment ``0 -> d`` (metres^2)."""
    length2 = dx * dx + dy * dy
    wd = wx * dx + wy * dy
    s = wd / length2 if length2 > 0.0 else wd
    if s < 0.0:
        s = 0.0
    elif s > 1.0:
        s = 1.0
    ex = wx - s * dx
    ey = wy - s * dy
    return ex * ex + ey * ey


@njit(cache=True)
def stable_order(keys):
    """Indices that sort the float64 ``keys`` (n,) ascending, equal keys in input order.

    Insertion sort: the kernels sort a handful of items at a time (a frame's bearings, a
    robot's detections), where it is fastest, and it compiles far quicker than ``np.argsort``.
    """
    n = keys.shape[0]
    order = np.arange(n)
    for i in range(1, n):
        j = i
        item = order[i]
        while j > 0 and keys[order[j - 1]] > keys[item]:
            order[j] = order[j - 1]
            j -= 1
        order[j] = item
    return order
