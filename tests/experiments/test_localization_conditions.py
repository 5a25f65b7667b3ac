"""experiments/localization_conditions.py on a tiny budget, and its arithmetic."""

from __future__ import annotations

import json
import math

import pytest

from experiments import localization_conditions as lc
from experiments.results_page import _check


def test_band_pct_weights_bins_by_their_pair_steps():
    by_range = {
        "edges_m": [0.0, 0.5, 1.0, 1.5, 2.0],
        "pair_steps": [100, 300, 0, 50],
        "pct_err_gt_30cm": [10.0, 2.0, float("nan"), 40.0],
    }
    assert lc.band_pct(by_range, 0.0, 1.0) == pytest.approx((10 * 100 + 2 * 300) / 400)
    assert lc.band_pct(by_range, 1.0, 2.0) == pytest.approx(40.0)
    assert math.isnan(lc.band_pct(by_range, 2.0, 3.0))


def _row(median, gospa, ugv0, cost=1.0):
    return {
        "pair_median_pct": median,
        "gospa_m": gospa,
        "ugv0_above_25": ugv0,
        "cost_ms_per_step": cost,
    }


def test_goals_say_missed_when_the_camera_makes_it_worse():
    rows = {
        "phd-lc": _row(3.5, 0.81, 2),
        "phd-lo": _row(2.7, 0.75, 2),
        "pmb-lc": _row(2.0, 0.60, 1, cost=1.2),
        "pmb-lo": _row(2.5, 0.70, 2),
    }
    verdicts = lc.goals("sim-6m-20", rows)
    assert verdicts[0].endswith("missed") and verdicts[1].endswith("met")
    assert "GOSPA 25.9 % lower" in verdicts[2] and verdicts[2].endswith("met")
    # The cost ratio from the alternated timing when given: 2x phd-lc's misses the goal.
    slow = lc.goals("sim-6m-20", rows, {"phd-lc": 1.0, "pmb-lc": 2.0})
    assert "cost 2.00x" in slow[2] and slow[2].endswith("missed")
    study = lc.goals("perera2021", rows)
    assert study[0].endswith("missed")  # 2.7 / 3.5 < 2x


def test_camera_rays_config_comes_from_the_measured_camera():
    from swarm_env.config import SIMULATOR_PHD

    phd = lc.camera_rays_phd(SIMULATOR_PHD)
    assert phd.births.camera == "ray"
    assert phd.births.camera_weight == pytest.approx(1.00 / 1.22)
    assert phd.camera.clutter_intensity == pytest.approx(0.22)
    assert phd.births.camera_max_range_m == 4.75
    assert phd.lidar.pd_midpoint_m == SIMULATOR_PHD.lidar.pd_midpoint_m  # the rest unchanged


def _tiny(tmp_path, preset: str, *extra: str) -> dict:
    """A 2 s run of ``preset`` on report seed 4: its results file, checked by the page."""
    args = ["--presets", preset, "--report-seeds", "4", "--duration", "2", *extra]
    assert lc.main([*args, "--out", str(tmp_path)]) == 0
    path = tmp_path / f"localization_conditions_{preset.replace('-', '_')}.json"
    data = json.loads(path.read_text())
    _check(path.name, data)  # the results page accepts it
    return data


def test_tiny_run_writes_a_results_page_file(tmp_path):
    data = _tiny(tmp_path, "perera2021", "--decision-seeds", "0")
    assert data["seeds"] == {"decision": [0], "report": [4]}
    assert [r[0] for r in data["table"]["rows"]] == list(lc.LOCALIZERS)
    for name in lc.LOCALIZERS:
        row = data["rows"][name]
        assert row["gospa_m"] > 0.0  # 20 robots: none localizes every teammate in 2 s
        assert row["per_seed_gospa_m"] == [pytest.approx(row["gospa_m"])]  # one seed
        assert row["cost_ms_per_step"] > 0.0
    # The camera localizers are scored to 3 m, the lidar-only ones are not.
    assert data["rows"]["pmb-lc"]["by_range_pct"]["2-3"] is not None
    assert data["rows"]["pmb-lo"]["by_range_pct"]["2-3"] is None


def test_tiny_simulator_run_has_the_camera_rays_row(tmp_path):
    data = _tiny(tmp_path, "lab-3m-4")
    assert data["table"]["rows"][-1][0] == lc.CAMERA_RAYS
    assert any(v.startswith(lc.CAMERA_RAYS) for v in data["verdict"].split("; "))


def test_report_seeds_must_not_be_decision_seeds(tmp_path):
    with pytest.raises(ValueError, match="decision seeds"):
        lc.main(
            [
                "--presets",
                "lab-3m-4",
                "--decision-seeds",
                "0,1",
                "--report-seeds",
                "1",
                "--out",
                str(tmp_path),
            ]
        )
    with pytest.raises(ValueError, match="preset"):
        lc.main(["--presets", "nope", "--out", str(tmp_path)])
