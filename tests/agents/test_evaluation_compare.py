"""``swarm-phd evaluate`` with task policies: env resolution and ``--compare`` (side by side,
and paired by seed with ``--policy``)."""

from __future__ import annotations

import json
import math
import statistics

import pytest

from agents.policies import policy_env
from agents.sb3.policy import write_metadata
from swarm_phd.evaluate import paired_by_seed, shared_env_kwargs


@pytest.fixture
def fake_model(tmp_path):
    """A zip carrying only swarm-phd metadata (enough for env resolution, not for acting)."""
    import zipfile

    path = tmp_path / "model.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", "{}")
    write_metadata(
        path,
        {
            "env_kwargs": {
                "preset": "seed-lab",
                "task": "formation",
                "task_params": {"radius_m": 0.7},
                "observation": "truth",
                "localize": False,
                "max_steps": 300,
            },
            "obs_norm": None,
        },
    )
    return str(path)


def test_model_env_defaults_to_the_models_settings(fake_model):
    env = policy_env(None, None, fake_model)
    assert env.config.n_robots == 4 and env.config.observation == "truth"
    assert env.task.name == "formation" and env.task.radius_m == 0.7


def test_task_params_given_are_merged_over_the_models_own(fake_model):
    """A reward weight given on the command line keeps the formation the model learnt; on
    another task the model's parameters are dropped (they belong to its task)."""
    from agents.policies import trained_policy_env

    given = {"task_params": {"progress_weight": 10}}
    merged = {"radius_m": 0.7, "progress_weight": 10}
    assert trained_policy_env(fake_model, **given)["task_params"] == merged
    assert shared_env_kwargs(fake_model, None, None, **given)["task_params"] == merged
    env = policy_env(None, None, fake_model, **given)
    assert env.task.radius_m == 0.7 and env.task.progress_weight == 10
    assert trained_policy_env(fake_model, task="wander", **given)["task_params"] == {
        "progress_weight": 10
    }
    assert shared_env_kwargs(fake_model, None, "wander", **given)["task_params"] == {
        "progress_weight": 10
    }
    assert given == {"task_params": {"progress_weight": 10}}  # the caller's dict untouched
    # None given is nothing given; a policy by name has only what is given.
    assert trained_policy_env(fake_model, task_params=None)["task_params"] == {"radius_m": 0.7}
    assert shared_env_kwargs("scripted:formation", None, "formation", **given)["task_params"] == {
        "progress_weight": 10
    }


def test_a_model_without_a_task_was_trained_on_wander():
    """Both resolvers of a policy's env agree: one rule (agents.policies.model_on_task)."""
    from agents.policies import model_on_task

    model = {"task_params": {"a": 1}, "observation": "phd"}
    assert model_on_task(model, None, {})["task"] == "wander"
    assert model_on_task(model, "wander", {})["task_params"] == {"a": 1}
    assert model_on_task(model, "formation", {"task_params": {"b": 2}})["task_params"] == {"b": 2}
    assert model_on_task({}, None, {"max_steps": 5}) == {
        "task": None,
        "task_params": {},
        "max_steps": 5,
    }


def test_scripted_phd_controller_gets_a_phd_env():
    env = policy_env("seed-lab", "formation", "scripted:formation")
    assert env.config.observation == "phd" and env.config.localize
    env = policy_env("seed-lab", None, "scripted:wander")
    assert env.config.observation == "measurements" and not env.config.localize


def test_compare_shares_everything_but_the_observation(fake_model):
    shared = shared_env_kwargs(fake_model, None, None)
    assert shared == {
        "preset": "seed-lab",
        "task": "formation",
        "task_params": {"radius_m": 0.7},
        "max_steps": 300,
    }
    other = shared_env_kwargs(
        "scripted:formation", "seed-lab", "formation", task_params={"radius_m": 0.5}
    )
    assert other["task_params"] == {"radius_m": 0.5} and "observation" not in other


def test_evaluate_compare_end_to_end(tmp_path):
    from swarm_phd.cli import main

    out = tmp_path / "eval"
    code = main(
        [
            "evaluate",
            "--preset",
            "seed-lab",
            "--task",
            "formation",
            "--policy",
            "scripted:formation",
            "--compare",
            "random,scripted:wander",
            "--duration",
            "3",
            "--localizer",
            "phd-lc",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    rows = json.loads((out / "comparison.json").read_text())["side_by_side"]
    # Several --compare policies, one row each, in the order given.
    assert [r["policy"] for r in rows] == ["scripted:formation", "random", "scripted:wander"]
    assert (out / "compare" / "metrics.json").is_file()
    assert (out / "compare2" / "metrics.json").is_file()
    assert all("formation_error_m" in r and "phd-lc GOSPA" in r for r in rows)
    assert all("phd-lc ugv_0 teammates > 25 %" in r for r in rows)
    # Perera 2021's scoring, per tracked teammate of ugv_0 and over all observers, and the
    # pooled per-observer figure, under their own names.
    metrics = json.loads((out / "metrics.json").read_text())
    lc = metrics["localizers"]["phd-lc"]
    n = metrics["config"]["n_robots"]
    one = lc["seed_fig7"]["observer_ugv_0"]
    assert len(one["per_teammate"]) == n and one["in_range_steps"][0] == 0
    tracked = sum(s > 0 for s in one["in_range_steps"])
    assert one["tracked_teammates"] == tracked
    assert lc["seed_fig7"]["all_observers"]["tracked_pairs"] >= tracked
    assert len(lc["pooled_per_observer"]["per_robot"]) == n
    assert lc["definition"]["in_range_m"] == metrics["config"]["localization_range_m"]
    assert lc["at_camera_range"]["definition"]["in_range_m"] == 3.0
    assert (lc["gospa"]["c_m"], lc["gospa"]["p"], lc["gospa"]["alpha"]) == (1.0, 2.0, 2.0)
    assert {"in_range_mae", "total_mae"} <= set(lc["cardinality"])
    assert {"pct_time_position_err_lt_10cm", "pct_time_bearing_err_lt_7deg"} <= set(lc["seed001"])
    for name in ("fig7_error_time.png", "fig8_weight_sum.png", "fig9_paths.png", "gospa.png"):
        assert (out / name).stat().st_size > 10_000


def _compare(tmp_path, seeds: str, capsys) -> tuple:
    """A tiny ``--compare`` run (lab arena, formation task, 2 s per seed): its
    comparison.json, both policies' metrics.json and what it printed."""
    from swarm_phd.cli import main

    out = tmp_path / "eval"
    args = ["evaluate", "--preset", "seed-lab", "--task", "formation", "--localizer", "phd-lc"]
    args += ["--policy", "scripted:formation", "--compare", "scripted:wander"]
    code = main([*args, "--duration", "2", "--seeds", seeds, "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    files = ("comparison.json", "metrics.json", "compare/metrics.json")
    return (*(json.loads((out / name).read_text()) for name in files), printed)


def test_compare_pairs_by_seed_as_by_hand(tmp_path, capsys):
    """Each paired row (comparison.json and the printed table) against the hand computation
    from the two policies' own per-seed results: scripted:wander − scripted:formation on
    seeds 3, 4, 5, mean of the differences, sample SE, seeds where wander is lower."""
    comparison, reference, other, printed = _compare(tmp_path, "3-5", capsys)
    paired = {(r["localizer"], r["metric"]): r for r in comparison["paired_by_seed"]}
    loc = "phd-lc"
    tables = {
        None: (other["task_per_seed"], reference["task_per_seed"]),
        loc: (other["localizers"][loc]["per_seed"], reference["localizers"][loc]["per_seed"]),
    }
    expected = [(None, k) for k in ("formation_error_m", "spacing_error_m")]
    expected += [(loc, k) for k in ("gospa_mean_m", "pooled_per_observer_median_pct")]
    expected += [(loc, "pct_pair_steps_err_gt_30cm")]
    assert set(expected) <= set(paired)
    for localizer, metric in expected:
        mine, theirs = tables[localizer]
        assert [d["seed"] for d in mine] == [d["seed"] for d in theirs] == [3, 4, 5]
        diffs = [a[metric] - b[metric] for a, b in zip(mine, theirs, strict=True)]
        assert all(math.isfinite(d) for d in diffs)  # in range on every seed of this run
        mean = statistics.mean(diffs)
        se = statistics.stdev(diffs) / math.sqrt(3)
        verdict = (
            "better by > 2 SE"
            if mean < -2 * se
            else "worse by > 2 SE"
            if mean > 2 * se
            else "within 2 SE"
        )
        row = paired[(localizer, metric)]
        assert (row["policy"], row["reference"]) == ("scripted:wander", "scripted:formation")
        assert row["seeds"] == [3, 4, 5] and row["n_seeds"] == 3
        assert row["differences"] == pytest.approx(diffs)
        assert row["mean_difference"] == pytest.approx(mean)
        assert row["standard_error"] == pytest.approx(se)
        assert row["seeds_better"] == sum(d < 0 for d in diffs)
        assert row["verdict"] == verdict
    # The printed table shows the same numbers, under the side-by-side one.
    lines = printed.splitlines()
    side = next(
        k for k, ln in enumerate(lines) if ln.startswith("  | metric | scripted:formation")
    )
    r = paired[(loc, "gospa_mean_m")]
    gospa = (
        f"  | phd-lc GOSPA | scripted:wander − scripted:formation | {r['mean_difference']:+.3f} | "
        f"{r['standard_error']:.3f} | {r['seeds_better']} of 3 | {r['verdict']} |"
    )
    assert gospa in lines and lines.index(gospa) > side
    assert "nan" not in printed.split("paired by seed", 1)[1].lower()


def test_compare_with_one_seed_gives_the_difference_without_an_se(tmp_path, capsys):
    comparison, reference, other, printed = _compare(tmp_path, "4", capsys)
    rows = comparison["paired_by_seed"]
    assert rows and all(r["n_seeds"] == 1 and r["standard_error"] is None for r in rows)
    assert all(r["verdict"] == "SE needs at least 2 seeds" for r in rows)
    gospa = next(r for r in rows if r["metric"] == "gospa_mean_m")
    own = other["localizers"]["phd-lc"]["per_seed"][0]["gospa_mean_m"]
    ref = reference["localizers"]["phd-lc"]["per_seed"][0]["gospa_mean_m"]
    assert gospa["mean_difference"] == pytest.approx(own - ref)
    table = printed.split("paired by seed", 1)[1]
    assert f"| {own - ref:+.3f} | - | " in table and "SE needs at least 2 seeds" in table
    assert "nan" not in table.lower()


def _crafted(
    policy: str,
    seeds: list[int],
    localizer_seeds: list[int] | None = None,
    requested: list[int] | None = None,
) -> dict:
    """A result of evaluate_localization with only what paired_by_seed reads (``requested``:
    an interrupted run's seeds asked for, ``seeds`` those it finished)."""
    per_seed = localizer_seeds if localizer_seeds is not None else seeds
    config = {"policy": policy, "seeds": seeds}
    if requested is not None:
        config.update(interrupted=True, seeds_requested=requested)
    return {
        "config": config,
        "task_per_seed": [{"seed": s, "formation_error_m": 0.1 * s} for s in seeds],
        "localizers": {
            "phd-lc": {"per_seed": [{"seed": s, "gospa_mean_m": 0.2 + s} for s in per_seed]}
        },
    }


def test_an_interrupt_ends_the_whole_comparison(tmp_path, capsys, monkeypatch):
    """The policy in which a Ctrl-C lands is scored on its finished seeds (evaluate catches
    it there); the policies after it are not started, and what ran is still paired."""
    from swarm_phd import evaluate
    from swarm_phd.cli import main

    started = []

    def fake(preset, duration, localizers, seeds, policy, **kwargs):
        started.append(policy)
        if policy == "random":  # interrupted after its first two seeds
            return _crafted(policy, seeds[:2], requested=seeds)
        return _crafted(policy, seeds)

    monkeypatch.setattr(evaluate, "evaluate_localization", fake)
    for name in ("print_table", "print_comparison"):  # they read what _crafted leaves out
        monkeypatch.setattr(evaluate, name, lambda results: None)
    monkeypatch.setattr(evaluate, "comparison_rows", lambda results: [])
    args = ["evaluate", "--preset", "seed-lab", "--task", "formation", "--localizer", "phd-lc"]
    args += ["--policy", "scripted:formation", "--compare", "random,scripted:wander,wander"]
    out = tmp_path / "eval"
    assert main([*args, "--duration", "2", "--seeds", "0-2", "--out", str(out)]) == 0
    assert started == ["scripted:formation", "random"]
    assert "interrupted; not run: scripted:wander, wander" in capsys.readouterr().err
    rows = json.loads((out / "comparison.json").read_text())["paired_by_seed"]
    assert rows and all(r["policy"] == "random" and r["seeds"] == [0, 1] for r in rows)


def test_paired_by_seed_refuses_seeds_that_do_not_line_up():
    ref = _crafted("scripted:formation", [0, 1, 2])
    rows = paired_by_seed([ref, _crafted("scripted:wander", [0, 1, 2])])
    assert [(r["localizer"], r["metric"], r["mean_difference"]) for r in rows] == [
        (None, "formation_error_m", 0.0),
        ("phd-lc", "gospa_mean_m", 0.0),
    ]
    for bad in (
        _crafted("runs/x/model.zip", [0, 2, 1]),  # same seeds, another order
        _crafted("runs/x/model.zip", [0, 1]),  # asked for other seeds
        _crafted("runs/x/model.zip", [0, 1, 2], localizer_seeds=[0, 2, 1]),
    ):
        with pytest.raises(ValueError, match="runs/x/model.zip.*same seeds in the same order"):
            paired_by_seed([ref, _crafted("random", [0, 1, 2]), bad])
    # Interrupted after two seeds (the reference, or the compared policy): paired on those.
    cut = _crafted("runs/x/model.zip", [0, 1], requested=[0, 1, 2])
    for results in ([ref, cut], [cut, ref]):
        rows = paired_by_seed(results)
        assert rows and all(r["seeds"] == [0, 1] and r["n_seeds"] == 2 for r in rows)
    from agents.evaluation import paired_difference

    with pytest.raises(ValueError, match="same seeds"):
        paired_difference([0.1, 0.2], [0.1], "gospa_mean_m")  # no silent broadcasting
    # A seed with no value on one side (NaN: nothing in range) is left out, for every caller.
    stat = paired_difference([0.1, float("nan"), 0.3], [0.0, 0.1, 0.1], "gospa_mean_m")
    assert stat["n_seeds"] == 2 and stat["mean_difference"] == pytest.approx(0.15)
    assert stat["standard_error"] == pytest.approx(0.05) and stat["seeds_better"] == 0
    empty = paired_difference([float("nan")], [0.1], "gospa_mean_m")
    assert empty["n_seeds"] == 0 and empty["verdict"] == "no seed scored by both"
