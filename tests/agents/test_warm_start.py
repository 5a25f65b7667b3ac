"""Warm start from a scripted controller: demonstrations, the actor fit, the CLI, the critic
warm-up (training runs only a few thousand steps)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402

from agents.policies import load_policy  # noqa: E402
from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from agents.sb3.features import NeighbourSetExtractor  # noqa: E402
from agents.sb3.warm_start import (  # noqa: E402
    Demonstrations,
    actor_mean,
    actor_parameters,
    collect_demonstrations,
    fit_actor,
    fit_report,
)
from swarm_env import parallel_env  # noqa: E402
from swarm_phd.cli import main  # noqa: E402
from tests.env_kwargs import formation_env  # noqa: E402

ENV = formation_env(60, observation="phd", task_params={"progress_weight": 10})


def _model(obs_dim_env=ENV, share=False):
    venv = BatchedSwarmVecEnv(obs_dim_env, 1, seed=0)
    model = PPO(
        "MlpPolicy",
        venv,
        device="cpu",
        seed=0,
        policy_kwargs={
            "net_arch": {"pi": [64, 64], "vf": [64, 64]},
            "share_features_extractor": share,
            "features_extractor_class": NeighbourSetExtractor,
            "features_extractor_kwargs": {"top_k": 16},
        },
    )
    return model, venv


def test_demonstrations_are_the_teachers_actions_in_unit_scale():
    torch.set_num_threads(1)
    demos = collect_demonstrations(ENV, "scripted:formation", 200, n_copies=2, seed=0)
    env = parallel_env(**ENV)
    agent = env.possible_agents[0]
    assert demos.obs.shape == (len(demos), env.observation_space(agent).shape[0])
    assert len(demos) == 25 * 8  # ceil(200 / 8 entries) steps x 8 entries
    assert np.all(np.abs(demos.actions) <= 1.0)
    # The labels are the teacher's [v, omega] over [v_max, omega_max]: a robot that sees nobody
    # wanders at cruise speed, one that sees teammates drives on the vector field; in a 3 m
    # arena both move, so labels are not all zero, and v never exceeds the teacher's limit.
    assert np.abs(demos.actions).max() > 0.1
    high = env.action_space(agent).high
    teacher = load_policy("scripted:formation", env)
    assert teacher.max_speed_mps / high[0] >= np.abs(demos.actions[:, 0]).max() - 1e-6
    with pytest.raises(ValueError, match="scripted:NAME"):
        collect_demonstrations(ENV, "random", 10)
    with pytest.raises(ValueError, match="bc steps"):
        collect_demonstrations(ENV, "scripted:formation", 0)


def test_fit_actor_reproduces_a_function_of_the_observation():
    # Labels that are an exact (smooth) function of the table: the fit must reproduce them on
    # held-out observations far better than the best constant. A broken fit (wrong parameters
    # optimised, labels misaligned, wrong extractor) fails this.
    torch.set_num_threads(1)
    model, venv = _model()
    rng = np.random.default_rng(0)
    demos = collect_demonstrations(ENV, "scripted:formation", 1200, n_copies=2, seed=1)
    obs = demos.obs
    x_first = obs[:, 1]  # x of the heaviest component (0 when nobody is estimated)
    target = np.stack([np.tanh(x_first), np.tanh(-0.5 * x_first)], axis=1).astype(np.float32)
    order = rng.permutation(len(obs))
    train, held = order[: len(obs) * 3 // 4], order[len(obs) * 3 // 4 :]
    value_before = [p.detach().clone() for p in model.policy.value_net.parameters()]
    losses = fit_actor(
        model.policy, Demonstrations(obs[train], target[train]), epochs=60, log_std=-2.0
    )
    assert losses[-1] < 0.2 * losses[0]
    report = fit_report(model.policy, Demonstrations(obs[held], target[held]))
    assert report["r2_v"] > 0.8 and report["r2_omega"] > 0.8
    assert torch.allclose(model.policy.log_std, torch.full((2,), -2.0))
    for before, after in zip(value_before, model.policy.value_net.parameters(), strict=True):
        assert torch.equal(before, after)  # only the actor moves
    venv.close()


@pytest.fixture(scope="module")
def warm_run(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("runs") / "warm"
    args = [
        "train",
        "--preset",
        "lab-3m-4",
        "--task",
        "formation",
        "--task-params",
        '{"progress_weight": 10}',
        "--observation",
        "phd",
        "--max-steps",
        "60",
        "--vec",
        "batched",
        "--n-copies",
        "1",
        "--n-steps",
        "128",
        "--batch-size",
        "256",
        "--n-epochs",
        "2",
        "--timesteps",
        "1024",
        "--warm-start",
        "scripted:formation",
        "--bc-steps",
        "2400",
        "--bc-rounds",
        "2",
        "--bc-epochs",
        "15",
        "--bc-log-std",
        "-1.2",
        "--critic-warmup",
        "100",
        "--out",
        str(out),
        "--no-progress-bar",
    ]
    assert main(args) == 0
    return out


def test_warm_start_cli_writes_the_clone_and_its_fit(warm_run):
    summary = json.loads((warm_run / "warm_start.json").read_text())
    assert summary["teacher"] == "scripted:formation" and summary["rounds"] == 2
    assert summary["transitions"] >= 2400
    fit = summary["holdout_fit"]
    # The clone beats the best constant action on held-out teacher episodes. The speed follows
    # from the PHD table; the turn rate less so (the teacher also reads its lidar and
    # random-walks when it sees nobody, neither of which is in the observation).
    assert fit["r2_v"] > 0.3
    assert fit["rmse_v"] < fit["baseline_rmse_v"]
    config = json.loads((warm_run / "train_config.json").read_text())
    assert config["warm_start"]["teacher"] == "scripted:formation"
    assert config["policy_kwargs"]["share_features_extractor"] is False


def test_critic_warmup_keeps_the_cloned_actor_and_the_models_load(warm_run):
    # 1024 steps = 2 rollouts, all within the 100-rollout critic warm-up: the final actor is
    # exactly the clone, and the value function did train.
    clone = PPO.load(warm_run / "warm_start.zip", device="cpu")
    final = PPO.load(warm_run / "model.zip", device="cpu")
    for a, b in zip(actor_parameters(clone.policy), actor_parameters(final.policy), strict=True):
        assert torch.equal(a, b)
    assert any(
        not torch.equal(a, b)
        for a, b in zip(
            clone.policy.value_net.parameters(), final.policy.value_net.parameters(), strict=True
        )
    )
    assert all(p.requires_grad for p in actor_parameters(final.policy))
    # Both zips are swarm policies: deterministic actions are the clipped actor mean.
    env = parallel_env(**ENV)
    obs, infos = env.reset(seed=100)
    policy = load_policy(str(warm_run / "warm_start.zip"), env)
    actions = policy(obs, infos)
    batch = torch.as_tensor(np.stack([obs[a] for a in env.agents]))
    with torch.no_grad():
        mu = actor_mean(clone.policy, batch).numpy()
    high = env.action_space(env.possible_agents[0]).high
    np.testing.assert_allclose(
        np.stack([actions[a] for a in env.agents]), np.clip(mu, -1, 1) * high, atol=1e-5
    )


def test_bad_warm_start_arguments_are_rejected(tmp_path, capsys):
    base = ["train", "--preset", "lab-3m-4", "--out", str(tmp_path / "x"), "--timesteps", "10"]
    for extra, field in (
        (["--warm-start", "random"], "--warm-start"),
        (["--warm-start", "scripted:formation", "--bc-steps", "0"], "--bc-steps"),
        (["--critic-warmup", "-1"], "--critic-warmup"),
    ):
        assert main([*base, *extra]) == 2
        assert field in capsys.readouterr().err
    assert not (tmp_path / "x" / "model.zip").exists()


def test_bad_ppo_clip_and_kl_flags_are_rejected(tmp_path, capsys):
    base = ["train", "--preset", "lab-3m-4", "--out", str(tmp_path / "x"), "--timesteps", "10"]
    for flag in ("--clip-range", "--target-kl"):
        for value in ("0", "-0.1", "nan", "inf"):
            assert main([*base, flag, value]) == 2
            err = capsys.readouterr().err
            assert flag in err and value in err
    assert not (tmp_path / "x").exists()


def test_interrupt_during_the_warm_start_saves_a_usable_model(tmp_path, monkeypatch):
    # Ctrl-C while the actor is being fitted (the handler turns it into KeyboardInterrupt):
    # the run still saves model.zip, says so, and exits with 130.
    import agents.sb3.warm_start as ws

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(ws, "fit_actor", interrupted)
    out = tmp_path / "cut"
    args = ["train", "--preset", "lab-3m-4", "--max-steps", "20", "--vec", "batched"]
    args += ["--n-copies", "1", "--timesteps", "256", "--warm-start", "scripted:formation"]
    args += ["--bc-steps", "40", "--task", "formation", "--out", str(out), "--no-progress-bar"]
    assert main(args) == 130
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["interrupted"] == "SIGINT" and summary["timesteps"] == 0
    env = parallel_env(**{**ENV, "max_steps": 20})
    obs, infos = env.reset(seed=0)
    actions = load_policy(str(out / "model.zip"), env)(obs, infos)
    assert set(actions) == set(env.agents)
