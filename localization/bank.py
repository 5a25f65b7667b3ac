"""Many robots' filters advanced together: the compiled filter banks.

A swarm env runs one robot-centric filter per robot and makes ~100 small filter calls per
control step. A bank keeps the ``R`` robots' states in padded tables and runs a whole batch of
calls in one compiled function, so the cost is the arithmetic, not ~100 numpy calls per
filter update.

:class:`FilterBank` is the driver every compiled family shares: it validates and encodes the
calls (:class:`_Batch`), keeps the per-robot tables, pending births, process-noise clocks and
scan memories, runs the family's kernel, and is itself a
:class:`~localization.protocol.Localizer` (``step(feed)`` runs the feed's packed arrays,
``padded_tables()``, ``mixture(r)``, ``estimate(r)``, ``reset()``, pickling, ``views``). A
family is a small subclass that names its hooks: its tables, its kernel and parameters, its
reference filter and its extraction. :class:`PHDBank` (below) is the GM-PHD family;
``localization.pmb.PMBBank`` the Poisson multi-Bernoulli one.

:class:`PHDBank` keeps the ``R`` mixtures in one padded table of shape ``(6, R, C)``: rows
``w, x, y, Pxx, Pxy, Pyy``, robot ``r`` uses the first ``counts[r]`` of its ``C =
max_components`` columns and the rest is zero. Every robot gets what its own
:class:`~localization.RobotCentricPHD` (the pure-numpy reference) would compute for the same
calls: the same components, values equal up to floating-point summation order, which
``tests/localization/test_bank.py`` checks (to 1e-10) on random call sequences for every model
option.

>>> import numpy as np
>>> from localization import PHDBank, PHDConfig
>>> bank = PHDBank(PHDConfig(), n_robots=20)
>>> bank.predict(np.arange(20), np.zeros((20, 3)))
>>> bank.update_lidar([0, 3], [np.array([[1.0, 0.5]]), np.empty((0, 2))], None)
>>> bank.update_camera([3], [np.array([0.2, -1.0])])
>>> bank.views[3].mixture          # a GaussianMixture, as RobotCentricPHD.mixture
GaussianMixture(...)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np

from swarm_core.validation import as_float_array

from . import kernels
from .config import PHDConfig
from .feed import SwarmFeed
from .filter import (
    MAX_INPUT_MAGNITUDE,
    MAX_MEASUREMENTS_PER_CALL,
    RobotCentricPHD,
    _checked_angles,
    _checked_odometry,
    _checked_points,
    _checked_stamp,
    checked_pose,
    checked_scan_profile,
    estimate_table,
)
from .mixture import N_ROWS, ROW_W, GaussianMixture
from .protocol import LocalizerBase, LocalizerView
from .scan_memory import MEMORY_LEN, N_BINS, scan_memory_from_state

__all__ = ["FilterBank", "BankTable", "PHDBank", "BankView"]

_KIND_CODES = {
    "predict": kernels.PREDICT,
    "lidar": kernels.LIDAR,
    "camera": kernels.CAMERA,
    "advance": kernels.ADVANCE,
}
# ("predict", odometry), ("lidar", points, nulls, sensor_pose, scan_profile),
# ("camera", bearings, sensor_pose), ("advance", stamp_s)
_MAX_CALL_LEN = {"predict": 2, "lidar": 5, "camera": 3, "advance": 2}
_F64 = np.dtype(np.float64)
# Positions in the encoded batch (_Batch.encode): the stamps (any clock) and the scan profiles.
_STAMPS, _PROFILES = 17, 18


class BankTable:
    """One padded per-robot table of a bank family: ``name`` (its key in the bank's pickled
    state and in the reference filter's ``__getstate__``), ``count_name`` (the key of its
    counts in the bank's pickled state) and ``width(config)``, its number of columns."""

    __slots__ = ("name", "count_name", "width")

    def __init__(self, name: str, count_name: str, width: Callable[[Any], int]) -> None:
        self.name = name
        self.count_name = count_name
        self.width = width


class FilterBank(LocalizerBase):
    """``n_robots`` robot-centric filters of one family sharing one config, updated in
    batches: the driver of every compiled family.

    Parameters
    ----------
    config
        Configuration of every filter (the family's config class, see :meth:`checked_config`).
    n_robots : int
        Number of filters ``R`` (robot ``r`` is index ``r``).

    Notes
    -----
    State: the family's padded tables ``(6, R, width)`` and their counts ``(R,)``, each
    robot's pending measurement births, process-noise clock and scan memory.
    :meth:`predict`, :meth:`update_lidar` and :meth:`update_camera` take ``robots``, an int
    array of distinct robot indices ``(K,)``, and the per-robot inputs in the same order;
    :meth:`apply` takes every robot's time-ordered call list at once, :meth:`step` a whole
    :class:`~localization.feed.SwarmFeed` (what the env does each step). Robots not named are
    untouched. Every method validates all of its inputs before changing any state
    (``ValueError`` naming the argument). Per robot, the math is that of the family's
    :attr:`reference` filter.

    ``views`` holds one :class:`BankView` per robot, read and stepped like a single filter.

    A family subclass sets the hooks: :attr:`tables` (the first is the one
    :meth:`padded_tables` shows), :attr:`reference`, :attr:`weight_meaning`,
    :meth:`checked_config`, :meth:`pack_params`, :meth:`kernel` and, where they differ from
    the defaults, :meth:`estimate_table`, :attr:`reads_scans` and :meth:`filter_with_mixture`.
    """

    #: The family's padded tables; ``tables[0]`` is what :meth:`padded_tables` shows.
    tables: ClassVar[tuple[BankTable, ...]] = ()
    #: The pure-numpy single filter whose math the kernel runs (``from_filters``, ``to_filter``,
    #: ``set_mixture``), or None for a family without one.
    reference: ClassVar[type | None] = None

    # ------------------------------------------------------------------ family hooks
    @classmethod
    def checked_config(cls, config: Any) -> Any:
        """The family's config from ``config`` (``ValueError`` naming it when it is not one)."""
        raise NotImplementedError(f"{cls.__name__} must define checked_config")

    @staticmethod
    def pack_params(config: Any) -> tuple[np.ndarray, ...]:
        """The model parameters of ``config``, the tuple the :meth:`kernel` takes as ``params``."""
        raise NotImplementedError("a bank family must define pack_params")

    @staticmethod
    def kernel(state: tuple, calls: tuple, params: tuple) -> None:
        """The compiled ``apply_calls(state, calls, params)`` that runs encoded calls on the
        bank's state in place: ``state = (table_0, counts_0, table_1, counts_1, ..., pending,
        pending_counts, clock, scan_memory)`` (:meth:`kernel_state`), ``calls`` the encoded
        batch (:mod:`localization.kernels`), ``params`` :meth:`pack_params`."""
        raise NotImplementedError("a bank family must define kernel")

    @staticmethod
    def estimate_table(table: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """Robot extraction from its ``(6, N)`` table: ``positions (K, 2), weights (K,)``
        (default: the GM-PHD's, :func:`localization.filter.estimate_table`)."""
        return estimate_table(table, threshold)

    def filter_with_mixture(self, mixture: GaussianMixture) -> Any:
        """A reference filter whose first table is ``mixture`` (validated by it)."""
        f = self._reference()(self.config)
        f.set_mixture(mixture)
        return f

    @property
    def reads_scans(self) -> bool:
        """Whether the lidar calls' scan profiles are used (``config.reads_scans``); a
        :class:`~localization.feed.SwarmFeed` packs them only then."""
        return bool(self.config.reads_scans)

    # ------------------------------------------------------------------ construction
    def __init__(self, config: Any, n_robots: int) -> None:
        if not self.tables:
            raise NotImplementedError(f"{type(self).__name__} must define its tables")
        config = self.checked_config(config)
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        if n_robots < 1:
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        self.config = config
        self.n_robots = r = int(n_robots)
        self._params = self.pack_params(config)
        self._tables = [np.zeros((N_ROWS, r, t.width(config))) for t in self.tables]
        self._counts = [np.zeros(r, dtype=np.int64) for _ in self.tables]
        self._pending = np.zeros((r, 8, 2))
        self._pending_counts = np.zeros(r, dtype=np.int64)
        # Per robot: last stamp (nan: none yet), advanced since the last predict (kernels).
        self._clock = new_clock(r)
        # Per robot: its last lidar scan (localization.scan_memory), row 0 = none yet.
        self._scan_memory = np.zeros((r, MEMORY_LEN))
        self._mixtures: list[GaussianMixture | None] = [None] * r
        self._views = [BankView(self, i) for i in range(r)]

    def __getstate__(self) -> dict[str, Any]:
        state: dict[str, Any] = {"config": self.config, "n_robots": self.n_robots}
        for t, table, counts in zip(self.tables, self._tables, self._counts, strict=True):
            state[t.name] = table
            state[t.count_name] = counts
        state.update(
            pending=self._pending,
            pending_counts=self._pending_counts,
            clock=self._clock,
            scan_memory=self._scan_memory,
        )
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"], state["n_robots"])  # type: ignore[misc]
        self._tables = [np.array(state[t.name], dtype=float) for t in self.tables]
        self._counts = [np.array(state[t.count_name], dtype=np.int64) for t in self.tables]
        self._pending = np.array(state["pending"], dtype=float)
        self._pending_counts = np.array(state["pending_counts"], dtype=np.int64)
        if "clock" in state:  # absent from states pickled before the clock existed
            self._clock = np.array(state["clock"], dtype=float)
        if "scan_memory" in state:  # absent from states pickled before the scan memory
            self._scan_memory = bank_scan_memory(state["scan_memory"], self.n_robots)

    @classmethod
    def from_filters(cls, filters: Sequence[Any]) -> FilterBank:
        """A bank holding copies of the states of ``filters`` (all of the family's
        :attr:`reference` class, all with the same config).

        Raises
        ------
        ValueError
            If ``filters`` is empty, holds another kind of filter, or the configs differ.
        """
        reference = cls._reference()
        filters = list(filters)
        name = reference.__name__
        if not filters or not all(isinstance(f, reference) for f in filters):
            raise ValueError(f"filters must be a non-empty sequence of {name}")
        config = filters[0].config
        if any(f.config != config for f in filters):
            raise ValueError("filters must all have the same config")
        bank = cls(config, len(filters))
        for r, f in enumerate(filters):
            bank.load_filter(r, f)
        return bank

    def load_filter(self, robot: int, f: Any) -> None:
        """Copy the state of ``f`` (a :attr:`reference` filter, same config) into robot
        ``robot``."""
        r = self._robot(robot)
        reference = self._reference()
        if not isinstance(f, reference) or f.config != self.config:
            raise ValueError(f"f must be a {reference.__name__} with the bank's config")
        state = f.__getstate__()
        tables = [np.asarray(state[t.name], dtype=float).reshape(N_ROWS, -1) for t in self.tables]
        for t, table, padded in zip(self.tables, tables, self._tables, strict=True):
            if table.shape[1] > padded.shape[2]:
                raise ValueError(
                    f"f has {table.shape[1]} {t.name} columns, more than the bank's "
                    f"{padded.shape[2]}"
                )
        births = np.asarray(state["pending_births"], dtype=float).reshape(-1, 2)
        memory = scan_memory_from_state(state["scan_memory"])  # checked before any change
        self._reserve_pending(births.shape[0])
        for table, padded, counts in zip(tables, self._tables, self._counts, strict=True):
            n = table.shape[1]
            padded[:, r, :n] = table
            padded[:, r, n:] = 0.0
            counts[r] = n
        self._pending[r, : births.shape[0]] = births
        self._pending_counts[r] = births.shape[0]
        self._clock[r] = state["clock"]
        self._scan_memory[r] = memory
        self._mixtures[r] = None

    def to_filter(self, robot: int) -> Any:
        """An independent :attr:`reference` filter with robot ``robot``'s current state."""
        r = self._robot(robot)
        f = self._reference()(self.config)
        state = {"config": self.config}
        for k, t in enumerate(self.tables):
            state[t.name] = self._table_of(k, r)
        state.update(
            pending_births=self.pending_births(r),
            clock=self._clock[r].copy(),
            scan_memory=self._scan_memory[r].copy(),
        )
        f.__setstate__(state)
        return f

    def to_filters(self) -> list[Any]:
        """:meth:`to_filter` for every robot."""
        return [self.to_filter(r) for r in range(self.n_robots)]

    # ------------------------------------------------------------------ state access
    @property
    def views(self) -> list[BankView]:  # type: ignore[override]
        """One :class:`BankView` per robot."""
        return self._views

    @property
    def counts(self) -> np.ndarray:
        """Number of columns of the first table per robot, shape ``(R,)`` (a copy)."""
        return self._counts[0].astype(np.intp)

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's first table at once: a read-only view ``(6, R, width)`` (rows
        ``w, x, y, pxx, pxy, pyy``; columns past ``counts[r]`` are zero) and ``counts (R,)``.
        """
        view = self._tables[0].view()
        view.setflags(write=False)
        return view, self.counts

    def table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s first table, shape ``(6, N)`` (a new array)."""
        return self._table_of(0, self._robot(robot))

    def pending_births(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s measurement births awaiting the next time update, ``(B, 2)`` m."""
        robot = self._robot(robot)
        return self._pending[robot, : self._pending_counts[robot]].copy()

    def mixture(self, robot: int) -> GaussianMixture:
        """Robot ``robot``'s first table as a read-only :class:`GaussianMixture` (cached)."""
        robot = self._robot(robot)
        mix = self._mixtures[robot]
        if mix is None:
            mix = GaussianMixture.from_table(self._tables[0][:, robot, : self._counts[0][robot]])
            self._mixtures[robot] = mix
        return mix

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """The reference filter's ``estimate(threshold)`` of robot ``robot``:
        ``positions (K, 2), weights (K,)``, heaviest first."""
        robot = self._robot(robot)
        return self.estimate_table(self._tables[0][:, robot, : self._counts[0][robot]], threshold)

    def reset(self, robots: Any = None) -> None:
        """Back to the empty prior, for ``robots`` (default: every robot)."""
        rob = np.arange(self.n_robots) if robots is None else self._checked_robots(robots)
        for table, counts in zip(self._tables, self._counts, strict=True):
            table[:, rob] = 0.0
            counts[rob] = 0
        self._pending_counts[rob] = 0
        self._clock[rob] = new_clock(1)
        self._scan_memory[rob] = 0.0
        for r in rob.tolist():
            self._mixtures[r] = None

    def set_mixture(self, robot: int, mixture: GaussianMixture) -> None:
        """Robot ``robot``'s first table becomes ``mixture``, validated by the reference
        filter (its other tables emptied, pending births cleared; clock and scan kept)."""
        r = self._robot(robot)
        f = self.filter_with_mixture(mixture)
        state = f.__getstate__()
        state["clock"] = self._clock[r].copy()
        state["scan_memory"] = self._scan_memory[r].copy()
        f.__setstate__(state)
        self.load_filter(r, f)

    # ------------------------------------------------------------------ steps
    def step(self, feed: SwarmFeed) -> None:
        """Consume one env step of the whole swarm's measurements: its packed arrays
        (:meth:`SwarmFeed.packed <localization.feed.SwarmFeed.packed>`) when they pass the
        batch-wide checks, else its call tuples, whose checks name the bad value."""
        self._check_feed(feed)
        packed = feed.packed(self.reads_scans)
        if packed is not None and all_finite(packed.encoded):
            if packed.robots:
                self._reserve_pending(packed.max_points)
                self._run_encoded(packed.encoded, packed.robots)
            return
        self.apply(feed.call_lists())

    def predict(self, robots: Any, odometry: Any) -> None:
        """Time update of ``robots`` (the reference's ``predict``, one row per robot).

        Parameters
        ----------
        robots : array_like of int, shape (K,)
            Distinct robot indices.
        odometry : array_like, shape (K, 3)
            ``[dx_m, dy_m, dpsi_rad]`` per robot, in its frame at the start of the interval.

        Raises
        ------
        ValueError
            Bad ``robots`` or ``odometry`` (shape or non-finite values); nothing changes.
        """
        rob = self._checked_robots(robots)
        odo = as_float_array(odometry, "odometry")
        if odo.shape != (rob.shape[0], 3):
            raise ValueError(
                f"odometry must have shape ({rob.shape[0]}, 3) [dx_m, dy_m, dpsi_rad] to "
                f"match robots, got shape {odo.shape}"
            )
        if not np.isfinite(odo).all():
            bad = int(np.flatnonzero(~np.isfinite(odo).all(axis=1))[0])
            raise ValueError(f"odometry must be finite, got odometry[{bad}] = {odo[bad].tolist()}")
        batch = _Batch()
        for r, row in zip(rob.tolist(), odo, strict=True):
            batch.predict(r, row)
        self._run(batch)

    def update_lidar(self, robots: Any, points: Sequence[Any], null_bearings: Any = None) -> None:
        """Lidar update of ``robots`` (the reference's ``update_lidar``).

        Parameters
        ----------
        robots : array_like of int, shape (K,)
            Distinct robot indices.
        points : sequence of K array_like, shape (M_k, 2)
            Each robot's detections (``M_k = 0`` allowed).
        null_bearings : None, or sequence of K (array_like, shape (B_k,), or None)
            Each robot's zero-intensity return bearings (rad).

        Raises
        ------
        ValueError
            Bad ``robots``, ``points`` or ``null_bearings``; nothing changes.
        """
        rob = self._checked_robots(robots)
        pts = _checked_list(points, "points", rob.shape[0], _checked_points)
        nulls = [None] * rob.shape[0]
        if null_bearings is not None:
            nulls = _checked_list(
                null_bearings, "null_bearings", rob.shape[0], _checked_nulls, allow_none=True
            )
        batch = _Batch()
        for r, p, nb in zip(rob.tolist(), pts, nulls, strict=True):
            batch.lidar(r, p, nb)
        self._run(batch)

    def update_camera(self, robots: Any, bearings: Sequence[Any]) -> None:
        """Camera update of ``robots`` (the reference's ``update_camera``); a no-op (after
        validation) in ``mode="lidar-only"``.

        Parameters
        ----------
        robots : array_like of int, shape (K,)
            Distinct robot indices.
        bearings : sequence of K array_like, shape (M_k,)
            Each robot's bearings (rad; ``M_k = 0`` allowed).

        Raises
        ------
        ValueError
            Bad ``robots`` or ``bearings``; nothing changes.
        """
        rob = self._checked_robots(robots)
        brg = _checked_list(bearings, "bearings", rob.shape[0], _checked_bearings)
        batch = _Batch()
        for r, b in zip(rob.tolist(), brg, strict=True):
            batch.camera(r, b)
        self._run(batch)

    def apply(self, calls: Sequence[Sequence[tuple]]) -> None:
        """Run each robot's calls in order, all robots in one compiled batch.

        Parameters
        ----------
        calls : sequence of R sequences
            ``calls[r]`` is robot ``r``'s time-ordered list of ``("predict", odometry)``,
            ``("lidar", points, null_bearings_or_None[, sensor_pose[, scan_profile]])``,
            ``("camera", bearings[, sensor_pose])`` and ``("advance", stamp_s)``. The optional
            ``sensor_pose`` ``(3,)`` ``[x_m, y_m, psi_rad]`` (or None) is where the robot
            measured from, in the filter's frame: the measurement is moved into it first
            (:mod:`localization.frames`). ``("advance", stamp_s)`` moves the robot's
            process-noise clock to ``stamp_s`` (any finite clock, e.g. ROS time).

        Raises
        ------
        ValueError
            A malformed call (``calls[r]`` and the argument are named), or not one list per
            robot. All calls are validated before any state changes.
        """
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
            # Slow path, only to name the culprit: re-check every call exactly.
            for r, seq in enumerate(calls):
                for c in seq:
                    _Batch().add_call(r, c, exact=True)
        self._run(batch, encoded)

    # ------------------------------------------------------------------ internals
    @classmethod
    def _reference(cls) -> type:
        if cls.reference is None:
            raise ValueError(f"{cls.__name__} has no reference filter to load from or convert to")
        return cls.reference

    def _table_of(self, k: int, robot: int) -> np.ndarray:
        """Table ``k`` of robot ``robot`` (checked), ``(6, N)`` (a new array)."""
        return self._tables[k][:, robot, : self._counts[k][robot]].copy()

    def _checked_robots(self, robots: Any) -> np.ndarray:
        try:
            rob = np.asarray(robots)
        except (TypeError, ValueError) as exc:  # pragma: no cover - asarray rarely fails
            raise ValueError(f"robots must be integers, got {robots!r}") from exc
        if rob.ndim != 1 or (rob.size and rob.dtype.kind not in "iu"):
            raise ValueError(f"robots must be a 1-D array of int indices, got {robots!r}")
        rob = rob.astype(np.intp)
        if rob.size and (rob.min() < 0 or rob.max() >= self.n_robots):
            raise ValueError(f"robots must be in [0, {self.n_robots}), got {rob.tolist()}")
        if np.unique(rob).shape[0] != rob.shape[0]:
            raise ValueError(f"robots must be distinct, got {rob.tolist()}")
        return rob

    def _reserve_pending(self, n_points: int) -> None:
        """Room for ``n_points`` pending births per robot (a lidar call may leave that many)."""
        if n_points > self._pending.shape[1]:
            grown = np.zeros((self.n_robots, max(n_points, 2 * self._pending.shape[1]), 2))
            grown[:, : self._pending.shape[1]] = self._pending
            self._pending = grown

    def _run(self, batch: _Batch, encoded: tuple[np.ndarray, ...] | None = None) -> None:
        """Run the calls of a validated ``batch`` (``encoded``: its :meth:`_Batch.encode`)."""
        if not batch.robots:
            return
        if encoded is None:
            encoded = batch.encode()
        self._reserve_pending(batch.max_points)
        self._run_encoded(encoded, set(batch.robots))

    def kernel_state(self) -> tuple[np.ndarray, ...]:
        """The state the :meth:`kernel` writes: ``(table_0, counts_0, ..., pending,
        pending_counts, clock, scan_memory)``, the bank's own arrays (not copies)."""
        tables = [a for pair in zip(self._tables, self._counts, strict=True) for a in pair]
        return (*tables, self._pending, self._pending_counts, self._clock, self._scan_memory)

    def _run_encoded(self, encoded: tuple[np.ndarray, ...], robots: Any) -> None:
        """Run validated ``encoded`` calls touching ``robots``; pending room reserved."""
        self.kernel(self.kernel_state(), encoded, self._params)
        mixtures = self._mixtures
        for r in robots:
            mixtures[r] = None


class PHDBank(FilterBank):
    """``n_robots`` robot-centric GM-PHD filters sharing one config, updated in batches
    (:class:`FilterBank`; per robot the math of :class:`~localization.RobotCentricPHD`).

    Parameters
    ----------
    config : PHDConfig
        Configuration of every filter.
    n_robots : int
        Number of filters ``R`` (robot ``r`` is index ``r``).

    Notes
    -----
    One table, ``(6, R, max_components)``: each robot's PHD components (``w`` = expected
    number of teammates). Bounds per robot and filter call (``W = sum w``): a time update gives
    ``W' <= P_s,max W + measurement_birth_weight B`` (``B``: detections of the last scan since
    the last time update); a scan of ``M`` detections ``W' <= sum_i (1 - P_d,i) w_i + M``
    (Bernoulli missed copies: ``w_i (1 - P_d,i) / (1 - r_i P_d,i)``, ``r_i = w_i / max(1,
    ceil(w_i))``); a frame of ``K`` bearings the same with the camera's ``P_d`` and ``+ K (1 +
    camera_birth_weight)`` with ray births; at most ``max_components`` components.
    """

    name = "phd"
    weight_meaning = "phd-weight"
    tables = (BankTable("table", "counts", lambda c: c.reduction.max_components),)
    reference = RobotCentricPHD
    pack_params = staticmethod(kernels.pack_params)
    kernel = staticmethod(kernels.apply_calls)

    @classmethod
    def checked_config(cls, config: Any) -> PHDConfig:
        if not isinstance(config, PHDConfig):
            raise ValueError(f"config must be a PHDConfig, got {type(config).__name__}")
        return config


class BankView(LocalizerView):
    """Robot ``robot`` of a :class:`FilterBank`, read and stepped like its family's single
    reference filter.

    For readers (``.mixture``, ``.table``, ``.estimate()``, ``.identities()``,
    ``.total_weight``, ``len()``) and for occasional single-robot calls (``.predict()``,
    ``.advance()``, ``.update_lidar()``, ``.update_camera()``, ``.reset()``,
    ``.set_mixture()``), which run as batches of one: correct but without the speed-up.
    Batch the calls on the bank in hot loops.
    """

    __slots__ = ()

    @property
    def bank(self) -> FilterBank:
        return self.localizer  # type: ignore[return-value]

    @property
    def config(self) -> Any:
        return self.bank.config

    @property
    def table(self) -> np.ndarray:
        """Current ``(6, N)`` table (a read-only copy)."""
        t = self.bank.table(self.robot)
        t.flags.writeable = False
        return t

    @property
    def total_weight(self) -> float:
        """Sum of row ``w``: expected number of teammates (GM-PHD), ``sum r`` (PMB)."""
        return float(self.bank._tables[0][ROW_W, self.robot].sum())

    def __len__(self) -> int:
        return int(self.bank._counts[0][self.robot])

    def __repr__(self) -> str:
        return (
            f"BankView({type(self.bank).__name__}, robot={self.robot}, components={len(self)}, "
            f"total_weight={self.total_weight:.3f})"
        )

    def predict(self, odometry: Any) -> None:
        self._one(("predict", odometry))

    def advance(self, stamp_s: float) -> None:
        self._one(("advance", stamp_s))

    def update_lidar(self, points, null_bearings=None, sensor_pose=None, scan_profile=None):
        """As the reference's ``update_lidar``: ``points (M, 2)``, ``null_bearings (B,)``,
        ``sensor_pose (3,)`` and ``scan_profile (N_BINS,)`` (each optional but the points)."""
        self._one(("lidar", points, null_bearings, sensor_pose, scan_profile))

    def update_camera(self, bearings: Any, sensor_pose: Any = None) -> None:
        self._one(("camera", bearings, sensor_pose))

    def reset(self) -> None:
        self.bank.reset([self.robot])

    def set_mixture(self, mixture: GaussianMixture) -> None:
        """As the bank's :meth:`FilterBank.set_mixture` for this robot."""
        self.bank.set_mixture(self.robot, mixture)

    def to_filter(self) -> Any:
        return self.bank.to_filter(self.robot)

    def _one(self, call: tuple) -> None:
        calls: list[list[tuple]] = [[] for _ in range(self.bank.n_robots)]
        calls[self.robot].append(call)
        self.bank.apply(calls)


class _Batch:
    """Validated filter calls, encoded as the flat arrays of :mod:`localization.kernels`."""

    __slots__ = (
        "robots",
        "kinds",
        "index",
        "odometry",
        "points",
        "nulls",
        "bearings",
        "lidar_poses",
        "profiles",
        "camera_poses",
        "stamps",
    )

    def __init__(self) -> None:
        self.robots: list[int] = []
        self.kinds: list[int] = []
        self.index: list[int] = []  # rank of the call among those of its kind
        self.odometry: list[np.ndarray] = []  # (3,) per predict
        self.points: list[np.ndarray] = []  # (M, 2) per lidar call
        self.nulls: list[np.ndarray] = []  # (B,) per lidar call
        self.bearings: list[np.ndarray] = []  # (M,) per camera call
        self.lidar_poses: list[np.ndarray | None] = []  # sensor pose (3,) per lidar call
        self.profiles: list[np.ndarray | None] = []  # scan profile (N_BINS,) per lidar call
        self.camera_poses: list[np.ndarray | None] = []  # sensor pose (3,) per camera call
        self.stamps: list[float] = []  # per advance call (s)

    @property
    def max_points(self) -> int:
        return max((p.shape[0] for p in self.points), default=0)

    def predict(self, r: int, odo: np.ndarray) -> None:
        self.robots.append(r)
        self.kinds.append(kernels.PREDICT)
        self.index.append(len(self.odometry))
        self.odometry.append(odo)

    def lidar(
        self,
        r: int,
        pts: np.ndarray,
        nulls: np.ndarray | None,
        pose: np.ndarray | None = None,
        profile: np.ndarray | None = None,
    ) -> None:
        self.robots.append(r)
        self.kinds.append(kernels.LIDAR)
        self.index.append(len(self.points))
        self.points.append(pts)
        self.nulls.append(_NO_ANGLES if nulls is None else nulls)
        self.lidar_poses.append(pose)
        self.profiles.append(profile)

    def camera(self, r: int, brg: np.ndarray, pose: np.ndarray | None = None) -> None:
        self.robots.append(r)
        self.kinds.append(kernels.CAMERA)
        self.index.append(len(self.bearings))
        self.bearings.append(brg)
        self.camera_poses.append(pose)

    def advance(self, r: int, stamp_s: float) -> None:
        self.robots.append(r)
        self.kinds.append(kernels.ADVANCE)
        self.index.append(len(self.stamps))
        self.stamps.append(stamp_s)

    def add_call(self, r: int, call: Any, exact: bool = False) -> None:
        """Append ``calls[r]``'s tuple ``call``. Shapes are checked here; finiteness by
        :meth:`all_finite` over the whole batch (or here, per array, when ``exact``)."""
        if (
            not isinstance(call, tuple)
            or not call
            or not isinstance(call[0], str)
            or call[0] not in _KIND_CODES
            or len(call) > _MAX_CALL_LEN[call[0]]
        ):
            raise ValueError(f"calls[{r}] has an invalid call {call!r}")
        kind = call[0]
        try:
            if kind == "camera":
                brg = call[1]
                if exact or not _is_f64(brg, 1) or brg.shape[0] > MAX_MEASUREMENTS_PER_CALL:
                    brg = _checked_bearings(brg)
                self.camera(r, brg, _checked_pose(call[2], exact) if len(call) > 2 else None)
            elif kind == "predict":
                odo = call[1]
                if exact or not _is_f64(odo, 1) or odo.shape[0] != 3:
                    odo = _checked_odometry(odo)
                self.predict(r, odo)
            elif kind == "advance":
                self.advance(r, _checked_stamp(call[1]))
            else:
                pts = call[1]
                if (
                    exact
                    or not _is_f64(pts, 2)
                    or pts.shape[1] != 2
                    or pts.shape[0] > MAX_MEASUREMENTS_PER_CALL
                ):
                    pts = _checked_points(pts)
                nb = call[2] if len(call) > 2 else None
                if nb is not None and (
                    exact or not _is_f64(nb, 1) or nb.shape[0] > MAX_MEASUREMENTS_PER_CALL
                ):
                    nb = _checked_nulls(nb)
                pose = _checked_pose(call[3], exact) if len(call) > 3 else None
                profile = call[4] if len(call) > 4 else None
                if profile is not None and (
                    exact or not _is_f64(profile, 1) or profile.shape[0] != N_BINS
                ):
                    profile = checked_scan_profile(profile)
                self.lidar(r, pts, nb, pose, profile)
        except (ValueError, IndexError) as exc:
            raise ValueError(f"calls[{r}]: {exc}") from exc

    def encode(self) -> tuple[np.ndarray, ...]:
        """``robots, kinds, index, odometry, lidar_start, lidar_stop, points, null_start,
        null_stop, nulls, camera_start, camera_stop, bearings, lidar_pose, lidar_has_pose,
        camera_pose, camera_has_pose, stamps, profiles, lidar_has_profile``, as
        :func:`localization.kernels.apply_calls` takes them."""
        lidar_stop = np.cumsum([p.shape[0] for p in self.points], dtype=np.int64)
        null_stop = np.cumsum([b.shape[0] for b in self.nulls], dtype=np.int64)
        camera_stop = np.cumsum([b.shape[0] for b in self.bearings], dtype=np.int64)
        return (
            np.array(self.robots, dtype=np.int64),
            np.array(self.kinds, dtype=np.int64),
            np.array(self.index, dtype=np.int64),
            _joined(self.odometry, (3,)),
            np.concatenate(([0], lidar_stop[:-1])).astype(np.int64),
            lidar_stop,
            _joined(self.points, (2,)),
            np.concatenate(([0], null_stop[:-1])).astype(np.int64),
            null_stop,
            _joined(self.nulls, ()),
            np.concatenate(([0], camera_stop[:-1])).astype(np.int64),
            camera_stop,
            _joined(self.bearings, ()),
            *_poses(self.lidar_poses),
            *_poses(self.camera_poses),
            np.array(self.stamps, dtype=np.float64),
            *_profiles(self.profiles),
        )


def all_finite(encoded: tuple[np.ndarray, ...]) -> bool:
    """Whether the float buffers of an encoded batch hold only finite values within
    :data:`~localization.filter.MAX_INPUT_MAGNITUDE` (m or rad), finite stamps (seconds of any
    clock, ROS time included) and scan profiles >= 0; else the caller re-checks every call
    exactly to name the culprit."""
    stamps, profiles = encoded[_STAMPS], encoded[_PROFILES]
    return (
        bool(np.isfinite(stamps).all())
        and all(
            a.size == 0 or np.abs(a).max() <= MAX_INPUT_MAGNITUDE  # NaN compares False
            for k, a in enumerate(encoded)
            if a.dtype == _F64 and k != _STAMPS
        )
        and (profiles.size == 0 or profiles.min() >= 0.0)
    )


def bank_scan_memory(value: Any, n_robots: int) -> np.ndarray:
    """A bank's saved scan memories as today's ``(n_robots, MEMORY_LEN)``
    (:func:`~localization.scan_memory.scan_memory_from_state`, which names what is wrong).

    Raises
    ------
    ValueError
        Also for a shape that does not hold one memory per robot."""
    memory = scan_memory_from_state(value)
    if memory.shape != (n_robots, MEMORY_LEN):
        raise ValueError(
            f"scan_memory: shape {memory.shape} for {n_robots} robots, expected "
            f"{(n_robots, MEMORY_LEN)}"
        )
    return memory


def new_clock(n_robots: int) -> np.ndarray:
    """A fresh per-robot process-noise clock, shape ``(n_robots, 2)``: no stamp yet (nan),
    not advanced since the last predict (see :func:`localization.kernels.advance_clock`)."""
    clock = np.zeros((n_robots, 2))
    clock[:, 0] = np.nan
    return clock


def _joined(arrays: list[np.ndarray], tail: tuple[int, ...]) -> np.ndarray:
    """``arrays`` stacked along their first axis; ``(0, *tail)`` when there are none."""
    if not arrays:
        return np.zeros((0, *tail))
    if not tail:
        return np.concatenate(arrays)
    return np.concatenate(arrays).reshape(-1, *tail)


def _poses(poses: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """Sensor poses ``(N, 3)`` (zeros where None) and their flags ``(N,)``."""
    flags = np.array([p is not None for p in poses], dtype=np.int64)
    out = np.zeros((len(poses), 3))
    if flags.any():
        out[flags.astype(bool)] = [p for p in poses if p is not None]
    return out, flags


def _profiles(profiles: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """Scan profiles ``(L, N_BINS)`` (zeros where None) and their flags ``(L,)``."""
    flags = np.array([p is not None for p in profiles], dtype=np.int64)
    out = np.zeros((len(profiles), N_BINS))
    if flags.any():
        out[flags.astype(bool)] = [p for p in profiles if p is not None]
    return out, flags


def _checked_pose(value: Any, exact: bool) -> np.ndarray | None:
    """A call's optional sensor pose ``[x_m, y_m, psi_rad]`` (finiteness: see all_finite)."""
    if not exact and _is_f64(value, 1) and value.shape[0] == 3:
        return value  # the fast path: finiteness is checked batch-wide
    return checked_pose(value)


_NO_ANGLES = np.empty(0)


def _is_f64(value: Any, ndim: int) -> bool:
    return type(value) is np.ndarray and value.dtype == _F64 and value.ndim == ndim


# ---------------------------------------------------------------------- helpers
def _checked_bearings(value: Any) -> np.ndarray:
    return _checked_angles(value, "bearings")


def _checked_nulls(value: Any) -> np.ndarray:
    return _checked_angles(value, "null_bearings")


def _checked_list(
    values: Any, name: str, k: int, check: Any, allow_none: bool = False
) -> list[Any]:
    """Validate a per-robot list with the single filter's checks; errors name ``name[i]``."""
    if isinstance(values, np.ndarray) or not isinstance(values, Sequence):
        raise ValueError(
            f"{name} must be a list of {k} arrays (one per robot), got {type(values)}"
        )
    if len(values) != k:
        raise ValueError(f"{name} must have one entry per robot ({k}), got {len(values)}")
    out = []
    for i, v in enumerate(values):
        if v is None and allow_none:
            out.append(None)
            continue
        try:
            out.append(check(v))
        except ValueError as exc:
            raise ValueError(f"{name}[{i}]: {exc}") from exc
    return out
