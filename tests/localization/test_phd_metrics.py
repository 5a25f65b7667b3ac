"""OSPA / GOSPA / seed error metrics and the time accumulator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import GaussianMixture, metrics


def test_ospa_edge_cases_and_known_values():
    e = np.empty((0, 2))
    assert metrics.ospa(e, e) == 0.0
    assert metrics.ospa(e, [[1.0, 2.0]], c=2.0) == 2.0
    assert metrics.ospa([[0.0, 0.0]], [[0.3, 0.4]]) == pytest.approx(0.5)
    # One matched at 0.5, one unmatched: ((0.25 + 1) / 2) ** 0.5
    got = metrics.ospa([[0.0, 0.0]], [[0.3, 0.4], [5.0, 5.0]])
    assert got == pytest.approx(math.sqrt(1.25 / 2))
    assert metrics.ospa([[0.0, 0.0], [9.0, 9.0]], [[0.0, 0.1]]) == metrics.ospa(
        [[0.0, 0.1]], [[0.0, 0.0], [9.0, 9.0]]
    )
    with pytest.raises(ValueError, match="shape"):
        metrics.ospa(np.zeros((2, 3)), e)


def test_gospa_decomposition():
    x = np.array([[0.0, 0.0], [2.0, 0.0], [5.0, 5.0]])
    y = np.array([[0.1, 0.0], [2.0, 0.2], [-4.0, 0.0], [-6.0, 0.0]])
    r = metrics.gospa(x, y, c=1.0, p=2, alpha=2)
    assert r.missed == 1 and r.false == 2
    assert r.localisation == pytest.approx(0.01 + 0.04)
    assert r.distance**2 == pytest.approx(0.05 + 0.5 * 3)
    assert r.missed_cost == pytest.approx(0.5) and r.false_cost == pytest.approx(1.0)
    assert metrics.gospa(np.empty((0, 2)), np.empty((0, 2))).distance == 0.0
    assert metrics.gospa([[0.0, 0.0]], np.empty((0, 2))).distance == pytest.approx(math.sqrt(0.5))
    # A pair farther than c costs exactly a miss plus a false alarm.
    far = metrics.gospa([[0.0, 0.0]], [[3.0, 0.0]])
    assert far.missed == 1 and far.false == 1 and far.distance == pytest.approx(1.0)


def test_closest_component_error_ignores_light_components_and_is_inf_safe():
    mix = GaussianMixture(
        np.array([0.05, 0.9]), np.array([[0.0, 0.0], [1.0, 0.0]]), np.tile(np.eye(2), (2, 1, 1))
    )
    err = metrics.closest_component_errors([[0.0, 0.0], [1.0, 0.1]], mix)
    assert np.allclose(err, [1.0, 0.1])
    empty = metrics.closest_component_errors([[0.0, 0.0]], GaussianMixture.empty())
    assert np.isinf(empty).all()
    assert metrics.in_range_mask([[1.0, 1.0], [1.5, 1.5]]).tolist() == [True, False]


def test_closest_component_errors_padded_is_the_per_robot_reference_and_the_seed_scorer():
    # Every robot at once must give closest_component_errors robot by robot, and the errors
    # SeedScorer.update scores on the pairs in range: the localization term and the evaluation
    # share one matching rule (weight > 0.1, closest component).
    rng = np.random.default_rng(7)
    r, c = 5, 6
    counts = np.array([0, 1, 3, 6, 4])
    weights = np.where(np.arange(c) < counts[:, None], rng.uniform(0, 1, (r, c)), 0.0)
    means = rng.uniform(-2, 2, (r, c, 2))
    rel = rng.uniform(-2, 2, (r, r, 2))
    err = metrics.closest_component_errors_padded(rel, weights, means, 0.1)
    assert err.shape == (r, r)
    for i in range(r):
        k = counts[i]
        mix = GaussianMixture(weights[i, :k], means[i, :k], np.tile(np.eye(2), (k, 1, 1)))
        np.testing.assert_allclose(err[i], metrics.closest_component_errors(rel[i], mix))
    assert np.isinf(err[0]).all()  # no component at all
    in_range = metrics.in_range_pairs(rel, 2.0)
    scored = metrics.SeedScorer(r, range_m=2.0).update(rel, in_range, weights, means)
    np.testing.assert_allclose(scored[in_range], err[in_range])
    empty = metrics.closest_component_errors_padded(rel, np.zeros((r, 0)), np.zeros((r, 0, 2)))
    assert empty.shape == (r, r) and np.isinf(empty).all()


def test_scorer_accumulates_percentages_and_cardinality():
    scorer = metrics.LocalizationScorer()
    good = GaussianMixture(np.array([1.0]), np.array([[1.0, 0.0]]), np.eye(2)[None] * 0.01)
    scorer.update([[1.0, 0.05]], [7], good)  # accurate
    scorer.update([[1.0, 0.2]], [7], good)  # 0.2 m: neither accurate nor large
    scorer.update([[1.0, 0.5]], [7], good)  # large
    scorer.update([[1.0, 0.0]], [7], GaussianMixture.empty())  # no component: large
    scorer.update(np.empty((0, 2)), [], good)  # nobody in range
    assert scorer.percent_large_error() == {7: 50.0}
    assert scorer.percent_accurate() == {7: 25.0}
    s = scorer.summary()
    assert s["percent_large_error"] == 50.0 and s["robots_over_25pct"] == 1.0
    assert s["cardinality_mae"] == pytest.approx((0 + 0 + 0 + 1 + 1) / 5)
    with pytest.raises(ValueError, match="ids"):
        scorer.update([[1.0, 0.0]], [1, 2], good)


def test_scorer_per_observer_api_and_gospa_mapping():
    scorer = metrics.LocalizationScorer(3)
    mix = GaussianMixture(np.array([1.0]), np.array([[1.0, 0.0]]), np.eye(2)[None] * 0.01)
    scorer.add(0, [[1.0, 0.05]], mix, range_m=2.0)  # accurate, GOSPA 0.05
    scorer.add(2, [[1.0, 0.5], [0.0, 1.0]], mix)  # large + inf (nothing near (0, 1))
    s = scorer.summary()
    assert s["pct_time_err_gt_30cm"]["per_robot"][0] == 0.0
    assert math.isnan(s["pct_time_err_gt_30cm"]["per_robot"][1])  # observer never scored
    assert s["pct_time_err_gt_30cm"]["per_robot"][2] == 100.0
    assert s["pct_time_within_10cm"]["median"] == 50.0
    # GOSPA step 2: (0.5^2 + 0.5 * 1) ** 0.5 (one assigned at 0.5, one missed)
    assert s["gospa_mean"] == pytest.approx((0.05 + math.sqrt(0.25 + 0.5)) / 2)
    r = metrics.gospa([[0.0, 0.0]], [[0.3, 0.4]])
    assert r["total"] == r.distance == pytest.approx(0.5)
    assert r.as_dict()["missed"] == 0
    with pytest.raises(KeyError):
        r["nope"]
    with pytest.raises(TypeError):
        metrics.LocalizationScorer(3, 0.5)  # thresholds are keyword-only
