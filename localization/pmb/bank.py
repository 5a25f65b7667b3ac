"""Many robots' PMB localizers advanced together: :class:`PMBBank`.

The interface users touch is that of :class:`localization.PHDBank`: ``apply(calls)`` with the
same call tuples, ``predict`` / ``update_lidar`` / ``update_camera(robots, ...)``, ``reset()``,
``padded_tables()``, ``views[r]`` (``.mixture``, ``.estimate()``, ``.table``), pickling.
The padded table holds the **Bernoulli tracks** (weight row = existence ``r``), so an
observation encoder written for the GM-PHD's table reads the PMB's unchanged.

Every robot gets what its own :class:`~localization.pmb.RobotCentricPMB` computes for the same
calls (to 1e-10, ``tests/localization/test_pmb_bank.py``). Calls are validated and encoded by
the GM-PHD bank's own batch encoder, so both banks accept and reject exactly the same input.

>>> import numpy as np
>>> from localization.pmb import PMBBank, PMBConfig
>>> bank = PMBBank(PMBConfig(), n_robots=20)
>>> bank.apply([[("predict", np.zeros(3)), ("lidar", np.array([[1.0, 0.5]]), None)]] + [[]] * 19)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..bank import _Batch, all_finite, bank_scan_memory, new_clock, run_packed
from ..mixture import N_ROWS, ROW_W, GaussianMixture
from ..scan_evidence import MEMORY_LEN, scan_memory_from_state
from . import kernels
from .config import PMBConfig, pmb_config
from .filter import RobotCentricPMB, estimate_table

__all__ = ["PMBBank", "PMBBankView"]


class PMBBank:
    """``n_robots`` robot-centric PMB filters sharing one config, updated in batches.

    Parameters
    ----------
    config : PMBConfig or PHDConfig
        Configuration of every filter (a ``PHDConfig``: shared models, PMB defaults).
    n_robots : int
        Number of filters ``R``.

    Notes
    -----
    State: tracks ``(6, R, max_tracks)``, Poisson intensities ``(6, R, max_components)``, their
    counts, and pending measurement births. All inputs are validated before any state changes
    (``ValueError`` naming ``calls[r]`` and the argument).
    """

    def __init__(self, config: Any, n_robots: int) -> None:
        try:
            config = pmb_config(config)
        except ValueError as exc:
            raise ValueError(f"config must be a PMBConfig or PHDConfig, got {config!r}") from exc
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        if n_robots < 1:
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        self.config = config
        self.n_robots = int(n_robots)
        self._params = kernels.pack_pmb_params(config)
        r = self.n_robots
        self._tracks = np.zeros((N_ROWS, r, config.max_tracks))
        self._track_counts = np.zeros(r, dtype=np.int64)
        self._poisson = np.zeros((N_ROWS, r, config.phd.max_components))
        self._poisson_counts = np.zeros(r, dtype=np.int64)
        self._pending = np.zeros((r, 8, 2))
        self._pending_counts = np.zeros(r, dtype=np.int64)
        self._clock = new_clock(r)  # process-noise clock per robot (localization.kernels)
        # Each robot's last scan with its wide objects (RobotCentricPMB's scan memory).
        self._scan_memory = np.zeros((r, MEMORY_LEN))
        self._mixtures: list[GaussianMixture | None] = [None] * r
        self.views = [PMBBankView(self, i) for i in range(r)]

    def __getstate__(self) -> dict[str, Any]:
        return {
            "config": self.config,
            "n_robots": self.n_robots,
            "tracks": self._tracks,
            "track_counts": self._track_counts,
            "poisson": self._poisson,
            "poisson_counts": self._poisson_counts,
            "pending": self._pending,
            "pending_counts": self._pending_counts,
            "clock": self._clock,
            "scan_memory": self._scan_memory,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"], state["n_robots"])  # type: ignore[misc]
        self._tracks = np.array(state["tracks"], dtype=float)
        self._track_counts = np.array(state["track_counts"], dtype=np.int64)
        self._poisson = np.array(state["poisson"], dtype=float)
        self._poisson_counts = np.array(state["poisson_counts"], dtype=np.int64)
        self._pending = np.array(state["pending"], dtype=float)
        self._pending_counts = np.array(state["pending_counts"], dtype=np.int64)
        if "clock" in state:  # absent from states pickled before the clock existed
            self._clock = np.array(state["clock"], dtype=float)
        if "scan_memory" in state:  # absent from states pickled before the wide objects
            self._scan_memory = bank_scan_memory(state["scan_memory"], self.n_robots)

    # ------------------------------------------------------------------ state access
    @property
    def counts(self) -> np.ndarray:
        """Number of Bernoulli tracks per robot, ``(R,)`` (a copy)."""
        return self._track_counts.astype(np.intp)

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's tracks: a read-only view ``(6, R, max_tracks)`` (rows ``r, x, y, Pxx,
        Pxy, Pyy``; columns past ``counts[r]`` are zero) and ``counts (R,)``."""
        view = self._tracks.view()
        view.setflags(write=False)
        return view, self.counts

    def table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s tracks, ``(6, N)`` (a new array)."""
        r = self._robot(robot)
        return self._tracks[:, r, : self._track_counts[r]].copy()

    def poisson_table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s Poisson intensity, ``(6, K)`` (a new array)."""
        r = self._robot(robot)
        return self._poisson[:, r, : self._poisson_counts[r]].copy()

    def pending_births(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s measurement births awaiting the next time update, ``(B, 2)``."""
        r = self._robot(robot)
        return self._pending[r, : self._pending_counts[r]].copy()

    def mixture(self, robot: int) -> GaussianMixture:
        """Robot ``robot``'s tracks as a :class:`GaussianMixture` (weights = ``r``; cached)."""
        r = self._robot(robot)
        mix = self._mixtures[r]
        if mix is None:
            mix = GaussianMixture.from_table(self._tracks[:, r, : self._track_counts[r]])
            self._mixtures[r] = mix
        return mix

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`RobotCentricPMB.estimate` of one robot: ``means (K, 2), existences (K,)``."""
        r = self._robot(robot)
        return estimate_table(self._tracks[:, r, : self._track_counts[r]], threshold)

    def reset(self, robots: Any = None) -> None:
        """Back to the empty prior, for ``robots`` (default: every robot)."""
        rob = np.arange(self.n_robots) if robots is None else self._checked_robots(robots)
        self._tracks[:, rob] = 0.0
        self._track_counts[rob] = 0
        self._poisson[:, rob] = 0.0
        self._poisson_counts[rob] = 0
        self._pending_counts[rob] = 0
        self._clock[rob] = new_clock(1)
        self._scan_memory[rob] = 0.0
        for r in rob.tolist():
            self._mixtures[r] = None

    # ------------------------------------------------------------------ conversion
    def load_filter(self, robot: int, f: RobotCentricPMB) -> None:
        """Copy the state of ``f`` (same config) into robot ``robot``."""
        r = self._robot(robot)
        if not isinstance(f, RobotCentricPMB) or f.config != self.config:
            raise ValueError("f must be a RobotCentricPMB with the bank's config")
        state = f.__getstate__()
        t, p, b = state["tracks"], state["poisson"], state["pending_births"]
        memory = scan_memory_from_state(state["scan_memory"])  # checked before any change
        self._reserve_pending(b.shape[0])
        self._tracks[:, r] = 0.0
        self._tracks[:, r, : t.shape[1]] = t
        self._track_counts[r] = t.shape[1]
        self._poisson[:, r] = 0.0
        self._poisson[:, r, : p.shape[1]] = p
        self._poisson_counts[r] = p.shape[1]
        self._pending[r, : b.shape[0]] = b
        self._pending_counts[r] = b.shape[0]
        self._clock[r] = state["clock"]
        self._scan_memory[r] = memory
        self._mixtures[r] = None

    @classmethod
    def from_filters(cls, filters: Sequence[RobotCentricPMB]) -> PMBBank:
        """A bank holding copies of the states of ``filters`` (all with the same config)."""
        filters = list(filters)
        if not filters or not all(isinstance(f, RobotCentricPMB) for f in filters):
            raise ValueError("filters must be a non-empty sequence of RobotCentricPMB")
        if any(f.config != filters[0].config for f in filters):
            raise ValueError("filters must all have the same config")
        bank = cls(filters[0].config, len(filters))
        for r, f in enumerate(filters):
            bank.load_filter(r, f)
        return bank

    def to_filter(self, robot: int) -> RobotCentricPMB:
        """An independent :class:`RobotCentricPMB` with robot ``robot``'s state."""
        f = RobotCentricPMB(self.config)
        f.__setstate__(
            {
                "config": self.config,
                "tracks": self.table(robot),
                "poisson": self.poisson_table(robot),
                "pending_births": self.pending_births(robot),
                "clock": self._clock[self._robot(robot)].copy(),
                "scan_memory": self._scan_memory[self._robot(robot)].copy(),
            }
        )
        return f

    @property
    def reads_scans(self) -> bool:
        """Whether the lidar calls' scan profiles are used: for the wide objects' camera
        clutter (``config.phd.models_wide_objects``); the scan evidence is the GM-PHD's
        only. A :class:`~localization.feed.SwarmFeed` packs them only then."""
        return self.config.phd.models_wide_objects

    # ------------------------------------------------------------------ steps
    def apply(self, calls: Sequence[Sequence[tuple]]) -> None:
        """Run each robot's calls in order, all robots in one compiled batch.

        Parameters
        ----------
        calls : sequence of R sequences
            ``calls[r]``: robot ``r``'s time-ordered ``("predict", odometry (3,))``,
            ``("lidar", points (M, 2), null_bearings (B,) or None[, sensor_pose (3,) or None])``
            ``("camera", bearings (M,)[, sensor_pose])`` and ``("advance", stamp_s)`` (as
            :meth:`PHDBank.apply`; a ``SwarmFeed.calls()`` sequence runs from its packed
            arrays, as there).

        Raises
        ------
        ValueError
            A malformed call (``calls[r]`` and the argument named); nothing changes.
        """
        if run_packed(self, calls):  # a SwarmFeed's calls: its arrays, no tuples
            return
        calls = list(calls)
        if len(calls) != self.n_robots:
            raise ValueError(
                f"calls must have one list per robot ({self.n_robots}), got {len(calls)}"
            )
        batch = _Batch()
        for r, seq in enumerate(calls):
            if isinstance(seq, (str, bytes)) or not isinstance(seq, Sequence):
                raise ValueError(f"calls[{r}] must be a list of call tuples, got {seq!r}")
            for c in seq:
                batch.add_call(r, c)
        encoded = batch.encode()
        if not all_finite(encoded):
            for r, seq in enumerate(calls):  # slow path, only to name the culprit
                for c in seq:
                    _Batch().add_call(r, c, exact=True)
        if not batch.robots:
            return
        self._reserve_pending(batch.max_points)
        self._run_encoded(encoded, set(batch.robots))

    def _run_encoded(self, encoded: tuple, robots: Any) -> None:
        """Run validated ``encoded`` calls touching ``robots``; pending room reserved."""
        kernels.apply_calls(
            self._tracks,
            self._track_counts,
            self._poisson,
            self._poisson_counts,
            self._pending,
            self._pending_counts,
            self._clock,
            self._scan_memory,
            encoded,
            *self._params,
        )
        for r in robots:
            self._mixtures[r] = None

    def predict(self, robots: Any, odometry: Any) -> None:
        """Time update of ``robots (K,)`` (distinct) with ``odometry (K, 3)``, as
        :meth:`PHDBank.predict`."""
        rob = self._checked_robots(robots)
        odo = np.asarray(odometry, dtype=float)
        if odo.shape != (rob.shape[0], 3):
            raise ValueError(
                f"odometry must have shape ({rob.shape[0]}, 3) [dx_m, dy_m, dpsi_rad] to "
                f"match robots, got shape {odo.shape}"
            )
        self._apply_one_each(rob, [("predict", row) for row in odo])

    def update_lidar(self, robots: Any, points: Sequence[Any], null_bearings: Any = None) -> None:
        """Lidar update of ``robots``: ``points[k] (M_k, 2)``, ``null_bearings`` None or a list
        of ``(B_k,)`` / None, as :meth:`PHDBank.update_lidar`."""
        rob = self._checked_robots(robots)
        pts = _per_robot(points, "points", rob.shape[0])
        nulls = [None] * rob.shape[0]
        if null_bearings is not None:
            nulls = _per_robot(null_bearings, "null_bearings", rob.shape[0])
        self._apply_one_each(rob, [("lidar", p, nb) for p, nb in zip(pts, nulls, strict=True)])

    def update_camera(self, robots: Any, bearings: Sequence[Any]) -> None:
        """Camera update of ``robots`` with ``bearings[k] (M_k,)``, as
        :meth:`PHDBank.update_camera`."""
        rob = self._checked_robots(robots)
        brg = _per_robot(bearings, "bearings", rob.shape[0])
        self._apply_one_each(rob, [("camera", b) for b in brg])

    # ------------------------------------------------------------------ internals
    def _apply_one_each(self, robots: np.ndarray, calls: list[tuple]) -> None:
        per_robot: list[list[tuple]] = [[] for _ in range(self.n_robots)]
        for r, c in zip(robots.tolist(), calls, strict=True):
            per_robot[r].append(c)
        self.apply(per_robot)

    def _robot(self, robot: Any) -> int:
        if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)):
            raise ValueError(f"robot must be an int index, got {robot!r}")
        if not 0 <= robot < self.n_robots:
            raise ValueError(f"robot must be in [0, {self.n_robots}), got {robot}")
        return int(robot)

    def _checked_robots(self, robots: Any) -> np.ndarray:
        rob = np.asarray(robots)
        if rob.ndim != 1 or (rob.size and rob.dtype.kind not in "iu"):
            raise ValueError(f"robots must be a 1-D array of int indices, got {robots!r}")
        rob = rob.astype(np.intp)
        if rob.size and (rob.min() < 0 or rob.max() >= self.n_robots):
            raise ValueError(f"robots must be in [0, {self.n_robots}), got {rob.tolist()}")
        if np.unique(rob).shape[0] != rob.shape[0]:
            raise ValueError(f"robots must be distinct, got {rob.tolist()}")
        return rob

    def _reserve_pending(self, n_points: int) -> None:
        if n_points > self._pending.shape[1]:
            grown = np.zeros((self.n_robots, max(n_points, 2 * self._pending.shape[1]), 2))
            grown[:, : self._pending.shape[1]] = self._pending
            self._pending = grown


def _per_robot(values: Any, name: str, k: int) -> list[Any]:
    """A list of ``k`` per-robot entries (validated later, per call, by ``apply``)."""
    if isinstance(values, np.ndarray) or not isinstance(values, Sequence):
        raise ValueError(
            f"{name} must be a list of {k} arrays (one per robot), got {type(values)}"
        )
    if len(values) != k:
        raise ValueError(f"{name} must have one entry per robot ({k}), got {len(values)}")
    return list(values)


class PMBBankView:
    """Robot ``robot`` of a :class:`PMBBank`, read like a :class:`RobotCentricPMB`."""

    __slots__ = ("bank", "robot")

    def __init__(self, bank: PMBBank, robot: int) -> None:
        self.bank = bank
        self.robot = robot

    @property
    def config(self) -> PMBConfig:
        return self.bank.config

    @property
    def mixture(self) -> GaussianMixture:
        """Tracks (weights = existence probabilities), read-only, cached until the next call."""
        return self.bank.mixture(self.robot)

    @property
    def table(self) -> np.ndarray:
        """Tracks as a ``(6, N)`` table (a read-only copy)."""
        t = self.bank.table(self.robot)
        t.flags.writeable = False
        return t

    @property
    def total_weight(self) -> float:
        return float(self.bank._tracks[ROW_W, self.robot].sum())

    def __len__(self) -> int:
        return int(self.bank._track_counts[self.robot])

    def __repr__(self) -> str:
        return (
            f"PMBBankView(robot={self.robot}, tracks={len(self)}, sum_r={self.total_weight:.3f})"
        )

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return self.bank.estimate(self.robot, threshold)

    def reset(self) -> None:
        self.bank.reset([self.robot])

    # Occasional single-robot calls, run as batches of one (batch them on the bank in loops).
    def predict(self, odometry: Any) -> None:
        self._one(("predict", odometry))

    def update_lidar(
        self, points: Any, null_bearings: Any = None, sensor_pose: Any = None
    ) -> None:
        self._one(("lidar", points, null_bearings, sensor_pose))

    def update_camera(self, bearings: Any, sensor_pose: Any = None) -> None:
        self._one(("camera", bearings, sensor_pose))

    def _one(self, call: tuple) -> None:
        calls: list[list[tuple]] = [[] for _ in range(self.bank.n_robots)]
        calls[self.robot].append(call)
        self.bank.apply(calls)

    def to_filter(self) -> RobotCentricPMB:
        return self.bank.to_filter(self.robot)
