"""Training stopped safely: SIGINT and SIGTERM become ``KeyboardInterrupt`` in the main thread
while a trainer runs (``agents.sb3.train``, ``agents.rllib.train``,
``agents.sb3.recurrent_ppo``, ``agents.sb3.recurrent_student``), so it can save and exit
with one line; during the save they are ignored. A wall-time budget
(``--max-wall-minutes``, :class:`WallBudget`) stops a trainer the same way, exit code 0.

Every trainer records why it stopped early as ``"stopped"`` (:func:`stop_reason`): the
signal's name, :data:`WALL_BUDGET`, or None when it did all it was asked."""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from collections.abc import Iterator
from typing import Any

__all__ = [
    "EXIT_CODES",
    "WALL_BUDGET",
    "Interrupts",
    "WallBudget",
    "max_wall_seconds",
    "set_signal",
    "signal_interrupt",
    "stop_reason",
]

#: Exit codes of an interrupted run (the shell's 128 + signal number).
EXIT_CODES = {"SIGINT": 130, "SIGTERM": 143}
#: The ``"stopped"`` reason of a run that its wall-time budget ended (named by its flag).
WALL_BUDGET = "max-wall-minutes"


def add_max_wall_argument(parser: Any, stops: str = "once") -> None:
    """``--max-wall-minutes`` (read by :func:`max_wall_seconds`); ``stops``: where a run
    stops once the budget has passed, for the help (e.g. "after the iteration in which")."""
    parser.add_argument(
        "--max-wall-minutes",
        type=float,
        default=None,
        help=f"stop (and save) {stops} this much wall time has passed",
    )


def max_wall_seconds(minutes: Any) -> float | None:
    """``--max-wall-minutes`` in seconds (None: no budget); ``ValueError`` naming the flag
    unless it is a finite number > 0."""
    from swarm_core.validation import check_number  # imports the kernels' package: only when used

    check_number("--max-wall-minutes", minutes, low=0, above=True, optional=True)
    return None if minutes is None else 60.0 * minutes


class WallBudget:
    """A run's wall-time budget of ``seconds`` (None: none), counted from construction. A
    trainer asks :meth:`passed` where it can stop cleanly (SB3: every env step; the recurrent
    trainers: after each iteration or round)."""

    def __init__(self, seconds: float | None) -> None:
        self.seconds = seconds
        self.start = time.perf_counter()
        self.reached = False

    def passed(self) -> bool:
        """Whether the budget has run out; says so once, when it first has."""
        if self.seconds is None or self.reached:
            return self.reached
        if time.perf_counter() - self.start > self.seconds:
            self.reached = True
            print(f"stopping: wall-time budget of {self.seconds:.0f} s reached", flush=True)
        return self.reached


def stop_reason(interrupted: str | None, budget: WallBudget) -> str | None:
    """Why a run ended before doing all it was asked: the signal that interrupted it, else
    :data:`WALL_BUDGET` if its budget ran out, else None."""
    return interrupted or (WALL_BUDGET if budget.reached else None)


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

    @contextlib.contextmanager
    def caught(self) -> Iterator[None]:
        """Run the block until a stop request: its ``KeyboardInterrupt`` (or numba's wrapping
        of it, :func:`signal_interrupt`) ends the block quietly and stays in ``received``
        (``"SIGINT"`` if none of this handler's signals raised it); other errors pass."""
        try:
            yield
        except (KeyboardInterrupt, SystemError) as exc:
            if not signal_interrupt(exc):
                raise
            self.received = self.received or "SIGINT"

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
