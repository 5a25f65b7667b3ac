"""One controller per robot on this computer: a lock file per (rosbridge server, robot).

Two bridge processes driving the same robots (a forgotten terminal, a second ``swarm-phd
bridge``) would fight over every command and defeat each other's watchdog. Before a
:class:`~hardware_bridge.world.RealWorld` connects it takes an exclusive ``flock`` on
``<dir>/swarm-phd-bridge-<host>-<port>-<robot>.lock`` for each of its robots (``<dir>`` =
the temporary directory, ``/tmp``, shared by every user); a robot already claimed is refused with
an error naming the robot and the process holding it. The kernel drops the lock when the
holder exits in any way (even SIGKILL), so a crash never leaves a stale claim. The loopback
names ``127.0.0.1``, ``localhost`` and ``::1`` are one host.

The lock covers the processes of one computer; two computers driving the same robots share
nothing but the rosbridge server (run the bridge from one computer).
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no cross-process claim
    fcntl = None

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


class RobotClaimedError(RuntimeError):
    """Another process already drives this robot through this rosbridge server."""


def lock_dir() -> Path:
    """The system's temporary directory (``$TMPDIR``, else ``/tmp``): shared by every user and
    session of the computer, so a second bridge started by anyone is seen."""
    return Path(tempfile.gettempdir())


def lock_path(host: str, port: int, robot: str) -> Path:
    name = "loopback" if host in LOOPBACK_HOSTS else re.sub(r"[^A-Za-z0-9_.-]", "_", host)
    return lock_dir() / f"swarm-phd-bridge-{name}-{int(port)}-{robot}.lock"


class RobotClaim:
    """Exclusive claims on ``robots`` at ``host:port`` for this process; :meth:`release`
    (idempotent) gives them back. Raises :class:`RobotClaimedError` (nothing held) if one is
    taken."""

    def __init__(self, host: str, port: int, robots: tuple[str, ...]) -> None:
        self._fds: list[int] = []
        if fcntl is None:
            return
        try:
            for robot in robots:
                self._take(lock_path(host, port, robot), robot, host, port)
        except BaseException:
            self.release()
            raise

    def _take(self, path: Path, robot: str, host: str, port: int) -> None:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            writable = True
        except PermissionError:  # another user's lock file: it can still be locked
            fd = os.open(path, os.O_RDONLY)
            writable = False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "?"
            except OSError:
                holder = "?"
            os.close(fd)
            raise RobotClaimedError(
                f"robot {robot!r} at {host}:{port} is already driven by another bridge process "
                f"(pid {holder}, lock {str(path)!r}); stop that process first: two controllers "
                "must never command the same robot"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        if writable:
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
            except OSError:
                pass
        self._fds.append(fd)

    @property
    def held(self) -> int:
        return len(self._fds)

    def release(self) -> None:
        fds, self._fds = self._fds, []
        for fd in fds:
            try:
                os.close(fd)  # closing the descriptor drops the flock
            except OSError:
                pass
