"""ROS 2 bags without ROS: record any bridge episode, replay it through the env API, export a
simulated episode. Uses the ``rosbags`` library (pure Python; sqlite3 storage, bag version 8).

Bag layout
----------
Per robot, standard message types, each at its message stamp (header stamp; arrival stamp for
the header-less bearings):

=============================  ==============================  ===============================
topic                          type                            what
=============================  ==============================  ===============================
``/<robot>/scan``              ``sensor_msgs/msg/LaserScan``    scans the bridge used
``/<robot>/odom``              ``nav_msgs/msg/Odometry``        odometry poses it used
``/<robot>/camera/bearings``   ``std_msgs/msg/Float32MultiArray`` bearings it used
``/mocap/<robot>/pose``        ``geometry_msgs/msg/PoseStamped`` motion capture
``/<robot>/cmd_vel``           ``geometry_msgs/msg/Twist``      commands sent (incl. stops)
``/bridge/step``               ``std_msgs/msg/String``          one JSON marker per reset/step
=============================  ==============================  ===============================

A marker ``{"kind": "reset"|"step", "index": k, "stale": {...}}`` is written at the end of each
reset/step, at the step's end time; the messages of step k are those stamped after marker k-1 and
up to marker k. The bag's ``custom_data["swarm_phd"]`` holds JSON metadata (robot ids, the env
config, the bridge's mocap freshness rule). Everything read back is parsed with
:func:`json.loads` and validated exactly as live messages are: never pickle or eval.

:class:`ReplayWorld` rebuilds each step's records from these messages with the same
:class:`~hardware_bridge.assembly.RecordAssembler` as the live bridge, so the filters get the
same inputs and produce the same output.
"""

from __future__ import annotations

import bisect
import dataclasses
import json
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hardware_bridge.assembly import RecordAssembler
from hardware_bridge.config import FEED_SENSORS
from hardware_bridge.messages import (
    BAG_TYPES,
    Counters,
    InvalidMessage,
    Pose,
    check_robot_id,
    ns_to_s,
    parse_bearings,
    parse_laser_scan,
    parse_odometry,
    parse_pose_stamped,
    topics,
    twist_msg,
)
from swarm_core.world import WorldStep, reject_extra_commands
from swarm_env.config import SwarmConfig, make_config

META_KEY = "swarm_phd"
STEP_TOPIC = "/bridge/step"
STRING_TYPE = "std_msgs/msg/String"
BAG_VERSION = 8
SENSORS = ("lidar", "odometry", "camera", "mocap")


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


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
    ) -> None:
        from rosbags.rosbag2 import Writer

        self.path = Path(path)
        self.robot_ids = tuple(robot_ids)
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
                }
            ),
        )
        self._writer.open()
        self._connections: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.messages_written = 0
        self._sensor_of = {}
        for robot in self.robot_ids:
            for sensor, topic in topics(robot).items():
                self._sensor_of[topic] = sensor

    def _connection(self, topic: str, msgtype: str):
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self._ts)
            self._connections[topic] = conn
        return conn

    def write(self, topic: str, sensor: str, stamp_ns: int, msg: dict) -> None:
        """Write one message dict (``sensor`` in lidar/odometry/camera/mocap/cmd_vel)."""
        obj = to_rosbags(self._ts, sensor, msg)
        data = self._ts.serialize_cdr(obj, BAG_TYPES[sensor])
        with self._lock:
            if self._closed:
                return
            self._writer.write(self._connection(topic, BAG_TYPES[sensor]), int(stamp_ns), data)
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
            self._writer.write(self._connection(STEP_TOPIC, STRING_TYPE), int(end_ns), data)

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
    ) -> None:
        if commands is not None:
            self.write_commands(*commands)
        for robot in self.robot_ids:
            for sensor in SENSORS:
                for _parsed, (topic, stamp_ns, msg) in used.get(robot, {}).get(sensor, []):
                    self.write(topic, sensor, stamp_ns, msg)
        self.write_marker(kind, index, end_ns, stale)

    def record_stop(self, t_ns: int, robots: Sequence[str]) -> None:
        self.write_commands(t_ns, np.zeros((len(robots), 2)))

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.close()


# ---------------------------------------------------------------------------- replay
def read_meta(path: str | Path) -> dict[str, Any]:
    """The bag's swarm-phd metadata (``custom_data`` of ``metadata.yaml``, YAML safe loader)."""
    from ruamel.yaml import YAML

    metafile = Path(path) / "metadata.yaml"
    if not metafile.is_file():
        raise ValueError(f"{path}: not a ROS 2 bag directory (no metadata.yaml)")
    info = YAML(typ="safe").load(metafile.read_text())
    try:
        custom = info["rosbag2_bagfile_information"].get("custom_data") or {}
    except (TypeError, KeyError, AttributeError) as exc:
        raise ValueError(f"{path}: invalid metadata.yaml") from exc
    raw = custom.get(META_KEY)
    if not isinstance(raw, str):
        raise ValueError(
            f"{path}: not a swarm-phd bag (no custom_data[{META_KEY!r}]); record it "
            "with the bridge (record=PATH) or swarm-phd export-bag"
        )
    meta = json.loads(raw)
    if (
        not isinstance(meta, dict)
        or not isinstance(meta.get("robots"), list)
        or not isinstance(meta.get("config"), dict)
    ):
        raise ValueError(f"{path}: invalid swarm-phd metadata")
    for robot in meta["robots"]:
        check_robot_id(robot)
    return meta


class ReplayWorld:
    """A World that replays a recorded bag step by step (open loop: commands are ignored).

    Each :meth:`reset` moves to the next recorded episode; :meth:`step` returns the next
    recorded step and raises ``EOFError`` past the end of the episode.
    """

    layout = None  # obstacle geometry is not known off the simulator

    def __init__(self, path: str | Path, config: SwarmConfig | None = None) -> None:
        from rosbags.rosbag2 import Reader

        self.path = Path(path)
        meta = read_meta(self.path)
        self.meta = meta
        self.robot_ids = tuple(meta["robots"])
        self.config = config if config is not None else config_from_dict(meta["config"])
        self.stale_mocap_ns = float(meta.get("stale_mocap_s", 0.5)) * 1e9
        self.use_mocap = bool(meta.get("use_mocap", True))
        self.assembler = RecordAssembler(self.robot_ids, self.config)
        self.counters = Counters()
        ts = _typestore()
        sensor_of = {}
        for robot in self.robot_ids:
            for sensor, topic in topics(robot).items():
                sensor_of[topic] = (robot, sensor)
        markers: list[tuple[int, dict]] = []
        messages: list[tuple[int, str, str, dict]] = []
        with Reader(self.path) as reader:
            for conn, stamp, raw in reader.messages():
                if conn.topic == STEP_TOPIC:
                    text = ts.deserialize_cdr(raw, conn.msgtype).data
                    marker = json.loads(text)
                    if not isinstance(marker, dict) or marker.get("kind") not in ("reset", "step"):
                        raise ValueError(f"{path}: invalid step marker {text[:100]!r}")
                    markers.append((stamp, marker))
                elif conn.topic in sensor_of:
                    robot, sensor = sensor_of[conn.topic]
                    if sensor == "cmd_vel":
                        continue
                    msg = from_rosbags(sensor, ts.deserialize_cdr(raw, conn.msgtype))
                    messages.append((stamp, robot, sensor, msg))
        if not markers or markers[0][1]["kind"] != "reset":
            raise ValueError(f"{path}: no reset marker on {STEP_TOPIC}; not a replayable episode")
        markers.sort(key=lambda m: m[0])
        stamps = [m[0] for m in markers]
        groups: list[list[tuple[int, str, str, dict]]] = [[] for _ in markers]
        for item in messages:
            k = bisect.bisect_left(stamps, item[0])  # first marker at or after the message
            if k < len(markers):
                groups[k].append(item)
        # Episodes: a reset marker and the step markers after it.
        self._episodes: list[list[int]] = []
        for k, (_, marker) in enumerate(markers):
            if marker["kind"] == "reset":
                self._episodes.append([k])
            else:
                self._episodes[-1].append(k)
        self._markers = markers
        self._groups = groups
        self._episode = -1
        self._cursor = 0
        self._truth_pose: dict[str, Pose | None] = {r: None for r in self.robot_ids}

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
        for stamp, robot, sensor, msg in self._groups[k]:
            try:
                if sensor == "lidar":
                    parsed = parse_laser_scan(msg)
                elif sensor == "odometry":
                    parsed = parse_odometry(msg)
                elif sensor == "camera":
                    parsed = parse_bearings(msg, stamp)
                else:
                    parsed = parse_pose_stamped(msg)
            except InvalidMessage as exc:
                self.counters.reject(f"{sensor}.invalid", f"{robot}: {exc}")
                continue
            out[robot][sensor].append(parsed)
        for robot in self.robot_ids:
            for sensor in SENSORS:
                out[robot][sensor].sort(key=lambda m: m.stamp_ns)
        return out

    def _truth(self, parsed: dict, end_ns: int):
        if not self.use_mocap:
            return None
        for robot in self.robot_ids:
            if parsed[robot]["mocap"]:
                self._truth_pose[robot] = parsed[robot]["mocap"][-1]
        fresh = {
            r: (p if p is not None and end_ns - p.stamp_ns <= self.stale_mocap_ns else None)
            for r, p in self._truth_pose.items()
        }
        return self.assembler.truth(fresh)

    def _world_step(self, k: int) -> WorldStep:
        end_ns, marker = self._markers[k]
        parsed = self._parse(k)
        stale = {r: tuple(s) for r, s in marker.get("stale", {}).items()}
        if marker["kind"] == "reset":
            for robot in self.robot_ids:
                self.assembler.odometry(robot, parsed[robot]["odometry"][-1:])
            per_robot = {
                r: {"lidar": parsed[r]["lidar"][-1:], "camera": parsed[r]["camera"][-1:]}
                for r in self.robot_ids
            }
        else:
            per_robot = {r: {s: parsed[r][s] for s in FEED_SENSORS} for r in self.robot_ids}
        measurements = self.assembler.measurements(per_robot)
        return WorldStep(
            time_s=ns_to_s(end_ns),
            measurements=measurements,
            truth=self._truth(parsed, end_ns),
            stale=stale,
        )

    def reset(self, rng: np.random.Generator | None = None) -> WorldStep:
        self._episode += 1
        if self._episode >= len(self._episodes):
            raise EOFError(f"{self.path}: all {len(self._episodes)} recorded episode(s) replayed")
        self.assembler.reset()
        self._truth_pose = {r: None for r in self.robot_ids}
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
        world.assembler = RecordAssembler(world.robot_ids, config)
    max_steps = overrides.get("max_steps")
    if max_steps is None:
        config = dataclasses.replace(config, max_steps=max(1, world.n_steps(0)))
        world.config = config
        world.assembler = RecordAssembler(world.robot_ids, config)
    return SwarmEnv(
        config=config,
        task=task,
        world=world,
        render_mode=render_mode,
        render_agent=world.robot_ids[0],
    )


# ---------------------------------------------------------------------------- export
