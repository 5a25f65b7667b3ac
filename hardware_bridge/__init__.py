"""Hardware bridge: drive a real ROS swarm through the same env API as the simulator.

>>> from hardware_bridge import real_env                       # doctest: +SKIP
>>> env = real_env(robots=["ugv_0", "ugv_1"], preset="seed-lab")
>>> obs, infos = env.reset()
>>> obs, rew, term, trunc, infos = env.step({a: [0.1, 0.0] for a in env.agents})
>>> env.close()                                               # stops every robot

The env is :class:`swarm_env.env.SwarmEnv` itself (same spaces, localization, task and
observation code) with a :class:`~hardware_bridge.world.RealWorld` instead of the simulator.
See ``docs/how-to/real-robots.md`` for running it on robots.

Modules: :mod:`~hardware_bridge.config` (``BridgeConfig``), :mod:`~hardware_bridge.messages`
(validation and builders), :mod:`~hardware_bridge.transport` (rosbridge client),
:mod:`~hardware_bridge.world` (``RealWorld``), :mod:`~hardware_bridge.watchdog`,
:mod:`~hardware_bridge.guard` (the watchdog process), :mod:`~hardware_bridge.signals`,
:mod:`~hardware_bridge.safety` (limits, geofence), :mod:`~hardware_bridge.bag` (record,
``ReplayWorld``), :mod:`~hardware_bridge.emit` (sim records to robot messages),
:mod:`~hardware_bridge.loopback` (a rosbridge server over the sim),
:mod:`~hardware_bridge.faults` (corruption catalog). Reliability figures:
``docs/reference/reliability.md``.
Twisted (roslibpy) is imported only when a RealWorld is created.
"""

from __future__ import annotations

from typing import Any

from hardware_bridge.config import BridgeConfig

__all__ = [
    "BridgeConfig",
    "real_env",
    "real_supervised_env",
    "replay_env",
    "replay_supervised_env",
    "RealWorld",
    "ReplayWorld",
    "BagRecorder",
    "LoopbackServer",
    "FaultConfig",
    "RobotsSilentError",
    "TransportLostError",
    "BagError",
]


def real_env(
    robots: list[str] | tuple[str, ...] | None = None,
    host: str = "127.0.0.1",
    port: int = 9090,
    preset: str = "seed-lab",
    task: Any = "wander",
    *,
    allow_remote: bool = False,
    record: str | None = None,
    bridge: BridgeConfig | dict | None = None,
    task_params: dict | None = None,
    onboard: bool = False,
    **overrides: Any,
):
    """A PettingZoo ``ParallelEnv`` over real robots behind a rosbridge server.

    Parameters
    ----------
    robots : list of str, optional
        Robot namespaces, in agent order (default: ``ugv_0 ... ugv_{n-1}`` of the preset).
        ``n_robots`` is ``len(robots)``.
    host, port : str, int
        The rosbridge server (``rosbridge_websocket``). Loopback by default.
    preset : str
        SwarmConfig preset for the filter, control period, limits (``seed-lab`` = the Perera 2021
        study's real 3 m x 3 m testing area).
    task : str or Task
        A task without simulated extra robots.
    allow_remote : bool
        Required for a non-loopback ``host``.
    record : str, optional
        Record the episode(s) to a new ROS 2 bag directory at this path.
    bridge : BridgeConfig or dict, optional
        Watchdog, staleness, limits, geofence, queues.
    onboard : bool
        The robots run their own filters (``ros/swarm_phd_onboard``, family
        ``config.localizer``, one of :data:`hardware_bridge.onboard.ONBOARD_FAMILIES`) and
        publish ``/<robot>/swarm_phd/estimate``: the bridge subscribes to those instead of the
        scans and bearings, and the observation is built from the received estimates by the
        same encoder (``env.localizer`` is a
        :class:`~hardware_bridge.estimate.ReceivedEstimates`). A stale estimate is named in
        ``infos[agent]["stale"]`` and stops its robot; estimates are recorded in the bag.
    **overrides
        SwarmConfig fields (``control_period_s=0.1``, ``phd={"mode": "lidar-only"}``,
        ``phd={"lidar": {"noise_std_m": 0.04}}``...). The filter defaults to the Perera 2021
        study's own model, ``PHDConfig.perera2021()`` (that study's hardware), not the
        simulator presets' ``PHDConfig()``; a ``phd`` dict overrides fields of the former.

    Notes
    -----
    The returned env refuses pickling, copying and vectorisation (it drives real robots).
    """
    from hardware_bridge.config import make_bridge_config
    from hardware_bridge.estimate import weight_kind_of
    from hardware_bridge.transport import check_host
    from localization.config import PHDConfig, config_with_overrides
    from swarm_env.config import make_config
    from swarm_env.env import SwarmEnv
    from swarm_env.tasks import make_task

    check_host(host, allow_remote)
    bridge_cfg = make_bridge_config(bridge)
    phd = overrides.get("phd")
    if phd is None or isinstance(phd, dict):  # Perera 2021's model, with any dict overrides
        overrides["phd"] = config_with_overrides(PHDConfig.perera2021(), PHDConfig, phd or {})
    if robots is None:
        n = make_config(preset, **overrides).n_robots
        robots = [f"ugv_{i}" for i in range(n)]
    if isinstance(robots, str):
        robots = [r for r in robots.split(",") if r]
    robots = list(robots)
    if "n_robots" in overrides and overrides["n_robots"] != len(robots):
        raise ValueError(f"n_robots={overrides['n_robots']} but {len(robots)} robots were named")
    overrides["n_robots"] = len(robots)
    config = make_config(preset, **overrides)
    task_obj = make_task(task, **(task_params or {}))
    if task_obj.n_extra_robots:
        raise ValueError(
            f"task {task_obj.name!r} needs {task_obj.n_extra_robots} simulated extra robot(s); "
            "it cannot run on real robots"
        )
    localizer = None
    if onboard is not True and onboard is not False:
        raise ValueError(f"onboard must be a bool, got {onboard!r}")
    if onboard:
        from hardware_bridge.onboard import ONBOARD_FAMILIES

        if config.localizer not in ONBOARD_FAMILIES:
            raise ValueError(
                f"onboard=True: the robots run localizer={config.localizer!r}, which needs the "
                f"radio or ground truth; on board: {list(ONBOARD_FAMILIES)}"
            )
        if config.observation != "phd" or config.lidar_sectors:
            raise ValueError(
                "onboard=True: the observation is built from the robots' estimates only "
                f"(observation='phd', lidar_sectors=0), got observation={config.observation!r}, "
                f"lidar_sectors={config.lidar_sectors} (the scans stay on the robots)"
            )
    meaning = "existence" if config.localizer.startswith("pmb") else "phd-weight"
    world = _open_real_world(
        robots,
        config,
        host,
        port,
        allow_remote,
        bridge_cfg,
        record,
        onboard=onboard,
        estimate_weight_kind=weight_kind_of(meaning) if onboard else None,
    )
    try:
        if onboard:
            from hardware_bridge.estimate import ReceivedEstimates

            localizer = ReceivedEstimates(
                robots, config.localizer, meaning, lambda: world.step_estimates
            )
        env = SwarmEnv(
            config=config,
            task=task_obj,
            world=world,
            localizer=localizer,
            render_agent=robots[0],
        )
    except BaseException:
        world.close()
        raise
    # Never vectorise: SuperSuit and friends read this flag.
    env.metadata = {**env.metadata, "is_parallelizable": False}
    return env


def _open_real_world(robots, config, host, port, allow_remote, bridge_cfg, record, **world_kwargs):
    """The :class:`~hardware_bridge.world.RealWorld` of :func:`real_env` and
    :func:`real_supervised_env`, recording to a new bag at ``record`` if given (the bag is
    closed again if the world cannot start)."""
    from hardware_bridge.bag import BagRecorder
    from hardware_bridge.world import RealWorld

    recorder = None
    if record is not None:
        recorder = BagRecorder(
            record,
            robots,
            config,
            source="bridge",
            stale_mocap_s=bridge_cfg.stale_mocap_s,
            use_mocap=bridge_cfg.use_mocap,
            uav_id=bridge_cfg.uav_id,
            odometry_jump_factor=bridge_cfg.odometry_jump_factor,
            onboard=bool(world_kwargs.get("onboard", False)),
        )
    try:
        return RealWorld(
            robots,
            config,
            host=host,
            port=port,
            allow_remote=allow_remote,
            bridge=bridge_cfg,
            recorder=recorder,
            **world_kwargs,
        )
    except BaseException:
        if recorder is not None:
            recorder.close()
        raise


def real_supervised_env(
    robots: list[str] | tuple[str, ...] | None = None,
    host: str = "127.0.0.1",
    port: int = 9090,
    preset: str = "seed-uav",
    task: str = "wander",
    *,
    uav_id: str = "uav_0",
    uav: Any = None,
    allow_remote: bool = False,
    record: str | None = None,
    bridge: BridgeConfig | dict | None = None,
    task_params: dict | None = None,
    filter_lag_s: float | None = None,
    **overrides: Any,
):
    """Stegagno 2013 on real robots: :class:`swarm_env.uav.SupervisedSwarmEnv` (UGV agents plus
    ``uav_0``) over a :class:`~hardware_bridge.world.RealWorld` that also subscribes to the UAV
    ``uav_id`` (its pose and detections) and publishes its commands.

    The UGVs' odometry reaches the UAV's ID-PHD through the env's radio model
    (``SwarmConfig.comms``) applied to the odometry records the bridge received. ``uav`` is
    the :class:`~swarm_env.uav.UAVConfig` (limits, camera geometry). Other arguments as
    :func:`real_env`; the filter model stays the preset's (``seed-uav``).
    """
    import dataclasses

    from hardware_bridge.config import make_bridge_config
    from hardware_bridge.transport import check_host
    from swarm_env.config import make_config
    from swarm_env.uav import SupervisedSwarmEnv

    check_host(host, allow_remote)
    bridge_cfg = dataclasses.replace(make_bridge_config(bridge), uav_id=uav_id)
    if robots is None:
        robots = [f"ugv_{i}" for i in range(make_config(preset, **overrides).n_robots)]
    robots = list(robots)
    overrides["n_robots"] = len(robots)
    config = make_config(preset, **overrides)
    # The env owns the radio (to the UAV); the UGV world runs none.
    ground = dataclasses.replace(config, comms=dataclasses.replace(config.comms, enabled=False))
    world = _open_real_world(robots, ground, host, port, allow_remote, bridge_cfg, record)
    try:
        env = SupervisedSwarmEnv(
            config=config,
            uav=uav,
            task=task,
            task_params=task_params,
            filter_lag_s=filter_lag_s,
            world=world,
        )
    except BaseException:
        world.close()
        raise
    env.metadata = {**env.metadata, "is_parallelizable": False}
    return env


def replay_supervised_env(path: str, *, task: str = "wander", uav: Any = None, **kwargs: Any):
    """:class:`swarm_env.uav.SupervisedSwarmEnv` over a bag recorded by
    :func:`real_supervised_env` (open loop): the UAV's filter sees the recorded pose and
    detections and the UGVs' recorded odometry; the radio is the recorded config's. The
    recorded config has the radio off (the UGV world's); it is switched back on here."""
    import dataclasses

    from hardware_bridge.bag import ReplayWorld
    from swarm_env.uav import SupervisedSwarmEnv

    world = ReplayWorld(path)
    if world.uav_id is None:
        from hardware_bridge.bag import BagError

        raise BagError(path, "no UAV in this bag (record it with real_supervised_env)")
    config = dataclasses.replace(
        world.config,
        comms=dataclasses.replace(world.config.comms, enabled=True),
        max_steps=max(1, world.n_steps(0)),
    )
    return SupervisedSwarmEnv(config=config, uav=uav, task=task, world=world, **kwargs)


def __getattr__(name: str) -> Any:
    if name in ("RealWorld", "RobotsSilentError", "TransportLostError"):
        from hardware_bridge import world

        return getattr(world, name)
    if name in ("ReplayWorld", "BagRecorder", "replay_env", "BagError"):
        from hardware_bridge import bag

        return getattr(bag, name)
    if name in ("LoopbackServer", "FaultConfig"):
        from hardware_bridge import loopback

        return getattr(loopback, name)
    raise AttributeError(f"module 'hardware_bridge' has no attribute {name!r}")
