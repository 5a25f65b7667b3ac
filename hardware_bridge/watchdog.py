"""The safety watchdog: a steady-clock thread that sends zero velocity to every robot.

It fires when

* ``step()`` has not been called within ``timeout_s`` of the previous one returning (a stalled or
  crashed controller: policy exception, debugger, blocked GC);
* :meth:`trip` is called: ``close()``, ``halt()``, an exception inside ``step()``, SIGINT,
  SIGTERM or SIGHUP, loss of the transport (the zero command then goes out the moment the link
  is back).

This thread lives in the env process; a stall that holds the GIL delays it. The
:mod:`~hardware_bridge.guard` process is its twin that nothing in the env process can stall.

While tripped, the zero command is repeated every ``repeat_s`` until the next ``step()``, so a
single lost message cannot leave a robot moving. The clock is ``time.monotonic`` (immune to NTP
or chrony steps); ``threading.Event.wait`` uses it too.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable

LOGGER = logging.getLogger("hardware_bridge")


class Watchdog:
    """Steady-clock dead-man switch.

    Parameters
    ----------
    stop_all : callable(reason) -> None
        Sends zero velocity to every robot. Must be thread-safe and must not block for long.
    timeout_s : float
        Allowed time between the end of one ``step()`` and the start of the next.
    poll_s : float
        Thread tick; the firing latency is at most ``timeout_s + poll_s``.
    repeat_s : float
        Re-send period of the zero command while tripped.
    max_step_s : float
        A single ``step()`` longer than this (a hung step) also trips the watchdog (the world
        passes its control period + ``BridgeConfig.step_overrun_s``).
    """

    def __init__(
        self,
        stop_all: Callable[[str], None],
        timeout_s: float = 0.5,
        poll_s: float = 0.01,
        repeat_s: float = 0.25,
        max_step_s: float = 0.3,
        guard=None,
    ) -> None:
        self._stop_all = stop_all
        self.guard = guard  # GuardClient or None: gets the same deadlines, in another process
        self.timeout_s = timeout_s
        self.poll_s = poll_s
        self.repeat_s = repeat_s
        self.max_step_s = max_step_s
        self._lock = threading.RLock()
        self._signal_pending: int | None = None
        self._signals = None
        self._armed = False
        self._in_step = False
        self._last_kick = time.monotonic()
        self._tripped_at: float | None = None
        self._last_stop = 0.0
        self._closed = threading.Event()
        self.trips: list[tuple[float, str]] = []  # (monotonic time, reason)
        self._thread = threading.Thread(target=self._run, name="bridge-watchdog", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ controller side
    def step_started(self) -> None:
        with self._lock:
            self._armed = True
            self._in_step = True
            self._last_kick = time.monotonic()
            self._tripped_at = None
        if self.guard is not None:
            self.guard.arm(self._last_kick + self.max_step_s)

    def step_finished(self) -> None:
        with self._lock:
            self._in_step = False
            self._last_kick = time.monotonic()
        if self.guard is not None:
            self.guard.arm(self._last_kick + self.timeout_s)

    def disarm(self) -> None:
        """No controller is expected (before the first step, after a reset): no timeout."""
        with self._lock:
            self._armed = False
            self._in_step = False
        if self.guard is not None:
            self.guard.disarm()

    @property
    def tripped(self) -> bool:
        return self._tripped_at is not None

    def trip(self, reason: str) -> None:
        """Stop every robot now (from any thread) and keep them stopped until the next step."""
        with self._lock:
            now = time.monotonic()
            self._tripped_at = now
            self._last_stop = now
            self._in_step = False
            self.trips.append((now, reason))
        level = logging.INFO if reason in ("close()", "halt()") else logging.WARNING
        LOGGER.log(level, "watchdog: stopping all robots (%s)", reason)
        if self.guard is not None:
            self.guard.stop()
        self._safe_stop(reason)

    def close(self) -> None:
        self._closed.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=1.0)
        self.uninstall_sigint()

    # ------------------------------------------------------------------ signals
    def install_sigint(self) -> bool:
        """Trip on SIGINT (Ctrl-C), SIGTERM and SIGHUP before the exception unwinds the main
        thread (``KeyboardInterrupt``, or :class:`~hardware_bridge.signals.Terminated`), so
        ``finally`` blocks close bags. Main thread only."""
        from hardware_bridge.signals import ExitSignals

        def flag(signum: int) -> None:
            # No locks or I/O in a signal handler (the main thread may hold them): flag it; the
            # watchdog thread sends the stop within one poll tick.
            self._signal_pending = signum

        self._signals = ExitSignals(flag)
        return self._signals.installed

    def uninstall_sigint(self) -> None:
        if self._signals is not None:
            self._signals.restore()
            if not self._signals.installed:
                self._signals = None

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        while not self._closed.wait(self.poll_s):
            reason = None
            if self.guard is not None:
                try:
                    self.guard.supervise()  # a dead guard is restarted within one tick
                except Exception:  # noqa: BLE001 - the watchdog must survive anything
                    LOGGER.exception("watchdog: guard supervision failed")
            if self._signal_pending is not None:
                signum, self._signal_pending = self._signal_pending, None
                self.trip(signal.Signals(signum).name)
                continue
            with self._lock:
                now = time.monotonic()
                if self._tripped_at is not None:
                    if now - self._last_stop >= self.repeat_s:
                        self._last_stop = now
                        reason = "repeat"
                elif self._armed:
                    idle = now - self._last_kick
                    if not self._in_step and idle > self.timeout_s:
                        reason = f"step() not called for {idle:.3f} s"
                    elif self._in_step and idle > self.max_step_s:
                        reason = f"step() running for {idle:.3f} s"
                    if reason is not None:
                        self._tripped_at = now
                        self._last_stop = now
                        self.trips.append((now, reason))
            if reason is not None:
                if reason != "repeat":
                    LOGGER.warning("watchdog: stopping all robots (%s)", reason)
                self._safe_stop(reason)

    def _safe_stop(self, reason: str) -> None:
        try:
            self._stop_all(reason)
        except Exception:  # the watchdog must survive anything the transport throws
            LOGGER.exception("watchdog: stop command failed")
