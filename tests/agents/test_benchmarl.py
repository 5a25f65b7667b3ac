"""The swarm's tasks as BenchMARL tasks: the task enum, its config and specs, and a tiny CPU
MAPPO run through BenchMARL's own Experiment."""

from __future__ import annotations

import math

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("benchmarl")

from agents.benchmarl_task import (  # noqa: E402
    SwarmTask,
    SwarmTaskClass,
    SwarmTaskConfig,
    make_experiment,
)
from swarm_env.tasks import TASKS  # noqa: E402


def test_one_member_per_swarm_task():
    assert [m.lower() for m in SwarmTask.__members__] == list(TASKS)
    task = SwarmTask.FORMATION.get_task()
    assert isinstance(task, SwarmTaskClass) and task.task_name == "formation"
    assert task.config == {
        "preset": "lab-3m-4",
        "max_steps": 200,
        "task_params": {},
        "env_kwargs": {},
    }
    assert SwarmTask.FORMATION.get_from_yaml().config == SwarmTaskConfig().__dict__


def test_task_config_from_yaml(tmp_path):
    path = tmp_path / "formation.yaml"
    path.write_text("preset: lab-3m-4\nmax_steps: 40\ntask_params:\n  radius_m: 0.7\n")
    task = SwarmTask.FORMATION.get_from_yaml(str(path))
    assert task.config["max_steps"] == 40 and task.config["task_params"] == {"radius_m": 0.7}


def test_bad_task_config_is_refused():
    with pytest.raises(ValueError, match=r"unknown swarm task config key\(s\) \['n_robots'\]"):
        SwarmTask.WANDER.get_task({"n_robots": 3})
    with pytest.raises(ValueError, match="env_kwargs must not name the task"):
        SwarmTask.WANDER.get_task({"env_kwargs": {"task": "formation"}})
    task = SwarmTask.WANDER.get_task({"max_steps": 10})
    with pytest.raises(ValueError, match="continuous"):
        task.get_env_fun(1, continuous_actions=False, seed=0, device="cpu")
    with pytest.raises(ValueError, match="algorithm must be one of"):
        make_experiment("formation", "qmix-typo")
    with pytest.raises(ValueError, match="has no continuous actions"):
        make_experiment("formation", "qmix")


def test_env_and_specs_benchmarl_reads():
    task = SwarmTask.EXPLORATION.get_task(
        {"max_steps": 12, "env_kwargs": {"n_robots": 3, "localizer": "pmb-lc"}}
    )
    env = task.get_env_fun(1, continuous_actions=True, seed=0, device="cpu")()
    assert env.group_map == {"ugv": ["ugv_0", "ugv_1", "ugv_2"]}
    assert task.max_steps(env) == 12
    assert list(task.observation_spec(env)["ugv"].keys()) == ["observation"]
    assert list(task.info_spec(env)["ugv"].keys()) == ["info"]
    assert task.state_spec(env)["state"].shape == (3 * 6,)
    assert task.action_spec(env)["ugv", "action"].shape == (3, 2)
    assert task.action_mask_spec(env) is None
    assert not task.has_render(env)  # frames only when asked for
    td = env.rollout(3)
    assert td["ugv", "observation"].shape[:2] == (3, 3)
    env.close()
    drawn = SwarmTask.WANDER.get_task({"env_kwargs": {"render_mode": "rgb_array"}})
    env = drawn.get_env_fun(1, continuous_actions=True, seed=0, device="cpu")()
    assert drawn.has_render(env)
    env.reset()
    frame = SwarmTaskClass.render_callback(None, env, None)
    assert frame.shape == (640, 928, 3) and frame.dtype == torch.uint8
    env.close()


@pytest.mark.slow
def test_tiny_mappo_experiment_trains_on_cpu(tmp_path):
    experiment = make_experiment(
        "formation",
        "mappo",
        max_n_frames=100,
        frames_per_batch=100,
        minibatch_size=50,
        minibatch_iters=2,
        save_folder=tmp_path,
        max_steps=25,  # episodes end inside the batch: a mean return is logged
    )
    before = [p.detach().clone() for p in experiment.policy.parameters()]
    experiment.run()
    assert experiment.total_frames == 100 and experiment.n_iters_performed == 1
    after = list(experiment.policy.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert list(run_dir.glob("checkpoints/checkpoint_100.pt"))
    (loss_csv,) = run_dir.glob("*/scalars/train_ugv_loss_critic.csv")
    (returns_csv,) = run_dir.glob("*/scalars/collection_ugv_reward_episode_reward_mean.csv")
    for csv in (loss_csv, returns_csv):
        value = float(csv.read_text().strip().splitlines()[-1].split(",")[-1])
        assert math.isfinite(value)
