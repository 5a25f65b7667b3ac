"""The formation controller's error diagnosis (agents.formation_diagnosis)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agents.formation_diagnosis import classify_components, diagnose, lost_teammate_cause
from swarm_env.world.arena import Layout


def test_classify_components_by_hand():
    layout = Layout(
        posts_xy=np.array([[1.0, 1.0]]),
        red_decoys_xy=np.array([[-1.0, 0.0]]),
        boxes=np.zeros((0, 5)),
    )
    teammates = np.array([[0.0, 0.0], [1.1, 1.0]])  # the second stands beside the post
    world = np.array(
        [
            [0.1, 0.0],  # on teammate 0
            [1.12, 1.0],  # on teammate 1, and near the post: a teammate wins
            [0.95, 1.0],  # on the post, 0.15 m from teammate 1 (the match radius is 0.1)
            [-1.1, 0.1],  # on the red decoy
            [0.0, 1.45],  # 5 cm from the wall y = 1.5
            [0.5, -0.5],  # nothing
        ]
    )
    kind = classify_components(world, teammates, layout, (1.5, 1.5), match_m=0.1)
    assert kind.tolist() == ["teammate", "teammate", "post", "red_decoy", "wall", "other"]
    assert classify_components(np.zeros((0, 2)), teammates, layout, (1.5, 1.5)).shape == (0,)


def test_on_true_neighbours_every_component_is_a_teammate():
    """With the true-neighbour table every component sits on a teammate, so nothing is
    spurious and the controller's centroid is the oracle's (a wrong body-to-world rotation
    would misplace them)."""
    out = diagnose("lab-3m-4", [200], from_step=20, max_steps=30, observation="truth")
    assert out["spurious_per_observer_step"] == 0.0
    assert out["teammate_error_m"]["median"] == pytest.approx(0.0, abs=1e-5)
    errors = out["centroid_error_m"]
    assert errors["controller"] == errors["oracle"]


def test_diagnose_runs_and_its_shares_add_up():
    out = diagnose("lab-3m-4", [200], from_step=20, max_steps=30)
    assert out["observer_steps"] == 4 * 10
    assert set(out["centroid_error_m"]) == {"controller", "oracle", "oracle_weight_1"}
    if out["spurious_per_observer_step"] > 0:
        assert sum(out["spurious_share"].values()) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="from-step"):
        diagnose("lab-3m-4", [200], from_step=30, max_steps=30)


def test_env_overrides_reach_the_env_and_cannot_replace_the_diagnosis_settings():
    out = diagnose(
        "lab-3m-4", [200], from_step=0, max_steps=5, env_overrides={"phd": {"scan_evidence": True}}
    )
    assert out["observer_steps"] == 4 * 5
    # the env's own validation sees the override (the filter's config names the field)
    with pytest.raises(ValueError, match="scan_margin_sigmas"):
        diagnose("lab-3m-4", [200], 0, 5, env_overrides={"phd": {"scan_margin_sigmas": -1.0}})
    with pytest.raises(ValueError, match=r"may not set \['task'\]"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, env_overrides={"task": "wander"})


def test_lost_teammate_cause_by_hand():
    """The component nearest the lost teammate's bearing, within the window, names the cause;
    bearings wrap at +-pi."""
    teammate = np.array([2.2, 0.0])  # straight ahead, beyond the lidar
    components = np.array([[1.1, 0.03], [0.0, 1.0], [-1.0, 0.0]])
    kinds = np.array(["post", "teammate", "wall"], dtype=object)
    window = np.radians(3.0)
    assert lost_teammate_cause(teammate, components, kinds, window) == "post"  # 1.6 deg off
    assert lost_teammate_cause(np.array([0.0, -2.0]), components, kinds, window) == "none"
    behind = np.array([-2.0, -0.05])  # bearing -178.6 deg; the wall component is at 180
    assert lost_teammate_cause(behind, components, kinds, window) == "wall"
    assert lost_teammate_cause(teammate, np.zeros((0, 2)), np.zeros(0), window) == "none"


def test_lost_teammates_add_up_and_truth_loses_none():
    """On the true-neighbour table no teammate is lost; on the PHD the shares add up to 1."""
    out = diagnose("lab-3m-4", [200], from_step=20, max_steps=30, observation="truth")
    assert out["lost_teammates"]["per_observer_step"] == 0.0
    out = diagnose("lab-3m-4", [105], from_step=150, max_steps=170)
    lost = out["lost_teammates"]
    assert lost["per_observer_step"] > 0  # seed 105: a teammate behind a post (docs/results.md)
    assert sum(lost["bearing_held_by_share"].values()) == pytest.approx(1.0)
    assert lost["bearing_held_by_share"]["post"] > 0
    assert 0.0 <= lost["camera_blob_on_bearing_share"] <= 1.0
    near = out["teammates_in_lidar_range"]
    blind = near["on_blind_sector_share"]
    assert 0.0 < blind < 1.0
    # The overall lost share is the blind and in-view shares, weighted by how often each is.
    mixed = blind * near["lost_share_on_blind_sector"] + (1 - blind) * near["lost_share_in_view"]
    assert near["lost_share"] == pytest.approx(mixed)
    with pytest.raises(ValueError, match="bearing-window-deg"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, bearing_window_deg=0.0)
    with pytest.raises(ValueError, match="--policy must be one of"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, policy="scripted:wander")


def test_lidar_blind_sector_factor_by_hand():
    """Behind a pillar (+-45, +-135 deg) the factor is ~0; between them and dead ahead ~1; at
    half a sector's width off its centre it is 1 - exp((cos(5 deg) - 1) / sigma^2), sigma = 5 deg
    (seed eq. 18's bump)."""
    from agents.scripted import lidar_blind_sector_factor
    from swarm_env.config import SIMULATOR_PHD

    deg = np.radians([45.0, -135.0, 0.0, 90.0, 50.0])
    got = lidar_blind_sector_factor(deg, SIMULATOR_PHD)
    sigma = np.radians(5.0)
    edge = 1.0 - np.exp((np.cos(np.radians(5.0)) - 1.0) / sigma**2)
    np.testing.assert_allclose(got[:4], [0.0, 0.0, 1.0, 1.0], atol=1e-9)
    assert got[4] == pytest.approx(edge, rel=1e-3)
    none = dataclasses.replace(
        SIMULATOR_PHD, blind_sector_centers_deg=(), blind_sector_widths_deg=()
    )
    np.testing.assert_array_equal(lidar_blind_sector_factor(deg, none), np.ones(5))
