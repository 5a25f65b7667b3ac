"""K env copies in one process as one native SB3 ``VecEnv``, with one localizer call per step.

:func:`agents.sb3.adapter.make_vec_env` goes through SuperSuit: every copy runs its own
filter call per step (or its own worker process). Here the ``K`` copies of an ``R``-robot env
share **one** localizer of ``K x R`` robots (each copy holds a
:class:`~localization.protocol.LocalizerSlice` of it), and a step is made in the env's three
phases: every copy's World moves (``SwarmEnv.step_world``), the shared localizer consumes all
``K`` feeds in one compiled call, then every copy makes its rewards and observations
(``finish_step``). The VecEnv's entries are agents x copies (entry ``k R + i`` is agent ``i``
of copy ``k``): one policy shared by all agents, as with SuperSuit.

Per robot the filter math is the same as in a lone env, so a batched copy's rollout is
bit-identical to the same env run alone (``tests/agents/test_batched_vec_env.py``). Families
that know identities (``id-phd``, ``ukf``, ``pf``) index their teammates and read one World's
truth, so they cannot be shared by copies: each copy then keeps its own localizer, stepped on
its own feed (no batching of the filter call, but the same VecEnv, residual and critic options;
``shared`` is ``None``).

As :class:`~agents.sb3.adapter.TrainingWrapper` does, it rescales the policy's ``[-1, 1]^2``
actions to ``[v_max, omega_max]``, flags time-limit truncation (``TimeLimit.truncated``) so
PPO bootstraps from ``terminal_observation``, and drops the env's heavy ``infos``. A copy whose
episode ends is reset at once (SB3's auto-reset); tasks must end all agents of a copy together
(every task of :mod:`swarm_env.tasks` does).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from agents.sb3.adapter import UNIT_ACTION_SPACE, scale_actions
from agents.sb3.central_critic import critic_state, critic_state_dims
from agents.sb3.residual import base_in_unit_scale
from localization.feed import SwarmFeed
from localization.protocol import LocalizerSlice
from localization.registry import make_localizer
from swarm_env.config import make_config
from swarm_env.env import SwarmEnv

__all__ = [
    "BatchedSwarmVecEnv",
    "check_unit_actions",
    "copy_seeds_for_reset",
    "make_batched_vec_env",
]


class BatchedSwarmVecEnv(VecEnv):
    """``n_copies`` :class:`~swarm_env.env.SwarmEnv` copies as one SB3 VecEnv (module doc).

    Parameters
    ----------
    env_kwargs : dict
        Keyword arguments of :func:`swarm_env.parallel_env` (``preset``, ``task``, overrides).
    n_copies : int
        Env copies ``K`` (>= 1); the VecEnv has ``K x n_robots`` entries.
    seed : int or None
        Copy ``k`` is reset with ``seed + k`` at the first :meth:`reset`.
    residual : str or None
        ``"scripted:NAME"``: a residual policy (:mod:`agents.sb3.residual`): each copy's
        command is ``clip(scripted(obs, infos) + action x high, -high, high)`` (or the gain
        of ``residual_mode``), the scripted controller (one per copy) reading that copy's last
        observations and infos.
    residual_observes_base : bool
        With ``residual``: append the scripted command, in unit scale ``base / high`` (2
        entries in [-1, 1]), to the observation, so the correction can depend on it directly
        (the policy would otherwise have to recompute the controller from the observation).
    residual_mode : str
        With ``residual``: ``"add"`` (the correction is added) or ``"gain"`` (it scales each
        command by ``4 ** correction``); :func:`agents.sb3.residual.compose`.
    critic_state : bool
        Append each agent's true-state block for a centralised critic
        (:mod:`agents.sb3.central_critic`; simulation only): the observation space grows by
        ``P = critic_state_dims`` unbounded entries, after the env's observation.
    copy_offset : int
        These copies are copies ``copy_offset ..`` of a larger batch split across processes
        (:mod:`agents.sb3.batched_subproc`): copy ``k`` takes the seeds of copy
        ``copy_offset + k`` (first reset ``seed + copy_offset + k``, the residual base's
        reseeding), so the split rollout equals the unsplit one.
    """

    def __init__(
        self,
        env_kwargs: dict[str, Any],
        n_copies: int,
        seed: int | None = 0,
        residual: str | None = None,
        critic_state: bool = False,
        residual_observes_base: bool = False,
        residual_mode: str = "add",
        copy_offset: int = 0,
    ) -> None:
        from agents.sb3.residual import check_residual_mode

        if residual_observes_base and residual is None:
            raise ValueError("residual_observes_base needs a residual (--residual scripted:NAME)")
        if check_residual_mode(residual_mode) != "add" and residual is None:
            raise ValueError(f"residual_mode {residual_mode!r} needs a residual")
        self.residual_mode = residual_mode
        if isinstance(n_copies, bool) or not isinstance(n_copies, int) or n_copies < 1:
            raise ValueError(f"n_copies must be an int >= 1, got {n_copies!r}")
        if isinstance(copy_offset, bool) or not isinstance(copy_offset, int) or copy_offset < 0:
            raise ValueError(f"copy_offset must be an int >= 0, got {copy_offset!r}")
        self.copy_offset = copy_offset
        kwargs = dict(env_kwargs)
        if "world" in kwargs:
            raise ValueError("the batched VecEnv simulates its copies itself: no world= argument")
        preset = kwargs.pop("preset", "sim-6m-20")
        config = make_config(preset, kwargs.pop("config", None), **_config_overrides(kwargs))
        n = config.n_robots
        #: The localizer all copies' robots share, or ``None`` for an identity family: those
        #: know their teammates by index and read one World's truth, so K copies in one
        #: localizer would mix robots of different copies; each copy makes its own.
        self.shared: Any = None
        if not make_localizer(config.localizer, 1, config.phd).has_identities:
            self.shared = make_localizer(config.localizer, n * n_copies, config.phd)
        self.envs = [
            SwarmEnv(
                config=config,
                localizer=None if self.shared is None else LocalizerSlice(self.shared, k * n, n),
                **kwargs,
            )
            for k in range(n_copies)
        ]
        #: Each copy's infos for its current observation (:meth:`copy_infos`).
        self._infos: list[dict[str, dict[str, Any]]] = [{} for _ in range(n_copies)]
        first = self.envs[0]
        self.agents_per_copy = n
        self._high = np.array(first.action_space(first.possible_agents[0]).high, np.float64)
        space = first.observation_space(first.possible_agents[0])
        #: Entries of the scripted command in the observation (0 or 2).
        self.base_dims = 2 if residual_observes_base else 0
        #: Width of the critic block (0 without ``critic_state``).
        self.critic_dims = critic_state_dims(n, first.task) if critic_state else 0
        if self.base_dims or self.critic_dims:
            ones = np.ones(self.base_dims, np.float32)
            unbounded = np.full(self.critic_dims, np.inf, np.float32)
            space = gym.spaces.Box(
                np.concatenate([space.low, -ones, -unbounded]),
                np.concatenate([space.high, ones, unbounded]),
                dtype=np.float32,
            )
        super().__init__(n * n_copies, space, UNIT_ACTION_SPACE)
        self._actions: np.ndarray | None = None
        self._next_seed = None if seed is None else seed + copy_offset
        self._bases = None
        if residual is not None:
            from agents.sb3.residual import ResidualBase

            self._bases = [ResidualBase(residual, env) for env in self.envs]
            # The base's command for each copy's current (obs, infos), computed when the obs is
            # made and sent at the next step; an auto-reset episode reseeds its random walk
            # from (seed, copy, episode), so the rollout stays reproducible.
            self._base_commands: list[dict[str, np.ndarray] | None] = [None] * n_copies
            self._episodes = [0] * n_copies
            self._base_seed = 0 if seed is None else int(seed)

    def copy_infos(self, copy: int) -> dict[str, dict[str, Any]]:
        """The env's own ``infos`` for copy ``copy``'s current observation (what its last
        reset or step returned: sensor records and, in simulation, ground truth). The VecEnv
        does not pass them to SB3; a teacher labelling the copy reads them here. Plain dicts:
        the env builds each agent's info on first read (:class:`swarm_env.env.LazyInfo`), and
        the worker processes' copies arrive as plain dicts too."""
        return {agent: dict(info.items()) for agent, info in self._infos[copy].items()}

    def scripted_commands(self, copy: int) -> dict[str, np.ndarray]:
        """The residual base's commands ``[v_mps, omega_radps]`` per agent for copy ``copy``'s
        current observation: what a zero correction would send (residual mode only)."""
        if self._bases is None:
            raise ValueError(
                "scripted_commands needs a residual VecEnv (residual='scripted:NAME')"
            )
        return {a: c.copy() for a, c in self._base_commands[copy].items()}

    @property
    def action_high(self) -> np.ndarray:
        """``[v_max, omega_max]``: a unit action times this is the env command, shape (2,)."""
        return self._high.copy()

    # ------------------------------------------------------------------ VecEnv API
    def reset(self, copy_seeds: Sequence[int] | None = None) -> np.ndarray:
        """Reset every copy; ``copy_seeds`` (one int per copy) overrides the constructor's
        seed and :meth:`seed`, e.g. to give two copies the same episode (common random
        numbers, ``experiments/paired_returns.py``)."""
        seeds = copy_seeds_for_reset(
            len(self.envs), self.agents_per_copy, self._next_seed, self._seeds, copy_seeds
        )
        self._next_seed = None
        self._reset_seeds()
        return self.reset_with_seeds(seeds)

    def reset_with_seeds(self, seeds: Sequence[int | None]) -> np.ndarray:
        """Reset copy ``k`` with ``seeds[k]`` (``None``: its generator goes on); the observation
        (num_envs, D). What :meth:`reset` does once it has chosen the seeds."""
        seeds = _checked_seeds("seeds", seeds, len(self.envs), none_ok=True)
        obs = self._reset_copies(self._copies, seeds)
        return np.concatenate([obs[k] for k in self._copies])

    def step_async(self, actions: np.ndarray) -> None:
        # Checked before any copy moves: a bad entry must not leave some copies stepped.
        self._actions = check_unit_actions(actions, self.num_envs, self.agents_per_copy)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        n, actions = self.agents_per_copy, self._actions
        self._actions = None
        feeds = []
        for k, env in enumerate(self.envs):
            if self._bases is not None:
                from agents.sb3.residual import compose

                base = self._base_commands[k]
                commands = {
                    a: compose(base[a], actions[k * n + i], self._high, self.residual_mode)
                    for i, a in enumerate(env.possible_agents)
                }
            else:
                commands = {
                    a: scale_actions(actions[k * n + i], self._high)
                    for i, a in enumerate(env.possible_agents)
                }
            feeds.append(env.step_world(commands))
        self._step_localizers(dict(enumerate(feeds)))
        obs = np.zeros((self.num_envs, *self.observation_space.shape), np.float32)
        rewards = np.zeros(self.num_envs, np.float32)
        dones = np.zeros(self.num_envs, bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        ended = []
        for k, env in enumerate(self.envs):
            o, r, term, trunc, step_infos = env.finish_step()
            self._infos[k] = step_infos
            base = None
            if self._bases is not None and (env.agents or self.base_dims):
                # (on a terminal obs only to fill its entries: the reset below reseeds the base)
                base = self._base_commands[k] = self._bases[k](o, step_infos)
            obs[k * n : (k + 1) * n] = self._observation(env, o, base)
            for i, a in enumerate(env.possible_agents):
                j = k * n + i
                rewards[j] = r[a]
                dones[j] = term[a] or trunc[a]
                infos[j]["TimeLimit.truncated"] = bool(trunc[a] and not term[a])
            if env.agents:
                if dones[k * n : (k + 1) * n].any():
                    raise ValueError(
                        f"task {env.task.name!r} ended some agents of a copy but not all: "
                        "batched training needs tasks that end all agents together"
                    )
                continue
            for i in range(n):
                infos[k * n + i]["terminal_observation"] = obs[k * n + i].copy()
            # The finished episode's task metrics, once per copy (its first agent's entry).
            infos[k * n]["task_metrics"] = env.task.metrics()
            ended.append(k)
        if ended:
            fresh = self._reset_copies(ended, [None] * len(ended))
            for k in ended:
                obs[k * n : (k + 1) * n] = fresh[k]
        return obs, rewards, dones, infos

    def close(self) -> None:
        for env in self.envs:
            env.close()

    # SB3's contract: one result per VecEnv entry; an entry's env is its copy.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        n = self.agents_per_copy
        return [getattr(self.envs[i // n], attr_name) for i in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for k in self._copies_of(indices):
            setattr(self.envs[k], attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        results = {
            k: getattr(self.envs[k], method_name)(*args, **kwargs)
            for k in self._copies_of(indices)
        }
        return [results[i // self.agents_per_copy] for i in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [env.render() if env.render_mode == "rgb_array" else None for env in self.envs]

    # ------------------------------------------------------------------ internals
    @property
    def _copies(self) -> range:
        return range(len(self.envs))

    def _copies_of(self, indices) -> list[int]:
        """The copies holding the VecEnv entries ``indices`` (each copy once, in order)."""
        return sorted({i // self.agents_per_copy for i in self._indices(indices)})

    def _indices(self, indices) -> list[int]:
        return list(self._get_indices(indices))  # SB3's reading of None / int / iterable

    def _step_localizers(self, feeds: dict[int, SwarmFeed | None]) -> None:
        """Give the localizer(s) the feeds of the copies in ``feeds`` (``None``: the copy does
        not localize): one call of the shared localizer, the other copies' robots fed nothing
        (a no-op for them), or each copy's own localizer in turn."""
        n = self.agents_per_copy
        if self.shared is not None:
            parts = [
                SwarmFeed.empty(n) if feeds.get(k) is None else feeds[k] for k in self._copies
            ]
            self.shared.step(SwarmFeed.concat(parts))
            return
        for k, feed in feeds.items():
            if feed is not None:
                self.envs[k].localizer.step(feed)

    def _observation(
        self, env: SwarmEnv, obs: dict[str, np.ndarray], base: dict[str, np.ndarray] | None
    ) -> np.ndarray:
        """One copy's VecEnv rows (R, D [+ 2] [+ P]): the agents' observations, the scripted
        command in unit scale (``residual_observes_base``), then the critic block from the
        copy's ground truth (``critic_state``)."""
        agents = env.possible_agents
        parts = [np.stack([obs[a] for a in agents])]
        if self.base_dims:
            parts.append(base_in_unit_scale([base[a] for a in agents], self._high))
        if self.critic_dims:
            parts.append(critic_state(env.last_world_step.truth, env.task, len(agents)))
        return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]

    def _reset_copies(self, copies: Sequence[int], seeds: Sequence[int | None]) -> dict:
        """Reset ``copies`` (their robots' filters in one shared call); their obs per copy."""
        feeds = {k: self.envs[k].reset_world(seed=s) for k, s in zip(copies, seeds, strict=True)}
        self._step_localizers(feeds)
        out = {}
        for k, s in zip(copies, seeds, strict=True):
            obs, infos = self.envs[k].finish_reset()
            self._infos[k] = infos
            base = None
            if self._bases is not None:
                if s is None:
                    copy = self.copy_offset + k
                    s = 1_000_003 * (self._base_seed + 1) + 1009 * copy + self._episodes[k]
                self._bases[k].reset(int(s))
                self._episodes[k] += 1
                base = self._base_commands[k] = self._bases[k](obs, infos)
            out[k] = self._observation(self.envs[k], obs, base)
        return out


def copy_seeds_for_reset(
    n_copies: int,
    agents_per_copy: int,
    next_seed: int | None,
    entry_seeds: Sequence[int | None],
    copy_seeds: Sequence[int] | None,
) -> list[int | None]:
    """The seed of each copy at a reset: ``copy_seeds`` when given (checked: one int >= 0 per
    copy), else ``VecEnv.seed()``'s per-entry seeds (``entry_seeds``, the copy's first agent's)
    when it was called, else the constructor's ``next_seed + k`` (first reset only: ``None``
    after it, i.e. the copy's generator goes on; fresh entropy only for a copy never seeded)."""
    seeds = [None if next_seed is None else next_seed + k for k in range(n_copies)]
    if any(s is not None for s in entry_seeds):  # VecEnv.seed() was called: per entry
        seeds = [entry_seeds[k * agents_per_copy] for k in range(n_copies)]
    if copy_seeds is not None:
        seeds = _checked_seeds("copy_seeds", copy_seeds, n_copies, none_ok=False)
    return seeds


def _checked_seeds(
    name: str, seeds: Sequence[int | None], n_copies: int, none_ok: bool
) -> list[int | None]:
    """``seeds`` as a list of ``n_copies`` ints >= 0 (or None where ``none_ok``), else
    ``ValueError`` naming ``name`` and the value."""
    seeds = list(seeds)
    if len(seeds) != n_copies or not all(
        (none_ok and s is None)
        or (isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0)
        for s in seeds
    ):
        what = "ints >= 0 or None" if none_ok else "ints >= 0"
        raise ValueError(f"{name} must be {n_copies} {what} (one per copy), got {seeds!r}")
    return [None if s is None else int(s) for s in seeds]


def check_unit_actions(actions: Any, num_envs: int, agents_per_copy: int) -> np.ndarray:
    """``actions`` (num_envs, 2) as an array of its own dtype, or ``ValueError`` naming the
    shape or the first non-finite entry (its copy and agent); unit actions are clipped later."""
    values = np.asarray(actions)  # the dtype kept: the rollout stays bit-identical
    if values.dtype.kind not in "fiu":
        raise ValueError(f"actions must be a real ({num_envs}, 2) array, got dtype {values.dtype}")
    if values.shape != (num_envs, 2):
        raise ValueError(f"actions must have shape ({num_envs}, 2), got {values.shape}")
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        j = int(bad[0])
        raise ValueError(
            f"actions[{j}] (copy {j // agents_per_copy}, agent {j % agents_per_copy}) is not "
            f"finite: {values[j].tolist()}"
        )
    return values


def _config_overrides(kwargs: dict[str, Any]) -> dict[str, Any]:
    """Split the env kwargs that are SwarmConfig overrides from the SwarmEnv arguments."""
    env_args = {"task", "task_params", "render_mode", "render_agent", "world"}
    return {k: kwargs.pop(k) for k in list(kwargs) if k not in env_args}


def batched_vec_env(
    env_kwargs: dict[str, Any],
    n_copies: int = 4,
    seed: int | None = 0,
    n_workers: int = 0,
    **options: Any,
):
    """``n_copies`` copies stepped in this process (:class:`BatchedSwarmVecEnv`, ``n_workers``
    0) or split across ``n_workers`` worker processes
    (:class:`~agents.sb3.batched_subproc.SubprocBatchedVecEnv`, the same rollout); ``options``
    are :class:`BatchedSwarmVecEnv`'s (``residual``, ``critic_state``, ...)."""
    if isinstance(n_workers, bool) or not isinstance(n_workers, int) or n_workers < 0:
        raise ValueError(f"n_workers must be an int >= 0 (0: in this process), got {n_workers!r}")
    if n_workers == 0:
        return BatchedSwarmVecEnv(env_kwargs, n_copies, seed, **options)
    from agents.sb3.batched_subproc import SubprocBatchedVecEnv

    return SubprocBatchedVecEnv(env_kwargs, n_copies, n_workers, seed, **options)


def make_batched_vec_env(
    env_kwargs: dict[str, Any],
    n_copies: int = 4,
    seed: int | None = 0,
    monitor_file: str | None = None,
    residual: str | None = None,
    critic_state: bool = False,
    residual_observes_base: bool = False,
    residual_mode: str = "add",
    n_workers: int = 0,
):
    """:func:`batched_vec_env` wrapped in SB3's ``VecMonitor`` (episode statistics)."""
    from stable_baselines3.common.vec_env import VecMonitor

    venv = batched_vec_env(
        env_kwargs,
        n_copies,
        seed,
        n_workers,
        residual=residual,
        critic_state=critic_state,
        residual_observes_base=residual_observes_base,
        residual_mode=residual_mode,
    )
    return VecMonitor(venv, filename=monitor_file)
