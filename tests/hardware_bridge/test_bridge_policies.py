"""``swarm-phd bridge --policy``: scripted controllers and trained policies drive the robots in
their own env (task, observation, preset, localizer), and what cannot drive robots is refused
before anything connects."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from swarm_phd import bridge
from swarm_phd.cli import main

torch = pytest.importorskip("torch")

from agents.sb3.recurrent_student import new_student, save_student  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from tests.env_kwargs import formation_env  # noqa: E402

STUDENT_ENV = formation_env(
    300,
    observation="phd",
    task_params={"radius_m": 0.7},
    lidar_sectors=16,
    n_robots=3,
    control_period_s=0.1,  # a training override the robots do not take
)
BASE = "scripted:formation-known-n-fast"


@pytest.fixture(scope="module")
def student(tmp_path_factory):
    env = parallel_env(**STUDENT_ENV)
    try:
        torch.manual_seed(0)
        model = new_student(env.observation_space(env.possible_agents[0])).eval()
    finally:
        env.close()
    path = tmp_path_factory.mktemp("student") / "student.pt"
    save_student(path, model, STUDENT_ENV, BASE)
    return str(path)


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    bridge.add_arguments(parser)
    return parser.parse_args(["--loopback", *argv])


def test_a_trained_student_runs_in_its_own_env_minus_its_episode_length(student):
    kwargs, dropped = bridge.bridge_env_kwargs(_args("--policy", student), robots=None)
    assert kwargs == {
        "preset": "lab-3m-4",
        "task": "formation",
        "task_params": {"radius_m": 0.7},
        "observation": "phd",
        "lidar_sectors": 16,
        "n_robots": 3,
        "localizer": "phd",
        "max_steps": 300,  # its episode's length, unless --steps is given
    }
    assert dropped == ["control_period_s"]  # listed, not applied to the robots
    # Named robots set the count; the command line's preset, localizer and task parameters win.
    kwargs, _ = bridge.bridge_env_kwargs(
        _args(
            "--policy", student, "--preset", "sim-6m-20", "--localizer", "pmb",
            "--task-params", '{"radius_m": 0.5}', "--steps", "20",
        ),
        robots=["ugv_0", "ugv_1", "ugv_2", "ugv_3"],
    )  # fmt: skip
    assert "n_robots" not in kwargs and kwargs["preset"] == "sim-6m-20"
    assert kwargs["localizer"] == "pmb" and kwargs["task_params"] == {"radius_m": 0.5}
    assert kwargs["max_steps"] == 20


def test_scripted_controllers_get_their_observation_and_wander_the_defaults():
    kwargs, _ = bridge.bridge_env_kwargs(
        _args("--policy", "scripted:formation-known-n-fast", "--task", "formation"), None
    )
    assert kwargs == {
        "preset": "lab-3m-4",
        "task": "formation",
        "observation": "phd",
        "localizer": "phd",
        "max_steps": 100,
    }
    for policy in ("wander", "stop", "random", "scripted:wander"):
        kwargs, dropped = bridge.bridge_env_kwargs(_args("--policy", policy), None)
        assert kwargs == {
            "preset": "lab-3m-4",
            "task": "wander",
            "localizer": "phd",
            "max_steps": 100,
        }
        assert dropped == []


@pytest.fixture(scope="module")
def truth_student(student, tmp_path_factory):
    from agents.sb3.recurrent_student import load_student

    path = tmp_path_factory.mktemp("truth") / "truth.pt"
    env = parallel_env(**STUDENT_ENV)
    try:
        model = load_student(student, env).model
    finally:
        env.close()
    save_student(path, model, {**STUDENT_ENV, "observation": "truth"}, BASE)
    return str(path)


def test_a_policy_trained_on_the_truth_is_refused(truth_student, capsys):
    assert main(["bridge", "--loopback", "--policy", truth_student]) == 2
    captured = capsys.readouterr()
    assert "observation='truth'" in captured.err and "loopback" not in captured.out


@pytest.mark.parametrize(
    "policy, message",
    [
        ("privileged:formation-known-n-fast@truth", "simulator's truth"),
        ("scripted:nope", "scripted:nope"),
        ("gone.pt", "gone.pt"),
        ("gone.zip", "gone.zip"),
        ("fast", "'fast'"),
    ],
)
def test_policies_that_cannot_drive_robots_are_refused_before_anything_starts(
    policy, message, capsys
):
    with pytest.raises(ValueError, match="--policy"):
        bridge.bridge_env_kwargs(_args("--policy", policy), None)
    assert main(["bridge", "--loopback", "--policy", policy]) == 2
    captured = capsys.readouterr()
    assert message in captured.err
    assert "loopback robot server" not in captured.out  # refused before the server started


def test_bad_task_parameters_and_steps_are_refused(capsys):
    assert main(["bridge", "--loopback", "--task-params", "[1]"]) == 2
    assert "--task-params" in capsys.readouterr().err
    assert main(["bridge", "--loopback", "--steps", "0"]) == 2
    assert "--steps must be >= 1, got 0" in capsys.readouterr().err


def test_a_controller_without_its_task_is_refused_before_anything_starts(capsys):
    # Built once on a simulator first: its own error names the task it needs.
    assert main(["bridge", "--loopback", "--policy", "scripted:formation-known-n-fast"]) == 2
    captured = capsys.readouterr()
    assert "task='formation'" in captured.err and "loopback" not in captured.out


@pytest.mark.timeout(120)
def test_a_student_and_a_scripted_controller_drive_the_loopback_robots(
    student, capsys, monkeypatch
):
    import agents.policies

    calls: dict[str, int] = {}
    load = agents.policies.load_policy

    def counting_load(spec, env, **kwargs):  # counts the calls of the policy driving the robots
        policy = load(spec, env, **kwargs)

        def act(obs, infos):
            calls[spec] = calls.get(spec, 0) + 1
            return policy(obs, infos)

        act.reset = policy.reset
        return act

    monkeypatch.setattr(agents.policies, "load_policy", counting_load)
    argv = ["bridge", "--loopback", "--steps", "15", "--json"]
    assert main([*argv, "--policy", student]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["policy"] == student and out["steps"] == 15 and out["rejected_messages"] == 0
    assert calls[student] == 15  # it chose every command
    # In its own env: its preset, task, observation and robot count (the loopback's too).
    assert out["robots"] == ["ugv_0", "ugv_1", "ugv_2"] and out["preset"] == "lab-3m-4"
    assert out["observation"] == "phd"
    assert out["policy_settings_not_applied"] == ["control_period_s"]
    # Its task, scored on the loopback's ground truth (its mocap).
    assert out["task"]["name"] == "formation" and out["task"]["formation_error_m"] > 0
    assert out["metrics"]["scored_observations"] > 0

    spec = "scripted:formation-known-n-fast"
    calls.clear()  # (the student's base is this controller, loaded the same way)
    assert main([*argv, "--policy", spec, "--task", "formation"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["task"]["name"] == "formation" and "spacing_error_m" in out["task"]
    assert calls[spec] == 15 and len(out["robots"]) == 4


def test_run_episode_resets_the_policy_with_the_episodes_seed():
    from swarm_phd.episode import run_episode

    class Stay:
        seeds: list = []

        def reset(self, seed):
            self.seeds.append(seed)

        def __call__(self, obs, infos):
            return {a: np.zeros(2, np.float32) for a in obs}

    env = parallel_env("lab-3m-4", max_steps=5)
    try:
        policy = Stay()
        run_episode(env, policy, 2, seed=7)
        run_episode(env, policy, 2, seed=None)  # a replay's: the policy keeps its state
    finally:
        env.close()
    assert policy.seeds == [7]
