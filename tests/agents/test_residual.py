"""Residual policies (scripted controller + learned correction, agents.sb3.residual)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.policies import load_policy  # noqa: E402
from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from agents.sb3.residual import check_residual, compose  # noqa: E402
from swarm_env import parallel_env  # noqa: E402

KWARGS = {
    "preset": "lab-3m-4",
    "task": "formation",
    "task_params": {"progress_weight": 10},
    "max_steps": 15,
    "lidar_sectors": 8,
}


def test_compose_adds_and_clips():
    high = np.array([0.3, 1.5])
    base = np.array([[0.15, -0.3], [0.27, 1.5], [-0.3, 0.0]])  # env units
    corr = np.array([[0.1, 0.1], [0.5, -3.0], [-0.5, 2.0]])  # unit scale
    np.testing.assert_allclose(
        compose(base, corr, high), [[0.18, -0.15], [0.3, 0.0], [-0.3, 1.5]], rtol=1e-6
    )
    # A zero correction is the base command bit for bit.
    b32 = np.array([[0.123456, -0.987654]], np.float32)
    np.testing.assert_array_equal(compose(b32, np.zeros((1, 2)), high), b32)


def test_bad_residual_names_are_refused():
    for bad in ("formation", "scripted:nope", None, 3):
        with pytest.raises(ValueError, match="residual"):
            check_residual(bad)


@pytest.mark.parametrize("observes_base", [False, True])
def test_zero_correction_in_the_batched_env_is_the_scripted_controller(observes_base):
    """With a zero correction every copy moves exactly as the scripted controller drives the
    same env alone (same seeds, the base reseeded the same way), across an auto-reset; with
    ``residual_observes_base`` the two extra entries are that controller's command / high."""
    vec = BatchedSwarmVecEnv(
        KWARGS, 2, seed=3, residual="scripted:formation", residual_observes_base=observes_base
    )
    n = vec.agents_per_copy
    d = parallel_env(**KWARGS).observation_space("ugv_0").shape[0]
    assert vec.observation_space.shape == (d + 2 * observes_base,)
    obs = vec.reset()
    lone = []
    for k in range(2):
        env = parallel_env(**KWARGS)
        policy = load_policy("scripted:formation", env)
        policy.reset(3 + k)
        o, i = env.reset(seed=3 + k)
        lone.append([env, policy, o, i])
    high = vec.action_high
    for t in range(20):  # max_steps 15: the second episode's base is reseeded
        commands = []
        for k, (env, policy, o, i) in enumerate(lone):
            want = np.stack([o[a] for a in env.possible_agents])
            rows = obs[k * n : (k + 1) * n]
            np.testing.assert_array_equal(rows[:, :d], want, err_msg=f"t={t}")
            commands.append(policy(o, i))
            if observes_base:
                unit = np.stack([commands[k][a] for a in env.possible_agents]) / high
                np.testing.assert_allclose(rows[:, d:], unit, rtol=1e-6, err_msg=f"t={t}")
        obs, _, dones, _ = vec.step(np.zeros((vec.num_envs, 2), np.float32))
        for k, entry in enumerate(lone):
            env, policy, o, i = entry
            o, _, _, _, i = env.step(commands[k])
            if not env.agents:
                assert dones[k * n : (k + 1) * n].all()
                seed = 1_000_003 * (3 + 1) + 1009 * k + 1  # the copy's second episode
                policy.reset(seed)
                o, i = env.reset(seed=None)
            entry[2], entry[3] = o, i
    vec.close()


def train_tiny(out, **train_kwargs):
    """Two PPO updates of 2 batched copies on ``KWARGS`` (a few seconds)."""
    from agents.sb3.train import train

    return train(
        KWARGS,
        2 * 4 * 32 * 2,
        out,
        n_copies=2,
        vec="batched",
        progress_bar=False,
        ppo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1},
        checkpoint_every=10_000,
        **train_kwargs,
    )


def train_frozen_residual(out, **train_kwargs):
    """A tiny residual run whose actor never leaves the critic warm-up: the scripted
    controller in a model zip."""
    return train_tiny(
        out, **{"critic_warmup": 5, "residual": "scripted:formation", **train_kwargs}
    )


def assert_drives_like_scripted(policy, seed: int = 100, steps: int = 12):
    """``policy`` gives the scripted formation controller's commands on a held-out seed;
    returns the env and the last (obs, infos)."""
    env = parallel_env(**KWARGS)
    scripted = load_policy("scripted:formation", parallel_env(**KWARGS))
    policy.reset(seed)
    scripted.reset(seed)
    obs, infos = env.reset(seed=seed)
    for _ in range(steps):
        actions, want = policy(obs, infos), scripted(obs, infos)
        for agent in obs:
            np.testing.assert_allclose(actions[agent], want[agent], atol=1e-6)
        obs, _, _, _, infos = env.step(actions)
    return env, obs, infos


def test_train_residual_saves_a_model_that_starts_as_the_scripted_controller(tmp_path):
    """`swarm-phd train --residual`: the correction's mean starts at 0; while the critic warms
    up the actor does not move, so the saved deterministic policy *is* the scripted controller
    (same actions on a held-out seed); the zip says it is a residual."""
    from agents.sb3.policy import load_sb3_policy, read_metadata

    path = train_frozen_residual(tmp_path / "run", residual_log_std=-2.0)
    meta = read_metadata(path)
    assert meta["residual"] == "scripted:formation"
    config = json.loads((tmp_path / "run" / "train_config.json").read_text())
    assert config["residual"] == "scripted:formation"
    learned = load_sb3_policy(path, parallel_env(**KWARGS))
    assert learned.base is not None
    np.testing.assert_allclose(learned.model.policy.log_std.detach().numpy(), -2.0, rtol=0, atol=0)
    assert_drives_like_scripted(learned)
    # The one-table scorer: same motion, so the same task and localization metrics.
    from agents.sb3.localization_table import main

    out = tmp_path / "table"
    assert (
        main(
            [
                "--policies",
                str(path),
                "scripted:formation",
                "--seeds",
                "100",
                "--out",
                str(out),
                "--name",
                "t",
            ]
        )
        == 0
    )
    table = json.loads((out / "results_t.json").read_text())
    rows = table["rows"]
    # Paired by seed: the task metric and each localization figure, model - scripted = 0.
    assert set(table["paired"]) == {
        "formation_error_m",
        "phd-lc gospa_m",
        "phd-lc pct_above_0.30m",
    }
    for pairs in table["paired"].values():
        assert [(p["policy"], p["baseline"]) for p in pairs] == [("scripted:formation", str(path))]
        assert pairs[0]["mean_difference"] == 0.0
    assert rows[0]["formation_error_m"] == rows[1]["formation_error_m"]
    assert rows[0]["formation_error_m"][0] == rows[0]["formation_error_m_evaluate"]
    assert rows[0]["localizers"] == rows[1]["localizers"]
    assert "| scripted:formation |" in (out / "results_t.md").read_text()


def test_residual_refuses_supersuit(tmp_path):
    from agents.sb3.train import train

    with pytest.raises(ValueError, match="batched"):
        train(
            KWARGS,
            64,
            tmp_path / "b",
            vec="supersuit",
            residual="scripted:formation",
            progress_bar=False,
        )
