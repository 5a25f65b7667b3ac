"""The ``perera2021`` preset's sensors against the Perera 2021 study's equations.

Each sensor's detection fraction is measured against range on isolated (observer, teammate)
pairs (:mod:`swarm_env.sensors.detection_trials`) and compared with the curve it claims: the
lidar's with eq. 19, the cameras' with eq. 30, their bearing noise with the 5 deg of eq. 28.
Tolerances are four binomial standard errors plus what the simulated geometry adds where the
stated curve is already near zero (below 0.04).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env import parallel_env
from swarm_env.config import make_config
from swarm_env.sensors.detection_fade import RangeFade, keep_mask, thin_bearings, thin_points
from swarm_env.sensors.detection_trials import camera_bearing_errors, lidar_detects


def eq19(r):
    return 1.0 / (1.02 + np.exp(8.0 * (np.asarray(r) - 1.5)))


def eq30(r):
    return 1.0 / (1.1 + np.exp(5.0 * (np.asarray(r) - 4.0)))


def test_range_fade_is_the_stated_sigmoid():
    r = np.linspace(0.0, 6.0, 61)
    assert np.allclose(RangeFade.perera2021_lidar().probability(r), eq19(r), rtol=0, atol=1e-15)
    assert np.allclose(RangeFade.perera2021_camera().probability(r), eq30(r), rtol=0, atol=1e-15)
    assert 0.0 <= RangeFade(1.0, 8.0, 1.5).probability(1e9) < 1e-300  # no overflow far away


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"offset": 0.9, "slope_per_m": 8.0, "midpoint_m": 1.5}, "offset"),
        ({"offset": 1.0, "slope_per_m": 0.0, "midpoint_m": 1.5}, "slope_per_m"),
        ({"offset": 1.0, "slope_per_m": 8.0, "midpoint_m": float("nan")}, "midpoint_m"),
    ],
)
def test_range_fade_rejects_bad_values_by_name(kwargs, field):
    with pytest.raises(ValueError, match=field):
        RangeFade(**kwargs)


def test_swarm_config_rejects_a_fade_of_the_wrong_type():
    with pytest.raises(ValueError, match="lidar_fade"):
        make_config("perera2021", lidar_fade="eq19")
    with pytest.raises(ValueError, match="camera_fade"):
        make_config("sim-6m-20", camera_fade={"offset": 1.1})
    # A preset's fade takes field overrides like the other sub-configs.
    assert make_config("perera2021", lidar_fade={"midpoint_m": 1.4}).lidar_fade.midpoint_m == 1.4


def test_preset_is_the_studys_setup():
    cfg = make_config("perera2021")
    assert cfg.n_robots == 20
    assert (cfg.arena.width_m, cfg.arena.height_m) == (6.0, 6.0)
    assert cfg.max_steps * cfg.control_period_s == pytest.approx(300.0)
    assert (cfg.arena.n_decoy_posts, cfg.arena.n_red_decoys, cfg.arena.n_boxes) == (0, 0, 0)
    assert cfg.camera.false_positive_rate == 0.0
    assert cfg.camera.bearing_noise_std_deg == 5.0
    assert cfg.lidar.blind_sector_centers_deg == cfg.phd.lidar.blind_sector_centers_deg
    assert cfg.phd == type(cfg.phd).perera2021()


@pytest.mark.parametrize("range_m", [0.5, 1.0, 1.3, 1.5, 1.7, 1.9, 2.1])
def test_lidar_detection_fraction_follows_eq19(range_m):
    rng = np.random.default_rng(int(range_m * 100))
    n = 400
    # Bearings away from the four pillar sectors (45 deg +- 5 deg and its mirrors).
    bearings = np.deg2rad(rng.uniform(-30.0, 30.0, n) + 90.0 * rng.integers(0, 4, n))
    found = lidar_detects(range_m, bearings, rng, preset="perera2021", fade=True)
    p = float(eq19(range_m))
    tol = 4.0 * math.sqrt(max(p * (1 - p), 0.01) / n) + (0.04 if p < 0.04 else 0.0)
    assert abs(found.mean() - p) <= tol, (range_m, found.mean(), p)


@pytest.mark.parametrize("range_m", [1.0, 2.0, 3.0, 3.5, 4.0, 4.5, 5.0])
def test_camera_detection_fraction_follows_eq30(range_m):
    rng = np.random.default_rng(int(range_m * 100) + 1)
    n = 400
    errors = camera_bearing_errors(range_m, n, rng, preset="perera2021")
    found = np.isfinite(errors)
    p = float(eq30(range_m))
    tol = 4.0 * math.sqrt(max(p * (1 - p), 0.01) / n) + (0.04 if p < 0.04 else 0.0)
    assert abs(found.mean() - p) <= tol, (range_m, found.mean(), p)


def test_camera_bearing_noise_is_5_deg():
    rng = np.random.default_rng(7)
    errors = camera_bearing_errors(2.0, 1500, rng, preset="perera2021")
    errors = errors[np.isfinite(errors)]
    # Chi-square: the sample std of ~1360 normals is within 6 % of sigma at > 4 SE.
    assert np.rad2deg(errors.std()) == pytest.approx(5.0, rel=0.06)
    assert abs(np.rad2deg(errors.mean())) < 4 * 5.0 / math.sqrt(errors.size)


def test_thinning_keeps_order_and_leaves_clutter():
    fade = RangeFade(1.0, 50.0, 1.0)  # ~1 below 0.9 m, ~0 beyond 1.1 m
    rng = np.random.default_rng(0)
    points = [np.array([[0.5, 0.0], [3.0, 0.0], [0.0, -0.2]]), np.zeros((0, 2))]
    kept = thin_points(points, fade, rng)
    assert np.array_equal(kept[0], points[0][[0, 2]]) and kept[1].shape == (0, 2)
    bearings = [np.array([-1.0, 0.5, 2.0])]
    sources = [np.array([0, -1, 1])]
    circles = np.array([[0.3, 0.0], [5.0, 0.0]])
    b, s = thin_bearings(bearings, sources, circles, np.zeros((1, 2)), fade, rng)
    assert np.array_equal(b[0], [-1.0, 0.5]) and np.array_equal(s[0], [0, -1])
    with pytest.raises(ValueError, match="frames"):
        thin_bearings(bearings, sources, circles, np.zeros((2, 2)), fade, rng)
    assert keep_mask(fade, np.zeros(0), rng).shape == (0,)


def _rollout(preset: str, seed: int, steps: int, **overrides):
    env = parallel_env(
        preset, task="wander", observation="measurements", localize=False, **overrides
    )
    try:
        env.reset(seed=seed)
        far_lidar, far_camera, trace = 0, 0, []
        for _ in range(steps):
            env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
            step = env.last_world_step
            for m in step.measurements.values():
                for rec in m.lidar:
                    r = np.hypot(rec.detections[:, 0], rec.detections[:, 1])
                    far_lidar += int((r > 1.6).sum())
                    trace.append(rec.detections.copy())
                for rec in m.camera:
                    far_camera += rec.bearings_rad.size
                    trace.append(rec.bearings_rad.copy())
        return far_lidar, far_camera, trace
    finally:
        env.close()


def test_env_applies_the_fades_deterministically():
    a = _rollout("perera2021", 3, 20)
    b = _rollout("perera2021", 3, 20)
    assert len(a[2]) == len(b[2]) and all(
        np.array_equal(x, y) for x, y in zip(a[2], b[2], strict=True)
    )
    unfaded = _rollout("perera2021", 3, 20, lidar_fade=None, camera_fade=None)
    # eq. 19 keeps < 30 % beyond 1.6 m where the geometric lidar keeps nearly all; eq. 30
    # drops about 10 % of every bearing.
    assert a[0] < 0.5 * unfaded[0]
    assert a[1] < 0.95 * unfaded[1]
