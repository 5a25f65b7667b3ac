"""BenchMARL's door: every swarm task as a BenchMARL task (its custom-task recipe: a
``TaskClass`` that builds the TorchRL env, a ``Task`` enum naming the tasks, a config
dataclass), trainable with any of BenchMARL's continuous-action algorithms (MAPPO, IPPO,
MASAC, MADDPG...).

>>> from benchmarl.algorithms import MappoConfig
>>> from benchmarl.experiment import Experiment, ExperimentConfig
>>> from benchmarl.models.mlp import MlpConfig
>>> from agents.benchmarl_task import SwarmTask
>>> task = SwarmTask.FORMATION.get_task({"preset": "lab-3m-4", "max_steps": 200})
>>> experiment = Experiment(
...     task=task,
...     algorithm_config=MappoConfig.get_from_yaml(),
...     model_config=MlpConfig.get_from_yaml(),
...     critic_model_config=MlpConfig.get_from_yaml(),
...     seed=0,
...     config=ExperimentConfig.get_from_yaml(),
... )
>>> experiment.run()

``SwarmTask.<NAME>.get_task()`` without a config uses :class:`SwarmTaskConfig`'s defaults
(BenchMARL's own tasks read a YAML file of its package; ``get_from_yaml(path)`` reads one of
yours). The env is :func:`agents.torchrl_env.make_torchrl_env`: every robot in group ``"ugv"``,
continuous ``[v, omega]`` actions, the global ``"state"`` for centralised critics. :func:`
make_experiment` builds an :class:`~benchmarl.experiment.Experiment` with a frame budget in
one call (what the tests and the docs' example use). Needs the ``marl`` extra.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmarl.environments.common import Task, TaskClass
from torchrl.data import Composite
from torchrl.envs import EnvBase

from agents.torchrl_env import make_torchrl_env
from swarm_core.validation import check_number


@dataclass
class SwarmTaskConfig:
    """A swarm task's settings (BenchMARL's task config).

    ``preset``: the arena and swarm (``swarm-phd list``); ``max_steps``: the episode length in
    control steps (also BenchMARL's evaluation horizon); ``task_params``: the task's
    parameters (e.g. ``{"radius_m": 0.8}`` for formation); ``env_kwargs``: any other
    :class:`~swarm_env.env.SwarmEnv` keyword (``localizer``, ``observation``, config fields
    such as ``n_robots``)."""

    preset: str = "lab-3m-4"
    max_steps: int = 200
    task_params: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)


_CONFIG_KEYS = tuple(f.name for f in dataclasses.fields(SwarmTaskConfig))


def _checked(config: dict[str, Any] | None) -> dict[str, Any]:
    """``config`` over :class:`SwarmTaskConfig`'s defaults; ValueError naming an unknown key or
    a ``task`` key (the enum member is the task)."""
    config = dict(config or {})
    unknown = sorted(set(config) - set(_CONFIG_KEYS))
    if unknown:
        raise ValueError(
            f"unknown swarm task config key(s) {unknown}; known: {list(_CONFIG_KEYS)} (other "
            "SwarmEnv keywords go under 'env_kwargs')"
        )
    if "task" in config.get("env_kwargs", {}):
        raise ValueError("env_kwargs must not name the task: choose the SwarmTask member")
    return dataclasses.asdict(SwarmTaskConfig(**config))


class SwarmTaskClass(TaskClass):
    """Builds the TorchRL env of one swarm task (``self.name``, e.g. ``FORMATION``) from its
    config (:class:`SwarmTaskConfig`)."""

    def __init__(self, name: str, config: dict[str, Any] | None):
        super().__init__(name, _checked(config))

    @property
    def task_name(self) -> str:
        """The swarm task (``swarm_env.tasks.TASKS`` key) this member names."""
        return self.name.lower()

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        if not continuous_actions:
            raise ValueError(
                "the swarm's actions are continuous [v, omega]: use an algorithm with "
                "continuous actions (MAPPO, IPPO, MASAC, MADDPG, ...)"
            )
        config = copy.deepcopy(self.config)
        kwargs = {
            **config["env_kwargs"],
            "max_steps": config["max_steps"],
            "task_params": config["task_params"],
        }
        task, preset = self.task_name, config["preset"]
        # One env per call: BenchMARL batches ``num_envs`` of them (SerialEnv / ParallelEnv).
        return lambda: make_torchrl_env(preset, task, seed=seed, device=device, **kwargs)

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        """Frames for BenchMARL's evaluation videos only when asked for:
        ``env_kwargs={"render_mode": "rgb_array"}`` (drawing a frame costs more than a step)."""
        return self.config["env_kwargs"].get("render_mode") == "rgb_array"

    def max_steps(self, env: EnvBase) -> int:
        return int(self.config["max_steps"])

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def _group_entries(self, env: EnvBase, keep: str) -> Composite:
        spec = env.observation_spec.clone()
        for group in self.group_map(env):
            for key in list(spec[group].keys()):
                if key != keep:
                    del spec[group][key]
        if "state" in spec.keys():
            del spec["state"]
        return spec

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._group_entries(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return self._group_entries(env, "info")

    def state_spec(self, env: EnvBase) -> Composite | None:
        if "state" in env.observation_spec.keys():
            return Composite({"state": env.observation_spec["state"].clone()})
        return None

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None  # every action is always available

    @staticmethod
    def env_name() -> str:
        return "swarm_phd"

    @staticmethod
    def render_callback(experiment: Any, env: EnvBase, data: Any) -> Any:
        """The env's ``rgb_array`` frame as a tensor (H, W, 3)."""
        import torch

        return torch.as_tensor(env.render())


class SwarmTask(Task):
    """The swarm's tasks, one member per :data:`swarm_env.tasks.TASKS` entry."""

    WANDER = None
    FORMATION = None
    EXPLORATION = None
    ENCIRCLEMENT = None

    @staticmethod
    def associated_class():
        return SwarmTaskClass

    def get_task(self, config: dict[str, Any] | None = None) -> TaskClass:
        """This task with ``config`` over :class:`SwarmTaskConfig`'s defaults."""
        return SwarmTaskClass(self.name, config)

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        """This task's config from the YAML file ``path`` (keys of :class:`SwarmTaskConfig`);
        without one, the defaults."""
        if path is None:
            return self.get_task()
        from benchmarl.utils import _read_yaml_config

        return self.get_task(_read_yaml_config(str(Path(path).resolve())))


def make_experiment(
    task: str = "formation",
    algorithm: str = "mappo",
    *,
    max_n_frames: int = 200_000,
    frames_per_batch: int = 2_000,
    minibatch_size: int = 500,
    minibatch_iters: int = 8,
    n_envs: int = 1,
    save_folder: str | Path | None = None,
    seed: int = 0,
    **task_config: Any,
):
    """A BenchMARL :class:`~benchmarl.experiment.Experiment` of swarm ``task`` trained by
    ``algorithm`` (``"mappo"``, ``"ippo"``, ``"masac"``, ``"maddpg"``, ...: a BenchMARL
    algorithm with continuous actions) for ``max_n_frames`` env steps, on CPU, with MLP actor
    and critic, logging to CSV under ``save_folder`` (no videos). ``task_config``: the task's
    :class:`SwarmTaskConfig` keys. Call ``.run()`` on it."""
    import benchmarl.algorithms as algorithms
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    member = task.upper()
    if member not in SwarmTask.__members__:
        raise ValueError(f"task must be one of {[m.lower() for m in SwarmTask.__members__]}")
    configs = {
        name[: -len("Config")].lower(): getattr(algorithms, name)
        for name in dir(algorithms)
        if name.endswith("Config") and name != "AlgorithmConfig"
    }
    if algorithm not in configs:
        raise ValueError(f"algorithm must be one of {sorted(configs)}, got {algorithm!r}")
    algorithm_config = configs[algorithm].get_from_yaml()
    if not algorithm_config.supports_continuous_actions():
        raise ValueError(f"algorithm {algorithm!r} has no continuous actions")
    for name, value in (
        ("max_n_frames", max_n_frames),
        ("frames_per_batch", frames_per_batch),
        ("minibatch_size", minibatch_size),
        ("minibatch_iters", minibatch_iters),
        ("n_envs", n_envs),
    ):
        check_number(name, value, integer=True, low=1)
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = max_n_frames
    config.max_n_iters = None
    config.on_policy_collected_frames_per_batch = frames_per_batch
    config.on_policy_minibatch_size = minibatch_size
    config.on_policy_n_minibatch_iters = minibatch_iters
    config.on_policy_n_envs_per_worker = n_envs
    config.off_policy_collected_frames_per_batch = frames_per_batch
    config.off_policy_n_envs_per_worker = n_envs
    config.off_policy_train_batch_size = minibatch_size
    config.off_policy_n_optimizer_steps = minibatch_iters
    config.off_policy_init_random_frames = 0
    config.evaluation = False
    config.render = False
    config.create_video = False  # BenchMARL's videos need torchvision
    config.loggers = ["csv"]
    config.checkpoint_interval = 0
    config.checkpoint_at_end = True
    if save_folder is not None:
        Path(save_folder).mkdir(parents=True, exist_ok=True)
        config.save_folder = str(save_folder)
    return Experiment(
        task=SwarmTask[member].get_task(task_config),
        algorithm_config=algorithm_config,
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=seed,
        config=config,
    )
