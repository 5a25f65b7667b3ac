"""Evaluation sweeps on Ray: a 2-worker local Ray gives the serial metrics bit for bit, shows a
line per finished point, and a failing point is reported with its seed without losing the
others' results."""

from __future__ import annotations

import argparse
import json
import os

import pytest

from swarm_core.atomic_files import write_json_atomically
from swarm_phd import sweep

ray = pytest.importorskip("ray", reason="the ray extra is not installed")

LOCALIZERS = ["phd-lc", "phd-lo"]


def _metrics(results: dict) -> str:
    """The results without the run's wall time, as canonical JSON (NaN compares equal)."""
    return json.dumps({k: v for k, v in results.items() if k != "wall_time_s"}, sort_keys=True)


def test_ray_sweep_equals_serial_and_survives_a_failing_point(local_ray, tmp_path):
    from swarm_phd.evaluate import evaluate_localization

    parser = argparse.ArgumentParser()
    sweep.add_arguments(parser)
    out = tmp_path / "sweep.json"
    # "no-such-preset" makes its two points fail inside their workers (the env rejects it).
    args = parser.parse_args(
        ["--presets", "lab-3m-4,no-such-preset", "--localizer", ",".join(LOCALIZERS),
         "--seeds", "0-1", "--duration", "3", "--out", str(out)]
    )  # fmt: skip
    lines: list[str] = []
    points = sweep.grid(["lab-3m-4", "no-such-preset"], LOCALIZERS, [0, 1], 3.0, overrides={})
    merged = sweep.run_sweep(points, out=out, report=lines.append)
    assert len(lines) == 4 and all(line.startswith("sweep [") for line in lines)
    assert sorted(int(line.split("/")[0].split("[")[1]) for line in lines) == [1, 2, 3, 4]
    on_disk = json.loads(out.read_text())
    assert on_disk["complete"] and not list(tmp_path.glob(".sweep.json.*"))  # no temp left
    ok = {e["seed"]: e for e in on_disk["points"] if e["status"] == "ok"}
    failed = on_disk["failed"]
    assert sorted(ok) == [0, 1]
    assert sorted((f["preset"], f["seed"]) for f in failed) == [
        ("no-such-preset", 0),
        ("no-such-preset", 1),
    ]
    assert all("no-such-preset" in f["error"] for f in failed)
    assert any("FAILED" in line and "seed 1" in line for line in lines)
    for seed in (0, 1):
        serial = evaluate_localization("lab-3m-4", 3.0, LOCALIZERS, [seed])
        assert _metrics(ok[seed]["results"]) == _metrics(serial)
        assert ok[seed]["results"]["config"]["seeds"] == [seed]
    # The summary is the mean over the seeds' own numbers, for every scalar of the block.
    for name in LOCALIZERS:
        summary = on_disk["summary"]["lab-3m-4"][name]
        assert summary  # the evaluation's block has scalars
        for key, stats in summary.items():
            values = []
            for s in (0, 1):
                value = ok[s]["results"]["localizers"][name]
                for part in key.split("."):
                    value = value[part]
                values.append(float(value))
            finite = [v for v in values if v == v]
            assert stats["n"] == 2
            if finite:
                assert stats["mean"] == pytest.approx(sum(finite) / len(finite))
                assert stats["min"] == min(finite) and stats["max"] == max(finite)
    assert merged["failed"] == failed
    # The command's own path checks every preset before any point runs (the CLI exits 2):
    # the file of the run above is left as it was.
    before = out.read_text()
    with pytest.raises(ValueError, match="no-such-preset"):
        sweep.run(args)
    assert out.read_text() == before


def test_parse_seeds():
    assert sweep.parse_seeds("0-3,7") == [0, 1, 2, 3, 7]
    assert sweep.parse_seeds("5") == [5]
    for bad in ("a", "3-1", "1.5", ""):
        with pytest.raises(ValueError, match="--seeds"):
            sweep.parse_seeds(bad)


def test_grid_checks_shared_arguments_before_any_worker():
    with pytest.raises(ValueError, match="--localizer"):
        sweep.grid(["lab-3m-4"], ["nope"], [0], 3.0)
    with pytest.raises(ValueError, match="--duration"):
        sweep.grid(["lab-3m-4"], ["phd-lc"], [0], 0.0)
    points = sweep.grid(["a", "b"], ["phd-lc"], [0, 1, 2], 1.0)
    assert [(p.preset, p.seed) for p in points] == [(p, s) for p in "ab" for s in (0, 1, 2)]


def test_write_json_atomic_replaces_whole_file(tmp_path):
    path = tmp_path / "sub" / "x.json"
    write_json_atomically(path, {"a": 1})
    write_json_atomically(path, {"b": [1, 2]})
    assert json.loads(path.read_text()) == {"b": [1, 2]}
    assert os.listdir(path.parent) == ["x.json"]

    class Unserialisable:
        pass

    with pytest.raises(TypeError):
        write_json_atomically(path, {"c": Unserialisable()})
    assert json.loads(path.read_text()) == {"b": [1, 2]}  # the old file survives a failed write
    assert os.listdir(path.parent) == ["x.json"]


def test_evaluate_ray_writes_the_serial_runs_metrics_and_figures(local_ray, tmp_path, capsys):
    from swarm_phd import evaluate

    parser = argparse.ArgumentParser()
    evaluate.add_arguments(parser)
    common = ["--preset", "lab-3m-4", "--duration", "2", "--seeds", "3,4", "--localizer"]
    common.append("phd-lc,id-phd")  # a camera localizer and an identity-aware one
    args = parser.parse_args(["--ray", *common, "--out", str(tmp_path / "ray")])
    assert evaluate.run(args) == 0
    ray_printed = capsys.readouterr().out
    args = parser.parse_args([*common, "--out", str(tmp_path / "serial")])
    assert evaluate.run(args) == 0
    serial_printed = capsys.readouterr().out
    ray_run = json.loads((tmp_path / "ray" / "metrics.json").read_text())
    serial = json.loads((tmp_path / "serial" / "metrics.json").read_text())
    # Every number but the wall time, exactly: the seeds' tallies are added in the same order.
    ray_run.pop("wall_time_s"), serial.pop("wall_time_s")
    assert ray_run == serial
    assert serial["config"]["seeds"] == [3, 4] and "identity" in serial
    assert "at_camera_range" in serial["localizers"]["phd-lc"]

    def table(text: str) -> list[str]:  # the printed tables, without the machine's wall time
        return [line for line in text.splitlines() if "wall time" not in line]

    assert table(ray_printed) == table(serial_printed) and "| phd-lc (2 m) |" in serial_printed
    ray_files = sorted(p.name for p in (tmp_path / "ray").iterdir())
    assert ray_files == sorted(p.name for p in (tmp_path / "serial").iterdir())
    assert "metrics.json" in ray_files and any(name.endswith(".png") for name in ray_files)
    assert not (tmp_path / "ray" / "sweep.json").exists()


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    from swarm_core.atomic_files import atomic_write

    path = tmp_path / "model.zip"
    path.write_bytes(b"old")

    def failing(tmp):
        assert tmp.suffix == ".zip" and tmp.parent == path.parent  # same dir, same format
        tmp.write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, failing)
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]  # no temporary left


def test_atomic_write_gives_the_umask_permissions(tmp_path):
    import os

    from swarm_core.atomic_files import write_text_atomically

    mask = os.umask(0o022)
    try:
        path = write_text_atomically(tmp_path / "out.json", "{}")
        assert path.stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(mask)


def test_parse_json_object_names_the_flag_and_the_text():
    assert sweep.parse_json_object('{"localizer": "pmb"}', "--x") == {"localizer": "pmb"}
    assert sweep.parse_json_object(None, "--x") == {}
    for bad in ("[1, 2]", "nope", '"text"'):
        with pytest.raises(ValueError, match=r"--x must be a JSON object, got"):
            sweep.parse_json_object(bad, "--x")
