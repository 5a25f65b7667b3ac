"""What a lidar scan's raw ranges say about where a teammate can and cannot be.

The lidar feature extractor turns a scan into robot-like clusters, and the filters' update
uses only those: a teammate beyond the extractor's ~2 m is "not detected", which says almost
nothing (``P_d`` ~ 0 there). The ranges themselves say more. Along each bearing the scan
found the first surface at some range ``d``; both sensors sit on the robot's axis, so:

* **Free space refutes** ("negative information", Perera 2021 section 6 and Stegagno 2012
  on landmarks "expected and not seen"): if the beams at a component's bearing, all of whose
  footprints would have hit a 65 mm housing at the component's range ``r``, returned from
  beyond ``r``, no teammate is there. Up to the X4's range (a housing still takes a beam at
  8 m), not only the extractor's 2 m. The weight is multiplied by ``1 - P_free``.
* **A surface occludes**: a component beyond the first surface at its bearing (by more than a
  housing radius) is hidden from both the lidar and the camera: their ``P_d`` is multiplied by
  the visibility ``V``. A component that drifted behind a wall is then neither confirmed by a
  bearing that a red object in front of the wall explains, nor penalised; it decays with the
  survival probability.

Per component (mean ``m``, covariance ``P``), from the scanner's position, with ``r`` the
range, ``theta`` the bearing, ``sigma_r(d) = a + b d^2`` the scanner's range noise at range
``d``, ``s^2 = u^T P u + sigma_r(d)^2`` the component's radial variance plus that (``u`` the
unit bearing vector), ``sigma_t^2 = v^T P v`` its tangential variance (``v`` perpendicular to
``u``), ``R`` the housing radius and ``k`` the margin in sigmas:

* ``alpha = asin(R / r)`` is the housing's angular half-width.
* **Visibility** ``V``: a housing at range ``rho`` behind a first surface ``d`` is seen with
  probability ``Phi((d + R - rho) / sigma_r(d) + k)`` (hidden only ``k`` sensor sigmas behind
  the surface, so a housing's own returns never hide it), with ``d = d_max`` the farthest
  return over the bins that overlap ``[beta - alpha, beta + alpha]`` at its bearing ``beta``
  (hidden only if even the farthest beam across it stopped short). ``V`` is that averaged
  over the component: over ``rho`` exactly (the probit-Gaussian integral,
  ``Phi((d + R - r + k sigma_r(d)) / s)``), and over ``beta`` by quadrature on candidate
  bearings within ``+-4 sigma_t / r`` (a quarter bin apart; at most 129, spread evenly and
  clamped to a quarter turn each side when wider), weighted by the bearing's Gaussian.
  A component behind a red decoy is thus hidden except where its bearing spread clears the
  decoy's edge (a Monte Carlo test checks the average).
* **Free space** ``P_free = Phi((d_min - r) / s - k)``, with ``d_min`` the nearest return over
  the bins whose whole footprint lies on the housing at some bearing within ``theta +- delta``,
  ``delta = k sigma_t / r``: ``|c_b - theta| + footprint / 2 <= alpha + delta`` (every one of
  them passed beyond the housing's centre), provided every bearing of the spread has such a
  bin. The margin is ``k`` sigmas of the component *and* the sensor, and the bearing is
  covered to ``k`` sigmas rather than averaged: unlike ``V``, a wrong ``P_free`` destroys a
  teammate's weight. Without the spread, a well-tracked teammate 2 cm off its mean at 2 m
  (0.6 deg) fell between the two or three bins that would see it, and the scan "refuted" it.
  No evidence beyond ``R / sin(footprint / 2)`` (7.4 m for the X4), nor where a housing in the
  spread could sit between two bins (beyond 3.7 m, where the bins are wider apart than a
  housing's inner width, unless one bin covers the whole spread).

A bin without a valid return (nothing in range, a blind-sector pillar, an interference null,
a mixed edge pixel) is unknown: a candidate bearing whose window touches one counts as
visible, and ``P_free = 0`` for every component whose window touches one. A teammate on the
scan keeps its weight: its own housing returns ``d = r - R``, so ``P_free <= Phi(-R / s -
k)``. Its visibility is at least ``Phi(k sigma_r / s)``: near ``Phi(k)`` for a well-localised
component, lower for a wide one (radial std 0.1 m at 1 m: ``s ~ 0.1``, ``sigma_r ~ 0.012``,
about 0.64), whose mass partly lies behind the surface the teammate itself returned.

The camera update (:func:`localization.phd.camera_update`) uses ``V`` twice: a missed copy
with ``P_d V(prior)``, each detected copy with ``P_d V(its posterior)``. The bearing says
where along its ray the target would be, so the occluder that matters is the one on that
bearing: a component behind the red object that explains a bearing gets only ``V`` of its
support.

The scan is kept as a **profile**: :data:`N_BINS` bins of 0.5 deg (the X4's resolution), bin
``b`` centred on ``-pi + b 2 pi / N_BINS`` in the scanner's frame, holding the farthest valid
return of its beams or 0 (unknown). Bins and beams need not match: a denser scanner puts
several beams per bin (the farthest counts; one invalid beam makes the bin unknown), a sparser
one leaves bins empty (unknown). Each filter keeps its last scan's profile and the scanner's
pose in its own frame (moved with the odometry at every time update), so a camera frame taken
between two scans is judged against the latest one.

Left out: the scan's own **skew**. A real head takes 0.14 s per revolution while the robot
turns, and the driver reports each beam in the robot's frame at that beam's own instant (8 deg
out of shape by the end at 1 rad/s). The simulator's scans are snapshots, so this does not
arise there; on a real robot, de-skewing needs each beam's time (``LaserScan.time_increment``)
and the odometry's turn rate. Also left out: other robots' motion since the scan (0.04 m at
0.3 m/s), and low obstacles the camera sees over (the simulator's decoy posts): a teammate
hidden from the lidar by one loses its camera updates while it is hidden, never its weight.
Why it is off in the simulator's filter (``swarm_env.config.SIMULATOR_PHD``): alone it did not
make the agents' estimate better; with the wide objects' camera clutter
(:mod:`localization.object_clutter`) it does, at several times the filter's cost
(``docs/concepts/localizers.md``).

This module holds the numpy reference (:func:`scan_profile`, :func:`scan_factors`) and the
compiled versions the banks call (:func:`profile_into`, :func:`scan_factors_into`), checked
equal in ``tests/localization/test_scan_evidence.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy import special

__all__ = [
    "N_BINS",
    "BIN_WIDTH_RAD",
    "MEMORY_LEN",
    "MAX_WIDE_OBJECTS",
    "WIDE_OBJECTS_AT",
    "scan_profile",
    "scan_factors",
    "move_scan_pose",
    "profile_into",
    "profiles_of",
    "scan_factors_into",
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
_INV_SQRT2 = 1.0 / math.sqrt(2.0)
_MIN_STD_M = 1e-9  # a noiseless scanner and a point-mass component: no 0 / 0
_TWO_PI = 2.0 * math.pi
# Widest tangential spread, rad: with the housing's half-width (<= pi / 2) a window then
# covers the whole scan, and no wider window is needed.
_MAX_SPREAD = 0.5 * math.pi
# The visibility averages over candidate bearings within +-4 sigmas of the bearing (an
# occluder's edge is often in the tails), a quarter bin apart (a window's reach changes
# within a bin: bin centres alone would under-reach by half a bin on average), or, when that
# would take more than 64 each side, 64 evenly over the spread (at most a quarter turn):
# the quadrature then has 129 points, whatever the spread, and the count never depends on a
# rounding.
_CANDIDATE_STEP_RAD = BIN_WIDTH_RAD / 4
_BEARING_SIGMAS = 4.0
_CUT_DENSITY = math.exp(-0.5 * _BEARING_SIGMAS**2)
_MAX_CANDIDATES = 64


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


def scan_factors(
    table: np.ndarray,
    pose: np.ndarray,
    profile: np.ndarray,
    target_radius_m: float,
    range_std_m: float,
    range_std_quadratic_per_m: float,
    footprint_rad: float,
    margin_sigmas: float,
    min_range_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Visibility ``V`` and free-space probability ``P_free`` per component (module doc).

    Parameters
    ----------
    table : ndarray, shape (6, N)
        Components ``w, x, y, Pxx, Pxy, Pyy`` in the filter's frame (m, m^2).
    pose : ndarray, shape (3,)
        The scanner's ``(x_m, y_m, psi_rad)`` in the same frame.
    profile : ndarray, shape (N_BINS,)
        :func:`scan_profile` of the scan.

    Returns
    -------
    visible, free : ndarray, shape (N,)
        Both in ``[0, 1]``; a component within ``min_range_m`` of the scanner gets 1 and 0.
    """
    n = table.shape[1]
    visible, free = np.ones(n), np.zeros(n)
    dx, dy = table[1] - pose[0], table[2] - pose[1]
    r = np.hypot(dx, dy)
    near = r < min_range_m
    r = np.where(near, 1.0, r)  # placeholders; those components keep 1 and 0
    radial_var = (dx * dx * table[3] + 2 * dx * dy * table[4] + dy * dy * table[5]) / (r * r)
    tangential_var = (dy * dy * table[3] - 2 * dx * dy * table[4] + dx * dx * table[5]) / (r * r)
    spread = np.minimum(margin_sigmas * np.sqrt(np.maximum(tangential_var, 0.0)) / r, _MAX_SPREAD)
    alpha = np.arcsin(np.minimum(1.0, target_radius_m / r))
    centre = (np.arctan2(dy, dx) - pose[2] + math.pi) / BIN_WIDTH_RAD
    inner = alpha - 0.5 * footprint_rad

    def window(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Profile ranges ``(n, W)`` over bins ``lo..hi`` per component (padded with nan),
        and whether every bin is known (an empty window counts as unknown)."""
        width = max(int((hi - lo).max(initial=-1)) + 1, 1)
        bins = lo[:, None] + np.arange(width)
        inside = bins <= hi[:, None]
        ranges = np.where(inside, profile[bins % N_BINS], np.nan)
        known = (hi >= lo) & ~(inside & (ranges <= 0.0)).any(axis=1)
        return ranges, known

    def noise_std(d: np.ndarray) -> np.ndarray:
        return range_std_m + range_std_quadratic_per_m * d * d

    def scale(d: np.ndarray, var: np.ndarray) -> np.ndarray:
        return np.maximum(np.sqrt(var + noise_std(d) ** 2), _MIN_STD_M)

    # Visibility: the housing's window at each candidate bearing, a quarter bin apart over
    # +-4 sigmas of the bearing, weighted by its Gaussian (offsets in quarter bins, (n, C)).
    bearing_std = np.sqrt(np.maximum(tangential_var, 0.0)) / r
    reach = _BEARING_SIGMAS * bearing_std
    wide_spread = reach >= _MAX_CANDIDATES * _CANDIDATE_STEP_RAD
    steps = np.where(wide_spread, _MAX_CANDIDATES, np.floor(reach / _CANDIDATE_STEP_RAD)).astype(
        np.intp
    )
    step_rad = np.where(
        wide_spread,
        np.minimum(reach, _MAX_SPREAD) / _MAX_CANDIDATES,
        _CANDIDATE_STEP_RAD,
    )
    offsets = np.arange(-int(steps.max(initial=0)), int(steps.max(initial=0)) + 1)
    use = np.abs(offsets)[None, :] <= steps[:, None]
    z = offsets[None, :] * (step_rad / np.maximum(bearing_std, _MIN_STD_M))[:, None]
    # The Gaussian minus its value at the cut, so a candidate enters with weight 0 as the
    # spread grows (no jump); a single candidate (no spread) keeps weight 1.
    cut = _CUT_DENSITY * (steps > 0)
    weight = np.where(use, np.maximum(np.exp(-0.5 * z * z) - cut[:, None], 0.0), 0.0)
    weight /= weight.sum(axis=1, keepdims=True)
    candidate = centre[:, None] + offsets[None, :] * (step_rad / BIN_WIDTH_RAD)[:, None]
    lo = np.floor(candidate - (alpha / BIN_WIDTH_RAD)[:, None] + 0.5).astype(np.intp)
    hi = np.floor(candidate + (alpha / BIN_WIDTH_RAD)[:, None] + 0.5).astype(np.intp)
    bins = lo[..., None] + np.arange(int((hi - lo).max(initial=0)) + 1)
    inside = bins <= hi[..., None]
    wide = np.where(inside, profile[bins % N_BINS], np.nan)
    known = ~(inside & (wide <= 0.0)).any(axis=2)
    d_max = np.nanmax(np.where(known[..., None], wide, 1.0), axis=2)
    per_bearing = np.where(
        known,
        _phi(
            (d_max + target_radius_m - r[:, None] + margin_sigmas * noise_std(d_max))
            / scale(d_max, radial_var[:, None])
        ),
        1.0,
    )
    # 1 minus the hidden share: exactly 1 where nothing hides it
    visible = np.where(near, 1.0, 1.0 - (weight * (1.0 - per_bearing)).sum(axis=1))
    half = (np.maximum(inner, 0.0) + spread) / BIN_WIDTH_RAD
    central, known = window(
        np.ceil(centre - half).astype(np.intp), np.floor(centre + half).astype(np.intp)
    )
    # Every bearing within the spread must have a bin whole on the housing: always so when
    # the bins are no farther apart than the housing's inner width, else only if one bin
    # covers the whole spread (a housing between two bins is never seen, nor refuted).
    sure = np.maximum(inner - spread, 0.0) / BIN_WIDTH_RAD
    covered = (2.0 * inner >= BIN_WIDTH_RAD) | (
        (inner >= spread) & (np.ceil(centre - sure) <= np.floor(centre + sure))
    )
    ok = known & ~near & (inner >= 0.0) & covered
    d_min = np.nanmin(np.where(ok[:, None], central, 1.0), axis=1)
    free[ok] = _phi((d_min - r) / scale(d_min, radial_var) - margin_sigmas)[ok]
    return visible, free


def _phi(x: np.ndarray) -> np.ndarray:
    """Standard normal CDF, elementwise."""
    return 0.5 * special.erfc(-x * _INV_SQRT2)


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


@njit(cache=True)
def _phi_nb(x):
    return 0.5 * math.erfc(-x * _INV_SQRT2)


@njit(cache=True)
def scan_factors_into(
    visible, free, tab, n, memory, ox, oy, radius, std0, std2, footprint, k, min_range
):
    """:func:`scan_factors` of ``tab``'s first ``n`` columns against ``memory`` (a filter's
    ``[has_scan, x, y, psi, profile, wide objects]``), the table's frame being the filter's
    shifted by ``(-ox, -oy)`` (a camera update's view). Writes ``visible (n,)`` and
    ``free (n,)``."""
    for i in range(n):
        visible[i] = 1.0
        free[i] = 0.0
    if memory[0] == 0.0:
        return
    sx, sy, psi = memory[1] - ox, memory[2] - oy, memory[3]
    for i in range(n):
        dx, dy = tab[1, i] - sx, tab[2, i] - sy
        r = math.hypot(dx, dy)
        if r < min_range:
            continue
        radial_var = (dx * dx * tab[3, i] + 2 * dx * dy * tab[4, i] + dy * dy * tab[5, i]) / (
            r * r
        )
        tangential_var = (dy * dy * tab[3, i] - 2 * dx * dy * tab[4, i] + dx * dx * tab[5, i]) / (
            r * r
        )
        spread = min(k * math.sqrt(max(tangential_var, 0.0)) / r, _MAX_SPREAD)
        theta = math.atan2(dy, dx) - psi
        alpha = math.asin(min(1.0, radius / r))
        centre = (theta + math.pi) / BIN_WIDTH_RAD
        bearing_std = math.sqrt(max(tangential_var, 0.0)) / r
        reach = _BEARING_SIGMAS * bearing_std
        if reach >= _MAX_CANDIDATES * _CANDIDATE_STEP_RAD:
            steps = _MAX_CANDIDATES
            step_rad = min(reach, _MAX_SPREAD) / _MAX_CANDIDATES
        else:
            steps = int(math.floor(reach / _CANDIDATE_STEP_RAD))
            step_rad = _CANDIDATE_STEP_RAD
        cut = _CUT_DENSITY if steps > 0 else 0.0
        total = 0.0
        hidden = 0.0
        for j in range(-steps, steps + 1):
            z = 0.0 if j == 0 else j * (step_rad / max(bearing_std, _MIN_STD_M))
            weight = max(math.exp(-0.5 * z * z) - cut, 0.0)
            candidate = centre + j * (step_rad / BIN_WIDTH_RAD)
            lo = math.floor(candidate - alpha / BIN_WIDTH_RAD + 0.5)
            hi = math.floor(candidate + alpha / BIN_WIDTH_RAD + 0.5)
            d_max = 0.0
            known = True
            for b in range(lo, hi + 1):
                d = memory[4 + b % N_BINS]
                if d <= 0.0:
                    known = False
                    break
                d_max = max(d_max, d)
            if known:
                noise = std0 + std2 * d_max * d_max
                s = max(math.sqrt(radial_var + noise * noise), _MIN_STD_M)
                hidden += weight * (1.0 - _phi_nb((d_max + radius - r + k * noise) / s))
            total += weight
        visible[i] = 1.0 - hidden / total
        inner = alpha - 0.5 * footprint
        if inner < 0.0:
            continue
        if 2.0 * inner < BIN_WIDTH_RAD:  # one bin must cover every bearing of the spread
            if inner < spread:
                continue
            sure = (inner - spread) / BIN_WIDTH_RAD
            if math.floor(centre + sure) < math.ceil(centre - sure):
                continue
        half = (inner + spread) / BIN_WIDTH_RAD
        lo = math.ceil(centre - half)
        hi = math.floor(centre + half)
        if hi < lo:
            continue
        d_min = math.inf
        for b in range(lo, hi + 1):
            d = memory[4 + b % N_BINS]
            if d <= 0.0:
                d_min = -1.0
                break
            d_min = min(d_min, d)
        if d_min > 0.0:
            s = max(math.sqrt(radial_var + (std0 + std2 * d_min * d_min) ** 2), _MIN_STD_M)
            free[i] = _phi_nb((d_min - r) / s - k)
