"""Detection that fades with range as a stated sigmoid: the Perera 2021 study's sensor curves.

The simulated lidar and cameras detect what their geometry lets them (a 65 mm housing to
1.86 m, a 5 cm strip to 4.7 m). The Perera 2021 study describes its own sensors by the
range factors of its filter instead: the lidar's eq. 19, ``1 / (1.02 + exp(8 (r - 1.5)))``,
and the cameras' eq. 30, ``1 / (1.1 + exp(5 (r - 4)))``. A :class:`RangeFade` on
``SwarmConfig.lidar_fade`` / ``camera_fade`` thins each sensor's detections after the sensor
model: a detection at range ``r`` from the observer is kept with probability ``P(r)``, one
independent draw per detection from the env's one generator (so a seed replays the same
detections). Where the geometric sensor detects with probability 1 the kept fraction is
``P(r)`` itself; beyond its reach (lidar past 1.86 m, camera past 4.7 m) it is
``P(r)`` times the geometric one, and ``P(r)`` is already below 0.05 there.

Functions here are plain numpy on purpose: they run once per control period on the batch of
detections, next to the sensor kernels, and leave those kernels alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm_core.validation import check_number_fields, check_positive


@dataclass(frozen=True, slots=True)
class RangeFade:
    """Detection probability ``P(r) = 1 / (offset + exp(slope_per_m (r - midpoint_m)))``.

    Attributes
    ----------
    offset : float
        Sets the near-range plateau ``1 / offset`` (>= 1, so P <= 1).
    slope_per_m : float
        Steepness of the fade (1/m, > 0).
    midpoint_m : float
        Range (m) at which ``exp`` is 1: ``P = 1 / (offset + 1)`` there.
    """

    offset: float
    slope_per_m: float
    midpoint_m: float

    def __post_init__(self) -> None:
        check_number_fields(self, "RangeFade")
        if not self.offset >= 1.0:
            raise ValueError(f"RangeFade.offset must be >= 1 (P <= 1), got {self.offset!r}")
        check_positive("RangeFade.slope_per_m", self.slope_per_m)
        check_positive("RangeFade.midpoint_m", self.midpoint_m)
        if self.offset > 1e6 or self.slope_per_m > 1e3 or self.midpoint_m > 100.0:
            raise ValueError(
                "RangeFade must have offset <= 1e6, slope_per_m <= 1e3 1/m and midpoint_m <= "
                f"100 m, got {self!r}"
            )

    @classmethod
    def perera2021_lidar(cls) -> RangeFade:
        """The Perera 2021 study's lidar range factor, eq. 19."""
        return cls(offset=1.02, slope_per_m=8.0, midpoint_m=1.5)

    @classmethod
    def perera2021_camera(cls) -> RangeFade:
        """The Perera 2021 study's camera range factor, eq. 30."""
        return cls(offset=1.1, slope_per_m=5.0, midpoint_m=4.0)

    def probability(self, range_m: np.ndarray | float) -> np.ndarray:
        """``P(r)`` for ranges (m), any shape; exp overflow beyond the fade gives 0."""
        r = np.asarray(range_m, dtype=np.float64)
        exponent = np.minimum(self.slope_per_m * (r - self.midpoint_m), 700.0)
        return 1.0 / (self.offset + np.exp(exponent))


def keep_mask(fade: RangeFade, range_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(M,) bool: which of M detections at ``range_m`` (M,) survive the fade (one uniform
    draw each from ``rng``, in order)."""
    range_m = np.asarray(range_m, dtype=np.float64).reshape(-1)
    if range_m.size == 0:
        return np.zeros(0, dtype=bool)
    return rng.random(range_m.size) < fade.probability(range_m)


def thin_points(
    points: list[np.ndarray], fade: RangeFade, rng: np.random.Generator
) -> list[np.ndarray]:
    """Lidar detections of K scans, each ``(M_k, 2)`` in its robot's frame (m), with each
    point kept with probability ``fade.probability(||point||)``. One draw per point, scans in
    order; arrays keep their dtype and are new (the inputs are not modified)."""
    counts = [len(p) for p in points]
    if sum(counts) == 0:
        return [np.asarray(p).copy() for p in points]
    stacked = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points])
    keep = keep_mask(fade, np.hypot(stacked[:, 0], stacked[:, 1]), rng)
    out, start = [], 0
    for p, n in zip(points, counts, strict=True):
        out.append(np.asarray(p)[keep[start : start + n]])
        start += n
    return out


def thin_bearings(
    bearings: list[np.ndarray],
    sources: list[np.ndarray],
    source_xy: np.ndarray,
    observer_xy: np.ndarray,
    fade: RangeFade,
    rng: np.random.Generator,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Camera bearings of K frames thinned by the range of what produced them.

    Parameters
    ----------
    bearings, sources : list of K ndarray, shape (M_k,)
        Each frame's bearings (rad) and the scene circle behind each (-1: clutter).
    source_xy : ndarray, shape (C, 2)
        World position (m) of every scene circle.
    observer_xy : ndarray, shape (K, 2)
        World position (m) of each frame's camera.
    fade, rng
        The fade and the generator (one draw per bearing with a source, frames in order).

    Returns
    -------
    (bearings, sources) : the kept ones, new arrays, order within a frame unchanged. Clutter
    bearings (source -1) have no range and are always kept.
    """
    if len(bearings) != len(sources) or len(bearings) != len(observer_xy):
        raise ValueError(
            f"thin_bearings: {len(bearings)} frames of bearings, {len(sources)} of sources and "
            f"{len(observer_xy)} observer positions must agree"
        )
    counts = [len(s) for s in sources]
    if sum(counts) == 0:
        return [np.asarray(b).copy() for b in bearings], [np.asarray(s).copy() for s in sources]
    src = np.concatenate([np.asarray(s, dtype=np.int64) for s in sources])
    frame = np.repeat(np.arange(len(sources)), counts)
    real = src >= 0
    ranges = np.full(src.size, math.nan)
    delta = source_xy[src[real]] - observer_xy[frame[real]]
    ranges[real] = np.hypot(delta[:, 0], delta[:, 1])
    keep = np.ones(src.size, dtype=bool)
    keep[real] = keep_mask(fade, ranges[real], rng)
    out_b, out_s, start = [], [], 0
    for b, s, n in zip(bearings, sources, counts, strict=True):
        k = keep[start : start + n]
        out_b.append(np.asarray(b)[k])
        out_s.append(np.asarray(s)[k])
        start += n
    return out_b, out_s
