"""A geometry snapshot of the world at one instant: what the sensor models ray-cast against.

The physics engine (pymunk) owns the bodies; the sensors never query it ray by ray. Instead the
World flattens everything a sensor can see into arrays of circles and segments, and the sensor
models work on those arrays with vectorised numpy. All coordinates are in the world frame
(REP-103, metres, radians).

A scene may stack several instants (the physics substeps of one env step): robot poses then have
a leading time axis, every moving circle carries the index of the instant it belongs to
(``circle_time``; -1 for static shapes, present at every instant), and each sensor reading names
its instant (``time_index``). One vectorised sensor call then serves a whole control period.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True, slots=True)
class Scene:
    """Circles and segments in the world frame, with per-shape sensor properties.

    Attributes
    ----------
    robot_xy : ndarray, shape (N, 2) or (T, N, 2)
        Robot centres (= lidar and camera origins), metres, at one or T instants.
    robot_yaw : ndarray, shape (N,) or (T, N)
        Robot headings, rad, counter-clockwise from world x.
    circle_xy : ndarray, shape (C, 2)
        Circle centres: robots' lidar housings and camera holders, decoy posts, red decoys,
        cylindrical obstacles.
    circle_radius_m : ndarray, shape (C,)
    circle_owner : ndarray, shape (C,), int
        Index of the robot the circle belongs to, or -1 for static objects. A sensor ignores
        the circles of its own robot.
    circle_lidar : ndarray, shape (C,), bool
        The circle is at lidar height (the lidar sees it).
    circle_camera_occluder : ndarray, shape (C,), bool
        The circle blocks camera lines of sight.
    circle_red : ndarray, shape (C,), bool
        The circle is a red colour blob the camera detects (robots' strips, red decoys).
    circle_intensity : ndarray, shape (C,)
        Mean lidar return intensity of the surface (arbitrary units, > 0).
    segment_a, segment_b : ndarray, shape (S, 2)
        End points of wall and box-obstacle edges. Segments block the lidar and the camera.
    segment_intensity : ndarray, shape (S,)
    circle_time : ndarray, shape (C,), int, optional
        Instant each circle exists at (index into the time axis), -1 for every instant.
        ``None`` (the default) means every circle exists at every instant.
    """

    robot_xy: np.ndarray
    robot_yaw: np.ndarray
    circle_xy: np.ndarray
    circle_radius_m: np.ndarray
    circle_owner: np.ndarray
    circle_lidar: np.ndarray
    circle_camera_occluder: np.ndarray
    circle_red: np.ndarray
    circle_intensity: np.ndarray
    segment_a: np.ndarray
    segment_b: np.ndarray
    segment_intensity: np.ndarray
    circle_time: np.ndarray | None = None

    @property
    def n_robots(self) -> int:
        return int(self.robot_xy.shape[-2])

    def observer_poses(
        self, robots: np.ndarray, time_index: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Origins (K, 2) and headings (K,) of ``robots`` at their instants ``time_index``."""
        if self.robot_xy.ndim == 2:
            return self.robot_xy[robots], self.robot_yaw[robots]
        t = np.zeros_like(robots) if time_index is None else time_index
        return self.robot_xy[t, robots], self.robot_yaw[t, robots]

    def at(self, instant: int) -> tuple[Scene, np.ndarray]:
        """The single-instant scene of a time-stacked one, and the kept circle indices (C',)."""
        if self.circle_time is None:
            return self, np.arange(self.circle_xy.shape[0])
        kept = np.flatnonzero((self.circle_time < 0) | (self.circle_time == instant))
        robot_xy = self.robot_xy[instant] if self.robot_xy.ndim == 3 else self.robot_xy
        robot_yaw = self.robot_yaw[instant] if self.robot_yaw.ndim == 2 else self.robot_yaw
        sub = replace(
            self,
            robot_xy=robot_xy,
            robot_yaw=robot_yaw,
            circle_xy=self.circle_xy[kept],
            circle_radius_m=self.circle_radius_m[kept],
            circle_owner=self.circle_owner[kept],
            circle_lidar=self.circle_lidar[kept],
            circle_camera_occluder=self.circle_camera_occluder[kept],
            circle_red=self.circle_red[kept],
            circle_intensity=self.circle_intensity[kept],
            circle_time=None,
        )
        return sub, kept
