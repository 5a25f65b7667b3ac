"""Bad input on the command line: every command refuses it with exit status 2 and one line
``swarm-phd COMMAND: error: ...`` naming the flag and the value, before any episode runs (the
functions that do the work are replaced here by ones that fail the test if called)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm_phd.cli import main

TINY = ["--preset", "lab-3m-4"]
SWEEP = ["sweep", "--serial", "--presets", "lab-3m-4"]


def _work_ran(*args, **kwargs):
    raise AssertionError("work ran before the input was refused")


@pytest.fixture
def no_work(monkeypatch):
    """Every command's work (episodes, rollouts, env builds of a run) fails the test."""
    import swarm_phd.bench as bench
    import swarm_phd.bridge as bridge
    import swarm_phd.demo as demo
    import swarm_phd.evaluate as evaluate
    import swarm_phd.export_bag as export_bag
    import swarm_phd.mutual as mutual
    import swarm_phd.seed003 as seed003
    import swarm_phd.sweep as sweep
    import swarm_phd.uav as uav

    for module, name in (
        (evaluate, "make_localizer"),  # the first thing of each seed's episode
        (sweep, "run_sweep"),
        (sweep, "evaluate_point"),
        (demo, "parallel_env"),
        (demo, "rollout"),
        (bench, "median_of_runs"),
        (export_bag, "export_sim_episode"),
        (mutual, "run_mutual"),
        (mutual, "symmetry_experiment"),
        (uav, "run_seed002"),
        (seed003, "run_seed003"),
        (bridge, "bridge_env_kwargs"),
    ):
        monkeypatch.setattr(module, name, _work_ran)


def _refused(capsys, argv: list[str], *named: str) -> str:
    """``argv`` exits 2 with one error line that names each of ``named``; the line."""
    code = main([*argv, "--quiet"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"swarm-phd {argv[0]}: error: "), err
    for text in named:
        assert text in lines[0], (text, lines[0])
    return lines[0]


# (1) Durations and counts: finite, > 0 (0 only where it means "none"/"skip").
@pytest.mark.parametrize(
    "argv, named",
    [
        (["evaluate", *TINY, "--duration", "inf"], ["--duration", "inf"]),
        (["evaluate", *TINY, "--duration", "nan"], ["--duration", "nan"]),
        (["evaluate", "--scenario", "seed003", "--duration", "inf"], ["--duration", "inf"]),
        (["bench", *TINY, "--duration", "inf"], ["--duration", "inf"]),
        (["bench", *TINY, "--duration", "nan"], ["--duration", "nan"]),
        (["demo", *TINY, "--duration", "inf"], ["--duration", "inf"]),
        (
            ["demo", *TINY, "--duration", "-1", "--eval-duration", "0", "--frames", "0"],
            ["--duration", "-1"],
        ),
        (["demo", *TINY, "--duration", "1", "--frames", "-3"], ["--frames", "-3"]),
        (["demo", *TINY, "--duration", "1", "--eval-duration", "-5"], ["--eval-duration", "-5"]),
        (["demo", *TINY, "--duration", "1", "--eval-duration", "nan"], ["--eval-duration", "nan"]),
        (
            [*SWEEP, "--duration", "inf"],
            ["--duration", "inf"],
        ),
        (["seed003", "--duration", "nan"], ["--duration", "nan"]),
        (["mutual", "--duration", "inf"], ["--duration", "inf"]),
        (["uav", "--duration", "-2"], ["--duration", "-2"]),
    ],
)
def test_a_duration_or_count_that_is_not_finite_or_not_positive_is_refused(
    argv, named, no_work, capsys
):
    _refused(capsys, argv, *named)


def test_export_bag_refuses_an_infinite_duration(no_work, tmp_path, capsys):
    bag = tmp_path / "bag"
    _refused(capsys, ["export-bag", *TINY, "--out", str(bag), "--duration", "inf"], "inf")
    assert not bag.exists()


# (2) Shorter than one control period (0.1 s on lab-3m-4): no step to score.
@pytest.mark.parametrize(
    "argv, flag",
    [
        (["evaluate", *TINY, "--duration", "1e-9", "--localizer", "phd-lc"], "--duration"),
        ([*SWEEP, "--duration", "1e-9"], "--duration"),
        (["bench", *TINY, "--duration", "1e-9"], "--duration"),
        (["demo", *TINY, "--duration", "1e-9"], "--duration"),
        (["demo", *TINY, "--duration", "1", "--eval-duration", "1e-9"], "--eval-duration"),
    ],
)
def test_a_duration_shorter_than_one_control_period_is_refused(argv, flag, no_work, capsys):
    line = _refused(capsys, argv, flag, "1e-09", "control period", "0.1 s")
    assert line.count("--") == 1  # only the flag at fault is named


# (3) Counts that a method needs, and a hold time that cannot be negative.
def test_mutual_refuses_too_few_particles_instead_of_using_the_default(no_work, capsys):
    for n in ("0", "1", "-4"):
        _refused(capsys, ["mutual", "--methods", "fastslam", "--particles", n], "--particles", n)


def test_make_methods_passes_a_zero_particle_count_to_the_config():
    """``n_particles=0`` is not "the default" (a falsy check took it for None)."""
    from swarm_phd.mutual import _make_methods

    ids = ("ugv_0", "ugv_1")
    for method in ("fastslam", "p-multireg", "p-multibeareg"):
        with pytest.raises(ValueError, match="n_particles"):
            _make_methods((method,), ids, ids, 0, 0)


def test_uav_refuses_a_negative_hold_time(no_work, capsys):
    _refused(capsys, ["uav", "--hold-s", "-1"], "--hold-s", "-1")
    _refused(capsys, ["uav", "--hold-s", "nan"], "--hold-s", "nan")


def test_zero_where_it_means_none_is_still_taken(monkeypatch, capsys):
    """``demo --frames 0 --eval-duration 0`` (no animation, no comparison), ``uav --hold-s 0``
    and ``mutual --particles 2`` (the methods' minimum) pass the checks and reach the work."""
    import swarm_phd.mutual as mutual
    import swarm_phd.uav as uav

    class Reached(Exception):
        pass

    def reached(*args, **kwargs):
        raise Reached(kwargs)

    monkeypatch.setattr(uav, "run_seed002", reached)
    monkeypatch.setattr(mutual, "run_mutual", reached)
    with pytest.raises(Reached) as got:
        main(["uav", "--hold-s", "0", "--quiet"])
    assert got.value.args[0]["hold_s"] == 0.0
    with pytest.raises(Reached) as got:
        main(["mutual", "--methods", "fastslam", "--particles", "2", "--quiet"])
    assert got.value.args[0]["n_particles"] == 2


def test_demo_takes_zero_frames_and_zero_eval_duration(tmp_path, capsys):
    out = tmp_path / "demo"
    argv = ["demo", *TINY, "--duration", "0.2", "--frames", "0", "--eval-duration", "0"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    assert (out / "demo.json").is_file() and not (out / "demo.gif").exists()
    assert not (out / "localization").exists()  # the comparison skipped


# (4) Seeds: non-negative integers, refused with the flag and the value at parse time.
@pytest.mark.parametrize(
    "argv, flag, value",
    [
        (["evaluate", *TINY, "--seeds=-1"], "--seeds", "-1"),
        (["evaluate", *TINY, "--seeds", "0--2"], "--seeds", "0--2"),
        (["evaluate", *TINY, "--ray", "--seeds=-1"], "--seeds", "-1"),
        (["demo", *TINY, "--seed", "-1"], "--seed", "-1"),
        (["bench", *TINY, "--seed", "-1"], "--seed", "-1"),
        (["seed003", "--seeds=-1"], "--seeds", "-1"),
        (["mutual", "--seeds=-1"], "--seeds", "-1"),
        (["mutual", "--symmetry", "--seeds=-1"], "--seeds", "-1"),
        (["uav", "--seeds=0,-1"], "--seeds", "0,-1"),
        ([*SWEEP, "--seeds=-1"], "--seeds", "-1"),
        (["bridge", "--loopback", "--seed", "-1"], "--seed", "-1"),
    ],
)
def test_a_negative_seed_is_refused_naming_the_flag(argv, flag, value, no_work, capsys):
    line = _refused(capsys, argv, flag, value)
    assert "expected non-negative integer" not in line  # numpy's message, naming nothing


def test_export_bag_refuses_a_negative_seed(no_work, tmp_path, capsys):
    _refused(capsys, ["export-bag", "--out", str(tmp_path / "bag"), "--seed", "-1"], "--seed")


def test_parse_seeds_refuses_negative_seeds():
    from swarm_core.inputs import parse_seeds

    assert parse_seeds("0-2,7") == [0, 1, 2, 7]
    for bad in ("-1", "0,-3", "-2-1", "0--1"):
        with pytest.raises(ValueError, match="--x.*non-negative"):
            parse_seeds(bad, "--x")


def test_format_seeds_writes_what_parse_seeds_reads():
    from swarm_core.inputs import format_seeds, parse_seeds

    assert format_seeds([0, 1, 2, 3, 7]) == "0-3,7"
    assert format_seeds([5, 3, 4]) == "5,3-4"  # in the given order
    for text in ("0-199", "2", "200-209,5,7-8"):
        assert format_seeds(parse_seeds(text)) == text


def test_one_number_check_serves_fields_and_flags():
    """The config fields' checks are :func:`check_number`'s common cases: same bounds, same
    message naming the field and the value (a bool is never a number)."""
    from swarm_core.validation import (
        check_int_range,
        check_non_negative,
        check_number,
        check_positive,
    )

    for check, args, message in (
        (check_positive, ("f", 0.0), "f must be a finite number > 0, got 0.0"),
        (check_positive, ("f", float("inf")), "f must be a finite number > 0, got inf"),
        (check_non_negative, ("f", -1), "f must be a finite number >= 0, got -1"),
        (check_int_range, ("f", 2.0, 1, 3), "f must be an integer in [1, 3], got 2.0"),
        (check_int_range, ("f", True, 0, 3), "f must be an integer in [0, 3], got True"),
    ):
        with pytest.raises(ValueError) as info:
            check(*args)
        assert str(info.value) == message
    check_positive("f", 1e-9)
    check_non_negative("f", 0)
    check_int_range("f", np.int64(3), 1, 3)
    check_number("--x", None, low=0, optional=True)
    check_number("--lr", lambda progress: 3e-4 * progress, low=0, above=True, schedule=True)
    with pytest.raises(ValueError, match=r"--x must be a finite number in \(0, 1\], got 0"):
        check_number("--x", 0, low=0, high=1, above=True)
    with pytest.raises(ValueError, match=r"--x must be a finite number in \[0, 1\), got 1"):
        check_number("--x", 1, low=0, high=1, below=True)
    with pytest.raises(ValueError, match=r"--x must be a finite number <= 2, got 3"):
        check_number("--x", 3, high=2)
    check_number("--x", 0.999, low=0, high=1, below=True)
    with pytest.raises(ValueError, match=r"--x must be a finite number >= 0, got 1000"):
        check_number("--x", 10**400, low=0)


# (5) Outputs: a location that cannot be written is refused before the run, not after it.
@pytest.fixture
def unwritable(tmp_path) -> Path:
    """A path under a regular file: no directory can be made there."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    return blocker / "out"


@pytest.mark.parametrize(
    "argv, flag",
    [
        (["evaluate", *TINY, "--duration", "1", "--out"], "--out"),
        (["evaluate", *TINY, "--duration", "1", "--ray", "--out"], "--out"),
        (["evaluate", "--scenario", "seed003", "--duration", "1", "--out"], "--out"),
        (["demo", *TINY, "--duration", "1", "--out"], "--out"),
        ([*SWEEP, "--duration", "1", "--out"], "--out"),
        (["bench", *TINY, "--duration", "1", "--json"], "--json"),
        (["export-bag", *TINY, "--out"], "--out"),
        (["uav", "--json"], "--json"),
        (["uav", "--figure"], "--figure"),
        (["uav", "--loopback", "--record"], "--record"),
        (["mutual", "--out"], "--out"),
        (["seed003", "--out"], "--out"),
        (["bridge", "--loopback", "--record"], "--record"),
    ],
)
def test_an_unwritable_output_is_refused_before_any_work(argv, flag, unwritable, no_work, capsys):
    line = _refused(capsys, [*argv, str(unwritable)], flag, str(unwritable), "not a directory")
    assert "a-file" in line


def test_outputs_that_exist_as_the_wrong_kind_are_refused(no_work, tmp_path, capsys):
    a_file = tmp_path / "metrics"
    a_file.write_text("")
    _refused(capsys, ["evaluate", *TINY, "--duration", "1", "--out", str(a_file)], "--out")
    _refused(capsys, ["bench", *TINY, "--duration", "1", "--json", str(tmp_path)], "--json")
    # A bag is never overwritten: an existing directory is refused for export-bag and --record.
    _refused(capsys, ["export-bag", "--out", str(tmp_path)], "--out", "exists already")
    _refused(capsys, ["bridge", "--loopback", "--record", str(tmp_path)], "--record")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics"]  # nothing was made


def test_a_missing_output_directory_is_still_made(tmp_path, capsys):
    """The check creates nothing, and refuses nothing that can be made: a new nested
    ``--out`` of ``evaluate`` is written after the run."""
    out = tmp_path / "new" / "nested"
    argv = ["evaluate", *TINY, "--duration", "0.2", "--localizer", "phd-lc", "--out", str(out)]
    assert main([*argv, "--quiet"]) == 0
    assert (out / "metrics.json").is_file()


# (6) Sweep: every preset is checked before the first point.
def test_sweep_refuses_an_unknown_preset_before_any_point(no_work, tmp_path, capsys):
    out = tmp_path / "sweep.json"
    argv = ["sweep", "--serial", "--presets", "lab-3m-4,nope", "--duration", "1"]
    _refused(capsys, [*argv, "--out", str(out)], "--presets", "nope")
    assert not out.exists()
    argv = [*SWEEP, "--localizer", "phd-lc,nope"]
    _refused(capsys, argv, "--localizer", "nope")


def test_the_process_prints_one_line_and_no_traceback():
    """The user's view: ``evaluate --duration inf`` was an OverflowError traceback."""
    proc = subprocess.run(
        [sys.executable, "-m", "swarm_phd.cli", "evaluate", *TINY, "--duration", "inf"],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
        timeout=600,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        "swarm-phd evaluate: error: --duration must be a finite number > 0, got inf"
    )
    assert "Traceback" not in proc.stderr


def test_the_kernels_compile_at_the_first_env_after_the_input_is_checked(monkeypatch, capsys):
    """On a cold cache the CLI compiled every kernel (about a minute) before the command read
    its flags. It now does so at the command's first env: a bad flag is refused with no
    compile, and a good command compiles once, before its episode."""
    from swarm_env import kernel_cache

    calls = []
    monkeypatch.setattr("swarm_env.warmup.warm_if_cold", lambda: calls.append(1) or True)
    monkeypatch.setattr(kernel_cache, "_noted", False)  # as in a fresh process
    _refused(capsys, ["evaluate", *TINY, "--duration", "nan"], "--duration", "nan")
    assert calls == []
    code = main(["evaluate", *TINY, "--duration", "0.2", "--seeds", "0", "--quiet"])
    assert code == 0 and calls == [1]
    assert kernel_cache._first_use_action is None  # cleared for what runs after the command


@pytest.mark.parametrize(
    ("argv", "flag", "value"),
    [
        (["uav", "--altitude", "-1"], "--altitude", "-1"),
        (["uav", "--altitude", "nan"], "--altitude", "nan"),
        (["uav", "--loss", "1.5"], "--loss", "1.5"),
        (["uav", "--latency", "-0.1"], "--latency", "-0.1"),
        (["uav", "--filter-lag", "inf"], "--filter-lag", "inf"),
        (["seed003", "--n-robots", "1"], "--n-robots", "1"),
        (["seed003", "--arena-m", "0"], "--arena-m", "0"),
        (["seed003", "--init-s", "0"], "--init-s", "0"),
        (["seed003", "--duration", "10", "--init-s", "10"], "--init-s", "10"),
        (["seed003", "--speed", "-0.05"], "--speed", "-0.05"),
    ],
)
def test_the_seed_studies_name_their_own_flags(argv, flag, value, no_work, capsys):
    """Refused by the command with the flag's name, not deep in a config by a field's."""
    _refused(capsys, argv, flag, value)
