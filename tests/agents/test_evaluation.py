"""The statistics of :mod:`agents.evaluation`: scoring policies, pooling runs over training
seeds, and pairing policies with the baselines by seed."""

from __future__ import annotations

import numpy as np
import pytest

from agents.evaluation import (
    markdown_table,
    paired_differences,
    paired_table,
    pooled,
)

ESTIMATE_TERM = {"localization_weight": 1.0, "localization_term": "estimate"}


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


def test_paired_differences_by_hand():
    """Two runs of a group (per-seed mean [0.15, 0.35, 0.25, 0.25]) against baseline b
    [0.2, 0.4, 0.3, 0.2]: differences [-0.05, -0.05, -0.05, +0.05], mean -0.025, sample std
    0.05, SE 0.025, better on 3 of 4 seeds, within 2 SE. Baseline c = b - 0.1 on every seed
    is better than b beyond any SE (SE 0); a higher-is-better metric flips the counts."""
    policies = {
        "a0.zip": _result([0.1, 0.3, 0.2, 0.2]),
        "a1.zip": _result([0.2, 0.4, 0.3, 0.3]),
        "b": _result([0.2, 0.4, 0.3, 0.2]),
        "c": _result([0.1, 0.3, 0.2, 0.1]),
    }
    rows = paired_differences(
        policies, {"g": ["a0.zip", "a1.zip"]}, ["b", "c"], "formation_error_m"
    )
    by_pair = {(r["policy"], r["baseline"]): r for r in rows}
    assert set(by_pair) == {("g", "b"), ("g", "c"), ("c", "b")}  # b - c is not repeated
    gb = by_pair[("g", "b")]
    assert gb["mean_difference"] == pytest.approx(-0.025)
    assert gb["standard_error"] == pytest.approx(0.025)
    assert (gb["seeds_better"], gb["n_seeds"], gb["verdict"]) == (3, 4, "within 2 SE")
    cb = by_pair[("c", "b")]
    assert cb["mean_difference"] == pytest.approx(-0.1)
    assert cb["standard_error"] == pytest.approx(0.0, abs=1e-12)
    assert cb["seeds_better"] == 4 and cb["verdict"] == "better"
    # episode_return = -10 x error: higher is better, so the same pairs count the other way
    rows = paired_differences(policies, {"g": ["a0.zip", "a1.zip"]}, ["b"], "episode_return")
    assert rows[0]["mean_difference"] == pytest.approx(0.25)
    assert rows[0]["seeds_better"] == 3 and rows[0]["verdict"] == "within 2 SE"
    far = {"a": _result([0.1, 0.1, 0.1, 0.12]), "b": _result([0.3, 0.31, 0.3, 0.3])}
    assert paired_differences(far, {"g": ["a"]}, ["b"], "formation_error_m")[0]["verdict"] == (
        "better"
    )
    assert paired_differences(far, {"g": ["b"]}, ["a"], "formation_error_m")[0]["verdict"] == (
        "worse"
    )
    table = paired_table(by_pair.values(), "formation_error_m").strip().splitlines()
    assert len(table) == 2 + 3 and "| g − b | -0.0250 | 0.0250 | 3 of 4 | within 2 SE |" in table


def test_paired_differences_pair_a_group_with_earlier_groups():
    """A fine-tuned group against the group it started from, by hand: tuned per-seed mean
    [0.15, 0.25, 0.20], start [0.20, 0.30, 0.22]: differences [-0.05, -0.05, -0.02], mean
    -0.04, sample std sqrt(0.0003), SE 0.01, better on 3 of 3 and by 4 SE.
    The earlier group is not paired with the later one, and a lone group with none."""
    policies = {
        "t0.pt": _result([0.1, 0.2, 0.2]),
        "t1.pt": _result([0.2, 0.3, 0.2]),
        "s0.pt": _result([0.2, 0.3, 0.1]),
        "s1.pt": _result([0.2, 0.3, 0.34]),
        "b": _result([0.3, 0.3, 0.3]),
    }
    groups = {"start": ["s0.pt", "s1.pt"], "tuned": ["t0.pt", "t1.pt"]}
    rows = paired_differences(policies, groups, ["b"], "formation_error_m")
    by_pair = {(r["policy"], r["baseline"]): r for r in rows}
    assert set(by_pair) == {("start", "b"), ("tuned", "b"), ("tuned", "start")}
    ts = by_pair[("tuned", "start")]
    assert ts["mean_difference"] == pytest.approx(-0.04)
    assert ts["standard_error"] == pytest.approx(0.01)
    assert (ts["seeds_better"], ts["verdict"]) == (3, "better")
    alone = paired_differences(policies, {"tuned": groups["tuned"]}, ["b"], "formation_error_m")
    assert [(r["policy"], r["baseline"]) for r in alone] == [("tuned", "b")]


@pytest.mark.parametrize("spec", ["scripted:wander", "scripted:formation-known-n@truth"])
def test_score_keeps_the_filters_on_when_the_reward_scores_the_estimate(spec):
    # Policies that read no estimate (wander; a controller on the truth) switch the env's
    # filters off, but a localization term on the estimate needs them: scored, not refused.
    from agents.evaluation import score

    kwargs = {"preset": "lab-3m-4", "task": "formation", "task_params": ESTIMATE_TERM}
    out = score(spec, {**kwargs, "max_steps": 4}, [0])
    assert 0.0 <= out["per_seed"][0]["mislocalized_fraction"] <= 1.0


def test_evaluate_keeps_the_filters_on_when_the_reward_scores_the_estimate():
    from swarm_phd.evaluate import evaluate_localization

    out = evaluate_localization(
        "lab-3m-4",
        0.5,
        ["phd-lc"],
        [0],
        policy="scripted:wander",
        task="formation",
        task_params=ESTIMATE_TERM,
    )
    assert 0.0 <= out["task"]["mislocalized_fraction"] <= 1.0


def test_phase_metrics_average_each_series_over_each_phase():
    from agents.evaluation import phase_metrics, phase_spans

    series = {"formation_error_m": np.array([1.0, 2.0, 3.0, 4.0, 5.0])}
    out = phase_metrics(series, [0, 2])
    assert out == {"formation_error_m@0-2": 1.5, "formation_error_m@2-": 4.0}
    assert np.isnan(phase_metrics(series, [0, 9])["formation_error_m@9-"])  # never reached
    assert phase_spans([0, 150, 200]) == [(0, 150), (150, 200), (200, None)]
    for bad in ([150, 0], [], [-1, 5], [3, 3]):
        with pytest.raises(ValueError, match="phases"):
            phase_spans(bad)


def test_step_series_has_one_error_per_step_after_it():
    # Index t is the swarm's error after env step t + 1 (the reset's pose is not in it): the
    # series is as long as the steps taken and its first entry is the first step's error.
    from swarm_env import parallel_env

    env = parallel_env(preset="lab-3m-4", task="formation", observation="truth", localize=False)
    env.reset(seed=3)
    first = env.task.errors(env.last_world_step.truth.poses[:, :2])[0].mean()
    for t in range(4):
        env.step({a: np.array([0.2, 0.5]) for a in env.agents})
        series = env.task.step_series()
        assert len(series["formation_error_m"]) == t + 1
        shape, spacing = env.task.errors(env.last_world_step.truth.poses[:, :2])
        assert series["formation_error_m"][-1] == pytest.approx(float(shape.mean()), abs=0)
        assert series["spacing_error_m"][-1] == pytest.approx(float(spacing.mean()), abs=0)
    assert series["formation_error_m"][0] != pytest.approx(float(first))  # the robots moved
    env.close()


def test_score_by_phase_splits_the_episode_mean():
    # One phase from step 0 is the episode's own metric; two phases weighted by their lengths
    # give it back, so the per-step series is the one the metric averages.
    from agents.evaluation import score

    kwargs = {"preset": "lab-3m-4", "task": "formation", "max_steps": 12}
    out = score("scripted:formation-known-n", kwargs, [0, 1], phases=[0, 5])
    for d in out["per_seed"]:
        whole = d["formation_error_m"]
        assert (5 * d["formation_error_m@0-5"] + 7 * d["formation_error_m@5-"]) / 12 == (
            pytest.approx(whole, rel=1e-12)
        )
        assert d["formation_error_m@0-5"] != pytest.approx(d["formation_error_m@5-"])
        assert "spacing_error_m@5-" in d
    plain = score("scripted:formation-known-n", kwargs, [0, 1])
    assert [d["formation_error_m"] for d in plain["per_seed"]] == [
        d["formation_error_m"] for d in out["per_seed"]
    ]


def test_parse_phases_reads_text_or_a_sequence_and_names_the_flag():
    from agents.evaluation import parse_phases

    assert parse_phases("0,25,150") == [0, 25, 150]
    assert parse_phases((0, 50)) == [0, 50]
    for bad in ("5,2", "0,x", "", (-1, 3), (3, 3)):
        with pytest.raises(ValueError, match=r"--phases must be increasing integers >= 0"):
            parse_phases(bad)
    with pytest.raises(ValueError, match=r"^phases of the run must be"):
        parse_phases("2,1", "phases of the run")
