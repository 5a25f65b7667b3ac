"""The single-agent Gymnasium view: registration, Gymnasium's own checker, reproducibility,
that the teammates really are driven by the given policy and the controlled robot by the
action."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import swarm_env  # noqa: F401  (registers SwarmPHD-v0)
from swarm_env.single_agent import RandomWalkTeammates, SingleAgentEnv


def _rollout(env, seed, n=12):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for k in range(n):
        obs, reward, term, trunc, info = env.step(np.array([0.1, 0.2 * (-1) ** k], np.float32))
        out.append(obs)
    return np.stack(out), info


def test_registered_and_passes_gymnasium_env_checker():
    env = gym.make("SwarmPHD-v0", preset="lab-3m-4", max_steps=30)
    assert isinstance(env.unwrapped, SingleAgentEnv)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert "truth" in info
    env.close()


def test_same_seed_same_episode_and_seed_matters():
    env = SingleAgentEnv("lab-3m-4", max_steps=50)
    a, _ = _rollout(env, 3)
    b, _ = _rollout(env, 3)
    c, _ = _rollout(env, 4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_teammates_follow_the_given_policy_and_the_agent_the_action():
    calls = []

    def stand_still(observations, infos):
        calls.append(sorted(observations))
        return {a: np.zeros(2, np.float32) for a in observations}

    built_on = []

    def make(swarm):
        built_on.append(swarm)
        return stand_still

    env = SingleAgentEnv("lab-3m-4", agent="ugv_2", make_teammates=make, max_steps=50)
    assert built_on == [env.env]
    env.reset(seed=0)
    start = env.env.last_world_step.truth.poses.copy()
    for _ in range(15):
        env.step(np.array([0.2, 0.0], np.float32))
    end = env.env.last_world_step.truth.poses
    assert calls[0] == ["ugv_0", "ugv_1", "ugv_3"]
    moved = np.hypot(*(end[:, :2] - start[:, :2]).T)
    assert moved[2] > 0.1  # 0.2 m/s for 1.5 s, minus the acceleration ramp
    assert np.all(np.delete(moved, 2) < 0.02)  # teammates held still (contacts aside)


def test_bad_arguments_are_value_errors():
    with pytest.raises(ValueError, match="agent"):
        SingleAgentEnv("lab-3m-4", agent="ugv_9")
    with pytest.raises(ValueError, match="teammates"):
        SingleAgentEnv("lab-3m-4", teammates=42)
    with pytest.raises(ValueError, match="not both"):
        SingleAgentEnv("lab-3m-4", teammates=lambda o, i: {}, make_teammates=lambda e: None)
    env = SingleAgentEnv("lab-3m-4", teammates=lambda o, i: {}, max_steps=5)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="no action"):
        env.step(np.zeros(2, np.float32))


def test_random_walk_teammates_are_seeded_and_within_bounds():
    high = np.array([0.3, 1.5])
    walk = RandomWalkTeammates(high, switch_prob=0.5)
    obs = {f"ugv_{i}": None for i in range(3)}
    walk.reset(7)
    a = [walk(obs, {}) for _ in range(20)]
    walk.reset(7)
    b = [walk(obs, {}) for _ in range(20)]
    for x, y in zip(a, b, strict=True):
        for agent in obs:
            np.testing.assert_array_equal(x[agent], y[agent])
            assert 0.0 <= x[agent][0] <= 0.15 and abs(x[agent][1]) <= 0.75
    assert len({tuple(step["ugv_0"]) for step in a}) > 1  # it does switch
