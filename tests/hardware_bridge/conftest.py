"""Fixtures for the hardware bridge tests: loopback servers on ephemeral 127.0.0.1 ports.

Twisted's reactor (roslibpy) runs once per process in a daemon thread and is never stopped, so
every test shares it; each test gets its own server and its own bridge client.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("roslibpy")
pytest.importorskip("rosbags")
pytest.importorskip("websockets")

from hardware_bridge import real_env  # noqa: E402
from hardware_bridge.loopback import (  # noqa: E402
    FaultConfig,
    LoopbackServer,
    spawn,
)

ROOT = Path(__file__).resolve().parents[2]


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until true or ``timeout_s`` passes (a bounded wait, not an assertion)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def zero_times(server: LoopbackServer, after: float) -> dict[str, float]:
    """First zero-velocity cmd_vel per robot that ``server`` received after ``after``
    (monotonic s)."""
    out: dict[str, float] = {}
    for t, robot, v, w in server.twists():
        if t > after and v == 0.0 and w == 0.0 and robot not in out:
            out[robot] = t
    return out


def drive(env, steps: int, v: float = 0.2) -> dict | None:
    """``steps`` env steps commanding every agent ``[v, 0]``; the last step's infos."""
    infos = None
    for _ in range(steps):
        _, _, _, _, infos = env.step({a: np.array([v, 0.0], dtype=np.float32) for a in env.agents})
    return infos


def crash_in_step(
    env, monkeypatch: pytest.MonkeyPatch, target: Any, attr: str, v: float = 0.2
) -> float:
    """Make ``target.attr`` raise ``RuntimeError("<attr> crashed")`` (``monkeypatch`` undoes it)
    and take one step commanding every agent ``[v, 0]`` (m/s, rad/s), which must raise it:
    returns the monotonic time (s) just before that step."""

    def crashed(*args: Any, **kwargs: Any) -> None:
        raise RuntimeError(f"{attr} crashed")

    monkeypatch.setattr(target, attr, crashed)
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match=f"{attr} crashed"):
        drive(env, 1, v=v)
    return t0


def hold_the_gil(seconds: float) -> None:
    """Busy-loop for ``seconds`` without letting another thread of this process run (a step
    that hangs holding the GIL: only another process can act)."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(10.0)
    try:
        t0 = time.monotonic()
        x = 0
        while time.monotonic() - t0 < seconds:
            x += 1
    finally:
        sys.setswitchinterval(interval)


def end_process(proc: subprocess.Popen, wait_s: float) -> None:
    """Wait up to ``wait_s`` for ``proc`` to exit, kill it if it has not, and close its pipes."""
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
    for pipe in (proc.stdin, proc.stdout):
        if pipe is not None:
            pipe.close()


@pytest.fixture
def robot_process(tmp_path: Path) -> Iterator[tuple[int, Path]]:
    """Loopback robots in another process (its own GIL), logging every command they receive:
    yields ``(port, twist log path)``; the process ends (stdin closed) after the test."""
    log = tmp_path / "twists.log"
    proc, port = spawn(log, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        yield port, log
    finally:
        proc.stdin.close()  # the loopback process ends at the end of its input
        end_process(proc, 10.0)


@pytest.fixture
def loopback() -> Iterator[Callable[..., LoopbackServer]]:
    """Factory: ``loopback(seed=0, faults=None, **overrides)`` -> a started LoopbackServer."""
    servers: list[LoopbackServer] = []

    def make(seed: int = 0, faults: FaultConfig | None = None, **kwargs) -> LoopbackServer:
        server = LoopbackServer("seed-lab", seed=seed, faults=faults, **kwargs)
        server.start()
        servers.append(server)
        return server

    yield make
    for server in servers:
        server.close()


@pytest.fixture
def guarded_lab(robot_process: tuple[int, Path]) -> Iterator[tuple[Any, Path]]:
    """A ``real_env`` (preset ``seed-lab``) on :func:`robot_process`'s robots, reset with seed 0
    and its guard process connected: yields ``(env, twist log path)``; the env is closed after
    the test, before the robots' process ends."""
    port, log = robot_process
    env = real_env(port=port, preset="seed-lab", bridge={"reset_timeout_s": 20.0})
    try:
        env.reset(seed=0)
        assert env.world.guard is not None and env.world.guard.connected.is_set()
        yield env, log
    finally:
        env.close()


@pytest.fixture
def lab(loopback) -> Iterator[Callable[..., tuple[LoopbackServer, Any]]]:
    """Factory: ``lab(server_kwargs=None, **env_kwargs)`` -> ``(server, env)``, a loopback server
    started by :func:`loopback` (with ``server_kwargs``) and a ``real_env`` on it (preset
    ``seed-lab``), reset with seed 0. Every env it made is closed after the test (closing twice
    is a no-op, so a test may close it itself, e.g. before reading the bag it recorded)."""
    envs: list[Any] = []

    def make(
        server_kwargs: dict[str, Any] | None = None, **kwargs: Any
    ) -> tuple[LoopbackServer, Any]:
        server = loopback(**(server_kwargs or {}))
        env = real_env(port=server.port, preset="seed-lab", **kwargs)
        envs.append(env)
        env.reset(seed=0)
        return server, env

    yield make
    for env in envs:
        env.close()


@pytest.fixture(autouse=True)
def _quiet_bridge_logs():
    logger = logging.getLogger("hardware_bridge")
    level = logger.level
    logger.setLevel(logging.ERROR)
    yield
    logger.setLevel(level)
