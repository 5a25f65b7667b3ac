"""FastSLAM with Monte-Carlo data association (Stegagno 2012 chapter 5) on a synthetic swarm."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.mutual.fastslam import FastSLAMConfig, FastSLAMLocalizer
from swarm_core.geometry import wrap_angle

from .synthetic import SyntheticSwarm


def _run(world: SyntheticSwarm, vel: np.ndarray, steps: int, **cfg) -> FastSLAMLocalizer:
    loc = FastSLAMLocalizer("ugv_0", world.ids, FastSLAMConfig(**cfg), np.random.default_rng(0))
    for _ in range(steps):
        meas, comms = world.step(vel, det_noise_m=0.015)
        loc.step(world.time_s, meas["ugv_0"], comms["ugv_0"])
    return loc


def test_positions_and_identities_of_still_teammates():
    """Everyone still on an irregular triangle: the observer's own detections give the positions,
    the teammates' broadcast detections tell which teammate is where (identity)."""
    world = SyntheticSwarm(np.array([[0.0, 0.0, 0.3], [1.1, 0.4, 2.0], [0.2, 1.3, -1.0]]), seed=1)
    loc = _run(world, np.zeros((3, 2)), 40, n_particles=500)
    est = loc.estimates()
    for j in (1, 2):
        truth = world.relative(0, j)
        assert np.hypot(*(est[f"ugv_{j}"][:2] - truth[:2])) < 0.1, j
    assert loc.mu_r.shape == (500, 2, 3) and loc.cov_r.shape == (500, 2, 3, 3)


def test_a_moving_teammate_gets_its_orientation():
    """A teammate that drives a curve, with its odometry on the radio: the particles whose bank
    orientation fits its odometry keep explaining the detections; its heading converges."""
    world = SyntheticSwarm(np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 2.2], [-0.4, 1.1, 0.5]]), seed=2)
    vel = np.array([[0.0, 0.0], [0.1, 0.25], [0.0, 0.0]])
    loc = _run(world, vel, 120, n_particles=400)
    est = loc.estimates()["ugv_1"]
    truth = world.relative(0, 1)
    assert np.hypot(*(est[:2] - truth[:2])) < 0.1
    assert abs(float(wrap_angle(est[2] - truth[2]))) < math.radians(15.0)


def test_bank_orientations_are_regular():
    world = SyntheticSwarm(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 1.0]]), seed=3)
    loc = _run(world, np.zeros((2, 2)), 1, n_particles=400, n_orientations=4)
    theta = loc.mu_r[loc.init_r[:, 0], 0, 2]
    # New teammates start on the bank's orientations 0, 90, 180, 270 deg (then EKF-updated).
    k = np.round(np.mod(theta, 2 * np.pi) / (np.pi / 2)) % 4
    assert set(k.astype(int)) == {0, 1, 2, 3}
    assert np.allclose(np.mod(theta - k * np.pi / 2 + 0.1, 2 * np.pi), 0.1, atol=0.05)


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="n_particles"):
        FastSLAMConfig(n_particles=0)
    with pytest.raises(ValueError, match="detection_std_m"):
        FastSLAMConfig(detection_std_m=-0.1)


def test_detection_weight_is_the_marginal_likelihood_by_hand():
    """A particle's log-weight grows by the detection's marginal likelihood: the sum over the
    landmarks it may come from of N(z; m, P + R), plus the "new" density. Written out here
    with scipy's Gaussian, for a teammate, a feature and a landmark already used by the scan."""
    from scipy.stats import multivariate_normal

    loc = FastSLAMLocalizer(
        "ugv_0",
        ("ugv_0", "ugv_1", "ugv_2"),
        FastSLAMConfig(n_particles=2, max_features=2),
        np.random.default_rng(0),
    )
    loc.init_r[:] = [[True, True], [True, False]]
    loc.mu_r[:, 0] = [[1.0, 0.2, 0.3], [0.9, -0.1, 1.0]]
    loc.mu_r[:, 1] = [[-0.5, 1.0, 0.0], [0.0, 0.0, 0.0]]
    loc.cov_r[0, 0] = [[0.02, 0.005, 0.0], [0.005, 0.01, 0.0], [0.0, 0.0, 0.1]]
    loc.active_f[:, 0] = True
    loc.mu_f[:, 0] = [[1.2, 0.0], [0.8, 0.3]]
    loc.cov_f[:, 0] = 0.04 * np.eye(2)
    used = np.zeros((2, 4), dtype=bool)
    used[1, 2] = True  # particle 1's feature took an earlier detection of this scan
    z = np.array([1.05, 0.12])
    r_meas = loc.config.detection_std_m**2 * np.eye(2)
    before = loc.logw.copy()
    loc._update_detection(z, used)

    def n(mean, cov):
        return multivariate_normal(mean, cov + r_meas).pdf(z)

    density = loc.config.new_density_per_m2
    expected = [
        n([1.0, 0.2], [[0.02, 0.005], [0.005, 0.01]])
        + n([-0.5, 1.0], np.eye(2))
        + n([1.2, 0.0], 0.04 * np.eye(2))
        + density,
        n([0.9, -0.1], np.eye(2)) + density,
    ]
    np.testing.assert_allclose(loc.logw - before, np.log(expected), rtol=1e-12)
