"""The env's per-agent infos are built on first use and behave as the dicts they stand for."""

from __future__ import annotations

import copy
import pickle

import numpy as np
from gymnasium.utils.env_checker import data_equivalence

from swarm_env import parallel_env
from swarm_env.env import LazyInfo


def _counting_builder():
    calls = []

    def build(x):
        calls.append(x)
        return {"x": x, "arr": np.arange(3.0)}

    return build, calls


def test_nothing_is_built_until_read():
    build, calls = _counting_builder()
    info = LazyInfo(build, 7)
    assert isinstance(info, dict) and calls == []
    assert info["x"] == 7 and calls == [7]
    assert len(info) == 2 and calls == [7]  # built once


def test_every_way_of_reading_sees_the_items():
    build, _ = _counting_builder()
    readers = [
        lambda d: sorted(d),
        lambda d: sorted(d.keys()),
        lambda d: len(d),
        lambda d: bool(d),
        lambda d: "x" in d,
        lambda d: d.get("x"),
        lambda d: sorted(k for k, _ in d.items()),
        lambda d: len(list(d.values())),
        lambda d: sorted(dict(d)),
        lambda d: sorted({**d}),
        lambda d: sorted(d.copy()),
        lambda d: sorted(d | {"y": 1}),
        lambda d: sorted({"y": 1} | d),
        lambda d: repr(d).startswith("{'x': 7"),
        lambda d: sorted(pickle.loads(pickle.dumps(d))),
        lambda d: type(pickle.loads(pickle.dumps(d))).__name__,
        lambda d: sorted(copy.copy(d)),
        lambda d: sorted(copy.deepcopy(d)),
        lambda d: d.pop("x"),
        lambda d: d.setdefault("x", 0),
    ]
    for read in readers:
        assert read(LazyInfo(build, 7)) == read({"x": 7, "arr": np.arange(3.0)}), read


def test_writes_land_on_the_built_items():
    build, _ = _counting_builder()
    info = LazyInfo(build, 1)
    info["comms"] = []
    assert sorted(info) == ["arr", "comms", "x"]
    info = LazyInfo(build, 1)
    info.update(x=2)
    assert info["x"] == 2
    info = LazyInfo(build, 1)
    del info["arr"]
    assert list(info) == ["x"]


def test_comparisons_fill_both_sides():
    build, _ = _counting_builder()
    plain = {"x": 3, "arr": 0}
    other = lambda x: {"x": x, "arr": 0}  # noqa: E731
    assert LazyInfo(other, 3) == plain and plain == LazyInfo(other, 3)
    assert LazyInfo(other, 3) == LazyInfo(other, 3)
    assert LazyInfo(other, 3) != LazyInfo(other, 4)
    assert {"a": LazyInfo(other, 3)} == {"a": LazyInfo(other, 3)}


def test_env_infos_equal_the_eager_dicts():
    env = parallel_env("seed-lab", max_steps=20)
    twin = parallel_env("seed-lab", max_steps=20)
    obs, infos = env.reset(seed=4)
    twin.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(8):
        actions = {a: rng.uniform(-0.2, 0.2, 2) for a in env.agents}
        _, _, _, _, infos = env.step(actions)
        _, _, _, _, twin_infos = twin.step(actions)
        step = env.last_world_step
        for agent in env.agents:
            assert isinstance(infos[agent], LazyInfo)
            eager = env._agent_info(step, agent)
            assert sorted(infos[agent]) == ["comms", "measurements", "stale", "time_s", "truth"]
            assert data_equivalence(dict(infos[agent]), eager)
            assert data_equivalence(dict(infos[agent]), dict(twin_infos[agent]))
