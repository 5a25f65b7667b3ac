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
from tests.env_kwargs import formation_env  # noqa: E402

KWARGS = formation_env(15, task_params={"progress_weight": 10}, lidar_sectors=8)


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


def test_compose_gain_scales_each_command_and_clips():
    """``mode="gain"``: ``base * 4 ** clip(correction, -1, 1)`` per axis, then the bounds."""
    high = np.array([0.3, 1.5])
    base = np.array([[0.1, -0.5], [0.2, 1.0], [0.0, 0.4], [-0.12, 0.9]])
    corr = np.array([[0.5, -0.5], [1.0, 1.0], [1.0, -3.0], [-1.0, 0.0]])
    np.testing.assert_allclose(
        compose(base, corr, high, "gain"),
        # x2 and /2; x4 clipped to the bounds; zero stays zero, the -3 is clipped to -1 (/4);
        # /4 on a negative speed.
        [[0.2, -0.25], [0.3, 1.5], [0.0, 0.1], [-0.03, 0.9]],
        rtol=1e-6,
    )
    b32 = np.array([[0.123456, -0.987654]], np.float32)
    np.testing.assert_array_equal(compose(b32, np.zeros((1, 2)), high, "gain"), b32)
    with pytest.raises(ValueError, match="residual-mode.*'scale'"):
        compose(base, corr, high, "scale")


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
    assert_batched_copies_drive_as_alone(vec, np.zeros(2), lambda command: command)


def test_gain_mode_in_the_batched_env_scales_the_scripted_command():
    """``residual_mode="gain"``: a constant correction ``[0.5, -0.5]`` sends the scripted
    command with its speed doubled and its turn rate halved (``4 ** 0.5 = 2``), clipped to the
    action bounds: every copy moves as the env alone driven by that rescaled command."""
    vec = BatchedSwarmVecEnv(
        KWARGS, 2, seed=3, residual="scripted:formation", residual_mode="gain"
    )
    high = vec.action_high

    def rescaled(command):
        return np.clip(np.asarray(command, np.float64) * [2.0, 0.5], -high, high).astype(
            np.float32
        )

    assert_batched_copies_drive_as_alone(vec, np.array([0.5, -0.5]), rescaled)


def assert_batched_copies_drive_as_alone(vec, correction, lone_command):
    """Step the 2-copy residual ``vec`` (seed 3) with ``correction`` for every agent for 20
    steps (across the auto-reset at ``max_steps`` 15) beside each copy's env run alone with
    ``lone_command(scripted command)``: the observations must agree bit for bit."""
    n = vec.agents_per_copy
    d = parallel_env(**KWARGS).observation_space("ugv_0").shape[0]
    assert vec.observation_space.shape == (d + vec.base_dims,)
    obs = vec.reset()
    lone = []
    for k in range(2):
        env = parallel_env(**KWARGS)
        policy = load_policy("scripted:formation", env)
        policy.reset(3 + k)
        o, i = env.reset(seed=3 + k)
        lone.append([env, policy, o, i])
    high = vec.action_high
    actions = np.tile(np.asarray(correction, np.float32), (vec.num_envs, 1))
    for t in range(20):  # max_steps 15: the second episode's base is reseeded
        commands = []
        for k, (env, policy, o, i) in enumerate(lone):
            want = np.stack([o[a] for a in env.possible_agents])
            rows = obs[k * n : (k + 1) * n]
            np.testing.assert_array_equal(rows[:, :d], want, err_msg=f"t={t}")
            commands.append(policy(o, i))
            if vec.base_dims:
                unit = np.stack([commands[k][a] for a in env.possible_agents]) / high
                np.testing.assert_allclose(rows[:, d:], unit, rtol=1e-6, err_msg=f"t={t}")
        obs, _, dones, _ = vec.step(actions)
        for k, entry in enumerate(lone):
            env, policy, o, i = entry
            o, _, _, _, i = env.step({a: lone_command(c) for a, c in commands[k].items()})
            if not env.agents:
                assert dones[k * n : (k + 1) * n].all()
                seed = 1_000_003 * (3 + 1) + 1009 * k + 1  # the copy's second episode
                policy.reset(seed)
                o, i = env.reset(seed=None)
            entry[2], entry[3] = o, i
    vec.close()


def train_tiny(out, sde=False, **train_kwargs):
    """Two PPO updates of 2 batched copies on ``KWARGS`` (a few seconds); ``sde``: gSDE."""
    from agents.sb3.train import train

    return train(
        KWARGS,
        2 * 4 * 32 * 2,
        out,
        n_copies=2,
        vec="batched",
        progress_bar=False,
        ppo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1, "use_sde": sde},
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
    from experiments.localization_table import main

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


def test_gain_mode_model_zip_scales_the_scripted_command(tmp_path, monkeypatch):
    """A ``--residual-mode gain`` model says so in its zip, and the evaluated policy applies
    the gain: with its correction's mean set to ``[0.5, 0]`` it sends the scripted command
    with the speed doubled (clipped) and the turn rate unchanged."""
    import torch

    import agents.sb3.batched as batched
    from agents.sb3.policy import load_sb3_policy, read_metadata

    built = []  # the training VecEnvs: the mode must reach them, not only the metadata
    make = batched.make_batched_vec_env

    def spy(*args, **kwargs):
        venv = make(*args, **kwargs)
        built.append(venv.venv.residual_mode)
        return venv

    monkeypatch.setattr(batched, "make_batched_vec_env", spy)
    path = train_frozen_residual(tmp_path / "run", residual_mode="gain")
    assert built == ["gain"]
    assert read_metadata(path)["residual_mode"] == "gain"
    learned = load_sb3_policy(path, parallel_env(**KWARGS))
    assert learned.residual_mode == "gain"
    assert_drives_like_scripted(learned, steps=3)  # zero correction: the base itself
    with torch.no_grad():
        learned.model.policy.action_net.bias.copy_(torch.tensor([0.5, 0.0]))
    env = parallel_env(**KWARGS)
    scripted = load_policy("scripted:formation", parallel_env(**KWARGS))
    learned.reset(100)
    scripted.reset(100)
    obs, infos = env.reset(seed=100)
    high = learned.action_high
    moving = 0
    for _ in range(10):
        actions, base = learned(obs, infos), scripted(obs, infos)
        for agent in obs:
            want = np.clip(np.asarray(base[agent], np.float64) * [2.0, 1.0], -high, high)
            np.testing.assert_allclose(actions[agent], want, rtol=1e-6)
            moving += 0 < abs(base[agent][0]) < high[0] / 2  # the doubling is not clipped
        obs, _, _, _, infos = env.step(actions)
    assert moving > 0
    # experiments/residual_gains.py reads the gains back: 1 for the zero correction, [2, 1] here.
    from agents.sb3.policy import write_metadata
    from experiments.residual_gains import main, requested_gains

    np.testing.assert_array_equal(requested_gains(path, [100]), np.ones((4 * 15, 2)))
    # The policy loads weights only (no SB3 algorithm to save): SB3's model of the same run,
    # given the changed weights, saved in the run directory.
    from stable_baselines3 import PPO

    sb3 = PPO.load(path, device="cpu")
    sb3.policy.load_state_dict(learned.model.policy.state_dict())
    doubled = tmp_path / "run" / "doubled.zip"
    sb3.save(doubled)
    write_metadata(doubled, read_metadata(path))
    np.testing.assert_allclose(requested_gains(doubled, [100, 101]), [[2.0, 1.0]] * (2 * 4 * 15))
    assert main([str(doubled), "--seeds", "100", "--out", str(tmp_path / "g.json")]) == 0
    summary = json.loads((tmp_path / "g.json").read_text())["models"][str(doubled)]
    assert summary["speed"]["mean"] == pytest.approx(2.0) and summary["agent_steps"] == 60
    additive = train_frozen_residual(tmp_path / "add")
    with pytest.raises(ValueError, match="not a --residual-mode gain model: residual_mode 'add'"):
        requested_gains(additive, [100])
    # A wrong model anywhere in the list is refused before any model runs.
    with pytest.raises(ValueError, match="not a --residual-mode gain model"):
        main([str(doubled), str(additive), "--out", str(tmp_path / "h.json")])
    assert not (tmp_path / "h.json").exists()


SDE = {"ppo_kwargs": {"use_sde": True}}
WARM = {"teacher": "scripted:formation", "steps": 64}


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ({"vec": "supersuit", "residual": "scripted:formation"}, "batched"),
        ({"residual_mode": "gain"}, "--residual-mode gain needs --residual"),
        (
            {"residual": "scripted:formation", "residual_mode": "gain", "warm_start": WARM},
            "--residual-mode gain and --warm-start",
        ),
        ({"residual": "scripted:formation", "residual_mode": "scale"}, "residual-mode.*'scale'"),
        ({**SDE, "critic_state": True}, "--sde and --critic-state"),
        ({**SDE, "lstm_hidden": 8}, "--sde and --recurrent"),
        ({**SDE, "warm_start": WARM}, "--sde and --warm-start"),
    ],
)
def test_residual_and_sde_refusals_leave_no_run_directory(tmp_path, extra, match):
    """The residual needs the batched VecEnv; the gain mode needs a residual and excludes the
    additive warm start; gSDE excludes the policies whose noise is the per-step Gaussian. All
    are refused before the run directory is written."""
    from agents.sb3.train import train

    with pytest.raises(ValueError, match=match):
        train(KWARGS, 64, tmp_path / "run", progress_bar=False, **extra)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("flags", [["--residual-mode", "gain"], ["--sde"]])
def test_cli_refuses_gain_mode_and_sde_on_rllib(tmp_path, capsys, flags):
    from swarm_phd.cli import main

    out = tmp_path / "run"
    argv = ["train", "--preset", "lab-3m-4", "--task", "formation", "--timesteps", "64"]
    assert main([*argv, "--engine", "rllib", *flags, "--out", str(out)]) == 2
    assert f"{flags[0]} are SB3-only" in capsys.readouterr().err
    assert not out.exists()


def test_sde_residual_starts_as_its_base_and_records_the_noise(tmp_path):
    """``--sde``: SB3's gSDE with one exploration matrix per agent per rollout
    (``sde_sample_freq -1``), a per-hidden-unit log-std (128 x 2, at the residual's default
    for gSDE, -3: about the per-step default's action std), and still a zero correction at
    the start: the saved deterministic policy is the scripted controller."""
    from agents.sb3.policy import load_sb3_policy

    path = train_frozen_residual(tmp_path / "run", sde=True)  # default log-std -3 with gSDE
    config = json.loads((tmp_path / "run" / "train_config.json").read_text())
    assert config["ppo"]["use_sde"] is True and config["ppo"]["sde_sample_freq"] == -1
    learned = load_sb3_policy(path, parallel_env(**KWARGS))
    assert learned.model.policy.use_sde
    log_std = learned.model.policy.log_std.detach().numpy()
    assert log_std.shape == (128, 2)
    np.testing.assert_array_equal(log_std, -3.0)
    assert_drives_like_scripted(learned, steps=3)
