"""Lidar ray casting, interference and the feature extractor vs analytic cases and a naive loop."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swarm_core.perception.lidar_features import (
    LidarFeatureConfig,
    extract_clusters,
    extract_detections,
    null_bearings,
)
from swarm_core.validation import check_blind_sectors
from swarm_env.sensors.lidar import (
    HIT_CIRCLE,
    HIT_NONE,
    HIT_SEGMENT,
    LidarConfig,
    LidarSensor,
)
from swarm_env.sensors.scene_builder import make_pair_scene
from tests.swarm_env.scene_factory import EXACT_LIDAR as EXACT
from tests.swarm_env.scene_factory import (
    HOUSING_RADIUS_M,
    POST_RADIUS_M,
    SceneBuilder,
    make_arena_scene,
)

DEG = math.pi / 180.0


def scan_one(scene, robot=0, config=EXACT, seed=0, stamp=1.0, sensor=None):
    sensor = sensor or LidarSensor(config, scene.n_robots)
    batch = sensor.scan(scene, np.array([robot]), np.array([stamp]), np.random.default_rng(seed))
    return sensor, batch


def beam_index(angle_rad: float, n_beams: int = 720) -> int:
    return int(round((angle_rad + math.pi) / (2 * math.pi / n_beams))) % n_beams


def rel_world(x0, y0, yaw, bearing, dist):
    """World point at robot-frame bearing/distance from a robot at (x0, y0, yaw)."""
    return x0 + dist * math.cos(yaw + bearing), y0 + dist * math.sin(yaw + bearing)


# --------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("rate_hz", -7.0),
        ("n_beams", 0),
        ("range_min_m", -0.1),
        ("range_max_m", 0.1),
        ("range_noise_std_m", -0.01),
        ("interference_tolerance_deg", 200.0),
        ("head_rate_jitter_hz", 8.0),
    ],
)
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        LidarConfig(**{field: value})


def test_config_rejects_mismatched_blind_sectors():
    with pytest.raises(ValueError, match="blind_sector_widths_deg"):
        LidarConfig(blind_sector_centers_deg=(45.0,), blind_sector_widths_deg=(10.0, 10.0))


def test_beam_angles_follow_the_convention():
    sensor = LidarSensor(LidarConfig(), 1)
    angles = sensor.angles_rad
    assert angles.shape == (720,)
    assert angles[0] == -math.pi
    np.testing.assert_allclose(np.diff(angles), 0.5 * DEG, atol=1e-12)
    assert angles.max() < math.pi


# --------------------------------------------------------------------------- analytic ranges


@pytest.mark.parametrize("yaw", [0.0, 0.3, -2.9])
def test_beam_through_circle_centre_returns_distance_minus_radius(yaw):
    b = SceneBuilder()
    b.add_robot(1.0, 2.0, yaw_rad=yaw)
    bearing = -30.0 * DEG  # beam 300 exactly
    x, y = rel_world(1.0, 2.0, yaw, bearing, 1.5)
    b.add_robot(x, y, yaw_rad=0.7)
    _, batch = scan_one(b.build())
    k = beam_index(bearing)
    assert batch.angles_rad[k] == pytest.approx(bearing)
    assert batch.ranges_m[0, k] == pytest.approx(1.5 - HOUSING_RADIUS_M, abs=1e-9)
    assert batch.hit_owner[0, k] == 1
    assert batch.hit_kind[0, k] == HIT_CIRCLE


def test_wall_at_two_metres_returns_two_over_cos():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_segment(2.0, -50.0, 2.0, 50.0)
    _, batch = scan_one(b.build())
    a = batch.angles_rad
    expected = 2.0 / np.cos(a)
    in_reach = (np.abs(a) < math.pi / 2) & (expected <= EXACT.range_max_m)
    np.testing.assert_allclose(batch.ranges_m[0, in_reach], expected[in_reach], rtol=1e-12)
    assert np.all(batch.ranges_m[0, ~in_reach] == 0.0)
    assert np.all(batch.hit_kind[0, in_reach] == HIT_SEGMENT)
    assert np.all(batch.hit_kind[0, ~in_reach] == HIT_NONE)
    assert np.all(batch.hit_owner[0] == -1)


def test_corner_beam_is_not_lost_between_two_walls():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_walls(6.0, 6.0)  # beam 450 (+45 deg) goes exactly through the corner (3, 3)
    _, batch = scan_one(b.build())
    assert np.all(batch.ranges_m[0] > 0.0)
    assert batch.ranges_m[0, beam_index(45 * DEG)] == pytest.approx(3.0 * math.sqrt(2.0))


def test_range_limits_drop_returns():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_circle(11.0, 0.0, 0.5)  # nearest point 10.5 m > range_max
    b.add_circle(0.0, 0.1, 0.0)  # zero-radius: never hit
    b.add_circle(-0.08, 0.0, 0.03)  # every point it shows is nearer than range_min
    _, batch = scan_one(b.build())
    assert np.all(batch.ranges_m == 0.0)
    assert np.all(batch.intensities == 0.0)
    assert np.all(batch.hit_kind == HIT_NONE)


def test_own_circles_and_non_lidar_circles_are_ignored():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)  # own housing and strip surround the sensor
    b.add_circle(1.0, 0.0, 0.1, lidar=False)  # above lidar height
    b.add_segment(2.0, -1.0, 2.0, 1.0)
    _, batch = scan_one(b.build())
    assert batch.ranges_m[0, beam_index(0.0)] == pytest.approx(2.0)


def naive_scan(scene, robot, config):
    """Reference: loop over every beam and every shape with textbook formulas."""
    n_beams = config.n_beams
    ox, oy = scene.robot_xy[robot]
    yaw = scene.robot_yaw[robot]
    ranges = np.zeros(n_beams)
    owners = np.full(n_beams, -1)
    for k in range(n_beams):
        theta = yaw - math.pi + k * 2 * math.pi / n_beams
        ux, uy = math.cos(theta), math.sin(theta)
        best, best_owner = math.inf, -1
        for c in range(scene.circle_xy.shape[0]):
            if not scene.circle_lidar[c] or scene.circle_owner[c] == robot:
                continue
            px, py = scene.circle_xy[c, 0] - ox, scene.circle_xy[c, 1] - oy
            r = scene.circle_radius_m[c]
            tc = px * ux + py * uy
            disc = r * r - (px * px + py * py - tc * tc)
            if disc < 0 or px * px + py * py <= r * r:
                continue
            t = tc - math.sqrt(disc)
            if 0 < t < best:
                best, best_owner = t, scene.circle_owner[c]
        for s in range(scene.segment_a.shape[0]):
            ax, ay = scene.segment_a[s, 0] - ox, scene.segment_a[s, 1] - oy
            ex = scene.segment_b[s, 0] - scene.segment_a[s, 0]
            ey = scene.segment_b[s, 1] - scene.segment_a[s, 1]
            den = ux * ey - uy * ex
            if den == 0:
                continue
            t = (ax * ey - ay * ex) / den
            u = (ax * uy - ay * ux) / den
            if 0 <= u <= 1 and 0 < t < best:
                best, best_owner = t, -1
        if config.range_min_m <= best <= config.range_max_m:
            ranges[k], owners[k] = best, best_owner
    return ranges, owners


@pytest.mark.parametrize("seed", [1, 2])
def test_vectorised_scan_matches_naive_loop(seed):
    scene = make_arena_scene(np.random.default_rng(seed), n_robots=8, n_posts=5, n_boxes=3)
    robots = np.array([0, 3, 7])
    sensor = LidarSensor(EXACT, scene.n_robots)
    batch = sensor.scan(scene, robots, np.ones(3), np.random.default_rng(0))
    for row, robot in enumerate(robots):
        ranges, owners = naive_scan(scene, robot, EXACT)
        np.testing.assert_allclose(batch.ranges_m[row], ranges, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(batch.hit_owner[row], owners)
    assert np.any(batch.hit_owner >= 0)  # the comparison covered robot hits too


# --------------------------------------------------------------------------- noise, intensity


def test_range_noise_is_gaussian_with_the_configured_sigma():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_walls(6.0, 6.0)
    scene = b.build()
    config = dataclasses.replace(EXACT, range_noise_std_m=0.01)
    sensor = LidarSensor(config, 1)
    exact = LidarSensor(EXACT, 1).scan(scene, [0], [0.0], np.random.default_rng(0)).ranges_m
    batch = sensor.scan(scene, np.zeros(50, int), np.zeros(50), np.random.default_rng(3))
    err = batch.ranges_m - exact
    assert abs(err.mean()) < 5e-4
    assert err.std() == pytest.approx(0.01, rel=0.05)


def test_intensity_positive_exactly_on_valid_returns():
    scene = make_arena_scene(np.random.default_rng(4))
    sensor = LidarSensor(LidarConfig(), scene.n_robots)
    sensor.reset(np.random.default_rng(5))
    batch = sensor.scan(scene, np.arange(6), np.full(6, 2.0), np.random.default_rng(6))
    valid = batch.ranges_m > 0
    assert np.all(batch.intensities[valid] > 0)
    assert np.all(batch.intensities[~valid] == 0)
    assert valid.mean() > 0.8


def test_intensity_falls_with_range():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_segment(1.0, -0.5, 1.0, 0.5, intensity=1.0)
    b.add_segment(-3.0, -0.5, -3.0, 0.5, intensity=1.0)
    _, batch = scan_one(b.build())
    near, far = batch.intensities[0, beam_index(0.0)], batch.intensities[0, 0]
    assert 0 < far < near


# --------------------------------------------------------------------------- blind sectors


def test_blind_sector_beams_return_nothing():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_walls(6.0, 6.0)
    sensor, batch = scan_one(b.build(), config=LidarConfig(range_noise_std_m=0.0))
    blind = sensor.blind_mask
    assert blind.sum() == 4 * 21  # +/- 5 deg around each centre, 0.5 deg beams, inclusive
    for centre in (45.0, 135.0, -135.0, -45.0):
        assert blind[beam_index(centre * DEG)]
    assert np.all(batch.ranges_m[0, blind] == 0) and np.all(batch.intensities[0, blind] == 0)
    assert np.all(batch.ranges_m[0, ~blind] > 0)


# --------------------------------------------------------------------------- contract


def _readonly_scene(scene):
    for f in dataclasses.fields(scene):
        if getattr(scene, f.name) is not None:
            getattr(scene, f.name).setflags(write=False)
    return scene


def test_scan_is_deterministic_and_does_not_mutate_the_scene():
    scene = _readonly_scene(make_arena_scene(np.random.default_rng(7)))  # writes would raise
    before = {f.name: np.copy(getattr(scene, f.name)) for f in dataclasses.fields(scene)}
    sensor = LidarSensor(LidarConfig(), scene.n_robots)
    sensor.reset(np.random.default_rng(8))
    a = sensor.scan(scene, np.arange(5), np.full(5, 3.0), np.random.default_rng(9))
    b = sensor.scan(scene, np.arange(5), np.full(5, 3.0), np.random.default_rng(9))
    c = sensor.scan(scene, np.arange(5), np.full(5, 3.0), np.random.default_rng(10))
    for f in dataclasses.fields(a):
        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name))
    assert not np.array_equal(a.ranges_m, c.ranges_m)
    for f in dataclasses.fields(scene):
        np.testing.assert_array_equal(getattr(scene, f.name), before[f.name])


def test_scan_rejects_bad_inputs():
    scene = make_arena_scene(np.random.default_rng(0), n_robots=3)
    sensor = LidarSensor(LidarConfig(), 3)
    with pytest.raises(ValueError, match="stamps_s"):
        sensor.scan(scene, np.array([0, 1]), np.array([0.0]), np.random.default_rng(0))
    with pytest.raises(ValueError, match="robots"):
        sensor.scan(scene, np.array([3]), np.array([0.0]), np.random.default_rng(0))


def test_empty_batch_and_empty_scene():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0, housing=False, strip=False)
    scene = b.build()
    sensor = LidarSensor(LidarConfig(), 1)
    batch = sensor.scan(scene, np.zeros(0, int), np.zeros(0), np.random.default_rng(0))
    assert batch.ranges_m.shape == (0, 720)
    batch = sensor.scan(scene, [0], [0.0], np.random.default_rng(0))
    assert np.all(batch.ranges_m == 0) and np.all(batch.hit_index == -1)


def test_owner_beam_counts_match_hit_owner():
    scene = make_arena_scene(np.random.default_rng(11), n_robots=10)
    sensor = LidarSensor(LidarConfig(), 10)
    batch = sensor.scan(scene, np.arange(4), np.zeros(4), np.random.default_rng(0))
    counts = batch.owner_beam_counts(10, after_interference=False)
    for k in range(4):
        np.testing.assert_array_equal(
            counts[k], np.bincount(batch.hit_owner[k][batch.hit_owner[k] >= 0], minlength=10)
        )
        assert counts[k, k] == 0


# --------------------------------------------------------------------------- interference


def facing_pair(yaw_j=math.pi):
    b = SceneBuilder()
    b.add_robot(0.0, 0.0, yaw_rad=0.0)
    b.add_robot(1.0, 0.0, yaw_rad=yaw_j)
    b.add_walls(6.0, 6.0)  # every other beam returns
    return b.build()


def align_head(sensor, scene, j, i_stamp, aligned=True):
    """Set robot j's head phase so it points at robot 0 when robot 0's beam 360 fires."""
    cfg = sensor.config
    rate = sensor.rates_hz[0]
    t_fire = i_stamp - 1.0 / rate + (360 / cfg.n_beams) / rate
    to_i = math.atan2(
        scene.robot_xy[0, 1] - scene.robot_xy[j, 1], scene.robot_xy[0, 0] - scene.robot_xy[j, 0]
    )
    target_body = to_i - scene.robot_yaw[j] + (0.0 if aligned else math.pi)
    phase = target_body - 2 * math.pi * sensor.rates_hz[j] * t_fire
    sensor.head_phase_rad[j] = phase % (2 * math.pi)


def test_facing_heads_null_exactly_the_beams_on_the_other_housing():
    scene = facing_pair()
    config = dataclasses.replace(EXACT, interference_tolerance_deg=6.0)
    sensor = LidarSensor(config, 2)
    sensor.rate_offset_hz[:] = (0.02, -0.03)
    align_head(sensor, scene, 1, i_stamp=5.0)
    _, batch = scan_one(scene, sensor=sensor, stamp=5.0)
    on_j = batch.hit_owner[0] == 1
    assert 5 <= on_j.sum() <= 9  # +/- asin(32.5 mm / 1 m) at 0.5 deg per beam
    np.testing.assert_array_equal(batch.interfered[0], on_j)
    assert np.all(batch.ranges_m[0, on_j] == 0) and np.all(batch.intensities[0, on_j] == 0)
    nulls = null_bearings(batch.angles_rad, batch.ranges_m[0], batch.intensities[0])
    np.testing.assert_array_equal(nulls, batch.angles_rad[on_j])


def test_misaligned_heads_return_normally():
    scene = facing_pair()
    config = dataclasses.replace(EXACT, interference_tolerance_deg=6.0)
    sensor = LidarSensor(config, 2)
    align_head(sensor, scene, 1, i_stamp=5.0, aligned=False)
    _, batch = scan_one(scene, sensor=sensor, stamp=5.0)
    on_j = batch.hit_owner[0] == 1
    assert on_j.sum() >= 5
    assert not batch.interfered.any()
    np.testing.assert_allclose(batch.ranges_m[0, on_j].min(), 1.0 - HOUSING_RADIUS_M, atol=1e-9)


def test_head_pointing_into_its_own_pillar_does_not_interfere():
    # j's yaw puts the direction to i at robot-frame -135 deg: inside j's blind sector.
    scene = facing_pair(yaw_j=math.pi + 135 * DEG)
    config = dataclasses.replace(
        LidarConfig(range_noise_std_m=0.0), interference_tolerance_deg=6.0
    )
    sensor = LidarSensor(config, 2)
    align_head(sensor, scene, 1, i_stamp=5.0)
    _, batch = scan_one(scene, sensor=sensor, stamp=5.0)
    assert (batch.hit_owner[0] == 1).sum() >= 5
    assert not batch.interfered.any()


def test_interference_is_pseudo_periodic_over_time():
    scene = facing_pair()
    sensor = LidarSensor(LidarConfig(), 2)
    sensor.reset(np.random.default_rng(12))
    stamps = np.arange(0.0, 60.0, 1 / 7.0)
    batch = sensor.scan(scene, np.zeros(stamps.size, int), stamps, np.random.default_rng(0))
    hit_scans = batch.interfered.any(axis=1)
    # Some revolutions are nulled, most are not (the heads drift in and out of phase).
    assert 0 < hit_scans.sum() < 0.5 * stamps.size


def test_scan_stamps_end_revolutions_with_the_head_at_minus_pi():
    sensor = LidarSensor(LidarConfig(), 5)
    sensor.reset(np.random.default_rng(13))
    robots, stamps = sensor.scan_stamps(10.0, 12.0)
    assert np.all((stamps > 10.0) & (stamps <= 12.0)) and np.all(np.diff(stamps) >= 0)
    counts = np.bincount(robots, minlength=5)
    assert np.all((counts >= 13) & (counts <= 15))  # 2 s at ~7 Hz
    head = sensor.head_angle_rad(robots, stamps)
    np.testing.assert_allclose(np.abs(head), math.pi, atol=1e-6)


# --------------------------------------------------------------------------- features


def detect(scene, robot=0, lidar=None, features=None, seed=0):
    sensor = LidarSensor(lidar or LidarConfig(interference_tolerance_deg=0.0), scene.n_robots)
    batch = sensor.scan(scene, np.array([robot]), np.zeros(1), np.random.default_rng(seed))
    return extract_detections(batch.angles_rad, batch.ranges_m, features)[0]


def test_robot_at_known_position_is_detected_there():
    b = SceneBuilder()
    b.add_robot(0.5, -0.2, yaw_rad=0.4)
    x, y = rel_world(0.5, -0.2, 0.4, 20 * DEG, 1.2)
    b.add_robot(x, y)
    b.add_walls(6.0, 6.0)
    det = detect(b.build())
    assert det.shape == (1, 2)
    expected = 1.2 * np.array([math.cos(20 * DEG), math.sin(20 * DEG)])
    assert np.linalg.norm(det[0] - expected) < 0.02


def test_decoy_post_is_a_false_positive_and_a_box_is_rejected():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_post(1.0, 0.5, radius_m=POST_RADIUS_M)
    b.add_box(-1.5, 0.5, 0.5, 0.4, yaw_rad=0.3)
    b.add_walls(6.0, 6.0)
    det = detect(b.build())
    assert det.shape == (1, 2)
    np.testing.assert_allclose(det[0], [1.0, 0.5], atol=0.03)


def test_empty_arena_with_boxes_yields_no_detections():
    b = SceneBuilder()
    b.add_robot(0.3, -0.4, yaw_rad=1.0)
    b.add_box(1.5, 1.0, 0.5, 0.5)
    b.add_box(-1.2, -1.5, 0.3, 0.6, yaw_rad=0.7)
    b.add_walls(6.0, 6.0)
    for seed in range(5):
        assert detect(b.build(), seed=seed).shape == (0, 2)


@pytest.mark.parametrize(("bearing_deg", "seen"), [(45.0, False), (-135.0, False), (60.0, True)])
def test_blind_sector_hides_a_robot(bearing_deg, seen):
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(*rel_world(0.0, 0.0, 0.0, bearing_deg * DEG, 1.0))
    det = detect(b.build())
    assert det.shape[0] == int(seen)


def test_occluded_robot_is_missing():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.0)
    b.add_robot(2.0, 0.0)  # hidden behind robot 1
    det = detect(b.build())
    assert det.shape == (1, 2)
    np.testing.assert_allclose(det[0], [1.0, 0.0], atol=0.02)


def test_robot_straddling_the_seam_is_one_detection():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(-1.0, 0.0)  # directly behind: beams on both sides of +/-pi
    det = detect(b.build())
    assert det.shape == (1, 2)
    np.testing.assert_allclose(det[0], [-1.0, 0.0], atol=0.02)


def test_frame_signs_robot_on_the_right_is_at_negative_y():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0, yaw_rad=math.pi / 2)  # facing world +y
    b.add_robot(1.0, 0.0)  # world +x = the observer's right
    det = detect(b.build())
    np.testing.assert_allclose(det[0], [0.0, -1.0], atol=0.02)


def test_extractor_on_synthetic_ranges():
    angles = -math.pi + np.arange(720) * (2 * math.pi / 720)
    ranges = np.zeros((3, 720))
    ranges[0, [0, 1, 2, 718, 719]] = 1.0  # one cluster through the seam
    ranges[1, :] = 2.0  # a ring: the whole circle is one (huge) cluster
    ranges[2, 100:104] = 1.5  # a small object ...
    ranges[2, 104:110] = 3.0  # ... in front of a jump
    clusters = extract_clusters(angles, ranges)
    np.testing.assert_array_equal(clusters.scan_index, [0, 2])
    assert clusters.n_beams.tolist() == [5, 4]
    np.testing.assert_allclose(clusters.xy_m[0], [-1.0 - HOUSING_RADIUS_M, 0.0], atol=1e-9)
    per_scan = clusters.split()
    assert [len(p) for p in per_scan] == [1, 0, 1]


def test_extractor_width_range_and_count_gates():
    angles = -math.pi + np.arange(720) * (2 * math.pi / 720)
    ranges = np.zeros((1, 720))
    ranges[0, 10:30] = 1.0  # 20 beams at 1 m: ~0.17 m wide
    ranges[0, 200:203] = 6.0  # 3 beams: 10 cm across at 6 m, narrower than the width limit
    ranges[0, 400:402] = 1.0  # 2 beams: fewer than min_beams = 3
    width_only = LidarFeatureConfig(extent_test=False)
    assert extract_detections(angles, ranges, width_only)[0].shape == (1, 2)  # the 3-beam one
    # ... which spans 1.5 deg with its footprints, where a housing at 6 m subtends 0.62 deg.
    assert extract_detections(angles, ranges)[0].shape == (0, 2)
    clusters = extract_clusters(
        angles, ranges, dataclasses.replace(width_only, tracking_range_m=5.0)
    )
    assert clusters.xy_m.shape == (0, 2)
    clusters = extract_clusters(angles, ranges, dataclasses.replace(width_only, min_beams=2))
    assert clusters.n_beams.tolist() == [3, 2]
    clusters = extract_clusters(
        angles, ranges, dataclasses.replace(width_only, max_width_m=0.2, tracking_range_m=5.0)
    )
    assert clusters.n_beams.tolist() == [20]  # the wide one; the narrow one is beyond 5 m


def test_extent_test_keeps_housings_and_rejects_wider_cylinders_at_every_range():
    """The arena's 120 mm red decoy passes the end-to-end width test at 1.5-3 m (range noise
    tolerance); the angular extent test rejects it up to 2.2 m with the geometric bound (the
    default, which holds for any scanner) and at every range with the simulated scanner's own
    footprint (``beam_footprint_deg=0.5``); a housing passes both alike. Targets clear of the
    blind sectors (one that a blind sector cuts shows a narrower arc)."""
    rng = np.random.default_rng(5)
    cfg = LidarConfig(interference_tolerance_deg=0.0)
    configs = {
        "default": None,
        "footprint": LidarFeatureConfig(beam_footprint_deg=cfg.beam_footprint_deg),
        "width_only": LidarFeatureConfig(extent_test=False),
    }
    for r in (0.5, 1.0, 1.5, 2.0, 2.2, 3.0, 3.5):
        margin = math.degrees(math.asin(0.06 / r)) + 1.0
        scene, bearings = make_pair_scene(
            rng,
            r,
            200,
            avoid_centers_deg=cfg.blind_sector_centers_deg,
            avoid_half_widths_deg=tuple(0.5 * w + margin for w in cfg.blind_sector_widths_deg),
        )
        truth = r * np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
        decoy = dataclasses.replace(
            scene,
            circle_radius_m=np.where(
                scene.circle_lidar & (scene.circle_owner % 2 == 1), 0.06, scene.circle_radius_m
            ),
        )
        rates = {}
        for name, target in (("housing", scene), ("decoy", decoy)):
            sensor = LidarSensor(cfg, target.n_robots)
            observers = np.arange(0, target.n_robots, 2)
            batch = sensor.scan(target, observers, np.ones(observers.size), rng)
            for features, feature_cfg in configs.items():
                dets = extract_clusters(batch.angles_rad, batch.ranges_m, feature_cfg)
                near = np.linalg.norm(dets.xy_m - truth[dets.scan_index], axis=1) <= 0.15
                rates[name, features] = np.unique(dets.scan_index[near]).size / observers.size
        assert rates["housing", "default"] == rates["housing", "width_only"], r
        assert rates["housing", "footprint"] == rates["housing", "width_only"], r
        if r <= 1.5:
            assert rates["housing", "default"] == 1.0, r  # every housing in reach is kept
        assert rates["decoy", "footprint"] == 0.0, r
        if r <= 2.2:
            assert rates["decoy", "default"] == 0.0, r
        if 1.5 <= r <= 3.0:
            assert rates["decoy", "width_only"] > 0.9, r  # what the width test alone lets by


def test_width_tolerance_grows_with_the_range_noise():
    """Width limit = 65 mm + 2 sqrt(2) sigma(r), sigma(r) = 0.01 + 0.0025 r^2 (defaults), at the
    cluster's mean range: a 3-beam cluster whose end-to-end width is 2 % under the limit is
    kept, 2 % over it is not (the width test alone: the extent test is off here)."""
    from scipy.optimize import brentq

    angles = -math.pi + np.arange(720) * (2 * math.pi / 720)
    cfg = LidarFeatureConfig(jump_range_gain=1.0, extent_test=False)

    def width_over_limit(r: float, dr: float) -> float:
        """End-to-end width / limit of returns (r, r, r + dr) on beams 100-102."""
        chord = math.hypot(
            (r + dr) * math.cos(angles[102]) - r * math.cos(angles[100]),
            (r + dr) * math.sin(angles[102]) - r * math.sin(angles[100]),
        )
        mean_r = r + dr / 3
        return chord / (0.065 + 2.0 * math.sqrt(2.0) * (0.01 + 0.0025 * mean_r**2))

    for r in (1.0, 2.0, 3.0):
        for ratio, kept in ((0.98, 1), (1.02, 0)):
            # the range step that makes the width `ratio` times the limit
            dr = brentq(lambda d, r=r, ratio=ratio: width_over_limit(r, d) - ratio, 0.0, 0.5)
            ranges = np.zeros((1, 720))
            ranges[0, 100:103] = [r, r, r + dr]
            assert extract_clusters(angles, ranges, cfg).xy_m.shape[0] == kept, (r, ratio)


def test_oblique_walls_shatter_only_without_the_breakpoint_and_foreground_tests():
    b = SceneBuilder()
    b.add_robot(0.0, -2.7)  # 0.3 m from the bottom wall: long oblique stretches
    b.add_walls(6.0, 6.0)
    scene = b.build()
    # The previous round's rules: one return suffices, a fixed 78 mm width limit.
    old = {"min_beams": 1, "width_noise_sigmas": 0.0, "max_width_m": 0.078}
    seed_like = LidarFeatureConfig(jump_range_gain=0.0, foreground_only=False, **old)
    adaptive_only = LidarFeatureConfig(foreground_only=False, **old)
    assert detect(scene, features=seed_like).shape[0] > 20
    assert 0 < detect(scene, features=adaptive_only).shape[0] < 10  # beyond 80 deg incidence
    assert detect(scene, features=LidarFeatureConfig(**old)).shape[0] == 0
    # Three returns per cluster alone remove the grazing slivers too.
    no_foreground = LidarFeatureConfig(foreground_only=False)
    assert detect(scene, features=no_foreground).shape[0] == 0
    assert detect(scene).shape[0] == 0


def test_null_bearings_exclude_mask():
    angles = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    ranges = np.array([0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 1.0, 1.0])
    intens = np.array([0.0, 5.0, 0.0, 3.0, 1.0, 0.0, 1.0, 1.0])  # beam 3: range 0, intensity 3
    np.testing.assert_array_equal(null_bearings(angles, ranges, intens), angles[[0, 2, 5]])
    exclude = np.zeros(8, bool)
    exclude[2] = True
    np.testing.assert_array_equal(null_bearings(angles, ranges, intens, exclude), angles[[0, 5]])


@pytest.mark.parametrize(
    ("field", "value"), [("max_width_m", 0.0), ("min_beams", 0), ("jump_threshold_m", -1.0)]
)
def test_feature_config_validation(field, value):
    with pytest.raises(ValueError, match=field):
        LidarFeatureConfig(**{field: value})


# --------------------------------------------------------------------------- detection vs range


def housing_scans(r, n_pairs=300, seed=0, config=None):
    """Scans of ``n_pairs`` isolated (scanner, housing at range r) pairs, the whole housing
    outside the blind sectors, without interference."""
    cfg = config or LidarConfig(interference_tolerance_deg=0.0)
    margin = math.degrees(math.asin(HOUSING_RADIUS_M / r)) + 1.0
    half = tuple(0.5 * w + margin for w in cfg.blind_sector_widths_deg)
    rng = np.random.default_rng(seed)
    scene, bearings = make_pair_scene(
        rng, r, n_pairs, avoid_centers_deg=cfg.blind_sector_centers_deg, avoid_half_widths_deg=half
    )
    sensor = LidarSensor(cfg, scene.n_robots)
    observers = np.arange(0, scene.n_robots, 2)
    batch = sensor.scan(scene, observers, np.ones(observers.size), rng)
    counts = batch.owner_beam_counts(scene.n_robots)[np.arange(observers.size), observers + 1]
    return batch, bearings, counts


DEFAULT_LIDAR = LidarConfig()


def clean_returns(r, cfg=DEFAULT_LIDAR):
    """Expected returns on a 65 mm housing at range r: beams whose 0.5 deg footprint lies on it,
    ``2 asin(R / r) / 0.5 deg - 1`` (~ 65 mm / (r x 0.5 deg) - 1)."""
    return (2.0 * math.asin(HOUSING_RADIUS_M / r) - math.radians(cfg.beam_footprint_deg)) / (
        cfg.beam_spacing_rad
    )


@pytest.mark.parametrize("r", [0.5, 1.0, 1.5, 2.0, 3.0])
def test_housing_return_count_matches_the_beam_geometry(r):
    _, _, counts = housing_scans(r)
    n = clean_returns(r)
    assert abs(n - (0.065 / (r * math.radians(0.5)) - 1.0)) < 0.01 * n + 0.01  # small angles
    # Each scan gets floor(n) or ceil(n) returns (the beam grid's phase is uniform) ...
    assert set(np.unique(counts).tolist()) <= {math.floor(n), math.ceil(n)}
    # ... and ceil(n) with probability frac(n): the mean is n.
    assert counts.mean() == pytest.approx(n, abs=3.0 * 0.5 / math.sqrt(counts.size) + 0.02)


@pytest.mark.parametrize("r", [1.0, 1.7, 2.0, 2.2, 2.6, 3.5])
def test_detection_probability_falls_as_the_return_count_predicts(r):
    """A cluster needs 3 returns: P_d = P(returns >= 3) = clip(n - 2, 0, 1), times the width
    test's pass rate (>= 95 % by construction, ~99 % measured)."""
    batch, bearings, _ = housing_scans(r, n_pairs=400, seed=1)
    dets = extract_clusters(batch.angles_rad, batch.ranges_m)
    truth = r * np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
    ok = np.linalg.norm(dets.xy_m - truth[dets.scan_index], axis=1) <= 0.15
    found = np.zeros(bearings.size, dtype=bool)
    found[dets.scan_index[ok]] = True
    expected = min(max(clean_returns(r) - 2.0, 0.0), 1.0)
    tol = 3.0 * math.sqrt(max(expected * (1 - expected), 0.01) / bearings.size) + 0.02
    assert found.mean() == pytest.approx(expected, abs=tol)
    assert found.mean() <= expected + 0.01  # never better than the geometry allows


def test_centre_error_grows_with_range_but_stays_below_the_filter_noise():
    errs = []
    for r in (0.5, 1.5):
        batch, bearings, _ = housing_scans(r, n_pairs=200, seed=2)
        dets = extract_clusters(batch.angles_rad, batch.ranges_m)
        truth = r * np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
        errs.append(np.sqrt(np.mean(np.sum((dets.xy_m - truth[dets.scan_index]) ** 2, axis=1))))
    assert errs[0] < errs[1] < 0.05  # Perera 2021's R_L sigma is 5 cm


@pytest.mark.parametrize("r", [1.0, 3.0, 5.0])
def test_range_noise_grows_quadratically_with_range(r):
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_segment(r, -2.0, r, 2.0)  # a wall at x = r
    config = LidarConfig(interference_tolerance_deg=0.0)
    sensor = LidarSensor(config, 1)
    batch = sensor.scan(b.build(), np.zeros(400, int), np.ones(400), np.random.default_rng(4))
    front = np.abs(batch.angles_rad) < math.radians(2.0)  # within 2 deg: range ~ r
    exact = r / np.cos(batch.angles_rad[front])
    z = batch.ranges_m[:, front] - exact
    sigma = 0.01 + 0.0025 * r * r
    assert float(config.range_noise_std_at(r)) == pytest.approx(sigma)
    assert z.std() == pytest.approx(sigma, rel=0.03)
    assert abs(z.mean()) < 0.01 * sigma + 1e-4


def test_footprint_drops_the_edge_beams_of_a_circle_only():
    """With a footprint, a circle returns only the beams wholly on it; walls are unchanged."""
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.0)
    b.add_walls(6.0, 6.0)
    scene = b.build()
    thin = scan_one(scene, config=EXACT)[1]
    thick = scan_one(scene, config=dataclasses.replace(EXACT, beam_footprint_deg=0.5))[1]
    half = math.asin(HOUSING_RADIUS_M / 1.0)
    on_thin = np.abs(thin.angles_rad) <= half
    on_thick = np.abs(thick.angles_rad) <= half - math.radians(0.25)
    np.testing.assert_array_equal(thin.hit_owner[0] == 1, on_thin)
    np.testing.assert_array_equal(thick.hit_owner[0] == 1, on_thick)
    walls = thin.hit_kind[0] == HIT_SEGMENT
    np.testing.assert_array_equal(thick.ranges_m[0, walls], thin.ranges_m[0, walls])
    # A housing narrower than one footprint returns nothing.
    far = SceneBuilder()
    far.add_robot(0.0, 0.0)
    far.add_robot(8.0, 0.0)  # subtends 0.47 deg < 0.5 deg
    assert not (
        scan_one(far.build(), config=dataclasses.replace(EXACT, beam_footprint_deg=0.5))[
            1
        ].hit_owner
        == 1
    ).any()


@pytest.mark.parametrize(
    ("centers", "widths", "match"),
    [
        ((45.0,), (0.0,), r"LidarConfig.blind_sector_widths_deg must be in \[0.001, 360\)"),
        ((45.0,), (1e-200,), r"must be in \[0.001, 360\) deg, got 1e-200"),
        ((45.0,), (360.0,), "blind_sector_widths_deg"),
        ((45.0, 90.0), (10.0,), "one width per centre"),
        ([45.0], [10.0], "blind_sector_centers_deg must be a tuple"),
        ((float("nan"),), (10.0,), "blind_sector_centers_deg must be a tuple of finite"),
    ],
)
def test_blind_sectors_share_one_validation_rule(centers, widths, match):
    """swarm_core.validation.check_blind_sectors: the rule of the lidar and of the filter."""
    with pytest.raises(ValueError, match=match):
        LidarConfig(blind_sector_centers_deg=centers, blind_sector_widths_deg=widths)
    with pytest.raises(ValueError, match=match.replace("LidarConfig", "Owner")):
        check_blind_sectors("Owner", centers, widths)
    check_blind_sectors("Owner", (), ())  # no sectors at all
    check_blind_sectors("Owner", (45.0, -135.0), (10.0, 0.5))
