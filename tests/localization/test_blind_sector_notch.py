"""The ``"visible-width"`` blind-sector factor: hand-derived values, its Gaussian average, and
the simulated lidar it describes."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.integrate import quad

from localization import PHDConfig
from localization.detection import (
    DetectionModel,
    blind_sector_first_beams,
    expected_ramp,
    visible_width_factor,
)
from swarm_env.config import SIMULATOR_PHD, make_config
from swarm_env.sensors.detection_trials import lidar_detects

DEG = math.pi / 180.0
X4 = dict(target_radius_m=0.0325, footprint_rad=0.5 * DEG, spacing_rad=0.5 * DEG, min_returns=3)


def notch(offset_deg, range_m, std_deg=0.0, first_beam_deg=None):
    """The factor of a 10 deg sector: drifting beams, or fixed beams whose first past each
    edge is ``first_beam_deg`` from the centre."""
    drifting = first_beam_deg is None
    first = 5.0 * DEG if drifting else first_beam_deg * DEG
    return float(
        visible_width_factor(
            np.float64(offset_deg * DEG),
            range_m,
            std_deg * DEG,
            5.0 * DEG,
            (first, first),
            X4["spacing_rad"] if drifting else 0.0,
            **X4,
        )
    )


def test_notch_edges_by_hand_at_one_metre():
    """At 1 m a 32.5 mm housing spans +/- a = asin(0.0325) = 1.8623 deg. Whole-footprint beam
    centres outside the 5 deg half-sector fill ``L = s + a - 0.25 - 5`` deg, and three of them
    fit with probability ``clip(L / 0.5 - 2, 0, 1)``: 0 up to s0 = 4.3877 deg, 1 from
    s0 + 0.5 deg, linear between; symmetric about the centre."""
    a = math.degrees(math.asin(0.0325))
    s0 = 5.0 - a + 0.25 + 1.0
    assert s0 == pytest.approx(4.38756, abs=1e-5)
    for offset, expected in ((0.0, 0.0), (s0 - 0.01, 0.0), (s0 + 0.25, 0.5), (s0 + 0.4, 0.8)):
        assert notch(offset, 1.0) == pytest.approx(expected, abs=1e-9)
        assert notch(-offset, 1.0) == pytest.approx(expected, abs=1e-9)
    assert notch(s0 + 0.5, 1.0) == pytest.approx(1.0, abs=1e-9)
    assert notch(30.0, 1.0) == 1.0


def test_fixed_beams_make_the_edge_a_step_at_the_third_beam():
    """The simulated X4's beams sit at -180 + 0.5 k deg; the beam at a 10 deg sector's edge
    (40 or 50 deg for the one at 45) is blind, so the first that can return is 5.5 deg from the
    centre, and the third falls on a housing at 1 m once ``s + a - 0.25 >= 5.5 + 1.0`` deg:
    ``s >= 4.8877`` deg."""
    first, ramp = blind_sector_first_beams(SIMULATOR_PHD)
    np.testing.assert_allclose(first, 5.5 * DEG, rtol=1e-12)
    assert ramp == 0.0
    step = 5.5 - math.degrees(math.asin(0.0325)) + 0.25 + 1.0
    assert notch(step - 0.01, 1.0, first_beam_deg=5.5) == 0.0
    assert notch(step + 0.01, 1.0, first_beam_deg=5.5) == 1.0
    assert notch(-(step + 0.01), 1.0, first_beam_deg=5.5) == 1.0
    drifting = SIMULATOR_PHD.replace(lidar={"beam_phase": "drifting"})
    np.testing.assert_allclose(blind_sector_first_beams(drifting)[0], 5.0 * DEG)
    assert blind_sector_first_beams(drifting)[1] == pytest.approx(0.5 * DEG)


def test_beyond_three_returns_the_notch_is_the_housing_clearing_the_sector():
    """At 3 m (a = 0.6207 deg) a housing gives ``(2a - 0.5) / 0.5 = 1.48`` whole returns in
    full view, fewer than three: the range factor says no, and the notch is a step where the
    housing clears the sector, ``s1 = 5 + a - 0.25`` deg."""
    s1 = 5.0 + math.degrees(math.asin(0.0325 / 3.0)) - 0.25
    assert notch(s1 - 1e-3, 3.0) == 0.0
    assert notch(s1 + 1e-3, 3.0) == 1.0


def test_a_housing_wider_than_the_sector_is_seen_on_either_side():
    """At 0.2 m (a = 9.35 deg) a centred housing still leaves 9.35 - 0.25 - 5 = 4.1 deg of beam
    centres on each side of the sector, room for eight returns."""
    assert notch(0.0, 0.2) == pytest.approx(1.0, abs=1e-15)
    assert notch(0.0, 0.4) == 0.0  # a = 4.66 deg: the pillars hide all of it


@pytest.mark.parametrize(
    ("mean", "std", "start", "width"),
    [(0.0, 1.0, -0.5, 1.0), (2.0, 0.3, 1.5, 0.2), (-1.0, 2.0, 0.0, 3.0), (0.1, 0.05, 0.0, 0.0)],
)
def test_expected_ramp_is_the_gaussian_average_of_the_ramp(mean, std, start, width):
    def ramp(x):
        if width == 0.0:
            return float(x >= start)
        return min(max((x - start) / width, 0.0), 1.0)

    def density(x):
        return math.exp(-0.5 * ((x - mean) / std) ** 2) / (std * math.sqrt(2 * math.pi))

    points = [start, start + width] if width else [start]
    expected, _ = quad(
        lambda x: ramp(x) * density(x), mean - 12 * std, mean + 12 * std, points=points, limit=200
    )
    assert expected_ramp(mean, std, start, width) == pytest.approx(expected, abs=1e-9)


def test_the_bearing_std_smooths_the_notch():
    """A component 1 deg uncertain in bearing sees the edge as a ramp about 4 deg wide; its
    factor at the centre and far outside is still 0 and 1."""
    sharp = [notch(s, 1.0) for s in (3.0, 4.0, 5.0, 6.0)]
    smooth = [notch(s, 1.0, std_deg=1.0) for s in (3.0, 4.0, 5.0, 6.0)]
    np.testing.assert_allclose(sharp, [0.0, 0.0, 1.0, 1.0], atol=1e-15)
    assert 0.0 < smooth[0] < smooth[1] < smooth[2] < smooth[3] < 1.0
    assert notch(0.0, 1.0, std_deg=1.0) < 1e-5
    assert notch(12.0, 1.0, std_deg=1.0) > 1.0 - 1e-9


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("blind_sector_model", "gaussian", "lidar.blind_sector_model"),
        ("min_returns", 0, "lidar.min_returns must be an integer in [1, 100], got 0"),
        ("min_returns", 2.5, "lidar.min_returns must be an int, got 2.5"),
        ("beam_phase", "random", "lidar.beam_phase"),
        (
            "beam_spacing_deg",
            0.0,
            "lidar.beam_spacing_deg must be a finite number in [0.001, 10.0]",
        ),
    ],
)
def test_bad_notch_configuration_names_the_field(field, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        PHDConfig.perera2021().replace(lidar={field: value})


def test_the_simulator_filter_uses_the_x4_geometry():
    cfg = SIMULATOR_PHD
    assert cfg.lidar.blind_sector_model == "visible-width"
    assert cfg.lidar.beam_phase == "fixed"
    sim = make_config("seed-sim")
    assert cfg.lidar.beam_spacing_deg == pytest.approx(math.degrees(sim.lidar.beam_spacing_rad))
    assert cfg.lidar.beam_footprint_deg == sim.lidar.beam_footprint_deg
    assert cfg.lidar.min_returns == sim.lidar_features.min_beams
    assert cfg.lidar.target_radius_m == sim.robot.housing_radius_m


def measured_notch(range_m: float, offsets_deg: np.ndarray, seed: int) -> np.ndarray:
    """Whether the simulated X4 and the feature extractor report a housing at ``range_m`` and
    each bearing offset from a random blind sector's centre (random side), one pair each."""
    rng = np.random.default_rng(seed)
    centres = rng.choice(
        np.asarray(SIMULATOR_PHD.lidar.blind_sector_centers_deg), offsets_deg.size
    )
    signs = rng.choice([-1.0, 1.0], offsets_deg.size)
    return lidar_detects(range_m, np.radians(centres + signs * offsets_deg), rng).astype(float)


@pytest.mark.parametrize("range_m", [0.6, 1.0, 1.5, 2.0])
def test_the_notch_matches_the_simulated_lidar(range_m):
    """Against ground truth: per 1.5 deg bin of offset, the simulator's detection rate is its
    full-view rate at that range (measured 20-40 deg from the centres) times the filter's notch
    to within 0.1 (about 3 standard errors), while the Perera 2021 study's bump misses it by more
    than 0.1 somewhere at every range."""
    rng = np.random.default_rng(11)
    offsets = np.concatenate((rng.uniform(0.0, 9.0, 1200), rng.uniform(20.0, 40.0, 400)))
    found = measured_notch(range_m, offsets, seed=int(100 * range_m))
    full_view = found[1200:].mean()
    offsets, found = offsets[:1200], found[:1200]
    bearings = np.radians(45.0 + offsets)
    ranges = np.full(offsets.size, range_m)
    predicted = full_view * DetectionModel(SIMULATOR_PHD).lidar_blind_sector_factor(
        bearings, ranges
    )
    seed_bump = DetectionModel(SIMULATOR_PHD.replace(lidar={"blind_sector_model": "seed"}))
    bumped = full_view * seed_bump.lidar_blind_sector_factor(bearings, ranges)
    bins = np.digitize(offsets, np.arange(0.0, 9.01, 1.5)) - 1
    worst_bump = 0.0
    for b in range(6):
        sel = bins == b
        assert found[sel].mean() == pytest.approx(predicted[sel].mean(), abs=0.1), (
            f"{range_m} m, offsets {1.5 * b}-{1.5 * b + 1.5} deg"
        )
        worst_bump = max(worst_bump, abs(found[sel].mean() - bumped[sel].mean()))
    assert worst_bump > 0.1


def test_fixed_beams_must_tile_the_turn():
    with pytest.raises(ValueError, match=r"lidar\.beam_spacing_deg must divide 360"):
        PHDConfig.perera2021().replace(lidar={"beam_phase": "fixed", "beam_spacing_deg": 0.7})
    PHDConfig.perera2021().replace(
        lidar={"beam_phase": "drifting", "beam_spacing_deg": 0.7}
    )  # any spacing drifts


def test_an_uncertain_bearing_averages_the_larger_side():
    """At the sector centre the housing is hidden, but a component 5.7 deg uncertain in bearing
    may be on either side of the notch: the average of the larger side is the sum of the two
    sides' averages (Monte Carlo over the bearing, 200 000 draws), not the larger average."""
    draws = np.random.default_rng(0).normal(0.0, 5.7, 200_000)
    sampled = float(
        visible_width_factor(
            draws * DEG, 1.0, 0.0, 5.0 * DEG, (5.5 * DEG, 5.5 * DEG), 0.0, **X4
        ).mean()
    )
    assert notch(0.0, 1.0, std_deg=5.7, first_beam_deg=5.5) == pytest.approx(sampled, abs=0.005)
    assert sampled > 0.35  # the larger side's average alone would give 0.20
