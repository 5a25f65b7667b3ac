"""PPO training smoke run (through ``swarm-phd train``), checkpoints, loading and determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

from agents.policies import load_policy  # noqa: E402
from agents.sb3.adapter import make_vec_env, scale_actions  # noqa: E402
from agents.sb3.policy import env_kwargs_for_model, read_metadata  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from swarm_phd.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    import numba

    out = tmp_path_factory.mktemp("runs") / "smoke"
    threads_before = numba.get_num_threads()
    code = main(
        [
            "train",
            "--preset",
            "lab-3m-4",
            "--task",
            "formation",
            "--observation",
            "phd",
            "--timesteps",
            "3000",
            "--out",
            str(out),
            "--n-copies",
            "1",
            "--n-steps",
            "256",
            "--batch-size",
            "256",
            "--n-epochs",
            "2",
            "--checkpoint-every",
            "1000",
            "--max-steps",
            "100",
            "--task-params",
            '{"radius_m": 0.7, "progress_weight": 5}',
            "--no-progress-bar",
        ]
    )
    assert code == 0
    assert numba.get_num_threads() == threads_before  # --kernel-threads 1, then restored
    return out


def test_training_writes_model_checkpoints_logs(run_dir):
    assert (run_dir / "model.zip").is_file()
    checkpoints = sorted((run_dir / "checkpoints").glob("model_*_steps.zip"))
    assert len(checkpoints) >= 2
    assert (run_dir / "monitor.csv").is_file()
    assert list((run_dir / "tb").glob("events.out.tfevents.*"))
    kwargs = json.loads((run_dir / "env_kwargs.json").read_text())
    assert kwargs["task"] == "formation" and kwargs["observation"] == "phd"
    assert kwargs["task_params"] == {"radius_m": 0.7, "progress_weight": 5}
    meta = read_metadata(checkpoints[0])
    assert meta["env_kwargs"] == kwargs
    assert meta["extractor"] == "sets" and meta["obs_norm"] is None
    assert json.loads((run_dir / "train_config.json").read_text())["kernel_threads"] == 1


def _actions(model_path, seed):
    kwargs = env_kwargs_for_model(model_path)
    env = parallel_env("lab-3m-4", **kwargs)
    policy = load_policy(str(model_path), env)
    policy.reset(seed)
    obs, infos = env.reset(seed=seed)
    out = []
    for _ in range(15):
        actions = policy(obs, infos)
        for agent, a in actions.items():
            assert env.action_space(agent).contains(a)
        out.append(np.stack([actions[a] for a in sorted(actions)]))
        obs, _, _, _, infos = env.step(actions)
    return np.stack(out)


def test_checkpoint_loads_and_acts_deterministically(run_dir):
    checkpoint = sorted((run_dir / "checkpoints").glob("model_*_steps.zip"))[0]
    a = _actions(checkpoint, seed=7)
    b = _actions(checkpoint, seed=7)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a).max() > 0  # it does act


def test_model_on_a_mismatched_env_is_a_clear_error(run_dir):
    env = parallel_env("lab-3m-4", task="wander")
    with pytest.raises(ValueError, match="expects observations of shape"):
        load_policy(str(run_dir / "model.zip"), env)


def test_bad_training_input_is_rejected(tmp_path):
    assert (
        main(["train", "--task", "nope", "--timesteps", "10", "--out", str(tmp_path / "x")]) == 2
    )
    assert (
        main(
            [
                "train",
                "--task",
                "formation",
                "--task-params",
                "[1]",
                "--timesteps",
                "10",
                "--out",
                str(tmp_path / "y"),
            ]
        )
        == 2
    )


def test_vec_env_is_one_entry_per_agent_and_flags_truncation():
    kwargs = {
        "preset": "lab-3m-4",
        "task": "formation",
        "observation": "truth",
        "localize": False,
        "max_steps": 3,
    }
    venv = make_vec_env(kwargs, n_copies=2, seed=0)
    assert venv.num_envs == 8
    assert venv.action_space.high.tolist() == [1.0, 1.0]
    venv.reset()
    for _ in range(3):
        _, rewards, dones, infos = venv.step(np.zeros((8, 2), dtype=np.float32))
    assert dones.all()
    assert all(info["TimeLimit.truncated"] and "terminal_observation" in info for info in infos)
    assert "episode" in infos[0]  # VecMonitor statistics
    venv.close()
    np.testing.assert_allclose(
        scale_actions(np.array([2.0, -0.5]), np.array([0.3, 1.5])), [0.3, -0.75]
    )


def test_set_extractor_ignores_row_order_and_padding():
    import torch

    from agents.sb3.features import NeighbourSetExtractor

    env = parallel_env("lab-3m-4", task="formation")
    space = env.observation_space("ugv_0")
    extractor = NeighbourSetExtractor(space, top_k=16)
    obs = np.zeros(space.shape, dtype=np.float32)
    rows = np.array(
        [
            [1.0, 0.5, -0.2, 0.01, 0.0, 0.02, 1.0],
            [0.8, -1.0, 0.7, 0.05, 0.01, 0.04, 1.0],
            [0.3, 2.0, 1.0, 0.2, 0.0, 0.1, 1.0],
        ],
        dtype=np.float32,
    )
    obs[:21] = rows.ravel()
    obs[-4:] = [0.1, 0.2, 0.8, 1.13]
    swapped = obs.copy()
    swapped[:21] = rows[[2, 0, 1]].ravel()
    with torch.no_grad():
        a = extractor(torch.as_tensor(obs[None]))
        b = extractor(torch.as_tensor(swapped[None]))
    torch.testing.assert_close(a, b)
    assert a.shape == (1, extractor.features_dim)


def _pooled_as_before(extractor, obs):
    """The set extractor's pooling as written until 2026-12-05: invalid rows set to -1e4 for
    the max, an empty table's max replaced by 0 (the reference for the current one)."""
    import torch

    from agents.sb3.features import ROW

    inputs, w, valid = extractor.row_inputs(obs)
    h = extractor.phi(inputs)
    mask = valid.float().unsqueeze(-1)
    weighted = (h * mask * w.unsqueeze(-1)).sum(dim=1)
    maxed = (h * mask - (1 - mask) * 1e4).max(dim=1).values
    maxed = torch.where(mask.sum(dim=1) > 0, maxed, torch.zeros_like(maxed))
    extra = obs[:, ROW * extractor.top_k : extractor.n_read] / extractor.extra_scale
    return torch.cat([weighted, maxed, extra], dim=1)


def test_set_extractor_pools_bit_for_bit_as_its_reference_formula():
    """Values and gradients equal the pre-2026-12-05 formula exactly, over real PHD tables
    (some with no valid row) and three Adam steps: saved models act as they did."""
    import copy

    import torch

    from agents.sb3.batched import BatchedSwarmVecEnv
    from agents.sb3.features import NeighbourSetExtractor

    vec = BatchedSwarmVecEnv({"preset": "lab-3m-4", "task": "formation"}, 2, seed=0)
    rng = np.random.default_rng(0)
    batches = [vec.reset()]
    for _ in range(25):
        batches.append(vec.step(rng.uniform(-1, 1, (vec.num_envs, 2)).astype(np.float32))[0])
    vec.close()
    obs = torch.as_tensor(np.concatenate([*batches, np.zeros_like(batches[0])]))
    valid = obs[:, : 7 * 16].reshape(len(obs), 16, 7)[..., 6] > 0.5
    assert (~valid.any(dim=1)).sum() >= 8 and valid.any(dim=1).sum() >= 80
    torch.manual_seed(0)
    current = NeighbourSetExtractor(vec.observation_space, top_k=16)
    before = copy.deepcopy(current)
    steps = [torch.optim.Adam(m.parameters(), lr=1e-2) for m in (current, before)]
    weights = torch.randn(len(obs), current.features_dim)
    for _ in range(3):
        a, b = current(obs), _pooled_as_before(before, obs)
        assert torch.equal(a, b)
        for optim, out in zip(steps, (a, b), strict=True):
            optim.zero_grad()
            (out * weights).sum().backward()
        for p, q in zip(current.parameters(), before.parameters(), strict=True):
            assert torch.equal(p.grad, q.grad)
        for optim in steps:
            optim.step()


def _threads_after_copy(make, queue) -> None:
    """In a child process: build a copy, report the kernel threads then in use."""
    import numba

    make()
    queue.put(numba.get_num_threads())


def test_supersuit_workers_use_one_kernel_thread_and_the_trainer_keeps_its_own():
    import multiprocessing

    import numba

    from agents.sb3.adapter import CopyForWorker

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs a kernel pool of 2 or more threads to tell 1 apart")
    make = CopyForWorker({"a": 1})
    before = numba.get_num_threads()
    assert make() == {"a": 1}
    assert numba.get_num_threads() == before  # the training process keeps its threads
    ctx = multiprocessing.get_context("spawn")  # as the trainer starts SuperSuit's workers
    queue = ctx.Queue()
    child = ctx.Process(target=_threads_after_copy, args=(make, queue))
    child.start()
    child.join(60)
    assert queue.get(timeout=5) == 1


def test_training_in_supersuit_worker_processes_saves_a_usable_model(tmp_path):
    # Step an env here first: forked workers of a process that has run the parallel kernels
    # die at their first kernel (the trainer spawns them instead).
    env = parallel_env("lab-3m-4", task="formation", observation="phd")
    env.reset(seed=0)
    env.step({a: env.action_space(a).sample() * 0 for a in env.agents})
    env.close()
    out = tmp_path / "procs"
    args = ["train", "--preset", "lab-3m-4", "--task", "formation", "--observation", "phd"]
    args += ["--vec", "supersuit", "--num-cpus", "2", "--n-copies", "2", "--timesteps", "512"]
    args += ["--n-steps", "64", "--batch-size", "128", "--n-epochs", "1", "--max-steps", "50"]
    assert main([*args, "--out", str(out), "--no-progress-bar"]) == 0
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["timesteps"] >= 512
    actions = _actions(out / "model.zip", seed=3)
    assert np.isfinite(actions).all() and np.abs(actions).max() > 0
