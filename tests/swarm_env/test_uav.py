"""The UAV supervisor: downward camera geometry and statistics, kinematics, env API."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from swarm_env.sensors.downward_camera import (
    DownwardCamera,
    DownwardCameraConfig,
    in_footprint,
    measure_camera,
    to_level_frame,
)
from swarm_env.uav import UAV_ID, SupervisedSwarmEnv, UAVConfig, UGVView, centroid_command
from swarm_env.uav.env import body_increment, relative_increment


# ---------------------------------------------------------------------- camera geometry
def test_footprint_grows_linearly_with_altitude_by_hand():
    cfg = DownwardCameraConfig(horizontal_fov_deg=60.0, vertical_fov_deg=47.0)
    # tan(30 deg) = 0.57735, tan(23.5 deg) = 0.434812
    np.testing.assert_allclose(cfg.half_extents_m(2.0), [1.154701, 0.869625], atol=1e-6)
    np.testing.assert_allclose(cfg.half_extents_m(4.0), 2.0 * cfg.half_extents_m(2.0))
    # 90 deg square field of view: half extent = altitude.
    square = DownwardCameraConfig(horizontal_fov_deg=90.0, vertical_fov_deg=90.0)
    np.testing.assert_allclose(square.half_extents_m(3.0), [3.0, 3.0])


def test_noise_std_by_hand():
    cfg = DownwardCameraConfig(image_width_px=640, pixel_noise_std_px=2.0)
    f = 320.0 / math.tan(math.radians(30.0))  # 554.26 px
    assert cfg.focal_length_px == pytest.approx(f)
    assert cfg.noise_std_m(2.8) == pytest.approx(2.8 * 2.0 / f)
    assert cfg.noise_std_m(5.6) == pytest.approx(2.0 * cfg.noise_std_m(2.8))


def test_level_frame_follows_the_uav_yaw():
    # UAV at (1, 1) facing +y: a UGV at (1, 3) is 2 m ahead; one at (0, 1) is 1 m to the left.
    rel = to_level_frame(np.array([1.0, 1.0, math.pi / 2]), np.array([[1.0, 3.0], [0.0, 1.0]]))
    np.testing.assert_allclose(rel, [[2.0, 0.0], [0.0, 1.0]], atol=1e-12)
    half = np.array([1.5, 1.0])
    np.testing.assert_array_equal(in_footprint(rel, half), [False, True])


def test_targets_outside_the_footprint_are_never_detected():
    cfg = DownwardCameraConfig(detection_probability=1.0, clutter_per_frame=0.0)
    cam = DownwardCamera(cfg)
    half = cfg.half_extents_m(2.0)
    targets = np.array([[0.0, 0.0], [half[0] + 0.05, 0.0], [0.0, -half[1] - 0.05], [0.5, 0.3]])
    rng = np.random.default_rng(0)
    for _ in range(50):
        f = cam.frame(0.0, np.zeros(3), 2.0, targets, rng)
        assert sorted(f.source.tolist()) == [0, 3]


@pytest.mark.parametrize("altitude", [0.0, -1.0, float("nan"), float("inf"), None, "2.0"])
def test_frame_refuses_a_bad_altitude_before_any_draw(altitude):
    cam = DownwardCamera(DownwardCameraConfig())
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="altitude_m"):
        cam.frame(0.0, np.zeros(3), altitude, np.zeros((2, 2)), rng)
    assert rng.random() == np.random.default_rng(0).random()  # the stream was not touched


def test_detection_noise_misses_and_clutter_statistics():
    cfg = DownwardCameraConfig(detection_probability=0.8, clutter_per_frame=1.5)
    cam = DownwardCamera(cfg)
    h = 3.0
    half = cfg.half_extents_m(h)
    targets = np.array([[0.2, -0.3], [-0.5, 0.4], [1.0, 0.1]])
    rng = np.random.default_rng(1)
    hits, clutter, errors = 0, [], []
    n = 3000
    for _ in range(n):
        f = cam.frame(0.0, np.zeros(3), h, targets, rng)
        real = f.source >= 0
        hits += int(real.sum())
        errors.append(f.detections[real] - targets[f.source[real]])
        clutter.append(f.detections[~real])
    pd = hits / (3 * n)
    assert abs(pd - 0.8) < 4 * math.sqrt(0.8 * 0.2 / (3 * n))
    err = np.concatenate(errors)
    sigma = cfg.noise_std_m(h)
    np.testing.assert_allclose(err.std(axis=0), sigma, rtol=0.05)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=4 * sigma / math.sqrt(len(err)))
    pts = np.concatenate(clutter)
    assert abs(len(pts) / n - 1.5) < 4 * math.sqrt(1.5 / n)  # Poisson mean
    assert in_footprint(pts, half).all()
    # Uniform over the footprint: mean 0, variance half^2 / 3 per axis.
    np.testing.assert_allclose(pts.var(axis=0), half**2 / 3.0, rtol=0.08)


def test_measured_statistics_match_the_configuration():
    cfg = DownwardCameraConfig(pixel_noise_std_px=3.0, detection_probability=0.9)
    stats = measure_camera(cfg, altitudes_m=(1.0, 3.0), n_frames=300, n_targets=16)
    np.testing.assert_allclose(stats.detection_probability, 0.9, atol=0.03)
    np.testing.assert_allclose(
        stats.noise_std_m, [cfg.noise_std_m(1.0), cfg.noise_std_m(3.0)], rtol=0.06
    )
    assert stats.noise_per_altitude == pytest.approx(cfg.noise_std_m(1.0), rel=0.06)
    assert stats.mean_clutter_per_frame == pytest.approx(cfg.clutter_per_frame, abs=0.1)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"horizontal_fov_deg": 180.0}, "uav.camera.horizontal_fov_deg"),
        ({"detection_probability": 1.5}, "uav.camera.detection_probability"),
        ({"clutter_per_frame": -1.0}, "uav.camera.clutter_per_frame"),
        ({"image_width_px": 1.5}, "uav.camera.image_width_px"),
        ({"rate_hz": float("nan")}, "uav.camera.rate_hz"),
    ],
)
def test_bad_camera_config_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        DownwardCameraConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"max_speed_mps": -1.0}, "uav.max_speed_mps"),
        ({"velocity_frame": "ned"}, "uav.velocity_frame"),
        ({"start_altitude_m": 9.0}, "uav.start_altitude_m"),
        ({"max_altitude_m": 0.5}, "uav.max_altitude_m"),
        ({"yaw_control": 1}, "uav.yaw_control"),
        ({"odometry_std_mps": "x"}, "uav.odometry_std_mps"),
    ],
)
def test_bad_uav_config_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        UAVConfig(**kwargs)


# ---------------------------------------------------------------------- kinematics
def test_body_increment_is_the_exact_arc():
    v, w, dt = np.array([0.6, -0.2]), 0.9, 0.7
    pose = np.zeros(3)
    k = 20000
    for _ in range(k):  # fine Euler reference
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = pose + (dt / k) * np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], w])
    np.testing.assert_allclose(body_increment(v, w, dt), pose, atol=1e-4)
    np.testing.assert_allclose(body_increment(v, 0.0, dt), [0.42, -0.14, 0.0])


def test_relative_increment_composes_a_lost_broadcast_away():
    a = np.array([0.3, 0.1, 0.4])
    b = np.array([0.5, -0.2, 1.0])
    c = np.array([0.9, 0.4, -2.9])
    ab, bc, ac = relative_increment(a, b), relative_increment(b, c), relative_increment(a, c)
    # Composing ab then bc (the two broadcasts) equals ac (only the second one received).
    cs, sn = math.cos(ab[2]), math.sin(ab[2])
    composed = np.array(
        [ab[0] + cs * bc[0] - sn * bc[1], ab[1] + sn * bc[0] + cs * bc[1], ab[2] + bc[2]]
    )
    composed[2] = (composed[2] + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(composed, ac, atol=1e-12)


# ---------------------------------------------------------------------- the env
def _env(**kwargs):
    kwargs.setdefault("max_steps", 40)
    return SupervisedSwarmEnv("seed-uav", **kwargs)


def _hold(env, uav_action):
    return {a: np.zeros(2, dtype=np.float32) for a in env.ugv_agents} | {UAV_ID: uav_action}


def test_agents_and_spaces_differ_per_type():
    env = _env()
    assert env.possible_agents == ["ugv_0", "ugv_1", "ugv_2", "uav_0"]
    assert env.action_space(UAV_ID).shape == (4,)
    assert env.action_space("ugv_0").shape == (2,)
    assert env.observation_space(UAV_ID).shape == (3 * 6 + 4,)
    assert env.observation_space("ugv_0") is env.ground.observation_space("ugv_0")
    planar = _env(uav=UAVConfig(yaw_control=False, altitude_control=False))
    assert planar.action_space(UAV_ID).shape == (2,)


def test_parallel_api():
    parallel_api_test(_env(max_steps=25), num_cycles=30)


def test_ugv_view_for_shared_policies():
    view = UGVView(_env(max_steps=25), controller="centroid")
    parallel_api_test(view, num_cycles=30)
    obs, _ = view.reset(seed=2)
    assert sorted(obs) == ["ugv_0", "ugv_1", "ugv_2"]
    assert len({view.action_space(a).shape for a in view.possible_agents}) == 1
    with pytest.raises(ValueError, match="controller"):
        UGVView(_env(), controller="loiter")


def test_centroid_controller_flies_towards_the_detections():
    from swarm_core.aerial import AerialFrame

    frame = AerialFrame(0.0, 2.0, np.ones(2), np.array([[1.0, 0.0], [0.0, 0.4]]), np.zeros(2))
    np.testing.assert_allclose(centroid_command(frame, gain_per_s=0.5), [0.25, 0.1])
    assert centroid_command(None).tolist() == [0.0, 0.0]


def test_uav_flies_kinematically_within_its_limits():
    env = _env(uav=UAVConfig(start_yaw_rad=math.pi / 2, max_speed_mps=1.0), max_steps=80)
    env.reset(seed=0)
    for _ in range(10):  # 1 s at 0.5 m/s forward (world +y), climbing at 0.5 m/s
        env.step(_hold(env, np.array([0.5, 0.0, 0.0, 0.5], dtype=np.float32)))
    np.testing.assert_allclose(env.uav_pose, [0.0, 0.5, math.pi / 2], atol=1e-9)
    assert env.altitude_m == pytest.approx(3.3)
    # Planar speed limit on the norm, and the geofence (arena half side 1.25 + margin 1.0).
    for _ in range(60):  # world velocity (-0.707, 0.707) m/s: 2.8 m, into the fence
        env.step(_hold(env, np.array([3.0, 3.0, 0.0, 9.0], dtype=np.float32)))
    np.testing.assert_allclose(env.uav_pose[:2], [-2.25, 2.25])
    assert env.altitude_m == pytest.approx(env.uav_config.max_altitude_m)


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.zeros(3), r"uav_0 must have shape \(4,\)"),
        (np.array([0.0, np.nan, 0.0, 0.0]), "uav_0 must be finite"),
        ("fast", "uav_0 must be a numeric array"),
    ],
)
def test_bad_uav_action_raises_before_anything_changes(action, match):
    env = _env()
    env.reset(seed=0)
    pose, t = env.uav_pose.copy(), env.time_s
    with pytest.raises(ValueError, match=match):
        env.step(_hold(env, action))
    assert env.time_s == t
    np.testing.assert_array_equal(env.uav_pose, pose)


def test_missing_uav_action_and_disabled_radio_raise():
    env = _env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="uav_0"):
        env.step({a: np.zeros(2, dtype=np.float32) for a in env.ugv_agents})
    with pytest.raises(ValueError, match="comms.enabled"):
        _env(comms={"enabled": False})


def test_same_seed_same_rollout():
    def rollout(seed):
        env = _env(comms={"loss_probability": 0.3, "latency_jitter_s": 0.15})
        obs, _ = env.reset(seed=seed)
        out = [obs[UAV_ID]]
        rng = np.random.default_rng(5)
        for _ in range(30):
            acts = {a: rng.uniform(-0.2, 0.2, 2).astype(np.float32) for a in env.ugv_agents}
            acts[UAV_ID] = rng.uniform(-0.3, 0.3, 4).astype(np.float32)
            obs, *_ = env.step(acts)
            out.append(np.concatenate([obs[a] for a in env.possible_agents]))
        return np.concatenate(out), env.state()

    a, sa = rollout(4)
    b, sb = rollout(4)
    c, _ = rollout(5)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(sa, sb)
    assert not np.array_equal(a, c)


def test_ugvs_broadcast_to_the_uav_with_loss():
    env = _env()
    env.reset(seed=1)
    senders = set()
    for _ in range(5):
        _, _, _, _, infos = env.step(_hold(env, np.zeros(4, dtype=np.float32)))
        senders |= {m.sender for m in infos[UAV_ID]["comms"]}
    assert senders == set(env.ugv_agents)
    deaf = _env(comms={"loss_probability": 1.0})
    deaf.reset(seed=1)
    for _ in range(5):
        _, _, _, _, infos = deaf.step(_hold(deaf, np.zeros(4, dtype=np.float32)))
        assert infos[UAV_ID]["comms"] == []
    # Without odometry the UAV can recover no identity.
    assert not [i for i in infos[UAV_ID]["estimate"] if i >= 0]


def test_cli_uav_prints_and_writes_the_metrics(tmp_path, capsys):
    import json

    from swarm_phd.cli import main

    out = tmp_path / "uav.json"
    fig = tmp_path / "uav.png"
    args = ["uav", "--seeds", "1", "--duration", "8", "--hold-s", "2", "-q"]
    assert main([*args, "--json", str(out), "--figure", str(fig)]) == 0
    text = capsys.readouterr().out
    assert "Stegagno 2013" in text and "converged" in text
    result = json.loads(out.read_text())
    assert result["setup"]["preset"] == "seed-uav"
    ids = result["episodes"][0]["identities"]
    assert len(ids) == 3 and all(m["convergence_time_s"] < 6.0 for m in ids)
    assert result["episodes"][0]["camera_model"]["detection_probability"] == pytest.approx(
        0.95, abs=0.02
    )
    assert fig.stat().st_size > 10_000


def test_pickle_round_trip_continues_the_same_rollout():
    import pickle

    env = _env()
    env.reset(seed=3)
    rng = np.random.default_rng(0)

    def acts():
        a = {u: rng.uniform(-0.2, 0.2, 2).astype(np.float32) for u in env.ugv_agents}
        return a | {UAV_ID: rng.uniform(-0.3, 0.3, 4).astype(np.float32)}

    for _ in range(5):
        env.step(acts())
    clone = pickle.loads(pickle.dumps(env))
    for a in [acts() for _ in range(5)]:
        o1, o2 = env.step(a)[0], clone.step(a)[0]
        for agent in o1:
            np.testing.assert_array_equal(o1[agent], o2[agent])


def test_fixed_lag_filter_settles_what_a_radio_without_latency_gives():
    """With 0.2 s of latency (2 steps of lag), the settled filter at step k is bit for bit the
    filter of the same rollout without latency at step k - 2 (same random draws): every
    increment is applied with the frame it belongs to. Without the lag it is not."""
    comms = {"loss_probability": 0.2}
    fast = _env(comms=comms)
    late = _env(comms=comms | {"latency_s": 0.2})
    eager = _env(comms=comms | {"latency_s": 0.2}, filter_lag_s=0.0)
    assert (late.filter_lag_steps, eager.filter_lag_steps) == (2, 0)
    history = []
    rng = np.random.default_rng(1)
    for env in (fast, late, eager):
        env.reset(seed=7)
    for _ in range(25):
        a = {u: rng.uniform(-0.3, 0.3, 2).astype(np.float32) for u in fast.ugv_agents}
        a[UAV_ID] = np.zeros(4, dtype=np.float32)
        for env in (fast, late, eager):
            env.step(dict(a))
        history.append((fast.filter.means.copy(), fast.filter.weights.copy()))
    means, weights = history[-3]
    np.testing.assert_array_equal(late.settled_filter.means, means)
    np.testing.assert_array_equal(late.settled_filter.weights, weights)
    assert late.filter is not late.settled_filter  # the reported one is re-run to now
    assert eager.filter.means.shape != means.shape or not np.array_equal(eager.filter.means, means)
    with pytest.raises(ValueError, match="filter_lag_s"):
        _env(filter_lag_s=-1.0)
