"""Teammates' broadcasts from real robots' topics (hardware_bridge.comms), live and in replay."""

from __future__ import annotations

import dataclasses

import numpy as np

from hardware_bridge.bag import ReplayWorld
from hardware_bridge.comms import TeammateRelay
from hardware_bridge.messages import Odom
from swarm_core.records import CameraRecord, LidarRecord, RobotMeasurements
from swarm_phd.export_bag import export_sim_episode


def _lidar(stamp_s: float, detections: list) -> LidarRecord:
    empty = np.zeros(0)
    return LidarRecord(stamp_s, empty, empty, empty, np.array(detections).reshape(-1, 2), empty)


def test_relay_sends_each_robots_newest_odometry_and_detections_to_the_others():
    relay = TeammateRelay(("a", "b", "c"))
    parsed = {
        "a": {"odometry": [Odom(1_000_000_000, 0.1, 0.2, 0.3, 0.0, 0.0),
                           Odom(1_100_000_000, 0.4, 0.5, 0.6, 0.0, 0.0)]},
        "b": {"odometry": []},  # nothing arrived: b sends nothing this step
        "c": {"odometry": [Odom(1_050_000_000, -1.0, 2.0, -0.5, 0.0, 0.0)]},
    }  # fmt: skip
    frames = [CameraRecord(1.03, np.array([0.5])), CameraRecord(1.07, np.array([0.2, -1.0]))]
    measurements = {"a": RobotMeasurements([], [_lidar(1.08, [[1.0, 0.0]])], frames)}
    out = relay.step(parsed, measurements)
    assert [m.sender for m in out["b"]] == ["a", "c"]
    assert [m.sender for m in out["a"]] == ["c"] and [m.sender for m in out["c"]] == ["a"]
    a = out["b"][0]
    assert a.stamp_s == 1.1 and np.allclose(a.odometry_pose, [0.4, 0.5, 0.6])
    assert np.allclose(a.detections, [[1.0, 0.0]]) and a.detections_stamp_s == 1.08
    # The newest camera frame's bearings (the Stegagno 2012 thesis's P-MultiBeaReg features).
    assert np.allclose(a.bearings_rad, [0.2, -1.0]) and a.bearings_stamp_s == 1.07
    assert out["b"][1].detections.shape == (0, 2)  # c has not scanned yet
    assert out["b"][1].bearings_rad.size == 0 and np.isnan(out["b"][1].bearings_stamp_s)
    # Detections and bearings persist until the next scan / frame; a reset forgets them.
    again = relay.step({"a": {"odometry": parsed["a"]["odometry"][:1]}}, {})
    assert np.allclose(again["c"][0].detections, [[1.0, 0.0]])
    assert np.allclose(again["c"][0].bearings_rad, [0.2, -1.0])
    relay.reset()
    after_reset = relay.step({"a": {"odometry": parsed["a"]["odometry"][:1]}}, {})["c"][0]
    assert after_reset.detections.size == 0 and after_reset.bearings_rad.size == 0


def test_replay_fills_comms_from_the_recorded_odometry(tmp_path):
    bag = tmp_path / "sim"
    export_sim_episode(bag, preset="lab-3m-4", duration_s=1.0, seed=2)
    plain = ReplayWorld(bag)
    plain.reset()
    assert plain.step(np.zeros((len(plain.robot_ids), 2))).comms == {}
    config = dataclasses.replace(
        plain.config, comms=dataclasses.replace(plain.config.comms, enabled=True)
    )
    world = ReplayWorld(bag, config=config)
    world.reset()
    step = world.step(np.zeros((len(world.robot_ids), 2)))
    for receiver, messages in step.comms.items():
        senders = [m.sender for m in messages]
        assert receiver not in senders and len(senders) == len(world.robot_ids) - 1
        for m in messages:
            assert np.isfinite(m.odometry_pose).all() and m.detections.shape[1] == 2
