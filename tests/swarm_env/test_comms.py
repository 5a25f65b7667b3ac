"""The simulated radio: rate, loss, latency, radius and the odometry it carries."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_core.geometry import integrate_body_delta
from swarm_core.records import Broadcast
from swarm_env.comms import CommsChannel, CommsConfig
from swarm_env.env import SwarmEnv


def _drive(env, steps, seed=3):
    obs, infos = env.reset(seed=seed)
    history = [infos]
    for k in range(steps):
        turn = 0.5 * np.sin(0.1 * k)
        _, _, _, _, infos = env.step({a: np.array([0.15, turn]) for a in env.agents})
        history.append(infos)
    return history


def test_radio_off_by_default_and_on_it_changes_no_sensor_noise():
    quiet = SwarmEnv("lab-3m-4", localize=False, observation="truth")
    loud = SwarmEnv(
        "lab-3m-4",
        localize=False,
        observation="truth",
        comms={"enabled": True, "loss_probability": 0.5},
    )
    a, b = _drive(quiet, 20), _drive(loud, 20)
    assert all(info["comms"] == [] for step in a for info in step.values())
    assert sum(len(info["comms"]) for step in b for info in step.values()) > 0
    # The radio has its own random stream: the measurements are the same bit for bit.
    for sa, sb in zip(a, b, strict=True):
        for agent in sa:
            for ra, rb in zip(
                sa[agent]["measurements"]["lidar"], sb[agent]["measurements"]["lidar"], strict=True
            ):
                np.testing.assert_array_equal(ra["detections"], rb["detections"])
            for ca, cb in zip(
                sa[agent]["measurements"]["camera"],
                sb[agent]["measurements"]["camera"],
                strict=True,
            ):
                np.testing.assert_array_equal(ca["bearings_rad"], cb["bearings_rad"])


def test_lossless_radio_delivers_every_teammate_each_period_with_its_own_odometry():
    env = SwarmEnv("lab-3m-4", localize=False, observation="truth", comms={"enabled": True})
    history = _drive(env, 25)
    n = len(env.possible_agents)
    # Each robot's own integration of its odometry records, to compare with what it sent.
    pose = {a: np.zeros(3) for a in env.possible_agents}
    for infos in history[1:]:
        for agent, info in infos.items():
            for odo in info["measurements"]["odometry"]:
                pose[agent] = integrate_body_delta(pose[agent], odo["delta"])
        for agent, info in infos.items():
            senders = [m.sender for m in info["comms"]]
            # 10 Hz radio, 10 Hz steps, no loss or latency: one message from each teammate.
            assert sorted(senders) == sorted(set(env.possible_agents) - {agent})
            assert len(senders) == n - 1
            for m in info["comms"]:
                np.testing.assert_allclose(m.odometry_pose, pose[m.sender], atol=1e-12)
    # Dead reckoning drifts from the truth but stays close over 2.5 s.
    truth0 = history[0]["ugv_0"]["truth"]["pose"]
    truth = history[-1]["ugv_0"]["truth"]["pose"]
    c, s = np.cos(truth0[2]), np.sin(truth0[2])
    d = truth[:2] - truth0[:2]
    expected = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
    assert np.linalg.norm(pose["ugv_0"][:2] - expected) < 0.05


def _broadcast(sender: str, t: float) -> Broadcast:
    return Broadcast(sender, t, np.zeros(3), np.zeros((0, 2)))


def test_channel_loss_latency_and_radius():
    ids = ("a", "b", "c")
    cfg = CommsConfig(
        enabled=True, rate_hz=10.0, loss_probability=0.3, latency_s=0.25, radius_m=2.0
    )
    channel = CommsChannel(cfg, ids)
    channel.reset(np.random.default_rng(0))
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]])  # c is out of everyone's radius
    got = {rid: [] for rid in ids}
    n_sent = 2000
    for k in range(n_sent):
        t = 0.1 * k
        out = [_broadcast("a", t)]
        for rid, msgs in channel.exchange(t, out, xy[:1], ids, xy).items():
            for m in msgs:
                assert t - m.stamp_s >= 0.25 - 1e-9  # never early
                assert t - m.stamp_s < 0.25 + 0.1 + 1e-9  # delivered at the first step after
            got[rid].extend(msgs)
    assert got["a"] == [] and got["c"] == []
    # Loss 0.3 per pair: binomial(2000, 0.7) has std ~20 deliveries.
    assert abs(len(got["b"]) - 0.7 * n_sent) < 5 * np.sqrt(n_sent * 0.21) + 3


def test_jitter_can_reorder_and_deliveries_come_in_arrival_order():
    ids = ("a", "b")
    cfg = CommsConfig(enabled=True, latency_s=0.0, latency_jitter_s=1.0)
    channel = CommsChannel(cfg, ids)
    channel.reset(np.random.default_rng(1))
    xy = np.zeros((2, 2))
    stamps = []
    for k in range(200):
        t = 0.1 * k
        stamps += [
            m.stamp_s for m in channel.exchange(t, [_broadcast("a", t)], xy[:1], ids, xy)["b"]
        ]
    assert len(stamps) > 150
    assert any(np.diff(stamps) < 0)  # out of send order, as UDP can be


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("loss_probability", 1.5),
        ("rate_hz", 0.0),
        ("latency_s", -1.0),
        ("radius_m", float("nan")),
        ("enabled", "yes"),
    ],
)
def test_bad_comms_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"comms.{field}"):
        CommsConfig(**{field: value})


def test_same_seed_same_broadcasts():
    cfg = {"enabled": True, "loss_probability": 0.4, "latency_jitter_s": 0.2}
    runs = []
    for _ in range(2):
        env = SwarmEnv("lab-3m-4", localize=False, observation="truth", comms=cfg)
        runs.append(
            [
                [(m.sender, m.stamp_s) for m in i["comms"]]
                for s in _drive(env, 15)
                for i in s.values()
            ]
        )
    assert runs[0] == runs[1]


def test_a_send_due_within_the_tolerance_still_moves_the_schedule_one_period():
    channel = CommsChannel(CommsConfig(enabled=True, rate_hz=5.0), ("a",))
    channel.reset(np.random.default_rng(0))
    channel._next_send_s[:] = 5e-10  # due at t = 0 only thanks to the 1e-9 tolerance
    sends = sum(len(channel.due_senders(0.1 * k)) for k in range(50))  # 5 s at 10 Hz steps
    assert sends == 25  # 5 Hz, not one per step


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"sender": ""}, "sender"), ({"sender": 3}, "sender"), ({"stamp_s": float("nan")}, "stamp_s"),
     ({"stamp_s": "1.0"}, "stamp_s"), ({"odometry_pose": np.zeros(2)}, "reshape|shape|size")],
)  # fmt: skip
def test_bad_broadcast_is_refused(kwargs, field):
    args = {
        "sender": "ugv_1",
        "stamp_s": 1.0,
        "odometry_pose": np.zeros(3),
        "detections": np.zeros((0, 2)),
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        Broadcast(**args)


def test_broadcast_carries_the_senders_latest_camera_frame():
    """Each broadcast holds the sender's newest camera frame (body-frame bearings and stamp) as of
    the send; before its first frame, none (empty, nan)."""
    empty = Broadcast("ugv_1", 0.0, np.zeros(3), np.zeros((0, 2)))
    assert empty.bearings_rad.shape == (0,) and np.isnan(empty.bearings_stamp_s)
    env = SwarmEnv("lab-3m-4", localize=False, observation="truth", comms={"enabled": True})
    history = _drive(env, 15)
    latest: dict[str, tuple[float, np.ndarray]] = {}
    checked = 0
    for infos in history[1:]:
        for agent, info in infos.items():
            frames = info["measurements"]["camera"]
            if frames:
                latest[agent] = (frames[-1]["stamp_s"], frames[-1]["bearings_rad"])
        for info in infos.values():
            for m in info["comms"]:  # no latency: sent this step, after the step's records
                stamp, bearings = latest[m.sender]
                assert m.bearings_stamp_s == stamp
                np.testing.assert_array_equal(m.bearings_rad, bearings)
                assert m.bearings_stamp_s <= m.stamp_s
                checked += 1
    assert checked > 100


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"bearings_rad": np.zeros((2, 2))}, "bearings_rad"),
     ({"bearings_rad": 0.5}, "bearings_rad"),
     ({"bearings_stamp_s": "0.1"}, "bearings_stamp_s")],
)  # fmt: skip
def test_bad_broadcast_bearings_are_refused(kwargs, field):
    args = {"sender": "ugv_1", "stamp_s": 1.0, "odometry_pose": np.zeros(3)}
    with pytest.raises(ValueError, match=field):
        Broadcast(**args, detections=np.zeros((0, 2)), **kwargs)
