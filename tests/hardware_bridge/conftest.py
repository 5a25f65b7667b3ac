"""Fixtures for the hardware bridge tests: loopback servers on ephemeral 127.0.0.1 ports.

Twisted's reactor (roslibpy) runs once per process in a daemon thread and is never stopped, so
every test shares it; each test gets its own server and its own bridge client.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator

import pytest

pytest.importorskip("roslibpy")
pytest.importorskip("rosbags")
pytest.importorskip("websockets")

from hardware_bridge.loopback import FaultConfig, LoopbackServer  # noqa: E402


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until true or ``timeout_s`` passes (a bounded wait, not an assertion)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


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


@pytest.fixture(autouse=True)
def _quiet_bridge_logs():
    logger = logging.getLogger("hardware_bridge")
    level = logger.level
    logger.setLevel(logging.ERROR)
    yield
    logger.setLevel(level)
