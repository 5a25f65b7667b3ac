"""Where a result came from: the source tree's git commit, for the files that record one."""

from __future__ import annotations

import subprocess
from pathlib import Path

__all__ = ["source_commit"]

_ROOT = Path(__file__).resolve().parent.parent


def source_commit(mark_dirty: bool = True) -> str | None:
    """The short commit of the source tree this package runs from, with ``+dirty`` appended
    when tracked files have uncommitted changes (unless ``mark_dirty`` is False); None outside
    a git checkout or without git."""

    def git(*args: str) -> str:
        command = ["git", "-C", str(_ROOT), *args]
        done = subprocess.run(command, capture_output=True, text=True, timeout=10, check=True)
        return done.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = mark_dirty and git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    return (head + ("+dirty" if dirty else "")) or None
