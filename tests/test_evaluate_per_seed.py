"""`swarm-phd evaluate` keeps each seed's headline figures, for comparisons paired by seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_phd.evaluate import PER_SEED_FIGURES, evaluate_localization, seed_figures


def test_seed_figures_by_hand():
    """Between the two counts: GOSPA 2 m over 4 observer-steps; observer 0 has 1 of 10 in-range
    pair-steps above 0.30 m, observer 1 has 2 of 30, observer 2 none in range (no figure)."""
    before = (1.0, 4, np.array([5, 0, 0]), np.array([7, 3, 0]))
    after = (3.0, 8, np.array([6, 2, 0]), np.array([17, 33, 0]))
    figures = seed_figures(before, after)
    assert set(figures) == set(PER_SEED_FIGURES)
    assert figures["gospa_mean_m"] == pytest.approx(0.5)
    # median(10 %, 6.67 %) over the observers; 3 of 40 over all pairs.
    assert figures["pooled_per_observer_median_pct"] == pytest.approx(0.5 * (10.0 + 20.0 / 3))
    assert figures["pct_pair_steps_err_gt_30cm"] == pytest.approx(7.5)
    empty = seed_figures(before, before)
    assert all(math.isnan(v) for v in empty.values())


def test_per_seed_figures_match_a_run_of_that_seed_alone():
    both = evaluate_localization("lab-3m-4", 2.0, ["phd-lc"], [3, 4])["localizers"]["phd-lc"]
    alone = evaluate_localization("lab-3m-4", 2.0, ["phd-lc"], [4])["localizers"]["phd-lc"]
    assert [d["seed"] for d in both["per_seed"]] == [3, 4]
    # Equal to rounding: a seed's GOSPA is a difference of running sums.
    assert both["per_seed"][1] == pytest.approx(alone["per_seed"][0], rel=1e-12, nan_ok=True)
    figures = alone["per_seed"][0]
    assert figures["gospa_mean_m"] == pytest.approx(alone["gospa"]["mean_m"])
    assert figures["pooled_per_observer_median_pct"] == pytest.approx(
        alone["pooled_per_observer"]["median"]
    )
    assert figures["pct_pair_steps_err_gt_30cm"] == pytest.approx(
        alone["pct_pair_steps_err_gt_30cm"]
    )


def test_phase_figures_by_hand():
    from swarm_phd.evaluate import phase_figures

    # per step: (pair-steps above 0.30 m, in-range pair-steps)
    counts = np.array([[2, 4], [1, 4], [0, 0], [0, 6], [3, 6]])
    got = phase_figures(counts, [(0, 2), (2, 3), (3, None)])
    key = "pct_pair_steps_err_gt_30cm@"
    assert got[key + "0-2"] == pytest.approx(100 * 3 / 8)
    assert math.isnan(got[key + "2-3"])  # nothing in range
    assert got[key + "3-"] == pytest.approx(100 * 3 / 12)


def test_phases_split_the_whole_episodes_share_seed_by_seed():
    """One open phase is the whole episode's share; the first k steps' share is that of an
    episode k steps long (the same steps: indexing off by one step would differ), per seed
    and pooled; a bad split is refused before any rollout."""
    key = "pct_pair_steps_err_gt_30cm"
    whole = evaluate_localization("lab-3m-4", 2.0, ["phd-lc"], [3, 4], phases=[0, 7])
    short = evaluate_localization("lab-3m-4", 0.7, ["phd-lc"], [3, 4], phases=[0])
    whole, short = whole["localizers"]["phd-lc"], short["localizers"]["phd-lc"]
    assert whole["by_phase"][f"{key}@0-7"] == pytest.approx(short[key])
    assert short["by_phase"][f"{key}@0-"] == pytest.approx(short[key])
    for long, first in zip(whole["per_seed"], short["per_seed"], strict=True):
        assert long[f"{key}@0-7"] == pytest.approx(first[key], nan_ok=True)
        assert first[f"{key}@0-"] == pytest.approx(first[key], nan_ok=True)
    assert short[key] > 0 and whole["by_phase"][f"{key}@7-"] != short[key]
    with pytest.raises(ValueError, match="phases"):
        evaluate_localization("lab-3m-4", 2.0, ["phd-lc"], [3], phases=[5, 2])
