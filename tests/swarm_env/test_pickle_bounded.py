"""The exact-pickle record is bounded: it holds the current episode only (its reset and the
commands since), however many unseeded episodes a training run has had, and an env unpickled
after many episodes continues bit for bit."""

from __future__ import annotations

import pickle

import numpy as np

from swarm_env import parallel_env


def _run_episode(env, rng, steps: int) -> None:
    for _ in range(steps):
        env.step({a: np.array([0.3, rng.uniform(-1.0, 1.0)]) for a in env.agents})


def test_the_pickle_does_not_grow_with_the_number_of_episodes():
    env = parallel_env("lab-3m-4", max_steps=1000)
    rng = np.random.default_rng(0)
    env.reset(seed=1)
    _run_episode(env, rng, 30)
    sizes = []
    for _ in range(6):  # SB3 and most trainers seed once, then reset unseeded
        env.reset()
        _run_episode(env, rng, 30)
        sizes.append(len(pickle.dumps(env)))
    assert max(sizes) - min(sizes) < 256, sizes
    kinds = [kind for kind, _ in env._replay_log]
    assert kinds[0] == "reset_from" and kinds.count("step") == 30 and len(kinds) == 31


def test_an_env_unpickled_after_many_unseeded_episodes_continues_bit_for_bit():
    env = parallel_env("lab-3m-4", task="formation", max_steps=1000)
    rng = np.random.default_rng(2)
    env.reset(seed=5)
    for _ in range(3):
        _run_episode(env, rng, 25)
        env.reset()
    _run_episode(env, rng, 10)
    clone = pickle.loads(pickle.dumps(env))
    for other in (env, clone):
        other_rng = np.random.default_rng(9)
        poses = []
        for _ in range(20):
            obs, rewards, *_ = other.step(
                {a: np.array([0.3, other_rng.uniform(-1.0, 1.0)]) for a in other.agents}
            )
            poses.append(other.last_world_step.truth.poses.copy())
        other.reset()  # the next unseeded episode too
        _run_episode(other, np.random.default_rng(4), 5)
        poses.append(other.last_world_step.truth.poses.copy())
        if other is env:
            expected = poses
    assert all(np.array_equal(a, b) for a, b in zip(expected, poses, strict=True))


def test_within_an_episode_the_record_grows_by_one_command_array_per_step():
    env = parallel_env("lab-3m-4", max_steps=1000)
    rng = np.random.default_rng(0)
    env.reset(seed=1)
    _run_episode(env, rng, 20)
    before = len(pickle.dumps(env))
    _run_episode(env, rng, 100)
    per_step = (len(pickle.dumps(env)) - before) / 100
    n = env.config.n_robots
    assert 16 * n <= per_step <= 16 * n + 48, per_step  # the float64 commands and little else
    kind, commands = env._replay_log[-1]
    assert kind == "step" and commands.shape == (n, 2) and commands.dtype == np.float64
