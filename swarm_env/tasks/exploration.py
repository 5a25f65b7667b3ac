"""``exploration``: cover the arena's grid cells with the swarm.

The arena is divided into square cells of side ``cell_m`` (the last row/column may be narrower).
A cell is covered once any robot's centre has been in it during the episode.

Reward (per agent i, per step), ``new`` = cells covered for the first time at this step by anyone::

    r_i = coverage_reward * new  -  collision_penalty * [i collides]

The coverage term is shared (every agent gets the whole swarm's gain); the collision term is each
robot's own. With ``p_i`` the true centre, ``W`` the walls and ``O`` the episode's obstacles
(boxes, decoy posts, red decoys)::

    [i collides] = min_{j != i} ||p_i - p_j|| < collision_distance_m
                   or dist(p_i, W) < wall_margin_m
                   or min_{o in O} dist(p_i, o) < wall_margin_m

``dist(p, o)`` is the distance to the obstacle's surface: to the (rotated) rectangle of a box, or
centre distance minus radius for a post. Walls and obstacles share ``wall_margin_m`` (0.16 m,
just above the chassis' enclosing radius of 0.143 m): a robot pressed against either counts
whatever its heading. The obstacles come from the World's ``layout`` at ``reset`` (the
simulator's); without one (real robots) only robots and walls count.

Optional localization term (``localization_weight`` = w > 0): ``r_i -= w u_i``, ``u_i`` in [0, 1]
(:mod:`swarm_env.tasks.localization_term`: teammates unseen by lidar and camera, or, with
``localization_term="estimate"``, misplaced by i's own estimate). Spreading out covers cells but
loses sight of teammates; the term prices that. Off by default; when on, the metrics add the
episode mean of ``u``.

Termination: the whole swarm, once the covered fraction reaches ``target_coverage``.
Truncation: ``max_steps`` of the config. No task features (F = 0): a robot cannot sense the
swarm's coverage map; what it can learn is to spread out and keep moving.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_core.world import GroundTruth
from swarm_env.tasks.base import Task
from swarm_env.tasks.common import check_param, collisions
from swarm_env.tasks.localization_term import LocalizationTerm


class ExplorationTask(Task):
    """Grid-cell coverage with a shared reward and a per-robot collision penalty (robots, walls
    and obstacles).

    Parameters
    ----------
    cell_m : float
        Cell side, default 0.5 m.
    target_coverage : float
        Covered fraction that ends the episode, in (0, 1], default 0.9.
    coverage_reward : float
        Reward per newly covered cell, default 1.0.
    collision_penalty : float
        Penalty per step in collision, default 0.1.
    collision_distance_m : float
        Robot-robot centre distance counted as a collision, default 0.3 m (about touching).
    wall_margin_m : float
        Centre-to-wall and centre-to-obstacle-surface distance counted as a collision, default
        0.16 m (the chassis' enclosing radius is 0.143 m).
    localization_weight : float
        Weight of the optional localization term (default 0, see the module doc).
    localization_term : {"unseen", "estimate"}
        What the term charges (:mod:`swarm_env.tasks.localization_term`), default "unseen".
    """

    name = "exploration"

    def __init__(
        self,
        cell_m: float = 0.5,
        target_coverage: float = 0.9,
        coverage_reward: float = 1.0,
        collision_penalty: float = 0.1,
        collision_distance_m: float = 0.3,
        wall_margin_m: float = 0.16,
        localization_weight: float = 0.0,
        localization_term: str = "unseen",
        **params: Any,
    ) -> None:
        super().__init__(**params)
        self.cell_m = check_param(self.name, "cell_m", cell_m, 0.0, 10.0, low_open=True)
        self.target_coverage = check_param(
            self.name, "target_coverage", target_coverage, 0.0, 1.0, low_open=True
        )
        self.coverage_reward = check_param(self.name, "coverage_reward", coverage_reward, 0.0, 1e3)
        self.collision_penalty = check_param(
            self.name, "collision_penalty", collision_penalty, 0.0, 1e3
        )
        self.collision_distance_m = check_param(
            self.name, "collision_distance_m", collision_distance_m, 0.0, 5.0
        )
        self.wall_margin_m = check_param(self.name, "wall_margin_m", wall_margin_m, 0.0, 5.0)
        self.localization = LocalizationTerm(self.name, localization_weight, localization_term)
        self.localization_weight = self.localization.weight
        self.covered = np.zeros((0, 0), dtype=bool)
        self._collision_steps = 0
        self._steps = 0
        self._robot_steps = 0

    def grid_shape(self, arena: Any) -> tuple[int, int]:
        """Coverage cells along x and y of ``arena``; ``ValueError`` below 2 cells."""
        nx = math.ceil(arena.width_m / self.cell_m - 1e-9)
        ny = math.ceil(arena.height_m / self.cell_m - 1e-9)
        if nx * ny < 2:
            raise ValueError(
                f"task {self.name!r}: cell_m={self.cell_m} leaves fewer than 2 cells "
                f"in a {arena.width_m} x {arena.height_m} m arena"
            )
        return nx, ny

    def check_arena(self, arena: Any) -> None:
        self.grid_shape(arena)

    def start(self, truth: GroundTruth | None) -> None:
        self.covered = np.zeros(self.grid_shape(self._arena), dtype=bool)
        self._collision_steps = 0
        self._steps = 0
        self._robot_steps = 0
        if truth is not None:
            self._cover(truth.poses[:, :2])  # the start cells are free: no reward for them

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices ``(ix, iy)`` of world positions (clipped into the grid)."""
        ix = np.floor((xy[:, 0] + 0.5 * self._arena.width_m) / self.cell_m).astype(int)
        iy = np.floor((xy[:, 1] + 0.5 * self._arena.height_m) / self.cell_m).astype(int)
        return (
            np.clip(ix, 0, self.covered.shape[0] - 1),
            np.clip(iy, 0, self.covered.shape[1] - 1),
        )

    def _cover(self, xy: np.ndarray) -> int:
        ix, iy = self.cells(xy)
        before = int(self.covered.sum())
        self.covered[ix, iy] = True
        return int(self.covered.sum()) - before

    @property
    def coverage(self) -> float:
        return float(self.covered.mean()) if self.covered.size else 0.0

    def rewards(self, truth: GroundTruth | None, actions: np.ndarray) -> np.ndarray:
        if truth is None:
            return np.zeros(len(actions))
        xy = truth.poses[:, :2]
        new = self._cover(xy)
        hit = collisions(
            xy, self.collision_distance_m, self._arena, self.wall_margin_m, layout=self._layout
        )
        self._collision_steps += int(hit.sum())
        self._steps += 1
        self._robot_steps += len(xy)
        reward = self.coverage_reward * new - self.collision_penalty * hit.astype(float)
        return reward - self.localization.penalty(truth)

    def terminated(self, truth: GroundTruth | None) -> bool:
        return truth is not None and self.coverage >= self.target_coverage

    def metrics(self) -> dict[str, float]:
        if not self._steps:
            return {}
        return {
            "coverage": self.coverage,
            "collision_rate": self._collision_steps / max(1, self._robot_steps),
            **self.localization.metrics(),
        }
