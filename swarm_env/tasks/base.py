"""The Task protocol: reward, termination and task features, computed on top of any World.

A task never changes what the robots can sense: the observation stays each agent's own PHD
estimate; the task only appends a few constant or self-measured features (e.g. the goal radius).
Rewards and terminations are computed from ground truth, which the simulator always has and a real
swarm has only with motion capture (without it, rewards are zero and nothing terminates).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_core.world import GroundTruth

if TYPE_CHECKING:
    from swarm_env.tasks.localization_term import LocalizationTerm
    from swarm_env.world.arena import Layout


class Task:
    """Base class: subclasses override what they need. The defaults describe a task with no
    reward, no features, no extra robots and no termination (Perera 2021's free wandering)."""

    name = "base"
    n_extra_robots = 0
    #: The episode's generator, ArenaConfig and obstacle layout, kept by :meth:`reset`.
    _rng: np.random.Generator | None = None
    _arena: Any = None
    _layout: Layout | None = None

    def __init__(self, **params: Any) -> None:
        if params:
            raise ValueError(f"task {self.name!r} got unknown parameters {sorted(params)}")

    # -- observation ------------------------------------------------------------------------
    def feature_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Low and high of the task features appended to every observation, shapes (F,)."""
        return np.zeros(0), np.zeros(0)

    def features(self, n_agents: int) -> np.ndarray:
        """Task features per agent, shape (N, F)."""
        return np.zeros((n_agents, 0))

    def check_arena(self, arena: Any) -> None:
        """Refuse parameters that ``arena`` (an ArenaConfig) cannot hold, with a ``ValueError``
        naming the parameter: called when the env is built, so an impossible task fails there
        and not at the first reset."""

    # -- episode ----------------------------------------------------------------------------
    def reset(
        self,
        truth: GroundTruth | None,
        rng: np.random.Generator,
        arena: Any,
        *,
        layout: Layout | None = None,
    ) -> None:
        """Start an episode.

        ``arena`` is the ArenaConfig (bounds, obstacle sizes); ``layout`` the episode's obstacle
        geometry when the World has one (``SimWorld.layout``; ``None`` on real robots), for tasks
        that score contact with obstacles. The task keeps the three (``_rng``, ``_arena``,
        ``_layout``) for the episode, restarts its :attr:`localization` term, then calls
        :meth:`start`: subclasses override that, not this.
        """
        self._rng = rng
        self._arena = arena
        self._layout = layout
        if self.localization is not None:
            self.localization.reset()
        self.start(truth)

    def start(self, truth: GroundTruth | None) -> None:
        """Reset the task's own episode state; called by :meth:`reset` once the episode's
        generator, arena and layout are in place. ``truth`` is the first step's ground truth
        (``None`` on real robots without motion capture). Default: nothing to reset."""

    def extra_commands(self, truth: GroundTruth | None, dt_s: float) -> np.ndarray | None:
        """Commands ``(E, 2)`` for the non-agent robots this task adds, or ``None``."""
        return None

    def rewards(self, truth: GroundTruth | None, actions: np.ndarray) -> np.ndarray:
        """Reward per agent, shape (N,). ``actions`` are the clipped commands, shape (N, 2)."""
        return np.zeros(len(actions))

    #: The task's optional localization term (tasks that offer ``localization_weight``).
    localization: LocalizationTerm | None = None

    @property
    def needs_estimates(self) -> bool:
        """Whether :meth:`observe_estimates` must be called before every :meth:`rewards`."""
        return self.localization is not None and self.localization.needs_estimates

    def observe_estimates(self, table: np.ndarray, counts: np.ndarray) -> None:
        """The env's localizer after this step's update, ``padded_tables()``: ``table``
        (6, R, C), ``counts`` (R,), each robot's components in its own frame. Called just
        before :meth:`rewards` when :attr:`needs_estimates`."""
        if self.localization is not None:
            self.localization.observe_estimates(table, counts)

    def terminated(self, truth: GroundTruth | None) -> np.ndarray | bool:
        """Termination per agent (N,) bool, or one bool for the whole swarm."""
        return False

    def metrics(self) -> dict[str, float]:
        """Episode metrics so far (e.g. final formation error), for evaluation tables."""
        return {}

    def step_series(self) -> dict[str, np.ndarray]:
        """The per-step values behind :meth:`metrics`' episode means, one entry per env step
        so far (``{name: (T,)}``), for scoring phases of an episode. Default: none."""
        return {}

    # -- training only ----------------------------------------------------------------------
    #: Width of :meth:`critic_features` (a class constant or set in ``__init__``).
    n_critic_features = 0

    def critic_features(self, truth: GroundTruth) -> np.ndarray:
        """True per-agent task state for a centralised critic, shape (N, ``n_critic_features``).

        Simulation-only training input (:mod:`agents.sb3.central_critic`): the value function
        may read it, the policy never does. Default: none."""
        return np.zeros((len(truth.poses), 0))
