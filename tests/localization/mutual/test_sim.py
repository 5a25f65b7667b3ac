"""P-MultiReg in the simulator with the radio on (``swarm-phd mutual``'s episode), short."""

from __future__ import annotations

import math

import pytest

from swarm_phd.mutual import run_episode


def test_square_start_is_ambiguous_until_a_robot_moves():
    """Four robots on a square (Table 2's start): P-MultiReg returns several formations until
    ugv_3 starts its circle at 5 s; then every teammate is registered uniquely and right."""
    res = run_episode(
        "square", ("p-multireg",), seed=0, observer="ugv_0", duration_s=12.0, n_particles=200
    )
    rows = res["methods"]["p-multireg"]["pairs"]
    assert set(rows) == {"ugv_0->ugv_1", "ugv_0->ugv_2", "ugv_0->ugv_3"}
    for pair, row in rows.items():
        assert 5.0 < row["first_correct_registration_s"] < 9.0, pair
        # Right from the first unique registration to the end (12 s): over a third of the time.
        assert row["pct_distance"] > 30.0 and row["pct_orientation"] > 30.0, pair
        assert row["pct_distance"] < 70.0, pair  # and wrong (ambiguous) before it
    assert math.isfinite(res["methods"]["p-multireg"]["cost_ms_per_step_per_observer"])


def test_bad_arguments():
    with pytest.raises(ValueError, match="scenario"):
        run_episode("moon", ("p-multireg",), seed=0)
    with pytest.raises(ValueError, match="methods"):
        run_episode("square", ("ekf",), seed=0, duration_s=1.0)


def test_lattice_start_is_symmetric_and_its_posts_are_seen():
    """Table 3's start: robots and posts fill a 2 x 3 lattice (symmetric of order 2, so
    ambiguous); the posts moved onto the lattice are where the lidar sees them."""
    import numpy as np

    from localization.mutual.symmetry import symmetry_order
    from swarm_env.env import SwarmEnv
    from swarm_phd.mutual import LATTICE_SPACING_M, _lattice, _place, _place_posts

    robots, posts = _lattice(LATTICE_SPACING_M)
    assert symmetry_order(np.vstack([robots, posts]), 0.01) == 2
    assert symmetry_order(robots, 0.01) == 2
    env = SwarmEnv(
        "lab-3m-4",
        arena={"n_decoy_posts": 2, "n_red_decoys": 0, "n_boxes": 0},
        observation="truth",
        localize=False,
    )
    env.reset(seed=1)
    _place_posts(env, posts)
    _place(env, np.column_stack([robots, np.zeros(4)]))  # all facing +x
    np.testing.assert_array_equal(env.world.layout.posts_xy, posts)
    seen = []
    for _ in range(3):
        env.step({a: np.zeros(2, np.float32) for a in env.possible_agents})
        for rec in env.last_world_step.measurements["ugv_0"].lidar:
            seen.extend(rec.detections.tolist())
    env.close()
    # ugv_0 at (0, -0.4) facing +x: the post at (-0.8, -0.4) is 0.8 m behind it.
    expected = posts[0] - robots[0]
    assert min(np.hypot(*(np.array(seen) - expected).T)) < 0.06


def test_partial_sensing_waypoints_keep_the_ends_out_of_lidar_range():
    """Table 5's staging: from 90 to 150 s every goal of ugv_0 / ugv_1 is more than the
    thesis's lidar range (4.095 m) from every goal of ugv_2 / ugv_3, and the go-to controller
    turns toward the goal, drives forward only, and stops on it."""
    from types import SimpleNamespace

    import numpy as np

    from swarm_phd.mutual import PARTIAL_WAYPOINTS, _partial_actions

    def goals(k, t0, t1):
        ws = PARTIAL_WAYPOINTS[k]
        active = [w for w in ws if w[0] <= t0][-1:] + [w for w in ws if t0 < w[0] < t1]
        return np.array([w[1:] for w in active])

    for a in (0, 1):
        for b in (2, 3):
            d = np.hypot(*(goals(a, 90, 150)[:, None] - goals(b, 90, 150)[None]).T)
            assert d.min() > 4.2, (a, b)
    poses = np.array([[2.3, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    env = SimpleNamespace(last_world_step=SimpleNamespace(truth=SimpleNamespace(poses=poses)))
    ids = ("a", "b", "c", "d")
    cmd = _partial_actions(env, ids, 100.0, 0.1)
    np.testing.assert_array_equal(cmd["a"], [0.0, 0.0])  # on its goal (2.3, 1.0)
    v, w = cmd["b"]  # at the origin facing +x, goal (2.0, -1.1): right and ahead
    assert 0.0 < v <= 0.1 and -0.6 <= w < 0.0
    v, w = cmd["c"]  # goal (-2.5, 1.1): behind, turn in place (left)
    assert v == 0.0 and w == 0.6


def test_compared_localizers_are_scored_alike():
    """``--compare``: a registry localizer on the same feed; an anonymous one has no
    orientation (nan), an identity one has; names are checked."""
    res = run_episode(
        "square",
        ("p-multireg",),
        seed=0,
        observer="ugv_0",
        duration_s=3.0,
        n_particles=50,
        compare=("phd-lc", "id-phd"),
    )
    phd = res["methods"]["phd-lc"]["mean"]
    assert math.isnan(phd["pct_orientation"]) and 0.0 <= phd["pct_distance"] <= 100.0
    # Still robots on the square, in range: the GM-PHD finds them within 0.1 m most of the time.
    assert phd["pct_distance_in_range"] > 50.0
    assert not math.isnan(res["methods"]["id-phd"]["mean"]["pct_orientation"])
    for bad in (("nope",), ("p-multireg",), ("phd-lc", "phd-lc")):
        with pytest.raises(ValueError, match="compare"):
            run_episode("square", ("p-multireg",), seed=0, duration_s=1.0, compare=bad)
