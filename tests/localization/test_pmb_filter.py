"""The reference PMB localizer: hand-derived updates, ego motion, invariants, validation."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from localization import GaussianMixture, PHDConfig
from localization.frames import bearings_to_filter_frame, points_to_filter_frame
from localization.pmb import PMBConfig, RobotCentricPMB

# Constant models (P_d = 0.9 everywhere, P_s = 1), measurement births (no fixed birth joins
# the Poisson prior), so every number below can be derived by hand.
HAND = PHDConfig.perera2021().replace(
    lidar={
        "pd_model": "constant",
        "detection_probability": 0.9,
        "range_m": 100.0,
        "clutter_intensity": 0.05,
        "occlusion_min_separation_m": 0.0,
    },
    prediction={"survival_model": "constant", "survival_probability": 1.0},
    births={"model": "measurement"},
)
R_L = 0.05**2


def mix(weights, means, var):
    means = np.asarray(means, dtype=float).reshape(-1, 2)
    return GaussianMixture(
        np.asarray(weights, float), means, np.tile(var * np.eye(2), (len(means), 1, 1))
    )


def gauss2(d2, var):
    """N(d; 0, var I) in 2-D for squared distance d2."""
    return math.exp(-0.5 * d2 / var) / (2 * math.pi * var)


def test_one_miss_keeps_existence():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([0.99], [[1.0, 0.0]], 0.01))
    f.update_lidar(np.empty((0, 2)))
    r = 0.99 * 0.1 / (1 - 0.99 * 0.9)
    assert r == pytest.approx(0.908, abs=1e-3)
    t = f.tracks
    np.testing.assert_allclose(t.r, [r], rtol=1e-12)
    np.testing.assert_allclose(t.means, [[1.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(t.covs, [0.01 * np.eye(2)], atol=1e-15)
    # a GM-PHD component would keep only 0.099
    assert f.mixture.weights[0] > 9 * 0.099


def test_misses_recycle_the_track_into_the_poisson_intensity():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([0.99], [[1.0, 0.0]], 0.01))
    r = 0.99
    for _ in range(3):
        f.update_lidar(np.empty((0, 2)))
        r = r * 0.1 / (1 - 0.9 * r)
    assert r < 0.1 and len(f) == 0  # 0.99 -> 0.908 -> 0.497 -> 0.090: recycled
    np.testing.assert_allclose(f.poisson.weights, [r], rtol=1e-12)
    # detected again, it comes back as a track: r = e / (kappa + e)
    z = np.array([[1.02, 0.0]])
    f.update_lidar(z)
    e = 0.9 * r * gauss2(0.02**2, 0.01 + R_L)
    np.testing.assert_allclose(f.tracks.r, [e / (0.05 + e)], rtol=1e-10)
    np.testing.assert_allclose(f.poisson.weights, [0.1 * r], rtol=1e-12)


def test_two_targets_one_measurement_by_hand():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([0.9, 0.9], [[1.0, 0.0], [1.3, 0.0]], 0.01))
    z = np.array([1.1, 0.0])
    f.update_lidar(z[None])
    s = 0.01 + R_L
    g = np.array([gauss2(0.1**2, s), gauss2(0.2**2, s)])
    miss = 1 - 0.9 * 0.9
    # joint hypotheses: nobody / A / B takes z (the single measurement: a tree, BP exact)
    h_none = miss * miss * 0.05
    h_a = 0.81 * g[0] * miss
    h_b = 0.81 * g[1] * miss
    total = h_none + h_a + h_b
    p = np.array([h_a, h_b]) / total
    r0 = 0.9 * 0.1 / miss
    r_expected = (1 - p) * r0 + p
    t = f.tracks
    np.testing.assert_allclose(t.r, r_expected, rtol=1e-10)
    gain = 0.01 / s
    prior = np.array([[1.0, 0.0], [1.3, 0.0]])
    updated = prior + gain * (z - prior)
    mean = ((1 - p) * r0 * prior[:, 0] + p * updated[:, 0]) / r_expected
    np.testing.assert_allclose(t.means[:, 0], mean, atol=1e-12)
    np.testing.assert_allclose(t.means[:, 1], 0.0, atol=1e-15)
    # moment matching: spread along x, posterior variance 0.01 * R / s in the detected branch
    post_var = 0.01 * R_L / s
    var_x = (
        (1 - p) * r0 * (0.01 + (prior[:, 0] - mean) ** 2)
        + p * (post_var + (updated[:, 0] - mean) ** 2)
    ) / r_expected
    np.testing.assert_allclose(t.covs[:, 0, 0], var_x, rtol=1e-10)
    np.testing.assert_allclose(t.covs[:, 1, 1], ((1 - p) * r0 * 0.01 + p * post_var) / r_expected)
    # no Poisson mass, so z makes no new track (r = 0), and it is explained by A
    assert len(f) == 2


def test_bearing_update_against_hand_ekf():
    cfg = PHDConfig.perera2021().replace(
        births={"model": "measurement"}, camera={"clutter_intensity": 0.5}
    )
    f = RobotCentricPMB(cfg)
    f.set_state(mix([0.95], [[2.0, 0.0]], 0.04))
    theta = 0.05
    f.update_camera([theta])
    pd = 1.0 / (1.1 + math.exp(5 * (2.0 - 4.0)))
    rc = math.radians(5.0) ** 2
    h = np.array([0.0, 0.5])  # [-y, x] / r^2
    p_prior = 0.04 * np.eye(2)
    s = h @ p_prior @ h + rc
    k = p_prior @ h / s
    m_det = np.array([2.0, 0.0]) + k * theta
    ikh = np.eye(2) - np.outer(k, h)
    p_det = ikh @ p_prior @ ikh.T + rc * np.outer(k, k)
    g = math.exp(-0.5 * theta**2 / s) / math.sqrt(2 * math.pi * s)
    miss = 1 - 0.95 * pd
    psi = 0.95 * pd * g / (miss * 0.5)
    p1 = psi / (1 + psi)
    r0 = 0.95 * (1 - pd) / miss
    r = (1 - p1) * r0 + p1
    mean = ((1 - p1) * r0 * np.array([2.0, 0.0]) + p1 * m_det) / r
    d0, d1 = np.array([2.0, 0.0]) - mean, m_det - mean
    cov = ((1 - p1) * r0 * (p_prior + np.outer(d0, d0)) + p1 * (p_det + np.outer(d1, d1))) / r
    t = f.tracks
    np.testing.assert_allclose(t.r, [r], rtol=1e-12)
    np.testing.assert_allclose(t.means[0], mean, atol=1e-13)
    np.testing.assert_allclose(t.covs[0], cov, atol=1e-13)
    # the tangential variance shrank, the radial one did not (beyond the mixture spread)
    assert t.covs[0, 1, 1] < 0.04 and t.covs[0, 0, 0] == pytest.approx(0.04, abs=1e-12)


def test_new_track_from_poisson_by_hand():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([], np.empty((0, 2)), 0.01), mix([0.5], [[1.0, 0.0]], 0.01))
    z = np.array([1.05, 0.0])
    f.update_lidar(z[None])
    s = 0.01 + R_L
    e = 0.9 * 0.5 * gauss2(0.05**2, s)
    t = f.tracks
    np.testing.assert_allclose(t.r, [e / (0.05 + e)], rtol=1e-12)
    np.testing.assert_allclose(t.means[0], [1.0 + 0.01 / s * 0.05, 0.0], atol=1e-13)
    np.testing.assert_allclose(t.covs[0], 0.01 * R_L / s * np.eye(2), atol=1e-15)
    np.testing.assert_allclose(f.poisson.weights, [0.05], rtol=1e-12)


def test_gate_removes_far_pairs():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([0.9], [[1.0, 0.0]], 0.01))
    s = math.sqrt(0.01 + R_L)
    f.update_lidar([[1.0 + 4.01 * s, 0.0]])  # just outside the 4-sigma gate: a miss
    np.testing.assert_allclose(f.tracks.r, [0.9 * 0.1 / (1 - 0.81)], rtol=1e-12)
    np.testing.assert_allclose(f.tracks.means, [[1.0, 0.0]], atol=1e-15)


def test_static_teammate_stays_put_in_world():
    """Ego-motion sign: a static teammate's track follows the observer's own motion."""

    def rel(pose, target):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        d = target - pose[:2]
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])

    rng = np.random.default_rng(0)
    pose = np.array([0.3, -0.2, 0.7])
    target = np.array([1.5, 0.9])
    f = RobotCentricPMB(HAND, prediction={"process_noise_std_m": 1e-9})
    f.set_state(mix([0.99], [rel(pose, target)], 0.01))
    for _ in range(50):
        odo = np.array([rng.uniform(-0.05, 0.1), rng.uniform(-0.03, 0.03), rng.uniform(-0.3, 0.3)])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = pose + np.array([c * odo[0] - s * odo[1], s * odo[0] + c * odo[1], odo[2]])
        f.predict(odo)
        np.testing.assert_allclose(f.tracks.means[0], rel(pose, target), atol=1e-9)
    # and with updates: the track ends on the teammate
    g = RobotCentricPMB(HAND)
    pose = np.zeros(3)
    for _ in range(60):
        odo = np.array([0.03, 0.0, 0.1])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = pose + np.array([c * odo[0] - s * odo[1], s * odo[0] + c * odo[1], odo[2]])
        g.predict(odo)
        g.update_lidar(rel(pose, target)[None] + rng.normal(0, 0.05, (1, 2)))
    means, _ = g.estimate()
    assert means.shape == (1, 2) and np.linalg.norm(means[0] - rel(pose, target)) < 0.06


def test_sensor_pose_moves_measurements_like_frames():
    pose = np.array([0.03, -0.01, 0.12])
    pts = np.array([[1.0, 0.4], [0.2, -1.1]])
    nulls = np.array([0.3, -2.0])
    brg = np.array([0.4, -1.0])
    a = RobotCentricPMB(
        PMBConfig(phd=PHDConfig.perera2021().replace(births={"model": "measurement"}))
    )
    b = copy.deepcopy(a)
    for f, with_pose in ((a, True), (b, False)):
        for _ in range(3):
            f.predict([0.01, 0.0, 0.02])
            if with_pose:
                f.update_lidar(pts, nulls, sensor_pose=pose)
                # A pure rotation: the bearings turn (the camera's position is the parallax
                # test's, tests/localization/test_process_clock.py).
                f.update_camera(brg, sensor_pose=pose * [0.0, 0.0, 1.0])
            else:
                f.update_lidar(
                    points_to_filter_frame(pts, pose), bearings_to_filter_frame(nulls, pose)
                )
                f.update_camera(bearings_to_filter_frame(brg, pose))
    np.testing.assert_array_equal(a.table, b.table)
    np.testing.assert_array_equal(a.poisson_table, b.poisson_table)
    assert len(a) == 2


CONFIGS = {
    "seed": PMBConfig(),
    "measurement": PMBConfig(phd=PHDConfig.perera2021().replace(births={"model": "measurement"})),
    "lidar-only": PMBConfig(
        phd=PHDConfig.perera2021().replace(mode="lidar-only", births={"model": "measurement"})
    ),
    "cap": PMBConfig(
        phd=PHDConfig.perera2021().replace(
            births={"model": "measurement"}, reduction={"max_components": 5}
        ),
        max_tracks=3,
    ),
    "no-clutter": PMBConfig(
        phd=PHDConfig.perera2021().replace(
            births={"model": "measurement"},
            lidar={"clutter_intensity": 0.0},
            camera={"clutter_intensity": 0.0},
        )
    ),
    "pd-one": PMBConfig(phd=HAND.replace(lidar={"detection_probability": 1.0})),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_invariants_on_random_sequences(name):
    cfg = CONFIGS[name]
    f = RobotCentricPMB(cfg)
    rng = np.random.default_rng(1)
    mates = rng.uniform(-2.5, 2.5, (8, 2))
    seen_tracks = 0
    for _ in range(150):
        mates += rng.normal(0, 0.02, mates.shape)
        kind = rng.integers(3)
        if kind == 0:
            f.predict(rng.normal(0, [0.03, 0.01, 0.05]))
        elif kind == 1:
            pts = mates[rng.random(8) < 0.8] + rng.normal(0, 0.05, (1, 2))
            if rng.random() < 0.5:
                pts = np.concatenate([pts, rng.uniform(-2, 2, (2, 2))])
            f.update_lidar(pts, rng.uniform(-np.pi, np.pi, 2) if rng.random() < 0.3 else None)
        else:
            b = np.arctan2(mates[:, 1], mates[:, 0]) + rng.normal(0, 0.08, 8)
            f.update_camera(b[rng.random(8) < 0.9])
        for table in (f.table, f.poisson_table):
            assert np.isfinite(table).all()
            pxx, pxy, pyy = table[3:]
            assert (pxx > 0).all() and (pxx * pyy - pxy * pxy > 0).all()
            assert (table[0] >= 0).all()
        t = f.tracks
        np.testing.assert_array_equal(t.covs, t.covs.transpose(0, 2, 1))
        assert (t.r <= 1.0).all() and (t.r >= 0.0).all()
        if kind == 1 or (kind == 2 and cfg.phd.mode == "lidar-camera"):
            # updates recycle every track below the threshold (predict only decays r)
            assert (t.r >= cfg.recycle_threshold).all()
        assert (
            len(f) <= cfg.max_tracks
            and f.poisson_table.shape[1] <= cfg.phd.reduction.max_components
        )
        seen_tracks = max(seen_tracks, len(f))
    assert seen_tracks > 0


def test_estimate_sorted_and_thresholded():
    f = RobotCentricPMB(HAND)
    f.set_state(mix([0.6, 0.95, 0.3], [[1, 0], [2, 0], [3, 0]], 0.01))
    means, existences = f.estimate(0.5)
    np.testing.assert_array_equal(means, [[2, 0], [1, 0]])
    np.testing.assert_array_equal(existences, [0.95, 0.6])
    assert f.estimate(0.99)[0].shape == (0, 2)
    with pytest.raises(ValueError, match="threshold"):
        f.estimate(float("nan"))


def test_lidar_only_ignores_camera_and_copies_are_independent():
    f = RobotCentricPMB(PHDConfig.perera2021().replace(mode="lidar-only"))
    f.set_state(mix([0.9], [[1.0, 0.0]], 0.01))
    f.update_camera([0.0, 1.0])
    np.testing.assert_array_equal(f.tracks.r, [0.9])
    g = pickle.loads(pickle.dumps(f))
    h = copy.copy(f)
    f.update_lidar(np.empty((0, 2)))
    assert g.tracks.r[0] == 0.9 and h.tracks.r[0] == 0.9 and f.tracks.r[0] < 0.9
    assert g.config == f.config
    f.reset()
    assert len(f) == 0 and f.poisson_table.shape == (6, 0)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda f: f.predict([0.0, np.nan, 0.0]), "odometry"),
        (lambda f: f.predict([0.0, 0.0]), "odometry"),
        (lambda f: f.update_lidar([[1.0, np.inf]]), "points"),
        (lambda f: f.update_lidar([[1.0, 2.0, 3.0]]), "points"),
        (lambda f: f.update_lidar([[1.0, 2.0]], [np.nan]), "null_bearings"),
        (lambda f: f.update_lidar([[1.0, 2.0]], None, [0.0, 0.0]), "sensor_pose"),
        (lambda f: f.update_camera([[0.1]]), "bearings"),
        (lambda f: f.update_camera([0.1], [0.0, np.nan, 0.0]), "sensor_pose"),
        (lambda f: f.set_state(mix([1.5], [[1.0, 0.0]], 0.01)), "tracks"),
        (lambda f: f.set_state(mix([0.5], [[1.0, 0.0]], -0.01)), "positive definite"),
    ],
)
def test_bad_input_raises_before_any_change(call, name):
    f = RobotCentricPMB(
        PMBConfig(phd=PHDConfig.perera2021().replace(births={"model": "measurement"}))
    )
    f.update_lidar([[1.0, 0.5]])
    f.predict([0.0, 0.0, 0.0])
    f.update_lidar([[1.0, 0.5]])
    before = (f.table.copy(), f.poisson_table.copy())
    with pytest.raises(ValueError, match=name):
        call(f)
    np.testing.assert_array_equal(f.table, before[0])
    np.testing.assert_array_equal(f.poisson_table, before[1])


def test_config_validation_and_overrides():
    with pytest.raises(ValueError, match="gate_sigma"):
        PMBConfig(gate_sigma=-1.0)
    with pytest.raises(ValueError, match="max_tracks"):
        PMBConfig(max_tracks=0)
    with pytest.raises(ValueError, match="recycle_threshold"):
        PMBConfig(recycle_threshold=1.5)
    with pytest.raises(ValueError, match="unknown"):
        RobotCentricPMB(nope=1)
    f = RobotCentricPMB(
        PHDConfig.perera2021().replace(births={"model": "measurement"}),
        max_tracks=7,
        mode="lidar-only",
    )
    assert f.config.max_tracks == 7 and f.config.phd.mode == "lidar-only"
    assert f.config.phd.births.model == "measurement"


def test_pmb_tracks_the_synthetic_swarm_at_least_as_well_as_the_gm_phd(monkeypatch):
    """The GM-PHD's synthetic scenario (tests/localization/scenario.py), same data for both:
    the PMB's mean GOSPA is not above the GM-PHD's (measured: 0.97 vs 1.09 LC, 0.88 vs 0.97 LO)."""
    import tests.localization.scenario as scenario
    from localization import RobotCentricPHD

    for mode in ("lidar-camera", "lidar-only"):
        gospa = {}
        for name, cls in (("phd", RobotCentricPHD), ("pmb", RobotCentricPMB)):
            monkeypatch.setattr(scenario, "RobotCentricPHD", cls)
            runs = [
                scenario.run_scenario(
                    mode, seed=s, steps=400, config=PHDConfig.perera2021().replace(mode=mode)
                )
                for s in range(3)
            ]
            gospa[name] = np.mean([r.mean_gospa for r in runs])
        assert gospa["pmb"] <= gospa["phd"], (mode, gospa)
