"""Validated messages -> measurement records, shared by the live bridge and the bag replay.

Both :class:`~hardware_bridge.world.RealWorld` and :class:`~hardware_bridge.bag.ReplayWorld`
turn the same parsed messages into records with this code, so a replayed bag feeds the filters
exactly what the live run fed them.

* Odometry: ``nav_msgs/Odometry`` carries a pose in the odom frame. The record of a message is
  the increment since the previous one used, ``delta = R(yaw_prev)^T (p - p_prev)``,
  ``dpsi = wrap(yaw - yaw_prev)``: robot frame at the start of the interval, as the sim's
  encoders report it. The first message after a reset only sets the baseline.
* Lidar: the simulator's own feature extractor
  (:func:`swarm_core.perception.lidar_features.extract_detections` and ``null_bearings``, with the
  configured blind sectors excluded as in the simulator) runs on the scan, batched over all
  scans that share a beam layout.
* Camera: bearings wrapped to ``[-pi, pi)``.
* Ground truth: from motion capture poses when every robot has one no older than the mocap
  stale age at the end of the step (:meth:`RecordAssembler.truth_from_mocap`); relative
  positions and in-range masks as in the simulator; visibility is unknown on real robots.
* Reset: the newest scan and bearing frame of each robot become the reset's records; the newest
  odometry pose only sets the baseline (:meth:`RecordAssembler.reset_selection`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from hardware_bridge.messages import Bearings, Odom, Pose, Scan, ns_to_s
from swarm_core.aerial import pose_increment
from swarm_core.geometry import integrate_body_delta, wrap_angle
from swarm_core.perception.blind_sectors import blind_mask
from swarm_core.perception.lidar_features import extract_detections, null_bearings
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from swarm_core.world import GroundTruth, truth_from_poses
from swarm_env.config import SwarmConfig


def odometry_increment(prev: Odom, cur: Odom) -> np.ndarray:
    """``[dx, dy, dpsi]`` of ``cur`` relative to ``prev``, in ``prev``'s body frame."""
    return pose_increment(prev, cur)


def integrate_odometry(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The inverse of :func:`odometry_increment`: the odom pose ``[x, y, yaw]`` after a
    body-frame increment ``[dx, dy, dpsi]`` (the loopback robots and ``export-bag`` publish
    odometry poses built this way). Yaw wrapped to ``[-pi, pi)``."""
    return integrate_body_delta(pose, delta)


class RecordAssembler:
    """Per-robot odometry baselines and mocap truth poses, plus the stateless lidar and camera
    conversions.

    Parameters
    ----------
    robot_ids, config : the robots (agent order) and the env config.
    jump_factor : float
        Odometry plausibility: a pose further from the baseline than
        ``jump_factor * max_speed * dt + 0.05 m`` (or turned more than
        ``jump_factor * max_turn_rate * dt + 0.1 rad``) is a jump and is not integrated.
    counters : :class:`~hardware_bridge.messages.Counters`, optional
        Receives ``odometry.implausible``.
    """

    JUMP_SLACK_M = 0.05
    JUMP_SLACK_RAD = 0.1
    MAX_BACKSTEP_NS = 1_000_000_000

    def __init__(
        self,
        robot_ids: Sequence[str],
        config: SwarmConfig,
        *,
        jump_factor: float = 3.0,
        counters=None,
    ) -> None:
        self.robot_ids = tuple(robot_ids)
        self.config = config
        self.jump_factor = float(jump_factor)
        self.counters = counters
        self._baseline: dict[str, Odom | None] = {r: None for r in self.robot_ids}
        self._truth_pose: dict[str, Pose | None] = {r: None for r in self.robot_ids}

    def reset(self) -> None:
        for robot in self.robot_ids:
            self._baseline[robot] = None
            self._truth_pose[robot] = None

    def _plausible(self, prev: Odom, cur: Odom) -> bool:
        dt = (cur.stamp_ns - prev.stamp_ns) * 1e-9
        robot = self.config.robot
        reach = self.jump_factor * robot.max_speed_mps * dt + self.JUMP_SLACK_M
        turn = self.jump_factor * robot.max_turn_rate_radps * dt + self.JUMP_SLACK_RAD
        moved = math.hypot(cur.x_m - prev.x_m, cur.y_m - prev.y_m)
        turned = abs(float(wrap_angle(cur.yaw_rad - prev.yaw_rad)))
        return moved <= reach and turned <= turn

    @staticmethod
    def reset_selection(taken: dict[str, dict[str, list]]) -> dict[str, dict[str, list]]:
        """What a reset uses of the messages it waited for: the newest of each sensor per robot
        (items sorted oldest first; any item type, so the live bridge keeps the raw messages)."""
        return {
            robot: {s: list(items)[-1:] for s, items in sensors.items()}
            for robot, sensors in taken.items()
        }

    def reset_measurements(
        self, selected: dict[str, dict[str, list]]
    ) -> dict[str, RobotMeasurements]:
        """Records of a reset from parsed messages chosen by :meth:`reset_selection`: the
        odometry pose only sets the baseline, the scan and bearings are the first records."""
        for robot in self.robot_ids:
            self.odometry(robot, selected.get(robot, {}).get("odometry", []))
        return self.measurements(
            {
                r: {s: selected.get(r, {}).get(s, []) for s in ("lidar", "camera")}
                for r in self.robot_ids
            }
        )

    def truth_from_mocap(
        self, mocap: dict[str, list[Pose]], end_ns: int, stale_s: float
    ) -> GroundTruth | None:
        """Ground truth at ``end_ns`` from the newest mocap pose of each robot seen so far (this
        step's ``mocap[robot]``, sorted, or an earlier one), if every robot has one no older
        than ``stale_s``. The live bridge and the replay apply this same rule."""
        for robot in self.robot_ids:
            poses = mocap.get(robot, [])
            if poses:
                self._truth_pose[robot] = poses[-1]
        limit_ns = stale_s * 1e9
        fresh = {
            r: (p if p is not None and end_ns - p.stamp_ns <= limit_ns else None)
            for r, p in self._truth_pose.items()
        }
        return self.truth(fresh)

    def odometry(self, robot: str, messages: Iterable[Odom]) -> list[OdometryRecord]:
        out = []
        for msg in sorted(messages, key=lambda m: m.stamp_ns):
            prev = self._baseline[robot]
            if prev is not None and msg.stamp_ns <= prev.stamp_ns:
                if prev.stamp_ns - msg.stamp_ns > self.MAX_BACKSTEP_NS:
                    # The baseline is far ahead of the sensor (its clock was stepped back): a
                    # baseline from the "future" would refuse every later pose; start anew.
                    self._baseline[robot] = msg
                    if self.counters is not None:
                        self.counters.incr("odometry.rebaselined")
                continue  # out of order: keep the newer baseline, never count motion twice
            self._baseline[robot] = msg
            if prev is None:
                continue
            if not self._plausible(prev, msg):
                # A jump (driver restart, glitch): never integrate it; the pose is the new
                # baseline, so a reset odom frame costs one interval of motion, not a teleport.
                if self.counters is not None:
                    self.counters.incr("odometry.implausible")
                continue
            out.append(
                OdometryRecord(
                    ns_to_s(msg.stamp_ns),
                    odometry_increment(prev, msg),
                    np.array([msg.v_mps, msg.omega_radps]),
                )
            )
        return out

    def lidar(self, scans: Sequence[Scan]) -> list[LidarRecord]:
        """Records of ``scans`` in input order, detections extracted in batches."""
        records: list[LidarRecord | None] = [None] * len(scans)
        groups: dict[bytes, list[int]] = {}
        for k, scan in enumerate(scans):
            groups.setdefault(scan.angles_rad.tobytes(), []).append(k)
        for members in groups.values():
            angles = scans[members[0]].angles_rad
            ranges = np.stack([scans[k].ranges_m for k in members])
            detections = extract_detections(angles, ranges, self.config.lidar_features)
            blind = self.blind_mask(angles)
            for k, det in zip(members, detections, strict=True):
                scan = scans[k]
                records[k] = LidarRecord(
                    stamp_s=ns_to_s(scan.stamp_ns),
                    angles_rad=scan.angles_rad,
                    ranges_m=scan.ranges_m,
                    intensities=scan.intensities,
                    detections=det,
                    null_bearings_rad=null_bearings(
                        scan.angles_rad, scan.ranges_m, scan.intensities, exclude=blind
                    ),
                )
        return [r for r in records if r is not None]

    def blind_mask(self, angles_rad: np.ndarray) -> np.ndarray:
        """Beams inside the configured blind sectors (camera pillars), as the simulator's
        :class:`~swarm_env.sensors.lidar.LidarSensor` computes them: their null returns are
        not interference, so they are not reported (the filter has a blind-sector factor)."""
        return blind_mask(angles_rad, self.config.lidar)

    @staticmethod
    def camera(frames: Iterable[Bearings]) -> list[CameraRecord]:
        return [
            CameraRecord(ns_to_s(f.stamp_ns), f.bearings_rad)
            for f in sorted(frames, key=lambda f: f.stamp_ns)
        ]

    def measurements(self, per_robot: dict[str, dict[str, list]]) -> dict[str, RobotMeasurements]:
        """``{robot: {"odometry": [Odom], "lidar": [Scan], "camera": [Bearings]}}`` -> records."""
        scans: list[Scan] = []
        owners: list[str] = []
        for robot in self.robot_ids:
            for scan in sorted(
                per_robot.get(robot, {}).get("lidar", []), key=lambda s: s.stamp_ns
            ):
                scans.append(scan)
                owners.append(robot)
        lidar = {robot: [] for robot in self.robot_ids}
        for robot, record in zip(owners, self.lidar(scans), strict=True):
            lidar[robot].append(record)
        out = {}
        for robot in self.robot_ids:
            msgs = per_robot.get(robot, {})
            out[robot] = RobotMeasurements(
                odometry=self.odometry(robot, msgs.get("odometry", [])),
                lidar=lidar[robot],
                camera=self.camera(msgs.get("camera", [])),
            )
        return out

    def truth(self, poses: dict[str, Pose | None]) -> GroundTruth | None:
        """Ground truth from one mocap pose per robot, or ``None`` if any robot lacks one."""
        if any(poses.get(r) is None for r in self.robot_ids):
            return None
        arr = np.array([[poses[r].x_m, poses[r].y_m, poses[r].yaw_rad] for r in self.robot_ids])
        return truth_from_poses(
            arr, self.config.localization_range_m, self.config.camera.range_max_m
        )
