"""The swarm in PettingZoo's registries (``swarm_phd/<task>_v0``, parallel and AEC), its AEC
``env()``, and PettingZoo's own API tests on both forms."""

from __future__ import annotations

import numpy as np
import pettingzoo
import pytest
from pettingzoo.test import api_test, parallel_api_test

import swarm_env
from swarm_env import swarm_v0
from swarm_env.env import SwarmEnv
from swarm_env.registration import env_id, registered_ids
from swarm_env.tasks import TASKS

SMALL = {"preset": "lab-3m-4"}


@pytest.mark.parametrize("kind", ["parallel", "aec"])
def test_every_task_is_registered(kind):
    registry = pettingzoo.parallel_registry if kind == "parallel" else pettingzoo.aec_registry
    for task in TASKS:
        assert pettingzoo.spec(kind, env_id(task)).id in registry
    assert registered_ids() == [f"swarm_phd/{t}_v0" for t in TASKS]


def test_make_parallel_builds_the_task_and_steps():
    env = pettingzoo.make("parallel", "swarm_phd/formation_v0", **SMALL)
    assert isinstance(env, SwarmEnv)
    assert env.task.name == "formation"
    assert env.config.n_robots == 4
    obs, _ = env.reset(seed=3)
    actions = {a: env.action_space(a).sample() for a in env.agents}
    obs2, rewards, terms, truncs, _ = env.step(actions)
    assert set(obs2) == set(env.possible_agents)
    assert all(np.isfinite(r) for r in rewards.values())
    env.close()


def test_make_aec_steps_the_swarm_once_per_cycle():
    env = pettingzoo.make("aec", "swarm_phd/wander_v0", max_cycles=3, **SMALL)
    env.reset(seed=1)
    inner = env.unwrapped
    assert isinstance(inner, SwarmEnv) and inner.config.max_steps == 3
    cycles = 0
    for agent in env.agent_iter():
        obs, reward, term, trunc, info = env.last()
        assert obs.shape == env.observation_space(agent).shape
        env.step(None if term or trunc else env.action_space(agent).sample())
        if agent == env.possible_agents[-1] and not (term or trunc):
            cycles += 1
            assert inner._step_count == cycles  # the swarm moves after the last robot acts
    assert cycles == 3
    env.close()


def test_registered_id_fixes_the_task_and_reads_max_cycles():
    with pytest.raises(ValueError, match=r"swarm_phd/formation_v0 is the 'formation' task"):
        pettingzoo.make("parallel", "swarm_phd/formation_v0", task="wander", **SMALL)
    with pytest.raises(ValueError, match="max_cycles=5 and max_steps=7"):
        pettingzoo.make("parallel", "swarm_phd/wander_v0", max_cycles=5, max_steps=7, **SMALL)
    env = pettingzoo.make("parallel", "swarm_phd/wander_v0", max_cycles=9, **SMALL)
    assert env.config.max_steps == 9
    env.close()


def test_unknown_id_names_the_registered_ones():
    with pytest.raises(pettingzoo.env_registry.exceptions.NameNotFound, match="formation"):
        pettingzoo.make("parallel", "swarm_phd/flocking_v0")


def test_package_and_versioned_module_entry_points():
    aec = swarm_env.env(preset="lab-3m-4", task="exploration")
    assert isinstance(aec, pettingzoo.AECEnv)
    assert aec.unwrapped.task.name == "exploration"
    assert isinstance(swarm_v0.parallel_env(preset="lab-3m-4"), SwarmEnv)
    assert isinstance(swarm_v0.env(preset="lab-3m-4"), pettingzoo.AECEnv)
    assert isinstance(swarm_v0.raw_env(preset="lab-3m-4"), pettingzoo.AECEnv)


def test_parallel_api_test_on_a_registered_env():
    env = pettingzoo.make("parallel", "swarm_phd/formation_v0", max_cycles=30, **SMALL)
    parallel_api_test(env, num_cycles=35)


def test_aec_api_test_on_a_registered_env():
    env = pettingzoo.make("aec", "swarm_phd/formation_v0", max_cycles=20, **SMALL)
    api_test(env, num_cycles=25)
