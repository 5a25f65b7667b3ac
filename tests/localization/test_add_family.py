"""docs/how-to/add-a-localizer-family.md: its example family, taken from the page, registers with
one line, follows the protocol and runs in the env."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from localization import PHDConfig
from localization.feed import SwarmFeed
from localization.protocol import Localizer
from localization.registry import LOCALIZERS, make_localizer

PAGE = Path(__file__).resolve().parents[2] / "docs" / "how-to" / "add-a-localizer-family.md"


@pytest.fixture(scope="module")
def family(tmp_path_factory):
    """The page's first python block, imported as a module (its kernel cached in a temporary
    directory); the family it registers is removed afterwards."""
    blocks = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.DOTALL)
    assert blocks, f"{PAGE} has no python block"
    path = tmp_path_factory.mktemp("family") / "last_scan.py"
    path.write_text(blocks[0])
    spec = importlib.util.spec_from_file_location("last_scan_family", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    yield module
    LOCALIZERS.pop("last-scan", None)
    sys.modules.pop(spec.name, None)


def test_a_lidar_call_leaves_its_detections_and_a_predict_moves_them(family):
    cfg = PHDConfig.perera2021()
    bank = make_localizer("last-scan", 3, cfg)
    assert isinstance(bank, Localizer) and isinstance(bank, family.LastScanBank)
    pts = np.array([[1.0, 0.5], [-2.0, 0.25]])
    bank.apply([[("lidar", pts, None)], [], [("lidar", np.empty((0, 2)), None)]])
    table = bank.table(0)
    np.testing.assert_array_equal(table[0], [1.0, 1.0])
    np.testing.assert_array_equal(table[1:3].T, pts)
    np.testing.assert_array_equal(table[3], [cfg.lidar.noise_var_m2] * 2)
    np.testing.assert_array_equal(table[4], [0.0, 0.0])
    assert bank.counts.tolist() == [2, 0, 0]
    # A sensor pose moves the detections into the filter's frame first.
    bank.apply([[], [("lidar", pts, None, np.array([0.5, 0.0, np.pi / 2]))], []])
    np.testing.assert_allclose(bank.table(1)[1:3].T, [[0.0, 1.0], [0.25, -2.0]], atol=1e-12)
    # Moving forward 0.5 m and turning left by pi / 2: m' = R(pi/2)^T (m - d).
    bank.apply([[("predict", np.array([0.5, 0.0, np.pi / 2]))], [], []])
    moved = bank.table(0)
    np.testing.assert_allclose(moved[1:3].T, [[0.5, -0.5], [0.25, 2.5]], atol=1e-12)
    np.testing.assert_allclose(
        moved[3], cfg.lidar.noise_var_m2 + cfg.prediction.process_noise_std_m**2
    )
    np.testing.assert_array_equal(moved[0], [1.0, 1.0])
    positions, weights = bank.estimate(0)
    assert positions.shape == (2, 2) and weights.tolist() == [1.0, 1.0]


def test_a_bad_call_is_refused_before_any_change(family):
    bank = make_localizer("last-scan", 2)
    bank.apply([[("lidar", np.array([[1.0, 0.5]]), None)], []])
    before = bank.padded_tables()[0].copy()
    with pytest.raises(ValueError, match=r"calls\[1\].*points"):
        bank.apply([[("predict", np.zeros(3))], [("lidar", np.array([[np.nan, 0.0]]), None)]])
    np.testing.assert_array_equal(bank.padded_tables()[0], before)
    with pytest.raises(ValueError, match="no reference filter"):
        bank.to_filter(0)


def test_it_runs_in_the_env(family):
    from swarm_env import parallel_env

    env = parallel_env("lab-3m-4", localizer="last-scan", max_steps=20)
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(8):
        obs, *_ = env.step({a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents})
        table, counts = env.localizer.padded_tables()
        assert np.isfinite(table).all() and np.all(table[0][table[0] != 0] == 1.0)
        seen += int(counts.sum())
    assert env.localizer.name == "last-scan" and seen > 0
    assert all(np.isfinite(o).all() for o in obs.values())
    env.localizer.reset()
    assert env.localizer.padded_tables()[1].sum() == 0
    env.localizer.step(SwarmFeed.empty(env.localizer.n_robots))
    env.close()
