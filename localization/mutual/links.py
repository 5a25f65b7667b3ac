"""What an observer keeps of its own odometry and of each teammate's broadcasts.

Registration compares scans taken at different instants: the observer's at ``t_i``, teammate
``j``'s at ``t_j`` (a lidar turns at 7 Hz, the radio adds latency), while the filters hold ``j``'s
pose at ``j``'s latest broadcast odometry, seen from the observer now. :class:`PoseTrack`
keeps a short stamped history of dead-reckoned poses so that both ends can be moved to the
filters' instants (:func:`to_filter_instant`); at 1.5 rad/s a 0.14 s gap is 12 deg of heading.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm_core.geometry import integrate_body_delta, wrap_angle
from swarm_core.records import Broadcast

from .se2 import compose, inverse_compose, rotation

__all__ = [
    "ObserverLocalizer",
    "PoseTrack",
    "TeammateLink",
    "absorb_broadcasts",
    "next_due",
    "to_filter_instant",
]


def next_due(due_s: float, time_s: float, period_s: float) -> float:
    """The next instant of a periodic schedule that is due at ``time_s`` (s).

    The schedule is the grid ``due_s + k period_s`` (no drift when the callers' steps do not
    divide the period), advanced past ``time_s`` (to within 1e-9 s) when it is more than a period
    behind; ``due_s = -inf`` (never run) anchors the grid at ``time_s``."""
    if not math.isfinite(due_s):
        return time_s + period_s
    return due_s + (math.floor((time_s + 1e-9 - due_s) / period_s) + 1) * period_s


class PoseTrack:
    """Stamped dead-reckoned poses (odometry frame), the newest ``maxlen``."""

    def __init__(self, maxlen: int = 64) -> None:
        self.stamps: deque[float] = deque(maxlen=maxlen)
        self.poses: deque[np.ndarray] = deque(maxlen=maxlen)

    def append(self, stamp_s: float, pose: np.ndarray) -> None:
        self.stamps.append(float(stamp_s))
        self.poses.append(np.asarray(pose, dtype=np.float64).copy())

    def integrate(self, stamp_s: float, delta: np.ndarray) -> None:
        """Append the last pose moved by a body-frame increment (own wheel odometry)."""
        last = self.poses[-1] if self.poses else np.zeros(3)
        self.append(stamp_s, integrate_body_delta(last, delta))

    @property
    def latest(self) -> np.ndarray | None:
        return self.poses[-1] if self.poses else None

    def at(self, stamp_s: float) -> np.ndarray | None:
        """The pose at ``stamp_s``, linearly interpolated (clamped to the history's ends)."""
        if not self.poses:
            return None
        t = np.fromiter(self.stamps, float, len(self.stamps))
        k = int(np.searchsorted(t, stamp_s))
        if k <= 0:
            return self.poses[0].copy()
        if k >= len(t):
            return self.poses[-1].copy()
        a, b = self.poses[k - 1], self.poses[k]
        f = (stamp_s - t[k - 1]) / max(t[k] - t[k - 1], 1e-9)
        out = a + f * (b - a)
        out[2] = wrap_angle(a[2] + f * float(wrap_angle(b[2] - a[2])))
        return out


@dataclass
class TeammateLink:
    """What the observer knows of one teammate from the radio."""

    track: PoseTrack = field(default_factory=PoseTrack)
    stamp_s: float = -math.inf
    detections: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    detections_stamp_s: float = math.nan
    bearings: np.ndarray = field(default_factory=lambda: np.zeros(0))
    bearings_stamp_s: float = math.nan

    @property
    def odometry_pose(self) -> np.ndarray | None:
        return self.track.latest


def absorb_broadcasts(links: dict[str, TeammateLink], broadcasts: list[Broadcast]):
    """Record the broadcasts (in send order; late duplicates dropped) and yield each teammate's
    motion between consecutive ones: ``(sender, v_new (-) v_old)`` (eq. 15's ``u_j``; a radio gap
    is bridged by the same difference)."""
    for b in sorted(broadcasts, key=lambda m: m.stamp_s):
        link = links.get(b.sender)
        if link is None or b.stamp_s <= link.stamp_s:
            continue  # unknown sender, or overtaken by a newer broadcast (jitter)
        previous = link.odometry_pose
        link.track.append(b.stamp_s, b.odometry_pose)
        link.stamp_s = b.stamp_s
        if np.isfinite(b.detections_stamp_s):
            link.detections = np.array(b.detections)
            link.detections_stamp_s = b.detections_stamp_s
        if np.isfinite(b.bearings_stamp_s):
            link.bearings = np.array(b.bearings_rad)
            link.bearings_stamp_s = b.bearings_stamp_s
        if previous is not None:
            yield b.sender, inverse_compose(np.asarray(b.odometry_pose), previous)


def to_filter_instant(
    poses: np.ndarray,
    covariances: np.ndarray,
    own: PoseTrack,
    own_scan_s: float,
    link: TeammateLink,
) -> tuple[np.ndarray, np.ndarray]:
    """Registration poses (H, 3) of ``j``'s frame at its scan in the observer's frame at its
    scan, moved to the filters' instants: the observer now (its latest odometry) and ``j`` at its
    latest broadcast odometry. The covariances (H, 3, 3) turn with the observer's frame (the
    small right-composition with ``j``'s own motion is left out)."""
    p_scan, p_now = own.at(own_scan_s), own.latest
    v_scan, v_last = link.track.at(link.detections_stamp_s), link.track.latest
    out = np.asarray(poses, dtype=np.float64)
    covs = np.asarray(covariances, dtype=np.float64)
    if v_scan is not None and v_last is not None:
        out = compose(out, inverse_compose(v_last, v_scan))
    if p_scan is not None and p_now is not None:
        out = inverse_compose(compose(p_scan, out), p_now)
        g = np.eye(3)
        g[:2, :2] = rotation(float(p_scan[2] - p_now[2]))
        covs = g @ covs @ g.T
    return out, covs


class ObserverLocalizer:
    """What every mutual localizer of one observer starts from: its checked arguments, its own
    dead-reckoned track, one link per teammate and an unanchored registration schedule.

    Subclasses set ``config_type`` (their config dataclass, which has ``update_period_s``) and
    build their filters in ``_init_filters``, called last.

    Parameters
    ----------
    observer : str
        The observer's robot id.
    teammates : sequence of str
        Every robot id it may hear (the observer itself is dropped).
    config : config_type or None
        None: ``config_type()``.
    rng : numpy Generator or None
        The filters' own stream; None: ``default_rng(0)``.
    """

    #: The family's config dataclass (set by every subclass).
    config_type: type

    def __init__(
        self,
        observer: str,
        teammates: tuple[str, ...],
        config: Any = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        check_localizer_args(observer, teammates, config, self.config_type, rng)
        self.observer = observer
        self.teammates = tuple(t for t in teammates if t != observer)
        self.config = config if config is not None else self.config_type()
        self.rng = np.random.default_rng(0) if rng is None else rng
        self.links = {t: TeammateLink() for t in self.teammates}
        self.own_track = PoseTrack()
        self._own_stamp = math.nan
        self._next_update_s = -math.inf  # the first registration anchors the schedule
        self._init_filters()

    def _init_filters(self) -> None:
        """Build the family's filters from ``self.config``, ``self.teammates`` and ``self.rng``."""
        raise NotImplementedError


def check_localizer_args(
    observer: object, teammates: object, config: object, config_type: type, rng: object
) -> None:
    """The mutual localizers' constructor arguments (``config`` and ``rng`` may be ``None``)."""
    if not isinstance(observer, str):
        raise ValueError(f"observer must be a robot id (str), got {observer!r}")
    if (
        isinstance(teammates, str)
        or not hasattr(teammates, "__iter__")
        or not all(isinstance(t, str) for t in teammates)
    ):
        raise ValueError(f"teammates must be a sequence of robot ids (str), got {teammates!r}")
    if config is not None and not isinstance(config, config_type):
        raise ValueError(f"config must be a {config_type.__name__}, got {config!r}")
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator, got {rng!r}")
