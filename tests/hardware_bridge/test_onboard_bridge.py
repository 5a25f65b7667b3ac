"""``real_env(..., onboard=True)``: the robots run their own filters and the bridge builds each
agent's observation from the estimate its robot publishes.

Against the loopback server (``LoopbackServer(onboard=True)``: every simulated robot runs
:class:`~hardware_bridge.onboard.OnBoardFilter`) and against a rosbridge server written here
from the protocol alone (JSON ``op`` frames over a websocket), which publishes estimates built
by hand from plain geometry, malformed ones, and a stream that stops.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time

import numpy as np
import pytest

from hardware_bridge import real_env
from hardware_bridge.onboard import mixture_arrays
from swarm_env.config import make_config
from tests.swarm_env.test_env_api import phd_table

from .conftest import wait_until

K = 16  # the seed-lab preset's top_k: rows of the observation's estimate table
COLUMNS = 7  # w, x, y, sxx, sxy, syy, valid


def _estimate_rows(obs: np.ndarray) -> np.ndarray:
    return obs[: K * COLUMNS].reshape(K, COLUMNS)


# ---------------------------------------------------------------------------- the loopback
@pytest.mark.timeout(60)
def test_onboard_over_the_loopback_observes_the_robots_own_filters(loopback, tmp_path):
    """The simulated robots run phd-lc on board; every agent's observation is exactly its
    robot's published mixture (top K by weight), the scans and bearings are never subscribed,
    and the estimates used are recorded in the bag."""
    server = loopback(onboard=True, localizer="phd-lc")
    bag = tmp_path / "onboard"
    env = real_env(
        port=server.port,
        preset="seed-lab",
        localizer="phd-lc",
        onboard=True,
        phd=make_config("seed-lab").phd,  # the simulated robots' sensor model
        max_steps=100,
        record=str(bag),
    )
    compared = components = 0
    try:
        env.reset(seed=0)
        subscribed = server.call(lambda: set().union(*(set(c.subs) for c in server._conns)))
        assert "/ugv_0/swarm_phd/estimate" in subscribed
        assert not any(t.endswith(("/scan", "/bearings_stamped")) for t in subscribed), subscribed
        published = {}
        for _ in range(8):
            obs, _, _, _, infos = env.step(
                {a: np.array([0.05, 0.3 * (-1) ** i]) for i, a in enumerate(env.agents)}
            )
            sent = server.call(lambda: list(server.published_estimates))  # the server's thread
            published.update({(robot, stamp): msg for stamp, robot, msg in sent})
            for i, agent in enumerate(env.possible_agents):
                stamp = int(env.localizer.stamps_ns[i])
                if stamp == 0 or "estimate" in infos[agent]["stale"]:
                    continue
                w, m, p = mixture_arrays(published[(agent, stamp)])
                got = env.localizer.mixture(i)
                np.testing.assert_array_equal(got.weights, w)
                np.testing.assert_array_equal(got.means, m)
                np.testing.assert_array_equal(got.covs, p)
                # The observation: the K heaviest, as the simulator's encoder lays them out.
                want = phd_table(w, m, p, K)
                np.testing.assert_allclose(_estimate_rows(obs[agent]), want, rtol=1e-6, atol=1e-7)
                compared += 1
                components += min(w.size, K)
        counters = env.world.counters_snapshot()
    finally:
        env.close()
    assert compared >= 20, compared  # 8 steps x 4 robots, a few late ones skipped
    assert components > compared  # the filters held teammates
    assert counters.get("estimate.invalid", 0) == 0
    assert "lidar.received" not in counters and "camera.received" not in counters

    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types["/ugv_0/swarm_phd/estimate"] == "swarm_phd_msgs/msg/EstimateStamped"
    assert counts["/ugv_0/swarm_phd/estimate"] >= 5
    assert "/ugv_0/scan" not in counts
    from hardware_bridge.bag import BagError, ReplayWorld

    with pytest.raises(BagError, match="on-board filters"):
        ReplayWorld(bag)


# ---------------------------------------------------------------------------- a protocol server
class RosbridgeProtocolServer:
    """A rosbridge v2 server from the protocol alone: JSON objects with an ``op`` over a
    websocket. ``subscribe`` registers the client for a topic, ``publish`` from the client is
    logged; :meth:`send` publishes to the subscribers. Knows nothing of this project's
    messages."""

    def __init__(self) -> None:
        self.subscribers: dict[str, set] = {}
        self.received: list[tuple[float, str, dict]] = []  # (monotonic s, topic, msg)
        self.lock = threading.Lock()
        self.loop = asyncio.new_event_loop()
        self.port = 0
        ready = threading.Event()

        async def handler(ws) -> None:
            try:
                async for raw in ws:
                    frame = json.loads(raw)
                    op, topic = frame.get("op"), frame.get("topic")
                    with self.lock:
                        if op == "subscribe":
                            self.subscribers.setdefault(topic, set()).add(ws)
                        elif op == "unsubscribe":
                            self.subscribers.get(topic, set()).discard(ws)
                        elif op == "publish":
                            self.received.append((time.monotonic(), topic, frame.get("msg")))
            except Exception:  # noqa: BLE001 - the client went away
                pass
            finally:
                with self.lock:
                    for subs in self.subscribers.values():
                        subs.discard(ws)

        async def main() -> None:
            from websockets.asyncio.server import serve

            self.server = await serve(handler, "127.0.0.1", 0, ping_interval=None)
            self.port = self.server.sockets[0].getsockname()[1]
            ready.set()

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            self.loop.run_until_complete(main())
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert ready.wait(5.0)

    def send(self, topic: str, msg: dict) -> None:
        text = json.dumps({"op": "publish", "topic": topic, "msg": msg})

        def deliver() -> None:
            with self.lock:
                targets = list(self.subscribers.get(topic, ()))
            for ws in targets:
                asyncio.ensure_future(ws.send(text))

        self.loop.call_soon_threadsafe(deliver)

    def commands(self, robot: str, since: float) -> list[tuple[float, float]]:
        """``(linear.x, angular.z)`` of the TwistStamped commands received since ``since``."""
        with self.lock:
            rows = [
                m for t, topic, m in self.received if topic == f"/{robot}/cmd_vel" and t > since
            ]
        return [(m["twist"]["linear"]["x"], m["twist"]["angular"]["z"]) for m in rows]

    def close(self) -> None:
        async def stop() -> None:
            self.server.close()
            await self.server.wait_closed()

        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(5.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5.0)


def _stamp(now_ns: int) -> dict:
    return {"sec": now_ns // 1_000_000_000, "nanosec": now_ns % 1_000_000_000}


def _odometry(now_ns: int) -> dict:
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {
        "header": {"stamp": _stamp(now_ns), "frame_id": "odom"},
        "child_frame_id": "base_link",
        "pose": {
            "pose": {"position": zero, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "covariance": [0.0] * 36,
        },
        "twist": {"twist": {"linear": zero, "angular": zero}, "covariance": [0.0] * 36},
    }


def _estimate(now_ns: int, robot: str, weights, means, covs, kind: int = 0) -> dict:
    """An EstimateStamped as the .msg defines it: flat means (x0, y0, ...) and row-major 2x2
    covariances."""
    return {
        "header": {"stamp": _stamp(now_ns), "frame_id": f"{robot}/base_link"},
        "localizer": "phd",
        "weight_kind": kind,
        "weights": [float(w) for w in weights],
        "means": [float(v) for xy in means for v in xy],
        "covariances": [float(v) for c in covs for row in c for v in row],
    }


# Plain geometry: ugv_0 stands at (1, 1) facing +y (yaw 90 deg); its teammates stand at (1, 2)
# and (0, 1) in the world. In its body frame (x forward, y left) they are 1 m ahead and 1 m to
# its left; the on-board filter's estimate holds them with these weights and covariances.
POSE = (1.0, 1.0, math.pi / 2)
TEAMMATES_WORLD = [(1.0, 2.0), (0.0, 1.0)]
WEIGHTS = [0.95, 0.7]
COVS = [[[0.010, 0.002], [0.002, 0.020]], [[0.030, 0.0], [0.0, 0.015]]]


def _body(xy: tuple[float, float]) -> tuple[float, float]:
    x, y, yaw = POSE
    dx, dy = xy[0] - x, xy[1] - y
    return (math.cos(yaw) * dx + math.sin(yaw) * dy, -math.sin(yaw) * dx + math.cos(yaw) * dy)


class _Robots:
    """Publishes both robots' odometry and estimates at 20 Hz from a thread; ``estimates`` per
    robot can be switched off (a silent on-board filter)."""

    def __init__(self, server: RosbridgeProtocolServer) -> None:
        self.server = server
        self.publish_estimate = {"ugv_0": True, "ugv_1": True}
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        means0 = [_body(p) for p in TEAMMATES_WORLD]
        while not self._stop.is_set():
            now = time.time_ns()
            for robot in ("ugv_0", "ugv_1"):
                self.server.send(f"/{robot}/odom", _odometry(now))
            if self.publish_estimate["ugv_0"]:
                self.server.send(
                    "/ugv_0/swarm_phd/estimate", _estimate(now, "ugv_0", WEIGHTS, means0, COVS)
                )
            if self.publish_estimate["ugv_1"]:  # ugv_1 sees nobody
                self.server.send("/ugv_1/swarm_phd/estimate", _estimate(now, "ugv_1", [], [], []))
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2.0)


@pytest.fixture
def protocol_robots():
    server = RosbridgeProtocolServer()
    robots = _Robots(server)
    yield server, robots
    robots.close()
    server.close()


def _env(port: int, **bridge):
    return real_env(
        robots=["ugv_0", "ugv_1"],
        port=port,
        preset="seed-lab",
        localizer="phd",
        onboard=True,
        max_steps=1000,
        bridge={"use_mocap": False, "guard_process": False, **bridge},
    )


@pytest.mark.timeout(30)
def test_hand_built_estimates_are_the_observation_in_the_robots_frame(protocol_robots, caplog):
    server, _ = protocol_robots
    caplog.set_level(logging.WARNING, logger="hardware_bridge")
    env = _env(server.port)
    try:
        obs, infos = env.reset(seed=0)
        for _ in range(3):
            obs, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
        rows = _estimate_rows(obs["ugv_0"])
        # Heaviest first: 1 m ahead, then 1 m to the left (REP-103 body frame).
        want = [
            [0.95, 1.0, 0.0, 0.010, 0.002, 0.020, 1.0],
            [0.7, 0.0, 1.0, 0.030, 0.0, 0.015, 1.0],
        ]
        np.testing.assert_allclose(rows[:2], want, rtol=1e-6, atol=1e-7)  # float32
        assert not rows[2:].any()
        assert not _estimate_rows(obs["ugv_1"]).any()
        assert infos["ugv_0"]["stale"] == () and infos["ugv_1"]["stale"] == ()
        positions, weights = env.localizer.estimate(0)
        np.testing.assert_allclose(positions, [[1.0, 0.0], [0.0, 1.0]], atol=1e-12)

        # Malformed estimates on ugv_1's topic, freshly stamped: each is a counted drop with
        # its reason, never a crash and never an observation.
        now = time.time_ns()
        one = [[1.0, 0.0]]
        eye = [[[0.01, 0.0], [0.0, 0.01]]]
        bad = {
            "nan": _estimate(now, "ugv_1", [0.9], [[float("nan"), 0.0]], eye),
            "not_pd": _estimate(now, "ugv_1", [0.9], one, [[[0.01, 0.02], [0.02, 0.01]]]),
            "singular": _estimate(now, "ugv_1", [0.9], one, [[[0.0, 0.0], [0.0, 0.0]]]),
            "sizes": {**_estimate(now, "ugv_1", [0.9], one, eye), "means": [1.0, 0.0, 2.0]},
            "unknown_robot": _estimate(now, "ugv_7", [0.9], one, eye),
            "weight_kind": _estimate(now, "ugv_1", [0.9], one, eye, kind=1),
        }
        for msg in bad.values():
            server.send("/ugv_1/swarm_phd/estimate", msg)
        assert wait_until(
            lambda: env.world.counters_snapshot().get("estimate.invalid", 0) >= len(bad), 3.0
        ), env.world.counters_snapshot()
        for _ in range(3):
            obs, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
            assert not _estimate_rows(obs["ugv_1"]).any()
        counters = env.world.counters_snapshot()
    finally:
        env.close()
    assert counters["estimate.invalid"] == len(bad)
    prefix = "estimate.invalid_field."
    fields = {k[len(prefix) :]: v for k, v in counters.items() if k.startswith(prefix)}
    assert fields == {"means": 2, "covariances": 2, "header.frame_id": 1, "weight_kind": 1}, fields
    reasons = " ".join(
        r.getMessage() for r in caplog.records if "estimate.invalid" in r.getMessage()
    )
    for needle in (
        "non-finite",
        "not positive definite",
        "means",
        "expected 'ugv_1/base_link'",
    ):
        assert needle in reasons, (needle, reasons)


@pytest.mark.timeout(30)
def test_a_stale_estimate_stream_stops_its_robot(protocol_robots):
    server, robots = protocol_robots
    env = _env(server.port, stale_estimate_s=0.3)
    drive = {"ugv_0": np.array([0.1, 0.2]), "ugv_1": np.array([0.1, 0.2])}
    try:
        env.reset(seed=0)
        for _ in range(3):
            env.step(drive)
        # ugv_1's on-board filter goes silent; its odometry keeps flowing.
        robots.publish_estimate["ugv_1"] = False
        stale_steps = 0
        for _ in range(15):
            _, _, _, _, infos = env.step(drive)
            if "estimate" in infos["ugv_1"]["stale"]:
                stale_steps += 1
                if stale_steps == 2:
                    since = time.monotonic()
            assert "estimate" not in infos["ugv_0"]["stale"]
            assert "odometry" not in infos["ugv_1"]["stale"]
        assert stale_steps >= 8
        # The estimate kept is the last one received (ugv_1 saw nobody).
        assert env.localizer.mixture(1).weights.size == 0
        wait_until(lambda: server.commands("ugv_1", since), 1.0)
        stopped = server.commands("ugv_1", since)
        moving = server.commands("ugv_0", since)
        assert stopped and all(v == 0.0 and w == 0.0 for v, w in stopped), stopped
        assert moving and all(v > 0.0 for v, _ in moving), moving
        # The stream comes back: the robot drives again.
        robots.publish_estimate["ugv_1"] = True
        for _ in range(8):
            _, _, _, _, infos = env.step(drive)
        assert infos["ugv_1"]["stale"] == ()
        again = time.monotonic()
        env.step(drive)
        wait_until(lambda: server.commands("ugv_1", again), 1.0)
        assert any(v > 0.0 for v, _ in server.commands("ugv_1", again))
        counters = env.world.counters_snapshot()
    finally:
        env.close()
    assert counters["safety.stale_estimate_stops"] >= 8
    assert counters["estimate.stale_steps"] >= 8


def test_onboard_refuses_what_the_robots_cannot_run():
    with pytest.raises(ValueError, match="onboard=True: the robots run localizer='id-phd'"):
        real_env(robots=["ugv_0"], onboard=True, localizer="id-phd")
    with pytest.raises(ValueError, match="observation='measurements'"):
        real_env(robots=["ugv_0"], onboard=True, observation="measurements")
    with pytest.raises(ValueError, match="onboard must be a bool"):
        real_env(robots=["ugv_0"], onboard="yes")


def test_the_bridge_cli_takes_onboard():
    import argparse

    from swarm_phd.bridge import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--loopback", "--onboard"])
    assert args.onboard and args.loopback
