"""numba's on-disk kernel cache, stamped with every kernel source of the project, not one file.

numba stamps a cached kernel with the hash of its own source file. A kernel that calls a kernel
from another module (the filter bank's camera update calls
``localization.scan_evidence.scan_factors_into``) holds the callee's machine code in its own
cache entry. After an edit or a ``git pull`` that changes only the callee's file, the caller's
entry still matches its own file, so it is loaded and silently runs the old callee.

:func:`install` puts cache locators in front of numba's own. For a kernel in one of
:data:`PACKAGES` they keep numba's cache place (``__pycache__`` next to the source, or
``$NUMBA_CACHE_DIR``) but stamp the entry with :func:`project_stamp`: the hash of every ``.py``
file of those packages that defines a kernel (an edit to a module without kernels recompiles
nothing). Any change to a kernel source then recompiles every kernel once (about two minutes
on a 2-core VM; ``swarm-phd warmup`` does it ahead of time). Other code's kernels keep numba's
locators. ``$NUMBA_CACHE_LOCATOR_CLASSES``, if set, overrides both (numba's own switch).

:mod:`swarm_core` calls :func:`install` on import, before any package defines a kernel:
numba picks a kernel's locator when the ``@njit(cache=True)`` decorator runs.
"""

from __future__ import annotations

import functools
import hashlib
import re
from pathlib import Path

from numba.core import caching

#: Packages whose kernels share the project stamp (their modules call each other's kernels).
PACKAGES = ("swarm_core", "swarm_env", "localization")
#: The directory holding the packages (the repository root in a checkout).
ROOT = Path(__file__).resolve().parent.parent


# A kernel: a line that starts with an ``@njit`` / ``@numba.njit`` / ``@jit`` decorator.
_KERNEL_DECORATOR = re.compile(rb"^[ \t]*@(?:numba\.)?n?jit\b", re.MULTILINE)


def sources_stamp(root: Path, packages: tuple[str, ...] = PACKAGES) -> str:
    """SHA-256 over the path and content of every ``.py`` file under ``root / package`` that
    defines a kernel (an ``@njit`` decorator), in sorted order (hex)."""
    digest = hashlib.sha256()
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            data = path.read_bytes()
            if _KERNEL_DECORATOR.search(data):
                digest.update(path.relative_to(root).as_posix().encode())
                digest.update(hashlib.sha256(data).digest())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def project_stamp() -> str:
    """:func:`sources_stamp` of this installation's packages, computed once per process."""
    return sources_stamp(ROOT)


def _in_project(py_file: str) -> bool:
    try:
        parts = Path(py_file).resolve().relative_to(ROOT).parts
    except ValueError:
        return False
    return len(parts) > 1 and parts[0] in PACKAGES


class _ProjectStamped:
    """Mixin: only the project's kernels, stamped with :func:`project_stamp`."""

    def get_source_stamp(self):
        return ("swarm-phd kernel sources", project_stamp())

    @classmethod
    def from_function(cls, py_func, py_file):
        if not _in_project(py_file):
            return None
        return super().from_function(py_func, py_file)


class ProjectUserProvidedCacheLocator(_ProjectStamped, caching.UserProvidedCacheLocator):
    """numba's ``$NUMBA_CACHE_DIR`` locator, with the project stamp."""


class ProjectInTreeCacheLocator(_ProjectStamped, caching.InTreeCacheLocator):
    """numba's ``__pycache__`` locator, with the project stamp."""


class ProjectUserWideCacheLocator(_ProjectStamped, caching.UserWideCacheLocator):
    """numba's per-user locator (read-only source trees), with the project stamp."""


LOCATORS = (
    ProjectUserProvidedCacheLocator,
    ProjectInTreeCacheLocator,
    ProjectUserWideCacheLocator,
)


def install() -> None:
    """Put :data:`LOCATORS` first in numba's locator list, in numba's own order (idempotent)."""
    classes = caching.CacheImpl._locator_classes  # numba's list; no public hook for it
    for cls in reversed(LOCATORS):
        if cls not in classes:
            classes.insert(0, cls)
