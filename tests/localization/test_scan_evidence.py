"""The lidar scan's negative information (:mod:`localization.scan_evidence`): the profile and the
per-component factors against hand-derived cases and the simulator's ground truth, the compiled
versions against the numpy reference, and the bank against independent reference filters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.feed import scan_profile_of
from localization.registry import run_calls
from localization.scan_evidence import (
    BIN_WIDTH_RAD,
    N_BINS,
    move_scan_pose,
    profile_into,
    scan_factors,
    scan_factors_into,
    scan_profile,
)
from swarm_env.config import SIMULATOR_PHD

HOUSING = 0.0325
DECOY = 0.06  # the arena's red decoys (radius, m)
ANGLES = -np.pi + np.arange(N_BINS) * BIN_WIDTH_RAD  # the simulated X4's beams
PARAMS = dict(
    target_radius_m=HOUSING,
    range_std_m=0.01,
    range_std_quadratic_per_m=0.0025,
    footprint_rad=math.radians(0.5),
    margin_sigmas=3.0,
    min_range_m=0.1,
)


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


def component(x: float, y: float, var: float = 1e-4, w: float = 1.0) -> np.ndarray:
    return np.array([[w], [x], [y], [var], [0.0], [var]])


def factors(table, ranges):
    return scan_factors(table, np.zeros(3), scan_profile(ANGLES, ranges), **PARAMS)


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


# ---------------------------------------------------------------------- hand-derived cases
@pytest.mark.parametrize("r", [0.5, 1.0, 2.0, 3.0, 3.5])
def test_a_teammate_on_the_scan_is_neither_hidden_nor_refuted(r):
    ranges = cast(ANGLES, np.array([[r, 0.0, HOUSING]]), wall_m=r + 1.5)
    visible, free = factors(component(r, 0.0), ranges)
    assert visible[0] > 0.998 and free[0] < 1e-4


@pytest.mark.parametrize("r", [0.5, 1.0, 2.0, 3.0, 3.7])
def test_free_space_refutes_a_component_the_beams_passed(r):
    ranges = cast(ANGLES, np.zeros((0, 3)), wall_m=r + 0.5)
    visible, free = factors(component(r, 0.0), ranges)
    assert visible[0] == pytest.approx(1.0) and free[0] > 0.999


def test_refutation_needs_every_beam_on_the_housing_to_pass():
    # one of the central bins stops short (something thin in front): no refutation
    ranges = cast(ANGLES, np.zeros((0, 3)), wall_m=2.5)
    ranges[N_BINS // 2] = 0.9
    assert factors(component(1.5, 0.0), ranges)[1][0] == 0.0


def test_beyond_the_scanners_resolution_there_is_no_free_space_evidence():
    # beyond R / sin(0.25 deg) = 7.4 m a housing is narrower than one 0.5 deg footprint
    ranges = cast(ANGLES, np.zeros((0, 3)), wall_m=9.5)
    assert factors(component(7.0, 0.0, var=1e-8), ranges)[1][0] > 0.999
    assert factors(component(7.6, 0.0, var=1e-8), ranges)[1][0] == 0.0
    # beyond 3.7 m a housing fits between two bins: with a 1 cm spread (3 sigmas = 0.25 deg
    # at 7 m) it may sit where no bin is whole on it, so the scan cannot refute it; at 3.5 m
    # every bearing has such a bin
    assert factors(component(7.0, 0.0, var=1e-4), ranges)[1][0] == 0.0
    assert factors(component(3.5, 0.0, var=1e-4), ranges)[1][0] > 0.999


@pytest.mark.parametrize("r", [1.0, 2.0, 3.0])
def test_a_teammate_off_the_mean_by_its_spread_is_not_refuted(r):
    """The housing may be anywhere within k sigmas tangentially: a 3 cm-std component whose
    teammate is 7 cm (2.3 sigmas) to the side is not refuted, though the bins at its mean
    are free; the same scan does refute a component with a 2 mm std there."""
    beside = np.array([[r, 0.07, HOUSING]])
    ranges = cast(ANGLES, beside, wall_m=4.0)
    mean_bins = np.abs(ANGLES) < math.asin(HOUSING / r) - math.radians(0.25)
    assert (ranges[mean_bins] > r).all()  # the bins at the mean passed beyond it
    visible, free = factors(component(r, 0.0, var=0.03**2), ranges)
    assert free[0] < 0.01 and visible[0] > 0.99
    assert factors(component(r, 0.0, var=0.002**2), ranges)[1][0] > 0.99


def test_a_component_behind_the_first_surface_is_hidden():
    ranges = cast(ANGLES, np.zeros((0, 3)), wall_m=2.0)
    visible, free = factors(component(2.8, 0.0, var=0.01), ranges)
    # (d + R - r + k sigma_r(d)) / s with s = sqrt(0.01 + sigma_r(d)^2): far below 0 (every
    # bearing of the spread sees the same wall)
    noise = 0.01 + 0.0025 * 2.0**2
    s = math.sqrt(0.01 + noise**2)
    expected = 0.5 * math.erfc(-((2.0 + HOUSING - 2.8 + 3.0 * noise) / s) / math.sqrt(2.0))
    assert visible[0] == pytest.approx(expected, rel=1e-9) and visible[0] < 0.001
    assert free[0] < 1e-12


@pytest.mark.parametrize("behind", [0.1, 0.3, 0.6])
def test_the_visibility_is_the_pointwise_model_averaged_over_the_component(behind):
    """``V`` is ``E[Phi((d_max(x) + R - |x|) / sigma_r(d) + k)]`` over ``x ~ N(m, P)``, with
    ``d_max(x)`` the farthest return across a housing at ``x``: checked by Monte Carlo for a
    component behind a red-decoy-sized occluder, which hides only part of its bearing spread."""
    from scipy.special import ndtr

    occluder = np.array([[1.0, 0.0, 0.06]])
    ranges = cast(ANGLES, occluder, wall_m=2.6)
    profile = scan_profile(ANGLES, ranges)
    r = 1.0 + behind
    sd_r, sd_t = 0.08, 0.04
    visible = factors(np.array([[1.0], [r], [0.0], [sd_r**2], [0.0], [sd_t**2]]), ranges)[0][0]
    rng = np.random.default_rng(5)
    x = rng.normal([r, 0.0], [sd_r, sd_t], size=(20_000, 2))
    rho = np.hypot(x[:, 0], x[:, 1])
    centre = (np.arctan2(x[:, 1], x[:, 0]) + math.pi) / BIN_WIDTH_RAD
    alpha = np.arcsin(HOUSING / rho) / BIN_WIDTH_RAD
    lo, hi = np.floor(centre - alpha + 0.5).astype(int), np.floor(centre + alpha + 0.5).astype(int)
    windows = zip(lo, hi, strict=True)
    d_max = np.array([profile[np.arange(a, b + 1) % N_BINS].max() for a, b in windows])
    noise = 0.01 + 0.0025 * d_max**2
    expected = ndtr((d_max + HOUSING - rho) / noise + 3.0).mean()
    assert 0.02 < expected < 0.98  # partly hidden: the spread matters
    assert visible == pytest.approx(expected, abs=0.04), (visible, expected)


def test_unknown_bins_give_no_evidence():
    ranges = np.zeros(N_BINS)  # nothing returned: open space, blind sector or nulls
    visible, free = factors(component(1.0, 0.0), ranges)
    assert visible[0] == 1.0 and free[0] == 0.0


def test_the_scanner_pose_moves_with_the_frame():
    # the scan was taken 0.5 m ahead, looking left; the frame then moved 0.2 m forward
    pose = move_scan_pose(np.array([0.5, 0.0, np.pi / 2]), np.array([0.2, 0.0, 0.0]))
    assert np.allclose(pose, [0.3, 0.0, np.pi / 2])
    # a free beam straight ahead of the scanner is the +y axis of the frame
    ranges = cast(ANGLES, np.zeros((0, 3)), wall_m=3.0)
    profile = scan_profile(ANGLES, ranges)
    _, free = scan_factors(component(0.3, 1.5), pose, profile, **PARAMS)
    assert free[0] > 0.999
    _, free = scan_factors(component(1.5, 0.0), pose, profile, **PARAMS)
    assert free[0] > 0.999  # every direction is free up to 3 m here
    rotated = move_scan_pose(pose, np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(rotated, [0.0, -0.3, 0.0])


def test_compiled_factors_equal_the_reference():
    rng = np.random.default_rng(3)
    circles = np.column_stack([rng.uniform(-3, 3, (12, 2)), np.full(12, HOUSING)])
    ranges = cast(ANGLES, circles, wall_m=3.2)
    ranges[rng.random(N_BINS) < 0.05] = 0.0
    profile = scan_profile(ANGLES, ranges)
    pose = np.array([0.05, -0.02, 0.1])
    n = 300
    table = np.empty((6, n))
    table[0] = rng.uniform(0.1, 1.0, n)
    table[1:3] = np.concatenate([circles[:, :2].T, rng.uniform(-4, 4, (2, n - 12))], axis=1)
    a = rng.uniform(1e-6, 2e-3, n)
    b = rng.uniform(1e-6, 2e-3, n)
    # the edge cases: very wide (the spread's clamp), a point mass, inside min_range
    a[12:20], b[12:20] = rng.uniform(0.5, 20.0, 8), rng.uniform(0.5, 20.0, 8)
    a[20:24], b[20:24] = 0.0, 0.0
    table[1:3, 24:28] = pose[:2, None] + rng.uniform(-0.05, 0.05, (2, 4))
    table[3], table[5] = a, b
    table[4] = rng.uniform(-0.5, 0.5, n) * np.sqrt(a * b)
    memory = np.concatenate([[1.0], pose + [0.3, -0.1, 0.0], profile])
    ref = scan_factors(table, pose, profile, **PARAMS)
    visible, free = np.empty(n), np.empty(n)
    # the memory's pose read from a view shifted by (0.3, -0.1)
    scan_factors_into(visible, free, table, n, memory, 0.3, -0.1, *PARAMS.values())
    assert np.allclose(visible, ref[0], rtol=0, atol=1e-12)
    assert np.allclose(free, ref[1], rtol=0, atol=1e-12)
    assert 0.05 < (ref[1] > 0.5).mean() < 0.95 and (ref[0] < 0.5).any()  # both exercised
    assert (ref[0][24:28] == 1.0).all() and (ref[1][24:28] == 0.0).all()  # inside min_range


# ---------------------------------------------------------------------- the simulator
def test_no_teammate_is_refuted_at_its_true_position():
    """On the simulator's scans, from observers that neither turned nor moved 1 cm during the
    step (the truth is the step's end, the scan its own instant; collisions turn robots that
    are told to drive straight): every teammate within 3 m that also held still is, at its
    true position (with a tracked teammate's 3 cm spread), not refuted, and points halfway
    along valid beams are. A turning observer is not checked here: the truth is only known
    at the step's end, which it has already turned away from (the scan itself is a snapshot
    of one substep)."""
    from swarm_core.world import relative_positions
    from swarm_env import parallel_env

    env = parallel_env(preset="lab-3m-4", task="formation", max_steps=80)
    rng = np.random.default_rng(0)
    checked = refuted_points = 0
    for seed in (0, 1):
        env.reset(seed=seed)
        before = env.last_world_step.truth.poses.copy()
        for _ in range(80):
            env.step({a: np.array([rng.uniform(0.0, 0.1), 0.0]) for a in env.agents})
            step = env.last_world_step
            poses = step.truth.poses[: len(env.possible_agents)]
            still = (np.hypot(*(poses[:, :2] - before[: len(poses), :2]).T) < 0.01) & (
                np.abs(poses[:, 2] - before[: len(poses), 2]) < 0.002
            )
            before = step.truth.poses.copy()
            rel = relative_positions(poses, poses[:, :2])
            for i, agent in enumerate(env.possible_agents):
                if not still[i]:
                    continue
                for record in step.measurements[agent].lidar:
                    profile = scan_profile_of(record)
                    mates = [j for j in range(len(poses)) if j != i and still[j]]
                    others = rel[i, mates]
                    table = np.zeros((6, len(others)))
                    table[0], table[1:3], table[3], table[5] = 1.0, others.T, 9e-4, 9e-4
                    _, free = scan_factors(table, np.zeros(3), profile, **PARAMS)
                    in_view = np.hypot(*others.T) < 3.0
                    assert (free[in_view] < 0.05).all(), (seed, agent, free[in_view])
                    checked += int(in_view.sum())
                    ok = record.ranges_m > 0.5
                    half = 0.5 * record.ranges_m[ok]
                    mid = np.zeros((6, int(ok.sum())))
                    mid[0], mid[3], mid[5] = 1.0, 1e-4, 1e-4
                    mid[1] = half * np.cos(record.angles_rad[ok])
                    mid[2] = half * np.sin(record.angles_rad[ok])
                    free_mid = scan_factors(mid, np.zeros(3), profile, **PARAMS)[1]
                    refuted_points += int((free_mid > 0.99).sum())
    env.close()
    assert checked > 100 and refuted_points > 10_000, (checked, refuted_points)


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


ON = dataclasses.replace(SIMULATOR_PHD, scan_evidence=True)
SCAN_CONFIGS = {
    "simulator": dataclasses.replace(ON, camera_noise_std_deg=3.0),
    "fixed-birth": PHDConfig(scan_evidence=True),
    "camera-ray": PHDConfig(birth="measurement", camera_birth="ray", scan_evidence=True),
    "off": dataclasses.replace(SIMULATOR_PHD, scan_evidence=False, camera_noise_std_deg=3.0),
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


def test_the_scan_evidence_removes_refuted_clutter():
    """The same calls with and without the evidence: clutter tracks in free space lose weight,
    the targets' tracks keep theirs."""
    totals = {}
    for on in (False, True):
        config = dataclasses.replace(ON, scan_evidence=on)
        rng = np.random.default_rng(4)
        calls = scanned_calls(rng, 3, 80)
        bank = PHDBank(config, 3)
        bank.apply(calls)
        totals[on] = sum(bank.table(r)[0].sum() for r in range(3))
    assert totals[True] < totals[False]


def test_bad_scan_profile_is_refused_before_any_change():
    bank = PHDBank(ON, 2)
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
        RobotCentricPHD(ON).update_lidar(np.zeros((0, 2)), scan_profile=np.zeros(3))


def test_a_record_whose_angles_and_ranges_differ_is_refused():
    """A driver that reports 720 angles and 719 ranges: named, not read out of bounds."""
    from swarm_core.records import LidarRecord

    record = LidarRecord(0.5, ANGLES, np.ones(N_BINS - 1), np.ones(N_BINS - 1), [], [])
    with pytest.raises(ValueError, match=r"angles_rad and ranges_m .* \(720,\) and \(719,\)"):
        scan_profile_of(record)
