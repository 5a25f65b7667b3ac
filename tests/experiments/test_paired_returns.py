"""Paired returns of a scripted base at two gains (experiments/paired_returns.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from experiments import paired_returns as pr  # noqa: E402
from tests.env_kwargs import formation_env  # noqa: E402

KWARGS = formation_env(12, task_params={"progress_weight": 10})
BASE = "scripted:formation-known-n"


def test_summary_by_hand():
    a = np.array([[1.0, 3.0], [5.0, 7.0], [0.0, 4.0]])  # per-seed means 2, 6, 2
    b = np.array([[1.0, 1.0], [3.0, 5.0], [2.0, 2.0]])  # 1, 4, 2
    s = pr.summarise_pairs(a, b)
    assert s["pairs"] == 3
    assert s["difference"] == pytest.approx(1.0)  # differences 1, 2, 0
    assert s["difference_se"] == pytest.approx(1.0 / math.sqrt(3.0))  # their sd is 1
    assert s["episodes_for_2se_paired"] == pytest.approx(4.0)  # (2 x 1 / 1)^2
    # Episode means' variances 48/9 and 21/9: unpaired needs 2 (2 sd / 1)^2 = 8 x 69/18.
    assert s["episode_return_sd"] == pytest.approx(math.sqrt(69 / 18))
    assert s["episodes_for_2se_unpaired"] == pytest.approx(8 * 69 / 18)
    # Per-agent variances 20/3 and 34/15.
    assert s["agent_return_sd"] == pytest.approx(math.sqrt((20 / 3 + 34 / 15) / 2))
    assert s["return_a"] == pytest.approx(20 / 6) and s["return_b"] == pytest.approx(14 / 6)
    # Episode means (2, 6, 2) and (1, 4, 2): covariance 10/3 over sqrt(48/9 x 21/9).
    assert s["episode_return_correlation"] == pytest.approx((10 / 3) / math.sqrt(48 * 21 / 81))
    assert s["agent_return_correlation"] == pytest.approx(np.corrcoef(a.ravel(), b.ravel())[0, 1])
    same = pr.summarise_pairs(a, a)  # no difference: no number of episodes resolves it
    assert same["difference"] == 0.0 and same["episodes_for_2se_paired"] == math.inf
    assert same["agent_return_correlation"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="seeds >= 2"):
        pr.summarise_pairs(a[:1], b[:1])


def test_equal_gains_give_equal_returns_and_a_gain_changes_only_its_arm():
    """Common random numbers: the two copies of a seed run the same episode bit for bit when
    their gains are equal; doubling arm A's speed changes A's returns and leaves B's as they
    were. Five seeds: one full chunk of four and a padded chunk of one."""
    seeds = [3, 4, 5, 6, 7]
    a, b = pr.paired_returns(KWARGS, BASE, (1.0, 1.0), (1.0, 1.0), seeds)
    assert a.shape == (5, 4)
    np.testing.assert_array_equal(a, b)
    assert len({tuple(row) for row in a}) == 5  # different seeds, different episodes
    a2, b2 = pr.paired_returns(KWARGS, BASE, (2.0, 1.0), (1.0, 1.0), seeds)
    np.testing.assert_array_equal(b2, b)
    assert not np.array_equal(a2, a)
    # Gathering faster removes more error per step at first: the shaped return rises.
    assert a2.mean() > a.mean()


def test_an_arm_is_the_base_run_alone():
    """Arm B at gains (1, 1) sums the same rewards, final step included, as the residual base
    with a zero correction in a VecEnv of its own, reset with that seed."""
    seeds = [5, 9]
    _, b = pr.paired_returns(KWARGS, BASE, (0.5, 2.0), (1.0, 1.0), seeds)
    for row, seed in zip(b, seeds, strict=True):
        venv = BatchedSwarmVecEnv(KWARGS, 1, seed=seed, residual=BASE, residual_mode="gain")
        venv.reset()
        total = np.zeros(venv.num_envs)
        for _ in range(KWARGS["max_steps"]):
            _, rewards, dones, _ = venv.step(np.zeros((venv.num_envs, 2), np.float32))
            total += rewards
        assert dones.all()
        venv.close()
        np.testing.assert_array_equal(row, total)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="gains_a"):
        pr.paired_returns(KWARGS, BASE, (5.0, 1.0), (1.0, 1.0), [0, 1])
    with pytest.raises(ValueError, match="gains_b"):
        pr.paired_returns(KWARGS, BASE, (1.0, 1.0), (1.0, float("nan")), [0, 1])
    with pytest.raises(ValueError, match="gains_a"):
        pr.paired_returns(KWARGS, BASE, ("fast", 1.0), (1.0, 1.0), [0, 1])
    with pytest.raises(ValueError, match="base must be 'scripted:NAME'"):
        pr.paired_returns(KWARGS, "random", (1.0, 1.0), (1.0, 1.0), [0, 1])
    for seeds in ([3], [0, -1], [0, 1.5]):
        with pytest.raises(ValueError, match="seeds must be at least 2 ints"):
            pr.paired_returns(KWARGS, BASE, (1.0, 1.0), (1.0, 1.0), seeds)
    venv = BatchedSwarmVecEnv(KWARGS, 2, seed=0)
    with pytest.raises(ValueError, match="copy_seeds must be 2 ints"):
        venv.reset(copy_seeds=[1])
    with pytest.raises(ValueError, match="copy_seeds"):
        venv.reset(copy_seeds=[1, -2])
    venv.close()


def test_cli_writes_the_summary(tmp_path, capsys):
    out = tmp_path / "pairs.json"
    code = pr.main(
        [
            "--base", BASE, "--preset", "lab-3m-4", "--max-steps", "12",
            "--task-params", '{"progress_weight": 10}', "--speed-gains", "2", "1",
            "--seeds", "0-1", "--out", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    record = json.loads(out.read_text())
    assert record["seeds"] == [0, 1] and record["gains_a"] == [2.0, 1.0]
    assert record["env_kwargs"]["max_steps"] == 12
    assert "episodes for 2 SE" in capsys.readouterr().out
