"""P-MultiReg in the simulator with the radio on (``swarm-phd mutual``'s episode), short."""

from __future__ import annotations

import math

import pytest

from swarm_phd.mutual import run_episode


def test_square_start_is_ambiguous_until_a_robot_moves():
    """Four robots on a square (Table 2's start): P-MultiReg returns several formations until
    ugv_3 starts its circle at 5 s; then every teammate is registered uniquely and right."""
    res = run_episode(
        "square", ("p-multireg",), seed=0, observer="ugv_0", duration_s=12.0, n_particles=200
    )
    rows = res["methods"]["p-multireg"]["pairs"]
    assert set(rows) == {"ugv_0->ugv_1", "ugv_0->ugv_2", "ugv_0->ugv_3"}
    for pair, row in rows.items():
        assert 5.0 < row["first_correct_registration_s"] < 9.0, pair
        # Right from the first unique registration to the end (12 s): over a third of the time.
        assert row["pct_distance"] > 30.0 and row["pct_orientation"] > 30.0, pair
        assert row["pct_distance"] < 70.0, pair  # and wrong (ambiguous) before it
    assert math.isfinite(res["methods"]["p-multireg"]["cost_ms_per_step_per_observer"])


def test_bad_arguments():
    with pytest.raises(ValueError, match="scenario"):
        run_episode("moon", ("p-multireg",), seed=0)
    with pytest.raises(ValueError, match="methods"):
        run_episode("square", ("ekf",), seed=0, duration_s=1.0)
