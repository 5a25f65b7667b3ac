"""The packages' layers point down: a module imports only its own package and the ones below.

    swarm_core < localization < swarm_env < hardware_bridge < agents < swarm_phd

Every import of every module is read with ``ast`` (those inside functions and ``if`` blocks
too: a lazy import is still a dependency), and an import of a higher package fails the test
naming the file, the line and the import. ``experiments/`` (the studies, not installed) may
import any package; no package may import it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Lowest first: a package may import itself and those before it.
LAYERS = ("swarm_core", "localization", "swarm_env", "hardware_bridge", "agents", "swarm_phd")
#: Top-level directories of the repository that no package may import.
OUTSIDE = ("experiments", "benchmarks", "tests")


def imported_modules(tree: ast.AST, module: str) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in ``tree`` (relative ones resolved
    against ``module``, the dotted name of the file; a package's ``__init__`` is the package)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: len(module.split(".")) - node.level]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            found.append((node.lineno, name))
    return found


def module_imports(root: Path, path: Path) -> list[tuple[Path, int, str]]:
    """``(file, line, module)`` of every import of the modules at ``path`` (a file, or a
    directory read recursively), ``file`` relative to ``root``."""
    if not path.exists():
        return []
    files = sorted(path.rglob("*.py")) if path.is_dir() else [path]
    found = []
    for file in files:
        rel = file.relative_to(root)
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        tree = ast.parse(file.read_text(encoding="utf-8"), filename=str(rel))
        found += [(rel, line, name) for line, name in imported_modules(tree, ".".join(parts))]
    return found


def upward_imports(root: Path = ROOT) -> list[str]:
    """``path:line: imports X (layer of X above layer of path)`` for every offending import."""
    rank = {name: i for i, name in enumerate(LAYERS)}
    problems = []
    for package in LAYERS:
        for rel, line, name in module_imports(root, root / package):
            top = name.split(".")[0]
            if top in OUTSIDE or rank.get(top, -1) > rank[package]:
                problems.append(
                    f"{rel}:{line}: imports {name} ({top} is above {package}: "
                    f"layers {' < '.join(LAYERS)})"
                )
    return problems


#: Directions inside a package: the modules under a path never import the named module. The
#: world hands the sensors a scene (they cast rays in it, never reading the world), and the
#: env hands the observation encoders what they read.
INNER_RULES = (
    ("swarm_env/sensors", "swarm_env.world"),
    ("swarm_env/observation.py", "swarm_env.env"),
)


def forbidden_imports(path: str, forbidden: str, root: Path = ROOT) -> list[str]:
    """``file:line: imports X`` for every import of ``forbidden`` (or a submodule) by the
    modules at ``path`` (a file or a directory)."""
    return [
        f"{rel}:{line}: imports {name}"
        for rel, line, name in module_imports(root, root / path)
        if name == forbidden or name.startswith(forbidden + ".")
    ]


@pytest.mark.parametrize(("path", "forbidden"), INNER_RULES)
def test_inner_directions(path, forbidden):
    problems = forbidden_imports(path, forbidden)
    assert not problems, f"{path} must not import {forbidden}:\n" + "\n".join(problems)


def test_no_package_imports_upward():
    problems = upward_imports()
    assert not problems, "upward imports:\n" + "\n".join(problems)


def test_the_packages_installed_are_the_layers():
    """``experiments/`` and ``benchmarks/`` stay out of the installed packages."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    include = project["tool"]["setuptools"]["packages"]["find"]["include"]
    assert sorted(p.rstrip("*") for p in include) == sorted(LAYERS)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("import swarm_phd.cli\n", ["x.py:1: imports swarm_phd.cli"]),
        ("def f():\n    from agents.policies import load_policy\n", ["x.py:2: imports agents"]),
        ("if True:\n    import experiments.report\n", ["x.py:2: imports experiments.report"]),
        ("from . import y\nfrom .z import w\nimport numpy\nimport swarm_core\n", []),
    ],
)
def test_the_check_finds_upward_imports_anywhere_in_a_module(tmp_path, source, expected):
    """A top-level import, one inside a function, one under ``if``; relative imports and
    imports of lower layers or other libraries pass."""
    (tmp_path / "swarm_env").mkdir()
    (tmp_path / "swarm_env" / "x.py").write_text(source)
    found = upward_imports(tmp_path)
    assert len(found) == len(expected)
    for got, want in zip(found, expected, strict=True):
        path, rest = want.split(":", 1)
        assert got.startswith(f"swarm_env/{path}:{rest}")
