"""The centralised critic (agents.sb3.central_critic): what it reads, and what the actor cannot."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch  # noqa: E402

from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from agents.sb3.central_critic import (  # noqa: E402
    CentralCriticPolicy,
    critic_state,
    critic_state_dims,
)
from swarm_core.world import truth_from_poses  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from swarm_env.tasks.formation import FormationTask  # noqa: E402
from tests.agents.test_residual import (  # noqa: E402
    KWARGS,
    assert_drives_like_scripted,
    train_frozen_residual,
)


def test_critic_state_by_hand():
    """Three robots: robot 0 at the origin facing +y, 1 at (1, 0), 2 at (0, 2). In robot 0's
    frame (x forward = world +y, y left = world -x): robot 2 at (2, 0) and robot 1 at (0, -1),
    nearest first. Centroid (1/3, 2/3): shape error |sqrt(5)/3 - 0.8|, body (2/3, -1/3)."""
    poses = np.array([[0.0, 0.0, np.pi / 2], [1.0, 0.0, 0.0], [0.0, 2.0, np.pi]])
    truth = truth_from_poses(poses, 2.0, 2.0)
    task = FormationTask(shape="circle", radius_m=0.8)
    block = critic_state(truth, task, 3)
    assert block.shape == (3, critic_state_dims(3, task)) == (3, 8)
    np.testing.assert_allclose(block[0, :4], [0.0, -1.0, 2.0, 0.0], atol=1e-6)
    chord = 2 * 0.8 * np.sin(np.pi / 3)
    np.testing.assert_allclose(
        block[0, 4:], [abs(np.sqrt(5) / 3 - 0.8), abs(1.0 - chord), 2 / 3, -1 / 3], atol=1e-6
    )
    # Robot 2 faces -x: the world offsets (0, -2) to robot 0 and (1, -2) to robot 1 turn by
    # -pi into (0, 2) and (-1, 2); distances 2 and sqrt(5), so robot 0 first.
    np.testing.assert_allclose(block[2, :4], [0.0, 2.0, -1.0, 2.0], atol=1e-6)
    lattice = FormationTask(shape="lattice", spacing_m=1.0)
    assert critic_state(truth, lattice, 3).shape == (3, critic_state_dims(3, lattice)) == (3, 5)


def _policy(critic_dims: int):
    """A CentralCriticPolicy for KWARGS' observation plus a ``critic_dims`` block."""
    import gymnasium as gym

    env_space = parallel_env(**KWARGS).observation_space("ugv_0")
    space = gym.spaces.Box(
        np.concatenate([env_space.low, np.full(critic_dims, -np.inf, np.float32)]),
        np.concatenate([env_space.high, np.full(critic_dims, np.inf, np.float32)]),
    )
    action = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    return CentralCriticPolicy(space, action, lambda _: 1e-3, critic_dims=critic_dims, top_k=16)


def test_the_actor_ignores_the_critic_block_and_the_critic_reads_it():
    env = parallel_env(**KWARGS)
    d = env.observation_space("ugv_0").shape[0]
    policy = _policy(6)
    rng = np.random.default_rng(0)
    obs = np.zeros((5, d + 6), np.float32)
    obs[:, :d] = np.stack([env.observation_space("ugv_0").sample() for _ in range(5)])
    other = obs.copy()
    other[:, d:] = rng.normal(size=(5, 6))
    with torch.no_grad():
        dists = [policy.get_distribution(torch.as_tensor(o)) for o in (obs, other)]
        mean = [dist.distribution.mean for dist in dists]
        value = [policy.predict_values(torch.as_tensor(o)) for o in (obs, other)]
    torch.testing.assert_close(mean[0], mean[1], rtol=0, atol=0)
    assert not torch.allclose(value[0], value[1])
    # Separate extractors, and the critic's sees more.
    assert policy.pi_features_extractor is not policy.vf_features_extractor
    assert policy.vf_features_extractor.features_dim > policy.pi_features_extractor.features_dim
    with pytest.raises(ValueError, match="critic_dims"):
        _policy(0)


def test_batched_env_appends_the_true_state_and_keeps_the_rollout():
    """The first D entries are the plain batched env's, bit for bit, under the same actions;
    the block is the copy's truth."""
    plain = BatchedSwarmVecEnv(KWARGS, 2, seed=5)
    central = BatchedSwarmVecEnv(KWARGS, 2, seed=5, critic_state=True)
    d = plain.observation_space.shape[0]
    p = central.critic_dims
    assert p == critic_state_dims(4, central.envs[0].task) == 2 * 3 + 4
    assert central.observation_space.shape == (d + p,)
    a, b = plain.reset(), central.reset()
    stepped = {}  # copy -> truth of its last step, kept past the auto-reset

    def recording(k, env):
        finish = env.finish_step

        def finish_step():
            out = finish()
            stepped[k] = env.last_world_step.truth
            return out

        return finish_step

    for k, env in enumerate(central.envs):
        env.finish_step = recording(k, env)
    rng = np.random.default_rng(1)
    for t in range(18):  # across the auto-reset at max_steps 15
        np.testing.assert_array_equal(a, b[:, :d], err_msg=f"t={t}")
        for k, env in enumerate(central.envs):
            want = critic_state(env.last_world_step.truth, env.task, 4)
            np.testing.assert_array_equal(b[4 * k : 4 * k + 4, d:], want)
        actions = rng.uniform(-1, 1, (plain.num_envs, 2)).astype(np.float32)
        a, _, done_a, info_a = plain.step(actions)
        b, _, done_b, info_b = central.step(actions)
        np.testing.assert_array_equal(done_a, done_b)
        if done_b.any():  # the terminal block is the last step's truth, not the reset's
            term = info_b[0]["terminal_observation"]
            assert term.shape == (d + p,)
            np.testing.assert_array_equal(term[:d], info_a[0]["terminal_observation"])
            last = critic_state(stepped[0], central.envs[0].task, 4)[0]
            np.testing.assert_array_equal(term[d:], last)
            assert not np.array_equal(term[d:], b[0, d:])
    plain.close()
    central.close()


def test_train_with_a_central_critic_saves_a_policy_that_runs_without_truth(tmp_path):
    """`swarm-phd train --critic-state --residual-observes-base`: the zip records both; the
    loaded policy appends the scripted command and pads zeros for the block, so it runs on the
    plain env (and a real robot). The actor is frozen during the critic warm-up, so it is
    still the scripted controller: same commands."""
    from agents.policies import load_policy
    from agents.sb3.policy import read_metadata

    path = train_frozen_residual(tmp_path / "run", critic_state=True, residual_observes_base=True)
    meta = read_metadata(path)
    assert meta["critic_dims"] == 10 and meta["residual_observes_base"]
    config = json.loads((tmp_path / "run" / "train_config.json").read_text())
    assert config["critic_state"] and config["residual_observes_base"]
    policy = load_policy(str(path), parallel_env(**KWARGS))
    assert type(policy.model.policy).__name__ == "CentralCriticPolicy"
    d = parallel_env(**KWARGS).observation_space("ugv_0").shape[0]
    assert policy.model.observation_space.shape[0] == d + 2 + 10
    env, obs, infos = assert_drives_like_scripted(policy, steps=6)
    scripted = load_policy("scripted:formation", env)
    # A correction that reads its inputs: the deployed policy feeds the actor [obs | command /
    # high | zeros], in that order.
    from agents.sb3.residual import base_in_unit_scale, compose

    torch.manual_seed(0)
    with torch.no_grad():
        policy.model.policy.action_net.weight.normal_(0.0, 0.5)
    scripted.reset(7)
    policy.reset(7)
    base = scripted(obs, infos)
    agents = list(obs)
    manual = np.concatenate(
        [
            np.stack([obs[a] for a in agents]),
            base_in_unit_scale([base[a] for a in agents], policy.action_high),
            np.zeros((len(agents), 10), np.float32),
        ],
        axis=1,
    )
    correction, _ = policy.model.predict(manual.astype(np.float32), deterministic=True)
    actions = policy(obs, infos)
    assert np.abs(correction).max() > 1e-3
    for k, agent in enumerate(agents):
        want = compose(base[agent], correction[k], policy.action_high)
        np.testing.assert_allclose(actions[agent], want, atol=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"vec": "supersuit"}, "batched"),
        ({"extractor": "mlp"}, "extractor sets"),
        ({"warm_start": {"teacher": "scripted:formation", "steps": 10}}, "warm-start"),
        ({"critic_state": False, "residual_observes_base": True}, "needs --residual"),
    ],
)
def test_critic_state_refuses_what_it_cannot_serve(tmp_path, kwargs, match):
    from agents.sb3.train import train

    with pytest.raises(ValueError, match=match):
        train(
            KWARGS, 64, tmp_path / "a", **{"critic_state": True, "progress_bar": False, **kwargs}
        )
    assert not (tmp_path / "a").exists()  # refused before the run directory is written
