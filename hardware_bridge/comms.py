"""Teammates' broadcasts on real robots: what each robot's radio would carry, from its topics.

In simulation :mod:`swarm_env.comms` models the radio. On real robots every robot already
publishes its odometry (``/<robot>/odom``, a pose in its own odometry frame) and its scans over
the network the bridge listens to, so what the Stegagno 2012 thesis's mutual localization needs
from a teammate (its odometry pose since start and its anonymous detections) is on the wire: this
relay turns each robot's newest ``Odom`` and detections of a step into a
:class:`~swarm_core.records.Broadcast` for every other robot. Loss and latency are the real
network's (a robot whose odometry did not arrive in the step sends nothing), so there is no
simulated channel here; the same relay serves the live bridge and the bag replay, which
therefore reproduce each other's broadcasts.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hardware_bridge.messages import ns_to_s
from swarm_core.records import Broadcast, RobotMeasurements

_NO_DETECTIONS = np.zeros((0, 2))
_NO_BEARINGS = np.zeros(0)


class TeammateRelay:
    """Per step: one broadcast per robot whose odometry arrived, delivered to the others.

    Parameters
    ----------
    robot_ids : sequence of str
        The robots, senders and receivers alike.
    """

    def __init__(self, robot_ids: Sequence[str]) -> None:
        self.robot_ids = tuple(robot_ids)
        self.reset()

    def reset(self) -> None:
        """Forget every robot's last detections (a new episode)."""
        self._detections = {r: (_NO_DETECTIONS, float("nan")) for r in self.robot_ids}
        self._bearings = {r: (_NO_BEARINGS, float("nan")) for r in self.robot_ids}

    def step(
        self, parsed: dict[str, dict[str, list]], measurements: dict[str, RobotMeasurements]
    ) -> dict[str, list[Broadcast]]:
        """Broadcasts of one step.

        Parameters
        ----------
        parsed : dict
            ``robot -> sensor -> [parsed messages]`` of the step, oldest first; the newest
            ``"odometry"`` (:class:`~hardware_bridge.messages.Odom`) is the sender's pose.
        measurements : dict
            ``robot -> RobotMeasurements`` of the step: the newest lidar record's detections
            and the newest camera frame's bearings are what the sender shares (its anonymous
            feature sets, body frame; kept until a newer one arrives).

        Returns
        -------
        dict
            ``receiver -> [Broadcast]``, senders in robot order; a robot never hears itself.
        """
        for robot in self.robot_ids:
            records = measurements.get(robot)
            if records is not None and records.lidar:
                scan = records.lidar[-1]
                self._detections[robot] = (scan.detections, scan.stamp_s)
            if records is not None and records.camera:
                frame = records.camera[-1]  # its camera's red-blob bearings (body frame)
                self._bearings[robot] = (frame.bearings_rad, frame.stamp_s)
        outgoing = []
        for robot in self.robot_ids:
            odometry = parsed.get(robot, {}).get("odometry", [])
            if not odometry:
                continue
            odom = odometry[-1]
            detections, detections_stamp = self._detections[robot]
            bearings, bearings_stamp = self._bearings[robot]
            outgoing.append(
                Broadcast(
                    robot,
                    ns_to_s(odom.stamp_ns),
                    np.array([odom.x_m, odom.y_m, odom.yaw_rad]),
                    detections,
                    detections_stamp,
                    bearings,
                    bearings_stamp,
                )
            )
        return {r: [m for m in outgoing if m.sender != r] for r in self.robot_ids}
