"""Simulator records -> the ROS messages a real robot publishes. The inverse of
:mod:`hardware_bridge.assembly`, shared by the loopback robot server and ``swarm-phd
export-bag`` so both speak exactly what the bridge expects of a robot:

* odometry: the encoder increments integrated into an odom-frame pose
  (:func:`~hardware_bridge.assembly.integrate_odometry`), ``nav_msgs/Odometry``;
* lidar: ``sensor_msgs/LaserScan`` of the simulated beams;
* camera: ``swarm_phd_msgs/BearingsStamped`` (or the legacy header-less ``Float32MultiArray``
  for the robots named in ``unstamped_bearings``);
* motion capture: the simulator's truth pose, ``geometry_msgs/PoseStamped``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hardware_bridge.assembly import integrate_odometry
from hardware_bridge.messages import (
    bearings_msg,
    bearings_stamped_msg,
    kind_topics,
    laser_scan_msg,
    odometry_msg,
    pose_stamped_msg,
)
from swarm_core.records import RobotMeasurements
from swarm_env.config import SwarmConfig

# Publication order of messages with equal stamps (odometry first, as a robot's base driver).
_ORDER = {"odometry": 0, "lidar": 1, "camera": 2, "mocap": 3}


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One message a simulated robot publishes at sim time ``t_s`` (ROS stamp ``stamp_ns``)."""

    t_s: float
    order: int
    sensor: str
    kind: str
    topic: str
    stamp_ns: int
    msg: dict[str, Any]


class RobotEmitter:
    """Per-robot odom poses plus the message builders.

    Parameters
    ----------
    robot_ids : robots in agent order.
    config : SwarmConfig of the simulator (lidar range limits and rate).
    unstamped_bearings : robots that publish legacy header-less bearings.
    """

    def __init__(
        self,
        robot_ids: Sequence[str],
        config: SwarmConfig,
        *,
        unstamped_bearings: Sequence[str] = (),
    ) -> None:
        self.robot_ids = tuple(robot_ids)
        self.config = config
        self.kinds = {
            r: kind_topics(r, stamped_bearings=r not in set(unstamped_bearings))
            for r in self.robot_ids
        }
        self.odom_pose = {r: np.zeros(3) for r in self.robot_ids}

    def reset(self) -> None:
        """The odom frame starts where each robot stands (publish :meth:`origin` next)."""
        for robot in self.robot_ids:
            self.odom_pose[robot] = np.zeros(3)

    def origin(self, robot: str, stamp_ns: int) -> Outgoing:
        """The odometry message of the odom-frame origin (published once after a reset)."""
        kind, topic = self.kinds[robot]["odometry"]
        return Outgoing(
            0.0, 0, "odometry", kind, topic, stamp_ns, self._odometry(robot, stamp_ns, (0.0, 0.0))
        )

    def _odometry(self, robot: str, stamp_ns: int, velocity) -> dict[str, Any]:
        return odometry_msg(
            stamp_ns,
            *self.odom_pose[robot],
            *(float(v) for v in velocity),
            frame_id=f"{robot}/odom",
            child_frame_id=f"{robot}/base_link",
        )

    def step(
        self,
        robot: str,
        records: RobotMeasurements,
        stamp_ns: Callable[[float], int],
        truth: tuple[float, np.ndarray] | None = None,
    ) -> list[Outgoing]:
        """Messages of one robot's records of one step, sorted by (time, sensor order).
        ``truth = (time_s, pose)`` adds a mocap pose."""
        cfg = self.config
        kinds = self.kinds[robot]
        out: list[Outgoing] = []
        for r in records.odometry:
            self.odom_pose[robot] = integrate_odometry(self.odom_pose[robot], r.delta)
            t = stamp_ns(r.stamp_s)
            kind, topic = kinds["odometry"]
            msg = self._odometry(robot, t, r.velocity)
            out.append(Outgoing(r.stamp_s, _ORDER["odometry"], "odometry", kind, topic, t, msg))
        scan_time = 1.0 / cfg.lidar.rate_hz
        for r in records.lidar:
            t = stamp_ns(r.stamp_s)
            kind, topic = kinds["lidar"]
            msg = laser_scan_msg(
                t,
                r.angles_rad,
                r.ranges_m,
                r.intensities,
                range_min_m=cfg.lidar.range_min_m,
                range_max_m=cfg.lidar.range_max_m,
                scan_time_s=scan_time,
                frame_id=f"{robot}/laser",
            )
            out.append(Outgoing(r.stamp_s, _ORDER["lidar"], "lidar", kind, topic, t, msg))
        for r in records.camera:
            t = stamp_ns(r.stamp_s)
            kind, topic = kinds["camera"]
            if kind == "camera_stamped":
                msg = bearings_stamped_msg(t, r.bearings_rad, frame_id=f"{robot}/camera")
            else:
                msg = bearings_msg(r.bearings_rad)
            out.append(Outgoing(r.stamp_s, _ORDER["camera"], "camera", kind, topic, t, msg))
        if truth is not None:
            time_s, pose = truth
            t = stamp_ns(time_s)
            kind, topic = kinds["mocap"]
            msg = pose_stamped_msg(t, *pose)
            out.append(Outgoing(time_s, _ORDER["mocap"], "mocap", kind, topic, t, msg))
        out.sort(key=lambda o: (o.t_s, o.order))
        return out
