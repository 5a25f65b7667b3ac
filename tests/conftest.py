"""Shared fixtures. Tests run headless and seeded."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray of 2 CPUs for a module's tests, shut down after them (one already running
    is used and left running); skipped without the ray extra."""
    ray = pytest.importorskip("ray", reason="the ray extra is not installed")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    if started:
        ray.shutdown()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile (or load from numba's cache) the sensor and filter kernels once, before any test.

    A fresh checkout compiles them on first use (tens of seconds); that must not happen inside
    a real-time test (the bridge's loopback, the watchdog) or a test with a timeout. Done here,
    outside every test, no per-test timeout applies.
    """
    from swarm_env.warmup import warmup

    warmup("lab-3m-4")  # every localizer family's kernels, both sensor modes
