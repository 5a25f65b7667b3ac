"""Lidar feature extractor: robot-sized clusters of a scan become position measurements.

Shared perception: the simulator, the hardware bridge and the replay run this same code on
simulated and real YDLidar X4 scans.

The seed (000, "Lidar measurements") segments each scan into clusters of consecutive returns and
keeps the objects narrower than the 65 mm lidar housing of a teammate, reported as a point in the
scanner's body frame. The cluster rules come from the sensor's geometry and noise, with no range
cut: a cluster needs ``min_beams`` = 3 returns (the fewest that define an arc), and its width may
exceed the housing diameter by ``width_noise_sigmas`` standard deviations of the difference of
two returns' range noise at its range. A housing at range r spans about
``2 asin(0.0325 / r) / 0.5 deg`` returns with thin rays (at least 3 up to 2.48 m, at least 2 up
to 3.7 m) and one fewer with the simulated X4's footprint (``LidarConfig.beam_footprint_deg``),
whose detection probability falls from 1 at 1.86 m to 0 at 2.48 m (measured in
``benchmarks/bench_detection_curves.py``). A single missing return between two returns that
link (a dropout) does not break a cluster (``max_gap_beams``). By construction:

* decoy posts (radius <= 32.5 mm) pass: lidar false positives;
* occluded robots, robots in a blind sector or interfered robots return nothing: false negatives;
* walls and large obstacles form wide clusters and are rejected, except small fragments where a
  nearer object cuts a wall into a narrow visible sliver (a realistic false positive, rare at the
  Perera 2021 study's 2 m tracking range);
* round objects wider than a housing (the arena's 120 mm red decoys) are rejected by the angular
  extent test (``extent_test``): every return's ray meets the object, so the angle between a
  cluster's first and last beams is at most the angle the object subtends, and a housing whose
  front is the cluster's nearest return subtends ``2 asin(0.0325 / d)``. This holds for any
  scanner, whatever its beam footprint does at an object's edge (thin rays that hit up to the
  tangent, or a footprint that drops edge-straddling samples as the simulated X4's), so a
  housing is never rejected for its extent. A 120 mm decoy spans ~1.85 times a housing's angle,
  so its returns overflow that bound up to ~2.2 m whatever the scanner (to 3 m with thin
  rays; ``tests/hardware_bridge/test_real_scans.py``); beyond, a scanner that drops its edge
  samples leaves a decoy as few returns as a housing, and only ``beam_footprint_deg`` (a
  scanner known to do so) tells them apart;
  the end-to-end width alone must allow for two returns' range noise, and lets a 120 mm
  cylinder pass 98-100 % of the time from 1.5 to 3 m;
* two robots touching side by side merge into one wide cluster: both are missed.

All K scans are segmented in one compiled pass (``_cluster_kernel``): each scan is walked once,
from its first cluster start, so a cluster through the +/-pi seam needs no special case.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from swarm_core.geometry import wrap_angle
from swarm_core.validation import check_number_fields


@dataclass(frozen=True, slots=True)
class LidarFeatureConfig:
    """Cluster segmentation and robot-likeness test.

    Attributes
    ----------
    jump_threshold_m : float
        A cluster breaks between consecutive beams whose ranges differ by more than
        ``jump_threshold_m + jump_range_gain * r`` (or at an invalid return). 5 cm is 3.5
        sigma of the difference of two 1 cm-noise ranges.
    jump_range_gain : float
        Range-proportional part of the break threshold (dimensionless). Adjacent beams on a
        flat surface seen at incidence angle ``beta`` differ by ``~ r dtheta tan(beta)``, so a
        fixed threshold shatters a wall seen obliquely into one-beam "robots". The default,
        ``sin(0.5 deg) / sin(10 deg - 0.5 deg)``, is the adaptive breakpoint detector of Borges
        & Aldon (2004) with lambda = 10 deg: surfaces up to 80 deg incidence stay connected.
        Set 0 for the plain fixed threshold.
    max_width_m : float
        Noise-free width limit: the 65 mm housing diameter (seed: "arc length below 65 mm").
        A cluster is kept when its end-to-end width is at most
        ``max_width_m + width_noise_sigmas * sqrt(2) * sigma(r)``, with ``sigma(r)`` the range
        noise at the cluster's mean range ``r``. The chord between two returns on a housing is
        at most the diameter, and their range difference is ``N(0, 2 sigma^2)``, so a housing
        passes with probability >= 95 % at 2 sigmas, at every range.
    width_noise_sigmas : float
        Width tolerance in standard deviations of the two edge returns' range difference.
    range_noise_std_m, range_noise_quadratic_per_m : float
        The scanner's range noise ``sigma(r) = std + quadratic * r^2`` (defaults: the simulated
        X4, :class:`swarm_env.sensors.lidar.LidarConfig`; on real robots, the real X4's).
    min_beams : int
        Minimum returns in a kept cluster. Default 3: three points define a circle, so three
        returns are the fewest whose arc shape can be told from a wall edge, a range spike or a
        mixed pixel (Perera 2021 recognises teammates as "a small set of points, which has a shape
        of an arch"). With one or two returns any surface edge would pass the width test.
    housing_radius_m : float
        The centre estimate is pushed this far behind the mean return, along the beam.
    tracking_range_m : float
        Detections whose centre is farther are dropped. Default 10 m, the X4's maximum range:
        no cut. Perera 2021's "range of the lidar is limited to 2m" (sec. 3.2) follows from the
        rules above (fewer returns at longer range), not from a threshold.
    extent_test : bool
        Also require the cluster's angular extent to fit a housing. Every return's ray meets
        the object, so the angle ``alpha`` between the first and last beams is at most the
        angle the object subtends. The housing's front is the cluster's nearest return
        ``r_min`` (the ray nearest the housing's centre line is within half a beam spacing of
        it: ``r_min`` exceeds the front by < 2 mm at 2.5 m), so its centre is ``d = r_min +
        housing_radius_m`` away and it subtends ``2 asin(max_width_m / 2 / d)``; ``d`` is
        taken ``width_noise_sigmas`` range-noise standard deviations nearer, for the noise of
        ``r_min`` (measured on exact ray-cylinder scans with 4 mm noise and on the simulator's:
        no housing lost from 0.3 to 2.5 m, ``tests/hardware_bridge/test_real_scans.py``). The
        cluster is kept when ``alpha + beam_footprint_deg`` fits in that angle. It rejects a
        120 mm decoy's returns wherever they overflow a housing's angle: up to ~2.2 m whatever
        the beam footprint, to 3 m with thin rays. ``False`` gives the end-to-end width test
        alone. The angles are the scanner's, taken as exact (no angular jitter).
    beam_footprint_deg : float
        The angular width that every return's beam is known to have on the object (the
        simulated X4 drops a sample whose 0.5 deg footprint straddles an object's edge:
        ``LidarConfig.beam_footprint_deg``). Default 0: thin rays, the bound that holds for
        every scanner, including one that returns a range from any ray meeting the housing up
        to its tangent. With 0.5 a housing seen by thin rays is rejected at about half of its
        positions (at 1.12 m, seven returns span 3.0 deg + 0.5 > the 3.33 deg it subtends): set
        it only for a scanner whose edge samples are known to drop; it then also rejects
        120 mm decoys beyond 2.2 m.
    foreground_only : bool
        Keep only clusters standing in front of both neighbouring returns (or next to invalid
        returns; the neighbour is the nearest return within ``max_gap_beams`` missing ones). A
        free-standing post or housing always does; a one-beam sliver of a wall seen at grazing
        incidence (beyond what ``jump_range_gain`` keeps connected) or a wall
        fragment showing between two nearer objects does not. Costs the robots partially
        hidden behind a nearer object, whose truncated arc would bias the centre anyway.
        ``False`` gives the Perera 2021 study's plain width test.
    max_gap_beams : int
        Missing returns (range 0) a cluster bridges: a return at most this many beams after
        the previous one continues its cluster when their ranges link. A surface does not
        vanish for one 0.5 deg sample: a real scanner drops single returns on dark or glancing
        spots, and without the bridge a dropout splits a wall into fragments whose
        no-return neighbours make them look free-standing (three returns between two
        dropouts at 2 m pass every other rule), and splits a housing into two detections.
        Two housings one beam apart (< 1 cm at 1 m) merge and are missed. Blind sectors
        (10 deg) are never bridged. 0: every missing return breaks a cluster.
    """

    jump_threshold_m: float = 0.05
    jump_range_gain: float = float(np.sin(np.deg2rad(0.5)) / np.sin(np.deg2rad(9.5)))
    max_width_m: float = 0.065
    width_noise_sigmas: float = 2.0
    range_noise_std_m: float = 0.01
    range_noise_quadratic_per_m: float = 0.0025
    min_beams: int = 3
    housing_radius_m: float = 0.0325
    tracking_range_m: float = 10.0
    extent_test: bool = True
    beam_footprint_deg: float = 0.0
    foreground_only: bool = True
    max_gap_beams: int = 1

    def __post_init__(self) -> None:
        check_number_fields(self)
        for name in (
            "jump_threshold_m",
            "jump_range_gain",
            "housing_radius_m",
            "width_noise_sigmas",
            "range_noise_std_m",
            "range_noise_quadratic_per_m",
            "beam_footprint_deg",
        ):
            if not math.isfinite(getattr(self, name)) or not getattr(self, name) >= 0.0:
                raise ValueError(
                    f"LidarFeatureConfig.{name} must be >= 0, got {getattr(self, name)!r}"
                )
        if not self.beam_footprint_deg < 10.0:  # as LidarConfig's: a sample is < 10 deg wide
            raise ValueError(
                f"LidarFeatureConfig.beam_footprint_deg must be < 10, got "
                f"{self.beam_footprint_deg!r}"
            )
        for name in ("max_width_m", "tracking_range_m"):
            if not getattr(self, name) > 0.0:
                raise ValueError(
                    f"LidarFeatureConfig.{name} must be > 0, got {getattr(self, name)!r}"
                )
        if (
            isinstance(self.max_gap_beams, bool)
            or not isinstance(self.max_gap_beams, (int, np.integer))
            or not 0 <= self.max_gap_beams <= 8
        ):
            raise ValueError(
                f"LidarFeatureConfig.max_gap_beams must be an int in [0, 8], got "
                f"{self.max_gap_beams!r}"
            )
        if not isinstance(self.min_beams, (int, np.integer)) or self.min_beams < 1:
            raise ValueError(
                f"LidarFeatureConfig.min_beams must be an int >= 1, got {self.min_beams!r}"
            )


@dataclass(frozen=True, slots=True)
class LidarDetections:
    """Robot-like clusters of K scans, flat and sorted by scan then bearing.

    Attributes
    ----------
    xy_m : ndarray, shape (M, 2)
        Centre estimates ``[x, y]`` in the scanning robot's body frame, metres.
    scan_index : ndarray, shape (M,), int
        Which scan (row of the ranges) each detection comes from.
    width_m : ndarray, shape (M,)
        End-to-end cluster width, metres.
    n_beams : ndarray, shape (M,), int
        Returns in the cluster.
    n_scans : int
    """

    xy_m: np.ndarray
    scan_index: np.ndarray
    width_m: np.ndarray
    n_beams: np.ndarray
    n_scans: int

    def split(self) -> list[np.ndarray]:
        """Per-scan detections: a list of K arrays of shape (M_k, 2)."""
        bounds = np.searchsorted(self.scan_index, np.arange(self.n_scans + 1)).tolist()
        xy = self.xy_m.view()
        xy.setflags(write=False)  # read-only views, as records want them (no copy)
        return [xy[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def extract_clusters(
    angles_rad: np.ndarray, ranges_m: np.ndarray, config: LidarFeatureConfig | None = None
) -> LidarDetections:
    """Segment K scans into clusters and keep the robot-sized ones.

    Parameters
    ----------
    angles_rad : ndarray, shape (B,)
        Beam bearings in the robot frame, increasing, covering the full circle (beam B-1 is
        adjacent to beam 0: a cluster straddling +/-pi is one cluster).
    ranges_m : ndarray, shape (K, B) or (B,)
        Ranges, 0 = no valid return.
    config : LidarFeatureConfig, optional

    Returns
    -------
    LidarDetections
        Cluster width = distance between its first and last return; centre = the point at
        the circular-mean bearing and mean range, plus ``housing_radius_m`` along that bearing.
    """
    return _extract(angles_rad, ranges_m, config, 0.0, "extract_clusters")


def extract_wide_objects(
    angles_rad: np.ndarray,
    ranges_m: np.ndarray,
    config: LidarFeatureConfig | None = None,
    *,
    max_width_m: float,
) -> LidarDetections:
    """Compact objects of K scans that the robot test rejects: clusters that pass every rule
    of :func:`extract_clusters` (beams, foreground, range) except the housing's width or
    angular extent, up to ``max_width_m`` end to end (the arena's 120 mm red decoys, posts and
    pillars wider than a housing, a box's narrow face). The filters read them as places a
    camera blob may come from that is not a teammate
    (``localization.PHDConfig.camera_clutter_per_wide_object``).

    Returns
    -------
    LidarDetections
        As :func:`extract_clusters`'s, but each centre is pushed half the cluster's width
        (not a housing radius) behind its mean return.
    """
    if not max_width_m > 0.0:
        raise ValueError(f"extract_wide_objects: max_width_m must be > 0, got {max_width_m!r}")
    return _extract(angles_rad, ranges_m, config, float(max_width_m), "extract_wide_objects")


def _extract(angles_rad, ranges_m, config, wider_than_housing_up_to, caller) -> LidarDetections:
    cfg = config if config is not None else LidarFeatureConfig()
    ranges = np.ascontiguousarray(np.atleast_2d(np.asarray(ranges_m, dtype=np.float64)))
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    n_scans, n_beams = ranges.shape
    if angles.shape[0] != n_beams:
        raise ValueError(f"{caller}: {angles.shape[0]} angles for ranges of shape {ranges.shape}")
    cos_a, sin_a = _directions(angles)
    xy, scan, width, count = _cluster_kernel(
        ranges,
        cos_a,
        sin_a,
        *cluster_rule(cfg),
        wider_than_housing_up_to,
    )
    return LidarDetections(xy_m=xy, scan_index=scan, width_m=width, n_beams=count, n_scans=n_scans)


def cluster_rule(cfg: LidarFeatureConfig) -> tuple:
    """``cfg`` as :func:`_cluster_kernel`'s rule arguments (``jump_threshold`` to
    ``max_gap``), the form in which compiled callers pass it on."""
    return (
        cfg.jump_threshold_m,
        cfg.jump_range_gain,
        cfg.max_width_m,
        cfg.width_noise_sigmas * math.sqrt(2.0) * cfg.range_noise_std_m,
        cfg.width_noise_sigmas * math.sqrt(2.0) * cfg.range_noise_quadratic_per_m,
        int(cfg.min_beams),
        cfg.housing_radius_m,
        cfg.tracking_range_m,
        bool(cfg.extent_test),
        math.radians(cfg.beam_footprint_deg),
        bool(cfg.foreground_only),
        int(cfg.max_gap_beams),
    )


_DIRECTIONS: list = [None, None, None]  # angles, cos, sin of the last call (a copy)


def _directions(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the beam bearings; a scanner passes the same bearings every call."""
    cached, cos_a, sin_a = _DIRECTIONS
    if cached is None or not np.array_equal(angles, cached):
        cos_a, sin_a = np.cos(angles), np.sin(angles)
        _DIRECTIONS[:] = angles.copy(), cos_a, sin_a
    return cos_a, sin_a


@njit(cache=True)
def _cluster_kernel(
    ranges,
    cos_a,
    sin_a,
    jump_threshold,
    jump_gain,
    max_width,
    width_tol_const,
    width_tol_quadratic,
    min_beams,
    housing_radius,
    tracking_range,
    extent_test,
    footprint,
    foreground_only,
    max_gap,
    wider_than_housing_up_to,
):
    """Robot-like clusters of K scans: ``ranges`` (K, B) m (0 = no return), beam directions
    ``cos_a``, ``sin_a`` (B,). A cluster of mean range r is robot-like when its width is at
    most ``max_width + width_tol_const + width_tol_quadratic r^2`` and, with ``extent_test``,
    its returns' angular spread plus ``footprint`` (rad) fits the angle a ``max_width``
    housing subtends when its front is the nearest return (see :class:`LidarFeatureConfig`).

    With ``wider_than_housing_up_to`` > 0 (m) the test is inverted: the clusters kept are the
    ones that pass every other rule but are *not* robot-like, up to that end-to-end width
    (:func:`extract_wide_objects`), and their centre is pushed half their width behind the
    mean return instead of ``housing_radius``.

    Returns ``xy`` (M, 2) m, ``scan`` (M,), ``width`` (M,) m and ``count`` (M,) beams, sorted
    by scan then bearing. Each scan is walked once from its first cluster start (a valid beam
    not linked to its predecessor), so a cluster through the +/-pi seam is one piece.
    """
    n_scans, n_beams = ranges.shape
    wide = wider_than_housing_up_to > 0.0
    # link[k, b]: return b continues the cluster of the previous return, at most max_gap
    # missing returns before it (b = 0 looks back through B-1: the seam).
    link = np.empty((n_scans, n_beams), dtype=np.bool_)
    n_starts = 0  # every cluster starts at a valid beam not linked to its predecessor
    for k in range(n_scans):
        r = ranges[k]
        prev = r[n_beams - 1]
        for b in range(n_beams):
            cur = r[b]
            if not prev > 0.0 and cur > 0.0 and max_gap > 0:
                # Look back over the dropouts for the previous return.
                for g in range(2, max_gap + 2):
                    prev = r[b - g]  # negative indices wrap through the seam
                    if prev > 0.0:
                        break
            link[k, b] = (
                (cur > 0.0)
                & (prev > 0.0)
                & (abs(prev - cur) <= min(cur, prev) * jump_gain + jump_threshold)
            )
            n_starts += (cur > 0.0) & ~link[k, b]
            prev = cur
    xy = np.empty((n_starts, 2))
    scan = np.empty(n_starts, dtype=np.intp)
    width = np.empty(n_starts)
    count = np.empty(n_starts, dtype=np.intp)
    bearing = np.empty(n_beams)
    m = 0
    for k in range(n_scans):
        r = ranges[k]
        first = -1
        for b in range(n_beams):
            if r[b] > 0.0 and not link[k, b]:
                first = b
                break
        if first < 0:
            # No return, or returns linked all around (one room-wide cluster): nothing kept.
            continue
        m_scan = m
        b = first
        done = 0
        while done < n_beams:
            if not r[b] > 0.0:
                b = b + 1 if b + 1 < n_beams else 0
                done += 1
                continue
            # A cluster starts at b (not linked to its previous return); extend it while the
            # next return, at most max_gap missing returns on, links.
            s = e = b
            n = 1
            span = 1  # beams from s to e, missing returns included
            sum_r, sum_s, sum_c = r[b], sin_a[b], cos_a[b]
            min_r = r[b]
            nxt = b + 1 if b + 1 < n_beams else 0
            while done + span < n_beams:
                q = nxt
                gap = 0
                while gap < max_gap and not r[q] > 0.0 and done + span + gap + 1 < n_beams:
                    q = q + 1 if q + 1 < n_beams else 0
                    gap += 1
                if not link[k, q]:  # (a missing return is never linked)
                    break
                e = q
                n += 1
                span += gap + 1
                sum_r += r[e]
                sum_s += sin_a[e]
                sum_c += cos_a[e]
                min_r = min(min_r, r[e])
                nxt = e + 1 if e + 1 < n_beams else 0
            done += span
            b = nxt
            r_s, r_e = r[s], r[e]
            w = math.hypot(r_e * cos_a[e] - r_s * cos_a[s], r_e * sin_a[e] - r_s * sin_a[s])
            if n < min_beams:
                continue
            mean_r = sum_r / n
            robot_like = w <= max_width + width_tol_const + width_tol_quadratic * mean_r * mean_r
            if wide:
                if not w <= wider_than_housing_up_to:
                    continue
            elif not robot_like:
                continue
            if foreground_only:
                # Neighbours just outside: farther, or no return, for a standalone object. The
                # neighbour is the nearest return within max_gap dropouts of the cluster.
                before, after = r[s - 1], r[nxt]
                for g in range(2, max_gap + 2):
                    if before > 0.0:
                        break
                    before = r[s - g]
                for g in range(1, max_gap + 1):
                    if after > 0.0:
                        break
                    after = r[(nxt + g) % n_beams]
                if not (before == 0.0 or before > r_s) or not (after == 0.0 or after > r_e):
                    continue
            # The robot test judges a housing's centre in both modes, so that the wide objects
            # are exactly the clusters it rejects; a wide object is reported at its own centre.
            housing_r = mean_r + housing_radius
            centre_r = mean_r + 0.5 * w if wide else housing_r
            if not centre_r <= tracking_range:
                continue
            phi = math.atan2(sum_s, sum_c)
            if extent_test and robot_like:
                # A housing's front is the nearest return; its centre may be n_sigmas sigma
                # nearer than measured (the tolerances hold n_sigmas sqrt(2) sigma), which
                # widens its subtense.
                near = (width_tol_const + width_tol_quadratic * min_r * min_r) / math.sqrt(2.0)
                half = 0.5 * max_width / max(min_r + housing_radius - near, 1e-9)
                subtense = 2.0 * math.asin(half) if half < 1.0 else math.pi
                spread = abs(
                    math.atan2(
                        sin_a[e] * cos_a[s] - cos_a[e] * sin_a[s],
                        cos_a[e] * cos_a[s] + sin_a[e] * sin_a[s],
                    )
                )
                robot_like = spread + footprint <= subtense
            if robot_like == wide:
                continue
            # Insert in bearing order (stable; a seam cluster is walked last but may be first).
            j = m - m_scan
            while j > 0 and bearing[j - 1] > phi:
                bearing[j] = bearing[j - 1]
                xy[m_scan + j, 0] = xy[m_scan + j - 1, 0]
                xy[m_scan + j, 1] = xy[m_scan + j - 1, 1]
                width[m_scan + j] = width[m_scan + j - 1]
                count[m_scan + j] = count[m_scan + j - 1]
                j -= 1
            bearing[j] = phi
            xy[m_scan + j, 0] = centre_r * math.cos(phi)
            xy[m_scan + j, 1] = centre_r * math.sin(phi)
            width[m_scan + j] = w
            count[m_scan + j] = n
            scan[m] = k
            m += 1
    return xy[:m].copy(), scan[:m].copy(), width[:m].copy(), count[:m].copy()


def extract_detections(
    angles_rad: np.ndarray, ranges_m: np.ndarray, config: LidarFeatureConfig | None = None
) -> list[np.ndarray]:
    """Robot-like detections of K scans, one ``(M_k, 2)`` array per scan (robot frame, m).

    See :func:`extract_clusters` for the parameters; this is ``extract_clusters(...).split()``.
    """
    return extract_clusters(angles_rad, ranges_m, config).split()


def null_bearings(
    angles_rad: np.ndarray,
    ranges_m: np.ndarray,
    intensities: np.ndarray,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """Bearings of null returns (range 0 and intensity 0), for the interference P_d factor.

    Parameters
    ----------
    angles_rad : ndarray, shape (B,)
    ranges_m, intensities : ndarray, shape (B,)
        One scan.
    exclude : ndarray, shape (B,), bool, optional
        Beams never to report, e.g. ``LidarSensor.blind_mask``: the camera pillars also
        return range 0 / intensity 0, and the filter already has a blind-sector factor.

    Returns
    -------
    ndarray, shape (M,)
        Robot-frame bearings in ``[-pi, pi)``, increasing.
    """
    null = (np.asarray(ranges_m) == 0.0) & (np.asarray(intensities) == 0.0)
    if exclude is not None:
        null &= ~np.asarray(exclude, dtype=bool)
    return wrap_angle(np.asarray(angles_rad, dtype=np.float64)[null])


def null_beams(
    ranges_m: np.ndarray, intensities: np.ndarray, exclude: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Null returns of K scans at once (the batched :func:`null_bearings`, one compiled pass).

    Parameters
    ----------
    ranges_m, intensities : ndarray, shape (K, B)
    exclude : ndarray, shape (B,), bool, optional
        Beams never to report (the blind sectors).

    Returns
    -------
    bounds : ndarray, shape (K + 1,), int
        Scan k's nulls are ``beams[bounds[k]:bounds[k + 1]]``.
    beams : ndarray, shape (M,), int
        Beam indices of the nulls (range 0 and intensity 0), increasing within each scan.
    """
    ranges = np.ascontiguousarray(np.atleast_2d(ranges_m), dtype=np.float64)
    intens = np.ascontiguousarray(np.atleast_2d(intensities), dtype=np.float64)
    if ranges.shape != intens.shape:
        raise ValueError(
            f"null_beams: intensities of shape {intens.shape} for ranges of shape {ranges.shape}"
        )
    if exclude is None:
        exclude = np.zeros(ranges.shape[1], dtype=np.bool_)
    return _null_kernel(ranges, intens, np.asarray(exclude, dtype=np.bool_))


@njit(cache=True)
def _null_kernel(ranges, intensities, exclude):
    """``bounds`` (K + 1,) and ``beams`` (M,) of the beams with range 0 and intensity 0 that
    are not ``exclude``d, scan by scan."""
    n_scans, n_beams = ranges.shape
    beams = np.empty(n_scans * n_beams, dtype=np.intp)
    bounds = np.empty(n_scans + 1, dtype=np.intp)
    m = 0
    for k in range(n_scans):
        bounds[k] = m
        for b in range(n_beams):
            if ranges[k, b] == 0.0 and intensities[k, b] == 0.0 and not exclude[b]:
                beams[m] = b
                m += 1
    bounds[n_scans] = m
    return bounds, beams[:m].copy()
