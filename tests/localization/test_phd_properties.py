"""Property tests: whatever the measurements, the mixture stays a valid PHD."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from localization import PHDConfig, RobotCentricPHD
from localization.mixture import table_from_arrays
from localization.reducer import merge

coord = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)
near = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False, allow_infinity=False)
angle = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False, allow_infinity=False)


@st.composite
def point_sets(draw):
    kind = draw(st.sampled_from(["random", "empty", "coincident", "far", "origin"]))
    if kind == "empty":
        return np.empty((0, 2))
    n = draw(st.integers(1, 8))
    if kind == "coincident":
        p = draw(st.tuples(near, near))
        return np.tile(np.array(p, dtype=float), (n, 1))
    if kind == "origin":
        return np.zeros((n, 2))
    elems = coord if kind == "far" else near
    return draw(arrays(np.float64, (n, 2), elements=elems))


def assert_valid(f: RobotCentricPHD) -> None:
    t = f.table
    assert np.isfinite(t).all()
    assert (t[0] >= 0).all()
    pxx, pxy, pyy = t[3:]
    assert (pxx > 0).all() and (pyy > 0).all()
    assert (pxx * pyy - pxy * pxy > 0).all()
    mix = f.mixture
    assert np.array_equal(mix.covs, mix.covs.transpose(0, 2, 1))
    assert len(f) <= f.config.reduction.max_components + 1


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    steps=st.lists(
        st.tuples(
            point_sets(),
            st.lists(angle, max_size=6),
            st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-3.2, 3.2)),
            st.lists(angle, max_size=4),
        ),
        min_size=1,
        max_size=6,
    ),
    birth=st.sampled_from(["fixed", "measurement"]),
    pd_model=st.sampled_from(["seed", "constant"]),
)
def test_updates_keep_a_valid_mixture(steps, birth, pd_model):
    f = RobotCentricPHD(
        PHDConfig.perera2021().replace(
            births={"model": birth}, lidar={"pd_model": pd_model}, reduction={"max_components": 32}
        )
    )
    for points, bearings, odo, nulls in steps:
        f.predict(np.array(odo))
        assert_valid(f)
        f.update_lidar(points, null_bearings=np.array(nulls))
        assert_valid(f)
        f.update_camera(np.array(bearings))
        assert_valid(f)
    positions, weights = f.estimate()
    assert np.isfinite(positions).all() and (weights >= 0.5 / 1e3).all()


@settings(max_examples=60, deadline=None)
@given(
    data=arrays(np.float64, (12, 2), elements=near),
    log_var=arrays(np.float64, 12, elements=st.floats(-10.0, 1.0)),
    weights=arrays(np.float64, 12, elements=st.floats(0.0, 2.0)),
    n=st.integers(1, 12),
    threshold=st.sampled_from([0.5, 4.0, 16.0, 1e6]),
)
def test_merge_preserves_weight_and_gives_pd_covariances(data, log_var, weights, n, threshold):
    covs = np.exp(log_var[:n])[:, None, None] * np.eye(2)
    table = table_from_arrays(weights[:n], data[:n], covs)
    out = merge(table, threshold)
    # Exact up to the 1e-150 weight floor of the moment matching.
    assert np.isclose(out[0].sum(), weights[:n].sum(), rtol=1e-12, atol=1e-140)
    pxx, pxy, pyy = out[3:]
    assert np.isfinite(out).all()
    assert (pxx > 0).all() and (pxx * pyy - pxy * pxy > -1e-18).all()
