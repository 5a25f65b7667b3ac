"""The results tables of ``agents.sb3.report``: pooling runs over training seeds."""

from __future__ import annotations

import numpy as np
import pytest

from agents.sb3.report import markdown_table, pooled


def _result(values):
    per_seed = [{"formation_error_m": v, "episode_return": -10 * v} for v in values]
    keys = per_seed[0]
    mean = {k: float(np.mean([d[k] for d in per_seed])) for k in keys}
    std = {k: float(np.std([d[k] for d in per_seed])) for k in keys}
    return {"per_seed": per_seed, "mean": mean, "std": std}


def test_pooled_is_over_all_episodes_and_reports_the_run_spread():
    # Two runs (training seeds) x two held-out seeds: pooled mean of [0.1, 0.3, 0.2, 0.4] is
    # 0.25, population std sqrt(0.0125); run means 0.2 and 0.3 -> their std 0.05.
    p = pooled([_result([0.1, 0.3]), _result([0.2, 0.4])], "formation_error_m")
    assert p["mean"] == pytest.approx(0.25)
    assert p["std"] == pytest.approx(0.0125**0.5)
    assert p["std_of_run_means"] == pytest.approx(0.05)
    assert p["n_runs"] == 2


def test_markdown_table_has_a_row_per_policy_and_a_pooled_row_per_group():
    results = {"a.zip": _result([0.1, 0.3]), "b.zip": _result([0.2, 0.4]), "x": _result([1.0])}
    table = markdown_table(results, "formation_error_m", {"PPO g": ["a.zip", "b.zip"]})
    lines = table.strip().splitlines()
    assert len(lines) == 2 + 3 + 1
    assert "0.200 ± 0.100" in lines[2]  # a.zip: mean 0.2, std 0.1
    assert "**0.250 ±" in lines[-1] and "2 training seeds" in lines[-1]
