"""The filter model the simulator runs: ``PHDConfig()`` is the presets' model, its geometry is
the simulated sensors', ``PHDConfig.perera2021()`` carries the Perera 2021 study's values, and
overrides take nested dicts (old flat names refused, flat recordings converted)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from localization.config import (
    MOVED_FIELDS,
    BirthModel,
    CameraModel,
    LidarModel,
    PHDConfig,
    PredictionModel,
    Reduction,
    nest_flat_phd,
)
from swarm_env.config import PRESETS, SIMULATOR_PHD, make_config


@pytest.mark.parametrize("preset", sorted(set(PRESETS) - {"perera2021"}))
def test_the_default_filter_is_what_every_simulator_preset_runs(preset):
    assert PHDConfig() == make_config(preset).phd == SIMULATOR_PHD


def test_the_perera2021_preset_runs_the_studys_filter():
    assert make_config("perera2021").phd == PHDConfig.perera2021()


def test_the_default_geometry_is_the_simulated_sensors():
    sim = make_config("sim-6m-20")
    lidar = PHDConfig().lidar
    assert lidar.beam_spacing_deg == pytest.approx(360.0 / sim.lidar.n_beams)
    assert lidar.beam_footprint_deg == sim.lidar.beam_footprint_deg
    assert lidar.min_returns == sim.lidar_features.min_beams
    assert lidar.target_radius_m == sim.robot.housing_radius_m
    assert lidar.blind_sector_centers_deg == sim.lidar.blind_sector_centers_deg
    assert lidar.blind_sector_widths_deg == sim.lidar.blind_sector_widths_deg
    assert PHDConfig().camera.target_radius_m == sim.robot.camera_holder_radius_m


def test_the_default_sensor_models_are_the_measured_ones():
    cfg = PHDConfig()
    assert (cfg.lidar.pd_offset, cfg.lidar.pd_slope_per_m, cfg.lidar.pd_midpoint_m) == (
        1.0,
        8.78,
        2.14,
    )
    assert (cfg.camera.pd_offset, cfg.camera.pd_slope_per_m, cfg.camera.pd_midpoint_m) == (
        1.05,
        3.84,
        4.08,
    )
    assert (cfg.camera.noise_std_deg, cfg.camera.noise_width_fraction) == (0.027, 0.0845)
    assert cfg.camera.clutter_intensity == 1.22
    assert cfg.camera_clutter_uniform_per_rad == pytest.approx(1.22 - 0.131)
    assert cfg.lidar.blind_sector_model == "visible-width" and cfg.lidar.beam_phase == "fixed"
    assert cfg.births.model == "measurement" and cfg.births.camera == "none"
    assert cfg.missed_detection == "bernoulli" and cfg.prediction.time_update == "measurement"
    assert cfg.reads_scans


def test_perera2021_carries_the_studys_values():
    cfg = PHDConfig.perera2021()
    p = cfg.prediction
    # eq. 10: P_s = 1 / (1.05 + exp(4 (r - 4)))
    assert (p.survival_model, p.survival_offset, p.survival_slope_per_m, p.survival_range_m) == (
        "seed",
        1.05,
        4.0,
        4.0,
    )
    assert p.time_update == "odometry"
    # eq. 11: one birth component N(0, diag(4, 4)) of weight 0.001
    b = cfg.births
    assert (b.model, b.weight, b.mean_m, b.std_m**2) == ("fixed", 0.001, (0.0, 0.0), 4.0)
    assert b.camera == "none"
    lidar = cfg.lidar
    assert lidar.noise_var_m2 == pytest.approx(0.0025)  # eq. 17
    assert (lidar.pd_offset, lidar.pd_slope_per_m, lidar.pd_midpoint_m) == (1.02, 8.0, 1.5)  # 19
    # eq. 20: bumps of sigma = width / 2 at the four pillars
    assert lidar.blind_sector_model == "seed"
    assert lidar.blind_sector_centers_deg == (45.0, 135.0, -135.0, -45.0)
    assert lidar.blind_sector_widths_deg == (10.0,) * 4
    assert lidar.occlusion_std_deg == 3.0  # eqs. 21-22
    assert lidar.interference_depth == 0.6  # eq. 23
    assert not lidar.missed_moments
    camera = cfg.camera
    assert camera.noise_var_rad2 == pytest.approx(math.radians(5.0) ** 2)  # "25 deg": 25 deg^2
    assert camera.noise_width_fraction == 0.0
    assert (camera.pd_offset, camera.pd_slope_per_m, camera.pd_midpoint_m) == (1.1, 5.0, 4.0)  # 30
    assert camera.clutter_per_wide_object == 0.0 and not cfg.reads_scans
    assert cfg.missed_detection == "phd"


def test_the_two_models_differ_only_in_their_sensor_models_and_switches():
    sim, study = PHDConfig(), PHDConfig.perera2021()
    assert sim.reduction == study.reduction and sim.mode == study.mode
    assert dataclasses.replace(sim.prediction, time_update="odometry") == study.prediction
    assert dataclasses.replace(sim.births, model="fixed") == study.births


@pytest.mark.parametrize(
    "component, field, value",
    [
        (PredictionModel, "process_noise_std_m", -1.0),
        (LidarModel, "noise_std_m", 0.0),
        (LidarModel, "beam_phase", "sometimes"),
        (CameraModel, "clutter_wide_object_share_per_rad", 5.0),
        (BirthModel, "camera_components", 0),
        (Reduction, "max_components", 2.5),
    ],
)
def test_each_component_checks_its_own_fields(component, field, value):
    with pytest.raises(ValueError, match=rf"{component.PREFIX}\.{field} .*{value!r}"):
        component(**{field: value})


def test_overrides_take_nested_dicts_and_refuse_old_flat_names():
    cfg = make_config("lab-3m-4", phd={"lidar": {"noise_std_m": 0.04}, "mode": "lidar-only"})
    assert cfg.phd.lidar.noise_std_m == 0.04 and cfg.phd.mode == "lidar-only"
    assert cfg.phd.lidar.pd_offset == PHDConfig().lidar.pd_offset  # the rest kept
    assert PHDConfig(lidar=LidarModel(noise_std_m=0.04)) == PHDConfig().replace(
        lidar={"noise_std_m": 0.04}
    )
    with pytest.raises(ValueError, match=r"phd\.camera_noise_std_deg is now phd\.camera\."):
        make_config("lab-3m-4", phd={"camera_noise_std_deg": 1.0})
    with pytest.raises(ValueError, match=r"unknown config key 'phd\.lidar\.colour'"):
        make_config("lab-3m-4", phd={"lidar": {"colour": 1}})
    with pytest.raises(ValueError, match="PHDConfig.lidar must be a LidarModel"):
        PHDConfig(lidar={"noise_std_m": 0.04})


def test_a_flat_config_of_an_earlier_release_is_converted():
    flat = {old: None for old in MOVED_FIELDS}
    nested = nest_flat_phd({**flat, "mode": "lidar-only", "scan_evidence": False})
    assert set(nested) == {"mode", "prediction", "lidar", "camera", "births", "reduction"}
    assert sum(len(v) for v in nested.values() if isinstance(v, dict)) == len(MOVED_FIELDS)
    with pytest.raises(ValueError, match="scan_evidence=True"):
        nest_flat_phd({"scan_evidence": True})


def test_a_bag_recorded_with_a_flat_filter_config_still_loads():
    from hardware_bridge.bag import config_from_dict, config_to_dict

    data = config_to_dict(make_config("lab-3m-4"))
    phd = data["phd"]
    flat = {"mode": phd["mode"], "missed_detection": phd["missed_detection"]}
    for old, new in MOVED_FIELDS.items():
        component, name = new.split(".")
        flat[old] = phd[component][name]
    flat.update(scan_evidence=False, scan_margin_sigmas=3.0)
    flat["camera_noise_std_deg"] = 0.5
    loaded = config_from_dict({**data, "phd": flat})
    assert loaded.phd == PHDConfig().replace(camera={"noise_std_deg": 0.5})
    assert config_from_dict(data) == make_config("lab-3m-4")
