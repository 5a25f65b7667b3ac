"""Camera colour-blob bearings: geometry, occlusion, range, noise statistics, determinism."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swarm_env.sensors.camera import CameraConfig, CameraSensor
from swarm_env.sensors.scene import Scene
from swarm_env.sensors.scene_builder import make_pair_scene
from tests.swarm_env.scene_factory import (
    SceneBuilder,
    make_arena_scene,
    sight_line_crosses_segments,
)

# Ideal blobs: always fully lit (centroid at the centre), pixel rounding below 1e-12 rad.
EXACT = CameraConfig(
    bearing_noise_std_deg=0.0,
    miss_probability=0.0,
    false_positive_rate=0.0,
    fill_min=1.0,
    pixels_per_rad=1e12,
)
DEG = math.pi / 180.0


def observe(scene, robots=(0,), config=EXACT, seed=0):
    return CameraSensor(config).observe(scene, np.asarray(robots), np.random.default_rng(seed))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("rate_hz", 0.0),
        ("range_max_m", 0.05),
        ("bearing_noise_std_deg", -1.0),
        ("miss_probability", 1.5),
        ("false_positive_rate", -0.1),
    ],
)
def test_config_rejects_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CameraConfig(**{field: value})


def test_frame_signs_robot_on_the_right_is_at_minus_90_deg():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0, yaw_rad=math.pi / 2)  # facing world +y
    b.add_robot(1.0, 0.0)  # world +x: the observer's right
    batch = observe(b.build())
    np.testing.assert_allclose(batch.bearings[0], [-math.pi / 2], atol=1e-12)
    np.testing.assert_array_equal(batch.visible, [[False, True]])


def test_bearings_in_a_rotated_observer_frame():
    b = SceneBuilder()
    b.add_robot(1.0, 1.0, yaw_rad=0.7)
    targets = [(2.0, 1.5), (0.0, 2.5), (-0.5, 0.2), (1.5, -1.0)]
    for x, y in targets:
        b.add_robot(x, y)
    batch = observe(b.build())
    expected = [
        (math.atan2(y - 1.0, x - 1.0) - 0.7 + math.pi) % (2 * math.pi) - math.pi
        for x, y in targets
    ]
    np.testing.assert_allclose(batch.bearings[0], np.sort(expected), atol=1e-12)
    assert np.all(np.diff(batch.bearings[0]) >= 0)  # sorted: no identity leaks through order


def test_out_of_range_and_too_close_are_not_seen():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(5.4, 0.0)
    b.add_robot(0.0, 5.6)
    b.add_robot(-0.05, 0.0, housing=False)  # closer than range_min (geometry only)
    batch = observe(b.build())
    np.testing.assert_array_equal(batch.visible, [[False, True, False, False]])


def test_box_and_other_robot_occlude_but_own_circles_do_not():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(2.0, 0.0)  # behind a box
    b.add_box(1.0, 0.0, 0.2, 0.6)
    b.add_robot(0.0, 1.0)  # in front of robot 3
    b.add_robot(0.0, 2.5)  # hidden by robot 2's strip
    b.add_robot(-1.5, 0.0)  # clear
    batch = observe(b.build())
    np.testing.assert_array_equal(batch.visible[0], [False, False, True, False, True])
    assert len(batch.bearings[0]) == 2


def test_decoy_post_occludes_red_decoy_is_seen_as_a_robot_bearing():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    red = b.add_red_decoy(0.0, -1.5)
    b.add_robot(1.5, 0.0)
    b.add_post(0.8, 0.0)  # blocks robot 1's strip
    batch = observe(b.build())
    np.testing.assert_array_equal(batch.visible, [[False, False]])
    np.testing.assert_allclose(batch.bearings[0], [-math.pi / 2])
    np.testing.assert_array_equal(batch.sources[0], [red])
    assert batch.target_visible[0, batch.target_index == red].all()


def test_occlusion_is_symmetric_between_observers():
    b = SceneBuilder()
    for x in (0.0, 1.0, 2.0):
        b.add_robot(x, 0.0)
    batch = observe(b.build(), robots=(0, 1, 2))
    np.testing.assert_array_equal(
        batch.visible,
        [[False, True, False], [True, False, True], [False, True, False]],
    )


def test_vectorised_visibility_matches_a_loop():
    scene = make_arena_scene(np.random.default_rng(3))
    cam = CameraSensor(EXACT)
    target, visible, bearing = cam.visibility(scene, np.arange(scene.n_robots))
    occ = np.flatnonzero(scene.circle_camera_occluder)
    for k in range(scene.n_robots):
        o = scene.robot_xy[k]
        for ti, c in enumerate(target):
            p = scene.circle_xy[c]
            d = p - o
            dist = math.hypot(*d)
            ok = scene.circle_owner[c] != k and EXACT.range_min_m <= dist <= EXACT.range_max_m
            if not ok:
                assert not visible[k, ti]
                continue
            if sight_line_crosses_segments(scene, o, d):
                ok = False
            for j in occ:
                if j == c or scene.circle_owner[j] == k:
                    continue
                if scene.circle_owner[c] >= 0 and scene.circle_owner[j] == scene.circle_owner[c]:
                    continue
                s = np.clip(np.dot(scene.circle_xy[j] - o, d) / dist**2, 0, 1)
                if np.linalg.norm(o + s * d - scene.circle_xy[j]) < scene.circle_radius_m[j]:
                    ok = False
            assert visible[k, ti] == ok, (k, c)
    assert 0 < visible.sum() < visible.size


def test_miss_probability_and_false_positive_statistics():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.0)
    b.add_robot(-1.0, 1.0)
    scene = b.build()
    config = CameraConfig(miss_probability=0.3, false_positive_rate=0.5)
    n = 4000
    batch = observe(scene, robots=np.zeros(n, int), config=config, seed=11)
    sources = np.concatenate(batch.sources)
    bearings = np.concatenate(batch.bearings)
    detected = (sources >= 0).sum() / (2 * n)
    clutter = bearings[sources < 0]
    assert detected == pytest.approx(0.7, abs=0.02)
    assert clutter.size / n == pytest.approx(0.5, abs=0.04)
    # Clutter is uniform on the circle: mean resultant length ~ 0.
    assert abs(np.mean(np.exp(1j * clutter))) < 0.05
    assert np.all((bearings >= -math.pi) & (bearings < math.pi))


def test_bearing_noise_has_the_configured_sigma():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(-2.0, 0.001)  # near the +/-pi seam: errors must be wrapped
    config = dataclasses.replace(EXACT, bearing_noise_std_deg=5.0)
    batch = observe(b.build(), robots=np.zeros(3000, int), config=config, seed=5)
    bearings = np.concatenate(batch.bearings)
    err = (bearings - math.atan2(0.001, -2.0) + math.pi) % (2 * math.pi) - math.pi
    assert err.std() == pytest.approx(5.0 * DEG, rel=0.05)
    assert abs(err.mean()) < 0.5 * DEG


def test_deterministic_given_rng_and_scene_untouched():
    scene = make_arena_scene(np.random.default_rng(2))
    for f in dataclasses.fields(scene):
        if getattr(scene, f.name) is not None:
            getattr(scene, f.name).setflags(write=False)  # any write raises
    cam = CameraSensor()
    a = cam.observe(scene, np.arange(20), np.random.default_rng(4))
    b = cam.observe(scene, np.arange(20), np.random.default_rng(4))
    c = cam.observe(scene, np.arange(20), np.random.default_rng(5))
    for x, y in zip(a.bearings, b.bearings, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.visible, b.visible)
    assert any(not np.array_equal(x, y) for x, y in zip(a.bearings, c.bearings, strict=True))


def test_visible_columns_cover_sensorless_owners():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.0)
    b.add_circle(0.0, 1.0, 0.05, owner=2, red=True, occluder=True)  # an intruder's strip
    batch = observe(b.build())
    np.testing.assert_array_equal(batch.visible, [[False, True, True]])


def test_observe_rejects_unknown_robots():
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    with pytest.raises(ValueError, match="robots"):
        observe(b.build(), robots=(1,))


def test_empty_observers():
    batch = observe(make_arena_scene(np.random.default_rng(0)), robots=np.zeros(0, int))
    assert batch.bearings == [] and batch.visible.shape == (0, 20)


def _stacked_scene_without_moving_red() -> Scene:
    """Two robots at two instants whose circles occlude but are not red; one static red decoy."""
    robot_xy = np.array([[[0.0, 0.0], [3.0, 0.0]], [[0.0, 0.5], [3.0, 0.5]]])  # (T=2, N=2, 2)
    moving = robot_xy.reshape(-1, 2)
    xy = np.vstack([[[1.5, 1.5]], moving])
    n = 1 + len(moving)
    return Scene(
        robot_xy=robot_xy,
        robot_yaw=np.zeros((2, 2)),
        circle_xy=xy,
        circle_radius_m=np.full(n, 0.05),
        circle_owner=np.array([-1, 0, 1, 0, 1]),
        circle_lidar=np.zeros(n, bool),
        circle_camera_occluder=np.ones(n, bool),
        circle_red=np.array([True, False, False, False, False]),
        circle_intensity=np.ones(n),
        segment_a=np.zeros((0, 2)),
        segment_b=np.zeros((0, 2)),
        segment_intensity=np.zeros(0),
        circle_time=np.array([-1, 0, 0, 1, 1]),
    )


def test_time_stacked_scene_with_only_static_red_targets():
    scene = _stacked_scene_without_moving_red()
    target, visible, bearing = CameraSensor().visibility(scene, np.array([0, 1]), np.array([0, 1]))
    assert target.tolist() == [0]
    assert visible.tolist() == [[True], [True]]
    # Robot 1 at instant 1 sits at (3, 0.5): the decoy at (1.5, 1.5) is up and to the left.
    assert bearing[1, 0] == pytest.approx(math.atan2(1.0, -1.5))


@pytest.mark.parametrize("bad", [-1, 2])
def test_time_index_outside_the_scene_is_rejected(bad):
    scene = _stacked_scene_without_moving_red()
    with pytest.raises(ValueError, match="time_index"):
        CameraSensor().visibility(scene, np.array([0]), np.array([bad]))


# --------------------------------------------------------------------------- detection vs range


def test_blob_area_is_the_strip_in_pixels_of_the_fisheye():
    cam = CameraSensor(CameraConfig())
    f = 1920.0 / math.pi  # 1920 px across 180 deg
    # A 5 cm-radius, 15 mm-high strip at 2 m: 2 asin(0.025) rad wide, 0.0075 rad high.
    expected = (f * 2.0 * math.asin(0.025)) * (f * 0.015 / 2.0)
    assert cam.blob_area_px(2.0, 0.05) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(140.1, abs=0.1)
    # ~1 / d^2: four times smaller at twice the range.
    assert cam.blob_area_px(4.0, 0.05) == pytest.approx(expected / 4.0, rel=0.001)


def pair_frames(r, radius=0.05, n_pairs=2000, config=None, seed=0):
    rng = np.random.default_rng(seed)
    scene, bearings = make_pair_scene(rng, r, n_pairs, strip_radius_m=radius)
    cam = CameraSensor(config or CameraConfig(false_positive_rate=0.0))
    observers = np.arange(0, scene.n_robots, 2)
    batch = cam.observe(scene, observers, rng)
    return cam, batch, bearings


@pytest.mark.parametrize("r", [1.0, 3.0, 3.8, 4.1, 4.4, 4.8])
def test_detection_probability_follows_the_blob_area_model(r):
    cam, batch, _ = pair_frames(r)
    found = np.array([b.size for b in batch.bearings])
    assert set(np.unique(found).tolist()) <= {0, 1}
    expected = float(cam.detection_probability(r, 0.05))
    # Hand-derived: need = 25 px / A(r); P = 0.95 clip((1 - need) / 0.5, 0, 1).
    need = 25.0 / float(cam.blob_area_px(r, 0.05))
    assert expected == pytest.approx(0.95 * min(max((1 - need) / 0.5, 0.0), 1.0))
    tol = 3.0 * math.sqrt(max(expected * (1 - expected), 0.01) / found.size) + 0.01
    assert found.mean() == pytest.approx(expected, abs=tol)


def test_detection_falls_from_3_to_5_m_like_the_seed():
    cam = CameraSensor(CameraConfig())
    pd = cam.detection_probability(np.array([1.0, 3.0, 3.5, 4.0, 4.5, 5.0]), 0.05)
    assert pd[0] == pytest.approx(0.95) and pd[1] == pytest.approx(0.95)
    assert 0.8 < pd[2] < 0.95 and 0.4 < pd[3] < 0.7 and 0.1 < pd[4] < 0.3 and pd[5] == 0.0
    # A wider red decoy (6 cm) is seen a little farther: a false positive out to ~5.2 m.
    assert cam.detection_probability(5.0, 0.06) > 0.0 == cam.detection_probability(5.3, 0.06)
    # range_max_m is only a computational bound: nothing passes the area test beyond it.
    assert cam.detection_probability(CameraConfig().range_max_m, 0.06) == 0.0


@pytest.mark.parametrize("r", [0.5, 1.0, 2.5])
def test_bearing_noise_is_blob_centroid_plus_pixel_rounding(r):
    """Offset (s - 1/2)(1 - u) w with s ~ U(0, 1), 1 - u ~ U(0, 1/2), w = 2 asin(R / r); plus
    U(-1/2, 1/2) / f: variance w^2 (1/12)(1/12) + 1 / (12 f^2)."""
    cam, batch, bearings = pair_frames(
        r, config=CameraConfig(miss_probability=0.0, false_positive_rate=0.0)
    )
    err = np.array(
        [
            (b[0] - t + math.pi) % (2 * math.pi) - math.pi
            for b, t in zip(batch.bearings, bearings, strict=True)
        ]
    )
    w = 2.0 * math.asin(0.05 / r)
    f = CameraConfig().pixels_per_rad
    sigma = math.sqrt(w * w / 144.0 + 1.0 / (12.0 * f * f))
    assert err.std() == pytest.approx(sigma, rel=0.06)
    assert abs(err.mean()) < 4.0 * sigma / math.sqrt(err.size)
    assert np.abs(err).max() <= 0.25 * w + 0.5 / f + 1e-12  # the centroid stays on the strip


@pytest.mark.parametrize("radius", [0.03, 0.05, 0.06, 0.5])
def test_detectable_range_is_a_tight_upper_bound_of_the_area_root(radius):
    cam = CameraSensor(CameraConfig(range_max_m=100.0))
    reach = float(cam.detectable_range_m(radius))
    assert float(cam.blob_area_px(reach, radius)) <= 25.0  # nothing passes beyond it
    assert float(cam.blob_area_px(0.999 * reach, radius)) > 25.0  # and it is tight
    assert float(CameraSensor().detectable_range_m(radius)) <= CameraConfig().range_max_m
