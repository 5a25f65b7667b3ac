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
        (
            {"lidar": {"beam_footprint_deg": 0.0}, "lidar_features": {"beam_footprint_deg": 0.5}},
            r"lidar_features.beam_footprint_deg=0.5 exceeds",
        ),
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
        (
            {"lidar": {"blind_sector_centers_deg": (float("nan"), 90.0, 180.0, 270.0)}},
            "blind",
        ),
        ({"odometry": {"pulses_per_revolution": 0.5}}, "pulses_per_revolution"),
        ({"lidar": {"range_max_m": float("inf")}}, "range_max_m"),
        ({"camera": {"range_max_m": 1e300}}, "range_max_m"),
        ({"lidar": {"n_beams": 10**7}}, "n_beams"),  # cost guard: 54 s per step
        ({"camera": {"false_positive_rate": 1e7}}, "false_positive_rate"),  # memory guard
        ({"localizer": "phd-xyz"}, "localizer"),
        ({"phd": {"camera": {"noise_std_deg": float("nan")}}}, r"camera\.noise_std_deg"),
        ({"phd": {"camera_noise_std_deg": 1.0}}, r"camera_noise_std_deg is now phd\.camera\."),
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


@pytest.mark.parametrize(
    "group", ["arena", "robot", "odometry", "lidar", "lidar_features", "camera", "comms", "phd"]
)
@pytest.mark.parametrize("bad", [5, None, "x"])
def test_a_sub_config_of_the_wrong_type_is_refused_naming_it(group, bad):
    """Not an AttributeError deep in a check, nor (``phd=None``) the Perera 2021 study's
    hardware model silently in place of the preset's."""
    from swarm_env.config import make_config

    with pytest.raises(
        ValueError, match=rf"^{group} must be a \w+Config \(as an override.*{bad!r}"
    ):
        make_config("lab-3m-4", **{group: bad})


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"config": {"n_robots": 3}}, "config must be a SwarmConfig"),
        ({"preset": ["lab-3m-4"]}, "preset must be one of"),
        ({"world": 5}, "world must be None or a World, got 5"),
        ({"task": "formation", "task_params": [("radius_m", 1.0)]}, "task_params must be"),
        ({"task": "formation", "task_params": "radius_m"}, "task_params must be"),
    ],
)
def test_bad_constructor_arguments_name_themselves(kwargs, match):
    kwargs = {"preset": "lab-3m-4", **kwargs}
    with pytest.raises(ValueError, match=match):
        parallel_env(kwargs.pop("preset"), **kwargs)


def test_numpy_numbers_are_accepted_and_stored_as_python_numbers():
    """A sweep's np.int64 / np.float32 are numbers: taken (before, refused with "must be an
    integer ... got np.int64(4)"), and stored as Python numbers (the bag's JSON config)."""
    e = parallel_env(
        "lab-3m-4",
        n_robots=np.int64(3),
        control_period_s=np.float64(0.1),
        task="formation",
        task_params={"radius_m": np.float32(0.5)},
    )
    assert e.config.n_robots == 3 and type(e.config.n_robots) is int
    assert type(e.config.control_period_s) is float
    assert e.task.radius_m == 0.5
    with pytest.raises(ValueError, match="n_robots"):
        parallel_env("lab-3m-4", n_robots=np.bool_(True))


@pytest.mark.parametrize(
    "task, params, match",
    [
        ("exploration", {"cell_m": 5.0}, "cell_m=5.0 leaves fewer than 2 cells"),
        ("formation", {"radius_m": 15.0}, "radius_m=15.0 does not fit"),
        ("formation", {"shape": "lattice", "spacing_m": 4.0}, "spacing_m=4.0 does not fit"),
        ("encirclement", {"radius_m": 1.6}, "radius_m=1.6 does not fit"),
        (
            "encirclement",
            {"path": "circle", "intruder_speed_mps": 0.1, "path_radius_m": 40.0},
            "path_radius_m=40.0 does not fit",
        ),
    ],
)
def test_a_task_the_arena_cannot_hold_is_refused_at_construction(task, params, match):
    with pytest.raises(ValueError, match=match):
        parallel_env("lab-3m-4", task=task, task_params=params)


def test_a_failed_reset_leaves_an_env_that_refuses_to_step():
    """A layout that cannot be placed fails reset(); the env must not then step a half-reset
    World (it did: "SimWorld.step() called before reset()", or an IndexError in a task)."""
    e = parallel_env("lab-3m-4", arena={"n_decoy_posts": 1000})
    with pytest.raises(ValueError, match="could not place.*arena.n_decoy_posts"):
        e.reset(seed=0)
    assert e.agents == []
    with pytest.raises(RuntimeError, match=r"step\(\) called before a successful reset\(\)"):
        e.step({a: np.zeros(2) for a in e.possible_agents})


def test_step_before_any_reset_says_so():
    e = parallel_env("lab-3m-4")
    with pytest.raises(RuntimeError, match=r"before a successful reset\(\)"):
        e.step({a: np.zeros(2) for a in e.possible_agents})
