"""Measurements taken away from the filter's frame, moved into it.

A robot's filter lives in the robot's frame at its last odometry sample, but a lidar scan or a
camera frame is taken up to one odometry period later, from wherever the robot has moved since
(at 1.5 rad/s and 10 Hz odometry: 0.15 rad, i.e. 0.3 m at 2 m range). A measurement therefore
comes with the **sensor pose** ``(x_m, y_m, psi_rad)``: where the robot was, in the filter's
frame, when it measured. :class:`~localization.PHDBank` applies it inside its compiled engine;
this module is the reference (and what single-filter users call before
:class:`~localization.RobotCentricPHD`'s updates).

* Positions move rigidly: ``p_filter = R(psi) p_sensor + (x, y)``.
* Bearings rotate: ``theta_filter = wrap(theta_sensor + psi)``. The translation cannot be
  applied to a bearing (it has no range), so the filters take it into their bearing model
  instead: ``h(m) = atan2(m_y - y, m_x - x)``, evaluated from the camera's position
  (``RobotCentricPHD.update_camera(..., sensor_pose)`` and the banks' kernels). Left out, the
  parallax is up to ``atan(|(x, y)| / range)``: 0.9 deg for 3 cm at 2 m and 3.4 deg at 0.5 m,
  about 3.6 sigma of the simulated camera's measured bearing noise at either range (0.24 and
  0.96 deg: both scale as 1 / range).
"""

from __future__ import annotations

import math

import numpy as np

from .gaussian import wrap_angle

__all__ = ["points_to_filter_frame", "bearings_to_filter_frame"]


def points_to_filter_frame(points: np.ndarray, sensor_pose: np.ndarray) -> np.ndarray:
    """Positions ``(M, 2)`` (m) seen from ``sensor_pose`` ``(3,)``, in the filter's frame."""
    c, s = math.cos(sensor_pose[2]), math.sin(sensor_pose[2])
    out = np.empty_like(points, dtype=float)
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + sensor_pose[0]
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + sensor_pose[1]
    return out


def bearings_to_filter_frame(bearings: np.ndarray, sensor_pose: np.ndarray) -> np.ndarray:
    """Bearings ``(M,)`` (rad) seen from ``sensor_pose`` ``(3,)``, in the filter's frame."""
    return wrap_angle(bearings + sensor_pose[2])
