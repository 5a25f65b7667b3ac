"""Tracks the camera can start and keep: ray births, untracked-teammate clutter, the Bernoulli
missed-detection term (hand-derived cases; the bank's equivalence is in test_bank.py)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from localization import GaussianMixture, PHDConfig, RobotCentricPHD
from localization.config import CAMERA_BIRTH_RADIAL_STD_FRACTION
from localization.phd import missed_weights, ray_births
from localization.reducer import reduce


def camera_pd(cfg: PHDConfig, r: float) -> float:
    """Perera 2021 eq. 30 by hand."""
    return 1.0 / (cfg.camera.pd_offset + math.exp(cfg.camera.pd_slope_per_m * (r - 4.0)))


def one_track(cfg: PHDConfig, weight: float, xy=(1.0, 0.0), var=0.01) -> RobotCentricPHD:
    f = RobotCentricPHD(cfg)
    f.set_mixture(GaussianMixture([weight], [xy], [np.eye(2) * var]))
    return f


# ---------------------------------------------------------------------- Bernoulli missed term
def test_missed_weights_by_hand():
    # r = 0.95, P_d = 0.91, no measurement: 0.95 * 0.09 / (1 - 0.95 * 0.91) = 0.6310
    w = missed_weights(np.array([0.95, 0.01, 2.0]), np.array([0.91, 0.91, 0.5]))
    assert w[0] == pytest.approx(0.95 * 0.09 / (1 - 0.95 * 0.91), rel=1e-14)
    assert w[0] == pytest.approx(0.6310, abs=1e-4)
    # small r: the PHD's (1 - P_d) w to first order in r
    assert w[1] == pytest.approx(0.01 * 0.09 / (1 - 0.0091), rel=1e-14)
    # w = 2 (two certain targets, r = 1 each): a miss tells nothing new
    assert w[2] == pytest.approx(2.0, rel=1e-14)
    # w = 1.3 (a merged component): two targets of existence 0.65
    w13 = missed_weights(np.array([1.3]), np.array([0.9]))[0]
    assert w13 == pytest.approx(1.3 * 0.1 / (1 - 0.65 * 0.9), rel=1e-14)
    # P_d = 1 and r = 1: the numerator is 0, no 0 / 0
    assert missed_weights(np.array([1.0]), np.array([1.0]))[0] == 0.0


@pytest.mark.parametrize("model", ["phd", "bernoulli"])
def test_empty_camera_frame(model):
    cfg = PHDConfig.perera2021().replace(missed_detection=model)
    f = one_track(cfg, 0.95)
    f.update_camera(np.empty(0))
    pd = camera_pd(cfg, 1.0)
    expected = 0.95 * (1 - pd) if model == "phd" else 0.95 * (1 - pd) / (1 - 0.95 * pd)
    assert f.total_weight == pytest.approx(expected, rel=1e-12)


def test_bernoulli_missed_copy_with_a_measurement_by_hand():
    # One track at (1, 0), var 0.01, w = 0.8; one bearing at 0.05 rad; kappa_C = 0.5.
    cfg = PHDConfig.perera2021().replace(
        missed_detection="bernoulli", reduction={"merge_threshold": 1e-9, "prune_threshold": 1e-12}
    )
    f = one_track(cfg, 0.8)
    f.update_camera(np.array([0.05]))
    pd = camera_pd(cfg, 1.0)
    s = 0.01 + math.radians(5.0) ** 2  # H P H^T = P_yy / r^2 at (1, 0)
    g = math.exp(-0.5 * 0.05**2 / s) / math.sqrt(2 * math.pi * s)
    lam = pd * g / 0.5  # nothing else competes: kappa + sum_{j != i} = kappa
    missed = 0.8 * (1 - pd) / (1 - 0.8 * pd + 0.8 * lam)
    detected = pd * 0.8 * g / (0.5 + pd * 0.8 * g)
    w = np.sort(np.asarray(f.table)[0])
    assert w == pytest.approx(np.sort([missed, detected]), rel=1e-10)
    # the PHD keeps (1 - P_d) w = 0.072 beside the detected copy; the evidence removes most
    assert missed < 0.25 * 0.8 * (1 - pd)


def test_track_survives_one_dropped_frame_and_dies_after_three():
    """A tracked teammate at 1 m: one missed frame leaves it above the metric's 0.1 with the
    Bernoulli term (below with the PHD's); three missed frames with time updates remove it."""
    target = np.array([[1.0, 0.2]])
    bearing = np.arctan2(target[:, 1], target[:, 0])
    results = {}
    for model in ("phd", "bernoulli"):
        f = RobotCentricPHD(
            PHDConfig.perera2021().replace(missed_detection=model, births={"model": "measurement"})
        )
        for _ in range(10):
            f.predict(np.zeros(3))
            f.update_lidar(target)
            for _ in range(3):
                f.update_camera(bearing)
        established = f.total_weight
        f.update_camera(np.empty(0))
        one_miss = f.total_weight
        for _ in range(2):
            f.predict(np.zeros(3))
            f.update_camera(np.empty(0))
        results[model] = (established, one_miss, f.total_weight)
    assert results["phd"][1] < 0.1 < 0.3 < results["bernoulli"][1]
    assert results["bernoulli"][2] < 0.1
    # Established: without the missed copy's (1 - P_d) w the weight settles where the detected
    # copy P_d w g / (kappa_C + P_d w g) equals w, i.e. w = 1 - kappa_C / (P_d g), with g the
    # peak bearing likelihood (S ~ R_C once the track is sharp): 0.88 for kappa_C = 0.5.
    cfg = PHDConfig.perera2021()
    g = 1.0 / math.sqrt(2 * math.pi * cfg.camera.noise_var_rad2)
    w_star = 1.0 - cfg.camera.clutter_intensity / (camera_pd(cfg, math.hypot(1.0, 0.2)) * g)
    assert results["bernoulli"][0] == pytest.approx(w_star, abs=0.02)
    assert results["phd"][0] > results["bernoulli"][0]


# ---------------------------------------------------------------------- ray births
def test_ray_births_by_hand():
    cfg = PHDConfig.perera2021().replace(births={"camera": "ray"})
    theta = 0.3
    births = ray_births(
        np.array([theta]),
        0.25,
        6,
        0.3,
        4.0,
        CAMERA_BIRTH_RADIAL_STD_FRACTION,
        cfg.camera.noise_var_rad2,
        1.1,
        5.0,
        4.0,
    )
    assert births.shape == (6, 6)
    d = 3.7 / 6
    ranges = 0.3 + d * (np.arange(6) + 0.5)
    share = np.array([r * camera_pd(cfg, r) for r in ranges])
    assert births[0] == pytest.approx(0.25 * share / share.sum(), rel=1e-12)
    assert births[0].sum() == pytest.approx(0.25, rel=1e-14)
    assert births[1] == pytest.approx(ranges * math.cos(theta), rel=1e-12)
    assert births[2] == pytest.approx(ranges * math.sin(theta), rel=1e-12)
    u = np.array([math.cos(theta), math.sin(theta)])
    v = np.array([-u[1], u[0]])
    for k in range(6):
        cov = np.array([[births[3, k], births[4, k]], [births[4, k], births[5, k]]])
        assert u @ cov @ u == pytest.approx((0.45 * d) ** 2, rel=1e-10)
        assert v @ cov @ v == pytest.approx(ranges[k] ** 2 * cfg.camera.noise_var_rad2, rel=1e-10)
        assert u @ cov @ v == pytest.approx(0.0, abs=1e-15)


def test_ray_covers_the_band_flat_and_survives_the_default_merge():
    # equal-weight cells: the summed radial density is flat to the ripple the config claims
    d = 0.5
    centres = np.arange(40) * d
    sigma = CAMERA_BIRTH_RADIAL_STD_FRACTION * d
    r = np.linspace(10 * d, 30 * d, 2001)
    density = np.exp(-0.5 * ((r[:, None] - centres) / sigma) ** 2).sum(axis=1)
    # first harmonic: +- 2 exp(-2 pi^2 0.45^2) = +- 3.7 %
    ripple = 0.5 * (density.max() - density.min()) / density.mean()
    assert ripple == pytest.approx(2 * math.exp(-2 * math.pi**2 * 0.45**2), rel=0.02)
    # adjacent cells are d^2 / sigma^2 = 4.94 apart: the default merge (U = 4) keeps them
    births = ray_births(
        np.array([1.0]), 0.25, 6, 0.3, 4.0, CAMERA_BIRTH_RADIAL_STD_FRACTION, 0.0076, 1.1, 5, 4
    )
    assert reduce(births, 1e-4, PHDConfig.perera2021().reduction.merge_threshold, 64).shape[1] == 6


def test_unexplained_bearing_starts_a_ray_explained_one_does_not():
    cfg = PHDConfig.perera2021().replace(births={"camera": "ray"})
    f = one_track(cfg, 1.0, xy=(1.0, 0.0), var=0.005)
    f.update_camera(np.array([0.0, 2.0]))  # 0.0 is the track's, 2.0 nobody's
    table = np.asarray(f.table)
    ray = np.abs(np.arctan2(table[2], table[1]) - 2.0) < 1e-9
    assert ray.sum() == cfg.births.camera_components
    assert table[0, ray].sum() == pytest.approx(cfg.births.camera_weight, rel=1e-12)
    assert not (np.abs(np.arctan2(table[2], table[1])) > 0.2).sum() - ray.sum()
    # off by default: the Perera 2021 study's model
    g = one_track(PHDConfig.perera2021(), 1.0, xy=(1.0, 0.0), var=0.005)
    g.update_camera(np.array([0.0, 2.0]))
    assert len(g) == 1


def test_camera_only_teammate_is_localised_by_parallax():
    """A static teammate at (2.5, 1.0) that the lidar never reports: the observer drives
    forward; the ray's components converge on it through the bearing's change."""
    cfg = PHDConfig.perera2021().replace(
        births={"camera": "ray"},
        prediction={"survival_model": "constant", "survival_probability": 0.999},
    )
    f = RobotCentricPHD(cfg)
    rng = np.random.default_rng(0)
    pos = np.array([2.5, 1.0])
    step = np.array([0.03, 0.0, 0.0])
    for _ in range(40):
        for _ in range(3):
            b = math.atan2(pos[1], pos[0]) + rng.normal(0.0, math.radians(2.0))
            f.update_camera(np.array([b]))
        f.predict(step)
        pos = pos - step[:2]
    positions, _ = f.estimate(0.3)
    assert positions.shape[0] >= 1
    assert np.linalg.norm(positions[0] - pos) < 0.35
    assert f.total_weight == pytest.approx(1.0, abs=0.35)


# ---------------------------------------------------------------------- untracked clutter
def test_untracked_clutter_by_hand():
    # A step-like range factor (P = 1 up to 4 m, 0 beyond): integral_2^4 r dr = 6 m^2.
    cfg = PHDConfig.perera2021().replace(
        camera={
            "clutter_intensity": 0.1,
            "untracked_density_per_m2": 0.2,
            "pd_offset": 1.0,
            "pd_slope_per_m": 400.0,
        }
    )
    assert cfg.camera_clutter_total_per_rad == pytest.approx(0.1 + 0.2 * 6.0, rel=1e-4)
    assert (
        PHDConfig.perera2021().camera_clutter_total_per_rad
        == PHDConfig.perera2021().camera.clutter_intensity
    )


def test_untracked_clutter_enters_the_update():
    base = PHDConfig.perera2021().replace(camera={"clutter_intensity": 0.2})
    dense = PHDConfig.perera2021().replace(
        camera={"clutter_intensity": 0.0, "untracked_density_per_m2": 1.0}
    )
    same = PHDConfig.perera2021().replace(
        camera={"clutter_intensity": dense.camera_clutter_total_per_rad}
    )
    out = {}
    for name, cfg in (("base", base), ("dense", dense), ("same", same)):
        f = one_track(cfg, 1.0)
        f.update_camera(np.array([0.02]))
        out[name] = np.asarray(f.table)
    assert np.array_equal(out["dense"], out["same"])
    assert out["dense"][0].sum() < out["base"][0].sum()


@pytest.mark.parametrize(
    "field, value",
    [
        ("births.camera", "lidar"),
        ("missed_detection", "cphd"),
        ("births.camera_weight", -0.1),
        ("births.camera_components", 0),
        ("births.camera_components", 2.0),
        ("births.camera_min_range_m", 0.0),
        ("births.camera_max_range_m", 0.2),
        ("births.camera_max_explained", 1.5),
        ("camera.untracked_density_per_m2", -1.0),
        ("camera.untracked_min_range_m", float("nan")),
    ],
)
def test_bad_new_fields_raise_naming_the_field(field, value):
    component, _, name = field.rpartition(".")
    change = {component: {name: value}} if component else {field: value}
    with pytest.raises(ValueError, match=re.escape(field)):
        PHDConfig.perera2021().replace(**change)
