"""Hostile measurement sets through every localizer family (hypothesis): each call either
raises ValueError and leaves every robot's estimate unchanged, or leaves finite estimates of
bounded size. Never a numba error, a NaN or an unbounded mixture."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from localization.feed import SwarmFeed
from localization.registry import make_localizer
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from swarm_env.config import SIMULATOR_PHD

FAMILIES = ["phd-lc", "pmb-lc", "phd-reference-lc", "pmb-reference-lc"]

values = st.one_of(
    st.floats(-1e3, 1e3),
    st.sampled_from([0.0, 1e-300, 1e160, -1e160, 1e300, np.nan, np.inf, -np.inf]),
)


def _record_set(data, stamp):
    n_det = data.draw(st.integers(0, 40))
    det = np.array([[data.draw(values), data.draw(values)] for _ in range(n_det)]).reshape(-1, 2)
    n_brg = data.draw(st.integers(0, 40))
    brg = np.array([data.draw(values) for _ in range(n_brg)])
    delta = np.array([data.draw(values) for _ in range(3)])
    lidar = LidarRecord(stamp, np.zeros(0), np.zeros(0), np.zeros(0), det, np.zeros(0))
    return RobotMeasurements(
        [OdometryRecord(stamp, delta, np.zeros(2))], [lidar], [CameraRecord(stamp, brg)]
    )


def _snapshot(loc):
    table, counts = loc.padded_tables()
    return table.copy(), counts.copy()


@pytest.mark.parametrize("family", FAMILIES)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_hostile_feeds_raise_cleanly_or_stay_finite_and_bounded(family, data):
    loc = make_localizer(family, 2, SIMULATOR_PHD)
    good = RobotMeasurements(
        [OdometryRecord(0.1, np.zeros(3), np.zeros(2))],
        [LidarRecord(0.1, np.zeros(0), np.zeros(0), np.zeros(0), np.array([[1.0, 0.5]]),
                     np.zeros(0))],
        [],
    )  # fmt: skip
    for k in range(5):  # an established track first
        loc.step(SwarmFeed(0.1 * k, [good, good], [(), ()]))
    for k in range(3):
        before = _snapshot(loc)
        feed = SwarmFeed(1.0 + k, [_record_set(data, 1.0 + k), good], [(), ()])
        try:
            loc.step(feed)
        except ValueError:
            after = _snapshot(loc)
            np.testing.assert_array_equal(after[1], before[1])
            np.testing.assert_array_equal(after[0], before[0])
            continue
        table, counts = loc.padded_tables()
        for r in range(2):
            cols = table[:, r, : counts[r]]
            assert np.all(np.isfinite(cols)), f"robot {r}: non-finite estimate"
            assert np.all(cols[0] >= 0)
            assert np.all(cols[3] >= 0) and np.all(cols[5] >= 0)  # variances
        assert counts.max() <= table.shape[2]
        if loc.weight_meaning == "existence":
            assert np.all(table[0][table[0] > 0] <= 1.0)
