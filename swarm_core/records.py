"""Measurement records: what a World hands to the localizers, in simulation and on real robots.

Every record is stamped in seconds of the World's clock (sim time, or the robots' synchronised
ROS time) and expressed in the measuring robot's body frame (REP-103: x forward, y left, yaw
counter-clockwise, metres, radians). Records are immutable; arrays inside them are read-only
views of what the producer passed in (no copy), so a producer must not write to an array after
making a record of it. ``Record._make(...)`` (the fields' values in their order) skips the
checks, for producers (the simulator) that already hold read-only float64 arrays of the
documented shapes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_F64 = np.dtype(np.float64)
_new = object.__new__
_set = object.__setattr__


def _frozen(array: np.ndarray, shape: tuple[int, ...] | None = None, ndim: int = 0) -> np.ndarray:
    """A read-only float64 view of ``array`` (reshaped to ``shape``, or flattened if ``ndim``
    is 1). Not a copy: records are made on the hot path (about a hundred per env step), and
    producers hand over arrays they no longer write to."""
    if array.__class__ is np.ndarray and array.dtype is _F64 and not array.flags.writeable:
        # Fast path: already a read-only view (e.g. a row of a frozen batch) of the right shape.
        if shape is None:
            if ndim != 1 or array.ndim == 1:
                return array
        elif array.shape == shape or (
            len(shape) == array.ndim
            and all(s in (-1, a) for s, a in zip(shape, array.shape, strict=True))
        ):
            return array
    if type(array) is not np.ndarray or array.dtype != np.float64:
        array = np.asarray(array, dtype=np.float64)
    if shape is not None:
        out = array.reshape(shape)
    elif ndim == 1 and array.ndim != 1:
        out = array.reshape(-1)
    else:
        out = array.view()
    out.setflags(write=False)
    return out


def _unchecked(cls: type, *values: object) -> object:
    """The records' ``_make``: a ``cls`` whose slots (its dataclass fields, in order) hold
    ``values``, without ``__init__`` and ``__post_init__``. Unchecked: the arrays must already be
    read-only float64 of the documented shapes (see :func:`_frozen`)."""
    record = _new(cls)
    for name, value in zip(cls.__slots__, values, strict=False):  # unchecked, as the rest
        _set(record, name, value)
    return record


@dataclass(frozen=True, slots=True)
class OdometryRecord:
    """Own motion between the previous odometry sample and ``stamp_s``.

    Attributes
    ----------
    stamp_s : float
        End of the interval, seconds.
    delta : ndarray, shape (3,)
        ``[dx_m, dy_m, dpsi_rad]``: the displacement of the robot expressed in its body frame at
        the *start* of the interval, and its heading change (counter-clockwise positive).
    velocity : ndarray, shape (2,)
        ``[v_mps, omega_radps]`` averaged over the interval (the policy's own speed).
    """

    stamp_s: float
    delta: np.ndarray
    velocity: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "delta", _frozen(self.delta, shape=(3,)))
        object.__setattr__(self, "velocity", _frozen(self.velocity, shape=(2,)))

    _make = classmethod(_unchecked)


@dataclass(frozen=True, slots=True)
class LidarRecord:
    """One lidar revolution and what the feature extractor found in it.

    Attributes
    ----------
    stamp_s : float
        Time of the scan, seconds.
    angles_rad : ndarray, shape (B,)
        Beam bearings in the robot frame, in [-pi, pi).
    ranges_m : ndarray, shape (B,)
        Measured range; ``0.0`` means no valid return (as the YDLidar driver reports it).
    intensities : ndarray, shape (B,)
        Return intensity; ``0`` with range ``0`` marks a null return (e.g. lidar interference).
    detections : ndarray, shape (M, 2)
        Robot-like clusters (width <= ~65 mm), centre estimates ``[x_m, y_m]`` in the robot frame.
    null_bearings_rad : ndarray, shape (K,)
        Bearings of null returns (range 0 and intensity 0), for the interference P_d factor.
    """

    stamp_s: float
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    intensities: np.ndarray
    detections: np.ndarray
    null_bearings_rad: np.ndarray

    def __post_init__(self) -> None:
        for name in ("angles_rad", "ranges_m", "intensities", "null_bearings_rad"):
            object.__setattr__(self, name, _frozen(getattr(self, name), ndim=1))
        object.__setattr__(self, "detections", _frozen(self.detections, shape=(-1, 2)))

    _make = classmethod(_unchecked)


@dataclass(frozen=True, slots=True)
class CameraRecord:
    """One camera frame (front + back fisheye fused): bearings of red colour blobs.

    Attributes
    ----------
    stamp_s : float
        Time of the frame, seconds.
    bearings_rad : ndarray, shape (M,)
        Bearings in the robot frame, wrapped to [-pi, pi).
    """

    stamp_s: float
    bearings_rad: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "bearings_rad", _frozen(self.bearings_rad, ndim=1))

    _make = classmethod(_unchecked)


@dataclass(frozen=True, slots=True)
class Broadcast:
    """What one robot told its teammates over the radio (Stegagno 2012 ch. 5-6, Stegagno 2013).

    Robots are anonymous to each other's sensors, but not on the radio: a broadcast names its
    sender. Its contents are in the sender's own frames, so a receiver needs no shared frame.

    Attributes
    ----------
    sender : str
        The sending robot's id (``"ugv_3"``).
    stamp_s : float
        When the sender sent it, seconds of the World's clock. Receivers get it later (latency).
    odometry_pose : ndarray, shape (3,)
        ``[x_m, y_m, yaw_rad]``: the sender's dead-reckoned pose since its start, in its
        odometry frame (its own wheel odometry integrated, drift included).
    detections : ndarray, shape (M, 2)
        The sender's latest anonymous lidar detections, ``[x_m, y_m]`` in its body frame.
    detections_stamp_s : float
        Stamp of the scan ``detections`` came from (``nan`` before the first scan).
    bearings_rad : ndarray, shape (M,)
        The sender's latest camera frame: anonymous red-blob bearings in its body frame (the
        camera sits at the body origin), wrapped to ``[-pi, pi)``; empty by default.
    bearings_stamp_s : float
        Stamp of that frame (``nan`` before the first frame, or when the sender shares none).
    """

    sender: str
    stamp_s: float
    odometry_pose: np.ndarray
    detections: np.ndarray
    detections_stamp_s: float = float("nan")
    bearings_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    bearings_stamp_s: float = float("nan")

    def __post_init__(self) -> None:
        if not isinstance(self.sender, str) or not self.sender:
            raise ValueError(f"Broadcast.sender must be a robot id, got {self.sender!r}")
        stamp = self.stamp_s
        if isinstance(stamp, bool) or not isinstance(stamp, (int, float, np.integer, np.floating)):
            raise ValueError(f"Broadcast.stamp_s must be a number of seconds, got {stamp!r}")
        if not np.isfinite(stamp):
            raise ValueError(f"Broadcast.stamp_s must be finite, got {stamp!r}")
        object.__setattr__(self, "odometry_pose", _frozen(self.odometry_pose, shape=(3,)))
        object.__setattr__(self, "detections", _frozen(self.detections, shape=(-1, 2)))
        if np.ndim(self.bearings_rad) != 1:
            raise ValueError(
                f"Broadcast.bearings_rad must be a 1-D array of bearings, "
                f"got {self.bearings_rad!r}"
            )
        object.__setattr__(self, "bearings_rad", _frozen(self.bearings_rad, ndim=1))
        b_stamp = self.bearings_stamp_s
        if isinstance(b_stamp, bool) or not isinstance(
            b_stamp, (int, float, np.integer, np.floating)
        ):
            raise ValueError(
                f"Broadcast.bearings_stamp_s must be a number of seconds (nan: no frame), "
                f"got {b_stamp!r}"
            )


@dataclass(frozen=True, slots=True)
class RobotMeasurements:
    """Everything one robot measured during one env step, each list sorted by stamp."""

    odometry: list[OdometryRecord] = field(default_factory=list)
    lidar: list[LidarRecord] = field(default_factory=list)
    camera: list[CameraRecord] = field(default_factory=list)

    _make = classmethod(_unchecked)  # without the dataclass machinery (20 per sim step)

    def in_time_order(self) -> list[OdometryRecord | LidarRecord | CameraRecord]:
        """All records merged by stamp; on equal stamps odometry comes first (predict first)."""
        merged = [*self.odometry, *self.lidar, *self.camera]
        return sorted(merged, key=_time_order_key)


_KIND_ORDER = {OdometryRecord: 0, LidarRecord: 1, CameraRecord: 2}


def _time_order_key(record: OdometryRecord | LidarRecord | CameraRecord) -> tuple[float, int]:
    """Sort key of :meth:`RobotMeasurements.in_time_order`: stamp, then odometry < lidar <
    camera (a stable sort keeps each kind's list order on ties)."""
    return record.stamp_s, _KIND_ORDER[type(record)]
