"""Lidar feature extractor: robot-sized clusters of a scan become position measurements.

The seed (000, "Lidar measurements") segments each scan into clusters of consecutive returns and
keeps the objects narrower than the 65 mm lidar housing of a teammate, reported as a point in the
scanner's body frame. By construction:

* decoy posts (radius <= 32.5 mm) pass: lidar false positives;
* occluded robots, robots in a blind sector or interfered robots return nothing: false negatives;
* walls and large obstacles form wide clusters and are rejected, except small fragments where a
  nearer object cuts a wall into a narrow visible sliver (a realistic false positive, rare at the
  seed's 2 m tracking range);
* two robots touching side by side merge into one wide cluster: both are missed.

Everything is vectorised over (scans x beams): clusters are labelled with a cumulative sum of
cluster starts and reduced with ``np.bincount``; no Python loop over beams or clusters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm_env.sensors.geometry import wrap_angle


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
        Keep clusters whose end-to-end width is at most this: the 65 mm housing diameter with a
        20 % tolerance for range noise at the cluster edges (seed: "arc length below 65 mm").
    min_beams : int
        Minimum returns in a kept cluster.
    housing_radius_m : float
        The centre estimate is pushed this far behind the mean return, along the beam.
    tracking_range_m : float
        Detections whose centre is farther are dropped. The seed limits the lidar to 2 m for
        teammate detection ("the range of the lidar is limited to 2m", sec. 3.2), and its
        filter's range P_d (eq. 19) is built for that limit; beyond it a 65 mm housing returns
        only one or two beams and most clusters there are fragments. Raise it together with
        ``PHDConfig.lidar_pd_midpoint_m``.
    foreground_only : bool
        Keep only clusters standing in front of both neighbouring returns (or next to invalid
        returns). A free-standing post or housing always does; a one-beam sliver of a wall
        seen at grazing incidence (beyond what ``jump_range_gain`` keeps connected) or a wall
        fragment showing between two nearer objects does not. Costs the robots partially
        hidden behind a nearer object, whose truncated arc would bias the centre anyway.
        ``False`` gives the seed's plain width test.
    """

    jump_threshold_m: float = 0.05
    jump_range_gain: float = float(np.sin(np.deg2rad(0.5)) / np.sin(np.deg2rad(9.5)))
    max_width_m: float = 0.065 * 1.2
    min_beams: int = 1
    housing_radius_m: float = 0.0325
    tracking_range_m: float = 2.0
    foreground_only: bool = True

    def __post_init__(self) -> None:
        for name in ("jump_threshold_m", "jump_range_gain", "housing_radius_m"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(
                    f"LidarFeatureConfig.{name} must be >= 0, got {getattr(self, name)!r}"
                )
        for name in ("max_width_m", "tracking_range_m"):
            if not getattr(self, name) > 0.0:
                raise ValueError(
                    f"LidarFeatureConfig.{name} must be > 0, got {getattr(self, name)!r}"
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
    cfg = config if config is not None else LidarFeatureConfig()
    ranges = np.atleast_2d(np.asarray(ranges_m, dtype=np.float64))
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    n_scans, n_beams = ranges.shape
    if angles.shape[0] != n_beams:
        raise ValueError(
            f"extract_clusters: {angles.shape[0]} angles for ranges of shape {ranges.shape}"
        )
    valid = ranges > 0.0
    prev = _roll_beams(ranges, 1)
    threshold = np.minimum(ranges, prev)
    threshold *= cfg.jump_range_gain
    threshold += cfg.jump_threshold_m
    # link[k, b]: beam b continues the cluster of beam b-1 (b = 0 links to B-1: the seam).
    prev -= ranges
    link = np.abs(prev, out=prev) <= threshold
    link &= valid
    link &= _roll_beams(valid, 1)
    start = valid & ~link
    end = valid & ~_roll_beams(link, -1)
    # A scan whose valid returns all link around the full circle has no start: call it one
    # cluster from beam 0 to beam B-1 (as wide as the room, so it is rejected below).
    ring = valid.any(axis=1) & ~start.any(axis=1)
    start[ring, 0] = True
    end[ring, n_beams - 1] = True

    # Pair every cluster's first and last beam. Within a scan, starts and ends alternate in
    # column order, except that a cluster through the seam ends (at a small column) before
    # its start: unwrap such an end by +B, then sort the ends back into start order.
    s_rows, s_cols = np.divmod(np.flatnonzero(start), n_beams)
    e_rows, e_cols = np.divmod(np.flatnonzero(end), n_beams)
    first_start = np.full(n_scans, n_beams, dtype=np.intp)
    first_start[s_rows[::-1]] = s_cols[::-1]  # reversed: the smallest column is written last
    e_cols += n_beams * (e_cols < first_start[e_rows])
    # Row-major order of (row, unwrapped column): one integer sort.
    e_cols = np.sort(e_rows * (2 * n_beams) + e_cols) % (2 * n_beams)
    count = e_cols - s_cols + 1
    e_wrapped = e_cols % n_beams
    r_s, r_e = ranges[s_rows, s_cols], ranges[s_rows, e_wrapped]
    cos_a, sin_a = np.cos(angles), np.sin(angles)
    width = np.hypot(
        r_e * cos_a[e_wrapped] - r_s * cos_a[s_cols], r_e * sin_a[e_wrapped] - r_s * sin_a[s_cols]
    )
    keep = (count >= cfg.min_beams) & (width <= cfg.max_width_m) & (count < n_beams)
    if cfg.foreground_only:
        # Neighbours just outside the cluster: farther, or no return, for a standalone object.
        before = ranges[s_rows, s_cols - 1]  # column -1 wraps to B-1: the seam
        after = ranges[s_rows, (e_wrapped + 1) % n_beams]
        keep &= (before == 0.0) | (before > r_s)
        keep &= (after == 0.0) | (after > r_e)

    # Range and bearing means over the (few) surviving clusters only.
    s_rows, s_cols, count, width = s_rows[keep], s_cols[keep], count[keep], width[keep]
    offsets = np.cumsum(count) - count
    beam = np.repeat(s_cols - offsets, count) + np.arange(int(count.sum()))
    beam %= n_beams
    r = ranges[np.repeat(s_rows, count), beam]
    if count.size:
        mean_r = np.add.reduceat(r, offsets) / count
        bearing = np.arctan2(
            np.add.reduceat(sin_a[beam], offsets), np.add.reduceat(cos_a[beam], offsets)
        )
    else:
        mean_r = bearing = np.zeros(0)
    centre_r = mean_r + cfg.housing_radius_m
    near = centre_r <= cfg.tracking_range_m
    xy = np.stack((centre_r * np.cos(bearing), centre_r * np.sin(bearing)), axis=1)[near]
    scan, width, count = s_rows[near], width[near], count[near]
    # Sort by scan then bearing (a seam cluster is found first but may belong last).
    order = np.lexsort((bearing[near], scan))
    return LidarDetections(
        xy_m=xy[order],
        scan_index=scan[order],
        width_m=width[order],
        n_beams=count[order],
        n_scans=n_scans,
    )


def _roll_beams(a: np.ndarray, shift: int) -> np.ndarray:
    """``np.roll(a, shift, axis=1)`` for shift +-1, as two slice copies (np.roll is ~5x slower)."""
    out = np.empty_like(a)
    if shift == 1:
        out[:, 1:] = a[:, :-1]
        out[:, 0] = a[:, -1]
    else:
        out[:, :-1] = a[:, 1:]
        out[:, -1] = a[:, 0]
    return out


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
