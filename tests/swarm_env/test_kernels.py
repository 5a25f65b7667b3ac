"""The compiled sensor kernels against simple references, on random scenes and edge cases.

References are brute force (every beam against every shape, every sight line against every
occluder) or, where that is the clearest statement of the behaviour, the vectorised numpy code
the kernels replaced (the feature extractor, the camera frame assembly, the scan schedule).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swarm_core.geometry import wrap_angle
from swarm_core.perception.lidar_features import (
    LidarFeatureConfig,
    extract_clusters,
    extract_wide_objects,
    null_beams,
    null_bearings,
)
from swarm_env.sensors import noise
from swarm_env.sensors.camera import CameraConfig, CameraSensor
from swarm_env.sensors.kernels import wrap
from swarm_env.sensors.lidar import (
    HIT_CIRCLE,
    HIT_NONE,
    HIT_SEGMENT,
    LidarConfig,
    LidarSensor,
    blind_mask,
)
from swarm_env.sensors.odometry import pulses_to_delta
from swarm_env.sensors.scene import Scene
from swarm_env.sensors.scene_builder import HOUSING_RADIUS_M
from swarm_env.world.sim import _drive_velocities, _due_readings
from tests.swarm_env.scene_factory import (
    EXACT_LIDAR as EXACT,
)
from tests.swarm_env.scene_factory import (
    SceneBuilder,
    make_arena_scene,
    sight_line_crosses_segments,
)

# --------------------------------------------------------------------------- references


def reference_scan(scene, robot, config, instant=None):
    """Nearest return of every beam, brute force: (ranges (B,), hit index (B,), kind (B,))."""
    n_beams = config.n_beams
    xy = scene.robot_xy if instant is None or scene.robot_xy.ndim == 2 else scene.robot_xy[instant]
    yaws = scene.robot_yaw if scene.robot_yaw.ndim == 1 else scene.robot_yaw[instant or 0]
    ox, oy = xy[robot]
    yaw = yaws[robot]
    ranges, index, kind = np.zeros(n_beams), np.full(n_beams, -1), np.zeros(n_beams, int)
    for k in range(n_beams):
        theta = yaw - math.pi + k * 2 * math.pi / n_beams
        ux, uy = math.cos(theta), math.sin(theta)
        best, best_i, best_kind = math.inf, -1, HIT_NONE
        for c in range(scene.circle_xy.shape[0]):
            if not scene.circle_lidar[c] or scene.circle_owner[c] == robot:
                continue
            if scene.circle_time is not None and instant is not None:
                if scene.circle_time[c] not in (-1, instant):
                    continue
            px, py = scene.circle_xy[c, 0] - ox, scene.circle_xy[c, 1] - oy
            r = scene.circle_radius_m[c]
            tc = px * ux + py * uy
            disc = r * r - (px * px + py * py - tc * tc)
            # A beam within 1e-9 rad of the tangent is a grazing hit (documented widening).
            if disc < -2e-9 * r * math.hypot(px, py) or px * px + py * py <= r * r or tc <= 0:
                continue
            t = tc - math.sqrt(max(disc, 0.0))
            if 0 < t < best:
                best, best_i, best_kind = t, c, HIT_CIRCLE
        for s in range(scene.segment_a.shape[0]):
            ax, ay = scene.segment_a[s, 0] - ox, scene.segment_a[s, 1] - oy
            ex = scene.segment_b[s, 0] - scene.segment_a[s, 0]
            ey = scene.segment_b[s, 1] - scene.segment_a[s, 1]
            den = ux * ey - uy * ex
            if den == 0:
                continue
            t = (ax * ey - ay * ex) / den
            u = (ax * uy - ay * ux) / den
            if -1e-12 <= u <= 1 + 1e-12 and 0 < t < best:
                best, best_i, best_kind = t, s, HIT_SEGMENT
        if config.range_min_m <= best <= config.range_max_m:
            ranges[k], index[k], kind[k] = best, best_i, best_kind
    return ranges, index, kind


def assert_scan_matches(batch, row, scene, robot, config, instant=None):
    ranges, index, kind = reference_scan(scene, robot, config, instant)
    np.testing.assert_allclose(batch.ranges_m[row], ranges, rtol=0, atol=1e-9)
    # Surfaces agree wherever the nearest hit is unambiguous (not a shared corner).
    same = (batch.hit_kind[row] == kind) & (batch.hit_index[row] == index)
    corner = np.zeros_like(same)
    for b in np.flatnonzero(~same):
        corner[b] = kind[b] == HIT_SEGMENT == batch.hit_kind[row, b]
    assert np.all(same | corner), np.flatnonzero(~(same | corner))


def stacked_arena(rng, n_robots=8, n_instants=3):
    """A random arena whose robots sit at ``n_instants`` instants (as SimWorld stacks them)."""
    base = make_arena_scene(rng, n_robots=n_robots, n_posts=5, n_red_decoys=3, n_boxes=3)
    static = base.circle_owner < 0
    moving = ~static
    xy = np.stack(
        [base.robot_xy + rng.normal(0.0, 0.05, base.robot_xy.shape) for _ in range(n_instants)]
    )
    yaw = np.stack([base.robot_yaw + rng.normal(0.0, 0.3, n_robots) for _ in range(n_instants)])
    owner = base.circle_owner[moving]
    fields = {}
    for name in (
        "circle_radius_m",
        "circle_owner",
        "circle_lidar",
        "circle_camera_occluder",
        "circle_red",
        "circle_intensity",
    ):
        value = getattr(base, name)
        fields[name] = np.concatenate([value[static]] + [value[moving]] * n_instants)
    circle_xy = np.concatenate(
        [base.circle_xy[static]] + [xy[t][owner] for t in range(n_instants)]
    )
    circle_time = np.concatenate(
        [np.full(static.sum(), -1)] + [np.full(moving.sum(), t) for t in range(n_instants)]
    )
    return Scene(
        robot_xy=xy,
        robot_yaw=yaw,
        circle_xy=circle_xy,
        segment_a=base.segment_a,
        segment_b=base.segment_b,
        segment_intensity=base.segment_intensity,
        circle_time=circle_time,
        **fields,
    )


# --------------------------------------------------------------------------- lidar casting


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_scan_kernel_matches_brute_force_on_random_arenas(seed):
    scene = make_arena_scene(np.random.default_rng(seed), n_robots=10, n_posts=6, n_boxes=4)
    robots = np.array([0, 2, 5, 9])
    batch = LidarSensor(EXACT, scene.n_robots).scan(
        scene, robots, np.ones(4), np.random.default_rng(0)
    )
    for row, robot in enumerate(robots):
        assert_scan_matches(batch, row, scene, robot, EXACT)
    assert (batch.hit_kind == HIT_CIRCLE).any() and (batch.hit_kind == HIT_SEGMENT).any()


def test_scan_kernel_matches_brute_force_on_a_time_stacked_scene():
    scene = stacked_arena(np.random.default_rng(8))
    robots = np.array([0, 3, 3, 7, 1])
    when = np.array([0, 0, 2, 1, 2])
    batch = LidarSensor(EXACT, 8).scan(
        scene, robots, np.ones(5), np.random.default_rng(0), time_index=when
    )
    for row, (robot, t) in enumerate(zip(robots, when, strict=True)):
        assert_scan_matches(batch, row, scene, robot, EXACT, instant=t)


def test_scan_edge_cases_corner_grazing_arena_edge_and_empty():
    # A robot 2 cm from the wall, next to the corner; a beam exactly through a box corner;
    # a circle the 0 deg beam grazes at exactly its radius (+ 1e-12).
    b = SceneBuilder()
    b.add_robot(2.98, -2.9, yaw_rad=0.0)  # at the arena edge
    b.add_robot(0.0, 0.0, yaw_rad=0.0)
    b.add_walls(6.0, 6.0)
    b.add_segment(1.0, 1.0, 2.0, 1.0)  # the 45 deg beam of robot 1 passes through (1, 1)
    b.add_segment(1.0, 1.0, 1.0, 2.0)
    b.add_circle(1.5, -(0.03 + 1e-12), 0.03, lidar=True)  # grazed by robot 1's 0 deg beam
    scene = b.build()
    batch = LidarSensor(EXACT, 2).scan(
        scene, np.array([0, 1]), np.ones(2), np.random.default_rng()
    )
    for row in range(2):
        assert_scan_matches(batch, row, scene, row, EXACT)
    corner = round((math.pi / 4 + math.pi) / (2 * math.pi / 720)) % 720
    assert batch.ranges_m[1, corner] == pytest.approx(math.sqrt(2.0), abs=1e-9)
    assert batch.hit_kind[1, corner] == HIT_SEGMENT
    graze = 360  # beam along +x
    assert batch.hit_kind[1, graze] == HIT_CIRCLE
    assert batch.ranges_m[1, graze] == pytest.approx(1.5, abs=1e-4)
    # Nothing to hit: every beam is "no return".
    empty = SceneBuilder()
    empty.add_robot(0.0, 0.0, housing=False, strip=False)
    batch = LidarSensor(LidarConfig(), 1).scan(
        empty.build(), np.array([0]), np.ones(1), np.random.default_rng(1)
    )
    assert not batch.ranges_m.any() and not batch.intensities.any()
    assert (batch.hit_kind == HIT_NONE).all() and (batch.hit_index == -1).all()
    assert (batch.hit_owner == -1).all() and not batch.interfered.any()


def test_noise_limits_and_blind_sectors_with_the_noisy_default_config():
    """The kernel applies noise, range limits and blind sectors as documented."""
    scene = make_arena_scene(np.random.default_rng(9))
    config = LidarConfig(interference_tolerance_deg=0.0)
    sensor = LidarSensor(config, scene.n_robots)
    batch = sensor.scan(scene, np.arange(6), np.ones(6), np.random.default_rng(2))
    thick = dataclasses.replace(EXACT, beam_footprint_deg=config.beam_footprint_deg)
    exact = LidarSensor(thick, scene.n_robots).scan(
        scene, np.arange(6), np.ones(6), np.random.default_rng(2)
    )
    valid = batch.ranges_m > 0
    assert not valid[:, sensor.blind_mask].any()
    assert np.all((batch.ranges_m[valid] >= config.range_min_m) & (batch.ranges_m[valid] <= 10))
    assert np.all(batch.intensities[valid] > 0) and not batch.intensities[~valid].any()
    both = valid & (exact.ranges_m > 0)
    # Same hits (the footprint rule does not depend on the noise); sigma(r) = 0.01 + 0.0025 r^2.
    assert (batch.hit_index[both] == exact.hit_index[both]).all()
    z = (batch.ranges_m[both] - exact.ranges_m[both]) / config.range_noise_std_at(
        exact.ranges_m[both]
    )
    assert abs(z.std() - 1.0) < 0.02 and abs(z.mean()) < 0.02


def reference_interference(sensor, scene, robots, stamps, batch, time_index=None):
    """Per-beam interference flags, straight from the documented model."""
    cfg = sensor.config
    tol = math.radians(cfg.interference_tolerance_deg)
    out = np.zeros(batch.hit_owner.shape, dtype=bool)
    n_heads = min(sensor.n_robots, scene.n_robots)
    for k, me in enumerate(robots):
        t = 0 if time_index is None else time_index[k]
        xy = scene.robot_xy if scene.robot_xy.ndim == 2 else scene.robot_xy[t]
        yaw = scene.robot_yaw if scene.robot_yaw.ndim == 1 else scene.robot_yaw[t]
        for b in range(cfg.n_beams):
            j = batch.hit_owner[k, b]
            if not 0 <= j < n_heads:
                continue
            rate = sensor.rates_hz[me]
            when = stamps[k] - 1.0 / rate + (b / cfg.n_beams) / rate
            head_body = sensor.head_angle_rad(np.array([j]), np.array([when]))[0]
            c = batch.hit_index[k, b]
            to_me = math.atan2(
                xy[me, 1] - scene.circle_xy[c, 1], xy[me, 0] - scene.circle_xy[c, 0]
            )
            aligned = abs(wrap_angle(yaw[j] + head_body - to_me)) <= tol
            head_beam = int(np.rint((head_body + math.pi) / cfg.beam_spacing_rad)) % cfg.n_beams
            out[k, b] = aligned and not sensor.blind_mask[head_beam]
    return out


@pytest.mark.parametrize("stacked", [False, True])
def test_interference_kernel_matches_the_per_beam_model(stacked):
    rng = np.random.default_rng(21)
    scene = stacked_arena(rng) if stacked else make_arena_scene(rng, n_robots=8)
    config = LidarConfig(range_noise_std_m=0.0, interference_tolerance_deg=60.0)
    sensor = LidarSensor(config, 8)
    sensor.reset(np.random.default_rng(4))
    robots = np.array([0, 1, 2, 3, 4, 5, 6, 7, 0, 4])
    stamps = np.linspace(3.0, 9.0, robots.size)
    when = np.array([0, 1, 2, 0, 1, 2, 0, 1, 2, 2]) if stacked else None
    batch = sensor.scan(scene, robots, stamps, np.random.default_rng(5), time_index=when)
    expected = reference_interference(sensor, scene, robots, stamps, batch, when)
    np.testing.assert_array_equal(batch.interfered, expected)
    assert 0 < expected.sum() < (batch.hit_owner >= 0).sum()  # both outcomes exercised
    assert not batch.ranges_m[expected].any() and not batch.intensities[expected].any()


def test_owner_beam_counts_match_a_bincount():
    scene = make_arena_scene(np.random.default_rng(6))
    sensor = LidarSensor(LidarConfig(interference_tolerance_deg=60.0), scene.n_robots)
    sensor.reset(np.random.default_rng(1))
    batch = sensor.scan(scene, np.arange(20), np.full(20, 2.0), np.random.default_rng(2))
    for after in (False, True):
        hit = (batch.hit_owner >= 0) & ~(batch.interfered if after else False)
        rows, cols = np.nonzero(hit)
        ref = np.bincount(rows * 20 + batch.hit_owner[rows, cols], minlength=400).reshape(20, 20)
        np.testing.assert_array_equal(batch.owner_beam_counts(20, after_interference=after), ref)


def test_scan_stamps_match_the_closed_form():
    sensor = LidarSensor(LidarConfig(), 12)
    sensor.reset(np.random.default_rng(7))
    for t0, t1 in ((0.0, 0.1), (10.0, 12.0), (5.0, 5.0), (123.4, 123.5)):
        rates = sensor.rates_hz
        first = np.mod(-np.pi - sensor.head_phase_rad, 2 * np.pi) / (2 * np.pi * rates)
        robots, stamps = [], []
        for i in range(12):
            n = math.floor((t0 - first[i]) * rates[i]) + 1
            while first[i] + n / rates[i] <= t1:
                if first[i] + n / rates[i] > t0:
                    robots.append(i)
                    stamps.append(first[i] + n / rates[i])
                n += 1
        order = np.lexsort((robots, stamps))
        got_robots, got_stamps = sensor.scan_stamps(t0, t1)
        np.testing.assert_array_equal(got_robots, np.array(robots, dtype=int)[order])
        np.testing.assert_allclose(got_stamps, np.array(stamps)[order], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- noise tables


def test_compact_tables_are_the_quantised_gaussian():
    table = noise.TabulatedNormal("normal", 1.0).table
    levels = noise.evaluate(table, np.arange(1 << 16))
    exact = noise._STANDARD
    assert np.abs(levels - exact).max() < 2e-4  # interpolated between exact quantiles
    assert np.all(np.diff(levels) > 0)
    assert abs(levels.mean()) < 1e-8 and abs(levels.std() - 1.0) < 1e-8
    assert table.nbytes < 40_000  # small enough to stay in cache between steps
    # The compiled lookup equals the numpy one, at every level.
    every = np.array([noise.tabulated(table, i) for i in range(1 << 16)])
    np.testing.assert_array_equal(every, levels)
    factor = noise.evaluate(noise.TabulatedNormal("lognormal", 0.05).table, np.arange(1 << 16))
    np.testing.assert_allclose(factor, np.exp(0.05 * exact), rtol=2e-5)


def test_wrap_matches_wrap_angle():
    x = np.r_[np.random.default_rng(0).uniform(-40, 40, 20_000), -np.pi, np.pi, 0.0, -1e-17]
    got = np.array([wrap(v) for v in x])
    assert np.all((got >= -np.pi) & (got < np.pi))
    np.testing.assert_allclose(np.cos(got - wrap_angle(x)), 1.0, rtol=0, atol=1e-24)


# --------------------------------------------------------------------------- feature extractor


def reference_clusters(angles, ranges, cfg, wide_up_to=0.0):
    """The vectorised numpy extractor the kernel replaced (xy, scan, width, count); with
    ``wide_up_to`` > 0, the clusters the robot test rejects up to that width instead
    (``extract_wide_objects``). Every missing return breaks a cluster (``max_gap_beams=0``)."""
    assert cfg.max_gap_beams == 0
    ranges = np.atleast_2d(ranges)
    n_scans, n_beams = ranges.shape
    valid = ranges > 0.0
    prev = np.roll(ranges, 1, axis=1)
    threshold = np.minimum(ranges, prev) * cfg.jump_range_gain + cfg.jump_threshold_m
    link = (np.abs(prev - ranges) <= threshold) & valid & np.roll(valid, 1, axis=1)
    start = valid & ~link
    end = valid & ~np.roll(link, -1, axis=1)
    ring = valid.any(axis=1) & ~start.any(axis=1)
    start[ring, 0] = True
    end[ring, n_beams - 1] = True
    s_rows, s_cols = np.divmod(np.flatnonzero(start), n_beams)
    e_rows, e_cols = np.divmod(np.flatnonzero(end), n_beams)
    first_start = np.full(n_scans, n_beams)
    first_start[s_rows[::-1]] = s_cols[::-1]
    e_cols = e_cols + n_beams * (e_cols < first_start[e_rows])
    e_cols = np.sort(e_rows * (2 * n_beams) + e_cols) % (2 * n_beams)
    count = e_cols - s_cols + 1
    e_wrapped = e_cols % n_beams
    r_s, r_e = ranges[s_rows, s_cols], ranges[s_rows, e_wrapped]
    cos_a, sin_a = np.cos(angles), np.sin(angles)
    width = np.hypot(
        r_e * cos_a[e_wrapped] - r_s * cos_a[s_cols], r_e * sin_a[e_wrapped] - r_s * sin_a[s_cols]
    )
    mean_r = np.array(
        [
            ranges[r, (c + np.arange(n)) % n_beams].mean()
            for r, c, n in zip(s_rows, s_cols, count, strict=True)
        ]
    ).reshape(-1)
    sigma = cfg.range_noise_std_m + cfg.range_noise_quadratic_per_m * mean_r**2
    limit = cfg.max_width_m + cfg.width_noise_sigmas * math.sqrt(2.0) * sigma
    robot_like = width <= limit
    keep = (count >= cfg.min_beams) & (count < n_beams)
    keep &= (width <= wide_up_to) if wide_up_to > 0.0 else robot_like
    if cfg.foreground_only:
        before = ranges[s_rows, s_cols - 1]
        after = ranges[s_rows, (e_wrapped + 1) % n_beams]
        keep &= ((before == 0.0) | (before > r_s)) & ((after == 0.0) | (after > r_e))
    out = []
    rows = zip(s_rows[keep], s_cols[keep], count[keep], width[keep], robot_like[keep], strict=True)
    for row, col, n, w, fits in rows:
        beams = (col + np.arange(n)) % n_beams
        bearing = math.atan2(sin_a[beams].sum(), cos_a[beams].sum())
        mean_range = ranges[row, beams].mean()
        centre = mean_range + (0.5 * w if wide_up_to > 0.0 else cfg.housing_radius_m)
        if cfg.extent_test and fits:
            # The returns' angular spread plus one footprint must fit the subtense of a
            # housing whose front is the nearest return, its centre up to n_sigmas sigma(r)
            # nearer than measured.
            front = ranges[row, beams].min()
            sigma = cfg.range_noise_std_m + cfg.range_noise_quadratic_per_m * front**2
            housing = front + cfg.housing_radius_m  # the robot test's centre, either mode
            nearest = max(housing - cfg.width_noise_sigmas * sigma, 1e-9)
            subtense = 2.0 * math.asin(min(0.5 * cfg.max_width_m / nearest, 1.0))
            spread = abs(wrap_angle(angles[beams[-1]] - angles[beams[0]]))
            fits = spread + math.radians(cfg.beam_footprint_deg) <= subtense
        if fits == (wide_up_to > 0.0):
            continue
        if centre <= cfg.tracking_range_m:
            out.append(
                (row, bearing, centre * math.cos(bearing), centre * math.sin(bearing), w, n)
            )
    out.sort(key=lambda d: (d[0], d[1]))
    return out


_NO_GAP = LidarFeatureConfig(max_gap_beams=0)  # the reference breaks at every missing return
FEATURE_CONFIGS = [
    _NO_GAP,
    dataclasses.replace(_NO_GAP, extent_test=False),
    dataclasses.replace(_NO_GAP, beam_footprint_deg=0.5),
    dataclasses.replace(_NO_GAP, beam_footprint_deg=0.0, width_noise_sigmas=0.0),
    dataclasses.replace(_NO_GAP, foreground_only=False, jump_range_gain=0.0),
    dataclasses.replace(_NO_GAP, min_beams=2, max_width_m=0.2, tracking_range_m=2.0),
    dataclasses.replace(_NO_GAP, min_beams=1, width_noise_sigmas=0.0, max_width_m=0.078),
]


def random_scans(rng, n_scans=40, n_beams=720):
    """Piecewise-constant ranges with gaps, single-beam spikes and clusters on the seam."""
    ranges = np.zeros((n_scans, n_beams))
    for k in range(n_scans):
        b = 0
        while b < n_beams:
            width = int(rng.integers(1, 12))
            kind = rng.random()
            if kind < 0.3:
                value = 0.0
            elif kind < 0.6:
                value = rng.uniform(0.3, 3.0)
            else:
                value = rng.uniform(0.3, 3.0) + 0.001 * rng.normal(size=width)
            ranges[k, b : b + width] = value if np.ndim(value) == 0 else value[: n_beams - b]
            b += width
    ranges[0] = 2.0  # one room-wide cluster (ring): rejected
    ranges[1] = 0.0  # no return at all
    ranges[2, :] = 0.0
    ranges[2, [0, 1, -2, -1]] = 1.0  # a cluster straddling the seam
    return ranges


@pytest.mark.parametrize("cfg", FEATURE_CONFIGS)
def test_cluster_kernel_matches_the_vectorised_extractor(cfg):
    angles = LidarSensor(LidarConfig()).angles_rad
    rng = np.random.default_rng(11)
    scene = make_arena_scene(rng)
    batch = LidarSensor(LidarConfig(), 20).scan(scene, np.arange(20), np.ones(20), rng)
    for ranges in (random_scans(rng), batch.ranges_m):
        got = extract_clusters(angles, ranges, cfg)
        ref = reference_clusters(angles, ranges, cfg)
        assert got.scan_index.tolist() == [d[0] for d in ref]
        np.testing.assert_allclose(
            got.xy_m, np.array([d[2:4] for d in ref]).reshape(-1, 2), atol=1e-12
        )
        np.testing.assert_allclose(got.width_m, [d[4] for d in ref], atol=1e-12)
        assert got.n_beams.tolist() == [d[5] for d in ref]
        for up_to in (0.15, 0.3):  # the rejected ones: extract_wide_objects
            got = extract_wide_objects(angles, ranges, cfg, max_width_m=up_to)
            ref = reference_clusters(angles, ranges, cfg, up_to)
            assert got.scan_index.tolist() == [d[0] for d in ref]
            np.testing.assert_allclose(
                got.xy_m, np.array([d[2:4] for d in ref]).reshape(-1, 2), atol=1e-12
            )
            assert got.n_beams.tolist() == [d[5] for d in ref]
    seam = extract_clusters(angles, random_scans(rng)[2:3], _NO_GAP)
    assert seam.xy_m.shape == (1, 2) and seam.xy_m[0, 0] < -0.9  # behind the robot, at -x


@pytest.mark.parametrize("footprint_deg", [0.0, 0.5])
def test_no_cluster_is_both_a_robot_and_a_wide_object(footprint_deg):
    """The wide objects are exactly what the robot test rejects: noisy housings and 120 mm
    decoys near the ranges where their subtenses cross a beam step (1.8-2.6 m) are one or the
    other, never both (a teammate reported as a wide object would turn its own camera bearing
    into clutter), with the geometric extent bound and with the footprint one."""
    cfg = LidarFeatureConfig(beam_footprint_deg=footprint_deg)
    angles = LidarSensor(LidarConfig()).angles_rad
    rng = np.random.default_rng(4)
    n = 2000
    centre = rng.uniform(1.8, 2.6, n)[:, None]
    radius = np.where(rng.random(n) < 0.5, HOUSING_RADIUS_M, 0.06)[:, None]
    phase = rng.uniform(-np.pi, np.pi, n)[:, None]
    miss = centre * np.sin(angles[None, :] - phase)  # beam's distance from the target's centre
    along = centre * np.cos(angles[None, :] - phase)
    hit = (np.abs(miss) <= radius) & (along > 0)
    clean = along - np.sqrt(np.maximum(radius**2 - miss**2, 0.0))
    noise = rng.normal(0.0, 1.0, clean.shape) * (0.01 + 0.0025 * clean**2)
    ranges = np.where(hit, clean + noise, 0.0)
    robots = extract_clusters(angles, ranges, cfg)
    wide = extract_wide_objects(angles, ranges, cfg, max_width_m=0.3)
    both = np.intersect1d(robots.scan_index, wide.scan_index)
    assert both.size == 0, both[:10]
    assert robots.scan_index.size > 100 and wide.scan_index.size > 10  # both sides exercised


# --------------------------------------------------------------------------- camera


def reference_visibility(scene, robots, time_index, config):
    """Line of sight per (frame, red circle), brute force over every segment and occluder."""
    targets = np.flatnonzero(scene.circle_red)
    when = scene.circle_time
    visible = np.zeros((len(robots), targets.size), dtype=bool)
    for k, me in enumerate(robots):
        t = None if time_index is None else time_index[k]
        xy = scene.robot_xy if scene.robot_xy.ndim == 2 else scene.robot_xy[t]
        o = xy[me]
        for j, c in enumerate(targets):
            if when is not None and t is not None and when[c] not in (-1, t):
                continue
            d = scene.circle_xy[c] - o
            dist = math.hypot(*d)
            owner = scene.circle_owner[c]
            reach = CameraSensor(config).detectable_range_m(scene.circle_radius_m[c])
            if owner == me or not config.range_min_m <= dist <= reach:
                continue
            ok = True
            if sight_line_crosses_segments(scene, o, d):
                ok = False
            for i in np.flatnonzero(scene.circle_camera_occluder):
                if when is not None and t is not None and when[i] not in (-1, t):
                    continue
                if i == c or scene.circle_owner[i] == me:
                    continue
                if owner >= 0 and scene.circle_owner[i] == owner:
                    continue
                s = np.clip(np.dot(scene.circle_xy[i] - o, d) / dist**2, 0, 1)
                if np.linalg.norm(o + s * d - scene.circle_xy[i]) < scene.circle_radius_m[i]:
                    ok = False
            visible[k, j] = ok
    return targets, visible


@pytest.mark.parametrize("stacked", [False, True])
def test_visibility_kernel_matches_brute_force(stacked):
    rng = np.random.default_rng(31)
    scene = stacked_arena(rng, n_robots=10) if stacked else make_arena_scene(rng)
    robots = np.arange(10) if stacked else np.arange(20)
    when = np.arange(10) % 3 if stacked else None
    config = CameraConfig(range_max_m=5.0)
    target, visible, bearing = CameraSensor(config).visibility(scene, robots, when)
    ref_target, ref_visible = reference_visibility(scene, robots, when, config)
    np.testing.assert_array_equal(target, ref_target)
    np.testing.assert_array_equal(visible, ref_visible)
    assert 0 < visible.sum() < visible.size


def test_visibility_edge_cases_grazing_occluder_and_no_shapes():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(2.0, 0.0)
    b.add_post(1.0, 0.03 + 1e-9, radius_m=0.03)  # passes just outside: not blocked
    inside = (0.03 - 1e-9) / math.sqrt(2.0)
    b.add_post(1.0 + inside, 1.0 - inside, radius_m=0.03)  # just inside the line to the decoy
    b.add_red_decoy(2.0, 2.0)  # so the decoy is hidden
    scene = b.build()
    target, visible, _ = CameraSensor(CameraConfig()).visibility(scene, np.array([0]))
    assert visible.tolist() == reference_visibility(scene, [0], None, CameraConfig())[1].tolist()
    assert visible[0].tolist() == [False, True, False]  # own strip, robot 1, decoy
    empty = SceneBuilder()
    empty.add_robot(0.0, 0.0, housing=False, strip=False)
    target, visible, bearing = CameraSensor().visibility(empty.build(), np.array([0]))
    assert target.size == 0 and visible.shape == (1, 0) and bearing.shape == (1, 0)


def test_frames_kernel_matches_the_vectorised_assembly():
    scene = make_arena_scene(np.random.default_rng(41))
    config = CameraConfig(false_positive_rate=2.0, miss_probability=0.3, bearing_noise_std_deg=2.0)
    cam = CameraSensor(config)
    robots = np.array([3, 0, 7, 7, 12, 19])
    batch = cam.observe(scene, robots, np.random.default_rng(5))
    # The same draws, assembled the way the numpy code did it.
    rng = np.random.default_rng(5)
    target, visible, bearing = cam.visibility(scene, robots)
    vis_obs, vis_t = np.nonzero(visible)
    draws = (noise.table_indices(rng, 4 * vis_obs.size).reshape(4, -1) + 0.5) / 65536.0
    extra = rng.standard_normal(vis_obs.size) * np.deg2rad(config.bearing_noise_std_deg)
    # Per visible pair, one at a time: blob area, fill, centroid offset, pixel rounding.
    noise_rad = np.empty(vis_obs.size)
    hit = np.empty(vis_obs.size, dtype=bool)
    f = config.pixels_per_rad
    for v, (k, t) in enumerate(zip(vis_obs, vis_t, strict=True)):
        c = target[t]
        d = math.dist(scene.circle_xy[c], scene.robot_xy[robots[k]])
        width = 2.0 * math.asin(scene.circle_radius_m[c] / d)
        fill = config.fill_min + (1.0 - config.fill_min) * draws[0, v]
        area = f * width * f * config.strip_height_m / d
        hit[v] = fill * area >= config.min_blob_area_px and draws[3, v] >= config.miss_probability
        centroid = (draws[1, v] - 0.5) * (1 - fill) * width
        noise_rad[v] = centroid + (draws[2, v] - 0.5) / f + extra[v]
    n_clutter = rng.poisson(config.false_positive_rate, size=robots.size)
    clutter = rng.uniform(-np.pi, np.pi, size=int(n_clutter.sum()))
    for k in range(robots.size):
        mine = hit & (vis_obs == k)
        values = np.r_[wrap_angle(bearing[k, vis_t[mine]] + noise_rad[mine]),
                       clutter[n_clutter[:k].sum() : n_clutter[: k + 1].sum()]]  # fmt: skip
        sources = np.r_[target[vis_t[mine]], np.full(n_clutter[k], -1)]
        order = np.argsort(values, kind="stable")
        np.testing.assert_allclose(batch.bearings[k], values[order], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(batch.sources[k], sources[order])
        owners = scene.circle_owner[target[visible[k]]]
        expected = np.zeros(batch.visible.shape[1], dtype=bool)
        expected[owners[owners >= 0]] = True
        np.testing.assert_array_equal(batch.visible[k], expected)
    assert n_clutter.sum() > 0 and (~hit).any()


# --------------------------------------------------------------------------- world helpers


def test_due_readings_match_the_per_substep_loop():
    rng = np.random.default_rng(2)
    next_s = rng.uniform(0.0, 1 / 30, 20)
    loop_next = next_s.copy()
    stamps = 0.02 * np.arange(1, 6) + 0.4
    robots, substep = _due_readings(next_s, stamps, 1 / 30, 1e-9)
    ref_robots, ref_sub = [], []
    for s, t in enumerate(stamps):
        due = np.flatnonzero(loop_next <= t + 1e-9)
        loop_next[due] += 1 / 30
        ref_robots += due.tolist()
        ref_sub += [s] * due.size
    assert robots.tolist() == ref_robots and substep.tolist() == ref_sub
    np.testing.assert_array_equal(next_s, loop_next)


def test_drive_velocities_and_pulses_to_delta_match_numpy():
    rng = np.random.default_rng(3)
    state = rng.normal(size=(9, 6))
    robot_rows, drive_rows = np.array([0, 2, 4, 6]), np.array([1, 3, 5, 7])
    speeds = rng.normal(size=(4, 2))
    got = _drive_velocities(state, robot_rows, drive_rows, speeds, 0.02)
    heading = state[robot_rows, 2] + 0.5 * speeds[:, 1] * 0.02
    ref = state[:, 3:6].copy()
    ref[drive_rows, 0] = speeds[:, 0] * np.cos(heading)
    ref[drive_rows, 1] = speeds[:, 0] * np.sin(heading)
    ref[drive_rows, 2] = speeds[:, 1]
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15)
    pulses = np.array([[1000, 1200], [500, 500], [-300, 40], [0, 0]])
    mpp = 2 * np.pi * 0.03 / 1920
    dist = mpp * 0.5 * pulses.sum(axis=1)
    dpsi = mpp * (pulses[:, 1] - pulses[:, 0]) / 0.15
    chord = dist * np.sinc(dpsi / (2 * np.pi))
    ref = np.stack([chord * np.cos(dpsi / 2), chord * np.sin(dpsi / 2), dpsi], axis=1)
    np.testing.assert_allclose(pulses_to_delta(pulses, 0.03, 0.15, 1920), ref, atol=1e-15)


def test_blind_mask_unchanged_by_the_kernel_path():
    cfg = LidarConfig()
    sensor = LidarSensor(cfg)
    np.testing.assert_array_equal(sensor.blind_mask, blind_mask(sensor.angles_rad, cfg))


def test_null_beams_kernel_matches_null_bearings_scan_by_scan():
    rng = np.random.default_rng(8)
    ranges = rng.choice([0.0, 1.0, 2.5], size=(9, 720), p=[0.3, 0.4, 0.3])
    intens = np.where(ranges > 0, 1.0, rng.choice([0.0, 0.7], size=ranges.shape))
    exclude = rng.random(720) < 0.1
    angles = -np.pi + np.arange(720) * (2 * np.pi / 720)
    bounds, beams = null_beams(ranges, intens, exclude)
    assert bounds[0] == 0 and bounds[-1] == beams.size
    for k in range(9):
        np.testing.assert_array_equal(
            wrap_angle(angles[beams[bounds[k] : bounds[k + 1]]]),
            null_bearings(angles, ranges[k], intens[k], exclude),
        )
    bounds, beams = null_beams(ranges[:0], intens[:0])
    assert bounds.tolist() == [0] and beams.size == 0
    with pytest.raises(ValueError, match="null_beams"):
        null_beams(ranges, intens[:, :10])
