"""SwarmEnv: a PettingZoo parallel env of a UGV swarm in which every agent observes its own
estimate of its teammates (GM-PHD by default, any family of :mod:`localization.registry`).

| Import              | ``from swarm_env import parallel_env``                     |
|---------------------|------------------------------------------------------------|
| Actions             | Continuous ``[v_mps, omega_radps]``                        |
| Parallel API        | Yes (AEC form: ``swarm_env.env()``; robots act together)   |
| Agents              | ``ugv_0`` ... ``ugv_{n-1}`` (20 in ``sim-6m-20``)          |
| Action shape        | (2,)                                                       |
| Observation         | own estimate (top-K rows) + own speed + task features      |
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from localization.feed import SwarmFeed
from localization.protocol import Localizer
from localization.registry import make_localizer
from swarm_core.records import RobotMeasurements
from swarm_core.signal_chain import unwrap_signal
from swarm_core.world import World, WorldStep
from swarm_env import observation as obs_lib
from swarm_env.config import SwarmConfig, make_config
from swarm_env.tasks import Task, make_task
from swarm_env.world.sim import SimWorld


class SwarmEnv(ParallelEnv):
    """A swarm of differential-drive UGVs with embedded robot-centric localization.

    ## Description
    ``n_robots`` DFRobot Cherokey UGVs move in a walled arena with decoy posts (lidar false
    positives), red decoys (camera false positives) and box obstacles (occluders). Each robot has
    wheel odometry (1920 pulses/rev, 10 Hz), a 720-beam 7 Hz lidar with four blind sectors and
    inter-lidar interference, and a 360-degree colour-blob camera (30 Hz, bearings only). Every
    robot runs its own filter (``localizer=``: the GM-PHD of :class:`localization.RobotCentricPHD`
    by default, or the Poisson multi-Bernoulli ``pmb-lc``...; all robots' filters advance in one
    :class:`~localization.protocol.Localizer` call per step) on its own anonymous measurements,
    at their own rates and timestamps, and *that estimate is the agent's observation*. Frames
    follow REP-103: x forward, y left, yaw counter-clockwise, SI units.

    ## Action Space
    ``Box([-v_max, -w_max], [v_max, w_max], float32)`` per agent:

    | Num | Action                          | Min     | Max    |
    |-----|---------------------------------|---------|--------|
    | 0   | forward speed ``v`` (m/s)       | -0.3    | 0.3    |
    | 1   | turn rate ``omega`` (rad/s, CCW)| -1.5    | 1.5    |

    Out-of-range actions are **clipped** to the box (the motor controller's limits). Non-finite
    values, a wrong shape, or a missing or unknown agent raise ``ValueError`` before anything
    moves. The motors then approach the command within the acceleration limits.

    ## Observation Space
    ``Box(float32)`` of size ``7 K + 2 + F`` (K = ``top_k`` = 16, F = task features):

    | Slice               | Observation                                      | Min   | Max  |
    |---------------------|--------------------------------------------------|-------|------|
    | ``7k + 0``          | component weight ``w`` (largest first)           | 0     | 10   |
    | ``7k + 1 : 7k + 3`` | component mean ``x, y``, agent's frame (m)       | -20   | 20   |
    | ``7k + 3``          | covariance ``sxx`` (m^2)                         | 0     | 25   |
    | ``7k + 4``          | covariance ``sxy`` (m^2)                         | -25   | 25   |
    | ``7k + 5``          | covariance ``syy`` (m^2)                         | 0     | 25   |
    | ``7k + 6``          | row valid (1) or padding (0)                     | 0     | 1    |
    | ``7K : 7K + 2``     | own odometry ``v`` (m/s), ``omega`` (rad/s)      | -vmax | vmax |
    | ``7K + 2 :``        | task features (e.g. the formation radius)        | task  | task |

    ``observation="truth"`` fills the table with the true neighbours within
    ``localization_range_m`` (``w = 1``, zero covariance); ``observation="measurements"`` gives
    padded raw lidar detections and camera bearings instead (see :mod:`swarm_env.observation`).

    ## Rewards
    Defined by the task (``task=``); ``wander`` gives 0. Rewards use ground truth.

    ## Starting State
    Obstacles and robots are placed uniformly at random without overlap (seeded); headings are
    uniform; filters start empty.

    ## Episode End
    1. Termination: defined by the task (``wander``: never).
    2. Truncation: after ``max_steps`` steps (3000 = the Perera 2021 study's 300 s).

    ## Arguments
    >>> from swarm_env import parallel_env
    >>> env = parallel_env(preset="lab-3m-4", max_steps=50)
    >>> obs, infos = env.reset(seed=0)
    >>> obs["ugv_0"].shape
    (114,)

    | Parameter     | Type        | Default      | Description                                   |
    |---------------|-------------|--------------|-----------------------------------------------|
    | preset        | str         | "sim-6m-20"  | "sim-6m-20" (6x6 m, 20), "lab-3m-4" (3x3 m, 4)|
    | config        | SwarmConfig | None         | a full config instead of a preset             |
    | task          | str / Task  | "wander"     | see :mod:`swarm_env.tasks`                    |
    | task_params   | dict        | {}           | keyword arguments of the task                 |
    | render_mode   | str         | None         | "rgb_array" or "human"                        |
    | render_agent  | str         | "ugv_0"      | whose sensors the renderer draws              |
    | world         | World       | None         | another World (real robots, replay)           |
    | localizer     | str / Loc.  | "phd"        | a family name (``swarm-phd list``) or a built |
    |               |             |              | Localizer of ``n_robots`` robots              |
    | **overrides   |             |              | any ``SwarmConfig`` field, e.g. ``n_robots=8``|

    ``infos[agent]`` holds ``time_s``, ``truth`` (pose, neighbours in the agent's frame, range and
    visibility per sensor; absent without ground truth), ``measurements`` (the raw records of the
    step, as dicts of arrays), ``stale`` (sensors reported silent by a real World) and ``comms``
    (the teammates' :class:`~swarm_core.records.Broadcast` received this step, with
    ``comms={"enabled": True}``; see :mod:`swarm_env.comms`). Each agent's info is a ``dict``
    built on first use (:class:`LazyInfo`): a loop that never reads them does not pay for them.

    ## Pickling
    An env that simulates its World (the one it builds, or a ``SimWorld`` passed as ``world=``)
    pickles exactly, whatever its other arguments (a family name or a built ``Localizer``, a
    task name or a ``Task``): an unpickled copy continues bit for bit (observations, rewards,
    infos), robots in contact with each other or the walls included. pymunk's contact cache
    (the impulses it warm-starts the next step's contacts from) does not pickle, so such an env
    pickles as its constructor arguments (a ``Localizer`` or ``SimWorld`` as it is; the replayed
    reset puts it back to its initial state), its last reset (the seed, or the generator an
    unseeded reset drew from) and the commands since, and unpickling re-simulates them. The
    record holds the current episode only, however many episodes a training run has had: it
    grows by one ``(n_robots, 2)`` float64 array per step (about ``16 n_robots + 40`` bytes
    pickled, ``16 n_robots + 190`` bytes in memory) up to ``max_steps``, and unpickling costs
    the simulation of the steps since the last reset (about as long as running them, without
    the policy). An episode of ``max_steps = 3000`` with 20 robots records at most about 1.1 MB
    pickled (1.5 MB in memory).
    ``SimWorld.place_robots`` is not recorded: an env pickled after a placement
    re-simulates without it. Any other World (real robots, a replay, a subclass of
    ``SimWorld``) pickles as its objects do: nothing is re-simulated, and a simulated one's
    robots in contact at pickling time then continue from a cold contact cache.

    ## Version History
    * v0: initial release.
    """

    metadata = {
        "name": "swarm_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        preset: str = "sim-6m-20",
        *,
        config: SwarmConfig | None = None,
        task: str | Task = "wander",
        task_params: dict[str, Any] | None = None,
        render_mode: str | None = None,
        render_agent: str = "ugv_0",
        world: World | None = None,
        localizer: str | Localizer | None = None,
        **overrides: Any,
    ) -> None:
        if isinstance(localizer, str):  # a family name: the config field of that name
            overrides["localizer"], localizer = localizer, None
        self.config = make_config(preset, config, **overrides)
        # An env that simulates its World (its own, or a SimWorld passed in) pickles as its
        # constructor arguments plus its last reset (a seed, or the generator it reset from)
        # and the commands since, and re-simulates them on unpickling (see __getstate__):
        # pymunk's contact cache does not pickle. A Localizer or SimWorld passed in is pickled
        # as it is at pickling time; the replayed reset puts it back to its initial state
        # (``Localizer.reset`` restores every filter, random streams included; ``World.reset``
        # lays out a new space), so the replay starts from the same state as the episode did.
        # The record holds one episode at most.
        self._rebuild_args: dict[str, Any] | None = (
            {
                "config": self.config,
                "task": task if isinstance(task, str) else copy.deepcopy(task),
                "task_params": copy.deepcopy(task_params),
                "render_mode": render_mode,
                "render_agent": render_agent,
                "world": world,
                "localizer": localizer,
            }
            if world is None or type(world) is SimWorld  # a subclass may keep state of its own
            else None
        )
        self._replay_log: list[tuple[str, Any]] = []
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        # Video wrappers play one frame per step at ``render_fps``: the control rate.
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.config.control_period_s}
        if task_params is not None and not isinstance(task_params, Mapping):
            raise ValueError(f"task_params must be None or a dict, got {task_params!r}")
        if world is not None and not isinstance(world, World):
            raise ValueError(f"world must be None or a World, got {world!r}")
        self.task = make_task(task, **(task_params or {}))
        self.task.check_arena(self.config.arena)  # an impossible task refused here, not at reset
        if self.task.needs_estimates and not self.config.localize:
            raise ValueError(
                f"task {self.task.name!r}: localization_term='estimate' scores the robots' own "
                "estimates, which localize=False switches off"
            )
        self.world: World = (
            world if world is not None else SimWorld(self.config, n_extra=self.task.n_extra_robots)
        )
        self.possible_agents = list(self.world.robot_ids)
        if len(self.possible_agents) != self.config.n_robots:
            raise ValueError(
                f"world has {len(self.possible_agents)} robots but n_robots={self.config.n_robots}"
            )
        if render_agent not in self.possible_agents:
            raise ValueError(f"render_agent {render_agent!r} is not one of the agents")
        self.render_agent = render_agent
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}

        robot = self.config.robot
        self._action_high = np.array([robot.max_speed_mps, robot.max_turn_rate_radps])
        action_space = spaces.Box(
            -self._action_high.astype(np.float32),
            self._action_high.astype(np.float32),
            dtype=np.float32,
        )
        feature_low, feature_high = self.task.feature_bounds()
        #: What each agent observes (``config.observation``), with its named columns.
        self.encoder = obs_lib.make_encoder(
            self.config.observation,
            self.config.top_k,
            int(np.size(feature_low)),
            self.config.lidar_sectors,
            self.config.lidar_sector_max_m,
        )
        observation_space = self.encoder.space(
            robot.max_speed_mps, robot.max_turn_rate_radps, feature_low, feature_high
        )
        # One space object per agent, identical, returned on every call (PettingZoo API).
        self.action_spaces = {a: copy.deepcopy(action_space) for a in self.possible_agents}
        self.observation_spaces = {a: observation_space for a in self.possible_agents}

        # Every robot's own filter (the family ``config.localizer``), advanced once per step
        # for the whole swarm; ``localizers[i]`` reads robot i's mixture and estimates.
        if localizer is None:
            localizer = make_localizer(
                self.config.localizer, len(self.possible_agents), self.config.phd
            )
        elif not isinstance(localizer, Localizer) or localizer.n_robots != self.config.n_robots:
            raise ValueError(
                f"localizer must be a Localizer of {self.config.n_robots} robots, got "
                f"{localizer!r}"
            )
        else:  # the config names the family it runs
            self.config = dataclasses.replace(self.config, localizer=localizer.name)
        self.localizer: Localizer = localizer
        self.localizers = self.localizer.views
        #: Global ground-truth state for centralised critics (:meth:`state`): per robot
        #: ``[x_m, y_m, cos yaw, sin yaw, ...]`` then its ``[v_mps, omega_radps]`` odometry.
        self.state_space = spaces.Box(
            -np.inf, np.inf, shape=(len(self.possible_agents) * 6,), dtype=np.float32
        )
        self._rng: np.random.Generator | None = None
        self._step_count = 0
        self._last_step: WorldStep | None = None
        self._velocity = np.zeros((self.config.n_robots, 2))
        # The last lidar detections / camera bearings of every robot (``measurements`` obs).
        self.last_detections = [np.zeros((0, 2)) for _ in self.possible_agents]
        self.last_bearings = [np.zeros(0) for _ in self.possible_agents]
        self._renderer = None
        self._closed = False
        self._last_commands = np.zeros((len(self.possible_agents), 2))
        # The first env of a process whose kernels are not cached yet says it will compile
        # (the first step() then takes about a minute; see swarm_env.kernel_cache).
        from swarm_env.kernel_cache import first_use_note

        first_use_note()

    # ------------------------------------------------------------------ PettingZoo API
    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    @property
    def last_world_step(self) -> WorldStep | None:
        """What the World returned at the last reset/step (records and ground truth)."""
        return self._last_step

    @property
    def time_s(self) -> float:
        return self._last_step.time_s if self._last_step is not None else 0.0

    def reset(self, seed: int | None = None, options: dict | None = None):
        feed = self.reset_world(seed, options)
        with self._halting_on_error():
            if feed is not None:
                self.localizer.step(feed)
        return self.finish_reset()

    def step(self, actions: dict[str, Any]):
        feed = self.step_world(actions)
        with self._halting_on_error():
            if feed is not None:
                self.localizer.step(feed)
        return self.finish_step()

    # A step in three phases, so that a batch of env copies can share one localizer call
    # (``agents.sb3.batched``): the World moves (``step_world``), the localizer consumes the
    # returned feed, then rewards and observations are made (``finish_step``). ``step()`` is
    # the three in a row; so is ``reset()``.
    def reset_world(self, seed: int | None = None, options: dict | None = None):
        """Phase 1 of :meth:`reset`: validate, reseed, reset the World, the task and this env's
        robots in the localizer. Returns the first :class:`~localization.feed.SwarmFeed` (or
        ``None`` with ``localize=False``) for the localizer to consume before
        :meth:`finish_reset`."""
        if self._closed:
            raise RuntimeError("reset() called after close()")
        if seed is not None and (
            isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
        ):
            raise ValueError(f"seed must be None or an int >= 0, got {seed!r}")
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be None or a dict, got {options!r}")
        if options:  # this env takes none; a warning, not an error: PettingZoo's own API
            # test (parallel_api_test) resets with options={"options": 1}
            warnings.warn(f"reset() ignores options {sorted(map(str, options))}", stacklevel=3)
        with self._halting_on_error():
            if seed is not None or self._rng is None:
                self._rng, seed = seeding.np_random(None if seed is None else int(seed))
                for i, agent in enumerate(self.possible_agents):
                    self.action_spaces[agent].seed(None if seed is None else seed + i)
                self._replay_log = [("reset", int(seed))]  # everything since is replayable
            else:
                # A new episode depends on nothing of the previous ones but the generator
                # (the World, the task and the filters start anew from its child streams): the
                # log restarts here, from a copy of it, so it holds one episode at most,
                # however many episodes a training run has.
                self._replay_log = [("reset_from", copy.deepcopy(self._rng))]
            # One generator per env; the world and the task get their own child streams.
            world_rng, task_rng = self._rng.spawn(2)
            # Not steppable until the World and the task have reset: a layout that cannot be
            # placed leaves an env that says so on step(), not a half-reset one that steps.
            self.agents, self._last_step = [], None
            self._step_count = 0
            self.localizer.reset()
            self.encoder.reset()
            self._velocity[:] = 0.0
            for i in range(len(self.possible_agents)):
                self.last_detections[i] = np.zeros((0, 2))
                self.last_bearings[i] = np.zeros(0)
            step = self.world.reset(world_rng)
            # Obstacle geometry, where the World knows it (the sim), for task rewards only.
            self.task.reset(step.truth, task_rng, self.config.arena, layout=self.world.layout)
            self.agents = list(self.possible_agents)
            return self._absorb(step)

    def finish_reset(self):
        """Phase 2 of :meth:`reset`: ``(observations, infos)``."""
        with self._halting_on_error():
            step = self._last_step
            obs = self._observations(step)
            infos = self._infos(step)
            if self.render_mode == "human":
                self.render()
        return obs, infos

    def step_world(self, actions: dict[str, Any]):
        """Phase 1 of :meth:`step`: validate ``actions`` (nothing changes on bad input), move
        the World one control period. Returns the step's feed for the localizer (``None``
        with ``localize=False``); :meth:`finish_step` completes the step."""
        if self._closed:
            raise RuntimeError("step() called after close()")
        if not self.agents:
            raise RuntimeError(
                "step() called before a successful reset()"
                if self._last_step is None
                else "step() called on a finished episode: call reset() first"
            )
        with self._halting_on_error():
            # Bad actions raise before the env changes, and stop real robots (halt) first.
            commands = self._validate_actions(actions)
            extra = self.task.extra_commands(
                self._last_step.truth if self._last_step else None, self.config.control_period_s
            )
            step = self.world.step(commands, extra_commands=extra)
            # One (N, 2) array per step: the live agents' rows are replayed (the replay has
            # the same live agents at every step), the others are zeros.
            self._replay_log.append(("step", commands.copy()))
            self._step_count += 1
            self._last_commands = commands
            return self._absorb(step)

    def finish_step(self):
        """Phase 2 of :meth:`step`: ``(observations, rewards, terminations, truncations,
        infos)`` of the step :meth:`step_world` made."""
        with self._halting_on_error():
            step = self._last_step
            if self.task.needs_estimates:  # the estimate after this step's update
                self.task.observe_estimates(*self.localizer.padded_tables())
            rewards_arr = self.task.rewards(step.truth, self._last_commands)
            term = np.broadcast_to(
                np.asarray(self.task.terminated(step.truth), dtype=bool),
                (len(self.possible_agents),),
            )
            truncated = self._step_count >= self.config.max_steps
            obs = self._observations(step)
            infos = self._infos(step)
            rewards = {a: float(rewards_arr[self._index[a]]) for a in self.agents}
            terminations = {a: bool(term[self._index[a]]) for a in self.agents}
            truncations = {a: truncated for a in self.agents}
            self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
            if self.render_mode == "human":
                self.render()
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global ground-truth state, for centralised critics (MAPPO-style training).

        Per robot, in agent order: ``[x_m, y_m, cos yaw, sin yaw, v_mps, omega_radps]`` (world
        frame; speeds from odometry), flattened to ``state_space.shape`` (float32). Raises
        ``ValueError`` on a World without ground truth (real robots without motion capture).
        """
        step = self._last_step
        if step is None:
            raise RuntimeError("state() called before reset()")
        if step.truth is None:
            raise ValueError("state() needs ground truth, which this World lacks")
        poses = step.truth.poses[: len(self.possible_agents)]
        out = np.column_stack(
            [poses[:, :2], np.cos(poses[:, 2]), np.sin(poses[:, 2]), self._velocity]
        )
        return out.astype(np.float32).ravel()

    def render(self):
        if self.render_mode is None:
            warnings.warn(
                "render() called without a render_mode: pass render_mode='rgb_array' or "
                "'human' to the env's constructor",
                stacklevel=2,
            )
            return None
        if self._renderer is None:
            from swarm_env.render import Renderer

            self._renderer = Renderer(self, mode=self.render_mode)
        return self._renderer.draw()

    def close(self) -> None:
        self._closed = True
        try:
            if self._renderer is not None:
                self._renderer.close()
                self._renderer = None
        finally:
            self.world.close()

    def __getstate__(self) -> dict[str, Any]:
        if self._rebuild_args is not None:
            # Exact: rebuilt from its arguments and re-simulated (same seed, same commands,
            # same state bit for bit, contacts included); the action spaces keep their RNGs.
            return {
                "rebuild": self._rebuild_args,
                # A compiled bank pickles without the registry name it was built under.
                "localizer_name": self.localizer.name,
                "replay": self._replay_log,
                "action_spaces": self.action_spaces,
                "closed": self._closed,
            }
        state = self.__dict__.copy()  # real robots, a replay, a SimWorld subclass: as is
        state["_renderer"] = None  # windows and canvases do not pickle; recreated on demand
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        if "rebuild" not in state:
            self.__dict__.update(state)
            return
        rebuild = state["rebuild"]
        if rebuild.get("localizer") is not None and "localizer_name" in state:
            rebuild["localizer"].name = state["localizer_name"]
        self.__init__(**rebuild)  # type: ignore[misc]
        render_mode, self.render_mode = self.render_mode, None  # no windows while replaying
        try:
            for kind, value in state["replay"]:
                if kind == "reset":
                    self.reset(seed=value)
                elif kind == "reset_from":  # an unseeded reset, from the generator it had
                    self._rng = copy.deepcopy(value)
                    self.reset()
                elif isinstance(value, dict):  # an env pickled as {agent: command} per step
                    self.step(value)
                else:
                    self.step({a: value[self._index[a]] for a in self.agents})
        finally:
            self.render_mode = render_mode
        self.action_spaces = state["action_spaces"]
        if state["closed"]:
            self.close()

    # ------------------------------------------------------------------ internals
    @contextlib.contextmanager
    def _halting_on_error(self):
        """Stop every robot (``World.halt``) on any exception before it propagates: on real
        robots a failure in the task, filter or observation code must not leave them moving.
        A signal's exception that a compiled kernel's callback wrapped in a ``SystemError``
        is re-raised as itself (:func:`swarm_core.signal_chain.unwrap_signal`), so a caller's
        ``except KeyboardInterrupt`` (or ``SystemExit``, SIGTERM's) still sees it."""
        try:
            yield
        except BaseException as exc:
            self.world.halt()
            signal_exc = unwrap_signal(exc) if isinstance(exc, SystemError) else None
            if signal_exc is None:
                raise
            raise signal_exc from None

    def _validate_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Check every action before anything changes; return clipped commands (N, 2)."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict agent -> (2,) array, got {type(actions)}")
        unknown = sorted(map(repr, set(actions) - set(self.agents)))
        if unknown:
            raise ValueError(f"unknown or finished agent(s) {unknown}; live agents: {self.agents}")
        missing = sorted(set(self.agents) - set(actions))
        if missing:
            raise ValueError(f"missing action for agent(s) {missing}")
        agents = list(actions)
        for agent in agents:  # cheap type gate: no strings, bools, complex or autograd tensors
            _check_action_type(agent, actions[agent])
        try:
            values = np.asarray([actions[a] for a in agents], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            values = None  # ragged or non-numeric: find the culprit below
        if values is None or values.shape != (len(agents), 2) or not np.isfinite(values).all():
            for agent in agents:  # slow path, only to name the agent and the value
                _check_action(agent, actions[agent])
        commands = np.zeros((len(self.possible_agents), 2))
        rows = [self._index[a] for a in agents]
        commands[rows] = np.clip(values, -self._action_high, self._action_high)
        return commands

    def _absorb(self, step: WorldStep) -> SwarmFeed | None:
        """Keep the step's last readings; the whole swarm's records as the localizer's feed."""
        self._last_step = step
        empty = RobotMeasurements()
        for i, agent in enumerate(self.possible_agents):
            records = step.measurements.get(agent, empty)
            stale = step.stale.get(agent, ())
            if records.odometry and "odometry" not in stale:
                self._velocity[i] = records.odometry[-1].velocity
            if records.lidar and "lidar" not in stale:
                self.last_detections[i] = records.lidar[-1].detections
            if records.camera and "camera" not in stale:
                self.last_bearings[i] = records.camera[-1].bearings_rad
        if not self.config.localize:
            return None
        return SwarmFeed.from_world_step(step, self.possible_agents)

    def _observations(self, step: WorldStep) -> dict[str, np.ndarray]:
        features = self.task.features(len(self.possible_agents))
        rows = [self._index[a] for a in self.agents]
        source = obs_lib.EncoderInput(
            self.possible_agents,
            self.localizer.padded_tables,
            self.last_detections,
            self.last_bearings,
        )
        tables = self.encoder.tables(source, step, rows)
        # One (agents, D) array for everyone (identical spaces); each agent gets its row.
        space = self.observation_spaces[self.possible_agents[0]]
        obs = obs_lib.assemble_rows(
            space,
            tables,
            self._velocity[rows],
            np.asarray(features)[rows].reshape(len(rows), -1),
        )
        return dict(zip(self.agents, obs, strict=True))

    def _infos(self, step: WorldStep) -> dict[str, dict[str, Any]]:
        """Every live agent's info, each a :class:`LazyInfo` that builds its dict on first use
        (a training loop that never reads them pays for none)."""
        return {agent: LazyInfo(self._agent_info, step, agent) for agent in self.agents}

    def _agent_info(self, step: WorldStep, agent: str) -> dict[str, Any]:
        """``infos[agent]`` of ``step`` (the class docstring lists its keys)."""
        i = self._index[agent]
        truth = step.truth
        info: dict[str, Any] = {
            "time_s": step.time_s,
            "measurements": measurements_as_dict(step.measurements.get(agent, _NO_RECORDS)),
            "stale": tuple(step.stale.get(agent, ())),
            "comms": step.comms.get(agent, []),
        }
        if truth is not None:
            # Views, not copies: every step's GroundTruth is new and never written to.
            info["truth"] = {
                "pose": truth.poses[i],
                "neighbours_xy": truth.relative_xy[i],
                "in_range": {k: v[i] for k, v in truth.in_range.items()},
                "visible": {k: v[i] for k, v in truth.visible.items()},
            }
        return info


_NO_RECORDS = RobotMeasurements()


class LazyInfo(dict):
    """One agent's info: a ``dict`` whose items are made by ``build(*args)`` on first use.

    Building twenty agents' dicts of records every step costs ~5 % of a step that no training
    loop reads. A ``LazyInfo`` is a real ``dict`` (PettingZoo's API test checks
    ``isinstance(info, dict)``) whose every read, write, comparison, copy and pickle fills it
    first; copies and pickles are plain dicts. ``build``'s inputs must not change before the
    first use (the env passes a step's records and truth, which are never written to).
    """

    __slots__ = ("_build", "_args")

    def __init__(self, build: Any, *args: Any) -> None:
        super().__init__()
        self._build = build
        self._args = args

    def _fill(self) -> None:
        build, self._build = self._build, None
        if build is not None:
            dict.update(self, build(*self._args))
            self._args = ()

    def __eq__(self, other: object) -> bool:
        self._fill()
        if isinstance(other, LazyInfo):
            other._fill()
        return dict.__eq__(self, other)

    def __ne__(self, other: object) -> bool:
        result = self.__eq__(other)
        return result if result is NotImplemented else not result

    __hash__ = None  # type: ignore[assignment]  # as dict's

    def __reduce_ex__(self, protocol: int) -> tuple:
        return dict, (dict(self.items()),)

    def __copy__(self) -> dict:
        return dict(self.items())

    def __deepcopy__(self, memo: dict) -> dict:
        return copy.deepcopy(dict(self.items()), memo)


def _filling(name: str) -> Any:
    method = getattr(dict, name)

    def filled_first(self, *args, **kwargs):
        if self._build is not None:
            self._fill()
        return method(self, *args, **kwargs)

    filled_first.__name__ = name
    filled_first.__doc__ = method.__doc__
    return filled_first


for _name in (
    "__getitem__", "__setitem__", "__delitem__", "__contains__", "__iter__", "__reversed__",
    "__len__", "__repr__", "__or__", "__ror__", "__ior__", "__sizeof__",
    "keys", "values", "items", "get", "copy", "pop", "popitem", "setdefault", "update", "clear",
):  # fmt: skip
    setattr(LazyInfo, _name, _filling(_name))
del _name


def measurements_as_dict(m: RobotMeasurements) -> dict[str, list[dict[str, Any]]]:
    """Records as plain dicts of arrays (comparable with ``data_equivalence``, JSON-friendly)."""
    return {
        "odometry": [
            {"stamp_s": r.stamp_s, "delta": r.delta, "velocity": r.velocity} for r in m.odometry
        ],
        "lidar": [
            {
                "stamp_s": r.stamp_s,
                "angles_rad": r.angles_rad,
                "ranges_m": r.ranges_m,
                "intensities": r.intensities,
                "detections": r.detections,
                "null_bearings_rad": r.null_bearings_rad,
            }
            for r in m.lidar
        ],
        "camera": [{"stamp_s": r.stamp_s, "bearings_rad": r.bearings_rad} for r in m.camera],
    }


def _check_action(agent: str, action: Any) -> None:
    """Raise ``ValueError`` naming ``agent`` and the value unless ``action`` is a finite (2,)."""
    try:
        value = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"action of {agent} is not a finite number pair: {action!r}") from exc
    if value.shape != (2,):
        raise ValueError(
            f"action of {agent} must have shape (2,) [v_mps, omega_radps], got shape "
            f"{value.shape}: {action!r}"
        )
    if not np.all(np.isfinite(value)):
        raise ValueError(f"action of {agent} must be finite, got {value.tolist()}")


def _check_action_type(agent: str, action: Any) -> None:
    """Raise ``ValueError`` naming ``agent`` unless ``action`` holds real numbers (no silent
    coercion of strings, bools or complex numbers; no autograd tensor, whose graph would be
    dropped)."""
    if isinstance(action, np.ndarray):
        if action.dtype.kind not in "iuf":
            raise ValueError(
                f"action of {agent} must hold real numbers, got dtype {action.dtype}: {action!r}"
            )
        return
    if isinstance(action, (list, tuple)):
        for value in action:
            if isinstance(value, (bool, np.bool_)) or not isinstance(
                value, (int, float, np.integer, np.floating)
            ):
                raise ValueError(
                    f"action of {agent} must hold real numbers, got {value!r} in {action!r}"
                )
        return
    if getattr(action, "requires_grad", False):
        raise ValueError(f"action of {agent} is a tensor that requires grad: detach() it first")
    kind = _dtype_kind(getattr(action, "dtype", None))
    if kind is not None:  # a tensor or scalar: its dtype decides (a bool tensor is no speed)
        if kind not in "iuf":
            raise ValueError(
                f"action of {agent} must hold real numbers, got dtype {action.dtype}: {action!r}"
            )
        return
    if isinstance(action, (str, bytes, bool, complex)) or np.iscomplexobj(action):
        raise ValueError(f"action of {agent} must hold real numbers, got {action!r}")


def _dtype_kind(dtype: Any) -> str | None:
    """numpy's kind letter of a numpy, torch or array-API dtype (``torch.bool`` -> ``'b'``,
    ``torch.bfloat16`` -> ``'f'``); None without a dtype or for one it cannot name."""
    if dtype is None:
        return None
    try:
        return np.dtype(dtype).kind
    except TypeError:
        pass
    name = str(dtype).rsplit(".", 1)[-1]
    try:
        return np.dtype(name).kind
    except TypeError:
        return "f" if name.startswith("bfloat") else None
