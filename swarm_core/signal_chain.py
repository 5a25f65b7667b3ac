"""The signal an exception chain was raised from.

A signal handler that raises (SIGINT's ``KeyboardInterrupt``, SIGTERM's ``SystemExit``) while C
code is calling back into Python (numba loading a cached kernel, a cffi callback) surfaces as a
``SystemError("... returned a result with an exception set")`` caused by the handler's
exception. A caller that catches ``KeyboardInterrupt`` or ``SystemExit`` would miss it, so the
env and the command line re-raise the signal's own exception (:func:`unwrap_signal`).
"""

from __future__ import annotations

from collections.abc import Iterator

__all__ = ["signal_cause", "unwrap_signal"]


def _chain(exc: BaseException | None) -> Iterator[BaseException]:
    """``exc``, then its ``__cause__`` or unsuppressed ``__context__``, transitively, as a
    traceback reads the chain (each exception once)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        yield exc
        seen.add(id(exc))
        exc = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)


def signal_cause(exc: BaseException | None) -> BaseException | None:
    """The ``KeyboardInterrupt`` or ``SystemExit`` (``hardware_bridge.signals.Terminated`` is
    one) that ``exc`` was raised from, if any: the first in :func:`_chain`. ``None``
    otherwise."""
    return next((e for e in _chain(exc) if isinstance(e, (KeyboardInterrupt, SystemExit))), None)


def unwrap_signal(exc: BaseException) -> BaseException | None:
    """The :func:`signal_cause` of ``exc``, ready to be raised in its place (``raise ... from
    None``), or ``None``.

    Raised while ``exc`` is being handled, the signal's exception gets ``exc`` as its
    context; the chain's links to it are cut first, so the chain holds no cycle (a traceback
    would print it backwards). It carries a note naming the wrapper instead."""
    cause = signal_cause(exc)
    if cause is None or cause is exc:
        return cause
    for node in list(_chain(exc)):  # the whole walk first: it follows the links being cut
        if node is cause:
            break
        if node.__cause__ is cause:
            node.__cause__ = None
        if node.__context__ is cause:
            node.__context__ = None
    cause.add_note(f"(re-raised from {type(exc).__name__}: {exc})")
    return cause
