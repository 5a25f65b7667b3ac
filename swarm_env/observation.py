"""Observation encoders: what each agent sees, as one flat float32 vector.

An encoder object is chosen at construction (``SwarmConfig.observation``, see :data:`ENCODERS`):
:class:`EstimateEncoder` (``"phd"``: the agent's own localizer estimate), :class:`TruthEncoder`
(``"truth"``) and :class:`MeasurementEncoder` (``"measurements"``). Each has a
:class:`ObservationLayout` naming its table columns, which scripted controllers and the SB3
feature extractor read instead of column numbers (``layout.column("x_m")``).

Layout (``observation="phd"`` and ``"truth"``)::

    [ K rows x (w, x_m, y_m, sxx_m2, sxy_m2, syy_m2, valid) | v_mps, omega_radps | task features ]

- ``phd``: the agent's own PHD components, largest weight first (``w`` = component weight).
- ``truth``: the true neighbours within ``localization_range_m``, nearest first, ``w = 1`` and zero
  covariance (the upper bound a perfect localizer would give).

Layout (``observation="measurements"``)::

    [ K rows x (x_m, y_m, valid) lidar detections of the last scan, nearest first
    | K rows x (cos b, sin b, valid) camera bearings of the last frame
    | v_mps, omega_radps | task features ]

With ``SwarmConfig.lidar_sectors = S > 0`` one more table follows the neighbour table(s), before
the odometry: ``S rows x (range_m,)``, the robot's own last lidar scan summarised per angular
sector (:func:`lidar_sector_ranges`; sector 0 centred straight ahead, then counter-clockwise,
REP-103). It is what the scripted controllers push off walls and obstacles with.

Positions are in the agent's body frame (REP-103). Unused rows are zeros. Every entry is clipped to
the observation space's bounds so that ``space.contains(obs)`` always holds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from numba import njit

from swarm_core.world import WorldStep
from swarm_env.sensors.kernels import stable_order

#: Columns of a row of the estimate / truth table. ``w``: the component's weight (GM-PHD: its
#: expected number of teammates) or the track's existence probability (multi-Bernoulli
#: localizers); covariances in m^2; ``valid``: 1 for a real row, 0 for padding.
ESTIMATE_COLUMNS = ("w", "x_m", "y_m", "sxx_m2", "sxy_m2", "syy_m2", "valid")
#: Columns of the measurement tables: lidar detections, then camera bearings.
LIDAR_COLUMNS = ("x_m", "y_m", "valid")
CAMERA_COLUMNS = ("cos_bearing", "sin_bearing", "valid")
#: Column of the lidar sector table (``SwarmConfig.lidar_sectors > 0``).
SECTOR_COLUMNS = ("range_m",)
SECTOR_TABLE = "lidar_sectors"
MAX_POSITION_M = 20.0
MAX_WEIGHT = 10.0
MAX_VARIANCE_M2 = 25.0


def table_bounds(top_k: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the K x 7 neighbour table, flattened."""
    low = np.array([0.0, -MAX_POSITION_M, -MAX_POSITION_M, 0.0, -MAX_VARIANCE_M2, 0.0, 0.0])
    high = np.array(
        [
            MAX_WEIGHT,
            MAX_POSITION_M,
            MAX_POSITION_M,
            MAX_VARIANCE_M2,
            MAX_VARIANCE_M2,
            MAX_VARIANCE_M2,
            1.0,
        ]
    )
    return np.tile(low, top_k), np.tile(high, top_k)


def measurement_bounds(top_k: int) -> tuple[np.ndarray, np.ndarray]:
    lidar_low = np.tile([-MAX_POSITION_M, -MAX_POSITION_M, 0.0], top_k)
    lidar_high = np.tile([MAX_POSITION_M, MAX_POSITION_M, 1.0], top_k)
    cam_low, cam_high = np.tile([-1.0, -1.0, 0.0], top_k), np.tile([1.0, 1.0, 1.0], top_k)
    return np.r_[lidar_low, cam_low], np.r_[lidar_high, cam_high]


def build_space(
    mode: str,
    top_k: int,
    max_speed_mps: float,
    max_turn_rate_radps: float,
    feature_low: np.ndarray,
    feature_high: np.ndarray,
) -> spaces.Box:
    """The observation space shared by all agents."""
    low, high = table_bounds(top_k) if mode != "measurements" else measurement_bounds(top_k)
    low = np.concatenate([low, [-max_speed_mps, -max_turn_rate_radps], feature_low])
    high = np.concatenate([high, [max_speed_mps, max_turn_rate_radps], feature_high])
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)


def phd_tables(tables: np.ndarray, counts: np.ndarray, top_k: int) -> np.ndarray:
    """Each robot's top-K components by weight as rows ``[w, x, y, sxx, sxy, syy, 1]``,
    zero-padded, for R robots at once, from padded component tables.

    Parameters
    ----------
    tables : ndarray, shape (6, R, N)
        Rows ``w, x, y, pxx, pxy, pyy``; robot r's columns past ``counts[r]`` are padding.
    counts : ndarray, shape (R,)

    Returns
    -------
    ndarray, shape (R, top_k, 7)
        Largest weight first; equal weights keep their table order.
    """
    n_robots, width = tables.shape[1], tables.shape[2]
    valid = np.arange(width)[None, :] < counts[:, None]
    # Padding sorts last; a stable sort keeps equal weights in table order.
    keys = np.where(valid, -tables[0], np.inf)
    order = np.argsort(keys, axis=1, kind="stable")[:, :top_k]
    rows = np.take_along_axis(tables, order[None], axis=2)  # (6, R, k)
    kept = np.take_along_axis(valid, order, axis=1)
    out = np.zeros((n_robots, top_k, 7))
    k = order.shape[1]
    out[:, :k, :6] = np.where(kept[None], rows, 0.0).transpose(1, 2, 0)
    out[:, :k, 6] = kept
    return out


def truth_table(neighbours_xy: np.ndarray, top_k: int) -> np.ndarray:
    """True neighbours (M, 2), nearest first, as rows ``[1, x, y, 0, 0, 0, 1]``, (K, 7)."""
    table = np.zeros((top_k, 7))
    order = np.argsort(np.hypot(neighbours_xy[:, 0], neighbours_xy[:, 1]), kind="stable")[:top_k]
    n = order.size
    table[:n, 0] = 1.0
    table[:n, 1:3] = neighbours_xy[order]
    table[:n, 6] = 1.0
    return table


def truth_tables(relative_xy: np.ndarray, in_range: np.ndarray, rows, top_k: int) -> np.ndarray:
    """:func:`truth_table` of every robot in ``rows`` at once, (R, K, 7).

    ``relative_xy`` (N, M, 2) and ``in_range`` (N, M) bool as in
    :class:`~swarm_core.world.GroundTruth`. One stable sort of all the in-range pairs by
    (robot, distance) replaces a Python call per robot (~20 ms a step at 1000 robots); the
    rows and their order are :func:`truth_table`'s (ties keep the neighbours' index order).
    """
    rows = np.asarray(rows, dtype=np.intp)
    r, j = np.nonzero(in_range[rows])  # row-major: j ascending within each robot
    xy = relative_xy[rows[r], j]
    dist = np.hypot(xy[:, 0], xy[:, 1])
    order = np.lexsort((dist, r))  # stable: by robot, then distance, then j
    r, xy = r[order], xy[order]
    rank = np.arange(r.size) - np.searchsorted(r, r)  # position within its robot's run
    keep = rank < top_k
    out = np.zeros((rows.size, top_k, 7))
    out[r[keep], rank[keep], 0] = 1.0
    out[r[keep], rank[keep], 1:3] = xy[keep]
    out[r[keep], rank[keep], 6] = 1.0
    return out


def measurement_tables(
    detections: list[np.ndarray], bearings: list[np.ndarray], top_k: int
) -> np.ndarray:
    """Each robot's lidar detections (M_r, 2), nearest first, and camera bearings (B_r,),
    ascending, as padded rows ``[x, y, valid]`` and ``[cos b, sin b, valid]``: (R, 6 top_k)."""
    n = len(detections)
    det_counts = np.fromiter(map(len, detections), dtype=np.intp, count=n)
    cam_counts = np.fromiter(map(len, bearings), dtype=np.intp, count=n)
    pts = np.concatenate(detections).reshape(-1, 2) if det_counts.any() else np.zeros((0, 2))
    b = np.concatenate(bearings) if cam_counts.any() else np.zeros(0)
    out = np.zeros((n, 2, top_k, 3))
    _fill_measurement_tables(
        np.ascontiguousarray(pts, dtype=np.float64),
        np.hypot(pts[:, 0], pts[:, 1]),
        det_counts,
        np.asarray(b, dtype=np.float64),
        cam_counts,
        out,
    )
    # cos and sin in numpy, on the few filled slots (padding stays 0).
    cam = out[:, 1]
    filled = cam[..., 2] > 0.0
    angles = cam[..., 0][filled]
    cam[..., 0][filled] = np.cos(angles)
    cam[..., 1][filled] = np.sin(angles)
    return out.reshape(n, -1)


@njit(cache=True)
def _fill_measurement_tables(pts, ranges, det_counts, bearings, cam_counts, out):
    """Fill ``out`` (R, 2, K, 3): ``out[r, 0]`` robot r's detections ``pts`` (its run of
    ``det_counts[r]`` rows, (M, 2) m) nearest first by ``ranges`` (M,) (stable), as
    ``[x, y, 1]``; ``out[r, 1]`` its bearings (run of ``cam_counts[r]``, rad) ascending, as
    ``[b, 0, 1]`` (the caller turns b into cos b, sin b)."""
    top_k = out.shape[2]
    start = 0
    for r in range(det_counts.shape[0]):
        m = det_counts[r]
        order = stable_order(ranges[start : start + m])
        for j in range(min(m, top_k)):
            out[r, 0, j, 0] = pts[start + order[j], 0]
            out[r, 0, j, 1] = pts[start + order[j], 1]
            out[r, 0, j, 2] = 1.0
        start += m
    start = 0
    for r in range(cam_counts.shape[0]):
        m = cam_counts[r]
        order = stable_order(bearings[start : start + m])
        for j in range(min(m, top_k)):
            out[r, 1, j, 0] = bearings[start + order[j]]
            out[r, 1, j, 2] = 1.0
        start += m


def lidar_sector_ranges(
    angles_rad: list[np.ndarray], ranges_m: list[np.ndarray], n_sectors: int, max_range_m: float
) -> np.ndarray:
    """Each robot's lidar scan as the minimum valid range per angular sector, (R, S).

    Sector ``j`` spans body-frame bearings ``[(j - 1/2) w, (j + 1/2) w)`` with ``w = 2 pi / S``:
    sector 0 is centred straight ahead (+x), sector 1 is the next one counter-clockwise
    (towards +y, REP-103), ..., sector ``S - 1`` is just right of ahead. A return is valid when
    its range is finite and > 0 (0 is the driver's "no return"). Ranges are clipped to
    ``max_range_m``; a sector without a valid return reads ``max_range_m``.

    Parameters
    ----------
    angles_rad, ranges_m : list of R arrays, shape (B_r,)
        Robot r's scan (beam bearings in rad, ranges in m); scans may differ in length.
    n_sectors : int
        S >= 1.
    max_range_m : float
        > 0.
    """
    n = len(ranges_m)
    out = np.full((n, n_sectors), float(max_range_m))
    if n == 0:
        return out
    counts = np.fromiter(map(len, ranges_m), dtype=np.intp, count=n)
    if not counts.any():
        return out
    a = np.concatenate(angles_rad).astype(np.float64)
    r = np.concatenate(ranges_m).astype(np.float64)
    robot = np.repeat(np.arange(n), counts)
    width = 2.0 * np.pi / n_sectors
    sector = np.floor(np.mod(a + 0.5 * width, 2.0 * np.pi) / width).astype(np.intp)
    sector = np.minimum(sector, n_sectors - 1)  # mod can round up to exactly 2 pi
    ok = np.isfinite(r) & (r > 0.0) & np.isfinite(a)
    # One unbuffered scatter-min over all beams of all robots (no loop over rays).
    np.minimum.at(out, (robot[ok], sector[ok]), np.minimum(r[ok], max_range_m))
    return out


def assemble(
    space: spaces.Box, table: np.ndarray, velocity: np.ndarray, features: np.ndarray
) -> np.ndarray:
    """Concatenate and clip into ``space``; returns float32 of ``space.shape``."""
    obs = np.concatenate([table.ravel(), velocity, features]).astype(np.float32)
    return np.minimum(np.maximum(obs, space.low, out=obs), space.high, out=obs)


def assemble_rows(
    space: spaces.Box, tables: np.ndarray, velocity: np.ndarray, features: np.ndarray
) -> np.ndarray:
    """:func:`assemble` for R agents at once: tables (R, X), velocity (R, 2), features (R, F);
    returns float32 (R, *space.shape), row r equal to ``assemble`` of agent r's parts."""
    obs = np.concatenate([tables.reshape(tables.shape[0], -1), velocity, features], axis=1).astype(
        np.float32
    )
    return np.minimum(np.maximum(obs, space.low, out=obs), space.high, out=obs)


# ---------------------------------------------------------------------- encoder objects
@dataclass(frozen=True)
class ObservationLayout:
    """Where everything sits in the flat observation vector.

    ``tables`` lists the neighbour tables in order as ``(name, rows, columns)``; each is stored
    row-major (``rows x len(columns)``). Then ``[v_mps, omega_radps]`` (own odometry speed),
    then ``n_features`` task features.
    """

    tables: tuple[tuple[str, int, tuple[str, ...]], ...]
    n_features: int

    @property
    def table_size(self) -> int:
        return sum(rows * len(cols) for _, rows, cols in self.tables)

    @property
    def odometry_slice(self) -> slice:
        return slice(self.table_size, self.table_size + 2)

    @property
    def features_slice(self) -> slice:
        return slice(self.table_size + 2, self.table_size + 2 + self.n_features)

    @property
    def size(self) -> int:
        return self.table_size + 2 + self.n_features

    def column(self, name: str, table: str | None = None) -> int:
        """Index of column ``name`` within a row of ``table`` (default: the first table)."""
        _, _, cols = self._table(table)
        if name not in cols:
            raise ValueError(f"column must be one of {cols}, got {name!r}")
        return cols.index(name)

    def table(self, obs: np.ndarray, table: str | None = None) -> np.ndarray:
        """Table ``table`` of observation(s) ``obs`` ``(..., D)`` as ``(..., rows, cols)``."""
        start = 0
        name = self.tables[0][0] if table is None else table
        for tname, rows, cols in self.tables:
            size = rows * len(cols)
            if tname == name:
                return obs[..., start : start + size].reshape(*obs.shape[:-1], rows, len(cols))
            start += size
        raise ValueError(f"table must be one of {[t[0] for t in self.tables]}, got {table!r}")

    def _table(self, table: str | None) -> tuple[str, int, tuple[str, ...]]:
        if table is None:
            return self.tables[0]
        for entry in self.tables:
            if entry[0] == table:
                return entry
        raise ValueError(f"table must be one of {[t[0] for t in self.tables]}, got {table!r}")


@dataclass(frozen=True)
class EncoderInput:
    """What the encoders read besides the World's step, handed in by the env.

    ``agents``: every robot's agent name, in robot order (the step's records are keyed by
    them); ``estimates``: returns the localizer's padded tables ``(weights, means_covs)`` (called
    only by the encoder that reads them); ``detections`` / ``bearings``: each robot's last
    lidar detections ``(M, 2)`` and camera bearings ``(B,)`` (the env keeps them across steps
    without a fresh scan or frame)."""

    agents: Sequence[str]
    estimates: Callable[[], tuple[np.ndarray, np.ndarray]]
    detections: Sequence[np.ndarray]
    bearings: Sequence[np.ndarray]


class ObservationEncoder:
    """Builds every agent's neighbour table(s) from one env step (subclasses below), plus the
    lidar sector table when ``lidar_sectors > 0``."""

    name = ""

    def __init__(
        self,
        top_k: int,
        n_features: int,
        lidar_sectors: int = 0,
        lidar_sector_max_m: float = 2.0,
    ) -> None:
        self.top_k = top_k
        self.lidar_sectors = int(lidar_sectors)
        self.lidar_sector_max_m = float(lidar_sector_max_m)
        layout = self._layout(top_k, n_features)
        if self.lidar_sectors:
            layout = ObservationLayout(
                layout.tables + ((SECTOR_TABLE, self.lidar_sectors, SECTOR_COLUMNS),),
                n_features,
            )
        self.layout = layout
        # Every robot's sectors from its last non-stale scan (a lidar slower than the control
        # rate leaves steps without a scan: the robot keeps what it last saw). Sized lazily.
        self._sectors: np.ndarray | None = None

    def reset(self) -> None:
        """Forget what the last episode saw (the env calls it on every reset)."""
        self._sectors = None

    def _layout(self, top_k: int, n_features: int) -> ObservationLayout:
        return ObservationLayout((("estimate", top_k, ESTIMATE_COLUMNS),), n_features)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Low and high of the flattened table(s), the sector table included."""
        low, high = self._neighbour_bounds()
        if not self.lidar_sectors:
            return low, high
        return (
            np.r_[low, np.zeros(self.lidar_sectors)],
            np.r_[high, np.full(self.lidar_sectors, self.lidar_sector_max_m)],
        )

    def _neighbour_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return table_bounds(self.top_k)

    def space(
        self,
        max_speed_mps: float,
        max_turn_rate_radps: float,
        feature_low: np.ndarray,
        feature_high: np.ndarray,
    ) -> spaces.Box:
        """The observation space of this layout (:func:`build_space` plus the sector table)."""
        low, high = self.bounds()
        low = np.concatenate([low, [-max_speed_mps, -max_turn_rate_radps], feature_low])
        high = np.concatenate([high, [max_speed_mps, max_turn_rate_radps], feature_high])
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    def tables(self, source: EncoderInput, step: WorldStep, rows: list[int]) -> np.ndarray:
        """``(len(rows), layout.table_size)`` tables of the agents at robot indices ``rows``."""
        tables = self.neighbour_tables(source, step, rows)
        if not self.lidar_sectors:
            return tables
        return np.concatenate([tables, self.sector_tables(source, step)[rows]], axis=1)

    def neighbour_tables(
        self, source: EncoderInput, step: WorldStep, rows: list[int]
    ) -> np.ndarray:
        raise NotImplementedError

    def sector_tables(self, source: EncoderInput, step: WorldStep) -> np.ndarray:
        """Every robot's lidar sectors, (N, S), updated from ``step``'s newest non-stale scans.

        "Nothing seen" (``lidar_sector_max_m``) until a robot's first scan of the episode
        (:meth:`reset`)."""
        agents = source.agents
        if self._sectors is None:
            self._sectors = np.full((len(agents), self.lidar_sectors), self.lidar_sector_max_m)
        fresh, angles, ranges = [], [], []
        for i, agent in enumerate(agents):  # per robot: pick its record (no per-ray work)
            records = step.measurements.get(agent)
            if records is None or not records.lidar or "lidar" in step.stale.get(agent, ()):
                continue
            fresh.append(i)
            angles.append(records.lidar[-1].angles_rad)
            ranges.append(records.lidar[-1].ranges_m)
        if fresh:
            self._sectors[fresh] = lidar_sector_ranges(
                angles, ranges, self.lidar_sectors, self.lidar_sector_max_m
            )
        return self._sectors


class EstimateEncoder(ObservationEncoder):
    """``"phd"``: the agent's own localizer estimate, the K heaviest rows, largest first."""

    name = "phd"

    def neighbour_tables(
        self, source: EncoderInput, step: WorldStep, rows: list[int]
    ) -> np.ndarray:
        return phd_tables(*source.estimates(), self.top_k)[rows].reshape(len(rows), -1)


class TruthEncoder(ObservationEncoder):
    """``"truth"``: the true neighbours within ``localization_range_m``, nearest first."""

    name = "truth"

    def neighbour_tables(
        self, source: EncoderInput, step: WorldStep, rows: list[int]
    ) -> np.ndarray:
        truth = step.truth
        if truth is None:
            raise ValueError('observation="truth" needs ground truth, which this World lacks')
        table = truth_tables(truth.relative_xy, truth.in_range["lidar"], rows, self.top_k)
        return table.reshape(len(rows), -1)


class MeasurementEncoder(ObservationEncoder):
    """``"measurements"``: the last scan's lidar detections and the last frame's bearings."""

    name = "measurements"

    def _layout(self, top_k: int, n_features: int) -> ObservationLayout:
        return ObservationLayout(
            (("lidar", top_k, LIDAR_COLUMNS), ("camera", top_k, CAMERA_COLUMNS)), n_features
        )

    def _neighbour_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return measurement_bounds(self.top_k)

    def neighbour_tables(
        self, source: EncoderInput, step: WorldStep, rows: list[int]
    ) -> np.ndarray:
        return measurement_tables(source.detections, source.bearings, self.top_k)[rows]


#: ``SwarmConfig.observation`` -> encoder class.
ENCODERS: dict[str, type[ObservationEncoder]] = {
    cls.name: cls for cls in (EstimateEncoder, TruthEncoder, MeasurementEncoder)
}


def make_encoder(
    name: str,
    top_k: int,
    n_features: int,
    lidar_sectors: int = 0,
    lidar_sector_max_m: float = 2.0,
) -> ObservationEncoder:
    """The encoder ``name`` (a key of :data:`ENCODERS`), with ``lidar_sectors`` sectors of the
    robot's own scan appended to its tables (0: none)."""
    if name not in ENCODERS:
        raise ValueError(f"observation must be one of {sorted(ENCODERS)}, got {name!r}")
    if isinstance(lidar_sectors, bool) or not isinstance(lidar_sectors, int) or lidar_sectors < 0:
        raise ValueError(f"lidar_sectors must be an int >= 0, got {lidar_sectors!r}")
    if not (np.isfinite(lidar_sector_max_m) and lidar_sector_max_m > 0):
        raise ValueError(f"lidar_sector_max_m must be > 0, got {lidar_sector_max_m!r}")
    return ENCODERS[name](top_k, n_features, lidar_sectors, lidar_sector_max_m)
