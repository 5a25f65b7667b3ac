"""``swarm-phd train --engine rllib``: PPO with parameter sharing on Ray RLlib (new API stack).

Same task, env and PPO options as the SB3 engine (:mod:`agents.sb3.train`, whose argument
definitions this reuses), plus :func:`add_engine_arguments`: ``--num-env-runners`` (env-runner
processes, each stepping ``--envs-per-runner`` env copies), ``--address`` (a Ray cluster;
default: start a local Ray) and ``--ray-num-cpus``. Every robot maps to one module
(:data:`agents.rllib.env.SHARED_POLICY`).

How the SB3 options map: ``--timesteps`` counts *agent* transitions (one env step of N robots
is N), as in SB3, rounded up to whole iterations (a first line says so); ``--n-steps`` is the
rollout fragment per env copy, so one PPO iteration trains on ``n_steps x max(1, runners) x
envs_per_runner`` env steps; ``--batch-size`` is the minibatch (default: 512 env steps, or the
whole iteration when smaller; a larger one given is refused); ``--n-epochs``,
``--learning-rate``, ``--gamma``, ``--ent-coef`` as named.

The learning lines give RLlib's mean episode return divided by the robots (per agent, as the
SB3 engine's) and the task's headline metric over the same finished episodes (logged by the env
runners, :func:`agents.rllib.env.task_metric_callback`), or "no episode finished yet" while the
iterations so far were shorter than one episode (RLlib reports NaN then). The final evaluation
and ``learning_curve.png`` are the SB3 engine's (:mod:`agents.train_report`; the run directory
is the policy, see :func:`agents.policies.load_policy`).
``--extractor`` and ``--n-copies`` / ``--num-cpus`` are SB3-only: RLlib's default MLP
encoder reads the observation vector (the Deep Sets extractor is an SB3 module), and the
runners replace the SB3 worker processes.

Writes, under ``--out``::

    env_kwargs.json       the env the policy was trained in
    train_config.json     the arguments and the RLlib PPO settings
    progress.csv          one row per iteration: agent/env steps, mean episode return, speed
    checkpoint/           the final Algorithm (``Algorithm.from_checkpoint``); the policy alone
                          is ``checkpoint/learner_group/learner/rl_module/shared``
    checkpoints/step_<agent steps>/   every ``--checkpoint-every`` agent transitions
    train_summary.json    totals, wall time, why it stopped early (``interrupted``, ``stopped``),
                          each runner's kernel threads and env start-up / first-step seconds
    learning_curve.csv / .png, final_evaluation.json    as the SB3 engine's

Ctrl-C / SIGTERM save ``checkpoint/`` and exit 130 / 143, as the SB3 engine does;
``--max-wall-minutes`` stops after the iteration in which the budget passes (exit 0).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from agents.interrupts import (
    EXIT_CODES,
    Interrupts,
    WallBudget,
    max_wall_seconds,
    stop_reason,
)
from swarm_core import inputs
from swarm_core.atomic_files import atomic_write


def add_engine_arguments(parser: argparse.ArgumentParser) -> None:
    """The RLlib-only options (the lead adds these to ``swarm-phd train``'s parser)."""
    parser.add_argument(
        "--num-env-runners",
        type=int,
        default=2,
        help="rllib: env-runner processes sampling in parallel (0: sample in the driver)",
    )
    parser.add_argument(
        "--envs-per-runner", type=int, default=1, help="rllib: env copies each runner steps"
    )
    parser.add_argument(
        "--address",
        default=None,
        help="rllib: Ray cluster to join ('auto', 'ray://HEAD:10001'); default: a local Ray",
    )
    parser.add_argument(
        "--ray-num-cpus",
        type=int,
        default=None,
        help="rllib: CPUs a local Ray may use (default: all of this machine's)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Every option of the RLlib engine: the SB3 engine's env/PPO options + the engine's own."""
    from agents.sb3.train import add_arguments as add_sb3_arguments

    add_sb3_arguments(parser)
    add_engine_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from agents.sb3.train import check_ppo_kwargs, env_kwargs_from_args, ppo_kwargs_from_args
    from swarm_core.validation import check_number

    # The shared flags, checked by the SB3 engine's rules before they are renamed for RLlib.
    check_ppo_kwargs(ppo_kwargs_from_args(args))
    max_wall_s = max_wall_seconds(getattr(args, "max_wall_minutes", None))
    check_number("--num-env-runners", args.num_env_runners, integer=True, low=0)
    check_number("--envs-per-runner", args.envs_per_runner, integer=True, low=1)
    check_number("--ray-num-cpus", args.ray_num_cpus, integer=True, low=1, optional=True)
    env_kwargs = env_kwargs_from_args(args)
    sb3_only = {
        "--warm-start": getattr(args, "warm_start", None) is not None,
        "--residual": getattr(args, "residual", None) is not None,
        "--residual-observes-base": getattr(args, "residual_observes_base", False),
        "--residual-mode": getattr(args, "residual_mode", "add") != "add",
        "--sde": getattr(args, "sde", False),
        "--critic-state": getattr(args, "critic_state", False),
        "--critic-warmup": bool(getattr(args, "critic_warmup", 0)),
        "--recurrent": getattr(args, "recurrent", False),
        # SB3's ratio clip and KL early stop have no like-for-like RLlib setting here.
        "--clip-range": getattr(args, "clip_range", 0.2) != 0.2,
        "--target-kl": getattr(args, "target_kl", None) is not None,
        # Its env runners run the kernels on one thread each, whatever this says.
        "--kernel-threads": getattr(args, "kernel_threads", 1) != 1,
    }
    given = [flag for flag, on in sb3_only.items() if on]
    if given:
        raise ValueError(f"swarm-phd train --engine rllib: {', '.join(given)} are SB3-only")
    ppo = {
        "rollout_fragment_length": args.n_steps,
        "num_epochs": args.n_epochs,
        "lr": args.learning_rate,
        "gamma": args.gamma,
        "entropy_coeff": args.ent_coef,
    }
    if args.batch_size is not None:  # else derived from the iteration's batch (build_config)
        ppo["minibatch_size"] = args.batch_size
    _, interrupted = _train(
        env_kwargs,
        args.timesteps,
        Path(args.out),
        seed=args.seed,
        overwrite=getattr(args, "overwrite", False),
        num_env_runners=args.num_env_runners,
        envs_per_runner=args.envs_per_runner,
        address=args.address,
        ray_num_cpus=args.ray_num_cpus,
        checkpoint_every=getattr(args, "checkpoint_every", 50_000),
        torch_threads=getattr(args, "torch_threads", 1),
        progress_bar=not (
            getattr(args, "no_progress_bar", False) or getattr(args, "quiet", False)
        ),
        ppo=ppo,
        max_wall_s=max_wall_s,
        eval_seeds=getattr(args, "eval_seeds", 0),
    )
    return EXIT_CODES.get(interrupted, 0) if interrupted else 0


def train(*args: Any, **kwargs: Any) -> Path:
    """Train and return the final checkpoint directory; arguments as :func:`_train`."""
    return _train(*args, **kwargs)[0]


def _task_metric(sampled: dict[str, Any], window: int) -> tuple[str, float, int] | None:
    """The task's headline metric over the last finished episodes, from the runners' results
    (:class:`agents.rllib.env.task_metric_callback`), as :class:`LearningLog` takes it."""
    from agents.rllib.env import TASK_METRIC_PREFIX

    for key, value in sampled.items():
        if isinstance(key, str) and key.startswith(TASK_METRIC_PREFIX):
            if isinstance(value, (int, float)) and math.isfinite(value):
                return key[len(TASK_METRIC_PREFIX) :], float(value), window
    return None


def build_config(
    env_kwargs: dict[str, Any],
    *,
    seed: int = 0,
    num_env_runners: int = 2,
    envs_per_runner: int = 1,
    ppo: dict[str, Any] | None = None,
):
    """The RLlib ``PPOConfig``: shared module, ``num_env_runners`` runners, PPO settings.

    ``ppo`` keys: ``rollout_fragment_length`` (env steps per env copy per iteration),
    ``minibatch_size``, ``num_epochs``, ``lr``, ``gamma``, ``entropy_coeff``, ``lambda_``,
    ``clip_param``. Without ``minibatch_size``, the minibatch is
    :data:`~agents.sb3.train.DEFAULT_BATCH_SIZE` env steps, or the iteration's whole batch when
    that is smaller. Raises ValueError naming a bad count, or a ``minibatch_size`` given larger
    than the iteration's batch.
    """
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    from agents.rllib.env import SHARED_POLICY, policy_mapping_fn, register, task_metric_callback

    if num_env_runners < 0:
        raise ValueError(f"--num-env-runners must be >= 0, got {num_env_runners}")
    if envs_per_runner < 1:
        raise ValueError(f"--envs-per-runner must be >= 1, got {envs_per_runner}")
    from agents.sb3.train import DEFAULT_BATCH_SIZE

    p = {
        "rollout_fragment_length": 128,
        "num_epochs": 10,
        "lr": 3e-4,
        "gamma": 0.99,
        "lambda_": 0.95,
        "entropy_coeff": 0.0,
        "clip_param": 0.2,
        **(ppo or {}),
    }
    fragment = int(p.pop("rollout_fragment_length"))
    if fragment < 1:
        raise ValueError(f"--n-steps (rollout fragment) must be >= 1, got {fragment}")
    # One iteration = one fragment from every env copy (env steps; RLlib counts them so).
    batch = fragment * max(1, num_env_runners) * envs_per_runner
    p.setdefault("minibatch_size", min(DEFAULT_BATCH_SIZE, batch))
    if int(p["minibatch_size"]) > batch:
        # RLlib's own check, said in this command's terms (before Ray builds anything).
        raise ValueError(
            f"--batch-size ({p['minibatch_size']}) must be <= the iteration's batch, "
            f"n_steps x max(1, runners) x envs_per_runner = {batch} env steps"
        )
    name = register()
    return (
        PPOConfig()
        .environment(name, env_config={"env_kwargs": env_kwargs, "kernel_threads": 1})
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=envs_per_runner,
            rollout_fragment_length=fragment,
            num_cpus_per_env_runner=1,
        )
        .training(train_batch_size_per_learner=batch, **p)
        .multi_agent(policies={SHARED_POLICY}, policy_mapping_fn=policy_mapping_fn)
        .rl_module(
            rl_module_spec=MultiRLModuleSpec(rl_module_specs={SHARED_POLICY: RLModuleSpec()})
        )
        .callbacks(task_metric_callback())
        .debugging(seed=seed)
    )


def start_ray(address: str | None = None, num_cpus: int | None = None) -> bool:
    """Join ``address`` or start a local Ray (no dashboard); returns whether this call started
    it (then the caller shuts it down). An already initialised Ray is reused as it is."""
    import ray

    if ray.is_initialized():
        return False
    # Ray forwards the driver's environment to local workers; the OpenMP policy set by
    # swarm_core.threads (PASSIVE) then reaches every runner before its libgomp loads.
    if address:
        ray.init(address=address, log_to_driver=True)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=True)
    return True


def _train(
    env_kwargs: dict[str, Any],
    timesteps: int,
    out: Path,
    *,
    seed: int = 0,
    overwrite: bool = False,
    num_env_runners: int = 2,
    envs_per_runner: int = 1,
    address: str | None = None,
    ray_num_cpus: int | None = None,
    checkpoint_every: int = 50_000,
    torch_threads: int = 1,
    progress_bar: bool = True,
    ppo: dict[str, Any] | None = None,
    max_wall_s: float | None = None,
    eval_seeds: int = 0,
) -> tuple[Path, str | None]:
    """Train; return the final checkpoint directory and the signal that stopped it (or None).
    ``eval_seeds``: afterwards, the final evaluation on that many held-out seeds
    (:mod:`agents.train_report`; 0: only ``learning_curve.csv`` / ``.png`` of the returns)."""
    from agents.sb3.train import check_run_flags
    from agents.train_report import LearningLog, finish, rollout_plan, say
    from agents.train_report import eval_seeds as held_out_seeds

    check_run_flags(timesteps, seed, checkpoint_every, torch_threads, max_wall_s)
    seeds = held_out_seeds(eval_seeds)
    try:
        import ray  # noqa: F401
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ValueError("--engine rllib needs the ray extra: pip install -e '.[rl,ray]'") from exc

    import swarm_core.threads  # noqa: F401 - sets OMP_WAIT_POLICY before Ray copies the env
    from agents.rllib.env import prewarm_kernels
    from swarm_core import progress
    from swarm_env import parallel_env

    inputs.run_dir("--out", out, overwrite=overwrite)
    probe = parallel_env(**env_kwargs)  # bad task / config keys fail here, before Ray starts
    n_agents = len(probe.possible_agents)
    probe.close()
    # Compile the kernels here, once, before any runner starts: the runners load the cache.
    prewarm_kernels()
    torch.set_num_threads(torch_threads)  # the learner runs in this process

    config = build_config(
        env_kwargs,
        seed=seed,
        num_env_runners=num_env_runners,
        envs_per_runner=envs_per_runner,
        ppo=ppo,
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "env_kwargs.json").write_text(json.dumps(env_kwargs, indent=2))
    (out / "train_config.json").write_text(
        json.dumps(
            {
                "engine": "rllib",
                "timesteps": timesteps,
                "seed": seed,
                "num_env_runners": num_env_runners,
                "envs_per_runner": envs_per_runner,
                "address": address,
                "n_agents_per_env": n_agents,
                "checkpoint_every": checkpoint_every,
                "torch_threads": torch_threads,
                "train_batch_size_env_steps": config.train_batch_size_per_learner,
                "ppo": {
                    "rollout_fragment_length": config.rollout_fragment_length,
                    "minibatch_size": config.minibatch_size,
                    "num_epochs": config.num_epochs,
                    "lr": config.lr,
                    "gamma": config.gamma,
                    "lambda": config.lambda_,
                    "entropy_coeff": config.entropy_coeff,
                    "clip_param": config.clip_param,
                },
                "model": "RLlib default MLP encoder (shared by all agents)",
            },
            indent=2,
        )
    )

    # One iteration trains on the batch's env steps, each of n_agents agent transitions.
    per_iteration = config.train_batch_size_per_learner * n_agents
    planned, rounded = rollout_plan(
        timesteps,
        per_iteration,
        f"--n-steps {config.rollout_fragment_length} x {max(1, num_env_runners)} runner(s) x "
        f"{envs_per_runner} env(s) per runner x {n_agents} agents",
    )
    if rounded:
        say(rounded.replace("rollout", "iteration"))
    say(
        f"rllib PPO: {planned} agent steps, one module shared by the {n_agents} robots, RLlib's "
        "default MLP encoder over the observation vector"
    )
    log = LearningLog(planned, "rllib")
    started = start_ray(address, ray_num_cpus)
    algo = None
    final = out / "checkpoint"
    bar = progress.bar(planned, "train (rllib)", unit="agent-step") if progress_bar else None
    start = time.perf_counter()
    budget = WallBudget(max_wall_s)
    agent_steps = env_steps = 0
    last_return: float | None = None
    rows: list[dict[str, Any]] = []
    runners: list[dict[str, Any]] = []
    try:
        with Interrupts() as interrupts:
            with interrupts.caught():
                algo = config.build_algo()
                next_ckpt = checkpoint_every
                while agent_steps < timesteps:
                    result = algo.train()
                    sampled = result["env_runners"]
                    new_agent = int(sum(sampled["num_agent_steps_sampled_lifetime"].values()))
                    row = {
                        "iteration": int(result["training_iteration"]),
                        "agent_steps": new_agent,
                        "env_steps": int(sampled["num_env_steps_sampled_lifetime"]),
                        "episode_return_mean": float(
                            sampled.get("episode_return_mean", float("nan"))
                        ),
                        "episode_len_mean": float(sampled.get("episode_len_mean", float("nan"))),
                        "time_this_iter_s": float(result["time_this_iter_s"]),
                        "env_steps_per_s": float(sampled["num_env_steps_sampled"])
                        / max(float(result["time_this_iter_s"]), 1e-9),
                    }
                    rows.append(row)
                    _write_progress(out / "progress.csv", rows)
                    # RLlib's return is the sum over the episode's agents: per agent, as SB3's.
                    per_agent = row["episode_return_mean"] / n_agents
                    if math.isfinite(per_agent):
                        last_return = per_agent
                    elif last_return is not None:
                        # RLlib reports NaN for an iteration in which no episode ended: the
                        # mean of the last finished episodes is the last one reported.
                        per_agent = last_return
                    window = min(  # the episodes RLlib's mean is over
                        int(sampled.get("num_episodes_lifetime", 0)),
                        int(config.metrics_num_episodes_for_smoothing),
                    )
                    log.add(new_agent, per_agent, window, bar, _task_metric(sampled, window))
                    if bar is not None:
                        bar.set_postfix_str(
                            f"return per agent {per_agent:.2f}"
                            if math.isfinite(per_agent)
                            else "no episode finished yet",
                            refresh=False,
                        )
                        bar.update(new_agent - agent_steps)
                    agent_steps, env_steps = new_agent, row["env_steps"]
                    if agent_steps >= next_ckpt:
                        step_dir = out / "checkpoints" / f"step_{agent_steps}"
                        algo.save_to_path(str(step_dir.resolve()))
                        next_ckpt = agent_steps + checkpoint_every
                    if budget.passed():
                        break
                    if interrupts.received:  # backstop: an interrupt that library code dropped
                        break
            interrupted = interrupts.received
        with Interrupts(ignore=True):  # a second signal must not leave a half-written save
            if algo is not None:
                algo.save_to_path(str(final.resolve()))
                runners = _runner_reports(algo, num_env_runners)
            elapsed = time.perf_counter() - start
            summary = {
                "engine": "rllib",
                "agent_steps": agent_steps,
                "env_steps": env_steps,
                "iterations": len(rows),
                "wall_time_s": elapsed,
                "agent_steps_per_s": agent_steps / max(elapsed, 1e-9),
                "interrupted": interrupted,
                "stopped": stop_reason(interrupted, budget),
                "checkpoint": str(final) if algo is not None else None,
                "runners": runners,
            }
            (out / "train_summary.json").write_text(json.dumps(summary, indent=2))
    finally:
        if bar is not None:
            bar.close()
        if algo is not None:
            algo.stop()
        if started:
            import ray

            ray.shutdown()
    if interrupted:
        print(
            f"swarm-phd train --engine rllib: {interrupted} at {agent_steps} agent steps: "
            f"saved {final}",
            file=sys.stderr,
        )
    else:
        why = ", wall-time budget" if budget.reached else ""
        print(f"trained {agent_steps} agent steps in {elapsed:.0f} s (rllib{why}) -> {final}")
    checkpoints = sorted(
        (int(p.name.split("_")[1]), str(p))
        for p in (out / "checkpoints").glob("step_*")
        if int(p.name.split("_")[1]) < agent_steps
    )
    finish(
        out,
        log,
        str(out),
        env_kwargs,
        [] if interrupted or algo is None else seeds,
        checkpoints,
        f"{env_kwargs.get('preset')}, task {env_kwargs.get('task')}, rllib PPO",
    )
    return final, interrupted


def _runner_reports(algo: Any, num_env_runners: int) -> list[dict[str, Any]]:
    """Each env runner's kernel threads, env start-up and first-step seconds
    (:func:`agents.rllib.env.runner_report`)."""
    from agents.rllib.env import runner_report

    return list(
        algo.env_runner_group.foreach_env_runner(
            runner_report, local_env_runner=num_env_runners == 0
        )
    )


def _write_progress(path: Path, rows: list[dict[str, Any]]) -> None:
    """The whole table, written to a temporary file and renamed (never half-written)."""

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)

    atomic_write(path, write)
