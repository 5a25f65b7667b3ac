"""The Stegagno 2012 thesis's methods behind the Localizer protocol
(``localization.mutual.localizer``): the protocol, the plumbing from the feed (own records,
broadcasts, stale sensors), bad input, and an end-to-end check against the simulator's ground
truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.feed import SwarmFeed
from localization.mutual.fastslam import FastSLAMConfig, FastSLAMLocalizer
from localization.mutual.localizer import (
    DEFAULT_RADIO,
    METHODS,
    MutualLocalizer,
    observer_rng,
)
from localization.mutual.pmultireg import PMultiRegConfig, PMultiRegLocalizer
from localization.mutual.se2 import inverse_compose
from localization.protocol import Localizer, LocalizerSlice
from localization.registry import LOCALIZERS, make_localizer
from swarm_core.geometry import wrap_angle
from swarm_core.records import (
    Broadcast,
    CameraRecord,
    LidarRecord,
    OdometryRecord,
    RobotMeasurements,
)

STEPS = 250  # 25 s of lab-3m-4 (0.1 s control period)


@pytest.fixture(scope="module")
def episode():
    """25 s of 4 robots wandering slowly in lab-3m-4 with the radio on: feeds and truth."""
    from agents.scripted import WanderPolicy
    from swarm_env.env import SwarmEnv

    env = SwarmEnv(
        "lab-3m-4", comms=dict(DEFAULT_RADIO), observation="truth", localize=False, max_steps=500
    )
    policy = WanderPolicy(
        max_speed_mps=0.1, max_turn_rate_radps=0.6, avoid_distance_m=0.35, seed=3
    )
    obs, infos = env.reset(seed=3)
    feeds, poses = [], []
    for _ in range(STEPS):
        obs, _, _, _, infos = env.step(policy(obs, infos))
        step = env.last_world_step
        feeds.append(SwarmFeed.from_world_step(step, env.possible_agents))
        poses.append(step.truth.poses.copy())
    env.close()
    return feeds, poses


def _run(loc, feeds):
    for feed in feeds:
        loc.step(feed)
    return loc


def test_registered_and_conform_to_the_protocol():
    for name in METHODS:
        assert LOCALIZERS[name].needs_comms
        loc = make_localizer(name, 4, seed=2)
        assert isinstance(loc, Localizer) and loc.name == name and loc.has_identities
        assert loc.weight_meaning == "existence"
        table, counts = loc.padded_tables()
        assert table.shape[:2] == (6, 4) and not counts.any()  # nobody known yet
        loc.step(SwarmFeed.empty(4, 0.1))  # an empty feed is a no-op
        assert loc.identities(0) == {} and loc.estimate(0)[0].shape == (0, 2)
    assert not LOCALIZERS["phd-lc"].needs_comms
    with pytest.raises(ValueError, match="sliced"):
        LocalizerSlice(make_localizer("p-multireg", 4), 0, 2)


def test_pmultireg_against_ground_truth(episode):
    """P-MultiReg behind the protocol, scored against the simulator's truth: after the first
    registrations (from 10 s) nearly every (observer, teammate) pose is within the thesis's
    thresholds, and the table is the identities' positions with the particles' covariance."""
    feeds, poses = episode
    loc = make_localizer("p-multireg", 4, seed=0)
    ok_d, ok_o, n = 0, 0, 0
    for k, feed in enumerate(feeds):
        loc.step(feed)
        if k < 100:
            continue
        for i in range(4):
            ids = loc.identities(i)
            for j in range(4):
                if j == i:
                    continue
                n += 1
                true = inverse_compose(poses[k][j], poses[k][i])
                est = ids.get(j)
                if est is not None:
                    ok_d += np.hypot(*(est[:2] - true[:2])) < 0.1
                    ok_o += abs(float(wrap_angle(est[2] - true[2]))) < math.radians(7)
    assert ok_d / n > 0.85 and ok_o / n > 0.7, (ok_d / n, ok_o / n)
    table, counts = loc.padded_tables()
    for i in range(4):
        ids = loc.identities(i)
        assert counts[i] == len(ids) == 3 and set(ids) == set(range(4)) - {i}
        np.testing.assert_allclose(table[1:3, i, :3].T, [ids[j][:2] for j in sorted(ids)])
        np.testing.assert_array_equal(table[0, i, :3], 1.0)
        # The particles' covariance: positive, a few cm to ~0.1 m, and consistent with the
        # final error (squared Mahalanobis distance below chi2(2) at 99.9 %, 13.8).
        for j, mean, c in zip(sorted(ids), loc.mixture(i).means, loc.mixture(i).covs, strict=True):
            assert np.all(np.linalg.eigvalsh(c) > 0) and c[0, 0] < 0.2**2 and c[1, 1] < 0.2**2
            err = mean - inverse_compose(poses[-1][j], poses[-1][i])[:2]
            assert err @ np.linalg.solve(c, err) < 13.8, (i, j, err, c)


def test_same_as_the_per_observer_systems_and_needs_the_radio(episode):
    """The wrapper feeds each observer exactly what ``swarm-phd mutual`` feeds it (same
    streams: same estimates); without the radio no teammate is ever estimated; an observer
    subset runs only those robots, unchanged."""
    feeds, _ = episode
    feeds = feeds[:80]
    loc = _run(MutualLocalizer("p-multireg", 4, seed=5), feeds)
    ids = [f"ugv_{i}" for i in range(4)]
    for i in (0, 2):
        ref = PMultiRegLocalizer(ids[i], ids, PMultiRegConfig(), observer_rng(5, 0, i))
        for feed in feeds:
            ref.step(feed.time_s, feed.measurements[i], list(feed.comms[i]))
        got = loc.identities(i)
        for t, est in ref.estimates().items():  # the same up to summation order
            np.testing.assert_allclose(got[ids.index(t)], est, rtol=0, atol=1e-12)
    sub = _run(MutualLocalizer("p-multireg", 4, seed=5, observers=[2]), feeds)
    assert sub.padded_tables()[1].tolist() == [0, 0, 3, 0]
    for j, est in sub.identities(2).items():
        np.testing.assert_array_equal(est, loc.identities(2)[j])
    assert len(sub.identities(2)) == 3
    deaf = [
        SwarmFeed(f.time_s, f.measurements, f.stale, f.truth, f.compensate_motion) for f in feeds
    ]
    assert not any(_run(make_localizer("p-multireg", 4), deaf).identities(i) for i in range(4))
    # Stale lidar: the records are not used (no registration, nobody known).
    blind = [SwarmFeed(f.time_s, f.measurements, [("lidar",)] * 4, comms=f.comms) for f in feeds]
    assert not any(_run(make_localizer("p-multireg", 4), blind).identities(i) for i in range(4))


def test_fastslam_and_beareg_run_from_the_feed(episode):
    """The two other methods find every teammate from the same feed (a loose check: their
    accuracy is reported in benchmarks/RESULTS.md, not asserted)."""
    feeds, _ = episode
    for name in ("fastslam-mc", "p-multibeareg"):
        loc = MutualLocalizer(name, 4, seed=0, n_particles=100)
        _run(loc, feeds[:60])
        for i in range(4):
            assert set(loc.identities(i)) == set(range(4)) - {i}, name
            assert np.all(np.isfinite(loc.padded_tables()[0]))


def test_fastslam_moments_are_the_mixture_moments():
    """Two particles holding teammate 0 at (0, 0) and (2, 0), covariances I and 3 I, weights
    1/4 and 3/4: mean (1.5, 0), covariance 0.25 I + 0.75 * 3 I + spread 0.75 along x."""
    f = FastSLAMLocalizer("a", ("a", "b"), FastSLAMConfig(n_particles=2))
    f.init_r[:] = True
    f.mu_r[:, 0] = [[0.0, 0.0, 0.1], [2.0, 0.0, 0.1]]
    f.cov_r[:, 0] = [np.eye(3), 3 * np.eye(3)]
    f.logw[:] = np.log([0.25, 0.75])
    mean, cov = f.moments()["b"]
    np.testing.assert_allclose(mean, [1.5, 0.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(cov[:2, :2], np.diag([2.5 + 0.75, 2.5]), atol=1e-12)


def _bcast(sender="ugv_1", x=0.0):
    return Broadcast(sender, 0.1, np.array([x, 0.0, 0.0]), np.array([[1.0, 0.0]]), 0.05)


def _records(det=((1.0, 0.5),)):
    return RobotMeasurements(
        [OdometryRecord(0.1, np.array([0.01, 0.0, 0.0]), np.array([0.1, 0.0]))],
        [
            LidarRecord(
                0.05, np.zeros(0), np.zeros(0), np.zeros(0), np.array(det, float), np.zeros(0)
            )
        ],
    )


def test_bad_input_is_refused_by_name_before_any_change():
    with pytest.raises(ValueError, match="method"):
        MutualLocalizer("ekf", 4)
    with pytest.raises(ValueError, match="n_robots"):
        MutualLocalizer("p-multireg", 0)
    with pytest.raises(ValueError, match="robot_ids"):
        MutualLocalizer("p-multireg", 2, robot_ids=["a", "a"])
    with pytest.raises(ValueError, match="robot must be in"):
        MutualLocalizer("p-multireg", 2, observers=[3])
    with pytest.raises(ValueError, match="n_particles"):
        MutualLocalizer("fastslam-mc", 2, n_particles=1)
    with pytest.raises(ValueError, match="config"):
        MutualLocalizer("p-multireg", 2, config=FastSLAMConfig())
    loc = MutualLocalizer("p-multireg", 2, robot_ids=["a", "b"])
    good = SwarmFeed(0.1, [_records()] * 2, [()] * 2, comms=[(), ()])
    loc.step(good)
    state = loc.systems[0].own_track.latest.copy()
    bad_feeds = {
        "sender": SwarmFeed(0.2, [_records()] * 2, [()] * 2, comms=[(_bcast("zz"),), ()]),
        "finite": SwarmFeed(0.2, [_records(), _records(((np.nan, 0.0),))], [()] * 2),
        "within 1e4": SwarmFeed(0.2, [_records()] * 2, [()] * 2, comms=[(), (_bcast("a", 1e6),)]),
        "robots": SwarmFeed.empty(3, 0.2),
        "comms has": SwarmFeed(0.2, [_records()] * 2, [()] * 2, comms=[()]),
        "bearings_rad": SwarmFeed(
            0.2,
            [_records()] * 2,
            [()] * 2,
            comms=[
                (
                    Broadcast(
                        "b", 0.1, np.zeros(3), np.zeros((0, 2)), math.nan, np.array([np.nan]), 0.1
                    ),
                ),
                (),
            ],
        ),
        "camera record": SwarmFeed(
            0.2,
            [
                RobotMeasurements(
                    _records().odometry, _records().lidar, [CameraRecord(0.1, np.array([np.inf]))]
                )
            ]
            * 2,
            [()] * 2,
        ),
    }
    for match, feed in bad_feeds.items():
        with pytest.raises(ValueError, match=match):
            loc.step(feed)
        np.testing.assert_array_equal(loc.systems[0].own_track.latest, state)
    with pytest.raises(ValueError, match="robot must be"):
        loc.identities(2)


def test_evaluate_switches_the_radio_on_and_refuses_it_off():
    from swarm_phd.evaluate import evaluate_localization

    with pytest.raises(ValueError, match="need the radio"):
        evaluate_localization("lab-3m-4", 1.0, ["p-multireg"], [0], comms={"enabled": False})
    res = evaluate_localization("lab-3m-4", 3.0, ["p-multireg", "phd-lc"], [0])
    ident = res["identity"]["p-multireg"]
    assert 0.0 <= ident["id_percent_within_10cm"] <= 100.0
    assert "id_percent_heading_within_7deg" in ident and "phd-lc" not in res["identity"]


def test_env_refuses_a_radio_family_without_the_radio():
    from swarm_env import parallel_env

    with pytest.raises(ValueError, match="localizer='p-multireg' needs the radio"):
        parallel_env("lab-3m-4", localizer="p-multireg")
    parallel_env(
        "lab-3m-4", localizer="p-multireg", localize=False, observation="truth"
    )  # no filter: no radio needed
    env = parallel_env("lab-3m-4", localizer="fastslam-mc", comms={"enabled": True})
    assert env.localizer.name == "fastslam-mc"
