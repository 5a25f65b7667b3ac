"""What ``swarm-phd train`` says and writes about learning (both engines): the budget's rounding,
one learning line per rollout, ``learning_curve.png`` with the baselines, the verdict table on
held-out seeds; the defaults run; an RLlib run is a policy for ``evaluate``, ``record`` and the
bridge."""

from __future__ import annotations

import csv
import json
import math

import pytest

from agents.train_report import (
    HELD_OUT_SEED,
    LearningLog,
    eval_seeds,
    rollout_plan,
    write_learning_curve,
)
from swarm_phd.cli import main

pytest.importorskip("stable_baselines3")

TINY = ["--preset", "lab-3m-4", "--task", "formation", "--max-steps", "20"]


def test_the_budget_is_whole_rollouts_and_a_rounding_is_said():
    assert rollout_plan(4096, 2048, "x") == (4096, None)
    total, line = rollout_plan(3000, 2048, "--n-steps 128 x 4 copies x 4 agents")
    assert total == 4096
    assert line == (
        "--timesteps 3000 rounds up to 4096 = 2 rollouts of 2048 agent steps "
        "(--n-steps 128 x 4 copies x 4 agents)"
    )
    assert rollout_plan(10, 64, "x")[0] == 64 and "1 rollout of 64" in rollout_plan(10, 64, "x")[1]


def test_eval_seeds_are_held_out_and_checked():
    assert eval_seeds(0) == []
    assert eval_seeds(3) == [HELD_OUT_SEED, HELD_OUT_SEED + 1, HELD_OUT_SEED + 2]
    with pytest.raises(ValueError, match="--eval-seeds"):
        eval_seeds(-1)


def test_learning_lines_say_when_no_episode_has_finished(capsys):
    log = LearningLog(total=400, engine="sb3")
    for k in range(1, 5):
        log.add(100 * k, math.nan if k == 1 else -10.0 + k, 4 * (k - 1))
    out = capsys.readouterr().out.splitlines()
    assert out[0] == (
        "train: 100/400 agent steps (25 %): no episode finished yet (an episode is "
        "--max-steps env steps)"
    )
    assert out[-1] == (
        "train: 400/400 agent steps (100 %): mean episode return per agent -6.00 "
        "(last 12 episodes)"
    )
    assert [r["agent_steps"] for r in log.rows] == [100, 200, 300, 400]


def test_sb3_defaults_train_report_and_draw_the_baselines(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", *TINY, "--timesteps", "100", "--n-steps", "16", "--n-copies", "1"]
    argv += ["--eval-seeds", "2", "--checkpoint-every", "64", "--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    # 16 env steps x 1 copy x 4 robots = 64 agent steps a rollout: 100 trains 128.
    assert (
        "--timesteps 100 rounds up to 128 = 2 rollouts of 64 agent steps "
        "(--n-steps 16 x 1 copies x 4 agents)" in text
    )
    assert "train: 64/128 agent steps (50 %)" in text
    assert "train: 128/128 agent steps (100 %): mean episode return per agent" in text
    config = json.loads((out / "train_config.json").read_text())
    assert config["ppo"]["batch_size"] == 64  # the default 512, cut to the whole rollout
    # The verdict table: the trained policy against the scripted controller and random.
    assert "held-out seeds (100000-100001), paired by seed" in text
    table = [line for line in text.splitlines() if line.startswith("| formation_error_m")]
    assert [line.split(" | ")[2] for line in table] == ["scripted:formation", "random"]
    report = json.loads((out / "final_evaluation.json").read_text())
    assert report["metric"] == "formation_error_m" and report["seeds"] == [100000, 100001]
    assert list(report["scores"]) == [str(out / "model.zip"), "scripted:formation", "random"]
    assert [c["agent_steps"] for c in report["checkpoints"]] == [64]
    rows = report["paired"]
    assert {(r["metric"], r["baseline"]) for r in rows} == {
        (m, b)
        for m in ("formation_error_m", "episode_return")
        for b in ("scripted:formation", "random")
    }
    assert all(r["n_seeds"] == 2 for r in rows)
    assert (out / "learning_curve.png").stat().st_size > 10_000
    curve = list(csv.DictReader((out / "learning_curve.csv").open()))
    assert [int(r["agent_steps"]) for r in curve] == [64, 128]
    # The figure's panels: the return and the task metric, each with both baselines drawn.
    # The batched VecEnv reported each training episode's formation error: 4 episodes of 20.
    # (none before the first episode ended, at env step 20 of the second rollout)
    assert [r["task_metric"] for r in curve] == ["", "formation_error_m"]
    assert curve[1]["task_metric_episodes"] == "1"
    assert 0 < float(curve[1]["task_metric_mean"]) < 3
    assert "; formation_error_m " in text and "(last 1 copy-episodes)" in text
    rows = [
        {
            "agent_steps": int(r["agent_steps"]),
            "episode_return_mean": float(r["episode_return_mean"]),
        }
        for r in curve
    ]
    drawn = write_learning_curve(tmp_path / "again.png", rows, report, "t")
    assert set(drawn) == {"episode_return", "formation_error_m"}
    for labels in drawn.values():
        assert "scripted:formation (held-out seeds)" in labels
        assert "random (held-out seeds)" in labels


def test_eval_seeds_zero_skips_the_evaluation(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", *TINY, "--timesteps", "64", "--n-steps", "16", "--n-copies", "1"]
    assert main([*argv, "--eval-seeds", "0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rounds up" not in text  # 64 is one whole rollout
    assert "paired by seed" not in text and not (out / "final_evaluation.json").exists()
    assert (out / "learning_curve.png").is_file()


@pytest.mark.slow
def test_rllib_defaults_train_and_the_run_is_a_policy(local_ray, tmp_path, capsys):
    pytest.importorskip("ray.rllib")
    from swarm_phd import bridge, record

    out = tmp_path / "rl"
    argv = ["train", "--engine", "rllib", *TINY, "--timesteps", "150", "--n-steps", "8"]
    argv += ["--num-env-runners", "1", "--n-epochs", "1", "--eval-seeds", "2"]
    # No --batch-size: the default minibatch (512) is cut to the iteration's 8 env steps.
    assert main([*argv, "--out", str(out)]) == 0
    first = capsys.readouterr()
    text = first.out
    assert "--timesteps 150 rounds up to 160 = 5 iterations of 32 agent steps" in text
    lines = [line for line in text.splitlines() if line.startswith("train: ")]
    assert len(lines) == 5 and "no episode finished yet" in lines[0]
    # Episodes end at env steps 20 and 40 (iterations 3 and 5): iteration 4 ends none, and
    # says the last mean, not "no episode".
    assert "no episode finished yet" in lines[1]
    assert all("mean episode return per agent" in line for line in lines[2:])
    assert lines[3].split("agent ")[2] == lines[2].split("agent ")[2]
    # The task's headline metric, from the env runners, beside the return once episodes end.
    assert "; formation_error_m " in lines[2] and "; formation_error_m " in lines[4]
    assert "RLlib's default MLP encoder" in text and "Deep Sets" not in first.err
    assert "paired by seed" in text and " | scripted:formation | " in text
    config = json.loads((out / "train_config.json").read_text())
    assert config["ppo"]["minibatch_size"] == 8
    assert (out / "learning_curve.png").is_file()

    # evaluate --policy RUN: the run's own env (preset, task, 20-step episodes).
    assert main(["evaluate", "--policy", str(out), "--seeds", "0", "--localizer", "phd-lo"]) == 0
    captured = capsys.readouterr()
    assert "lab-3m-4, 4 robots, 2 s x 1 seed(s), task formation" in captured.out
    assert "ends each episode after 20 steps" in captured.err
    # record and the bridge take it too (the bridge only with --trust-policy).
    record.check_policy_name(str(out))
    record.check_policy_name(str(out / "checkpoint"))
    parser = __import__("argparse").ArgumentParser()
    bridge.add_arguments(parser)
    with pytest.raises(ValueError, match="--trust-policy"):
        bridge.bridge_env_kwargs(parser.parse_args(["--loopback", "--policy", str(out)]), None)
    kwargs, _ = bridge.bridge_env_kwargs(
        parser.parse_args(["--loopback", "--trust-policy", "--policy", str(out)]), None
    )
    assert kwargs["preset"] == "lab-3m-4" and kwargs["task"] == "formation"
    assert kwargs["max_steps"] == 20
