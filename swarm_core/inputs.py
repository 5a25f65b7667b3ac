"""Checks of command-line input, one set for every command and trainer (numbers through
:func:`swarm_core.validation.check_number`, the config dataclasses' checks); the checks that
need the env's presets are :mod:`swarm_phd.presets`.

Bad input gets a clear error before any work: each check raises :class:`ValueError` naming the
flag and the value, which the ``swarm-phd`` CLI prints as one line
``swarm-phd COMMAND: error: ...`` (exit status 2, no traceback). A command calls them at the top
of its ``run``, before it builds an env or runs an episode. The output checks create nothing:
they refuse a location the command could not write after its run.
"""

from __future__ import annotations

import argparse
import json
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from swarm_core.validation import check_number, check_positive


def integer(flag: str, value: Any, *, minimum: int) -> int:
    """``value`` if it is an integer >= ``minimum``."""
    check_number(flag, value, integer=True, low=minimum)
    return int(value)


def seed(flag: str, value: Any) -> int:
    """A random seed: a non-negative integer (what numpy's generators take)."""
    return integer(flag, value, minimum=0)


def duration(flag: str, value: Any, control_period_s: float | None = None) -> float:
    """Simulated seconds: finite, > 0 and, given the env's control period, at least one
    period (a shorter run would take no step)."""
    check_positive(flag, value)
    if control_period_s is not None and value < control_period_s:
        raise ValueError(
            f"{flag} must be at least one control period ({control_period_s:g} s), got {value!r}"
        )
    return value


def steps_in(env: Any, flag: str, duration_s: float) -> int:
    """The control steps ``duration_s`` makes in a built ``env``: refused (``env`` closed first)
    when that is not one step, for a command that learns the period only from its env."""
    period = env.config.control_period_s
    if duration_s < period:
        env.close()
        duration(flag, duration_s, period)
    return int(round(duration_s / period))


def add_duration_argument(
    parser: argparse.ArgumentParser, default: float, what: str = "simulated seconds"
) -> None:
    """``--duration`` (s), for a command to share; :func:`duration` checks it. (``mutual``
    defines its own: without one, each scenario runs for its own duration.)"""
    parser.add_argument(
        "--duration",
        type=float,
        default=default,
        help=f"{what} (at least one control period)",
    )


def add_seed_argument(parser: argparse.ArgumentParser, what: str = "random seed") -> None:
    """``--seed`` (an integer >= 0, default 0), for a command to share; :func:`seed` checks
    it."""
    parser.add_argument("--seed", type=int, default=0, help=f"{what} (>= 0)")


def parse_seeds(text: str, name: str = "--seeds") -> list[int]:
    """``"0-3,7"`` -> ``[0, 1, 2, 3, 7]``; ValueError naming ``name`` and the text otherwise
    (a negative seed included)."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        match = re.fullmatch(r"(-?\d+)(?:-(-?\d+))?", part)
        if match is not None and (int(match[1]) < 0 or int(match[2] or 0) < 0):
            raise ValueError(f"{name} must be non-negative integers, got {text!r}")
        if match is None or (match[2] is not None and int(match[2]) < int(match[1])):
            raise ValueError(
                f"{name} must be comma-separated integers or ranges like 0-9, got {text!r}"
            )
        lo = int(match[1])
        seeds.extend(range(lo, int(match[2] if match[2] is not None else lo) + 1))
    if not seeds:
        raise ValueError(f"{name} names no seed: {text!r}")
    return seeds


def format_seeds(seeds: Iterable[int]) -> str:
    """The inverse of :func:`parse_seeds`: ``[0, 1, 2, 3, 7]`` -> ``"0-3,7"`` (runs of
    consecutive seeds as ranges, in the given order)."""
    parts: list[str] = []
    run: list[int] = []
    for seed in (int(s) for s in seeds):
        if run and seed == run[-1] + 1:
            run.append(seed)
            continue
        if run:
            parts.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [seed]
    if run:
        parts.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return ",".join(parts)


def parse_json_object(text: str | None, name: str) -> dict[str, Any]:
    """A JSON object given on the command line (``None``: ``{}``); ValueError naming ``name``
    and the text otherwise."""
    if text is None:
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{name} must be a JSON object, got {text!r}: {exc}") from exc
    if not isinstance(value, dict):
        raise ValueError(f"{name} must be a JSON object, got {text!r}")
    return value


def output_dir(flag: str, path: str | Path) -> Path:
    """A directory the command writes into after its run (made then, with its parents):
    refused now if it is not a directory, or cannot be made or written."""
    p = Path(path)
    if _exists(p) and not p.is_dir():
        raise ValueError(f"{flag} {str(path)!r}: exists and is not a directory")
    _check_creatable(flag, path, p)
    return p


def output_file(flag: str, path: str | Path) -> Path:
    """A file the command writes after its run (its directory made then): refused now if it is
    a directory, or its directory cannot be made or written."""
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{flag} {str(path)!r}: is a directory, not a file")
    if _exists(p) and not os.access(p, os.W_OK):
        raise ValueError(f"{flag} {str(path)!r}: not writable")
    _check_creatable(flag, path, p.parent)
    return p


def add_overwrite_argument(parser: argparse.ArgumentParser) -> None:
    """``--overwrite``, shared by the trainers: ``--out`` must otherwise be new or empty."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="train into an --out that holds a previous run anyway: the files the new run "
        "writes replace the old ones, and the others (older checkpoints, tensorboard runs) "
        "stay (default: refuse, so that a rerun never replaces a finished run)",
    )


def run_dir(
    flag: str,
    path: str | Path,
    *,
    overwrite: bool,
    holding: str = "a previous run",
    action: str = "train into",
) -> Path:
    """A run's output directory: new or empty, unless ``overwrite``. A rerun with the same
    ``--out`` would otherwise replace a finished run's model (or results), empty its monitor
    and mix its checkpoints with the new run's: "choose a new directory or pass --overwrite".
    ``holding`` and ``action`` word the refusal (``"{flag} ... holds {holding} (...): ...
    pass --overwrite to {action} it anyway"``); the defaults speak of training."""
    p = output_dir(flag, path)
    held = sorted(x.name for x in p.iterdir()) if p.is_dir() else []
    if held and not overwrite:
        shown = ", ".join(held[:4]) + (", ..." if len(held) > 4 else "")
        raise ValueError(
            f"{flag} {str(path)!r} holds {holding} ({shown}): choose a new directory, "
            f"or pass --overwrite to {action} it anyway"
        )
    return p


def new_bag_dir(flag: str, path: str | Path) -> Path:
    """A directory the command creates (a bag): refused if it exists, or cannot be made."""
    p = Path(path)
    if _exists(p):
        raise ValueError(f"{flag} {str(path)!r} exists already; bags are never overwritten")
    _check_creatable(flag, path, p.parent)
    return p


def _exists(p: Path) -> bool:
    try:
        return p.exists()
    except OSError:  # e.g. a parent that cannot be searched: not there for this user
        return False


def _check_creatable(flag: str, path: str | Path, directory: Path) -> None:
    """``directory`` exists and is writable, or its nearest existing ancestor is a writable
    directory (``mkdir(parents=True)`` will succeed)."""
    probe = directory
    while not _exists(probe) and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ValueError(f"{flag} {str(path)!r}: {str(probe)!r} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {str(path)!r}: directory {str(probe)!r} is not writable")
