"""Sensor diagnostics: how often each sensor detects, misses and hallucinates, checked against the
simulator's truth at the instant of each scan or frame (not at the end of the env step)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SensorStats:
    """Running counts for one sensor over all robots.

    ``targets_in_range`` counts (scan, robot) pairs with the robot inside ``range_m``;
    ``missed`` those with no measurement within the match gate; ``false_positives`` measurements
    matching no robot at all (any range). Rates are ``missed / targets_in_range`` and
    ``false_positives / measurements``.
    """

    range_m: float
    gate: float
    scans: int = 0
    measurements: int = 0
    false_positives: int = 0
    targets_in_range: int = 0
    missed: int = 0

    def summary(self) -> dict[str, float]:
        return {
            "scans": self.scans,
            "measurements_per_scan": self.measurements / max(self.scans, 1),
            "false_positive_rate": self.false_positives / max(self.measurements, 1),
            "missed_detection_rate": self.missed / max(self.targets_in_range, 1),
            "range_m": self.range_m,
        }

    def add_points(self, detections: np.ndarray, targets: np.ndarray) -> None:
        """Position measurements (M, 2) against true targets (T, 2), both in the sensor frame."""
        self.scans += 1
        self.measurements += len(detections)
        in_range = np.hypot(targets[:, 0], targets[:, 1]) <= self.range_m
        if len(detections) == 0:
            self.targets_in_range += int(in_range.sum())
            self.missed += int(in_range.sum())
            return
        d = np.linalg.norm(detections[:, None, :] - targets[None, :, :], axis=-1)  # (M, T)
        close = d <= self.gate
        self.false_positives += int((~close.any(axis=1)).sum())
        self.targets_in_range += int(in_range.sum())
        self.missed += int((in_range & ~close.any(axis=0)).sum())

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
