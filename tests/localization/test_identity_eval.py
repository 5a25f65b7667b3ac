"""``swarm-phd evaluate`` plumbing of the identity-aware localizers (id-phd, ukf, pf)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from localization.registry import LOCALIZERS
from localization.registry import oracle_range_bearing as _oracle_range_bearing
from swarm_phd.evaluate import IdentityScorer, evaluate_localization


def test_oracle_identities_match_detections_one_to_one():
    rel = np.zeros((3, 3, 2))
    rel[0, 1] = [1.0, 0.0]
    rel[0, 2] = [0.0, 1.5]
    truth = SimpleNamespace(relative_xy=rel)
    det = np.array([[0.05, 1.45], [1.02, 0.01], [2.0, 2.0], [1.05, 0.0]])
    out = _oracle_range_bearing(det, truth, observer=0)
    assert sorted(out) == [1, 2]  # the far one is clutter; one detection per robot
    np.testing.assert_allclose(out[2], [math.hypot(0.05, 1.45), math.atan2(1.45, 0.05)])
    assert out[1][0] in (pytest.approx(1.02, abs=1e-3), pytest.approx(1.05, abs=1e-3))


def test_identity_scorer_counts_missing_as_large():
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 0.0]])
    rel = np.zeros((3, 3, 2))
    rel[0, 1], rel[0, 2] = [1.0, 0.0], [0.0, 1.0]
    truth = SimpleNamespace(relative_xy=rel, poses=poses)
    sc = IdentityScorer(3)
    sc.add(0, truth, np.array([False, True, True]), {1: np.array([1.05, 0.0, 0.6])})
    s = sc.summary()
    assert s["id_percent_large_error"] == pytest.approx(50.0)
    assert s["id_percent_missing"] == pytest.approx(50.0)
    assert s["id_median_error_m"] == pytest.approx(0.05)
    assert s["id_median_heading_error_deg"] == pytest.approx(math.degrees(0.1))


def test_evaluate_runs_identity_localizers_and_keeps_phd_path_unchanged():
    assert {"phd-lc", "phd-lo", "id-phd", "ukf", "pf"} <= set(LOCALIZERS)
    both = evaluate_localization("seed-lab", 3.0, ["phd-lc", "id-phd", "ukf", "pf"], [0])
    alone = evaluate_localization("seed-lab", 3.0, ["phd-lc"], [0])
    assert both["localizers"]["phd-lc"] == alone["localizers"]["phd-lc"]
    assert "identity" not in alone
    assert set(both["identity"]) == {"id-phd", "ukf", "pf"}
    for name in ("id-phd", "ukf", "pf"):
        summary = both["localizers"][name]
        assert summary["scored_observations"] > 0
        assert math.isfinite(both["identity"][name]["id_percent_large_error"])
    with pytest.raises(ValueError, match="--localizer"):
        evaluate_localization("seed-lab", 1.0, ["id-phd", "nope"], [0])
