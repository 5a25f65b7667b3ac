"""The formation controller's error diagnosis (experiments/formation_diagnosis.py)."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.formation_diagnosis import (
    LostTeammateTally,
    _CommandTally,
    bearing_holder,
    centroid_distance,
    centroid_estimates,
    classify_components,
    diagnose,
)
from localization.detection import DetectionModel
from swarm_env.config import SIMULATOR_PHD
from swarm_env.world.arena import Layout
from tests.env_kwargs import formation_env


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
    for n, row in out["confident_components"].items():  # the truth's weights are all 1
        assert row["weight_sum"] == pytest.approx(int(n))


def test_oracle_centroids_follow_the_controllers_rule_by_hand():
    """Four confident components of weight 0.6 in a 4-robot swarm, the last spurious. The plain
    controller's oracle keeps the weights (``0.6 sum m / (1 + 1.8)``); the known-N controller's
    scales its three teammates to weight 1 each (``sum m / 4``), as its own centroid does with
    all four (weights 0.75)."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    env = parallel_env(preset="lab-3m-4", task="formation")
    features = np.array([0.6, 2 * 0.6 * np.sin(np.pi / 4)])  # [r, s*] of N = 4
    pts = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.5, 0.5]])
    w = np.full(4, 0.6)
    mate = np.array([True, True, True, False])
    plain = centroid_estimates(load_policy("scripted:formation", env), pts, w, mate, features)
    known = centroid_estimates(
        load_policy("scripted:formation-known-n", env), pts, w, mate, features
    )
    env.close()
    want = {
        "plain": {
            "controller": [0.3 / 3.4, 0.9 / 3.4],
            "oracle": [0.0, 0.6 / 2.8],
            "oracle_weight_1": [0.0, 0.25],
        },
        "known": {
            "controller": [0.75 * 0.5 / 4, 0.75 * 1.5 / 4],
            "oracle": [0.0, 0.25],
            "oracle_weight_1": [0.0, 0.25],
        },
    }
    for name, got in (("plain", plain), ("known", known)):
        for key, value in want[name].items():
            np.testing.assert_allclose(got[key], value, rtol=0, atol=1e-12, err_msg=key)


def test_centroid_distance_by_hand():
    poses = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 0.0], [1.0, 3.0, 2.0]])  # centroid (1, 1)
    np.testing.assert_allclose(
        centroid_distance(poses), [np.sqrt(2.0), np.sqrt(2.0), 2.0], rtol=0, atol=1e-12
    )


def test_the_diagnosis_refuses_the_lattice():
    with pytest.raises(ValueError, match="shape='lattice'"):
        diagnose("lab-3m-4", [200], 0, 5, env_overrides={"task_params": {"shape": "lattice"}})


def test_diagnose_runs_and_its_shares_add_up():
    out = diagnose("lab-3m-4", [200], from_step=20, max_steps=30)
    assert out["observer_steps"] == 4 * 10
    assert set(out["centroid_error_m"]) == {"controller", "oracle", "oracle_weight_1"}
    if out["spurious_per_observer_step"] > 0:
        assert sum(out["spurious_share"].values()) == pytest.approx(1.0)
    # The formation error is the mean of the radial errors' absolute values.
    assert out["radial_error_m"]["abs_mean"] == pytest.approx(out["formation_error_m"])
    counts = out["confident_components"]
    assert sum(row["share"] for row in counts.values()) == pytest.approx(1.0)
    for row in counts.values():  # the spread discount only lowers a weight
        assert row["weight_sum_discounted"] <= row["weight_sum"]
    with pytest.raises(ValueError, match="from-step"):
        diagnose("lab-3m-4", [200], from_step=30, max_steps=30)


def test_env_overrides_reach_the_env_and_cannot_replace_the_diagnosis_settings():
    out = diagnose(
        "lab-3m-4",
        [200],
        from_step=0,
        max_steps=5,
        env_overrides={"phd": {"births": {"camera": "ray"}}},
    )
    assert out["observer_steps"] == 4 * 5
    # the env's own validation sees the override (the filter's config names the field)
    with pytest.raises(ValueError, match=r"lidar\.noise_std_m"):
        diagnose("lab-3m-4", [200], 0, 5, env_overrides={"phd": {"lidar": {"noise_std_m": -1.0}}})
    with pytest.raises(ValueError, match=r"may not set \['task'\]"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, env_overrides={"task": "wander"})


def test_bearing_holder_by_hand():
    """The component nearest the lost teammate's bearing, within the window, holds it; bearings
    wrap at +-pi."""
    teammate = np.array([2.2, 0.0])  # straight ahead, beyond the lidar
    components = np.array([[1.1, 0.03], [0.0, 1.0], [-1.0, 0.0], [1.5, -0.02]])
    window = np.radians(3.0)
    assert bearing_holder(teammate, components, window) == 3  # 0.8 deg off; the first is 1.6
    assert bearing_holder(teammate, components[:3], window) == 0
    assert bearing_holder(np.array([0.0, -2.0]), components, window) == -1
    behind = np.array([-2.0, -0.05])  # bearing -178.6 deg; the third component is at 180
    assert bearing_holder(behind, components, window) == 2
    assert bearing_holder(teammate, np.zeros((0, 2)), window) == -1
    with pytest.raises(ValueError, match="bearing_window_rad must be in"):
        bearing_holder(teammate, components, -0.1)


def _info(camera_bearings, lidar_detections, lidar_nulls=None):
    """An ``infos[agent]`` entry with the given camera frames (lists of bearings, rad) and
    lidar scans (lists of (x, y) detections, body frame, m; and of null-return bearings, rad,
    none by default)."""
    nulls = lidar_nulls or [[] for _ in lidar_detections]
    return {
        "measurements": {
            "camera": [{"bearings_rad": np.asarray(b, dtype=float)} for b in camera_bearings],
            "lidar": [
                {
                    "detections": np.asarray(d, dtype=float).reshape(-1, 2),
                    "null_bearings_rad": np.asarray(n, dtype=float),
                }
                for d, n in zip(lidar_detections, nulls, strict=True)
            ],
        }
    }


def test_lost_teammate_tally_by_hand():
    """Three teammates of one observer: A at 1 m on the +45 deg sector (lost: a wall component
    on its bearing, farther), B at 1 m dead ahead (held; detected in 1 of 2 scans), C at 2.5 m
    (beyond the lidar; lost behind a post at 1.2 m that the camera's blob on C's bearing
    feeds). The second scan has a null return on B's bearing (interference)."""
    phd = SIMULATOR_PHD
    detection = DetectionModel(phd)
    tally = LostTeammateTally(detection, match_m=0.15, bearing_window_rad=np.radians(3.0))
    a = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    teammates = np.array([a, [1.0, 0.0], [-2.5, 0.0]])
    components = np.array([1.6 * a, [1.0, 0.01], [-1.2, 0.01]])
    kinds = np.array(["wall", "teammate", "post"], dtype=object)
    info = _info([[np.pi - 0.01], [0.3]], [[[1.02, 0.0]], [[0.5, 0.5]]], [[], [0.0]])
    tally.add(teammates, np.array([True, False, True]), components, kinds, info)
    out = tally.summary(observer_steps=1)
    lost, near = out["lost_teammates"], out["teammates_in_lidar_range"]
    assert lost["per_observer_step"] == 2
    assert lost["bearing_held_by_share"] == {
        "teammate": 0.0,
        "post": 0.5,
        "red_decoy": 0.0,
        "wall": 0.5,
        "other": 0.0,
        "none": 0.0,
    }
    assert lost["beyond_lidar_range_share"] == 0.5
    assert lost["beyond_lidar_range_share_by_holder"]["post"] == 1.0
    assert lost["holder_in_front_share_by_holder"] == pytest.approx(
        {"teammate": 0, "post": 1, "red_decoy": 0, "wall": 0, "other": 0, "none": 0}
    )
    assert lost["camera_blob_on_bearing_share"] == 0.5  # C's blob (at pi - 0.01); none on A
    # P_range = 1 / (offset + exp(slope (r - midpoint))) = 0.5 there
    half = phd.lidar.pd_midpoint_m + np.log(2.0 - phd.lidar.pd_offset) / phd.lidar.pd_slope_per_m
    assert near["lidar_range_m"] == pytest.approx(half, abs=0.001)
    assert near["per_observer_step"] == 2 and near["on_blind_sector_share"] == 0.5
    assert near["lost_share_on_blind_sector"] == 1.0 and near["lost_share_in_view"] == 0.0
    assert near["losses_on_blind_sector_share"] == 1.0
    p_range = detection.lidar_range_factor(np.array([1.0]))[0]
    assert near["lidar_pd_predicted_per_scan"]["in_view"] == pytest.approx(p_range)
    assert near["lidar_pd_predicted_per_scan"]["blind"] == pytest.approx(0.0, abs=1e-9)
    # With the nulls: scan 1 expects B with P_range, scan 2 with P_range (1 - depth) (the
    # null sits on B's bearing); A, C and B are 45 deg or more apart, so none occludes another.
    with_nulls = near["lidar_pd_predicted_with_nulls_per_scan"]
    assert with_nulls["in_view"] == pytest.approx(
        p_range * (2.0 - phd.lidar.interference_depth) / 2
    )
    assert with_nulls["blind"] == pytest.approx(0.0, abs=1e-9)
    assert near["lidar_detected_per_scan"] == {"blind": 0.0, "in_view": 0.5}
    profile = near["blind_sector_factor_by_offset"]  # A at offset 0 (bin 0), B at 45 deg
    assert profile["measured"][0] == 0.0 and profile["modelled"][0] == pytest.approx(0, abs=1e-9)
    assert profile["measured"][-1] == pytest.approx(0.5 / p_range)  # 1 of 2 scans
    assert profile["modelled"][-1] == pytest.approx(1.0)
    assert sum(w > 0 for w in profile["scans_weighted_by_p_range"]) == 2


def test_lost_teammates_on_the_post_seed_and_on_the_truth():
    """On the true-neighbour table no teammate is lost. On seed 105
    robots 2 and 3 lose each other behind the post between them: post-held losses, beyond the
    lidar's range, with the post in front; the lidar's detections of the teammates in its view
    match the filter's P_d (within 0.1 per scan)."""
    out = diagnose("lab-3m-4", [200], from_step=20, max_steps=30, observation="truth")
    assert out["lost_teammates"]["per_observer_step"] == 0.0
    # The scenario was found with the lidar extractor of the simulated X4's beam footprint and no
    # dropout bridging; the default extractor (plain ray geometry) changes seed 105's episode,
    # so the tool is checked on the scenario as it was found.
    footprint = {"lidar_features": {"beam_footprint_deg": 0.5, "max_gap_beams": 0}}
    out = diagnose("lab-3m-4", [105], from_step=150, max_steps=170, env_overrides=footprint)
    lost = out["lost_teammates"]
    assert lost["bearing_held_by_share"]["post"] > 0.2, lost
    assert lost["beyond_lidar_range_share_by_holder"]["post"] > 0.5, lost
    assert lost["holder_in_front_share_by_holder"]["post"] == 1.0, lost
    # The filter's lidar P_d against the detections: with the default extractor, whose
    # detection curve the simulator's P_d model is fitted to.
    out = diagnose("lab-3m-4", [105], from_step=150, max_steps=170)
    near = out["teammates_in_lidar_range"]
    predicted, detected = near["lidar_pd_predicted_per_scan"], near["lidar_detected_per_scan"]
    assert abs(predicted["in_view"] - detected["in_view"]) < 0.1, near
    # Every scan against the truth: the causes split the missed rate; the posts and the
    # pillars hide teammates from the beams.
    scans = out["lidar_scans_vs_truth"]
    # Only the scans the 20 scored observations read: at most one 7 Hz scan per 0.1 s period
    # per robot, each with 3 teammates (the whole 170-step episode would count 8x more).
    assert 0 < scans["targets_in_range"] <= 20 * 4 * 3, scans
    assert sum(scans["missed_rate_by_cause"].values()) == pytest.approx(scans["missed_rate"])
    assert scans["missed_rate_by_cause"]["hidden"] > 0.0, scans
    # The nulls and the occlusion only lower what the filter expects.
    with_nulls = near["lidar_pd_predicted_with_nulls_per_scan"]
    assert with_nulls["in_view"] <= predicted["in_view"] + 1e-12, near
    with pytest.raises(ValueError, match="bearing-window-deg"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, bearing_window_deg=0.0)
    with pytest.raises(ValueError, match="--policy must be one of"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, policy="scripted:wander")
    with pytest.raises(ValueError, match="--match-m must be > 0, got 0.0"):
        diagnose("lab-3m-4", [200], from_step=0, max_steps=5, match_m=0.0)


STUDENT_ENV = formation_env(
    300, observation="phd", task_params={"progress_weight": 10.0}, lidar_sectors=16, n_robots=3
)


def _student(tmp_path, bias, base="scripted:formation-known-n-fast", saved_env=None):
    """A recurrent student whose correction is ``bias`` everywhere (weights zeroed), saved
    with ``saved_env`` as its env (default: the one it was built in)."""
    import torch

    from agents.sb3.recurrent_student import new_student, save_student
    from swarm_env import parallel_env

    env = parallel_env(**STUDENT_ENV)
    try:
        model = new_student(env.observation_space(env.possible_agents[0]))
    finally:
        env.close()
    with torch.no_grad():
        model.head[-1].weight.zero_()
        model.head[-1].bias.copy_(torch.tensor(bias))
    path = tmp_path / f"student_{bias[0]}_{bias[1]}_{base.split(':')[1]}_{id(saved_env)}.pt"
    save_student(path, model.eval(), saved_env or STUDENT_ENV, base)
    return str(path)


def test_a_student_runs_in_its_own_env_and_reads_the_estimate_as_its_base(tmp_path):
    """A zero correction drives exactly as the base does, in the student's env (3 robots, 16
    lidar sectors): every figure equals the base's run in that env. A non-zero one drives
    differently, and the command tally shows it."""
    student = _student(tmp_path, [0.0, 0.0])
    got = diagnose(None, [200], from_step=10, max_steps=25, policy=student)
    base = diagnose(
        "lab-3m-4",
        [200],
        from_step=10,
        max_steps=25,
        policy="scripted:formation-known-n-fast",
        env_overrides={k: STUDENT_ENV[k] for k in ("task_params", "lidar_sectors", "n_robots")},
    )
    assert got["observer_steps"] == 3 * 15  # the student's 3 robots, not the preset's 4
    assert got["preset"] == "lab-3m-4" and got["observation"] == "phd"
    for key in base:
        if key not in ("policy", "env_overrides", "env_kwargs"):
            assert got[key] == base[key], key
    assert got["env_kwargs"] == {**base["env_kwargs"], "task_params": {"progress_weight": 10.0}}
    # The full speed limit taken off every command (a closed-loop base cannot undo it): every
    # command reverses, at |v| 0.09 against the base's 0.20 m/s here, and the formation suffers.
    braking = _student(tmp_path, [-1.0, 0.0])
    moved = diagnose(None, [200], from_step=10, max_steps=25, policy=braking)
    assert moved["commands"]["mean_abs_speed_mps"] < base["commands"]["mean_abs_speed_mps"] - 0.05
    assert moved["formation_error_m"] > base["formation_error_m"]


def test_the_diagnosis_refuses_a_model_it_cannot_read(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        diagnose(None, [200], 0, 5, policy=str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="must be one of"):
        diagnose(None, [200], 0, 5, policy="scripted:wander")
    not_formation = _student(tmp_path, [0.0, 0.0], base="scripted:wander")
    with pytest.raises(ValueError, match="not a residual on a formation controller"):
        diagnose(None, [200], 0, 5, policy=not_formation)
    with pytest.raises(ValueError, match="observation must be"):
        diagnose(None, [200], 0, 5, observation="pmb")
    other_task = _student(tmp_path, [0.0, 0.0], saved_env={**STUDENT_ENV, "task": "wander"})
    with pytest.raises(ValueError, match="trained on task 'wander'"):
        diagnose(None, [200], 0, 5, policy=other_task)


def test_the_env_is_closed_when_the_diagnosis_fails(tmp_path, monkeypatch):
    """A policy that fails at its first step still leaves the env closed."""
    import agents.policies as policies
    from swarm_env import SwarmEnv

    closed = []
    real_close = SwarmEnv.close
    monkeypatch.setattr(SwarmEnv, "close", lambda self: (closed.append(1), real_close(self)))

    def broken(spec, env):
        def act(obs, infos):
            raise RuntimeError("policy failed")

        act.reset = lambda seed=None: None
        act.top_k = act.n_sectors = act.min_weight = None
        return act

    monkeypatch.setattr(policies, "load_policy", broken)
    monkeypatch.setattr("experiments.formation_diagnosis.estimate_reader", lambda spec, d: d)
    with pytest.raises(RuntimeError, match="policy failed"):
        diagnose("lab-3m-4", [200], 0, 5)
    assert closed


def test_command_tally_by_hand():
    tally = _CommandTally(["a", "b"])
    tally.new_episode()
    tally.add({"a": np.array([0.1, 0.5]), "b": np.array([-0.2, -0.1])})
    tally.add({"a": np.array([0.3, -0.5]), "b": np.array([0.0, 0.1])})
    tally.new_episode()  # no change across episodes
    tally.add({"a": np.array([0.0, 1.0]), "b": np.array([0.0, 0.0])})
    out = tally.summary()
    assert out["mean_abs_speed_mps"] == pytest.approx((0.1 + 0.2 + 0.3) / 6)
    assert out["mean_abs_turn_rate_radps"] == pytest.approx((0.5 + 0.1 + 0.5 + 0.1 + 1.0) / 6)
    assert out["mean_abs_turn_rate_change_radps"] == pytest.approx((1.0 + 0.2) / 2)
