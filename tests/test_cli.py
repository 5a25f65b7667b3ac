"""The command line as a new user meets it: every command's --help (defaults shown), --version,
`list`, and a tiny run of every command that is cheap; interrupting `train` saves the model."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm_core import progress
from swarm_phd.cli import _REGISTRY, DEFAULT_PRESET, build_parser, main

COMMANDS = [name for name, *_ in _REGISTRY]
TINY = ["--preset", "lab-3m-4"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_help_with_defaults(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert f"swarm-phd {command}" in text and "--quiet" in text
    if "--preset" in text:
        assert "lab-3m-4" in text and "sim-6m-20" in text  # the presets are listed


def test_defaults_are_shown_and_one_preset_is_shared(capsys):
    parser = build_parser()
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    assert "(default: 60.0)" in capsys.readouterr().out
    presets = {}
    for action in parser._subparsers._group_actions[0].choices.items():
        name, sub = action
        for a in sub._actions:
            if a.dest == "preset" and a.default is not None:
                presets[name] = a.default
    # Real robots: the lab preset, unless the policy is a model trained on another.
    assert "bridge" not in presets
    bridge_help = parser._subparsers._group_actions[0].choices["bridge"].format_help()
    assert "else lab-3m-4" in " ".join(bridge_help.split())
    presets.pop("warmup")
    assert set(presets.values()) == {DEFAULT_PRESET}, presets


def test_version_and_list(capsys):
    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out.startswith("swarm-phd ")
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    for name in ("sim-6m-20", "lab-3m-4", "seed-sim", "formation", "wander", "phd-lc", "phd-lo"):
        assert name in text


def test_old_preset_names_still_work():
    from swarm_env.config import make_config

    assert make_config("seed-lab") == make_config("lab-3m-4")
    assert make_config("seed-sim") == make_config("sim-6m-20")
    with pytest.raises(ValueError, match="preset"):
        make_config("seed-moon")


def test_demo_tiny_writes_frames_the_comparison_and_the_measured_over_count(tmp_path, capsys):
    """One tiny demo: frames, figures, and the LC vs LO summary, which quotes this run's
    in-range weight bias (not a fixed figure)."""
    out = tmp_path / "demo"
    code = main(
        ["demo", *TINY, "--duration", "1", "--frames", "2", "--eval-duration", "2"]
        + ["--out", str(out)]
    )
    assert code == 0
    captured = capsys.readouterr()
    assert "real-time factor" in captured.out and "comparison.png" in captured.out
    assert "demo:" in captured.err  # the progress bar, as plain lines (not a TTY here)
    assert "\r" not in captured.err
    for name in ("demo.gif", "snapshot.png", "comparison.png", "demo.json"):
        assert (out / name).stat().st_size > 0
    # The lidar's misses split by cause (they sum to its missed rate).
    lidar = json.loads((out / "demo.json").read_text())["sensors"]["lidar"]
    causes = lidar["missed_rate_by_cause"]
    assert set(causes) == {"hidden", "interfered", "extractor"}
    assert sum(causes.values()) == pytest.approx(lidar["missed_detection_rate"])
    assert "missed by cause: hidden" in captured.out
    metrics = json.loads((out / "localization" / "metrics.json").read_text())
    bias = metrics["localizers"]["phd-lc"]["cardinality"]["in_range_bias"]
    assert f"LC's weight in range is {bias:+.2f} teammates" in captured.out


def test_bench_tiny_quiet(tmp_path, capsys):
    path = tmp_path / "bench.json"
    code = main(["bench", *TINY, "--duration", "0.5", "--repeats", "1", "--json", str(path)])
    assert code == 0
    rows = json.loads(path.read_text())
    assert [r["localization"] for r in rows] == ["off", "phd-lc"]
    assert all(r["steps"] == 5 for r in rows)
    assert "bench:" in capsys.readouterr().err  # one line per run
    code = main(["bench", *TINY, "--duration", "0.5", "--repeats", "1", "--quiet"])
    assert code == 0 and capsys.readouterr().err == ""  # --quiet: results only
    assert not progress.is_quiet()  # the switch does not leak past the command


def test_evaluate_tiny(tmp_path, capsys):
    out = tmp_path / "eval"
    code = main(
        ["evaluate", *TINY, "--duration", "1", "--localizer", "phd-lc", "--seeds", "0"]
        + ["--out", str(out), "--quiet"]
    )
    assert code == 0
    assert "phd-lc" in json.loads((out / "metrics.json").read_text())["localizers"]


def test_export_bag_then_replay_tiny(tmp_path, capsys):
    bag = tmp_path / "bag"
    assert main(["export-bag", *TINY, "--duration", "1", "--out", str(bag), "--quiet"]) == 0
    assert main(["replay", str(bag), "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out.split("\n", 1)[1])
    assert report["episodes"][0]["steps"] > 0
    # --overrides reach the replayed config (the scans are re-extracted with them) ...
    width_only = '{"lidar_features": {"extent_test": false}}'
    assert main(["replay", str(bag), "--overrides", width_only, "--quiet"]) == 0
    capsys.readouterr()
    # ... and a bad one is one line naming it.
    assert main(["replay", str(bag), "--overrides", '{"lidar_features": {"nope": 1}}']) == 2
    assert "unknown config key 'lidar_features.nope'" in capsys.readouterr().err
    assert main(["replay", str(bag), "--overrides", "[1]"]) == 2
    assert "--overrides" in capsys.readouterr().err


def test_warmup_reports_the_kernels(capsys):
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "kernels" in out and "cached" in out


TRAIN = [
    "train",
    *TINY,
    "--task",
    "formation",
    "--observation",
    "truth",
    "--extractor",
    "mlp",
    "--n-copies",
    "1",
    "--n-steps",
    "32",
    "--batch-size",
    "64",
    "--n-epochs",
    "1",
    "--max-steps",
    "50",
]


def test_train_tiny(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "train"
    assert (
        main([*TRAIN, "--timesteps", "200", "--out", str(out), "--checkpoint-every", "128"]) == 0
    )
    err = capsys.readouterr().err
    assert "train:" in err  # the bar, as plain lines
    assert (out / "model.zip").is_file()
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["timesteps"] == 256 and summary["interrupted"] is None  # 2 rollouts of 128
    assert summary["stopped"] is None


def test_train_stopped_by_its_wall_time_budget_saves_a_usable_model(tmp_path, capsys):
    """A budget already spent at the first env step: training stops there (the budget is
    checked every step), saves model.zip as a finished run does and exits 0."""
    pytest.importorskip("stable_baselines3")
    from agents.policies import load_policy
    from agents.sb3.policy import env_kwargs_for_model
    from swarm_env import parallel_env

    out = tmp_path / "train"
    argv = [*TRAIN, "--timesteps", "512", "--max-wall-minutes", "1e-6", "--out", str(out)]
    assert main([*argv, "--no-progress-bar"]) == 0
    printed = capsys.readouterr().out
    assert "wall-time budget of 0 s reached" in printed and "(wall-time budget)" in printed
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["stopped"] == "max-wall-minutes" and summary["interrupted"] is None
    assert 0 < summary["timesteps"] < 128  # within the first rollout of 128 agent steps
    kwargs = env_kwargs_for_model(out / "model.zip")
    env = parallel_env("lab-3m-4", **kwargs)
    try:
        policy = load_policy(str(out / "model.zip"), env)  # its predict, on the env's obs
        obs, infos = env.reset(seed=0)
        actions = policy(obs, infos)
        assert set(actions) == set(env.agents)
        assert all(env.action_space(a).contains(actions[a]) for a in actions)
    finally:
        env.close()


def _start_train(out: Path, *extra: str, new_session: bool = False) -> subprocess.Popen:
    env = {**os.environ, "SWARM_PHD_PROGRESS": "lines", "SWARM_PHD_PROGRESS_EVERY_S": "0.2"}
    return subprocess.Popen(
        [sys.executable, "-m", "swarm_phd.cli", *TRAIN, "--timesteps", "1000000"]
        + ["--checkpoint-every", "100000000", "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=Path(__file__).resolve().parents[1],
        start_new_session=new_session,
    )


def _wait_for_training(proc: subprocess.Popen) -> None:
    """Read stderr until the train bar's first line (training has started)."""
    lines = []
    # Generous: a busy machine, or a kernel source edited since the last compile, can make
    # the start slow; this test is about what happens on the signal, not about speed.
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        lines.append(line)
        if line.startswith("train:") or not line:
            break
    assert lines[-1].startswith("train:"), lines


def test_interrupted_train_saves_and_exits_with_one_line(tmp_path):
    """SIGINT (Ctrl-C) and SIGTERM, each to its own tiny run (both at once, to save time)."""
    pytest.importorskip("stable_baselines3")
    runs = {signum: tmp_path / signal.Signals(signum).name for signum in (2, 15)}
    procs = {signum: _start_train(out) for signum, out in runs.items()}
    for proc in procs.values():
        _wait_for_training(proc)
    time.sleep(1.0)
    for signum, proc in procs.items():
        proc.send_signal(signum)
    for signum, proc in procs.items():
        out = runs[signum]
        try:
            _, stderr = proc.communicate(timeout=90)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, stderr = proc.communicate()
            pytest.fail(f"{signal.Signals(signum).name} did not stop training: {stderr[-3000:]}")
        name = signal.Signals(signum).name
        assert proc.returncode == {"SIGINT": 130, "SIGTERM": 143}[name], stderr
        assert "Traceback" not in stderr and "meta_path" not in stderr, stderr
        final = [line for line in stderr.splitlines() if line.startswith("swarm-phd train:")]
        assert len(final) == 1 and name in final[0], stderr
        assert (out / "model.zip").is_file()
        checkpoints = list((out / "checkpoints").glob("model_*_steps.zip"))
        assert len(checkpoints) == 1
        summary = json.loads((out / "train_summary.json").read_text())
        assert summary["interrupted"] == summary["stopped"] == name and summary["timesteps"] > 0
        assert checkpoints[0].name == f"model_{summary['timesteps']}_steps.zip"


def test_ctrl_c_to_the_process_group_with_batched_workers_saves_and_ends_them(tmp_path):
    """A terminal's Ctrl-C reaches the trainer and its env workers (``--num-cpus 2``): the
    trainer alone acts on it (saves, exits 130) and closes the workers; none is left."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "workers"
    proc = _start_train(out, "--num-cpus", "2", "--n-copies", "2", new_session=True)
    try:
        _wait_for_training(proc)
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr, stderr
    assert (out / "model.zip").is_file()
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["interrupted"] == "SIGINT" and summary["timesteps"] > 0
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # the group is empty once the workers have exited
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("env workers outlived the trainer")


def test_progress_lines_when_not_a_tty_and_silent_when_quiet(monkeypatch):
    import io

    monkeypatch.delenv("SWARM_PHD_PROGRESS", raising=False)
    stream = io.StringIO()  # not a TTY: whole lines, about one per 10 %
    with progress.bar(2.0, "sim", unit="s sim", fmt="{:.1f}", stream=stream) as b:
        for _ in range(20):
            b.update(0.1)
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and 9 <= len(lines) <= 11
    assert lines[-1].startswith("sim: 2.0/2.0 s sim (100%)")
    progress.set_quiet(True)
    try:
        stream = io.StringIO()
        b = progress.bar(5, "quiet", stream=stream)
        b.update(5)
        b.close()
        assert stream.getvalue() == ""
    finally:
        progress.set_quiet(False)
    monkeypatch.setenv("SWARM_PHD_PROGRESS", "loud")
    with pytest.raises(ValueError, match="SWARM_PHD_PROGRESS"):
        progress.bar(1, "x")


def test_a_signal_raised_inside_a_c_callback_still_exits_as_the_signal(monkeypatch, tmp_path):
    # SIGTERM's Terminated raised while numba was loading a cached kernel reached the top as a
    # SystemError caused by it (CI, 2026-12-05: export-bag exited 1, not 143). The command line
    # re-raises the signal's exception, so the process exits 128 + 15 after every finally.
    import swarm_phd.export_bag as export_bag
    from hardware_bridge.signals import Terminated
    from swarm_core.signal_chain import signal_cause

    def wrapped(args):
        try:
            raise Terminated(signal.SIGTERM)
        except Terminated as err:
            raise SystemError("returned a result with an exception set") from err

    monkeypatch.setattr(export_bag, "run", wrapped)
    with pytest.raises(Terminated) as caught:
        main(["export-bag", "--out", str(tmp_path / "b")])
    assert caught.value.code == 128 + signal.SIGTERM
    # Found through __context__ too; a SystemError from anything else is not a signal.
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("implicit") from None
    except SystemError as err:
        assert signal_cause(err) is None  # "from None" hides the context: not ours to guess
        assert isinstance(signal_cause(err.__context__), KeyboardInterrupt)
    assert signal_cause(SystemError("other")) is None

    def other(args):
        raise SystemError("a real bug")

    monkeypatch.setattr(export_bag, "run", other)
    with pytest.raises(SystemError, match="a real bug"):
        main(["export-bag", "--out", str(tmp_path / "c")])
