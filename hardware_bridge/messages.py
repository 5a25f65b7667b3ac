"""ROS message schemas: validation of incoming message dicts, builders for outgoing ones.

Messages arrive as the JSON objects of the rosbridge v2 protocol (decoded with ``json.loads``,
never pickle or eval). Every field the bridge uses is checked before use: the right JSON type
(a number is an ``int`` or ``float``, never a ``bool`` or a string), finite, the right length.
A failing message raises :class:`InvalidMessage` naming the field; callers count and log it.

Conventions (REP-103 / REP-105): ``x`` forward, ``y`` left, yaw counter-clockwise, SI units.
Stamps are integer nanoseconds of ROS time (``header.stamp``, ROS 2 ``sec``/``nanosec`` or
ROS 1 ``secs``/``nsecs``). Scan ranges follow REP-117 and the YDLidar driver: ``0``, ``NaN``,
``+-inf``, ``null`` or a value outside ``[range_min, range_max]`` all mean "no valid return" and
become ``0``; that is data, not corruption. ``float32`` fields (scan, bearings) are rounded to
``float32`` on parsing, so a live message and its copy read back from a bag parse identically.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_core.geometry import wrap_angle
from swarm_core.stamps import NS_PER_S as _NS
from swarm_core.stamps import ns_to_s, s_to_ns  # noqa: F401 (this package imports them from here)

LOGGER = logging.getLogger("hardware_bridge")
TWO_PI = 2.0 * math.pi

_ROBOT_ID = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")

# Message kinds -> rosbridge type names (ROS 1 spelling, accepted by the ROS 2 rosbridge too) and
# bag type names. A kind is a sensor's wire format: the camera has two (``camera`` = legacy
# header-less Float32MultiArray, ``camera_stamped`` = BearingsStamped), commands too.
ROS_TYPES = {
    "lidar": "sensor_msgs/LaserScan",
    "odometry": "nav_msgs/Odometry",
    "camera": "std_msgs/Float32MultiArray",
    "camera_stamped": "swarm_phd_msgs/BearingsStamped",
    "mocap": "geometry_msgs/PoseStamped",
    "cmd_vel": "geometry_msgs/Twist",
    "cmd_vel_stamped": "geometry_msgs/TwistStamped",
}
BAG_TYPES = {key: value.replace("/", "/msg/", 1) for key, value in ROS_TYPES.items()}
SENSOR_OF_KIND = {
    "lidar": "lidar",
    "odometry": "odometry",
    "camera": "camera",
    "camera_stamped": "camera",
    "mocap": "mocap",
    "cmd_vel": "cmd_vel",
    "cmd_vel_stamped": "cmd_vel",
    "uav_pose": "uav_pose",
    "uav_detections": "uav_detections",
}
# The stamped bearings message (a package ``swarm_phd_msgs`` on the robots; see
# docs/how-to/real-robots.md). ROS 2 .msg syntax; registered in the bag typestore from this text.
BEARINGS_STAMPED_MSG = """std_msgs/Header header
float32[] bearings
"""
# Physical plausibility of velocities reported by odometry (m/s, rad/s): far beyond any UGV,
# so only corrupt values are refused.
MAX_PLAUSIBLE_SPEED = 100.0


class InvalidMessage(ValueError):
    """A message failed validation; ``field`` names the offending field."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


# ---------------------------------------------------------------------------- naming
def check_robot_id(robot: Any) -> str:
    if not isinstance(robot, str) or not _ROBOT_ID.match(robot):
        raise ValueError(
            f"robot id must match {_ROBOT_ID.pattern} (a ROS name segment), got {robot!r}"
        )
    return robot


def topics(robot: str) -> dict[str, str]:
    """The ROS topics of one robot, by message kind (see :data:`ROS_TYPES`)."""
    return {
        "lidar": f"/{robot}/scan",
        "odometry": f"/{robot}/odom",
        "camera": f"/{robot}/camera/bearings",
        "camera_stamped": f"/{robot}/camera/bearings_stamped",
        "mocap": f"/mocap/{robot}/pose",
        "cmd_vel": f"/{robot}/cmd_vel",
        "cmd_vel_stamped": f"/{robot}/cmd_vel",
    }


def kind_topics(robot: str, stamped_bearings: bool = True) -> dict[str, tuple[str, str]]:
    """``{sensor: (kind, topic)}`` of one robot's four sensors, for its bearings format."""
    names = topics(robot)
    camera = "camera_stamped" if stamped_bearings else "camera"
    return {
        sensor: (kind, names[kind])
        for sensor, kind in (
            ("lidar", "lidar"),
            ("odometry", "odometry"),
            ("camera", camera),
            ("mocap", "mocap"),
        )
    }


# ---------------------------------------------------------------------------- time
# ns_to_s / s_to_ns: swarm_core.stamps (the UAV's frames in swarm_core.aerial use them too),
# imported above for this package's modules.


# ---------------------------------------------------------------------------- parsed forms
@dataclass(frozen=True, slots=True)
class Scan:
    """A validated ``sensor_msgs/LaserScan``: beams sorted by bearing in ``[-pi, pi)``."""

    stamp_ns: int
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    intensities: np.ndarray


@dataclass(frozen=True, slots=True)
class Odom:
    """A validated ``nav_msgs/Odometry``: planar pose in the odom frame, body-frame twist."""

    stamp_ns: int
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    omega_radps: float


@dataclass(frozen=True, slots=True)
class Bearings:
    """A validated ``std_msgs/Float32MultiArray`` of bearings (robot frame, rad)."""

    stamp_ns: int
    bearings_rad: np.ndarray


@dataclass(frozen=True, slots=True)
class Pose:
    """A validated ``geometry_msgs/PoseStamped`` reduced to ``x, y, yaw`` (mocap frame)."""

    stamp_ns: int
    x_m: float
    y_m: float
    yaw_rad: float


# ---------------------------------------------------------------------------- primitives
def _get(msg: Any, path: str) -> Any:
    node = msg
    walked = []
    for key in path.split("."):
        if not isinstance(node, dict):
            where = ".".join(walked) or "message"
            raise InvalidMessage(where, f"expected an object, got {type(node).__name__}")
        walked.append(key)
        if key not in node:
            raise InvalidMessage(".".join(walked), "missing")
        node = node[key]
    return node


def _is_number(value: Any) -> bool:
    return type(value) in (int, float)  # excludes bool, str, None, containers


def _number(msg: Any, path: str) -> float:
    value = _get(msg, path)
    if not _is_number(value):
        raise InvalidMessage(path, f"expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise InvalidMessage(path, f"not finite: {value!r}")
    return value


def _optional_numbers(msg: dict, path: str, length: int) -> None:
    """A field we do not use but which, when present, must still be well formed."""
    try:
        value = _get(msg, path)
    except InvalidMessage as exc:
        if exc.reason == "missing":
            return
        raise
    _number_array(value, path, max_len=length, exact_len=length)


def _number_array(
    value: Any,
    path: str,
    *,
    max_len: int,
    exact_len: int | None = None,
    non_finite_ok: bool = False,
    none_ok: bool = False,
) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise InvalidMessage(path, f"expected an array, got {type(value).__name__}")
    n = len(value)
    if exact_len is not None and n != exact_len:
        raise InvalidMessage(path, f"expected {exact_len} elements, got {n}")
    if n > max_len:
        raise InvalidMessage(path, f"too long: {n} elements > {max_len}")
    types = {type(v) for v in value}
    allowed = {int, float} | ({type(None)} if none_ok else set())
    if not types <= allowed:
        bad = sorted(t.__name__ for t in types - allowed)
        raise InvalidMessage(path, f"elements must be numbers, got {bad}")
    if none_ok and type(None) in types:
        value = [math.nan if v is None else v for v in value]
    out = np.asarray(value, dtype=np.float64).reshape(-1)
    if not non_finite_ok and not np.all(np.isfinite(out)):
        raise InvalidMessage(path, "contains non-finite values")
    return out


def parse_stamp(msg: Any, path: str = "header.stamp") -> int:
    """``header.stamp`` as integer nanoseconds (ROS 2 ``sec``/``nanosec`` or ROS 1 ``secs``/
    ``nsecs``); zero and negative stamps are rejected (an unset driver clock)."""
    stamp = _get(msg, path)
    if not isinstance(stamp, dict):
        raise InvalidMessage(path, f"expected an object, got {type(stamp).__name__}")
    if "sec" in stamp:
        sec_key, nsec_key = "sec", "nanosec"
    elif "secs" in stamp:
        sec_key, nsec_key = "secs", "nsecs"
    else:
        raise InvalidMessage(f"{path}.sec", "missing")
    sec, nsec = stamp.get(sec_key), stamp.get(nsec_key, 0)
    for key, value in ((sec_key, sec), (nsec_key, nsec)):
        if type(value) is not int:
            raise InvalidMessage(
                f"{path}.{key}", f"expected an integer, got {type(value).__name__}"
            )
    if not 0 <= nsec < _NS:
        raise InvalidMessage(f"{path}.{nsec_key}", f"out of range [0, 1e9): {nsec}")
    if sec < 0 or sec > 2**40:
        raise InvalidMessage(f"{path}.{sec_key}", f"out of range: {sec}")
    stamp_ns = sec * _NS + nsec
    if stamp_ns == 0:
        raise InvalidMessage(path, "zero stamp (driver clock not set)")
    return stamp_ns


def _yaw(msg: Any, path: str) -> float:
    q = [_number(msg, f"{path}.{k}") for k in ("x", "y", "z", "w")]
    norm = math.sqrt(sum(c * c for c in q))
    if not 0.95 <= norm <= 1.05:
        raise InvalidMessage(path, f"not a unit quaternion (norm {norm:.4g})")
    x, y, z, w = (c / norm for c in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _root(msg: Any) -> dict:
    if not isinstance(msg, dict):
        raise InvalidMessage("message", f"expected an object, got {type(msg).__name__}")
    return msg


# ---------------------------------------------------------------------------- parsers
def parse_laser_scan(msg: Any, max_beams: int = 8192) -> Scan:
    """Validate a ``sensor_msgs/LaserScan`` and return its beams sorted by bearing."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    # float32 fields: round exactly as a bag would store them.
    angle_min = float(np.float32(_number(msg, "angle_min")))
    _number(msg, "angle_max")
    increment = float(np.float32(_number(msg, "angle_increment")))
    range_min = float(np.float32(_number(msg, "range_min")))
    range_max = float(np.float32(_number(msg, "range_max")))
    ranges = _number_array(
        _get(msg, "ranges"), "ranges", max_len=max_beams, non_finite_ok=True, none_ok=True
    )
    n = ranges.size
    if n == 0:
        raise InvalidMessage("ranges", "empty")
    if increment == 0.0:
        raise InvalidMessage("angle_increment", "zero")
    if abs(n * increment) > TWO_PI + abs(increment) + 1e-6:
        raise InvalidMessage(
            "angle_increment", f"{n} beams x {increment} rad exceed one revolution"
        )
    angle_max = float(np.float32(_number(msg, "angle_max")))
    span_error = abs(angle_min + (n - 1) * increment - angle_max)
    if span_error > 1.01 * abs(increment) + 1e-6:
        raise InvalidMessage(
            "angle_max",
            f"inconsistent with {n} beams from angle_min at angle_increment "
            f"(off by {span_error:.4g} rad)",
        )
    if range_min < 0.0 or not range_max > range_min:
        raise InvalidMessage(
            "range_max", f"need 0 <= range_min < range_max, got [{range_min}, {range_max}]"
        )
    raw_intensities = _get(msg, "intensities")
    if isinstance(raw_intensities, (list, tuple)) and len(raw_intensities) == 0:
        # No intensities: no return can be classified as a null (interference) return.
        intensities = np.ones(n)
    else:
        intensities = _number_array(raw_intensities, "intensities", max_len=max_beams, exact_len=n)
        intensities = np.float32(intensities).astype(np.float64)
    ranges = ranges.astype(np.float32).astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(ranges) & (ranges >= range_min) & (ranges <= range_max)
    ranges = np.where(valid, ranges, 0.0)
    angles = _beam_angles(angle_min, increment, n)
    order = np.argsort(angles, kind="stable")
    return Scan(stamp_ns, angles[order], ranges[order], intensities[order])


def _beam_angles(angle_min: float, increment: float, n: int) -> np.ndarray:
    """Beam bearings in ``[-pi, pi)``. A full revolution starting at ``-pi`` or ``0`` (to float32
    precision) is snapped to the exact grid ``start + i 2 pi / n``, as the simulator and the
    driver define it; ``float32`` angle fields cannot represent it, and a beam on the edge of a
    blind sector must not change sides between the simulator, the bridge and a replay."""
    if abs(abs(n * increment) - TWO_PI) < 0.5 * abs(increment):
        step = math.copysign(TWO_PI / n, increment)
        for start in (-math.pi, 0.0, math.pi):
            if abs(angle_min - start) < 1e-5:
                angles = start + np.arange(n) * step
                break
        else:
            angles = angle_min + np.arange(n) * step
    else:
        angles = angle_min + np.arange(n) * increment
    inside = (angles >= -math.pi) & (angles < math.pi)
    return np.where(inside, angles, wrap_angle(angles))


def _bounded(msg: Any, path: str, bound: float) -> float:
    """A finite number with ``|value| <= bound`` (physical plausibility)."""
    value = _number(msg, path)
    if abs(value) > bound:
        raise InvalidMessage(path, f"implausible magnitude {value!r} (limit {bound:g})")
    return value


def parse_odometry(msg: Any, max_position_m: float = 1.0e4) -> Odom:
    """Validate a ``nav_msgs/Odometry``: pose in the odom frame, twist in the body frame.
    Positions beyond ``max_position_m`` and speeds beyond :data:`MAX_PLAUSIBLE_SPEED` are
    refused (a finite 1.7e308 must never reach the integration)."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    x = _bounded(msg, "pose.pose.position.x", max_position_m)
    y = _bounded(msg, "pose.pose.position.y", max_position_m)
    yaw = _yaw(msg, "pose.pose.orientation")
    v = _bounded(msg, "twist.twist.linear.x", MAX_PLAUSIBLE_SPEED)
    omega = _bounded(msg, "twist.twist.angular.z", MAX_PLAUSIBLE_SPEED)
    _optional_numbers(msg, "pose.covariance", 36)
    _optional_numbers(msg, "twist.covariance", 36)
    return Odom(stamp_ns, x, y, yaw, v, omega)


def parse_bearings(msg: Any, stamp_ns: int, max_bearings: int = 256) -> Bearings:
    """Validate a ``std_msgs/Float32MultiArray`` of bearings. It has no header: the caller
    supplies ``stamp_ns`` (arrival time on the bridge's ROS clock)."""
    msg = _root(msg)
    data = _number_array(_get(msg, "data"), "data", max_len=max_bearings)
    if "layout" in msg:
        layout = msg["layout"]
        if not isinstance(layout, dict):
            raise InvalidMessage("layout", f"expected an object, got {type(layout).__name__}")
        dims = layout.get("dim", [])
        if not isinstance(dims, list):
            raise InvalidMessage("layout.dim", f"expected an array, got {type(dims).__name__}")
        if dims:
            if not isinstance(dims[0], dict):
                raise InvalidMessage("layout.dim[0]", "expected an object")
            size = dims[0].get("size")
            if type(size) is not int:
                raise InvalidMessage(
                    "layout.dim[0].size", f"expected an integer, got {type(size).__name__}"
                )
            if size != data.size:
                raise InvalidMessage(
                    "layout.dim[0].size", f"says {size} elements, data has {data.size}"
                )
    bearings = wrap_angle(data.astype(np.float32).astype(np.float64))
    return Bearings(stamp_ns, bearings)


def parse_bearings_stamped(msg: Any, max_bearings: int = 256) -> Bearings:
    """Validate a ``swarm_phd_msgs/BearingsStamped`` (``header`` + ``float32[] bearings``): the
    stamp is the camera's exposure time, so motion compensation uses it."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    data = _number_array(_get(msg, "bearings"), "bearings", max_len=max_bearings)
    return Bearings(stamp_ns, wrap_angle(data.astype(np.float32).astype(np.float64)))


def parse_pose_stamped(msg: Any, max_position_m: float = 1.0e4) -> Pose:
    """Validate a ``geometry_msgs/PoseStamped`` (motion capture) and reduce it to x, y, yaw."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    return Pose(
        stamp_ns,
        _bounded(msg, "pose.position.x", max_position_m),
        _bounded(msg, "pose.position.y", max_position_m),
        _yaw(msg, "pose.orientation"),
    )


def parse_message(
    kind: str,
    msg: Any,
    *,
    arrival_ns: int,
    max_beams: int = 8192,
    max_bearings: int = 256,
    max_position_m: float = 1.0e4,
) -> Any:
    """Validate one sensor message of ``kind`` (live and replay share this dispatch).
    ``arrival_ns`` stamps header-less bearings. The UAV's kinds (``uav_pose``,
    ``uav_detections``) give :class:`UAVPose` and :class:`GroundDetections`; a detections
    message holds at most ``max_bearings`` poses (the same per-frame bound as the bearings)."""
    if kind == "lidar":
        return parse_laser_scan(msg, max_beams)
    if kind == "odometry":
        return parse_odometry(msg, max_position_m)
    if kind == "camera":
        return parse_bearings(msg, arrival_ns, max_bearings)
    if kind == "camera_stamped":
        return parse_bearings_stamped(msg, max_bearings)
    if kind == "mocap":
        return parse_pose_stamped(msg, max_position_m)
    if kind == "uav_pose":
        return parse_uav_pose(msg, max_position_m)
    if kind == "uav_detections":
        # Detections are metres from the UAV: the plausibility bound of its altitude range.
        return parse_ground_detections(msg, max_bearings, min(max_position_m, 1.0e3))
    raise ValueError(f"unknown sensor message kind {kind!r}")


def parse_twist(msg: Any) -> tuple[float, float]:
    """Validate a ``geometry_msgs/Twist``; returns ``(v_mps, omega_radps)``. All six components
    must be finite numbers, even the ones a differential drive ignores."""
    msg = _root(msg)
    for part in ("linear", "angular"):
        for axis in ("x", "y", "z"):
            _number(msg, f"{part}.{axis}")
    return _number(msg, "linear.x"), _number(msg, "angular.z")


def parse_twist_stamped(msg: Any) -> tuple[int, float, float]:
    """Validate a ``geometry_msgs/TwistStamped``; returns ``(stamp_ns, v_mps, omega_radps)``."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    v, omega = parse_twist(_get(msg, "twist"))
    return stamp_ns, v, omega


# ---------------------------------------------------------------------------- builders
def header(stamp_ns: int, frame_id: str) -> dict[str, Any]:
    return {
        "stamp": {"sec": int(stamp_ns // _NS), "nanosec": int(stamp_ns % _NS)},
        "frame_id": frame_id,
    }


def _quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(0.5 * yaw), "w": math.cos(0.5 * yaw)}


def twist_msg(v_mps: float, omega_radps: float) -> dict[str, Any]:
    return {
        "linear": {"x": float(v_mps), "y": 0.0, "z": 0.0},
        "angular": {"x": 0.0, "y": 0.0, "z": float(omega_radps)},
    }


def twist_stamped_msg(
    stamp_ns: int, v_mps: float, omega_radps: float, frame_id: str = "base_link"
) -> dict[str, Any]:
    """A ``TwistStamped``: the stamp is the send time, so the robot can refuse a late command."""
    return {"header": header(stamp_ns, frame_id), "twist": twist_msg(v_mps, omega_radps)}


def laser_scan_msg(
    stamp_ns: int,
    angles_rad: np.ndarray,
    ranges_m: np.ndarray,
    intensities: np.ndarray,
    *,
    range_min_m: float,
    range_max_m: float,
    scan_time_s: float,
    frame_id: str,
) -> dict[str, Any]:
    """A LaserScan from evenly spaced, increasing beams (as the simulator produces them)."""
    angles = np.asarray(angles_rad, dtype=np.float64)
    n = angles.size
    increment = (angles[-1] - angles[0]) / (n - 1) if n > 1 else TWO_PI
    return {
        "header": header(stamp_ns, frame_id),
        "angle_min": float(np.float32(angles[0])),
        "angle_max": float(np.float32(angles[-1])),
        "angle_increment": float(np.float32(increment)),
        "time_increment": float(np.float32(scan_time_s / max(n, 1))),
        "scan_time": float(np.float32(scan_time_s)),
        "range_min": float(np.float32(range_min_m)),
        "range_max": float(np.float32(range_max_m)),
        "ranges": np.asarray(ranges_m, dtype=np.float32).tolist(),
        "intensities": np.asarray(intensities, dtype=np.float32).tolist(),
    }


def odometry_msg(
    stamp_ns: int,
    x_m: float,
    y_m: float,
    yaw_rad: float,
    v_mps: float,
    omega_radps: float,
    *,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
) -> dict[str, Any]:
    return {
        "header": header(stamp_ns, frame_id),
        "child_frame_id": child_frame_id,
        "pose": {
            "pose": {
                "position": {"x": float(x_m), "y": float(y_m), "z": 0.0},
                "orientation": _quaternion(float(yaw_rad)),
            },
            "covariance": [0.0] * 36,
        },
        "twist": {
            "twist": {
                "linear": {"x": float(v_mps), "y": 0.0, "z": 0.0},
                "angular": {"x": 0.0, "y": 0.0, "z": float(omega_radps)},
            },
            "covariance": [0.0] * 36,
        },
    }


def bearings_msg(bearings_rad: np.ndarray) -> dict[str, Any]:
    data = np.asarray(bearings_rad, dtype=np.float32).reshape(-1).tolist()
    return {
        "layout": {
            "dim": [{"label": "bearing", "size": len(data), "stride": len(data)}],
            "data_offset": 0,
        },
        "data": data,
    }


def bearings_stamped_msg(
    stamp_ns: int, bearings_rad: np.ndarray, frame_id: str = "camera"
) -> dict[str, Any]:
    data = np.asarray(bearings_rad, dtype=np.float32).reshape(-1).tolist()
    return {"header": header(stamp_ns, frame_id), "bearings": data}


def pose_stamped_msg(
    stamp_ns: int, x_m: float, y_m: float, yaw_rad: float, frame_id: str = "mocap"
) -> dict[str, Any]:
    return {
        "header": header(stamp_ns, frame_id),
        "pose": {
            "position": {"x": float(x_m), "y": float(y_m), "z": 0.0},
            "orientation": _quaternion(float(yaw_rad)),
        },
    }


# ---------------------------------------------------------------------------- counters
class Counters:
    """Thread-safe event counters (``"lidar.invalid"``, ``"transport.reconnects"``, ...), with
    rate-limited logging of rejected messages (the first 5 of a kind, then every 100th)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = defaultdict(int)

    def incr(self, key: str, n: int = 1) -> int:
        with self._lock:
            self._counts[key] += n
            return self._counts[key]

    def get(self, key: str) -> int:
        with self._lock:
            return self._counts.get(key, 0)

    def total(self, suffix: str) -> int:
        """Sum of every counter whose key ends with ``suffix`` (e.g. ``".invalid"``)."""
        with self._lock:
            return sum(v for k, v in self._counts.items() if k.endswith(suffix))

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(sorted(self._counts.items()))

    def reject(self, key: str, detail: str) -> None:
        n = self.incr(key)
        if n <= 5 or n % 100 == 0:
            LOGGER.warning("rejected message (%s, #%d): %s", key, n, detail[:300])


# ------------------------------------------------------------- the UAV (Stegagno 2013 study)
# The supervisor's two topics: its pose estimate (the Stegagno 2013 study's optical flow + IMU +
# height sensor; ``z`` is the altitude above the ground) and its downward camera's anonymous UGV
# positions, already back-projected to the ground and expressed in its level frame (x forward, y
# left, the UAV's yaw; roll and pitch compensated, Stegagno 2013 eqs. 2-4), one ``PoseArray`` per
# frame.
UAV_ROS_TYPES = {
    "uav_pose": "geometry_msgs/PoseStamped",
    "uav_detections": "geometry_msgs/PoseArray",
}
UAV_BAG_TYPES = {key: value.replace("/", "/msg/", 1) for key, value in UAV_ROS_TYPES.items()}
#: Plausible UAV altitude range (m): refuses a sonar's 0 and corrupt values.
MAX_PLAUSIBLE_ALTITUDE_M = 1000.0


#: The UAV's sensor kinds (its command topic is ``uav_cmd_topic``).
UAV_KINDS = ("uav_pose", "uav_detections")


def uav_topics(uav: str) -> dict[str, str]:
    """The ROS topics of one UAV's sensors, by message kind (see :data:`UAV_ROS_TYPES`)."""
    uav = check_robot_id(uav)
    return {"uav_pose": f"/{uav}/pose", "uav_detections": f"/{uav}/camera/detections"}


def uav_cmd_topic(uav: str) -> str:
    """The UAV's velocity command topic: ``Twist`` / ``TwistStamped`` (as the UGVs' commands)
    with ``linear.x, linear.y`` the planar velocity in its body frame (m/s), ``linear.z`` the
    climb rate (m/s) and ``angular.z`` the yaw rate (rad/s). A zero command is a hover."""
    return f"/{check_robot_id(uav)}/cmd_vel"


def uav_twist_msg(command: np.ndarray) -> dict[str, Any]:
    """A UAV ``Twist`` from ``[vx, vy, yaw_rate, climb]`` (the env's UAV command order)."""
    vx, vy, yaw_rate, climb = (float(v) for v in np.asarray(command, dtype=float).reshape(4))
    return {
        "linear": {"x": vx, "y": vy, "z": climb},
        "angular": {"x": 0.0, "y": 0.0, "z": yaw_rate},
    }


def uav_twist_stamped_msg(
    stamp_ns: int, command: np.ndarray, frame_id: str = "base_link"
) -> dict[str, Any]:
    return {"header": header(stamp_ns, frame_id), "twist": uav_twist_msg(command)}


def parse_uav_twist(msg: Any) -> tuple[int | None, np.ndarray]:
    """Validate a UAV ``Twist`` or ``TwistStamped`` (a ``header`` says which); returns
    ``(stamp_ns or None, [vx, vy, yaw_rate, climb])``. Every component must be a finite number
    below :data:`MAX_PLAUSIBLE_SPEED`."""
    msg = _root(msg)
    stamp_ns = None
    if "header" in msg:
        stamp_ns = parse_stamp(msg)
        msg = _root(_get(msg, "twist"))
    for part in ("linear", "angular"):
        for axis in ("x", "y", "z"):
            _bounded(msg, f"{part}.{axis}", MAX_PLAUSIBLE_SPEED)
    return stamp_ns, np.array(
        [
            _number(msg, "linear.x"),
            _number(msg, "linear.y"),
            _number(msg, "angular.z"),
            _number(msg, "linear.z"),
        ]
    )


@dataclass(frozen=True, slots=True)
class UAVPose:
    """A validated UAV ``geometry_msgs/PoseStamped``: planar pose in its odometry frame, altitude
    above the ground (m) and yaw."""

    stamp_ns: int
    x_m: float
    y_m: float
    altitude_m: float
    yaw_rad: float


@dataclass(frozen=True, slots=True)
class GroundDetections:
    """A validated ``geometry_msgs/PoseArray`` of anonymous ground positions ``(M, 2)`` (m) in
    the UAV's level frame, stamped at the exposure."""

    stamp_ns: int
    points_m: np.ndarray


def parse_uav_pose(msg: Any, max_position_m: float = 1.0e4) -> UAVPose:
    """Validate a UAV pose: finite position within ``max_position_m``, altitude in
    ``(0, MAX_PLAUSIBLE_ALTITUDE_M]``, unit quaternion (reduced to yaw; the detections are
    already roll/pitch compensated)."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    altitude = _bounded(msg, "pose.position.z", MAX_PLAUSIBLE_ALTITUDE_M)
    if altitude <= 0.0:
        raise InvalidMessage("pose.position.z", f"altitude must be > 0, got {altitude!r}")
    return UAVPose(
        stamp_ns,
        _bounded(msg, "pose.position.x", max_position_m),
        _bounded(msg, "pose.position.y", max_position_m),
        altitude,
        _yaw(msg, "pose.orientation"),
    )


def parse_ground_detections(
    msg: Any, max_detections: int = 256, max_position_m: float = 1.0e3
) -> GroundDetections:
    """Validate a ``geometry_msgs/PoseArray`` of detections: at most ``max_detections`` poses,
    each ``position.x`` / ``position.y`` a finite number within ``max_position_m`` (``z`` and
    the orientation, when present, must be numbers too; they are not used)."""
    msg = _root(msg)
    stamp_ns = parse_stamp(msg)
    poses = _get(msg, "poses")
    if not isinstance(poses, list):
        raise InvalidMessage("poses", f"expected an array, got {type(poses).__name__}")
    if len(poses) > max_detections:
        raise InvalidMessage("poses", f"too long: {len(poses)} elements > {max_detections}")
    points = np.empty((len(poses), 2))
    for k, pose in enumerate(poses):
        path = f"poses[{k}]"
        if not isinstance(pose, dict):
            raise InvalidMessage(path, f"expected an object, got {type(pose).__name__}")
        try:
            points[k, 0] = _bounded(pose, "position.x", max_position_m)
            points[k, 1] = _bounded(pose, "position.y", max_position_m)
        except InvalidMessage as exc:
            raise InvalidMessage(f"{path}.{exc.field}", exc.reason) from None
        for optional in ("position.z", "orientation.x", "orientation.y", "orientation.z"):
            try:
                _number(pose, optional)
            except InvalidMessage as exc:
                if exc.reason != "missing":
                    raise InvalidMessage(f"{path}.{exc.field}", exc.reason) from None
    return GroundDetections(stamp_ns, points)


def uav_pose_msg(
    stamp_ns: int,
    x_m: float,
    y_m: float,
    altitude_m: float,
    yaw_rad: float,
    frame_id: str = "odom",
) -> dict[str, Any]:
    return {
        "header": header(stamp_ns, frame_id),
        "pose": {
            "position": {"x": float(x_m), "y": float(y_m), "z": float(altitude_m)},
            "orientation": _quaternion(float(yaw_rad)),
        },
    }


def ground_detections_msg(
    stamp_ns: int, points_m: np.ndarray, frame_id: str = "uav_level"
) -> dict[str, Any]:
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    return {
        "header": header(stamp_ns, frame_id),
        "poses": [
            {
                "position": {"x": float(x), "y": float(y), "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            }
            for x, y in pts
        ],
    }
