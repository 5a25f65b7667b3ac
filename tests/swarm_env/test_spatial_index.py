"""The grid index and the big-swarm paths against their brute-force references, bit for bit.

The index only chooses which shapes a sensor reading tests; these tests check that it never
leaves out one that matters: lidar scans, camera frames, ground truth, the truth observation's
tables, spawning and whole rollouts come out identical with the index and with the all-pairs
reference paths.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_core.world import truth_from_poses
from swarm_env import parallel_env
from swarm_env.config import MAX_ROBOTS, PRESETS, make_config
from swarm_env.observation import truth_table, truth_tables
from swarm_env.sensors.camera import CameraConfig, CameraSensor
from swarm_env.sensors.lidar import LidarSensor
from swarm_env.sensors.scene_builder import SceneBuilder
from swarm_env.sensors.spatial_index import build_grid, query
from swarm_env.world.arena import sample_layout
from swarm_env.world.sim import SimWorld, _truth_kernel

LIDAR_FIELDS = ("ranges_m", "intensities", "hit_owner", "hit_kind", "hit_index", "interfered")


def test_grid_query_returns_every_shape_within_reach():
    rng = np.random.default_rng(0)
    m = 400
    xy = rng.uniform(-12.0, 9.0, size=(m, 2))
    extent = rng.uniform(0.0, 0.4, size=m)
    extent[:3] = [5.0, np.inf, 0.1]  # wider than a cell, infinite: the "always" cell
    xy[2] = [np.nan, 0.0]  # non-finite centre: "always" too
    slot = rng.integers(0, 3, size=m)
    grid = build_grid(xy, extent, slot, n_slots=3, cell_m=0.7)
    for _ in range(200):
        p = rng.uniform(-15.0, 12.0, size=2)
        radius = rng.uniform(0.0, 4.0)
        slots = rng.choice(3, size=rng.integers(1, 4), replace=False)
        got = query(grid, slots, p[0], p[1], radius)
        dist = np.hypot(*(xy - p).T) - extent
        must = np.flatnonzero(np.isin(slot, slots) & (dist <= radius))
        assert np.isin(must, got).all()  # never misses a shape that can reach the point
        assert np.isin(slot[got], slots).all()  # only the slots asked for
        assert len(np.unique(got)) == len(got)
        for always in (0, 1, 2):
            assert (always in got) == (slot[always] in slots)
    with pytest.raises(ValueError, match="slot"):
        build_grid(xy, extent, slot, n_slots=2)
    with pytest.raises(ValueError, match="cell_m"):
        build_grid(xy, extent, cell_m=0.0)


@pytest.fixture(scope="module")
def crowd():
    """A stepped 200-robot world at Perera 2021's density and a time-stacked scene of it."""
    world = SimWorld(make_config("sim-19m-200"))
    world.reset(np.random.default_rng(3))
    rng = np.random.default_rng(4)
    for _ in range(2):
        world.step(rng.uniform([-0.3, -1.5], [0.3, 1.5], size=(world.n_agents, 2)))
    poses = world.poses() + rng.normal(0.0, 0.02, size=(5, world.n_agents, 3))
    return world, world.scene(poses)


def test_lidar_indexed_scans_equal_brute_force(crowd):
    world, scene = crowd
    robots = np.arange(300) % world.n_agents
    stamps = np.linspace(0.1, 0.3, robots.size)
    when = np.arange(robots.size) % 5
    fast = world.lidar.scan(
        scene, robots, stamps, np.random.default_rng(5), time_index=when, indexed=True
    )
    slow = world.lidar.scan(
        scene, robots, stamps, np.random.default_rng(5), time_index=when, indexed=False
    )
    for name in LIDAR_FIELDS:
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    assert (fast.hit_owner >= 0).any() and fast.interfered.any()
    # A single-instant scene (no time index): every circle present.
    one, _ = scene.at(2)
    fast = world.lidar.scan(one, robots[:50], stamps[:50], np.random.default_rng(6), indexed=True)
    slow = world.lidar.scan(one, robots[:50], stamps[:50], np.random.default_rng(6), indexed=False)
    for name in LIDAR_FIELDS:
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)


def test_lidar_tie_goes_to_the_later_shape_in_either_path():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    first = b.add_post(1.0, 0.0)
    second = b.add_post(1.0, 0.0)  # the same post twice: every beam on it ties
    b.add_walls(20.0, 20.0)  # walls wider than a cell: the grid's "always" cell
    scene = b.build()
    sensor = LidarSensor(n_robots=1)
    for indexed in (True, False):
        batch = sensor.scan(
            scene, np.array([0]), np.array([0.1]), np.random.default_rng(0), indexed=indexed
        )
        on_post = batch.hit_index[0][batch.hit_kind[0] == 1]
        assert on_post.size > 0 and set(on_post.tolist()) == {second}, indexed
        assert first < second


def test_camera_indexed_frames_equal_brute_force(crowd):
    world, scene = crowd
    robots = np.arange(400) % world.n_agents
    when = np.arange(robots.size) % 5
    config = CameraConfig(false_positive_rate=1.0, bearing_noise_std_deg=0.5)
    camera = CameraSensor(config)
    fast = camera.observe(scene, robots, np.random.default_rng(7), time_index=when, indexed=True)
    slow = camera.observe(scene, robots, np.random.default_rng(7), time_index=when, indexed=False)
    for name in ("visible", "target_index", "pair_bounds", "pair_target", "target_visible"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    for a, b in zip(fast.bearings + fast.sources, slow.bearings + slow.sources, strict=True):
        np.testing.assert_array_equal(a, b)
    # The pairs are the dense reference's visible entries, row-major.
    _, visible, _ = camera.visibility(scene, robots, when)
    np.testing.assert_array_equal(fast.target_visible, visible)
    assert 0 < visible.sum() < visible.size // 20  # sparse: the point of the index


def test_small_scenes_skip_the_index_and_agree():
    """The default picks brute force where building the grid costs more (a 20-robot step)."""
    b = SceneBuilder()
    for i in range(20):
        b.add_robot(0.3 * i - 3.0, 0.1 * i)
    b.add_walls(8.0, 8.0)
    scene = b.build()
    robots = np.arange(20)
    camera = CameraSensor()
    for indexed in (None, True, False):
        batch = camera.observe(scene, robots, np.random.default_rng(1), indexed=indexed)
        ref = camera.observe(scene, robots, np.random.default_rng(1), indexed=False)
        for x, y in zip(batch.bearings, ref.bearings, strict=True):
            np.testing.assert_array_equal(x, y)
        scan = LidarSensor(n_robots=20).scan(
            scene, robots, np.full(20, 0.1), np.random.default_rng(2), indexed=indexed
        )
        ref = LidarSensor(n_robots=20).scan(
            scene, robots, np.full(20, 0.1), np.random.default_rng(2), indexed=False
        )
        np.testing.assert_array_equal(scan.ranges_m, ref.ranges_m)


def test_compiled_ground_truth_equals_numpy(crowd):
    world, _ = crowd
    fast, slow = world.ground_truth(), world.ground_truth_reference()
    np.testing.assert_array_equal(fast.poses, slow.poses)
    np.testing.assert_array_equal(fast.relative_xy, slow.relative_xy)
    for sensor in ("lidar", "camera"):
        np.testing.assert_array_equal(fast.in_range[sensor], slow.in_range[sensor])
        np.testing.assert_array_equal(fast.visible[sensor], slow.visible[sensor])
    assert fast.in_range["lidar"].any()


def test_truth_kernel_on_range_boundaries():
    """Pairs exactly at (or an ulp from) the lidar and camera ranges decide as numpy's hypot."""
    xy = [(0.0, 0.0), (2.0, 0.0), (0.0, 5.5), (1.2, 1.6), (3.3, 4.4), (-2.0, 1e-300)]
    xy += [(np.nextafter(2.0, 3.0), 0.0), (0.0, -np.nextafter(5.5, 0.0)), (0.0, 0.0)]
    rng = np.random.default_rng(8)
    poses = np.column_stack([np.array(xy), rng.uniform(-np.pi, np.pi, len(xy))])
    poses[0, 2] = 0.0
    rel, lidar, camera = _truth_kernel(
        np.ascontiguousarray(poses[:, :2]), np.cos(poses[:, 2]), np.sin(poses[:, 2]), 2.0, 5.5
    )
    ref = truth_from_poses(poses, 2.0, 5.5)
    np.testing.assert_array_equal(rel, ref.relative_xy)
    np.testing.assert_array_equal(lidar, ref.in_range["lidar"])
    np.testing.assert_array_equal(camera, ref.in_range["camera"])
    assert lidar[0, 1] and not lidar[0, 6] and camera[0, 2] and lidar[0, 8]  # co-located: in


def test_truth_tables_equal_one_table_per_robot():
    rng = np.random.default_rng(9)
    pos = rng.uniform(-6.0, 6.0, size=(150, 2))
    pos[70:73] = pos[5]  # equal distances: the neighbours' index order decides
    rel = pos[None] - pos[:, None]
    mask = (np.hypot(rel[..., 0], rel[..., 1]) <= 2.0) & ~np.eye(150, dtype=bool)
    rows = rng.permutation(150)[:120]
    for top_k in (1, 4, 16):
        fast = truth_tables(rel, mask, rows, top_k)
        slow = np.array([truth_table(rel[i][mask[i]], top_k) for i in rows])
        assert fast.tobytes() == slow.tobytes()
    assert mask.sum(axis=1).max() > 16  # some robots have more neighbours than rows
    assert truth_tables(rel, mask, [], 4).shape == (0, 4, 7)


def _brute_force_layout(arena, robot, n_robots, clearance_m, rng):
    """The spawner before the cell list: every candidate against every placed object."""
    placed = []

    def place(radius):
        hx = 0.5 * arena.width_m - radius - clearance_m
        hy = 0.5 * arena.height_m - radius - clearance_m
        for _ in range(20_000):
            x, y = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
            if all(
                (x - px) ** 2 + (y - py) ** 2 >= (radius + pr + clearance_m) ** 2
                for px, py, pr in placed
            ):
                placed.append((x, y, radius))
                return x, y
        raise ValueError("crowded")

    low, high = arena.box_size_range_m
    boxes = []
    for _ in range(arena.n_boxes):
        size = rng.uniform(low, high, size=2)
        yaw = rng.uniform(-np.pi, np.pi)
        x, y = place(0.5 * float(np.hypot(*size)))
        boxes.append([x, y, size[0], size[1], yaw])
    posts = [place(arena.decoy_post_radius_m) for _ in range(arena.n_decoy_posts)]
    reds = [place(arena.red_decoy_radius_m) for _ in range(arena.n_red_decoys)]
    robots = [place(robot.footprint_radius_m) for _ in range(n_robots)]
    yaws = rng.uniform(-np.pi, np.pi, size=n_robots)
    return np.array(boxes), np.array(posts), np.array(reds), np.array(robots), yaws


@pytest.mark.parametrize(
    ("preset", "overrides"),
    [("sim-6m-20", {}), ("sim-13m-100", {}), ("lab-3m-4", {"n_robots": 25})],
)
def test_spawning_with_the_cell_list_equals_brute_force(preset, overrides):
    cfg = make_config(preset, **overrides)
    for seed in range(3):
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        layout, poses = sample_layout(cfg.arena, cfg.robot, cfg.n_robots, 0.05, rng_a)
        boxes, posts, reds, robots, yaws = _brute_force_layout(
            cfg.arena, cfg.robot, cfg.n_robots, 0.05, rng_b
        )
        np.testing.assert_array_equal(layout.boxes.reshape(-1, 5), boxes.reshape(-1, 5))
        np.testing.assert_array_equal(layout.posts_xy, posts.reshape(-1, 2))
        np.testing.assert_array_equal(layout.red_decoys_xy, reds.reshape(-1, 2))
        np.testing.assert_array_equal(poses, np.column_stack([robots, yaws]))
        assert rng_a.random() == rng_b.random()  # the same number of draws


def test_big_swarm_presets_keep_the_seed_density_and_spawn_apart():
    seed = PRESETS["sim-6m-20"]
    assert MAX_ROBOTS >= 1000
    for name in ("sim-13m-100", "sim-19m-200", "sim-30m-500", "sim-42m-1000"):
        cfg = PRESETS[name]
        assert name.endswith(f"-{cfg.n_robots}")
        for attr in ("n_decoy_posts", "n_red_decoys", "n_boxes"):
            count = getattr(cfg.arena, attr) / cfg.arena.area_m2
            assert count == pytest.approx(getattr(seed.arena, attr) / seed.arena.area_m2, rel=0.02)
        density = cfg.n_robots / cfg.arena.area_m2
        assert density == pytest.approx(seed.n_robots / seed.arena.area_m2, rel=0.02)
    cfg = PRESETS["sim-42m-1000"]
    layout, poses = sample_layout(
        cfg.arena, cfg.robot, cfg.n_robots, cfg.spawn_clearance_m, np.random.default_rng(0)
    )
    gap = np.hypot(*(poses[:, None, :2] - poses[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(gap, np.inf)
    assert gap.min() >= 2 * cfg.robot.footprint_radius_m + cfg.spawn_clearance_m
    assert len(poses) == 1000 and len(layout.posts_xy) == 200 and len(layout.boxes) == 100
    half = 0.5 * cfg.arena.width_m - cfg.robot.footprint_radius_m
    assert np.abs(poses[:, :2]).max() <= half


def test_rollout_with_the_index_equals_the_brute_force_rollout():
    """Whole env steps (sensors, filters, observations, truth) on 100 robots, both paths."""
    outs = []
    for brute in (False, True):
        env = parallel_env("sim-13m-100", max_steps=50)
        env.world.brute_force = brute
        obs, _ = env.reset(seed=11)
        rng = np.random.default_rng(12)
        frames = [obs]
        for _ in range(4):
            acts = {a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents}
            obs, _, _, _, infos = env.step(acts)
            frames.append((obs, infos["ugv_7"]["truth"], infos["ugv_7"]["measurements"]))
        outs.append(frames)
    fast, slow = outs
    _assert_identical(fast, slow)
    assert not math.isnan(float(fast[-1][0]["ugv_0"].sum()))


def _assert_identical(a, b, where="rollout"):
    """Nested dicts / lists / tuples of arrays and scalars, equal bit for bit."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _assert_identical(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_identical(x, y, f"{where}[{k}]")
    else:
        x, y = np.asarray(a), np.asarray(b)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), where
