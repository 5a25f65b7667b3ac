"""Sensors inside the simulator, end to end: records land where ground truth says they should."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import make_config
from swarm_env.sensors.camera import CameraSensor
from swarm_env.world.sim import SimWorld

EMPTY = {"n_decoy_posts": 0, "n_red_decoys": 0, "n_boxes": 0}


def _world(n: int, **overrides) -> SimWorld:
    world = SimWorld(make_config("seed-sim", n_robots=n, arena=EMPTY, **overrides))
    world.reset(np.random.default_rng(0))
    return world


def _place(world: SimWorld, poses) -> None:
    for body, drive, (x, y, yaw) in zip(world.bodies, world._drives, poses, strict=False):
        body.position, body.angle = (x, y), yaw
        drive.position, drive.angle = (x, y), yaw
        world.space.reindex_shapes_for_body(body)


def _records(world: SimWorld, robot: str, seconds: float = 1.0):
    lidar, camera = [], []
    for _ in range(int(seconds / world.config.control_period_s)):
        step = world.step(np.zeros((world.n_agents, 2)))
        lidar += step.measurements[robot].lidar
        camera += step.measurements[robot].camera
    return lidar, camera


def test_lidar_detects_a_neighbour_at_its_relative_position():
    world = _world(2)
    # Observer facing +y; the neighbour 1 m to its left in the body frame sits at world (-1, 0).
    _place(world, [(0.0, 0.0, np.pi / 2), (-1.0, 0.0, 0.0)])
    lidar, _ = _records(world, "ugv_0")
    assert len(lidar) >= 6  # 7 Hz
    hits = [r.detections for r in lidar if len(r.detections)]
    assert len(hits) >= 0.8 * len(lidar)  # interference may null a few scans, not most
    near = np.concatenate(hits)
    near = near[np.linalg.norm(near - [0.0, 1.0], axis=1) < 0.2]
    assert len(near) >= 0.8 * len(lidar)
    assert np.allclose(near.mean(axis=0), [0.0, 1.0], atol=0.03)


def test_blind_sector_hides_a_neighbour_from_the_lidar():
    world = _world(2)
    centre = np.deg2rad(world.config.lidar.blind_sector_centers_deg[0])
    _place(world, [(0.0, 0.0, 0.0), (np.cos(centre), np.sin(centre), 0.0)])
    lidar, camera = _records(world, "ugv_0")
    assert all(len(r.detections) == 0 for r in lidar)
    # The camera has no pillar blind spot: it still sees the neighbour's red strip.
    bearings = np.concatenate([r.bearings_rad for r in camera])
    assert np.sum(np.abs(bearings - centre) < np.deg2rad(15)) >= 0.7 * len(camera)


def test_occluded_neighbour_is_missing_from_the_camera():
    # ugv_1 stands between ugv_0 and ugv_2, on the same line of sight.
    world = _world(3, camera={"false_positive_rate": 0.0})
    _place(world, [(-1.5, 0.0, 0.0), (-0.5, 0.0, 0.0), (1.0, 0.0, 0.0)])
    _, camera = _records(world, "ugv_0")
    bearings = np.concatenate([r.bearings_rad for r in camera])
    assert len(camera) >= 25
    # Only one blob ahead (ugv_1), never two: ugv_2 is hidden behind it.
    per_frame = [np.sum(np.abs(r.bearings_rad) < np.deg2rad(20)) for r in camera]
    assert max(per_frame) <= 1 and np.mean(bearings) < np.deg2rad(20)
    assert not world.ground_truth().visible["camera"][0, 2]
    assert world.ground_truth().visible["camera"][0, 1]


def test_time_stacked_scene_matches_single_instant_scenes():
    """One batched call over a step's substeps equals one call per substep's own scene."""
    world = SimWorld(
        make_config(
            "seed-sim",
            lidar={
                "range_noise_std_m": 0.0,
                "range_noise_quadratic_per_m": 0.0,
                "intensity_noise_std": 0.0,
            },
            camera={
                "bearing_noise_std_deg": 0.0,
                "miss_probability": 0.0,
                "false_positive_rate": 0.0,
                "fill_min": 1.0,
                "pixels_per_rad": 1e12,
            },
        )
    )
    world.reset(np.random.default_rng(3))
    instants = []
    for _ in range(3):  # instants 2 s apart, so occlusions differ between them
        for _ in range(20):
            world.step(np.tile([0.3, 0.8], (world.n_agents, 1)))
        instants.append(world.poses())
    stacked = world.scene(np.stack(instants))
    robots = np.tile(np.arange(world.n_agents), 3)
    when = np.repeat([0, 1, 2], world.n_agents)
    stamps = np.full(robots.size, 1.0)
    batch = world.lidar.scan(stacked, robots, stamps, np.random.default_rng(0), time_index=when)
    cams = world.camera.observe(stacked, robots, np.random.default_rng(0), time_index=when)
    for k, (i, t) in enumerate(zip(robots, when, strict=True)):
        single = world.scene(instants[t])
        alone = world.lidar.scan(single, np.array([i]), stamps[:1], np.random.default_rng(0))
        np.testing.assert_array_equal(batch.ranges_m[k], alone.ranges_m[0])
        np.testing.assert_array_equal(batch.hit_owner[k], alone.hit_owner[0])
        cam = world.camera.observe(single, np.array([i]), np.random.default_rng(0))
        np.testing.assert_array_equal(cams.visible[k], cam.visible[0])
        np.testing.assert_allclose(np.sort(cams.bearings[k]), np.sort(cam.bearings[0]))


def test_scans_end_when_the_head_completes_a_revolution():
    """Scan stamps follow each head's own phase and spin rate (what interference assumes)."""
    world = _world(4)
    lidar = []
    for _ in range(20):
        step = world.step(np.zeros((4, 2)))
        for i, rid in enumerate(world.robot_ids):
            lidar += [(i, r.stamp_s) for r in step.measurements[rid].lidar]
    robots = np.array([i for i, _ in lidar])
    stamps = np.array([s for _, s in lidar])
    heads = world.lidar.head_angle_rad(robots, stamps)
    assert np.allclose(np.abs(heads), np.pi, atol=1e-6)  # the head is back at -pi
    for i in range(4):  # and each robot scans at its own rate
        gaps = np.diff(stamps[robots == i])
        assert np.allclose(gaps, 1.0 / world.lidar.rates_hz[i])


def test_filters_track_static_neighbours_while_the_observer_spins_and_drives():
    """The odometry -> time update chain, end to end: a turning, driving observer keeps its
    neighbours where ground truth says they are."""
    from swarm_env import parallel_env

    env = parallel_env("seed-lab", arena=EMPTY)
    env.reset(seed=4)
    errors = []
    for k in range(150):
        command = np.array([0.15, 0.8 if (k // 30) % 2 == 0 else -0.6])
        actions = {a: np.zeros(2) for a in env.agents}
        actions["ugv_0"] = command
        env.step(actions)
        truth = env.last_world_step.truth
        mask = truth.in_range["lidar"][0]
        estimates, _ = env.localizers[0].estimate(0.5)
        if k > 20 and mask.any() and len(estimates):
            d = np.linalg.norm(truth.relative_xy[0][mask][:, None] - estimates[None], axis=-1)
            errors += d.min(axis=1).tolist()
    assert len(errors) > 50
    assert np.median(errors) < 0.06  # ~0.04 m; the 10 Hz odometry frame lag adds the rest


def test_simulator_filter_range_factors_follow_the_sensor_geometry():
    """SIMULATOR_PHD's range factors were fitted to the measured detection curves
    (benchmarks/bench_detection_curves.py); here they are checked against the curves the
    sensor geometry predicts, so a sensor change that invalidates them fails."""
    cfg = make_config("seed-sim")
    phd = cfg.phd
    r = np.arange(0.25, 5.51, 0.05)
    lidar = cfg.lidar
    footprint = np.deg2rad(lidar.beam_footprint_deg)
    clean = (2.0 * np.arcsin(cfg.robot.housing_radius_m / r) - footprint) / lidar.beam_spacing_rad
    lidar_geometry = np.clip(clean - (cfg.lidar_features.min_beams - 1), 0.0, 1.0)
    lidar_filter = 1.0 / (
        phd.lidar.pd_offset + np.exp(phd.lidar.pd_slope_per_m * (r - phd.lidar.pd_midpoint_m))
    )
    # A sigmoid cannot follow the ramp's corners exactly: max 0.1, RMS 0.03.
    assert np.abs(lidar_filter - lidar_geometry).max() < 0.1
    assert np.sqrt(np.mean((lidar_filter - lidar_geometry) ** 2)) < 0.03
    # 50 % where the housing spans 2.5 clean returns plus the footprint: 2.13 m.
    r50 = cfg.robot.housing_radius_m / np.sin(0.5 * (2.5 * lidar.beam_spacing_rad + footprint))
    assert abs(np.interp(0.5, lidar_filter[::-1], r[::-1]) - r50) < 0.03
    camera = CameraSensor(cfg.camera).detection_probability(r, cfg.robot.camera_holder_radius_m)
    camera_filter = 1.0 / (
        phd.camera.pd_offset + np.exp(phd.camera.pd_slope_per_m * (r - phd.camera.pd_midpoint_m))
    )
    assert np.abs(camera_filter - camera).max() < 0.1
    assert np.sqrt(np.mean((camera_filter - camera) ** 2)) < 0.03
    assert phd.camera.pd_offset == pytest.approx(1.0 / (1.0 - cfg.camera.miss_probability), 0.01)
