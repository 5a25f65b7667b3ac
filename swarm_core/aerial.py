"""The UAV's contract with the worlds that carry it: what a real or replayed UAV hands the
supervisor env each step, and how its messages become what its filter consumes.

The ground robots' contract is :mod:`swarm_core.world` and :mod:`swarm_core.records`; this is
the UAV's. A world that carries a UAV (the bridge's ``RealWorld``, the bag's ``ReplayWorld``)
exposes ``uav_id``, ``set_uav_command`` and, after every ``reset()`` / ``step()``,
``last_uav``: a :class:`UAVMessages` of that step's validated pose and detection messages. The
supervisor env (:class:`swarm_env.uav.env.SupervisedSwarmEnv`) turns them into odometry
increments and :class:`AerialFrame` s with a :class:`UAVAssembler`, as the simulated downward
camera (:mod:`swarm_env.sensors.downward_camera`) produces them.

A pose message is anything with ``stamp_ns``, ``x_m``, ``y_m``, ``yaw_rad`` and ``altitude_m``
(``hardware_bridge.messages.UAVPose``); a detections message anything with ``stamp_ns`` and
``points_m`` (``hardware_bridge.messages.GroundDetections``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_core.geometry import wrap_angle
from swarm_core.stamps import ns_to_s


@dataclass(frozen=True, slots=True)
class AerialFrame:
    """One processed frame of the downward camera.

    Attributes
    ----------
    stamp_s : float
    altitude_m : float
        The altitude the frame was taken at (the height sensor's reading).
    half_extents_m : ndarray, shape (2,)
        Footprint half extents along the UAV's x and y axes (m).
    detections : ndarray, shape (M, 2)
        Anonymous ``[x_m, y_m]`` in the UAV's level frame, random order.
    source : ndarray, shape (M,) int
        Ground truth for metrics only: the target row of each detection, ``-1`` for clutter.
    """

    stamp_s: float
    altitude_m: float
    half_extents_m: np.ndarray
    detections: np.ndarray
    source: np.ndarray


@dataclass(frozen=True)
class UAVMessages:
    """One step's validated UAV messages (pose and detections messages), oldest first, and the
    UAV's kinds that were stale at the step's end: a world's ``last_uav``."""

    poses: tuple = ()
    detections: tuple = ()
    stale: tuple[str, ...] = ()


def uav_messages(parsed: dict[str, list], stale: Sequence[str] = ()) -> UAVMessages:
    """``{"uav_pose": [...], "uav_detections": [...]}`` (parsed, any order) -> sorted
    :class:`UAVMessages`."""
    poses = sorted(parsed.get("uav_pose", []), key=lambda m: m.stamp_ns)
    frames = sorted(parsed.get("uav_detections", []), key=lambda m: m.stamp_ns)
    return UAVMessages(tuple(poses), tuple(frames), tuple(stale))


def pose_increment(prev: Any, cur: Any) -> np.ndarray:
    """``[dx, dy, dpsi]`` of pose ``cur`` relative to pose ``prev`` (each with ``x_m``, ``y_m``,
    ``yaw_rad``), in ``prev``'s body frame; ``dpsi`` wrapped to ``[-pi, pi)``."""
    c, s = math.cos(prev.yaw_rad), math.sin(prev.yaw_rad)
    dx, dy = cur.x_m - prev.x_m, cur.y_m - prev.y_m
    dpsi = float(wrap_angle(cur.yaw_rad - prev.yaw_rad))
    return np.array([c * dx + s * dy, -s * dx + c * dy, dpsi])


class UAVAssembler:
    """The UAV's pose and detections messages -> what its ID-PHD consumes.

    * Pose: the increment since the previous pose used, in the UAV's level frame at the start
      (:func:`pose_increment`); the first pose after :meth:`reset` only sets the baseline.
      The altitude is kept for the frames.
    * Detections: an :class:`AerialFrame` at the latest altitude, with the footprint of
      ``camera`` (anything with ``half_extents_m(altitude_m)``: the UAV's
      ``DownwardCameraConfig``) there. A frame before any pose has no altitude and raises
      ``ValueError``.
    """

    def __init__(self, camera: Any) -> None:
        if not callable(getattr(camera, "half_extents_m", None)):
            raise ValueError(
                f"camera must be a DownwardCameraConfig (with half_extents_m), got {camera!r}"
            )
        self.camera = camera
        self.reset()

    def reset(self) -> None:
        self._last: Any = None
        self.altitude_m: float | None = None

    def pose(self, msg: Any) -> np.ndarray | None:
        """``[dx, dy, dpsi]`` since the previous pose (``None`` for the first one); poses older
        than the previous one are ignored (``None``)."""
        self.altitude_m = msg.altitude_m
        prev, self._last = self._last, msg
        if prev is None:
            return None
        if msg.stamp_ns <= prev.stamp_ns:
            self._last = prev
            return None
        return pose_increment(prev, msg)

    def frame(self, msg: Any) -> AerialFrame:
        """An :class:`AerialFrame` of the detections (``source`` all ``-1``: no truth on
        hardware)."""
        if self.altitude_m is None:
            raise ValueError("uav detections before any uav pose: the altitude is unknown")
        points = np.asarray(msg.points_m, dtype=np.float64).reshape(-1, 2)
        return AerialFrame(
            ns_to_s(msg.stamp_ns),
            self.altitude_m,
            self.camera.half_extents_m(self.altitude_m),
            points,
            np.full(points.shape[0], -1, dtype=np.int64),
        )
