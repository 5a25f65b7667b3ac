"""The lidar's missed-detection copy under a range-dependent P_d, moment-matched
(``PHDConfig.lidar.missed_moments``), against Monte Carlo of ``(1 - P_d(x)) N(x; m, P)``."""

from __future__ import annotations

import numpy as np
import pytest

from localization import PHDConfig, RobotCentricPHD, phd
from localization.detection import inverse_sigmoid
from localization.mixture import GaussianMixture

SIGMOID = (1.0, 8.78, 2.14)  # the simulator's lidar range factor


@pytest.mark.parametrize(
    ("mean", "cov"),
    [((1.9, 0.3), ((0.02, 0.005), (0.005, 0.01))), ((0.0, -2.2), ((0.003, 0.0), (0.0, 0.04)))],
)
def test_moments_match_monte_carlo(mean, cov):
    m, p = np.array(mean), np.array(cov)
    table = np.array([[0.9], [m[0]], [m[1]], [p[0, 0]], [p[0, 1]], [p[1, 1]]])
    g = 0.9  # the angular factors, at the mean
    pd = g * inverse_sigmoid(np.array([np.hypot(*m)]), *SIGMOID)
    missed_prob, missed = phd.missed_moments(table, pd, *SIGMOID, 0.1)
    x = np.random.default_rng(0).multivariate_normal(m, p, 1_000_000)
    q = 1.0 - g * inverse_sigmoid(np.hypot(x[:, 0], x[:, 1]), *SIGMOID)
    z = q.mean()
    mc_mean = (x * q[:, None]).mean(axis=0) / z
    d = x - mc_mean
    mc_cov = np.einsum("ki,kj,k->ij", d, d, q) / (z * len(q))
    assert missed_prob[0] == pytest.approx(1.0 - z, abs=5e-3)
    np.testing.assert_allclose(missed[1:3, 0], mc_mean, atol=3e-3)  # linearised range
    np.testing.assert_allclose(missed[[3, 4, 5], 0], mc_cov[[0, 0, 1], [0, 1, 1]], atol=5e-4)
    # outwards: where the lidar would not have seen it
    assert np.hypot(*missed[1:3, 0]) > np.hypot(*m)


def test_flat_detection_probability_leaves_the_copy_as_the_seed_has_it():
    """Well inside the lidar's range f is flat: the missed copy is the prior reweighted."""
    plain = PHDConfig.perera2021().replace(
        lidar={
            "pd_offset": 1.0,
            "pd_midpoint_m": 3.0,
            "pd_slope_per_m": 8.78,
            "occlusion_min_separation_m": 0.0,
        }
    )
    cfg = plain.replace(lidar={"missed_moments": True})
    mix = GaussianMixture(np.array([0.8]), np.array([[0.6, 0.2]]), np.array([0.002 * np.eye(2)]))
    tables = []
    for c in (cfg, plain):
        f = RobotCentricPHD(c)
        f.set_mixture(mix)
        f.update_lidar(np.zeros((0, 2)))
        tables.append(f.table.copy())
    np.testing.assert_allclose(tables[0], tables[1], atol=1e-9)


def test_a_track_at_the_lidar_edge_drifts_outwards_with_missed_scans():
    cfg = PHDConfig.perera2021().replace(
        missed_detection="bernoulli",
        lidar={
            "missed_moments": True,
            "pd_offset": 1.0,
            "pd_slope_per_m": 8.78,
            "pd_midpoint_m": 2.14,
        },
    )
    f = RobotCentricPHD(cfg)
    f.set_mixture(
        GaussianMixture(np.array([0.95]), np.array([[1.9, 0.0]]), np.array([0.01 * np.eye(2)]))
    )
    ranges = []
    for _ in range(5):
        f.update_lidar(np.zeros((0, 2)))
        ranges.append(float(np.hypot(*f.table[1:3, np.argmax(f.table[0])])))
    assert all(b > a for a, b in zip([1.9, *ranges], ranges, strict=False))
    assert ranges[-1] > 2.0  # out of the 2 m disc the lidar covers
