"""agents.sb3.recurrent_ppo: PPO fine-tuning of a recurrent residual student."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.sb3 import recurrent_ppo  # noqa: E402
from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from agents.sb3.recurrent_student import (  # noqa: E402
    _digest,
    new_student,
    read_student_metadata,
    save_student,
)
from experiments.recurrent_ppo import main as run_main  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from tests.agents.test_recurrent_student import drive_one_step  # noqa: E402
from tests.env_kwargs import formation_env  # noqa: E402

ENV = formation_env(6, observation="phd")
BASE = "scripted:formation-known-n-fast"


@pytest.fixture(scope="module")
def space():
    env = parallel_env(**ENV)
    try:
        return env.observation_space(env.possible_agents[0])
    finally:
        env.close()


def _model(space, seed=0):
    torch.manual_seed(seed)
    model = new_student(space)
    with torch.no_grad():  # corrections large enough to move the robots
        model.head[-1].bias.copy_(torch.tensor([0.3, -0.4]))
    return model.eval()


@pytest.fixture
def student(space, tmp_path):
    path = tmp_path / "start.pt"
    save_student(path, _model(space), ENV, BASE, teacher="privileged:x@truth", round=3)
    return path


def test_gae_matches_a_hand_derived_case():
    rewards = np.array([[1.0], [2.0]])
    values = np.array([[0.5], [1.0]])
    # delta_1 = 2 + 0.9 * 3 - 1 = 3.7; delta_0 = 1 + 0.9 * 1 - 0.5 = 1.4;
    # A_0 = 1.4 + 0.9 * 0.8 * 3.7 = 4.064.
    adv, returns = recurrent_ppo.gae(rewards, values, np.array([3.0]), 0.9, 0.8)
    np.testing.assert_allclose(adv[:, 0], [4.064, 3.7])
    np.testing.assert_allclose(returns[:, 0], [4.564, 4.7])
    # lambda = 1: the discounted return to the bootstrap, minus the value.
    adv, _ = recurrent_ppo.gae(rewards, values, np.array([3.0]), 0.9, 1.0)
    np.testing.assert_allclose(adv[0, 0], 1 + 0.9 * 2 + 0.81 * 3 - 0.5)


def _args(**kw):
    return argparse.Namespace(**({"gamma": 0.99, "gae_lambda": 0.95} | kw))


@pytest.fixture
def rollout_batch(space):
    vec = BatchedSwarmVecEnv(
        ENV, 2, seed=None, residual=BASE, residual_observes_base=True, critic_state=True
    )
    try:
        model = _model(space)
        log_std = torch.nn.Parameter(torch.full((2,), -1.0))
        critic = recurrent_ppo.new_critic(space, vec.critic_dims)
        data = recurrent_ppo.rollout(vec, model, log_std, [3, 4], torch.Generator().manual_seed(0))
        values, last = recurrent_ppo._values(critic, data, model.encoder_obs_dim)
        batch = recurrent_ppo._batch(data, values, last, _args())
    finally:
        vec.close()
    return model, log_std, critic, data, batch


def test_a_rollout_is_whole_episodes_whose_log_probs_the_update_recomputes(rollout_batch):
    model, log_std, _, data, batch = rollout_batch
    n_entries = 2 * 4  # copies x robots
    assert data["rewards"].shape == (6, n_entries) and data["actions"].shape == (6, n_entries, 2)
    assert "last_obs" not in data  # the episode's end is terminal: nothing to bootstrap
    # The update unrolls the GRU over the whole episode: the rollout's own log-probs, so the
    # first ratio is 1 (PPO's clipping is measured from the policy that acted).
    dim = model.encoder_obs_dim
    obs = batch["obs"]
    with torch.no_grad():
        mean = model(obs[..., :dim], obs[..., dim : dim + 2], torch.zeros(obs.shape[:2]))
        logp = torch.distributions.Normal(mean, log_std.exp()).log_prob(batch["actions"])
    np.testing.assert_allclose(logp.sum(-1).numpy(), batch["logp"].numpy(), atol=1e-4)
    # Advantages are normalised; the value targets are advantages plus values.
    assert abs(float(batch["advantages"].mean())) < 1e-5
    assert batch["left"][0, 0] == 1.0 and batch["left"][0, -1] == pytest.approx(1 / 6)


def test_the_episodes_end_is_terminal_for_the_critic(rollout_batch):
    """The critic counts the time left down to the time limit, so nothing follows the last
    step: its value target there is the last reward itself, whatever the critic says."""
    model, _, critic, data, batch = rollout_batch
    _, last = recurrent_ppo._values(critic, data, model.encoder_obs_dim)
    assert np.array_equal(last, np.zeros(data["rewards"].shape[1]))
    np.testing.assert_allclose(batch["returns"][:, -1].numpy(), data["rewards"][-1], rtol=1e-6)


def test_the_warmup_trains_the_critic_alone_then_the_actor_moves(rollout_batch):
    model, log_std, critic, _, batch = rollout_batch
    before = {k: v.clone() for k, v in model.state_dict().items()}
    critic_before = [p.detach().clone() for p in critic.parameters()]
    actor_optim = torch.optim.Adam([*model.parameters(), log_std], lr=1e-3)
    critic_optim = torch.optim.Adam(critic.parameters(), lr=1e-3)
    rng = np.random.default_rng(0)
    stats = recurrent_ppo.ppo_update(
        model, log_std, critic, None, critic_optim, batch, 2, 4, 0.1, 0.02, rng
    )
    assert stats["passes"] == 2 and stats["actor_steps"] == 0 and stats["approx_kl"] == 0.0
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert any(
        not torch.equal(a, b) for a, b in zip(critic.parameters(), critic_before, strict=True)
    )
    stats = recurrent_ppo.ppo_update(
        model, log_std, critic, actor_optim, critic_optim, batch, 3, 4, 0.1, 1e3, rng
    )
    assert stats["actor_steps"] == 3 * 2 and stats["approx_kl"] > 0  # 8 sequences, 4 a batch
    assert any(not torch.equal(v, before[k]) for k, v in model.state_dict().items())
    # A tight KL target stops the actor's update at the first minibatch past it (the policy
    # that acted is no longer the current one); the critic's passes go on.
    stats = recurrent_ppo.ppo_update(
        model, log_std, critic, actor_optim, critic_optim, batch, 5, 4, 0.1, 1e-6, rng
    )
    assert stats["actor_steps"] == 0 and stats["passes"] == 5 and stats["approx_kl"] > 1.5e-6


TINY = ["--iterations", "2", "--n-copies", "2", "--critic-warmup", "1", "--eval-every", "1"]
TINY += ["--val-seeds", "200", "--phases", "0,4", "--train-seeds-start", "7000"]


def test_main_fine_tunes_saves_each_scored_student_and_is_reproducible(student, tmp_path):
    out = tmp_path / "run"
    argv = ["--student", str(student), "--out", str(out), *TINY]
    assert run_main([*argv, "--task-params", '{"progress_weight": 10}']) == 0
    names = ("student_it0.pt", "student_it1.pt", "student_it2.pt", "student.pt", "train_log.png")
    for name in names:
        assert (out / name).is_file(), name
    log = json.loads((out / "train_log.json").read_text())
    assert [it["iteration"] for it in log["iterations"]] == [1, 2]
    assert [it["critic_only"] for it in log["iterations"]] == [True, False]
    assert log["iterations"][1]["seeds"] == [7002, 7003]
    assert [v["iteration"] for v in log["val"]] == [0, 1, 2]
    assert "formation_error_m@4-" in log["val"][0] and log["interrupted"] is None
    assert log["stopped"] is None
    assert log["train_task_params"] == {"progress_weight": 10}
    # The warm-up iteration leaves the student as it started; the PPO iteration moves it.
    assert _digest(out / "student_it0.pt") == _digest(out / "student_it1.pt") == _digest(student)
    assert _digest(out / "student.pt") == _digest(out / "student_it2.pt") != _digest(student)
    meta = read_student_metadata(out / "student.pt")
    # Its own env (the reward's parameters do not change what it observes), and its origin.
    assert meta["env_kwargs"] == ENV and meta["reward_task_params"] == {"progress_weight": 10}
    assert meta["iteration"] == 2 and meta["start_student"] == str(student)
    drive_one_step(out / "student.pt")
    # Same arguments, same student, bit for bit (seeded env, noise and minibatches).
    again = tmp_path / "again"
    argv = ["--student", str(student), "--out", str(again), *TINY]
    assert run_main([*argv, "--task-params", '{"progress_weight": 10}']) == 0
    assert _digest(again / "student.pt") == _digest(out / "student.pt")


def test_worker_processes_train_the_same_student_bit_for_bit(student, tmp_path, monkeypatch):
    """``--num-cpus 2``: the copies stepped by 2 worker processes give the same rollouts, so
    the same student, as in one process."""
    from tests.agents.test_batched_subproc import _record_worker_vec_envs

    built = _record_worker_vec_envs(monkeypatch)
    runs = {}
    for name, extra in (("inproc", []), ("workers", ["--num-cpus", "2"])):
        out = tmp_path / name
        argv = ["--student", str(student), "--out", str(out), *TINY, *extra]
        assert run_main([*argv, "--task-params", '{"progress_weight": 10}']) == 0
        runs[name] = out
    assert _digest(runs["workers"] / "student.pt") == _digest(runs["inproc"] / "student.pt")
    assert built == [2]  # only the second run used workers


@pytest.mark.filterwarnings("ignore:No artists with labels")
@pytest.mark.parametrize("which", ["recurrent_ppo", "recurrent_student"])
def test_a_learning_curve_cut_while_written_leaves_the_last_one_whole(
    which, tmp_path, monkeypatch
):
    """``train_log.png`` is redrawn every iteration or round: a Ctrl-C in the middle of a
    redraw must leave the previous figure, not a truncated PNG."""
    import matplotlib.figure

    from agents.sb3 import recurrent_student

    figure = tmp_path / "train_log.png"
    figure.write_bytes(b"the previous figure")

    def cut(self, fname, **kwargs):
        Path(fname).write_bytes(b"half a PNG")
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", cut)
    plot = {
        "recurrent_ppo": lambda: recurrent_ppo.plot_ppo_logs([], figure),
        "recurrent_student": lambda: recurrent_student.plot_train_logs([], figure),
    }[which]
    with pytest.raises(KeyboardInterrupt):
        plot()
    assert figure.read_bytes() == b"the previous figure"
    assert [p.name for p in tmp_path.iterdir()] == ["train_log.png"]


def test_an_interrupt_saves_the_student_and_exits_130(student, tmp_path, monkeypatch, capsys):
    real = recurrent_ppo.rollout
    calls = []

    def interrupted_rollout(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(recurrent_ppo, "rollout", interrupted_rollout)
    out = tmp_path / "run"
    assert run_main(["--student", str(student), "--out", str(out), *TINY]) == 130
    assert "SIGINT in iteration 2 (1 completed)" in capsys.readouterr().err
    log = json.loads((out / "train_log.json").read_text())
    assert log["interrupted"] == log["stopped"] == "SIGINT" and len(log["iterations"]) == 1
    meta = read_student_metadata(out / "student.pt")
    assert meta["iteration"] == 1 and meta["interrupted_in"] == 2


def test_the_wall_time_budget_stops_after_an_iteration_and_saves(student, tmp_path, capsys):
    """A budget spent before iteration 1 ends: the run stops after it (not mid-iteration),
    saves student.pt and the log as a finished run does, and exits 0."""
    out = tmp_path / "run"
    argv = ["--student", str(student), "--out", str(out), *TINY, "--max-wall-minutes", "1e-6"]
    assert run_main(argv) == 0
    assert "(wall-time budget)" in capsys.readouterr().out
    log = json.loads((out / "train_log.json").read_text())
    assert log["stopped"] == "max-wall-minutes" and log["interrupted"] is None
    assert [it["iteration"] for it in log["iterations"]] == [1]  # of --iterations 2
    meta = read_student_metadata(out / "student.pt")
    assert meta["iteration"] == 1 and "interrupted_in" not in meta
    drive_one_step(out / "student.pt")


@pytest.mark.parametrize(
    ("extra", "flag"),
    [
        (["--iterations", "0"], "--iterations"),
        (["--learning-rate", "nan"], "--learning-rate"),
        (["--gamma", "1.5"], "--gamma"),
        (["--train-seeds-start", "199"], "--val-seeds"),
        (["--task-params", "[1]"], "--task-params"),
        (["--task-params", '{"shape": "blob"}'], "--task-params"),
        # The reward may change, not what the student observes (the circle's radius, a
        # lattice's layout): a student fine-tuned on another task would be deployed on its own.
        (["--task-params", '{"radius_m": 1.0}'], "changes what the student observes"),
        (["--task-params", '{"shape": "lattice"}'], "changes what the student observes"),
        (["--phases", "5,2"], "--phases"),
        (["--log-std", "inf"], "--log-std"),
        (["--max-wall-minutes", "0"], "--max-wall-minutes"),
        (["--num-cpus", "-1"], "--num-cpus must be an integer >= 0, got -1"),
        (["--num-cpus", "3"], "--num-cpus 3 exceeds --n-copies 2"),
    ],
)
def test_main_refuses_bad_arguments_before_any_rollout(student, tmp_path, capsys, extra, flag):
    with pytest.raises(SystemExit):
        run_main(["--student", str(student), "--out", str(tmp_path / "x"), *TINY, *extra])
    assert flag in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_the_students_own_directory_is_refused_as_out(student, capsys):
    with pytest.raises(SystemExit):
        run_main(["--student", str(student), "--out", str(student.parent), *TINY])
    assert "would be overwritten" in capsys.readouterr().err


def test_a_missing_or_foreign_student_is_refused(tmp_path, capsys):
    for path in (tmp_path / "gone.pt", tmp_path / "foreign.pt"):
        if path.name == "foreign.pt":
            torch.save({"format": "something else"}, path)
        with pytest.raises(SystemExit):
            run_main(["--student", str(path), "--out", str(tmp_path / "x"), *TINY])
        assert path.name in capsys.readouterr().err


def test_a_zero_start_drives_as_its_base_until_ppo_moves_it(student, tmp_path):
    """--base with --env-from: iteration 0 (and the critic's warm-up) is the base's own
    motion, bit for bit in the scored figures; the PPO iteration moves the student."""
    from agents.evaluation import score

    out = tmp_path / "zero"
    base = "scripted:formation-known-n"
    argv = ["--base", base, "--env-from", str(student), "--out", str(out), *TINY]
    assert run_main(argv) == 0
    log = json.loads((out / "train_log.json").read_text())
    assert log["base"] == base and log["env_kwargs"] == ENV
    assert log["val"][0] == {"iteration": 0, **log["base_val"]}
    meta = read_student_metadata(out / "student_it0.pt")
    assert meta["base"] == base and meta["start_student"] == f"zero:{base}"
    seeds = [200]
    warmed, own = (score(spec, ENV, seeds) for spec in (str(out / "student_it1.pt"), base))
    assert warmed.pop("policy") != own.pop("policy") and warmed == own
    assert _digest(out / "student.pt") != _digest(out / "student_it0.pt")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--base", "scripted:formation-known-n"], "--base needs --env-from"),
        (
            ["--base", "scripted:nope", "--env-from", "{student}"],
            "--base: unknown scripted policy 'nope'",
        ),
        (["--base", "scripted:formation-known-n", "--env-from", "x.json"], "x.json"),
        (["--student", "{student}", "--env-from", "{student}"], "--env-from goes with --base"),
        (["--student", "{student}", "--base", "scripted:formation"], "not allowed with"),
        ([], "one of the arguments --student --base is required"),
        (["--base", "scripted:formation", "--env-from", "gone.pt"], "--env-from: recurrent"),
        # The encoder reads the neighbour table: raw measurements would be misread.
        (["--base", "scripted:formation", "--env-from", "{raw}"], "observation='measurements'"),
        (["--base", "scripted:formation", "--env-from", "{rows}"], "top_k=8"),
    ],
)
def test_the_start_must_be_one_student_or_one_base_in_an_env(
    student, space, tmp_path, capsys, argv, message
):
    raw, rows = tmp_path / "raw.pt", tmp_path / "rows.pt"
    save_student(raw, _model(space), {**ENV, "observation": "measurements"}, BASE)
    save_student(rows, _model(space), {**ENV, "top_k": 8}, BASE)
    argv = [a.format(student=student, raw=raw, rows=rows) for a in argv]
    with pytest.raises(SystemExit):
        run_main([*argv, "--out", str(tmp_path / "x"), *TINY])
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_a_zero_start_in_a_models_env_and_its_own_directory_refused(space, tmp_path, capsys):
    """--env-from takes a .zip model's env too; --out may not be the directory it is read from."""
    import zipfile

    from agents.sb3.policy import write_metadata

    model = tmp_path / "m" / "model.zip"
    model.parent.mkdir()
    with zipfile.ZipFile(model, "w") as z:
        z.writestr("data", "{}")
    write_metadata(model, {"env_kwargs": ENV, "obs_norm": None})
    base = "scripted:formation-known-n"
    argv = ["--base", base, "--env-from", str(model), *TINY, "--iterations", "1"]
    assert run_main([*argv, "--out", str(tmp_path / "run")]) == 0
    assert read_student_metadata(tmp_path / "run" / "student.pt")["env_kwargs"] == ENV
    with pytest.raises(SystemExit):
        run_main([*argv, "--out", str(model.parent)])
    assert "holds --env-from" in capsys.readouterr().err


def test_a_previous_run_in_out_is_refused_without_overwrite(student, tmp_path, capsys):
    out = tmp_path / "previous"
    out.mkdir()
    (out / "student.pt").write_bytes(b"a finished run")
    with pytest.raises(SystemExit):
        run_main(["--student", str(student), "--out", str(out), *TINY])
    err = capsys.readouterr().err
    assert "holds a previous run" in err and "--overwrite" in err
    assert [p.name for p in out.iterdir()] == ["student.pt"]
    assert (out / "student.pt").read_bytes() == b"a finished run"
