"""RealWorld: the :class:`swarm_core.world.World` of a real swarm behind a rosbridge server.

Timing (honest by construction):

* ``step(commands)`` limits the commands (:class:`~hardware_bridge.safety.CommandLimiter`),
  publishes them, notes the ROS time ``t_cmd``, waits out the control period on the steady
  clock, and returns only records stamped in ``(t_cmd, now]``. Messages stamped before
  ``t_cmd`` (measured before the robots got this step's commands, e.g. during the policy's
  compute) are dropped and counted as ``<sensor>.pre_command``; future stamps (clock skew) wait
  for the next step. Odometry increments always span from the last pose used, so dropping a
  pose loses no motion.
* A sensor whose newest message is older than its configured age at the end of a step is
  reported in ``WorldStep.stale`` (the env puts it in ``infos[agent]["stale"]`` and does not
  feed it to the filter).
* ``reset()`` stops every robot and waits for fresh data from every robot; on timeout it raises
  :class:`RobotsSilentError` listing the silent robots and sensors.

ROS time is this host's ``time.time_ns()``; the robots' clocks must be synchronised to it
(chrony, see ``docs/how-to/real-robots.md``): a robot whose clock is behind by more than a
sensor's stale
age looks silent.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from hardware_bridge.assembly import RecordAssembler
from hardware_bridge.claim import RobotClaim
from hardware_bridge.comms import TeammateRelay
from hardware_bridge.config import FEED_SENSORS, BridgeConfig, make_bridge_config
from hardware_bridge.estimate import (
    ROS_TYPE as ESTIMATE_ROS_TYPE,
)
from hardware_bridge.estimate import (
    WEIGHT_KINDS,
    Estimate,
    estimate_frame,
    estimate_topic,
    parse_estimate_stamped,
)
from hardware_bridge.messages import (
    ROS_TYPES,
    UAV_KINDS,
    UAV_ROS_TYPES,
    Counters,
    InvalidMessage,
    Pose,
    check_robot_id,
    kind_topics,
    ns_to_s,
    parse_message,
    topics,
    twist_msg,
    twist_stamped_msg,
    uav_cmd_topic,
    uav_topics,
    uav_twist_msg,
    uav_twist_stamped_msg,
)
from hardware_bridge.safety import CommandLimiter
from hardware_bridge.signals import shielded
from hardware_bridge.transport import RosbridgeClient, Subscription, check_host
from hardware_bridge.watchdog import Watchdog
from swarm_core.aerial import UAVMessages, uav_messages
from swarm_core.world import WorldStep, reject_extra_commands
from swarm_env.config import SwarmConfig

LOGGER = logging.getLogger("hardware_bridge")

# One live RealWorld per (host, port, robot) per process: two controllers must never fight over
# the same robot (e.g. an accidental second env or a vectorised copy).
_ACTIVE: dict[tuple[str, int, str], weakref.ref] = {}
_ACTIVE_LOCK = threading.Lock()


class RobotsSilentError(TimeoutError):
    """``reset()`` did not hear from every robot in time. ``silent`` maps robot -> sensors."""

    def __init__(
        self, silent: dict[str, list[str]], timeout_s: float, connected: bool, where: str
    ) -> None:
        self.silent = silent
        if not connected:
            text = (
                f"could not connect to rosbridge at {where} within {timeout_s:.1f} s; "
                f"silent robots: {sorted(silent)}"
            )
        else:
            parts = [
                f"{robot} ({', '.join(sensors)})" for robot, sensors in sorted(silent.items())
            ]
            text = (
                f"no fresh data within {timeout_s:.1f} s from {len(silent)} robot(s): "
                f"{'; '.join(parts)}. Check that the robots run their drivers and "
                f"rosbridge at {where} sees the topics, and that their clocks are "
                "synchronised (chrony)."
            )
        super().__init__(text)


class TransportLostError(ConnectionError):
    """``step()`` on a link that has been down longer than ``transport_grace_s``."""


class _Buffer:
    """Validated messages of one topic, newest last, bounded; plus freshness bookkeeping."""

    __slots__ = ("items", "newest_ns", "last_payload", "last_arrival", "seen")

    def __init__(self, maxlen: int) -> None:
        self.items: deque = deque(maxlen=maxlen)
        self.newest_ns = 0
        self.last_payload: Any = None
        self.last_arrival = -1.0
        self.seen = False


class RealWorld:
    """Real robots as a :class:`~swarm_core.world.World` (see the module docstring).

    Parameters
    ----------
    robot_ids : sequence of str
        ROS namespaces of the robots (``ugv_0`` ...), in agent order.
    config : SwarmConfig
        The env's config: control period, robot limits, lidar feature extractor, rates.
    host, port : rosbridge server. A non-loopback host needs ``allow_remote=True``.
    bridge : BridgeConfig or dict, optional
    recorder : :class:`hardware_bridge.bag.BagRecorder`, optional
        Records every message the bridge uses and every command it sends.
    onboard : bool
        The robots run their own filters (``ros/swarm_phd_onboard``): subscribe to each
        robot's ``EstimateStamped`` (:func:`~hardware_bridge.estimate.estimate_topic`) instead
        of its scan and bearings. The sensor ``"estimate"`` then replaces ``lidar`` and
        ``camera`` in the required sensors, the staleness report and the bag; each step's
        newest estimates are :attr:`step_estimates`. A robot whose estimate is stale is sent
        zero velocity (``safety.stale_estimate_stops``) until a fresh one arrives.
    estimate_weight_kind : str, optional
        ``"intensity"`` or ``"existence"``: an estimate whose weights mean the other thing
        (a robot running another family than the policy expects) is refused.
    clock_ns : callable, optional
        ROS time in integer nanoseconds (default ``time.time_ns``).

    With ``bridge.uav_id`` set, the world also subscribes to that UAV's pose and detections
    (Stegagno 2013's supervisor): after each ``reset()`` / ``step()``, :attr:`last_uav` holds the
    step's validated UAV messages (:class:`~swarm_core.aerial.UAVMessages`; the newest
    of each at a reset), and :meth:`set_uav_command` sets the velocity command published with
    the UGVs' at the next step (stops and halts send the UAV a zero command: hover).
    """

    layout = None  # obstacle geometry is not known off the simulator

    def __init__(
        self,
        robot_ids: Sequence[str],
        config: SwarmConfig,
        *,
        host: str = "127.0.0.1",
        port: int = 9090,
        allow_remote: bool = False,
        bridge: BridgeConfig | dict | None = None,
        recorder: Any = None,
        clock_ns: Callable[[], int] = time.time_ns,
        onboard: bool = False,
        estimate_weight_kind: str | None = None,
    ) -> None:
        check_host(host, allow_remote)
        if not isinstance(onboard, bool):
            raise ValueError(f"onboard must be a bool, got {onboard!r}")
        if estimate_weight_kind is not None and estimate_weight_kind not in WEIGHT_KINDS:
            raise ValueError(
                f"estimate_weight_kind must be None or one of {sorted(WEIGHT_KINDS)}, got "
                f"{estimate_weight_kind!r}"
            )
        self.onboard = onboard
        self.estimate_weight_kind = estimate_weight_kind
        #: With ``onboard``: each robot's newest estimate taken by the last reset/step (a robot
        #: whose estimate is stale at the step's end is absent).
        self.step_estimates: dict[str, Estimate] = {}
        self._estimate_stale: set[str] = set()
        if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
            raise ValueError(f"port must be an int in 1..65535, got {port!r}")
        ids = tuple(check_robot_id(r) for r in robot_ids)
        if not ids:
            raise ValueError("robots must name at least one robot")
        if len(set(ids)) != len(ids):
            raise ValueError(f"robot ids must be unique, got {list(ids)}")
        self.robot_ids = ids
        self.config = config
        self.bridge = make_bridge_config(bridge)
        self.uav_id = self.bridge.uav_id
        if self.uav_id is not None and self.uav_id in ids:
            raise ValueError(f"bridge uav_id {self.uav_id!r} is also one of the robots {ids}")
        self._uav_ids = () if self.uav_id is None else (self.uav_id,)
        self._uav_command = np.zeros(4)  # [vx, vy, yaw_rate, climb], body frame
        self.last_uav = UAVMessages()
        self.host, self.port = host, port
        self.period_s = config.control_period_s
        self._clock_ns = clock_ns
        self.counters = Counters()
        self.recorder = recorder
        self.assembler = RecordAssembler(
            ids, config, jump_factor=self.bridge.odometry_jump_factor, counters=self.counters
        )
        self.limiter = CommandLimiter(ids, self.bridge, config.robot, self.period_s, self.counters)
        # Teammates' odometry and detections for WorldStep.comms, with SwarmConfig.comms on.
        self.relay = TeammateRelay(ids) if config.comms.enabled else None
        self._lock = threading.Lock()
        feed = ("odometry", "estimate") if onboard else FEED_SENSORS
        self._sensors = feed + (("mocap",) if self.bridge.use_mocap else ())
        required = self.bridge.required_sensors
        if onboard:  # the robots' scans and bearings stay on board
            required = tuple(s for s in required if s not in ("lidar", "camera"))
            required += () if "estimate" in required else ("estimate",)
        elif "estimate" in required:
            raise ValueError(
                "BridgeConfig.required_sensors has 'estimate' but onboard=False (the bridge "
                "runs the filters; set onboard=True to use the robots' own)"
            )
        self._required = required
        self._buffers = {
            (r, s): _Buffer(self.bridge.buffer_length) for r in ids for s in self._sensors
        }
        for uav in self._uav_ids:
            for kind in UAV_KINDS:
                self._buffers[(uav, kind)] = _Buffer(self.bridge.buffer_length)
        self._nominal_period_s = {
            "odometry": 1.0 / config.odometry.rate_hz,
            "lidar": 1.0 / config.lidar.rate_hz,
            "camera": 1.0 / config.camera.rate_hz,
        }
        self._mocap: dict[str, Pose | None] = {r: None for r in ids}  # newest, for the fence
        self._closed = False
        self._lost_since: float | None = None  # monotonic time the link went down
        self._atexit = None
        self.guard = None
        self._kinds = {
            r: kind_topics(r, stamped_bearings=r not in self.bridge.unstamped_bearings)
            for r in ids
        }
        if onboard:
            for r in ids:
                self._kinds[r]["estimate"] = ("estimate", estimate_topic(r))
        self._ros_types = {**ROS_TYPES, "estimate": ESTIMATE_ROS_TYPE}
        for uav in self._uav_ids:
            self._kinds[uav] = {kind: (kind, uav_topics(uav)[kind]) for kind in UAV_KINDS}
        self._cmd_kind = "cmd_vel_stamped" if self.bridge.stamped_commands else "cmd_vel"
        self._step_index = 0
        self._last_step_end_mono: float | None = None
        self._last_end_ns = 0
        self.timing = {"steps": 0, "overruns": 0, "max_gap_s": 0.0, "max_late_s": 0.0}

        self._claim()
        self.watchdog: Watchdog | None = None
        try:
            subscriptions, publications = [], {}
            for robot in ids:
                for sensor in self._sensors:
                    kind, topic = self._kinds[robot][sensor]
                    subscriptions.append(
                        Subscription(topic, self._ros_types[kind], self._callback(robot, sensor))
                    )
                publications[topics(robot)["cmd_vel"]] = ROS_TYPES[self._cmd_kind]
            for uav in self._uav_ids:
                for kind in UAV_KINDS:
                    _, topic = self._kinds[uav][kind]
                    subscriptions.append(
                        Subscription(topic, UAV_ROS_TYPES[kind], self._callback(uav, kind))
                    )
                publications[uav_cmd_topic(uav)] = ROS_TYPES[self._cmd_kind]
            self._cmd_topics = [topics(r)["cmd_vel"] for r in ids]
            # Every stop (watchdog, guard, halt, reconnection) zeroes the UAV too: a hover.
            self._stop_topics = self._cmd_topics + [uav_cmd_topic(u) for u in self._uav_ids]
            self.client = RosbridgeClient(
                host,
                port,
                subscriptions=subscriptions,
                publications=publications,
                config=self.bridge,
                counters=self.counters,
                on_ready=self._on_link_up,
                on_lost=self._on_link_lost,
            )
            if self.bridge.guard_process:
                from hardware_bridge.guard import GuardClient

                self.guard = GuardClient(
                    host,
                    port,
                    self._stop_topics,
                    ROS_TYPES[self._cmd_kind],
                    poll_s=self.bridge.watchdog_poll_s,
                    repeat_s=self.bridge.watchdog_repeat_s,
                    connect_timeout_s=self.bridge.connect_timeout_s,
                    allow_remote=allow_remote,
                    counters=self.counters,
                )
            self.watchdog = Watchdog(
                self._stop_all,
                timeout_s=self.bridge.watchdog_timeout_s,
                poll_s=self.bridge.watchdog_poll_s,
                repeat_s=self.bridge.watchdog_repeat_s,
                max_step_s=self.period_s + self.bridge.step_overrun_s,
                guard=self.guard,
            )
            self.watchdog.install_sigint()
            self._atexit = self._make_atexit()
            atexit.register(self._atexit)
            self.client.start()
        except BaseException:
            self._closed = True
            if self._atexit is not None:
                atexit.unregister(self._atexit)  # the hook holds self: do not leak it
            if self.watchdog is not None:
                self.watchdog.close()
            if self.guard is not None:
                self.guard.close()
            if getattr(self, "client", None) is not None:
                self.client.close()
            self._release()
            raise

    # ------------------------------------------------------------------ pickling / copies
    def __reduce_ex__(self, protocol):
        raise TypeError(
            "RealWorld cannot be pickled or copied: it drives real robots. Run the bridge env in "
            "one process, unvectorised (no SuperSuit/gymnasium vector envs, no subprocess copies)."
        )

    def __getstate__(self):
        self.__reduce_ex__(2)

    def __copy__(self):
        self.__reduce_ex__(2)

    def __deepcopy__(self, memo):
        self.__reduce_ex__(2)

    # ------------------------------------------------------------------ World API
    def reset(self, rng: np.random.Generator | None = None) -> WorldStep:
        """Stop the robots, wait for fresh data from every robot, return the first records."""
        if self._closed:
            raise RuntimeError("RealWorld.reset() after close()")
        try:
            return self._reset()
        except BaseException:
            self.halt()
            raise

    def _reset(self) -> WorldStep:
        self.watchdog.disarm()
        where = f"{self.host}:{self.port}"
        deadline = time.monotonic() + self.bridge.reset_timeout_s
        if not self.client.wait_connected(self.bridge.connect_timeout_s):
            silent = {r: list(self._required) for r in self.robot_ids}
            raise RobotsSilentError(silent, self.bridge.connect_timeout_s, False, where)
        self._stop_all("reset")
        if self.guard is not None and not self.guard.connected.wait(
            max(0.0, deadline - time.monotonic())
        ):
            self.counters.incr("guard.not_connected")
            LOGGER.warning("guard process not connected: only the in-process watchdog is active")
        start_ns = self._clock_ns()
        with self._lock:
            for buf in self._buffers.values():
                # A fresh start: no stamp of the previous episode (however wrong) can make
                # this episode's messages look out of order.
                buf.items.clear()
                buf.newest_ns = 0
                buf.last_payload = None
        self.assembler.reset()
        if self.relay is not None:
            self.relay.reset()
        self.limiter.stopped()
        self._step_index = 0
        while True:
            silent = self._silent_since(start_ns)
            if not silent:
                break
            if time.monotonic() >= deadline:
                raise RobotsSilentError(
                    silent, self.bridge.reset_timeout_s, self.client.connected, where
                )
            time.sleep(0.01)
        end_ns = self._clock_ns()
        # The newest message of each sensor (raw kept for the recorder).
        used = self.assembler.reset_selection(self._take(start_ns, end_ns))
        self._uav_command = np.zeros(4)
        stale = self._stale(end_ns)  # once: what is recorded is what the step reports
        self.last_uav = self._uav_part(used, stale)
        measurements = self.assembler.reset_measurements(self._parsed(used))
        self._take_estimates(used, stale)
        truth = self._truth(used, end_ns)
        self._last_end_ns = end_ns
        if self.recorder is not None:
            self.recorder.record_step("reset", 0, end_ns, used, None, stale)
        self._last_step_end_mono = time.monotonic()
        return WorldStep(
            time_s=ns_to_s(end_ns), measurements=measurements, truth=truth, stale=stale
        )

    def step(self, commands: np.ndarray, extra_commands: np.ndarray | None = None) -> WorldStep:
        if self._closed:
            raise RuntimeError("RealWorld.step() after close()")
        try:
            reject_extra_commands("RealWorld", extra_commands)
            self._check_link()
        except BaseException:
            self.halt()
            raise
        self.watchdog.step_started()
        try:
            return self._step(commands)
        except BaseException as exc:
            self.watchdog.trip(f"exception in step(): {type(exc).__name__}")
            raise
        finally:
            if not self.watchdog.tripped:
                self.watchdog.step_finished()

    def halt(self) -> None:
        """Stop every robot now: zero velocity from this process (flushed) and from the guard
        process, repeated until the next ``step()``. Idempotent, never raises, a no-op after
        :meth:`close` (which halted already). The env calls it on any exception in its
        ``step()``, ``reset()`` or ``close()``."""
        try:
            if self._closed or self.watchdog is None:
                return
            self.watchdog.trip("halt()")
            self.client.flush(0.5)
        except BaseException:  # noqa: BLE001 - halt() is called while unwinding: never mask
            LOGGER.exception("halt() failed")

    def _check_link(self) -> None:
        lost = self._lost_since
        if lost is None or self.client.connected:
            return
        down_s = time.monotonic() - lost
        if down_s > self.bridge.transport_grace_s:
            raise TransportLostError(
                f"rosbridge at {self.host}:{self.port} unreachable for {down_s:.1f} s "
                f"(transport_grace_s={self.bridge.transport_grace_s}); the robots were sent "
                "zero velocity when the link went down and stop on their own command timeout"
            )

    def close(self) -> None:
        """Stop every robot (zero velocity, from here and the guard), close the bag, then the
        slow part: flush, disconnect, end the guard, release the robots.

        The stop and the bag come first, and SIGINT/SIGTERM/SIGHUP arriving during ``close()``
        are held until it has finished (:func:`hardware_bridge.signals.shielded`): a second
        Ctrl-C can never leave a bag without its ``metadata.yaml``. An error in one part is
        logged and raised after every other part has run."""
        if self._closed:
            return
        self._closed = True
        if self.watchdog is not None:
            self.watchdog.uninstall_sigint()  # the shield holds signals from here on
        with shielded():
            parts = [
                lambda: self.watchdog.trip("close()"),
                lambda: self.recorder is not None and self.recorder.close(),
                lambda: self.client.flush(1.0),
                lambda: self.watchdog.close(),
                lambda: self.guard is not None and self.guard.close(),
                lambda: self.client.close(),
                self._release,
            ]
            first_error: Exception | None = None
            for part in parts:
                try:
                    part()
                except Exception as exc:  # noqa: BLE001 - every part runs; the first is raised
                    LOGGER.exception("close(): a clean-up step failed")
                    first_error = first_error or exc
            try:
                atexit.unregister(self._atexit)
            except Exception:  # noqa: BLE001
                pass
            if first_error is not None:
                raise first_error

    # ------------------------------------------------------------------ stepping internals
    def _step(self, commands: np.ndarray) -> WorldStep:
        start_mono = time.monotonic()
        if self._last_step_end_mono is not None:
            gap = start_mono - self._last_step_end_mono
            self.timing["max_gap_s"] = max(self.timing["max_gap_s"], gap)
        limited = self.limiter.limit(commands, self._fresh_mocap())
        for i, robot in enumerate(self.robot_ids):
            if robot in self._estimate_stale:  # driving on an old estimate: stop
                limited[i] = 0.0
                self.limiter.previous[i] = 0.0
                self.counters.incr("safety.stale_estimate_stops")
        t_cmd_ns = self._clock_ns()
        cmd_mono = time.monotonic()
        # One-shot: a step the env gave no UAV command sends a hover, never a stale command.
        uav_command, self._uav_command = self._uav_command, np.zeros(4)
        sent = self.client.publish(
            [
                (topic, self._command(t_cmd_ns, v, w))
                for topic, (v, w) in zip(self._cmd_topics, limited, strict=True)
            ]
            + [(uav_cmd_topic(u), self._uav_msg(t_cmd_ns, uav_command)) for u in self._uav_ids]
        )
        if not sent:
            self.counters.incr("commands.not_sent_steps")
        # Wait out the period on the steady clock.
        deadline = cmd_mono + self.period_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            time.sleep(min(remaining, 0.02))
        late = time.monotonic() - deadline
        self.timing["max_late_s"] = max(self.timing["max_late_s"], late)
        if late > 0.5 * self.period_s:
            self.timing["overruns"] += 1
        end_ns = self._clock_ns()
        after_ns = t_cmd_ns if self.bridge.drop_pre_command else self._last_end_ns
        used = self._take(after_ns, end_ns)
        self._last_end_ns = end_ns
        parsed = self._parsed(used)
        per_robot = {r: {s: parsed[r].get(s, []) for s in FEED_SENSORS} for r in self.robot_ids}
        measurements = self.assembler.measurements(per_robot)
        stale = self._stale(end_ns)  # once: what is recorded is what the step reports
        self.last_uav = self._uav_part(used, stale)
        self._take_estimates(used, stale)
        comms = {} if self.relay is None else self.relay.step(parsed, measurements)
        truth = self._truth(used, end_ns)
        self._step_index += 1
        self.timing["steps"] += 1
        if self.recorder is not None:
            self.recorder.record_step(
                "step",
                self._step_index,
                end_ns,
                used,
                (t_cmd_ns, limited) if sent else None,
                stale,
                **({"uav_command": (self.uav_id, uav_command)} if self._uav_ids and sent else {}),
            )
        self._last_step_end_mono = time.monotonic()
        return WorldStep(
            time_s=ns_to_s(end_ns),
            measurements=measurements,
            truth=truth,
            stale=stale,
            comms=comms,
        )

    def _take(self, after_ns: int, until_ns: int) -> dict[str, dict[str, list]]:
        """Remove and return buffered ``(parsed, raw)`` messages stamped in
        ``(after_ns, until_ns]``, oldest first; older ones are dropped (``pre_command``),
        newer ones (clock skew) stay for the next step. Keyed by robot (and UAV) id."""
        out: dict[str, dict[str, list]] = {r: {} for r in self.robot_ids + self._uav_ids}
        with self._lock:
            for (robot, sensor), buf in self._buffers.items():
                keep, take = [], []
                for item in buf.items:
                    stamp = item[0].stamp_ns
                    if stamp <= after_ns:
                        self.counters.incr(f"{sensor}.pre_command")
                    elif stamp <= until_ns:
                        take.append(item)
                    else:
                        keep.append(item)
                buf.items.clear()
                buf.items.extend(keep)
                take.sort(key=lambda it: it[0].stamp_ns)
                out[robot][sensor] = take
        return out

    def _take_estimates(
        self, used: dict[str, dict[str, list]], stale: dict[str, tuple[str, ...]]
    ) -> None:
        """:attr:`step_estimates` from the step's messages: each robot's newest estimate,
        unless its estimate is stale at the step's end (then it is also stopped next step)."""
        if not self.onboard:
            return
        self._estimate_stale = {r for r in self.robot_ids if "estimate" in stale.get(r, ())}
        self.step_estimates = {
            r: used[r]["estimate"][-1][0]
            for r in self.robot_ids
            if used.get(r, {}).get("estimate") and r not in self._estimate_stale
        }

    @staticmethod
    def _parsed(used: dict[str, dict[str, list]]) -> dict[str, dict[str, list]]:
        """``(parsed, raw)`` items -> parsed messages."""
        return {r: {s: [m for m, _ in items] for s, items in d.items()} for r, d in used.items()}

    def _uav_msg(self, stamp_ns: int, command: np.ndarray) -> dict:
        if self.bridge.stamped_commands:
            return uav_twist_stamped_msg(stamp_ns, command)
        return uav_twist_msg(command)

    def _uav_part(
        self, used: dict[str, dict[str, list]], stale: dict[str, tuple[str, ...]]
    ) -> UAVMessages:
        """The step's UAV messages (parsed), with the UAV's stale kinds from the step's
        ``stale`` (:meth:`_stale`)."""
        if self.uav_id is None:
            return UAVMessages()
        part = {k: [m for m, _ in items] for k, items in used.get(self.uav_id, {}).items()}
        return uav_messages(part, stale.get(self.uav_id, ()))

    def set_uav_command(self, command: np.ndarray) -> None:
        """The UAV's command ``[vx_mps, vy_mps, yaw_rate_radps, climb_mps]`` (body frame) for
        the next :meth:`step` only (a step without one sends a hover), already limited by the
        caller (the env's UAV action space).
        Raises ``ValueError`` without a UAV, or on a wrong shape or a non-finite value."""
        if self.uav_id is None:
            raise ValueError("set_uav_command: this RealWorld has no UAV (bridge uav_id=None)")
        cmd = np.asarray(command, dtype=np.float64)
        if cmd.shape != (4,) or not np.isfinite(cmd).all():
            raise ValueError(
                f"uav command must be 4 finite numbers [vx, vy, yaw_rate, climb], got {command!r}"
            )
        self._uav_command = cmd.copy()

    def _command(self, stamp_ns: int, v: float, w: float) -> dict:
        if self.bridge.stamped_commands:
            return twist_stamped_msg(stamp_ns, v, w)
        return twist_msg(v, w)

    def _truth(self, used: dict[str, dict[str, list]], end_ns: int):
        """Ground truth (mocap freshness rule of :meth:`RecordAssembler.truth_from_mocap`)."""
        if not self.bridge.use_mocap:
            return None
        mocap = {r: [m for m, _ in used[r].get("mocap", [])] for r in self.robot_ids}
        return self.assembler.truth_from_mocap(mocap, end_ns, self.bridge.stale_mocap_s)

    def _silent_since(self, start_ns: int) -> dict[str, list[str]]:
        silent: dict[str, list[str]] = {}
        with self._lock:
            for uav in self._uav_ids:
                missing = [k for k in UAV_KINDS if self._buffers[(uav, k)].newest_ns <= start_ns]
                if missing:
                    silent[uav] = missing
            for robot in self.robot_ids:
                missing = [
                    s for s in self._required if self._buffers[(robot, s)].newest_ns <= start_ns
                ]
                if missing:
                    silent[robot] = missing
        return silent

    def _stale(self, now_ns: int) -> dict[str, tuple[str, ...]]:
        out = {}
        with self._lock:
            for uav in self._uav_ids:
                late = [
                    k
                    for k in UAV_KINDS
                    if (now_ns - self._buffers[(uav, k)].newest_ns) * 1e-9
                    > self.bridge.stale_uav_s
                ]
                if late:
                    out[uav] = tuple(late)
            for robot in self.robot_ids:
                stale = []
                for sensor in self._sensors:
                    buf = self._buffers[(robot, sensor)]
                    if (
                        sensor == "mocap"
                        and not buf.seen
                        and "mocap" not in self.bridge.required_sensors
                    ):
                        continue  # no mocap in this lab: not "stale", just absent
                    age_s = (now_ns - buf.newest_ns) * 1e-9
                    if age_s > self.bridge.stale_age_s(sensor):
                        stale.append(sensor)
                if stale:
                    out[robot] = tuple(stale)
        for sensors in out.values():
            for sensor in sensors:
                self.counters.incr(f"{sensor}.stale_steps")
        return out

    def _fresh_mocap(self, now_ns: int | None = None) -> dict[str, Pose | None]:
        now_ns = self._clock_ns() if now_ns is None else now_ns
        limit_ns = self.bridge.stale_mocap_s * 1e9
        with self._lock:
            return {
                r: (p if p is not None and now_ns - p.stamp_ns <= limit_ns else None)
                for r, p in self._mocap.items()
            }

    # ------------------------------------------------------------------ receive side
    def _callback(self, robot: str, sensor: str) -> Callable[[Any], None]:
        key = sensor
        kind, topic = self._kinds[robot][sensor]
        buf = self._buffers[(robot, sensor)]
        bridge = self.bridge
        nominal = self._nominal_period_s.get(sensor)
        header_less = kind == "camera"
        future_ns = int(bridge.max_future_s * 1e9)
        past_ns = int(bridge.max_past_s * 1e9)

        def on_message(msg: Any) -> None:
            try:
                self.counters.incr(f"{key}.received")
                arrival = time.monotonic()
                now_ns = self._clock_ns()
                if kind == "estimate":
                    parsed = self._parse_estimate(robot, msg)
                else:
                    parsed = parse_message(
                        kind,
                        msg,
                        arrival_ns=now_ns,
                        max_beams=bridge.max_beams,
                        max_bearings=bridge.max_bearings,
                        max_position_m=bridge.max_position_m,
                    )
            except InvalidMessage as exc:
                self.counters.reject(f"{key}.invalid", f"{robot} {sensor}: {exc}")
                if kind == "estimate":  # which field, for the robot's maintainer
                    self.counters.incr(f"estimate.invalid_field.{exc.field}")
                return
            except Exception as exc:  # noqa: BLE001 - never let a message kill the reactor
                self.counters.reject(f"{key}.invalid", f"{robot} {sensor}: {exc!r}")
                return
            # Stamp window: one message from the far future must not make every later one "out
            # of order"; one from the far past is not a measurement of now.
            if parsed.stamp_ns > now_ns + future_ns:
                self.counters.reject(
                    f"{key}.future",
                    f"{robot} {sensor}: stamp {(parsed.stamp_ns - now_ns) * 1e-9:.3f} s ahead",
                )
                return
            if parsed.stamp_ns < now_ns - past_ns:
                self.counters.reject(
                    f"{key}.too_old",
                    f"{robot} {sensor}: stamp {(now_ns - parsed.stamp_ns) * 1e-9:.3f} s old",
                )
                return
            with self._lock:
                if buf.newest_ns > now_ns + future_ns:
                    # The newest accepted stamp is now beyond the window (this host's clock
                    # was stepped back): recover instead of refusing everything from now on.
                    buf.newest_ns = 0
                    self.counters.incr(f"{key}.stamp_recovered")
                if header_less:
                    # No header: a duplicate is the same payload again within a few ms.
                    if (
                        buf.last_payload is not None
                        and arrival - buf.last_arrival < bridge.duplicate_window_s
                        and np.array_equal(buf.last_payload, parsed.bearings_rad)
                    ):
                        self.counters.incr(f"{key}.duplicate")
                        return
                    buf.last_payload = parsed.bearings_rad
                else:
                    if parsed.stamp_ns == buf.newest_ns:
                        self.counters.incr(f"{key}.duplicate")
                        return
                    if parsed.stamp_ns < buf.newest_ns:
                        self.counters.incr(f"{key}.out_of_order")
                        return
                    if buf.newest_ns and nominal is not None:
                        gap_s = (parsed.stamp_ns - buf.newest_ns) * 1e-9
                        missed = int(round(gap_s / nominal)) - 1
                        if missed > 0:
                            self.counters.incr(f"{key}.missed_estimate", missed)
                buf.last_arrival = arrival
                buf.newest_ns = max(buf.newest_ns, parsed.stamp_ns)
                buf.seen = True
                if sensor == "mocap":
                    self._mocap[robot] = parsed
                if len(buf.items) == buf.items.maxlen:
                    self.counters.incr(f"{key}.overflow")
                buf.items.append((parsed, (topic, kind, parsed.stamp_ns, msg)))
            self.counters.incr(f"{key}.accepted")

        return on_message

    def _parse_estimate(self, robot: str, msg: Any) -> Estimate:
        """A robot's ``EstimateStamped``, validated (:func:`parse_estimate_stamped`), in that
        robot's body frame, with positive-definite covariances, weights of the expected kind
        and means within ``max_position_m``; :class:`InvalidMessage` names the field."""
        est = parse_estimate_stamped(msg)
        if est.frame_id != estimate_frame(robot):
            raise InvalidMessage(
                "header.frame_id",
                f"expected {estimate_frame(robot)!r} (the estimate of {robot}), "
                f"got {est.frame_id!r}",
            )
        p = est.covariances_m2
        det = p[:, 0, 0] * p[:, 1, 1] - p[:, 0, 1] * p[:, 1, 0]
        bad = np.flatnonzero((p[:, 0, 0] <= 0.0) | (det <= 0.0))
        if bad.size:
            raise InvalidMessage(
                "covariances", f"component {int(bad[0])} is not positive definite"
            )
        if est.means_m.size and np.abs(est.means_m).max() > self.bridge.max_position_m:
            raise InvalidMessage("means", f"beyond max_position_m={self.bridge.max_position_m} m")
        expected = self.estimate_weight_kind
        if expected is not None and est.weight_kind != expected:
            raise InvalidMessage(
                "weight_kind",
                f"{est.weight_kind!r} ({est.localizer}) but the policy reads {expected!r} "
                "weights: the robot runs another family",
            )
        return est

    # ------------------------------------------------------------------ safety side
    def _stop_all(self, reason: str) -> None:
        """Zero velocity to every robot (thread-safe; dropped and counted if the link is down)."""
        self.limiter.stopped()
        zero = self._command(self._clock_ns(), 0.0, 0.0)  # all zero: also the UAV's hover
        if self.client.publish([(topic, zero) for topic in self._stop_topics]):
            self.counters.incr("watchdog.stop_commands")
            if self.recorder is not None and reason != "repeat":
                self.recorder.record_stop(self._clock_ns(), self.robot_ids)
        else:
            self.counters.incr("watchdog.stop_unsent")

    def _on_link_up(self) -> None:
        # First thing on every (re)connection: stop every robot.
        self._lost_since = None
        self.limiter.stopped()
        zero = self._command(self._clock_ns(), 0.0, 0.0)
        self.client.publish([(topic, zero) for topic in self._stop_topics])

    def _on_link_lost(self) -> None:
        self._lost_since = time.monotonic()
        self.watchdog.trip("transport lost")

    def _make_atexit(self) -> Callable[[], None]:
        ref = weakref.ref(self)

        def _exit() -> None:
            world = ref()
            if world is not None:
                world.close()

        return _exit

    # ------------------------------------------------------------------ ownership
    def _claim(self) -> None:
        with _ACTIVE_LOCK:
            for robot in self.robot_ids:
                key = (self.host, self.port, robot)
                other = _ACTIVE.get(key)
                if other is not None and other() is not None and not other()._closed:
                    raise RuntimeError(
                        f"robot {robot!r} at {self.host}:{self.port} is already driven by "
                        "another open RealWorld in this process; close() it first (the bridge "
                        "env cannot be vectorised or copied)"
                    )
            # Across processes of this computer: a lock file per robot (hardware_bridge.claim).
            self._robot_claim = RobotClaim(self.host, self.port, self.robot_ids)
            for robot in self.robot_ids:
                _ACTIVE[(self.host, self.port, robot)] = weakref.ref(self)

    def _release(self) -> None:
        claim = getattr(self, "_robot_claim", None)
        if claim is not None:
            claim.release()
        with _ACTIVE_LOCK:
            for robot in self.robot_ids:
                key = (self.host, self.port, robot)
                ref = _ACTIVE.get(key)
                if ref is not None and ref() is self:
                    del _ACTIVE[key]

    # ------------------------------------------------------------------ reporting
    def counters_snapshot(self) -> dict[str, int]:
        return self.counters.snapshot()

    def rejected_total(self) -> int:
        return (
            self.counters.total(".invalid")
            + self.counters.get("transport.malformed")
            + self.counters.get("transport.oversize")
            + self.counters.get("transport.unplaced")
        )
