"""A geometry snapshot of the world at one instant: what the sensor models ray-cast against.

The physics engine (pymunk) owns the bodies; the sensors never query it ray by ray. Instead the
World flattens everything a sensor can see into arrays of circles and segments once per sensor
tick, and the sensor models work on those arrays with vectorised numpy. All coordinates are in
the world frame (REP-103, metres, radians).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Scene:
    """Circles and segments in the world frame, with per-shape sensor properties.

    Attributes
    ----------
    robot_xy : ndarray, shape (N, 2)
        Robot centres (= lidar and camera origins), metres.
    robot_yaw : ndarray, shape (N,)
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

    @property
    def n_robots(self) -> int:
        return int(self.robot_xy.shape[0])
