"""The kernels' cache stamp (:mod:`swarm_core.kernel_stamp`): every project kernel is stamped with
all the project's kernel sources, so a caller's cache entry goes stale when a callee's file
changes."""

from __future__ import annotations

from pathlib import Path

from numba.core import caching

from swarm_core import kernel_stamp
from swarm_core.kernel_stamp import kernel_sources


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_the_stamp_follows_every_kernel_source_and_nothing_else(tmp_path):
    write(tmp_path / "localization" / "__init__.py", "")
    write(
        tmp_path / "localization" / "kernels.py",
        "from .scan import g\nfrom localization.tables import (\n    NODES,\n)\n"
        "@njit(cache=True)\ndef f(x): return g(x) + NODES[0]\n",
    )
    write(tmp_path / "localization" / "scan.py", "@njit(cache=True)\ndef g(x): return x\n")
    write(tmp_path / "localization" / "tables.py", "from .deeper import BASE\nNODES = (BASE,)\n")
    write(tmp_path / "localization" / "deeper.py", "BASE = 1.0\n")
    write(tmp_path / "localization" / "docs.py", '"""Uses ``@njit(cache=True)``."""\n')
    write(tmp_path / "swarm_env" / "sub" / "deep.py", "    @numba.njit\n    def k(): pass\n")
    write(tmp_path / "swarm_env" / "env.py", "from localization import kernels\n")
    sources = kernel_sources(tmp_path)
    assert [p.relative_to(tmp_path.resolve()).as_posix() for p in sources] == [
        "localization/deeper.py",
        "localization/kernels.py",
        "localization/scan.py",
        "localization/tables.py",
        "swarm_env/sub/deep.py",
    ]
    stamps = [kernel_stamp.sources_stamp(tmp_path)]
    # the callee's file, a constant two imports away, another package's kernel: all count
    for path, text in (
        ("localization/scan.py", "@njit(cache=True)\ndef g(x): return x + 1\n"),
        ("localization/deeper.py", "BASE = 2.0\n"),
        ("swarm_env/sub/deep.py", "    @numba.njit\n    def k(): pass  # x\n"),
    ):
        write(tmp_path / path, text)
        stamps.append(kernel_stamp.sources_stamp(tmp_path))
        assert stamps[-1] != stamps[-2], path
    # a module that only mentions kernels, and one that imports them: neither counts
    write(tmp_path / "localization" / "docs.py", '"""Uses ``@njit``, edited."""\n')
    write(tmp_path / "swarm_env" / "env.py", "from localization import kernels  # edited\n")
    assert kernel_stamp.sources_stamp(tmp_path) == stamps[-1]


def test_project_kernels_use_the_project_stamp_and_others_do_not():
    from localization import kernels

    locator = kernels._camera_update._cache._impl.locator
    assert isinstance(locator, kernel_stamp.LOCATORS)
    assert locator.get_source_stamp() == ("swarm-phd kernel sources", kernel_stamp.project_stamp())
    assert kernel_stamp.project_stamp() == kernel_stamp.sources_stamp(kernel_stamp.ROOT)
    # the constants the filter kernels read from modules without kernels are covered
    covered = {
        p.relative_to(kernel_stamp.ROOT).as_posix() for p in kernel_sources(kernel_stamp.ROOT)
    }
    assert {"localization/phd.py", "localization/config.py", "localization/mixture.py"} <= covered
    assert "swarm_env/env.py" not in covered
    # numba's own locators still serve code outside the project
    assert not kernel_stamp._in_project(caching.__file__)
    assert kernel_stamp._in_project(kernels.__file__)
    # installing twice changes nothing
    before = list(caching.CacheImpl._locator_classes)
    kernel_stamp.install()
    assert caching.CacheImpl._locator_classes == before
