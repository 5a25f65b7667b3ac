"""Command limits enforced in the bridge, whatever the policy asks: velocity, acceleration and an
optional geofence (motion-capture frame)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hardware_bridge.config import BridgeConfig
from hardware_bridge.messages import Counters, Pose
from swarm_env.config import RobotConfig


class CommandLimiter:
    """Clips ``[v, omega]`` commands per robot.

    * velocity: ``|v| <= max_speed``, ``|omega| <= max_turn_rate``;
    * acceleration: the change from the previously *sent* command is at most ``a_max * dt``
      (``dt`` = the control period); an emergency stop resets the previous command to zero;
    * geofence: a robot outside ``(x_min, x_max, y_min, y_max)`` may turn, and drive only if
      that takes it back towards the inside; a robot without a fresh mocap pose is stopped.
    """

    def __init__(
        self,
        robot_ids: Sequence[str],
        bridge: BridgeConfig,
        robot: RobotConfig,
        period_s: float,
        counters: Counters,
    ) -> None:
        self.robot_ids = tuple(robot_ids)
        self.period_s = period_s
        self.counters = counters
        self.v_max = min(bridge.max_speed_mps or robot.max_speed_mps, robot.max_speed_mps)
        self.w_max = min(
            bridge.max_turn_rate_radps or robot.max_turn_rate_radps, robot.max_turn_rate_radps
        )
        self.a_max = bridge.max_accel_mps2 or robot.max_accel_mps2
        self.alpha_max = bridge.max_turn_accel_radps2 or robot.max_turn_accel_radps2
        self.geofence = bridge.geofence_m
        self.previous = np.zeros((len(self.robot_ids), 2))

    def stopped(self) -> None:
        """The robots were sent zero velocity: the next command ramps up from rest."""
        self.previous[:] = 0.0

    def limit(self, commands: np.ndarray, poses: dict[str, Pose | None]) -> np.ndarray:
        cmd = np.array(commands, dtype=np.float64).reshape(len(self.robot_ids), 2)
        if not np.all(np.isfinite(cmd)):
            raise ValueError(f"commands must be finite, got {cmd.tolist()}")
        high = np.array([self.v_max, self.w_max])
        clipped = np.clip(cmd, -high, high)
        if np.any(clipped != cmd):
            self.counters.incr("safety.velocity_clipped")
        step = np.array([self.a_max, self.alpha_max]) * self.period_s
        limited = self.previous + np.clip(clipped - self.previous, -step, step)
        if np.any(np.abs(limited - clipped) > 1e-12):
            self.counters.incr("safety.accel_limited")
        if self.geofence is not None:
            for i, robot in enumerate(self.robot_ids):
                limited[i] = self._fence(limited[i], poses.get(robot))
        self.previous = limited.copy()
        return limited

    def _fence(self, cmd: np.ndarray, pose: Pose | None) -> np.ndarray:
        if pose is None:
            self.counters.incr("safety.geofence_no_pose_stop")
            return np.zeros(2)
        x_min, x_max, y_min, y_max = self.geofence
        # Outward direction: sum of the normals of the violated bounds.
        out = np.array(
            [
                (pose.x_m > x_max) - (pose.x_m < x_min),
                (pose.y_m > y_max) - (pose.y_m < y_min),
            ],
            dtype=np.float64,
        )
        if not out.any():
            return cmd
        heading = np.array([math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)])
        v = cmd[0]
        if v * float(heading @ out) > 0.0:  # driving (forward or back) further out
            self.counters.incr("safety.geofence_stops")
            return np.array([0.0, cmd[1]])
        return cmd
