"""The signal an exception chain was raised from.

A signal handler that raises (SIGINT's ``KeyboardInterrupt``, SIGTERM's ``SystemExit``) while C
code is calling back into Python (numba loading a cached kernel, a cffi callback) surfaces as a
``SystemError("... returned a result with an exception set")`` caused by the handler's
exception. A caller that catches ``KeyboardInterrupt`` or ``SystemExit`` would miss it, so the
env and the command line re-raise the cause (:func:`signal_cause`).
"""

from __future__ import annotations

__all__ = ["signal_cause"]


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
