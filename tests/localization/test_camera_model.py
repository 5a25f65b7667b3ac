"""The camera's measurement model: bearings from the camera's position (parallax) and a
bearing noise that depends on range (the blob centroid wanders within the target's width)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.mixture import GaussianMixture
from localization.pmb import PMBBank, PMBConfig, RobotCentricPMB
from localization.registry import run_calls


@pytest.mark.parametrize("family", ["phd", "pmb", "phd-bank", "pmb-bank"])
def test_bearing_model_is_evaluated_from_the_camera_position(family):
    """A teammate at (0.5, 0) seen from a camera that has moved 3 cm left since the time update
    has bearing atan2(-0.03, 0.5) = -3.4 deg: with the camera's position in the model the track
    stays put and keeps its weight; the bearing taken as if from the origin would pull it 3 cm
    sideways (7.6 sigma of the 0.45 deg noise this test uses, at 0.5 m)."""
    config = PHDConfig.perera2021().replace(
        camera={"noise_std_deg": 0.45, "clutter_intensity": 0.5}
    )
    pose = np.array([0.0, 0.03, 0.0])
    bearing = np.array([np.arctan2(-0.03, 0.5)])
    _check_parallax(family, config, pose, bearing)


@pytest.mark.parametrize("family", ["phd", "pmb", "phd-bank", "pmb-bank"])
def test_parallax_with_rotation(family):
    """The camera moved (0.1, -0.08) and turned 0.3 rad: the teammate at (0.5, 0) in the
    filter's frame is seen at atan2(0.08, 0.4) - 0.3 in the camera's own frame."""
    config = PHDConfig.perera2021().replace(
        camera={"noise_std_deg": 0.45, "clutter_intensity": 0.5}
    )
    pose = np.array([0.1, -0.08, 0.3])
    bearing = np.array([np.arctan2(0.0 + 0.08, 0.5 - 0.1) - 0.3])
    _check_parallax(family, config, pose, bearing)


def _check_parallax(family, config, pose, bearing):
    if family.startswith("phd"):
        f = RobotCentricPHD(config)
    else:
        f = RobotCentricPMB(PMBConfig(config))
    mix = GaussianMixture(np.array([0.95]), np.array([[0.5, 0.0]]), np.array([1e-4 * np.eye(2)]))
    f.set_state(mix) if isinstance(f, RobotCentricPMB) else f.set_mixture(mix)
    call = ("camera", bearing, pose)
    if family.endswith("bank"):
        bank = (PHDBank if family == "phd-bank" else PMBBank)(f.config, 1)
        bank.load_filter(0, f)
        bank.apply([[call]])
        table = bank.table(0)
    else:
        run_calls(f, [call])
        table = f.table
    assert table.shape[1] == 1
    np.testing.assert_allclose(table[1:3, 0], [0.5, 0.0], atol=1e-9)
    assert table[0, 0] > 0.9


def test_range_dependent_bearing_variance_by_hand():
    cfg = PHDConfig.perera2021().replace(
        camera={"noise_std_deg": 0.03, "noise_width_fraction": 1 / 12}
    )
    # W(1 m) = 2 asin(0.05) = 5.732 deg: std sqrt(0.03^2 + (5.732 / 12)^2) = 0.4786 deg
    assert math.degrees(math.sqrt(cfg.camera_bearing_var(1.0))) == pytest.approx(0.4786, abs=1e-4)
    # below min_range_m (0.1 m) the range is floored: W = 2 asin(0.5) = pi / 3
    np.testing.assert_allclose(
        cfg.camera_bearing_var([0.01, 0.04]),
        math.radians(0.03) ** 2 + (math.pi / 3 / 12) ** 2,
    )
    # a target wider than its range (R > r) saturates at W = pi
    wide = PHDConfig.perera2021().replace(
        camera={"noise_width_fraction": 1.0, "target_radius_m": 0.5}
    )
    assert wide.camera_bearing_var(0.2) == pytest.approx(wide.camera.noise_var_rad2 + math.pi**2)
    assert (
        PHDConfig.perera2021().camera_bearing_var(3.0)
        == PHDConfig.perera2021().camera.noise_var_rad2
    )  # Perera 2021


@pytest.mark.parametrize("engine", ["reference", "bank"])
def test_bearing_update_uses_the_noise_at_the_component_range(engine):
    """A component at range d with isotropic prior variance p: a bearing measures the tangential
    position with variance d^2 R_C(d), so it becomes 1 / (1/p + 1/(d^2 R_C(d))); the radial
    variance is unchanged."""
    # P_d = 1: no missed copy to merge back into the detected one
    cfg = PHDConfig.perera2021().replace(
        camera={
            "noise_std_deg": 0.03,
            "noise_width_fraction": 1 / 12,
            "pd_offset": 1.0,
            "pd_midpoint_m": 50.0,
        }
    )
    p = 0.02**2
    for d in (0.4, 1.0, 2.5):
        f = RobotCentricPHD(cfg)
        f.set_mixture(
            GaussianMixture(np.array([0.9]), np.array([[0.0, d]]), np.array([p * np.eye(2)]))
        )
        if engine == "bank":
            bank = PHDBank(cfg, 1)
            bank.load_filter(0, f)
            bank.apply([[("camera", np.array([math.pi / 2]))]])
            table = bank.table(0)
        else:
            f.update_camera(np.array([math.pi / 2]))
            table = f.table
        detected = np.argmax(table[0])
        expected = 1.0 / (1.0 / p + 1.0 / (d * d * cfg.camera_bearing_var(d)))
        assert table[3, detected] == pytest.approx(expected, rel=1e-9)  # x: tangential at (0, d)
        assert table[5, detected] == pytest.approx(p, rel=1e-9)  # y: radial, unchanged


@pytest.mark.parametrize("range_m", [0.5, 1.0, 2.0, 3.0])
def test_simulator_filter_bearing_noise_matches_the_simulated_camera(range_m):
    """SIMULATOR_PHD's R_C(r) is the simulated blobs' measured error at each range (within the
    sampling error of 1500 pairs), not the all-range 0.45 deg RMS."""
    from swarm_env.config import SIMULATOR_PHD, make_config
    from swarm_env.sensors.camera import CameraSensor
    from swarm_env.sensors.scene_builder import make_pair_scene

    cfg = make_config("sim-6m-20")
    rng = np.random.default_rng(7)
    scene, bearings = make_pair_scene(rng, range_m, 1500, cfg.robot.camera_holder_radius_m)
    batch = CameraSensor(cfg.camera).observe(scene, np.arange(0, scene.n_robots, 2), rng)
    strip = np.flatnonzero(scene.circle_red)
    errs = [
        (bear[src == strip[2 * k + 1]][0] - bearings[k] + np.pi) % (2 * np.pi) - np.pi
        for k, (bear, src) in enumerate(zip(batch.bearings, batch.sources, strict=True))
        if (src == strip[2 * k + 1]).any()
    ]
    measured = float(np.sqrt(np.mean(np.square(errs))))
    model = float(np.sqrt(SIMULATOR_PHD.camera_bearing_var(range_m)))
    assert measured == pytest.approx(model, rel=0.08)
