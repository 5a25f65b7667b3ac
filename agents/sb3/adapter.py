"""SwarmEnv -> stable-baselines3 VecEnv, one policy shared by all agents (parameter sharing).

The chain is SuperSuit's, as the PettingZoo/SB3 docs recommend::

    SwarmEnv -> TrainingWrapper -> pettingzoo_env_to_vec_env_v1 -> concat_vec_envs_v1
             -> VecMonitor -> VecNormalize

``pettingzoo_env_to_vec_env_v1`` turns one N-agent env into N "envs" of a VecEnv (every agent is a
sample of the same policy); ``concat_vec_envs_v1`` stacks copies (optionally in worker
processes). :class:`TrainingWrapper` fills the two gaps SuperSuit leaves for SB3:

- SuperSuit's SB3 wrapper merges ``terminated`` and ``truncated`` into ``done`` and sets no
  ``TimeLimit.truncated`` flag, so PPO would treat the time limit as a real end (value 0) and
  learn a wrong value near ``max_steps``. The wrapper sets the flag in ``infos`` so SB3
  bootstraps from ``terminal_observation`` on truncation.
- The env's ``infos`` carry the raw sensor records (720-beam lidar scans) and ground truth; SB3
  never reads them, and with worker processes they would be pickled every step. The wrapper
  drops them.

It also rescales actions: the policy acts in ``[-1, 1]^2`` (what SB3's Gaussian policy is tuned
for) and the wrapper multiplies by ``[v_max, omega_max]``. :func:`scale_actions` does the same
at deployment (see :mod:`agents.sb3.policy`).
"""

from __future__ import annotations

import os
import warnings
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

UNIT_ACTION_SPACE = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


def scale_actions(action: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Policy output in ``[-1, 1]`` (clipped) -> env command ``[v_mps, omega_radps]``."""
    return (np.clip(action, -1.0, 1.0) * high).astype(np.float32)


class TrainingWrapper(ParallelEnv):
    """A ParallelEnv view of :class:`~swarm_env.env.SwarmEnv` for training (see module doc)."""

    def __init__(self, env: Any) -> None:
        super().__init__()
        self.env = env
        self.metadata = env.metadata
        self.possible_agents = list(env.possible_agents)
        self._high = np.array(env.action_space(self.possible_agents[0]).high, dtype=np.float64)
        self._action_spaces = {a: UNIT_ACTION_SPACE for a in self.possible_agents}

    @property
    def agents(self) -> list[str]:
        return self.env.agents

    @property
    def unwrapped(self) -> Any:
        return self.env

    @property
    def render_mode(self) -> str | None:
        return self.env.render_mode

    def observation_space(self, agent: str) -> spaces.Box:
        return self.env.observation_space(agent)

    def action_space(self, agent: str) -> spaces.Box:
        return self._action_spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, _ = self.env.reset(seed=seed, options=options)
        return obs, {a: {} for a in obs}

    def step(self, actions: dict[str, np.ndarray]):
        commands = {a: scale_actions(np.asarray(u), self._high) for a, u in actions.items()}
        obs, rewards, terms, truncs, _ = self.env.step(commands)
        infos = {a: {"TimeLimit.truncated": bool(truncs[a] and not terms[a])} for a in obs}
        return obs, rewards, terms, truncs, infos

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()


def make_vec_env(
    env_kwargs: dict[str, Any],
    n_copies: int = 1,
    num_cpus: int = 0,
    seed: int | None = 0,
    monitor_file: str | None = None,
):
    """A SB3 VecEnv with ``n_copies * n_robots`` entries, wrapped in ``VecMonitor``.

    ``num_cpus`` > 1 (and ``n_copies`` > 1) steps the copies in ``min(num_cpus, n_copies)``
    worker processes (SuperSuit's ``ProcConcatVec``), each with one kernel thread; 0 or 1
    keeps everything in this process (SuperSuit's own rule for one CPU).
    """
    import supersuit as ss
    from stable_baselines3.common.vec_env import VecMonitor

    from swarm_env import parallel_env

    env = TrainingWrapper(parallel_env(**env_kwargs))
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    if num_cpus > 0:
        vec = _worker_processes_vec_env(vec, n_copies, num_cpus)
    else:
        vec = ss.concat_vec_envs_v1(vec, n_copies, num_cpus=0, base_class="gymnasium")
    with warnings.catch_warnings():
        # SB3 asks every env for render_mode; SuperSuit's vector env answers None (we do not
        # render while training), which SB3 reports as "not defined".
        warnings.filterwarnings("ignore", message="The `render_mode` attribute is not defined")
        vec = _SeededSB3Wrapper(vec)
        vec.seed(seed)
        return VecMonitor(vec, filename=monitor_file)


def _worker_processes_vec_env(vec: Any, n_copies: int, num_cpus: int) -> Any:
    """SuperSuit's ``concat_vec_envs_v1(vec, n_copies, num_cpus)``, except that its worker
    processes are spawned and run their kernels on one thread each (:class:`CopyForWorker`)."""
    import multiprocessing

    from supersuit.vector import MakeCPUAsyncConstructor

    constructor = MakeCPUAsyncConstructor(min(num_cpus, n_copies))
    # SuperSuit forks its workers (the platform default). A process that has run the parallel
    # kernels (any env step) cannot: GNU OpenMP is not fork-safe, and numba terminates a forked
    # child at its first kernel. Spawn them, as LoopbackProcess does. SuperSuit and gymnasium
    # create their pipes, shared arrays and locks from the default context, so the default
    # start method is switched, only while the workers start.
    previous = multiprocessing.get_start_method(allow_none=True)
    multiprocessing.set_start_method("spawn", force=True)
    try:
        return constructor(
            [CopyForWorker(vec)] * n_copies, vec.observation_space, vec.action_space
        )
    finally:
        multiprocessing.set_start_method(previous, force=True)


class CopyForWorker:
    """Builds a copy of ``obj`` (pickled now). Called in any process but the one that made it
    (a SuperSuit worker), it first sets one kernel thread: the workers share the cores between
    them (issue 13: one env per core), where numba's default starts a full pool in each.
    SuperSuit also builds one copy in the training process (to count its envs); that process's
    threads are left alone."""

    def __init__(self, obj: Any) -> None:
        import cloudpickle

        self.blob = cloudpickle.dumps(obj)
        self.builder_pid = os.getpid()

    def __call__(self) -> Any:
        import cloudpickle

        if os.getpid() != self.builder_pid:
            from swarm_core.threads import set_kernel_threads

            set_kernel_threads(1)
        return cloudpickle.loads(self.blob)


def _sb3_wrapper_class():
    from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

    class SeededSB3Wrapper(SB3VecEnvWrapper):
        """SuperSuit's SB3 wrapper with a working ``seed()``: SB3 calls ``env.seed(s)`` and
        then ``env.reset()``; SuperSuit's version forwards ``seed`` to a vector env that has no
        such method. Here the seed is kept and passed to the next reset (copy k gets
        ``s + k``); later episodes continue each copy's own generator, so runs reproduce."""

        def __init__(self, venv) -> None:
            super().__init__(venv)
            self._pending_seed: int | None = None

        def seed(self, seed: int | None = None):
            self._pending_seed = seed
            return [None if seed is None else seed + k for k in range(self.num_envs)]

        def reset(self, seed=None, options=None):
            seed = self._pending_seed if seed is None else seed
            self._pending_seed = None
            observations, self.reset_infos = self.venv.reset(seed=seed)
            return observations

    return SeededSB3Wrapper


def _SeededSB3Wrapper(venv):  # noqa: N802 - a class factory (SB3 is imported lazily)
    return _sb3_wrapper_class()(venv)
