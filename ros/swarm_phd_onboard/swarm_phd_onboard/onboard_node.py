"""ROS 2 node: one robot's localizer on board, from its own topics.

In the robot's namespace it subscribes to ``scan`` (``sensor_msgs/LaserScan``), ``odom``
(``nav_msgs/Odometry``) and ``camera/bearings_stamped`` (``swarm_phd_msgs/BearingsStamped``),
validates each message with the bridge's parsers (:mod:`hardware_bridge.messages`, the rules the
bridge applies: a malformed message is counted and dropped), steps
:class:`hardware_bridge.onboard.OnBoardFilter` at ``rate_hz`` (10 Hz, the swarm's control rate)
and publishes ``swarm_phd/estimate`` (``swarm_phd_msgs/EstimateStamped``), the robot's teammate
mixture in its body frame.

Parameters: ``robot`` (its id, e.g. ``ugv_3``; default: the namespace), ``localizer``
(``phd-lc``; one of ``hardware_bridge.onboard.ONBOARD_FAMILIES``), ``preset`` (the swarm preset
whose sensor and filter configuration the robot uses, ``sim-6m-20``), ``rate_hz``.
"""

from __future__ import annotations

import collections
import sys

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rosidl_runtime_py.convert import message_to_ordereddict
from rosidl_runtime_py.set_message import set_message_fields
from sensor_msgs.msg import LaserScan
from swarm_phd_msgs.msg import BearingsStamped, EstimateStamped

from hardware_bridge.messages import (
    InvalidMessage,
    parse_bearings_stamped,
    parse_laser_scan,
    parse_odometry,
)
from hardware_bridge.onboard import OnBoardFilter
from swarm_core.ros_node import run_node
from swarm_env.config import make_config


def plain(value):
    """A converted ROS message as the rosbridge JSON the parsers read: arrays as lists."""
    if isinstance(value, dict):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if hasattr(value, "tolist"):  # array.array, numpy arrays
        return value.tolist()
    return value


class OnBoardNode(Node):
    def __init__(self) -> None:
        super().__init__("swarm_phd_onboard")
        self.declare_parameter("robot", self.get_namespace().strip("/") or "ugv_0")
        self.declare_parameter("localizer", "phd-lc")
        self.declare_parameter("preset", "sim-6m-20")
        self.declare_parameter("rate_hz", 10.0)
        param = self.get_parameter
        config = make_config(param("preset").value)
        self.filter = OnBoardFilter(param("robot").value, config, param("localizer").value)
        self.counts: collections.Counter[str] = collections.Counter()
        self.publisher = self.create_publisher(EstimateStamped, "swarm_phd/estimate", 10)
        qos = qos_profile_sensor_data
        for kind, msg_type, topic, parse in (
            ("lidar", LaserScan, "scan", parse_laser_scan),
            ("odometry", Odometry, "odom", parse_odometry),
            ("camera", BearingsStamped, "camera/bearings_stamped", parse_bearings_stamped),
        ):
            self.create_subscription(
                msg_type, topic, lambda m, k=kind, p=parse: self.on_message(k, p, m), qos
            )
        self.create_timer(1.0 / float(param("rate_hz").value), self.on_tick)

    def on_message(self, kind, parse, msg) -> None:
        try:
            self.filter.add(parse(plain(message_to_ordereddict(msg))))
            self.counts[kind] += 1
        except InvalidMessage as exc:
            self.counts[f"{kind}.invalid"] += 1
            if self.counts[f"{kind}.invalid"] <= 5:
                self.get_logger().warning(f"{kind}: dropped an invalid message: {exc}")

    def on_tick(self) -> None:
        now = self.get_clock().now().nanoseconds
        estimate = self.filter.step(now)
        msg = EstimateStamped()
        set_message_fields(msg, estimate)
        self.publisher.publish(msg)


def main(argv: list[str] | None = None) -> int:
    # a bad robot id, family or preset: said on stderr, status 2
    return run_node(OnBoardNode, "swarm_phd_onboard", ValueError, argv)


if __name__ == "__main__":
    sys.exit(main())
