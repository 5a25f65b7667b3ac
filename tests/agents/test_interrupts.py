"""Which exceptions a trainer treats as its signal handler's interrupt; the wall-time budget."""

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


def test_caught_ends_the_block_on_an_interrupt_and_passes_other_errors():
    from agents.interrupts import Interrupts

    interrupts = Interrupts()  # not entered: a KeyboardInterrupt raised directly
    with interrupts.caught():
        raise KeyboardInterrupt
    assert interrupts.received == "SIGINT"
    with pytest.raises(ValueError), interrupts.caught():
        raise ValueError("bad input")


def test_a_wall_budget_passes_once_spent_and_names_the_stop(capsys):
    from agents.interrupts import WALL_BUDGET, WallBudget, max_wall_seconds, stop_reason

    none, long, spent = WallBudget(None), WallBudget(3600.0), WallBudget(1e-9)
    assert not none.passed() and not long.passed()
    assert spent.passed() and spent.passed()  # stays passed, said once
    assert capsys.readouterr().out.count("wall-time budget") == 1
    assert stop_reason(None, none) is None and stop_reason(None, spent) == WALL_BUDGET
    assert stop_reason("SIGTERM", spent) == "SIGTERM"  # a signal is named before the budget
    assert max_wall_seconds(None) is None and max_wall_seconds(0.5) == 30.0
    for bad in (0, -1, float("nan"), True):
        with pytest.raises(ValueError, match="--max-wall-minutes"):
            max_wall_seconds(bad)
