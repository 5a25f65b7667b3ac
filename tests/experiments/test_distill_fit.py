"""experiments/distill_fit.py: the per-phase fit of a distilled residual to its teacher."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from experiments.distill_fit import collect_fit, main, phase_table  # noqa: E402
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
    assert first["r2_v"] == pytest.approx(0.75)  # half the label carried: 1 - (1 - 1/2)^2
    assert first["sd_base_v"] == pytest.approx(0.2)
    # Teacher's command 0.1 whatever the base's: slope 0; the student's: base / 2 + 0.05.
    assert first["slope_teacher_v"] == pytest.approx(0.0, abs=1e-12)
    assert first["slope_student_v"] == pytest.approx(0.5)
    assert first["slope_teacher_omega"] == pytest.approx(0.0, abs=1e-12)  # omega 0 and 0
    with pytest.raises(ValueError, match="phases"):
        phase_table(fit, phases=(5, 0))


def test_fit_beyond_the_base_by_hand():
    """The label is -base plus a part no line in the base explains (e, orthogonal to the
    base, mean 0). A student that only cancels the base explains most of the label's mean
    square and none of e; one that also carries half of e explains 1 - 1/4 of it."""
    x = np.array([0.0, 1.0, 2.0, 3.0])
    e = np.array([1.0, -1.0, -1.0, 1.0])
    label = -x + e
    common = {
        "step": np.arange(4),
        "label": np.stack([label, label], axis=1),
        "base": np.stack([x, x], axis=1),
        "wandering": np.zeros(4, bool),
    }
    (cancels,) = phase_table({**common, "correction": np.stack([-x, -x], axis=1)}, (0,))
    assert cancels["r2_v"] == pytest.approx(1.0 - 1.0 / np.mean(label**2))
    assert cancels["r2_beyond_base_v"] == pytest.approx(0.0, abs=1e-12)
    assert cancels["slope_teacher_v"] == pytest.approx(0.0, abs=1e-12)  # base + label = e
    half = np.stack([-x + e / 2, -x + e / 2], axis=1)
    (carries,) = phase_table({**common, "correction": half}, (0,))
    assert carries["r2_beyond_base_v"] == pytest.approx(0.75)


def test_a_teacher_that_is_the_base_has_nothing_to_carry(tmp_path):
    """A frozen residual (correction 0) of `scripted:formation` against the teacher
    `scripted:formation` itself: every label and correction is 0, both commands follow the
    base's with slope 1. Against the truth teacher the labels are near 0 where the estimate
    has the teammates and large elsewhere (non-wandering rows), and the frozen student
    carries none of them."""
    path = train_frozen_residual(tmp_path / "run")
    same = collect_fit(path, "scripted:formation", [100])
    assert len(same["step"]) > 0
    np.testing.assert_array_equal(same["label"][~same["wandering"]], 0.0)
    np.testing.assert_allclose(same["correction"], 0.0, atol=1e-6)
    # The frozen student commands what its base does: driving with it changes nothing.
    driven = collect_fit(path, "scripted:formation", [100], drive="student")
    for key in same:
        np.testing.assert_array_equal(driven[key], same[key])
    with pytest.raises(ValueError, match="drive"):
        collect_fit(path, "scripted:formation", [100], drive="teacher")
    (row,) = phase_table(same, phases=(0,))
    assert row["slope_teacher_v"] == pytest.approx(1.0)
    assert row["slope_student_v"] == pytest.approx(1.0, abs=1e-4)
    truth = collect_fit(path, "privileged:formation@truth", [100])
    taught = np.abs(truth["label"][~truth["wandering"]])
    assert (taught < 0.02).all(axis=1).any() and (taught > 0.05).any()
    (row,) = phase_table(truth, phases=(0,))
    assert row["r2_v"] == pytest.approx(0.0, abs=1e-3)
    out = tmp_path / "fit.json"
    assert main([str(path), "--teacher", "privileged:formation@truth", "--seeds", "100",
                 "--phases", "0,10", "--out", str(out)]) == 0  # fmt: skip
    rows = json.loads(out.read_text())["models"][str(path)]
    assert [r["from_step"] for r in rows] == [0, 10]
    assert rows[0]["mse_zero_v"] > 0.0
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nope.zip"), "--teacher", "scripted:formation"])


def test_a_gain_residual_is_refused(tmp_path):
    """A gain residual's correction is an exponent: comparing it with additive labels would
    be meaningless, so the tool names the mode and stops."""
    path = train_frozen_residual(tmp_path / "run", residual_mode="gain")
    with pytest.raises(ValueError, match="residual_mode 'gain'"):
        collect_fit(path, "scripted:formation", [100])
