"""``swarm-phd train --recipe NAME`` and the shipped ``pretrained:NAME`` policies: the recipes
run end to end (at a tiny budget) and write a policy the commands accept; a shipped policy
loads weights only wherever a policy is accepted and reproduces its card's held-out score."""

from __future__ import annotations

import json

import pytest

from agents import pretrained
from agents.evaluation import higher_is_better
from agents.recipes import RECIPES, check_recipe, run_recipe
from swarm_phd.cli import main

pytest.importorskip("stable_baselines3")

SHIPPED = ("formation", "exploration", "encirclement")


def test_an_unknown_recipe_or_pretrained_name_lists_the_known(tmp_path, capsys):
    with pytest.raises(ValueError, match="--recipe: unknown recipe 'fly'; known: formation, "):
        check_recipe("fly")
    assert main(["train", "--recipe", "fly", "--out", str(tmp_path / "r")]) == 2
    assert "known: formation, exploration, encirclement" in capsys.readouterr().err
    message = "--policy: unknown pretrained policy 'pretrained:fly'; known: pretrained:"
    with pytest.raises(ValueError, match=message):
        pretrained.resolve("pretrained:fly")
    assert main(["evaluate", "--policy", "pretrained:fly", "--out", str(tmp_path / "e")]) == 2
    assert "pretrained:formation" in capsys.readouterr().err
    assert not (tmp_path / "r").exists() and not (tmp_path / "e").exists()


def test_a_recipe_refuses_the_flags_it_sets_itself(tmp_path, capsys):
    out = tmp_path / "r"
    argv = ["train", "--recipe", "exploration", "--timesteps", "5000", "--out", str(out)]
    assert main(argv) == 2
    assert "--timesteps cannot be combined with it" in capsys.readouterr().err
    assert main(["train", "--recipe-scale", "0.5", "--out", str(out)]) == 2
    assert "--recipe-scale 0.5 needs --recipe" in capsys.readouterr().err
    assert main(["train", "--recipe", "exploration", "--recipe-scale", "2", "--out", str(out)])
    assert "--recipe-scale" in capsys.readouterr().err
    assert not out.exists()


def test_the_residual_recipe_runs_end_to_end_and_its_policy_is_a_policy(tmp_path, capsys):
    out = tmp_path / "expl"
    argv = ["train", "--recipe", "exploration", "--recipe-scale", "0.005", "--eval-seeds", "1"]
    assert main([*argv, "--no-progress-bar", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    summary = json.loads((out / "recipe.json").read_text())
    assert summary["recipe"] == "exploration" and summary["policy"] == "ppo/model.zip"
    assert summary["stages"][0]["residual"] == "scripted:exploration"
    assert summary["held_out_seeds"] == "100000"
    assert set(summary["held_out"]) == {
        str(out / "ppo/model.zip"),
        *RECIPES["exploration"].baselines,
    }
    assert "| coverage (higher is better) |" in text
    assert (out / "learning_curve.png").stat().st_size > 10_000
    # A second run into the same directory needs --overwrite.
    assert main([*argv, "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    ev = tmp_path / "ev"
    assert (
        main(
            ["evaluate", "--policy", str(out / "ppo/model.zip"), "--seeds", "1"]
            + ["--out", str(ev)]
        )
        == 0
    )


@pytest.mark.slow
def test_the_formation_recipe_distils_then_fine_tunes(tmp_path):
    out = tmp_path / "form"
    assert run_recipe("formation", out, scale=0.01, eval_seeds=1, progress_bar=False) == 0
    summary = json.loads((out / "recipe.json").read_text())
    assert [s["dir"] for s in summary["stages"]] == ["dagger", "ppo"]
    assert summary["policy"] == "ppo/student.pt"
    assert (out / "dagger" / "student_best.pt").is_file()
    ppo = json.loads((out / "ppo" / "train_log.json").read_text())
    assert ppo["config"]["student"] == str(out / "dagger" / "student_best.pt")
    assert "scripted:formation-known-n-fast" in summary["held_out"]


def test_every_task_ships_a_policy_with_its_card():
    assert pretrained.names() == sorted(SHIPPED)
    for name in SHIPPED:
        card = pretrained.card(name)
        assert card["task"] == name and card["recipe"] in RECIPES
        assert pretrained.policy_file(name).is_file()
        goal = card["goal"]
        assert goal["baseline"] == RECIPES[card["recipe"]].baselines[0]
        assert goal["status"] in ("met", "tie", "missed") and goal["met"] == (
            goal["status"] == "met"
        )
        sign = 1 if higher_is_better(goal["metric"]) else -1
        better = sign * goal["mean_difference"] >= 0
        assert goal["met"] == (better and not goal["verdict"].startswith("worse"))
        assert goal["n_seeds"] >= 20 and card["commit"]
        assert card["held_out_seeds"].startswith("100000")
        if not goal["met"]:
            assert card["note"], f"pretrained:{name} misses its goal without saying why"


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_policy_reproduces_its_card_on_a_held_out_seed(name):
    """The policy loads weights only (no trust needed) in its own env and scores, on the first
    held-out seed, what its card recorded: the card is true of the code that ships it."""
    from agents.evaluation import score
    from agents.policies import model_env_kwargs

    card = pretrained.card(name)
    spec = f"pretrained:{name}"
    env_kwargs = model_env_kwargs(spec)
    assert env_kwargs["task"] == name and env_kwargs["observation"] == "phd"
    got = score(spec, card["env_kwargs"], [100_000])["per_seed"][0]
    want = card["held_out_per_seed"][0]
    assert got[card["goal"]["metric"]] == pytest.approx(want[card["goal"]["metric"]], abs=1e-9)


def test_a_shipped_policy_is_recorded_in_its_own_env(tmp_path, capsys):
    pytest.importorskip("imageio_ffmpeg")
    out = tmp_path / "exploration.gif"
    argv = ["record", "--policy", "pretrained:exploration", "--duration", "1", "--fps", "5"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    assert "task exploration, 4 UGVs" in capsys.readouterr().out
    assert out.stat().st_size > 1000
