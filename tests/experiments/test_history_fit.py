"""experiments/history_fit.py: what one frame and what a history carry of a teacher's
correction."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("torch")

from agents.sb3.sequences import collect_sequences  # noqa: E402
from experiments.distill_fit import phase_table  # noqa: E402
from experiments.history_fit import (  # noqa: E402
    fit_regressors,
    fit_rows,
    main,
)
from swarm_env.observation import ESTIMATE_COLUMNS  # noqa: E402

ROW = len(ESTIMATE_COLUMNS)
ENV = {"preset": "lab-3m-4", "task": "formation", "observation": "phd", "max_steps": 6}


def _synthetic(rng, n_seq, t, lag):
    """Sequences whose table is empty and whose 3 extra entries are white noise; the label's
    speed is the first extra entry ``lag`` steps earlier (a negative lag: later), 0 where that
    step is outside the sequence. The last quarter of the sequences are padded after 3/4 of
    their steps, and every 5th step is a teacher's random walk with a junk label: both must be
    left out of the loss and the scores."""
    dim = ROW * 16 + 3
    obs = np.zeros((n_seq, t, dim), np.float32)
    obs[..., ROW * 16 :] = rng.uniform(-1, 1, (n_seq, t, 3))
    label = np.zeros((n_seq, t, 2), np.float32)
    x = obs[..., ROW * 16]
    if lag >= 0:
        label[:, lag:, 0] = x[:, : t - lag]
    else:
        label[:, :lag, 0] = x[:, -lag:]
    valid = np.ones((n_seq, t), bool)
    valid[-(n_seq // 4) :, 3 * t // 4 :] = False
    wandering = np.zeros((n_seq, t), bool)
    wandering[:, ::5] = True
    label[wandering | ~valid] = 50.0  # junk: a loss that read it would be ruined
    return {
        "obs": obs,
        "base": np.zeros((n_seq, t, 2), np.float32),
        "label": label,
        "step": np.tile(np.arange(t), (n_seq, 1)),
        "valid": valid,
        "wandering": wandering,
    }


@pytest.mark.parametrize("lag", [0, 3, -3])
def test_only_the_history_regressor_reads_the_past(lag):
    # A label readable from the current frame (lag 0) is learnt by every regressor; one that
    # is the input 3 steps back only by the GRU (the step number does not help); one that is
    # the input 3 steps ahead by none (the GRU is causal). Junk labels on padded and
    # wandering steps are left out. This is what the tool is for: telling these apart.
    rng = np.random.default_rng(0)
    train, test = _synthetic(rng, 64, 16, lag), _synthetic(rng, 32, 16, lag)
    space = gym.spaces.Box(-1.0, 1.0, (ROW * 16 + 3,), np.float32)
    preds = fit_regressors(train, test, space, epochs=30, seed=0)
    assert set(preds) == {"frame", "frame+age", "history"}
    r2 = {
        name: phase_table(fit_rows(test, p["test"]), (abs(lag),))[0]["r2_v"]
        for name, p in preds.items()
    }
    if lag == 0:
        assert min(r2.values()) > 0.8
    elif lag > 0:
        assert r2["history"] > 0.8
        assert r2["frame"] < 0.1 and r2["frame+age"] < 0.1
    else:
        assert max(r2.values()) < 0.1


def test_collect_sequences_labels_a_teacher_equal_to_its_base_zero():
    data = collect_sequences(
        ENV, "scripted:formation-known-n-fast", "scripted:formation-known-n-fast", [0, 1]
    )
    n_seq, t, dim = data["obs"].shape
    assert (n_seq, t) == (8, 6) and data["valid"].all()  # 4 robots x 2 seeds, 6 steps
    assert list(data["seed"]) == [0] * 4 + [1] * 4
    assert np.abs(data["base"]).max() > 0.1  # the base moves the robots
    assert not data["label"].any()  # the same controller, the same state: no correction
    taught = collect_sequences(
        ENV, "scripted:formation-known-n-fast", "privileged:formation-known-n-fast@truth", [0]
    )
    assert np.array_equal(taught["obs"], data["obs"][:4])  # the base drives either way
    assert np.abs(taught["label"]).max() > 0.01


def test_main_writes_every_regressors_tables(tmp_path):
    out = tmp_path / "fit.json"
    argv = ["--preset", "lab-3m-4", "--max-steps", "6", "--base", "scripted:formation"]
    argv += ["--teacher", "privileged:formation@truth", "--train-seeds", "0-1"]
    argv += ["--test-seeds", "5", "--epochs", "1", "--phases", "0,3", "--out", str(out)]
    assert main(argv) == 0
    saved = json.loads(out.read_text())
    rows = saved["fits"]["history/fit_seed0"]["test"]
    assert [(r["from_step"], r["to_step"]) for r in rows] == [(0, 3), (3, None)]
    assert set(saved["fits"]) == {f"{k}/fit_seed0" for k in ("frame", "frame+age", "history")}


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--train-seeds", "0-5", "--test-seeds", "5"], "share seeds [5]"),
        (["--regressors", "frame,lstm"], "--regressors"),
        (["--epochs", "0"], "--epochs"),
        (["--phases", "150,0"], "--phases"),
    ],
)
def test_main_refuses_bad_arguments_naming_them(flags, message, capsys):
    argv = ["--base", "scripted:formation", "--teacher", "privileged:formation@truth"]
    with pytest.raises(SystemExit):
        main([*argv, *flags])
    assert message in capsys.readouterr().err
