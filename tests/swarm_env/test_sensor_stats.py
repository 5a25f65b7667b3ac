"""Sensor diagnostics (``sensor_stats=True``): misses, false positives, and why the lidar
missed, against hand counts and against scenes whose cause is known."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import make_config
from swarm_env.world.diagnostics import LIDAR_MISS_CAUSES, SensorStats
from swarm_env.world.sim import SimWorld

EMPTY = {"n_decoy_posts": 0, "n_red_decoys": 0, "n_boxes": 0}


def test_lidar_misses_by_cause_by_hand():
    """Four targets within 2 m: one detected, one hidden (2 beams reached it, 3 needed), one
    interfered (5 reached, 1 came back), one the extractor missed (6 came back); a fifth beyond
    range is neither counted nor missed; a detection on nothing is a false positive."""
    stats = SensorStats(range_m=2.0, gate=0.15)
    targets = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.5], [3.0, 0.0]])
    detections = np.array([[1.05, 0.0], [0.5, 0.5]])
    stats.add_points(
        detections, targets, np.array([6, 2, 5, 6, 0]), np.array([6, 2, 1, 6, 0]), min_beams=3
    )
    with pytest.raises(ValueError, match="min_beams together"):
        stats.add_points(detections, targets, np.array([6, 2, 5, 6, 0]), np.array([6, 2, 1, 6, 0]))
    assert stats.missed == 3 and stats.targets_in_range == 4 and stats.false_positives == 1
    assert stats.missed_by_cause == {"hidden": 1, "interfered": 1, "extractor": 1}
    summary = stats.summary()
    assert summary["missed_rate_by_cause"] == pytest.approx(
        {"hidden": 0.25, "interfered": 0.25, "extractor": 0.25}
    )
    assert sum(summary["missed_rate_by_cause"].values()) == pytest.approx(
        summary["missed_detection_rate"]
    )
    # Without beam counts (the camera) there is no split.
    bare = SensorStats(range_m=2.0, gate=0.15)
    bare.add_points(np.zeros((0, 2)), targets)
    assert bare.missed == 4 and "missed_rate_by_cause" not in bare.summary()


def _facing_pair_world(seed: int, bearing_rad: float = 0.0, **overrides) -> SimWorld:
    """Two robots 1 m apart in an empty arena, the neighbour at ``bearing_rad`` in the
    observer's frame and facing it."""
    world = SimWorld(make_config("seed-sim", n_robots=2, arena=EMPTY, **overrides))
    world.reset(np.random.default_rng(seed))
    c, s = np.cos(bearing_rad), np.sin(bearing_rad)
    for body, drive, (x, y, yaw) in zip(
        world.bodies, world._drives, [(0.0, 0.0, 0.0), (c, s, bearing_rad + np.pi)], strict=True
    ):
        body.position, body.angle = (x, y), yaw
        drive.position, drive.angle = (x, y), yaw
        world.space.reindex_shapes_for_body(body)
    return world


def _facing_pair(seed: int, bearing_rad: float = 0.0, **overrides) -> SensorStats:
    """:func:`_facing_pair_world`, still for 10 s: the pair's lidar statistics."""
    world = _facing_pair_world(seed, bearing_rad, sensor_stats=True, **overrides)
    for _ in range(100):
        world.step(np.zeros((2, 2)))
    return world.stats["lidar"]


def test_interference_is_the_only_cause_of_a_facing_pairs_misses():
    """Seed 2's heads drift into phase: both robots' scans lose each other to interference,
    and only to it. With interference off, nothing is missed."""
    stats = _facing_pair(2)
    assert stats.missed > 5
    assert stats.missed_by_cause == {"hidden": 0, "interfered": stats.missed, "extractor": 0}
    quiet = _facing_pair(2, lidar={"interference_tolerance_deg": 0.0})
    assert quiet.missed == 0 and set(quiet.missed_by_cause) == set(LIDAR_MISS_CAUSES)


def test_a_neighbour_on_a_blind_sector_is_hidden():
    """A neighbour on the observer's pillar sector centre is missed by every scan, all of it
    hidden (no beam reaches its housing). The neighbour faces the observer and sees it, so
    about half of the pair's targets are missed."""
    config = make_config("seed-sim")
    centre = np.deg2rad(config.lidar.blind_sector_centers_deg[0])
    stats = _facing_pair(0, centre, lidar={"interference_tolerance_deg": 0.0})
    assert stats.targets_in_range > 100
    assert stats.missed_by_cause["hidden"] >= stats.targets_in_range // 2
    assert stats.missed_by_cause["interfered"] == stats.missed_by_cause["extractor"] == 0


def test_lidar_scan_observers_see_each_scan_beside_its_truth():
    """An observer gets every scan of the period, the bodies in the scanner's frame at the
    scan's instant, and the beam counts; the records are the ones the robots received."""
    world = _facing_pair_world(0)
    seen = []
    world.lidar_scan_observers.append(seen.append)
    received = []
    for _ in range(10):
        step = world.step(np.zeros((2, 2)))
        received += [r for robot in world.robot_ids for r in step.measurements[robot].lidar]
    records = [r for truth in seen for r in truth.records]
    assert len(records) == len(received) >= 12  # 7 Hz x 2 robots x 1 s
    assert {id(r) for r in records} == {id(r) for r in received}
    for truth in seen:
        k = len(truth.robots)
        assert truth.relative_xy.shape == (k, 2, 2)
        assert truth.beams_reaching.shape == truth.beams_returned.shape == (k, 2)
        assert np.all(truth.beams_returned <= truth.beams_reaching)
        assert not truth.relative_xy.flags.writeable and not truth.robots.flags.writeable
        for scan, robot in enumerate(truth.robots):
            # the scanner at its own origin, the other robot 1 m ahead (both face each other)
            assert np.allclose(truth.relative_xy[scan, robot], 0.0)
            assert np.allclose(truth.relative_xy[scan, 1 - robot], [1.0, 0.0], atol=1e-6)
            assert truth.beams_reaching[scan, 1 - robot] >= 3


def test_lidar_scan_truth_is_taken_at_the_scans_instant():
    """ugv_0 spins at 1.5 rad/s (0.15 rad per period): its neighbour's detections match the
    truth handed to observers for that scan, not the pose at the end of the period."""
    world = _facing_pair_world(0, lidar={"interference_tolerance_deg": 0.0})
    seen = []
    world.lidar_scan_observers.append(seen.append)
    matched = far_from_step_end = 0
    for _ in range(30):
        step = world.step(np.array([[0.0, 1.5], [0.0, 0.0]]))
        end = step.truth.relative_xy[0, 1]
        for truth in seen:
            for scan in np.flatnonzero(truth.robots == 0):
                detections = truth.records[scan].detections
                if not len(detections):  # the neighbour behind a pillar (the robot spins)
                    continue
                assert len(detections) == 1
                assert np.linalg.norm(detections[0] - truth.relative_xy[scan, 1]) < 0.03
                matched += 1
                far_from_step_end += np.linalg.norm(detections[0] - end) > 0.03
        seen.clear()
    assert matched >= 10
    assert far_from_step_end >= 5  # the scans fall inside the period, not at its end
