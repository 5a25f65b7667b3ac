"""Privileged teachers: scripted controllers that also read ground truth (simulation only).

A teacher may know what no robot knows, because only its student is deployed ("learning by
cheating", Chen et al. 2019). ``scripted:formation`` loses much of its accuracy to spurious
components of its own PHD estimate, mostly camera-only tracks beyond the lidar's range (a red
decoy's bearing, for example): its centroid estimate is off by ~0.16 m, ~0.04 m without them
(``python -m experiments.formation_diagnosis``). The teacher
here is the same controller on the same table with every component that sits on no true
teammate removed: the controller the robot would run if it could tell decoys from teammates.
A student distilled from it (``swarm-phd train --residual scripted:formation --warm-start
privileged:formation``: the correction is fitted to ``teacher - scripted`` by DAgger,
:mod:`agents.sb3.warm_start`) acts on the robot's own observation only.

A second kind of teacher, ``privileged:NAME@truth`` (any controller ``NAME`` of
:data:`agents.policies.SCRIPTED` that acts on the neighbour table), runs ``scripted:NAME`` on
the table of the true neighbours within the lidar's range, the table ``observation="truth"``
gives, while the env (and the student) stays on the estimate. It is what
``scripted:NAME@truth`` scores, as a teacher whose labels fall on the states the student
reaches from its own estimate. Its correction of the base ``scripted:NAME`` is what the
estimate costs that controller: lost teammates, mostly
(``python -m experiments.distill_fit``). The table is not clipped to the observation space's
bounds (20 m) as the truth encoder
clips it: a teammate in lidar range never reaches them.

Teachers are named ``privileged:NAME`` (:data:`TEACHERS`) or ``privileged:NAME@truth``; they
read ``infos[agent]["truth"]["neighbours_xy"]`` (true positions of every robot in the agent's
frame, itself at the origin) and, for ``@truth``, ``infos[agent]["truth"]["in_range"]
["lidar"]`` (which robots are within the lidar's range).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.scripted import TABLE_COLUMNS, FormationPolicy
from swarm_env.observation import ESTIMATE_COLUMNS, truth_table

__all__ = [
    "OracleFormationTeacher",
    "TEACHERS",
    "TruthTableTeacher",
    "drop_spurious_rows",
    "load_teacher",
    "with_truth_table",
]

_X, _Y, _VALID = (ESTIMATE_COLUMNS.index(c) for c in ("x_m", "y_m", "valid"))


def drop_spurious_rows(
    obs: np.ndarray, neighbours_xy: np.ndarray, top_k: int, match_m: float = 0.15
) -> np.ndarray:
    """A copy of a ``"phd"`` observation whose table rows farther than ``match_m`` from every
    true teammate are marked invalid.

    ``obs`` (D,); ``neighbours_xy`` (N, 2): every robot's true position in the agent's body
    frame, the agent itself at the origin (excluded); metres."""
    out = np.array(obs, dtype=np.float32, copy=True)
    table = out[: TABLE_COLUMNS * top_k].reshape(top_k, TABLE_COLUMNS)  # a view into out
    mates = np.asarray(neighbours_xy, dtype=np.float64).reshape(-1, 2)
    mates = mates[np.hypot(mates[:, 0], mates[:, 1]) > 1e-9]
    if not len(mates):
        table[:, _VALID] = 0.0
        return out
    d = np.linalg.norm(table[:, None, [_X, _Y]] - mates[None, :, :], axis=2).min(axis=1)
    table[d > match_m, _VALID] = 0.0
    return out


def with_truth_table(
    obs: np.ndarray, neighbours_xy: np.ndarray, in_range: np.ndarray, top_k: int
) -> np.ndarray:
    """A copy of a ``"phd"`` observation whose neighbour table is replaced by the true
    neighbours within range, nearest first (:func:`swarm_env.observation.truth_table`: the
    rows ``observation="truth"`` gives); every other entry (odometry, lidar sectors, task
    features) is kept.

    ``obs`` (D,); ``neighbours_xy`` (N, 2) every robot's true position in the agent's body
    frame (m), the agent itself at the origin; ``in_range`` (N,) bool, False for the agent."""
    out = np.array(obs, dtype=np.float32, copy=True)
    mates = np.asarray(neighbours_xy, dtype=np.float64).reshape(-1, 2)
    mask = np.asarray(in_range, dtype=bool).reshape(-1)
    if mask.shape[0] != mates.shape[0]:
        raise ValueError(f"truth in_range has {mask.shape[0]} entries for {mates.shape[0]} robots")
    out[: TABLE_COLUMNS * top_k] = truth_table(mates[mask], top_k).reshape(-1)
    return out


class TruthTableTeacher:
    """``privileged:NAME@truth``: the scripted controller ``NAME`` acting on the true
    neighbours within its lidar's range instead of its estimate (module doc).

    Wraps a built controller; its per-agent state, ``reset`` and ``wandering`` are the
    controller's. Refuses to run without ground truth in ``infos`` (a real robot has none)."""

    def __init__(self, controller: Any, name: str) -> None:
        self.controller = controller
        self.name = f"{name}@truth"
        self.top_k = controller.top_k

    @property
    def wandering(self) -> Any:
        return self.controller.wandering

    def reset(self, seed: int | None = None) -> None:
        self.controller.reset(seed)

    def __call__(self, observations, infos):
        swapped = {}
        for agent, obs in observations.items():
            truth = (infos or {}).get(agent, {}).get("truth")
            if truth is None or "lidar" not in truth.get("in_range", {}):
                raise ValueError(
                    f"privileged:{self.name} reads ground truth: infos[{agent!r}] has no "
                    "'truth' with 'in_range'['lidar']"
                )
            swapped[agent] = with_truth_table(
                obs, truth["neighbours_xy"], truth["in_range"]["lidar"], self.top_k
            )
        return self.controller(swapped, infos)


class OracleFormationTeacher(FormationPolicy):
    """``scripted:formation`` on the PHD table without its spurious components (module doc).

    Needs ``infos`` with ground truth; refuses to run without it (a real robot has none)."""

    name = "formation"

    def __init__(self, *args: Any, match_m: float = 0.15, **kwargs: Any) -> None:
        self.match_m = match_m
        super().__init__(*args, **kwargs)

    def __call__(self, observations, infos):
        filtered = {}
        for agent, obs in observations.items():
            truth = (infos or {}).get(agent, {}).get("truth")
            if truth is None:
                raise ValueError(
                    f"privileged:{self.name} reads ground truth: infos[{agent!r}] has no 'truth'"
                )
            filtered[agent] = drop_spurious_rows(
                obs, truth["neighbours_xy"], self.top_k, self.match_m
            )
        return super().__call__(filtered, infos)


TEACHERS = {"formation": OracleFormationTeacher.for_env}


def load_teacher(spec: str, env: Any) -> Any:
    """A teacher for ``env``: ``"scripted:NAME"`` (:func:`agents.policies.load_policy`),
    ``"privileged:NAME"`` (:data:`TEACHERS`) or ``"privileged:NAME@truth"``
    (:class:`TruthTableTeacher` of ``scripted:NAME``)."""
    if isinstance(spec, str) and spec.startswith("privileged:"):
        name = spec.split(":", 1)[1]
        if name.endswith("@truth"):
            from agents.policies import SCRIPTED

            base = name[: -len("@truth")]
            if base not in SCRIPTED:
                raise ValueError(
                    f"unknown controller {base!r} in privileged teacher {spec!r}; choose "
                    f"from {sorted(SCRIPTED)}"
                )
            controller = SCRIPTED[base](env)
            if "truth" not in getattr(controller, "observation_modes", ()):
                raise ValueError(
                    f"privileged teacher {spec!r}: scripted:{base} reads no neighbour table, "
                    "so there is no truth to give it (NAME@truth needs a controller that "
                    "acts on the estimate)"
                )
            return TruthTableTeacher(controller, base)
        if name not in TEACHERS:
            raise ValueError(
                f"unknown privileged teacher {name!r}; choose from {sorted(TEACHERS)} "
                "or NAME@truth for a scripted controller NAME"
            )
        return TEACHERS[name](env)
    from agents.policies import load_policy

    return load_policy(spec, env)
