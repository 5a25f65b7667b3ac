"""The signal an exception chain was raised from.

A signal handler that raises (SIGINT's ``KeyboardInterrupt``, SIGTERM's ``SystemExit``) while C
code is calling back into Python (numba loading a cached kernel, a cffi callback) surfaces as a
``SystemError("... returned a result with an exception set")`` caused by the handler's
exception. A caller that catches ``KeyboardInterrupt`` or ``SystemExit`` would miss it, so the
env and the command line re-raise the signal's own exception (:func:`unwrap_signal`).
"""

from __future__ import annotations

__all__ = ["signal_cause", "unwrap_signal"]


def signal_cause(exc: BaseException | None) -> BaseException | None:
    """The ``KeyboardInterrupt`` or ``SystemExit`` (``hardware_bridge.signals.Terminated`` is
    one) that ``exc`` was raised from, if any: ``exc`` itself, its ``__cause__`` or unsuppressed
    ``__context__``, transitively, as a traceback reads the chain. ``None`` otherwise."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    return None


def unwrap_signal(exc: BaseException) -> BaseException | None:
    """The :func:`signal_cause` of ``exc``, ready to be raised in its place (``raise ... from
    None``), or ``None``.

    Raised while ``exc`` is being handled, the signal's exception gets ``exc`` as its
    context; the chain's links to it are cut first, so the chain holds no cycle (a traceback
    would print it backwards). It carries a note naming the wrapper instead."""
    cause = signal_cause(exc)
    if cause is None or cause is exc:
        return cause
    node: BaseException | None = exc
    seen: set[int] = set()
    while node is not None and node is not cause and id(node) not in seen:
        seen.add(id(node))
        following = node.__cause__ or (None if node.__suppress_context__ else node.__context__)
        if node.__cause__ is cause:
            node.__cause__ = None
        if node.__context__ is cause:
            node.__context__ = None
        node = following
    cause.add_note(f"(re-raised from {type(exc).__name__}: {exc})")
    return cause
