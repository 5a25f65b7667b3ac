"""The IR-UKF study: IR sensor, direct estimation (SLSQP), Kabsch alignment, centralized UKF."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from localization.baselines.centralized_ukf import CentralizedUKF, CentralizedUKFConfig
from localization.baselines.direct import (
    align_poses,
    direct_estimate,
    direct_objective,
    kabsch,
    pose_errors,
)
from swarm_env.sensors.ir import IRConfig, IRSensor


def _rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _readings(poses: np.ndarray, pairs: list[tuple[int, int]]):
    """Exact range-bearing of ``target`` in ``observer``'s frame (hand geometry)."""
    obs = np.array([i for i, _ in pairs])
    tgt = np.array([j for _, j in pairs])
    rng, brg = [], []
    for i, j in pairs:
        local = _rot(poses[i, 2]).T @ (poses[j, :2] - poses[i, :2])
        rng.append(math.hypot(*local))
        brg.append(math.atan2(local[1], local[0]))
    return obs, tgt, np.array(rng), np.array(brg)


# --------------------------------------------------------------------------- Kabsch
def test_kabsch_recovers_known_rotation_and_translation():
    rng = np.random.default_rng(3)
    e = rng.uniform(-1, 1, (6, 2))
    rot, t = _rot(2.5), np.array([0.7, -1.3])
    q = e @ rot.T + t
    r_est, t_est = kabsch(e, q)
    np.testing.assert_allclose(r_est, rot, atol=1e-12)
    np.testing.assert_allclose(t_est, t, atol=1e-12)


def test_kabsch_returns_a_proper_rotation_for_a_mirrored_set():
    e = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [1.5, 1.0]])
    q = e * np.array([1.0, -1.0])  # a reflection: no rotation maps e onto q
    r_est, _ = kabsch(e, q)
    assert np.linalg.det(r_est) == pytest.approx(1.0)
    np.testing.assert_allclose(r_est @ r_est.T, np.eye(2), atol=1e-12)


def test_align_poses_rotates_headings_with_the_fit():
    truth = np.array([[0.0, 0.0, 0.1], [1.0, 0.0, -3.0], [0.0, 1.0, 3.1]])
    a, t = 1.2, np.array([0.4, 0.2])
    est = truth.copy()
    est[:, :2] = truth[:, :2] @ _rot(a).T + t  # the estimate = truth moved rigidly
    est[:, 2] = truth[:, 2] + a
    pos, head = pose_errors(align_poses(est, truth), truth)
    assert pos.max() < 1e-12 and head.max() < 1e-12  # heading wrap across +-pi included


def test_kabsch_rejects_bad_shapes():
    with pytest.raises(ValueError, match="estimate_xy"):
        kabsch(np.zeros((3, 2)), np.zeros((4, 2)))


# --------------------------------------------------------------------------- direct estimation
def test_objective_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    poses = rng.uniform(-1, 1, (4, 3))
    obs, tgt = np.array([0, 1, 2, 3, 1]), np.array([1, 2, 3, 0, 3])
    z = rng.uniform(-1, 1, (5, 2))
    _, grad = direct_objective(poses, obs, tgt, z)
    num = np.zeros_like(grad)
    for idx in np.ndindex(poses.shape):
        d = np.zeros_like(poses)
        d[idx] = 1e-6
        num[idx] = (
            direct_objective(poses + d, obs, tgt, z)[0]
            - direct_objective(poses - d, obs, tgt, z)[0]
        ) / 2e-6
    np.testing.assert_allclose(grad, num, atol=1e-6)


def test_slsqp_recovers_three_noiseless_poses_after_kabsch():
    truth = np.array([[0.3, -0.2, 0.4], [0.9, 0.1, -1.0], [0.5, 0.6, 2.5]])
    pairs = [(i, j) for i in range(3) for j in range(3) if i != j]
    res = direct_estimate(*_readings(truth, pairs), n_robots=3)
    assert res.enough_readings and res.observable.all()
    assert res.poses[0] == pytest.approx([0.0, 0.0, 0.0])  # the gauge
    pos, head = pose_errors(align_poses(res.poses, truth), truth)
    assert pos.max() < 1e-6 and head.max() < 1e-6
    assert res.cost < 1e-10


def test_slsqp_with_a_chain_of_one_way_readings():
    # 0 sees 1, 1 sees 2, 2 sees 0, 0 sees 2: 4 readings = 8 equations >= 3 * 3 - 3.
    truth = np.array([[1.0, 1.0, -0.5], [1.6, 1.2, 1.0], [1.2, 1.8, -2.8]])
    res = direct_estimate(*_readings(truth, [(0, 1), (1, 2), (2, 0), (0, 2)]), n_robots=3)
    pos, head = pose_errors(align_poses(res.poses, truth), truth)
    assert pos.max() < 1e-6 and head.max() < 1e-6


def test_too_few_readings_are_flagged():
    truth = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]])
    res = direct_estimate(*_readings(truth, [(0, 1)]), n_robots=3)
    assert not res.enough_readings and not res.observable.all()


def test_direct_estimate_rejects_bad_input():
    with pytest.raises(ValueError, match="target"):
        direct_estimate([0], [5], [0.5], [0.0], n_robots=3)
    with pytest.raises(ValueError, match="range_m"):
        direct_estimate([0], [1], [-0.5], [0.0], n_robots=3)


# --------------------------------------------------------------------------- centralized UKF
def _moving_truth(t: float) -> np.ndarray:
    """Four robots on circles of radius 0.3 m (different phases), heading along the motion."""
    phase = np.arange(4) * math.pi / 2
    centres = np.array([[0.0, 0.0], [0.6, 0.0], [0.6, 0.6], [0.0, 0.6]])
    w = 0.2
    ang = phase + w * t
    xy = centres + 0.3 * np.stack((np.cos(ang), np.sin(ang)), -1)
    return np.concatenate((xy, (ang + math.pi / 2)[:, None]), axis=1)


def _increments(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Body-frame odometry increment from poses ``a`` to ``b`` (N, 3)."""
    d = b[:, :2] - a[:, :2]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack(
        (c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], b[:, 2] - a[:, 2]), axis=-1
    )


def test_ukf_converges_on_a_known_trajectory():
    rng = np.random.default_rng(7)
    sensor = IRSensor(IRConfig(rate_hz=2.0, outlier_probability=0.0, dropout_probability=0.0))
    sensor.reset(rng, 4)
    ukf = CentralizedUKF(range_std_m=0.072, init_position_std_m=0.2, init_heading_std_rad=0.5)
    truth = _moving_truth(0.0)
    start = truth.copy()
    start[1:, :2] += np.array([[0.15, -0.1], [-0.12, 0.1], [0.1, 0.12]])
    start[1:, 2] += np.array([0.3, -0.35, 0.25])
    ukf.initialize(start)
    first = pose_errors(align_poses(ukf.poses, truth), truth)
    dt, errors = 0.1, []
    for k in range(1, 301):
        new = _moving_truth(k * dt)
        ukf.predict(_increments(truth, new), dt)
        truth = new
        r = sensor.step(k * dt, truth)
        ukf.update(r.observer, r.target, r.range_m, r.bearing_rad)
        errors.append(pose_errors(align_poses(ukf.poses, truth), truth))
    pos = np.array([e[0] for e in errors[-50:]])
    head = np.array([e[1] for e in errors[-50:]])
    assert first[0].max() > 0.15
    assert np.sqrt((pos**2).mean()) < 0.03  # 3 cm after 30 s, from up to 18 cm
    assert np.degrees(np.sqrt((head**2).mean())) < 3.0


def test_ukf_update_touches_only_the_observers():
    ukf = CentralizedUKF()
    truth = _moving_truth(0.0)
    ukf.initialize(truth + np.array([0.05, -0.05, 0.1]))
    before_x, before_p = ukf.poses, ukf.covs
    obs, tgt, rho, brg = _readings(truth, [(0, 1), (0, 3)])
    ukf.update(obs, tgt, rho, brg)
    assert not np.allclose(ukf.poses[0], before_x[0])
    np.testing.assert_array_equal(ukf.poses[1:], before_x[1:])
    np.testing.assert_array_equal(ukf.covs[1:], before_p[1:])
    assert np.trace(ukf.covs[0]) < np.trace(before_p[0])


def test_ukf_wraps_the_bearing_residual():
    # Target straight behind: true bearing +pi - 0.01, measured -pi + 0.01 (0.02 rad apart).
    ukf = CentralizedUKF(landmark_uncertainty=False)
    ukf.initialize(np.array([[0.0, 0.0, 0.0], [-1.0, 0.01, 0.0]]))
    ukf.update(np.array([0]), np.array([1]), np.array([1.0]), np.array([-math.pi + 0.01]))
    # An unwrapped residual of ~ -2 pi would spin robot 0 around; wrapped it nudges it.
    assert abs(ukf.poses[0, 2]) < 0.05


def test_ukf_predict_follows_odometry_exactly_without_noise():
    ukf = CentralizedUKF(motion_std_m=0.0, motion_std_rad=0.0)
    a = np.array([[0.0, 0.0, math.pi / 2], [1.0, 1.0, 0.0]])
    ukf.initialize(a, np.broadcast_to(1e-12 * np.eye(3), (2, 3, 3)))  # (a spread heading
    # would shorten the mean step by E[cos] = exp(-sigma^2 / 2), as the unscented transform does)
    ukf.predict(np.array([[0.1, 0.0, 0.2], [0.0, 0.1, -0.1]]), 0.1)
    np.testing.assert_allclose(
        ukf.poses, [[0.0, 0.1, math.pi / 2 + 0.2], [1.0, 1.1, -0.1]], atol=1e-9
    )


def test_ukf_rejects_bad_input():
    with pytest.raises(ValueError, match="range_std_m"):
        CentralizedUKFConfig(range_std_m=0.0)
    ukf = CentralizedUKF()
    with pytest.raises(RuntimeError):
        ukf.predict(np.zeros((2, 3)), 0.1)
    ukf.initialize(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="deltas"):
        ukf.predict(np.zeros((3, 3)), 0.1)
    with pytest.raises(ValueError, match="observer"):
        ukf.update(np.array([0]), np.array([0]), np.array([1.0]), np.array([0.0]))


# --------------------------------------------------------------------------- IR sensor
def test_ir_rate_and_range_cut():
    cfg = IRConfig(dropout_probability=0.0)
    sensor = IRSensor(cfg)
    sensor.reset(np.random.default_rng(0), 3)
    poses = np.array([[0.0, 0.0, 0.0], [0.8, 0.0, 1.0], [0.0, 1.2, 0.0]])  # 1.2, 1.44 m > 1 m
    counts = np.zeros((3, 3), dtype=int)
    for k in range(1, 201):  # 20 s at 0.1 s
        r = sensor.step(k * 0.1, poses)
        np.add.at(counts, (r.observer, r.target), 1)
    # 20 sweeps per robot at 1 Hz (first within the first second)
    assert counts[0, 1] == 20 and counts[1, 0] == 20
    assert counts[0, 2] == counts[2, 0] == counts[1, 2] == counts[2, 1] == 0  # beyond 1 m
    assert np.trace(counts) == 0


def test_ir_noise_statistics_match_the_config():
    cfg = IRConfig()
    sensor = IRSensor(cfg)
    sensor.reset(np.random.default_rng(1), 2)
    poses = np.array([[0.0, 0.0, 0.3], [0.61 * math.cos(0.3), 0.61 * math.sin(0.3), 2.0]])
    n_sweeps = 40000
    r = sensor.measure(poses, np.zeros(n_sweeps, dtype=int))
    err = r.range_m - 0.61
    core = err[r.range_m < 0.9]  # the IR-UKF study's outlier cut (readings > 90 cm)
    n = len(r)
    assert abs(n / n_sweeps - (1 - cfg.dropout_probability)) < 4 * math.sqrt(
        0.05 * 0.95 / n_sweeps
    )
    # standard deviation of a sample std ~ sigma / sqrt(2 n): allow 5 of those
    assert abs(core.std() - cfg.range_std_m) < 5 * cfg.range_std_m / math.sqrt(2 * len(core))
    assert abs(err.std() - 0.186) < 0.005  # the IR-UKF study's 18.6 cm with outliers
    outliers = np.mean(r.range_m >= 0.9)
    p = cfg.outlier_probability
    assert abs(outliers - p) < 4 * math.sqrt(p * (1 - p) / n)
    b_err = r.bearing_rad - 0.0  # target dead ahead in the observer frame
    assert abs(b_err.std() - cfg.bearing_std_rad) < 5 * cfg.bearing_std_rad / math.sqrt(2 * n)
    assert abs(b_err.mean()) < 4 * cfg.bearing_std_rad / math.sqrt(n)


def test_ir_is_reproducible_and_rejects_bad_config():
    poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.2, 1.0], [0.2, 0.5, -1.0]])
    out = []
    for _ in range(2):
        s = IRSensor()
        s.reset(np.random.default_rng(5), 3)
        out.append(s.step(1.0, poses))
    np.testing.assert_array_equal(out[0].range_m, out[1].range_m)
    with pytest.raises(ValueError, match="rate_hz"):
        IRConfig(rate_hz=0.0)
    with pytest.raises(ValueError, match="outlier_offset_m"):
        IRConfig(outlier_offset_m=(0.9, 0.3))


# --------------------------------------------------------------------------- the scenario
def test_seed003_episode_writes_metrics(tmp_path):
    from swarm_phd.seed003 import run_seed003

    res = run_seed003(
        preset="lab-3m-4",
        n_robots=5,
        arena_m=1.5,
        duration_s=8.0,
        init_s=3.0,
        speed_mps=0.05,
        seeds=[0],
        ir=IRConfig(),
        ukf=CentralizedUKFConfig(),
        out_dir=tmp_path,
    )
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert data["summary"]["ukf_pos_rmse_mean_m"] == pytest.approx(
        res["summary"]["ukf_pos_rmse_mean_m"]
    )
    assert data["episodes"][0]["init"]["enough_readings"]
    assert res["summary"]["ukf_pos_rmse_mean_m"] < 0.15
    assert (tmp_path / "seed003_error.png").stat().st_size > 0


def test_seed003_rejects_bad_arguments():
    from swarm_phd.seed003 import run_episode

    with pytest.raises(ValueError, match="n_robots"):
        run_episode(0, n_robots=1)
    with pytest.raises(ValueError, match="init_s"):
        run_episode(0, duration_s=2.0, init_s=3.0)


def test_ir_sweep_motion_reads_each_pair_when_the_sweep_passes_it():
    cfg = IRConfig(
        range_std_m=0.0,
        outlier_probability=0.0,
        bearing_std_deg=0.0,
        dropout_probability=0.0,
        sweep_motion=True,
    )
    sensor = IRSensor(cfg)
    sensor.reset(np.random.default_rng(0), 2)
    omega, dt = 0.5, 0.1  # observer 0 turns in place; target fixed 0.5 m away along world +x

    def poses(t: float) -> np.ndarray:
        return np.array([[0.0, 0.0, omega * t], [0.5, 0.0, 0.0]])

    got = []
    for k in range(1, 41):
        r = sensor.step(k * dt, poses(k * dt))
        keep = r.observer == 0
        got += [(k * dt, s, b) for s, b in zip(r.stamp_s[keep], r.bearing_rad[keep], strict=True)]
    assert len(got) == 4
    for t_step, stamp, bearing in got:
        # the sweep's end is read from the poses of the step that reports it
        b_end = math.remainder(-omega * t_step, 2 * math.pi)
        t_pass = stamp - 1.0 * (math.pi - b_end) / (2 * math.pi)
        t_row = max(dt, math.floor(t_pass / dt + 1e-9) * dt)  # latest given poses at or before
        assert bearing == pytest.approx(math.remainder(-omega * t_row, 2 * math.pi), abs=1e-9)
        assert abs(bearing - b_end) > 0.05  # the delay shows: not the end-of-sweep bearing


def test_evaluate_runs_the_seed003_scenario(tmp_path, capsys):
    from swarm_phd.cli import main

    out = tmp_path / "ev"
    argv = ["evaluate", "--scenario", "seed003", "--duration", "8", "--seeds", "1"]
    assert main([*argv, "--out", str(out), "-q"]) == 0
    data = json.loads((out / "metrics.json").read_text())
    assert data["config"]["n_robots"] == 5 and data["config"]["duration_s"] == 8.0
    assert data["summary"]["ukf_pos_rmse_mean_m"] < 0.15  # the IR-UKF study's ~10 cm, with margin
    assert main([*argv, "--policy", "random"]) != 0
    assert "--scenario seed003 takes no --policy" in capsys.readouterr().err
    assert main([*argv, "--ray"]) != 0  # Ray fans out the study's seeds only
    assert "--scenario seed003 is serial" in capsys.readouterr().err
    assert main(["evaluate", "--compare", ",", "--duration", "1"]) != 0  # before any run
    assert "--compare names no policy" in capsys.readouterr().err
