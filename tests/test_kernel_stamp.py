"""The kernels' cache stamp (:mod:`swarm_core.kernel_stamp`): every project kernel is stamped with
all the project's kernel sources, so a caller's cache entry goes stale when a callee's file
changes."""

from __future__ import annotations

from pathlib import Path

from numba.core import caching

from swarm_core import kernel_stamp


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_the_stamp_follows_every_kernel_source_and_nothing_else(tmp_path):
    write(tmp_path / "localization" / "kernels.py", "@njit(cache=True)\ndef f(x): return g(x)\n")
    write(tmp_path / "localization" / "scan.py", "@njit(cache=True)\ndef g(x): return x\n")
    write(tmp_path / "localization" / "docs.py", '"""Uses ``@njit(cache=True)``."""\n')
    write(tmp_path / "swarm_env" / "sub" / "deep.py", "    @numba.njit\n    def k(): pass\n")
    first = kernel_stamp.sources_stamp(tmp_path)
    assert kernel_stamp.sources_stamp(tmp_path) == first
    # the callee's file changes: every kernel's stamp changes, the caller's too
    write(tmp_path / "localization" / "scan.py", "@njit(cache=True)\ndef g(x): return x + 1\n")
    second = kernel_stamp.sources_stamp(tmp_path)
    assert second != first
    write(tmp_path / "swarm_env" / "sub" / "deep.py", "    @numba.njit\n    def k(): pass  # x\n")
    assert kernel_stamp.sources_stamp(tmp_path) != second
    # a module that only mentions kernels does not count
    third = kernel_stamp.sources_stamp(tmp_path)
    write(tmp_path / "localization" / "docs.py", '"""Uses ``@njit``, edited."""\n')
    assert kernel_stamp.sources_stamp(tmp_path) == third


def test_project_kernels_use_the_project_stamp_and_others_do_not():
    from localization import kernels

    locator = kernels._camera_update._cache._impl.locator
    assert isinstance(locator, kernel_stamp.LOCATORS)
    assert locator.get_source_stamp() == ("swarm-phd kernel sources", kernel_stamp.project_stamp())
    assert kernel_stamp.project_stamp() == kernel_stamp.sources_stamp(kernel_stamp.ROOT)
    # numba's own locators still serve code outside the project
    assert not kernel_stamp._in_project(caching.__file__)
    assert kernel_stamp._in_project(kernels.__file__)
    # installing twice changes nothing
    before = list(caching.CacheImpl._locator_classes)
    kernel_stamp.install()
    assert caching.CacheImpl._locator_classes == before
