"""Privileged teachers (agents.sb3.privileged) and residual distillation from them."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.sb3.privileged import drop_spurious_rows, load_teacher, with_truth_table  # noqa: E402
from agents.scripted import TABLE_COLUMNS  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from swarm_env.observation import ESTIMATE_COLUMNS  # noqa: E402
from tests.agents.test_residual import KWARGS, train_frozen_residual  # noqa: E402

VALID = ESTIMATE_COLUMNS.index("valid")


def _row(x, y, valid=1.0):
    row = np.zeros(TABLE_COLUMNS, np.float32)
    row[[ESTIMATE_COLUMNS.index(c) for c in ("w", "x_m", "y_m")]] = [1.0, x, y]
    row[VALID] = valid
    return row


def test_drop_spurious_rows_by_hand():
    rows = [_row(1.0, 0.0), _row(0.0, -2.0), _row(0.55, 0.5), _row(0.0, 0.0, valid=0.0)]
    obs = np.concatenate([np.concatenate(rows), [0.1, 0.2, 0.8, 0.9]]).astype(np.float32)
    truth = np.array([[0.0, 0.0], [1.05, 0.05], [0.5, 0.5]])  # self at the origin, 2 mates
    out = drop_spurious_rows(obs, truth, top_k=4, match_m=0.1)
    valid = out[: 4 * TABLE_COLUMNS].reshape(4, TABLE_COLUMNS)[:, VALID]
    assert valid.tolist() == [1.0, 0.0, 1.0, 0.0]
    np.testing.assert_array_equal(out[4 * TABLE_COLUMNS :], obs[4 * TABLE_COLUMNS :])
    assert obs[TABLE_COLUMNS + VALID] == 1.0  # the input is not modified
    # Nobody but the robot itself: every row goes.
    alone = drop_spurious_rows(obs, np.zeros((1, 2)), top_k=4)
    assert not alone[: 4 * TABLE_COLUMNS].reshape(4, TABLE_COLUMNS)[:, VALID].any()


def test_the_teacher_needs_truth_and_equals_the_controller_without_spurious_rows():
    env = parallel_env(**{**KWARGS, "observation": "phd"})
    teacher = load_teacher("privileged:formation", env)
    scripted = load_teacher("scripted:formation", env)
    obs, infos = env.reset(seed=3)
    with pytest.raises(ValueError, match="truth"):
        teacher(obs, {a: {} for a in obs})
    with pytest.raises(ValueError, match="privileged teacher"):
        load_teacher("privileged:nope", env)
    # Truth placed on every valid component: nothing is dropped, so the commands agree.
    k = env.config.top_k
    fake = {}
    for a, o in obs.items():
        table = o[: k * TABLE_COLUMNS].reshape(k, TABLE_COLUMNS)
        xy = table[table[:, VALID] > 0.5][:, [ESTIMATE_COLUMNS.index(c) for c in ("x_m", "y_m")]]
        fake[a] = {**infos[a], "truth": {"neighbours_xy": np.vstack([[0.0, 0.0], xy])}}
    teacher.reset(3)
    scripted.reset(3)
    a, b = teacher(obs, fake), scripted(obs, fake)
    for agent in obs:
        np.testing.assert_array_equal(a[agent], b[agent])


def test_residual_distillation_from_the_privileged_teacher(tmp_path):
    """`swarm-phd train --residual scripted:formation --warm-start privileged:formation`: the
    labels are corrections (teacher - base), the fit beats the best constant on its own data,
    and the saved student runs on an env whose infos carry no truth."""
    from agents.policies import load_policy

    path = train_frozen_residual(
        tmp_path / "run",
        residual_observes_base=True,
        warm_start={"teacher": "privileged:formation", "steps": 480, "rounds": 2, "epochs": 5},
    )
    summary = json.loads((tmp_path / "run" / "warm_start.json").read_text())
    assert summary["teacher"] == "privileged:formation"
    assert summary["residual"] == "scripted:formation"
    assert summary["train_fit"]["r2_v"] > 0.0
    env = parallel_env(**KWARGS)
    student = load_policy(str(path), env)
    obs, infos = env.reset(seed=100)
    for _ in range(5):
        bare = {a: {k: v for k, v in i.items() if k != "truth"} for a, i in infos.items()}
        obs, _, _, _, infos = env.step(student(obs, bare))


def test_residual_labels_are_the_teachers_correction_of_the_base():
    """A teacher that *is* the base controller has nothing to correct: every label is 0 (its
    random walk, on its own generator, is labelled 0 too). The privileged teacher corrects
    the base where a decoy or ghost is tracked, so some labels are not 0."""
    from agents.sb3.warm_start import collect_demonstrations

    same = collect_demonstrations(
        KWARGS, "scripted:formation", 320, n_copies=2, residual="scripted:formation"
    )
    assert len(same) == 320
    np.testing.assert_array_equal(same.actions, 0.0)
    # A teacher that only random-walks (Perera 2021's wander) has nothing to teach either.
    wander = collect_demonstrations(
        KWARGS, "scripted:wander", 160, n_copies=2, residual="scripted:formation"
    )
    np.testing.assert_array_equal(wander.actions, 0.0)
    privileged = collect_demonstrations(
        KWARGS, "privileged:formation", 320, n_copies=2, residual="scripted:formation"
    )
    assert np.abs(privileged.actions).max() > 0.05


def test_the_teacher_is_a_named_policy_for_scoring():
    """`--baselines privileged:formation` (report, evaluate): it runs on the PHD observation,
    where the simulator's infos carry the truth it reads."""
    from agents.policies import load_policy, policy_observation

    assert policy_observation("privileged:formation") == "phd"
    env = parallel_env(**{**KWARGS, "observation": "phd"})
    teacher = load_policy("privileged:formation", env)
    obs, infos = env.reset(seed=1)
    assert set(teacher(obs, infos)) == set(obs)


def test_truth_table_teacher_equals_the_controller_on_the_truth_observation():
    """`privileged:NAME@truth` inside an env on the estimate commands what `scripted:NAME`
    commands in the same state on `observation="truth"`: same seed, same world, so the two
    envs' truth, lidar and odometry agree, and only the table differs."""
    from agents.policies import load_policy, policy_observation

    name = "formation-known-n-fast"
    assert policy_observation(f"privileged:{name}@truth") == "phd"
    on_estimate = parallel_env(**{**KWARGS, "observation": "phd", "max_steps": 40})
    on_truth = parallel_env(**{**KWARGS, "observation": "truth", "max_steps": 40})
    teacher = load_policy(f"privileged:{name}@truth", on_estimate)
    scripted = load_policy(f"scripted:{name}", on_truth)
    obs_e, infos_e = on_estimate.reset(seed=5)
    obs_t, infos_t = on_truth.reset(seed=5)
    teacher.reset(5)
    scripted.reset(5)
    k = on_estimate.config.top_k
    compared = 0
    while on_estimate.agents:  # the whole episode
        act_e, act_t = teacher(obs_e, infos_e), scripted(obs_t, infos_t)
        for agent in obs_e:
            np.testing.assert_array_equal(act_e[agent], act_t[agent])
            # The swapped observation is the truth env's, entry for entry.
            truth = infos_e[agent]["truth"]
            xy, in_range = truth["neighbours_xy"], truth["in_range"]["lidar"]
            swapped = with_truth_table(obs_e[agent], xy, in_range, k)
            np.testing.assert_array_equal(swapped, obs_t[agent])
            compared += 1
        # Both envs step with the same commands: their worlds stay identical.
        obs_e, _, _, _, infos_e = on_estimate.step(act_e)
        obs_t, _, _, _, infos_t = on_truth.step(act_t)
        assert on_estimate.agents == on_truth.agents
    assert compared == 40 * len(on_estimate.possible_agents)
    obs_e, _ = on_estimate.reset(seed=6)
    with pytest.raises(ValueError, match="in_range"):
        teacher(obs_e, {a: {"truth": {"neighbours_xy": np.zeros((4, 2))}} for a in obs_e})
    with pytest.raises(ValueError, match="unknown controller 'nope'"):
        load_teacher("privileged:nope@truth", on_estimate)
    with pytest.raises(ValueError, match="scripted:wander reads no neighbour table"):
        load_teacher("privileged:wander@truth", on_estimate)


def test_the_truth_teacher_scores_as_the_controller_on_the_truth():
    """`report.score("privileged:NAME@truth")` runs in an env on the estimate and reads the
    truth from its infos; `scripted:NAME@truth` runs in an env on the truth: same world,
    same commands, same scores."""
    from agents.evaluation import score

    kwargs = {**KWARGS, "max_steps": 20}
    name = "formation-known-n-fast"
    teacher = score(f"privileged:{name}@truth", kwargs, [100, 101])
    scripted = score(f"scripted:{name}@truth", kwargs, [100, 101])
    assert teacher["per_seed"] == scripted["per_seed"]
    on_estimate = score(f"scripted:{name}", kwargs, [100, 101])
    assert on_estimate["per_seed"] != teacher["per_seed"]


def test_correction_labels_are_the_earlier_inline_formula():
    """Bit for bit what collect_demonstrations computed before the labels were factored out:
    the difference stored as float32, then divided by the float64 bounds and clipped."""
    from agents.sb3.warm_start import correction_labels

    rng = np.random.default_rng(0)
    agents = [f"robot_{i}" for i in range(64)]
    teacher = {a: rng.normal(0.0, 1.0, 2) for a in agents}
    base = {a: rng.normal(0.0, 1.0, 2) for a in agents}
    wandering = set(agents[::5])
    high = np.array([0.3, 1.5])
    earlier = np.zeros((len(agents), 2), np.float32)
    earlier[:] = [np.zeros(2) if a in wandering else teacher[a] - base[a] for a in agents]
    earlier = np.clip(earlier / high, -1.0, 1.0).astype(np.float32)
    got = correction_labels(teacher, base, wandering, agents, high)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, earlier)
    assert (got[::5] == 0).all() and (np.abs(got) == 1.0).any()  # wandering rows; clipping


def test_truth_table_teacher_corrects_the_base_where_the_estimate_differs():
    """The labels of `privileged:NAME@truth` on the base `scripted:NAME` are the corrections the
    estimate costs: near 0 where the estimate has every teammate within centimetres, large
    where it has lost one (or not yet found it, early in an episode)."""
    from agents.sb3.warm_start import collect_demonstrations

    name = "formation-known-n-fast"
    demos = collect_demonstrations(
        KWARGS, f"privileged:{name}@truth", 320, n_copies=2, residual=f"scripted:{name}"
    )
    assert len(demos) == 320
    assert np.abs(demos.actions).max() > 0.05
    assert (np.abs(demos.actions) < 0.02).all(axis=1).any()  # some states: nearly the same
