"""The lidar extractor on scans that follow plain ray geometry, built here without the simulator.

A real scanner's edge behaviour is not the simulated X4's (which drops every sample whose
0.5 deg footprint straddles a round object's edge). The generator below casts exact
ray-cylinder intersections with numpy: each beam's centre ray gives its range, a beam whose
footprint straddles an edge returns, with some probability, a mixed range between the two
surfaces (the classic mixed pixel), returns drop out at random, and the range noise is 4 mm.
The extractor must find a teammate's 65 mm housing in these scans and in the simulator's own
from 0.3 to 2.5 m at every bearing outside the blind sectors, and still reject 120 mm red
decoys and wider posts.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swarm_core.perception.lidar_features import LidarFeatureConfig, extract_clusters
from swarm_env.sensors.lidar import LidarConfig, LidarSensor
from swarm_env.sensors.scene_builder import make_pair_scene

HOUSING_M = 0.0325  # the lidar housing's radius (65 mm diameter)
DECOY_M = 0.06  # the arena's red decoys
N_BEAMS = 720
ANGLES = -math.pi + np.arange(N_BEAMS) * (2.0 * math.pi / N_BEAMS)
X4 = LidarConfig()
BLIND_CENTRES = np.deg2rad(X4.blind_sector_centers_deg)
BLIND_HALF = 0.5 * np.deg2rad(X4.blind_sector_widths_deg)
# A real X4 with 4 mm range noise: the extractor's noise model says so.
REAL = LidarFeatureConfig(range_noise_std_m=0.004, range_noise_quadratic_per_m=0.0)
# The rule before thin rays were allowed for: every return's footprint (0.5 deg) on the object.
FOOTPRINT_RULE = dataclasses.replace(REAL, beam_footprint_deg=0.5)


def ray_circle(ux, uy, cx, cy, radius):
    """Range along unit rays (ux, uy) from the origin to the circle's near side; inf = miss."""
    along = ux * cx + uy * cy
    miss2 = cx * cx + cy * cy - along * along
    chord2 = radius * radius - miss2
    hit = (chord2 >= 0.0) & (along > 0.0)
    return np.where(hit, along - np.sqrt(np.where(hit, chord2, 0.0)), np.inf)


def ray_room(ux, uy, centre, half_m):
    """Range along unit rays from the origin to the walls of a square room (origin inside)."""
    t = np.full(np.broadcast(ux, uy).shape, np.inf)
    for u, c in ((ux, centre[0]), (uy, centre[1])):
        for wall in (c - half_m, c + half_m):
            with np.errstate(divide="ignore", invalid="ignore"):
                d = wall / u
            t = np.where((d > 0.0) & np.isfinite(d), np.minimum(t, d), t)
    return t


def ray_scans(
    rng,
    circles,
    *,
    noise_m=0.004,
    mixed_prob=0.5,
    drop_prob=0.0,
    footprint_deg=0.5,
    room_half_m=4.0,
    n_sub=9,
):
    """K scans of a scanner at the origin (robot frame, REP-103) over 720 beams.

    ``circles`` (K, C, 3): per scan, circles ``x, y, radius`` (m). The room is a square of
    half side ``room_half_m`` centred near the scanner. Each beam is ``n_sub`` rays across its
    footprint; its range is the centre ray's exact first hit, except when the rays do not all
    meet the same surface (the footprint straddles an edge): then, with ``mixed_prob``, the
    mean of the rays' ranges (a mixed return between the two surfaces). Returns inside the
    blind sectors (the camera pillars) and ``drop_prob`` of the others are 0 (no return).

    Returns ``ranges`` (K, 720) and ``hit`` (K, 720) int: the circle the centre ray meets
    (-1: the room), and ``clean`` (K, 720) bool: the return is the centre ray's exact range.
    """
    circles = np.asarray(circles, dtype=np.float64)
    n_scans = circles.shape[0]
    half = 0.5 * math.radians(footprint_deg)
    offsets = np.linspace(-half, half, n_sub)
    theta = ANGLES[None, :, None] + offsets[None, None, :]  # (1, B, S)
    ux, uy = np.cos(theta), np.sin(theta)
    room_centre = rng.uniform(-0.5, 0.5, size=(n_scans, 2))
    ranges_sub = np.empty((n_scans, N_BEAMS, n_sub))
    what = np.empty((n_scans, N_BEAMS, n_sub), dtype=np.intp)
    for k in range(n_scans):
        best = ray_room(ux[0], uy[0], room_centre[k], room_half_m)
        owner = np.full(best.shape, -1)
        for j, (cx, cy, radius) in enumerate(circles[k]):
            t = ray_circle(ux[0], uy[0], cx, cy, radius)
            nearer = t < best
            best = np.where(nearer, t, best)
            owner = np.where(nearer, j, owner)
        ranges_sub[k], what[k] = best, owner
    centre = n_sub // 2
    exact = ranges_sub[:, :, centre]
    hit = what[:, :, centre]
    straddles = (what != what[:, :, :1]).any(axis=2)
    mixed = straddles & (rng.random(exact.shape) < mixed_prob)
    ranges = np.where(mixed, ranges_sub.mean(axis=2), exact)
    ranges = ranges + noise_m * rng.standard_normal(ranges.shape)
    offset = np.abs((ANGLES[:, None] - BLIND_CENTRES[None, :] + math.pi) % (2 * math.pi) - math.pi)
    blind = (offset <= BLIND_HALF[None, :]).any(axis=1)
    dropped = rng.random(ranges.shape) < drop_prob
    void = blind[None, :] | dropped
    ranges = np.where(void, 0.0, ranges)
    clean = ~mixed & ~void
    return ranges, hit, clean


def longest_clean_run(hit, clean, target):
    """Per scan, the longest run of consecutive beams (through the seam) whose centre ray
    meets ``target`` and returns its exact range: what the generator guarantees is there."""
    on = np.concatenate([(hit == target) & clean] * 2, axis=1)
    best = np.zeros(on.shape[0], dtype=np.intp)
    run = np.zeros(on.shape[0], dtype=np.intp)
    for b in range(on.shape[1]):
        run = np.where(on[:, b], run + 1, 0)
        best = np.maximum(best, run)
    return np.minimum(best, N_BEAMS)


def bearing_clear_of_blind_sectors(bearing_rad, range_m, radius_m=HOUSING_M):
    """The whole object, plus one beam on each side, lies outside every blind sector."""
    reach = math.asin(min(radius_m / range_m, 1.0)) + math.radians(0.5)
    off = np.abs((bearing_rad - BLIND_CENTRES + math.pi) % (2 * math.pi) - math.pi)
    return bool((off > BLIND_HALF + reach).all())


def at(range_m, bearing_rad, radius_m):
    return [range_m * math.cos(bearing_rad), range_m * math.sin(bearing_rad), radius_m]


def found(dets, truth_xy, tol_m):
    """Per scan: some detection lies within ``tol_m`` of ``truth_xy`` (K, 2)."""
    near = np.linalg.norm(dets.xy_m - truth_xy[dets.scan_index], axis=1) <= tol_m
    out = np.zeros(truth_xy.shape[0], dtype=bool)
    out[dets.scan_index[near]] = True
    return out


RANGES_M = (0.3, 0.5, 0.8, 1.0, 1.12, 1.5, 2.0, 2.45, 2.5)
BEARINGS_DEG = (0.0, 20.0, 70.0, 90.0, 110.0, 160.0, 180.0, -25.0, -90.0, -170.0)


@pytest.mark.parametrize("bearing_deg", BEARINGS_DEG)
@pytest.mark.parametrize("range_m", RANGES_M)
def test_housing_found_in_ray_geometry_scans(range_m, bearing_deg):
    """Every housing whose scan holds three consecutive exact returns on it is found, near its
    centre, with mixed edge returns, dropped returns and 4 mm noise; nothing else is reported.
    Each trial shifts the housing by a fraction of a beam (every beam phase is seen)."""
    rng = np.random.default_rng(int(1000 * range_m) + int(bearing_deg) % 360)
    n = 60
    bearings = math.radians(bearing_deg) + rng.uniform(-0.25, 0.25, n) * math.radians(1.0)
    assert all(bearing_clear_of_blind_sectors(b, range_m) for b in bearings)
    circles = np.array([[at(range_m, b, HOUSING_M)] for b in bearings])
    truth = circles[:, 0, :2]
    for drop_prob in (0.0, 0.03):
        ranges, hit, clean = ray_scans(rng, circles, drop_prob=drop_prob)
        dets = extract_clusters(ANGLES, ranges, REAL)
        ok = found(dets, truth, tol_m=0.04)
        must = longest_clean_run(hit, clean, 0) >= REAL.min_beams
        assert ok[must].all(), (drop_prob, np.flatnonzero(must & ~ok))
        # No detection anywhere else (walls, the room's corners). A mixed return linked to
        # the housing's cluster pulls its centre back by up to ~0.1 m at 2.5 m.
        far = np.linalg.norm(dets.xy_m - truth[dets.scan_index], axis=1) > 0.15
        assert not far.any(), dets.xy_m[far]
        if drop_prob == 0.0:
            # Not vacuous: three exact returns are there in most scans (mixed edges take
            # the outer rays; at 2.5 m the housing spans three rays at most).
            assert must.mean() >= (0.8 if range_m <= 2.0 else 0.3), must.mean()


def test_the_two_teammates_of_the_real_scan_report():
    """Two teammates standing still at 1.0 m and 1.12 m in exact ray-cylinder scans with 4 mm
    noise: both are found. The footprint rule (every return's 0.5 deg footprint on the
    housing) drops the one at 1.12 m at most beam phases: seven rays hit it, spanning
    3.0 deg + 0.5 deg > the 3.33 deg it subtends."""
    rng = np.random.default_rng(7)
    n = 200
    phase = rng.uniform(-0.25, 0.25, n) * math.radians(1.0)
    a, b = math.radians(20.0) + phase, math.radians(-70.0) + phase
    circles = np.array(
        [[at(1.0, x, HOUSING_M), at(1.12, y, HOUSING_M)] for x, y in zip(a, b, strict=True)]
    )
    ranges, _, _ = ray_scans(rng, circles, mixed_prob=0.0)
    rates = {}
    for name, cfg in (("thin", REAL), ("footprint", FOOTPRINT_RULE)):
        dets = extract_clusters(ANGLES, ranges, cfg)
        rates[name] = [found(dets, circles[:, j, :2], 0.04).mean() for j in (0, 1)]
    assert rates["thin"] == [1.0, 1.0]
    assert rates["footprint"][1] < 0.6, rates  # the old rule's loss, kept in view


@pytest.mark.parametrize("radius_m", [DECOY_M, 0.1])
@pytest.mark.parametrize("range_m", RANGES_M + (2.2, 3.0))
def test_wider_cylinders_rejected_in_ray_geometry_scans(range_m, radius_m):
    """120 mm red decoys and 200 mm posts (front at ``range_m``) are never taken for a
    housing: they span ~1.85 (3.1) times a housing's angle, so their returns overflow the
    housing's subtense, to 3 m with thin rays. Where mixed edges remove a decoy's outer
    returns it keeps fewer, as few as a housing's from 2.3 m on (measured: 5 % at 2.3 m, 13 %
    at 2.45 m with half the edge beams mixed): asserted to 2.2 m there."""
    rng = np.random.default_rng(int(1000 * range_m) + int(1000 * radius_m))
    n = 200
    bearings = rng.choice(np.deg2rad(BEARINGS_DEG), n) + rng.uniform(-0.5, 0.5, n) * 0.0175
    circles = np.array([[at(range_m + radius_m, b, radius_m)] for b in bearings])
    mixed = (0.0, 0.5) if range_m <= 2.2 or radius_m > DECOY_M else (0.0,)
    for mixed_prob in mixed:
        ranges, _, _ = ray_scans(rng, circles, mixed_prob=mixed_prob)
        dets = extract_clusters(ANGLES, ranges, REAL)
        assert dets.xy_m.shape[0] == 0, (dets.xy_m, dets.n_beams)


# --------------------------------------------------------------------------- the simulator's scans


def sim_scans(range_m, radius_m, seed, n_pairs=200):
    """The simulated X4's scans of isolated (scanner, target) pairs, the target (a housing,
    or a cylinder of ``radius_m``) at ``range_m`` outside the blind sectors."""
    cfg = LidarConfig(interference_tolerance_deg=0.0)
    rng = np.random.default_rng(seed)
    margin = math.degrees(math.asin(min(DECOY_M / range_m, 1.0))) + 1.0
    scene, bearings = make_pair_scene(
        rng,
        range_m,
        n_pairs,
        avoid_centers_deg=cfg.blind_sector_centers_deg,
        avoid_half_widths_deg=tuple(0.5 * w + margin for w in cfg.blind_sector_widths_deg),
    )
    if radius_m != HOUSING_M:
        targets = scene.circle_lidar & (scene.circle_owner % 2 == 1)
        scene = dataclasses.replace(
            scene, circle_radius_m=np.where(targets, radius_m, scene.circle_radius_m)
        )
    observers = np.arange(0, scene.n_robots, 2)
    batch = LidarSensor(cfg, scene.n_robots).scan(scene, observers, np.ones(observers.size), rng)
    truth = range_m * np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
    return batch, truth


@pytest.mark.parametrize("range_m", RANGES_M)
def test_simulated_scans_keep_every_housing_the_width_test_keeps(range_m):
    """In the simulator's scans (footprint model, its range noise) the extent test never costs
    a housing: the default rule finds exactly the housings the width test alone finds, all of
    them up to 1.8 m (beyond, the footprint model leaves fewer than three returns)."""
    batch, truth = sim_scans(range_m, HOUSING_M, seed=int(100 * range_m))
    rates = {}
    for name, cfg in (("default", None), ("width", LidarFeatureConfig(extent_test=False))):
        dets = extract_clusters(batch.angles_rad, batch.ranges_m, cfg)
        rates[name] = found(dets, truth, 0.15)
    np.testing.assert_array_equal(rates["default"], rates["width"])
    if range_m <= 1.8:
        assert rates["default"].all()


@pytest.mark.parametrize("range_m", [0.5, 1.0, 1.5, 2.0, 2.2])
def test_simulated_decoys_rejected_within_the_tracking_range(range_m):
    """The simulator's 120 mm red decoys are rejected up to 2.2 m by the thin-ray rule; the
    footprint rule, which knows the simulated scanner drops its edge samples, rejects them at
    every range (the rule the simulator's own scanner allows, ``beam_footprint_deg=0.5``)."""
    batch, truth = sim_scans(range_m + DECOY_M - HOUSING_M, DECOY_M, seed=int(100 * range_m))
    for cfg in (None, LidarFeatureConfig(beam_footprint_deg=0.5)):
        dets = extract_clusters(batch.angles_rad, batch.ranges_m, cfg)
        assert not found(dets, truth, 0.15).any(), cfg
    width_only = extract_clusters(
        batch.angles_rad, batch.ranges_m, LidarFeatureConfig(extent_test=False)
    )
    if range_m >= 1.5:
        assert found(width_only, truth, 0.15).mean() > 0.5  # the extent test is what rejects


# --------------------------------------------------------------------------- dropouts


def test_dropouts_neither_split_a_wall_into_housings_nor_a_housing_in_two():
    """Real scanners drop single returns. A wall 2 m away with a dropout every fourth beam
    gives no detection (each three-return fragment would otherwise pass every rule: its
    missing neighbours look like free space), and a housing at 1 m with a dropout in its middle
    is one detection of all its returns. Two missing returns in a row do break a cluster."""
    ranges = np.zeros((3, N_BEAMS))
    wall = slice(200, 300)
    ranges[0, wall] = 2.0 / np.cos(ANGLES[wall] - ANGLES[250])  # a flat wall, 2 m off
    ranges[0, 204:300:4] = 0.0
    exact, hit, _ = ray_scans(
        np.random.default_rng(1), [[at(1.0, 0.3, HOUSING_M)]], noise_m=0.0, mixed_prob=0.0
    )
    on = np.flatnonzero(hit[0] == 0)  # the housing's returns only (7 or 8 at 1 m)
    assert on.size >= 7
    ranges[1, on] = exact[0, on]
    ranges[1, on[3]] = 0.0  # a dropout in the middle of the housing
    ranges[2] = ranges[1]
    ranges[2, on[4]] = 0.0  # two in a row
    bridged = extract_clusters(ANGLES, ranges, REAL)
    assert (bridged.scan_index == 0).sum() == 0
    assert bridged.n_beams[bridged.scan_index == 1].tolist() == [on.size - 1]
    np.testing.assert_allclose(bridged.xy_m[0], [math.cos(0.3), math.sin(0.3)], atol=0.01)
    assert bridged.n_beams[bridged.scan_index == 2].max() <= on.size - 4  # split
    split = extract_clusters(ANGLES, ranges, dataclasses.replace(REAL, max_gap_beams=0))
    assert (split.scan_index == 0).sum() > 10  # the wall's fragments
    assert (split.scan_index == 1).sum() == 2


def test_a_fragment_behind_a_dropout_next_to_a_nearer_object_is_not_foreground():
    """The foreground test looks past a dropout for the neighbouring return: three returns at
    2 m right behind a nearer object, a dropout between them, are not free-standing."""
    ranges = np.zeros((1, N_BEAMS))
    ranges[0, 100:110] = 1.0  # a nearer object (10 beams, too wide to be a housing)
    ranges[0, 111:114] = 2.0  # three returns of something farther, after one dropout
    ranges[0, 114:140] = 0.0
    dets = extract_clusters(ANGLES, ranges, REAL)
    assert dets.xy_m.shape[0] == 0
    no_bridge = extract_clusters(ANGLES, ranges, dataclasses.replace(REAL, max_gap_beams=0))
    assert no_bridge.xy_m.shape[0] == 1  # what the missing return made of it


@pytest.mark.parametrize("value", [-1, 9, 1.5, True])
def test_max_gap_beams_is_checked(value):
    with pytest.raises(ValueError, match=r"LidarFeatureConfig.max_gap_beams must be an int"):
        LidarFeatureConfig(max_gap_beams=value)
