"""The batched SB3 VecEnv: K env copies sharing one localizer call per step."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from gymnasium.utils.env_checker import data_equivalence  # noqa: E402

from agents.sb3.adapter import scale_actions  # noqa: E402
from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from swarm_env import parallel_env  # noqa: E402

KWARGS = {"preset": "lab-3m-4", "task": "formation", "max_steps": 12}


@pytest.mark.parametrize("localizer", [None, "id-phd", "ukf", "pf"])
def test_batched_copies_equal_lone_envs_bit_for_bit(localizer):
    """Each copy of the batch gives exactly what the same env run alone gives (same seed,
    same actions): sharing the localizer call changes nothing per robot. The identity families
    (``id-phd``, ``ukf``, ``pf``) cannot be shared: each copy keeps its own localizer, with the
    same result."""
    kwargs = KWARGS if localizer is None else {**KWARGS, "localizer": localizer}
    k_copies, steps = 3, 20  # crosses an episode end (max_steps 12): auto-reset included
    vec = BatchedSwarmVecEnv(kwargs, k_copies, seed=7)
    assert (vec.shared is None) == (localizer is not None)
    n = vec.agents_per_copy
    lone = [parallel_env(**kwargs) for _ in range(k_copies)]
    first = [env.reset(seed=7 + k) for k, env in enumerate(lone)]
    lone_obs, lone_infos = [o for o, _ in first], [i for _, i in first]
    obs = vec.reset()
    rng = np.random.default_rng(0)
    # As TrainingWrapper: the policy's [-1, 1] scaled by the (float32) action-space bounds.
    high = np.array(lone[0].action_space("ugv_0").high, dtype=np.float64)
    for t in range(steps):
        for k, env in enumerate(lone):
            expected = np.stack([lone_obs[k][a] for a in env.possible_agents])
            np.testing.assert_array_equal(obs[k * n : (k + 1) * n], expected, err_msg=f"t={t}")
            # The copy's infos (what a teacher reads) are the lone env's for the same obs, as
            # plain dicts (the env builds each agent's on first read).
            plain = {a: dict(info.items()) for a, info in lone_infos[k].items()}
            assert data_equivalence(vec.copy_infos(k), plain), f"t={t}, copy {k}"
        actions = rng.uniform(-1, 1, (vec.num_envs, 2)).astype(np.float32)
        obs, rewards, dones, infos = vec.step(actions)
        for k, env in enumerate(lone):
            cmds = {
                a: scale_actions(actions[k * n + i], high)
                for i, a in enumerate(env.possible_agents)
            }
            o, r, term, trunc, lone_infos[k] = env.step(cmds)
            for i, a in enumerate(env.possible_agents):
                assert rewards[k * n + i] == np.float32(r[a])
                assert dones[k * n + i] == (term[a] or trunc[a])
            if not env.agents:
                for i, a in enumerate(env.possible_agents):
                    np.testing.assert_array_equal(infos[k * n + i]["terminal_observation"], o[a])
                    assert infos[k * n + i]["TimeLimit.truncated"] is True
                o, lone_infos[k] = env.reset()
            lone_obs[k] = o
    vec.close()


def test_ppo_learns_a_few_steps_on_the_batched_env(tmp_path):
    from stable_baselines3 import PPO

    from agents.sb3.batched import make_batched_vec_env

    vec = make_batched_vec_env(KWARGS, n_copies=2, seed=0)
    model = PPO("MlpPolicy", vec, n_steps=16, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=2 * 4 * 16 * 2)
    model.save(tmp_path / "model.zip")
    assert (tmp_path / "model.zip").exists()
    vec.close()


def test_bad_copy_count():
    with pytest.raises(ValueError, match="n_copies"):
        BatchedSwarmVecEnv(KWARGS, 0)
