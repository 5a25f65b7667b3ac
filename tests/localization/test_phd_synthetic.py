"""End-to-end: on the same synthetic data, lidar + camera beats lidar only (Perera 2021)."""

from __future__ import annotations

import numpy as np

from localization import PHDConfig
from tests.localization.scenario import run_scenario


def test_lidar_camera_beats_lidar_only_on_the_seed_metric():
    # The synthetic sensors follow the Perera 2021 study's models (eq. 19 lidar range factor, fixed
    # births), so the filters run with them: PHDConfig.perera2021().
    runs = {
        mode: [
            run_scenario(mode, seed=s, steps=400, config=PHDConfig.perera2021().replace(mode=mode))
            for s in (0, 1)
        ]
        for mode in ("lidar-camera", "lidar-only")
    }
    lc, lo = runs["lidar-camera"], runs["lidar-only"]
    for c, o in zip(lc, lo, strict=True):
        # % of in-range time with error > 0.30 m (seed fig. 7): LC clearly lower.
        assert c.summary["percent_large_error"] < 0.7 * o.summary["percent_large_error"]
        assert c.summary["median_error_m"] < o.summary["median_error_m"]
        assert c.summary["percent_accurate"] > o.summary["percent_accurate"]


def test_scenario_is_deterministic():
    a = run_scenario("lidar-camera", seed=3, steps=80)
    b = run_scenario("lidar-camera", seed=3, steps=80)
    assert a.summary == b.summary and a.mean_gospa == b.mean_gospa
    assert np.isfinite(a.mean_gospa)
