"""Many robots' GM-PHD filters advanced with vectorised calls: :class:`PHDBank`.

A swarm env runs one :class:`~localization.RobotCentricPHD` per robot, and at ~20 components
each update is ~100 small numpy calls: per-call overhead, not arithmetic, sets the cost. The
bank keeps the ``R`` mixtures in one padded array and advances a *batch* of robots with one
set of numpy calls, using the very same pure functions (:mod:`localization.phd`,
:mod:`localization.detection`, :mod:`localization.reducer`), which take an optional robot
axis: a batched component table has shape ``(6, K, N)`` (rows ``w, x, y, Pxx, Pxy, Pyy``,
``K`` robots, ``N`` columns of which robot ``k`` uses the first ``counts[k]``; the rest is
padding with weight 0, which prunes away and explains nothing).

Every robot gets exactly what its own ``RobotCentricPHD`` would compute for the same calls
(same components; values equal up to floating-point summation order, ~1e-15 relative), which
``tests/localization/test_bank.py`` checks on random call sequences.

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

from . import phd
from .config import PHDConfig
from .detection import DetectionModel
from .filter import RobotCentricPHD, _checked_angles, _checked_odometry, _checked_points
from .mixture import N_ROWS, ROW_W, GaussianMixture
from .reducer import reduce_batched

__all__ = ["PHDBank", "PHDBankView"]

_KINDS = ("predict", "lidar", "camera")


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
    State: ``table`` of shape ``(6, R, max_components)`` (zero padding beyond each robot's
    count), ``counts (R,)``, and each robot's pending measurement births (``birth ==
    "measurement"``). Each method takes ``robots``, an int array of distinct robot indices
    ``(K,)``, and the per-robot inputs in the same order; robots not listed are untouched.
    Every method validates all of its inputs before changing any state (``ValueError``
    naming the argument). Per robot, the math is that of :class:`RobotCentricPHD`.

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
        self._model = DetectionModel(config)
        self._fixed_birth = phd.birth_components(
            np.asarray([config.birth_mean_m], dtype=float),
            config.birth_std_m**2,
            config.birth_weight,
        )
        self._table = np.zeros((N_ROWS, self.n_robots, config.max_components))
        self._counts = np.zeros(self.n_robots, dtype=np.intp)
        self._pending: list[np.ndarray] = [np.empty((0, 2))] * self.n_robots
        self._mixtures: list[GaussianMixture | None] = [None] * self.n_robots
        self.views = [PHDBankView(self, r) for r in range(self.n_robots)]

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
        r = self._checked_robots([robot])[0]
        if not isinstance(f, RobotCentricPHD) or f.config != self.config:
            raise ValueError("f must be a RobotCentricPHD with the bank's config")
        state = f.__getstate__()
        table = np.asarray(state["table"], dtype=float)
        if table.shape[1] > self.config.max_components:
            raise ValueError(
                f"f has {table.shape[1]} components, more than max_components "
                f"{self.config.max_components}"
            )
        self._store(np.array([r]), table[:, None, :], np.array([table.shape[1]]))
        self._pending[r] = np.array(state["pending_births"], dtype=float).reshape(-1, 2)

    def to_filter(self, robot: int) -> RobotCentricPHD:
        """An independent :class:`RobotCentricPHD` with robot ``robot``'s current state."""
        r = self._checked_robots([robot])[0]
        f = RobotCentricPHD(self.config)
        f.__setstate__(
            {
                "config": self.config,
                "table": self.table(r),
                "pending_births": self._pending[r],
            }
        )
        return f

    def to_filters(self) -> list[RobotCentricPHD]:
        """:meth:`to_filter` for every robot."""
        return [self.to_filter(r) for r in range(self.n_robots)]

    # ------------------------------------------------------------------ state access
    @property
    def counts(self) -> np.ndarray:
        """Number of components per robot, shape ``(R,)`` (a copy)."""
        return self._counts.copy()

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Every robot's table at once: a read-only view ``(6, R, max_components)`` (rows
        ``w, x, y, pxx, pxy, pyy``; columns past ``counts[r]`` are padding) and ``counts (R,)``.
        """
        view = self._table.view()
        view.setflags(write=False)
        return view, self.counts

    def table(self, robot: int) -> np.ndarray:
        """Robot ``robot``'s component table, shape ``(6, N)`` (a new array)."""
        return self._table[:, robot, : self._counts[robot]].copy()

    def mixture(self, robot: int) -> GaussianMixture:
        """Robot ``robot``'s PHD as a read-only :class:`GaussianMixture` (cached)."""
        mix = self._mixtures[robot]
        if mix is None:
            mix = GaussianMixture.from_table(self._table[:, robot, : self._counts[robot]])
            self._mixtures[robot] = mix
        return mix

    def estimate(self, robot: int, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`RobotCentricPHD.estimate` of one robot: ``positions (K, 2), weights (K,)``."""
        holder = _TableHolder(self._table[:, robot, : self._counts[robot]])
        return RobotCentricPHD.estimate(holder, threshold)  # type: ignore[arg-type]

    def reset(self, robots: Any = None) -> None:
        """Back to the empty prior, for ``robots`` (default: every robot)."""
        rob = np.arange(self.n_robots) if robots is None else self._checked_robots(robots)
        self._table[:, rob] = 0.0
        self._counts[rob] = 0
        for r in rob.tolist():
            self._pending[r] = np.empty((0, 2))
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
        odo = _as_float(odometry, "odometry")
        if odo.shape != (rob.shape[0], 3):
            raise ValueError(
                f"odometry must have shape ({rob.shape[0]}, 3) [dx_m, dy_m, dpsi_rad] to "
                f"match robots, got shape {odo.shape}"
            )
        if not np.isfinite(odo).all():
            bad = int(np.flatnonzero(~np.isfinite(odo).all(axis=1))[0])
            raise ValueError(f"odometry must be finite, got odometry[{bad}] = {odo[bad].tolist()}")
        self._predict(rob, odo)

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
        nulls = None
        if null_bearings is not None:
            nulls = _checked_list(
                null_bearings, "null_bearings", rob.shape[0], _checked_nulls, allow_none=True
            )
        self._update_lidar(rob, pts, nulls)

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
        if self.config.mode == "lidar-only":
            return
        self._update_camera(rob, brg)

    def apply(self, calls: Sequence[Sequence[tuple]]) -> None:
        """Run each robot's calls in order, batching robots whose next call is of one kind.

        Parameters
        ----------
        calls : sequence of R sequences
            ``calls[r]`` is robot ``r``'s time-ordered list of ``("predict", odometry)``,
            ``("lidar", points, null_bearings_or_None)`` and ``("camera", bearings)``.

        Notes
        -----
        Robots are independent, so only each robot's own order matters. The batches are
        formed greedily: among the robots with calls left, the kind that is the next call of
        the most robots runs for all of them. All calls are validated before any state
        changes.
        """
        calls = list(calls)
        if len(calls) != self.n_robots:
            raise ValueError(
                f"calls must have one list per robot ({self.n_robots}), got {len(calls)}"
            )
        queues = []
        for r, seq in enumerate(calls):
            queue = []
            for c in seq:
                if not isinstance(c, tuple) or not c or c[0] not in _KINDS:
                    raise ValueError(f"calls[{r}] has an invalid call {c!r}")
                kind = c[0]
                try:
                    if kind == "predict":
                        queue.append((kind, _checked_odometry(c[1])))
                    elif kind == "lidar":
                        nb = c[2] if len(c) > 2 else None
                        queue.append(
                            (
                                kind,
                                _checked_points(c[1]),
                                None if nb is None else _checked_nulls(nb),
                            )
                        )
                    else:
                        queue.append((kind, _checked_bearings(c[1])))
                except (ValueError, IndexError) as exc:
                    raise ValueError(f"calls[{r}]: {exc}") from exc
            queue.reverse()  # pop() from the end
            queues.append(queue)
        while True:
            heads = [(q[-1][0] if q else None) for q in queues]
            tally = {k: heads.count(k) for k in _KINDS}
            kind = max(_KINDS, key=tally.__getitem__)
            if tally[kind] == 0:
                return
            rob = np.array([r for r, h in enumerate(heads) if h == kind], dtype=np.intp)
            items = [queues[r].pop() for r in rob.tolist()]
            if kind == "predict":
                self._predict(rob, np.array([it[1] for it in items]))
            elif kind == "lidar":
                nulls = [it[2] for it in items]
                self._update_lidar(
                    rob, [it[1] for it in items], None if all(x is None for x in nulls) else nulls
                )
            elif self.config.mode != "lidar-only":
                self._update_camera(rob, [it[1] for it in items])

    # ------------------------------------------------------------------ internals
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

    def _gather(self, rob: np.ndarray, extra: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """Batched table ``(6, K, W)`` of ``rob`` with room for ``extra`` more columns."""
        n = self._counts[rob]
        used = int(n.max(initial=0))
        width = max(int((n + extra).max(initial=0)), 1)
        tab = np.zeros((N_ROWS, rob.shape[0], width))
        tab[:, :, :used] = self._table[:, rob, :used]
        return tab, n

    def _store(self, rob: np.ndarray, table: np.ndarray, counts: np.ndarray) -> None:
        """Write a zero-padded batched table (width <= max_components) back."""
        width = table.shape[2]
        self._table[:, rob, :width] = table
        self._table[:, rob, width:] = 0.0
        self._counts[rob] = counts
        mixtures = self._mixtures
        for r in rob.tolist():
            mixtures[r] = None

    def _reduce_store(self, rob: np.ndarray, table: np.ndarray) -> None:
        cfg = self.config
        out, counts = reduce_batched(
            table, cfg.prune_threshold, cfg.merge_threshold, cfg.max_components
        )
        self._store(rob, out, counts)

    def _predict(self, rob: np.ndarray, odo: np.ndarray) -> None:
        if rob.shape[0] == 0:
            return
        cfg = self.config
        pending = [self._pending[r] for r in rob.tolist()]
        n_birth = np.array([p.shape[0] for p in pending], dtype=np.intp)
        tab, n = self._gather(rob, n_birth)
        survival = self._model.survival(tab)
        total = n + n_birth
        if n_birth.any():
            # Adaptive births measured in the previous frame: appended after each robot's
            # components, moved with the frame, no survival factor (as in RobotCentricPHD).
            births = phd.birth_components(
                np.concatenate(pending),
                cfg.measurement_birth_cov_scale * cfg.lidar_noise_var_m2,
                cfg.measurement_birth_weight,
            )
            rows = np.repeat(np.arange(rob.shape[0]), n_birth)
            slots = np.arange(rows.shape[0]) - np.repeat(np.cumsum(n_birth) - n_birth, n_birth)
            slots += n[rows]
            tab[:, rows, slots] = births
            survival[rows, slots] = 1.0
            for r in rob.tolist():
                self._pending[r] = np.empty((0, 2))
        out = phd.predict(tab, odo, survival, cfg.process_noise_std_m**2)
        out *= np.arange(out.shape[2]) < total[:, None]  # padding back to 0
        over = total > cfg.max_components
        if over.any():
            self._reduce_store(rob[over], out[:, over])
            keep = ~over
            rob, out, total = rob[keep], out[:, keep], total[keep]
        self._store(rob, out[:, :, : cfg.max_components], total)

    def _update_lidar(
        self, rob: np.ndarray, pts: list[np.ndarray], nulls: list[np.ndarray | None] | None
    ) -> None:
        if rob.shape[0] == 0:
            return
        cfg = self.config
        k = rob.shape[0]
        m = np.array([p.shape[0] for p in pts], dtype=np.intp)
        has = m > 0
        fixed_birth = cfg.birth == "fixed" and bool(has.any())
        tab, n = self._gather(rob, has.astype(np.intp) if fixed_birth else 0)
        if fixed_birth:
            # The fixed birth joins the prior of every lidar update with detections.
            tab[:, has.nonzero()[0], n[has]] = self._fixed_birth
        null_pad, null_valid = _pad_ragged(nulls, (), k) if nulls is not None else (None, None)
        pd = self._model.lidar(tab, null_pad, null_valid)
        if has.any():
            pts_pad, valid = _pad_ragged(pts, (2,), k)
            out, explained = phd.lidar_update(
                tab, pts_pad, pd, cfg.lidar_noise_var_m2, cfg.lidar_clutter_intensity, valid
            )
            if fixed_birth:
                out[ROW_W, has.nonzero()[0], n[has]] = 0.0  # drop the birth's missed copy
            if not has.all():
                # Robots without detections: the missed-detection factor only, written as
                # RobotCentricPHD writes it (w * (1 - P_d)).
                width = tab.shape[2]
                out[ROW_W, ~has, :width] = tab[ROW_W, ~has] * (1.0 - pd[~has])
        else:
            out = tab
            out[ROW_W] *= 1.0 - pd
            explained = valid = None
        if cfg.birth == "measurement":
            if explained is None:
                self._set_pending(rob, [np.empty((0, 2))] * k)
            else:
                born = valid & (explained < cfg.measurement_birth_max_explained)
                flat = pts_pad[born]
                split = np.cumsum(np.count_nonzero(born, axis=1))[:-1]
                self._set_pending(rob, np.split(flat, split))
        self._reduce_store(rob, out)

    def _update_camera(self, rob: np.ndarray, brg: list[np.ndarray]) -> None:
        if rob.shape[0] == 0:
            return
        cfg = self.config
        tab, _ = self._gather(rob, 0)
        pd = self._model.camera(tab)
        m = np.array([b.shape[0] for b in brg], dtype=np.intp)
        has = m > 0
        if has.any():
            brg_pad, valid = _pad_ragged(brg, (), rob.shape[0])
            out, _ = phd.camera_update(
                tab,
                brg_pad,
                pd,
                cfg.camera_noise_var_rad2,
                cfg.camera_clutter_intensity,
                cfg.min_range_m,
                valid,
            )
            if not has.all():
                width = tab.shape[2]
                out[ROW_W, ~has, :width] = tab[ROW_W, ~has] * (1.0 - pd[~has])
        else:
            out = tab
            out[ROW_W] *= 1.0 - pd
        self._reduce_store(rob, out)

    def _set_pending(self, rob: np.ndarray, births: list[np.ndarray]) -> None:
        for r, b in zip(rob.tolist(), births, strict=False):
            self._pending[r] = b


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


def _as_float(value: Any, name: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc


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


def _pad_ragged(
    arrays: list[np.ndarray | None], tail: tuple[int, ...], k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Stack K ragged ``(M_k, *tail)`` arrays (None: empty) as ``(K, M, *tail)`` + mask."""
    lengths = np.array([0 if a is None else a.shape[0] for a in arrays], dtype=np.intp)
    width = int(lengths.max(initial=0))
    valid = np.arange(width) < lengths[:, None]
    out = np.zeros((k, width, *tail))
    if width:
        out[valid] = np.concatenate([a for a in arrays if a is not None and a.shape[0]])
    return out, valid
