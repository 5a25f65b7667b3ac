"""A small synthetic world for the mutual-localization tests: robots on known trajectories,
records and broadcasts made from them (noise-free or with a known noise)."""

from __future__ import annotations

import numpy as np

from localization.mutual.se2 import inverse_compose, points_to_frame
from swarm_core.records import (
    Broadcast,
    CameraRecord,
    LidarRecord,
    OdometryRecord,
    RobotMeasurements,
)

EMPTY = np.zeros(0)


class SyntheticSwarm:
    """Robots with world poses (N, 3) moved by body-frame velocities; extra static features."""

    def __init__(self, poses: np.ndarray, features: np.ndarray | None = None, seed: int = 0):
        self.poses = np.asarray(poses, dtype=float).copy()
        self.features = np.zeros((0, 2)) if features is None else np.asarray(features, float)
        self.ids = tuple(f"ugv_{k}" for k in range(len(self.poses)))
        self.odom = np.zeros_like(self.poses)  # each robot's dead reckoning since start
        self.time_s = 0.0
        self.rng = np.random.default_rng(seed)

    def step(self, velocities: np.ndarray, dt: float = 0.1, det_noise_m: float = 0.0):
        """Move; return ``{id: RobotMeasurements}`` and ``{id: [Broadcast]}`` (everyone hears
        everyone, no latency)."""
        from swarm_core.geometry import integrate_body_delta

        v = np.asarray(velocities, dtype=float)
        delta = np.column_stack([v[:, 0] * dt, np.zeros(len(v)), v[:, 1] * dt])
        self.poses = integrate_body_delta(self.poses, delta)
        self.odom = integrate_body_delta(self.odom, delta)
        self.time_s += dt
        meas, said = {}, []
        for i, rid in enumerate(self.ids):
            others = np.vstack([np.delete(self.poses[:, :2], i, axis=0), self.features])
            z = points_to_frame(others, self.poses[i])
            z = z + self.rng.normal(0.0, det_noise_m, z.shape) if det_noise_m else z
            lidar = LidarRecord(self.time_s, EMPTY, EMPTY, EMPTY, z, EMPTY)
            # The camera sees the teammates' red strips (the features are not red), sorted.
            mates = z[: len(self.poses) - 1]
            bearings = np.sort(np.arctan2(mates[:, 1], mates[:, 0]))
            camera = CameraRecord(self.time_s, bearings)
            odo = OdometryRecord(self.time_s, delta[i], v[i])
            meas[rid] = RobotMeasurements([odo], [lidar], [camera])
            said.append(
                Broadcast(
                    rid, self.time_s, self.odom[i].copy(), z, self.time_s, bearings, self.time_s
                )
            )
        comms = {rid: [b for b in said if b.sender != rid] for rid in self.ids}
        return meas, comms

    def relative(self, i: int, j: int) -> np.ndarray:
        """Robot j's true pose in robot i's frame."""
        return inverse_compose(self.poses[j], self.poses[i])
