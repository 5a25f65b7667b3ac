"""Compile (or load) every numba kernel ahead of time, with progress (``swarm-phd warmup``).

It builds a tiny env in each filter mode and steps it a few times, as the test suite does at
session start: that calls every kernel the simulator and the filters use, so numba compiles
them and writes its cache (see :mod:`swarm_env.kernel_cache`). Later processes load them in a
couple of seconds. The bar counts kernels compiled or loaded so far; a background thread keeps
it moving while numba works (the compile of one kernel blocks the main thread for seconds).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from swarm_core import progress

#: Env settings that together call every kernel: both filter modes (each compiles its own
#: specialisations) and the raw-measurement observation (its table kernel).
CASES = (
    {"phd": {"mode": "lidar-camera"}},
    {"phd": {"mode": "lidar-only"}},
    {"localizer": "pmb-lc"},
    {"localizer": "pmb-lo"},
    {"observation": "measurements", "localize": False},
    # Big swarms take other kernels (the grid index, the compiled ground truth): compile them
    # too, or every command would find them cold and say so.
    {"preset": "sim-13m-100", "observation": "measurements", "localize": False, "steps": 2},
)
_ENV_MODULES = [
    "swarm_env.env",
    "swarm_env.observation",
    "swarm_env.world.sim",
    "swarm_env.sensors.lidar",
    "swarm_env.sensors.camera",
    "swarm_env.sensors.odometry",
    "localization.kernels",
    "localization.pmb.kernels",
]


def warmup(preset: str = "lab-3m-4", steps: int = 5) -> dict[str, float | int | bool | str]:
    """Compile or load every kernel; return what happened (counts, seconds, cache place)."""
    from swarm_env import kernel_cache, parallel_env

    importable = _importable()
    kernel_cache.mark_noted()  # this command prints its own message
    before = kernel_cache.status(importable)
    cold = before.cold
    verb = "compiling" if cold else "loading"
    progress.note(
        f"swarm-phd warmup: {verb} {before.total} numba kernels "
        f"({'about a minute, once' if cold else 'cached'}; cache: "
        f"{kernel_cache.cache_location()})"
    )
    start = time.perf_counter()
    # Only a compile is worth a bar: loading takes ~2 s, and a loaded caller carries its
    # callees inside its own cache entry, so they never show up as loaded on their own.
    bar = progress.bar(before.total, "kernels", unit="kernel") if cold else progress.NullBar()
    done = threading.Event()

    def tick() -> None:  # numba compiles in the main thread; report its progress from here
        seen = 0
        while not done.wait(0.5):
            now = sum(bool(d.overloads) for d in kernel_cache.dispatchers().values())
            now = min(now, before.total)
            if now > seen:
                bar.update(now - seen)
                seen = now
            else:
                bar.refresh()  # the elapsed time keeps moving on a terminal
        final = min(kernel_cache.status().in_memory, before.total)
        if final > seen:
            bar.update(final - seen)

    ticker = threading.Thread(target=tick, name="warmup-progress", daemon=True)
    ticker.start()
    try:
        for case in CASES:
            kwargs = dict(case)
            case_steps = kwargs.pop("steps", steps)
            env = parallel_env(kwargs.pop("preset", preset), max_steps=case_steps + 1, **kwargs)
            env.reset(seed=0)
            for _ in range(case_steps):
                env.step({a: np.zeros(2) for a in env.agents})
            env.close()
    finally:
        done.set()
        ticker.join()
        bar.close()
    after = kernel_cache.status()
    return {
        "compiled": cold,
        "kernels": after.in_memory if cold else after.total,
        "kernels_found": after.total,
        "cached_on_disk": after.on_disk,
        "seconds": time.perf_counter() - start,
        "cache": kernel_cache.cache_location(),
    }


def warm_if_cold() -> bool:
    """Run :func:`warmup` (message and bar) if some kernel is not cached yet; else nothing.

    Returns whether it compiled. Called by the CLI before every command that steps an env, and
    by the RLlib env runners.
    """
    from swarm_env import kernel_cache

    if not kernel_cache.status(_importable()).cold:
        return False
    warmup()
    return True


def _importable() -> list[str]:
    found = []
    for name in _ENV_MODULES:
        try:
            __import__(name)
            found.append(name)
        except ImportError:  # a module moved: the env imports what it needs anyway
            pass
    return found
