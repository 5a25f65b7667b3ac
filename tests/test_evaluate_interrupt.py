"""Ctrl-C during `swarm-phd evaluate` keeps (and writes) the finished seeds' scores."""

from __future__ import annotations

import json

import pytest

from swarm_phd import evaluate as evaluation


def test_interrupt_scores_the_finished_seeds(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = evaluation.SwarmFeed.from_world_step

    def interrupting(step, robot_ids, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 15:  # 10 steps per seed: inside the second seed
            raise KeyboardInterrupt
        return real(step, robot_ids, *args, **kwargs)

    monkeypatch.setattr(evaluation.SwarmFeed, "from_world_step", staticmethod(interrupting))
    results = evaluation.evaluate_localization(
        "lab-3m-4", 1.0, ["phd-lc"], [0, 1, 2], out_dir=tmp_path
    )
    assert results["config"]["seeds"] == [0]
    assert [d["seed"] for d in results["localizers"]["phd-lc"]["per_seed"]] == [0]
    assert results["config"]["interrupted"] is True
    assert results["config"]["seeds_requested"] == [0, 1, 2]
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["config"]["seeds"] == [0]
    uninterrupted = evaluation.evaluate_localization("lab-3m-4", 1.0, ["phd-lc"], [0])
    assert on_disk["localizers"]["phd-lc"]["headline"] == pytest.approx(
        uninterrupted["localizers"]["phd-lc"]["headline"], nan_ok=True
    )


def test_interrupt_before_any_seed_finishes_propagates(monkeypatch):
    def interrupting(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluation.SwarmFeed, "from_world_step", staticmethod(interrupting))
    with pytest.raises(KeyboardInterrupt):
        evaluation.evaluate_localization("lab-3m-4", 1.0, ["phd-lc"], [0, 1])


def test_interrupt_between_two_localizers_per_seed_figures_keeps_them_aligned(monkeypatch):
    """Ctrl-C after the first localizer's figures of seed 1 are in, before the second's: both
    keep seed 0 only, as the restored scores do."""
    calls = {"n": 0}
    real = evaluation.seed_figures

    def interrupting(before, after):
        calls["n"] += 1
        if calls["n"] == 4:  # two localizers per seed: the second one's, on seed 1
            raise KeyboardInterrupt
        return real(before, after)

    monkeypatch.setattr(evaluation, "seed_figures", interrupting)
    names = ["phd-lc", "phd-lo"]
    results = evaluation.evaluate_localization("lab-3m-4", 1.0, names, [0, 1, 2], phases=[0, 5])
    assert results["config"]["seeds"] == [0]
    for name in names:
        assert [d["seed"] for d in results["localizers"][name]["per_seed"]] == [0]
    # The phases' counts are cut back with them: seed 0's alone.
    monkeypatch.setattr(evaluation, "seed_figures", real)
    alone = evaluation.evaluate_localization("lab-3m-4", 1.0, names, [0], phases=[0, 5])
    for name in names:
        by_phase = results["localizers"][name]["by_phase"]
        assert by_phase == pytest.approx(alone["localizers"][name]["by_phase"], nan_ok=True)
