"""Progress output for the long commands: bars over simulated time, over seeds, over stages.

One switch for the whole process (:func:`set_quiet`, the CLI's ``--quiet``) and three output
styles, chosen once from where stderr goes:

- a terminal: tqdm bars redrawn in place (``\\r``), on stderr so stdout stays the results;
- not a terminal (a log file, CI, a pipe): one plain line per ~10 % of the work or per
  ``SWARM_PHD_PROGRESS_EVERY_S`` seconds (default 30), never a ``\\r``, so logs stay readable;
- quiet: nothing.

``SWARM_PHD_PROGRESS=tty|lines|off`` forces a style. Use::

    for k in progress.sim_steps(n_steps, env.config.control_period_s, "evaluate seed 0"):
        env.step(...)
    for seed in progress.over(seeds, "seeds"):
        ...
    with progress.bar(total=3, desc="bench", unit="case") as bar:
        ...; bar.update(1)
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO, TypeVar

T = TypeVar("T")

_quiet = False
STYLES = ("tty", "lines", "off")


def set_quiet(quiet: bool) -> None:
    """Silence (or restore) every bar of this process."""
    global _quiet
    _quiet = bool(quiet)


def is_quiet() -> bool:
    return _quiet


def style(stream: TextIO | None = None) -> str:
    """``"tty"``, ``"lines"`` or ``"off"`` for ``stream`` (default stderr); see the module doc."""
    if _quiet:
        return "off"
    forced = os.environ.get("SWARM_PHD_PROGRESS", "").strip().lower()
    if forced:
        if forced not in STYLES:
            raise ValueError(f"SWARM_PHD_PROGRESS must be one of {STYLES}, got {forced!r}")
        return forced
    stream = sys.stderr if stream is None else stream
    try:
        return "tty" if stream.isatty() else "lines"
    except (AttributeError, ValueError):  # closed or unusual stream
        return "lines"


def note(message: str) -> None:
    """One status line on stderr (the compile message, a stage), unless quiet."""
    if not _quiet:
        print(message, file=sys.stderr, flush=True)


class LineBar:
    """A tqdm-like bar that writes whole lines: at ~10 % steps of ``total`` or every
    ``every_s`` seconds, and once at the end. Same ``update``/``close``/``set_postfix_str``
    calls as tqdm, so callers do not care which one they got."""

    def __init__(
        self,
        total: float | None,
        desc: str,
        unit: str,
        stream: TextIO,
        every_s: float,
        fmt: str = "{:.0f}",
    ) -> None:
        self.total, self.desc, self.unit, self.stream = total, desc, unit, stream
        self.every_s, self.fmt = every_s, fmt
        self.n = 0.0
        self.postfix = ""
        self._t0 = self._last_t = time.perf_counter()
        self._last_decile = 0
        self._closed = False

    def update(self, n: float = 1) -> None:
        self.n += n
        now = time.perf_counter()
        decile = int(10 * self.n / self.total) if self.total else 0
        if decile > self._last_decile or now - self._last_t >= self.every_s:
            if self.total is None or self.n < self.total:  # the final line is close()'s
                self._emit(now)
            self._last_decile = decile

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        self.postfix = text

    def refresh(self) -> None:
        """A line only if ``every_s`` passed since the last one (long phases stay visible)."""
        now = time.perf_counter()
        if not self._closed and now - self._last_t >= self.every_s:
            self._emit(now)

    def _emit(self, now: float) -> None:
        self._last_t = now
        elapsed = now - self._t0
        done = self.fmt.format(self.n)
        if self.total:
            frac = self.n / self.total
            eta = max(0.0, elapsed * (1 - frac) / frac) if frac > 0 else float("nan")
            text = (
                f"{self.desc}: {done}/{self.fmt.format(self.total)} {self.unit} "
                f"({frac:.0%}), {elapsed:.0f} s elapsed, ~{eta:.0f} s left"
            )
        else:
            text = f"{self.desc}: {done} {self.unit}, {elapsed:.0f} s elapsed"
        if self.postfix:
            text += f", {self.postfix}"
        print(text, file=self.stream, flush=True)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._emit(time.perf_counter())

    def __enter__(self) -> LineBar:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class NullBar:
    """The quiet bar: accepts every call, prints nothing."""

    n = 0.0

    def update(self, n: float = 1) -> None:
        self.n += n

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> NullBar:
        return self

    def __exit__(self, *exc: Any) -> None:
        pass


def bar(
    total: float | None,
    desc: str,
    unit: str = "it",
    leave: bool = True,
    fmt: str = "{:.0f}",
    stream: TextIO | None = None,
):
    """A progress bar (tqdm, :class:`LineBar` or :class:`NullBar`, see the module doc).

    ``fmt`` formats counts for the line style (``"{:.1f}"`` for simulated seconds).
    """
    stream = sys.stderr if stream is None else stream
    chosen = style(stream)
    if chosen == "off":
        return NullBar()
    every = float(os.environ.get("SWARM_PHD_PROGRESS_EVERY_S", "30"))
    if chosen == "lines":
        return LineBar(total, desc, unit, stream, every, fmt)
    try:
        from tqdm import tqdm
    except ImportError:  # a core dependency, but never fail a run over a bar
        return LineBar(total, desc, unit, stream, every, fmt)

    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        leave=leave,
        file=stream,
        dynamic_ncols=True,
        bar_format=None
        if unit != "s sim"
        else "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s simulated "
        "[{elapsed}<{remaining}, {rate_fmt}]",
    )


def sim_steps(n_steps: int, dt_s: float, desc: str, leave: bool = True) -> Iterator[int]:
    """``range(n_steps)`` with a bar in simulated seconds (``dt_s`` per step).

    The bar closes when the loop ends or is left early (``break``, an exception).
    """
    total = n_steps * dt_s
    b = bar(total, desc, unit="s sim", leave=leave, fmt="{:.1f}")
    try:
        for k in range(n_steps):
            yield k
            b.update(min((k + 1) * dt_s, total) - b.n)  # no float drift past the total
    finally:
        b.close()


def over(items: Iterable[T], desc: str, unit: str = "seed", total: int | None = None):
    """Iterate ``items`` with a bar counting them (seeds, cases, localizers)."""
    items = list(items) if total is None else items
    n = len(items) if total is None else total  # type: ignore[arg-type]
    b = bar(n, desc, unit=unit)
    try:
        for item in items:
            yield item
            b.update(1)
    finally:
        b.close()
