"""Which exceptions a trainer treats as its signal handler's interrupt."""

from __future__ import annotations

import pytest

from agents.interrupts import signal_interrupt


def _raised(make):
    try:
        make()
    except BaseException as exc:  # noqa: BLE001 - the test inspects whatever came
        return exc
    raise AssertionError("nothing raised")


def test_the_interrupt_itself_and_numbas_wrapping_of_it_count():
    def wrapped():  # what numba's dispatcher raises when the handler fires in a callback
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError(
                "CPUDispatcher(...) returned a result with an exception set"
            ) from exc

    assert signal_interrupt(_raised(lambda: (_ for _ in ()).throw(KeyboardInterrupt)))
    assert signal_interrupt(_raised(wrapped))


@pytest.mark.parametrize("error", [SystemError("a real one"), ValueError("bad input")])
def test_other_errors_do_not(error):
    def chained():
        try:
            raise RuntimeError("unrelated cause")
        except RuntimeError as exc:
            raise error from exc

    assert not signal_interrupt(_raised(chained))
    cyclic = SystemError("cycle")
    cyclic.__context__ = ValueError("x")
    cyclic.__context__.__context__ = cyclic
    assert not signal_interrupt(cyclic)


def test_an_interrupt_dropped_in_a_finalizer_is_not_printed_and_is_remembered():
    """A signal landing in a finalizer (pymunk's ffi.gc callback, seen in CI) reaches
    ``sys.unraisablehook``: while a trainer runs it is silenced (``received`` is set and the
    trainer stops on it), anything else still goes to the previous hook, which comes back."""
    import gc
    import os
    import signal
    import sys

    from agents.interrupts import Interrupts

    seen = []
    previous = sys.unraisablehook
    sys.unraisablehook = seen.append
    try:
        with Interrupts() as interrupts:

            class Finalized:
                def __del__(self):
                    os.kill(os.getpid(), signal.SIGINT)  # the handler runs inside __del__
                    for _ in range(1000):  # bytecode boundaries for the handler to run at
                        pass

            Finalized()
            gc.collect()
            assert interrupts.received == "SIGINT"
            sys.unraisablehook(
                type("Args", (), {"exc_value": ValueError("other"), "exc_type": ValueError})()
            )
        assert sys.unraisablehook == seen.append
    finally:
        sys.unraisablehook = previous
    assert [type(u.exc_value) for u in seen] == [ValueError]
