"""A server's topic and service names are data: no frame can reach the link's own events
("close", "ready", "error"...). Frames the client cannot place are counted, never acted on; the
link, the sensor data and the command path stay up."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from tests.hardware_bridge.conftest import wait_until

CLOSE_FRAME = json.dumps({"op": "publish", "topic": "close", "msg": {}})  # 46 bytes

#: (frame, counter it must land in)
HOSTILE_FRAMES = [
    (CLOSE_FRAME, "transport.unplaced"),
    ('{"op":"publish","topic":"ready","msg":{}}', "transport.unplaced"),
    ('{"op":"publish","topic":"error","msg":{}}', "transport.unplaced"),
    ('{"op":"publish","topic":"bridge:status","msg":{}}', "transport.unplaced"),
    ('{"op":"publish","topic":"bridge:oversize","msg":1}', "transport.unplaced"),
    ('{"op":"publish","topic":"new_listener","msg":{}}', "transport.unplaced"),
    ('{"op":"publish","topic":["close"],"msg":{}}', "transport.unplaced"),
    ('{"op":"call_service","service":"close","id":"x","args":{}}', "transport.malformed"),
    ('{"op":"send_action_goal","action":"ready","id":"x"}', "transport.malformed"),
    ('{"op":"service_response","id":"nobody","values":{}}', "transport.malformed"),
    ('{"topic":"close","msg":{}}', "transport.malformed"),
]


def test_the_close_frame_is_46_bytes():
    assert len(CLOSE_FRAME.encode()) == 46


def _moving_commands(server, after: float) -> dict[str, int]:
    out: dict[str, int] = {}
    for t, robot, v, _ in server.twists():
        if t > after and v > 0:
            out[robot] = out.get(robot, 0) + 1
    return out


@pytest.mark.timeout(90)
def test_hostile_frames_are_counted_and_the_command_path_stays_up(lab):
    server, env = lab(max_steps=10_000)
    world = env.world
    robots = set(env.possible_agents)
    for frame, counter in HOSTILE_FRAMES:
        before = world.counters.get(counter)
        server.send_raw(frame)
        assert wait_until(lambda c=counter, b=before: world.counters.get(c) == b + 1, 3.0), (
            frame,
            world.counters_snapshot(),
        )
    t_sent = time.monotonic()
    odometry = world.counters.get("odometry.accepted")
    # 7 s of steps: past the 5.1 s after which a dropped command path used to raise.
    for _ in range(70):
        env.step({a: np.array([0.15, 0.0]) for a in env.agents})
    moved = _moving_commands(server, t_sent)
    assert set(moved) == robots and min(moved.values()) >= 60, moved
    assert world.counters.get("odometry.accepted") - odometry >= 4 * 50
    assert world.counters.get("transport.lost") == 0
    assert world.counters.get("transport.publish_dropped") == 0
    assert world.client.connected
    assert not any("transport lost" in reason for _, reason in world.watchdog.trips)
    assert world.rejected_total() >= len(HOSTILE_FRAMES)


@pytest.mark.timeout(60)
def test_a_message_on_a_subscribed_topic_still_reaches_its_robot(lab):
    """The table lookup routes real data: a hand-made odometry frame for ugv_0 is validated
    like every other (an invalid one is counted under the robot's sensor)."""
    server, env = lab()
    world = env.world
    topic = world._kinds["ugv_0"]["odometry"][1]
    before = world.counters.get("odometry.invalid")
    server.send_raw(json.dumps({"op": "publish", "topic": topic, "msg": {"pose": "x"}}))
    assert wait_until(lambda: world.counters.get("odometry.invalid") == before + 1, 3.0)
    assert world.counters.get("transport.unplaced") == 0
