"""A UAV supervisor over the UGV swarm (Stegagno 2013): kinematic quadrotor, downward camera,
the UGVs' odometry over the radio, and ID-PHD on board (see :mod:`swarm_env.uav.env`)."""

from __future__ import annotations

from swarm_env.uav.config import UAVConfig
from swarm_env.uav.control import UAV_CONTROLLERS, UGVView, centroid_command, uav_action
from swarm_env.uav.env import UAV_COLUMNS, UAV_ID, UAV_TAIL, SupervisedSwarmEnv

__all__ = [
    "UAV_COLUMNS",
    "UAV_CONTROLLERS",
    "UAV_ID",
    "UAV_TAIL",
    "SupervisedSwarmEnv",
    "UAVConfig",
    "UGVView",
    "centroid_command",
    "uav_action",
]
