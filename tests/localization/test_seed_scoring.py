"""The Perera 2021 study's Fig. 7 scoring per (observer, teammate), Stegagno 2012 metrics, GOSPA
split and cardinality (:class:`localization.metrics.SeedScorer`), on hand-derived cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import GaussianMixture, metrics


def _rel(points: dict[tuple[int, int], tuple[float, float]], r: int = 3) -> np.ndarray:
    rel = np.full((r, r, 2), 9.0)  # far away unless given
    rel[np.arange(r), np.arange(r)] = 0.0
    for (i, j), xy in points.items():
        rel[i, j] = xy
    return rel


def _mask(pairs: list[tuple[int, int]], r: int = 3) -> np.ndarray:
    m = np.zeros((r, r), bool)
    for i, j in pairs:
        m[i, j] = True
    return m


def _mix(rows: dict[int, list[tuple[float, float, float]]], r: int = 3):
    """Padded (weights, means) from ``{observer: [(w, x, y), ...]}``."""
    mixtures = []
    for i in range(r):
        comps = np.array(rows.get(i, []), float).reshape(-1, 3)
        mixtures.append(
            GaussianMixture(
                comps[:, 0], comps[:, 1:], np.tile(np.eye(2) * 0.01, (len(comps), 1, 1))
            )
        )
    return metrics.pad_mixtures(mixtures)


def test_never_matched_is_100_and_half_in_range_half_matched_is_50():
    sc = metrics.SeedScorer(3, range_m=2.0)
    rel = _rel({(0, 1): (1.0, 0.0), (0, 2): (0.0, 1.5)})
    # Observer 0 holds one component, on teammate 2 only at step 0.
    on_2 = _mix({0: [(0.9, 0.0, 1.5)]})
    off = _mix({0: [(0.9, -1.0, -1.0)]})
    sc.update(rel, _mask([(0, 1), (0, 2)]), *on_2)  # 1: large, 2: matched
    sc.update(rel, _mask([(0, 1), (0, 2)]), *off)  # 1: large, 2: large
    sc.update(rel, _mask([(0, 1)]), *off)  # 2 out of range: not counted
    sc.update(rel, _mask([(0, 1)]), *on_2)
    bars = sc.observer_bars(0)
    assert bars["per_teammate"][1] == 100.0
    assert bars["per_teammate"][2] == 50.0
    assert math.isnan(bars["per_teammate"][0])  # the observer itself
    assert bars["in_range_steps"] == [0, 4, 2]
    assert bars["tracked_teammates"] == 2 and bars["teammates_above_25pct"] == 2
    assert bars["median"] == 75.0 and bars["max"] == 100.0
    # Observer 1 never had anyone in range: no bar at all.
    assert sc.observer_bars(1)["tracked_teammates"] == 0
    assert math.isnan(sc.observer_bars(1)["median"])
    # Pooled over observer 0's pair-steps: 5 large of 6; a different, smaller number.
    pooled = sc.pooled_per_observer()
    assert pooled["per_robot"][0] == pytest.approx(500 / 6)
    assert math.isnan(pooled["per_robot"][1])
    every = sc.all_observer_bars()
    assert every["tracked_pairs"] == 2 and every["pairs_above_25pct"] == 2
    assert every["per_observer_teammates_above_25pct"] == [2.0, 0.0, 0.0]
    head = sc.summary()["headline"]
    assert head["ugv_0_teammates_above_25pct"] == 2.0
    assert head["ugv_0_median_teammate_pct_err_gt_30cm"] == 75.0
    assert head["pooled_per_observer_median_pct_err_gt_30cm"] == pytest.approx(500 / 6)


def test_threshold_is_strict_and_light_components_are_ignored():
    sc = metrics.SeedScorer(2, range_m=2.0)
    rel = np.array([[[0, 0], [1.0, 0.0]], [[-1.0, 0.0], [0, 0]]])
    mask = np.array([[False, True], [True, False]])
    # Observer 0: component at exactly 0.30 m (not "more than 0.30"), weight 0.5.
    # Observer 1: weight-0.1 component on the truth (not "> 0.1") and a heavy one 0.31 m away.
    w = np.array([[0.5, 0.0], [0.1, 0.9]])
    mu = np.array([[[1.0, 0.3], [0, 0]], [[-1.0, 0.0], [-1.0, 0.31]]])
    err = sc.update(rel, mask, w, mu)
    assert err[0, 1] == pytest.approx(0.3) and err[1, 0] == pytest.approx(0.31)
    pct = sc.per_pair_pct_large()
    assert pct[0, 1] == 0.0 and pct[1, 0] == 100.0
    causes = sc.summary()["large_error_causes_pct_of_pair_steps"]
    # Observer 1's miss: a component within 0.30 m exists but is too light.
    assert causes["low_weight"] == 50.0 and causes["displaced"] == 0.0


def test_seed001_rmse_and_bearing():
    sc = metrics.SeedScorer(2, range_m=2.0)
    rel = np.array([[[0, 0], [1.0, 0.0]], [[-1.0, 0.0], [0, 0]]])
    mask = np.array([[True, True], [False, False]]) & ~np.eye(2, dtype=bool)
    steps = [(1.0, 0.05), (1.0, 0.2), (1.5, 0.0)]  # errors 0.05, 0.2, 0.5 m
    for x, y in steps:
        sc.update(rel, mask, np.array([[0.8], [0.0]]), np.array([[[x, y]], [[0.0, 0.0]]]))
    sc.update(rel, mask, np.zeros((2, 0)), np.zeros((2, 0, 2)))  # nothing: unmatched
    s = sc.summary()
    # < 0.1 m once of 4 in-range steps; bearing errors 2.86, 11.31, 0 deg -> 2 of 4 < 7 deg.
    assert s["seed001"]["pct_time_position_err_lt_10cm"] == 25.0
    assert s["seed001"]["pct_time_bearing_err_lt_7deg"] == 50.0
    assert s["rmse_m"] == pytest.approx(math.sqrt((0.05**2 + 0.2**2 + 0.5**2) / 3))
    b = [math.degrees(math.atan(0.05)), math.degrees(math.atan(0.2)), 0.0]
    assert s["rmse_bearing_deg"] == pytest.approx(math.sqrt(sum(v * v for v in b) / 3))
    assert s["pct_unmatched"] == 25.0
    assert s["seed_fig7"]["observer_ugv_0"]["per_teammate"][1] == 50.0  # 0.5 m and none
    causes = s["large_error_causes_pct_of_pair_steps"]
    assert causes["displaced"] == 25.0 and causes["absent"] == 25.0


def test_bearing_error_wraps_across_pi():
    sc = metrics.SeedScorer(2, range_m=5.0)
    rel = np.array([[[0, 0], [-1.0, 0.01]], [[1.0, 0.0], [0, 0]]])
    mask = np.array([[False, True], [False, False]])
    sc.update(rel, mask, np.array([[1.0], [0.0]]), np.array([[[-1.0, -0.01]], [[0, 0]]]))
    # atan2 jumps from ~+pi to ~-pi; the error is 2 * atan(0.01) ~ 1.15 deg, not ~359 deg.
    assert sc.summary()["rmse_bearing_deg"] == pytest.approx(2 * math.degrees(math.atan(0.01)))


def test_gospa_split_cardinality_and_trace():
    sc = metrics.SeedScorer(3, range_m=2.0, trace_observer=0)
    rel = _rel({(0, 1): (1.0, 0.0), (0, 2): (0.0, 1.5)})
    mask = _mask([(0, 1), (0, 2)])
    # Observer 0: one estimate 0.2 m from teammate 1, a false one in range, a light one in
    # range (weight 0.3, not extracted) and one beyond range (weight 0.6, not extracted).
    w, mu = _mix({0: [(1.0, 1.2, 0.0), (0.8, -1.0, 0.0), (0.3, 0.5, 0.5), (0.6, 3.0, 0.0)]})
    sc.update(rel, mask, w, mu, time_s=0.1)
    g = sc.summary()["gospa"]
    # Observer 0: assigned 0.2 m, teammate 2 missed, one false: 0.04 + 0.5 + 0.5.
    # Observers 1 and 2: nothing in range, no estimates: 0.
    assert g["mean_m"] == pytest.approx(math.sqrt(1.04) / 3)
    assert g["mean_localisation_m2"] == pytest.approx(0.04 / 3)
    assert g["mean_missed_m2"] == pytest.approx(0.5 / 3)
    assert g["mean_false_m2"] == pytest.approx(0.5 / 3)
    assert g["mean_missed_count"] == pytest.approx(1 / 3)
    assert (g["c_m"], g["p"], g["alpha"]) == (1.0, 2.0, 2.0)
    c = sc.summary()["cardinality"]
    # In range: observer 0 holds 2.1 against 2; observers 1, 2 hold 0 against 0.
    assert c["in_range_mae"] == pytest.approx(0.1 / 3)
    # Whole mixture: 2.7 vs 2 teammates; 0 vs 2; 0 vs 2.
    assert c["total_mae"] == pytest.approx((0.7 + 2 + 2) / 3)
    assert c["total_bias"] == pytest.approx((0.7 - 2 - 2) / 3)
    assert sc.trace["weight_sum_in_range"] == [pytest.approx(2.1)]
    assert sc.trace["weight_sum_total"] == [pytest.approx(2.7)]
    assert sc.trace["true_count_in_range"] == [2] and sc.trace["true_count_total"] == [2]
    assert sc.trace["gospa"] == [pytest.approx(math.sqrt(1.04))]
    sc.update(rel, mask, w, mu)  # no time: no trace entry
    assert len(sc.trace["time_s"]) == 1


def test_range_bins():
    sc = metrics.SeedScorer(3, range_m=4.0, range_bins_m=(0.0, 1.0, 2.0))
    rel = _rel({(0, 1): (0.5, 0.0), (0, 2): (1.5, 0.0), (1, 2): (3.0, 0.0)})
    w, mu = _mix({0: [(1.0, 0.5, 0.0)]})
    sc.update(rel, _mask([(0, 1), (0, 2), (1, 2)]), w, mu)
    by = sc.summary()["by_range"]
    assert by["pair_steps"] == [1, 2]  # 3 m falls in the last bin
    assert by["pct_err_gt_30cm"] == [0.0, 100.0]


def test_vectorised_errors_match_the_per_observer_reference():
    rng = np.random.default_rng(3)
    r = 6
    sc = metrics.SeedScorer(r, range_m=2.0)
    for _ in range(5):
        rel = rng.uniform(-3, 3, (r, r, 2))
        rel[np.arange(r), np.arange(r)] = 0
        mask = (np.hypot(rel[..., 0], rel[..., 1]) <= 2.0) & ~np.eye(r, dtype=bool)
        mixtures = []
        for _ in range(r):
            k = int(rng.integers(0, 8))
            mixtures.append(
                GaussianMixture(
                    rng.uniform(0, 1, k), rng.uniform(-3, 3, (k, 2)), np.tile(np.eye(2), (k, 1, 1))
                )
            )
        err = sc.update(rel, mask, *metrics.pad_mixtures(mixtures))
        for i in range(r):
            ref = metrics.closest_component_errors(rel[i], mixtures[i])
            np.testing.assert_allclose(err[i][mask[i]], ref[mask[i]])
            assert np.isnan(err[i][~mask[i]]).all()


def test_bad_input_raises_before_counting():
    sc = metrics.SeedScorer(2)
    rel = np.zeros((2, 2, 2))
    w, mu = np.zeros((2, 1)), np.zeros((2, 1, 2))
    with pytest.raises(ValueError, match="diagonal"):
        sc.update(rel, np.ones((2, 2), bool), w, mu)
    with pytest.raises(ValueError, match="rel_xy"):
        sc.update(np.zeros((3, 3, 2)), np.zeros((2, 2), bool), w, mu)
    with pytest.raises(ValueError, match="weights"):
        sc.update(rel, np.zeros((2, 2), bool), w, np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="in_range"):
        sc.update(rel, np.zeros((2, 2)), w, mu)
    assert sc.in_range_steps.sum() == 0 and sc.observer_steps == 0
    with pytest.raises(ValueError, match="n_robots"):
        metrics.SeedScorer(1)
    with pytest.raises(ValueError, match="alpha"):
        metrics.SeedScorer(2, gospa_alpha=1.0)


def test_padded_table_helpers():
    table = np.zeros((6, 2, 3))
    table[0] = [[0.9, 0.5, 7.0], [0.2, 7.0, 7.0]]  # 7.0: stale data past counts
    table[1] = [[1.0, 2.0, 7.0], [3.0, 7.0, 7.0]]
    table[2] = [[0.5, -0.5, 7.0], [0.0, 7.0, 7.0]]
    w, mu = metrics.weights_means_from_table(table, np.array([2, 1]))
    np.testing.assert_array_equal(w, [[0.9, 0.5, 0.0], [0.2, 0.0, 0.0]])
    np.testing.assert_array_equal(mu[0, :2], [[1.0, 0.5], [2.0, -0.5]])
    assert (mu[0, 2] == 0).all() and (mu[1, 1:] == 0).all()
    rel = np.array([[[0, 0], [2.0, 0.0]], [[-2.0, 0.001], [0, 0]]])
    assert metrics.in_range_pairs(rel, 2.0).tolist() == [[False, True], [False, False]]
    with pytest.raises(ValueError, match="counts"):
        metrics.weights_means_from_table(table, np.array([1]))


def test_pooled_per_observer_matches_the_episode_scorer():
    """The pooled figure is :class:`LocalizationScorer.add`'s statistic, computed apart."""
    rng = np.random.default_rng(7)
    r = 5
    seed = metrics.SeedScorer(r, range_m=2.0)
    pooled = metrics.LocalizationScorer(r)
    for _ in range(20):
        rel = rng.uniform(-2.5, 2.5, (r, r, 2))
        mask = metrics.in_range_pairs(rel, 2.0)
        mixtures = [
            GaussianMixture(
                rng.uniform(0, 1, 4),
                rel[i, rng.integers(0, r, 4)] + rng.normal(0, 0.3, (4, 2)),
                np.tile(np.eye(2), (4, 1, 1)),
            )
            for i in range(r)
        ]
        seed.update(rel, mask, *metrics.pad_mixtures(mixtures))
        for i in range(r):
            pooled.add(i, rel[i][mask[i]], mixtures[i], range_m=2.0)
    ours = seed.summary()["pooled_per_observer"]["per_robot"]
    ref = pooled.summary()["pct_time_err_gt_30cm"]["per_robot"]
    np.testing.assert_allclose(ours, ref)
    assert seed.summary()["gospa"]["mean_m"] == pytest.approx(pooled.summary()["gospa_mean"])
    assert seed.summary()["cardinality"]["in_range_mae"] == pytest.approx(
        pooled.summary()["cardinality_mae"]
    )
