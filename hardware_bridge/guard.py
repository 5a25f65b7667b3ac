"""The guard: the watchdog's twin in a separate process, with its own websocket to rosbridge.

The in-process :class:`~hardware_bridge.watchdog.Watchdog` is a thread of the env process: a
stall that holds the GIL (a C extension, a long pure-Python loop with a large switch interval),
a deadlocked reactor or a killed env process delays or prevents its zero command. The guard does
not share any of that. The env process writes deadlines to the guard's stdin (one short line per
``step()`` start and end, a few microseconds); when the monotonic clock (system-wide on Linux and
macOS, so comparable across processes) passes the current deadline, the guard publishes zero
velocity to every robot on its own connection and repeats it every ``repeat_s`` until a new
deadline arrives. When its stdin closes (the env process exited or was killed), it stops the
robots, repeats for ``linger_s`` and exits.

Protocol (ASCII lines on stdin)::

    D <deadline>   arm: stop the robots if time.monotonic() passes <deadline>
    X              disarm (before the first step, during reset)
    S              stop now, keep stopping until the next D
    Q              stop now, then exit

The guard prints ``connected`` / ``lost`` on stdout as its link changes (the bridge counts them)
and imports nothing but the standard library and ``websockets``: it starts in ~0.2 s and does not
compile anything.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import select
import signal
import sys
import time

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
LOGGER = logging.getLogger("hardware_bridge")


def _zero(kind: str) -> dict:
    twist = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
    if kind == "geometry_msgs/TwistStamped":
        now = time.time_ns()
        return {
            "header": {
                "stamp": {"sec": now // 1_000_000_000, "nanosec": now % 1_000_000_000},
                "frame_id": "base_link",
            },
            "twist": twist,
        }
    return twist


class _Link:
    """A minimal rosbridge publisher (advertise + publish) that reconnects on demand."""

    def __init__(self, url: str, topics: list[str], msg_type: str, connect_timeout_s: float):
        self.url = url
        self.topics = topics
        self.msg_type = msg_type
        self.connect_timeout_s = connect_timeout_s
        self.ws = None
        self._next_try = 0.0

    def _report(self, text: str) -> None:
        try:
            sys.stdout.write(text + "\n")
            sys.stdout.flush()
        except (OSError, ValueError):
            pass

    def ensure(self) -> bool:
        if self.ws is not None:
            return True
        now = time.monotonic()
        if now < self._next_try:
            return False
        self._next_try = now + 0.2
        from websockets.sync.client import connect

        try:
            ws = connect(
                self.url,
                open_timeout=self.connect_timeout_s,
                close_timeout=0.2,
                compression=None,
                max_size=1 << 16,
            )
            for i, topic in enumerate(self.topics):
                ws.send(
                    json.dumps(
                        {
                            "op": "advertise",
                            "id": f"guard:advertise:{i}",
                            "topic": topic,
                            "type": self.msg_type,
                        }
                    )
                )
        except Exception:  # noqa: BLE001 - any failure: retry later
            return False
        self.ws = ws
        self._report("connected")
        return True

    def stop_all(self) -> bool:
        if not self.ensure():
            return False
        try:
            for topic in self.topics:
                self.ws.send(
                    json.dumps({"op": "publish", "topic": topic, "msg": _zero(self.msg_type)})
                )
            return True
        except Exception:  # noqa: BLE001
            self.drop()
            return False

    def drop(self) -> None:
        if self.ws is not None:
            try:
                self.ws.close()
            except Exception:  # noqa: BLE001
                pass
            self.ws = None
            self._report("lost")

    def drain(self) -> None:
        """Discard whatever the server sends (status messages), so its queue cannot fill."""
        if self.ws is None:
            return
        try:
            while True:
                self.ws.recv(timeout=0)
        except TimeoutError:
            return
        except Exception:  # noqa: BLE001 - closed by the server
            self.drop()


def run(
    url: str,
    topics: list[str],
    msg_type: str,
    *,
    poll_s: float,
    repeat_s: float,
    linger_s: float,
    connect_timeout_s: float,
) -> int:
    link = _Link(url, topics, msg_type, connect_timeout_s)
    link.ensure()
    fd = sys.stdin.fileno()
    os.set_blocking(fd, False)
    pending = b""
    deadline: float | None = None
    stopping = False  # tripped: repeat the zero until the next deadline
    last_stop = -1e9
    quit_at: float | None = None
    while True:
        now = time.monotonic()
        ready, _, _ = select.select([fd], [], [], poll_s)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except BlockingIOError:
                chunk = None
            if chunk == b"":  # the env process is gone: stop everything, then leave
                stopping, deadline = True, None
                if quit_at is None:
                    quit_at = time.monotonic() + linger_s
                    last_stop = -1e9
            elif chunk:
                pending += chunk
                *lines, pending = pending.split(b"\n")
                for line in lines:
                    cmd, _, arg = line.decode("ascii", "replace").strip().partition(" ")
                    if cmd == "D":
                        try:
                            deadline = float(arg)
                        except ValueError:
                            continue
                        stopping = False
                    elif cmd == "X":
                        deadline, stopping = None, False
                    elif cmd in ("S", "Q"):
                        stopping, deadline, last_stop = True, None, -1e9
                        if cmd == "Q":
                            quit_at = time.monotonic() + 0.05
        now = time.monotonic()
        if deadline is not None and now > deadline:
            stopping, deadline, last_stop = True, None, -1e9
        if stopping and now - last_stop >= repeat_s:
            if link.stop_all():
                last_stop = now
        link.drain()
        if quit_at is not None and now >= quit_at:
            if stopping:
                link.stop_all()
            link.drop()
            return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hardware_bridge.guard")
    parser.add_argument("--host", required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--topics", required=True, help="comma-separated cmd_vel topics")
    parser.add_argument("--type", default="geometry_msgs/TwistStamped")
    parser.add_argument("--poll", type=float, default=0.01)
    parser.add_argument("--repeat", type=float, default=0.25)
    parser.add_argument("--linger", type=float, default=1.0)
    parser.add_argument("--connect-timeout", type=float, default=2.0)
    parser.add_argument("--allow-remote", action="store_true")
    args = parser.parse_args(argv)
    # Terminal signals are for the env process; the guard ends when its stdin closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if args.host not in LOOPBACK_HOSTS and not args.allow_remote:
        print(f"guard: host {args.host!r} is not loopback", file=sys.stderr)
        return 2
    host = f"[{args.host}]" if ":" in args.host else args.host
    try:
        return run(
            f"ws://{host}:{args.port}",
            [t for t in args.topics.split(",") if t],
            args.type,
            poll_s=args.poll,
            repeat_s=args.repeat,
            linger_s=args.linger,
            connect_timeout_s=args.connect_timeout,
        )
    except KeyboardInterrupt:  # the terminal's Ctrl-C reaches the whole process group
        return 0


if __name__ == "__main__":
    sys.exit(main())


class GuardClient:
    """The env-process side: starts the guard and feeds it deadlines. Never raises after
    construction (a failed write is counted as ``guard.write_failed``).

    A guard that dies (killed, crashed, out of memory) is noticed by the watchdog thread
    within one tick (:meth:`supervise`), logged with its exit status, counted
    (``guard.restarts``) and restarted with the current deadline, so the process that
    nothing in the env process can stall is back within about 0.3 s (its start-up)."""

    #: Minimum time between two restarts (a guard that cannot start must not fork-loop).
    RESTART_INTERVAL_S = 0.5

    def __init__(
        self,
        host: str,
        port: int,
        topics: list[str],
        msg_type: str,
        *,
        poll_s: float,
        repeat_s: float,
        connect_timeout_s: float,
        allow_remote: bool,
        counters=None,
    ) -> None:
        import threading

        self._cmd = [
            sys.executable,
            "-m",
            "hardware_bridge.guard",
            "--host",
            host,
            "--port",
            str(port),
            "--topics",
            ",".join(topics),
            "--type",
            msg_type,
            "--poll",
            repr(poll_s),
            "--repeat",
            repr(repeat_s),
            "--connect-timeout",
            repr(connect_timeout_s),
        ]
        if allow_remote:
            self._cmd.append("--allow-remote")
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        self._env = dict(os.environ)
        self._env["PYTHONPATH"] = root + os.pathsep + self._env.get("PYTHONPATH", "")
        self.counters = counters
        self.connected = threading.Event()
        self._lock = threading.Lock()
        self._last_line: str | None = None  # the current state, re-sent to a restarted guard
        self._closing = False
        self._next_restart = 0.0
        self.restarts = 0
        self._spawn()

    def _spawn(self) -> None:
        import subprocess
        import threading

        self.proc = subprocess.Popen(
            self._cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=self._env,
            start_new_session=True,  # terminal signals go to the env, which stops the robots
        )
        self._reader = threading.Thread(
            target=self._read, args=(self.proc,), name="bridge-guard-reader", daemon=True
        )
        self._reader.start()

    def _read(self, proc) -> None:
        for line in proc.stdout:
            text = line.decode("ascii", "replace").strip()
            if proc is not self.proc:
                break
            if text == "connected":
                self.connected.set()
                if self.counters is not None:
                    self.counters.incr("guard.connects")
            elif text == "lost":
                self.connected.clear()
        if proc is self.proc:
            self.connected.clear()

    def _send(self, line: str) -> None:
        with self._lock:
            self._last_line = line
            self._write(line)

    def _write(self, line: str) -> None:
        try:
            self.proc.stdin.write(line.encode("ascii") + b"\n")
            self.proc.stdin.flush()
        except (OSError, ValueError):
            if self.counters is not None:
                self.counters.incr("guard.write_failed")

    def arm(self, deadline_mono: float) -> None:
        self._send(f"D {deadline_mono!r}")

    def disarm(self) -> None:
        self._send("X")

    def stop(self) -> None:
        self._send("S")

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def supervise(self) -> bool:
        """Restart the guard if it died (the watchdog thread calls this every tick); True if
        it was restarted. Logs the death with the exit status."""
        if self._closing or self.proc.poll() is None:
            return False
        now = time.monotonic()
        if now < self._next_restart:
            return False
        self._next_restart = now + self.RESTART_INTERVAL_S
        with self._lock:
            if self._closing:
                return False
            old = self.proc
            LOGGER.warning(
                "guard process %d died (exit status %s); restarting it", old.pid, old.returncode
            )
            self.connected.clear()
            self._close_streams(old)
            try:
                self._spawn()
            except OSError as exc:
                LOGGER.error("guard process could not be restarted: %s", exc)
                if self.counters is not None:
                    self.counters.incr("guard.restart_failed")
                return False
            self.restarts += 1
            if self.counters is not None:
                self.counters.incr("guard.restarts")
            if self._last_line is not None:
                self._write(self._last_line)
        return True

    @staticmethod
    def _close_streams(proc) -> None:
        for stream in (proc.stdin, proc.stdout):
            try:
                stream.close()
            except (OSError, ValueError):
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the robots from the guard too, then let it exit."""
        import subprocess

        with self._lock:
            self._closing = True
        if self.proc.poll() is None:
            self._send("Q")
            try:
                self.proc.stdin.close()
            except OSError:
                pass
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(1.0)
        self._close_streams(self.proc)
