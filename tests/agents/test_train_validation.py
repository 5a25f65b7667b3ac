"""``swarm-phd train`` refuses bad numeric input up front: exit code 2 and one line naming the flag
and the value (ValueError from :func:`agents.sb3.train.train`), before any env is built and
before anything is written to ``--out`` (a previous run there is left as it was)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

import agents.sb3.adapter as adapter  # noqa: E402
import agents.sb3.batched as batched  # noqa: E402
import agents.sb3.train as train_module  # noqa: E402
import swarm_env  # noqa: E402
from agents.sb3.train import train  # noqa: E402
from swarm_phd.cli import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BASE = ["train", "--preset", "lab-3m-4", "--task", "formation", "--timesteps", "64"]
KWARGS = {"preset": "lab-3m-4", "task": "formation", "max_steps": 15}
#: A previous run's files in ``--out``: a refused run must leave them exactly as they are.
SENTINELS = {
    "train_config.json": '{"previous": "run"}\n',
    "env_kwargs.json": '{"preset": "previous"}\n',
    "monitor.csv": "#previous run\nr,l,t\n1.0,300,30.0\n",
}


@pytest.fixture
def previous_run(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for name, text in SENTINELS.items():
        (out / name).write_text(text)
    return out


def assert_untouched(out: Path) -> None:
    assert sorted(p.name for p in out.iterdir()) == sorted(SENTINELS)
    for name, text in SENTINELS.items():
        assert (out / name).read_text() == text, name


@pytest.fixture
def no_env(monkeypatch):
    """Fail the test if an env is built or torch's thread count is changed."""
    import torch

    def built(*args, **kwargs):
        raise AssertionError("an env was built before the input was checked")

    def threads(n):
        raise AssertionError(f"torch.set_num_threads({n}) before the input was checked")

    # Every command module first, unpatched: a module imported under the patch would keep
    # `from swarm_env import parallel_env` bound to it for the rest of the session.
    from swarm_phd.cli import build_parser

    build_parser()
    monkeypatch.setattr(swarm_env, "parallel_env", built)
    monkeypatch.setattr(batched, "make_batched_vec_env", built)
    monkeypatch.setattr(adapter, "make_vec_env", built)
    monkeypatch.setattr(torch, "set_num_threads", threads)
    # The kernels are compiled once per session (conftest); no compile check per refusal.
    monkeypatch.setattr("swarm_env.warmup.warm_if_cold", lambda: False)


CLI_REFUSALS = [
    # (extra arguments, what the message names: the flag and the value)
    (["--learning-rate", "-1"], ["--learning-rate", "-1"]),
    (["--learning-rate", "0"], ["--learning-rate", "0"]),
    (["--learning-rate", "nan"], ["--learning-rate", "nan"]),
    (["--gamma", "2"], ["--gamma", "2"]),
    (["--gamma", "-0.5"], ["--gamma", "-0.5"]),
    (["--gamma", "nan"], ["--gamma", "nan"]),
    (["--ent-coef", "nan"], ["--ent-coef", "nan"]),
    (["--ent-coef", "-0.01"], ["--ent-coef", "-0.01"]),
    (["--ent-coef", "inf"], ["--ent-coef", "inf"]),
    (["--n-steps", "0"], ["--n-steps", "0"]),
    (["--batch-size", "0"], ["--batch-size", "0"]),
    (["--batch-size", "1"], ["--batch-size", "1", "advantage"]),
    (["--n-epochs", "0"], ["--n-epochs", "0"]),
    (["--max-wall-minutes", "-1"], ["--max-wall-minutes", "-1"]),
    (["--max-wall-minutes", "0"], ["--max-wall-minutes", "0"]),
    (["--max-wall-minutes", "nan"], ["--max-wall-minutes", "nan"]),
    (["--torch-threads", "-5"], ["--torch-threads", "-5"]),
    (["--torch-threads", "0"], ["--torch-threads", "0"]),
    (["--kernel-threads", "0"], ["--kernel-threads", "0"]),
    (["--kernel-threads", "999"], ["--kernel-threads", "999"]),
    (["--checkpoint-every", "0"], ["--checkpoint-every", "0"]),
    (["--seed", "-1"], ["--seed", "-1"]),
    (["--seed", str(2**32)], ["--seed", str(2**32)]),
    (["--extractor", "sets", "--observation", "measurements"], ["--extractor sets", "measure"]),
    (["--residual-log-std", "-2"], ["--residual-log-std", "-2", "--residual"]),
    # Checked before this change too; here for "nothing written, no env built".
    (["--timesteps", "0"], ["--timesteps", "0"]),
    (["--n-copies", "0"], ["--n-copies", "0"]),
    (["--num-cpus", "-1"], ["--num-cpus", "-1"]),
    (["--clip-range", "nan"], ["--clip-range", "nan"]),
    (["--target-kl", "-1"], ["--target-kl", "-1"]),
    (["--critic-warmup", "-1"], ["--critic-warmup", "-1"]),
    (["--recurrent", "--lstm-hidden", "0"], ["--lstm-hidden", "0"]),
    (["--residual", "scripted:formation", "--residual-log-std", "nan"], ["--residual-log-std"]),
    (["--warm-start", "scripted:formation", "--bc-steps", "0"], ["--bc-steps", "0"]),
    (["--warm-start", "scripted:formation", "--bc-log-std", "nan"], ["--bc-log-std", "nan"]),
    (["--n-copies", "2", "--num-cpus", "3"], ["--num-cpus 3", "--n-copies 2"]),
]


@pytest.mark.parametrize(("extra", "named"), CLI_REFUSALS, ids=lambda v: " ".join(v))
def test_cli_refuses_bad_input_before_building_or_writing(
    previous_run, no_env, capsys, extra, named
):
    assert main([*BASE, "--out", str(previous_run), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarm-phd train: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    for word in named:
        assert word in err, (word, err)
    assert_untouched(previous_run)


def test_cli_refuses_an_out_that_is_a_file(tmp_path, no_env, capsys):
    out = tmp_path / "run"
    out.write_text("not a directory")
    assert main([*BASE, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and str(out) in err and "Traceback" not in err
    assert out.read_text() == "not a directory"


def test_env_refusals_also_leave_the_previous_run(previous_run, capsys):
    """Env flags are checked by the env itself (one probe env, before anything is written); a
    rollout of one transition is refused once the probe gave the number of agents."""
    for extra, named in (
        (["--n-robots", "0"], "n_robots"),
        (["--max-steps", "0"], "max_steps"),
        (["--n-robots", "1", "--n-copies", "1", "--n-steps", "1"], "--n-steps 1"),
    ):
        # --overwrite: past the --out check, which comes before the probe env
        assert main([*BASE, "--out", str(previous_run), "--overwrite", *extra]) == 2
        err = capsys.readouterr().err
        assert named in err and "Traceback" not in err, err
        assert_untouched(previous_run)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ({"ppo_kwargs": {"gamma": 2.0}}, r"--gamma must be .*\[0, 1\], got 2\.0"),
        ({"ppo_kwargs": {"gamma": math.nan}}, "--gamma .*got nan"),
        ({"ppo_kwargs": {"gae_lambda": 1.5}}, r"gae_lambda.* got 1\.5"),
        ({"ppo_kwargs": {"ent_coef": math.inf}}, "--ent-coef .*got inf"),
        ({"ppo_kwargs": {"vf_coef": -1}}, "vf_coef.* got -1"),
        ({"ppo_kwargs": {"max_grad_norm": 0}}, "max_grad_norm.* got 0"),
        ({"ppo_kwargs": {"clip_range_vf": 0.0}}, r"clip_range_vf.* got 0\.0"),
        ({"ppo_kwargs": {"learning_rate": -1e-3}}, "--learning-rate .*got -0.001"),
        ({"ppo_kwargs": {"n_steps": 2.5}}, r"--n-steps must be an integer >= 1, got 2\.5"),
        ({"ppo_kwargs": {"n_epochs": True}}, "--n-epochs .*got True"),
        ({"ppo_kwargs": {"batch_size": 1}}, "--batch-size .*got 1"),
        ({"ppo_kwargs": {"normalize_advantage": "yes"}}, "normalize_advantage.*'yes'"),
        ({"ppo_kwargs": {"nope": 1}}, "ppo_kwargs.*'nope'"),
        ({"ppo_kwargs": {"seed": 3}}, "ppo_kwargs.*'seed'"),
        ({"torch_threads": 0}, "--torch-threads .*got 0"),
        ({"kernel_threads": 0}, "--kernel-threads .*got 0"),
        ({"checkpoint_every": 0}, "--checkpoint-every .*got 0"),
        ({"max_wall_s": -60.0}, r"max_wall_s .*got -60\.0"),
        ({"seed": -1}, "--seed .*got -1"),
        ({"extractor": "cnn"}, "extractor.*'cnn'"),
    ],
)
def test_train_raises_value_error_naming_the_field(previous_run, no_env, extra, match):
    with pytest.raises(ValueError, match=match):
        train(KWARGS, 64, previous_run, progress_bar=False, **extra)
    assert_untouched(previous_run)


def test_the_defaults_and_sb3s_own_exceptions_pass():
    check_ppo_kwargs = train_module.check_ppo_kwargs
    check_ppo_kwargs({})
    check_ppo_kwargs({"n_steps": 128, "batch_size": 512, "n_epochs": 10, "gamma": 1.0})
    # A batch of one is fine without advantage normalisation (SB3's own rule).
    check_ppo_kwargs({"batch_size": 1, "normalize_advantage": False})
    # SB3 schedules (callables) for the learning rate and the clip ranges; no KL stop.
    check_ppo_kwargs({"learning_rate": lambda p: 3e-4 * p, "clip_range": lambda p: 0.2})
    check_ppo_kwargs({"target_kl": None, "clip_range_vf": None, "use_sde": True})


def test_command_line_refuses_in_one_line(previous_run):
    """``swarm-phd train`` from a shell (the module entry point): one line, exit code 2."""
    proc = subprocess.run(
        [sys.executable, "-m", "swarm_phd.cli", *BASE, "--out", str(previous_run)]
        + ["--gamma", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NUMBA_NUM_THREADS": "1"},
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.splitlines()[-1].startswith("swarm-phd train: error: --gamma")
    assert "2.0" in proc.stderr and "Traceback" not in proc.stderr
    assert_untouched(previous_run)


def test_a_valid_run_into_a_previous_run_is_refused_without_overwrite(previous_run, capsys):
    """A rerun with the same --out would replace a finished run's model, empty its monitor and
    mix its checkpoints with the new ones: refused, naming --out and the way out."""
    assert main([*BASE, "--out", str(previous_run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarm-phd train: error: --out") and "holds a previous run" in err
    assert "--overwrite" in err and "Traceback" not in err
    assert_untouched(previous_run)
    with pytest.raises(ValueError, match="holds a previous run"):
        train(KWARGS, 64, previous_run, progress_bar=False)
    assert_untouched(previous_run)


def test_overwrite_trains_into_a_previous_run(previous_run):
    model = train(
        KWARGS,
        64,
        previous_run,
        overwrite=True,
        n_copies=1,
        progress_bar=False,
        ppo_kwargs={"n_steps": 16, "batch_size": 32, "n_epochs": 1},
    )
    assert model.is_file()
    assert (previous_run / "monitor.csv").read_text() != SENTINELS["monitor.csv"]


def test_run_dir_takes_a_new_or_empty_directory(tmp_path):
    from swarm_core.inputs import run_dir

    assert run_dir("--out", tmp_path / "new" / "run", overwrite=False) == tmp_path / "new" / "run"
    assert run_dir("--out", tmp_path, overwrite=False) == tmp_path  # empty
    (tmp_path / "model.zip").write_text("x")
    with pytest.raises(ValueError, match=r"--out .* holds a previous run \(model.zip\)"):
        run_dir("--out", tmp_path, overwrite=False)
    assert run_dir("--out", tmp_path, overwrite=True) == tmp_path
