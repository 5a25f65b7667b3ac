"""SwarmEnv: a PettingZoo parallel env of a UGV swarm in which every agent observes its own PHD.

| Import              | ``from swarm_env import parallel_env``                     |
|---------------------|------------------------------------------------------------|
| Actions             | Continuous ``[v_mps, omega_radps]``                        |
| Parallel API        | Yes (no AEC layer: robots act simultaneously)              |
| Agents              | ``ugv_0`` ... ``ugv_{n-1}`` (20 in ``seed-sim``)            |
| Action shape        | (2,)                                                       |
| Observation         | own GM-PHD estimate (top-K components) + own speed + task  |
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from localization import PHDBank
from swarm_core.records import LidarRecord, OdometryRecord, RobotMeasurements
from swarm_core.world import GroundTruth, World, WorldStep
from swarm_env import observation as obs_lib
from swarm_env.config import SwarmConfig, make_config
from swarm_env.tasks import Task, make_task
from swarm_env.world.sim import SimWorld


class SwarmEnv(ParallelEnv):
    """A swarm of differential-drive UGVs with embedded robot-centric GM-PHD localization.

    ## Description
    ``n_robots`` DFRobot Cherokey UGVs move in a walled arena with decoy posts (lidar false
    positives), red decoys (camera false positives) and box obstacles (occluders). Each robot has
    wheel odometry (1920 pulses/rev, 10 Hz), a 720-beam 7 Hz lidar with four blind sectors and
    inter-lidar interference, and a 360-degree colour-blob camera (30 Hz, bearings only). Every
    robot runs its own GM-PHD filter (the model of :class:`localization.RobotCentricPHD`; all
    robots' filters advance in one compiled :class:`localization.PHDBank` call per step) on its
    own anonymous measurements, at their own rates and timestamps, and *that estimate is the
    agent's observation*. Frames follow REP-103: x forward, y left, yaw counter-clockwise, SI
    units.

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
    2. Truncation: after ``max_steps`` steps (3000 = the seed's 300 s).

    ## Arguments
    >>> from swarm_env import parallel_env
    >>> env = parallel_env(preset="seed-lab", max_steps=50)
    >>> obs, infos = env.reset(seed=0)
    >>> obs["ugv_0"].shape
    (114,)

    | Parameter     | Type        | Default      | Description                                   |
    |---------------|-------------|--------------|-----------------------------------------------|
    | preset        | str         | "seed-sim"   | "seed-sim" (6x6 m, 20), "seed-lab" (3x3 m, 4) |
    | config        | SwarmConfig | None         | a full config instead of a preset             |
    | task          | str / Task  | "wander"     | see :mod:`swarm_env.tasks`                    |
    | task_params   | dict        | {}           | keyword arguments of the task                 |
    | render_mode   | str         | None         | "rgb_array" or "human"                        |
    | render_agent  | str         | "ugv_0"      | whose sensors the renderer draws              |
    | world         | World       | None         | another World (real robots, replay)           |
    | **overrides   |             |              | any ``SwarmConfig`` field, e.g. ``n_robots=8``|

    ``infos[agent]`` holds ``time_s``, ``truth`` (pose, neighbours in the agent's frame, range and
    visibility per sensor; absent without ground truth), ``measurements`` (the raw records of the
    step, as dicts of arrays) and ``stale`` (sensors reported silent by a real World).

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
        preset: str = "seed-sim",
        *,
        config: SwarmConfig | None = None,
        task: str | Task = "wander",
        task_params: dict[str, Any] | None = None,
        render_mode: str | None = None,
        render_agent: str = "ugv_0",
        world: World | None = None,
        **overrides: Any,
    ) -> None:
        self.config = make_config(preset, config, **overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.task = make_task(task, **(task_params or {}))
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
        observation_space = obs_lib.build_space(
            self.config.observation,
            self.config.top_k,
            robot.max_speed_mps,
            robot.max_turn_rate_radps,
            feature_low,
            feature_high,
        )
        # One space object per agent, identical, returned on every call (PettingZoo API).
        self.action_spaces = {a: copy.deepcopy(action_space) for a in self.possible_agents}
        self.observation_spaces = {a: observation_space for a in self.possible_agents}

        # Every robot's own filter, advanced in batches over robots (same math per robot as
        # RobotCentricPHD); ``localizers[i]`` reads robot i's mixture and estimates.
        self._bank = PHDBank(self.config.phd, len(self.possible_agents))
        self.localizers = self._bank.views
        self._rng: np.random.Generator | None = None
        self._step_count = 0
        self._last_step: WorldStep | None = None
        self._velocity = np.zeros((self.config.n_robots, 2))
        self._last_detections = [np.zeros((0, 2)) for _ in self.possible_agents]
        self._last_bearings = [np.zeros(0) for _ in self.possible_agents]
        self._renderer = None

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
        if seed is not None or self._rng is None:
            self._rng, seed = seeding.np_random(seed)
            for i, agent in enumerate(self.possible_agents):
                self.action_spaces[agent].seed(None if seed is None else seed + i)
        # One generator per env; the world and the task get their own child streams.
        world_rng, task_rng = self._rng.spawn(2)
        self.agents = list(self.possible_agents)
        self._step_count = 0
        self._bank.reset()
        self._velocity[:] = 0.0
        for i in range(len(self.possible_agents)):
            self._last_detections[i] = np.zeros((0, 2))
            self._last_bearings[i] = np.zeros(0)
        step = self.world.reset(world_rng)
        # The sim knows where its obstacles are (exploration penalises them); real robots do not.
        layout = getattr(self.world, "layout", None)
        self.task.reset(step.truth, task_rng, self.config.arena, layout=layout)
        self._absorb(step)
        obs = self._observations(step)
        infos = self._infos(step)
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        commands = self._validate_actions(actions)
        extra = self.task.extra_commands(
            self._last_step.truth if self._last_step else None, self.config.control_period_s
        )
        if extra is not None and isinstance(self.world, SimWorld):
            step = self.world.step(commands, extra_commands=extra)
        else:
            step = self.world.step(commands)
        self._step_count += 1
        self._absorb(step)
        rewards_arr = self.task.rewards(step.truth, commands)
        term = np.broadcast_to(
            np.asarray(self.task.terminated(step.truth), dtype=bool), (len(self.possible_agents),)
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

    def render(self):
        if self.render_mode is None:
            return None
        if self._renderer is None:
            from swarm_env.render import Renderer

            self._renderer = Renderer(self, mode=self.render_mode)
        return self._renderer.draw()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.world.close()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_renderer"] = None  # windows and canvases do not pickle; recreated on demand
        return state

    # ------------------------------------------------------------------ internals
    def _validate_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Check every action before anything changes; return clipped commands (N, 2)."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict agent -> (2,) array, got {type(actions)}")
        unknown = sorted(set(actions) - set(self.agents))
        if unknown:
            raise ValueError(f"unknown or finished agent(s) {unknown}; live agents: {self.agents}")
        missing = sorted(set(self.agents) - set(actions))
        if missing:
            raise ValueError(f"missing action for agent(s) {missing}")
        agents = list(actions)
        try:
            values = np.asarray([actions[a] for a in agents], dtype=np.float64)
        except (TypeError, ValueError):
            values = None  # ragged or non-numeric: find the culprit below
        if values is None or values.shape != (len(agents), 2) or not np.isfinite(values).all():
            for agent in agents:  # slow path, only to name the agent and the value
                _check_action(agent, actions[agent])
        commands = np.zeros((len(self.possible_agents), 2))
        rows = [self._index[a] for a in agents]
        commands[rows] = np.clip(values, -self._action_high, self._action_high)
        return commands

    def _absorb(self, step: WorldStep) -> None:
        """Feed every robot's records to its own filter, in time order (one batched call)."""
        self._last_step = step
        calls = []
        for i, agent in enumerate(self.possible_agents):
            records = step.measurements.get(agent, RobotMeasurements())
            stale = step.stale.get(agent, ())
            if records.odometry and "odometry" not in stale:
                self._velocity[i] = records.odometry[-1].velocity
            if records.lidar and "lidar" not in stale:
                self._last_detections[i] = records.lidar[-1].detections
            if records.camera and "camera" not in stale:
                self._last_bearings[i] = records.camera[-1].bearings_rad
            if self.config.localize:
                calls.append(localizer_calls(records, stale))
        if self.config.localize:
            self._bank.apply(calls)

    def _observations(self, step: WorldStep) -> dict[str, np.ndarray]:
        cfg = self.config
        features = self.task.features(len(self.possible_agents))
        rows = [self._index[a] for a in self.agents]
        if cfg.observation == "phd":
            tables = obs_lib.phd_tables(*self._bank.padded_tables(), cfg.top_k)[rows]
        elif cfg.observation == "measurements":
            tables = obs_lib.measurement_tables(
                self._last_detections, self._last_bearings, cfg.top_k
            )[rows]
        else:
            tables = np.array(
                [
                    obs_lib.truth_table(self._neighbours_in_range(step.truth, i), cfg.top_k)
                    for i in rows
                ]
            )
        # One (agents, D) array for everyone (identical spaces); each agent gets its row.
        space = self.observation_spaces[self.possible_agents[0]]
        obs = obs_lib.assemble_rows(
            space,
            tables.reshape(len(rows), -1),
            self._velocity[rows],
            np.asarray(features)[rows].reshape(len(rows), -1),
        )
        return dict(zip(self.agents, obs, strict=True))

    def _neighbours_in_range(self, truth: GroundTruth | None, i: int) -> np.ndarray:
        if truth is None:
            raise ValueError('observation="truth" needs ground truth, which this World lacks')
        mask = truth.in_range["lidar"][i]
        return truth.relative_xy[i][mask]

    def _infos(self, step: WorldStep) -> dict[str, dict[str, Any]]:
        infos = {}
        truth = step.truth
        measurements, stale, empty = step.measurements, step.stale, RobotMeasurements()
        for agent in self.agents:
            i = self._index[agent]
            info: dict[str, Any] = {
                "time_s": step.time_s,
                "measurements": measurements_as_dict(measurements.get(agent, empty)),
                "stale": tuple(stale.get(agent, ())),
            }
            if truth is not None:
                # Views, not copies: every step's GroundTruth is new and never written to.
                info["truth"] = {
                    "pose": truth.poses[i],
                    "neighbours_xy": truth.relative_xy[i],
                    "in_range": {k: v[i] for k, v in truth.in_range.items()},
                    "visible": {k: v[i] for k, v in truth.visible.items()},
                }
            infos[agent] = info
        return infos


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


def localizer_calls(
    records: RobotMeasurements, stale=(), compensate_motion: bool = True
) -> list[tuple]:
    """One robot's records as time-ordered filter calls, skipping ``stale`` sensors.

    ``("predict", delta)`` for odometry, ``("lidar", detections, null_bearings)`` and
    ``("camera", bearings)``, as :meth:`localization.PHDBank.apply` takes them.

    The filter's frame is the robot's pose at its **last odometry sample**, but a scan or a
    frame is taken up to one odometry period (0.1 s) later, from wherever the robot has moved
    and turned since (at 1.5 rad/s, 0.15 rad: 0.3 m at 2 m). With ``compensate_motion`` (the
    default) each lidar / camera record that has a later odometry sample in ``records`` gets
    its **sensor pose** in the frame of the last sample, from the robot's own motion up to its
    stamp: the next sample's motion ``delta`` minus its constant-velocity remainder
    ``velocity * tau`` over the ``tau`` seconds from the stamp to that sample (see
    :func:`_motion_since_sample`). The filter moves detections exactly and rotates bearings
    (:mod:`localization.frames`). Only the robot's own odometry is used. A record after the
    step's last odometry sample goes in uncompensated (in the simulator none is: odometry
    samples fall on step ends; on a real robot with unsynchronised odometry some are).

    Calls: ``("predict", delta)``, ``("lidar", detections, null_bearings, sensor_pose)`` and
    ``("camera", bearings, sensor_pose)``, ``sensor_pose`` a ``(3,)`` array or None.
    """
    ordered = records.in_time_order()
    use_odometry = "odometry" not in stale
    use_lidar, use_camera = "lidar" not in stale, "camera" not in stale
    compensate = compensate_motion and use_odometry
    calls: list[tuple] = []
    # Walk backwards so each measurement knows the next odometry sample (None after the last).
    upcoming: OdometryRecord | None = None
    for record in reversed(ordered):
        if isinstance(record, OdometryRecord):
            upcoming = record
            if use_odometry:
                calls.append(("predict", record.delta))
            continue
        pose = None
        if compensate and upcoming is not None and upcoming.stamp_s > record.stamp_s:
            pose = _motion_since_sample(upcoming, upcoming.stamp_s - record.stamp_s)
        if isinstance(record, LidarRecord):
            if use_lidar:
                calls.append(("lidar", record.detections, record.null_bearings_rad, pose))
        elif use_camera:
            calls.append(("camera", record.bearings_rad, pose))
    calls.reverse()
    return calls


def _motion_since_sample(odo: OdometryRecord, tau_s: float) -> np.ndarray:
    """Pose ``(x, y, psi)`` of the robot ``tau_s`` seconds before odometry sample ``odo``,
    in the frame of the previous sample.

    ``odo.delta`` is the motion from the previous sample to ``odo``; the last ``tau_s`` of it
    is taken at the interval's mean speed ``odo.velocity = (v, omega)``: turn
    ``psi_r = omega tau``, chord ``t_r = v tau (cos(psi_r / 2), sin(psi_r / 2))`` in the frame
    at the measurement. Removing it: ``psi = dpsi - psi_r``, ``t = d - R(psi) t_r``.
    """
    dx, dy, dpsi = odo.delta.tolist()
    v, omega = odo.velocity.tolist()
    # Never remove more than the whole interval's motion when tau exceeds it (irregular rates).
    psi_r = omega * tau_s
    if abs(psi_r) > abs(dpsi):
        psi_r = dpsi
    chord = v * tau_s
    psi = dpsi - psi_r
    tx, ty = chord * math.cos(0.5 * psi_r), chord * math.sin(0.5 * psi_r)
    c, s = math.cos(psi), math.sin(psi)
    return np.array([dx - (c * tx - s * ty), dy - (s * tx + c * ty), psi])


def _check_action(agent: str, action: Any) -> None:
    """Raise ``ValueError`` naming ``agent`` and the value unless ``action`` is a finite (2,)."""
    try:
        value = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"action of {agent} is not numeric: {action!r}") from exc
    if value.shape != (2,):
        raise ValueError(
            f"action of {agent} must have shape (2,) [v_mps, omega_radps], got shape "
            f"{value.shape}: {action!r}"
        )
    if not np.all(np.isfinite(value)):
        raise ValueError(f"action of {agent} must be finite, got {value.tolist()}")
