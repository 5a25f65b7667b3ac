"""SwarmEnv as an RLlib multi-agent env (new API stack), one process per env runner.

The chain::

    SwarmEnv -> agents.sb3.adapter.TrainingWrapper -> SwarmRLlibEnv (ParallelPettingZooEnv)

:class:`~agents.sb3.adapter.TrainingWrapper` is reused as it is: actions in ``[-1, 1]^2`` scaled
to ``[v_max, omega_max]``, the heavy raw-sensor ``infos`` dropped (Ray would serialise them
between processes every step). Every agent maps to one module id, :data:`SHARED_POLICY`
(parameter sharing, as the SB3 engine).

Two fixes over RLlib's ``ParallelPettingZooEnv`` (ray 2.60):

- ``render()`` calls ``self.par_env.render(self.render_mode)``, but a PettingZoo
  ``ParallelEnv.render()`` takes no argument since PettingZoo 1.22 (the mode is fixed when the
  env is built), so it raises ``TypeError: render() takes 1 positional argument but 2 were
  given``; and ``self.render_mode`` is gymnasium's class default ``None`` whatever mode the
  PettingZoo env has. :meth:`SwarmRLlibEnv.render` calls ``par_env.render()`` and
  ``render_mode`` mirrors the wrapped env's.
- Kernel threads: each env runner is its own process, so its numba kernels use one thread
  (:func:`swarm_core.threads.set_kernel_threads`); N runners then share the cores instead of
  each spawning a thread per core.

The kernels load from numba's on-disk cache (``__pycache__`` next to the sources, shared by all
processes of the machine): the driver compiles them first (:func:`prewarm_kernels`), so a runner
starts in ~2 s instead of compiling for a minute. A cluster node without the cache compiles
once, in its first runner, and later runners of that node load it.
"""

from __future__ import annotations

import time
from typing import Any

from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

#: The RLlib env name :func:`register` registers.
ENV_NAME = "swarm_phd"
#: The one module every agent maps to.
SHARED_POLICY = "shared"
#: The info key of the task's headline metric at an episode's end, and the prefix of the
#: value :class:`TaskMetricCallback` logs in the runners' results (``task/<metric>``).
TASK_METRIC_KEY = "task_metric"
TASK_METRIC_PREFIX = "task/"
#: Seconds each env of this process took to build and reset, and its first step (the first
#: calls of the sensor and filter kernels load them from numba's cache, or compile them).
_STARTUP_S: list[float] = []
_FIRST_STEP_S: list[float] = []


class SwarmRLlibEnv(ParallelPettingZooEnv):
    """RLlib multi-agent env of a SwarmEnv.

    ``config`` (RLlib's ``env_config``): ``env_kwargs`` (dict for
    :func:`swarm_env.parallel_env`, required), ``kernel_threads`` (int, default 1),
    ``render_mode`` (``None``, ``"rgb_array"`` or ``"human"``).
    """

    def __init__(self, config: dict[str, Any]) -> None:
        from agents.sb3.adapter import TrainingWrapper
        from swarm_core.threads import set_kernel_threads
        from swarm_env import parallel_env

        if "env_kwargs" not in config:
            raise ValueError(f"env_config needs 'env_kwargs', got keys {sorted(config)}")
        start = time.perf_counter()
        set_kernel_threads(config.get("kernel_threads", 1))
        env_kwargs = dict(config["env_kwargs"])
        if config.get("render_mode") is not None:
            env_kwargs["render_mode"] = config["render_mode"]
        super().__init__(TrainingWrapper(parallel_env(**env_kwargs)))
        self.render_mode = self.par_env.render_mode
        _STARTUP_S.append(time.perf_counter() - start)  # the base class reset the env once
        self._stepped = False

    def step(self, action_dict: dict[str, Any]):
        if self._stepped:
            return self._with_task_metric(super().step(action_dict))
        start = time.perf_counter()
        result = super().step(action_dict)
        _FIRST_STEP_S.append(time.perf_counter() - start)
        self._stepped = True
        return self._with_task_metric(result)

    def _with_task_metric(self, result: tuple) -> tuple:
        """At the episode's end, the task's headline metric (its first) in every agent's info
        (``TASK_METRIC_KEY``: ``(name, value)``), for :class:`TaskMetricCallback`."""
        obs, rewards, terminated, truncated, infos = result
        if terminated.get("__all__") or truncated.get("__all__"):
            metrics = self.par_env.unwrapped.task.metrics()
            if metrics:
                name = next(iter(metrics))
                for agent in infos:
                    infos[agent] = {**infos[agent], TASK_METRIC_KEY: (name, metrics[name])}
        return obs, rewards, terminated, truncated, infos

    def render(self) -> Any:
        # RLlib passes self.render_mode to a PettingZoo render() that takes none (module doc).
        return self.par_env.render()


def task_metric_callback() -> type:
    """The RLlib callback class that logs each finished episode's task metric (mean over
    RLlib's smoothing window) as ``task/<metric>`` in the env runners' results, so that the
    trainer prints it beside the return, as the SB3 engine does."""
    from ray.rllib.callbacks.callbacks import RLlibCallback

    class TaskMetricCallback(RLlibCallback):
        def on_episode_end(self, *, episode, metrics_logger=None, **kwargs) -> None:
            if metrics_logger is None:
                return
            for info in episode.get_infos(-1).values():
                if isinstance(info, dict) and TASK_METRIC_KEY in info:
                    name, value = info[TASK_METRIC_KEY]
                    metrics_logger.log_value(TASK_METRIC_PREFIX + name, float(value))
                    return

    return TaskMetricCallback


def make_env(config: dict[str, Any]) -> SwarmRLlibEnv:
    """The env creator :func:`register` gives RLlib."""
    return SwarmRLlibEnv(config)


def register() -> str:
    """Register :data:`ENV_NAME` with Ray Tune's registry (in the driver; RLlib ships the
    creator to every runner). Returns the name."""
    from ray.tune.registry import register_env

    register_env(ENV_NAME, make_env)
    return ENV_NAME


def policy_mapping_fn(agent_id: Any, episode: Any = None, **kwargs: Any) -> str:
    """Parameter sharing: every robot acts with :data:`SHARED_POLICY`."""
    return SHARED_POLICY


def runner_report(*_: Any) -> dict[str, Any]:
    """This process's kernel threads, env build+reset seconds and first-step seconds (called in
    each env runner; a first step of minutes would be a kernel compile)."""
    import numba

    return {
        "kernel_threads": int(numba.get_num_threads()),
        "env_startup_s": list(_STARTUP_S),
        "first_step_s": list(_FIRST_STEP_S),
    }


def prewarm_kernels() -> bool:
    """Compile (or check) every numba kernel in this process before any runner starts, so the
    runners load them from the cache. Returns whether a compile happened."""
    from swarm_env.warmup import warm_if_cold

    return warm_if_cold()
