"""Termination signals that unwind instead of killing: SIGTERM and SIGHUP raise
:class:`Terminated` (a ``SystemExit``) in the main thread, SIGINT raises ``KeyboardInterrupt``,
so every ``finally`` runs (the robots get their zero command, a bag is closed with its
``metadata.yaml``).

A signal that arrives inside a :func:`critical` section of the main thread (a bag recorder
writing one step's rows) is deferred to the end of the section, so a bag never holds half a
step that the reader would have to guess about.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

EXIT_SIGNALS = tuple(
    s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s
)

_depth = 0  # critical-section depth of the main thread
_pending: int | None = None


class Terminated(SystemExit):
    """Raised in the main thread by SIGTERM or SIGHUP (exit status 128 + signal number)."""

    def __init__(self, signum: int) -> None:
        super().__init__(128 + signum)
        self.signum = signum

    def __str__(self) -> str:
        return f"terminated by {signal.Signals(self.signum).name}"


def _raise_for(signum: int) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


@contextmanager
def critical() -> Iterator[None]:
    """Defer SIGINT/SIGTERM/SIGHUP exceptions to the end of this block (main thread only)."""
    global _depth, _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0 and _pending is not None:
            signum, _pending = _pending, None
            _raise_for(signum)


@contextmanager
def shielded() -> Iterator[None]:
    """Run a clean-up that must not be cut half-way (closing a bag): SIGINT, SIGTERM and SIGHUP
    arriving inside the block are held and raised at its end, whatever handler was installed
    before (Python's default SIGINT handler too). Main thread only (a no-op elsewhere).

    Why not ``signal.pthread_sigmask``: the kernel hands a process-directed signal to any
    thread that does not block it (the reactor, the watchdog), and CPython then runs the
    Python handler in the main thread at its next bytecode anyway; blocking the main thread
    alone holds nothing back. Holding the handler's exception is what keeps the block whole.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = ExitSignals()  # deferring handlers for the block, the previous ones after it
    try:
        with critical():
            yield
    finally:
        handlers.restore()


def make_handler(on_signal: Callable[[int], None] | None = None) -> Callable:
    """A handler that calls ``on_signal(signum)`` (must be signal-safe: set a flag) and then
    raises (deferred inside :func:`critical`)."""

    def handler(signum, frame):
        global _pending
        if on_signal is not None:
            on_signal(signum)
        if _depth > 0:
            _pending = signum
            return
        _raise_for(signum)

    return handler


def signal_exit(exc: BaseException) -> tuple[int, str] | None:
    """``(exit status, signal name)`` for an exception a termination signal raised
    (``KeyboardInterrupt``, :class:`Terminated`, or either wrapped in a ``SystemError`` by a C
    callback such as numba's kernel loading), else ``None``."""
    if isinstance(exc, SystemError):
        from swarm_core.signal_chain import unwrap_signal

        inner = unwrap_signal(exc)
        if inner is None or inner is exc:
            return None
        exc = inner
    if isinstance(exc, KeyboardInterrupt):
        return 128 + signal.SIGINT, "SIGINT"
    if isinstance(exc, Terminated):
        return 128 + exc.signum, signal.Signals(exc.signum).name
    return None


def ignore_exit_signals() -> None:
    """A command line that is leaving because of a signal (its clean-up done) ignores further
    SIGINT/SIGTERM/SIGHUP: a late second signal can neither kill it with the default action
    nor print a traceback during interpreter shutdown. Main thread only (a no-op elsewhere)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in EXIT_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


class ExitSignals:
    """Install the unwinding handlers for SIGINT, SIGTERM and SIGHUP; :meth:`restore` puts the
    previous ones back. No-op off the main thread (signals are delivered to it only)."""

    def __init__(self, on_signal: Callable[[int], None] | None = None) -> None:
        self._previous: dict[int, object] = {}
        self._handler = make_handler(on_signal)
        self.installed = False
        if threading.current_thread() is not threading.main_thread():
            return
        for signum in EXIT_SIGNALS:
            self._previous[signum] = signal.getsignal(signum)
            signal.signal(signum, self._handler)
        self.installed = True

    def restore(self) -> None:
        if not self.installed or threading.current_thread() is not threading.main_thread():
            return
        for signum, previous in self._previous.items():
            if signal.getsignal(signum) is self._handler:
                signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
        self.installed = False

    def __enter__(self) -> ExitSignals:
        return self

    def __exit__(self, *exc) -> None:
        self.restore()
