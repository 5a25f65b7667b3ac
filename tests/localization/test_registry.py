"""The Localizer protocol and registry: every family builds by name, steps on the same feed and
exposes its estimate in the one documented form."""

from __future__ import annotations

import numpy as np
import pytest

from localization.feed import SwarmFeed
from localization.protocol import Localizer, LocalizerSlice
from localization.registry import LOCALIZERS, make_localizer
from swarm_env import parallel_env


@pytest.fixture(scope="module")
def feeds():
    """Feeds of a short lab-3m-4 wander episode (4 robots, random motion), with truth."""
    env = parallel_env("lab-3m-4", max_steps=60)
    env.reset(seed=4)
    rng = np.random.default_rng(4)
    out = []
    for _ in range(40):
        env.step({a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents})
        out.append(SwarmFeed.from_world_step(env.last_world_step, env.possible_agents))
    phd = env.config.phd
    env.close()
    return phd, out


@pytest.mark.parametrize("name", sorted(LOCALIZERS))
def test_every_family_follows_the_protocol(name, feeds):
    phd, stream = feeds
    loc = make_localizer(name, 4, phd, seed=1)
    assert isinstance(loc, Localizer) and loc.name == name and loc.n_robots == 4
    for feed in stream[:15]:
        loc.step(feed)
    table, counts = loc.padded_tables()
    assert table.shape[:2] == (6, 4) and counts.shape == (4,)
    for r in range(4):
        mix = loc.mixture(r)
        n = counts[r]
        np.testing.assert_allclose(table[0, r, :n], mix.weights)
        np.testing.assert_allclose(table[1:3, r, :n].T, mix.means)
        np.testing.assert_allclose(table[3, r, :n], mix.covs[:, 0, 0])
        assert np.all(np.isfinite(table[:, r, :n]))
        if loc.weight_meaning == "existence":
            assert np.all((mix.weights >= 0) & (mix.weights <= 1))
        means, _ = loc.estimate(r, 0.5)
        assert means.ndim == 2 and means.shape[1] == 2
        ids = loc.identities(r)
        assert isinstance(ids, dict) and (loc.has_identities or not ids)
    loc.reset([1])
    assert loc.padded_tables()[1][1] == 0 or loc.has_identities  # robot 1 emptied
    loc.reset()
    with pytest.raises(ValueError, match="robots"):
        loc.step(SwarmFeed.empty(3))


@pytest.mark.parametrize("family", ["phd", "pmb"])
def test_compiled_bank_equals_its_reference_on_env_feeds(family, feeds):
    phd, stream = feeds
    bank = make_localizer(f"{family}-lc", 4, phd)
    ref = make_localizer(f"{family}-reference-lc", 4, phd)
    for feed in stream:
        bank.step(feed)
        ref.step(feed)
    for r in range(4):
        a, b = bank.mixture(r), ref.mixture(r)
        assert len(a.weights) == len(b.weights)
        order_a, order_b = np.lexsort(a.means.T), np.lexsort(b.means.T)
        np.testing.assert_allclose(a.weights[order_a], b.weights[order_b], atol=1e-10)
        np.testing.assert_allclose(a.means[order_a], b.means[order_b], atol=1e-10)
        np.testing.assert_allclose(a.covs[order_a], b.covs[order_b], atol=1e-10)


def test_slice_of_a_shared_localizer_equals_a_lone_one(feeds):
    phd, stream = feeds
    shared = make_localizer("phd-lc", 12, phd)
    middle = LocalizerSlice(shared, 4, 4)
    lone = make_localizer("phd-lc", 4, phd)
    for feed in stream:
        empty = SwarmFeed.empty(4)
        shared.step(SwarmFeed.concat([empty, feed, empty]))
        lone.step(feed)
    t_slice, c_slice = middle.padded_tables()
    t_lone, c_lone = lone.padded_tables()
    np.testing.assert_array_equal(c_slice, c_lone)
    for r in range(4):
        np.testing.assert_array_equal(t_slice[:, r, : c_lone[r]], t_lone[:, r, : c_lone[r]])
    assert shared.padded_tables()[1][[0, 1, 2, 3, 8, 9, 10, 11]].sum() == 0
    middle.reset([2])
    assert shared.padded_tables()[1][6] == 0 and lone.padded_tables()[1][2] > 0


def test_unknown_names_and_bad_counts_are_named():
    with pytest.raises(ValueError, match="localizer must be one of.*'nope'"):
        make_localizer("nope", 3)
    with pytest.raises(ValueError, match="n_robots"):
        make_localizer("phd-lc", 0)
    with pytest.raises(ValueError, match="localizer must be one of"):
        parallel_env("lab-3m-4", localizer="phd-xx")


def test_agents_observe_pmb_existence():
    env = parallel_env("lab-3m-4", localizer="pmb-lc", max_steps=30)
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(25):
        obs, *_ = env.step({a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents})
    layout = env.encoder.layout
    table = layout.table(obs["ugv_0"])
    w = table[:, layout.column("w")]
    valid = table[:, layout.column("valid")] > 0
    assert valid.any() and np.all((w[valid] >= 0) & (w[valid] <= 1))
    assert env.localizer.weight_meaning == "existence"


def test_identity_families_show_teammates_only_and_cannot_be_sliced(feeds):
    phd, stream = feeds
    loc = make_localizer("id-phd", 4, phd)
    for feed in stream:
        loc.step(feed)
    for r in range(4):
        tags = np.asarray(loc.filters[r].tags)
        assert len(loc.mixture(r).weights) == int((tags >= 0).sum())  # no static class
    with pytest.raises(ValueError, match="identities"):
        LocalizerSlice(loc, 0, 2)


def test_batched_vec_env_gives_identity_families_one_localizer_per_copy():
    """Identity families cannot be sliced from one shared localizer: each copy of the batched
    VecEnv makes its own (its rollout equals a lone env's: tests/agents/test_batched_vec_env)."""
    pytest.importorskip("stable_baselines3")
    from agents.sb3.batched import BatchedSwarmVecEnv

    vec = BatchedSwarmVecEnv({"preset": "lab-3m-4", "localizer": "id-phd"}, 2)
    assert vec.shared is None
    first, second = (env.localizer for env in vec.envs)
    assert first is not second and not isinstance(first, LocalizerSlice)
    assert first.name == "id-phd" and first.n_robots == 4
    vec.close()
