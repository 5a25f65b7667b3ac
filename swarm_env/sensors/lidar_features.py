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
        Detections whose centre is farther are dropped. The seed's *effective* lidar range is
        ~2 m (few beams hit a 65 mm target beyond); that falloff is modelled by the filter's
        range P_d, so the extractor keeps everything up to the sensor's reach by default.
    """

    jump_threshold_m: float = 0.05
    jump_range_gain: float = float(np.sin(np.deg2rad(0.5)) / np.sin(np.deg2rad(9.5)))
    max_width_m: float = 0.065 * 1.2
    min_beams: int = 1
    housing_radius_m: float = 0.0325
    tracking_range_m: float = 10.0

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
        return [self.xy_m[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


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
    prev = np.roll(ranges, 1, axis=1)
    threshold = cfg.jump_threshold_m + cfg.jump_range_gain * np.minimum(ranges, prev)
    # link[k, b]: beam b continues the cluster of beam b-1 (b = 0 links to B-1: the seam).
    link = valid & (prev > 0.0) & (np.abs(ranges - prev) <= threshold)
    start = valid & ~link
    end = valid & ~np.roll(link, -1, axis=1)
    # A scan whose valid returns all link around the full circle has no start: call it one
    # cluster starting at beam 0 (it is as wide as the room, so it is rejected below).
    ring = valid.any(axis=1) & ~start.any(axis=1)
    start[ring, 0] = True
    end[ring, n_beams - 1] = True

    n_starts = start.sum(axis=1)
    label = np.cumsum(start, axis=1)
    # Beams before a scan's first start belong to its last cluster (it wraps through the seam).
    label = np.where(label == 0, n_starts[:, None], label)
    first = np.cumsum(n_starts) - n_starts
    gid = first[:, None] + label - 1  # global cluster id, meaningful where valid
    n_clusters = int(n_starts.sum())

    cos_a, sin_a = np.cos(angles), np.sin(angles)
    rows, cols = np.nonzero(valid)
    g = gid[rows, cols]
    r = ranges[rows, cols]
    count = np.bincount(g, minlength=n_clusters)
    mean_r = np.bincount(g, weights=r, minlength=n_clusters) / np.maximum(count, 1)
    sum_c = np.bincount(g, weights=cos_a[cols], minlength=n_clusters)
    sum_s = np.bincount(g, weights=sin_a[cols], minlength=n_clusters)
    bearing = np.arctan2(sum_s, sum_c)

    # np.nonzero walks row-major, the order cluster ids were assigned in: the k-th start is
    # cluster k. Ends are scattered by their own id (a seam cluster ends before it starts).
    s_rows, s_cols = np.nonzero(start)
    e_rows, e_cols = np.nonzero(end)
    e_order = np.empty(n_clusters, dtype=np.intp)
    e_order[gid[e_rows, e_cols]] = np.arange(n_clusters)
    e_rows, e_cols = e_rows[e_order], e_cols[e_order]
    r_s, r_e = ranges[s_rows, s_cols], ranges[e_rows, e_cols]
    width = np.hypot(r_e * cos_a[e_cols] - r_s * cos_a[s_cols], r_e * sin_a[e_cols] - r_s * sin_a[s_cols])

    centre_r = mean_r + cfg.housing_radius_m
    keep = (count >= cfg.min_beams) & (width <= cfg.max_width_m)
    keep &= centre_r <= cfg.tracking_range_m
    keep[first[ring]] = False
    xy = np.stack((centre_r * np.cos(bearing), centre_r * np.sin(bearing)), axis=1)
    # Sort by scan then bearing: a seam cluster (labelled last) goes where its bearing says.
    scan = s_rows[keep]
    order = np.lexsort((bearing[keep], scan))
    return LidarDetections(
        xy_m=xy[keep][order],
        scan_index=scan[order],
        width_m=width[keep][order],
        n_beams=count[keep][order],
        n_scans=n_scans,
    )


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
