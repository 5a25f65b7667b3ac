"""Ray RLlib engine: the env wrapper (render fix, kernel threads, spaces) and one tiny PPO
iteration on a local 2-CPU Ray with one remote env runner, through the command's own path."""

from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest

pytest.importorskip("ray.rllib", reason="the ray extra is not installed")


ENV_KWARGS = {"preset": "lab-3m-4", "task": "formation", "max_steps": 10}


@pytest.fixture
def restore_kernel_threads():
    import numba

    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def test_render_works_where_rllibs_wrapper_raises(restore_kernel_threads):
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from agents.rllib.env import SwarmRLlibEnv
    from agents.sb3.adapter import TrainingWrapper
    from swarm_env import parallel_env

    env = SwarmRLlibEnv({"env_kwargs": ENV_KWARGS, "render_mode": "rgb_array"})
    env.reset(seed=0)
    frame = env.render()
    assert env.render_mode == "rgb_array"
    assert isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.std() > 0  # a drawn arena, not a blank buffer
    env.close()
    # The upstream bug this works around: render(self.render_mode) into a no-argument render().
    upstream = ParallelPettingZooEnv(
        TrainingWrapper(parallel_env(**ENV_KWARGS, render_mode="rgb_array"))
    )
    with pytest.raises(TypeError):
        upstream.render()
    upstream.close()


def test_env_steps_all_agents_with_unit_actions_and_one_kernel_thread(restore_kernel_threads):
    import numba

    from agents.rllib.env import SwarmRLlibEnv

    env = SwarmRLlibEnv({"env_kwargs": ENV_KWARGS})
    assert numba.get_num_threads() == 1
    obs, infos = env.reset(seed=3)
    agents = sorted(obs)
    assert agents == sorted(env.possible_agents) and len(agents) == 4
    space = env.action_space[agents[0]]
    assert space.low.tolist() == [-1, -1] and space.high.tolist() == [1, 1]
    for t in range(10):
        obs, rew, term, trunc, infos = env.step({a: np.ones(2, np.float32) for a in agents})
        assert set(rew) == set(agents) and "__all__" in term and "__all__" in trunc
        # Raw sensor records dropped; at the episode's end, the task's headline metric.
        last = {"task_metric"} if t == 9 else set()
        for a in agents:
            assert obs[a].shape == env.observation_space[a].shape
            assert set(infos[a]) == {"TimeLimit.truncated", *last}
    assert trunc["__all__"] and not term["__all__"]  # max_steps = 10: time limit, not an end
    name, value = infos[agents[0]]["task_metric"]
    assert name == next(iter(env.par_env.unwrapped.task.metrics())) and np.isfinite(value)
    # The unit action 1 reached the robots as the full command [v_max, omega_max].
    inner = env.par_env.unwrapped
    high = inner.action_space(agents[0]).high
    assert np.allclose(np.asarray(inner._last_commands[0]), high)
    env.close()


def test_one_tiny_training_run_on_local_ray(local_ray, tmp_path):
    from agents.rllib import train as rl_train
    from agents.rllib.policy import load_policy
    from swarm_env import parallel_env

    parser = argparse.ArgumentParser()
    rl_train.add_arguments(parser)
    out = tmp_path / "run"
    args = parser.parse_args(
        [
            "--preset", "lab-3m-4", "--task", "formation", "--max-steps", "10",
            "--timesteps", "40", "--n-steps", "10", "--batch-size", "10", "--n-epochs", "1",
            "--num-env-runners", "1", "--checkpoint-every", "40", "--no-progress-bar",
            "--extractor", "mlp", "--out", str(out),
        ]
    )  # fmt: skip
    assert rl_train.run(args) == 0
    summary = json.loads((out / "train_summary.json").read_text())
    # One iteration = 10 env steps x 4 robots = 40 agent steps: the budget of 40 takes one.
    assert summary["agent_steps"] == 40 and summary["env_steps"] == 10
    assert summary["iterations"] == 1 and summary["interrupted"] is summary["stopped"] is None
    # The remote runner built its env with one kernel thread and loaded the kernels from the
    # cache: its env build + reset and first step take seconds, a compile about a minute.
    (runner,) = summary["runners"]
    assert runner["kernel_threads"] == 1
    assert len(runner["env_startup_s"]) == 1 and len(runner["first_step_s"]) == 1
    assert runner["env_startup_s"][0] + runner["first_step_s"][0] < 20
    rows = list(csv.DictReader((out / "progress.csv").open()))
    assert [int(r["agent_steps"]) for r in rows] == [40]
    assert all(np.isfinite(float(r["episode_return_mean"])) for r in rows)
    assert (out / "checkpoints" / "step_40").is_dir()
    assert json.loads((out / "env_kwargs.json").read_text())["preset"] == "lab-3m-4"

    env = parallel_env(**json.loads((out / "env_kwargs.json").read_text()))
    policy = load_policy(out / "checkpoint", env)
    obs, _ = env.reset(seed=0)
    actions = policy(obs)
    high = env.action_space(env.possible_agents[0]).high
    assert set(actions) == set(obs)
    for a in actions.values():
        assert a.shape == (2,) and np.all(np.abs(a) <= high + 1e-6)
    env.step(actions)
    env.close()


def test_bad_counts_raise_before_ray_starts(tmp_path):
    from agents.rllib.train import build_config, train

    with pytest.raises(ValueError, match="num-env-runners"):
        build_config(ENV_KWARGS, num_env_runners=-1)
    with pytest.raises(ValueError, match="envs-per-runner"):
        build_config(ENV_KWARGS, envs_per_runner=0)
    with pytest.raises(ValueError, match="batch-size"):
        build_config(
            ENV_KWARGS,
            num_env_runners=1,
            ppo={"rollout_fragment_length": 10, "minibatch_size": 20},
        )
    with pytest.raises(ValueError, match="timesteps"):
        train(ENV_KWARGS, 0, tmp_path)


def test_engine_option_dispatches_to_the_chosen_engine(monkeypatch):
    from agents.rllib import engine
    from agents.rllib import train as rl_train
    from agents.sb3 import train as sb3_train

    parser = argparse.ArgumentParser()
    engine.add_arguments(parser)
    calls = []
    monkeypatch.setattr(rl_train, "run", lambda a: calls.append(("rllib", a)) or 0)
    monkeypatch.setattr(sb3_train, "run", lambda a: calls.append(("sb3", a)) or 0)
    base = ["--out", "x", "--preset", "lab-3m-4"]
    args = parser.parse_args(base)
    assert args.engine == "sb3" and args.num_env_runners == 2 and args.address is None
    engine.run(args)
    args = parser.parse_args([*base, "--engine", "rllib", "--num-env-runners", "3"])
    engine.run(args)
    assert [c[0] for c in calls] == ["sb3", "rllib"] and calls[1][1].num_env_runners == 3
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--engine", "tf"])


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--gamma", "2"], "--gamma"),
        (["--n-epochs", "0"], "--n-epochs"),
        (["--learning-rate", "nan"], "--learning-rate"),
        (["--torch-threads", "0"], "--torch-threads"),
        (["--envs-per-runner", "0"], "--envs-per-runner"),
        (["--num-env-runners", "-1"], "--num-env-runners"),
        (["--max-wall-minutes", "-5"], "--max-wall-minutes"),
        (["--timesteps", "0"], "--timesteps"),
        (["--clip-range", "0.1"], "--clip-range"),
        (["--target-kl", "0.02"], "--target-kl"),
        (["--kernel-threads", "2"], "--kernel-threads"),
    ],
)
def test_rllib_engine_refuses_bad_flags_before_ray_starts(monkeypatch, tmp_path, extra, named):
    """The SB3 engine's rules for the shared flags, and the engine's own counts: refused in
    one line (the CLI's exit 2) before an env is built or Ray starts."""
    import swarm_env
    from agents.rllib import engine
    from agents.rllib import train as rl_train

    def started(*args, **kwargs):
        raise AssertionError("an env was built before the input was checked")

    monkeypatch.setattr(swarm_env, "parallel_env", started)
    parser = argparse.ArgumentParser()
    engine.add_arguments(parser)
    args = parser.parse_args(
        ["--out", str(tmp_path / "run"), "--preset", "lab-3m-4", "--engine", "rllib", *extra]
    )
    with pytest.raises(ValueError, match=named):
        rl_train.run(args)
    assert not (tmp_path / "run").exists()
