"""Sensor diagnostics: how often each sensor detects, misses and hallucinates, checked against the
simulator's truth at the instant of each scan or frame (not at the end of the env step)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from swarm_core.records import LidarRecord

#: Why a lidar scan missed a robot within range, from the simulator's own beam counts on its
#: housing (:meth:`SensorStats.add_points`): ``"hidden"``, fewer than the extractor's minimum
#: returns reached the housing (occlusion, a blind sector, or too few beams at that range);
#: ``"interfered"``, enough reached it but the other robot's lidar nulled all but fewer than
#: that; ``"extractor"``, enough valid returns came back and the cluster extractor did not
#: report it (split, merged with a neighbour, or rejected by its shape tests). The split is by
#: counts, not by mechanism: ``"hidden"`` also holds returns outside the valid range, and
#: ``"extractor"`` holds interference that broke a run of returns without leaving fewer than the
#: minimum, robots partly behind nearer ones, and clusters reported beyond the match gate.
LIDAR_MISS_CAUSES = ("hidden", "interfered", "extractor")


@dataclass(frozen=True, slots=True)
class LidarScanTruth:
    """One period's lidar scans beside the simulator's truth at each scan's instant: what a
    :data:`LidarScanObserver` receives (``SimWorld.lidar_scan_observers``), for calibrating a
    filter's detection model against the sensor.

    Attributes
    ----------
    robots : ndarray, shape (K,), int
        The robot that took each scan.
    relative_xy : ndarray, shape (K, N + E, 2)
        Every body (agents, then extra robots) in the scanning robot's body frame at the
        scan's instant (m; the scanner itself at the origin).
    beams_reaching, beams_returned : ndarray, shape (K, N + E), int
        Beams of each scan that hit each body's housing, before and after interference nulling.
    records : tuple of LidarRecord, length K
        The scans as the robots received them (detections, null bearings).

    The arrays are read-only: every observer of the period sees the same ones.
    """

    robots: np.ndarray
    relative_xy: np.ndarray
    beams_reaching: np.ndarray
    beams_returned: np.ndarray
    records: tuple[LidarRecord, ...]


#: A callable that ``SimWorld`` hands each period's :class:`LidarScanTruth` (diagnostics only:
#: it must not change the arrays).
LidarScanObserver = Callable[[LidarScanTruth], None]


@dataclass
class SensorStats:
    """Running counts for one sensor over all robots.

    ``targets_in_range`` counts (scan, robot) pairs with the robot inside ``range_m``;
    ``missed`` those with no measurement within the match gate; ``false_positives`` measurements
    matching no robot at all (any range). Rates are ``missed / targets_in_range`` and
    ``false_positives / measurements``. ``missed_by_cause`` splits the lidar's misses by
    :data:`LIDAR_MISS_CAUSES` when the scans' beam counts are given.
    """

    range_m: float
    gate: float
    scans: int = 0
    measurements: int = 0
    false_positives: int = 0
    targets_in_range: int = 0
    missed: int = 0
    missed_by_cause: dict[str, int] = field(default_factory=dict)

    def summary(self) -> dict[str, float | dict[str, float]]:
        out: dict[str, float | dict[str, float]] = {
            "scans": self.scans,
            "measurements_per_scan": self.measurements / max(self.scans, 1),
            "false_positive_rate": self.false_positives / max(self.measurements, 1),
            "missed_detection_rate": self.missed / max(self.targets_in_range, 1),
            "range_m": self.range_m,
        }
        if self.missed_by_cause:
            # Each cause's share of the targets in range: the shares sum to the missed rate
            # when every call passed beam counts (the simulator's lidar does).
            out["missed_rate_by_cause"] = {
                cause: n / max(self.targets_in_range, 1)
                for cause, n in self.missed_by_cause.items()
            }
        return out

    def add_points(
        self,
        detections: np.ndarray,
        targets: np.ndarray,
        beams_reaching: np.ndarray | None = None,
        beams_returned: np.ndarray | None = None,
        *,
        min_beams: int | None = None,
    ) -> None:
        """Position measurements (M, 2) against true targets (T, 2), both in the sensor frame.

        ``beams_reaching`` and ``beams_returned`` (T,), optional: the scan's beams that hit
        each target's housing before and after interference nulling
        (:meth:`~swarm_env.sensors.lidar.LidarScanBatch.owner_beam_counts`); with them each miss
        is counted under its cause (:data:`LIDAR_MISS_CAUSES`), ``min_beams`` (required with
        them) being the extractor's minimum returns per cluster."""
        counted = beams_reaching is not None or beams_returned is not None
        if counted and (beams_reaching is None or beams_returned is None or min_beams is None):
            raise ValueError(
                "add_points needs beams_reaching, beams_returned and min_beams together, got "
                f"beams_reaching={beams_reaching!r}, beams_returned={beams_returned!r}, "
                f"min_beams={min_beams!r}"
            )
        self.scans += 1
        self.measurements += len(detections)
        in_range = np.hypot(targets[:, 0], targets[:, 1]) <= self.range_m
        if len(detections):
            d = np.linalg.norm(detections[:, None, :] - targets[None, :, :], axis=-1)  # (M, T)
            close = d <= self.gate
            self.false_positives += int((~close.any(axis=1)).sum())
            missed = in_range & ~close.any(axis=0)
        else:
            missed = in_range
        self.targets_in_range += int(in_range.sum())
        self.missed += int(missed.sum())
        if not counted:
            return
        hidden = beams_reaching < min_beams
        interfered = ~hidden & (beams_returned < min_beams)
        for cause, where in zip(
            LIDAR_MISS_CAUSES, (hidden, interfered, ~hidden & ~interfered), strict=True
        ):
            self.missed_by_cause[cause] = self.missed_by_cause.get(cause, 0) + int(
                (missed & where).sum()
            )

    def add_bearings(self, bearings: np.ndarray, targets: np.ndarray) -> None:
        """Bearing measurements (M,) against true targets (T, 2) in the sensor frame."""
        self.scans += 1
        self.measurements += len(bearings)
        in_range = np.hypot(targets[:, 0], targets[:, 1]) <= self.range_m
        self.targets_in_range += int(in_range.sum())
        if len(bearings) == 0:
            self.missed += int(in_range.sum())
            return
        true_b = np.arctan2(targets[:, 1], targets[:, 0])
        diff = np.abs((bearings[:, None] - true_b[None, :] + np.pi) % (2 * np.pi) - np.pi)
        # Only targets the camera could see count as explanations of a bearing.
        close = (diff <= self.gate) & in_range[None, :]
        self.false_positives += int((~close.any(axis=1)).sum())
        self.missed += int((in_range & ~close.any(axis=0)).sum())
