"""The env's filter calls re-express each scan and frame in the frame of the last odometry sample
(``localization.feed.localizer_calls``): the robot's own motion up to the stamp is removed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.feed import localizer_calls
from localization.frames import bearings_to_filter_frame, points_to_filter_frame
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements


def _pose_after(v: float, omega: float, t: float) -> np.ndarray:
    """Exact unicycle pose (x, y, psi) after ``t`` s at constant (v, omega), from the origin."""
    psi = omega * t
    if abs(omega) < 1e-12:
        return np.array([v * t, 0.0, 0.0])
    r = v / omega
    return np.array([r * math.sin(psi), r * (1.0 - math.cos(psi)), psi])


def _in_frame(pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = point - pose[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def _lidar(stamp: float, detections: np.ndarray, nulls: np.ndarray) -> LidarRecord:
    angles = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    zeros = np.zeros(8)
    return LidarRecord(stamp, angles, zeros, zeros, detections, nulls)


@pytest.mark.parametrize(("v", "omega"), [(0.3, 1.5), (0.2, -0.7), (0.0, 1.2), (0.25, 0.0)])
def test_measurements_are_moved_to_the_last_odometry_frame(v, omega):
    period = 0.1
    end = _pose_after(v, omega, period)
    odo = OdometryRecord(1.0 + period, end, np.array([v, omega]))
    teammate = np.array([1.2, 0.7])  # static, world frame = frame of the sample at t = 1.0
    calls_expected = []
    lidar_records, camera_records = [], []
    for tau in (0.07, 0.035, 0.01):  # measurements before the next sample, in time order
        stamp = 1.0 + period - tau
        pose = _pose_after(v, omega, period - tau)  # where the robot measured from
        seen = _in_frame(pose, teammate)
        lidar_records.append(_lidar(stamp, seen[None, :], np.array([0.3 - pose[2]])))
        camera_records.append(CameraRecord(stamp, np.array([math.atan2(seen[1], seen[0])])))
        calls_expected.append(stamp)
    records = RobotMeasurements([odo], lidar_records, camera_records)
    stamped = localizer_calls(records)
    assert [c[1] for c in stamped if c[0] == "advance"] == [
        *(s for s in calls_expected for _ in range(2)),
        1.0 + period,
    ]
    calls = _measurements_only(stamped)
    assert [c[0] for c in calls] == ["lidar", "camera"] * 3 + ["predict"]
    for call in calls[:-1]:
        if call[0] == "lidar":
            # exact up to the chord approximation of the remaining arc (< 0.1 mm here)
            assert np.allclose(points_to_filter_frame(call[1], call[3]), teammate, atol=1e-4)
            assert np.allclose(bearings_to_filter_frame(call[2], call[3]), [0.3], atol=1e-9)
        else:
            # rotation removed exactly; the < 3 cm translation is the camera's position, from
            # which the filter evaluates the bearing (exact up to the chord approximation)
            x, y = teammate - call[2][:2]
            moved = bearings_to_filter_frame(call[1], call[2])
            assert abs(moved[0] - math.atan2(y, x)) < 1e-4
    raw = _measurements_only(localizer_calls(records, compensate_motion=False))
    assert raw[0][3] is None and np.array_equal(raw[0][1], lidar_records[0].detections)
    # The bank applies the pose as the reference does.
    bank = PHDBank(PHDConfig.perera2021(), 1)
    bank.apply([stamped])
    f = RobotCentricPHD(PHDConfig.perera2021())
    for call in calls:
        if call[0] == "predict":
            f.predict(call[1])
        elif call[0] == "lidar":
            f.update_lidar(
                points_to_filter_frame(call[1], call[3]),
                bearings_to_filter_frame(call[2], call[3]),
            )
        else:
            f.update_camera(call[1], sensor_pose=call[2])
    assert len(f) > 0 and np.allclose(bank.table(0), f.table, atol=1e-12)


def test_records_without_a_later_sample_are_unchanged():
    odo = OdometryRecord(1.0, np.array([0.03, 0.0, 0.15]), np.array([0.3, 1.5]))
    lidar = _lidar(1.05, np.array([[1.0, 0.5]]), np.array([0.2]))
    camera = CameraRecord(1.0, np.array([0.4]))  # same stamp as the sample: already in frame
    calls = _measurements_only(localizer_calls(RobotMeasurements([odo], [lidar], [camera])))
    assert [c[0] for c in calls] == ["predict", "camera", "lidar"]
    assert calls[1][2] is None and np.array_equal(calls[1][1], camera.bearings_rad)
    assert calls[2][3] is None and np.array_equal(calls[2][1], lidar.detections)


def test_stale_odometry_disables_compensation():
    odo = OdometryRecord(1.1, np.array([0.03, 0.0, 0.15]), np.array([0.3, 1.5]))
    camera = CameraRecord(1.05, np.array([0.4]))
    calls = localizer_calls(RobotMeasurements([odo], [], [camera]), stale=("odometry",))
    assert calls == [("advance", 1.05), ("camera", camera.bearings_rad, None)]


def _measurements_only(calls):
    """The calls without the process-noise clock's ``("advance", stamp)`` entries."""
    return [c for c in calls if c[0] != "advance"]
