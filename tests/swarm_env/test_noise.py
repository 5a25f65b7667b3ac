"""Tabulated normal draws (lidar noise) and batched encoder advance."""

import pickle

import numpy as np
import pytest
from scipy import stats

from swarm_env.sensors.noise import TabulatedNormal
from swarm_env.sensors.odometry import OdometryConfig, WheelEncoders


def test_tabulated_normal_is_standard_normal():
    z = TabulatedNormal("normal", 1.0).draw(np.random.default_rng(0), 200_000).astype(np.float64)
    assert abs(z.mean()) < 0.01
    assert abs(z.std() - 1.0) < 0.01
    # Kolmogorov-Smirnov against N(0, 1): quantisation and the 4.3-sigma truncation are
    # far below what 2e5 samples can resolve.
    assert stats.kstest(z, "norm").pvalue > 0.01
    assert np.abs(z).max() < 4.4


def test_tabulated_transform_and_determinism():
    lognormal = TabulatedNormal("lognormal", 0.05)
    a = lognormal.draw(np.random.default_rng(3), (2, 500))
    b = lognormal.draw(np.random.default_rng(3), (2, 500))
    assert a.dtype == np.float32 and a.shape == (2, 500)
    assert np.array_equal(a, b)
    assert (a > 0).all()
    assert abs(np.log(a).std() - 0.05) < 0.005
    # Pickles as its parameters (envs stay small) and shares the table.
    clone = pickle.loads(pickle.dumps(lognormal))
    assert clone.table is lognormal.table
    assert len(pickle.dumps(lognormal)) < 1000
    with pytest.raises(ValueError, match="scale"):
        TabulatedNormal("normal", -1.0)
    with pytest.raises(ValueError, match="kind"):
        TabulatedNormal("uniform", 1.0)


def test_encoders_advance_many_substeps_equals_one_at_a_time():
    cfg = OdometryConfig()
    speeds = np.random.default_rng(1).uniform(-0.3, 0.3, size=(5, 4, 2))
    one = WheelEncoders(cfg, 4, 0.03, 0.15)
    many = WheelEncoders(cfg, 4, 0.03, 0.15)
    rng_one, rng_many = np.random.default_rng(7), np.random.default_rng(7)
    stepwise = np.stack([one.advance(s[None], 0.02, rng_one)[0] for s in speeds])
    batched = many.advance(speeds, 0.02, rng_many)
    np.testing.assert_allclose(batched, stepwise, rtol=0, atol=1e-12)
    np.testing.assert_allclose(many.wheel_angle_rad, one.wheel_angle_rad, rtol=0, atol=1e-12)
    d_one, v_one = one.sample(0.1)
    d_many, v_many = many.sample(0.1, batched[-1])
    np.testing.assert_array_equal(d_one, d_many)
    np.testing.assert_array_equal(v_one, v_many)
