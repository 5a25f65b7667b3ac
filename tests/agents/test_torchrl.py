"""The swarm under TorchRL: ``PettingZooWrapper`` with every robot in one group, its specs and
a rollout, and a short MAPPO run with TorchRL's own modules and loss."""

from __future__ import annotations

import math

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from agents.torchrl_env import GROUP, make_torchrl_env  # noqa: E402
from agents.torchrl_ppo import build_modules, train_ppo  # noqa: E402


def test_specs_and_rollout_of_the_grouped_swarm():
    env = make_torchrl_env("lab-3m-4", "formation", max_steps=5, seed=0)
    assert env.group_map == {GROUP: ["ugv_0", "ugv_1", "ugv_2", "ugv_3"]}
    check_env_specs(env)
    td = env.rollout(8, break_when_any_done=False)  # one truncation, then a reset
    obs_dim = env.observation_spec[GROUP, "observation"].shape[-1]
    assert td[GROUP, "observation"].shape == (8, 4, obs_dim)
    assert td["state"].shape == (8, 4 * 6)
    action = td[GROUP, "action"]
    high = torch.as_tensor([0.3, 1.5])
    assert action.shape == (8, 4, 2) and bool((action.abs() <= high + 1e-6).all())
    done = td["next", "done"].squeeze(-1)
    assert done.tolist() == [False] * 4 + [True] + [False] * 3  # max_steps = 5
    assert bool(td["next", GROUP, "truncated"][4].all())
    times = td["next", GROUP, "info", "time_s"][:, 0]
    assert times[4] == pytest.approx(0.5) and times[5] == pytest.approx(0.1)  # a new episode
    rewards = td["next", GROUP, "reward"]
    assert rewards.shape == (8, 4, 1) and bool(torch.isfinite(rewards).all())
    env.close()


def test_mappo_critic_sees_every_robot_and_ippo_only_its_own():
    env = make_torchrl_env("lab-3m-4", "formation", max_steps=5, seed=0)
    td = env.reset()
    other = td.clone()
    other[GROUP, "observation"][1:] += 1.0  # every robot's observation but ugv_0's
    for mappo in (True, False):
        torch.manual_seed(0)
        _, critic = build_modules(env, mappo=mappo)
        v = critic(td.clone())[GROUP, "state_value"]
        v_other = critic(other.clone())[GROUP, "state_value"]
        assert v.shape == (4, 1)
        assert bool(v[0] != v_other[0]) is mappo  # ugv_0's value reads the others (MAPPO)
    env.close()


def test_bad_budgets_are_refused():
    env = make_torchrl_env("lab-3m-4", "formation", max_steps=5)
    with pytest.raises(ValueError, match=r"total_frames \(50\) must be at least frames_per_batch"):
        train_ppo(env, total_frames=50, frames_per_batch=100)
    with pytest.raises(ValueError, match=r"minibatch_size \(30\) must divide frames_per_batch"):
        train_ppo(env, total_frames=100, frames_per_batch=100, minibatch_size=30)
    with pytest.raises(ValueError, match="epochs must be an integer >= 1, got 0"):
        train_ppo(env, total_frames=100, frames_per_batch=100, epochs=0)
    env.close()


@pytest.mark.slow
def test_short_mappo_run_updates_the_shared_policy():
    env = make_torchrl_env("lab-3m-4", "formation", max_steps=50, seed=0)
    torch.manual_seed(0)
    before, _ = build_modules(env, mappo=True)  # the same initial weights (seed 0)
    initial = [p.detach().clone() for p in before.parameters()]
    result = train_ppo(
        env, total_frames=200, frames_per_batch=100, minibatch_size=50, epochs=2, seed=0
    )
    assert [row["frames"] for row in result.log] == [100.0, 200.0]
    for row in result.log:
        assert all(math.isfinite(row[k]) for k in ("loss_objective", "loss_critic"))
        assert math.isfinite(row["episode_reward_mean"])  # 50-step episodes end in a batch
    trained = list(result.policy.parameters())
    assert [p.shape for p in trained] == [p.shape for p in initial]
    assert any(not torch.equal(a, b) for a, b in zip(trained, initial, strict=True))
    fresh = make_torchrl_env("lab-3m-4", "formation", max_steps=50, seed=1)
    td = fresh.rollout(5, policy=result.policy)
    assert td[GROUP, "action"].shape == (5, 4, 2)
    fresh.close()
