"""The UAV's bridge topics: pose and detections messages, parsed, validated, assembled."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from hardware_bridge.messages import (
    InvalidMessage,
    ground_detections_msg,
    parse_ground_detections,
    parse_uav_pose,
    s_to_ns,
    uav_pose_msg,
    uav_topics,
)
from swarm_core.aerial import UAVAssembler
from swarm_env.sensors.downward_camera import DownwardCameraConfig


def test_topics():
    assert uav_topics("uav_0") == {
        "uav_pose": "/uav_0/pose",
        "uav_detections": "/uav_0/camera/detections",
    }
    with pytest.raises(ValueError, match="robot id"):
        uav_topics("0uav")


def test_round_trip():
    pose = parse_uav_pose(uav_pose_msg(s_to_ns(12.5), 1.0, -2.0, 2.8, 0.7))
    assert (pose.x_m, pose.y_m, pose.altitude_m) == (1.0, -2.0, 2.8)
    assert pose.yaw_rad == pytest.approx(0.7)
    pts = np.array([[0.3, -0.4], [1.2, 0.5]])
    det = parse_ground_detections(ground_detections_msg(s_to_ns(12.5), pts))
    assert det.stamp_ns == s_to_ns(12.5)
    np.testing.assert_array_equal(det.points_m, pts)
    empty = parse_ground_detections(ground_detections_msg(s_to_ns(1.0), np.empty((0, 2))))
    assert empty.points_m.shape == (0, 2)


def _bad_pose(path, value):
    msg = uav_pose_msg(s_to_ns(1.0), 0.0, 0.0, 2.0, 0.0)
    node = msg
    keys = path.split(".")
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value
    return msg


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("pose.position.z", 0.0, "pose.position.z"),
        ("pose.position.z", -1.0, "pose.position.z"),
        ("pose.position.z", float("nan"), "pose.position.z"),
        ("pose.position.x", "1", "pose.position.x"),
        ("pose.position.y", 1e9, "pose.position.y"),
        ("pose.orientation.w", 3.0, "pose.orientation"),
        ("header.stamp.sec", 0, "header.stamp"),
    ],
)
def test_bad_pose_names_the_field(path, value, field):
    msg = _bad_pose(path, value)
    if path == "header.stamp.sec":
        msg["header"]["stamp"]["nanosec"] = 0
    with pytest.raises(InvalidMessage) as info:
        parse_uav_pose(msg)
    assert info.value.field == field


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda m: m.__setitem__("poses", {"x": 1}), "poses"),
        (lambda m: m["poses"][1]["position"].__setitem__("x", math.inf), "poses[1].position.x"),
        (lambda m: m["poses"][0]["position"].__setitem__("y", True), "poses[0].position.y"),
        (lambda m: m["poses"][0]["position"].pop("y"), "poses[0].position.y"),
        (lambda m: m["poses"][1]["orientation"].__setitem__("z", "a"), "poses[1].orientation.z"),
        (lambda m: m["poses"].__setitem__(0, 3), "poses[0]"),
        (lambda m: m["poses"].extend([m["poses"][0]] * 300), "poses"),
    ],
)
def test_bad_detections_name_the_field(mutate, field):
    msg = ground_detections_msg(s_to_ns(2.0), np.array([[0.1, 0.2], [0.3, 0.4]]))
    msg = copy.deepcopy(msg)
    mutate(msg)
    with pytest.raises(InvalidMessage) as info:
        parse_ground_detections(msg)
    assert info.value.field == field


def test_assembler_increments_and_frames():
    cam = DownwardCameraConfig()
    asm = UAVAssembler(cam)
    det = parse_ground_detections(ground_detections_msg(s_to_ns(1.0), np.array([[0.5, 0.1]])))
    with pytest.raises(ValueError, match="altitude"):
        asm.frame(det)
    assert asm.pose(parse_uav_pose(uav_pose_msg(s_to_ns(1.0), 1.0, 1.0, 2.0, math.pi / 2))) is None
    delta = asm.pose(parse_uav_pose(uav_pose_msg(s_to_ns(1.1), 1.0, 1.2, 3.0, math.pi / 2)))
    np.testing.assert_allclose(delta, [0.2, 0.0, 0.0], atol=1e-12)  # 0.2 m forward (+y world)
    # An older pose is ignored.
    assert asm.pose(parse_uav_pose(uav_pose_msg(s_to_ns(1.05), 0.0, 0.0, 3.0, 0.0))) is None
    frame = asm.frame(det)
    assert frame.altitude_m == 3.0
    np.testing.assert_allclose(frame.half_extents_m, cam.half_extents_m(3.0))
    np.testing.assert_array_equal(frame.detections, [[0.5, 0.1]])
    assert frame.source.tolist() == [-1]
