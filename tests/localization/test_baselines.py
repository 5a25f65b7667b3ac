"""Seed baselines: the UKF tracker (seed 003) and the particle filter (seed 004)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from localization.baselines import (
    ParticleConfig,
    ParticleFilterTracker,
    UKFConfig,
    UKFTracker,
)
from localization.baselines._common import compose_poses
from localization.baselines.ukf import merwe_weights, sigma_points
from localization.id_phd import compose_relative

from .relative_scenario import simulate


def _range_bearing(step) -> dict[int, tuple[float, float]]:
    return {
        int(i): (math.hypot(*p), math.atan2(p[1], p[0]))
        for p, i in zip(step.points, step.ids, strict=True)
        if i >= 0
    }


def _run(tracker, steps, start=100):
    pos, head = [], []
    for k, s in enumerate(steps):
        tracker.predict(s.own_delta, s.team_delta)
        if s.points is not None:
            tracker.update(_range_bearing(s))
        if k >= start:
            est = tracker.estimate()
            for i, true in enumerate(s.truth):
                if i in est:
                    pos.append(math.hypot(*(est[i][:2] - true[:2])))
                    if len(est[i]) == 3:
                        d = (est[i][2] - true[2] + math.pi) % (2 * math.pi) - math.pi
                        head.append(abs(d))
                else:
                    pos.append(math.inf)
    return np.array(pos), np.array(head)


def test_compose_poses_is_the_id_phd_mean_map():
    rng = np.random.default_rng(0)
    means = np.column_stack((rng.normal(size=(6, 2)), rng.uniform(-3, 3, 6)))
    team = rng.normal(0, 0.05, (6, 3))
    own = np.array([0.03, 0.01, -0.2])
    ref, _ = compose_relative(
        means, np.tile(np.eye(3), (6, 1, 1)), team, own, np.zeros((6, 3)), np.zeros(3)
    )
    np.testing.assert_allclose(compose_poses(means, team, own), ref, atol=1e-12)


def test_merwe_sigma_points_reproduce_mean_and_covariance():
    wm, wc, lam = merwe_weights(3, 0.5, 2.0, 0.0)
    assert wm.sum() == pytest.approx(1.0, abs=1e-12)
    mean = np.array([[0.5, -0.2, 0.3]])
    a = np.array([[0.3, 0.1, 0.0], [0.0, 0.2, 0.05], [0.1, 0.0, 0.4]])
    cov = (a @ a.T)[None]
    pts = sigma_points(mean, cov, lam)
    np.testing.assert_allclose(np.einsum("s,tsk->tk", wm, pts), mean, atol=1e-12)
    d = pts - mean[:, None]
    np.testing.assert_allclose(np.einsum("s,tsi,tsj->tij", wc, d, d), cov, atol=1e-12)


def test_ukf_converges_with_identities_and_heading():
    steps = simulate(n_teammates=4, steps=300, seed=5)
    pos, head = _run(UKFTracker(), steps)
    assert np.median(pos) < 0.05 and np.percentile(pos, 95) < 0.12
    assert np.median(head) < math.radians(8)


def test_ukf_wraps_the_bearing_residual():
    # A teammate right behind the observer, bearings either side of +-pi: no 2 pi jump.
    f = UKFTracker()
    f.update({0: (1.0, math.pi - 0.01)})
    f.predict(np.zeros(3), {0: np.zeros(3)})
    f.update({0: (1.0, -math.pi + 0.01)})
    x = f.estimate()[0]
    assert x[0] == pytest.approx(-1.0, abs=0.01) and abs(x[1]) < 0.02


def test_particle_filter_converges():
    steps = simulate(n_teammates=4, steps=300, seed=6)
    pos, _ = _run(ParticleFilterTracker(), steps)
    assert np.median(pos) < 0.08 and np.percentile(pos, 90) < 0.2


def test_particle_filter_resamples_90_and_reseeds_10_percent():
    cfg = ParticleConfig(n_particles=200, reseed_range_m=2.0)
    f = ParticleFilterTracker(cfg)
    for _ in range(5):
        f.update({3: (1.0, 0.5)})
    p = f.particles[0]
    core, seeded = p[: cfg.n_resampled], p[cfg.n_resampled :]
    assert cfg.n_resampled == 180 and seeded.shape[0] == 20
    target = np.array([math.cos(0.5), math.sin(0.5)])
    assert np.median(np.hypot(*(core[:, :2] - target).T)) < 0.1
    # the re-seeded 10 % are uniform over the disc (and speed box), not near the target
    assert (np.hypot(seeded[:, 0], seeded[:, 1]) <= 2.0 + 0.1).all()
    assert np.median(np.hypot(*(seeded[:, :2] - target).T)) > 0.5
    np.testing.assert_allclose(f.estimate()[3], core[:, :2].mean(axis=0))


def test_particle_filter_is_deterministic_for_a_seed():
    steps = simulate(n_teammates=2, steps=40, seed=1)
    a, _ = _run(ParticleFilterTracker(seed=3), steps, start=0)
    b, _ = _run(ParticleFilterTracker(seed=3), steps, start=0)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("cls", [UKFTracker, ParticleFilterTracker])
@pytest.mark.parametrize(
    "call, match",
    [
        (lambda f: f.predict([0.0, np.nan, 0.0], {}), "own_odometry"),
        (lambda f: f.predict(np.zeros(2), {}), "own_odometry"),
        (lambda f: f.predict(np.zeros(3), {0: [0.0, 0.0, np.inf]}), r"teammate_odometry\[0\]"),
        (lambda f: f.predict(np.zeros(3), {-1: np.zeros(3)}), "teammate_odometry keys"),
        (lambda f: f.update({0: (np.nan, 0.1)}), r"measurements\[0\]"),
        (lambda f: f.update({0: (-1.0, 0.1)}), r"measurements\[0\] range"),
        (lambda f: f.update({0: (1.0, 0.1, 0.0)}), r"measurements\[0\]"),
        (lambda f: f.update({"a": (1.0, 0.1)}), "measurements keys"),
    ],
)
def test_bad_input_raises_before_any_change(cls, call, match):
    f = cls()
    f.update({0: (1.0, 0.2)})
    before = {k: v.copy() for k, v in f.estimate().items()}
    with pytest.raises(ValueError, match=match):
        call(f)
    after = f.estimate()
    assert before.keys() == after.keys()
    for k in before:
        np.testing.assert_array_equal(before[k], after[k])


@pytest.mark.parametrize(
    "cls, field, value",
    [
        (UKFConfig, "range_std_m", 0.0),
        (UKFConfig, "alpha", float("nan")),
        (UKFConfig, "own_odometry_std_m", -1.0),
        (ParticleConfig, "n_particles", 3),
        (ParticleConfig, "resample_fraction", 1.5),
        (ParticleConfig, "velocity_damping", -0.1),
        (ParticleConfig, "bearing_std_rad", 0.0),
    ],
)
def test_config_validation_names_field(cls, field, value):
    with pytest.raises(ValueError, match=field):
        cls(**{field: value})


small = st.floats(min_value=-0.1, max_value=0.1, allow_nan=False)
turn = st.floats(min_value=-0.5, max_value=0.5, allow_nan=False)
rng_m = st.floats(min_value=0.0, max_value=3.0, allow_nan=False)
brg = st.floats(min_value=-4.0, max_value=4.0, allow_nan=False)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.tuples(small, small, turn),
            st.dictionaries(st.integers(0, 3), st.tuples(small, small, turn), max_size=4),
            st.dictionaries(st.integers(0, 3), st.tuples(rng_m, brg), max_size=4),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_ukf_covariances_stay_symmetric_pd(sequence):
    f = UKFTracker()
    for own, team, meas in sequence:
        f.predict(np.array(own), {k: np.array(v) for k, v in team.items()})
        f.update(meas)
        p = f.covs
        assert np.isfinite(p).all()
        np.testing.assert_allclose(p, p.transpose(0, 2, 1), atol=1e-12)
        if p.shape[0]:
            assert (np.linalg.eigvalsh(p) > 0).all()
        for x in f.estimate().values():
            assert np.isfinite(x).all() and abs(x[2]) <= math.pi
