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


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile (or load from numba's cache) the sensor and filter kernels once, before any test.

    A fresh checkout compiles them on first use (tens of seconds); that must not happen inside
    a real-time test (the bridge's loopback, the watchdog) or a test with a timeout. Done here,
    outside every test, no per-test timeout applies.
    """
    from swarm_env import parallel_env

    for mode in ("lidar-camera", "lidar-only"):
        env = parallel_env("seed-lab", max_steps=10, phd={"mode": mode})
        env.reset(seed=0)
        for _ in range(5):
            env.step({a: np.zeros(2) for a in env.agents})
        env.close()
