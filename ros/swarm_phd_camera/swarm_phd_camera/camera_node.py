"""ROS 2 node: a robot's two fisheye frames in, its teammates' red-strip bearings out.

Subscribes (in the robot's namespace) to ``camera/front/image_raw`` and ``camera/back/image_raw``
(``sensor_msgs/Image``, 8-bit colour), pairs frames whose stamps are within
``max_pair_skew_s``, and publishes ``camera/bearings_stamped``
(``swarm_phd_msgs/BearingsStamped``): the bearings of the red blobs in the robot frame
(REP-103), stamped with the frames' exposure time (the mean of the pair's header stamps, which
camera drivers set at capture). The image work is the library's
:func:`swarm_core.perception.fisheye_bearings.pair_bearings`; this file only moves messages.

A malformed image (wrong encoding, size or buffer) or an unusable frame (dark, saturated,
flooded with red) is counted and logged (rate-limited), never raised: the node keeps running
and publishes what the other lens sees. The counts (pairs, published, malformed, dropped per
reason) are logged every ``stats_period_s`` (10 s).

Parameters: ``front_calibration``, ``back_calibration`` (YAML files, see
``config/front.example.yaml``), ``frame_id`` (the robot's body frame), ``max_pair_skew_s``
(0.02), and the colour thresholds of :class:`RedBlobConfig` under the same names
(``hue_max_low``, ``hue_min_high``, ``saturation_min``, ``value_min``, ``min_area_px``,
``max_elevation_deg``).
"""

from __future__ import annotations

import collections
import sys

import message_filters
import yaml
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from swarm_phd_msgs.msg import BearingsStamped

from swarm_core.perception.fisheye_bearings import (
    FisheyeCalibration,
    FrameError,
    RedBlobConfig,
    decode_image,
    pair_bearings,
)
from swarm_core.ros_node import run_node

_NS = 1_000_000_000
_INT_PARAMS = ("hue_max_low", "hue_min_high", "saturation_min", "value_min", "min_area_px")
_FLOAT_PARAMS = ("max_elevation_deg",)


def load_calibration(path: str, where: str) -> FisheyeCalibration:
    """A lens calibration from its YAML file; errors name the file and the field."""
    try:
        with open(path, encoding="utf-8") as handle:
            data = yaml.safe_load(handle)
    except OSError as exc:
        raise FrameError(f"{where}: cannot read {path!r}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise FrameError(f"{where}: {path!r} is not valid YAML: {exc}") from None
    return FisheyeCalibration.from_dict(data, where=f"{where} ({path})")


class CameraNode(Node):
    def __init__(self) -> None:
        super().__init__("swarm_phd_camera")
        defaults = RedBlobConfig()
        self.declare_parameter("front_calibration", "")
        self.declare_parameter("back_calibration", "")
        self.declare_parameter("frame_id", "base_link")
        self.declare_parameter("max_pair_skew_s", 0.02)
        self.declare_parameter("stats_period_s", 10.0)
        for name in _INT_PARAMS + _FLOAT_PARAMS:
            self.declare_parameter(name, getattr(defaults, name))
        param = self.get_parameter
        self.config = RedBlobConfig(**{n: param(n).value for n in _INT_PARAMS + _FLOAT_PARAMS})
        self.lenses = tuple(
            load_calibration(param(f"{lens}_calibration").value, f"{lens}_calibration")
            for lens in ("front", "back")
        )
        self.frame_id = param("frame_id").value
        self.counts: collections.Counter[str] = collections.Counter()
        self.publisher = self.create_publisher(BearingsStamped, "camera/bearings_stamped", 10)
        subs = [
            message_filters.Subscriber(
                self, Image, f"camera/{lens}/image_raw", qos_profile=qos_profile_sensor_data
            )
            for lens in ("front", "back")
        ]
        self.sync = message_filters.ApproximateTimeSynchronizer(
            subs, queue_size=4, slop=float(param("max_pair_skew_s").value)
        )
        self.sync.registerCallback(self.on_pair)
        self.create_timer(float(param("stats_period_s").value), self.log_stats)

    def on_pair(self, front: Image, back: Image) -> None:
        self.counts["pairs"] += 1
        try:
            images = tuple(
                decode_image(m.height, m.width, m.encoding, m.step, m.data) for m in (front, back)
            )
            result = pair_bearings(images, self.lenses, self.config)
        except FrameError as exc:
            self.counts["malformed"] += 1
            if self.counts["malformed"] <= 5 or self.counts["malformed"] % 100 == 0:
                self.get_logger().warning(f"dropped a frame pair: {exc}")
            return
        for reason in result.dropped:
            self.counts[f"dropped_{reason}"] += 1
        stamps = [m.header.stamp.sec * _NS + m.header.stamp.nanosec for m in (front, back)]
        exposure_ns = sum(stamps) // 2
        msg = BearingsStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(exposure_ns, _NS)
        msg.header.frame_id = self.frame_id
        msg.bearings = [float(b) for b in result.bearings_rad]
        self.publisher.publish(msg)
        self.counts["published"] += 1

    def log_stats(self) -> None:
        self.get_logger().info(
            "frames: " + ", ".join(f"{k} {v}" for k, v in sorted(self.counts.items()))
        )


def main(argv: list[str] | None = None) -> int:
    # a bad calibration or parameter: said on stderr, status 2
    return run_node(CameraNode, "swarm_phd_camera", FrameError, argv)


if __name__ == "__main__":
    sys.exit(main())
