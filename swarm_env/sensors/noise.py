"""Fast standard-normal draws for per-beam sensor noise.

``Generator.standard_normal`` costs ~10 ns a sample on the reference machine; a lidar step needs
~20 000 of them (14 scans x 720 beams x range and intensity), a tenth of the whole simulator
step. Here a sample is a 16-bit uniform index into a table of the normal's quantiles at the
65 536 bin centres (inverse-CDF sampling, quantised): ~3x cheaper, and any function of the
sample (e.g. the log-normal factor ``exp(s z)``) is tabulated too, so it costs one gather.

The law differs from a Gaussian only where no sensor model can tell: values are quantised
(steps of ~4e-5 sigma near 0) and truncated at +-4.32 sigma (probability 1.5e-5 beyond that
for a true Gaussian). The table is rescaled to exactly zero mean and unit variance.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from scipy.special import ndtri

_BITS = 16
_SIZE = 1 << _BITS


def _standard_table() -> np.ndarray:
    z = ndtri((np.arange(_SIZE) + 0.5) / _SIZE)
    return z / z.std()  # symmetric, so the mean is exactly 0


_STANDARD = _standard_table()


@cache
def _table(kind: str, scale: float) -> np.ndarray:
    """Read-only float32 table of ``scale z`` (kind "normal") or ``exp(scale z)`` ("lognormal")."""
    z = scale * _STANDARD
    table = np.ascontiguousarray(z if kind == "normal" else np.exp(z), dtype=np.float32)
    table.setflags(write=False)
    return table


class TabulatedNormal:
    """``scale z`` or ``exp(scale z)`` for standard-normal ``z``, drawn as table lookups.

    Parameters
    ----------
    kind : {"normal", "lognormal"}
        ``"normal"``: additive noise ``N(0, scale^2)``; ``"lognormal"``: multiplicative factor
        ``exp(N(0, scale^2))``.
    scale : float
        Standard deviation of the underlying normal (>= 0).

    Notes
    -----
    Tables are built once per ``(kind, scale)`` and shared; a pickled instance stores only
    ``(kind, scale)`` (an env pickle stays small).

    Examples
    --------
    >>> TabulatedNormal("lognormal", 0.05).draw(np.random.default_rng(0), 4).shape
    (4,)
    """

    def __init__(self, kind: str = "normal", scale: float = 1.0) -> None:
        if kind not in ("normal", "lognormal"):
            raise ValueError(f"TabulatedNormal.kind must be 'normal' or 'lognormal', got {kind!r}")
        if not (np.isfinite(scale) and scale >= 0.0):
            raise ValueError(f"TabulatedNormal.scale must be finite and >= 0, got {scale!r}")
        self.kind, self.scale = kind, float(scale)
        self.table = _table(self.kind, self.scale)

    def __reduce__(self) -> tuple:
        return (TabulatedNormal, (self.kind, self.scale))

    def draw(self, rng: np.random.Generator, size: int | tuple[int, ...]) -> np.ndarray:
        """``size`` independent float32 draws; consumes ``rng`` as ``rng.integers(.., uint16)``."""
        index = rng.integers(0, _SIZE, size=size, dtype=np.uint16)
        return self.table[index]
