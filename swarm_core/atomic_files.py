"""Outputs that are never half-written: write to a temporary file beside, then rename.

A reader (or a crash, a Ctrl-C, a SIGTERM) sees either the old file or the whole new one:
``os.replace`` is atomic on one filesystem, and the temporary file is in the target's own
directory. Every command that writes results (evaluate, sweep, seed003, train) goes through
:func:`atomic_write`.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["atomic_write", "write_text_atomically", "write_json_atomically"]


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(tmp)`` to produce the file at a temporary path, then rename it to ``path``.

    The temporary name keeps ``path``'s suffix (libraries such as SB3 or matplotlib pick the
    format from it). On any exception the temporary file is removed and ``path`` is untouched.
    Returns ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        # mkstemp makes the file owner-only; give it what a plain open() would have.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)  # the only portable way to read it: set and restore
    os.umask(mask)
    return mask


def write_text_atomically(path: str | Path, text: str) -> Path:
    """``path.write_text(text)``, atomically (:func:`atomic_write`) and flushed to disk."""

    def write(tmp: Path) -> None:
        with tmp.open("w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    return atomic_write(path, write)


def write_json_atomically(path: str | Path, data: Any, indent: int = 2) -> Path:
    """``data`` as JSON at ``path``, atomically (:func:`atomic_write`)."""
    return write_text_atomically(path, json.dumps(data, indent=indent))
