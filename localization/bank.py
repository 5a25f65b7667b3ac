"""Many robots' GM-PHD filters advanced together: :class:`PHDBank`.

A swarm env runs one robot-centric GM-PHD filter per robot and makes ~100 small filter calls
per control step. The bank keeps the ``R`` mixtures in one padded table and runs a whole batch
of calls in one compiled function (:func:`localization.kernels.apply_calls`), so the cost is the
arithmetic, not ~100 numpy calls per filter update. The table has shape ``(6, R, C)``: rows
``w, x, y, Pxx, Pxy, Pyy``, robot ``r`` uses the first ``counts[r]`` of its ``C =
max_components`` columns and the rest is zero.

Every robot gets what its own :class:`~localization.RobotCentricPHD` (the pure-numpy reference)
would compute for the same calls: the same components, values equal up to floating-point
summation order, which ``tests/localization/test_bank.py`` checks (to 1e-10) on random call
sequences for every model option.

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

from collections.abc import Sequence
from typing import Any

import numpy as np

from swarm_core.validation import as_float_array

from . import kernels
from .config import PHDConfig
from .feed import FeedCalls
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
)
from .mixture import N_ROWS, ROW_W, GaussianMixture
from .scan_evidence import MEMORY_LEN, N_BINS, scan_memory_from_state

__all__ = ["PHDBank", "PHDBankView"]

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


class PHDBank:
    """``n_robots`` robot-centric GM-PHD filters sharing one config, updated in batches.

    Parameters
    ----------
    config : PHDConfig
        Configuration of every filter.
    n_robots : int
        Number of filters ``R`` (robot ``r`` is index ``r``).

    Notes
    -----
    State: the padded ``(6, R, max_components)`` table, ``counts (R,)`` and each robot's
    pending measurement births (``birth == "measurement"``). :meth:`predict`,
    :meth:`update_lidar` and :meth:`update_camera` take ``robots``, an int array of distinct
    robot indices ``(K,)``, and the per-robot inputs in the same order; :meth:`apply` takes
    every robot's time-ordered call list at once (what the env does each step). Robots not
    named are untouched. Every method validates all of its inputs before changing any state
    (``ValueError`` naming the argument). Per robot, the math is that of
    :class:`RobotCentricPHD`.

    ``views`` holds one :class:`PHDBankView` per robot: ``.mixture``, ``.table``,
    ``.estimate()``, ``.predict()``, ``.update_lidar()``, ``.update_camera()``, ``.reset()``...
    as on :class:`RobotCentricPHD`, so code that reads a list of filters keeps working.
    """

    def __init__(self, config: PHDConfig, n_robots: int) -> None:
        if not isinstance(config, PHDConfig):
            raise ValueError(f"config must be a PHDConfig, got {type(config).__name__}")
        if isinstance(n_robots, bool) or not isinstance(n_robots, (int, np.integer)):
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        if n_robots < 1:
            raise ValueError(f"n_robots must be an int >= 1, got {n_robots!r}")
        self.config = config
        self.n_robots = int(n_robots)
        self._params = kernels.pack_params(config)
        self._table = np.zeros((N_ROWS, self.n_robots, config.max_components))
        self._counts = np.zeros(self.n_robots, dtype=np.int64)
        self._pending = np.zeros((self.n_robots, 8, 2))
        self._pending_counts = np.zeros(self.n_robots, dtype=np.int64)
        # Per robot: last stamp (nan: none yet), advanced since the last predict (kernels).
        self._clock = new_clock(self.n_robots)
        # Per robot: its last lidar scan (localization.scan_evidence), row 0 = none yet.
        self._scan_memory = np.zeros((self.n_robots, MEMORY_LEN))
        self._mixtures: list[GaussianMixture | None] = [None] * self.n_robots
        self.views = [PHDBankView(self, r) for r in range(self.n_robots)]

    def __getstate__(self) -> dict[str, Any]:
        return {
            "config": self.config,
            "n_robots": self.n_robots,
            "table": self._table,
            "counts": self._counts,
            "pending": self._pending,
            "pending_counts": self._pending_counts,
            "clock": self._clock,
            "scan_memory": self._scan_memory,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"], state["n_robots"])  # type: ignore[misc]
        self._table = np.array(state["table"], dtype=float)
        self._counts = np.array(state["counts"], dtype=np.int64)
        self._pending = np.array(state["pending"], dtype=float)
        self._pending_counts = np.array(state["pending_counts"], dtype=np.int64)
        if "clock" in state:  # absent from states pickled before the clock existed
            self._clock = np.array(state["clock"], dtype=float)
        if "scan_memory" in state:  # absent from states pickled before the scan evidence
            self._scan_memory = bank_scan_memory(state["scan_memory"], self.n_robots)

    # ------------------------------------------------------------------ construction / export
    @classmethod
    def from_filters(cls, filters: Sequence[RobotCentricPHD]) -> PHDBank:
        """A bank holding copies of the states of ``filters`` (all with the same config).

        Raises
        ------
        ValueError
            If ``filters`` is empty, holds a non-filter, or the configs differ.
        """
        filters = list(filters)
        if not filters or not all(isinstance(f, RobotCentricPHD) for f in filters):
            raise ValueError("filters must be a non-empty sequence of RobotCentricPHD")
        config = filters[0].config
        if any(f.config != config for f in filters):
            raise ValueError("filters must all have the same config")
        bank = cls(config, len(filters))
        for r, f in enumerate(filters):
            bank.load_filter(r, f)
        return bank

    def load_filter(self, robot: int, f: RobotCentricPHD) -> None:
        """Copy the state of ``f`` (same config) into robot ``robot``."""
        r = int(self._checked_robots([robot])[0])
        if not isinstance(f, RobotCentricPHD) or f.config != self.config:
            raise ValueError("f must be a RobotCentricPHD with the bank's config")
        state = f.__getstate__()
        table = np.asarray(state["table"], dtype=float)
        n = table.shape[1]
        if n > self.config.max_components:
            raise ValueError(
                f"f has {n} components, more than max_components {self.config.max_components}"
            )
        births = np.asarray(state["pending_births"], dtype=float).reshape(-1, 2)
        memory = scan_memory_from_state(state["scan_memory"])  # checked before any change
        self._reserve_pending(births.shape[0])
        self._table[:, r, :n] = table
        self._table[:, r, n:] = 0.0
        self._counts[r] = n
        self._pending[r, : births.shape[0]] = births
        self._pending_counts[r] = births.shape[0]
        self._clock[r] = state["clock"]
        self._scan_memory[r] = memory
        self._mixtures[r] = None

    def to_filter(self, robot: int) -> RobotCentricPHD:
        """An independent :class:`RobotCentricPHD` with robot ``robot``'s current state."""
        r = int(self._checked_robots([robot])[0])
        f = RobotCentricPHD(self.config)
        f.__setstate__(
            {
                "config": self.config,
                "table": self.table(r),
                "pending_births": self.pending_births(r),
                "clock": self._clock[r].copy(),
                "scan_memory": self._scan_memory[r].copy(),
            }
        )
        return f

    def to_filters(self) -> list[RobotCentricPHD]:
        """:meth:`to_filter` for every robot."""
        return [self.to_filter(r) for r in range(self.n_robots)]

    # ------------------------------------------------------------------ state access
    @property
    def reads_scans(self) -> bool:
        """Whether the lidar calls' scan profiles are used (``config.reads_scans``: the scan
        evidence or the wide objects' camera clutter); a :class:`~localization.feed.SwarmFeed`
        packs them only then."""
        return self.config.reads_scans

    @property
    def counts(self) -> np.ndarray:
        """Number of components per robot, shape ``(R,)`` (a copy)."""
        return self._counts.astype(np.intp)

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's table at once: a read-only view ``(6, R, max_components)`` (rows
        ``w, x, y, pxx, pxy, pyy``; columns past ``counts[r]`` are zero) and ``counts (R,)``.
        """
        view = self._table.view()
        view.setflags(write=False)
        return view, self.counts

    def table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s component table, shape ``(6, N)`` (a new array)."""
        robot = self._robot(robot)
        return self._table[:, robot, : self._counts[robot]].copy()

    def pending_births(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s measurement births awaiting the next time update, ``(B, 2)`` m."""
        robot = self._robot(robot)
        return self._pending[robot, : self._pending_counts[robot]].copy()

    def mixture(self, robot: int) -> GaussianMixture:
        """Robot ``robot``'s PHD as a read-only :class:`GaussianMixture` (cached)."""
        robot = self._robot(robot)
        mix = self._mixtures[robot]
        if mix is None:
            mix = GaussianMixture.from_table(self._table[:, robot, : self._counts[robot]])
            self._mixtures[robot] = mix
        return mix

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`RobotCentricPHD.estimate` of one robot: ``positions (K, 2), weights (K,)``."""
        robot = self._robot(robot)
        holder = _TableHolder(self._table[:, robot, : self._counts[robot]])
        return RobotCentricPHD.estimate(holder, threshold)  # type: ignore[arg-type]

    def reset(self, robots: Any = None) -> None:
        """Back to the empty prior, for ``robots`` (default: every robot)."""
        rob = np.arange(self.n_robots) if robots is None else self._checked_robots(robots)
        self._table[:, rob] = 0.0
        self._counts[rob] = 0
        self._pending_counts[rob] = 0
        self._clock[rob] = new_clock(1)
        self._scan_memory[rob] = 0.0
        for r in rob.tolist():
            self._mixtures[r] = None

    # ------------------------------------------------------------------ steps
    def predict(self, robots: Any, odometry: Any) -> None:
        """Time update of ``robots`` (:meth:`RobotCentricPHD.predict`, one row per robot).

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
        """Lidar update of ``robots`` (:meth:`RobotCentricPHD.update_lidar`), then reduce.

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
        """Camera update of ``robots`` (:meth:`RobotCentricPHD.update_camera`), then reduce.

        A no-op (after validation) in ``mode="lidar-only"``.

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
            ``("lidar", points, null_bearings_or_None[, sensor_pose])`` and
            ``("camera", bearings[, sensor_pose])``. The optional ``sensor_pose`` ``(3,)``
            ``[x_m, y_m, psi_rad]`` (or None) is where the robot measured from, in the
            filter's frame: the measurement is moved into it first (:mod:`localization.frames`).
            ``("advance", stamp_s)`` moves the robot's process-noise clock to ``stamp_s``
            (:meth:`RobotCentricPHD.advance`; any finite clock, e.g. ROS time).
            A :meth:`SwarmFeed.calls() <localization.feed.SwarmFeed.calls>` sequence is run
            from its packed arrays (:func:`localization.feed.pack_calls`, the same calls
            encoded without tuples) whenever they pass the batch-wide checks.

        Raises
        ------
        ValueError
            A malformed call (``calls[r]`` and the argument are named), or not one list per
            robot. All calls are validated before any state changes.
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
            # Slow path, only to name the culprit: re-check every call exactly.
            for r, seq in enumerate(calls):
                for c in seq:
                    _Batch().add_call(r, c, exact=True)
        self._run(batch, encoded)

    # ------------------------------------------------------------------ internals
    def _robot(self, robot: Any) -> int:
        """One robot index, checked (no negative wrap-around)."""
        if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)):
            raise ValueError(f"robot must be an int index, got {robot!r}")
        if not 0 <= robot < self.n_robots:
            raise ValueError(f"robot must be in [0, {self.n_robots}), got {robot}")
        return int(robot)

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

    def _run_encoded(self, encoded: tuple[np.ndarray, ...], robots: Any) -> None:
        """Run validated ``encoded`` calls touching ``robots``; pending room reserved."""
        fparams, iparams, sector_scaled, sector_params = self._params
        kernels.apply_calls(
            self._table,
            self._counts,
            self._pending,
            self._pending_counts,
            self._clock,
            self._scan_memory,
            encoded,
            fparams,
            iparams,
            sector_scaled,
            sector_params,
        )
        mixtures = self._mixtures
        for r in robots:
            mixtures[r] = None


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


def run_packed(bank: Any, calls: Any) -> bool:
    """Run ``calls`` on ``bank`` (a :class:`PHDBank` or a ``PMBBank``) from their packed arrays
    if they are a checked :meth:`SwarmFeed.calls() <localization.feed.SwarmFeed.calls>`
    (:func:`packed_of`); False (nothing done) otherwise."""
    packed = packed_of(calls, bank.n_robots, bank.reads_scans)
    if packed is None:
        return False
    if packed.robots:
        bank._reserve_pending(packed.max_points)
        bank._run_encoded(packed.encoded, packed.robots)
    return True


def packed_of(calls: Any, n_robots: int, scan_profiles: bool = True) -> Any:
    """The :class:`~localization.feed.PackedCalls` behind ``calls`` when it is a
    :meth:`SwarmFeed.calls() <localization.feed.SwarmFeed.calls>` of ``n_robots`` robots whose
    arrays pass :func:`all_finite` (with the scan profiles only if ``scan_profiles``); else None
    (the caller encodes the tuples, whose checks name any bad value)."""
    if calls.__class__ is not FeedCalls or len(calls) != n_robots:
        return None
    packed = calls.feed.packed(scan_profiles)
    if packed is None or not all_finite(packed.encoded):
        return None
    return packed


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
    (:func:`~localization.scan_evidence.scan_memory_from_state`, which names what is wrong).

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


class PHDBankView:
    """Robot ``robot`` of a :class:`PHDBank`, with the :class:`RobotCentricPHD` interface.

    For readers (``.mixture``, ``.table``, ``.estimate()``, ``.total_weight``, ``len()``) and
    for occasional single-robot calls (``.predict()``, ``.update_lidar()``,
    ``.update_camera()``, ``.reset()``, ``.set_mixture()``), which run as batches of one:
    correct but without the speed-up. Batch the calls on the bank in hot loops.
    """

    __slots__ = ("bank", "robot")

    def __init__(self, bank: PHDBank, robot: int) -> None:
        self.bank = bank
        self.robot = robot

    @property
    def config(self) -> PHDConfig:
        return self.bank.config

    @property
    def mixture(self) -> GaussianMixture:
        """Current PHD (read-only, cached until the robot's next update)."""
        return self.bank.mixture(self.robot)

    @property
    def table(self) -> np.ndarray:
        """Current ``(6, N)`` component table (a read-only copy)."""
        t = self.bank.table(self.robot)
        t.flags.writeable = False
        return t

    @property
    def total_weight(self) -> float:
        return float(self.bank._table[ROW_W, self.robot].sum())

    def __len__(self) -> int:
        return int(self.bank._counts[self.robot])

    def __repr__(self) -> str:
        return (
            f"PHDBankView(robot={self.robot}, mode={self.config.mode!r}, "
            f"components={len(self)}, total_weight={self.total_weight:.3f})"
        )

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return self.bank.estimate(self.robot, threshold)

    def predict(self, odometry: Any) -> None:
        self.bank.predict([self.robot], np.asarray(_checked_odometry(odometry))[None])

    def update_lidar(self, points: Any, null_bearings: Any = None) -> None:
        self.bank.update_lidar(
            [self.robot], [points], None if null_bearings is None else [null_bearings]
        )

    def update_camera(self, bearings: Any) -> None:
        self.bank.update_camera([self.robot], [bearings])

    def reset(self) -> None:
        self.bank.reset([self.robot])

    def set_mixture(self, mixture: GaussianMixture) -> None:
        """Validated like :meth:`RobotCentricPHD.set_mixture` (clears pending births)."""
        f = RobotCentricPHD(self.config)
        f.set_mixture(mixture)
        self.bank.load_filter(self.robot, f)

    def to_filter(self) -> RobotCentricPHD:
        return self.bank.to_filter(self.robot)


# ---------------------------------------------------------------------- helpers
class _TableHolder:
    """Duck-typed stand-in so :meth:`RobotCentricPHD.estimate` runs on a bank table."""

    __slots__ = ("_table",)

    def __init__(self, table: np.ndarray) -> None:
        self._table = table


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
