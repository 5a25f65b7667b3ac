"""ROS 2 bags without ROS: record any bridge episode, replay it through the env API, export a
simulated episode. Uses the ``rosbags`` library (pure Python; sqlite3 storage, bag version 8).

Bag layout
----------
Per robot, standard message types (plus the two-field ``BearingsStamped``, whose definition is
stored in the bag), each at its message stamp (header stamp; arrival stamp for the legacy
header-less bearings):

=============================  ==============================  ===============================
topic                          type                            what
=============================  ==============================  ===============================
``/<robot>/scan``              ``sensor_msgs/msg/LaserScan``    scans the bridge used
``/<robot>/odom``              ``nav_msgs/msg/Odometry``        odometry poses it used
``/<robot>/camera/bearings_stamped`` ``swarm_phd_msgs/msg/BearingsStamped`` bearings it used
``/<robot>/camera/bearings``   ``std_msgs/msg/Float32MultiArray`` (legacy header-less robots)
``/mocap/<robot>/pose``        ``geometry_msgs/msg/PoseStamped`` motion capture
``/<robot>/cmd_vel``           ``geometry_msgs/msg/Twist``      commands sent (incl. stops)
``/bridge/step``               ``std_msgs/msg/String``          one JSON marker per reset/step
=============================  ==============================  ===============================

With a UAV supervisor (``BridgeConfig.uav_id``, Stegagno 2013) also ``/<uav>/pose``
(``geometry_msgs/msg/PoseStamped``), ``/<uav>/camera/detections``
(``geometry_msgs/msg/PoseArray``) and its commands on ``/<uav>/cmd_vel``; the metadata names it
(``"uav"``) and :class:`ReplayWorld` replays its messages into ``last_uav`` as the live bridge
fills it.

A marker ``{"kind": "reset"|"step", "index": k, "stale": {...}}`` is written at the end of each
reset/step, at the step's end time; the messages of step k are those stamped after marker k-1 and
up to marker k. A step's rows and its marker are written inside a signal-deferring critical
section and committed together, so a recording ended by SIGINT, SIGTERM, SIGHUP or an exception
holds whole steps, and its ``metadata.yaml`` is written by :meth:`BagRecorder.close` in the
``finally`` that the signal unwinds through.

Replay validates everything it reads (:class:`BagError`, one line naming the file and the
problem, for a bag it cannot replay; counted and reported skips for the parts it can).

The bag's ``custom_data["swarm_phd"]`` holds JSON metadata (robot ids, the env config, the
bridge's mocap freshness rule). Everything read back is parsed with
:func:`json.loads` and validated exactly as live messages are: never pickle or eval.

:class:`ReplayWorld` rebuilds each step's records from these messages with the same
:class:`~hardware_bridge.assembly.RecordAssembler` as the live bridge, so the filters get the
same inputs and produce the same output.
"""

from __future__ import annotations

import bisect
import dataclasses
import hashlib
import json
import stat
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hardware_bridge.assembly import RecordAssembler
from hardware_bridge.comms import TeammateRelay
from hardware_bridge.config import FEED_SENSORS
from hardware_bridge.estimate import BAG_TYPE as ESTIMATE_BAG_TYPE
from hardware_bridge.estimate import ESTIMATE_STAMPED_MSG
from hardware_bridge.messages import (
    BAG_TYPES,
    BEARINGS_STAMPED_MSG,
    SENSOR_OF_KIND,
    UAV_BAG_TYPES,
    UAV_KINDS,
    Counters,
    InvalidMessage,
    check_robot_id,
    ns_to_s,
    parse_message,
    topics,
    twist_msg,
    uav_cmd_topic,
    uav_topics,
    uav_twist_msg,
)
from hardware_bridge.signals import critical
from localization.config import nest_flat_phd
from swarm_core.aerial import UAVMessages, uav_messages
from swarm_core.world import WorldStep, reject_extra_commands
from swarm_env.config import SwarmConfig, make_config

META_KEY = "swarm_phd"
STEP_TOPIC = "/bridge/step"
STRING_TYPE = "std_msgs/msg/String"
BAG_VERSION = 8
SENSORS = ("lidar", "odometry", "camera", "mocap")
ALL_BAG_TYPES = {**BAG_TYPES, **UAV_BAG_TYPES, "estimate": ESTIMATE_BAG_TYPE}
#: What a bridge with on-board filters records of each robot besides :data:`SENSORS`.
RECORDED_EXTRA = ("estimate",)


class BagError(ValueError):
    """A bag that cannot be replayed: one line naming the file and the problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        text = " ".join(str(problem).split())  # one line, whatever the library said
        super().__init__(f"{path}: {text[:400]}")
        self.path = str(path)
        self.problem = text


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(BEARINGS_STAMPED_MSG, BAG_TYPES["camera_stamped"]))
    ts.register(get_types_from_msg(ESTIMATE_STAMPED_MSG, ESTIMATE_BAG_TYPE))
    return ts


# ---------------------------------------------------------------------------- config <-> JSON
def config_to_dict(config: SwarmConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


def config_from_dict(data: dict[str, Any]) -> SwarmConfig:
    """Rebuild a SwarmConfig from :func:`config_to_dict` output (lists back to tuples)."""

    def convert(template: Any, value: Any) -> Any:
        if dataclasses.is_dataclass(template) and isinstance(value, dict):
            names = {f.name for f in dataclasses.fields(template)}
            unknown = sorted(set(value) - names)
            if unknown:
                raise ValueError(f"bag config has unknown keys {unknown}")
            return {k: convert(getattr(template, k), v) for k, v in value.items()}
        if isinstance(template, tuple) and isinstance(value, list):
            return tuple(value)
        return value

    base = SwarmConfig()
    if isinstance(data.get("phd"), dict):  # bags of earlier releases store a flat PHDConfig
        data = {**data, "phd": nest_flat_phd(data["phd"])}
    converted = convert(base, data)
    return make_config(config=base, **converted)


# ---------------------------------------------------------------------------- dict <-> rosbags
def _num(d: Any, key: str, default: float = 0.0) -> float:
    v = d.get(key, default) if isinstance(d, dict) else default
    return float(v) if type(v) in (int, float) else default


def _vec3(ts, d: Any):
    return ts.types["geometry_msgs/msg/Vector3"](x=_num(d, "x"), y=_num(d, "y"), z=_num(d, "z"))


def _header(ts, d: dict):
    stamp = d["stamp"]
    sec = stamp["sec"] if "sec" in stamp else stamp["secs"]
    nsec = stamp.get("nanosec", stamp.get("nsecs", 0))
    frame = d.get("frame_id", "")
    return ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nsec)),
        frame_id=frame if isinstance(frame, str) else "",
    )


def _pose(ts, d: dict):
    return ts.types["geometry_msgs/msg/Pose"](
        position=ts.types["geometry_msgs/msg/Point"](
            x=_num(d["position"], "x"), y=_num(d["position"], "y"), z=_num(d["position"], "z")
        ),
        orientation=ts.types["geometry_msgs/msg/Quaternion"](
            x=_num(d["orientation"], "x"),
            y=_num(d["orientation"], "y"),
            z=_num(d["orientation"], "z"),
            w=_num(d["orientation"], "w", 1.0),
        ),
    )


def _cov(d: dict) -> np.ndarray:
    cov = d.get("covariance")
    if isinstance(cov, list) and len(cov) == 36 and all(type(v) in (int, float) for v in cov):
        return np.asarray(cov, dtype=np.float64)
    return np.zeros(36)


def _floats32(values: list) -> np.ndarray:
    return np.asarray([np.nan if v is None else v for v in values], dtype=np.float32)


def to_rosbags(ts, sensor: str, msg: dict):
    """A validated message dict (rosbridge JSON form) as a rosbags message object."""
    t = ts.types
    if sensor == "lidar":
        return t[BAG_TYPES["lidar"]](
            header=_header(ts, msg["header"]),
            angle_min=_num(msg, "angle_min"),
            angle_max=_num(msg, "angle_max"),
            angle_increment=_num(msg, "angle_increment"),
            time_increment=_num(msg, "time_increment"),
            scan_time=_num(msg, "scan_time"),
            range_min=_num(msg, "range_min"),
            range_max=_num(msg, "range_max"),
            ranges=_floats32(msg["ranges"]),
            intensities=_floats32(msg["intensities"]),
        )
    if sensor == "odometry":
        twist = msg["twist"]["twist"]
        child = msg.get("child_frame_id", "")
        return t[BAG_TYPES["odometry"]](
            header=_header(ts, msg["header"]),
            child_frame_id=child if isinstance(child, str) else "",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=_pose(ts, msg["pose"]["pose"]), covariance=_cov(msg["pose"])
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=_vec3(ts, twist["linear"]), angular=_vec3(ts, twist["angular"])
                ),
                covariance=_cov(msg["twist"]),
            ),
        )
    if sensor == "camera_stamped":
        return t[BAG_TYPES["camera_stamped"]](
            header=_header(ts, msg["header"]),
            bearings=np.asarray(msg["bearings"], dtype=np.float32),
        )
    if sensor == "camera":
        data = msg["data"]
        dims = [
            t["std_msgs/msg/MultiArrayDimension"](
                label="bearing", size=len(data), stride=len(data)
            )
        ]
        return t[BAG_TYPES["camera"]](
            layout=t["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0),
            data=np.asarray(data, dtype=np.float32),
        )
    if sensor == "mocap":
        return t[BAG_TYPES["mocap"]](
            header=_header(ts, msg["header"]), pose=_pose(ts, msg["pose"])
        )
    if sensor == "cmd_vel":
        return t[BAG_TYPES["cmd_vel"]](
            linear=_vec3(ts, msg["linear"]), angular=_vec3(ts, msg["angular"])
        )
    if sensor == "uav_pose":
        return t[UAV_BAG_TYPES["uav_pose"]](
            header=_header(ts, msg["header"]), pose=_pose(ts, msg["pose"])
        )
    if sensor == "uav_detections":
        return t[UAV_BAG_TYPES["uav_detections"]](
            header=_header(ts, msg["header"]), poses=[_pose(ts, p) for p in msg["poses"]]
        )
    if sensor == "estimate":
        return t[ESTIMATE_BAG_TYPE](
            header=_header(ts, msg["header"]),
            localizer=str(msg["localizer"]),
            weight_kind=int(msg["weight_kind"]),
            weights=np.asarray(msg["weights"], dtype=np.float64),
            means=np.asarray(msg["means"], dtype=np.float64),
            covariances=np.asarray(msg["covariances"], dtype=np.float64),
        )
    raise ValueError(f"unknown sensor {sensor!r}")


def _header_dict(h) -> dict:
    return {
        "stamp": {"sec": int(h.stamp.sec), "nanosec": int(h.stamp.nanosec)},
        "frame_id": h.frame_id,
    }


def _pose_dict(p) -> dict:
    return {
        "position": {"x": p.position.x, "y": p.position.y, "z": p.position.z},
        "orientation": {
            "x": p.orientation.x,
            "y": p.orientation.y,
            "z": p.orientation.z,
            "w": p.orientation.w,
        },
    }


def _vec_dict(v) -> dict:
    return {"x": v.x, "y": v.y, "z": v.z}


def from_rosbags(sensor: str, m) -> dict:
    """A rosbags message as the dict rosbridge would have delivered (ROS 2 header form)."""
    if sensor == "lidar":
        return {
            "header": _header_dict(m.header),
            "angle_min": float(m.angle_min),
            "angle_max": float(m.angle_max),
            "angle_increment": float(m.angle_increment),
            "time_increment": float(m.time_increment),
            "scan_time": float(m.scan_time),
            "range_min": float(m.range_min),
            "range_max": float(m.range_max),
            "ranges": m.ranges.astype(np.float64).tolist(),
            "intensities": m.intensities.astype(np.float64).tolist(),
        }
    if sensor == "odometry":
        return {
            "header": _header_dict(m.header),
            "child_frame_id": m.child_frame_id,
            "pose": {"pose": _pose_dict(m.pose.pose), "covariance": m.pose.covariance.tolist()},
            "twist": {
                "twist": {
                    "linear": _vec_dict(m.twist.twist.linear),
                    "angular": _vec_dict(m.twist.twist.angular),
                },
                "covariance": m.twist.covariance.tolist(),
            },
        }
    if sensor == "camera_stamped":
        return {
            "header": _header_dict(m.header),
            "bearings": m.bearings.astype(np.float64).tolist(),
        }
    if sensor == "camera":
        return {
            "layout": {
                "dim": [
                    {"label": d.label, "size": int(d.size), "stride": int(d.stride)}
                    for d in m.layout.dim
                ],
                "data_offset": int(m.layout.data_offset),
            },
            "data": m.data.astype(np.float64).tolist(),
        }
    if sensor == "mocap":
        return {"header": _header_dict(m.header), "pose": _pose_dict(m.pose)}
    if sensor == "cmd_vel":
        return {"linear": _vec_dict(m.linear), "angular": _vec_dict(m.angular)}
    if sensor == "uav_pose":
        return {"header": _header_dict(m.header), "pose": _pose_dict(m.pose)}
    if sensor == "uav_detections":
        return {"header": _header_dict(m.header), "poses": [_pose_dict(p) for p in m.poses]}
    raise ValueError(f"unknown sensor {sensor!r}")


# ---------------------------------------------------------------------------- recording
class BagRecorder:
    """Writes one ROS 2 bag (thread-safe). Create it, hand it to a world (``recorder=``) or call
    the ``write_*`` methods, and :meth:`close` it (that writes ``metadata.yaml``)."""

    def __init__(
        self,
        path: str | Path,
        robot_ids: Sequence[str],
        config: SwarmConfig,
        *,
        source: str = "bridge",
        stale_mocap_s: float = 0.5,
        use_mocap: bool = True,
        uav_id: str | None = None,
        odometry_jump_factor: float = 3.0,
        onboard: bool = False,
    ) -> None:
        from rosbags.rosbag2 import Writer

        self.path = Path(path)
        self.robot_ids = tuple(robot_ids)
        self.uav_id = None if uav_id is None else check_robot_id(uav_id)
        self._ts = _typestore()
        self._writer = Writer(self.path, version=BAG_VERSION)
        self._writer.set_custom_data(
            META_KEY,
            json.dumps(
                {
                    "format": 1,
                    "source": source,
                    "robots": list(self.robot_ids),
                    "config": config_to_dict(config),
                    "stale_mocap_s": stale_mocap_s,
                    "use_mocap": use_mocap,
                    # The live assembler's odometry plausibility, so the replay integrates the
                    # same increments.
                    "odometry_jump_factor": odometry_jump_factor,
                    **({} if uav_id is None else {"uav": uav_id}),
                    # The robots ran their own filters: the bag holds their estimates.
                    **({"onboard": True} if onboard else {}),
                }
            ),
        )
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._closed = False
        # sqlite3 objects work only in the thread that made them: rows from other threads (the
        # watchdog's stop commands) wait here and are written by the owner's next write.
        self._owner = threading.get_ident()
        self._pending: list[tuple[str, str, int, bytes]] = []
        self.messages_written = 0  # sensor, mocap and command messages
        self.markers_written = 0  # reset / step markers (also messages of the bag)

    def _connection(self, topic: str, msgtype: str):
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self._ts)
            self._connections[topic] = conn
        return conn

    def write(self, topic: str, sensor: str, stamp_ns: int, msg: dict) -> None:
        """Write one message dict of a message kind (``lidar``, ``odometry``, ``camera``,
        ``camera_stamped``, ``mocap``, ``cmd_vel``)."""
        obj = to_rosbags(self._ts, sensor, msg)
        data = bytes(self._ts.serialize_cdr(obj, ALL_BAG_TYPES[sensor]))
        with self._lock:
            if self._closed:
                return
            self._pending.append((topic, ALL_BAG_TYPES[sensor], int(stamp_ns), data))
            if threading.get_ident() == self._owner:
                self._flush_pending()

    def _flush_pending(self) -> None:
        """Write the queued rows (owner thread, lock held)."""
        pending, self._pending = self._pending, []
        for topic, msgtype, stamp_ns, data in pending:
            self._writer.write(self._connection(topic, msgtype), stamp_ns, data)
            self.messages_written += 1

    def write_marker(
        self, kind: str, index: int, end_ns: int, stale: dict[str, tuple[str, ...]]
    ) -> None:
        text = json.dumps(
            {"kind": kind, "index": index, "stale": {r: list(s) for r, s in stale.items()}}
        )
        obj = self._ts.types[STRING_TYPE](data=text)
        data = self._ts.serialize_cdr(obj, STRING_TYPE)
        with self._lock:
            if self._closed:
                return
            self._flush_pending()
            self._writer.write(self._connection(STEP_TOPIC, STRING_TYPE), int(end_ns), data)
            self.markers_written += 1
            # Commit the step: a process killed outright (SIGKILL, power loss) leaves whole
            # steps in the database (metadata.yaml is only written by close()).
            storage = getattr(self._writer, "storage", None)
            conn = getattr(storage, "conn", None)
            if conn is not None:
                conn.commit()

    def write_commands(self, t_ns: int, commands: np.ndarray) -> None:
        for robot, (v, w) in zip(self.robot_ids, np.asarray(commands).reshape(-1, 2), strict=True):
            self.write(topics(robot)["cmd_vel"], "cmd_vel", t_ns, twist_msg(v, w))

    # -- RealWorld hooks
    def record_step(
        self,
        kind: str,
        index: int,
        end_ns: int,
        used: dict,
        commands,
        stale: dict[str, tuple[str, ...]],
        uav_command: tuple[str, np.ndarray] | None = None,
    ) -> None:
        # One step = its rows and its marker, never half of it (signals wait for the end).
        with critical():
            if commands is not None:
                self.write_commands(*commands)
                if uav_command is not None:
                    uav, cmd = uav_command
                    self.write(uav_cmd_topic(uav), "cmd_vel", commands[0], uav_twist_msg(cmd))
            for uav in () if self.uav_id is None else (self.uav_id,):
                for uav_kind in UAV_KINDS:  # ``kind`` is the marker's
                    for _parsed, (topic, msg_kind, stamp_ns, msg) in used.get(uav, {}).get(
                        uav_kind, []
                    ):
                        self.write(topic, msg_kind, stamp_ns, msg)
            for robot in self.robot_ids:
                for sensor in SENSORS + RECORDED_EXTRA:
                    for _parsed, (topic, msg_kind, stamp_ns, msg) in used.get(robot, {}).get(
                        sensor, []
                    ):
                        self.write(topic, msg_kind, stamp_ns, msg)
            self.write_marker(kind, index, end_ns, stale)

    def record_stop(self, t_ns: int, robots: Sequence[str]) -> None:
        self.write_commands(t_ns, np.zeros((len(robots), 2)))
        if self.uav_id is not None:  # the stop is a hover for the UAV
            self.write(uav_cmd_topic(self.uav_id), "cmd_vel", t_ns, uav_twist_msg(np.zeros(4)))

    def close(self) -> None:
        """Write ``metadata.yaml`` and close the database (idempotent; signals deferred)."""
        with critical(), self._lock:
            if self._closed:
                return
            self._closed = True
            if threading.get_ident() == self._owner:
                self._flush_pending()
            self._writer.close()


def bag_state(path: str | Path) -> str:
    """What a command line says about the bag at ``path`` after a run, read from the disk
    (never from what the run meant to do): closed (``metadata.yaml`` written), left open (a
    database without ``metadata.yaml``: replay salvages its committed steps), or absent."""
    p = Path(path)
    if (p / "metadata.yaml").is_file():
        return f"bag {str(p)} closed"
    if any(p.glob("*.db3")):
        return (
            f"bag {str(p)} NOT closed (no metadata.yaml): `swarm-phd replay` reads its "
            "committed steps"
        )
    return f"no bag written at {str(p)}"


# ---------------------------------------------------------------------------- replay
def read_meta(path: str | Path) -> dict[str, Any]:
    """The bag's swarm-phd metadata (``custom_data`` of ``metadata.yaml``, YAML safe loader).
    Raises :class:`BagError` naming the problem."""
    from ruamel.yaml import YAML

    path = Path(path)
    if not path.exists():
        raise BagError(path, "no such bag directory")
    if not path.is_dir():
        raise BagError(path, "not a directory (a ROS 2 bag is a directory with metadata.yaml)")
    metafile = path / "metadata.yaml"
    if not metafile.is_file():
        hint = (
            "; a .db3 is there: the recorder was killed before closing (SIGKILL, power loss)"
            if any(path.glob("*.db3"))
            else ""
        )
        raise BagError(path, f"not a ROS 2 bag directory (no metadata.yaml){hint}")
    try:
        info = YAML(typ="safe").load(metafile.read_bytes())
    except Exception as exc:  # noqa: BLE001 - ruamel raises many types
        raise BagError(metafile, f"not valid YAML ({type(exc).__name__})") from None
    bag_info = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
    if not isinstance(bag_info, dict):
        raise BagError(metafile, "no rosbag2_bagfile_information mapping")
    custom = bag_info.get("custom_data") or {}
    raw = custom.get(META_KEY) if isinstance(custom, dict) else None
    if not isinstance(raw, str):
        raise BagError(
            metafile,
            f"not a swarm-phd bag (no custom_data[{META_KEY!r}] string); record it "
            "with the bridge (record=PATH) or swarm-phd export-bag",
        )
    try:
        meta = json.loads(raw)
    except ValueError as exc:
        raise BagError(metafile, f"custom_data[{META_KEY!r}] is not valid JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise BagError(metafile, f"custom_data[{META_KEY!r}] is not a JSON object")
    robots = meta.get("robots")
    if not isinstance(robots, list) or not robots:
        raise BagError(
            metafile, f"swarm-phd metadata: robots must be a non-empty list, got {robots!r}"
        )
    if not isinstance(meta.get("config"), dict):
        raise BagError(metafile, "swarm-phd metadata: config must be an object")
    try:
        for robot in robots:
            check_robot_id(robot)
    except ValueError as exc:
        raise BagError(metafile, f"swarm-phd metadata: {exc}") from None
    if len(set(robots)) != len(robots):
        raise BagError(metafile, f"swarm-phd metadata: duplicate robot ids {robots}")
    for key, default in (("stale_mocap_s", 0.5), ("odometry_jump_factor", 3.0)):
        value = meta.get(key, default)
        if type(value) not in (int, float) or not value > 0 or value != value:
            raise BagError(
                metafile, f"swarm-phd metadata: {key} must be a number > 0, got {value!r}"
            )
    if not isinstance(meta.get("use_mocap", True), bool):
        raise BagError(metafile, "swarm-phd metadata: use_mocap must be a bool")
    uav = meta.get("uav")
    if uav is not None:
        try:
            check_robot_id(uav)
        except ValueError as exc:
            raise BagError(metafile, f"swarm-phd metadata: uav: {exc}") from None
        if uav in robots:
            raise BagError(metafile, f"swarm-phd metadata: uav {uav!r} is also a robot")
    return meta


# Replay skips, by counter key: what a damaged bag lost (reported by ``swarm-phd replay``).
SKIP_REASONS = {
    "bag.undecodable": "messages whose bytes do not decode as their type",
    "bag.wrong_type": "messages of a known topic recorded with the wrong type",
    "bag.bad_marker": "step markers that are not valid JSON markers",
    "bag.duplicate_marker": "repeated step markers",
    "bag.missing_steps": "step markers missing (their steps merged into the next)",
    "bag.duplicate_rows": "repeated message rows",
    "bag.stamp_mismatch": "messages whose bag time differs from their header stamp",
    "bag.incomplete_step": "messages after the last step marker (an unfinished step)",
    "bag.orphan_steps": "step markers before any reset marker",
    "bag.read_error": "rows lost to damaged database pages",
    "bag.salvaged": "database refused by rosbags, rows read directly (order by insertion)",
}


class ReplayWorld:
    """A World that replays a recorded bag step by step (open loop: commands are ignored).

    Each :meth:`reset` moves to the next recorded episode; :meth:`step` returns the next
    recorded step and raises ``EOFError`` past the end of the episode. A bag that cannot be
    replayed raises :class:`BagError`; damage that leaves a replayable part is skipped and
    counted in :attr:`counters` (keys in :data:`SKIP_REASONS`, and ``<sensor>.invalid``).
    """

    layout = None  # obstacle geometry is not known off the simulator

    def __init__(self, path: str | Path, config: SwarmConfig | None = None) -> None:
        self.path = Path(path)
        meta = read_meta(self.path)
        self.meta = meta
        if meta.get("onboard"):
            raise BagError(
                self.path,
                "recorded with on-board filters (real_env(onboard=True)): it holds the robots' "
                "estimates (/<robot>/swarm_phd/estimate) and odometry, not their scans and "
                "bearings; replaying such a bag is not supported (read its estimates with "
                "rosbags)",
            )
        self.robot_ids = tuple(meta["robots"])
        self.uav_id: str | None = meta.get("uav")
        self._uav_ids = () if self.uav_id is None else (self.uav_id,)
        self.last_uav = UAVMessages()
        try:
            self.config = config if config is not None else config_from_dict(meta["config"])
        except Exception as exc:  # noqa: BLE001 - any wrong type in the recorded config
            raise BagError(
                self.path / "metadata.yaml",
                f"recorded config invalid: {type(exc).__name__}: {exc}",
            ) from None
        self.stale_mocap_s = float(meta.get("stale_mocap_s", 0.5))
        self.use_mocap = bool(meta.get("use_mocap", True))
        # Bags from before it was recorded: the factor's default of that time.
        self.odometry_jump_factor = float(meta.get("odometry_jump_factor", 3.0))
        self.counters = Counters()
        self.assembler = self.make_assembler(self.config)
        self.relay = TeammateRelay(self.robot_ids) if self.config.comms.enabled else None
        self.problems: list[str] = []  # first few skip details, for the report
        self._check_files()
        markers, messages = self._read()
        self._index(markers, messages)
        self.missing = self._missing(messages)
        self._episode = -1
        self._cursor = 0

    # ------------------------------------------------------------------ reading
    def _check_files(self) -> None:
        """Every file of the bag directory is a regular file: a FIFO, a device or a socket in
        the database's place would block the read forever (opening a FIFO waits for a
        writer), so it is refused before anything opens it."""
        for p in sorted(self.path.iterdir()):
            try:
                mode = p.lstat().st_mode
            except OSError as exc:
                raise BagError(p, f"cannot stat: {exc.strerror}") from None
            if stat.S_ISLNK(mode):
                try:
                    mode = p.stat().st_mode
                except OSError:
                    raise BagError(p, "a dangling symbolic link in the bag") from None
            if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                raise BagError(
                    p,
                    "not a regular file (a FIFO, socket or device): refused, reading it "
                    "could block forever",
                )

    def _missing(self, messages: list) -> dict[str, tuple[str, ...]]:
        """Sensors of which the bag holds no valid message at all, per robot (mocap only if
        the run used it). The replay reports them stale at every step (never fed, never
        scored as present); ``swarm-phd replay`` names them, and refuses a robot without
        odometry (its filter cannot move)."""
        have = {(robot, sensor) for _stamp, robot, sensor, _kind, _msg in messages}
        wanted = FEED_SENSORS + (("mocap",) if self.use_mocap else ())
        out = {}
        for robot in self.robot_ids:
            gone = tuple(s for s in wanted if (robot, s) not in have)
            if gone:
                out[robot] = gone
        return out

    def _skip(self, key: str, detail: str, n: int = 1) -> None:
        self.counters.incr(key, n)
        if len(self.problems) < 10:
            self.problems.append(detail)

    def skipped(self) -> dict[str, int]:
        """Skip counters of the read and of the replay so far (only the non-zero ones)."""
        snap = self.counters.snapshot()
        return {k: v for k, v in snap.items() if k in SKIP_REASONS or k.endswith(".invalid")}

    def _rosbags_rows(self):
        """``(connections, rows)`` through rosbags: connections ``(id, topic, type, count)``,
        rows ``(conn_id, topic, type, stamp_ns, bytes)`` in time order."""
        from rosbags.rosbag2 import Reader

        reader = Reader(self.path)
        reader.open()
        conns = [
            (c.id, c.topic, c.msgtype, int(getattr(c, "msgcount", 0) or 0))
            for c in reader.connections
        ]

        def rows():
            try:
                for conn, stamp, raw in reader.messages():
                    yield conn.id, conn.topic, conn.msgtype, int(stamp), bytes(raw)
            finally:
                try:
                    reader.close()
                except Exception:  # noqa: BLE001
                    pass

        return conns, rows()

    def _sqlite_rows(self, error: str):
        """Salvage a database that rosbags refuses (truncated, damaged pages): a copy with the
        page count in its header set to what the file holds, read row by row by id (a lookup
        per row, so a lost page loses only its own rows), in insertion order."""
        import sqlite3
        import struct
        import tempfile

        dbs = sorted(self.path.glob("*.db3"))
        if len(dbs) != 1:
            raise BagError(self.path, f"cannot open the bag: {error}")
        size = dbs[0].stat().st_size
        with open(dbs[0], "rb") as src:
            header = src.read(100)
        if len(header) < 100 or not header.startswith(b"SQLite format 3\x00"):
            raise BagError(self.path, f"cannot open the bag: {error}")
        page = struct.unpack(">H", header[16:18])[0]
        page = 65536 if page == 1 else page
        n_pages = size // max(page, 512)
        # A copy streamed in chunks (memory independent of the database size), cut to whole
        # pages, with the page count in its header set to what the file holds.
        tmp = tempfile.NamedTemporaryFile(suffix=".db3", delete=False)  # noqa: SIM115
        try:
            with open(dbs[0], "rb") as src:
                left = n_pages * page
                while left > 0:
                    chunk = src.read(min(left, 1 << 20))
                    if not chunk:
                        break
                    tmp.write(chunk)
                    left -= len(chunk)
            tmp.seek(28)
            tmp.write(struct.pack(">I", n_pages))
            tmp.close()
        except BaseException:
            tmp.close()
            Path(tmp.name).unlink(missing_ok=True)
            raise
        try:
            con = sqlite3.connect(f"file:{tmp.name}?mode=ro", uri=True)
            conns = [
                (int(i), str(name), str(msgtype), 0)
                for i, name, msgtype in con.execute("select id, name, type from topics")
            ]
        except Exception:  # noqa: BLE001 - not even the topic table: nothing to salvage
            Path(tmp.name).unlink(missing_ok=True)
            raise BagError(self.path, f"cannot open the bag: {error}") from None
        names = {i: (name, msgtype) for i, name, msgtype, _ in conns}
        # How many row ids to look up: the larger of the table's largest id (if its index is
        # readable) and metadata.yaml's count, neither believed beyond what the file can hold
        # (rows of >= 16 bytes); the look-up also ends after 10000 ids in a row without a row.
        try:
            top = con.execute("select max(id) from messages").fetchone()[0]
        except sqlite3.DatabaseError:
            top = None
        cap = size // 16
        recorded = self._recorded_count()
        recorded = recorded if recorded <= cap else 0  # an absurd count is not believed
        top = int(top) if isinstance(top, int) and 0 < top <= cap else 0
        total = max(top, recorded) or cap
        self._skip("bag.salvaged", f"rosbags refused the database ({error}); read with sqlite3")

        def rows():
            lost = 0
            try:
                row_id = 0
                run = 0  # ids in a row without a row
                while row_id < total and run < 10_000:
                    row_id += 1
                    try:
                        row = con.execute(
                            "select topic_id, timestamp, data from messages where id = ?",
                            (row_id,),
                        ).fetchone()
                    except sqlite3.DatabaseError:
                        row = None
                    if row is None:
                        lost += 1
                        run += 1
                        continue
                    run = 0
                    topic, msgtype = names.get(row[0], ("", ""))
                    yield row[0], topic, msgtype, int(row[1]), bytes(row[2])
                if run >= 10_000:  # stopped on a long empty run: those ids were never rows
                    lost -= run
                if lost:
                    self._skip("bag.read_error", f"{lost} rows on unreadable pages", lost)
            finally:
                con.close()
                Path(tmp.name).unlink(missing_ok=True)

        return conns, rows()

    def _recorded_count(self) -> int:
        """Total message count from metadata.yaml (0 if unreadable)."""
        from ruamel.yaml import YAML

        try:
            info = YAML(typ="safe").load((self.path / "metadata.yaml").read_bytes())
            count = info["rosbag2_bagfile_information"]["message_count"]
            return int(count) if type(count) is int and count > 0 else 0
        except Exception:  # noqa: BLE001
            return 0

    def _read(self) -> tuple[list[tuple[int, dict]], list[tuple[int, str, str, str, dict]]]:
        ts = _typestore()
        expected: dict[str, tuple[str, str]] = {}  # topic -> (robot, kind)
        for robot in self.robot_ids:
            for kind, topic in topics(robot).items():
                if not kind.startswith("cmd_vel"):
                    expected[topic] = (robot, kind)
        for uav in self._uav_ids:
            for kind, topic in uav_topics(uav).items():
                expected[topic] = (uav, kind)
        markers: list[tuple[int, dict]] = []
        messages: list[tuple[int, str, str, str, dict]] = []
        seen_rows: set[tuple[int, int, bytes]] = set()  # (connection, stamp, digest)
        salvaged = False
        try:
            conns, rows = self._rosbags_rows()
        except Exception as exc:  # noqa: BLE001 - rosbags, sqlite3, yaml: one line
            text = f"{type(exc).__name__}: {exc}"
            if "metadata" in str(exc).lower() or not any(self.path.glob("*.db3")):
                raise BagError(self.path, f"cannot open the bag: {text}") from None
            conns, rows = self._sqlite_rows(text)
            salvaged = True
        bad_conns: set[int] = set()
        for conn_id, topic, msgtype, count in conns:
            if topic in expected:
                kind = expected[topic][1]
                if msgtype != ALL_BAG_TYPES[kind]:
                    bad_conns.add(conn_id)
                    self._skip(
                        "bag.wrong_type",
                        f"{topic} recorded as {msgtype}, expected {ALL_BAG_TYPES[kind]}",
                        count,
                    )
            elif topic == STEP_TOPIC and msgtype != STRING_TYPE:
                raise BagError(self.path, f"{STEP_TOPIC} recorded as {msgtype}")
        n_read = 0
        while True:
            try:
                item = next(rows)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - a damaged database page
                if n_read == 0:
                    raise BagError(
                        self.path, f"cannot read messages: {type(exc).__name__}: {exc}"
                    ) from None
                self._skip(
                    "bag.read_error",
                    f"read stopped after {n_read} messages: {type(exc).__name__}: {exc}",
                )
                break
            n_read += 1
            conn_id, topic, msgtype, stamp, raw = item
            row = (conn_id, stamp, hashlib.blake2b(raw, digest_size=16).digest())
            if row in seen_rows:
                self._skip("bag.duplicate_rows", f"{topic} at {stamp} repeated")
                continue
            seen_rows.add(row)
            if topic == STEP_TOPIC:
                marker = self._marker(ts, msgtype, stamp, raw)
                if marker is not None:
                    markers.append((stamp, marker))
                continue
            if topic not in expected:
                continue  # commands and foreign topics
            if conn_id in bad_conns:
                if salvaged:  # no per-connection counts from metadata: count the rows
                    self.counters.incr("bag.wrong_type")
                continue
            robot, kind = expected[topic]
            try:
                msg = from_rosbags(kind, ts.deserialize_cdr(raw, msgtype))
            except Exception as exc:  # noqa: BLE001 - garbage bytes in a row
                self._skip("bag.undecodable", f"{topic} at {stamp}: {type(exc).__name__}")
                continue
            if kind != "camera":  # stamped kinds are written at their header stamp
                h = msg["header"]["stamp"]
                header_ns = h["sec"] * 1_000_000_000 + h["nanosec"]
                if header_ns != stamp:
                    self._skip(
                        "bag.stamp_mismatch",
                        f"{topic}: bag time {stamp} != header stamp {header_ns}",
                    )
                    continue
            messages.append((stamp, robot, SENSOR_OF_KIND[kind], kind, msg))
        return markers, messages

    def _marker(self, ts, msgtype: str, stamp: int, raw) -> dict | None:
        try:
            text = ts.deserialize_cdr(raw, msgtype).data
            marker = json.loads(text)
        except Exception as exc:  # noqa: BLE001
            self._skip("bag.bad_marker", f"marker at {stamp}: {type(exc).__name__}")
            return None
        index = marker.get("index") if isinstance(marker, dict) else None
        stale = marker.get("stale", {}) if isinstance(marker, dict) else None
        if (
            not isinstance(marker, dict)
            or marker.get("kind") not in ("reset", "step")
            or type(index) is not int
            or index < 0
            or not isinstance(stale, dict)
            or not all(
                isinstance(v, list) and all(isinstance(x, str) for x in v) for v in stale.values()
            )
        ):
            self._skip("bag.bad_marker", f"marker at {stamp}: {str(text)[:80]!r}")
            return None
        return marker

    def _index(self, markers, messages) -> None:
        if not markers:
            raise BagError(
                self.path, f"no valid step markers on {STEP_TOPIC}: not a replayable episode"
            )
        markers.sort(key=lambda m: m[0])
        # Episodes: a reset marker and the step markers after it, indices 1, 2, ...
        episodes: list[list[int]] = []
        kept: list[tuple[int, dict]] = []
        for stamp, marker in markers:
            if marker["kind"] == "reset":
                kept.append((stamp, marker))
                episodes.append([len(kept) - 1])
                continue
            if not episodes:
                self._skip("bag.orphan_steps", f"step marker {marker['index']} before any reset")
                continue
            last = kept[episodes[-1][-1]][1]
            expected = 1 if last["kind"] == "reset" else last["index"] + 1
            if marker["index"] < expected:
                self._skip("bag.duplicate_marker", f"step marker {marker['index']} repeated")
                continue
            if marker["index"] > expected:
                self._skip(
                    "bag.missing_steps",
                    f"episode {len(episodes) - 1}: step markers {expected}..{marker['index'] - 1} "
                    "missing",
                    marker["index"] - expected,
                )
            kept.append((stamp, marker))
            episodes[-1].append(len(kept) - 1)
        if not episodes:
            raise BagError(self.path, f"no reset marker on {STEP_TOPIC}: not a replayable episode")
        stamps = [m[0] for m in kept]
        groups: list[list[tuple[int, str, str, str, dict]]] = [[] for _ in kept]
        late = 0
        for item in messages:
            k = bisect.bisect_left(stamps, item[0])  # first marker at or after the message
            if k < len(kept):
                groups[k].append(item)
            else:
                late += 1
        if late:
            self._skip("bag.incomplete_step", f"{late} messages after the last step marker", late)
        self._episodes = episodes
        self._markers = kept
        self._groups = groups

    def make_assembler(self, config: SwarmConfig) -> RecordAssembler:
        """The live run's record assembler (its odometry plausibility), for ``config``."""
        return RecordAssembler(
            self.robot_ids, config, jump_factor=self.odometry_jump_factor, counters=self.counters
        )

    # ------------------------------------------------------------------ World API
    @property
    def n_episodes(self) -> int:
        return len(self._episodes)

    def n_steps(self, episode: int | None = None) -> int:
        """Recorded steps of an episode (default: the current one, or the first)."""
        e = max(self._episode, 0) if episode is None else episode
        return len(self._episodes[e]) - 1

    def __len__(self) -> int:
        return self.n_steps()

    def _parse(self, k: int) -> dict[str, dict[str, list]]:
        out: dict[str, dict[str, list]] = {r: {s: [] for s in SENSORS} for r in self.robot_ids}
        for uav in self._uav_ids:
            out[uav] = {kind: [] for kind in UAV_KINDS}
        for stamp, robot, sensor, kind, msg in self._groups[k]:
            try:
                parsed = parse_message(kind, msg, arrival_ns=stamp)
            except InvalidMessage as exc:
                self.counters.reject(f"{sensor}.invalid", f"{robot}: {exc}")
                continue
            out[robot][sensor].append(parsed)
        for sensors in out.values():
            for items in sensors.values():
                items.sort(key=lambda m: m.stamp_ns)
        return out

    def _world_step(self, k: int) -> WorldStep:
        end_ns, marker = self._markers[k]
        parsed = self._parse(k)
        comms: dict = {}
        stale = {r: tuple(s) for r, s in marker.get("stale", {}).items()}
        for robot, gone in self.missing.items():  # absent from the whole bag: stale throughout
            stale[robot] = tuple(dict.fromkeys(stale.get(robot, ()) + gone))
        if self.uav_id is not None:
            part = parsed[self.uav_id]
            if marker["kind"] == "reset":  # the newest of each, as the live reset
                part = {kind: items[-1:] for kind, items in part.items()}
            self.last_uav = uav_messages(part, stale.get(self.uav_id, ()))
        if marker["kind"] == "reset":
            measurements = self.assembler.reset_measurements(
                self.assembler.reset_selection(parsed)
            )
            mocap = {r: parsed[r]["mocap"][-1:] for r in self.robot_ids}
        else:
            per_robot = {r: {s: parsed[r][s] for s in FEED_SENSORS} for r in self.robot_ids}
            measurements = self.assembler.measurements(per_robot)
            mocap = {r: parsed[r]["mocap"] for r in self.robot_ids}
            if self.relay is not None:  # as the live bridge (hardware_bridge.comms)
                comms = self.relay.step(parsed, measurements)
        truth = (
            self.assembler.truth_from_mocap(mocap, end_ns, self.stale_mocap_s)
            if self.use_mocap
            else None
        )
        return WorldStep(
            time_s=ns_to_s(end_ns),
            measurements=measurements,
            truth=truth,
            stale=stale,
            comms=comms,
        )

    def reset(self, rng: np.random.Generator | None = None) -> WorldStep:
        self._episode += 1
        if self._episode >= len(self._episodes):
            raise EOFError(f"{self.path}: all {len(self._episodes)} recorded episode(s) replayed")
        self.assembler.reset()
        if self.relay is not None:
            self.relay.reset()
        self._cursor = 0
        return self._world_step(self._episodes[self._episode][0])

    def step(self, commands: np.ndarray, extra_commands: np.ndarray | None = None) -> WorldStep:
        reject_extra_commands("ReplayWorld", extra_commands)
        if self._episode < 0:
            raise RuntimeError("ReplayWorld.step() before reset()")
        episode = self._episodes[self._episode]
        self._cursor += 1
        if self._cursor >= len(episode):
            raise EOFError(
                f"{self.path}: episode {self._episode} has only {len(episode) - 1} recorded steps"
            )
        return self._world_step(episode[self._cursor])

    def set_uav_command(self, command: np.ndarray) -> None:
        """Checked like the live bridge's, then ignored: a replay is open loop."""
        if self.uav_id is None:
            raise ValueError("set_uav_command: this bag has no UAV")
        cmd = np.asarray(command, dtype=np.float64)
        if cmd.shape != (4,) or not np.isfinite(cmd).all():
            raise ValueError(
                f"uav command must be 4 finite numbers [vx, vy, yaw_rate, climb], got {command!r}"
            )

    def halt(self) -> None:
        """No robots to stop: a replay is open loop."""

    def close(self) -> None:
        """Nothing to release: the bag was read at construction."""


def replay_env(
    path: str | Path, *, task: str = "wander", render_mode: str | None = None, **overrides: Any
):
    """The env API over a recorded bag: ``SwarmEnv(world=ReplayWorld(path))``. ``overrides``
    change the recorded config (e.g. ``phd={"mode": "lidar-only"}`` to rerun another filter);
    the robots and timing come from the bag."""
    from swarm_env.env import SwarmEnv

    world = ReplayWorld(path)
    config = make_config(config=world.config, **overrides)
    if config is not world.config:
        world.config = config
        world.assembler = world.make_assembler(config)
    max_steps = overrides.get("max_steps")
    if max_steps is None:
        config = dataclasses.replace(config, max_steps=max(1, world.n_steps(0)))
        world.config = config
        world.assembler = world.make_assembler(config)
    return SwarmEnv(
        config=config,
        task=task,
        world=world,
        render_mode=render_mode,
        render_agent=world.robot_ids[0],
    )


# ---------------------------------------------------------------------------- export
