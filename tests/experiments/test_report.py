"""``experiments/report.py``: choosing a run's model on validation seeds, the policy kinds of
its tables, and its per-phase paired tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from experiments.report import policy_kind


def _fake_run(tmp_path, scores: dict[str, float], final_steps: int):
    """A run directory whose models' scores are given by file name (``score`` is patched)."""
    import json

    run = tmp_path / "run_s0"
    (run / "checkpoints").mkdir(parents=True)
    for name in scores:
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_bytes(b"")
    (run / "train_summary.json").write_text(json.dumps({"timesteps": final_steps}))
    return run


def test_select_model_picks_the_best_on_validation_seeds_in_either_direction(
    tmp_path, monkeypatch
):
    import agents.sb3.policy as policy_module
    import experiments.report as report

    scores = {
        "checkpoints/model_100_steps.zip": 0.30,
        "checkpoints/model_200_steps.zip": 0.10,
        "checkpoints/model_300_steps.zip": 0.10,  # a tie: the earlier model wins
        "model.zip": 0.20,
        "warm_start.zip": 0.25,
    }
    run = _fake_run(tmp_path, scores, final_steps=350)
    seen_seeds = []

    def fake_score(spec, env_kwargs, seeds):
        seen_seeds.append(list(seeds))
        value = scores[str(Path(spec).relative_to(run))]
        return {"mean": {"formation_error_m": value, "coverage": value}}

    monkeypatch.setattr(report, "score", fake_score)
    monkeypatch.setattr(policy_module, "read_metadata", lambda path: {"env_kwargs": {}})
    assert [s for s, _ in report.run_models(run)] == [0, 100, 200, 300, 350]
    chosen, candidates = report.select_model(run, [200, 201], "formation_error_m")
    assert chosen == run / "checkpoints" / "model_200_steps.zip"
    assert [c["mean"] for c in candidates] == [0.25, 0.30, 0.10, 0.10, 0.20]
    assert all(s == [200, 201] for s in seen_seeds)
    chosen, _ = report.select_model(run, [200], "coverage")  # more coverage is better
    assert chosen == run / "checkpoints" / "model_100_steps.zip"
    scores["warm_start.zip"] = 0.05  # the warm start itself can be the best
    assert report.select_model(run, [200], "formation_error_m")[0] == run / "warm_start.zip"
    with pytest.raises(ValueError, match="radius_error_m"):  # not this task's metric
        report.select_model(run, [200], "radius_error_m")


def test_select_on_must_not_share_the_scoring_seeds(tmp_path):
    from experiments.report import main

    with pytest.raises(ValueError, match="select-on"):
        main(["--runs", str(tmp_path), "--seeds", "100-109", "--select-on", "105-115"])


def test_policy_kind_names_how_the_residual_acts():
    assert policy_kind({}) == "PPO"
    add = {"residual": "scripted:formation"}
    assert policy_kind(add) == "residual PPO (scripted:formation + learned correction)"
    gain = {**add, "residual_mode": "gain"}
    assert policy_kind(gain) == "residual PPO (scripted:formation x learned gain)"


def test_report_phases_writes_a_paired_table_per_phase(tmp_path, monkeypatch):
    # main() on a stub run: the scores come from a fake score(); the phase keys flow into the
    # JSON and the markdown, paired per phase; bad phases and a metric without a per-step
    # series are refused.
    import json

    import experiments.report as report

    run = tmp_path / "x_s0"
    run.mkdir()
    (run / "model.zip").write_bytes(b"")
    (run / "monitor.csv").write_text("#\nr,l,t\n-1,300,1\n")
    values = {
        "scripted:a": [0.3, 0.2],
        "scripted:b": [0.1, 0.1],
        str(run / "model.zip"): [0.2, 0.1],
    }

    def fake_score(spec, env_kwargs, seeds, n_steps=None, phases=None):
        late, early = values[spec], [v + 1.0 for v in values[spec]]
        per_seed = [
            {
                "formation_error_m": (e + v) / 2,
                "formation_error_m@0-5": e,
                "formation_error_m@5-": v,
                "episode_return": -v,
            }
            for e, v in zip(early, late, strict=True)
        ]
        keys = per_seed[0]
        return {
            "seeds": seeds,
            "per_seed": per_seed,
            "mean": {k: float(np.mean([d[k] for d in per_seed])) for k in keys},
            "std": {k: float(np.std([d[k] for d in per_seed])) for k in keys},
        }

    monkeypatch.setattr(report, "score", fake_score)
    monkeypatch.setattr(report, "read_metadata", lambda p: {"env_kwargs": {}}, raising=False)
    import agents.sb3.policy as policy

    monkeypatch.setattr(policy, "read_metadata", lambda p: {"env_kwargs": {}})
    argv = ["--runs", str(run), "--baselines", "scripted:a", "scripted:b", "--seeds", "1-2"]
    argv += ["--out", str(tmp_path), "--name", "ph", "--phases", "0,5"]
    assert report.main(argv) == 0
    saved = json.loads((tmp_path / "results_ph.json").read_text())
    late = {
        (r["policy"], r["baseline"]): r for r in saved["paired_by_phase"]["formation_error_m@5-"]
    }
    assert late[("scripted:b", "scripted:a")]["mean_difference"] == pytest.approx(-0.15)
    md = (tmp_path / "results_ph.md").read_text()
    assert "formation_error_m@0-5" in md and "formation_error_m@5-" in md
    with pytest.raises(SystemExit):
        report.main([*argv[:-1], "5,0"])
    with pytest.raises(ValueError, match="step_series"):
        report.main([*argv, "--metric", "episode_return"])  # no per-step series
