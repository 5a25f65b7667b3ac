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
            "random",
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
    assert [r["policy"] for r in rows] == ["scripted:formation", "random"]
    assert all("formation_error_m" in r and "phd-lc GOSPA" in r for r in rows)
