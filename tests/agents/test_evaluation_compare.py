"""``swarm-phd evaluate`` with task policies: env resolution and ``--compare``."""

from __future__ import annotations

import json

import pytest

from agents.sb3.policy import write_metadata
from swarm_phd.evaluate import _make_env, shared_env_kwargs


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
    env = _make_env(None, None, fake_model)
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
    env = _make_env(None, None, fake_model, **given)
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
    env = _make_env("seed-lab", "formation", "scripted:formation")
    assert env.config.observation == "phd" and env.config.localize
    env = _make_env("seed-lab", None, "scripted:wander")
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
    rows = json.loads((out / "comparison.json").read_text())
    # Several --compare policies, one row each, in the order given.
    assert [r["policy"] for r in rows] == ["scripted:formation", "random", "scripted:wander"]
    assert (out / "compare" / "metrics.json").is_file()
    assert (out / "compare2" / "metrics.json").is_file()
    assert all("formation_error_m" in r and "phd-lc GOSPA" in r for r in rows)
    assert all("phd-lc ugv_0 teammates > 25 %" in r for r in rows)
    # The seed's scoring, per tracked teammate of ugv_0 and over all observers, and the
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
