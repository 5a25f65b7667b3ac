"""agents.sb3.distill_fit: the per-phase fit of a distilled residual to its teacher."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.sb3.distill_fit import collect_fit, main, phase_table  # noqa: E402
from tests.agents.test_residual import train_frozen_residual  # noqa: E402


def test_phase_table_by_hand():
    # Two phases; the teacher's command ignores the base's (label = -base + 0.1), the
    # student carries half the label; a wandering row with a huge label is left out.
    base = np.array([[0.2, 0.0], [-0.2, 0.4], [0.4, -0.4], [0.0, 0.0], [0.6, 0.2]])
    label = np.array([[-0.1, 0.0], [0.3, -0.4], [-0.3, 0.4], [0.9, 0.9], [-0.5, -0.2]])
    fit = {
        "step": np.array([0, 1, 5, 5, 6]),
        "label": label,
        "correction": label / 2,
        "base": base,
        "wandering": np.array([False, False, False, True, False]),
    }
    first, second = phase_table(fit, phases=(0, 5))
    assert (first["from_step"], first["to_step"], first["n"]) == (0, 5, 2)
    assert (second["from_step"], second["to_step"], second["n"]) == (5, None, 2)
    assert first["label_abs_v"] == pytest.approx(0.2)
    assert first["mse_zero_v"] == pytest.approx((0.01 + 0.09) / 2)
    assert first["mse_student_v"] == pytest.approx((0.0025 + 0.0225) / 2)
    assert first["r2_v"] == pytest.approx(0.75)  # half the label carried: 1 - 1/4
    # Teacher's command 0.1 whatever the base's: slope 0; the student's: base / 2 + 0.05.
    assert first["slope_teacher_v"] == pytest.approx(0.0, abs=1e-12)
    assert first["slope_student_v"] == pytest.approx(0.5)
    assert first["slope_teacher_omega"] == pytest.approx(0.0, abs=1e-12)  # omega 0 and 0
    with pytest.raises(ValueError, match="phases"):
        phase_table(fit, phases=(5, 0))


def test_a_teacher_that_is_the_base_has_nothing_to_carry(tmp_path):
    """A frozen residual (correction 0) of `scripted:formation` against the teacher
    `scripted:formation` itself: every label and correction is 0, both commands follow the
    base's with slope 1. Against the truth teacher the labels are not 0 and the frozen
    student carries none of them (R^2 0)."""
    path = train_frozen_residual(tmp_path / "run")
    same = collect_fit(path, "scripted:formation", [100])
    assert len(same["step"]) > 0
    np.testing.assert_array_equal(same["label"][~same["wandering"]], 0.0)
    np.testing.assert_allclose(same["correction"], 0.0, atol=1e-6)
    (row,) = phase_table(same, phases=(0,))
    assert row["slope_teacher_v"] == pytest.approx(1.0)
    assert row["slope_student_v"] == pytest.approx(1.0, abs=1e-4)
    out = tmp_path / "fit.json"
    assert main([str(path), "--teacher", "privileged:formation@truth", "--seeds", "100",
                 "--phases", "0,10", "--out", str(out)]) == 0  # fmt: skip
    rows = json.loads(out.read_text())["models"][str(path)]
    assert rows[0]["mse_zero_v"] > 0.0
    assert rows[0]["r2_v"] == pytest.approx(0.0, abs=1e-3)
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nope.zip"), "--teacher", "scripted:formation"])
