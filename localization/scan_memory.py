"""A lidar scan kept as a profile: what the filters remember of their last scan.

The lidar feature extractor turns a scan into robot-like clusters for the filters' updates;
the scan's raw ranges also show the compact objects wider than a housing (mostly red decoys),
where the camera's clutter concentrates (:mod:`localization.object_clutter`). For that each
filter keeps its last scan as a **profile**: :data:`N_BINS` bins of 0.5 deg (the X4's
resolution), bin ``b`` centred on ``-pi + b 2 pi / N_BINS`` in the scanner's frame, holding the
farthest valid return of its beams or 0 (unknown: nothing in range, a blind-sector pillar, an
interference null, a mixed edge pixel). Bins and beams need not match: a denser scanner puts
several beams per bin (the farthest counts; one invalid beam makes the bin unknown), a sparser
one leaves bins empty (unknown). Each filter keeps its last scan's profile and the scanner's
pose in its own frame (moved with the odometry at every time update), so a camera frame taken
between two scans is judged against the latest one: its **scan memory** (:data:`MEMORY_LEN`).

This module holds the numpy reference (:func:`scan_profile`, :func:`move_scan_pose`) and the
compiled versions the banks call (:func:`profile_into`, :func:`move_scan_pose_in_place`),
checked equal in ``tests/localization/test_scan_memory.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "N_BINS",
    "BIN_WIDTH_RAD",
    "MEMORY_LEN",
    "MAX_WIDE_OBJECTS",
    "WIDE_OBJECTS_AT",
    "scan_profile",
    "move_scan_pose",
    "profile_into",
    "profiles_of",
    "move_scan_pose_in_place",
    "scan_memory_from_state",
]

#: Bins of a scan profile: 0.5 deg each, the YDLidar X4's angular resolution.
N_BINS = 720
BIN_WIDTH_RAD = 2.0 * math.pi / N_BINS
#: Most wide objects a scan memory keeps (:mod:`localization.object_clutter`; a ``seed-sim``
#: scan shows 0.94 on average). Beyond it, the first by bearing from -pi are kept.
MAX_WIDE_OBJECTS = 32
#: Where the wide objects start in a scan memory: a count, then ``[x_m, y_m, half_angle_rad]``
#: per object, in the scanner's frame.
WIDE_OBJECTS_AT = 4 + N_BINS
#: A filter's scan memory: ``[has_scan, x_m, y_m, psi_rad, profile (N_BINS,), n_wide,
#: wide objects (MAX_WIDE_OBJECTS x 3)]``.
MEMORY_LEN = WIDE_OBJECTS_AT + 1 + 3 * MAX_WIDE_OBJECTS
_TWO_PI = 2.0 * math.pi


def scan_memory_from_state(value) -> np.ndarray:
    """A saved scan memory ``(..., L)`` as one of today's ``(..., MEMORY_LEN)``: a memory saved
    before the wide objects (``L = 4 + N_BINS``) gets none; the next scan brings them.

    Raises
    ------
    ValueError
        For another length, a non-finite entry, a has-scan flag other than 0 / 1, or a count of
        wide objects the memory cannot hold (the compiled filters index by it)."""
    memory = np.array(value, dtype=float)
    length = memory.shape[-1] if memory.ndim else 0
    if length not in (MEMORY_LEN, WIDE_OBJECTS_AT):
        raise ValueError(
            f"scan_memory: last axis of {length} entries, expected {MEMORY_LEN} (or "
            f"{WIDE_OBJECTS_AT} from before the wide objects)"
        )
    if length == WIDE_OBJECTS_AT:
        pad = np.zeros(memory.shape[:-1] + (MEMORY_LEN - length,))
        memory = np.concatenate([memory, pad], axis=-1)
    # The compiled filters index the objects by this count: it must be one they can hold.
    count = memory[..., WIDE_OBJECTS_AT]
    flags = memory[..., 0]
    if (
        not np.isfinite(memory).all()
        or not np.isin(flags, (0.0, 1.0)).all()
        or not ((count == np.round(count)) & (count >= 0) & (count <= MAX_WIDE_OBJECTS)).all()
    ):
        raise ValueError(
            "scan_memory: needs finite entries, a has-scan flag of 0 or 1 and a whole number "
            f"of wide objects in [0, {MAX_WIDE_OBJECTS}], got flags {np.unique(flags)[:5]} and "
            f"counts {np.unique(count)[:5]}"
        )
    return memory


# ---------------------------------------------------------------------- numpy reference
def scan_profile(angles_rad: np.ndarray, ranges_m: np.ndarray) -> np.ndarray:
    """A scan's profile, shape ``(N_BINS,)`` (m; 0 = unknown), from its beams.

    Parameters
    ----------
    angles_rad, ranges_m : ndarray, shape (B,)
        Beam bearings (rad, scanner frame) and ranges (m); a range that is not a finite
        positive number is no valid return.
    """
    angles = np.asarray(angles_rad, dtype=float).reshape(-1)
    ranges = np.asarray(ranges_m, dtype=float).reshape(-1)
    if angles.shape != ranges.shape:
        raise ValueError(
            f"scan angles and ranges differ in length: {angles.shape[0]} vs {ranges.shape[0]}"
        )
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(ranges) & (ranges > 0.0)
    finite = np.isfinite(angles)
    bins = np.zeros(angles.shape[0], dtype=np.intp)
    bins[finite] = np.floor(((angles[finite] + math.pi) % _TWO_PI) / BIN_WIDTH_RAD + 0.5).astype(
        np.intp
    )
    bins %= N_BINS
    profile = np.full(N_BINS, -1.0)
    np.maximum.at(profile, bins[valid & finite], ranges[valid & finite])
    profile[bins[~valid & finite]] = 0.0
    profile[profile < 0.0] = 0.0  # empty bins
    return profile


def move_scan_pose(pose: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """The scanner pose ``(3,)`` in the filter's frame after a time update with ``odometry``
    ``[dx, dy, dpsi]`` (the frame moves as the components do: ``p' = R(dpsi)^T (p - d)``)."""
    dx, dy, dpsi = (float(v) for v in odometry)
    c, s = math.cos(dpsi), math.sin(dpsi)
    x, y = pose[0] - dx, pose[1] - dy
    return np.array([c * x + s * y, -s * x + c * y, pose[2] - dpsi])


# ---------------------------------------------------------------------- compiled
@njit(cache=True)
def profile_into(out, angles, ranges):
    """:func:`scan_profile` of one scan, written into ``out (N_BINS,)``."""
    out[:] = -1.0
    for k in range(angles.shape[0]):
        a = angles[k]
        if not math.isfinite(a):
            continue
        b = int(math.floor(((a + math.pi) % _TWO_PI) / BIN_WIDTH_RAD + 0.5)) % N_BINS
        d = ranges[k]
        if math.isfinite(d) and d > 0.0:
            if out[b] != 0.0 and d > out[b]:
                out[b] = d
        else:
            out[b] = 0.0
    for b in range(N_BINS):
        if out[b] < 0.0:
            out[b] = 0.0


@njit(cache=True)
def profiles_of(angles, ranges, stops):
    """Profiles ``(S, N_BINS)`` of ``S`` scans concatenated in ``angles``, ``ranges``, scan
    ``j`` being entries ``stops[j - 1]:stops[j]``."""
    out = np.empty((stops.shape[0], N_BINS))
    start = 0
    for j in range(stops.shape[0]):
        profile_into(out[j], angles[start : stops[j]], ranges[start : stops[j]])
        start = stops[j]
    return out


@njit(cache=True)
def move_scan_pose_in_place(memory, odometry):
    """:func:`move_scan_pose` of the pose in ``memory[1:4]``."""
    c, s = math.cos(odometry[2]), math.sin(odometry[2])
    x, y = memory[1] - odometry[0], memory[2] - odometry[1]
    memory[1] = c * x + s * y
    memory[2] = -s * x + c * y
    memory[3] -= odometry[2]
