"""The World protocol: the only thing that differs between simulation, replay and real robots.

A World accepts one velocity command per robot, advances by one control period, and returns the
measurement records each robot produced in that period (see :mod:`swarm_core.records`) plus ground
truth when it exists (the simulator always; motion capture on real robots, optionally).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from swarm_core.records import Broadcast, RobotMeasurements


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """True state at the end of a step, for rewards and metrics (never for observations).

    Attributes
    ----------
    poses : ndarray, shape (N, 3)
        ``[x_m, y_m, yaw_rad]`` of every robot in the world frame.
    relative_xy : ndarray, shape (N, N, 2)
        ``relative_xy[i, j]``: robot j's position in robot i's body frame (0 on the diagonal).
    in_range : dict[str, ndarray (N, N) bool]
        Per sensor name (``"lidar"``, ``"camera"``): j is within i's nominal sensor range.
    visible : dict[str, ndarray (N, N) bool]
        Per sensor name: j was actually detectable by i at the last tick of that sensor
        (in range, line of sight, outside blind sectors, not interfered).
    extra_xy : ndarray, shape (E, 2)
        World positions of non-agent bodies that the sensors see like robots (e.g. an intruder).
    """

    poses: np.ndarray
    relative_xy: np.ndarray
    in_range: dict[str, np.ndarray] = field(default_factory=dict)
    visible: dict[str, np.ndarray] = field(default_factory=dict)
    extra_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def truth_from_poses(
    poses: np.ndarray,
    lidar_range_m: float,
    camera_range_m: float,
    visible: dict[str, np.ndarray] | None = None,
    extra_xy: np.ndarray | None = None,
) -> GroundTruth:
    """Ground truth from world poses (N, 3): relative positions and per-sensor range masks.

    Shared by every World that has truth (the simulator; motion capture on real robots).
    """
    rel = relative_positions(poses, poses)
    dist = np.hypot(rel[..., 0], rel[..., 1])
    off_diag = ~np.eye(len(poses), dtype=bool)
    return GroundTruth(
        poses=poses,
        relative_xy=rel,
        in_range={
            "lidar": off_diag & (dist <= lidar_range_m),
            "camera": off_diag & (dist <= camera_range_m),
        },
        visible=visible or {},
        extra_xy=np.zeros((0, 2)) if extra_xy is None else extra_xy,
    )


def relative_positions(observers: np.ndarray, targets_xy: np.ndarray) -> np.ndarray:
    """Targets in each observer's body frame.

    Parameters
    ----------
    observers : ndarray, shape (N, 3)
        ``[x, y, yaw]`` world poses.
    targets_xy : ndarray, shape (M, 2+)
        World positions (extra columns ignored).

    Returns
    -------
    ndarray, shape (N, M, 2)
        ``out[i, j] = R(yaw_i)^T (p_j - p_i)``.
    """
    dx = targets_xy[None, :, 0] - observers[:, None, 0]
    dy = targets_xy[None, :, 1] - observers[:, None, 1]
    c, s = np.cos(observers[:, 2])[:, None], np.sin(observers[:, 2])[:, None]
    out = np.empty(dx.shape + (2,))
    out[..., 0] = c * dx + s * dy
    out[..., 1] = c * dy - s * dx
    return out


@dataclass(frozen=True, slots=True)
class WorldStep:
    """What one control period produced: records per robot id, and ground truth or ``None``.

    ``comms`` maps a robot id to the teammates' :class:`~swarm_core.records.Broadcast` it
    received during the period, in order of arrival (empty when the World has no radio)."""

    time_s: float
    measurements: dict[str, RobotMeasurements]
    truth: GroundTruth | None
    stale: dict[str, tuple[str, ...]] = field(default_factory=dict)
    comms: dict[str, list[Broadcast]] = field(default_factory=dict)


@runtime_checkable
class World(Protocol):
    """Anything the env can drive: :class:`~swarm_env.world.sim.SimWorld`, replay, real robots."""

    #: Agent ids, in the order of the rows of ``commands`` and of ground truth.
    robot_ids: tuple[str, ...]
    #: The episode's obstacle geometry (:class:`swarm_env.world.arena.Layout`) when the World
    #: knows it (the simulator), else ``None`` (real robots, replay). Tasks may use it for
    #: rewards, never for observations.
    layout: Any | None

    def reset(self, rng: np.random.Generator) -> WorldStep:
        """Place the robots (sim) or wait for fresh data (real), and return the first records."""

    def step(self, commands: np.ndarray, extra_commands: np.ndarray | None = None) -> WorldStep:
        """Apply ``commands`` (shape (N, 2), ``[v_mps, omega_radps]``, already validated and
        clipped) for one control period and return what was measured during it.

        ``extra_commands`` (shape (E, 2)) drives the World's non-agent bodies (a task's
        intruder); a World that has none must raise ``ValueError`` when given any."""

    def halt(self) -> None:
        """Stop every robot now (a zero command each). Idempotent and never raises: the env
        calls it on any exception in ``step()`` / ``reset()`` before the exception propagates.
        The simulator has nothing to stop."""

    def close(self) -> None:
        """Release resources; a real World stops every robot here."""


def reject_extra_commands(world: str, extra_commands: np.ndarray | None) -> None:
    """For Worlds without non-agent bodies: raise ``ValueError`` if ``extra_commands`` has rows."""
    if extra_commands is not None and np.asarray(extra_commands).size:
        raise ValueError(
            f"{world} has no non-agent bodies to drive, got extra_commands of shape "
            f"{np.shape(extra_commands)} (a task with an intruder needs the simulator)"
        )
