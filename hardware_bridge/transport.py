"""rosbridge v2 client on roslibpy (twisted/autobahn), with reconnection and message counting.

Why not roslibpy's ``Topic`` objects: ``Topic.publish`` queues messages while the link is down and
replays them on reconnection (a stale velocity command arriving seconds late), and it re-subscribes
with a fixed 1 s delay. This client uses roslibpy for the websocket, the JSON framing and the
reconnecting factory, and sends its own ``advertise`` / ``subscribe`` operations every time the
link comes up, followed at once by a zero velocity for every robot. While the link is down,
:meth:`RosbridgeClient.publish` drops (and counts) commands instead of queueing them.

Slow consumers cannot build a backlog: every subscription asks rosbridge for ``queue_length``
(default 1: only the newest message waits) and ``throttle_rate``; on this side each callback only
validates and appends to a bounded buffer.

Malformed frames (not JSON, not an object, an ``op`` a client does not handle, binary) are
counted under ``transport.malformed`` and dropped; a ``publish`` on a topic this client did not
subscribe to under ``transport.unplaced`` (a topic name is only ever looked up in the table of
subscriptions, never dispatched as an event, so no name can reach the link's own events);
messages above ``max_message_bytes`` under ``transport.oversize`` (the link stays up);
``status`` operations are counted and logged.
A keep-alive ping (``ping_interval_s`` / ``ping_timeout_s``) detects a frozen server.

Twisted's reactor runs once per process in a daemon thread and is never stopped (it cannot be
restarted); clients come and go on it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hardware_bridge.config import BridgeConfig
from hardware_bridge.messages import Counters

LOGGER = logging.getLogger("hardware_bridge")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")

_REACTOR_LOCK = threading.Lock()
_REACTOR_THREAD: threading.Thread | None = None


def check_host(host: str, allow_remote: bool) -> None:
    """Refuse a non-loopback rosbridge host unless explicitly allowed."""
    if not isinstance(host, str) or not host:
        raise ValueError(f"host must be a non-empty string, got {host!r}")
    if host not in LOOPBACK_HOSTS and not allow_remote:
        raise ValueError(
            f"host {host!r} is not loopback: connecting to robots over the network needs "
            "allow_remote=True (CLI: --allow-remote). rosbridge has no authentication; use a "
            "trusted network or an SSH tunnel to 127.0.0.1."
        )


def _ensure_reactor() -> None:
    """Start the twisted reactor once, in a daemon thread, without signal handlers."""
    global _REACTOR_THREAD
    from twisted.internet import reactor

    with _REACTOR_LOCK:
        if _REACTOR_THREAD is not None and _REACTOR_THREAD.is_alive():
            return
        if reactor.running:
            return
        _REACTOR_THREAD = threading.Thread(
            target=reactor.run,
            kwargs={"installSignalHandlers": False},
            name="rosbridge-reactor",
            daemon=True,
        )
        _REACTOR_THREAD.start()


def _classes(config: BridgeConfig):
    """A protocol/factory pair with this config's reconnect backoff and size limits."""
    from roslibpy.comm.comm_autobahn import (
        AutobahnRosBridgeClientFactory,
        AutobahnRosBridgeProtocol,
    )

    class Protocol(AutobahnRosBridgeProtocol):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            # Only the operations a bridge client needs. roslibpy's own handlers emit a
            # server's topic (or service) name as an event of the factory, the emitter that
            # also carries the link's "ready", "close" and "error" events: a server publishing
            # on a topic named "close" would fire the link's close handling. A topic name is
            # data here, looked up in the client's table of subscriptions.
            self._message_handlers = {"publish": self._route, "status": self._handle_status}

        def _route(self, message):
            topic = message.get("topic")
            callback = self.factory.routes.get(topic) if isinstance(topic, str) else None
            if callback is None:  # a topic this client never subscribed to: counted, dropped
                self.factory.emit("bridge:unplaced", f"publish on topic {str(topic)[:80]!r}")
                return
            callback(message.get("msg"))

        def _handle_status(self, message):
            self.factory.emit("bridge:status", dict(message))

        def send_message(self, payload):
            # roslibpy's version lets autobahn's Disconnected escape into the reactor log (a
            # traceback on stderr) when the link closes between queueing and sending.
            from autobahn.exception import Disconnected
            from twisted.internet import reactor

            def _send():
                try:
                    self.sendMessage(payload, isBinary=False)
                except Disconnected:
                    self.factory.emit("bridge:send_failed", 1)

            return reactor.callFromThread(_send)

        def onMessage(self, payload, isBinary):  # noqa: N802 (autobahn API)
            if isBinary:
                self.factory.emit("bridge:malformed", "binary frame")
                return
            if len(payload) > config.max_message_bytes:
                # Refused before decoding; the link stays up (only frames beyond
                # hard_max_message_bytes cannot be received and drop the websocket).
                self.factory.emit("bridge:oversize", len(payload))
                return
            try:
                self.on_message(payload)  # json.loads + dispatch; never pickle or eval
            except Exception as exc:  # noqa: BLE001 - a bad frame must not kill the link
                self.factory.emit("bridge:malformed", f"{type(exc).__name__}: {exc}")

    class Factory(AutobahnRosBridgeClientFactory):
        protocol = Protocol
        initialDelay = config.reconnect_initial_delay_s
        delay = config.reconnect_initial_delay_s
        maxDelay = config.reconnect_max_delay_s
        factor = 1.5
        jitter = 0.1

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.routes: dict[str, Callable[[Any], None]] = {}  # topic -> callback
            self.setProtocolOptions(
                maxMessagePayloadSize=config.hard_max_message_bytes,
                maxFramePayloadSize=config.hard_max_message_bytes,
                openHandshakeTimeout=config.connect_timeout_s,
                autoPingInterval=config.ping_interval_s,
                autoPingTimeout=config.ping_timeout_s,
            )

    return Protocol, Factory


@dataclass(frozen=True)
class Subscription:
    topic: str
    msg_type: str
    callback: Callable[[Any], None]


class RosbridgeClient:
    """One websocket to one rosbridge server.

    Parameters
    ----------
    host, port : rosbridge server.
    subscriptions : list of :class:`Subscription`
        Callbacks run on the reactor thread with the ``msg`` object; they must not raise.
    publications : dict topic -> message type
    config : BridgeConfig
    counters : Counters
    on_ready : callable(), optional
        Called on the reactor thread after every (re)connection, after the advertise and
        subscribe operations went out (the world publishes its zero commands there).
    on_lost : callable(), optional
        Called on the reactor thread when an established link is lost.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        subscriptions: list[Subscription],
        publications: dict[str, str],
        config: BridgeConfig,
        counters: Counters,
        on_ready: Callable[[], None] | None = None,
        on_lost: Callable[[], None] | None = None,
    ) -> None:
        import roslibpy

        self.host, self.port = host, int(port)
        self.config = config
        self.counters = counters
        self.subscriptions = list(subscriptions)
        self.publications = dict(publications)
        self._on_ready_cb = on_ready
        self._on_lost_cb = on_lost
        self._proto = None
        self._proto_lock = threading.Lock()
        self._connected = threading.Event()
        self._closed = False
        self._ever_connected = False
        self._ids = 0
        _, factory_cls = _classes(config)
        url = factory_cls.create_url(host, self.port, False)

        class _Ros(roslibpy.Ros):
            # roslibpy.Ros with our factory class (same body as Ros.__init__).
            def __init__(inner, url_, factory):  # noqa: N805
                inner._id_counter = 0
                inner.factory = factory(url_)
                inner.is_connecting = False

        self.ros = _Ros(url, factory_cls)
        factory = self.ros.factory
        factory.on("ready", self._handle_ready)
        factory.on("close", self._handle_close)
        factory.on("bridge:malformed", self._handle_malformed)
        factory.on("bridge:status", self._handle_status)
        factory.on("bridge:oversize", self._handle_oversize)
        factory.on("bridge:send_failed", lambda n: self.counters.incr("transport.send_failed", n))
        factory.on("bridge:unplaced", self._handle_unplaced)
        # Subscriptions are a table, never event names (see Protocol.__init__ in _classes).
        factory.routes = {sub.topic: sub.callback for sub in self.subscriptions}

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start connecting (non-blocking); reconnection is automatic until :meth:`close`."""
        _ensure_reactor()
        self.ros.connect()

    def wait_connected(self, timeout_s: float) -> bool:
        return self._connected.wait(timeout_s)

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop reconnecting and close the websocket cleanly (after queued sends)."""
        if self._closed:
            return
        self._closed = True
        from twisted.internet import reactor

        factory = self.ros.factory
        done = threading.Event()

        def _shutdown():
            try:
                factory.stopTrying()
                with self._proto_lock:
                    proto = self._proto
                if proto is not None:
                    proto._manual_disconnect = True
                    proto.sendClose()
                elif factory.connector is not None:
                    factory.connector.disconnect()
            finally:
                done.set()

        reactor.callFromThread(_shutdown)
        done.wait(timeout_s)
        self._connected.clear()

    # ------------------------------------------------------------------ sending
    def _next_id(self, kind: str, topic: str) -> str:
        self._ids += 1
        return f"{kind}:{topic}:{self._ids}"

    def publish(self, items: list[tuple[str, dict]]) -> bool:
        """Publish ``[(topic, msg), ...]`` now if connected; otherwise drop and count them.
        Never queues for later: a late velocity command is worse than none."""
        from roslibpy import Message

        with self._proto_lock:
            proto = self._proto
        if proto is None or self._closed:
            self.counters.incr("transport.publish_dropped", len(items))
            return False
        for topic, msg in items:
            proto.send_ros_message(
                Message(
                    {
                        "op": "publish",
                        "id": self._next_id("publish", topic),
                        "topic": topic,
                        "msg": msg,
                    }
                )
            )
        self.counters.incr("transport.published", len(items))
        return True

    def flush(self, timeout_s: float = 1.0) -> bool:
        """Wait until the reactor has written everything queued before this call."""
        from twisted.internet import reactor

        if not reactor.running:
            return False
        done = threading.Event()
        reactor.callFromThread(lambda: reactor.callLater(0, done.set))
        return done.wait(timeout_s)

    # ------------------------------------------------------------------ reactor-thread events
    def _handle_ready(self, proto) -> None:
        from roslibpy import Message

        if self._closed:
            proto._manual_disconnect = True
            proto.sendClose()
            return
        for topic, msg_type in self.publications.items():
            proto.send_ros_message(
                Message(
                    {
                        "op": "advertise",
                        "id": self._next_id("advertise", topic),
                        "topic": topic,
                        "type": msg_type,
                        "queue_size": 1,
                        "latch": False,
                    }
                )
            )
        for sub in self.subscriptions:
            proto.send_ros_message(
                Message(
                    {
                        "op": "subscribe",
                        "id": self._next_id("subscribe", sub.topic),
                        "topic": sub.topic,
                        "type": sub.msg_type,
                        "compression": "none",
                        "throttle_rate": self.config.throttle_rate_ms,
                        "queue_length": self.config.queue_length,
                    }
                )
            )
        with self._proto_lock:
            self._proto = proto
        if self._ever_connected:
            self.counters.incr("transport.reconnects")
            LOGGER.warning("rosbridge %s:%d: reconnected", self.host, self.port)
        self._ever_connected = True
        self.counters.incr("transport.connects")
        self._connected.set()
        if self._on_ready_cb is not None:
            try:
                self._on_ready_cb()
            except Exception:  # noqa: BLE001
                LOGGER.exception("on_ready callback failed")

    def _handle_close(self, _proto) -> None:
        was_connected = self._connected.is_set()
        with self._proto_lock:
            self._proto = None
        self._connected.clear()
        if was_connected and not self._closed:
            self.counters.incr("transport.lost")
            LOGGER.warning("rosbridge %s:%d: connection lost; reconnecting", self.host, self.port)
            if self._on_lost_cb is not None:
                try:
                    self._on_lost_cb()
                except Exception:  # noqa: BLE001
                    LOGGER.exception("on_lost callback failed")

    def _handle_malformed(self, detail: str) -> None:
        self.counters.reject("transport.malformed", detail)

    def _handle_unplaced(self, detail: str) -> None:
        self.counters.reject("transport.unplaced", detail)

    def _handle_oversize(self, size: int) -> None:
        self.counters.reject(
            "transport.oversize",
            f"message of {size} bytes > max_message_bytes={self.config.max_message_bytes}",
        )

    def _handle_status(self, message: dict) -> None:
        level = message.get("level", "?")
        self.counters.incr("transport.status")
        LOGGER.info("rosbridge status (%s): %s", level, str(message.get("msg", ""))[:300])
