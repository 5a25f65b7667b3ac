"""Message validation and conversion, command limits, configuration: no network."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from hardware_bridge.assembly import RecordAssembler, odometry_increment
from hardware_bridge.config import BridgeConfig, make_bridge_config
from hardware_bridge.messages import (
    Counters,
    InvalidMessage,
    Odom,
    Pose,
    bearings_msg,
    laser_scan_msg,
    ns_to_s,
    odometry_msg,
    parse_bearings,
    parse_laser_scan,
    parse_odometry,
    parse_pose_stamped,
    parse_twist,
    pose_stamped_msg,
    twist_msg,
)
from hardware_bridge.safety import CommandLimiter
from hardware_bridge.transport import check_host
from swarm_core.world import relative_positions
from swarm_env.config import RobotConfig, make_config
from swarm_env.sensors.lidar import LidarSensor

STAMP = 1_700_000_000_123_456_789


def scan(n=720, **changes):
    angles = -np.pi + np.arange(n) * (2 * np.pi / n)
    ranges = np.full(n, 2.0)
    ranges[10:14] = 0.0
    intensities = np.full(n, 800.0)
    intensities[10:12] = 0.0
    msg = laser_scan_msg(
        STAMP,
        angles,
        ranges,
        intensities,
        range_min_m=0.12,
        range_max_m=10.0,
        scan_time_s=1 / 7,
        frame_id="laser",
    )
    msg.update(changes)
    return msg


def odom(x=1.0, y=2.0, yaw=0.5, v=0.1, w=0.2, stamp=STAMP):
    return odometry_msg(stamp, x, y, yaw, v, w)


# ---------------------------------------------------------------------------- valid messages
def test_valid_messages_parse_with_header_stamp_and_yaw():
    s = parse_laser_scan(scan())
    assert s.stamp_ns == STAMP and ns_to_s(s.stamp_ns) == pytest.approx(1_700_000_000.123456789)
    assert s.angles_rad.shape == (720,) and np.all(np.diff(s.angles_rad) > 0)
    assert s.angles_rad[0] >= -np.pi and s.angles_rad[-1] < np.pi
    o = parse_odometry(odom(yaw=-2.5))
    assert (o.x_m, o.y_m) == (1.0, 2.0) and o.yaw_rad == pytest.approx(-2.5)
    assert (o.v_mps, o.omega_radps) == (0.1, 0.2)
    p = parse_pose_stamped(pose_stamped_msg(STAMP, 0.5, -0.5, 3.0))
    assert (p.x_m, p.y_m) == (0.5, -0.5) and p.yaw_rad == pytest.approx(3.0)
    b = parse_bearings(bearings_msg([0.1, -3.0, 3.5]), STAMP)
    assert b.bearings_rad == pytest.approx([0.1, -3.0, 3.5 - 2 * np.pi], abs=1e-6)
    assert parse_twist(twist_msg(0.2, -1.0)) == (0.2, -1.0)


def test_ros1_stamps_are_accepted():
    msg = pose_stamped_msg(STAMP, 0.0, 0.0, 0.0)
    msg["header"]["stamp"] = {"secs": 5, "nsecs": 7}
    assert parse_pose_stamped(msg).stamp_ns == 5_000_000_007


def test_scan_angles_match_the_simulator_grid_so_blind_sectors_agree():
    """The float32 angle fields are snapped back to the exact beam grid of the sim's lidar."""
    sensor = LidarSensor(make_config("seed-lab").lidar, 1)
    s = parse_laser_scan(scan())
    assert np.array_equal(s.angles_rad, sensor.angles_rad)
    assembler = RecordAssembler(["a"], make_config("seed-lab", n_robots=1))
    assert np.array_equal(assembler.blind_mask(s.angles_rad), sensor.blind_mask)


def test_scan_rep117_no_returns_become_zero_and_nulls_are_kept():
    msg = scan()
    msg["ranges"][0] = None  # rosbridge's encoding of NaN/inf in some versions
    msg["ranges"][1] = math.inf
    msg["ranges"][2] = math.nan
    msg["ranges"][3] = 0.05  # below range_min
    msg["ranges"][4] = 50.0  # above range_max
    s = parse_laser_scan(json.loads(json.dumps(msg)))
    assert np.all(s.ranges_m[:5] == 0.0) and np.all(np.isfinite(s.ranges_m))
    assert np.count_nonzero((s.ranges_m == 0) & (s.intensities == 0)) == 2


def test_scan_from_zero_to_two_pi_is_reordered_to_minus_pi_pi():
    n = 8
    msg = laser_scan_msg(
        STAMP,
        np.arange(n) * 2 * np.pi / n,
        np.arange(1, n + 1, dtype=float),
        np.ones(n),
        range_min_m=0.1,
        range_max_m=20.0,
        scan_time_s=0.1,
        frame_id="l",
    )
    s = parse_laser_scan(msg)
    assert np.all(np.diff(s.angles_rad) > 0)
    # The beam at +pi/2 (index 2) keeps its range after reordering.
    k = int(np.argmin(np.abs(s.angles_rad - np.pi / 2)))
    assert s.ranges_m[k] == 3.0


def test_empty_intensities_mean_no_null_returns():
    msg = scan(intensities=[])
    s = parse_laser_scan(msg)
    assert np.all(s.intensities == 1.0)


# ---------------------------------------------------------------------------- invalid messages
def _mutate(msg, path, value):
    msg = copy.deepcopy(msg)
    node = msg
    keys = path.split(".")
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node[key]
    last = keys[-1]
    if value is KeyError:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return msg


@pytest.mark.parametrize(
    "path,value,field",
    [
        ("angle_increment", math.nan, "angle_increment"),  # NaN
        ("angle_min", math.inf, "angle_min"),  # inf
        ("angle_increment", "0.0087", "angle_increment"),  # string number
        ("angle_increment", True, "angle_increment"),  # bool is not a number
        ("angle_increment", 0.0, "angle_increment"),  # degenerate
        ("angle_max", 1.0, "angle_max"),  # inconsistent with the beams
        ("ranges.3", "1.0", "ranges"),  # wrong element type
        ("ranges", "not an array", "ranges"),  # wrong container type
        ("ranges", [], "ranges"),  # empty
        ("header", KeyError, "header"),  # missing
        ("header.stamp.sec", 1.5, "header.stamp.sec"),  # float seconds
        ("header.stamp.nanosec", 2_000_000_000, "header.stamp.nanosec"),
        ("header.stamp", {"sec": 0, "nanosec": 0}, "header.stamp"),  # unset clock
        ("range_max", 0.01, "range_max"),  # max < min
    ],
)
def test_invalid_scans_are_rejected_naming_the_field(path, value, field):
    with pytest.raises(InvalidMessage) as err:
        parse_laser_scan(_mutate(scan(), path, value))
    assert err.value.field == field


def test_scan_wrong_lengths_are_rejected():
    msg = scan()
    msg["intensities"] = msg["intensities"][:-1]
    with pytest.raises(InvalidMessage, match="intensities"):
        parse_laser_scan(msg)
    with pytest.raises(InvalidMessage, match="too long"):
        parse_laser_scan(scan(n=720), max_beams=500)
    with pytest.raises(InvalidMessage, match="message"):
        parse_laser_scan([1, 2, 3])


@pytest.mark.parametrize(
    "path,value",
    [
        ("pose.pose.position.x", math.nan),
        ("pose.pose.position.y", "1"),
        ("pose.pose.orientation.w", None),
        ("pose.pose.orientation", {"x": 0.0, "y": 0.0, "z": 0.0, "w": 3.0}),  # not unit
        ("twist.twist.angular.z", math.inf),
        ("pose.covariance", [0.0] * 35),  # wrong length
        ("twist.covariance", [0.0] * 35 + ["x"]),  # wrong type
        ("twist", KeyError),
    ],
)
def test_invalid_odometry_is_rejected(path, value):
    with pytest.raises(InvalidMessage):
        parse_odometry(_mutate(odom(), path, value))


@pytest.mark.parametrize(
    "msg",
    [
        {"data": [0.1, math.nan]},
        {"data": [0.1, "0.2"]},
        {"data": 0.1},
        {"data": [0.1, 0.2], "layout": {"dim": [{"label": "b", "size": 3, "stride": 3}]}},
        {"data": [0.1] * 300},
        {"layout": {"dim": []}},
    ],
)
def test_invalid_bearings_are_rejected(msg):
    with pytest.raises(InvalidMessage):
        parse_bearings(msg, STAMP, max_bearings=256)


@pytest.mark.parametrize(
    "bad",
    [
        {"linear": {"x": math.nan, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
        {"linear": {"x": 0.1, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": "1"}},
        {"linear": {"x": 0.1, "y": 0.0, "z": 0.0}},
        {"linear": {"x": 0.1, "y": 0.0, "z": math.inf}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
    ],
)
def test_invalid_twists_are_rejected(bad):
    with pytest.raises(InvalidMessage):
        parse_twist(bad)


def test_counters_count_rejections():
    c = Counters()
    c.reject("lidar.invalid", "x")
    c.reject("lidar.invalid", "y")
    c.incr("transport.malformed")
    assert c.get("lidar.invalid") == 2 and c.total(".invalid") == 2
    assert c.snapshot() == {"lidar.invalid": 2, "transport.malformed": 1}


# ---------------------------------------------------------------------------- conversions
def test_odometry_increment_is_in_the_robot_frame_at_interval_start():
    """A robot at yaw 90 deg moving +y in the odom frame moved *forward* in its own frame."""
    prev = Odom(1, 1.0, 1.0, np.pi / 2, 0.0, 0.0)
    cur = Odom(2, 1.0, 1.2, np.pi / 2 + 0.1, 0.0, 0.0)
    assert odometry_increment(prev, cur) == pytest.approx([0.2, 0.0, 0.1])
    # Heading change wraps across +-pi.
    prev = Odom(1, 0.0, 0.0, 3.1, 0.0, 0.0)
    cur = Odom(2, 0.0, 0.0, -3.1, 0.0, 0.0)
    assert odometry_increment(prev, cur)[2] == pytest.approx(2 * np.pi - 6.2)


def test_assembler_odometry_baseline_then_increments_compose_to_the_pose():
    config = make_config("seed-lab", n_robots=1)
    assembler = RecordAssembler(["r"], config)
    rng = np.random.default_rng(0)
    poses = np.cumsum(rng.normal(0, 0.05, (20, 3)), axis=0)
    msgs = [parse_odometry(odom(*p, stamp=STAMP + k * 100_000_000)) for k, p in enumerate(poses)]
    assert assembler.odometry("r", msgs[:1]) == []  # baseline only
    records = assembler.odometry("r", msgs[1:])
    assert len(records) == 19
    # Compose the increments: must land on the last pose.
    x, y, yaw = poses[0]
    for r in records:
        dx, dy, dpsi = r.delta
        x, y = x + np.cos(yaw) * dx - np.sin(yaw) * dy, y + np.sin(yaw) * dx + np.cos(yaw) * dy
        yaw += dpsi
    assert (x, y) == pytest.approx(tuple(poses[-1, :2]))
    assert np.angle(np.exp(1j * (yaw - poses[-1, 2]))) == pytest.approx(0.0, abs=1e-9)


def test_assembler_truth_from_mocap_matches_the_sim_convention():
    config = make_config("seed-lab", n_robots=2)
    assembler = RecordAssembler(["a", "b"], config)
    assert assembler.truth({"a": Pose(1, 0.0, 0.0, 0.0), "b": None}) is None
    truth = assembler.truth({"a": Pose(1, 0.0, 0.0, np.pi / 2), "b": Pose(1, 1.0, 0.0, 0.0)})
    # b is 1 m along world x = to the right (-y) of a, who faces world +y.
    assert truth.relative_xy[0, 1] == pytest.approx([0.0, -1.0])
    assert np.array_equal(truth.relative_xy, relative_positions(truth.poses, truth.poses))
    assert truth.in_range["lidar"][0, 1] and not truth.in_range["lidar"][0, 0]


# ---------------------------------------------------------------------------- limits
def _limiter(**bridge):
    return CommandLimiter(["a", "b"], BridgeConfig(**bridge), RobotConfig(), 0.1, Counters())


def test_velocity_and_acceleration_limits():
    lim = _limiter()
    out = lim.limit(np.array([[5.0, -9.0], [0.1, 0.0]]), {})
    # Clipped to 0.3 m/s / 1.5 rad/s, then at most a_max * dt = 0.06 m/s, 0.6 rad/s per step.
    assert out[0] == pytest.approx([0.06, -0.6])
    for _ in range(10):
        out = lim.limit(np.array([[5.0, -9.0], [0.1, 0.0]]), {})
    assert out[0] == pytest.approx([0.3, -1.5]) and out[1] == pytest.approx([0.1, 0.0])
    lim.stopped()
    assert lim.limit(np.array([[0.3, 0.0], [0.0, 0.0]]), {})[0] == pytest.approx([0.06, 0.0])
    with pytest.raises(ValueError):
        lim.limit(np.array([[np.nan, 0.0], [0.0, 0.0]]), {})
    assert _limiter(max_speed_mps=0.1).v_max == 0.1


def test_geofence_blocks_driving_out_allows_driving_back_and_stops_without_pose():
    lim = _limiter(geofence_m=(-1.0, 1.0, -1.0, 1.0), max_accel_mps2=100.0)
    cmd = np.array([[0.2, 0.5], [0.2, 0.5]])
    inside = Pose(1, 0.0, 0.0, 0.0)
    out_facing_out = Pose(1, 1.2, 0.0, 0.0)  # beyond x_max, facing +x
    assert lim.limit(cmd, {"a": inside, "b": out_facing_out}).tolist() == [[0.2, 0.5], [0.0, 0.5]]
    out_facing_in = Pose(1, 1.2, 0.0, np.pi)  # beyond x_max, facing back in
    assert lim.limit(cmd, {"a": inside, "b": out_facing_in})[1] == pytest.approx([0.2, 0.5])
    reversing_out = np.array([[0.2, 0.5], [-0.2, 0.5]])
    assert lim.limit(reversing_out, {"a": inside, "b": out_facing_in})[1, 0] == 0.0
    assert lim.limit(cmd, {"a": inside, "b": None})[1].tolist() == [0.0, 0.0]


# ---------------------------------------------------------------------------- config
def test_bridge_config_validation():
    assert make_bridge_config({"watchdog_timeout_s": 0.3}).watchdog_timeout_s == 0.3
    with pytest.raises(ValueError, match="unknown bridge config"):
        make_bridge_config({"watchdog_timeout": 0.3})
    with pytest.raises(ValueError, match="watchdog_timeout_s"):
        BridgeConfig(watchdog_timeout_s=-1.0)
    with pytest.raises(ValueError, match="geofence"):
        BridgeConfig(geofence_m=(1.0, -1.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="required_sensors"):
        BridgeConfig(required_sensors=("sonar",))
    with pytest.raises(ValueError, match="queue_length"):
        BridgeConfig(queue_length=0)


def test_remote_hosts_need_the_explicit_flag():
    check_host("127.0.0.1", False)
    check_host("localhost", False)
    with pytest.raises(ValueError, match="allow_remote"):
        check_host("192.168.1.20", False)
    check_host("192.168.1.20", True)


# ---------------------------------------------------------------------------- the ROS 2 package
# ros/swarm_phd_msgs is built by colcon on the robots; here its files are checked against the
# Python definitions the bridge parses, so the two cannot drift apart.

import re  # noqa: E402
import xml.etree.ElementTree as ET  # noqa: E402
from pathlib import Path  # noqa: E402

from hardware_bridge import estimate  # noqa: E402
from hardware_bridge.messages import (  # noqa: E402
    BEARINGS_STAMPED_MSG,
    bearings_stamped_msg,
    parse_bearings_stamped,
)

MSG_PACKAGE = Path(__file__).resolve().parents[2] / "ros" / "swarm_phd_msgs"
_BUILTIN = {
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
}  # fmt: skip


def msg_definition(text):
    """``(fields, constants)`` of ROS 2 .msg text: fields ``[(type, name)]``, constants
    ``[(type, name, value)]``; comments and blank lines dropped."""
    fields, constants = [], []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        kind, rest = line.split(None, 1)
        if "=" in rest:
            name, value = (part.strip() for part in rest.split("=", 1))
            constants.append((kind, name, value))
        else:
            assert " " not in rest.strip(), f"default values are not used here: {raw!r}"
            fields.append((kind, rest.strip()))
    return fields, constants


def json_matches(kind, value):
    """Does a rosbridge JSON value fit the .msg type ``kind``?"""
    if kind.endswith("[]"):
        return isinstance(value, list) and all(json_matches(kind[:-2], v) for v in value)
    if kind in ("float32", "float64"):
        return type(value) in (int, float)
    if kind == "uint8":
        return type(value) is int and 0 <= value <= 255
    if kind == "string":
        return isinstance(value, str)
    if kind == "std_msgs/Header":
        return set(value) == {"stamp", "frame_id"} and set(value["stamp"]) == {"sec", "nanosec"}
    raise AssertionError(f"no JSON rule for {kind}")


PACKAGE_MESSAGES = {
    "BearingsStamped": (
        BEARINGS_STAMPED_MSG,
        bearings_stamped_msg(STAMP, np.array([0.5, -2.0]), frame_id="ugv_3/base_link"),
    ),
    "EstimateStamped": (
        estimate.ESTIMATE_STAMPED_MSG,
        estimate.estimate_stamped_msg(
            STAMP,
            np.array([0.9, 0.2]),
            np.array([[1.0, 0.5], [-0.3, 2.0]]),
            np.array([np.eye(2) * 0.01, [[0.04, 0.01], [0.01, 0.02]]]),
            localizer="phd-lc",
        ),
    ),
}


@pytest.mark.parametrize("name", sorted(PACKAGE_MESSAGES))
def test_msg_files_match_the_python_definitions(name):
    text, built = PACKAGE_MESSAGES[name]
    file_fields, file_constants = msg_definition((MSG_PACKAGE / "msg" / f"{name}.msg").read_text())
    py_fields, py_constants = msg_definition(text)
    assert file_fields == py_fields
    assert file_constants == py_constants
    # rosidl's naming rules: lower snake-case fields, upper-case constants, CamelCase types.
    assert re.fullmatch(r"[A-Z][A-Za-z0-9]*", name)
    for kind, field in file_fields:
        assert re.fullmatch(r"[a-z][a-z0-9]*(_[a-z0-9]+)*", field), field
        base = kind.removesuffix("[]")
        assert base in _BUILTIN or re.fullmatch(r"[a-z][a-z0-9_]*/[A-Z][A-Za-z0-9]*", base), kind
    for _, constant, _ in file_constants:
        assert re.fullmatch(r"[A-Z][A-Z0-9_]*", constant), constant
    # What the bridge builds is exactly the message's fields, each of the right JSON type.
    assert list(built) == [field for _, field in file_fields]
    for kind, field in file_fields:
        assert json_matches(kind, built[field]), (field, built[field])
    json.dumps(built)  # plain JSON for rosbridge


def test_estimate_constants_are_the_python_codes():
    _, constants = msg_definition((MSG_PACKAGE / "msg" / "EstimateStamped.msg").read_text())
    assert {c[1]: int(c[2]) for c in constants} == {
        "WEIGHT_INTENSITY": estimate.WEIGHT_INTENSITY,
        "WEIGHT_EXISTENCE": estimate.WEIGHT_EXISTENCE,
    }


def test_package_builds_every_message_with_its_dependencies():
    """CMakeLists.txt generates every .msg file and depends on every package the messages use;
    package.xml declares the same name and the rosidl build, runtime and group."""
    cmake = (MSG_PACKAGE / "CMakeLists.txt").read_text()
    project = re.search(r"project\((\w+)\)", cmake).group(1)
    call = re.search(r"rosidl_generate_interfaces\(\$\{PROJECT_NAME\}(.*?)\)", cmake, re.S).group(
        1
    )
    listed = re.findall(r'"(msg/\w+\.msg)"', call)
    files = sorted(f"msg/{p.name}" for p in (MSG_PACKAGE / "msg").glob("*.msg"))
    assert sorted(listed) == files == sorted(f"msg/{n}.msg" for n in PACKAGE_MESSAGES)
    used = {
        kind.removesuffix("[]").split("/")[0]
        for f in files
        for kind, _ in msg_definition((MSG_PACKAGE / f).read_text())[0]
        if "/" in kind
    }
    deps = set(re.search(r"DEPENDENCIES\s+([\w\s]+)", call).group(1).split())
    assert used <= deps
    for dep in deps:
        assert f"find_package({dep} REQUIRED)" in cmake
    assert "find_package(rosidl_default_generators REQUIRED)" in cmake
    assert "ament_package()" in cmake
    root = ET.parse(MSG_PACKAGE / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == project == MSG_PACKAGE.name
    tags = {(child.tag, (child.text or "").strip()) for child in root}
    assert ("buildtool_depend", "ament_cmake") in tags
    assert ("buildtool_depend", "rosidl_default_generators") in tags
    assert ("exec_depend", "rosidl_default_runtime") in tags
    assert ("member_of_group", "rosidl_interface_packages") in tags
    for dep in deps:
        assert ("depend", dep) in tags
    assert root.find("export").findtext("build_type") == "ament_cmake"


def test_bearings_stamped_round_trip_keeps_the_exposure_stamp():
    msg = bearings_stamped_msg(STAMP, np.array([0.25, 3.0, -1.0]))
    parsed = parse_bearings_stamped(json.loads(json.dumps(msg)))
    assert parsed.stamp_ns == STAMP
    np.testing.assert_allclose(parsed.bearings_rad, [0.25, 3.0, -1.0], atol=1e-6)


def test_estimate_round_trip_and_bad_estimates_name_the_field():
    w = np.array([0.8, 0.3, 0.05])
    m = np.array([[1.2, -0.4], [0.0, 2.5], [-3.0, 0.1]])
    p = np.array([[[0.02, 0.005], [0.005, 0.03]], np.eye(2) * 0.1, np.eye(2)])
    msg = estimate.estimate_stamped_msg(
        STAMP, w, m, p, localizer="pmb-lc", weight_kind="existence"
    )
    got = estimate.parse_estimate_stamped(json.loads(json.dumps(msg)))
    assert (got.stamp_ns, got.localizer, got.weight_kind) == (STAMP, "pmb-lc", "existence")
    np.testing.assert_array_equal(got.weights, w)
    np.testing.assert_array_equal(got.means_m, m)
    np.testing.assert_array_equal(got.covariances_m2, p)
    empty = estimate.estimate_stamped_msg(STAMP, [], np.zeros((0, 2)), [], localizer="phd-lc")
    assert estimate.parse_estimate_stamped(empty).means_m.shape == (0, 2)
    bad = [
        ("means", lambda d: d.update(means=d["means"][:-1])),
        ("covariances", lambda d: d.update(covariances=d["covariances"] + [0.0])),
        ("weights", lambda d: d["weights"].__setitem__(0, -0.1)),
        ("weights", lambda d: d["weights"].__setitem__(0, "1")),
        ("covariances", lambda d: d["covariances"].__setitem__(1, 0.3)),  # xy != yx
        ("covariances", lambda d: d["covariances"].__setitem__(0, -1.0)),
        ("weight_kind", lambda d: d.update(weight_kind=7)),
        ("localizer", lambda d: d.update(localizer=3)),
        ("header.stamp", lambda d: d["header"].update(stamp={"sec": 0, "nanosec": 0})),
    ]
    for field, corrupt in bad:
        broken = copy.deepcopy(msg)
        corrupt(broken)
        with pytest.raises(InvalidMessage) as info:
            estimate.parse_estimate_stamped(broken)
        assert info.value.field == field, (field, str(info.value))
    with pytest.raises(ValueError, match="means: expected shape"):
        estimate.estimate_stamped_msg(STAMP, w, m[:2], p, localizer="phd-lc")
    with pytest.raises(ValueError, match="weight_kind must be one of"):
        estimate.estimate_stamped_msg(STAMP, w, m, p, localizer="phd-lc", weight_kind="mass")
