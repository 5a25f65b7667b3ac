"""RobotCentricPHD public API: inputs, state handling, copies, modes, extraction."""

from __future__ import annotations

import copy
import math
import pickle
import re

import numpy as np
import pytest

from localization import GaussianMixture, PHDConfig, RobotCentricPHD


def tracked_filter(config: PHDConfig | None = None) -> RobotCentricPHD:
    """A filter that has locked on to two teammates."""
    f = RobotCentricPHD(config)
    targets = np.array([[1.0, 0.3], [-0.5, 0.8]])
    for _ in range(6):
        f.predict(np.zeros(3))
        f.update_lidar(targets)
        f.update_camera(np.arctan2(targets[:, 1], targets[:, 0]))
    return f


def snapshot(f: RobotCentricPHD):
    return (np.array(f.table), np.array(f._pending_births))


def assert_unchanged(f: RobotCentricPHD, before) -> None:
    table, pending = snapshot(f)
    assert np.array_equal(table, before[0]) and np.array_equal(pending, before[1])


def test_tracks_two_static_teammates():
    f = tracked_filter()
    positions, weights = f.estimate()
    assert positions.shape == (2, 2) and weights.shape == (2,)
    order = np.argsort(positions[:, 0])
    assert np.allclose(positions[order], [[-0.5, 0.8], [1.0, 0.3]], atol=0.02)
    assert 1.5 < f.total_weight < 2.6


@pytest.mark.parametrize(
    "method, args, name",
    [
        ("predict", (np.array([np.nan, 0.0, 0.0]),), "odometry"),
        ("predict", (np.array([0.0, 0.0]),), "odometry"),
        ("predict", (np.zeros((1, 3)),), "odometry"),
        ("predict", ("abc",), "odometry"),
        ("update_lidar", (np.zeros((3, 3)),), "points"),
        ("update_lidar", (np.array([[0.0, np.inf]]),), "points"),
        ("update_lidar", (np.zeros(4),), "points"),
        ("update_lidar", (np.ones((2, 2)), np.array([0.1, np.nan])), "null_bearings"),
        ("update_lidar", (np.ones((2, 2)), np.ones((2, 2))), "null_bearings"),
        ("update_camera", (np.array([0.1, np.nan]),), "bearings"),
        ("update_camera", (np.zeros((2, 2)),), "bearings"),
        ("update_camera", ([[0.1], [0.2]],), "bearings"),
    ],
)
def test_bad_input_raises_naming_argument_and_leaves_state_unchanged(method, args, name):
    f = tracked_filter(PHDConfig.perera2021().replace(births={"model": "measurement"}))
    f.update_lidar(np.array([[1.5, -1.5]]))  # leaves a pending measurement birth
    before = snapshot(f)
    with pytest.raises(ValueError, match=name):
        getattr(f, method)(*args)
    assert_unchanged(f, before)


def test_error_messages_show_the_offending_value():
    f = RobotCentricPHD()
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        f.update_lidar(np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"points\[1\] = \[0.0, nan\]"):
        f.update_lidar(np.array([[0.0, 0.0], [0.0, np.nan]]))
    with pytest.raises(ValueError, match=r"\[0.0, inf, 0.0\]"):
        f.predict([0.0, math.inf, 0.0])


@pytest.mark.parametrize(
    "field, value",
    [
        ("mode", "camera-only"),
        ("births.model", "adaptive"),
        ("lidar.pd_model", "sigmoid"),
        ("prediction.process_noise_std_m", -0.1),
        ("prediction.process_noise_std_m", float("nan")),
        ("lidar.noise_std_m", 0.0),
        ("prediction.survival_probability", 1.5),
        ("lidar.detection_probability", -0.1),
        ("reduction.prune_threshold", 1.0),
        ("reduction.merge_threshold", 0.0),
        ("reduction.max_components", 0),
        ("reduction.max_components", 2.5),
        ("lidar.blind_sector_widths_deg", (10.0, 10.0)),
        ("lidar.blind_sector_centers_deg", (45.0, float("inf"), 0.0, 1.0)),
        ("births.mean_m", (0.0,)),
        ("prediction.survival_offset", 0.5),
        ("camera.clutter_intensity", -1.0),
        ("lidar.interference_depth", 2.0),
        ("reduction.min_range_m", 0.0),
        ("births.weight", "0.1"),
    ],
)
def test_bad_config_raises_naming_the_field(field, value):
    """Each component checks its own fields: the error names ``component.field``."""
    component, _, name = field.rpartition(".")
    change = {component: {name: value}} if component else {field: value}
    with pytest.raises(ValueError, match=re.escape(field)):
        PHDConfig.perera2021().replace(**change)


@pytest.mark.parametrize(
    "old, new",
    [
        ("camera_noise_std_deg", "camera.noise_std_deg"),
        ("birth", "births.model"),
        ("lidar_pd_offset", "lidar.pd_offset"),
        ("max_components", "reduction.max_components"),
        ("process_noise_std_m", "prediction.process_noise_std_m"),
    ],
)
def test_an_old_flat_field_is_refused_naming_its_new_place(old, new):
    with pytest.raises(ValueError, match=re.escape(f"{old} is now {new}")):
        PHDConfig().replace(**{old: 1.0})
    with pytest.raises(ValueError, match=re.escape(f"{old} is now {new}")):
        RobotCentricPHD(**{old: 1.0})
    with pytest.raises(ValueError, match="scan_evidence was removed"):
        PHDConfig().replace(scan_evidence=False)


def test_config_is_frozen_and_keyword_overrides_work():
    cfg = PHDConfig.perera2021()
    with pytest.raises(AttributeError):
        cfg.mode = "lidar-only"  # type: ignore[misc]
    f = RobotCentricPHD(cfg, mode="lidar-only", reduction={"max_components": 10})
    assert f.config.mode == "lidar-only" and f.config.reduction.max_components == 10
    with pytest.raises(ValueError, match="unknown"):
        RobotCentricPHD(cfg, not_a_field=1)
    with pytest.raises(ValueError, match="PHDConfig"):
        RobotCentricPHD(config={"mode": "lidar-only"})  # type: ignore[arg-type]


def test_empty_updates_are_valid_and_apply_missed_detection():
    f = tracked_filter()
    w_before = f.total_weight
    f.update_lidar(np.empty((0, 2)))
    assert f.total_weight < w_before  # (1 - P_d) applied
    w_before = f.total_weight
    f.update_lidar([])
    f.update_camera([])
    f.update_camera(np.empty(0))
    assert f.total_weight < w_before
    f.update_lidar(np.empty((0, 2)), null_bearings=np.empty(0))


def test_lidar_only_mode_ignores_camera():
    f = tracked_filter(PHDConfig.perera2021().replace(mode="lidar-only"))
    before = snapshot(f)
    f.update_camera(np.array([0.3, -2.0]))
    assert_unchanged(f, before)
    with pytest.raises(ValueError, match="bearings"):
        f.update_camera(np.array([np.nan]))


def test_mixture_is_a_read_only_snapshot():
    f = tracked_filter()
    mix = f.mixture
    assert mix is f.mixture  # cached until the state changes
    with pytest.raises(ValueError):
        mix.weights[0] = 5.0
    with pytest.raises(ValueError):
        mix.means[0, 0] = 5.0
    with pytest.raises(ValueError):
        f.table[0, 0] = 5.0
    old = np.array(mix.weights)
    f.update_lidar(np.empty((0, 2)))
    assert np.array_equal(mix.weights, old)  # the old snapshot did not change
    assert mix.weights.shape == (len(mix),) and mix.covs.shape == (len(mix), 2, 2)
    assert np.allclose(mix.covs, mix.covs.transpose(0, 2, 1))


def test_pickle_and_deepcopy_give_independent_equal_filters():
    f = tracked_filter(PHDConfig.perera2021().replace(births={"model": "measurement"}))
    f.update_lidar(np.array([[1.0, 0.3], [-0.5, 0.8], [1.7, -0.2]]))
    for clone in (pickle.loads(pickle.dumps(f)), copy.deepcopy(f), copy.copy(f)):
        assert clone.config == f.config
        assert np.array_equal(clone.table, f.table)
        assert np.array_equal(clone._pending_births, f._pending_births)
        clone.predict(np.array([0.1, 0.0, 0.2]))
        clone.update_lidar(np.array([[0.5, 0.5]]))
        g = copy.deepcopy(f)
        g.predict(np.array([0.1, 0.0, 0.2]))
        g.update_lidar(np.array([[0.5, 0.5]]))
        assert np.array_equal(clone.table, g.table)  # same inputs, same result
        assert not np.array_equal(clone.table, f.table)  # the original did not move


def test_reset_returns_to_empty_prior():
    f = tracked_filter()
    f.reset()
    assert len(f) == 0 and f.total_weight == 0.0
    assert f.estimate()[0].shape == (0, 2)
    assert len(f.mixture) == 0


def test_estimate_reports_heavy_components_round_w_times():
    f = RobotCentricPHD()
    f.set_mixture(
        GaussianMixture(
            np.array([0.3, 0.7, 1.6, 2.4]),
            np.array([[0.0, 1.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]),
            np.tile(0.01 * np.eye(2), (4, 1, 1)),
        )
    )
    pos, w = f.estimate(0.5)
    # 2.4 -> 2 copies, 1.6 -> 2 copies, 0.7 -> 1, 0.3 dropped; sorted by weight.
    assert np.allclose(pos[:, 0], [3.0, 3.0, 2.0, 2.0, 1.0])
    assert np.allclose(w, [1.2, 1.2, 0.8, 0.8, 0.7])
    pos, w = f.estimate(0.2)
    assert pos.shape == (6, 2)
    with pytest.raises(ValueError, match="threshold"):
        f.estimate(float("nan"))


def test_set_mixture_validates():
    f = RobotCentricPHD()
    bad_cov = np.array([[[1.0, 0.0], [0.0, -1.0]]])
    with pytest.raises(ValueError, match="positive definite"):
        f.set_mixture(GaussianMixture(np.ones(1), np.zeros((1, 2)), bad_cov))
    with pytest.raises(ValueError, match="weights"):
        f.set_mixture(GaussianMixture(-np.ones(1), np.zeros((1, 2)), np.eye(2)[None]))
    with pytest.raises(ValueError, match="shape"):
        GaussianMixture(np.ones(2), np.zeros((1, 2)), np.eye(2)[None])


def test_measurement_birth_confirms_a_new_teammate_in_a_few_scans():
    f = RobotCentricPHD(PHDConfig.perera2021().replace(births={"model": "measurement"}))
    z = np.array([[0.8, -0.4]])
    counts = []
    for _ in range(4):
        f.predict(np.zeros(3))
        f.update_lidar(z)
        counts.append(f.estimate()[0].shape[0])
    assert counts[0] == 0 and counts[-1] == 1
    assert np.allclose(f.estimate()[0], z, atol=0.01)
    # A single clutter detection is born but fades away without confirmation.
    f.predict(np.zeros(3))
    f.update_lidar(np.array([[0.8, -0.4], [-1.0, -1.0]]))
    for _ in range(6):
        f.predict(np.zeros(3))
        f.update_lidar(z)
    assert f.estimate()[0].shape[0] == 1


def test_interference_lowers_detection_probability_at_null_bearings():
    f = tracked_filter(PHDConfig.perera2021().replace(mode="lidar-only"))
    g = copy.deepcopy(f)
    bearing = math.atan2(0.3, 1.0)
    f.update_lidar(np.empty((0, 2)))
    g.update_lidar(np.empty((0, 2)), null_bearings=np.full(3, bearing))
    # With nulls at its bearing, the missed detection costs the component less weight.
    assert g.total_weight > f.total_weight


def test_component_count_stays_capped():
    cfg = PHDConfig.perera2021().replace(reduction={"max_components": 8})
    f = RobotCentricPHD(cfg)
    rng = np.random.default_rng(0)
    for _ in range(30):
        f.predict(np.zeros(3))
        f.update_lidar(rng.uniform(-2, 2, size=(12, 2)))
        assert len(f) <= 8
        f.update_camera(rng.uniform(-3, 3, size=10))
        assert len(f) <= 8
    for _ in range(20):  # time updates only: births are still capped
        f.predict(np.zeros(3))
        assert len(f) <= 9
