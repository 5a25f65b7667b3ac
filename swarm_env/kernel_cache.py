"""Where the numba kernels stand: compiled in this process, cached on disk, or neither.

Every hot-path kernel is ``@njit(cache=True)``: the first process compiles it (about a minute
for all of them on a 2-core VM) and writes it to numba's cache; later processes load it in ~2 s.
numba keeps the cache next to the source (``__pycache__/*.nbi`` index + ``*.nbc`` code), or
under ``$NUMBA_CACHE_DIR`` when that is set (read once, when numba is imported). An entry is
reused while every kernel source of the project, and every project module those import, is
unchanged (a content hash over all of them, :mod:`swarm_core.kernel_stamp`: a kernel carries
the code of the kernels it calls from other modules and the constants it reads), so it
survives a reinstall that leaves the sources alone; any change to one of them compiles every
kernel once more.

:func:`status` inspects that state without compiling anything; :func:`first_use_note` is the
one-line message :func:`swarm_env.parallel_env` prints when a process is about to compile.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

#: Packages whose kernels the env runs (searched among the modules already imported).
PACKAGES = ("swarm_core", "swarm_env", "localization")
_noted = False
#: What the first env of the process does in place of the note (the CLI's compile with a bar).
_first_use_action: Callable[[], object] | None = None


@dataclass(frozen=True)
class KernelStatus:
    """``total`` kernels found; ``on_disk`` have an up-to-date cache entry; ``in_memory`` have been
    compiled or loaded in this process."""

    total: int
    on_disk: int
    in_memory: int
    names: tuple[str, ...]

    @property
    def cold(self) -> bool:
        """Some kernel has no cache file: the next first call compiles it."""
        return self.on_disk < self.total


def dispatchers(modules: list[str] | None = None) -> dict[str, object]:
    """``{module.name: numba dispatcher}`` of the project's stand-alone kernels.

    ``modules`` lists modules to import first; by default only the modules already imported
    from :data:`PACKAGES` are searched. Kernels marked ``inline="always"`` are left out: they
    are compiled into their callers and have no cache entry of their own.
    """
    from numba.core.registry import CPUDispatcher

    for name in modules or ():
        importlib.import_module(name)
    found: dict[str, object] = {}
    for mod_name, mod in list(sys.modules.items()):
        if mod is None or mod_name.split(".")[0] not in PACKAGES:
            continue
        for attr, value in list(vars(mod).items()):
            if (
                isinstance(value, CPUDispatcher)
                and value.__module__ == mod_name
                and value.targetoptions.get("inline") != "always"
            ):
                found[f"{mod_name}.{attr}"] = value
    return dict(sorted(found.items()))


def _index_path(dispatcher: object) -> str | None:
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    return getattr(cache_file, "_index_path", None)  # numba internals; None if they change


def _cached(dispatcher: object) -> bool:
    """A cache index exists and matches the sources' stamp (numba's own staleness test:
    ``_load_index`` returns an empty dict for a missing or stale index)."""
    path = _index_path(dispatcher)
    if not path or not os.path.exists(path):
        return False
    try:
        return bool(dispatcher._cache._cache_file._load_index())  # type: ignore[attr-defined]
    except Exception:  # an unreadable index is recompiled by numba, so: not cached
        return False


def status(modules: list[str] | None = None) -> KernelStatus:
    """The kernels' state (see :class:`KernelStatus`); compiles nothing."""
    found = dispatchers(modules)
    on_disk = sum(_cached(d) for d in found.values())
    in_memory = sum(bool(d.overloads) for d in found.values())
    return KernelStatus(len(found), on_disk, in_memory, tuple(found))


def cache_location() -> str:
    """Where numba writes the cache: ``$NUMBA_CACHE_DIR`` or each package's ``__pycache__``."""
    from numba.core.config import CACHE_DIR

    return CACHE_DIR or "__pycache__ next to each source file"


def mark_noted() -> None:
    """Skip :func:`first_use_note` in this process (a caller prints its own message)."""
    global _noted
    _noted = True


def set_first_use_action(action: Callable[[], object] | None) -> None:
    """Run ``action`` (once) where the first env of this process would print its note: the CLI
    compiles there, after the command has checked its input, so a bad flag is refused at once
    even when every kernel must compile first. ``None`` restores the note."""
    global _first_use_action
    _first_use_action = action


def first_use_note(stream=None) -> bool:
    """Print, once per process and only if some kernel must compile, a one-line note saying so
    (or run the action of :func:`set_first_use_action` instead, once).

    Returns whether it printed (or acted). ``SWARM_PHD_QUIET=1`` silences the note.
    """
    global _noted, _first_use_action
    if not _noted and _first_use_action is not None:
        _noted = True  # the action builds envs of its own: they must not act again
        action, _first_use_action = _first_use_action, None
        action()
        return True
    if _noted or os.environ.get("SWARM_PHD_QUIET", "") not in ("", "0"):
        return False
    _noted = True
    try:
        state = status()
    except Exception:  # an internals change in numba must never break building an env
        return False
    if not state.cold or state.in_memory == state.total:
        return False
    n = state.total - state.on_disk
    print(
        f"swarm-phd: compiling {n} numba kernel{'s' if n != 1 else ''} on first use "
        f"(about a minute, once; cached in {cache_location()}). "
        f"`swarm-phd warmup` does this ahead of time.",
        file=sys.stderr if stream is None else stream,
        flush=True,
    )
    return True
