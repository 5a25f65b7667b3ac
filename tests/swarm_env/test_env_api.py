"""PettingZoo API compliance, determinism, pickling, spaces and truncation."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from pettingzoo.test import parallel_api_test

from swarm_env import parallel_env


@pytest.mark.parametrize(
    "kwargs",
    [
        {"preset": "seed-lab"},
        {"preset": "seed-lab", "observation": "truth"},
        {"preset": "seed-lab", "observation": "measurements", "localize": False},
        {"preset": "seed-sim", "n_robots": 6},
    ],
)
def test_parallel_api(kwargs):
    env = parallel_env(max_steps=30, **kwargs)
    parallel_api_test(env, num_cycles=40)


def _rollout(seed: int, n_steps: int, **kwargs):
    env = parallel_env("seed-lab", max_steps=n_steps + 5, **kwargs)
    obs, infos = env.reset(seed=seed)
    out = [(obs, infos)]
    for _ in range(n_steps):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        out.append(env.step(actions))
    return out


def test_same_seed_same_rollout_bit_for_bit():
    a = _rollout(seed=3, n_steps=200)
    b = _rollout(seed=3, n_steps=200)
    assert data_equivalence(a, b, exact=True)


def test_different_seed_differs():
    a = _rollout(seed=3, n_steps=20)
    b = _rollout(seed=4, n_steps=20)
    assert not data_equivalence(a, b, exact=True)


def test_pickle_round_trip_continues_identically():
    env = parallel_env("seed-lab", render_mode="rgb_array")
    env.reset(seed=1)
    actions = {a: np.array([0.2, 0.3], dtype=np.float32) for a in env.agents}
    env.step(actions)
    env.render()
    clone = pickle.loads(pickle.dumps(env))
    assert data_equivalence(env.step(actions), clone.step(actions), exact=True)


def test_spaces_are_float32_identical_and_stable():
    env = parallel_env("seed-lab")
    spaces_ = [env.observation_space(a) for a in env.possible_agents]
    assert all(s is spaces_[0] for s in spaces_)
    assert env.observation_space("ugv_0") is env.observation_space("ugv_0")
    assert env.action_space("ugv_1") is env.action_space("ugv_1")
    assert spaces_[0].dtype == np.float32 and env.action_space("ugv_0").dtype == np.float32
    high = env.action_space("ugv_0").high
    robot = env.config.robot
    assert np.allclose(high, [robot.max_speed_mps, robot.max_turn_rate_radps])
    obs, _ = env.reset(seed=0)
    assert obs["ugv_0"].shape == (7 * 16 + 2,)


def test_truncation_at_max_steps():
    env = parallel_env("seed-lab", max_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        _, _, term, trunc, _ = env.step({a: np.zeros(2) for a in env.agents})
    assert all(trunc.values()) and not any(term.values())
    assert env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})


def test_infos_carry_truth_and_raw_records():
    env = parallel_env("seed-lab")
    env.reset(seed=0)
    infos = None
    for _ in range(3):
        *_, infos = env.step({a: np.zeros(2) for a in env.agents})
    info = infos["ugv_1"]
    assert info["truth"]["pose"].shape == (3,)
    assert info["truth"]["neighbours_xy"].shape == (4, 2)
    assert set(info["truth"]["in_range"]) == {"lidar", "camera"}
    meas = info["measurements"]
    assert len(meas["odometry"]) == 1  # 10 Hz odometry, 0.1 s step
    assert 2 <= len(meas["camera"]) + len(meas["lidar"]) <= 6
    stamps = [r["stamp_s"] for r in meas["camera"]]
    assert all(0.2 < s <= env.time_s + 1e-9 for s in stamps)


def test_render_rgb_array_headless():
    env = parallel_env("seed-lab", render_mode="rgb_array")
    env.reset(seed=0)
    env.step({a: np.array([0.1, 0.0]) for a in env.agents})
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 0


def test_render_human_headless():
    env = parallel_env("seed-lab", render_mode="human")
    env.reset(seed=0)
    env.step({a: np.zeros(2) for a in env.agents})
    env.close()


def test_batched_phd_tables_match_the_per_robot_encoder():
    from swarm_env.observation import phd_tables

    env = parallel_env("seed-sim", n_robots=8)
    env.reset(seed=2)
    for _ in range(30):
        env.step({a: env.action_space(a).sample() for a in env.agents})
    tables, counts = env.localizer.padded_tables()
    for top_k in (3, 16, 80):
        batched = phd_tables(tables, counts, top_k)
        for i, view in enumerate(env.localizers):
            m = view.mixture
            np.testing.assert_array_equal(batched[i], phd_table(m.weights, m.means, m.covs, top_k))
    assert counts.max() > 3  # the cut at top_k=3 was exercised


def test_batched_measurement_tables_match_the_per_robot_encoder():
    from swarm_env.observation import measurement_tables

    rng = np.random.default_rng(0)
    detections = [rng.normal(size=(m, 2)) for m in (0, 3, 9, 1)]
    bearings = [rng.uniform(-3, 3, size=m) for m in (5, 0, 12, 2)]
    for top_k in (2, 8):
        batched = measurement_tables(detections, bearings, top_k)
        for i in range(4):
            single = measurement_table(detections[i], bearings[i], top_k)
            np.testing.assert_array_equal(batched[i], single)


# Reference encoders, one robot at a time (what the batched ones must reproduce).
def phd_table(weights: np.ndarray, means: np.ndarray, covs: np.ndarray, top_k: int) -> np.ndarray:
    """Top-K components by weight as rows ``[w, x, y, sxx, sxy, syy, 1]``, zero-padded, (K, 7)."""
    table = np.zeros((top_k, 7))
    order = np.argsort(-weights, kind="stable")[:top_k]
    n = order.size
    table[:n, 0] = weights[order]
    table[:n, 1:3] = means[order]
    table[:n, 3] = covs[order, 0, 0]
    table[:n, 4] = covs[order, 0, 1]
    table[:n, 5] = covs[order, 1, 1]
    table[:n, 6] = 1.0
    return table


def measurement_table(detections: np.ndarray, bearings: np.ndarray, top_k: int) -> np.ndarray:
    """Lidar detections (M, 2) nearest first and camera bearings (B,), padded, (2K*3,)."""
    lidar = np.zeros((top_k, 3))
    order = np.argsort(np.hypot(detections[:, 0], detections[:, 1]), kind="stable")[:top_k]
    lidar[: order.size, 0:2] = detections[order]
    lidar[: order.size, 2] = 1.0
    cam = np.zeros((top_k, 3))
    b = np.sort(bearings)[:top_k]
    cam[: b.size, 0], cam[: b.size, 1], cam[: b.size, 2] = np.cos(b), np.sin(b), 1.0
    return np.concatenate([lidar.ravel(), cam.ravel()])
