"""A UGV swarm with a UAV supervisor (Stegagno 2013), as a PettingZoo parallel env.

Agents: ``ugv_0 .. ugv_{n-1}`` (exactly the :class:`~swarm_env.env.SwarmEnv` agents, same spaces,
observations and rewards) plus ``uav_0``. The env composes an unchanged ``SwarmEnv`` (the UGVs,
their physics, sensors and filters) and adds, per control period:

1. the UAV's kinematic motion from its action (it flies above everything: no collisions) and
   its noisy estimate of that motion (optical flow + IMU in Stegagno 2013);
2. the radio: the UGVs broadcast their dead-reckoned odometry pose (``SwarmRadio`` with the UAV as
   an extra listener; loss, latency and radius from ``SwarmConfig.comms``);
3. a frame of the downward camera (:mod:`swarm_env.sensors.downward_camera`) when one is due;
4. the UAV's ID-PHD (:class:`localization.id_phd.aerial.AerialIDPHD`): time update with its own
   increment and each UGV's broadcast increment, camera update; its estimate (identity, position,
   heading of every UGV in the UAV's level frame) is the UAV's observation. With a late radio
   the filter runs at a fixed lag (``filter_lag_s``, default the radio's worst delay) so that
   every increment meets the frame it belongs to; the reported estimate re-runs the unsettled
   steps on a copy with what has arrived.

The camera parameters the filter uses (``P_d``, noise per metre of altitude, clutter per frame)
are measured on the simulated camera at construction (:func:`measure_camera`), never typed in.

Spaces differ per agent type: a UGV acts ``[v_mps, omega_radps]`` and observes its own PHD
estimate; the UAV acts ``[vx, vy(, yaw_rate)(, climb_rate)]`` and observes
:data:`UAV_COLUMNS` per UGV plus :data:`UAV_TAIL`. Parameter sharing is therefore per agent
type (one policy for all UGVs, one for the UAV); see ``docs/how-to/studies/stegagno2013-uav.md``.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from localization.id_phd import IDPHDConfig
from localization.id_phd.aerial import AerialIDPHD, CameraModel
from swarm_core.aerial import AerialFrame
from swarm_core.geometry import integrate_body_delta, wrap_angle
from swarm_core.records import Broadcast
from swarm_env.comms import SwarmRadio
from swarm_env.config import make_config
from swarm_env.env import SwarmEnv
from swarm_env.sensors.downward_camera import (
    DownwardCamera,
    in_footprint,
    measure_camera,
    to_level_frame,
)
from swarm_env.uav.config import UAVConfig

UAV_ID = "uav_0"
#: Per UGV (agent order) in the UAV's observation: its ID-PHD estimate in the UAV's level frame.
UAV_COLUMNS = ("valid", "x_m", "y_m", "cos_psi", "sin_psi", "weight")
#: After the per-UGV rows.
UAV_TAIL = ("altitude_m", "half_x_m", "half_y_m", "n_detections")
#: A UGV whose broadcasts stop is extrapolated at its last speed this many steps at most.
MAX_EXTRAPOLATED_STEPS = 5
#: Estimated positions are clipped to this box in the observation (m).
OBS_XY_LIMIT_M = 50.0


def _filter_step(
    f: AerialIDPHD, own: np.ndarray, team: dict[int, np.ndarray], frame: AerialFrame | None
) -> None:
    """One step of the UAV's ID-PHD: time update, then the frame's update if there is one."""
    f.predict(own, team)
    if frame is not None:
        f.update_camera(frame.detections, frame.altitude_m, frame.half_extents_m)


def body_increment(velocity: np.ndarray, yaw_rate: float, dt: float) -> np.ndarray:
    """Exact planar increment ``[dx, dy, dpsi]`` (frame at the start) of a constant body twist.

    ``velocity`` (2,) in the body frame, ``yaw_rate`` rad/s over ``dt`` s: the SE(2) exponential
    ``d = V v dt`` with ``V = [[sin a, -(1 - cos a)], [1 - cos a, sin a]] / a``, ``a = w dt``.
    """
    a = yaw_rate * dt
    if abs(a) < 1e-9:
        return np.array([velocity[0] * dt, velocity[1] * dt, a])
    s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a
    vx, vy = velocity[0] * dt, velocity[1] * dt
    return np.array([s * vx - c * vy, c * vx + s * vy, a])


def fly(
    pose: np.ndarray,
    altitude_m: float,
    command: np.ndarray,
    dt: float,
    config: UAVConfig,
    fence: np.ndarray,
) -> tuple[np.ndarray, float, np.ndarray]:
    """One control period of the kinematic UAV: ``(new pose [x, y, yaw], new altitude, true
    increment [dx, dy, dpsi])`` (increment in the body frame at the start) under ``command``
    ``[vx, vy, yaw_rate, climb]`` (checked and limited). The geofence ``|x|, |y| <= fence``
    (m) and the altitude range saturate the motion. Shared by the env and the loopback UAV."""
    x, y, yaw = pose
    v = command[:2]
    if config.velocity_frame == "world":
        c, s = math.cos(yaw), math.sin(yaw)
        v = np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1]])
    delta = body_increment(v, command[2], dt)
    c, s = math.cos(yaw), math.sin(yaw)
    new_xy = np.array([x + c * delta[0] - s * delta[1], y + s * delta[0] + c * delta[1]])
    new_xy = np.clip(new_xy, -fence, fence)
    new_yaw = float(wrap_angle(yaw + delta[2]))
    moved = new_xy - pose[:2]
    true = np.array([c * moved[0] + s * moved[1], -s * moved[0] + c * moved[1], delta[2]])
    new_altitude = float(
        np.clip(altitude_m + command[3] * dt, config.min_altitude_m, config.max_altitude_m)
    )
    return np.array([new_xy[0], new_xy[1], new_yaw]), new_altitude, true


def relative_increment(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """``old^-1 (+) new``: the increment from odometry pose ``old`` to ``new``, in ``old``'s
    frame."""
    c, s = math.cos(old[2]), math.sin(old[2])
    dx, dy = new[0] - old[0], new[1] - old[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(new[2] - old[2]))])


class SupervisedSwarmEnv(ParallelEnv):
    """UGVs (a :class:`SwarmEnv`) plus one UAV running ID-PHD on its downward camera.

    Parameters
    ----------
    preset : str
        A ``SwarmConfig`` preset (default ``"seed-uav"``, Stegagno 2013's setup).
    uav : UAVConfig, optional
    task, task_params :
        The UGVs' task, as for :class:`SwarmEnv`.
    id_phd : IDPHDConfig, optional
        The UAV's filter; by default ``IDPHDConfig`` with the UAV's own-odometry noise per step.
    filter_lag_s : float, optional
        Fixed lag of the UAV's *settled* filter (s), by default the radio's worst delay
        ``comms.latency_s + comms.latency_jitter_s``: a step is settled once every broadcast
        sent by its end has arrived, so each UGV's increment is applied with the frame it
        belongs to. The reported estimate (``env.filter``) is the settled filter re-run over
        the unsettled steps with the broadcasts heard so far. ``0``: no lag (increments are
        applied when they arrive).
    config : SwarmConfig, optional
        A full config instead of the preset (``overrides`` still apply).
    world : World, optional
        Real robots and a real UAV instead of the simulator: a
        :class:`~hardware_bridge.world.RealWorld` with ``bridge.uav_id`` set, or a
        :class:`~hardware_bridge.bag.ReplayWorld` of a bag recorded with one (both expose
        ``uav_id``, ``last_uav`` and ``set_uav_command``). Built with the UGV config (``comms``
        off: this env owns the radio). The UAV is then not simulated: its action is published
        as a velocity command, its increment comes from its pose messages and the camera frames
        from its detections messages (the newest per step;
        :class:`~swarm_core.aerial.UAVAssembler`). Without the UAV's true pose the
        UAV's reward is 0 and ``infos["uav_0"]["truth"]`` is ``None``.
    **overrides
        ``SwarmConfig`` fields (``n_robots=5``, ``comms={"loss_probability": 0.2}``, ...).
        ``comms.enabled`` must stay ``True``: without the radio the UAV cannot identify anyone.
    """

    metadata = {"name": "swarm_uav_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        preset: str = "seed-uav",
        *,
        uav: UAVConfig | None = None,
        task: str = "wander",
        task_params: dict[str, Any] | None = None,
        id_phd: IDPHDConfig | None = None,
        filter_lag_s: float | None = None,
        config: Any = None,
        world: Any = None,
        **overrides: Any,
    ) -> None:
        config = make_config(preset, config, **overrides)
        if not config.comms.enabled:
            raise ValueError(
                "comms.enabled must be True for a supervised swarm (the UAV needs the UGVs' "
                f"odometry broadcasts), got {config.comms.enabled!r}"
            )
        uav = UAVConfig() if uav is None else uav
        if not isinstance(uav, UAVConfig):
            raise ValueError(f"uav must be a UAVConfig, got {uav!r}")
        if id_phd is not None and not isinstance(id_phd, IDPHDConfig):
            raise ValueError(f"id_phd must be an IDPHDConfig, got {id_phd!r}")
        self.config = config
        self.uav_config = uav
        # The one radio is this env's (with the UAV as a listener): the UGV world runs none.
        ground_config = dataclasses.replace(
            config, comms=dataclasses.replace(config.comms, enabled=False)
        )
        self.world = world
        self._uav_assembler = None
        if world is not None:
            for name in ("uav_id", "last_uav", "set_uav_command"):
                if not hasattr(world, name):
                    raise ValueError(f"world must provide {name!r} (a RealWorld / ReplayWorld)")
            if world.uav_id is None:
                raise ValueError("world has no UAV: set the bridge config's uav_id")
            if uav.velocity_frame != "body":
                # cmd_vel is body-frame; over a bridge the UAV's world yaw is unknown, so a
                # world-frame command could not be converted.
                raise ValueError(
                    f"uav.velocity_frame must be 'body' with a world, got {uav.velocity_frame!r}"
                )
            from swarm_core.aerial import UAVAssembler  # only for real / replayed UAVs

            self._uav_assembler = UAVAssembler(uav.camera)
        self.ground = SwarmEnv(
            config=ground_config, task=task, task_params=task_params, world=world
        )
        self.ugv_agents = list(self.ground.possible_agents)
        self.possible_agents = self.ugv_agents + [UAV_ID]
        self.agents: list[str] = []
        self._ugv_index = {a: i for i, a in enumerate(self.ugv_agents)}
        self.radio = SwarmRadio(config.comms, tuple(self.ugv_agents))
        self.camera = DownwardCamera(uav.camera)
        #: The camera measured on the simulator; the filter's P_d, noise and clutter come from it.
        self.camera_statistics = measure_camera(uav.camera)
        stats = self.camera_statistics
        self.camera_model = CameraModel(
            stats.mean_detection_probability,
            stats.noise_per_altitude,
            stats.mean_clutter_per_frame,
        )
        dt = config.control_period_s
        if id_phd is None:
            id_phd = IDPHDConfig(
                own_odometry_std_m=max(uav.odometry_std_mps * dt, 1e-6),
                own_odometry_std_rad=max(uav.odometry_std_radps * dt, 1e-6),
            )
        #: The filter settled ``filter_lag_steps`` steps ago, and the reported one (the same
        #: object without lag): :meth:`_run_filter`.
        self.settled_filter = AerialIDPHD(self.camera_model, id_phd)
        self.filter = self.settled_filter
        dt = config.control_period_s
        if filter_lag_s is None:
            filter_lag_s = config.comms.latency_s + config.comms.latency_jitter_s
        if (
            isinstance(filter_lag_s, bool)
            or not isinstance(filter_lag_s, (int, float))
            or not 0.0 <= filter_lag_s <= 60.0
        ):
            raise ValueError(f"filter_lag_s must be a number in [0, 60] s, got {filter_lag_s!r}")
        self.filter_lag_steps = int(math.ceil(filter_lag_s / dt - 1e-9))

        n = len(self.ugv_agents)
        high = np.array(
            [uav.max_speed_mps, uav.max_speed_mps]
            + [uav.max_yaw_rate_radps] * uav.yaw_control
            + [uav.max_climb_rate_mps] * uav.altitude_control,
        )
        self._uav_action_high = high
        uav_action = spaces.Box(
            -high.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        row_low = np.array([0.0, -OBS_XY_LIMIT_M, -OBS_XY_LIMIT_M, -1.0, -1.0, 0.0])
        row_high = np.array([1.0, OBS_XY_LIMIT_M, OBS_XY_LIMIT_M, 1.0, 1.0, 2.0])
        max_half = uav.camera.half_extents_m(uav.max_altitude_m)
        tail_low = np.array([uav.min_altitude_m, 0.0, 0.0, 0.0])
        tail_high = np.array([uav.max_altitude_m, max_half[0], max_half[1], 1000.0])
        uav_obs = spaces.Box(
            np.concatenate([np.tile(row_low, n), tail_low]).astype(np.float32),
            np.concatenate([np.tile(row_high, n), tail_high]).astype(np.float32),
            dtype=np.float32,
        )
        self.observation_spaces = {a: self.ground.observation_space(a) for a in self.ugv_agents}
        self.observation_spaces[UAV_ID] = uav_obs
        self.action_spaces = {a: self.ground.action_space(a) for a in self.ugv_agents}
        self.action_spaces[UAV_ID] = uav_action
        self.state_space = spaces.Box(
            -np.inf, np.inf, shape=(self.ground.state_space.shape[0] + 6,), dtype=np.float32
        )
        hx, hy = 0.5 * config.arena.width_m, 0.5 * config.arena.height_m
        margin = uav.geofence_margin_m
        self._fence = np.array([hx + margin, hy + margin])
        self._rng: np.random.Generator | None = None
        self._streams: tuple[np.random.Generator, ...] = ()
        self.uav_pose = np.zeros(3)
        self.altitude_m = uav.start_altitude_m
        self.last_frame: AerialFrame | None = None
        self._next_frame_s = 0.0
        # Per UGV: (stamp of the pose last used, that pose, the pose the filter has applied,
        # extrapolation included, the last per-step increment); see _teammate_increments.
        self._odometry: dict[int, tuple[float, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._heard: dict[int, list[tuple[float, np.ndarray]]] = {}
        self._pending: list[tuple[float, np.ndarray, AerialFrame | None]] = []
        self._last_uav_delta = np.zeros(3)

    # ------------------------------------------------------------------ PettingZoo API
    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    @property
    def time_s(self) -> float:
        return self.ground.time_s

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None and (
            isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
        ):
            raise ValueError(f"seed must be None or an int >= 0, got {seed!r}")
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(None if seed is None else int(seed))
        # One generator per env: the UGV env's seed and the UAV's streams all derive from it.
        ground_seed = int(self._rng.integers(2**31 - 1))
        self._streams = tuple(self._rng.spawn(3))  # camera, UAV odometry, radio
        self.action_spaces[UAV_ID].seed(ground_seed + len(self.ugv_agents))
        obs, infos = self.ground.reset(seed=ground_seed, options=options)
        cfg = self.uav_config
        self.uav_pose = np.array(
            [cfg.start_x_m, cfg.start_y_m, float(wrap_angle(cfg.start_yaw_rad))]
        )
        self.altitude_m = cfg.start_altitude_m
        self.settled_filter.reset()
        self.filter = self.settled_filter
        self.radio.reset(self._streams[2])
        self._odometry, self._heard, self._pending = {}, {}, []
        self._last_uav_delta = np.zeros(3)
        self._next_frame_s = 0.0
        self.last_frame = None
        if self.world is not None:
            self._uav_assembler.reset()
            self.uav_pose = np.zeros(3)
            frame = self._external_uav()[1]
        else:
            frame = self._camera_tick(self.ground.time_s)
        if frame is not None:  # no odometry before the first frame: nothing to wait for
            self.settled_filter.update_camera(
                frame.detections, frame.altitude_m, frame.half_extents_m
            )
        self.agents = list(self.possible_agents)
        obs[UAV_ID] = self._uav_observation()
        for agent in self.ugv_agents:
            infos[agent]["comms"] = []
        infos[UAV_ID] = self._uav_info([])
        return obs, infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called on a finished episode: call reset() first")
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict agent -> array, got {type(actions)}")
        unknown = sorted(map(repr, set(actions) - set(self.agents)))
        if unknown:
            raise ValueError(f"unknown or finished agent(s) {unknown}; live agents: {self.agents}")
        if UAV_ID in self.agents and UAV_ID not in actions:
            raise ValueError(f"missing action for agent(s) ['{UAV_ID}']")
        command = self._check_uav_action(actions.get(UAV_ID))  # before anything changes
        ugv_actions = {a: v for a, v in actions.items() if a != UAV_ID}
        if self.world is not None:
            self.ground._validate_actions(ugv_actions)  # nothing goes out on bad input
            self.world.set_uav_command(command)  # published with the UGVs' commands
        obs, rewards, terms, truncs, infos = self.ground.step(ugv_actions)  # validates first
        dt = self.config.control_period_s
        if self.world is not None:
            own_delta, frame = self._external_uav()
        else:
            true_delta = self._fly(command, dt)
            cfg = self.uav_config
            noise = self._streams[1].standard_normal(3) * np.array(
                [cfg.odometry_std_mps * dt, cfg.odometry_std_mps * dt, cfg.odometry_std_radps * dt]
            )
            own_delta = true_delta + noise
        self._last_uav_delta = own_delta
        step = self.ground.last_world_step
        # The radio's range needs positions in one frame: the simulator's truth; over a bridge
        # (mocap truth and the UAV's own odometry frame differ) every UGV is in range (a lab
        # radio's range exceeds the arena).
        simulated = self.world is None and step.truth is not None
        ugv_xy = (
            step.truth.poses[: len(self.ugv_agents), :2]
            if simulated
            else np.zeros((len(self.ugv_agents), 2))
        )
        delivered = self.radio.step(
            step.time_s,
            step.measurements,
            ugv_xy,
            listeners=((UAV_ID,), self.uav_pose[None, :2] if simulated else ugv_xy[:1]),
        )
        self._hear(delivered[UAV_ID])
        if self.world is None:
            frame = self._camera_tick(step.time_s)
        self._pending.append((step.time_s, own_delta, frame))
        self._run_filter()
        for agent in self.ugv_agents:
            if agent in infos:
                infos[agent]["comms"] = delivered.get(agent, [])
        if UAV_ID in self.agents:
            obs[UAV_ID] = self._uav_observation()
            rewards[UAV_ID] = self._uav_reward()
            terms[UAV_ID] = False
            truncs[UAV_ID] = not self.ground.agents
            infos[UAV_ID] = self._uav_info(delivered[UAV_ID])
        self.agents = list(self.ground.agents) + ([UAV_ID] if self.ground.agents else [])
        return obs, rewards, terms, truncs, infos

    def state(self) -> np.ndarray:
        """The UGV env's state, then ``[x_m, y_m, cos yaw, sin yaw, altitude_m, 0]`` of the UAV
        (over a bridge: its own pose estimate, in its odometry frame)."""
        x, y, yaw = self.uav_pose
        tail = np.array([x, y, math.cos(yaw), math.sin(yaw), self.altitude_m, 0.0])
        return np.concatenate([self.ground.state(), tail.astype(np.float32)])

    def render(self):
        raise NotImplementedError("SupervisedSwarmEnv has no renderer (render_modes is empty)")

    def close(self) -> None:
        self.ground.close()

    # ------------------------------------------------------------------ the UAV
    def _external_uav(self) -> tuple[np.ndarray, AerialFrame | None]:
        """A real (or replayed) UAV's step: its increment over the step's pose messages
        (composed, body frame at the start; zero without a new pose) and an ``AerialFrame`` of
        its newest detections message (``None`` without one, or before any altitude)."""
        msgs = self.world.last_uav
        delta = np.zeros(3)
        for pose in msgs.poses:
            inc = self._uav_assembler.pose(pose)
            if inc is not None:
                delta = integrate_body_delta(delta, inc)
            self.uav_pose = np.array([pose.x_m, pose.y_m, pose.yaw_rad])  # its odometry frame
        if self._uav_assembler.altitude_m is not None:
            self.altitude_m = self._uav_assembler.altitude_m
        frame = None
        if msgs.detections and self._uav_assembler.altitude_m is not None:
            frame = self._uav_assembler.frame(msgs.detections[-1])
            self.last_frame = frame
        return delta, frame

    def ugv_level_poses(self) -> np.ndarray:
        """Ground truth ``(n, 3)``: each UGV's ``[x, y, psi]`` in the UAV's level frame now."""
        poses = self.ground.last_world_step.truth.poses[: len(self.ugv_agents)]
        out = np.empty((poses.shape[0], 3))
        out[:, :2] = to_level_frame(self.uav_pose, poses[:, :2])
        out[:, 2] = wrap_angle(poses[:, 2] - self.uav_pose[2])
        return out

    def _check_uav_action(self, action: Any) -> np.ndarray:
        """The UAV's action as ``[vx, vy, yaw_rate, climb]`` (clipped), or ``ValueError``."""
        if UAV_ID not in self.agents:
            return np.zeros(4)
        if isinstance(action, (str, bytes, bool)) or action is None:
            raise ValueError(f"action of {UAV_ID} must be a numeric array, got {action!r}")
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"action of {UAV_ID} must be numeric, got {action!r}") from err
        size = self.uav_config.action_size
        if a.shape != (size,):
            raise ValueError(f"action of {UAV_ID} must have shape ({size},), got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action of {UAV_ID} must be finite, got {a.tolist()}")
        a = np.clip(a, -self._uav_action_high, self._uav_action_high)
        speed = math.hypot(a[0], a[1])
        if speed > self.uav_config.max_speed_mps:  # the limit is on the planar speed
            a[:2] *= self.uav_config.max_speed_mps / speed
        out = np.zeros(4)
        out[:2] = a[:2]
        k = 2
        if self.uav_config.yaw_control:
            out[2], k = a[k], k + 1
        if self.uav_config.altitude_control:
            out[3] = a[k]
        return out

    def _fly(self, command: np.ndarray, dt: float) -> np.ndarray:
        """Move the UAV one period (:func:`fly`); return its true increment."""
        self.uav_pose, self.altitude_m, true = fly(
            self.uav_pose, self.altitude_m, command, dt, self.uav_config, self._fence
        )
        return true

    def _camera_tick(self, time_s: float) -> AerialFrame | None:
        """Take a frame if one is due (at most one per period)."""
        if time_s + 1e-9 < self._next_frame_s:
            return None
        period = 1.0 / self.uav_config.camera.rate_hz
        self._next_frame_s += (math.floor((time_s - self._next_frame_s) / period) + 1) * period
        poses = self.ground.last_world_step.truth.poses[: len(self.ugv_agents)]
        frame = self.camera.frame(
            time_s, self.uav_pose, self.altitude_m, poses[:, :2], self._streams[0]
        )
        self.last_frame = frame
        return frame

    def _hear(self, messages: list[Broadcast]) -> None:
        """Keep every received broadcast's odometry pose by sender, in stamp order."""
        for msg in messages:
            i = self._ugv_index.get(msg.sender)
            if i is not None:
                self._heard.setdefault(i, []).append((msg.stamp_s, np.array(msg.odometry_pose)))
                self._heard[i].sort(key=lambda item: item[0])

    def _run_filter(self) -> None:
        """Settle the steps older than the lag, then re-run the unsettled ones on a copy.

        Without lag the settled filter is the reported one, and each step's increments are the
        broadcasts heard by its end."""
        while len(self._pending) > self.filter_lag_steps:
            stamp, own, frame = self._pending.pop(0)
            team = self._teammate_increments(self._odometry, stamp)
            _filter_step(self.settled_filter, own, team, frame)
            for i, (used, *_) in self._odometry.items():  # older poses are never needed again
                self._heard[i] = [item for item in self._heard[i] if item[0] >= used]
        if not self._pending:
            self.filter = self.settled_filter
            return
        nowcast = copy.deepcopy(self.settled_filter)
        odometry = dict(self._odometry)
        for stamp, own, frame in self._pending:
            _filter_step(nowcast, own, self._teammate_increments(odometry, stamp), frame)
        self.filter = nowcast

    def _teammate_increments(
        self, odometry: dict[int, tuple], stamp_s: float
    ) -> dict[int, np.ndarray]:
        """Each UGV's increment over the step ending at ``stamp_s`` (``odometry`` is updated in
        place).

        With a pose newer than the last one used (the newest stamped by ``stamp_s``): the
        increment from the pose the filter has applied so far to it. Total odometry makes a lost
        broadcast cost nothing in the end: the next pose carries the whole displacement. Without
        one (lost, or not arrived yet): the UGV's last per-step increment again (constant
        velocity), for at most :data:`MAX_EXTRAPOLATED_STEPS` steps after its last pose, then
        none; the next pose corrects what was extrapolated. A UGV's first pose makes it known
        with a null increment."""
        dt = self.config.control_period_s
        team: dict[int, np.ndarray] = {}
        for i, heard in self._heard.items():
            usable = [item for item in heard if item[0] <= stamp_s + 1e-9]
            state = odometry.get(i)
            if state is None:
                if usable:
                    newest_s, pose = usable[-1]
                    team[i] = np.zeros(3)
                    odometry[i] = (newest_s, pose, pose, np.zeros(3))
                continue
            used_s, used_pose, applied, per_step = state
            if usable and usable[-1][0] > used_s:
                newest_s, pose = usable[-1]
                team[i] = relative_increment(applied, pose)
                n_steps = max(1, round((newest_s - used_s) / dt))
                odometry[i] = (newest_s, pose, pose, relative_increment(used_pose, pose) / n_steps)
            elif stamp_s - used_s <= MAX_EXTRAPOLATED_STEPS * dt + 1e-9:
                team[i] = per_step
                odometry[i] = (
                    used_s,
                    used_pose,
                    integrate_body_delta(applied, per_step),
                    per_step,
                )
        return team

    def _uav_observation(self) -> np.ndarray:
        n = len(self.ugv_agents)
        rows = np.zeros((n, len(UAV_COLUMNS)))
        for i, (mean, weight, _) in self.filter.best_components().items():
            if 0 <= i < n:
                rows[i] = [
                    1.0,
                    np.clip(mean[0], -OBS_XY_LIMIT_M, OBS_XY_LIMIT_M),
                    np.clip(mean[1], -OBS_XY_LIMIT_M, OBS_XY_LIMIT_M),
                    math.cos(mean[2]),
                    math.sin(mean[2]),
                    min(weight, 2.0),
                ]
        frame = self.last_frame
        half = self.uav_config.camera.half_extents_m(self.altitude_m)
        n_det = 0 if frame is None else min(frame.detections.shape[0], 1000)
        tail = np.array([self.altitude_m, half[0], half[1], n_det])
        return np.concatenate([rows.ravel(), tail]).astype(np.float32)

    def _uav_reward(self) -> float:
        """Supervision: the fraction of the UGVs inside the camera's footprint (0 over a bridge:
        the UAV's true pose is unknown)."""
        if self.world is not None:
            return 0.0
        half = self.uav_config.camera.half_extents_m(self.altitude_m)
        return float(in_footprint(self.ugv_level_poses()[:, :2], half).mean())

    def _uav_info(self, messages: list[Broadcast]) -> dict[str, Any]:
        return {
            "time_s": self.ground.time_s,
            "comms": messages,
            "frame": self.last_frame,
            "odometry_delta": self._last_uav_delta.copy(),
            "estimate": self.filter.estimate(),
            "stale": () if self.world is None else self.world.last_uav.stale,
            "truth": None
            if self.world is not None
            else {
                "uav_pose": self.uav_pose.copy(),
                "altitude_m": self.altitude_m,
                "ugv_level_poses": self.ugv_level_poses(),
            },
        }
