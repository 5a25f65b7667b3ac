"""A loopback robot server: the rosbridge v2 protocol over websocket on 127.0.0.1, whose robots are
the simulator stepped in real time. For tests and dry runs without robots.

It implements the operations a rosbridge client uses: ``advertise``, ``unadvertise``,
``publish``, ``subscribe`` (with ``queue_length`` and ``throttle_rate``), ``unsubscribe``,
``call_service`` (answered "unsupported"), ``set_level``; unknown operations get a ``status``
error. Every robot publishes what a real one does (topics in :func:`messages.topics`):
``LaserScan`` (the sim's scan), ``Odometry`` (the encoder increments integrated into an odom
pose), ``BearingsStamped`` (or legacy ``Float32MultiArray``) bearings, ``PoseStamped`` motion
capture (the sim's truth); the messages are built by :class:`~hardware_bridge.emit.RobotEmitter`.
It obeys ``Twist`` and ``TwistStamped`` commands as ros2_control's ``diff_drive_controller``
does: a command is valid for ``robot_cmd_timeout_s`` after its stamp (after its arrival for a
header-less ``Twist``), so a robot stops by itself when ``cmd_vel`` goes silent, and a stamped
command older than that on arrival (held up by a frozen server, a reconnection) or older than the
last one applied is never executed (``server.stale_commands``, ``server.out_of_order_commands``).

With ``onboard=True`` every robot also runs its own filter, as ``ros/swarm_phd_onboard`` does on a
robot: an :class:`~hardware_bridge.onboard.OnBoardFilter` of the family ``config.localizer``
stepped on the robot's simulated records once per control period, whose estimate goes out on
``/<robot>/swarm_phd/estimate`` (``swarm_phd_msgs/EstimateStamped``, stamped at the period's
end; the last ones sent are kept in :attr:`LoopbackServer.published_estimates`), for
``real_env(..., onboard=True)``.

With ``uav=UAVConfig(...)`` it also flies Stegagno 2013's supervisor (``uav_id``, default
``uav_0``): the env's kinematic UAV (:func:`swarm_env.uav.env.fly`) obeying ``/<uav>/cmd_vel``
(same timeout and staleness rules; silence = hover), publishing its pose (its own noisy
odometry, integrated from where it started, ``z`` = altitude) and each downward-camera frame of
the UGVs (:class:`~swarm_env.sensors.downward_camera.DownwardCamera`, level frame) on the topics
of :func:`messages.uav_topics`. :attr:`uav_true_pose` / :attr:`uav_altitude_m` are its truth.

Real time: the sim runs one control period ahead and every message is sent when the wall clock
reaches its stamp, stamped in ROS time (``time.time_ns()``), so the client sees realistic
arrival times. Faults can be injected on the outgoing sensor messages (:class:`FaultConfig`).

The server runs its own asyncio loop in a daemon thread; :meth:`stop` takes the network down
(the robots keep living), :meth:`start` brings it back on the same port, :meth:`close` ends it.
:class:`LoopbackProcess` runs one in a process of its own, so that its real-time sim does not
compete with the bridge for this process's GIL.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hardware_bridge.emit import RobotEmitter
from hardware_bridge.messages import (
    Counters,
    InvalidMessage,
    ground_detections_msg,
    header,
    parse_stamp,
    parse_twist,
    parse_twist_stamped,
    parse_uav_twist,
    topics,
    uav_cmd_topic,
    uav_pose_msg,
    uav_topics,
)
from swarm_core.stamps import s_to_ns
from swarm_env.config import SwarmConfig, make_config
from swarm_env.world.sim import SimWorld

LOGGER = logging.getLogger("hardware_bridge.loopback")
_MALFORMED_ANY = ("invalid_json", "not_object", "unknown_op", "binary", "missing_field")
_MALFORMED_CONTENT = {
    "lidar": ("nan", "wrong_length", "wrong_type"),
    "odometry": ("nan", "wrong_length", "wrong_type"),
    "camera": ("nan", "wrong_length", "wrong_type"),
    "camera_stamped": ("nan", "wrong_type"),
    "mocap": ("nan", "wrong_type"),
}


@dataclass(frozen=True)
class FaultConfig:
    """Probabilities of faults on each outgoing sensor message (mutually exclusive per message).

    ``drop``: not sent. ``delay``: sent ``delay_s`` late. ``duplicate``: sent twice.
    ``malformed``: replaced by a broken message (bad JSON, not an object, unknown op, binary
    frame, missing header, NaN, wrong length, wrong type; cycled in turn).
    """

    drop: float = 0.0
    delay: float = 0.0
    duplicate: float = 0.0
    malformed: float = 0.0
    delay_s: float = 0.3
    sensors: tuple[str, ...] = ("lidar", "odometry", "camera", "mocap")
    seed: int = 0

    def __post_init__(self) -> None:
        total = self.drop + self.delay + self.duplicate + self.malformed
        for name in ("drop", "delay", "duplicate", "malformed"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"FaultConfig.{name} must be in [0, 1], got {p!r}")
        if total > 1.0:
            raise ValueError(f"FaultConfig probabilities sum to {total} > 1")


@dataclass
class _Item:
    payload: str | bytes
    kind: str | None = None  # None, "duplicate", "delayed", "malformed"


@dataclass
class _Sub:
    topic: str
    queue: deque
    throttle_s: float
    event: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task | None = None
    sent: deque = field(default_factory=lambda: deque(maxlen=32))  # hashes of recent payloads


class _Conn:
    def __init__(self, ws) -> None:
        self.ws = ws
        self.subs: dict[str, _Sub] = {}


class LoopbackServer:
    """Simulated robots behind a rosbridge-compatible websocket on 127.0.0.1.

    Parameters
    ----------
    preset : str
        SwarmConfig preset of the simulated robots (``**overrides`` apply to it).
    config : SwarmConfig, optional
        A full config instead.
    port : int
        0 picks a free port (read :attr:`port` after :meth:`start`).
    seed : int
        Seeds the simulated arena and sensors.
    faults : FaultConfig, optional
    robot_cmd_timeout_s : float
        A robot stops when its ``cmd_vel`` has been silent this long (robot-side safety).
    mocap : bool
        Publish ``/mocap/<robot>/pose``.
    uav : UAVConfig, optional
        Fly a UAV supervisor too (module docstring), named ``uav_id``.
    onboard : bool
        Run each robot's filter on board and publish its estimate (module docstring).
    """

    def __init__(
        self,
        preset: str = "seed-lab",
        *,
        config: SwarmConfig | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        seed: int = 0,
        faults: FaultConfig | None = None,
        robot_cmd_timeout_s: float = 0.5,
        mocap: bool = True,
        unstamped_bearings: tuple[str, ...] = (),
        uav: Any = None,
        uav_id: str = "uav_0",
        onboard: bool = False,
        **overrides: Any,
    ) -> None:
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"the loopback server only binds to loopback, got {host!r}")
        self.config = make_config(preset, config, **overrides)
        self.host = host
        self.port = int(port)
        self.seed = seed
        self.faults = faults or FaultConfig()
        self.robot_cmd_timeout_s = robot_cmd_timeout_s
        self.mocap = mocap
        self.world = SimWorld(self.config)
        self.robot_ids = self.world.robot_ids
        self.emitter = RobotEmitter(
            self.robot_ids, self.config, unstamped_bearings=unstamped_bearings
        )
        self.counters = Counters()
        self._fault_rng = np.random.default_rng(self.faults.seed)
        self._malformed_turn = 0
        self._topic_sensor: dict[str, tuple[str, str]] = {}
        self._cmd_topics: dict[str, str] = {}
        for robot in self.robot_ids:
            for sensor, (_kind, topic) in self.emitter.kinds[robot].items():
                self._topic_sensor[topic] = (robot, sensor)
            self._cmd_topics[topics(robot)["cmd_vel"]] = robot
        n = len(self.robot_ids)
        self._commands = np.zeros((n, 2))
        self._command_time = np.full(n, -math.inf)  # monotonic time the command was issued
        self._command_stamp = np.zeros(n, dtype=np.int64)  # newest applied TwistStamped stamp
        self._twists: deque = deque(maxlen=200_000)  # (monotonic s, robot, v, omega)
        # Every cmd_vel, applied or not: (monotonic s, robot, v, omega, age_s or None, applied)
        self._command_log: deque = deque(maxlen=200_000)
        self._twist_lock = threading.Lock()
        self._conns: set[_Conn] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server = None
        self._sim_task: asyncio.Task | None = None
        self._running = False
        self.sim_steps = 0
        self.max_lag_s = 0.0
        self._truth_log: deque = deque(maxlen=int(20.0 / self.config.control_period_s))
        self._init_uav(uav, uav_id)
        self._init_onboard(onboard)

    def _init_onboard(self, onboard: bool) -> None:
        from hardware_bridge.estimate import estimate_topic
        from hardware_bridge.onboard import OnBoardFilter

        if not isinstance(onboard, bool):
            raise ValueError(f"onboard must be a bool, got {onboard!r}")
        self.onboard = onboard
        #: ``(stamp_ns, robot, EstimateStamped JSON)`` of the estimates sent, newest last.
        self.published_estimates: deque = deque(maxlen=10_000)
        self._filters: dict[str, OnBoardFilter] = {}
        if onboard:
            for robot in self.robot_ids:
                self._filters[robot] = OnBoardFilter(robot, self.config, self.config.localizer)
                self._topic_sensor[estimate_topic(robot)] = (robot, "estimate")

    def _onboard_events(self, step: Any, stamp_ns: Callable[[float], int]) -> list[tuple]:
        """Each robot's filter stepped on its records: its estimate, sent at the period's end
        (after the sensors of that instant)."""
        from hardware_bridge.estimate import estimate_topic

        events = []
        end_ns = stamp_ns(step.time_s)
        for robot, onboard in self._filters.items():
            msg = onboard.step_records(step.measurements[robot], s_to_ns(step.time_s))
            msg["header"] = header(end_ns, msg["header"]["frame_id"])
            events.append((step.time_s, 1_000, estimate_topic(robot), msg))
        return events

    def _init_uav(self, uav: Any, uav_id: str) -> None:
        """The simulated UAV's state (``uav=None``: none)."""
        self.uav = uav
        self.uav_id = None
        if uav is None:
            return
        from swarm_env.sensors.downward_camera import DownwardCamera
        from swarm_env.uav.config import UAVConfig

        if not isinstance(uav, UAVConfig):
            raise ValueError(f"uav must be a UAVConfig, got {uav!r}")
        self.uav_id = uav_id
        if uav_id in self.robot_ids:
            raise ValueError(f"uav_id {uav_id!r} is also a robot id")
        self._uav_topics = uav_topics(uav_id)
        for kind, topic in self._uav_topics.items():
            self._topic_sensor[topic] = (uav_id, kind)
        self._uav_cmd_topic = uav_cmd_topic(uav_id)
        self.uav_camera = DownwardCamera(uav.camera)
        # Its own streams, apart from the robots': camera, odometry noise.
        self._uav_rng = np.random.default_rng([self.seed, 2002]).spawn(2)
        self.uav_true_pose = np.array([uav.start_x_m, uav.start_y_m, uav.start_yaw_rad])
        self.uav_altitude_m = float(uav.start_altitude_m)
        self.uav_odometry_pose = np.zeros(3)  # its own estimate, from where it started
        self._uav_command = np.zeros(4)
        self._uav_command_time = -math.inf
        self._uav_command_stamp = 0
        self._uav_next_frame_s = 0.0
        hx, hy = 0.5 * self.config.arena.width_m, 0.5 * self.config.arena.height_m
        self._uav_fence = np.array([hx, hy]) + uav.geofence_margin_m
        high = np.array(
            [uav.max_speed_mps, uav.max_speed_mps, uav.max_yaw_rate_radps, uav.max_climb_rate_mps]
        )
        self._uav_high = high * np.array([1, 1, uav.yaw_control, uav.altitude_control])

    # ------------------------------------------------------------------ lifecycle
    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def start(self, timeout_s: float = 5.0) -> int:
        """Start (or restart) serving; starts the real-time sim on first call. Returns the port."""
        if self._thread is None:
            ready = threading.Event()

            def run() -> None:
                self._loop = asyncio.new_event_loop()
                asyncio.set_event_loop(self._loop)
                ready.set()
                self._loop.run_forever()

            self._thread = threading.Thread(target=run, name="loopback-server", daemon=True)
            self._thread.start()
            ready.wait(timeout_s)
        self._call(self._start_async(), timeout_s)
        return self.port

    def stop(self, timeout_s: float = 5.0) -> None:
        """Take the network down (close every connection); the simulated robots keep running."""
        if self._loop is not None and self._server is not None:
            self._call(self._stop_async(), timeout_s)

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop everything, including the sim and the loop thread."""
        if self._loop is None:
            return
        self.stop(timeout_s)

        async def _end() -> None:
            self._running = False
            if self._sim_task is not None:
                self._sim_task.cancel()
                try:
                    await self._sim_task
                except (asyncio.CancelledError, Exception):  # noqa: BLE001
                    pass

        self._call(_end(), timeout_s)
        self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._loop = None
        self._thread = None

    def __enter__(self) -> LoopbackServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, coro, timeout_s: float):
        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout_s)

    def call(self, fn: Callable[[], Any], timeout_s: float = 5.0) -> Any:
        """Run ``fn`` on the server's loop thread (e.g. read the sim state consistently)."""

        async def _run():
            return fn()

        return self._call(_run(), timeout_s)

    def pause(self, seconds: float) -> None:
        """Freeze the whole server (network and robots) for ``seconds``, as SIGSTOP does to a
        rosbridge process: nothing is read or sent; what the client sends meanwhile waits in
        the socket buffers and arrives as a burst on resume."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(time.sleep, float(seconds))

    def send_raw(self, payload: str | bytes) -> None:
        """Send ``payload`` as one websocket message to every client (fault injection)."""

        async def _send() -> None:
            for conn in list(self._conns):
                await self._send_raw(conn, payload)

        self._call(_send(), 10.0)

    def set_faults(self, faults: FaultConfig) -> None:
        """Change the injected faults (takes effect with the next message)."""
        self.call(lambda: setattr(self, "faults", faults))

    # ------------------------------------------------------------------ inspection
    def twists(self) -> list[tuple[float, str, float, float]]:
        """Every ``cmd_vel`` applied: ``(monotonic time s, robot, v, omega)``."""
        with self._twist_lock:
            return list(self._twists)

    def command_log(self) -> list[tuple[float, str, float, float, float | None, bool]]:
        """Every ``cmd_vel`` received: ``(monotonic s, robot, v, omega, age_s, applied)``;
        ``age_s`` is arrival minus stamp (``None`` for a header-less Twist)."""
        with self._twist_lock:
            return list(self._command_log)

    def poses(self) -> np.ndarray:
        """True ``[x, y, yaw]`` of the simulated robots."""
        return self.call(lambda: self.world.poses()[: len(self.robot_ids)].copy())

    def truth_at(self, stamp_ns: int) -> tuple[np.ndarray, np.ndarray | None, float | None]:
        """Scoring only: ``(robot poses (N, 3), UAV pose [x, y, yaw] or None, UAV altitude or
        None)`` of the newest sim step stamped at or before ``stamp_ns`` (ROS time), so that an
        estimate made from the messages up to a step's end meets the truth of that instant
        (the sim runs up to a period ahead of the wall clock). Keeps the last 20 s."""
        with self._twist_lock:
            log = list(self._truth_log)
        if not log:
            raise ValueError("truth_at: the loopback has not stepped yet")
        stamps = [entry[0] for entry in log]
        k = max(0, int(np.searchsorted(stamps, stamp_ns, side="right")) - 1)
        return log[k][1].copy(), log[k][2], log[k][3]

    @property
    def n_clients(self) -> int:
        return len(self._conns)

    # ------------------------------------------------------------------ async internals
    async def _start_async(self) -> None:
        from websockets.asyncio.server import serve

        if self._server is None:
            self._server = await serve(
                self._handle,
                self.host,
                self.port,
                max_size=4 * 1024 * 1024,
                compression=None,
                ping_interval=None,
            )
            self.port = self._server.sockets[0].getsockname()[1]
            self.counters.incr("server.starts")
        if self._sim_task is None:
            self.world.reset(np.random.default_rng(self.seed))
            self.emitter.reset()
            for onboard in self._filters.values():
                onboard.localizer.reset()
            self._running = True
            self._sim_task = asyncio.get_running_loop().create_task(self._sim_loop())

    async def _stop_async(self) -> None:
        server, self._server = self._server, None
        if server is None:
            return
        server.close(close_connections=True)
        await server.wait_closed()
        for conn in list(self._conns):
            for sub in conn.subs.values():
                if sub.task is not None:
                    sub.task.cancel()
        self._conns.clear()
        self.counters.incr("server.stops")

    async def _handle(self, ws) -> None:
        conn = _Conn(ws)
        self._conns.add(conn)
        self.counters.incr("server.connections")
        try:
            async for raw in ws:
                self._on_client_message(conn, raw)
        except Exception:  # noqa: BLE001 - connection errors end this client only
            pass
        finally:
            self._conns.discard(conn)
            for sub in conn.subs.values():
                if sub.task is not None:
                    sub.task.cancel()

    def _command(self, robot: str, stamp_ns: int | None, v: float, omega: float) -> None:
        """Apply one velocity command as diff_drive_controller does (see the module doc)."""
        i = self.robot_ids.index(robot)
        now = time.monotonic()
        age_s = None
        issued = now
        applied = True
        if stamp_ns is not None:
            age_s = (time.time_ns() - stamp_ns) * 1e-9
            issued = now - max(age_s, 0.0)
            if age_s > self.robot_cmd_timeout_s:
                applied = False
                self.counters.incr("server.stale_commands")
            elif stamp_ns < self._command_stamp[i]:
                applied = False
                self.counters.incr("server.out_of_order_commands")
        with self._twist_lock:
            self._command_log.append((now, robot, v, omega, age_s, applied))
            if applied:
                self._twists.append((now, robot, v, omega))
        if not applied:
            return
        if stamp_ns is not None:
            self._command_stamp[i] = stamp_ns
        self._commands[i] = (v, omega)
        self._command_time[i] = issued
        self.counters.incr("server.twists")

    def _uav_command_in(self, stamp_ns: int | None, command: np.ndarray) -> None:
        """The UAV's autopilot takes a command under the robots' timeout and staleness rules."""
        now = time.monotonic()
        issued = now
        if stamp_ns is not None:
            age_s = (time.time_ns() - stamp_ns) * 1e-9
            issued = now - max(age_s, 0.0)
            if age_s > self.robot_cmd_timeout_s:
                self.counters.incr("server.uav_stale_commands")
                return
            if stamp_ns < self._uav_command_stamp:
                self.counters.incr("server.uav_out_of_order_commands")
                return
            self._uav_command_stamp = stamp_ns
        with self._twist_lock:
            self._uav_command = np.asarray(command, dtype=np.float64).copy()
            self._uav_command_time = issued
        self.counters.incr("server.uav_twists")

    def _uav_step(self, step: Any, stamp_ns: Callable[[float], int]) -> list[tuple]:
        """Fly the UAV one control period; its pose message and, when due, a camera frame, as
        ``(t_s, order, topic, msg)`` events at the step's end."""
        from swarm_env.uav.env import fly

        uav, dt = self.uav, self.config.control_period_s
        with self._twist_lock:
            command = self._uav_command.copy()
            if time.monotonic() - self._uav_command_time > self.robot_cmd_timeout_s:
                command[:] = 0.0  # silence: hover
        command = np.clip(command, -self._uav_high, self._uav_high)
        speed = math.hypot(command[0], command[1])
        if speed > uav.max_speed_mps:
            command[:2] *= uav.max_speed_mps / speed
        self.uav_true_pose, self.uav_altitude_m, true = fly(
            self.uav_true_pose, self.uav_altitude_m, command, dt, uav, self._uav_fence
        )
        noise = self._uav_rng[1].standard_normal(3) * np.array(
            [uav.odometry_std_mps * dt, uav.odometry_std_mps * dt, uav.odometry_std_radps * dt]
        )
        from swarm_core.geometry import integrate_body_delta

        self.uav_odometry_pose = integrate_body_delta(self.uav_odometry_pose, true + noise)
        t_s = step.time_s
        x, y, yaw = self.uav_odometry_pose
        events = [
            (
                t_s,
                10_000,
                self._uav_topics["uav_pose"],
                uav_pose_msg(stamp_ns(t_s), x, y, self.uav_altitude_m, yaw),
            )
        ]
        if t_s + 1e-9 >= self._uav_next_frame_s:
            period = 1.0 / uav.camera.rate_hz
            self._uav_next_frame_s += (
                math.floor((t_s - self._uav_next_frame_s) / period) + 1
            ) * period
            ugv_xy = step.truth.poses[: len(self.robot_ids), :2]
            frame = self.uav_camera.frame(
                t_s, self.uav_true_pose, self.uav_altitude_m, ugv_xy, self._uav_rng[0]
            )
            events.append(
                (
                    t_s,
                    10_001,
                    self._uav_topics["uav_detections"],
                    ground_detections_msg(stamp_ns(t_s), frame.detections),
                )
            )
        return events

    def _status(self, conn: _Conn, level: str, text: str) -> None:
        self.counters.incr(f"server.status_{level}")
        payload = json.dumps({"op": "status", "level": level, "msg": text})
        asyncio.get_running_loop().create_task(self._send_raw(conn, payload))

    async def _send_raw(self, conn: _Conn, payload: str) -> None:
        try:
            await conn.ws.send(payload)
        except Exception:  # noqa: BLE001
            pass

    def _on_client_message(self, conn: _Conn, raw: str | bytes) -> None:
        if isinstance(raw, bytes):
            self.counters.incr("server.invalid_in")
            self._status(conn, "error", "binary frames are not supported")
            return
        try:
            msg = json.loads(raw)
        except ValueError as exc:
            self.counters.incr("server.invalid_in")
            self._status(conn, "error", f"invalid JSON: {exc}")
            return
        if not isinstance(msg, dict) or not isinstance(msg.get("op"), str):
            self.counters.incr("server.invalid_in")
            self._status(conn, "error", "a message must be an object with a string 'op'")
            return
        op = msg["op"]
        topic = msg.get("topic")
        if op == "publish" and self.uav_id is not None and topic == self._uav_cmd_topic:
            try:
                stamp_ns, command = parse_uav_twist(msg.get("msg"))
            except InvalidMessage as exc:
                self.counters.incr("server.invalid_in")
                self._status(conn, "error", f"{topic}: {exc}")
                return
            self._uav_command_in(stamp_ns, command)
        elif op == "publish":
            robot = self._cmd_topics.get(topic)
            if robot is None:
                self._status(conn, "warning", f"publish to unknown topic {topic!r} ignored")
                return
            body = msg.get("msg")
            try:
                if isinstance(body, dict) and "header" in body:
                    stamp_ns, v, omega = parse_twist_stamped(body)
                else:
                    stamp_ns, (v, omega) = None, parse_twist(body)
            except InvalidMessage as exc:
                self.counters.incr("server.invalid_in")
                self._status(conn, "error", f"{topic}: {exc}")
                return
            self._command(robot, stamp_ns, v, omega)
        elif op == "subscribe":
            if not isinstance(topic, str):
                self._status(conn, "error", "subscribe needs a topic")
                return
            queue_length = msg.get("queue_length", 0)
            throttle_ms = msg.get("throttle_rate", 0)
            if type(queue_length) is not int or queue_length < 0:
                queue_length = 0
            if type(throttle_ms) not in (int, float) or throttle_ms < 0:
                throttle_ms = 0
            old = conn.subs.pop(topic, None)
            if old is not None and old.task is not None:
                old.task.cancel()
            sub = _Sub(topic, deque(maxlen=queue_length or 100), throttle_ms / 1000.0)
            sub.task = asyncio.get_running_loop().create_task(self._sender(conn, sub))
            conn.subs[topic] = sub
            self.counters.incr("server.subscriptions")
        elif op == "unsubscribe":
            sub = conn.subs.pop(topic, None)
            if sub is not None and sub.task is not None:
                sub.task.cancel()
        elif op in ("advertise", "unadvertise", "set_level", "status"):
            self.counters.incr(f"server.{op}")
        elif op == "call_service":
            reply = {
                "op": "service_response",
                "service": msg.get("service"),
                "id": msg.get("id"),
                "result": False,
                "values": "services are not supported by the loopback",
            }
            asyncio.get_running_loop().create_task(self._send_raw(conn, json.dumps(reply)))
        else:
            self.counters.incr("server.invalid_in")
            self._status(conn, "error", f"unknown op {op!r}")

    async def _sender(self, conn: _Conn, sub: _Sub) -> None:
        try:
            while True:
                await sub.event.wait()
                sub.event.clear()
                while sub.queue:
                    item = sub.queue.popleft()
                    key = hash(item.payload)
                    if item.kind == "duplicate" and key not in sub.sent:
                        item.kind = None  # the original never went out: not a duplicate
                    await conn.ws.send(item.payload)
                    sub.sent.append(key)
                    self.counters.incr("server.sent")
                    if item.kind is not None:
                        self.counters.incr(f"delivered.{item.kind}")
                        self.counters.incr(f"delivered.{item.kind}.{self._sensor_of(sub.topic)}")
                    if sub.throttle_s > 0:
                        await asyncio.sleep(sub.throttle_s)
        except asyncio.CancelledError:
            raise
        except Exception:  # noqa: BLE001 - the connection is gone
            return

    def _sensor_of(self, topic: str) -> str:
        return self._topic_sensor.get(topic, ("", "other"))[1]

    def _enqueue(self, topic: str, item: _Item) -> None:
        for conn in list(self._conns):
            sub = conn.subs.get(topic)
            if sub is None:
                continue
            if len(sub.queue) == sub.queue.maxlen:
                self.counters.incr("server.evicted")
            sub.queue.append(_Item(item.payload, item.kind))
            sub.event.set()

    def _publish(self, topic: str, msg: dict) -> None:
        """Send one sensor message, through the fault injector."""
        sensor = self._sensor_of(topic)
        text = json.dumps({"op": "publish", "topic": topic, "msg": msg})
        faults = self.faults
        self.counters.incr(f"published.{sensor}")
        if sensor in faults.sensors:
            u = self._fault_rng.random()
            edges = np.cumsum([faults.drop, faults.delay, faults.duplicate, faults.malformed])
            kind = ("drop", "delay", "duplicate", "malformed", None)[
                int(np.searchsorted(edges, u, side="right"))
            ]
            if kind == "drop":
                self.counters.incr("injected.drop")
                self.counters.incr(f"injected.drop.{sensor}")
                return
            if kind == "delay":
                self.counters.incr("injected.delayed")
                self.counters.incr(f"injected.delayed.{sensor}")
                asyncio.get_running_loop().call_later(
                    faults.delay_s, self._enqueue, topic, _Item(text, "delayed")
                )
                return
            if kind == "duplicate":
                self.counters.incr("injected.duplicate")
                self.counters.incr(f"injected.duplicate.{sensor}")
                self._enqueue(topic, _Item(text))
                asyncio.get_running_loop().call_later(
                    0.001, self._enqueue, topic, _Item(text, "duplicate")
                )
                return
            if kind == "malformed":
                variant, payload = self._malform(topic, sensor, msg)
                self.counters.incr("injected.malformed")
                self.counters.incr(f"injected.malformed.{variant}")
                self._enqueue(topic, _Item(payload, "malformed"))
                return
        self._enqueue(topic, _Item(text))

    def _malform(self, topic: str, sensor: str, msg: dict) -> tuple[str, str | bytes]:
        key = "camera_stamped" if sensor == "camera" and "bearings" in msg else sensor
        variants = _MALFORMED_ANY + _MALFORMED_CONTENT.get(key, ())
        variant = variants[self._malformed_turn % len(variants)]
        self._malformed_turn += 1
        if variant == "invalid_json":
            return variant, '{"op": "publish", "topic": "' + topic + '", "msg": {'
        if variant == "not_object":
            return variant, "[1, 2, 3]"
        if variant == "unknown_op":
            return variant, json.dumps({"op": "teleport", "topic": topic})
        if variant == "binary":
            return variant, b"\x00\x01binary"
        bad = json.loads(json.dumps(msg))  # deep copy
        if variant == "missing_field":
            bad.pop("header", None)
            bad.pop("data", None)
        elif variant == "nan":
            if sensor == "lidar":
                bad["angle_increment"] = math.nan
            elif sensor == "odometry":
                bad["pose"]["pose"]["position"]["x"] = math.nan
            elif sensor == "camera" and "bearings" in bad:
                bad["bearings"] = [math.nan] + bad["bearings"]
            elif sensor == "camera":
                bad["data"] = [math.nan] + bad["data"]
                bad["layout"]["dim"][0]["size"] += 1
            else:
                bad["pose"]["position"]["x"] = math.inf
        elif variant == "wrong_length":
            if sensor == "lidar":
                bad["intensities"] = bad["intensities"][:-1]
            elif sensor == "odometry":
                bad["pose"]["covariance"] = bad["pose"]["covariance"][:-1]
            else:
                bad["layout"]["dim"][0]["size"] += 1
        elif variant == "wrong_type":
            if sensor == "lidar":
                bad["ranges"][0] = "1.0"
            elif sensor == "odometry":
                bad["pose"]["pose"]["position"]["x"] = "0.5"
            elif sensor == "camera" and "bearings" in bad:
                bad["bearings"] = ["0.5"] + bad["bearings"]
            elif sensor == "camera":
                bad["data"] = ["0.5"] + bad["data"]
                bad["layout"]["dim"][0]["size"] += 1
            else:
                bad["pose"]["position"]["x"] = [0.5]
        return variant, json.dumps({"op": "publish", "topic": topic, "msg": bad})

    # ------------------------------------------------------------------ the robots
    def _robot_commands(self) -> np.ndarray:
        now = time.monotonic()
        cmd = self._commands.copy()
        cmd[now - self._command_time > self.robot_cmd_timeout_s] = 0.0
        high = np.array([self.config.robot.max_speed_mps, self.config.robot.max_turn_rate_radps])
        return np.clip(cmd, -high, high)

    async def _sim_loop(self) -> None:
        loop = asyncio.get_running_loop()
        anchor = {"mono": time.monotonic(), "wall_ns": time.time_ns()}

        def stamp_ns(t_s: float) -> int:
            return anchor["wall_ns"] + int(round(t_s * 1e9))

        # The odom frame starts where each robot stands.
        for robot in self.robot_ids:
            origin = self.emitter.origin(robot, stamp_ns(0.0))
            self._publish(origin.topic, origin.msg)
        while self._running:
            t_start = self.world.time_s
            step = await loop.run_in_executor(None, self.world.step, self._robot_commands())
            onboard = (
                await loop.run_in_executor(None, self._onboard_events, step, stamp_ns)
                if self._filters
                else []
            )
            self.sim_steps += 1
            behind = time.monotonic() - (anchor["mono"] + t_start)
            if behind > 0.25:
                # The host cannot keep up (CPU starvation): slow the sim down rather than
                # stamping in the past, as a robot's sensors always stamp at acquisition.
                anchor["mono"] += behind
                anchor["wall_ns"] += int(behind * 1e9)
                self.counters.incr("server.realtime_resyncs")
            mono0 = anchor["mono"]
            events = []
            for i, robot in enumerate(self.robot_ids):
                truth = None
                if self.mocap and step.truth is not None:
                    truth = (step.time_s, step.truth.poses[i])
                events.extend(
                    (o.t_s, o.order, o.topic, o.msg)
                    for o in self.emitter.step(robot, step.measurements[robot], stamp_ns, truth)
                )
            if self.uav is not None:
                events.extend(self._uav_step(step, stamp_ns))
            events.extend(onboard)
            if step.truth is not None:
                entry = (
                    stamp_ns(step.time_s),
                    step.truth.poses[: len(self.robot_ids)].copy(),
                    None if self.uav is None else self.uav_true_pose.copy(),
                    None if self.uav is None else self.uav_altitude_m,
                )
                with self._twist_lock:
                    self._truth_log.append(entry)
            events.sort(key=lambda e: (e[0], e[1]))
            for t_s, _, topic, msg in events:
                delay = mono0 + t_s - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
                else:
                    self.max_lag_s = max(self.max_lag_s, -delay)
                self._publish(topic, msg)
                if topic.endswith("/swarm_phd/estimate"):
                    robot = self._topic_sensor[topic][0]
                    self.published_estimates.append((parse_stamp(msg), robot, msg))
            # Next period starts when the wall clock reaches the end of this one.
            delay = mono0 + step.time_s - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)


class LoopbackProcess:
    """A :class:`LoopbackServer` in a process of its own (``spawn``): its real-time sim does not
    share this process's GIL and garbage collector with the bridge, as a real robot does not
    share the host. For tests and dry runs whose timing must be the robots' own.

    ``LoopbackProcess(preset, seed=0, **kwargs)`` takes :class:`LoopbackServer`'s arguments;
    :meth:`start` returns the port, :meth:`close` stops the server and returns its figures
    (``max_lag_s``: how late the sim published at worst; ``sim_steps``; ``counters``, e.g.
    ``server.realtime_resyncs``)."""

    def __init__(self, preset: str = "seed-lab", **kwargs: Any) -> None:
        self.preset = preset
        self.kwargs = kwargs
        self.port: int | None = None
        self._proc: Any = None
        self._conn: Any = None

    def start(self, timeout_s: float = 60.0) -> int:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")  # never fork a process with threads
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve_loopback, args=(child, self.preset, self.kwargs), daemon=True
        )
        self._proc.start()
        child.close()
        if not self._conn.poll(timeout_s):
            self._proc.kill()
            raise TimeoutError(f"the loopback process did not start within {timeout_s} s")
        reply = self._conn.recv()
        if isinstance(reply, BaseException):
            raise reply
        self.port = int(reply)
        return self.port

    def close(self, timeout_s: float = 10.0) -> dict[str, Any]:
        """Stop the server and its process; its figures (class doc), {} if it had died."""
        if self._proc is None:
            return {}
        stats: dict[str, Any] = {}
        try:
            self._conn.send("close")
            if self._conn.poll(timeout_s):
                stats = self._conn.recv()
        except (BrokenPipeError, EOFError, OSError):
            pass
        self._proc.join(timeout_s)
        if self._proc.is_alive():
            self._proc.kill()
        self._proc = None
        return stats

    def __enter__(self) -> LoopbackProcess:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _serve_loopback(conn: Any, preset: str, kwargs: dict[str, Any]) -> None:
    """:class:`LoopbackProcess`'s child: serve until told to close, then report."""
    try:
        server = LoopbackServer(preset, **kwargs)
        conn.send(server.start())
    except BaseException as err:  # noqa: BLE001 - reported to the parent, which raises it
        conn.send(err)
        return
    try:
        conn.recv()
    except EOFError:  # the parent is gone
        pass
    stats = {
        "max_lag_s": server.max_lag_s,
        "sim_steps": server.sim_steps,
        "counters": server.counters.snapshot(),
    }
    server.close()
    try:
        conn.send(stats)
    except (BrokenPipeError, OSError):
        pass


# ---------------------------------------------------------------------------- hostile inputs
def hostile_inputs(robot: str, now_ns: int, max_message_bytes: int) -> dict[str, str]:
    """Hostile rosbridge frames for one robot, by class name (the fault benchmark and the soak
    test send them through :meth:`LoopbackServer.send_raw`). Each must be refused and counted
    by the bridge without dropping the link, stopping a robot or silencing a sensor."""
    from hardware_bridge.messages import odometry_msg, pose_stamped_msg

    names = topics(robot)
    hour_ns = 3600 * 1_000_000_000

    def publish(topic: str, msg: Any) -> str:
        return json.dumps({"op": "publish", "topic": topic, "msg": msg})

    huge = odometry_msg(now_ns, 1.7e308, -1.7e308, 0.0, 0.0, 0.0)
    pad = "x" * (max_message_bytes + 1024)
    return {
        "odometry_future_1h": publish(
            names["odometry"], odometry_msg(now_ns + hour_ns, 0, 0, 0, 0, 0)
        ),
        "odometry_past_1h": publish(
            names["odometry"], odometry_msg(now_ns - hour_ns, 0, 0, 0, 0, 0)
        ),
        "odometry_x_1.7e308": publish(names["odometry"], huge),
        "mocap_future_1h": publish(names["mocap"], pose_stamped_msg(now_ns + hour_ns, 0, 0, 0)),
        "mocap_x_1e300": publish(names["mocap"], pose_stamped_msg(now_ns, 1e300, 0, 0)),
        "oversize": publish(names["odometry"], {"padding": pad}),
        "not_json": "{" * 1000,
        "deep_nesting": "[" * 100_000 + "]" * 100_000,
    }


# ---------------------------------------------------------------------------- subprocess entry
def spawn(
    twist_log: str | Path, cwd: str | Path | None = None, env: dict[str, str] | None = None
) -> tuple[subprocess.Popen, int]:
    """Loopback robots in a new process (its own GIL; :func:`main`), logging every command
    they receive to ``twist_log``: returns ``(process, port)`` once it serves. It serves until
    its stdin closes; its stdout is a pipe, its stderr discarded. ``cwd`` and ``env`` are the
    child's (default: this process's)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hardware_bridge.loopback", "--twist-log", str(twist_log)],
        cwd=cwd,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    line = proc.stdout.readline()
    if not line.strip().isdigit():
        proc.kill()
        proc.wait(5)
        raise RuntimeError(f"loopback process did not start: {line!r}")
    return proc, int(line)


def spawn_driving_env(
    port: int,
    v_mps: float = 0.2,
    cwd: str | Path | None = None,
    env: dict[str, str] | None = None,
) -> subprocess.Popen:
    """A ``real_env`` (preset ``seed-lab``, reset with seed 0) in a new process, commanding
    every robot of the server on 127.0.0.1:``port`` ``[v_mps, 0]`` (m/s, rad/s) every step
    until it is killed: returns the process once it has reset and starts driving. Killing it
    (SIGKILL: no ``finally``, no watchdog thread) leaves only the bridge's guard process to
    stop the robots. Its stdout is a pipe, its stderr discarded; ``cwd`` and ``env`` are the
    child's (default: this process's)."""
    script = (
        "import numpy as np\n"
        "from hardware_bridge import real_env\n"
        f"env = real_env(port={int(port)}, preset='seed-lab', max_steps=10**6)\n"
        "env.reset(seed=0)\n"
        "print('driving', flush=True)\n"
        "while True:\n"
        f"    env.step({{a: np.array([{float(v_mps)!r}, 0.0]) for a in env.agents}})\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    line = proc.stdout.readline()  # blocks until it drives (it may compile the kernels first)
    if line.strip() != b"driving":
        proc.kill()
        proc.wait(5)
        raise RuntimeError(f"the driving env process did not start: {line!r}")
    return proc


def read_twist_log(path: str | Path) -> list[tuple[float, str, float, float, bool]]:
    """A ``--twist-log`` file (:func:`main`): ``(monotonic_s, robot, v_mps, omega_radps,
    applied)`` per command received, in order."""
    out = []
    for line in Path(path).read_text().splitlines():
        t, robot, v, w, _age, applied = line.split()
        out.append((float(t), robot, float(v), float(w), applied == "1"))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m hardware_bridge.loopback --port 0 [--twist-log FILE] [--uav uav_0]``: serve
    (with a UAV supervisor if asked) until stdin
    closes (a robot in another process: tests pause it with SIGSTOP or starve the client's GIL
    without starving the robots). Prints the port, then logs every ``cmd_vel`` received to
    ``FILE`` as ``monotonic_s robot v omega age_s applied`` lines."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m hardware_bridge.loopback")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--preset", default="seed-lab")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--twist-log", default=None)
    parser.add_argument(
        "--uav",
        default=None,
        metavar="ID",
        help="also fly a UAV supervisor named ID (Stegagno 2013 study)",
    )
    parser.add_argument(
        "--onboard",
        action="store_true",
        help="every robot runs its own filter and publishes /<robot>/swarm_phd/estimate",
    )
    args = parser.parse_args(argv)
    uav = None
    if args.uav is not None:
        from swarm_env.uav.config import UAVConfig

        uav = UAVConfig()
    server = LoopbackServer(
        args.preset,
        port=args.port,
        seed=args.seed,
        uav=uav,
        uav_id=args.uav or "uav_0",
        onboard=args.onboard,
    )
    log = open(args.twist_log, "a", buffering=1) if args.twist_log else None  # noqa: SIM115
    if log is not None:
        original = server._command

        def logged(robot, stamp_ns, v, omega):
            before = len(server._command_log)
            original(robot, stamp_ns, v, omega)
            if len(server._command_log) > before:
                t, r, v_, w_, age, applied = server._command_log[-1]
                log.write(f"{t!r} {r} {v_!r} {w_!r} {age!r} {int(applied)}\n")

        server._command = logged
    port = server.start()
    print(port, flush=True)
    try:
        sys.stdin.read()  # until the parent closes our stdin (or dies)
    finally:
        server.close()
        if log is not None:
            log.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
