"""Recurrent PPO (``swarm-phd train --recurrent``): training, saving, and deployment with each
agent's LSTM memory carried between steps."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("sb3_contrib")

from agents.policies import load_policy  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from tests.agents.test_residual import (  # noqa: E402
    KWARGS,
    assert_drives_like_scripted,
    train_tiny,
)


def train_recurrent(out, **train_kwargs):
    return train_tiny(out, **{"lstm_hidden": 8, **train_kwargs})


@pytest.fixture(scope="module")
def recurrent_model(tmp_path_factory):
    return train_recurrent(tmp_path_factory.mktemp("recurrent") / "run")


def test_recurrent_model_is_saved_with_its_kind(recurrent_model):
    from sb3_contrib import RecurrentPPO

    from agents.sb3.policy import load_sb3_policy, read_metadata

    assert read_metadata(recurrent_model)["recurrent"] is True
    config = json.loads((recurrent_model.parent / "train_config.json").read_text())
    assert config["recurrent"] is True
    policy = load_sb3_policy(recurrent_model, parallel_env(**KWARGS))
    # Rebuilt from the run's JSON and loaded weights-only (agents.sb3.safe_load).
    assert isinstance(policy.model.policy, RecurrentPPO.policy_aliases["MlpLstmPolicy"])
    assert policy.model.policy.lstm_actor.hidden_size == 8


def test_deployment_carries_each_agents_memory_as_sb3_does(recurrent_model):
    """The deployed policy's actions equal RecurrentPPO's own batched predict with the state
    threaded through the episode, and the memory matters: the same observations from a
    cleared memory give other actions. reset() clears it."""
    policy = load_policy(str(recurrent_model), parallel_env(**KWARGS))
    model = policy.model
    env = parallel_env(**KWARGS)
    policy.reset(3)
    obs, infos = env.reset(seed=3)
    agents = list(obs)
    state, start = None, np.ones(len(agents), bool)
    history = []
    for _ in range(6):
        batch = policy.normalize(np.stack([obs[a] for a in agents]))
        want, state = model.predict(batch, state=state, episode_start=start, deterministic=True)
        start = np.zeros(len(agents), bool)
        got = policy(obs, infos)
        for k, a in enumerate(agents):
            np.testing.assert_allclose(got[a], want[k] * policy.action_high, atol=1e-6)
        history.append((obs, infos, got))
        obs, _, _, _, infos = env.step(got)
    # Memory matters: the last observations again, from a cleared memory, act differently.
    last_obs, last_infos, last_actions = history[-1]
    policy.reset(3)
    fresh = policy(last_obs, last_infos)
    assert any(not np.allclose(fresh[a], last_actions[a]) for a in agents)
    # ... and a cleared memory acts as at the episode's first step.
    policy.reset(3)
    first = policy(*history[0][:2])
    for a in agents:
        np.testing.assert_allclose(first[a], history[0][2][a], atol=0)


def test_an_agent_leaving_keeps_the_others_memory(recurrent_model):
    """Memory is kept by agent name: calling with a subset of agents gives each the action
    its own state gives, whatever the others do."""
    env = parallel_env(**KWARGS)
    full = load_policy(str(recurrent_model), env)
    part = load_policy(str(recurrent_model), env)
    obs, infos = env.reset(seed=5)
    part.reset(5)
    part(obs, infos)
    full.reset(5)
    obs, _, _, _, infos = env.step(full(obs, infos))
    a, b = full(obs, infos), part({k: obs[k] for k in list(obs)[1:]}, infos)
    for agent in list(obs)[1:]:
        np.testing.assert_allclose(b[agent], a[agent], atol=1e-6)


def test_recurrent_residual_starts_as_the_scripted_controller(tmp_path):
    """With --residual the LSTM's correction starts at 0 too (the action head is zeroed), so
    an actor frozen by the critic warm-up, LSTM included, is the scripted controller."""
    path = train_recurrent(tmp_path / "run", residual="scripted:formation", critic_warmup=5)
    learned = load_policy(str(path), parallel_env(**KWARGS))
    assert learned.recurrent and learned.base is not None
    assert_drives_like_scripted(learned)


@pytest.mark.parametrize(
    ("extra", "flag"),
    [
        ({"critic_state": True}, "--critic-state"),
        ({"warm_start": {"teacher": "scripted:formation", "steps": 64}}, "--warm-start"),
        ({"lstm_hidden": 0}, "--lstm-hidden"),
    ],
)
def test_recurrent_refusals_leave_no_run_directory(tmp_path, extra, flag):
    with pytest.raises(ValueError, match=flag):
        train_recurrent(tmp_path / "run", **extra)
    assert not (tmp_path / "run").exists()


def test_cli_refuses_lstm_size_without_recurrent_and_sb3_flags_on_rllib(tmp_path, capsys):
    """``--lstm-hidden`` alone and ``--recurrent`` (or another SB3-only flag) with ``--engine
    rllib`` are refused with the flag named, before a run directory is written."""
    from swarm_phd.cli import main

    base = ["train", "--preset", "lab-3m-4", "--task", "formation", "--timesteps", "64"]
    out = tmp_path / "run"
    assert main([*base, "--lstm-hidden", "32", "--out", str(out)]) == 2
    assert "--lstm-hidden 32 needs --recurrent" in capsys.readouterr().err
    assert main([*base, "--engine", "rllib", "--recurrent", "--out", str(out)]) == 2
    assert "--recurrent are SB3-only" in capsys.readouterr().err
    assert not out.exists()


def test_critic_warmup_freezes_the_actors_lstm(recurrent_model):
    """The critic warm-up freezes ``actor_parameters``: for a recurrent policy that list holds
    the actor's LSTM, and not the critic's."""
    from agents.sb3.warm_start import actor_parameters

    policy = load_policy(str(recurrent_model), parallel_env(**KWARGS)).model.policy
    frozen = {id(p) for p in actor_parameters(policy)}
    assert all(id(p) in frozen for p in policy.lstm_actor.parameters())
    assert not any(id(p) in frozen for p in policy.lstm_critic.parameters())
