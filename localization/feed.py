"""From measurement records to filter calls: the one seam between every World and every localizer.

A World (simulator, real robots, bag replay) hands over, per env step, each robot's stamped
records (:mod:`swarm_core.records`) and the sensors it reports stale. :class:`SwarmFeed` is that
step as the localizers see it, for the whole swarm; :func:`localizer_calls` turns one robot's
records into its time-ordered filter calls, with **motion compensation**: each lidar scan and
camera frame gets its sensor pose in the filter's frame (the robot's pose at its last odometry
sample). Every localizer family (:mod:`localization.registry`) consumes the same feed, so the
env, ``swarm-phd evaluate``, the bridge and the replay all feed filters the same way.

The compiled banks do not read those calls as Python tuples: :func:`pack_calls` encodes the
whole swarm's calls straight into the bank's flat arrays in one pass (the same calls, bit for
bit; ``tests/localization/test_packed_calls.py``), which at 1000 robots saves making and
re-reading ~9,400 tuples per step (``docs/how-to/scaling-out.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import chain
from operator import attrgetter

import numpy as np
from numba import njit

from swarm_core.records import (
    Broadcast,
    CameraRecord,
    LidarRecord,
    OdometryRecord,
    RobotMeasurements,
)
from swarm_core.world import GroundTruth, WorldStep

from . import kernels
from .filter import MAX_MEASUREMENTS_PER_CALL
from .scan_memory import N_BINS, profile_into, profiles_of

__all__ = ["SwarmFeed", "FeedCalls", "PackedCalls", "localizer_calls", "pack_calls", "Call"]

#: One filter call: ``("predict", delta (3,))``, ``("lidar", detections (M, 2), null_bearings
#: (K,), sensor_pose (3,) or None, scan_profile (N_BINS,))``, ``("camera", bearings (M,),
#: sensor_pose (3,) or None)`` or ``("advance", stamp_s)``.
Call = tuple

_EMPTY = RobotMeasurements()


@dataclass(frozen=True, eq=False)
class SwarmFeed:
    """One env step of measurements for every robot, in robot-index order.

    Attributes
    ----------
    time_s : float
        End of the step, seconds of the World's clock.
    measurements : sequence of RobotMeasurements, length R
        Robot ``r``'s records of the step (each list sorted by stamp).
    stale : sequence of tuple of str, length R
        Sensors (``"odometry"``, ``"lidar"``, ``"camera"``) the World reports silent for robot
        ``r``; their records, if any, are not used.
    truth : GroundTruth or None
        Ground truth, for the oracle-identity baselines only (``ukf``, ``pf``); the anonymous
        localizers never read it.
    compensate_motion : bool
        Give each scan / frame its sensor pose (see :func:`localizer_calls`).
    comms : sequence of tuple of Broadcast, length R, or empty
        What robot ``r`` heard over the radio this step (:class:`~swarm_core.records.Broadcast`,
        teammates' odometry and anonymous detections); empty when the radio is off. Read by the
        families that use communication (:mod:`localization.mutual`).
    """

    time_s: float
    measurements: Sequence[RobotMeasurements]
    stale: Sequence[tuple[str, ...]]
    truth: GroundTruth | None = None
    compensate_motion: bool = True
    comms: Sequence[tuple[Broadcast, ...]] = ()
    _calls: list = field(default_factory=list, init=False, repr=False, compare=False)
    _packed: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def from_world_step(
        cls, step: WorldStep, robot_ids: Sequence[str], compensate_motion: bool = True
    ) -> SwarmFeed:
        """The feed of ``step`` for the robots ``robot_ids`` (their order is the index order)."""
        return cls(
            time_s=step.time_s,
            measurements=[step.measurements.get(r, _EMPTY) for r in robot_ids],
            stale=[tuple(step.stale.get(r, ())) for r in robot_ids],
            truth=step.truth,
            compensate_motion=compensate_motion,
            comms=[tuple(step.comms.get(r, ())) for r in robot_ids] if step.comms else (),
        )

    @classmethod
    def concat(cls, feeds: Sequence[SwarmFeed]) -> SwarmFeed:
        """One feed of the robots of ``feeds`` in order (several env copies sharing one
        localizer); truth is dropped (the oracle baselines need a single World's truth)."""
        if not feeds:
            raise ValueError("concat() needs at least one feed")
        if len({f.compensate_motion for f in feeds}) > 1:
            raise ValueError("concat() needs feeds with the same compensate_motion")
        feed = cls(
            time_s=max(f.time_s for f in feeds),
            measurements=[m for f in feeds for m in f.measurements],
            stale=[s for f in feeds for s in f.stale],
            truth=None,
            compensate_motion=feeds[0].compensate_motion,
            comms=(
                [c for f in feeds for c in (f.comms or [()] * f.n_robots)]
                if any(f.comms for f in feeds)
                else ()
            ),
        )
        if all(f._calls for f in feeds):  # reuse each robot's calls where already made
            feed._calls.extend(c for f in feeds for c in f._calls)
        return feed

    @classmethod
    def empty(cls, n_robots: int, time_s: float = 0.0) -> SwarmFeed:
        """A feed in which no robot measured anything (a no-op for every localizer)."""
        return cls(time_s, [_EMPTY] * n_robots, [()] * n_robots)

    @property
    def n_robots(self) -> int:
        return len(self.measurements)

    def calls(self) -> FeedCalls:
        """Every robot's time-ordered filter calls (:func:`localizer_calls`; a sequence of R
        lists of call tuples, made on first access and shared by all localizers).

        The compiled banks (``PHDBank.step``, ``PMBBank.step``) never make the tuples: they
        take the whole swarm's calls as arrays from :meth:`packed` (the same calls, encoded).
        """
        return FeedCalls(self)

    def call_lists(self) -> list[list[Call]]:
        """:meth:`calls` as a plain list of R lists (computed once)."""
        if not self._calls:
            self._calls.extend(
                localizer_calls(m, s, self.compensate_motion)
                for m, s in zip(self.measurements, self.stale, strict=True)
            )
        return self._calls

    def packed(self, scan_profiles: bool = True) -> PackedCalls | None:
        """Every robot's calls as the flat arrays the compiled banks run
        (:func:`pack_calls`, computed once per ``scan_profiles``), or None where that path
        cannot vouch for its input (the banks then encode :meth:`call_lists`, which names the
        bad value). A bank that does not read the scans asks for ``scan_profiles=False``."""
        if scan_profiles not in self._packed:
            self._packed[scan_profiles] = pack_calls(
                self.measurements, self.stale, self.compensate_motion, scan_profiles
            )
        return self._packed[scan_profiles]


class FeedCalls(Sequence):
    """:meth:`SwarmFeed.calls`: a read-only sequence of R per-robot call lists that builds the
    tuples only when an element is read."""

    __slots__ = ("feed",)

    def __init__(self, feed: SwarmFeed) -> None:
        self.feed = feed

    def __len__(self) -> int:
        return self.feed.n_robots

    def __getitem__(self, index):
        return self.feed.call_lists()[index]

    def __iter__(self):
        return iter(self.feed.call_lists())

    def __repr__(self) -> str:
        return f"FeedCalls(n_robots={self.feed.n_robots})"


def localizer_calls(
    records: RobotMeasurements, stale=(), compensate_motion: bool = True
) -> list[tuple]:
    """One robot's records as time-ordered filter calls, skipping ``stale`` sensors.

    ``("predict", delta)`` for odometry, ``("lidar", detections, null_bearings)`` and
    ``("camera", bearings)``, each after an ``("advance", stamp_s)``, as every bank's
    ``apply`` takes them.

    The filter's frame is the robot's pose at its **last odometry sample**, but a scan or a
    frame is taken up to one odometry period (0.1 s) later, from wherever the robot has moved
    and turned since (at 1.5 rad/s, 0.15 rad: 0.3 m at 2 m). With ``compensate_motion`` (the
    default) each lidar / camera record that has a later odometry sample in ``records`` gets
    its **sensor pose** in the frame of the last sample, from the robot's own motion up to its
    stamp: the next sample's motion ``delta`` minus its constant-velocity remainder
    ``velocity * tau`` over the ``tau`` seconds from the stamp to that sample (see
    :func:`_motion_since_sample`). The filter moves detections exactly, rotates bearings
    (:mod:`localization.frames`) and evaluates their model from the camera's position (the
    parallax a bearing cannot carry). Only the robot's own odometry is used. A record after the
    step's last odometry sample goes in uncompensated (in the simulator none is: odometry
    samples fall on step ends; on a real robot with unsynchronised odometry some are).

    Calls: ``("predict", delta)``, ``("lidar", detections, null_bearings, sensor_pose,
    scan_profile)`` and ``("camera", bearings, sensor_pose)``, ``sensor_pose`` a ``(3,)`` array
    or None, ``scan_profile`` the scan's ranges binned (:func:`scan_profile_of`). Each is
    preceded by ``("advance", stamp_s)``, the record's stamp: a filter with
    ``time_update == "measurement"`` adds the process noise that accrued up to it first
    (:meth:`localization.RobotCentricPHD.advance`); the others only move a clock.
    """
    ordered = records.in_time_order()
    use_odometry = "odometry" not in stale
    use_lidar, use_camera = "lidar" not in stale, "camera" not in stale
    compensate = compensate_motion and use_odometry
    calls: list[tuple] = []
    # Walk backwards so each measurement knows the next odometry sample (None after the last).
    upcoming: OdometryRecord | None = None
    for record in reversed(ordered):
        if isinstance(record, OdometryRecord):
            upcoming = record
            if use_odometry:
                calls.append(("predict", record.delta))
                calls.append(("advance", record.stamp_s))  # reversed below: goes first
            continue
        pose = None
        if compensate and upcoming is not None and upcoming.stamp_s > record.stamp_s:
            pose = _motion_since_sample(upcoming, upcoming.stamp_s - record.stamp_s)
        if isinstance(record, LidarRecord):
            if use_lidar:
                calls.append(
                    (
                        "lidar",
                        record.detections,
                        record.null_bearings_rad,
                        pose,
                        scan_profile_of(record),
                    )
                )
                calls.append(("advance", record.stamp_s))
        elif use_camera:
            calls.append(("camera", record.bearings_rad, pose))
            calls.append(("advance", record.stamp_s))
    calls.reverse()
    return calls


def scan_profile_of(record: LidarRecord) -> np.ndarray:
    """The scan of ``record`` as a profile ``(N_BINS,)`` (:mod:`localization.scan_memory`),
    compiled; :func:`localization.scan_memory.scan_profile` is its reference.

    Raises
    ------
    ValueError
        If the record's ``angles_rad`` and ``ranges_m`` are not 1-D arrays of one length.
    """
    angles = np.asarray(record.angles_rad, dtype=np.float64)
    ranges = np.asarray(record.ranges_m, dtype=np.float64)
    if angles.ndim != 1 or angles.shape != ranges.shape:
        raise ValueError(
            f"LidarRecord at {record.stamp_s!r} s: angles_rad and ranges_m must be 1-D and of "
            f"one length, got shapes {angles.shape} and {ranges.shape}"
        )
    out = np.empty(N_BINS)
    profile_into(out, angles, ranges)
    return out


def _motion_since_sample(odo: OdometryRecord, tau_s: float) -> np.ndarray:
    """Pose ``(x, y, psi)`` of the robot ``tau_s`` seconds before odometry sample ``odo``,
    in the frame of the previous sample.

    ``odo.delta`` is the motion from the previous sample to ``odo``; the last ``tau_s`` of it
    is taken at the interval's mean speed ``odo.velocity = (v, omega)``: turn
    ``psi_r = omega tau``, chord ``t_r = v tau (cos(psi_r / 2), sin(psi_r / 2))`` in the frame
    at the measurement. Removing it: ``psi = dpsi - psi_r``, ``t = d - R(psi) t_r``.
    """
    dx, dy, dpsi = odo.delta.tolist()
    v, omega = odo.velocity.tolist()
    return np.array(_motion_pose(dx, dy, dpsi, v, omega, float(tau_s)))


@dataclass(frozen=True, eq=False)
class PackedCalls:
    """A whole swarm's filter calls as flat arrays (:func:`pack_calls`).

    Attributes
    ----------
    encoded : tuple of ndarray
        The 18 arrays of :func:`localization.kernels.apply_calls` (``robots, kinds, index,
        odometry, ...``; see that module's docstring), exactly what
        ``PHDBank``'s batch encoder makes of :meth:`SwarmFeed.call_lists`.
    max_points : int
        The most detections in one lidar call (0 without lidar calls).
    robots : list of int
        The robots with at least one call, ascending.
    """

    encoded: tuple
    max_points: int
    robots: list


_ADVANCE, _PREDICT, _LIDAR, _CAMERA = (
    kernels.ADVANCE,
    kernels.PREDICT,
    kernels.LIDAR,
    kernels.CAMERA,
)
_STAMP_TYPES = frozenset({float, np.float64})
_MEASUREMENTS_TYPE = frozenset({RobotMeasurements})
_ODOMETRY_TYPE = frozenset({OdometryRecord})
_LIDAR_TYPE = frozenset({LidarRecord})
_CAMERA_TYPE = frozenset({CameraRecord})
_STAMP = attrgetter("stamp_s")


def pack_calls(
    measurements: Sequence[RobotMeasurements],
    stale: Sequence[tuple[str, ...]],
    compensate_motion: bool = True,
    scan_profiles: bool = True,
) -> PackedCalls | None:
    """Every robot's :func:`localizer_calls`, encoded for the compiled banks in one pass over
    the swarm: no call tuple is made, the merge by stamp is one ``lexsort`` and the sensor
    poses one compiled pass (:func:`_motion_poses`). With ``scan_profiles=False`` the lidar
    calls carry no profile (flags 0, a ``(0, N_BINS)`` array): at 1000 robots binning every
    scan costs ~7 ms per step that a filter which does not read scans never uses
    (``PHDConfig.reads_scans``: the wide objects' camera clutter).

    With ``scan_profiles`` (the default) the result equals, array for array and bit for bit,
    the bank's encoding of
    ``[localizer_calls(m, s, compensate_motion) for m, s in zip(measurements, stale)]``
    (``tests/localization/test_packed_calls.py``): records merged per robot by
    ``(stamp, odometry < lidar < camera, list order)``, each call after its ``advance``, the
    same sensor poses. Returns None (the caller then encodes the tuples, whose checks name the
    culprit) when it cannot vouch for the input: a non-record, a stamp that is not a float, an
    array of the wrong rank or too many measurements in one call. Finiteness and magnitudes
    are the bank's batch-wide check (:func:`localization.bank.all_finite`), as for tuples.
    """
    n_robots = len(measurements)
    if len(stale) != n_robots or not set(map(type, measurements)) <= _MEASUREMENTS_TYPE:
        return None
    odo_lists = [m.odometry for m in measurements]
    lid_lists = [m.lidar for m in measurements]
    cam_lists = [m.camera for m in measurements]
    if any(stale):  # a stale sensor's records are not used (a stale odometry: nor its motion)
        for r, s in enumerate(stale):
            if s:
                if "odometry" in s:
                    odo_lists[r] = ()
                if "lidar" in s:
                    lid_lists[r] = ()
                if "camera" in s:
                    cam_lists[r] = ()
    odo = list(chain.from_iterable(odo_lists))
    lid = list(chain.from_iterable(lid_lists))
    cam = list(chain.from_iterable(cam_lists))
    if not len(odo) + len(lid) + len(cam):
        return PackedCalls(_encode_empty(), 0, [])
    if (
        not set(map(type, odo)) <= _ODOMETRY_TYPE
        or not set(map(type, lid)) <= _LIDAR_TYPE
        or not set(map(type, cam)) <= _CAMERA_TYPE
    ):
        return None
    per_robot = np.array(
        [list(map(len, odo_lists)), list(map(len, lid_lists)), list(map(len, cam_lists))],
        dtype=np.int64,
    ).reshape(3, n_robots)
    stamp_list = list(map(_STAMP, odo))
    stamp_list += map(_STAMP, lid)
    stamp_list += map(_STAMP, cam)
    if not set(map(type, stamp_list)) <= _STAMP_TYPES:
        return None  # ints, bools, strings...: the tuple path's checks decide
    try:
        return _pack(odo, lid, cam, per_robot, stamp_list, compensate_motion, scan_profiles)
    except (ValueError, TypeError, IndexError):
        return None  # a malformed array: the tuple path names it


def _pack(
    odo, lid, cam, per_robot, stamp_list, compensate_motion, scan_profiles
) -> PackedCalls | None:
    """:func:`pack_calls` past its checks: ``per_robot (3, R)`` records of each kind per
    robot, ``stamp_list`` every record's stamp (odometry, lidar, camera, robot-major)."""
    n_o, n_l, n_c = len(odo), len(lid), len(cam)
    stamps = np.array(stamp_list, dtype=np.float64)
    robot = np.repeat(np.tile(np.arange(per_robot.shape[1], dtype=np.int64), 3), per_robot.ravel())
    kind = np.repeat(np.arange(3, dtype=np.int64), (n_o, n_l, n_c))
    # localizer_calls' merge (RobotMeasurements.in_time_order, a stable sort by (stamp, kind))
    # per robot, robots in index order: lexsort is stable, so equal keys keep list order.
    order = np.lexsort((kind, stamps, robot))
    delta, velocity = np.zeros((0, 3)), np.zeros((0, 2))
    if n_o:
        delta = np.array([rec.delta for rec in odo], dtype=np.float64)
        velocity = np.array([rec.velocity for rec in odo], dtype=np.float64)
        if delta.shape != (n_o, 3) or velocity.shape != (n_o, 2):
            return None
    (robots, kinds, index, odometry, s_stamp, l_src, c_src, l_pose, l_has, c_pose, c_has) = (
        _assemble(order, robot, kind, stamps, delta, velocity, n_o, n_l, bool(compensate_motion))
    )
    points = [lid[i].detections for i in l_src.tolist()]
    nulls = [lid[i].null_bearings_rad for i in l_src.tolist()]
    bearings = [cam[i].bearings_rad for i in c_src.tolist()]
    n_points = np.fromiter(map(len, points), np.int64, n_l)
    n_nulls = np.fromiter(map(len, nulls), np.int64, n_l)
    n_bearings = np.fromiter(map(len, bearings), np.int64, n_c)
    limit = MAX_MEASUREMENTS_PER_CALL
    if (n_l and max(n_points.max(), n_nulls.max()) > limit) or (n_c and n_bearings.max() > limit):
        return None
    points_arr = np.concatenate(points) if n_l else np.zeros((0, 2))
    nulls_arr = np.concatenate(nulls) if n_l else np.zeros(0)
    bearings_arr = np.concatenate(bearings) if n_c else np.zeros(0)
    if (
        points_arr.ndim != 2
        or points_arr.shape[1] != 2
        or nulls_arr.ndim != 1
        or bearings_arr.ndim != 1
        or points_arr.dtype != np.float64
        or nulls_arr.dtype != np.float64
        or bearings_arr.dtype != np.float64
    ):
        return None
    lidar_stop = np.cumsum(n_points, dtype=np.int64)
    null_stop = np.cumsum(n_nulls, dtype=np.int64)
    camera_stop = np.cumsum(n_bearings, dtype=np.int64)
    has_profile = np.full(n_l, int(scan_profiles), dtype=np.int64)
    if n_l and scan_profiles:
        scans = [lid[i] for i in l_src.tolist()]
        angles = [rec.angles_rad for rec in scans]
        ranges = [rec.ranges_m for rec in scans]
        n_beams = np.fromiter(map(len, angles), np.int64, n_l)
        if not np.array_equal(n_beams, np.fromiter(map(len, ranges), np.int64, n_l)):
            return None
        profiles = profiles_of(
            np.concatenate(angles).astype(np.float64, copy=False),
            np.concatenate(ranges).astype(np.float64, copy=False),
            np.cumsum(n_beams, dtype=np.int64),
        )
    else:
        profiles = np.zeros((0, N_BINS))
    encoded = (
        robots,
        kinds,
        index,
        odometry,
        _starts(lidar_stop),
        lidar_stop,
        points_arr,
        _starts(null_stop),
        null_stop,
        nulls_arr,
        _starts(camera_stop),
        camera_stop,
        bearings_arr,
        l_pose,
        l_has,
        c_pose,
        c_has,
        s_stamp,
        profiles,
        has_profile,
    )
    max_points = int(n_points.max()) if n_l else 0
    # the robots with a record, ascending (each record is two of its calls)
    return PackedCalls(encoded, max_points, np.flatnonzero(per_robot.sum(axis=0)).tolist())


@njit(cache=True)
def _assemble(order, robot, kind, stamps, delta, velocity, n_o, n_l, compensate):
    """The call arrays of :func:`_pack` from the merged ``order`` of the records (``kind`` 0
    odometry, 1 lidar, 2 camera; their ``robot``, ``stamps``; odometry ``delta (n_o, 3)`` and
    ``velocity (n_o, 2)``), in :func:`localizer_calls`' terms: per record an advance then its
    call; each lidar / camera record's sensor pose from the robot's next odometry sample, found
    by the same backward walk. Returns ``robots, kinds, index (2n,)``, ``odometry (n_o, 3)``
    in call order, ``stamps (n,)`` in call order, the lidar / camera records' source ranks
    ``l_src``, ``c_src`` and their poses and pose flags."""
    n = order.shape[0]
    n_c = n - n_o - n_l
    robots = np.empty(2 * n, dtype=np.int64)
    kinds = np.empty(2 * n, dtype=np.int64)
    index = np.empty(2 * n, dtype=np.int64)
    odometry = np.empty((n_o, 3))
    s_stamp = np.empty(n)
    rank = np.empty(n, dtype=np.int64)
    l_src = np.empty(n_l, dtype=np.int64)
    c_src = np.empty(n_c, dtype=np.int64)
    l_pose = np.zeros((n_l, 3))
    c_pose = np.zeros((n_c, 3))
    l_has = np.zeros(n_l, dtype=np.int64)
    c_has = np.zeros(n_c, dtype=np.int64)
    io = il = ic = 0
    for p in range(n):
        q = order[p]
        k = kind[q]
        s_stamp[p] = stamps[q]
        robots[2 * p] = robot[q]
        robots[2 * p + 1] = robot[q]
        kinds[2 * p] = _ADVANCE
        index[2 * p] = p
        if k == 0:
            kinds[2 * p + 1] = _PREDICT
            rank[p] = io
            odometry[io, 0] = delta[q, 0]
            odometry[io, 1] = delta[q, 1]
            odometry[io, 2] = delta[q, 2]
            io += 1
        elif k == 1:
            kinds[2 * p + 1] = _LIDAR
            rank[p] = il
            l_src[il] = q - n_o
            il += 1
        else:
            kinds[2 * p + 1] = _CAMERA
            rank[p] = ic
            c_src[ic] = q - n_o - n_l
            ic += 1
        index[2 * p + 1] = rank[p]
    if compensate:
        # Backwards, so each measurement knows its robot's next odometry sample (-1: none).
        upcoming = -1
        up_stamp = 0.0
        for p in range(n - 1, -1, -1):
            if p == n - 1 or robots[2 * p] != robots[2 * p + 2]:
                upcoming = -1  # a new robot
            q = order[p]
            k = kind[q]
            if k == 0:
                upcoming = q
                up_stamp = s_stamp[p]
                continue
            if upcoming < 0 or not up_stamp > s_stamp[p]:
                continue
            x, y, psi = _motion_pose(
                delta[upcoming, 0],
                delta[upcoming, 1],
                delta[upcoming, 2],
                velocity[upcoming, 0],
                velocity[upcoming, 1],
                up_stamp - s_stamp[p],
            )
            j = rank[p]
            if k == 1:
                l_pose[j, 0], l_pose[j, 1], l_pose[j, 2] = x, y, psi
                l_has[j] = 1
            else:
                c_pose[j, 0], c_pose[j, 1], c_pose[j, 2] = x, y, psi
                c_has[j] = 1
    return robots, kinds, index, odometry, s_stamp, l_src, c_src, l_pose, l_has, c_pose, c_has


def _starts(stops: np.ndarray) -> np.ndarray:
    """Start offsets from stop offsets, as the bank's encoder writes them (``[0]`` if none)."""
    return np.concatenate(([0], stops[:-1])).astype(np.int64)


def _encode_empty() -> tuple:
    empty_i = np.zeros(0, dtype=np.int64)
    zero = np.zeros(1, dtype=np.int64)
    return (
        empty_i,
        empty_i,
        empty_i,
        np.zeros((0, 3)),
        zero,
        empty_i,
        np.zeros((0, 2)),
        zero,
        empty_i,
        np.zeros(0),
        zero,
        empty_i,
        np.zeros(0),
        np.zeros((0, 3)),
        empty_i,
        np.zeros((0, 3)),
        empty_i,
        np.zeros(0),
        np.zeros((0, N_BINS)),
        empty_i,
    )


@njit(cache=True)
def _motion_pose(dx, dy, dpsi, v, omega, tau):
    """:func:`_motion_since_sample`'s pose ``(x, y, psi)`` from the scalars of one sample (m,
    m, rad, m/s, rad/s, s): the one implementation of the scalar and the packed paths."""
    # Never remove more than the whole interval's motion when tau exceeds it (irregular rates).
    psi_r = omega * tau
    if abs(psi_r) > abs(dpsi):
        psi_r = dpsi
    chord = v * tau
    psi = dpsi - psi_r
    tx, ty = chord * math.cos(0.5 * psi_r), chord * math.sin(0.5 * psi_r)
    c, s = math.cos(psi), math.sin(psi)
    return dx - (c * tx - s * ty), dy - (s * tx + c * ty), psi


def _motion_poses(delta: np.ndarray, velocity: np.ndarray, tau_s: np.ndarray) -> np.ndarray:
    """:func:`_motion_pose` of ``K`` samples, ``delta (K, 3)``, ``velocity (K, 2)``,
    ``tau_s (K,)`` -> poses ``(K, 3)``: the compiled scalar called from Python, for the
    equivalence test (not a kernel of its own, so ``swarm-phd warmup`` has nothing to add)."""
    return np.array(
        [_motion_pose(*d, *v, t) for d, v, t in zip(delta, velocity, tau_s, strict=True)]
    ).reshape(-1, 3)
