"""numba's on-disk kernel cache, stamped with every kernel source of the project, not one file.

numba stamps a cached kernel with the hash of its own source file. A kernel that calls a kernel
from another module (the filter bank's camera update calls
``localization.object_clutter.clutter_density_into``) holds the callee's machine code in its own
cache entry. After an edit or a ``git pull`` that changes only the callee's file, the caller's
entry still matches its own file, so it is loaded and silently runs the old callee.

:func:`install` puts cache locators in front of numba's own. For a kernel in one of
:data:`PACKAGES` they keep numba's cache place (``__pycache__`` next to the source, or
``$NUMBA_CACHE_DIR``) but stamp the entry with :func:`project_stamp`: the hash of every ``.py``
file of those packages that defines a kernel, and of the project modules those import,
transitively (:func:`kernel_sources`: a kernel bakes in the constants it reads). Any change
to one of them recompiles every kernel once (about two minutes on a 2-core VM; ``swarm-phd
warmup`` does it ahead of time); an edit to a module outside that set (the env, the tasks,
the trainers) recompiles nothing. Other code's kernels keep numba's
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


# Import statements, read without parsing the module (``ast`` takes ~0.4 s for the project):
# ``from <dots><module> import <names or (names)>`` and ``import <modules>``.
_FROM_IMPORT = re.compile(
    rb"^[ \t]*from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]*(\([^)]*\)|[^\n#]*)", re.MULTILINE
)
_IMPORT = re.compile(rb"^[ \t]*import[ \t]+([\w., \t]+)", re.MULTILINE)
_NAME = re.compile(rb"[A-Za-z_]\w*")


def _project_imports(path: Path, text: bytes, root: Path, scope: dict) -> set[Path]:
    """The files in ``scope`` that module ``path`` (source ``text``) imports (``import a.b``,
    ``from a import b``, ``from .c import d``; a name may be a module or a value of one).
    Imports inside functions count too: a superset is safe, it only recompiles more often."""
    package = path.relative_to(root).parts[:-1]  # the package holding the module
    modules: list[tuple[str, ...]] = []
    for dots, module, names in _FROM_IMPORT.findall(text):
        level = len(dots)
        base = package[: len(package) - level + 1] if level else ()
        parts = base + tuple(module.decode().split(".") if module else ())
        modules.append(parts)
        modules.extend(parts + (name.decode(),) for name in _NAME.findall(names))
    for names in _IMPORT.findall(text):
        modules.extend(
            tuple(n.strip().split(" ")[0].split(".")) for n in names.decode().split(",")
        )
    found: set[Path] = set()
    for parts in modules:
        if not parts or not all(parts):
            continue
        for candidate in (
            root.joinpath(*parts[:-1], parts[-1] + ".py"),
            root.joinpath(*parts, "__init__.py"),
        ):
            if candidate in scope:
                found.add(candidate)
    return found


def kernel_sources(root: Path, packages: tuple[str, ...] = PACKAGES) -> dict[Path, bytes]:
    """The ``.py`` files under ``root / package`` that a kernel's compiled code can depend on,
    with their contents: those that define a kernel (an ``@njit`` decorator) and,
    transitively, the project modules they import (a kernel bakes in the constants it reads,
    such as a table of Gauss-Hermite nodes from a module without kernels). Sorted by path."""
    root = root.resolve()
    scope = {p: p.read_bytes() for pkg in packages for p in (root / pkg).rglob("*.py")}
    todo = [p for p, text in scope.items() if _KERNEL_DECORATOR.search(text)]
    seen = set(todo)
    while todo:
        path = todo.pop()
        for dependency in _project_imports(path, scope[path], root, scope) - seen:
            seen.add(dependency)
            todo.append(dependency)
    return {p: scope[p] for p in sorted(seen)}


def sources_stamp(root: Path, packages: tuple[str, ...] = PACKAGES) -> str:
    """SHA-256 over the path and content of every :func:`kernel_sources` file (hex)."""
    root = root.resolve()
    digest = hashlib.sha256()
    for path, text in kernel_sources(root, packages).items():
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(hashlib.sha256(text).digest())
    return digest.hexdigest()


@functools.lru_cache(maxsize=4)
def _stamp_of(files: tuple[tuple[str, int, int], ...]) -> str:
    """:func:`sources_stamp` of :data:`ROOT`; ``files`` (path, mtime, size) is the cache key."""
    return sources_stamp(ROOT)


def project_stamp() -> str:
    """:func:`sources_stamp` of this installation's packages, recomputed only when a file's
    modification time or size changed (as numba re-hashes its own stamp), so a module
    reloaded after an edit in a running process gets a fresh stamp."""
    files = []
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            st = path.stat()
            files.append((str(path), st.st_mtime_ns, st.st_size))
    return _stamp_of(tuple(sorted(files)))


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
