"""The packed feed (``SwarmFeed.packed``, ``localization.feed.pack_calls``): the whole swarm's
filter calls as the compiled banks' arrays, built without call tuples. It must be the bank's own
encoding of ``localizer_calls`` array for array, bit for bit, and fall back to the tuple path
(which names the culprit) on anything it cannot vouch for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.bank import PHDBank, _Batch
from localization.config import PHDConfig
from localization.feed import (
    SwarmFeed,
    _motion_poses,
    _motion_since_sample,
    localizer_calls,
    pack_calls,
)
from localization.pmb import PMBBank, PMBConfig
from localization.scan_memory import N_BINS
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements


def tuple_encoding(feed: SwarmFeed) -> tuple:
    batch = _Batch()
    for r, seq in enumerate(feed.call_lists()):
        for c in seq:
            batch.add_call(r, c)
    return batch.encode()


def assert_same_encoding(packed, reference) -> None:
    assert len(packed) == len(reference) == 20
    for k, (a, b) in enumerate(zip(packed, reference, strict=True)):
        assert a.dtype == b.dtype, k
        assert a.shape == b.shape, k
        assert a.tobytes() == b.tobytes(), k  # bit for bit (NaN-free)


def odo(t: float, rng) -> OdometryRecord:
    return OdometryRecord(t, rng.normal(0, 0.05, 3), rng.normal(0, 0.5, 2))


def lidar(t: float, rng, m: int = 2) -> LidarRecord:
    return LidarRecord(
        t, np.zeros(4), np.ones(4), np.ones(4), rng.normal(0, 2, (m, 2)), rng.uniform(-3, 3, 2)
    )


def camera(t: float, rng, m: int = 3) -> CameraRecord:
    return CameraRecord(t, rng.uniform(-3, 3, m))


def hand_feed(compensate: bool) -> SwarmFeed:
    """Ties on stamps across and within kinds, a record after the last odometry sample, no
    odometry at all, stale sensors, an empty robot."""
    rng = np.random.default_rng(3)
    robots = [
        RobotMeasurements(
            [odo(0.1, rng), odo(0.2, rng)],
            [lidar(0.05, rng), lidar(0.1, rng, 0), lidar(0.25, rng)],
            [camera(0.1, rng), camera(0.1, rng, 0), camera(0.15, rng), camera(0.2, rng)],
        ),
        RobotMeasurements([], [lidar(0.02, rng)], [camera(0.03, rng)]),
        RobotMeasurements(),
        RobotMeasurements([odo(0.1, rng)], [lidar(0.05, rng)], [camera(0.07, rng)]),
        RobotMeasurements([odo(0.1, rng)], [lidar(0.05, rng)], [camera(0.07, rng)]),
        RobotMeasurements([odo(0.1, rng)], [lidar(0.05, rng)], [camera(0.07, rng)]),
    ]
    stale = [(), (), (), ("odometry",), ("lidar", "camera"), ("camera",)]
    return SwarmFeed(0.3, robots, stale, compensate_motion=compensate)


@pytest.mark.parametrize("compensate", [True, False])
def test_hand_made_records_encode_as_the_tuples(compensate):
    feed = hand_feed(compensate)
    packed = feed.packed()
    assert packed is not None
    assert_same_encoding(packed.encoded, tuple_encoding(feed))
    assert packed.robots == [0, 1, 3, 4, 5]
    assert packed.max_points == 2
    if compensate:  # the poses are really there (not trivially zero on both sides)
        assert packed.encoded[14].sum() > 0 and packed.encoded[16].sum() > 0


def test_simulated_rollout_encodes_as_the_tuples():
    from swarm_env import parallel_env

    env = parallel_env("sim-6m-20", observation="measurements", localize=False)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(12):
        actions = {a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents}
        env.step(actions)
        step = env.last_world_step
        for compensate in (True, False):
            feed = SwarmFeed.from_world_step(step, env.possible_agents, compensate)
            packed = feed.packed()
            assert packed is not None
            assert_same_encoding(packed.encoded, tuple_encoding(feed))
    env.close()


def test_motion_poses_match_the_scalar_function_bit_for_bit():
    rng = np.random.default_rng(7)
    k = 2000
    delta = rng.normal(0, 0.1, (k, 3))
    delta[::7, 2] = 0.0
    velocity = rng.normal(0, 1.0, (k, 2))
    tau = rng.uniform(0, 0.2, k)
    got = _motion_poses(delta, velocity, tau)
    for i in range(k):
        rec = OdometryRecord(1.0, delta[i], velocity[i])
        want = _motion_since_sample(rec, float(tau[i]))
        assert got[i].tobytes() == want.tobytes()
    assert math.isfinite(got.sum())


def test_motion_since_sample_leaves_the_tail_motion_to_the_sample():
    """The pose composed with the removed last ``tau`` (turn ``psi_r``, chord ``v tau`` at
    ``psi_r / 2``) is the whole interval's ``delta``; the turn never exceeds ``dpsi``."""
    rng = np.random.default_rng(8)
    for _ in range(500):
        delta = rng.normal(0, 0.1, 3)
        v, omega = rng.normal(0, 1.0, 2)
        tau = float(rng.uniform(0, 0.2))
        x, y, psi = _motion_since_sample(OdometryRecord(1.0, delta, np.array([v, omega])), tau)
        psi_r = omega * tau if abs(omega * tau) <= abs(delta[2]) else delta[2]
        chord = v * tau
        tx, ty = chord * math.cos(psi_r / 2), chord * math.sin(psi_r / 2)
        assert psi + psi_r == pytest.approx(delta[2], abs=1e-15)
        assert x + math.cos(psi) * tx - math.sin(psi) * ty == pytest.approx(delta[0], abs=1e-12)
        assert y + math.sin(psi) * tx + math.cos(psi) * ty == pytest.approx(delta[1], abs=1e-12)


def test_banks_take_the_packed_path_and_end_in_the_same_state():
    """The bank stepped on a feed (its packed arrays) and the bank fed the tuples hold the
    same bits."""
    for make in (
        lambda: PHDBank(PHDConfig.perera2021(), 6),
        lambda: PMBBank(PHDConfig.perera2021(), 6),
    ):
        a, b = make(), make()
        for repeat in range(3):  # the same calls again: the banks move on, both alike
            feed = hand_feed(True)
            a.step(feed)
            assert not feed._calls  # no tuple was made
            b.apply(list(hand_feed(True).call_lists()))
            ta, ca = a.padded_tables()
            tb, cb = b.padded_tables()
            assert ta.tobytes() == tb.tobytes() and (ca == cb).all(), repeat


def test_falls_back_on_what_it_cannot_vouch_for():
    rng = np.random.default_rng(0)
    int_stamp = RobotMeasurements([OdometryRecord(1, np.zeros(3), np.zeros(2))])
    assert pack_calls([int_stamp], [()]) is None
    assert pack_calls(["not records"], [()]) is None
    many = RobotMeasurements([], [], [CameraRecord(0.1, np.zeros(5000))])
    assert pack_calls([many], [()]) is None
    # ... and the bank then names the bad value, as for tuples.
    bad = RobotMeasurements([OdometryRecord(0.1, [np.nan, 0, 0], [0, 0])])
    bank = PHDBank(PHDConfig.perera2021(), 1)
    with pytest.raises(ValueError, match="odometry"):
        bank.step(SwarmFeed(0.1, [bad], [()]))
    huge = RobotMeasurements([], [lidar(0.1, rng)], [CameraRecord(0.1, np.array([1e9]))])
    with pytest.raises(ValueError, match="calls\\[0\\]"):
        bank.step(SwarmFeed(0.1, [huge], [()]))
    assert bank.counts.tolist() == [0]  # nothing changed


def test_calls_sequence_reads_as_the_lists():
    feed = hand_feed(True)
    calls = feed.calls()
    assert len(calls) == 6
    assert [len(c) for c in calls] == [
        len(localizer_calls(m, s)) for m, s in zip(feed.measurements, feed.stale, strict=True)
    ]
    assert calls[0] is feed.call_lists()[0]
    both = SwarmFeed.concat([feed, hand_feed(True)])
    assert_same_encoding(both.packed().encoded, tuple_encoding(both))


@pytest.mark.parametrize(
    "records",
    [
        RobotMeasurements([], [lidar(0.1, np.random.default_rng(1))], []),
        RobotMeasurements([odo(0.1, np.random.default_rng(2))], [], []),
        RobotMeasurements([], [], [camera(0.1, np.random.default_rng(3))]),
        RobotMeasurements(),
    ],
)
def test_single_kind_feeds_take_the_packed_path(records):
    feed = SwarmFeed(0.1, [records, records], [(), ()])
    packed = feed.packed()
    assert packed is not None
    assert_same_encoding(packed.encoded, tuple_encoding(feed))


def test_scan_profiles_are_packed_only_when_asked():
    rng = np.random.default_rng(5)
    records = RobotMeasurements([odo(0.2, rng)], [lidar(0.1, rng), lidar(0.15, rng)], [])
    feed = SwarmFeed(0.2, [records, records], [(), ()])
    full, bare = feed.packed(), feed.packed(scan_profiles=False)
    assert feed.packed() is full and feed.packed(scan_profiles=False) is bare  # cached
    assert full.encoded[18].shape == (4, N_BINS) and (full.encoded[19] == 1).all()
    assert bare.encoded[18].shape == (0, N_BINS) and (bare.encoded[19] == 0).all()
    for k, (a, b) in enumerate(zip(full.encoded, bare.encoded, strict=True)):
        if k not in (18, 19):
            assert np.array_equal(a, b), k
    assert PHDBank(PHDConfig.perera2021(), 2).reads_scans is False
    assert PHDBank(PHDConfig(), 2).reads_scans is True  # the wide objects' camera clutter
    assert PMBBank(PMBConfig(phd=PHDConfig.perera2021()), 2).reads_scans is False
    assert PMBBank(PMBConfig(), 2).reads_scans is True


@pytest.mark.parametrize("family", ["phd-lc", "pmb-lc"])
def test_env_rollout_is_bit_identical_to_the_tuple_path(family, monkeypatch):
    """A seeded env with the packed feed (the default) and one forced down the tuple path
    hold the same filter bits at every step, and the default makes no call tuple at all (both
    banks read the scans, for the wide objects' camera clutter)."""
    import localization.feed
    from swarm_env import parallel_env

    def run(packed: bool) -> list[bytes]:
        with monkeypatch.context() as m:
            if packed:  # the env must never need the tuples
                m.setattr(localization.feed, "localizer_calls", _no_tuples)
            else:
                # no packed arrays: both banks encode the feed's call tuples
                m.setattr(localization.feed.SwarmFeed, "packed", lambda *a: None)
            env = parallel_env("sim-6m-20", localizer=family)
            env.reset(seed=4)
            rng = np.random.default_rng(4)
            out = []
            for _ in range(15):
                env.step({a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents})
                tables, counts = env.localizer.padded_tables()
                out.append(tables.tobytes() + counts.tobytes())
            env.close()
            return out

    assert run(packed=True) == run(packed=False)


def _no_tuples(*args, **kwargs):
    raise AssertionError("the packed path made call tuples")
