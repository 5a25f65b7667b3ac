"""Camera blobs that are not teammates, placed by the lidar: objects wider than a housing.

The camera reports every red blob, and some red things are not teammates: in the simulator's
arenas, the 120 mm red decoys. A uniform clutter intensity ``kappa_C`` spreads their blobs over
the whole circle, so at a decoy's bearing it is far too low: a component that sits there (a
shadow behind the decoy, or mass on the decoy itself) is confirmed by every frame, while the
lidar, whose extractor rejects the decoy as too wide for a housing, misses it every scan.

The lidar sees where those blobs come from. The scan shows the decoy as a compact foreground
cluster that the robot test rejects (:func:`swarm_core.perception.lidar_features.
extract_wide_objects`): a **wide object**. Each filter extracts the wide objects of its last
scan once, into its scan memory, and a camera frame's clutter intensity at bearing ``beta``
becomes

``kappa(beta) = kappa_C - share + lambda * sum_o N(beta; beta_o, (f alpha_o)^2 + s0^2)``

with ``beta_o`` the object's bearing from the camera (the scan's pose moves with the odometry,
so a frame taken between two scans is judged from where the camera is), ``alpha_o`` its
angular half-width in the scan, ``s0^2`` the camera's constant bearing variance, ``lambda``
(``PHDConfig.camera.clutter_per_wide_object``) the blobs per frame per wide object that are not
teammates, and ``f`` (``PHDConfig.camera.wide_object_std_fraction``) the spread of those blobs
about the object's centre in half-widths. Both are measured in ``seed-sim``
(``benchmarks/bench_detection_curves.py``): ``lambda = 0.878``, ``f = 0.280``. The uniform part
then no longer counts the decoy blobs the objects explain (67 % of them,
``PHDConfig.camera.clutter_wide_object_share_per_rad``), except before the first scan (or
after a lidar call without one), when the objects are unknown and it is the whole.

A teammate's bearing at a wide object's is rarely lost: in front of the object it hides it from
the lidar (no wide object), behind it is hidden from the camera too, and within the lidar's
range its lidar detections hold it anyway.

The segmentation is the default extractor's (:class:`~swarm_core.perception.lidar_features.
LidarFeatureConfig`), run on the scan profile (bins of the X4's 0.5 deg), up to
:data:`WIDE_OBJECT_MAX_WIDTH_M`. :func:`wide_objects_into` and :func:`clutter_density_into` are
compiled; :func:`wide_objects` and :func:`clutter_density` are their numpy references.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarm_core.perception.lidar_features import (
    LidarFeatureConfig,
    _cluster_kernel,
    cluster_rule,
    extract_wide_objects,
)

from .scan_memory import BIN_WIDTH_RAD, MAX_WIDE_OBJECTS, N_BINS, WIDE_OBJECTS_AT

__all__ = [
    "WIDE_OBJECT_MAX_WIDTH_M",
    "wide_objects",
    "wide_objects_into",
    "clutter_density",
    "clutter_density_into",
    "camera_clutter",
]

#: Widest cluster counted as a wide object, end to end (m): the red decoys' diameter. Measured
#: in ``seed-sim`` by width (``benchmarks/bench_detection_curves.py``, 2026-12-02): clusters up
#: to 0.12 m bring 0.81-0.90 non-teammate blobs per frame and 0.008-0.034 of teammates; wider
#: ones 0.05-0.25 and 0.23-0.34, so that treating them as clutter would take teammates' bearings
#: (tried at 0.3 m: teammates lost on held-out seeds 105 and 107 of ``lab-3m-4``).
WIDE_OBJECT_MAX_WIDTH_M = 0.12
#: The profile's bin centres as beam bearings (:mod:`localization.scan_memory`).
BIN_ANGLES_RAD = -math.pi + BIN_WIDTH_RAD * np.arange(N_BINS)
_BIN_COS = np.cos(BIN_ANGLES_RAD)
_BIN_SIN = np.sin(BIN_ANGLES_RAD)
# The default extractor's rule, as _cluster_kernel's flat arguments (a compile-time constant).
_RULE = cluster_rule(LidarFeatureConfig())
_INV_SQRT_TWO_PI = 1.0 / math.sqrt(2.0 * math.pi)


# ---------------------------------------------------------------------- numpy reference
def wide_objects(profile: np.ndarray, max_width_m: float = WIDE_OBJECT_MAX_WIDTH_M) -> np.ndarray:
    """The wide objects of a scan profile ``(N_BINS,)``: ``(K, 3)`` rows ``[x_m, y_m,
    half_angle_rad]`` in the scanner's frame, by bearing, at most :data:`MAX_WIDE_OBJECTS`
    (the filters use the default ``max_width_m``)."""
    found = extract_wide_objects(
        BIN_ANGLES_RAD, np.asarray(profile, dtype=np.float64), max_width_m=max_width_m
    )
    xy = found.xy_m[:MAX_WIDE_OBJECTS]
    r = np.hypot(xy[:, 0], xy[:, 1])
    half = np.arcsin(np.minimum(0.5 * found.width_m[:MAX_WIDE_OBJECTS] / r, 1.0))
    return np.column_stack([xy, half])


def clutter_density(
    bearings: np.ndarray,
    memory: np.ndarray,
    offset: np.ndarray,
    base: float,
    per_object: float,
    std_fraction: float,
    noise_var: float,
) -> np.ndarray:
    """Camera clutter intensity ``(M,)`` (1/rad) at ``bearings`` (filter frame, rad) seen from
    the camera at ``offset`` ``(2,)`` (m, filter frame), against the wide objects in a scan
    ``memory`` (``kappa(beta)`` of the module docstring; ``base`` = ``kappa_C``)."""
    bearings = np.asarray(bearings, dtype=np.float64)
    out = np.full(bearings.shape[0], float(base))
    count = int(memory[WIDE_OBJECTS_AT])
    if memory[0] == 0.0 or count == 0 or per_object <= 0.0:
        return out
    objects = memory[WIDE_OBJECTS_AT + 1 : WIDE_OBJECTS_AT + 1 + 3 * count].reshape(count, 3)
    c, s = math.cos(memory[3]), math.sin(memory[3])
    x = memory[1] + c * objects[:, 0] - s * objects[:, 1] - offset[0]
    y = memory[2] + s * objects[:, 0] + c * objects[:, 1] - offset[1]
    var = (std_fraction * objects[:, 2]) ** 2 + noise_var
    d = np.angle(np.exp(1j * (bearings[:, None] - np.arctan2(y, x)[None, :])))
    out += per_object * (np.exp(-0.5 * d * d / var) / np.sqrt(2.0 * math.pi * var)).sum(axis=1)
    return out


def camera_clutter(
    config, bearings: np.ndarray, memory: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """A filter's camera clutter intensity ``(M,)`` (1/rad) at ``bearings`` seen from
    ``offset`` (2,): :func:`clutter_density` with ``config``'s (a ``PHDConfig``) uniform part
    and wide objects. Without a scan the objects are unknown, and the uniform part is the
    whole. The numpy reference of ``localization.kernels.camera_clutter``, for both filters."""
    return clutter_density(
        bearings,
        memory,
        offset,
        config.camera_clutter_uniform_per_rad
        if memory[0]
        else config.camera_clutter_total_per_rad,
        config.camera.clutter_per_wide_object,
        config.camera.wide_object_std_fraction,
        config.camera.noise_var_rad2,
    )


# ---------------------------------------------------------------------- compiled
@njit(cache=True)
def wide_objects_into(memory):
    """:func:`wide_objects` of ``memory``'s profile, written into ``memory`` (count, then
    ``[x, y, half_angle]`` rows)."""
    ranges = np.empty((1, N_BINS))
    ranges[0, :] = memory[4 : 4 + N_BINS]
    xy, _, width, _ = _cluster_kernel(ranges, _BIN_COS, _BIN_SIN, *_RULE, WIDE_OBJECT_MAX_WIDTH_M)
    count = min(xy.shape[0], MAX_WIDE_OBJECTS)
    memory[WIDE_OBJECTS_AT] = count
    for o in range(count):
        at = WIDE_OBJECTS_AT + 1 + 3 * o
        r = math.hypot(xy[o, 0], xy[o, 1])
        memory[at] = xy[o, 0]
        memory[at + 1] = xy[o, 1]
        memory[at + 2] = math.asin(min(0.5 * width[o] / r, 1.0))


@njit(cache=True)
def clutter_density_into(out, bearings, memory, ox, oy, per_object, std_fraction, noise_var):
    """Adds the wide objects' part of :func:`clutter_density` to ``out (M,)`` (``base``
    already in it), the camera at ``(ox, oy)``."""
    count = int(memory[WIDE_OBJECTS_AT])
    if memory[0] == 0.0 or count == 0 or per_object <= 0.0:
        return
    c, s = math.cos(memory[3]), math.sin(memory[3])
    for o in range(count):
        at = WIDE_OBJECTS_AT + 1 + 3 * o
        x = memory[1] + c * memory[at] - s * memory[at + 1] - ox
        y = memory[2] + s * memory[at] + c * memory[at + 1] - oy
        centre = math.atan2(y, x)
        spread = std_fraction * memory[at + 2]
        var = spread * spread + noise_var
        peak = per_object * _INV_SQRT_TWO_PI / math.sqrt(var)
        half_inv_var = -0.5 / var
        for h in range(bearings.shape[0]):
            d = bearings[h] - centre
            d = (d + math.pi) % (2.0 * math.pi) - math.pi
            out[h] += peak * math.exp(d * d * half_inv_var)
