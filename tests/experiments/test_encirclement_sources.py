"""``experiments/encirclement_sources.py``: the encirclement task under each intruder source,
end to end on short runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from experiments.encirclement_sources import setting_params

ROOT = Path(__file__).resolve().parents[2]


def run_script(*args: str) -> subprocess.CompletedProcess:
    """``python -m experiments.encirclement_sources ARGS`` from the repository root."""
    return subprocess.run(
        [sys.executable, "-m", "experiments.encirclement_sources", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )


def test_scores_each_policy_and_setting(tmp_path):
    """``experiments/encirclement_sources.py`` end to end on a 3 s run: one entry per policy and
    intruder setting, mean and std over the seeds, and the task filter's track for
    ``particle+filter``; a model path that does not exist is refused."""
    args = ["--duration", "3", "--seeds", "0-1", "--out", str(tmp_path)]
    run = run_script(*args, "--sources", "beacon,particle+filter")
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads((tmp_path / "encirclement_sources.json").read_text())
    assert result["config"]["seeds"] == [0, 1]
    scored = result["results"]["scripted:encirclement"]
    assert set(scored) == {"beacon", "particle+filter"}
    for setting in scored.values():
        assert len(setting["radius_error_m"]["per_seed"]) == 2
        assert setting["radius_error_m"]["std"] >= 0.0
    assert "track_on_intruder" in scored["particle+filter"]
    assert "track_on_intruder" not in scored["beacon"]
    assert (tmp_path / "encirclement_sources.png").is_file()
    bad = run_script(*args, "--policies", str(tmp_path / "missing.zip"))
    assert bad.returncode != 0 and "does not exist" in bad.stderr


# ------------------------------------------------ range-only sensing and the trilateration start


def test_range_only_settings_and_starts(tmp_path):
    """The range-only settings' task parameters, and ``--particle-starts`` keying the results
    ``SETTING/START`` (a 2 s run, one seed)."""
    assert setting_params("particle-range") == {
        "intruder_source": "particle",
        "intruder_sensing": "range",
    }
    assert setting_params("particle-range+filter") == {
        "intruder_source": "particle",
        "intruder_features": "filter",
        "intruder_sensing": "range",
    }
    assert setting_params("particle+filter") == {
        "intruder_source": "particle",
        "intruder_features": "filter",
    }
    assert setting_params("estimate") == {"intruder_source": "estimate"}
    args = ["--duration", "2", "--seeds", "0", "--sources", "particle-range"]
    args += ["--out", str(tmp_path)]
    run = run_script(*args, "--particle-starts", "uniform,trilateration")
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads((tmp_path / "encirclement_sources.json").read_text())
    assert set(result["results"]["scripted:encirclement"]) == {
        "particle-range/uniform",
        "particle-range/trilateration",
    }
    bad = run_script(*args, "--particle-starts", "gps")
    assert bad.returncode != 0 and "particle-starts" in bad.stderr
