"""From measurement records to filter calls: the one seam between every World and every localizer.

A World (simulator, real robots, bag replay) hands over, per env step, each robot's stamped
records (:mod:`swarm_core.records`) and the sensors it reports stale. :class:`SwarmFeed` is that
step as the localizers see it, for the whole swarm; :func:`localizer_calls` turns one robot's
records into its time-ordered filter calls, with **motion compensation**: each lidar scan and
camera frame gets its sensor pose in the filter's frame (the robot's pose at its last odometry
sample). Every localizer family (:mod:`localization.registry`) consumes the same feed, so the
env, ``swarm-phd evaluate``, the bridge and the replay all feed filters the same way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from swarm_core.records import LidarRecord, OdometryRecord, RobotMeasurements
from swarm_core.world import GroundTruth, WorldStep

__all__ = ["SwarmFeed", "localizer_calls", "Call"]

#: One filter call: ``("predict", delta (3,))``, ``("lidar", detections (M, 2), null_bearings
#: (K,), sensor_pose (3,) or None)``, ``("camera", bearings (M,), sensor_pose (3,) or None)``
#: or ``("advance", stamp_s)``.
Call = tuple

_EMPTY = RobotMeasurements()


@dataclass(frozen=True, eq=False)
class SwarmFeed:
    """One env step of measurements for every robot, in robot-index order.

    Attributes
    ----------
    time_s : float
        End of the step, seconds of the World's clock.
    measurements : sequence of RobotMeasurements, length R
        Robot ``r``'s records of the step (each list sorted by stamp).
    stale : sequence of tuple of str, length R
        Sensors (``"odometry"``, ``"lidar"``, ``"camera"``) the World reports silent for robot
        ``r``; their records, if any, are not used.
    truth : GroundTruth or None
        Ground truth, for the oracle-identity baselines only (``ukf``, ``pf``); the anonymous
        localizers never read it.
    compensate_motion : bool
        Give each scan / frame its sensor pose (see :func:`localizer_calls`).
    """

    time_s: float
    measurements: Sequence[RobotMeasurements]
    stale: Sequence[tuple[str, ...]]
    truth: GroundTruth | None = None
    compensate_motion: bool = True
    _calls: list = field(default_factory=list, init=False, repr=False, compare=False)

    @classmethod
    def from_world_step(
        cls, step: WorldStep, robot_ids: Sequence[str], compensate_motion: bool = True
    ) -> SwarmFeed:
        """The feed of ``step`` for the robots ``robot_ids`` (their order is the index order)."""
        return cls(
            time_s=step.time_s,
            measurements=[step.measurements.get(r, _EMPTY) for r in robot_ids],
            stale=[tuple(step.stale.get(r, ())) for r in robot_ids],
            truth=step.truth,
            compensate_motion=compensate_motion,
        )

    @classmethod
    def concat(cls, feeds: Sequence[SwarmFeed]) -> SwarmFeed:
        """One feed of the robots of ``feeds`` in order (several env copies sharing one
        localizer); truth is dropped (the oracle baselines need a single World's truth)."""
        if not feeds:
            raise ValueError("concat() needs at least one feed")
        if len({f.compensate_motion for f in feeds}) > 1:
            raise ValueError("concat() needs feeds with the same compensate_motion")
        feed = cls(
            time_s=max(f.time_s for f in feeds),
            measurements=[m for f in feeds for m in f.measurements],
            stale=[s for f in feeds for s in f.stale],
            truth=None,
            compensate_motion=feeds[0].compensate_motion,
        )
        feed._calls.extend(c for f in feeds for c in f.calls())  # each robot's, computed once
        return feed

    @classmethod
    def empty(cls, n_robots: int, time_s: float = 0.0) -> SwarmFeed:
        """A feed in which no robot measured anything (a no-op for every localizer)."""
        return cls(time_s, [_EMPTY] * n_robots, [()] * n_robots)

    @property
    def n_robots(self) -> int:
        return len(self.measurements)

    def calls(self) -> list[list[Call]]:
        """Every robot's time-ordered filter calls (computed once, shared by all localizers)."""
        if not self._calls:
            self._calls.extend(
                localizer_calls(m, s, self.compensate_motion)
                for m, s in zip(self.measurements, self.stale, strict=True)
            )
        return self._calls


def localizer_calls(
    records: RobotMeasurements, stale=(), compensate_motion: bool = True
) -> list[tuple]:
    """One robot's records as time-ordered filter calls, skipping ``stale`` sensors.

    ``("predict", delta)`` for odometry, ``("lidar", detections, null_bearings)`` and
    ``("camera", bearings)``, each after an ``("advance", stamp_s)``, as every bank's
    ``apply`` takes them.

    The filter's frame is the robot's pose at its **last odometry sample**, but a scan or a
    frame is taken up to one odometry period (0.1 s) later, from wherever the robot has moved
    and turned since (at 1.5 rad/s, 0.15 rad: 0.3 m at 2 m). With ``compensate_motion`` (the
    default) each lidar / camera record that has a later odometry sample in ``records`` gets
    its **sensor pose** in the frame of the last sample, from the robot's own motion up to its
    stamp: the next sample's motion ``delta`` minus its constant-velocity remainder
    ``velocity * tau`` over the ``tau`` seconds from the stamp to that sample (see
    :func:`_motion_since_sample`). The filter moves detections exactly, rotates bearings
    (:mod:`localization.frames`) and evaluates their model from the camera's position (the
    parallax a bearing cannot carry). Only the robot's own odometry is used. A record after the
    step's last odometry sample goes in uncompensated (in the simulator none is: odometry
    samples fall on step ends; on a real robot with unsynchronised odometry some are).

    Calls: ``("predict", delta)``, ``("lidar", detections, null_bearings, sensor_pose)`` and
    ``("camera", bearings, sensor_pose)``, ``sensor_pose`` a ``(3,)`` array or None. Each is
    preceded by ``("advance", stamp_s)``, the record's stamp: a filter with
    ``time_update == "measurement"`` adds the process noise that accrued up to it first
    (:meth:`localization.RobotCentricPHD.advance`); the others only move a clock.
    """
    ordered = records.in_time_order()
    use_odometry = "odometry" not in stale
    use_lidar, use_camera = "lidar" not in stale, "camera" not in stale
    compensate = compensate_motion and use_odometry
    calls: list[tuple] = []
    # Walk backwards so each measurement knows the next odometry sample (None after the last).
    upcoming: OdometryRecord | None = None
    for record in reversed(ordered):
        if isinstance(record, OdometryRecord):
            upcoming = record
            if use_odometry:
                calls.append(("predict", record.delta))
                calls.append(("advance", record.stamp_s))  # reversed below: goes first
            continue
        pose = None
        if compensate and upcoming is not None and upcoming.stamp_s > record.stamp_s:
            pose = _motion_since_sample(upcoming, upcoming.stamp_s - record.stamp_s)
        if isinstance(record, LidarRecord):
            if use_lidar:
                calls.append(("lidar", record.detections, record.null_bearings_rad, pose))
                calls.append(("advance", record.stamp_s))
        elif use_camera:
            calls.append(("camera", record.bearings_rad, pose))
            calls.append(("advance", record.stamp_s))
    calls.reverse()
    return calls


def _motion_since_sample(odo: OdometryRecord, tau_s: float) -> np.ndarray:
    """Pose ``(x, y, psi)`` of the robot ``tau_s`` seconds before odometry sample ``odo``,
    in the frame of the previous sample.

    ``odo.delta`` is the motion from the previous sample to ``odo``; the last ``tau_s`` of it
    is taken at the interval's mean speed ``odo.velocity = (v, omega)``: turn
    ``psi_r = omega tau``, chord ``t_r = v tau (cos(psi_r / 2), sin(psi_r / 2))`` in the frame
    at the measurement. Removing it: ``psi = dpsi - psi_r``, ``t = d - R(psi) t_r``.
    """
    dx, dy, dpsi = odo.delta.tolist()
    v, omega = odo.velocity.tolist()
    # Never remove more than the whole interval's motion when tau exceeds it (irregular rates).
    psi_r = omega * tau_s
    if abs(psi_r) > abs(dpsi):
        psi_r = dpsi
    chord = v * tau_s
    psi = dpsi - psi_r
    tx, ty = chord * math.cos(0.5 * psi_r), chord * math.sin(0.5 * psi_r)
    c, s = math.cos(psi), math.sin(psi)
    return np.array([dx - (c * tx - s * ty), dy - (s * tx + c * ty), psi])
