"""Training interrupted safely: SIGINT and SIGTERM become ``KeyboardInterrupt`` in the main thread
while a trainer runs (``agents.sb3.train``, ``agents.rllib.train``), so it can save and exit
with one line; during the save they are ignored."""

from __future__ import annotations

import signal
import sys
from typing import Any

__all__ = ["Interrupts", "set_signal", "signal_interrupt"]


def set_signal(signum: int, handler: Any) -> Any:
    """``signal.signal`` that is a no-op (returns None) outside the main thread."""
    try:
        return signal.signal(signum, handler)
    except ValueError:  # not the main thread: signals are the caller's business
        return None


def signal_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is the ``KeyboardInterrupt`` of :class:`Interrupts`, or carries it as its
    cause or context. The handler can fire while a numba-compiled function is calling back into
    Python (a dispatcher's first call unpickles its constants): numba then raises
    ``SystemError(... returned a result with an exception set)`` from the interrupt, and a
    trainer must still save and exit with one line. Unlike
    :func:`swarm_core.signal_chain.signal_cause` it also reads a suppressed ``__context__``:
    while a trainer runs, its handler is the only source of ``KeyboardInterrupt``, so any in
    the chain is the stop request."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


class Interrupts:
    """While active, SIGINT and SIGTERM raise ``KeyboardInterrupt`` in the main thread (and
    remember which came), or with ``ignore=True`` are ignored; the old handlers come back on
    exit."""

    def __init__(self, ignore: bool = False) -> None:
        self.ignore = ignore
        self.received: str | None = None
        self._old: dict[int, Any] = {}
        self._old_unraisable: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        self.received = self.received or signal.Signals(signum).name
        raise KeyboardInterrupt

    def _unraisable(self, unraisable: Any) -> None:
        # A signal that lands in a finalizer or a C callback (seen in CI: pymunk's ffi.gc
        # callback freeing a body) raises there, where Python cannot propagate it: it prints
        # "Exception ignored ..." with a traceback and drops it. ``received`` is set, and the
        # trainers stop on it at their next step (their backstops), so say nothing.
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and self.received:
            return
        self._old_unraisable(unraisable)

    def __enter__(self) -> Interrupts:
        handler = signal.SIG_IGN if self.ignore else self._handle
        for signum in (signal.SIGINT, signal.SIGTERM):
            old = set_signal(signum, handler)
            if old is not None:
                self._old[signum] = old
        if self._old and not self.ignore:
            self._old_unraisable, sys.unraisablehook = sys.unraisablehook, self._unraisable
        return self

    def __exit__(self, *exc: Any) -> None:
        for signum, old in self._old.items():
            set_signal(signum, old)
        if self._old_unraisable is not None:
            sys.unraisablehook, self._old_unraisable = self._old_unraisable, None
