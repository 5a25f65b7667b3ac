"""The camera clutter the lidar places (:mod:`localization.object_clutter`): wide objects found
where they are, the density against hand-derived values, compiled = reference, and the bank
against independent reference filters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.mixture import GaussianMixture
from localization.object_clutter import (
    clutter_density,
    clutter_density_into,
    wide_objects,
    wide_objects_into,
)
from localization.pmb import PMBBank, PMBConfig, RobotCentricPMB
from localization.registry import run_calls
from localization.scan_memory import (
    BIN_WIDTH_RAD,
    MEMORY_LEN,
    N_BINS,
    WIDE_OBJECTS_AT,
    scan_profile,
)
from swarm_env.config import SIMULATOR_PHD

from .test_scan_memory import ANGLES, DECOY, HOUSING, cast, scanned_calls


def memory_of(ranges: np.ndarray, pose=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A scan memory of ``ranges`` taken from ``pose``, with its wide objects."""
    memory = np.zeros(MEMORY_LEN)
    memory[0] = 1.0
    memory[1:4] = pose
    memory[4:WIDE_OBJECTS_AT] = scan_profile(ANGLES, ranges)
    objects = wide_objects(memory[4:WIDE_OBJECTS_AT])
    memory[WIDE_OBJECTS_AT] = objects.shape[0]
    memory[WIDE_OBJECTS_AT + 1 : WIDE_OBJECTS_AT + 1 + objects.size] = objects.ravel()
    return memory


@pytest.mark.parametrize("r", [0.8, 1.5, 2.5, 3.5])
def test_a_decoy_is_a_wide_object_and_a_housing_is_not(r):
    bearing = 0.7
    circles = np.array(
        [
            [r * math.cos(bearing), r * math.sin(bearing), DECOY],
            [1.2 * math.cos(-1.0), 1.2 * math.sin(-1.0), HOUSING],
        ]
    )
    objects = wide_objects(scan_profile(ANGLES, cast(ANGLES, circles, wall_m=5.0)))
    assert objects.shape == (1, 3)  # the decoy only: not the housing, not the wall
    assert math.atan2(objects[0, 1], objects[0, 0]) == pytest.approx(bearing, abs=0.005)
    assert math.hypot(objects[0, 0], objects[0, 1]) == pytest.approx(r, abs=0.03)
    # The half-width is the returns' end-to-end width over two: the chord between the first
    # and last returns, short of the object's edges by up to a beam on each side.
    assert math.asin(DECOY / r) - BIN_WIDTH_RAD <= objects[0, 2] <= math.asin(DECOY / r)


def test_the_density_adds_lambda_blobs_per_object_around_its_bearing():
    circles = np.array([[2.0, 0.0, DECOY], [0.0, -1.5, DECOY]])
    memory = memory_of(cast(ANGLES, circles, wall_m=0.0))
    assert memory[WIDE_OBJECTS_AT] == 2
    grid = np.linspace(-math.pi, math.pi, 200_001)[:-1]
    density = clutter_density(grid, memory, np.zeros(2), 1.2, 0.72, 0.28, 1e-6)
    step = grid[1] - grid[0]
    # The uniform part over the circle, plus 0.72 blobs per object.
    assert density.sum() * step == pytest.approx(1.2 * 2 * math.pi + 2 * 0.72, rel=1e-6)
    # Its peak, hand-derived: 0.72 / sqrt(2 pi var), var = (0.28 alpha)^2 + s0^2.
    alpha = memory[WIDE_OBJECTS_AT + 6]  # the second by bearing: the one at (2, 0)
    peak = 0.72 / math.sqrt(2 * math.pi * ((0.28 * alpha) ** 2 + 1e-6))
    at = clutter_density(np.array([0.0]), memory, np.zeros(2), 1.2, 0.72, 0.28, 1e-6)
    assert at[0] == pytest.approx(1.2 + peak, rel=1e-3)
    # Far from both objects only the uniform part is left; without a scan, only it.
    far = clutter_density(np.array([2.5]), memory, np.zeros(2), 1.2, 0.72, 0.28, 1e-6)
    assert far[0] == pytest.approx(1.2, abs=1e-12)
    empty = clutter_density(np.array([0.0]), np.zeros(MEMORY_LEN), np.zeros(2), 1.2, 0.72, 0.28, 0)
    assert empty[0] == 1.2


def test_the_object_is_seen_from_where_the_scan_and_the_camera_are():
    # Scanned from (0.5, 0, +90 deg): the decoy 2 m ahead of the scanner is at (0.5, 2) in the
    # filter's frame; a camera at (0.5, 0) sees it at +90 deg, one at (0, 0) at atan2(2, 0.5).
    memory = memory_of(cast(ANGLES, np.array([[2.0, 0.0, DECOY]]), 0.0), (0.5, 0.0, math.pi / 2))
    for offset in (np.array([0.5, 0.0]), np.zeros(2)):
        expected = math.atan2(2.0 - offset[1], 0.5 - offset[0])
        grid = expected + np.linspace(-0.2, 0.2, 4001)
        density = clutter_density(grid, memory, offset, 0.0, 1.0, 0.28, 1e-6)
        assert grid[np.argmax(density)] == pytest.approx(expected, abs=2e-3)


def test_compiled_equals_the_reference():
    rng = np.random.default_rng(5)
    for _ in range(30):
        k = int(rng.integers(0, 6))
        circles = np.column_stack(
            [rng.uniform(-3.0, 3.0, (k, 2)), rng.choice([HOUSING, DECOY, 0.1], size=k)]
        )
        ranges = cast(ANGLES, circles, wall_m=float(rng.uniform(0.0, 4.0)))
        ranges[rng.random(N_BINS) < 0.02] = 0.0
        memory = memory_of(ranges, rng.normal(0.0, [0.2, 0.2, 1.0]))
        compiled = memory.copy()
        compiled[WIDE_OBJECTS_AT:] = -1.0
        wide_objects_into(compiled)
        count = int(memory[WIDE_OBJECTS_AT])
        assert compiled[WIDE_OBJECTS_AT] == count
        np.testing.assert_allclose(
            compiled[WIDE_OBJECTS_AT + 1 : WIDE_OBJECTS_AT + 1 + 3 * count],
            memory[WIDE_OBJECTS_AT + 1 : WIDE_OBJECTS_AT + 1 + 3 * count],
            rtol=0,
            atol=1e-12,
        )
        brg = rng.uniform(-math.pi, math.pi, 40)
        ox, oy = rng.normal(0.0, 0.05, 2)
        ref = clutter_density(brg, memory, np.array([ox, oy]), 0.9, 0.72, 0.28, 2e-7)
        out = np.full(40, 0.9)
        clutter_density_into(out, brg, memory, ox, oy, 0.72, 0.28, 2e-7)
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)


def _phd_on_decoy(phd, mixture, profile):
    f = RobotCentricPHD(phd)
    f.update_lidar(np.zeros((0, 2)), scan_profile=profile)
    f.set_mixture(mixture)
    return f


def _pmb_on_decoy(phd, mixture, profile):
    f = RobotCentricPMB(PMBConfig(phd=phd))
    f.set_state(mixture)
    f.update_lidar(np.zeros((0, 2)), scan_profile=profile)
    return f


@pytest.mark.parametrize("on_decoy", [_phd_on_decoy, _pmb_on_decoy], ids=["gm-phd", "pmb"])
def test_a_camera_bearing_on_a_decoy_no_longer_confirms_an_estimate_there(on_decoy):
    """A component (GM-PHD) or track (PMB) of weight 0.3 on a red decoy, after a scan that
    shows the decoy as a wide object: under the uniform clutter the decoy's camera blob
    confirms it (the weight after one frame, ``P_d w g / (kappa_h + P_d w g)``, rises); with
    the decoy's own clutter the density at the bearing explains the blob instead."""
    decoy = np.array([1.8, 0.6])
    ranges = cast(ANGLES, np.array([[*decoy, DECOY]]), wall_m=0.0)
    brg = np.array([math.atan2(decoy[1], decoy[0])])
    mixture = GaussianMixture(np.array([0.3]), decoy[None, :], 1e-3 * np.eye(2)[None])
    weights = {}
    for per_object in (0.0, 0.72):
        phd = SIMULATOR_PHD.replace(camera={"clutter_per_wide_object": per_object})
        f = on_decoy(phd, mixture, scan_profile(ANGLES, ranges))
        f.update_camera(brg)
        weights[per_object] = f.table[0].sum()
    assert weights[0.0] > 0.3
    assert weights[0.72] < 0.5 * weights[0.0]


@pytest.mark.parametrize(
    "config",
    [
        SIMULATOR_PHD.replace(camera={"clutter_per_wide_object": 0.72}),
        PHDConfig.perera2021().replace(
            births={"model": "measurement", "camera": "ray"},
            camera={"clutter_per_wide_object": 2.0},
        ),
    ],
    ids=["simulator", "camera-ray"],
)
def test_bank_matches_reference_filters(config):
    rng = np.random.default_rng(3)
    n_robots = 4
    calls = scanned_calls(rng, n_robots, 70, decoys=2)
    filters = [RobotCentricPHD(config) for _ in range(n_robots)]
    for f, seq in zip(filters, calls, strict=True):
        run_calls(f, seq)
    bank = PHDBank(config, n_robots)
    assert bank.reads_scans
    bank.apply(calls)
    found = []
    for r, f in enumerate(filters):
        a, b = f.table, bank.table(r)
        assert a.shape == b.shape, (r, a.shape, b.shape)
        order_a, order_b = np.lexsort(a[::-1]), np.lexsort(b[::-1])
        np.testing.assert_allclose(a[:, order_a], b[:, order_b], rtol=0, atol=1e-10)
        memory = bank.to_filter(r).__getstate__()["scan_memory"]
        np.testing.assert_allclose(memory, f.__getstate__()["scan_memory"], rtol=0, atol=1e-12)
        found.append(memory[WIDE_OBJECTS_AT])
    assert max(len(f) for f in filters) > 0
    assert max(found) > 0  # the decoys were found: the density was exercised


def test_a_memory_saved_before_the_wide_objects_loads_without_them():
    config = SIMULATOR_PHD.replace(camera={"clutter_per_wide_object": 0.72})
    f = RobotCentricPHD(config)
    state = f.__getstate__()
    state["scan_memory"] = np.ones(WIDE_OBJECTS_AT)
    f.__setstate__(state)
    memory = f.__getstate__()["scan_memory"]
    assert memory.shape == (MEMORY_LEN,) and memory[WIDE_OBJECTS_AT:].sum() == 0.0
    state["scan_memory"] = np.ones(7)
    with pytest.raises(ValueError, match="scan_memory"):
        f.__setstate__(state)


def test_only_a_filter_with_a_camera_keeps_the_scan_for_the_objects():
    assert SIMULATOR_PHD.models_wide_objects and SIMULATOR_PHD.reads_scans
    lidar_only = dataclasses.replace(SIMULATOR_PHD, mode="lidar-only")
    assert not lidar_only.models_wide_objects and not PHDBank(lidar_only, 2).reads_scans
    uniform = SIMULATOR_PHD.camera_clutter_total_per_rad
    assert lidar_only.camera_clutter_uniform_per_rad == uniform
    assert SIMULATOR_PHD.camera_clutter_uniform_per_rad == pytest.approx(
        uniform - SIMULATOR_PHD.camera.clutter_wide_object_share_per_rad
    )


@pytest.mark.parametrize(
    "field, value",
    [
        ("camera_clutter_per_wide_object", -0.1),
        ("camera_wide_object_std_fraction", 11.0),
        ("camera_clutter_wide_object_share_per_rad", 2.0),  # more than the whole (0.5)
    ],
)
def test_impossible_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        PHDConfig.perera2021().replace(**{field: value})


def test_an_object_across_the_seam_is_one_bump():
    # An object straight behind (bearing pi): the bearings just either side of +-pi see it alike.
    memory = memory_of(cast(ANGLES, np.array([[-2.0, 0.0, DECOY]]), 0.0))
    assert memory[WIDE_OBJECTS_AT] == 1
    brg = np.array([math.pi - 0.002, -math.pi + 0.002, -math.pi, 0.0])
    ref = clutter_density(brg, memory, np.zeros(2), 0.5, 0.878, 0.28, 1e-7)
    out = np.full(4, 0.5)
    clutter_density_into(out, brg, memory, 0.0, 0.0, 0.878, 0.28, 1e-7)
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    assert ref[0] == pytest.approx(ref[1], rel=0.05) and ref[2] > 10.0 and ref[3] == 0.5


def test_before_the_first_scan_the_camera_uses_the_whole_uniform_clutter():
    mixture = GaussianMixture(np.array([0.4]), np.array([[1.5, 0.3]]), 1e-3 * np.eye(2)[None])
    brg = np.array([math.atan2(0.3, 1.5) + 0.002, 1.0])
    tables = []
    for per_object in (0.0, 0.878):
        config = SIMULATOR_PHD.replace(camera={"clutter_per_wide_object": per_object})
        f = RobotCentricPHD(config)  # no scan yet
        f.set_mixture(mixture)
        bank = PHDBank(config, 1)
        bank.load_filter(0, f)
        f.update_camera(brg)
        bank.apply([[("camera", brg, None)]])
        np.testing.assert_allclose(bank.table(0), f.table, rtol=0, atol=1e-12)
        tables.append(f.table)
    np.testing.assert_array_equal(tables[0], tables[1])


def test_a_bank_state_from_before_the_wide_objects_loads_and_a_bad_one_is_refused():
    config = SIMULATOR_PHD.replace(camera={"clutter_per_wide_object": 0.878})
    bank = PHDBank(config, 3)
    bank.apply(scanned_calls(np.random.default_rng(2), 3, 20, decoys=1))
    state = bank.__getstate__()
    old = dict(state, scan_memory=state["scan_memory"][:, :WIDE_OBJECTS_AT])
    loaded = PHDBank.__new__(PHDBank)
    loaded.__setstate__(old)
    assert loaded.__getstate__()["scan_memory"][:, WIDE_OBJECTS_AT:].sum() == 0.0
    bad = state["scan_memory"].copy()
    bad[0, WIDE_OBJECTS_AT] = 40  # more objects than a memory holds: would read past the row
    with pytest.raises(ValueError, match="scan_memory"):
        PHDBank.__new__(PHDBank).__setstate__(dict(state, scan_memory=bad))
    f = bank.to_filter(1)
    f_state = f.__getstate__()
    f_state["scan_memory"] = bad[0]
    before = bank.table(1).copy()
    broken = RobotCentricPHD(config)
    with pytest.raises(ValueError, match="scan_memory"):
        broken.__setstate__(f_state)
    np.testing.assert_array_equal(bank.table(1), before)


# ---------------------------------------------------------------------- the PMB
@pytest.mark.parametrize(
    "phd",
    [
        SIMULATOR_PHD,
        dataclasses.replace(SIMULATOR_PHD, mode="lidar-only"),  # keeps no scan
        PHDConfig.perera2021().replace(
            births={"model": "fixed"}, camera={"clutter_per_wide_object": 2.0}
        ),
    ],
    ids=["simulator", "lidar-only", "fixed-birth"],
)
def test_pmb_bank_matches_reference_filters(phd):
    """The PMB's compiled bank against its numpy reference with the wide objects' clutter:
    tracks, Poisson intensity and scan memory, on scans with red decoys that the camera sees."""
    rng = np.random.default_rng(5)
    n_robots = 4
    calls = scanned_calls(rng, n_robots, 70, decoys=2)
    config = PMBConfig(phd=phd)
    filters = [RobotCentricPMB(config) for _ in range(n_robots)]
    for f, seq in zip(filters, calls, strict=True):
        run_calls(f, seq)
    bank = PMBBank(config, n_robots)
    assert bank.reads_scans == phd.models_wide_objects
    bank.apply(calls)
    found = []
    for r, f in enumerate(filters):
        for a, b in ((f.table, bank.table(r)), (f.poisson_table, bank.poisson_table(r))):
            assert a.shape == b.shape, (r, a.shape, b.shape)
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-10)
        memory = bank.to_filter(r).__getstate__()["scan_memory"]
        np.testing.assert_allclose(memory, f.__getstate__()["scan_memory"], rtol=0, atol=1e-12)
        found.append(memory[WIDE_OBJECTS_AT])
    assert max(len(f) for f in filters) > 0
    assert (max(found) > 0) == phd.models_wide_objects  # the density was exercised


def test_a_pmb_bank_state_from_before_the_wide_objects_loads():
    config = PMBConfig(phd=SIMULATOR_PHD)
    bank = PMBBank(config, 3)
    bank.apply(scanned_calls(np.random.default_rng(2), 3, 20, decoys=1))
    state = bank.__getstate__()
    assert state["scan_memory"][:, WIDE_OBJECTS_AT].max() > 0
    old = {k: v for k, v in state.items() if k != "scan_memory"}
    loaded = PMBBank.__new__(PMBBank)
    loaded.__setstate__(old)
    assert not loaded.__getstate__()["scan_memory"].any()  # no scan until the next one
    bad = state["scan_memory"].copy()
    bad[0, WIDE_OBJECTS_AT] = 40  # more objects than a memory holds
    with pytest.raises(ValueError, match="scan_memory"):
        PMBBank.__new__(PMBBank).__setstate__(dict(state, scan_memory=bad))
