"""Scripted swarm controllers that use only what a real robot has: its own lidar scan, its own
odometry and its own PHD estimate (never ground truth).

Every policy maps ``(observations, infos) -> actions`` for all live agents at once, so the same
object drives the simulator and the hardware bridge.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class ScriptedPolicy:
    """Base class: per-agent state is kept in dicts keyed by agent name."""

    name = "scripted"

    def __init__(self, max_speed_mps: float = 0.3, max_turn_rate_radps: float = 1.5) -> None:
        self.max_speed_mps = max_speed_mps
        self.max_turn_rate_radps = max_turn_rate_radps

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any) -> ScriptedPolicy:
        robot = env.config.robot
        return cls(max_speed_mps=robot.max_speed_mps,
                   max_turn_rate_radps=robot.max_turn_rate_radps, **kwargs)

    def reset(self, seed: int | None = None) -> None:
        """Forget per-agent state; reseed any randomness."""

    def __call__(self, observations: dict[str, np.ndarray],
                 infos: dict[str, dict[str, Any]]) -> dict[str, np.ndarray]:
        raise NotImplementedError


def latest_scan(info: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(angles_rad (B,), ranges_m (B,))`` of the newest lidar scan in ``info``, or ``None``."""
    scans = info.get("measurements", {}).get("lidar", [])
    if not scans:
        return None
    return scans[-1]["angles_rad"], scans[-1]["ranges_m"]


class WanderPolicy(ScriptedPolicy):
    """The seed's pseudo-random motion with lidar obstacle avoidance.

    Each robot cruises at ``cruise_fraction * v_max`` with a turn rate that follows an
    Ornstein-Uhlenbeck process (smooth random heading changes). When the nearest valid lidar return
    in the front sector (+/- ``front_half_angle_deg``) is closer than ``avoid_distance_m``, the
    robot slows down and turns towards the side with more free space until the front is clear.
    Teammates and obstacles are avoided alike: the lidar cannot tell them apart.
    """

    name = "wander"

    def __init__(self, max_speed_mps: float = 0.3, max_turn_rate_radps: float = 1.5,
                 cruise_fraction: float = 0.6, avoid_distance_m: float = 0.45,
                 front_half_angle_deg: float = 50.0, turn_noise: float = 0.6,
                 seed: int | None = 0) -> None:
        super().__init__(max_speed_mps, max_turn_rate_radps)
        self.cruise_mps = cruise_fraction * max_speed_mps
        self.avoid_distance_m = avoid_distance_m
        self.front_half_angle_rad = np.deg2rad(front_half_angle_deg)
        self.turn_noise = turn_noise
        self._seed = seed
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(self._seed if seed is None else seed)
        self._turn: dict[str, float] = {}
        self._scan: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._avoid_sign: dict[str, float] = {}

    def __call__(self, observations, infos):
        actions = {}
        for agent in observations:
            scan = latest_scan(infos.get(agent, {}))
            if scan is not None:
                self._scan[agent] = scan
            actions[agent] = self._act(agent)
        return actions

    def _act(self, agent: str) -> np.ndarray:
        # Ornstein-Uhlenbeck turn rate: mean-reverting, so paths curve but do not spin.
        turn = self._turn.get(agent, 0.0)
        turn += -0.2 * turn + self.turn_noise * self._rng.standard_normal() * 0.3
        self._turn[agent] = float(np.clip(turn, -0.5, 0.5) * self.max_turn_rate_radps)
        v, omega = self.cruise_mps, self._turn[agent]
        scan = self._scan.get(agent)
        if scan is not None:
            angles, ranges = scan
            valid = ranges > 0
            front = valid & (np.abs(angles) < self.front_half_angle_rad)
            nearest = ranges[front].min() if front.any() else np.inf
            if nearest < self.avoid_distance_m:
                if agent not in self._avoid_sign:
                    # Turn towards the side whose nearest return is further away; keep that
                    # choice until clear so the robot does not dither between sides.
                    left = valid & (angles > 0) & (angles < np.pi / 2)
                    right = valid & (angles < 0) & (angles > -np.pi / 2)
                    free_left = ranges[left].min() if left.any() else np.inf
                    free_right = ranges[right].min() if right.any() else np.inf
                    self._avoid_sign[agent] = 1.0 if free_left >= free_right else -1.0
                v = self.cruise_mps * max(0.0, (nearest - 0.25) / self.avoid_distance_m) - 0.05
                omega = self._avoid_sign[agent] * self.max_turn_rate_radps
            else:
                self._avoid_sign.pop(agent, None)
        return np.array([v, omega], dtype=np.float32)
