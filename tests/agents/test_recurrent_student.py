"""agents.sb3.recurrent_student: a GRU residual on the estimate, distilled by DAgger."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.policies import load_policy, policy_observation  # noqa: E402
from agents.sb3.recurrent_student import (  # noqa: E402
    RecurrentStudentPolicy,
    _digest,
    load_student,
    new_student,
    read_student_metadata,
    save_student,
)
from agents.sb3.residual import ResidualBase, base_in_unit_scale, compose  # noqa: E402
from agents.sb3.sequences import collect_sequences  # noqa: E402
from experiments.recurrent_student import main  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from tests.env_kwargs import formation_env  # noqa: E402

ENV = formation_env(8, observation="phd")
BASE = "scripted:formation-known-n-fast"
TEACHER = "privileged:formation-known-n-fast@truth"


@pytest.fixture(scope="module")
def env():
    e = parallel_env(**ENV)
    yield e
    e.close()


def _student(env, seed=0, zero=False):
    torch.manual_seed(seed)
    model = new_student(env.observation_space(env.possible_agents[0]))
    if zero:  # the head's last layer at 0: no correction at all
        with torch.no_grad():
            model.head[-1].weight.zero_()
            model.head[-1].bias.zero_()
    else:  # large enough corrections to change the motion within a few steps
        with torch.no_grad():
            model.head[-1].bias.copy_(torch.tensor([0.3, -0.4]))
    return model.eval()


def drive_one_step(path):
    """Load the student saved at ``path`` as a policy in its own env and drive one step: what
    a usable student does."""
    env = parallel_env(**read_student_metadata(path)["env_kwargs"])
    try:
        policy = load_policy(str(path), env)
        obs, infos = env.reset(seed=0)
        actions = policy(obs, infos)
        assert set(actions) == set(env.agents)
        env.step(actions)
    finally:
        env.close()


def test_a_step_equals_the_sequence_forward(env):
    # The policy runs the GRU one step at a time; training runs it over whole sequences.
    model = _student(env)
    rng = np.random.default_rng(0)
    dim = env.observation_space(env.possible_agents[0]).shape[0]
    obs = torch.as_tensor(rng.uniform(-1, 1, (3, 7, dim)), dtype=torch.float32)
    base = torch.as_tensor(rng.uniform(-1, 1, (3, 7, 2)), dtype=torch.float32)
    with torch.no_grad():
        whole = model(obs, base, torch.zeros(3, 7))
        h, steps = None, []
        for t in range(7):
            out, h = model.step(obs[:, t], base[:, t], h)
            steps.append(out)
    np.testing.assert_allclose(torch.stack(steps, 1).numpy(), whole.numpy(), atol=1e-6)


def test_a_zero_correction_gives_the_base_command_bit_for_bit(env):
    policy = RecurrentStudentPolicy(_student(env, zero=True), BASE, env)
    base = ResidualBase(BASE, env)
    policy.reset(3)
    base.reset(3)
    obs, infos = env.reset(seed=3)
    for _ in range(4):
        got, want = policy(obs, infos), base(obs, infos)
        for a in obs:
            assert np.array_equal(got[a], np.asarray(want[a], np.float32)), a
        obs, _, _, _, infos = env.step(got)


def test_each_agents_state_is_kept_by_name_whatever_the_order(env):
    # The same steps with the agents listed in reverse order give each agent the same action:
    # the GRU state follows the agent's name, not its position in the dict.
    a, b = (RecurrentStudentPolicy(_student(env), BASE, env) for _ in range(2))
    for p in (a, b):
        p.reset(6)
    obs, infos = env.reset(seed=6)
    for _ in range(4):
        commands = a.base(obs, infos)
        b.base(obs, infos)  # keep b's scripted base in step with a's
        forward = a.correct(obs, commands)
        backward = b.correct(dict(reversed(obs.items())), dict(reversed(commands.items())))
        for agent in obs:
            np.testing.assert_allclose(backward[agent], forward[agent], atol=1e-6)
        obs, _, _, _, infos = env.step(forward)


def test_the_closed_loop_keeps_each_agents_state_and_resets_it(env):
    # Stepping agent by agent in closed loop gives what the model gives over each agent's
    # recorded sequence from the episode's start: the GRU state is the agent's own, and
    # reset() starts it again.
    policy = RecurrentStudentPolicy(_student(env), BASE, env)
    for seed in (1, 2):  # the second episode after a reset
        policy.reset(seed)
        obs, infos = env.reset(seed=seed)
        seen = {a: {"obs": [], "base": [], "act": []} for a in env.agents}
        while env.agents:
            commands = policy.base(obs, infos)
            actions = policy.correct(obs, commands)
            for a in obs:
                seen[a]["obs"].append(obs[a])
                seen[a]["base"].append(base_in_unit_scale(commands[a], policy.high))
                seen[a]["act"].append(actions[a])
            obs, _, _, _, infos = env.step(actions)
        for a, s in seen.items():
            x = torch.as_tensor(np.stack(s["obs"])[None], dtype=torch.float32)
            b = torch.as_tensor(np.stack(s["base"])[None])
            with torch.no_grad():
                corr = policy.model(x, b, torch.zeros(1, x.shape[1]))[0].numpy()
            want = compose(np.stack(s["base"]) * policy.high, corr, policy.high)
            np.testing.assert_allclose(np.stack(s["act"]), want, atol=1e-5, err_msg=a)
            assert np.abs(corr).max() > 0.1  # the check is not vacuous


def test_dagger_states_are_the_students_and_labels_stay_against_the_base(env):
    seeds = [4]
    by_base = collect_sequences(ENV, BASE, TEACHER, seeds)
    zero = RecurrentStudentPolicy(_student(env, zero=True), BASE, env)
    same = collect_sequences(ENV, BASE, TEACHER, seeds, student=zero)
    for k in by_base:  # a student that corrects nothing drives as the base does
        assert np.array_equal(by_base[k], same[k]), k
    moving = RecurrentStudentPolicy(_student(env), BASE, env)
    own = collect_sequences(ENV, BASE, TEACHER, seeds, student=moving)
    assert own["obs"].shape == by_base["obs"].shape
    assert not np.array_equal(own["obs"][:, 2:], by_base["obs"][:, 2:])  # other states
    # ... and the labels are the teacher's correction of the base there, not of the student:
    # replayed with the same student, clip((teacher - base) / high) step by step.
    from agents.sb3.privileged import load_teacher
    from agents.sb3.warm_start import correction_labels

    base, tutor = ResidualBase(BASE, env), load_teacher(TEACHER, env)
    again = RecurrentStudentPolicy(_student(env), BASE, env)
    for p in (base, tutor, again):
        p.reset(seeds[0])
    obs, infos = env.reset(seed=seeds[0])
    step = 0
    while env.agents:
        commands, taught = base(obs, infos), tutor(obs, infos)
        want = correction_labels(taught, commands, tutor.wandering, list(obs), base.high)
        np.testing.assert_array_equal(own["label"][:, step], want)
        obs, _, _, _, infos = env.step(again.correct(obs, commands))
        step += 1
    assert step == own["obs"].shape[1] and not np.allclose(own["label"], 0.0)


def test_a_saved_student_loads_and_acts_the_same(env, tmp_path):
    model = _student(env)
    path = tmp_path / "s.pt"
    save_student(path, model, ENV, BASE, teacher=TEACHER, round=2)
    meta = read_student_metadata(path)
    assert meta["env_kwargs"] == ENV and meta["base"] == BASE and meta["round"] == 2
    assert policy_observation(str(path)) == "phd"
    a, b = RecurrentStudentPolicy(model, BASE, env), load_policy(str(path), env)
    assert isinstance(b, RecurrentStudentPolicy)
    for p in (a, b):
        p.reset(5)
    obs, infos = env.reset(seed=5)
    for _ in range(3):
        got, want = b(obs, infos), a(obs, infos)
        for agent in obs:
            assert np.array_equal(got[agent], want[agent])
        obs, _, _, _, infos = env.step(want)


def test_bad_student_files_are_refused(env, tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_student(tmp_path / "missing.pt", env)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="not a recurrent student"):
        load_student(junk, env)
    other = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, other)
    with pytest.raises(ValueError, match="not a recurrent student"):
        load_student(other, env)
    # A student trained on another observation (fewer lidar sectors) says so.
    wide = parallel_env(**ENV, lidar_sectors=16)
    try:
        path = tmp_path / "wide.pt"
        save_student(path, _student(wide), {**ENV, "lidar_sectors": 16}, BASE)
        with pytest.raises(ValueError, match="observations of length"):
            load_student(path, env)
    finally:
        wide.close()


ARGS = [
    "--preset",
    "lab-3m-4",
    "--max-steps",
    "8",
    "--base",
    BASE,
    "--teacher",
    TEACHER,
    "--val-seeds",
    "9",
    "--phases",
    "0,4",
    "--epochs",
    "2",
    "--dagger-epochs",
    "1",
]


def test_main_trains_two_rounds_and_resumes_from_kept_data(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [*ARGS, "--round-seeds", "0-1", "2", "--out", str(out)]
    assert main(argv) == 0
    names = ("student_round1.pt", "student_round2.pt", "student.pt", "round1.npz")
    for name in (*names, "train_log.png"):
        assert (out / name).is_file(), name
    log = json.loads((out / "train_log.json").read_text())
    assert [r["round"] for r in log["rounds"]] == [1, 2]
    assert [r["sequences"] for r in log["rounds"]] == [8, 12]  # 4 robots per episode
    assert not any(r["data_reused"] for r in log["rounds"])
    assert "formation_error_m@4-" in log["rounds"][1]["val"]
    assert "formation_error_m@4-" in log["base_val"]
    assert read_student_metadata(out / "student.pt")["round"] == 2
    assert _digest(out / "student.pt") == _digest(out / "student_round2.pt")
    assert log["stopped"] is None and log["interrupted"] is None
    # student_best.pt: the round with the lowest validation formation error, whole.
    errors = {r["round"]: r["val"]["formation_error_m"] for r in log["rounds"]}
    best = min(errors, key=errors.get)
    assert log["best_round"] == best
    assert _digest(out / "student_best.pt") == _digest(out / f"student_round{best}.pt")
    assert main(argv) == 0  # rerun: round 1's data is kept and reused, and round 2's, since
    log = json.loads((out / "train_log.json").read_text())  # the refit student is the same
    assert [r["data_reused"] for r in log["rounds"]] == [True, True]
    assert log["fit_seed"] == 0 and log["epochs"] == 2 and log["dagger_epochs"] == 1
    # Another fit seed: another round-1 student, so round 2's data is collected again.
    assert main([*argv, "--fit-seed", "1"]) == 0
    log = json.loads((out / "train_log.json").read_text())
    assert [r["data_reused"] for r in log["rounds"]] == [True, False]
    # Other seeds for round 1: its data is collected again.
    assert main([*ARGS, "--round-seeds", "0", "2", "--out", str(out)]) == 0
    log = json.loads((out / "train_log.json").read_text())
    assert not log["rounds"][0]["data_reused"] and log["rounds"][0]["sequences"] == 4


@pytest.mark.parametrize(
    ("extra", "flag"),
    [
        (["--round-seeds", "0-2", "2"], "--round-seeds"),
        (["--round-seeds", "0-2", "--val-seeds", "1"], "--val-seeds"),
        (["--round-seeds", "0", "--epochs", "0"], "--epochs"),
        (["--round-seeds", "0", "--phases", "5,2"], "--phases"),
        (["--round-seeds", "0", "--base", "random"], "--base"),
        (["--round-seeds", "0", "--teacher", "privileged:nope"], "--teacher"),
        (["--round-seeds", "0", "--fit-seed", "-2"], "--fit-seed"),
        (["--round-seeds", "0", "--observation", "measurements"], "observation='measurements'"),
        (["--round-seeds", "0", "--env-overrides", '{"top_k": 4}'], "top_k=4"),
        (["--round-seeds", "0", "--max-wall-minutes", "-1"], "--max-wall-minutes"),
    ],
)
def test_main_refuses_bad_arguments_before_any_rollout(tmp_path, capsys, extra, flag):
    with pytest.raises(SystemExit):
        main([*ARGS, "--out", str(tmp_path / "x"), *extra])
    assert flag in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _stopped_in_round_2(out, log, stopped):
    """A run of two rounds stopped in round 2: the log has round 1 and says why, and
    ``student.pt`` is round 1's student, whole (nothing half-written beside it) and usable."""
    assert [r["round"] for r in log["rounds"]] == [1] and log["stopped"] == stopped
    assert _digest(out / "student.pt") == _digest(out / "student_round1.pt")
    assert read_student_metadata(out / "student.pt")["round"] == 1
    assert not (out / "student_round2.pt").exists()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporary files
    drive_one_step(out / "student.pt")


@pytest.mark.parametrize(
    ("name", "where"), [("SIGINT", "collect_sequences"), ("SIGTERM", "train_sequences")]
)
def test_a_signal_keeps_the_last_completed_rounds_student(
    tmp_path, monkeypatch, capsys, name, where
):
    """A real signal in round 2: SIGINT as its episodes are collected, SIGTERM once its fit
    has moved the model (which must then not become student.pt). Exit 130 / 143."""
    from agents.sb3 import sequences

    real, calls = getattr(sequences, where), []

    def signalled(*args, **kwargs):
        calls.append(1)
        result = real(*args, **kwargs)
        if len(calls) == 2:
            os.kill(os.getpid(), getattr(signal, name))
        return result

    monkeypatch.setattr(sequences, where, signalled)
    # Were the trainer's handler missing, a SIGTERM would end pytest: make it a plain
    # KeyboardInterrupt (then read as SIGINT, and the exit code check fails).
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        out = tmp_path / "run"
        code = main([*ARGS, "--round-seeds", "0-1", "2", "--out", str(out)])
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == {"SIGINT": 130, "SIGTERM": 143}[name]
    err = capsys.readouterr().err
    assert f"{name} in round 2 (1 completed): student.pt is round 1's" in err
    log = json.loads((out / "train_log.json").read_text())
    assert log["interrupted"] == name
    _stopped_in_round_2(out, log, name)
    # Round 2's data is kept (for a rerun) only if it was complete when the signal came.
    assert (out / "round2.json").is_file() == (where == "train_sequences")


def test_the_wall_time_budget_stops_after_a_round_with_its_student(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [*ARGS, "--round-seeds", "0-1", "2", "--out", str(out), "--max-wall-minutes", "1e-6"]
    assert main(argv) == 0
    assert "wall-time budget, stopped after round 1" in capsys.readouterr().out
    log = json.loads((out / "train_log.json").read_text())
    assert log["interrupted"] is None
    _stopped_in_round_2(out, log, "max-wall-minutes")
    assert not (out / "round2.npz").exists()  # round 2 never started


def test_student_best_is_the_round_best_on_validation_not_the_last(tmp_path, monkeypatch):
    import agents.evaluation as evaluation

    real_score = evaluation.score
    errors = iter([0.09, 0.05, 0.07])  # the base, round 1, round 2: round 1 is best

    def score(*args, **kwargs):
        result = real_score(*args, **kwargs)
        result["mean"]["formation_error_m"] = next(errors)
        return result

    monkeypatch.setattr(evaluation, "score", score)
    out = tmp_path / "run"
    assert main([*ARGS, "--round-seeds", "0-1", "2", "--out", str(out)]) == 0
    log = json.loads((out / "train_log.json").read_text())
    assert log["best_round"] == 1
    assert _digest(out / "student_best.pt") == _digest(out / "student_round1.pt")
    assert _digest(out / "student.pt") == _digest(out / "student_round2.pt")


def test_a_rerun_into_the_same_out_leaves_no_student_of_the_earlier_run(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*ARGS, "--round-seeds", "0-1", "2", "--out", str(out)]) == 0
    assert (out / "student_round2.pt").is_file()
    argv = [*ARGS, "--round-seeds", "0-1", "2", "--out", str(out), "--max-wall-minutes", "1e-6"]
    assert main(argv) == 0  # stops after round 1: the earlier run's round 2 must be gone
    log = json.loads((out / "train_log.json").read_text())
    _stopped_in_round_2(out, log, "max-wall-minutes")
    assert log["best_round"] == 1
    assert _digest(out / "student_best.pt") == _digest(out / "student_round1.pt")


def test_report_scores_students_pooled_against_their_base_without_training_runs(
    env, tmp_path, capsys
):
    from experiments import report

    paths = [tmp_path / "s0.pt", tmp_path / "s1.pt"]
    for seed, path in enumerate(paths):
        save_student(path, _student(env, seed=seed), ENV, BASE)
    argv = ["--baselines", BASE, "--seeds", "3-4", "--phases", "0,4"]
    argv += ["--group", f"students={paths[0]},{paths[1]}", "--out", str(tmp_path), "--name", "rs"]
    assert report.main([*argv, "--env-from", str(paths[0])]) == 0
    saved = json.loads((tmp_path / "results_rs.json").read_text())
    assert set(saved["policies"]) == {BASE, *map(str, paths)}
    assert saved["env_kwargs"]["max_steps"] == 8
    assert saved["groups"] == {"students": [str(p) for p in paths]}
    (pair,) = saved["paired"]
    assert (pair["policy"], pair["baseline"]) == ("students", BASE)
    # The pooled difference is the students' per-seed mean against the base's, seed by seed.
    per = {
        p: [d["formation_error_m"] for d in saved["policies"][p]["per_seed"]]
        for p in saved["policies"]
    }
    want = np.mean(np.mean([per[str(p)] for p in paths], axis=0) - np.array(per[BASE]))
    assert pair["mean_difference"] == pytest.approx(want)
    assert want != 0.0  # the students really drove (nonzero corrections)
    assert "formation_error_m@4-" in saved["paired_by_phase"]
    with pytest.raises(SystemExit):
        report.main(argv)  # neither --runs nor --env-from: no env to score in
    assert "--env-from" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        report.main([*argv, "--env-from", str(paths[0]), "--group", "nameless"])
    assert "--group" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a missing member is named before any scoring
        report.main([*argv, "--env-from", str(paths[0]), "--group", f"x={tmp_path}/gone.pt"])
    assert "gone.pt" in capsys.readouterr().err


def test_evaluate_runs_a_student_in_its_own_env(env, tmp_path):
    from agents.policies import policy_env
    from swarm_phd.evaluate import _model_preset, evaluate_localization

    path = tmp_path / "s.pt"
    save_student(path, _student(env), {**ENV, "task_params": {"radius_m": 0.7}}, BASE)
    made = policy_env(None, None, str(path))
    try:  # the student's env: its preset, task, parameters and observation
        assert made.config.n_robots == 4 and made.config.observation == "phd"
        assert made.task.name == "formation" and made.task.radius_m == 0.7
    finally:
        made.close()
    assert _model_preset(str(path)) == "lab-3m-4"
    out = evaluate_localization(
        "lab-3m-4", 0.5, ["phd-lc"], [0], policy=str(path), task="formation"
    )
    base = evaluate_localization("lab-3m-4", 0.5, ["phd-lc"], [0], policy=BASE, task="formation")
    assert out["config"]["policy"] == str(path)
    # Its own correction drove the robots: not the base's motion.
    assert out["task"]["formation_error_m"] != base["task"]["formation_error_m"]


def test_localization_table_scores_a_student_in_its_own_env(env, tmp_path):
    from experiments import localization_table

    path = tmp_path / "s.pt"
    save_student(path, _student(env), ENV, BASE)
    argv = ["--policies", str(path), BASE, "--seeds", "2", "--out", str(tmp_path)]
    assert localization_table.main([*argv, "--name", "loc"]) == 0
    saved = json.loads((tmp_path / "results_loc.json").read_text())
    assert saved["env_kwargs"] == ENV  # the table's env is the student's
    student, base = saved["rows"]
    # The same rollouts scored twice: the task metric agrees between score and evaluate.
    assert student["formation_error_m_evaluate"] == pytest.approx(student["formation_error_m"][0])
    assert student["formation_error_m"] != base["formation_error_m"]  # it drove, not the base
    # --phases: each phase's share, per policy and paired by seed, in the json and the table.
    argv = [*argv, "--seeds", "2,3", "--phases", "0,3", "--name", "phased"]
    assert localization_table.main(argv) == 0
    saved = json.loads((tmp_path / "results_phased.json").read_text())
    keys = [
        "pct_pair_steps_err_gt_30cm",
        *(f"pct_pair_steps_err_gt_30cm@{p}" for p in ("0-3", "3-")),
    ]
    for row in saved["rows"]:
        assert list(row["localizers"]["phd-lc"]["by_phase"]) == keys
    paired = saved["paired"][f"phd-lc {keys[1]}"][0]
    assert paired["n_seeds"] == 2 and paired["baseline"] == str(path)
    assert "steps 3-" in (tmp_path / "results_phased.md").read_text()
    with pytest.raises(SystemExit):  # a phase past the episode's end (ENV: 8 steps)
        localization_table.main([*argv, "--phases", "0,8"])
