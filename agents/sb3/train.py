"""``swarm-phd train``: PPO with parameter sharing (one policy for every agent) on a SwarmEnv task.

Bad input is refused before anything is written under ``--out``: a flag out of its range (a
NaN) and an ``--out`` holding a previous run (without ``--overwrite``) before any env is built;
the env's own settings by one probe env.
One line naming the flag and the value, exit code 2 (from Python, :func:`train` raises
``ValueError``).

Writes, under ``--out``::

    model.zip                 final model (+ swarm_phd.json inside: env kwargs, obs normalisation)
    env_kwargs.json           the env the model was trained in
    train_config.json         the command's arguments and PPO hyper-parameters
    checkpoints/model_<steps>_steps.zip   every --checkpoint-every agent-steps
    tb/                       tensorboard logs (PPO_1/...)
    monitor.csv               one row per agent-episode (VecMonitor): r, l, t
    tb/progress.csv           rollout/ep_rew_mean etc. per PPO iteration
    warm_start.zip/.json      with --warm-start: the cloned actor before PPO, and its fit
    learning_curve.csv        one row per rollout: agent steps, mean episode return per agent
                              (and the task's first metric) over the last finished episodes
    final_evaluation.json     the held-out scores and the paired table (--eval-seeds > 0)
    learning_curve.png        return and task metric against agent steps, baselines drawn

Timesteps count *agent* transitions: one env step of N robots is N timesteps. PPO collects
whole rollouts (``n_steps`` x agents), so the run ends at the first multiple of a rollout at or
past ``--timesteps``; a first line says so when that is more than asked, and the progress bar
counts to that number. ``--batch-size`` defaults to 512, or the whole rollout when smaller.

While it trains, a line per rollout (at most about ten) gives the mean episode return per agent
and, with the batched VecEnv, the task's first metric over the last finished episodes. After
it, :mod:`agents.train_report` scores the model, its checkpoints, the task's scripted controller
and ``random`` on ``--eval-seeds`` held-out seeds (5 from the command line, none by default from
Python) and prints the paired verdict table.

Ctrl-C (SIGINT) or SIGTERM stops training cleanly: the current model is saved as ``model.zip``
and as ``checkpoints/model_<steps>_steps.zip``, the env workers and logs are closed, and the
command prints one line and exits with 130 (SIGINT) or 143 (SIGTERM). ``--max-wall-minutes``
stops training at the first env step past the budget and saves ``model.zip`` as a finished run
does (exit 0). ``train_summary.json`` records why a run stopped early: ``"stopped"`` is
``"SIGINT"``, ``"SIGTERM"``, ``"max-wall-minutes"`` or null (``"interrupted"``: the signal).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from agents.interrupts import (
    EXIT_CODES,
    Interrupts,
    WallBudget,
    add_max_wall_argument,
    max_wall_seconds,
    set_signal,
    stop_reason,
)
from agents.sb3.policy import save_model
from swarm_core import inputs
from swarm_core.atomic_files import write_json_atomically
from swarm_core.inputs import parse_json_object
from swarm_core.validation import check_number

DEFAULT_PRESET = "sim-6m-20"
DEFAULT_MAX_STEPS = 300
#: The largest seed SB3 accepts (it seeds numpy's legacy generator with it).
MAX_SEED = 2**32 - 1
#: PPO's minibatch when ``--batch-size`` is not given (the whole rollout when that is smaller).
DEFAULT_BATCH_SIZE = 512


#: PPO keyword -> (the name an error gives it, :func:`check_number` bounds). The keys with a
#: ``swarm-phd train`` flag are named by the flag; the others can come only from Python.
PPO_NUMBERS: dict[str, tuple[str, dict[str, Any]]] = {
    "n_steps": ("--n-steps", {"integer": True, "low": 1}),
    "batch_size": ("--batch-size", {"integer": True, "low": 1}),
    "n_epochs": ("--n-epochs", {"integer": True, "low": 1}),
    "learning_rate": ("--learning-rate", {"low": 0, "above": True, "schedule": True}),
    "gamma": ("--gamma", {"low": 0, "high": 1}),
    "gae_lambda": ("ppo_kwargs['gae_lambda']", {"low": 0, "high": 1}),
    "ent_coef": ("--ent-coef", {"low": 0}),
    "vf_coef": ("ppo_kwargs['vf_coef']", {"low": 0}),
    "max_grad_norm": ("ppo_kwargs['max_grad_norm']", {"low": 0, "above": True}),
    "clip_range": ("--clip-range", {"low": 0, "above": True, "schedule": True}),
    "clip_range_vf": (
        "ppo_kwargs['clip_range_vf']",
        {"low": 0, "above": True, "schedule": True, "optional": True},
    ),
    "target_kl": ("--target-kl", {"low": 0, "above": True, "optional": True}),
    # SB3: -1 (or 0) draws gSDE's noise matrix once per rollout, n > 0 every n steps.
    "sde_sample_freq": ("ppo_kwargs['sde_sample_freq']", {"integer": True, "low": -1}),
    "stats_window_size": ("ppo_kwargs['stats_window_size']", {"integer": True, "low": 1}),
}
PPO_FLAGS = ("use_sde", "normalize_advantage")


def check_ppo_kwargs(ppo_kwargs: dict[str, Any]) -> None:
    """``ValueError`` naming the field and the value for a PPO hyper-parameter that SB3 would
    reject (with an assertion, deep in the constructor) or would train on silently (a NaN
    discount, a negative entropy weight, zero epochs); keys that :func:`train` does not know
    (or sets itself, such as ``seed``) are refused too."""
    for key, value in ppo_kwargs.items():
        if key in PPO_NUMBERS:
            name, bounds = PPO_NUMBERS[key]
            check_number(name, value, **bounds)
        elif key in PPO_FLAGS:
            if not isinstance(value, bool):
                raise ValueError(f"ppo_kwargs[{key!r}] must be True or False, got {value!r}")
        else:
            known = ", ".join([*PPO_NUMBERS, *PPO_FLAGS])
            raise ValueError(f"ppo_kwargs has an unknown key {key!r} (known: {known})")
    # SB3 asserts it: advantages normalised over a minibatch of one are NaN.
    if ppo_kwargs.get("normalize_advantage", True) and ppo_kwargs.get("batch_size") == 1:
        raise ValueError(
            "--batch-size must be > 1 when the advantages are normalised (SB3: a minibatch of "
            "one normalises to NaN), got 1"
        )


def add_env_arguments(parser: argparse.ArgumentParser) -> None:
    """The env's flags (task, observation, preset, overrides): :func:`env_kwargs_from_args`."""
    parser.add_argument("--task", default="formation", help="task name (see swarm_env.tasks)")
    parser.add_argument(
        "--task-params",
        default="{}",
        help="JSON dict of task parameters, e.g. '{\"radius_m\": 0.8}'",
    )
    parser.add_argument("--observation", default="phd", choices=["phd", "truth", "measurements"])
    parser.add_argument("--preset", default=DEFAULT_PRESET)
    parser.add_argument("--n-robots", type=int, default=None, help="default: the preset's")
    parser.add_argument(
        "--max-steps",
        type=int,
        default=DEFAULT_MAX_STEPS,
        help="episode length in env steps (0.1 s each)",
    )
    parser.add_argument(
        "--env-overrides",
        default="{}",
        help='JSON dict of further SwarmConfig overrides, e.g. \'{"arena": {"n_boxes": 0}}\'',
    )
    parser.add_argument(
        "--lidar-sectors",
        type=int,
        default=None,
        help="add the robot's own lidar scan as S sector minima to the observation "
        "(SwarmConfig.lidar_sectors; default: the preset's, 0)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_env_arguments(parser)
    parser.add_argument("--timesteps", type=int, default=200_000, help="agent transitions")
    parser.add_argument("--out", required=True, help="run directory, e.g. runs/formation_phd")
    inputs.add_overwrite_argument(parser)
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--n-copies", type=int, default=4, help="env copies (x n_robots agents)")
    parser.add_argument(
        "--num-cpus",
        type=int,
        default=0,
        help="worker processes for the env copies (0: step them in-process); batched: each "
        "worker steps a block of the copies (1: all of them, not in parallel; 2 with 16 copies "
        "on an idle 2-core machine: 1.1-1.3x faster than in-process, no gain with a core "
        "busy)",
    )
    parser.add_argument(
        "--vec",
        choices=("auto", "batched", "supersuit"),
        default="auto",
        help="VecEnv: 'batched' steps the copies with one filter call for all of them "
        "(agents.sb3.batched; with --num-cpus N, one call per worker); 'supersuit' uses "
        "SuperSuit's vectorizers; 'auto': batched (a localizer that knows identities, id-phd, "
        "ukf or pf, gets one per copy)",
    )
    parser.add_argument("--n-steps", type=int, default=128, help="PPO rollout length per agent")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        help="PPO minibatch size (default: 512, or the whole rollout when it is smaller)",
    )
    parser.add_argument("--n-epochs", type=int, default=10, help="PPO epochs per rollout")
    parser.add_argument("--learning-rate", type=float, default=3e-4, help="Adam step size")
    parser.add_argument("--gamma", type=float, default=0.99, help="discount factor")
    parser.add_argument("--ent-coef", type=float, default=0.0, help="entropy bonus weight")
    parser.add_argument(
        "--clip-range", type=float, default=0.2, help="PPO ratio clip (smaller: stay nearer)"
    )
    parser.add_argument(
        "--target-kl",
        type=float,
        default=None,
        help="stop a PPO update's epochs once the KL to the rollout policy passes this",
    )
    parser.add_argument(
        "--warm-start",
        default=None,
        metavar="scripted:NAME",
        help="behaviour-clone this teacher (on the same observation) before PPO "
        "(agents.sb3.warm_start): scripted:NAME, or privileged:NAME / privileged:NAME@truth "
        "(read ground truth, agents.sb3.privileged); with --residual the clone is the "
        "correction from the scripted base to the teacher",
    )
    parser.add_argument(
        "--residual",
        default=None,
        metavar="scripted:NAME",
        help="RESIDUAL policy (agents.sb3.residual): the command is this scripted controller's "
        "action plus the learned correction, whose mean starts at zero (batched VecEnv only)",
    )
    parser.add_argument(
        "--residual-log-std",
        type=float,
        default=None,
        help="initial log-std of the residual correction (unit action scale; default -1.5, "
        "std 0.22). With --sde it is per hidden unit, and the default is -3.0: about the "
        "same action std, the formation policy's hidden layer having a norm of about 4.5",
    )
    parser.add_argument(
        "--sde",
        action="store_true",
        help="generalised state-dependent exploration (gSDE, Raffin et al. 2022): the "
        "exploration noise is a random linear map of the policy's last hidden layer, drawn "
        "per agent once per rollout, so a perturbation persists for --n-steps steps instead "
        "of changing every step. The log-std (--residual-log-std with --residual) is then "
        "per hidden unit: the action's noise std is exp(log_std) times that layer's norm",
    )
    parser.add_argument(
        "--residual-mode",
        choices=("add", "gain"),
        default="add",
        help="with --residual: add the correction to the scripted command (add), or scale "
        "each of its two commands by 4**correction, from 1/4 to 4 times (gain)",
    )
    parser.add_argument(
        "--residual-observes-base",
        action="store_true",
        help="with --residual: append the scripted command (unit scale) to the policy's "
        "observation, so the correction can depend on it directly",
    )
    parser.add_argument(
        "--critic-state",
        action="store_true",
        help="centralised critic (agents.sb3.central_critic): the value function also reads "
        "the true teammate positions and task state, the policy does not (batched VecEnv, "
        "--extractor sets)",
    )
    parser.add_argument(
        "--recurrent",
        action="store_true",
        help="recurrent PPO (sb3-contrib RecurrentPPO): an LSTM after the extractor, in the "
        "actor and the critic, so the policy acts on the history of its observations "
        "(a static decoy and a moving teammate differ over time, not in one frame)",
    )
    parser.add_argument(
        "--lstm-hidden",
        type=int,
        default=None,
        help="with --recurrent: LSTM hidden units (default 64)",
    )
    parser.add_argument(
        "--bc-steps", type=int, default=40_000, help="demonstration agent transitions"
    )
    parser.add_argument(
        "--bc-rounds",
        type=int,
        default=1,
        help="1: plain behaviour cloning; R > 1: R DAgger rounds (rounds 2.. driven by the "
        "clone, labelled by the teacher)",
    )
    parser.add_argument("--bc-epochs", type=int, default=30, help="fit epochs per round")
    parser.add_argument(
        "--bc-log-std",
        type=float,
        default=-1.5,
        help="action log-std after the warm start (PPO's exploration around the clone)",
    )
    parser.add_argument(
        "--critic-warmup",
        type=int,
        default=0,
        help="first PPO rollouts that train only the value function (actor frozen)",
    )
    parser.add_argument("--checkpoint-every", type=int, default=50_000, help="agent transitions")
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch intra-op threads (1 leaves the other core to the envs)",
    )
    parser.add_argument(
        "--kernel-threads",
        type=int,
        default=1,
        help="threads of the compiled sensor and filter kernels of the envs in this process "
        "(1: lab-3m-4 training ran 1.3x faster than with 2 on 2 cores, benchmarks/RESULTS.md; "
        "env worker processes, batched or SuperSuit's, use 1 each)",
    )
    parser.add_argument(
        "--extractor",
        default="sets",
        choices=["sets", "mlp"],
        help="'sets': permutation-invariant Deep Sets over the neighbour table "
        "(phd/truth observations); 'mlp': plain MLP on the normalised "
        "vector",
    )
    add_max_wall_argument(parser, "once")  # SB3: at the next env step; RLlib: that iteration
    from agents.train_report import add_eval_arguments

    add_eval_arguments(parser)
    parser.add_argument(
        "--no-progress-bar", action="store_true", help="no progress bar (as --quiet, for train)"
    )


def env_kwargs_from_args(args: argparse.Namespace) -> dict[str, Any]:
    kwargs: dict[str, Any] = {
        "preset": args.preset,
        "task": args.task,
        "task_params": parse_json_object(args.task_params, "--task-params"),
        "observation": args.observation,
        "max_steps": args.max_steps,
        **parse_json_object(args.env_overrides, "--env-overrides"),
    }
    if args.n_robots is not None:
        kwargs["n_robots"] = args.n_robots
    if getattr(args, "lidar_sectors", None) is not None:
        kwargs["lidar_sectors"] = args.lidar_sectors
    if args.observation != "phd":
        kwargs.setdefault("localize", False)  # the filters cost most of the step; unused here
    return kwargs


def check_run_flags(
    timesteps: Any, seed: Any, checkpoint_every: Any, torch_threads: Any, max_wall_s: Any
) -> None:
    """The run's own numbers, the same for both engines (``ValueError`` naming the flag)."""
    check_number("--timesteps", timesteps, integer=True, low=1)
    check_number("--seed", seed, integer=True, low=0, high=MAX_SEED)
    check_number("--checkpoint-every", checkpoint_every, integer=True, low=1)
    check_number("--torch-threads", torch_threads, integer=True, low=1)
    check_number("max_wall_s", max_wall_s, low=0, above=True, optional=True)


def ppo_kwargs_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The PPO flags as SB3's keywords: what the SB3 engine trains on, and what both engines
    check (:func:`check_ppo_kwargs`) before the RLlib engine renames its share of them."""
    ppo_kwargs = {
        "n_steps": args.n_steps,
        "n_epochs": args.n_epochs,
        "learning_rate": args.learning_rate,
        "gamma": args.gamma,
        "ent_coef": args.ent_coef,
        "clip_range": args.clip_range,
        "target_kl": args.target_kl,
    }
    if args.batch_size is not None:  # else derived from the rollout (DEFAULT_BATCH_SIZE)
        ppo_kwargs["batch_size"] = args.batch_size
    if args.sde:
        ppo_kwargs["use_sde"] = True
    return ppo_kwargs


def run(args: argparse.Namespace) -> int:
    max_wall_s = max_wall_seconds(args.max_wall_minutes)
    env_kwargs = env_kwargs_from_args(args)
    ppo_kwargs = ppo_kwargs_from_args(args)
    warm = None
    if args.warm_start is not None:
        warm = {
            "teacher": args.warm_start,
            "steps": args.bc_steps,
            "rounds": args.bc_rounds,
            "epochs": args.bc_epochs,
            "log_std": args.bc_log_std,
        }
    _, interrupted = _train(
        env_kwargs,
        args.timesteps,
        Path(args.out),
        seed=args.seed,
        overwrite=args.overwrite,
        n_copies=args.n_copies,
        num_cpus=args.num_cpus,
        vec=args.vec,
        checkpoint_every=args.checkpoint_every,
        torch_threads=args.torch_threads,
        kernel_threads=args.kernel_threads,
        progress_bar=not (args.no_progress_bar or getattr(args, "quiet", False)),
        ppo_kwargs=ppo_kwargs,
        max_wall_s=max_wall_s,
        extractor=args.extractor,
        warm_start=warm,
        critic_warmup=args.critic_warmup,
        residual=args.residual,
        residual_log_std=args.residual_log_std,
        critic_state=args.critic_state,
        residual_observes_base=args.residual_observes_base,
        residual_mode=args.residual_mode,
        lstm_hidden=_lstm_hidden(args),
        eval_seeds=args.eval_seeds,
    )
    return EXIT_CODES.get(interrupted, 0) if interrupted else 0


def _lstm_hidden(args: argparse.Namespace) -> int | None:
    """The LSTM size of ``--recurrent`` (64 unless ``--lstm-hidden``), else None."""
    if not args.recurrent:
        if args.lstm_hidden is not None:
            raise ValueError(f"--lstm-hidden {args.lstm_hidden} needs --recurrent")
        return None
    return 64 if args.lstm_hidden is None else args.lstm_hidden


def _vec_env(
    vec: str,
    env_kwargs,
    n_copies: int,
    num_cpus: int,
    seed: int,
    monitor: str,
    residual: str | None = None,
    critic_state: bool = False,
    residual_observes_base: bool = False,
    residual_mode: str = "add",
):
    """The training VecEnv (``--vec``): batched copies (in this process, or in ``num_cpus``
    worker processes) or SuperSuit's."""
    from agents.sb3.adapter import make_vec_env
    from agents.sb3.batched import make_batched_vec_env

    vec = _resolve_vec(vec, n_copies, num_cpus, residual is not None, critic_state)
    if vec == "batched":
        return make_batched_vec_env(
            env_kwargs,
            n_copies=n_copies,
            n_workers=num_cpus,
            seed=seed,
            monitor_file=monitor,
            residual=residual,
            critic_state=critic_state,
            residual_observes_base=residual_observes_base,
            residual_mode=residual_mode,
        )
    return make_vec_env(
        env_kwargs, n_copies=n_copies, num_cpus=num_cpus, seed=seed, monitor_file=monitor
    )


def _resolve_vec(
    vec: str, n_copies: int, num_cpus: int, residual: bool, critic_state: bool
) -> str:
    """``"batched"`` or ``"supersuit"`` for ``--vec`` (``"auto"`` resolved); ``ValueError``
    for a combination the chosen VecEnv cannot serve."""
    if vec not in ("auto", "batched", "supersuit"):
        raise ValueError(f"--vec must be auto, batched or supersuit, got {vec!r}")
    if vec == "auto":
        vec = "batched"
    if vec == "batched" and num_cpus > n_copies:
        raise ValueError(
            f"--num-cpus {num_cpus} exceeds --n-copies {n_copies}: each batched worker "
            "steps at least one copy"
        )
    for flag, on in (("--residual", residual), ("--critic-state", critic_state)):
        if on and vec != "batched":
            raise ValueError(f"{flag} needs the batched VecEnv (--vec batched or auto)")
    return vec


def train(*args: Any, **kwargs: Any) -> Path:
    """Train and return the path of ``model.zip``; see the module docstring for the outputs.

    Arguments as :func:`_train` and :func:`_train_with`. An interrupt (SIGINT/SIGTERM) ends
    training early with the model saved; ``train_summary.json`` then says ``"interrupted":
    "SIGINT"`` and ``"stopped": "SIGINT"``. ``max_wall_s`` ends it at the first env step past
    that many seconds, the model saved, with ``"stopped": "max-wall-minutes"``.
    """
    return _train(*args, **kwargs)[0]


def _train(
    env_kwargs: dict[str, Any], timesteps: int, out: Path, *, kernel_threads: int = 1, **kwargs
) -> tuple[Path, str | None]:
    """:func:`_train_with` on ``kernel_threads`` threads of the compiled kernels (checked here,
    ``ValueError`` naming ``--kernel-threads``); the caller's setting is restored after."""
    import numba

    from swarm_core.threads import set_kernel_threads

    limit = numba.config.NUMBA_NUM_THREADS
    check_number("--kernel-threads", kernel_threads, integer=True, low=1, high=limit)
    previous = numba.get_num_threads()
    set_kernel_threads(kernel_threads)
    try:
        return _train_with(env_kwargs, timesteps, out, **kwargs)
    finally:
        numba.set_num_threads(previous)


@dataclass(frozen=True)
class TrainConfig:
    """The options of one SB3 training run (``swarm-phd train``'s flags; :func:`train`'s
    keywords), checked by :func:`_checked` before anything is built or written.

    ``warm_start``: ``{"teacher": "scripted:NAME", "steps": int, "rounds": int, "epochs": int,
    "log_std": float}`` clones the teacher into the actor first (:mod:`agents.sb3.warm_start`;
    writes ``warm_start.zip`` and ``warm_start.json``). ``critic_warmup``: that many first PPO
    rollouts update only the value function. ``residual``: ``"scripted:NAME"`` trains a
    residual policy (:mod:`agents.sb3.residual`; correction mean 0 and log-std
    ``residual_log_std`` at the start, by default -1.5, or -3.0 per hidden unit with gSDE
    (``ppo_kwargs["use_sde"]``); ``residual_observes_base`` appends the scripted command
    to the policy's observation; ``residual_mode`` ``"gain"`` scales the command instead of
    adding to it). ``critic_state``: a centralised critic that also reads
    the true state (:mod:`agents.sb3.central_critic`). ``lstm_hidden``: recurrent PPO
    (sb3-contrib ``RecurrentPPO``, an LSTM of that many units in the actor and in the critic,
    after the extractor); the model's metadata says ``"recurrent": true``. ``eval_seeds``: after
    training, score the model, its checkpoints, the task's scripted controller and ``random``
    on that many held-out seeds (:mod:`agents.train_report`: ``final_evaluation.json``, the
    verdict table, the task-metric panel of ``learning_curve.png``; 0: none).
    """

    seed: int = 0
    overwrite: bool = False
    n_copies: int = 4
    num_cpus: int = 0
    vec: str = "auto"
    checkpoint_every: int = 50_000
    torch_threads: int = 1
    progress_bar: bool = True
    ppo_kwargs: dict[str, Any] | None = None
    max_wall_s: float | None = None
    extractor: str = "sets"
    warm_start: dict[str, Any] | None = None
    critic_warmup: int = 0
    residual: str | None = None
    residual_log_std: float | None = None
    critic_state: bool = False
    residual_observes_base: bool = False
    residual_mode: str = "add"
    lstm_hidden: int | None = None
    eval_seeds: int = 0


@dataclass(frozen=True)
class _Probed:
    """What one probe env of the run says: agents per copy, table rows, the critic's block."""

    n_agents: int
    top_k: int
    critic_dims: int


def _train_with(
    env_kwargs: dict[str, Any], timesteps: int, out: Path, **options: Any
) -> tuple[Path, str | None]:
    """Train; return the path of ``model.zip`` and the signal that interrupted it (or None).
    ``options``: :class:`TrainConfig`'s fields.

    Every option is checked first, before an env is built or anything is written to ``out``
    (a refused run leaves a previous run's files there as they were); then one probe env,
    the run's files, the VecEnv and the model are built (:func:`_build_model`), the model
    learns (:func:`_learn`) and is saved with the run's summary.
    """
    out = Path(out)
    config, ppo = _checked(env_kwargs, timesteps, out, TrainConfig(**options))
    try:
        import torch
        from stable_baselines3.common.logger import configure
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ValueError("training needs the rl extras: pip install -e '.[rl]'") from exc

    # After the flags' own checks (their errors come first), before any env is built.
    inputs.run_dir("--out", out, overwrite=config.overwrite)
    probed = _probe(env_kwargs, config, ppo)
    if "batch_size" not in (config.ppo_kwargs or {}):
        # The default minibatch, or the whole rollout when that is smaller.
        rollout = ppo["n_steps"] * config.n_copies * probed.n_agents
        ppo["batch_size"] = min(DEFAULT_BATCH_SIZE, rollout)
    torch.set_num_threads(config.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    (out / "checkpoints").mkdir(exist_ok=True)
    write_json_atomically(out / "env_kwargs.json", env_kwargs)
    policy_kwargs = _policy_kwargs(config, ppo, probed)
    _write_train_config(out, timesteps, config, ppo, probed, policy_kwargs)
    venv = _training_venv(env_kwargs, out, config, ppo)
    model = _build_model(venv, config, ppo, probed, policy_kwargs)
    logger = configure(str(out / "tb"), ["csv", "tensorboard"])
    model.set_logger(logger)
    return _learn(model, venv, logger, env_kwargs, timesteps, out, config, ppo, probed)


def _checked(
    env_kwargs: dict[str, Any], timesteps: int, out: Path, config: TrainConfig
) -> tuple[TrainConfig, dict[str, Any]]:
    """``config`` checked (``ValueError`` naming the flag), with its defaults filled in (the
    residual's log-std, the warm start's settings), and PPO's keywords with SB3's defaults."""
    inputs.output_dir("--out", out)
    check_run_flags(
        timesteps, config.seed, config.checkpoint_every, config.torch_threads, config.max_wall_s
    )
    check_number("--n-copies", config.n_copies, integer=True, low=1)
    check_number("--num-cpus", config.num_cpus, integer=True, low=0)
    check_number("--critic-warmup", config.critic_warmup, integer=True, low=0)
    from agents.train_report import eval_seeds

    eval_seeds(config.eval_seeds)
    ppo_kwargs = config.ppo_kwargs or {}
    check_ppo_kwargs(ppo_kwargs)
    ppo = {
        "n_steps": 128,
        "batch_size": DEFAULT_BATCH_SIZE,
        "n_epochs": 10,
        "learning_rate": 3e-4,
        "gamma": 0.99,
        "gae_lambda": 0.95,
        "ent_coef": 0.0,
        "clip_range": 0.2,
        **ppo_kwargs,
    }
    if ppo.get("use_sde"):
        # One exploration matrix per agent per rollout (SB3 resamples it at each rollout).
        ppo.setdefault("sde_sample_freq", -1)
    residual, warm_start, extractor = config.residual, config.warm_start, config.extractor
    _resolve_vec(
        config.vec, config.n_copies, config.num_cpus, residual is not None, config.critic_state
    )
    if extractor not in ("sets", "mlp"):
        raise ValueError(f"--extractor must be 'sets' or 'mlp', got {extractor!r}")
    if extractor == "sets" and env_kwargs.get("observation", "phd") == "measurements":
        raise ValueError(
            "--extractor sets reads the neighbour table, which --observation measurements has "
            "not: use it with --observation phd or truth (or --extractor mlp)"
        )
    residual_log_std = config.residual_log_std
    if residual_log_std is not None and residual is None:
        raise ValueError(f"--residual-log-std {residual_log_std} needs --residual scripted:NAME")
    if config.residual_observes_base and residual is None:
        raise ValueError("--residual-observes-base needs --residual scripted:NAME")
    from agents.sb3.residual import check_residual_mode

    residual_mode = config.residual_mode
    if check_residual_mode(residual_mode) != "add":
        if residual is None:
            raise ValueError(f"--residual-mode {residual_mode} needs --residual scripted:NAME")
        if warm_start is not None:
            raise ValueError(
                f"--residual-mode {residual_mode} and --warm-start exclude each other (the "
                "clone fits an additive correction)"
            )
    if residual_log_std is None:
        residual_log_std = -3.0 if ppo_kwargs.get("use_sde") else -1.5
    if residual is not None:
        from agents.sb3.residual import check_residual

        check_residual(residual)
        check_number("--residual-log-std", residual_log_std, low=-5, high=1)
    if config.critic_state:
        if warm_start is not None:
            raise ValueError(
                "--critic-state and --warm-start exclude each other (the clone is fitted on "
                "the env's observation, without the critic block)"
            )
        if extractor != "sets":
            raise ValueError(f"--critic-state needs --extractor sets, got {extractor!r}")
    if ppo_kwargs.get("use_sde"):
        for flag, on in (
            ("--warm-start", warm_start is not None),
            ("--critic-state", config.critic_state),
            ("--recurrent", config.lstm_hidden is not None),
        ):
            if on:
                raise ValueError(
                    f"--sde and {flag} exclude each other (not built or tested together: "
                    "the clone, the centralised critic and the LSTM policy are fitted and "
                    "tested with the per-step Gaussian)"
                )
    if config.lstm_hidden is not None:
        check_number("--lstm-hidden", config.lstm_hidden, integer=True, low=1)
        for flag, on in (
            ("--warm-start", warm_start is not None),
            ("--critic-state", config.critic_state),
        ):
            if on:
                raise ValueError(
                    f"--recurrent and {flag} exclude each other (the behaviour cloning and the "
                    "centralised critic's policy are feed-forward)"
                )
    if warm_start is not None:
        warm_start = {"rounds": 1, "epochs": 30, "log_std": -1.5, **warm_start}
        teacher = warm_start.get("teacher")
        if not isinstance(teacher, str) or not teacher.startswith(("scripted:", "privileged:")):
            raise ValueError(
                f"--warm-start must be 'scripted:NAME' or 'privileged:NAME', got {teacher!r}"
            )
        for key in ("steps", "rounds", "epochs"):
            check_number(f"--bc-{key}", warm_start.get(key), integer=True, low=1)
        check_number("--bc-log-std", warm_start["log_std"], low=-5, high=1)
    config = replace(config, residual_log_std=residual_log_std, warm_start=warm_start)
    return config, ppo


def _probe(env_kwargs: dict[str, Any], config: TrainConfig, ppo: dict[str, Any]) -> _Probed:
    """Build one env first: bad task / config keys fail here with the env's own message; a
    rollout of fewer than two transitions is refused."""
    from swarm_env import parallel_env

    probe = parallel_env(**env_kwargs)
    n_agents = len(probe.possible_agents)
    critic_dims = 0
    if config.critic_state:
        from agents.sb3.central_critic import critic_state_dims

        critic_dims = critic_state_dims(n_agents, probe.task)
    probed = _Probed(n_agents, probe.config.top_k, critic_dims)
    probe.close()
    if ppo.get("normalize_advantage", True) and ppo["n_steps"] * config.n_copies * n_agents < 2:
        # SB3 asserts it: a rollout of one transition normalises its advantage to NaN.
        raise ValueError(
            f"--n-steps {ppo['n_steps']} x --n-copies {config.n_copies} x {n_agents} agent(s) "
            "is a rollout of one transition: PPO needs at least 2 (SB3 normalises the "
            "advantages)"
        )
    return probed


def _policy_kwargs(config: TrainConfig, ppo: dict[str, Any], probed: _Probed) -> dict[str, Any]:
    """The policy's keywords for the MLP / set-extractor policy (``train_config.json`` records
    them; :func:`_build_model` adapts them to the centralised critic and the LSTM)."""
    policy_kwargs: dict[str, Any] = {
        "net_arch": {"pi": [128, 128], "vf": [128, 128]},
        # gSDE's log-std is per hidden unit: SB3's default -2 (noise std exp(-2) x |latent|).
        "log_std_init": -2.0 if ppo.get("use_sde") else -0.5,
    }
    if config.warm_start is not None or config.critic_warmup or config.residual is not None:
        # The value loss must not move the (cloned) actor's features: separate extractors.
        policy_kwargs["share_features_extractor"] = False
    if config.extractor == "sets":
        from agents.sb3.features import NeighbourSetExtractor

        policy_kwargs.update(
            features_extractor_class=NeighbourSetExtractor,
            features_extractor_kwargs={"top_k": probed.top_k},
        )
    return policy_kwargs


def _write_train_config(
    out: Path,
    timesteps: int,
    config: TrainConfig,
    ppo: dict[str, Any],
    probed: _Probed,
    policy_kwargs: dict[str, Any],
) -> None:
    """``train_config.json``: every setting of the run, as resolved."""
    import numba

    residual = config.residual
    write_json_atomically(
        out / "train_config.json",
        {
            "timesteps": timesteps,
            "seed": config.seed,
            "n_copies": config.n_copies,
            "num_cpus": config.num_cpus,
            "vec": config.vec,
            "n_agents_per_env": probed.n_agents,
            "checkpoint_every": config.checkpoint_every,
            "torch_threads": config.torch_threads,
            "kernel_threads": numba.get_num_threads(),
            "ppo": ppo,
            "extractor": config.extractor,
            "warm_start": config.warm_start,
            "critic_warmup": config.critic_warmup,
            "residual": residual,
            "residual_log_std": config.residual_log_std if residual else None,
            "critic_state": config.critic_state,
            "critic_dims": probed.critic_dims,
            "residual_observes_base": config.residual_observes_base,
            "residual_mode": config.residual_mode if residual else None,
            "recurrent": config.lstm_hidden is not None,
            "lstm_hidden": config.lstm_hidden,
            "policy_kwargs": {
                k: v for k, v in policy_kwargs.items() if k != "features_extractor_class"
            },
        },
    )


def _training_venv(
    env_kwargs: dict[str, Any], out: Path, config: TrainConfig, ppo: dict[str, Any]
) -> Any:
    """The run's VecEnv (:func:`_vec_env`, its monitor in ``out``) in SB3's ``VecNormalize``."""
    from stable_baselines3.common.vec_env import VecNormalize

    # SB3 asks each env for render_mode; SuperSuit's vector env answers None (no rendering
    # while training), which SB3 reports as "not defined" on every wrapper.
    warnings.filterwarnings("ignore", message="The `render_mode` attribute is not defined")
    # SuperSuit's worker processes (--vec supersuit --num-cpus) inherit "ignore SIGINT": a
    # Ctrl-C reaches the whole process group, and only this process must act on it (it saves,
    # then closes the workers). The batched VecEnv's workers see to it themselves.
    supersuit_workers = config.num_cpus > 0 and config.vec == "supersuit"
    previous_sigint = set_signal(signal.SIGINT, signal.SIG_IGN) if supersuit_workers else None
    try:
        venv = _vec_env(
            config.vec,
            env_kwargs,
            config.n_copies,
            config.num_cpus,
            config.seed,
            str(out / "monitor.csv"),
            config.residual,
            config.critic_state,
            config.residual_observes_base,
            config.residual_mode,
        )
    finally:
        if previous_sigint is not None:
            set_signal(signal.SIGINT, previous_sigint)
    # The set extractor scales its rows itself (per-slot statistics would break permutation
    # invariance); the MLP gets VecNormalize's running mean/std. Rewards are normalised in both.
    return VecNormalize(
        venv,
        norm_obs=config.extractor == "mlp",
        norm_reward=True,
        clip_obs=10.0,
        gamma=ppo["gamma"],
    )


def _model_metadata(
    env_kwargs: dict[str, Any], venv: Any, config: TrainConfig, probed: _Probed
) -> dict[str, Any]:
    """The metadata saved inside every model zip of the run (:func:`save_model`): its env, its
    observation normalisation as it stands now, and how the policy acts."""
    norm = (
        None
        if not venv.norm_obs
        else {
            "mean": venv.obs_rms.mean.tolist(),
            "var": venv.obs_rms.var.tolist(),
            "clip": venv.clip_obs,
            "epsilon": venv.epsilon,
        }
    )
    out_meta = {
        "env_kwargs": env_kwargs,
        "action_scale": "unit",
        "obs_norm": norm,
        "extractor": config.extractor,
    }
    if config.residual is not None:
        out_meta["residual"] = config.residual
    if config.residual_observes_base:
        out_meta["residual_observes_base"] = True
    if config.residual is not None and config.residual_mode != "add":
        out_meta["residual_mode"] = config.residual_mode
    if probed.critic_dims:
        out_meta["critic_dims"] = probed.critic_dims
    if config.lstm_hidden is not None:
        out_meta["recurrent"] = True
    return out_meta


def _build_model(
    venv: Any,
    config: TrainConfig,
    ppo: dict[str, Any],
    probed: _Probed,
    policy_kwargs: dict[str, Any],
) -> Any:
    """The PPO model (``RecurrentPPO`` with ``lstm_hidden``; the centralised critic's policy
    with ``critic_state``), a residual's correction zeroed at the start."""
    from stable_baselines3 import PPO

    policy_class: Any = "MlpPolicy"
    if probed.critic_dims:
        from agents.sb3.central_critic import CentralCriticPolicy

        policy_class = CentralCriticPolicy
        policy_kwargs = {
            k: v for k, v in policy_kwargs.items() if not k.startswith(("features_", "share_"))
        }
        policy_kwargs.update(critic_dims=probed.critic_dims, top_k=probed.top_k)
    algorithm: Any = PPO
    if config.lstm_hidden is not None:
        from sb3_contrib import RecurrentPPO

        algorithm, policy_class = RecurrentPPO, "MlpLstmPolicy"
        # One LSTM per side: the critic's must not move the actor's memory.
        policy_kwargs = {
            **policy_kwargs,
            "lstm_hidden_size": config.lstm_hidden,
            "shared_lstm": False,
        }
    model = algorithm(
        policy_class,
        venv,
        seed=config.seed,
        device="cpu",
        verbose=0,
        policy_kwargs=policy_kwargs,
        tensorboard_log=None,
        **ppo,
    )
    if config.residual is not None:
        from agents.sb3.residual import zero_correction

        zero_correction(model.policy, config.residual_log_std)
    return model


def _learn(
    model: Any,
    venv: Any,
    logger: Any,
    env_kwargs: dict[str, Any],
    timesteps: int,
    out: Path,
    config: TrainConfig,
    ppo: dict[str, Any],
    probed: _Probed,
) -> tuple[Path, str | None]:
    """The warm start (if any) and PPO's ``learn``, checkpointed, stopped by a signal or the
    wall-time budget; then the model and ``train_summary.json`` saved (a second signal
    ignored meanwhile) and the VecEnv closed. Returns ``model.zip`` and the signal, if any."""
    from stable_baselines3.common.callbacks import BaseCallback

    def meta() -> dict[str, Any]:
        return _model_metadata(env_kwargs, venv, config, probed)

    budget = WallBudget(config.max_wall_s)  # counts the warm start too

    class Checkpoints(BaseCallback):
        """Save ``model_<steps>_steps.zip`` (with its metadata) every ``every`` transitions;
        stop training once the wall-time budget has passed."""

        def __init__(self, every: int) -> None:
            super().__init__()
            self.every = every
            self.next_at = self.every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_at:
                path = out / "checkpoints" / f"model_{self.num_timesteps}_steps.zip"
                save_model(self.model, path, meta())
                self.next_at += self.every
            return not budget.passed()

    from agents.train_report import LearningLog, rollout_plan, say

    rollout_size = ppo["n_steps"] * venv.num_envs
    planned, rounded = rollout_plan(
        timesteps,
        rollout_size,
        f"--n-steps {ppo['n_steps']} x {config.n_copies} copies x {probed.n_agents} agents",
    )
    if rounded:
        say(rounded)
    log = LearningLog(planned, "sb3")
    callbacks = [Checkpoints(config.checkpoint_every)]
    if config.critic_warmup:
        callbacks.append(_CriticWarmup(BaseCallback, config.critic_warmup))
    bar_callback = None
    if config.progress_bar:
        bar_callback = _progress_callback(BaseCallback, timesteps, rollout_size, ppo)
        callbacks.append(bar_callback)
    callbacks.append(_LearningCallback(BaseCallback, log, bar_callback))
    start = time.perf_counter()
    with Interrupts() as interrupts:
        callbacks.append(_StopOnSignal(BaseCallback, interrupts))
        with interrupts.caught():
            # Inside the handler: a signal during the warm start saves the actor as it is.
            if config.warm_start is not None:
                _warm_start(
                    model,
                    venv,
                    env_kwargs,
                    config.warm_start,
                    config.n_copies,
                    config.seed,
                    venv.norm_obs,
                    out,
                    meta,
                    config.residual,
                    config.residual_observes_base,
                )
            model.learn(total_timesteps=timesteps, callback=callbacks, progress_bar=False)
        interrupted = interrupts.received
        # A second signal while saving must not leave a half-written model.
        with Interrupts(ignore=True):
            for cb in callbacks:
                if hasattr(cb, "close"):
                    cb.close()
            path = out / "model.zip"
            save_model(model, path, meta())
            if interrupted:
                last = out / "checkpoints" / f"model_{model.num_timesteps}_steps.zip"
                save_model(model, last, meta())
            elapsed = time.perf_counter() - start
            summary = {
                "timesteps": int(model.num_timesteps),
                "wall_time_s": elapsed,
                "agent_steps_per_s": model.num_timesteps / max(elapsed, 1e-9),
                "interrupted": interrupted,
                "stopped": stop_reason(interrupted, budget),
            }
            write_json_atomically(out / "train_summary.json", summary)
            logger.close()
            venv.close()
    if interrupted:
        print(
            f"swarm-phd train: {interrupted} at {model.num_timesteps} agent steps: saved {path} "
            f"and {last.relative_to(out)}",
            file=sys.stderr,
        )
    else:
        why = " (wall-time budget)" if budget.reached else ""
        print(f"trained {model.num_timesteps} agent steps in {elapsed:.0f} s{why} -> {path}")
    from agents.train_report import eval_seeds, finish

    finish(
        out,
        log,
        str(path),
        env_kwargs,
        [] if interrupted else eval_seeds(config.eval_seeds),
        _saved_checkpoints(out, model.num_timesteps),
        f"{env_kwargs.get('preset')}, task {env_kwargs.get('task')}, sb3 PPO",
    )
    return path, interrupted


def _saved_checkpoints(out: Path, final_steps: int) -> list[tuple[int, str]]:
    """``(agent steps, path)`` of the run's ``checkpoints/model_<steps>_steps.zip`` before the
    final model, by steps."""
    found = []
    for path in (out / "checkpoints").glob("model_*_steps.zip"):
        steps = int(path.stem.split("_")[1])
        if steps < final_steps:
            found.append((steps, str(path)))
    return sorted(found)


def _LearningCallback(base: type, log: Any, bar_callback: Any):  # noqa: N802 - SB3 lazily
    """A callback adding one point per rollout to ``log`` (:class:`agents.train_report.
    LearningLog`): the mean return of the last finished agent-episodes (SB3's window)."""

    from collections import deque

    class LearningCallback(base):  # type: ignore[misc, valid-type]
        def __init__(self) -> None:
            super().__init__()
            # The task's first metric of the last finished copy-episodes (the batched VecEnv
            # reports each episode's task metrics when it ends), SB3's window of 100.
            self.metric: str | None = None
            self.values: deque[float] = deque(maxlen=100)

        def _on_rollout_end(self) -> None:
            episodes = [float(e["r"]) for e in self.model.ep_info_buffer]
            mean = sum(episodes) / len(episodes) if episodes else float("nan")
            bar = getattr(bar_callback, "bar", None)
            metric = None
            if self.metric is not None:
                n = len(self.values)
                metric = (self.metric, sum(self.values) / n if n else float("nan"), n)
            log.add(self.num_timesteps, mean, len(episodes), bar, metric)

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", ()):
                metrics = info.get("task_metrics")
                if metrics:
                    self.metric = self.metric or next(iter(metrics))
                    self.values.append(float(metrics[self.metric]))
            return True

    return LearningCallback()


def _warm_start(
    model,
    venv,
    env_kwargs,
    warm,
    n_copies,
    seed,
    norm_obs,
    out,
    meta,
    residual=None,
    residual_observes_base=False,
) -> None:
    """Clone the teacher into ``model``'s actor (with ``residual``: the correction from the
    scripted base to the teacher); save it as ``warm_start.zip``."""
    from agents.sb3.warm_start import warm_start

    start = time.perf_counter()
    summary = warm_start(
        model.policy,
        env_kwargs,
        warm["teacher"],
        warm["steps"],
        rounds=warm["rounds"],
        n_copies=n_copies,
        seed=seed,
        epochs=warm["epochs"],
        log_std=warm["log_std"],
        # The MLP reads VecNormalize's output: its statistics start from the demonstrations.
        obs_transform=venv.normalize_obs if norm_obs else None,
        observe=venv.obs_rms.update if norm_obs else None,
        residual=residual,
        residual_observes_base=residual_observes_base,
    )
    summary["wall_time_s"] = time.perf_counter() - start
    write_json_atomically(out / "warm_start.json", summary)
    save_model(model, out / "warm_start.zip", meta())
    fit = summary["holdout_fit"]
    print(
        f"warm start from {warm['teacher']}: {summary['transitions']} transitions, held-out "
        f"R^2 v {fit['r2_v']:.2f} omega {fit['r2_omega']:.2f} "
        f"({summary['wall_time_s']:.0f} s)"
    )


def _CriticWarmup(base: type, rollouts: int):  # noqa: N802 - SB3 imported lazily
    """A callback freezing the actor (and its log-std) for the first ``rollouts`` PPO updates,
    so the value function learns the warm-started policy's returns before the policy gradient
    (which uses its advantages) moves the actor."""
    from agents.sb3.warm_start import actor_parameters

    class CriticWarmup(base):  # type: ignore[misc, valid-type]
        def __init__(self) -> None:
            super().__init__()
            self.rollouts = 0

        def _set(self, trainable: bool) -> None:
            for p in actor_parameters(self.model.policy):
                p.requires_grad_(trainable)

        def _on_training_start(self) -> None:
            self._set(False)

        def _on_rollout_end(self) -> None:
            self.rollouts += 1
            if self.rollouts == rollouts + 1:  # before the (rollouts + 1)-th update
                self._set(True)

        def _on_step(self) -> bool:
            return True

        def _on_training_end(self) -> None:
            self._set(True)

    return CriticWarmup()


def _StopOnSignal(base: type, interrupts: Interrupts):  # noqa: N802 - SB3 imported lazily
    """A callback that ends ``learn`` at the next env step once a signal came: the backstop
    for a ``KeyboardInterrupt`` that library code caught and dropped."""

    class StopOnSignal(base):  # type: ignore[misc, valid-type]
        def _on_step(self) -> bool:
            return interrupts.received is None

    return StopOnSignal()


def _progress_callback(base: type, timesteps: int, rollout_size: int, ppo: dict[str, Any]):
    """A bar over agent steps that stays alive during the PPO update: it counts the optimiser's
    gradient steps (epochs x minibatches) while the policy trains on a rollout."""
    from swarm_core import progress

    class ProgressCallback(base):  # type: ignore[misc, valid-type]
        def __init__(self) -> None:
            super().__init__()
            self.total = math.ceil(timesteps / rollout_size) * rollout_size
            self.grad_steps = ppo["n_epochs"] * math.ceil(rollout_size / ppo["batch_size"])
            self.bar: Any = None
            self._hook: Any = None
            self._grad = 0

        def _on_training_start(self) -> None:
            self.bar = progress.bar(self.total, "train", unit="agent-step")
            self.bar.update(self.num_timesteps)
            optimizer = self.model.policy.optimizer
            self._hook = optimizer.register_step_post_hook(self._on_grad_step)

        def _on_grad_step(self, *args: Any) -> None:
            self._grad += 1
            if self._grad == 1 or self._grad % 4 == 0 or self._grad == self.grad_steps:
                self.bar.set_postfix_str(f"PPO update {self._grad}/{self.grad_steps}")
                self.bar.refresh()

        def _on_rollout_start(self) -> None:
            self._grad = 0
            self.bar.set_postfix_str("collecting rollout")

        def _on_rollout_end(self) -> None:
            self.bar.set_postfix_str(f"PPO update 0/{self.grad_steps}")
            self.bar.refresh()

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def close(self) -> None:
            if self._hook is not None:
                self._hook.remove()
                self._hook = None
            if self.bar is not None:
                self.bar.close()
                self.bar = None

    return ProgressCallback()
