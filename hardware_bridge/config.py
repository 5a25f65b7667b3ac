"""Bridge configuration: timing, safety limits, staleness, queues. One frozen dataclass.

Kinematic limits default to ``None`` = the env's :class:`swarm_env.config.RobotConfig` values, so
the bridge never lets through more than the simulator's action space allows.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

SENSORS = ("odometry", "lidar", "camera", "mocap", "estimate")
FEED_SENSORS = ("odometry", "lidar", "camera")


#: Bounds of every number of :class:`BridgeConfig`: ``(low, high, low_inclusive)``. A safety
#: limit outside them (a watchdog that never fires, a stamp window of years, a speed no robot
#: has) is refused when the config is built, before anything connects or moves.
BOUNDS: dict[str, tuple[float, float, bool]] = {
    "watchdog_timeout_s": (0.0, 1.0, False),
    "watchdog_poll_s": (0.001, 0.05, True),
    "watchdog_repeat_s": (0.01, 0.5, True),
    "step_overrun_s": (0.0, 1.0, False),
    "stale_odometry_s": (0.0, 10.0, False),
    "stale_lidar_s": (0.0, 10.0, False),
    "stale_camera_s": (0.0, 10.0, False),
    "stale_mocap_s": (0.0, 10.0, False),
    "stale_uav_s": (0.0, 10.0, False),
    "stale_estimate_s": (0.0, 10.0, False),
    "connect_timeout_s": (0.0, 60.0, False),
    "reset_timeout_s": (0.0, 300.0, False),
    "max_speed_mps": (0.0, 10.0, False),
    "max_turn_rate_radps": (0.0, 20.0, False),
    "max_accel_mps2": (0.0, 1000.0, False),
    "max_turn_accel_radps2": (0.0, 1000.0, False),
    "queue_length": (1, 1000, True),
    "throttle_rate_ms": (0, 10_000, True),
    "buffer_length": (1, 100_000, True),
    "duplicate_window_s": (0.0, 1.0, False),
    "max_beams": (1, 100_000, True),
    "max_bearings": (1, 10_000, True),
    "max_message_bytes": (1, 256 * 1024 * 1024, True),
    "hard_max_message_bytes": (1, 1024 * 1024 * 1024, True),
    "reconnect_initial_delay_s": (0.0, 10.0, False),
    "reconnect_max_delay_s": (0.0, 60.0, False),
    "transport_grace_s": (0.0, 60.0, False),
    "ping_interval_s": (0.0, 5.0, False),
    "ping_timeout_s": (0.0, 5.0, False),
    "max_future_s": (0.0, 5.0, False),
    "max_past_s": (0.0, 60.0, False),
    "max_position_m": (0.0, 1.0e5, False),
    "odometry_jump_factor": (0.0, 100.0, False),
    "robot_cmd_timeout_s": (0.0, 5.0, False),
}
#: Fields that must be ints (the rest of :data:`BOUNDS` are real numbers).
INT_FIELDS = (
    "queue_length",
    "throttle_rate_ms",
    "buffer_length",
    "max_beams",
    "max_bearings",
    "max_message_bytes",
    "hard_max_message_bytes",
)
#: Fields that may be ``None`` (= the env's robot config).
OPTIONAL_FIELDS = (
    "max_speed_mps",
    "max_turn_rate_radps",
    "max_accel_mps2",
    "max_turn_accel_radps2",
)


# Its own check, not swarm_core.validation's: the guard process (``python -m
# hardware_bridge.guard``) imports this package, and it must start on the standard library alone.
def _check_bounded(name: str, value: Any) -> None:
    low, high, low_inclusive = BOUNDS[name]
    whole = name in INT_FIELDS
    kind = "an int" if whole else "a finite number"
    if (
        isinstance(value, bool)
        or not isinstance(value, int if whole else (int, float))
        or not math.isfinite(value)
        or not (value >= low if low_inclusive else value > low)
        or value > high
    ):
        side = ">=" if low_inclusive else ">"
        raise ValueError(
            f"BridgeConfig.{name} must be {kind} {side} {low:g} and <= {high:g}, got {value!r}"
        )


@dataclass(frozen=True, slots=True)
class BridgeConfig:
    """How the bridge talks to, times and protects the robots.

    Attributes
    ----------
    watchdog_timeout_s : float
        Zero velocity goes to every robot when ``step()`` has not been called for this long
        after the previous one returned (the controller's own compute between steps, a few ms,
        stalled: a frozen policy, a debugger, SIGSTOP). With the default the robots stop at
        most ``period + 0.3 s + watchdog_poll_s`` (0.41 s at 10 Hz) after the last command.
    watchdog_poll_s : float
        Watchdog thread tick (steady clock); bounds the firing latency beyond the timeout.
    watchdog_repeat_s : float
        While tripped, the zero command is re-sent at this period (a single lost message must not
        leave a robot moving).
    step_overrun_s : float
        A ``step()`` still running this long after its control period ended (a hung send, a
        stalled callback, the env process frozen by SIGSTOP or Ctrl-Z mid-step) trips the
        watchdog and the guard process: the robots get zero velocity at most
        ``control period + step_overrun_s + watchdog_poll_s`` after the step's command went
        out (0.31 s at 10 Hz with the defaults), inside the robots' own command timeout.
    stale_odometry_s, stale_lidar_s, stale_camera_s, stale_mocap_s : float
        A sensor whose newest message is older than this (ROS time) at the end of a step is
        reported in ``infos[agent]["stale"]`` and its records are not fed to the filter.
    connect_timeout_s : float
        Wait for the websocket to open in :meth:`RealWorld.reset`.
    reset_timeout_s : float
        ``reset()`` waits this long for fresh data from every robot, then raises
        :class:`RobotsSilentError` naming the silent robots and sensors.
    required_sensors : tuple of str
        Sensors every robot must deliver before ``reset()`` returns.
    use_mocap : bool
        Subscribe to ``/mocap/<robot>/pose`` (ground truth for rewards and metrics).
    max_speed_mps, max_turn_rate_radps, max_accel_mps2, max_turn_accel_radps2 : float or None
        Command limits enforced in the bridge; ``None`` = the env's robot config.
    geofence_m : (x_min, x_max, y_min, y_max) or None
        Allowed area in the motion-capture frame. Outside it a robot may only turn or drive back
        in; without a fresh mocap pose it is stopped.
    queue_length : int
        rosbridge-side subscription queue (``queue_length``): 1 = always the newest message, a
        slow link drops old ones instead of building a backlog.
    throttle_rate_ms : int
        rosbridge-side minimum interval between messages per topic (0 = no throttling).
    buffer_length : int
        Client-side bound per topic; older unread messages are dropped and counted.
    duplicate_window_s : float
        Header-less messages (camera bearings) identical to the previous one and arriving within
        this window are counted as duplicates and dropped.
    max_beams, max_bearings : int
        Size limits of a scan and of a bearing array; larger messages are rejected.
    max_message_bytes : int
        Websocket frame / message size limit (bytes).
    drop_pre_command : bool
        A step feeds the filter only the sensor messages stamped after its command went out
        (older ones are dropped and counted as ``<sensor>.pre_command``); ``False`` keeps
        everything since the previous step ended.
    reconnect_initial_delay_s, reconnect_max_delay_s : float
        Backoff of the automatic reconnection.
    transport_grace_s : float
        ``step()`` raises :class:`~hardware_bridge.world.TransportLostError` once the link has
        been down this long (the robots were stopped the moment it went down).
    ping_interval_s, ping_timeout_s : float
        Websocket keep-alive: a server that answers no ping within ``ping_timeout_s`` (a frozen
        rosbridge) is declared lost after at most ``ping_interval_s + ping_timeout_s``.
    hard_max_message_bytes : int
        Websocket limit above which the frame cannot even be received (the link is dropped);
        messages between ``max_message_bytes`` and this are rejected, counted as
        ``transport.oversize``, and the link stays up.
    max_future_s, max_past_s : float
        A stamped message more than ``max_future_s`` ahead of the bridge clock, or more than
        ``max_past_s`` behind it, is rejected (``<sensor>.future`` / ``<sensor>.too_old``): one
        bad stamp must never make later good messages look out of order.
    max_position_m : float
        Odometry and mocap coordinates beyond this magnitude are rejected as implausible.
    odometry_jump_factor : float
        An odometry pose further from the previous one than ``factor x max speed x dt + 0.05 m``
        (or turned more than ``factor x max turn rate x dt + 0.1 rad``) is a jump (driver restart,
        glitch): the increment is not integrated, the pose becomes the new baseline
        (``odometry.implausible``).
    stamped_commands : bool
        Publish ``geometry_msgs/TwistStamped`` (``header.stamp`` = send time) instead of
        ``Twist``. The robot-side controller (ros2_control ``diff_drive_controller`` with
        ``use_stamped_vel: true``) drops a command older than its ``cmd_vel_timeout``, so a
        command delayed by a frozen server or a reconnection is never executed.
    robot_cmd_timeout_s : float
        The robots' configured command timeout (documented robot-side setting; the loopback
        server enforces it). The guard process (below) must fire well inside it.
    guard_process : bool
        Run the watchdog's twin in a separate process with its own websocket, so a stall that
        holds the GIL, or the death of the env process, still stops the robots.
    unstamped_bearings : tuple of str
        Robots that publish legacy header-less ``std_msgs/Float32MultiArray`` bearings (stamped
        on arrival). Every other robot publishes ``swarm_phd_msgs/BearingsStamped``.
    uav_id : str or None
        A UAV supervisor (Stegagno 2013) to subscribe to: its pose and downward-camera detections
        (``hardware_bridge.messages.uav_topics``), validated and stamp-windowed like the UGVs'
        messages, recorded and replayed with them; its velocity command goes out with the
        UGVs' and is zeroed (hover) by every stop. ``reset()`` waits for both of its topics.
    stale_uav_s : float
        The UAV's pose or detections older than this at the end of a step are reported stale
        (``infos["uav_0"]["stale"]``).
    stale_estimate_s : float
        With on-board filters (``real_env(..., onboard=True)``): a robot whose newest
        ``EstimateStamped`` is older than this at the end of a step is reported stale
        (``"estimate"`` in ``infos[agent]["stale"]``), keeps its last estimate, and is sent
        zero velocity until a fresh estimate arrives (its policy would be driving on an old
        picture of its teammates).
    """

    watchdog_timeout_s: float = 0.3
    watchdog_poll_s: float = 0.01
    watchdog_repeat_s: float = 0.25
    step_overrun_s: float = 0.2
    stale_odometry_s: float = 0.5
    stale_lidar_s: float = 0.6
    stale_camera_s: float = 0.5
    stale_mocap_s: float = 0.5
    connect_timeout_s: float = 5.0
    reset_timeout_s: float = 5.0
    required_sensors: tuple[str, ...] = ("odometry", "lidar", "camera")
    use_mocap: bool = True
    max_speed_mps: float | None = None
    max_turn_rate_radps: float | None = None
    max_accel_mps2: float | None = None
    max_turn_accel_radps2: float | None = None
    geofence_m: tuple[float, float, float, float] | None = None
    queue_length: int = 1
    throttle_rate_ms: int = 0
    buffer_length: int = 64
    duplicate_window_s: float = 0.005
    max_beams: int = 8192
    max_bearings: int = 256
    max_message_bytes: int = 4 * 1024 * 1024
    drop_pre_command: bool = True
    reconnect_initial_delay_s: float = 0.2
    reconnect_max_delay_s: float = 2.0
    transport_grace_s: float = 5.0
    ping_interval_s: float = 0.5
    ping_timeout_s: float = 1.0
    hard_max_message_bytes: int = 64 * 1024 * 1024
    max_future_s: float = 0.5
    max_past_s: float = 10.0
    max_position_m: float = 1.0e4
    odometry_jump_factor: float = 3.0
    stamped_commands: bool = True
    robot_cmd_timeout_s: float = 0.5
    guard_process: bool = True
    unstamped_bearings: tuple[str, ...] = ()
    uav_id: str | None = None
    stale_uav_s: float = 0.5
    stale_estimate_s: float = 0.5

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name in BOUNDS:
                value = getattr(self, f.name)
                if value is None and f.name in OPTIONAL_FIELDS:
                    continue
                _check_bounded(f.name, value)
        for name in ("use_mocap", "drop_pre_command", "stamped_commands", "guard_process"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"BridgeConfig.{name} must be a bool, got {getattr(self, name)!r}"
                )
        # A watchdog must fire before the robots' own command timeout, and tick well inside it.
        if self.watchdog_poll_s >= self.watchdog_timeout_s:
            raise ValueError(
                "BridgeConfig.watchdog_poll_s must be < watchdog_timeout_s, got "
                f"{self.watchdog_poll_s!r} >= {self.watchdog_timeout_s!r}"
            )
        if self.reconnect_max_delay_s < self.reconnect_initial_delay_s:
            raise ValueError(
                "BridgeConfig.reconnect_max_delay_s must be >= reconnect_initial_delay_s, got "
                f"{self.reconnect_max_delay_s!r} < {self.reconnect_initial_delay_s!r}"
            )
        if self.hard_max_message_bytes < self.max_message_bytes:
            raise ValueError(
                "BridgeConfig.hard_max_message_bytes must be >= max_message_bytes, got "
                f"{self.hard_max_message_bytes!r} < {self.max_message_bytes!r}"
            )
        if (
            isinstance(self.unstamped_bearings, str)
            or not isinstance(self.unstamped_bearings, (tuple, list))
            or not all(isinstance(r, str) for r in self.unstamped_bearings)
        ):
            raise ValueError(
                "BridgeConfig.unstamped_bearings must be a tuple of robot ids, got "
                f"{self.unstamped_bearings!r}"
            )
        object.__setattr__(self, "unstamped_bearings", tuple(self.unstamped_bearings))
        if self.uav_id is not None:
            from hardware_bridge.messages import check_robot_id

            try:
                check_robot_id(self.uav_id)
            except ValueError as exc:
                raise ValueError(f"BridgeConfig.uav_id: {exc}") from None
        if isinstance(self.required_sensors, str) or not isinstance(
            self.required_sensors, (tuple, list)
        ):
            raise ValueError(
                "BridgeConfig.required_sensors must be a tuple of sensor names, got "
                f"{self.required_sensors!r}"
            )
        object.__setattr__(self, "required_sensors", tuple(self.required_sensors))
        unknown = set(self.required_sensors) - set(SENSORS)
        if unknown:
            raise ValueError(
                f"BridgeConfig.required_sensors has unknown sensors {sorted(unknown)}; "
                f"valid: {SENSORS}"
            )
        if "mocap" in self.required_sensors and not self.use_mocap:
            raise ValueError("BridgeConfig.required_sensors has 'mocap' but use_mocap=False")
        if self.geofence_m is not None:
            fence = tuple(self.geofence_m)
            if len(fence) != 4 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in fence
            ):
                raise ValueError(
                    "BridgeConfig.geofence_m must be 4 finite numbers (x_min, x_max, y_min, "
                    f"y_max), got {self.geofence_m!r}"
                )
            if not (fence[0] < fence[1] and fence[2] < fence[3]):
                raise ValueError(
                    f"BridgeConfig.geofence_m needs x_min < x_max and y_min < y_max, got {fence!r}"
                )
            object.__setattr__(self, "geofence_m", tuple(float(v) for v in fence))

    def stale_age_s(self, sensor: str) -> float:
        return float(getattr(self, f"stale_{sensor}_s"))


def make_bridge_config(bridge: BridgeConfig | dict[str, Any] | None) -> BridgeConfig:
    """A :class:`BridgeConfig` from ``None`` (defaults), a config, or a dict of fields."""
    if bridge is None:
        return BridgeConfig()
    if isinstance(bridge, BridgeConfig):
        return bridge
    if isinstance(bridge, dict):
        names = {f.name for f in dataclasses.fields(BridgeConfig)}
        unknown = sorted(set(bridge) - names)
        if unknown:
            raise ValueError(
                f"unknown bridge config key(s) {unknown}; valid keys: {sorted(names)}"
            )
        return BridgeConfig(**bridge)
    raise ValueError(f"bridge must be a BridgeConfig or a dict, got {type(bridge).__name__}")
