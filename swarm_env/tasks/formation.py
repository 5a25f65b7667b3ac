"""``formation``: the swarm forms a circle of radius ``r`` around its own centroid (the
Stegagno 2013 study's UAV/UGV task T4), or, with ``shape="lattice"``, every robot keeps distance
``d`` to its neighbours.

Rewards (per agent i, per step, metres; ground-truth world positions ``p``):

- circle: with centroid ``c = mean_j p_j``, target spacing ``s* = 2 r sin(pi / N)`` (the chord of
  N robots evenly spread on the circle) and ``nn_i`` the distance to i's nearest teammate::

      r_i = -( | ||p_i - c|| - r |  +  spacing_weight * | nn_i - s* | )

- lattice: with ``N_i`` = teammates closer than ``1.5 d``, plus the nearest one in any case::

      r_i = -mean_{j in N_i} | ||p_i - p_j|| - d |

Optional shaping (``progress_weight`` = k > 0, for training): with ``e_i`` the bracket above
(circle) or the lattice error, ``r_i += k (e_i(t-1) - e_i(t))``, i.e. a reward for the error
removed in this step. It is potential-based (potential ``-k e_i``, discount 1), so it does not
change which policy is optimal, but it credits each agent's own motion at once.

Optional localization term (``localization_weight`` = w > 0): ``r_i -= w u_i``, ``u_i`` in [0, 1]
(:mod:`swarm_env.tasks.localization_term`): with ``localization_term="unseen"`` (default) the
fraction of i's teammates that its lidar and camera did not both detect at their last tick; with
``"estimate"`` the fraction that i's own estimate misplaces by more than 0.30 m (the
Perera 2021 study's scoring). Motion that keeps teammates measured keeps them localized. Off by
default; when on, the metrics add the episode mean of ``u`` (``unseen_fraction`` or
``mislocalized_fraction``).

Termination: never (holding the formation is the task). Truncation: ``max_steps`` of the config.

Task features appended to each observation (mission parameters a robot is given, not sensed):
circle ``[r, s*]``, lattice ``[d]``.

Critic features (training only, :meth:`FormationTask.critic_features`): circle ``[shape error,
spacing error, true centroid x, y in the robot's body frame]``, lattice ``[lattice error]``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_core.world import GroundTruth, relative_positions
from swarm_env.tasks.base import Task
from swarm_env.tasks.common import (
    check_choice,
    check_param,
    pairwise_distances,
)
from swarm_env.tasks.localization_term import LocalizationTerm

SHAPES = ("circle", "lattice")
_NEIGHBOUR_FACTOR = 1.5


class FormationTask(Task):
    """Circle around the centroid (T4) or lattice with neighbour distance ``d``.

    Parameters
    ----------
    shape : {"circle", "lattice"}
    progress_weight : float
        Weight of the optional shaping term (default 0, see the module doc).
    localization_weight : float
        Weight of the optional localization term (default 0, see the module doc).
    localization_term : {"unseen", "estimate"}
        What the term charges (:mod:`swarm_env.tasks.localization_term`), default "unseen".
    radius_m : float
        Circle radius (circle only), default 0.8 m.
    spacing_m : float
        Neighbour distance ``d`` (lattice only), default 0.6 m.
    spacing_weight : float
        Weight of the even-spread term (circle only), default 0.5.
    """

    name = "formation"

    def __init__(
        self,
        shape: str = "circle",
        radius_m: float | None = None,
        spacing_m: float | None = None,
        spacing_weight: float | None = None,
        progress_weight: float = 0.0,
        localization_weight: float = 0.0,
        localization_term: str = "unseen",
        **params: Any,
    ) -> None:
        super().__init__(**params)
        self.shape = check_choice(self.name, "shape", shape, SHAPES)
        self.progress_weight = check_param(self.name, "progress_weight", progress_weight, 0.0, 1e3)
        self.localization = LocalizationTerm(self.name, localization_weight, localization_term)
        self.localization_weight = self.localization.weight
        self._previous: np.ndarray | None = None
        if self.shape == "circle":
            if spacing_m is not None:
                raise ValueError(
                    f"task {self.name!r}: spacing_m applies to shape='lattice'; "
                    "a circle's spacing follows from radius_m and the robot count"
                )
            radius_m = 0.8 if radius_m is None else radius_m
            spacing_weight = 0.5 if spacing_weight is None else spacing_weight
            self.radius_m = check_param(self.name, "radius_m", radius_m, 0.0, 20.0, low_open=True)
            self.spacing_weight = check_param(
                self.name, "spacing_weight", spacing_weight, 0.0, 10.0
            )
            self.spacing_m = None
        else:
            for name, value in (("radius_m", radius_m), ("spacing_weight", spacing_weight)):
                if value is not None:
                    raise ValueError(
                        f"task {self.name!r}: {name} applies to shape='circle', "
                        "not 'lattice' (use spacing_m)"
                    )
            spacing_m = 0.6 if spacing_m is None else spacing_m
            self.spacing_m = check_param(
                self.name, "spacing_m", spacing_m, 0.0, 20.0, low_open=True
            )
            self.radius_m = None
            self.spacing_weight = 0.0
        self.n_critic_features = 4 if self.shape == "circle" else 1
        self._errors: list[float] = []
        self._spacing_errors: list[float] = []

    def check_arena(self, arena: Any) -> None:
        if self.shape == "circle":
            name, value, size = "radius_m", self.radius_m, 2 * self.radius_m
        else:
            name, value, size = "spacing_m", self.spacing_m, self.spacing_m
        if size >= min(arena.width_m, arena.height_m):
            raise ValueError(
                f"task {self.name!r}: {name}={value} does not fit a "
                f"{arena.width_m} m x {arena.height_m} m arena"
            )

    # -- observation ----------------------------------------------------------------------
    def feature_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if self.shape == "circle":
            return np.zeros(2), np.array([self.radius_m, 2 * self.radius_m])
        return np.zeros(1), np.array([self.spacing_m])

    def features(self, n_agents: int) -> np.ndarray:
        if self.shape == "circle":
            row = [self.radius_m, target_chord(self.radius_m, n_agents)]
        else:
            row = [self.spacing_m]
        return np.tile(np.asarray(row, dtype=float), (n_agents, 1))

    # -- episode --------------------------------------------------------------------------
    def start(self, truth: GroundTruth | None) -> None:
        self._errors = []
        self._spacing_errors = []
        self._previous = None
        if truth is not None:
            shape_err, spacing_err = self.errors(truth.poses[:, :2])
            self._previous = shape_err + self.spacing_weight * spacing_err

    def errors(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-robot shape error and spacing error (m), shapes (N,), from world positions."""
        n = len(xy)
        if self.shape == "circle":
            c = xy.mean(axis=0)
            shape_err = np.abs(np.linalg.norm(xy - c, axis=1) - self.radius_m)
            if n < 2:
                return shape_err, np.zeros(n)
            nn = pairwise_distances(xy).min(axis=1)
            return shape_err, np.abs(nn - target_chord(self.radius_m, n))
        return lattice_errors(xy, self.spacing_m), np.zeros(n)

    def rewards(self, truth: GroundTruth | None, actions: np.ndarray) -> np.ndarray:
        if truth is None:
            return np.zeros(len(actions))
        shape_err, spacing_err = self.errors(truth.poses[:, :2])
        self._errors.append(float(shape_err.mean()))
        self._spacing_errors.append(float(spacing_err.mean()))
        err = shape_err + self.spacing_weight * spacing_err
        reward = -err
        if self.progress_weight and self._previous is not None and len(self._previous) == len(err):
            reward = reward + self.progress_weight * (self._previous - err)
        self._previous = err
        return reward - self.localization.penalty(truth)

    def critic_features(self, truth: GroundTruth) -> np.ndarray:
        xy = truth.poses[:, :2]
        shape_err, spacing_err = self.errors(xy)
        if self.shape != "circle":
            return shape_err[:, None]
        centroid = relative_positions(truth.poses, xy.mean(axis=0, keepdims=True))[:, 0]
        return np.column_stack([shape_err, spacing_err, centroid])

    def step_series(self) -> dict[str, np.ndarray]:
        """Per step: the swarm's mean shape error and spacing error (m), (T,) each."""
        return {
            "formation_error_m": np.asarray(self._errors, dtype=float),
            "spacing_error_m": np.asarray(self._spacing_errors, dtype=float),
        }

    def metrics(self) -> dict[str, float]:
        if not self._errors:
            return {}
        tail = max(1, len(self._errors) // 5)
        return {
            "formation_error_m": float(np.mean(self._errors)),
            "final_formation_error_m": float(np.mean(self._errors[-tail:])),
            "spacing_error_m": float(np.mean(self._spacing_errors)),
            "final_spacing_error_m": float(np.mean(self._spacing_errors[-tail:])),
            **self.localization.metrics(),
        }


def target_chord(radius_m: float, n: int) -> float:
    """Distance between neighbours of ``n`` robots evenly spread on a circle (0 for n < 2)."""
    return 2.0 * radius_m * math.sin(math.pi / n) if n >= 2 else 0.0


def lattice_errors(xy: np.ndarray, spacing_m: float) -> np.ndarray:
    """Per robot: mean | d_ij - d | over teammates within 1.5 d plus the nearest one, (N,)."""
    n = len(xy)
    if n < 2:
        return np.zeros(n)
    d = pairwise_distances(xy)
    near = d < _NEIGHBOUR_FACTOR * spacing_m
    near[np.arange(n), d.argmin(axis=1)] = True
    err = np.where(near, np.abs(d - spacing_m), 0.0)
    return err.sum(axis=1) / near.sum(axis=1)
