"""The batched VecEnv split across worker processes: the same rollout, and clear failures."""

from __future__ import annotations

import json
import multiprocessing
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from gymnasium.utils.env_checker import data_equivalence  # noqa: E402

from agents.sb3.batched import BatchedSwarmVecEnv  # noqa: E402
from agents.sb3.batched_subproc import RemoteTraceback, SubprocBatchedVecEnv, split_copies  # noqa: E402
from swarm_phd.cli import main  # noqa: E402
from tests.agents.test_sb3 import _actions  # noqa: E402

KWARGS = {"preset": "lab-3m-4", "task": "formation", "max_steps": 12}
RESIDUAL = {
    "residual": "scripted:formation",
    "residual_observes_base": True,
    "critic_state": True,
}


def _assert_steps_equal(a, b, t):
    for x, y, what in zip(a[:3], b[:3], ("obs", "rewards", "dones"), strict=True):
        np.testing.assert_array_equal(x, y, err_msg=f"{what}, t={t}")
    assert len(a[3]) == len(b[3])
    for j, (x, y) in enumerate(zip(a[3], b[3], strict=True)):
        assert x.keys() == y.keys(), (t, j)
        assert data_equivalence(x, y), (t, j)


@pytest.mark.parametrize("options", [{}, RESIDUAL], ids=["plain", "residual-critic"])
def test_workers_give_the_in_process_rollout_bit_for_bit(options):
    """5 copies in 2 workers (blocks of 3 and 2) against the same 5 copies in one process:
    the same observations, rewards, dones and infos at every step, across auto-resets (12-step
    episodes), a ``seed()`` reset and a ``copy_seeds`` reset. With the residual, the base's
    reseeding at each auto-reset uses the copy's global index (``copy_offset``)."""
    ref = BatchedSwarmVecEnv(KWARGS, 5, seed=11, **options)
    vec = SubprocBatchedVecEnv(KWARGS, 5, 2, seed=11, **options)
    try:
        assert [list(b) for b in vec.blocks] == [[0, 1, 2], [3, 4]]
        assert vec.num_envs == ref.num_envs == 20
        assert vec.observation_space == ref.observation_space
        np.testing.assert_array_equal(vec.action_high, ref.action_high)
        np.testing.assert_array_equal(vec.reset(), ref.reset())
        rng = np.random.default_rng(0)
        for t in range(40):
            if t == 15:
                vec.seed(123)
                ref.seed(123)
                np.testing.assert_array_equal(vec.reset(), ref.reset())
            if t == 30:
                seeds = [9, 8, 7, 6, 5]
                np.testing.assert_array_equal(vec.reset(seeds), ref.reset(seeds))
            actions = rng.uniform(-1, 1, (ref.num_envs, 2)).astype(np.float32)
            _assert_steps_equal(vec.step(actions), ref.step(actions), t)
        for k in (0, 3):
            assert data_equivalence(vec.copy_infos(k), ref.copy_infos(k))
            if options:
                assert data_equivalence(vec.scripted_commands(k), ref.scripted_commands(k))
        # Entries map to their copies across workers, in the order asked.
        for env in (vec, ref):
            env.set_attr("tag", "late", indices=[19, 9])
            env.set_attr("tag", "early", indices=[0, 4])
        asked = [19, 0, 4, 9]
        assert vec.get_attr("tag", asked) == ref.get_attr("tag", asked)
        assert vec.get_attr("tag", asked) == ["late", "early", "early", "late"]
        assert vec.env_method("__getattribute__", "tag", indices=[9, 4]) == ["late", "early"]
        with pytest.raises(AttributeError):
            vec.get_attr("tag", [13])  # copy 3 was never tagged
    finally:
        vec.close()
        ref.close()


def test_bad_actions_a_failing_call_and_a_dead_worker_are_reported():
    vec = SubprocBatchedVecEnv(KWARGS, 3, 2, seed=0)
    ref = BatchedSwarmVecEnv(KWARGS, 3, seed=0)
    try:
        np.testing.assert_array_equal(vec.reset(), ref.reset())
        good = np.full((12, 2), 0.5, np.float32)
        bad = good.copy()
        bad[9, 1] = np.nan
        # Refused before any worker moves: the next good step is the reference's first one.
        with pytest.raises(ValueError, match=r"actions\[9\] \(copy 2, agent 1\) is not finite"):
            vec.step(bad)
        with pytest.raises(ValueError, match=r"shape \(12, 2\), got \(11, 2\)"):
            vec.step(good[:11])
        _assert_steps_equal(vec.step(good), ref.step(good), 0)
        # A failing call comes back with the worker's traceback and leaves the env usable.
        with pytest.raises(AttributeError) as caught:
            vec.env_method("no_such_method", indices=[5])
        assert isinstance(caught.value.__cause__, RemoteTraceback)
        assert "no_such_method" in str(caught.value.__cause__)
        _assert_steps_equal(vec.step(good), ref.step(good), 1)
        with pytest.raises(ValueError, match="index 12 is outside"):
            vec.get_attr("agents", [12])
        # A worker killed from outside: named, with its exit code; the VecEnv is then closed.
        os.kill(vec._processes[1].pid, signal.SIGKILL)
        vec._processes[1].join(10)
        with pytest.raises(
            RuntimeError, match=r"env worker 1 \(copies 2-2, pid \d+\) died: exit code -9"
        ):
            vec.step(good)
        with pytest.raises(RuntimeError, match=r"unusable \(env worker 1 .* died"):
            vec.reset()
        assert not vec._processes[0].is_alive()
    finally:
        vec.close()
        ref.close()


def test_an_interrupted_exchange_leaves_the_vec_env_refusing_until_closed(monkeypatch):
    """A Ctrl-C between two workers' answers leaves the second answer unread: the next
    command must not take it for its own. A step awaited must come before another command."""
    vec = SubprocBatchedVecEnv(KWARGS, 2, 2, seed=0)
    try:
        vec.reset()
        actions = np.zeros((vec.num_envs, 2), np.float32)
        vec.step_async(actions)
        with pytest.raises(RuntimeError, match=r"step_wait\(\) must come first"):
            vec.reset()
        vec.step_wait()
        real = type(vec._connections[1]).recv
        conn = vec._connections[1]

        def interrupted(self):
            if self is conn:
                raise KeyboardInterrupt
            return real(self)

        monkeypatch.setattr(type(conn), "recv", interrupted)
        with pytest.raises(KeyboardInterrupt):
            vec.step(actions)
        monkeypatch.undo()
        with pytest.raises(RuntimeError, match=r"unusable \(interrupted while reading"):
            vec.step(actions)
        with pytest.raises(RuntimeError, match="unusable"):
            vec.get_attr("agents")
    finally:
        start = time.monotonic()
        vec.close()  # reads past worker 1's stale answer to its "closed"
    assert time.monotonic() - start < 5
    assert [p.exitcode for p in vec._processes] == [0, 0]


def test_close_kills_a_worker_that_does_not_answer_and_a_bad_argument_breaks_nothing():
    vec = SubprocBatchedVecEnv(KWARGS, 2, 2, seed=0)
    vec.reset()
    # An argument that cannot be pickled fails before anything is sent: still usable.
    with pytest.raises((AttributeError, TypeError, pickle.PicklingError)):
        vec.set_attr("f", lambda: 0)
    vec.step(np.zeros((vec.num_envs, 2), np.float32))
    os.kill(vec._processes[1].pid, signal.SIGSTOP)  # alive, never answers
    start = time.monotonic()
    vec.close(timeout=1.0)
    assert time.monotonic() - start < 8
    assert vec._processes[0].exitcode == 0 and vec._processes[1].exitcode == -signal.SIGKILL


def test_a_vec_env_never_closed_does_not_hang_the_interpreter_at_exit(tmp_path):
    """The workers ignore SIGTERM, multiprocessing's own exit handler's way to end them: the
    VecEnv's finalizer closes them first."""
    script = tmp_path / "unclosed.py"
    script.write_text(
        "from agents.sb3.batched_subproc import SubprocBatchedVecEnv\n"
        "if __name__ == '__main__':\n"
        f"    vec = SubprocBatchedVecEnv({KWARGS!r}, 2, 2, seed=0)\n"
        "    vec.reset()\n"
        "    print('built', flush=True)\n"
    )
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, str(script)], cwd=root, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0 and "built" in done.stdout, done.stderr[-2000:]


def test_a_split_batch_reseeds_the_residual_base_as_the_whole_batch():
    """The residual base's seed at each auto-reset depends on the copy's index in the whole
    batch (``copy_offset``), not in its worker's block."""
    whole = BatchedSwarmVecEnv(KWARGS, 4, seed=11, residual="scripted:formation")
    tail = BatchedSwarmVecEnv(KWARGS, 2, seed=11, residual="scripted:formation", copy_offset=2)
    seen: dict[str, list] = {"whole": [], "tail": []}
    for name, env in (("whole", whole), ("tail", tail)):
        for k, base in enumerate(env._bases):
            base.reset = lambda s, k=k, name=name, real=base.reset: (
                seen[name].append((k, s)) or real(s)
            )
    whole.reset()
    tail.reset()
    zeros = np.zeros((whole.num_envs, 2), np.float32)
    for _ in range(13):  # across the 12-step episode's end: an auto-reset with seed None
        whole.step(zeros)
        tail.step(zeros[: tail.num_envs])
    auto = {k: s for k, s in seen["whole"][4:] if k >= 2}
    assert len(seen["whole"]) == 8 and len(auto) == 2
    assert [(k + 2, s) for k, s in seen["tail"]] == [(k, s) for k, s in seen["whole"] if k >= 2]
    whole.close()
    tail.close()


def test_the_in_process_batch_refuses_bad_actions_before_any_copy_moves():
    vec = BatchedSwarmVecEnv(KWARGS, 2, seed=4)
    ref = BatchedSwarmVecEnv(KWARGS, 2, seed=4)
    vec.reset()
    ref.reset()
    good = np.zeros((8, 2), np.float32)
    bad = good.copy()
    bad[6, 0] = np.inf  # copy 1: copy 0 must not have moved either
    with pytest.raises(ValueError, match=r"actions\[6\] \(copy 1, agent 2\) is not finite"):
        vec.step(bad)
    with pytest.raises(ValueError, match="real"):
        vec.step(np.full((8, 2), "a"))
    _assert_steps_equal(vec.step(good), ref.step(good), 0)


def test_a_worker_that_cannot_build_its_copies_is_reported_and_nothing_is_left():
    signal_before = signal.getsignal(signal.SIGINT)
    with pytest.raises(ValueError, match="preset") as caught:
        SubprocBatchedVecEnv({**KWARGS, "preset": "no-such-preset"}, 2, 2, seed=0)
    assert isinstance(caught.value.__cause__, RemoteTraceback)
    assert "BatchedSwarmVecEnv" in str(caught.value.__cause__)  # the worker's build frames
    assert signal.getsignal(signal.SIGINT) is signal_before
    assert not signal.pthread_sigmask(signal.SIG_BLOCK, set())  # the mask restored
    left = [p.name for p in multiprocessing.active_children()]
    assert not [name for name in left if name.startswith("swarm-env-copies")], left


def test_split_copies_blocks_and_refusals():
    assert split_copies(16, 2) == [range(0, 8), range(8, 16)]
    assert split_copies(5, 3) == [range(0, 2), range(2, 4), range(4, 5)]
    assert split_copies(4, 1) == [range(0, 4)]
    for args, match in (
        ((2, 3), "n_workers \\(3\\) must not exceed n_copies \\(2\\)"),
        ((4, 0), "n_workers must be an integer >= 1, got 0"),
        ((0, 1), "n_copies must be an integer >= 1, got 0"),
        ((4, True), "n_workers must be an integer >= 1, got True"),
    ):
        with pytest.raises(ValueError, match=match):
            split_copies(*args)


def _record_worker_vec_envs(monkeypatch) -> list[int]:
    """The ``n_workers`` of every :class:`SubprocBatchedVecEnv` built from now on."""
    built: list[int] = []
    init = SubprocBatchedVecEnv.__init__

    def recording(self, env_kwargs, n_copies, n_workers, *args, **kwargs):
        built.append(n_workers)
        init(self, env_kwargs, n_copies, n_workers, *args, **kwargs)

    monkeypatch.setattr(SubprocBatchedVecEnv, "__init__", recording)
    return built


def test_training_with_batched_workers_saves_a_usable_model(tmp_path, monkeypatch):
    """``swarm-phd train --num-cpus 2``: the batched copies in two workers (``--vec auto``)."""
    built = _record_worker_vec_envs(monkeypatch)
    out = tmp_path / "workers"
    args = ["train", "--preset", "lab-3m-4", "--task", "formation", "--observation", "phd"]
    args += ["--num-cpus", "2", "--n-copies", "2", "--timesteps", "512", "--max-steps", "50"]
    args += ["--n-steps", "64", "--batch-size", "128", "--n-epochs", "1"]
    assert main([*args, "--out", str(out), "--no-progress-bar"]) == 0
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["timesteps"] >= 512
    config = json.loads((out / "train_config.json").read_text())
    assert (config["num_cpus"], config["vec"]) == (2, "auto")
    assert built == [2]  # the batched copies in 2 workers, not SuperSuit's
    actions = _actions(out / "model.zip", seed=3)
    assert np.isfinite(actions).all() and np.abs(actions).max() > 0
