"""The Localizer protocol: what every localizer family offers the env, evaluation and bridge.

A :class:`Localizer` holds **every robot's** filter of one family (robot ``r`` estimates its
teammates in its own body frame, REP-103). Once per env step it consumes the whole swarm's
measurements, a :class:`~localization.feed.SwarmFeed`, and afterwards exposes each robot's
estimate in one form:

- :meth:`Localizer.padded_tables`: ``table (6, R, C)`` with rows ``w, x_m, y_m, Pxx_m2,
  Pxy_m2, Pyy_m2`` and ``counts (R,)``; robot ``r`` uses the first ``counts[r]`` columns.
  ``w`` is a PHD component's weight (its expected number of teammates) or a Bernoulli track's
  existence probability ``r`` in ``[0, 1]`` (:attr:`Localizer.weight_meaning` says which).
  This is what the observation encoders read.
- :meth:`Localizer.mixture` / :meth:`Localizer.estimate`: robot ``r``'s components as a
  :class:`~localization.mixture.GaussianMixture`, and the extracted teammates.
- :meth:`Localizer.identities`: ``{teammate index: (x_m, y_m[, psi_rad])}`` for the families
  that know identities (ID-PHD, the oracle-identity baselines); ``{}`` otherwise.

Each family bounds its total weight and its number of components per filter call (a time
update: at most ``P_s`` times the mass plus the pending births; an update: at most one more per
measurement; at most a configured number of components): see each class docstring and
``docs/concepts/localizers.md``, "Bounds on weight and cardinality".

Families are built by name through :mod:`localization.registry`. To add one, see
``docs/how-to/add-a-localizer-family.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from .feed import SwarmFeed
from .mixture import N_ROWS, GaussianMixture

__all__ = [
    "Localizer",
    "LocalizerView",
    "LocalizerBase",
    "LocalizerSlice",
    "robot_index",
    "tables_from_mixtures",
]

#: ``Localizer.weight_meaning`` values.
WEIGHT_MEANINGS = ("phd-weight", "existence")


@runtime_checkable
class Localizer(Protocol):
    """Every robot's filter of one family (see the module docstring)."""

    #: Registry name, e.g. ``"phd-lc"``.
    name: str
    #: Number of robots ``R`` (robot ``r`` is index ``r`` of the feed).
    n_robots: int
    #: ``"phd-weight"`` (expected count) or ``"existence"`` (probability), for table row 0.
    weight_meaning: str
    #: Whether :meth:`identities` can return anything.
    has_identities: bool

    def reset(self, robots: Sequence[int] | None = None) -> None:
        """Robots ``robots``' filters (default: every robot's) back to their initial state."""

    def step(self, feed: SwarmFeed) -> None:
        """Consume one env step of measurements for the whole swarm (``feed.n_robots == R``).

        Raises ``ValueError`` naming the culprit before any state changes on bad input. A robot
        with no records is left as it is (a feed of empty records is a no-op)."""

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """``(table (6, R, C), counts (R,))``, see the module docstring. Read-only views."""

    def mixture(self, robot: int) -> GaussianMixture:
        """Robot ``robot``'s components (weights or existences, means, covariances)."""

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``robot``'s extracted teammates: positions ``(K, 2)`` m in its frame and their
        weights ``(K,)``, heaviest first. GM-PHD: a component of weight ``w >= threshold``
        gives ``round(w)`` teammates of weight ``w / round(w)``; multi-Bernoulli: each track
        with existence ``r >= threshold`` gives one, of weight ``r``."""

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        """``{teammate index: (x_m, y_m[, psi_rad])}`` in robot ``robot``'s frame; ``{}``
        for anonymous families."""


class LocalizerView:
    """Robot ``robot`` of a localizer, read like a single filter (``.mixture``,
    ``.estimate()``, ``.identities()``), for code that holds a list of per-robot filters."""

    __slots__ = ("localizer", "robot")

    def __init__(self, localizer: Localizer, robot: int) -> None:
        self.localizer = localizer
        self.robot = robot

    @property
    def mixture(self) -> GaussianMixture:
        return self.localizer.mixture(self.robot)

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return self.localizer.estimate(self.robot, threshold)

    def identities(self) -> dict[int, np.ndarray]:
        return self.localizer.identities(self.robot)


def robot_index(robot: int, n_robots: int) -> int:
    """``robot`` as a Python int after checking it indexes one of ``n_robots`` robots
    (``ValueError`` naming ``robot`` and its value otherwise; a bool is refused)."""
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)):
        raise ValueError(f"robot must be an int index, got {robot!r}")
    if not 0 <= robot < n_robots:
        raise ValueError(f"robot must be in [0, {n_robots}), got {robot}")
    return int(robot)


class LocalizerBase:
    """Shared plumbing: robot-index checks, :attr:`views`, and anonymous identities."""

    name: str = ""
    n_robots: int = 0
    weight_meaning: str = "phd-weight"
    has_identities: bool = False

    @property
    def views(self) -> list[LocalizerView]:
        """One :class:`LocalizerView` per robot."""
        return [LocalizerView(self, r) for r in range(self.n_robots)]  # type: ignore[arg-type]

    def _check_feed(self, feed: SwarmFeed) -> None:
        if not isinstance(feed, SwarmFeed):
            raise ValueError(f"{self.name}: step() takes a SwarmFeed, got {type(feed).__name__}")
        if feed.n_robots != self.n_robots:
            raise ValueError(
                f"{self.name}: the feed has {feed.n_robots} robots, the localizer {self.n_robots}"
            )

    def _robot(self, robot: int) -> int:
        return robot_index(robot, self.n_robots)

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        self._robot(robot)
        return {}

    def _robots(self, robots: Sequence[int] | None) -> list[int]:
        """``robots`` checked (default: all of them)."""
        if robots is None:
            return list(range(self.n_robots))
        return [self._robot(r) for r in robots]


class LocalizerSlice(LocalizerBase):
    """Robots ``start .. start + n_robots - 1`` of a shared localizer, as a localizer of its
    own: what one env copy of a batch holds (``agents.sb3.batched``), all copies' robots
    advancing in one call of the shared localizer. Stepping a slice on its own is correct
    for the anonymous families (the other robots get empty records) but gives up that
    batching; the identity families cannot be sliced (their teammates are indices into the
    whole localizer, and the oracle baselines need one World's truth)."""

    def __init__(self, shared: Localizer, start: int, n_robots: int) -> None:
        if start < 0 or n_robots < 1 or start + n_robots > shared.n_robots:
            raise ValueError(
                f"slice [{start}, {start + n_robots}) outside the shared localizer's "
                f"{shared.n_robots} robots"
            )
        if shared.has_identities:
            raise ValueError(f"{shared.name}: a localizer that knows identities cannot be sliced")
        self.shared = shared
        self.start = start
        self.n_robots = n_robots
        self.name = shared.name
        self.weight_meaning = shared.weight_meaning
        self.has_identities = shared.has_identities

    def reset(self, robots: Sequence[int] | None = None) -> None:
        self.shared.reset([self.start + r for r in self._robots(robots)])

    def step(self, feed: SwarmFeed) -> None:
        self._check_feed(feed)
        n = self.shared.n_robots
        before = SwarmFeed.empty(self.start, feed.time_s)
        after = SwarmFeed.empty(n - self.start - self.n_robots, feed.time_s)
        self.shared.step(SwarmFeed.concat([f for f in (before, feed, after) if f.n_robots]))

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        table, counts = self.shared.padded_tables()
        rows = slice(self.start, self.start + self.n_robots)
        return table[:, rows], counts[rows]

    def mixture(self, robot: int) -> GaussianMixture:
        return self.shared.mixture(self.start + self._robot(robot))

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return self.shared.estimate(self.start + self._robot(robot), threshold)

    def identities(self, robot: int) -> dict[int, np.ndarray]:
        return self.shared.identities(self.start + self._robot(robot))


def tables_from_mixtures(mixtures: list[GaussianMixture]) -> tuple[np.ndarray, np.ndarray]:
    """Pad per-robot mixtures into ``(table (6, R, C), counts (R,))`` (C = largest count)."""
    counts = np.array([len(m.weights) for m in mixtures], dtype=np.intp)
    width = int(counts.max(initial=0))
    table = np.zeros((N_ROWS, len(mixtures), max(width, 1)))
    for r, m in enumerate(mixtures):
        n = counts[r]
        if n:
            table[0, r, :n] = m.weights
            table[1:3, r, :n] = m.means.T
            table[3, r, :n] = m.covs[:, 0, 0]
            table[4, r, :n] = m.covs[:, 0, 1]
            table[5, r, :n] = m.covs[:, 1, 1]
    return table, counts
