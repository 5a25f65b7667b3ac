"""The formation controller's error diagnosis (agents.formation_diagnosis)."""

from __future__ import annotations

import numpy as np
import pytest

from agents.formation_diagnosis import classify_components, diagnose
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
