"""Small checks shared by the config dataclasses: each error names the field and the value."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np


def is_real(value: object) -> bool:
    """A real number (Python or numpy), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_number(
    name: str,
    value: Any,
    *,
    integer: bool = False,
    low: float | None = None,
    high: float | None = None,
    above: bool = False,
    below: bool = False,
    optional: bool = False,
    schedule: bool = False,
) -> None:
    """Refuse ``value`` unless it is a finite number (an int with ``integer``; never a bool) in
    ``[low, high]`` (open at ``low`` with ``above``, at ``high`` with ``below``); None passes
    with ``optional``, a callable (an SB3 schedule) with ``schedule``. The ``ValueError`` names
    ``name`` (a field, or a command-line flag) and the value. The one number check of the
    project: the others below are its common cases."""
    if (optional and value is None) or (schedule and callable(value)):
        return
    if integer:
        ok = is_real(value) and isinstance(value, numbers.Integral)
        kind = "an integer"
    else:
        try:
            ok = is_real(value) and math.isfinite(value)
        except OverflowError:  # an int beyond the float range (10**400)
            ok = False
        kind = "a finite number"
    ok = ok and (low is None or value > low or (value == low and not above))
    ok = ok and (high is None or value < high or (value == high and not below))
    if ok:
        return
    if low is not None and high is not None:
        bounds = f" in {'(' if above else '['}{low}, {high}{')' if below else ']'}"
    elif low is not None:
        bounds = f" {'>' if above else '>='} {low}"
    elif high is not None:
        bounds = f" {'<' if below else '<='} {high}"
    else:
        bounds = ""
    raise ValueError(f"{name} must be {kind}{bounds}, got {value!r}")


def check_positive(name: str, value: float) -> None:
    """Raise ``ValueError`` unless ``value`` is a finite number > 0."""
    check_number(name, value, low=0, above=True)


def check_non_negative(name: str, value: float) -> None:
    """Raise ``ValueError`` unless ``value`` is a finite number >= 0."""
    check_number(name, value, low=0)


def check_int_range(name: str, value: int, low: int, high: int) -> None:
    """Raise ``ValueError`` unless ``value`` is an int in ``[low, high]``."""
    check_number(name, value, integer=True, low=low, high=high)


def check_probability(name: str, value: float) -> None:
    """Raise ``ValueError`` unless ``value`` is in [0, 1]."""
    if not is_real(value) or not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be a probability in [0, 1], got {value!r}")


#: The narrowest blind sector accepted (deg): far below a beam spacing (0.5 deg on the X4),
#: and wide enough that ``1 / sigma^2`` (rad^-2) keeps the sector's geometry to ~1e-10.
MIN_BLIND_SECTOR_WIDTH_DEG = 1e-3


def check_blind_sectors(owner: str, centers_deg: object, widths_deg: object) -> None:
    """Raise ``ValueError`` unless the blind sectors ``centers_deg`` / ``widths_deg`` are valid.

    One rule for every user of the camera-pillar sectors (the simulated lidar, the filter's
    blind-sector factor, the perception code on real robots), so a value accepted by one is
    accepted by all: two tuples of finite numbers (degrees, robot frame) of equal length, each
    width in ``[MIN_BLIND_SECTOR_WIDTH_DEG, 360)``. A width of 0 is rejected (the filter's
    factor divides by it), and so is a width too small to be a pillar: the compiled filter
    keeps each sector as ``1 / sigma^2`` and recovers its direction and half-width from it,
    which loses precision as ``sigma`` goes to 0. No sectors at all is written as two empty
    tuples. ``owner`` prefixes the field names in the message, e.g. ``"LidarConfig"``.
    """
    for name, value in (
        ("blind_sector_centers_deg", centers_deg),
        ("blind_sector_widths_deg", widths_deg),
    ):
        ok = isinstance(value, tuple) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in value
        )
        if not ok:
            raise ValueError(f"{owner}.{name} must be a tuple of finite numbers, got {value!r}")
    if len(centers_deg) != len(widths_deg):  # type: ignore[arg-type]
        raise ValueError(
            f"{owner}.blind_sector_widths_deg must have one width per centre, got "
            f"{widths_deg!r} for blind_sector_centers_deg={centers_deg!r}"
        )
    for width in widths_deg:  # type: ignore[union-attr]
        if not MIN_BLIND_SECTOR_WIDTH_DEG <= width < 360.0:
            raise ValueError(
                f"{owner}.blind_sector_widths_deg must be in [{MIN_BLIND_SECTOR_WIDTH_DEG}, 360) "
                f"deg, got {width!r}"
            )


def as_float_array(value: object, name: str) -> np.ndarray:
    """``value`` as a float64 ndarray (no copy if it already is one).

    Raises ``ValueError`` naming ``name`` and the value when it is not numeric. Shape and
    finiteness are the caller's to check (they differ per field).
    """
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric, got {value!r}") from exc


def check_number_fields(obj: object, owner: str | None = None) -> None:
    """Every field of the dataclass ``obj`` annotated ``int`` or ``float`` must hold a finite
    number of that kind, and every field annotated ``bool`` a bool: ``ValueError`` naming
    ``owner.field`` and the value otherwise.

    The one type check every config runs first (its own ranges come after it), so a string,
    ``None``, a bool, NaN, infinity or an int too large for a float (``10**400``, whose
    comparisons with floats raise ``OverflowError``) never reaches a comparison or a kernel.
    """
    import dataclasses
    import reprlib

    owner = owner or type(obj).__name__
    for f in dataclasses.fields(obj):  # type: ignore[arg-type]
        annotation = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        if annotation == "bool":
            value = getattr(obj, f.name)
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{owner}.{f.name} must be True or False, got {value!r}")
            continue
        if annotation not in ("int", "float"):
            continue
        value = getattr(obj, f.name)
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2**63 - 1:
            # Beyond int64 / float range: numpy and every float comparison would overflow.
            raise ValueError(f"{owner}.{f.name} is too large, got {reprlib.repr(value)}")
        if annotation == "int":
            kinds: tuple[type, ...] = (int, np.integer)
        else:
            kinds = (int, float, np.integer, np.floating)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds):
            kind = "an int" if annotation == "int" else "a real number"
            raise ValueError(f"{owner}.{f.name} must be {kind}, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{owner}.{f.name} must be finite, got {value!r}")
