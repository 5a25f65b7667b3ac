"""Source-study baselines: the UKF tracker (IR-UKF study) and the particle filter (Lee 2012)."""

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


# ------------------------------------------ Lee 2012: range-only readings and the filter's start
def test_trilaterate_recovers_the_point_from_exact_ranges():
    from localization.baselines.particle import trilaterate

    # Hand-derived: stations (0,0), (2,0), (0,2), all sqrt(2) from (1,1).
    st3 = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    np.testing.assert_allclose(trilaterate(st3, np.full(3, math.sqrt(2.0))), [1.0, 1.0])
    rng = np.random.default_rng(0)
    stations = rng.uniform(-1.0, 1.0, (6, 2))
    q = np.array([1.7, -0.9])
    np.testing.assert_allclose(trilaterate(stations, np.hypot(*(q - stations).T)), q, atol=1e-10)
    with pytest.raises(ValueError, match="stations"):
        trilaterate(stations[:2], np.ones(2))


def test_trilaterate_noisy_ranges_within_the_expected_error():
    """Range noise sigma. Linear fix: subtracting circle 0 makes the right-hand side's noise
    ``2 r_0 dr_0 - 2 r_i dr_i``, so its covariance is ``A^+ S A^+T`` with
    ``S = 4 sigma^2 (r_0^2 11^T + diag(r_i^2))``, above the Cramer-Rao bound
    ``sigma^2 (H^T H)^-1`` (H = unit vectors stations -> point) that the Gauss-Newton
    refinement reaches."""
    from localization.baselines.particle import refine_fix, trilaterate

    stations = np.array([[0.0, 0.0], [0.4, 0.0], [0.0, 0.4], [0.3, 0.3]])
    q = np.array([1.2, 0.8])
    sigma = 0.05
    d = q - stations
    h = d / np.hypot(*d.T)[:, None]
    bound = math.sqrt(sigma**2 * np.trace(np.linalg.inv(h.T @ h)))
    rng = np.random.default_rng(1)
    ranges = np.hypot(*d.T) + rng.normal(0.0, sigma, (2000, 4))
    r = np.hypot(*d.T)
    a = 2.0 * (stations[1:] - stations[0])
    s_b = 4 * sigma**2 * (r[0] ** 2 + np.diag(r[1:] ** 2))
    a_pinv = np.linalg.pinv(a)
    linear_rms = math.sqrt(np.trace(a_pinv @ s_b @ a_pinv.T))
    assert linear_rms > 1.2 * bound
    fixes = np.array([trilaterate(stations, z) for z in ranges])
    rms = math.sqrt(np.mean(np.sum((fixes - q) ** 2, axis=1)))
    assert rms == pytest.approx(linear_rms, rel=0.1)
    refined = np.array([refine_fix(stations, z, f) for z, f in zip(ranges, fixes, strict=True)])
    rms_refined = math.sqrt(np.mean(np.sum((refined - q) ** 2, axis=1)))
    assert rms_refined == pytest.approx(bound, rel=0.1)


def test_collinear_stations_refuse_to_start():
    """Range-only readings from a robot driving straight: the stations are collinear (spread
    0), the mirror point fits as well, so no track starts however many readings arrive."""
    from localization.baselines.particle import station_spread

    assert station_spread(np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]])) < 1e-12
    pf = ParticleFilterTracker(start="trilateration")
    for _ in range(30):
        pf.update({0: (1.0, math.nan)})
        pf.predict(np.array([0.1, 0.0, 0.0]))
    assert pf.ids == ()
    stations, ranges = pf.pending[0]
    assert stations.shape == (20, 2) and ranges.shape == (20,)  # the last max_stations kept
    np.testing.assert_allclose(stations[:, 1], 0.0)


def test_pending_stations_move_with_own_odometry():
    pf = ParticleFilterTracker(start="trilateration")
    pf.update({0: np.array([1.0])})  # a 1-vector is range-only too
    pf.predict(np.array([0.5, 0.0, math.pi / 2]))
    # R(pi/2)^T ((0, 0) - (0.5, 0)) = (0, 0.5)
    np.testing.assert_allclose(pf.pending[0][0], [[0.0, 0.5]], atol=1e-12)


def _range_only_run(start: str, seed: int = 1, n: int = 40) -> list[float | None]:
    """Observer driving a 0.33 m arc per reading, target fixed at (1.5, 0.8): the filter's
    error (m) after each range-only reading (sigma 0.05 m), ``None`` while it has no track."""
    pf = ParticleFilterTracker(start=start, n_particles=300, seed=seed)
    rng = np.random.default_rng(seed)
    target, pose = np.array([1.5, 0.8]), np.zeros(3)
    inc = np.array([0.1 * math.cos(0.15), 0.1 * math.sin(0.15), 0.3])
    out = []
    for _ in range(n):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        d = target - pose[:2]
        rel = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
        pf.update({0: (np.hypot(*rel) + rng.normal(0.0, 0.05), math.nan)})
        est = pf.estimate().get(0)
        out.append(None if est is None else float(np.hypot(*(est - rel))))
        pose = pose + np.array([c * inc[0] - s * inc[1], s * inc[0] + c * inc[1], inc[2]])
        pf.predict(inc)
    return out


def test_range_only_trilateration_start_fixes_then_tracks():
    errors = _range_only_run("trilateration")
    first = next(k for k, e in enumerate(errors) if e is not None)
    assert 2 <= first < 20  # >= 3 stations, then as soon as they are spread enough
    assert errors[first] < 0.3  # the fix itself
    assert max(errors[first:]) < 0.35 and np.mean(errors[-10:]) < 0.2
    # the uniform start estimates from the first reading on, far off at first (a ring)
    uniform = _range_only_run("uniform")
    assert uniform[0] is not None and uniform[0] > 0.5


def test_range_only_likelihood_drops_the_bearing():
    """One range-only reading on a uniform cloud: the resampled particles sit on the ring of
    that range, all around (no bearing information)."""
    pf = ParticleFilterTracker(n_particles=4000, seed=3)
    pf.update({0: (1.0, math.nan)})
    core = pf.particles[0, : pf.config.n_resampled, :2]
    r = np.hypot(*core.T)
    assert abs(np.median(r) - 1.0) < 0.03
    # bearings spread over the circle: mean resultant length ~ 1/sqrt(the ~130 distinct
    # survivors of the 0.2 m annulus), where a reading with a bearing makes it ~ 1
    b = np.arctan2(core[:, 1], core[:, 0])
    assert np.hypot(np.cos(b).mean(), np.sin(b).mean()) < 0.3
    with_bearing = ParticleFilterTracker(n_particles=4000, seed=3)
    with_bearing.update({0: (1.0, 0.0)})
    b = np.arctan2(*with_bearing.particles[0, : pf.config.n_resampled, 1::-1].T)
    assert np.hypot(np.cos(b).mean(), np.sin(b).mean()) > 0.9


def test_range_bearing_trilateration_start_is_the_polar_fix():
    z = (1.2, 0.7)
    fix = np.array([1.2 * math.cos(0.7), 1.2 * math.sin(0.7)])
    pf = ParticleFilterTracker(start="trilateration", seed=2)
    pf.update({4: z})
    assert pf.ids == (4,) and not pf.pending
    cloud = pf.particles[0, :, :2]
    # every particle (the 10 % re-seeded aside) within a few range/bearing sigmas of the fix
    near = np.hypot(*(cloud - fix).T) < 4 * (0.05 + 1.2 * 0.05)
    assert near.mean() > 0.88
    assert np.hypot(*(pf.estimate()[4] - fix)) < 0.02


def test_range_only_and_start_bad_input():
    with pytest.raises(ValueError, match="start"):
        ParticleFilterTracker(start="gps")
    with pytest.raises(ValueError, match="min_station_spread_m"):
        ParticleFilterTracker(min_station_spread_m=0.0)
    pf = ParticleFilterTracker(start="trilateration")
    with pytest.raises(ValueError, match="measurements"):
        pf.update({0: (math.nan, math.nan)})
    with pytest.raises(ValueError, match="measurements"):
        pf.update({0: (-1.0, math.nan)})
    assert pf.ids == () and not pf.pending
