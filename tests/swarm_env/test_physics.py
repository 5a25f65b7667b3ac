"""The pymunk world: spawning, differential-drive kinematics, collisions, odometry and frames."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_core.world import relative_positions
from swarm_env import make_config
from swarm_env.sensors.odometry import pulses_to_delta
from swarm_env.world.sim import SimWorld

EMPTY = {"n_decoy_posts": 0, "n_red_decoys": 0, "n_boxes": 0}


def _world(**overrides) -> SimWorld:
    return SimWorld(make_config("seed-sim", **overrides))


def _set_pose(world: SimWorld, i: int, x: float, y: float, yaw: float) -> None:
    body = world.bodies[i]
    body.position, body.angle = (x, y), yaw
    world.space.reindex_shapes_for_body(body)


@pytest.mark.parametrize("seed", range(5))
def test_spawn_never_overlaps(seed):
    world = _world()
    world.reset(np.random.default_rng(seed))
    poses = world.poses()
    r = world.config.robot.footprint_radius_m
    d = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1)
    assert (d[~np.eye(len(poses), dtype=bool)] >= 2 * r).all()
    layout = world.layout
    for obstacle in [*layout.posts_xy, *layout.red_decoys_xy, *layout.boxes[:, :2]]:
        assert (np.linalg.norm(poses[:, :2] - obstacle, axis=1) > r).all()
    half = 0.5 * world.config.arena.width_m
    assert (np.abs(poses[:, :2]) < half - r).all()


def test_spawn_is_seeded():
    a, b = _world(), _world()
    a.reset(np.random.default_rng(7))
    b.reset(np.random.default_rng(7))
    assert np.array_equal(a.poses(), b.poses())


def test_differential_drive_follows_the_arc():
    world = _world(n_robots=1, arena=EMPTY, odometry={"slip_noise_std": 0.0})
    world.reset(np.random.default_rng(0))
    _set_pose(world, 0, 0.0, 0.0, 0.0)
    v, omega = 0.2, 0.5
    for _ in range(5):  # let the motors reach the command (acceleration-limited)
        world.step(np.array([[v, omega]]))
    start = world.poses()[0].copy()
    for _ in range(20):  # 2 s at constant speed
        world.step(np.array([[v, omega]]))
    end = world.poses()[0]
    radius, dpsi = v / omega, omega * 2.0
    expected_local = np.array([radius * np.sin(dpsi), radius * (1 - np.cos(dpsi))])
    c, s = np.cos(start[2]), np.sin(start[2])
    got_local = np.array([[c, s], [-s, c]]) @ (end[:2] - start[:2])
    assert np.allclose(got_local, expected_local, atol=5e-3)
    assert np.isclose((end[2] - start[2]), dpsi, atol=5e-3)


def test_no_tunnelling_at_top_speed():
    world = _world(n_robots=20)
    world.reset(np.random.default_rng(1))
    vmax = world.config.robot.max_speed_mps
    half = 0.5 * world.config.arena.width_m
    commands = np.tile([vmax, 0.0], (20, 1))
    for _ in range(300):  # 30 s straight at full speed: everyone hits a wall or a teammate
        world.step(commands)
        assert (np.abs(world.poses()[:, :2]) < half).all()
    poses = world.poses()
    d = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1)
    # Chassis may touch but never pass through each other (centres stay >= the chassis width).
    assert (d[~np.eye(20, dtype=bool)] > 0.9 * world.config.robot.width_m).all()


def test_pulses_to_delta_signs_follow_rep103():
    cfg = make_config("seed-sim").robot
    # Right wheel further than left: a left (counter-clockwise) turn, positive dpsi and dy.
    d = pulses_to_delta(np.array([[1000, 1200]]), cfg.wheel_radius_m, cfg.axle_width_m, 1920)[0]
    assert d[0] > 0 and d[1] > 0 and d[2] > 0
    per_pulse = 2 * np.pi * cfg.wheel_radius_m / 1920
    assert np.isclose(d[2], per_pulse * 200 / cfg.axle_width_m)
    straight = pulses_to_delta(
        np.array([[1920, 1920]]), cfg.wheel_radius_m, cfg.axle_width_m, 1920
    )[0]
    assert np.allclose(straight, [2 * np.pi * cfg.wheel_radius_m, 0.0, 0.0])


def _compose(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array(
        [
            pose[0] + c * delta[0] - s * delta[1],
            pose[1] + s * delta[0] + c * delta[1],
            pose[2] + delta[2],
        ]
    )


@pytest.mark.parametrize("slip", [0.0, 0.02])
def test_odometry_integrates_to_the_true_displacement(slip):
    world = _world(n_robots=1, arena=EMPTY, odometry={"slip_noise_std": slip})
    world.reset(np.random.default_rng(2))
    _set_pose(world, 0, -1.5, -1.0, 0.3)
    start = world.poses()[0].copy()
    estimate = np.zeros(3)
    commands = [(0.25, 0.4)] * 30 + [(0.2, -0.6)] * 30 + [(0.15, 0.0)] * 20
    for v, w in commands:
        step = world.step(np.array([[v, w]]))
        for rec in step.measurements["ugv_0"].odometry:
            estimate = _compose(estimate, rec.delta)
    end = world.poses()[0]
    c, s = np.cos(start[2]), np.sin(start[2])
    true_local = np.array([[c, s], [-s, c]]) @ (end[:2] - start[:2])
    distance = 0.25 * 3 + 0.2 * 3 + 0.15 * 2
    tol = 0.01 + 3 * slip * distance
    assert np.linalg.norm(estimate[:2] - true_local) < tol
    assert abs(estimate[2] - (end[2] - start[2])) < 0.02 + 10 * slip


def test_relative_positions_frame_signs():
    # Observer at the origin facing +y (yaw 90 deg); a robot at world (1, 0) is on its right.
    rel = relative_positions(np.array([[0.0, 0.0, np.pi / 2]]), np.array([[1.0, 0.0]]))
    assert np.allclose(rel[0, 0], [0.0, -1.0])
    # A robot straight ahead (world (0, 2)) is at x = +2 in the body frame.
    rel = relative_positions(np.array([[0.0, 0.0, np.pi / 2]]), np.array([[0.0, 2.0]]))
    assert np.allclose(rel[0, 0], [2.0, 0.0])


def test_truth_matches_the_bodies():
    world = _world(n_robots=3, arena=EMPTY)
    world.reset(np.random.default_rng(0))
    _set_pose(world, 0, 0.0, 0.0, np.pi / 2)
    _set_pose(world, 1, 1.0, 0.0, 0.0)
    _set_pose(world, 2, -2.5, 2.5, 0.0)
    truth = world.ground_truth()
    assert np.allclose(truth.relative_xy[0, 1], [0.0, -1.0])
    assert truth.in_range["lidar"][0, 1] and not truth.in_range["lidar"][0, 2]
    assert not truth.in_range["lidar"][0, 0]
