"""What the filters keep of a lidar scan (:mod:`localization.scan_memory`): the profile against
hand-derived cases, the compiled version against the numpy reference, the scanner pose's motion,
and the bank's scan memory against independent reference filters."""

from __future__ import annotations

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.feed import scan_profile_of
from localization.registry import run_calls
from localization.scan_memory import (
    BIN_WIDTH_RAD,
    N_BINS,
    move_scan_pose,
    profile_into,
    scan_profile,
)

HOUSING = 0.0325
DECOY = 0.06  # the arena's red decoys (radius, m)
ANGLES = -np.pi + np.arange(N_BINS) * BIN_WIDTH_RAD  # the simulated X4's beams


def cast(angles: np.ndarray, circles: np.ndarray, wall_m: float) -> np.ndarray:
    """Ranges of thin beams from the origin against circles ``(K, 3)`` ``[x, y, radius]`` and a
    round wall of radius ``wall_m`` (0 beyond it: no wall)."""
    ux, uy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    cx, cy, rad = circles[:, 0], circles[:, 1], circles[:, 2]
    along = ux * cx + uy * cy
    miss2 = (cx**2 + cy**2) - along**2
    hit = (along > 0) & (miss2 <= rad**2)
    dist = np.where(hit, along - np.sqrt(np.maximum(rad**2 - miss2, 0.0)), np.inf)
    nearest = dist.min(axis=1, initial=np.inf)
    out = np.minimum(nearest, wall_m if wall_m > 0 else np.inf)
    return np.where(np.isfinite(out), out, 0.0)


# ---------------------------------------------------------------------- profile
def test_profile_bins_the_farthest_valid_return_and_marks_unknowns():
    angles = np.array([0.0, 0.001, 0.5 * BIN_WIDTH_RAD + 1e-6, -np.pi, np.pi - 1e-9, 1.0, 1.0])
    ranges = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 2.0, 0.0])
    profile = scan_profile(angles, ranges)
    centre = N_BINS // 2  # bearing 0
    assert profile[centre] == 2.0  # two beams: the farther
    assert profile[centre + 1] == 3.0  # rounds up into the next bin
    assert profile[0] == 5.0  # -pi and just below +pi are the same bin
    assert profile[int(np.floor((1.0 + np.pi) / BIN_WIDTH_RAD + 0.5))] == 0.0  # one invalid
    assert np.count_nonzero(profile) == 3  # every other bin is empty: unknown


@pytest.mark.parametrize("n_beams", [720, 1000, 360, 97])
def test_compiled_profile_equals_the_reference(n_beams):
    rng = np.random.default_rng(n_beams)
    angles = np.sort(rng.uniform(-np.pi, np.pi, n_beams))
    ranges = rng.uniform(0.1, 8.0, n_beams)
    ranges[rng.random(n_beams) < 0.1] = 0.0
    ranges[rng.random(n_beams) < 0.02] = np.inf
    ranges[rng.random(n_beams) < 0.02] = np.nan
    out = np.empty(N_BINS)
    profile_into(out, angles, ranges)
    assert np.array_equal(out, scan_profile(angles, ranges))


def test_the_scanner_pose_moves_with_the_frame():
    # the scan was taken 0.5 m ahead, looking left; the frame then moved 0.2 m forward
    pose = move_scan_pose(np.array([0.5, 0.0, np.pi / 2]), np.array([0.2, 0.0, 0.0]))
    assert np.allclose(pose, [0.3, 0.0, np.pi / 2])
    rotated = move_scan_pose(pose, np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(rotated, [0.0, -0.3, 0.0])


# ---------------------------------------------------------------------- the bank
def scanned_calls(rng: np.random.Generator, n_robots: int, steps: int, decoys: int = 0):
    """Random per-robot call lists whose lidar calls carry scans of each robot's targets (and of
    clutter that the scans then refute), with and without sensor poses and profiles; with
    ``decoys``, that many red-decoy-sized cylinders per robot stand in every scan and the
    camera frames see them too."""
    targets = rng.uniform(-2.5, 2.5, size=(n_robots, 6, 2))
    decoy_xy = rng.uniform(-3.0, 3.0, size=(n_robots, decoys, 2)) if decoys else None
    calls = [[] for _ in range(n_robots)]
    for r in range(n_robots):
        seen_by_camera = targets[r] if decoys == 0 else np.concatenate([targets[r], decoy_xy[r]])
        for _ in range(steps):
            kind = rng.choice(["predict", "lidar", "camera"], p=[0.3, 0.35, 0.35])
            pose = rng.normal(0.0, [0.03, 0.01, 0.1]) if rng.random() < 0.5 else None
            if kind == "predict":
                calls[r].append(("predict", rng.normal(0.0, [0.03, 0.01, 0.05])))
            elif kind == "lidar":
                seen = targets[r, rng.random(6) < 0.7]
                pts = seen + rng.normal(0.0, 0.02, seen.shape)
                if rng.random() < 0.4:  # clutter the scan will refute later
                    pts = np.concatenate([pts, rng.uniform(-2.0, 2.0, (2, 2))])
                circles = np.column_stack([seen, np.full(len(seen), HOUSING)])
                if decoys:
                    circles = np.concatenate(
                        [circles, np.column_stack([decoy_xy[r], np.full(decoys, DECOY)])]
                    )
                ranges = cast(ANGLES, circles, wall_m=float(rng.uniform(2.0, 3.5)))
                ranges[rng.random(N_BINS) < 0.03] = 0.0
                profile = scan_profile(ANGLES, ranges) if rng.random() < 0.9 else None
                calls[r].append(("lidar", pts, None, pose, profile))
            else:
                tg = seen_by_camera[rng.integers(0, len(seen_by_camera), int(rng.integers(0, 8)))]
                brg = np.arctan2(tg[:, 1], tg[:, 0]) + rng.normal(0.0, 0.03, len(tg))
                calls[r].append(("camera", brg, pose))
    return calls


SCAN_CONFIGS = {
    # the wide objects' camera clutter reads the scan memory
    "simulator": PHDConfig().replace(camera={"noise_std_deg": 3.0}),
    "camera-ray": PHDConfig().replace(births={"camera": "ray"}, camera={"noise_std_deg": 3.0}),
}


@pytest.mark.parametrize("name", sorted(SCAN_CONFIGS))
def test_bank_matches_reference_filters_with_scans(name):
    config = SCAN_CONFIGS[name]
    rng = np.random.default_rng(11)
    n_robots = 4
    calls = scanned_calls(rng, n_robots, 70)
    filters = [RobotCentricPHD(config) for _ in range(n_robots)]
    for f, seq in zip(filters, calls, strict=True):
        run_calls(f, seq)
    bank = PHDBank(config, n_robots)
    bank.apply(calls)
    for r, f in enumerate(filters):
        a, b = f.table, bank.table(r)
        order_a, order_b = np.lexsort(a[::-1]), np.lexsort(b[::-1])
        assert a.shape == b.shape, (name, r, a.shape, b.shape)
        assert np.allclose(a[:, order_a], b[:, order_b], rtol=0, atol=1e-10), (name, r)
        state = bank.to_filter(r).__getstate__()["scan_memory"]
        assert np.allclose(state, f.__getstate__()["scan_memory"], rtol=0, atol=1e-12)
    assert max(len(f) for f in filters) > 0


def test_bad_scan_profile_is_refused_before_any_change():
    bank = PHDBank(PHDConfig(), 2)
    before = bank.__getstate__()["scan_memory"].copy()
    for bad, word in (
        (np.zeros(10), "shape"),
        (np.full(N_BINS, -1.0), ">= 0"),
        (np.full(N_BINS, np.nan), "finite"),
    ):
        with pytest.raises(ValueError, match="scan_profile") as raised:
            bank.apply([[("lidar", np.zeros((0, 2)), None, None, bad)], []])
        assert word in str(raised.value)
    assert np.array_equal(bank.__getstate__()["scan_memory"], before)
    with pytest.raises(ValueError, match="scan_profile"):
        RobotCentricPHD(PHDConfig()).update_lidar(np.zeros((0, 2)), scan_profile=np.zeros(3))


def test_a_record_whose_angles_and_ranges_differ_is_refused():
    """A driver that reports 720 angles and 719 ranges: named, not read out of bounds."""
    from swarm_core.records import LidarRecord

    record = LidarRecord(0.5, ANGLES, np.ones(N_BINS - 1), np.ones(N_BINS - 1), [], [])
    with pytest.raises(ValueError, match=r"angles_rad and ranges_m .* \(720,\) and \(719,\)"):
        scan_profile_of(record)
