"""Bad input: clear ValueErrors naming the field and value, raised before any state changes."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import parallel_env


@pytest.fixture
def env():
    e = parallel_env("seed-lab")
    e.reset(seed=0)
    return e


def _state(env):
    return (
        env.world.poses().copy(),
        env.time_s,
        env.localizers[0].mixture.weights.copy(),
        env.world.motor_speeds.copy(),
        env._rng.bit_generator.state,
    )


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.array([np.nan, 0.0]), "ugv_2.*finite"),
        (np.array([0.1, np.inf]), "ugv_2.*finite"),
        (np.array([0.1, 0.0, 0.0]), r"ugv_2.*shape \(2,\)"),
        ("fast", "ugv_2.*real numbers"),
        (np.array([True, False]), "ugv_2.*real numbers"),
        ([True, 0.0], "ugv_2.*real numbers"),
        (["0.1", "0.2"], "ugv_2.*real numbers"),
        (np.array([0.1 + 1j, 0.0]), "ugv_2.*real numbers"),
        ([10**400, 0.0], "ugv_2.*finite"),
    ],
)
def test_bad_action_raises_before_state_changes(env, bad, match):
    env.step({a: np.array([0.2, 0.1]) for a in env.agents})
    before = _state(env)
    actions = {a: np.zeros(2) for a in env.agents}
    actions["ugv_2"] = bad
    with pytest.raises(ValueError, match=match):
        env.step(actions)
    after = _state(env)
    assert np.array_equal(before[0], after[0]) and before[1] == after[1]
    assert np.array_equal(before[2], after[2]) and np.array_equal(before[3], after[3])
    assert before[4] == after[4]  # no random draw either


def test_autograd_tensor_action_is_refused(env):
    torch = pytest.importorskip("torch")
    actions = {a: np.zeros(2) for a in env.agents}
    actions["ugv_1"] = torch.zeros(2, requires_grad=True)
    with pytest.raises(ValueError, match="ugv_1.*requires grad"):
        env.step(actions)
    assert env.time_s == 0.0


@pytest.mark.parametrize("seed", [True, -1, 1.5, "0"])
def test_bad_reset_seed(env, seed):
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=seed)


def test_unknown_and_missing_agents(env):
    actions = {a: np.zeros(2) for a in env.agents}
    with pytest.raises(ValueError, match="ugv_99"):
        env.step({**actions, "ugv_99": np.zeros(2)})
    del actions["ugv_1"]
    with pytest.raises(ValueError, match="missing.*ugv_1"):
        env.step(actions)
    assert env.time_s == 0.0


def test_out_of_range_action_is_clipped(env):
    env.step({a: np.array([50.0, -50.0]) for a in env.agents})
    for _ in range(20):
        env.step({a: np.array([50.0, -50.0]) for a in env.agents})
    speeds = env.world.motor_speeds
    assert np.allclose(speeds[:, 0], env.config.robot.max_speed_mps)
    assert np.allclose(speeds[:, 1], -env.config.robot.max_turn_rate_radps)


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"lidar": {"rate_hz": -7.0}}, "rate_hz.*-7"),
        ({"camera": {"rate_hz": 0.0}}, "rate_hz"),
        ({"odometry": {"rate_hz": -1.0}}, "odometry.rate_hz"),
        ({"n_robots": 0}, "n_robots"),
        ({"n_robots": 500}, "n_robots"),
        ({"n_robots": 150}, "do not fit"),
        ({"robot": {"max_speed_mps": -0.3}}, "max_speed_mps"),
        ({"robot": {"max_speed_mps": 5.0}}, "max_speed_mps"),
        ({"arena": {"n_boxes": -1}}, "n_boxes"),
        ({"control_period_s": 0.0}, "control_period_s"),
        ({"observation": "pixels"}, "observation"),
        ({"warp_drive": True}, "unknown config key 'warp_drive'"),
        ({"lidar": {"colour": 1}}, "unknown config key 'lidar.colour'"),
        ({"lidar": {"beam_footprint_deg": 0.0}}, r"lidar_features.beam_footprint_deg=0.5 exceeds"),
        ({"lidar_features": {"beam_footprint_deg": -1.0}}, "beam_footprint_deg"),
    ],
)
def test_impossible_config_raises_at_construction(overrides, match):
    with pytest.raises(ValueError, match=match):
        parallel_env("seed-sim", **overrides)


def test_unknown_preset_and_render_mode():
    with pytest.raises(ValueError, match="preset"):
        parallel_env("seed-moon")
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env("seed-lab", render_mode="ascii")


def test_sensor_faster_than_the_substeps_is_refused():
    with pytest.raises(ValueError, match="camera.rate_hz=30.0 exceeds"):
        parallel_env("seed-lab", physics_substeps=2)


@pytest.mark.parametrize(
    "override, match",
    [
        ({"localize": "no"}, "localize"),
        ({"lidar": {"blind_sector_centers_deg": (float("nan"), 90.0, 180.0, 270.0)}}, "blind"),
        ({"odometry": {"pulses_per_revolution": 0.5}}, "pulses_per_revolution"),
        ({"lidar": {"range_max_m": float("inf")}}, "range_max_m"),
        ({"camera": {"range_max_m": 1e300}}, "range_max_m"),
        ({"lidar": {"n_beams": 10**7}}, "n_beams"),  # cost guard: 54 s per step
        ({"camera": {"false_positive_rate": 1e7}}, "false_positive_rate"),  # memory guard
        ({"localizer": "phd-xyz"}, "localizer"),
        ({"phd": {"camera_noise_std_deg": float("nan")}}, "camera_noise_std_deg"),
    ],
)
def test_bad_config_is_refused_at_construction_naming_the_field(override, match):
    from swarm_env.config import make_config

    with pytest.raises(ValueError, match=match):
        make_config("lab-3m-4", **override)


def test_every_numeric_config_field_refuses_non_numbers_and_non_finite_values():
    """Each int / float field of every sub-config, set to NaN, inf, a string, None or a bool:
    a ValueError naming the field, at construction (never a TypeError inside a comparison)."""
    import dataclasses

    from swarm_env.config import SwarmConfig, make_config

    base = make_config("lab-3m-4")
    checked = 0
    for group in dataclasses.fields(SwarmConfig):
        sub = getattr(base, group.name)
        if not dataclasses.is_dataclass(sub):
            continue
        for f in dataclasses.fields(sub):
            if f.type not in ("int", "float"):
                continue
            for bad in (float("nan"), float("inf"), "x", None, True):
                with pytest.raises(ValueError, match=f.name):
                    make_config("lab-3m-4", **{group.name: {f.name: bad}})
            checked += 1
    assert checked > 40  # every sensor, arena, robot and filter field
