"""``swarm-phd evaluate``: the Perera 2021 study's localization experiment, under scripted or
learned motion.

Every robot runs its own filter, for each requested localizer at once (``phd-lc``: Lidar+Camera,
``phd-lo``: Lidar-Only, ``id-phd``: ID-PHD on the lidar with every teammate's odometry as radio
messages, ``ukf`` / ``pf``: the IR-UKF / Lee 2012 baselines on identified range-bearing
detections), fed with the same records, so the comparison is paired: same motion,
same measurements. The motion comes from ``--policy`` (default ``scripted:wander``, the
Perera 2021 study's pseudo-random motion with obstacle avoidance; or ``random``, another
``scripted:NAME``, a trained ``model.zip`` or a recurrent student ``.pt``). ``--compare Q,R``
runs further policies on the same env and seeds: side by side, then each one against
``--policy`` paired by seed (:func:`paired_by_seed`: mean difference, its standard error,
seeds better, verdict at 2 SE).

Metrics (:class:`localization.metrics.SeedScorer`; definitions in ``docs/localization.md``,
"Metrics"), every robot being an observer, "in range" = within ``localization_range_m`` (the
lidar tracking range, 2 m) for every localizer, and also within 3 m (the Perera 2021 study's camera
range, ``at_camera_range``) for the localizers that use the camera:

- ``seed_fig7``: the Perera 2021 study's Fig. 7, one bar per tracked teammate (in range at least
  once): the % of the teammate's in-range time during which the observer's closest component with
  weight > 0.1 is more than 0.30 m away; for ``observer_ugv_0`` (as the study) and
  ``all_observers`` (every tracked pair), with the count above 25 % and the median;
- ``pooled_per_observer``: the same % over all of an observer's (step, teammate) pairs
  together (the statistic reported before; lower and not comparable with Perera 2021's count);
- ``seed001``: % of in-range time with position error < 0.1 m and bearing error < 7 deg;
  ``rmse_m`` / ``rmse_bearing_deg`` of the matched component;
- ``gospa``: mean GOSPA (c = 1 m, p = 2, alpha = 2) between the teammates in range and the
  extracted estimates (weight >= 0.5) within the same range, with its localisation / missed /
  false split;
- ``cardinality``: weight sum within range vs the true in-range count, and the whole
  mixture's weight sum vs the true number of teammates (Fig. 8);
- ``large_error_causes_pct_of_pair_steps`` and ``by_range``: why and where errors > 0.30 m.

The identity-aware localizers (``id-phd``, ``ukf``, ``pf``) also get an ``identity`` block: per
observer, over the same pairs, the error of *that neighbour's own ID estimate*
(:class:`IdentityScorer`). Their records: each robot's odometry records of the step stand for
the radio messages (every teammate's own increment with its ID); ``ukf`` and ``pf`` get each
lidar detection with the identity of the true robot within 0.2 m of it (an oracle standing in
for the IR-UKF / Lee 2012 studies' identifying sensors; other detections are dropped).
Stegagno 2012's ``p-multireg``, ``fastslam-mc`` and ``p-multibeareg`` read what each robot heard on
the radio: selecting one switches the radio on (``DEFAULT_RADIO`` of
:mod:`localization.mutual.localizer`, unless ``comms`` is given), and a config with the radio
off is refused. Their ``identity`` block adds the thesis's pooled % of pair-steps within 0.1 m,
bearing < 7 deg and heading < 7 deg. Each localizer's ms per env step goes to stderr.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from localization.feed import SwarmFeed
from localization.metrics import SeedScorer, in_range_pairs, weights_means_from_table
from localization.registry import LOCALIZERS, make_localizer
from swarm_core import inputs, progress
from swarm_core.atomic_files import write_json_atomically
from swarm_core.inputs import parse_json_object, parse_seeds
from swarm_env.env import SwarmEnv

#: ``--scenario`` values.
SCENARIOS = ("study", "seed003")


def add_policy_arguments(parser: argparse.ArgumentParser) -> None:
    """``--policy``, ``--task`` and ``--task-params``: what runs, as every command that runs a
    policy in its own env takes them (evaluate, record)."""
    parser.add_argument(
        "--policy",
        default="scripted:wander",
        help="'scripted:NAME', 'privileged:NAME', 'random', a trained model.zip, a recurrent "
        "student .pt or the --out directory of train --engine rllib",
    )
    parser.add_argument(
        "--task",
        default=None,
        help="default: the model's task for a model.zip or student .pt, else 'wander'",
    )
    parser.add_argument(
        "--task-params",
        default=None,
        help="JSON dict of task parameters, merged over a model's own (default: the model's, "
        "else {})",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from agents.policies import add_trust_policy_argument

    parser.add_argument(
        "--preset",
        default=None,
        help="default: a trained policy's (model.zip, student .pt) own preset, else sim-6m-20 "
        "(alias seed-sim: the Perera 2021 study's 6 m x 6 m arena with 20 UGVs)",
    )
    add_trust_policy_argument(parser)
    inputs.add_duration_argument(parser, 300.0)
    parser.add_argument(
        "--localizer",
        default="phd-lc,phd-lo",
        help=f"comma-separated, from {sorted(LOCALIZERS)} (`swarm-phd list` describes them)",
    )
    parser.add_argument("--seeds", default="0", help="comma-separated integers or ranges (0-4)")
    add_policy_arguments(parser)
    parser.add_argument(
        "--compare",
        default=None,
        help="further policies (comma-separated) run on the same env and seeds, reported side "
        "by side, then each against --policy paired by seed (mean difference, SE, seeds "
        "better, verdict at 2 SE; e.g. --policy runs/X/model.zip --compare "
        "scripted:formation,scripted:wander)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="write metrics.json and figures here: a new or empty directory, unless --overwrite",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="write into an --out that holds earlier results anyway: the files this run "
        "writes replace the old ones (default: refuse, so that a rerun never replaces "
        "finished results)",
    )
    parser.add_argument(
        "--scenario",
        choices=SCENARIOS,
        default="study",
        help="'study': the source study's experiment (or a policy's evaluation) with the "
        "localizers above; 'seed003': the IR-UKF study's 5-robot experiment, IR readings with "
        "identities, SLSQP direct estimation then the centralized UKF, errors after the Kabsch "
        "fit (swarm_phd/seed003.py; --preset, --duration, --seeds and --out apply)",
    )
    parser.add_argument(
        "--ray",
        action="store_true",
        help="one Ray task per seed (swarm_phd/sweep.py), added up as the serial run adds "
        "its seeds: the same table, metrics.json and figures, faster with several CPUs",
    )
    from swarm_phd.sweep import add_ray_arguments

    add_ray_arguments(parser)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM scores the finished seeds, as Ctrl-C does


def run(args: argparse.Namespace) -> int:
    import signal

    signal.signal(signal.SIGTERM, _interrupt)
    if getattr(args, "trust_policy", False):  # this process and its workers
        from agents.policies import trust_policy_files

        trust_policy_files()
    if getattr(args, "scenario", "study") != "study" and getattr(args, "ray", False):
        raise ValueError(f"--ray runs the study's seeds; --scenario {args.scenario} is serial")
    # Refused before any episode: the control period is checked once the env is built.
    inputs.duration("--duration", args.duration)
    seeds = parse_seeds(args.seeds)
    if args.out:
        # As train takes it: a rerun must never silently replace finished results.
        inputs.run_dir(
            "--out",
            args.out,
            overwrite=getattr(args, "overwrite", False),
            holding="earlier results",
            action="write into",
        )
    if getattr(args, "ray", False):
        from swarm_phd.sweep import run_evaluate_ray

        return run_evaluate_ray(args)
    localizers = [s.strip() for s in args.localizer.split(",") if s.strip()]
    if getattr(args, "scenario", "study") == "seed003":
        return _run_seed003(args, seeds)
    specs = [s.strip() for s in (args.compare or "").split(",") if s.strip()]
    if args.compare is not None and not specs:
        raise ValueError(f"--compare names no policy: {args.compare!r}")
    overrides: dict[str, Any] = {}
    if args.task_params is not None:
        overrides["task_params"] = parse_json_object(args.task_params, "--task-params")
    out_dir = Path(args.out) if args.out else None
    results = evaluate_localization(
        args.preset,
        args.duration,
        localizers,
        seeds,
        policy=args.policy,
        task=args.task,
        out_dir=out_dir,
        **overrides,
    )
    print_table(results)
    if args.compare:
        compared = [results]
        for k, spec in enumerate(specs):
            if compared[-1]["config"].get("interrupted"):
                # A Ctrl-C or SIGTERM ends the whole comparison, not the policy it landed in.
                print(
                    f"swarm-phd evaluate: interrupted; not run: {', '.join(specs[k:])}",
                    file=sys.stderr,
                )
                break
            shared = shared_env_kwargs(args.policy, args.preset, args.task, **overrides)
            other = evaluate_localization(
                shared.pop("preset"),
                args.duration,
                localizers,
                seeds,
                policy=spec,
                task=shared.pop("task"),
                out_dir=(out_dir / ("compare" if k == 0 else f"compare{k + 1}"))
                if out_dir
                else None,
                **shared,
            )
            print_table(other)
            compared.append(other)
        print_comparison(compared)
        paired = paired_by_seed(compared)
        print_paired(paired)
        if out_dir is not None:
            write_json_atomically(
                out_dir / "comparison.json",
                {"side_by_side": comparison_rows(compared), "paired_by_seed": paired},
            )
    return 0


def _run_seed003(args: argparse.Namespace, seeds: list[int]) -> int:
    """``--scenario seed003``: the IR-UKF study's centralized pipeline (not a per-robot localizer,
    so ``--localizer``, ``--policy``, ``--task`` and ``--compare`` do not apply)."""
    from swarm_phd.seed003 import print_summary, run_seed003

    for name, value, default in (
        ("--policy", args.policy, "scripted:wander"),
        ("--task", args.task, None),
        ("--compare", args.compare, None),
        ("--task-params", args.task_params, None),
    ):
        if value != default:
            raise ValueError(f"--scenario seed003 takes no {name} (got {value!r})")
    results = run_seed003(
        preset=args.preset or "lab-3m-4",
        duration_s=args.duration,
        seeds=seeds,
        out_dir=Path(args.out) if args.out else None,
    )
    print_summary(results)
    return 0


def shared_env_kwargs(
    policy: str, preset: str | None, task: str | None, **overrides: Any
) -> dict[str, Any]:
    """Preset, task, task parameters and config overrides of ``policy``'s evaluation env, minus
    the observation mode (each policy brings its own): what a ``--compare`` run must share."""
    from agents.policies import model_env_kwargs, model_on_task

    kwargs = model_on_task(model_env_kwargs(policy) or {}, task, overrides)
    for key in ("observation", "localize"):
        kwargs.pop(key, None)
    kwargs["preset"] = preset or kwargs.get("preset") or "seed-sim"
    kwargs["task"] = kwargs["task"] or "wander"
    return kwargs


#: The figures :func:`seed_figures` gives per seed (keys of ``results["localizers"][name]
#: ["per_seed"]``), each as in :meth:`SeedScorer.summary` over that seed alone.
PER_SEED_FIGURES = ("gospa_mean_m", "pooled_per_observer_median_pct", "pct_pair_steps_err_gt_30cm")


def seed_counts(scorer: SeedScorer) -> tuple[float, int, np.ndarray, np.ndarray]:
    """The running totals of ``scorer`` that :func:`seed_figures` differences: GOSPA sum,
    observer-steps, and per observer (R,) the in-range pair-steps above 0.30 m and all of them."""
    return (
        scorer.gospa_sum,
        scorer.observer_steps,
        scorer.large_steps.sum(axis=1),
        scorer.in_range_steps.sum(axis=1),
    )


def seed_figures(before: tuple, after: tuple) -> dict[str, float]:
    """:data:`PER_SEED_FIGURES` of the steps scored between two :func:`seed_counts`: mean
    GOSPA (m), the median over observers of each one's % of in-range pair-steps above 0.30 m
    (``pooled_per_observer``'s median), and that % over all pairs (NaN: nothing in range)."""
    gospa = after[0] - before[0]
    steps = after[1] - before[1]
    large = after[2] - before[2]
    in_range = after[3] - before[3]
    with np.errstate(invalid="ignore", divide="ignore"):
        per_observer = np.where(in_range > 0, 100.0 * large / np.maximum(in_range, 1), np.nan)
    finite = per_observer[np.isfinite(per_observer)]
    total = in_range.sum()
    return {
        "gospa_mean_m": float(gospa / steps) if steps else math.nan,
        "pooled_per_observer_median_pct": float(np.median(finite)) if finite.size else math.nan,
        "pct_pair_steps_err_gt_30cm": float(100.0 * large.sum() / total) if total else math.nan,
    }


def evaluate_localization(
    preset: str,
    duration_s: float,
    localizers: list[str],
    seeds: list[int],
    policy: str = "scripted:wander",
    task: str = "wander",
    out_dir: Path | None = None,
    phases: list[int] | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Run the experiment; return (and optionally write) the metrics per localizer.

    ``phases`` (first steps, e.g. ``[0, 20, 100]``; :func:`agents.evaluation.phase_spans`)
    also splits the share of in-range pair-steps above 0.30 m by step of the episode: where
    in it a motion loses its teammates (the first steps' births are every motion's).

    Each seed is scored on its own (:func:`score_seed`) and the seeds' tallies are added in
    the order of ``seeds`` (:func:`assemble`), so ``evaluate --ray``, which scores each seed in
    its own process, gives the same numbers.

    Returns
    -------
    dict
        ``{"config": ..., "localizers": {name: SeedScorer.summary() (+ "at_camera_range":
        the same at 3 m for camera localizers, + "per_seed": [{"seed", *PER_SEED_FIGURES,
        and with ``phases`` "pct_pair_steps_err_gt_30cm@<lo>-<hi>" per phase}] per finished
        seed, + with ``phases`` "by_phase": {that key: % over all seeds})},
        "identity": {...} (identity-aware localizers), "task": {...} (means over the seeds),
        "task_per_seed": [{"seed", **task metrics}] per finished seed, "wall_time_s": ...}``
    """
    start = time.perf_counter()
    env, n_steps, duration_s, spans = _episode_env(
        preset, duration_s, localizers, policy, task, phases, overrides
    )
    runs: list[SeedRun] = []
    interrupted = False
    try:
        for seed in progress.over(seeds, "evaluate", unit="seed"):
            runs.append(
                score_seed(env, policy, localizers, seed, n_steps, spans, first=seed == seeds[0])
            )
    except KeyboardInterrupt:
        if not runs:
            raise
        interrupted = True
        finished = [run.seed for run in runs]
        print(
            f"swarm-phd evaluate: interrupted; scoring the {len(finished)} finished seed(s) "
            f"{finished}",
            file=sys.stderr,
        )
    finally:
        env.close()
    return assemble(
        runs,
        preset=preset,
        duration_s=duration_s,
        localizers=localizers,
        seeds=seeds,
        policy=policy,
        phases=phases,
        interrupted=interrupted,
        out_dir=out_dir,
        start=start,
    )


def _episode_env(
    preset: str | None,
    duration_s: float,
    localizers: list[str],
    policy: str,
    task: str | None,
    phases: list[int] | None,
    overrides: dict[str, Any],
) -> tuple[SwarmEnv, int, float, list[tuple[int, int | None]] | None]:
    """The checked arguments' env, its steps per seed, the duration that runs (a trained
    policy's env ends its episodes where its training did) and the phase spans."""
    unknown = [name for name in localizers if name not in LOCALIZERS]
    if unknown or not localizers:
        raise ValueError(f"--localizer must name some of {sorted(LOCALIZERS)}, got {localizers}")
    inputs.duration("--duration", duration_s)
    spans = None
    if phases is not None:
        from agents.evaluation import phase_spans

        spans = phase_spans(phases)  # ValueError before any rollout
    overrides = dict(overrides)
    radio = [name for name in localizers if LOCALIZERS[name].needs_comms]
    if radio and "comms" not in overrides:  # Stegagno 2012's methods hear teammates by radio
        from localization.mutual.localizer import DEFAULT_RADIO

        overrides["comms"] = dict(DEFAULT_RADIO)
    from agents.policies import policy_env

    env = policy_env(preset, task, policy, **overrides)
    if radio and not env.config.comms.enabled:
        env.close()
        raise ValueError(f"localizers {radio} need the radio: comms.enabled is False")
    n_steps = inputs.steps_in(env, "--duration", duration_s)
    if n_steps > env.config.max_steps:
        # A trained policy's env ends its episodes where its training did: say what runs.
        period = env.config.control_period_s
        progress.note(
            f"swarm-phd evaluate: {policy}'s env ends each episode after "
            f"{env.config.max_steps} steps: {env.config.max_steps * period:g} s per seed, not "
            f"--duration {duration_s:g} s"
        )
        n_steps = env.config.max_steps
        duration_s = n_steps * period
    return env, n_steps, duration_s, spans


@dataclass
class SeedRun:
    """One seed's scoring (:func:`score_seed`): its own tallies, added up over the seeds by
    :func:`assemble`. The trajectory and ugv_0's estimates (the figures) only for the first
    seed; ``cost_s``: each localizer's seconds (not in the results: machine-dependent)."""

    seed: int
    env: dict[str, Any]
    scorers: dict[str, SeedScorer]
    camera_scorers: dict[str, SeedScorer]
    id_scorers: dict[str, IdentityScorer]
    figures: dict[str, dict[str, float]]
    by_step: dict[str, np.ndarray]
    task_metrics: dict[str, float]
    paths: list[np.ndarray]
    estimates: dict[str, list[np.ndarray]]
    cost_s: dict[str, float]
    steps_run: int


def score_seed(
    env: SwarmEnv,
    policy: str,
    localizers: list[str],
    seed: int,
    n_steps: int,
    spans: list[tuple[int, int | None]] | None = None,
    first: bool = True,
) -> SeedRun:
    """Run one episode of ``policy`` in ``env`` from ``seed`` and score every localizer on it
    (fresh filters and scorers, seeded from ``seed`` alone). ``first``: the first seed of an
    evaluation, whose trajectory, estimates and cardinality trace the figures draw."""
    from agents.policies import load_policy

    n_agents = len(env.possible_agents)
    range_m = env.config.localization_range_m
    # One localizer (every robot's filter) per name, fed the same records: a paired
    # comparison, same motion, same measurements.
    built = {name: make_localizer(name, n_agents, env.config.phd, seed) for name in localizers}
    # The Perera 2021 study's scoring per (observer, teammate); in range = the lidar tracking range
    # for every localizer (paired), and also that study's camera range for those using the camera.
    scorers = {name: SeedScorer(n_agents, range_m) for name in localizers}
    camera_scorers = {
        name: SeedScorer(n_agents, CAMERA_SCORING_RANGE_M, trace_observer=None)
        for name, loc in built.items()
        if _uses_camera(loc)
    }
    id_scorers = {
        name: IdentityScorer(env.config.n_robots)
        for name, loc in built.items()
        if loc.has_identities
    }
    act = load_policy(policy, env)
    if hasattr(act, "reset"):
        act.reset(seed)
    by_step = {name: np.zeros((n_steps, 2), dtype=np.int64) for name in localizers}
    paths: list[np.ndarray] = []
    estimates: dict[str, list[np.ndarray]] = {name: [] for name in localizers}
    cost_s = dict.fromkeys(localizers, 0.0)
    steps_run = 0
    obs, infos = env.reset(seed=seed)
    for t in progress.sim_steps(n_steps, env.config.control_period_s, f"seed {seed}", leave=False):
        if not env.agents:
            break
        obs, _, _, _, infos = env.step(act(obs, infos))
        step = env.last_world_step
        truth = step.truth
        feed = SwarmFeed.from_world_step(step, env.possible_agents)
        for name, loc in built.items():
            t0 = time.perf_counter()
            loc.step(feed)
            cost_s[name] += time.perf_counter() - t0
            views = loc.views
            weights, means = weights_means_from_table(*loc.padded_tables())
            visible = _visible(truth, name in camera_scorers)
            tallied = _pair_tallies(scorers[name]) if spans is not None else None
            scorers[name].update(
                truth.relative_xy,
                truth.in_range["lidar"],
                weights,
                means,
                visible=visible,
                time_s=step.time_s if first else None,  # Fig. 8: the first seed
            )
            if tallied is not None:  # this step's share of the scorer's own tallies
                by_step[name][t] = _pair_tallies(scorers[name]) - tallied
            if name in camera_scorers:
                camera_scorers[name].update(
                    truth.relative_xy,
                    in_range_pairs(truth.relative_xy, CAMERA_SCORING_RANGE_M),
                    weights,
                    means,
                    visible=visible,
                )
            if name in id_scorers:
                for i in range(n_agents):
                    id_scorers[name].add(
                        i, truth, truth.in_range["lidar"][i], views[i].identities()
                    )
            if first:
                estimates[name].append(_world_estimates(views[0], truth.poses[0]))
        if first:
            paths.append(truth.poses[:, :2].copy())
        steps_run += 1
    empty = seed_counts(SeedScorer(n_agents, range_m))
    figures = {
        name: {
            **seed_figures(empty, seed_counts(scorers[name])),
            **(phase_figures(by_step[name], spans) if spans is not None else {}),
        }
        for name in localizers
    }
    return SeedRun(
        seed=seed,
        env={
            "n_agents": n_agents,
            "n_robots": env.config.n_robots,
            "localization_range_m": range_m,
            "task": env.task.name,
        },
        scorers=scorers,
        camera_scorers=camera_scorers,
        id_scorers=id_scorers,
        figures=figures,
        by_step=by_step,
        task_metrics=env.task.metrics(),
        paths=paths,
        estimates=estimates,
        cost_s=cost_s,
        steps_run=steps_run,
    )


#: Attributes of the scorers that are settings, the same in every seed's scorer; the others
#: are tallies, added over the seeds by :func:`merge_tallies` (``trace``: the first seed's).
SCORER_SETTINGS = frozenset(
    {
        "n_robots",
        "range_m",
        "trace_observer",
        "error_threshold_m",
        "accurate_threshold_m",
        "bearing_threshold_deg",
        "min_weight",
        "over_pct",
        "gospa_c",
        "gospa_p",
        "gospa_alpha",
        "extraction_threshold",
        "range_bins_m",
        "n_observers",
    }
)


def merge_tallies(scorers: list[Any]) -> Any:
    """One scorer (:class:`SeedScorer` or :class:`IdentityScorer`) holding the tallies of
    ``scorers`` (one per seed, in seed order) added up: arrays and numbers summed, lists
    concatenated, dicts of numbers summed per key, the first's ``trace``; the settings
    (:data:`SCORER_SETTINGS`) must agree. TypeError for an attribute of another kind (a new
    tally this function does not know how to add)."""
    merged = copy.deepcopy(scorers[0])
    for other in scorers[1:]:
        for name, value in vars(other).items():
            mine = getattr(merged, name)
            if name in SCORER_SETTINGS:
                if not np.array_equal(np.asarray(mine), np.asarray(value)):
                    raise ValueError(f"scorers with different {name}: {mine!r} and {value!r}")
            elif name == "trace":
                continue  # the first seed's (Fig. 8)
            elif isinstance(value, (np.ndarray, list)):  # arrays summed, lists concatenated
                setattr(merged, name, mine + value)
            elif isinstance(value, dict):
                setattr(merged, name, {k: mine[k] + value[k] for k in mine})
            elif isinstance(value, (int, float, np.integer, np.floating)):
                setattr(merged, name, mine + value)
            else:
                raise TypeError(f"cannot add {type(other).__name__}.{name} over seeds: {value!r}")
    return merged


def assemble(
    runs: list[SeedRun],
    *,
    preset: str | None,
    duration_s: float,
    localizers: list[str],
    seeds: list[int],
    policy: str,
    phases: list[int] | None = None,
    interrupted: bool = False,
    out_dir: Path | None = None,
    start: float | None = None,
) -> dict[str, Any]:
    """The results of :func:`evaluate_localization` from its seeds' runs (in seed order),
    written with the figures to ``out_dir`` (``metrics.json``) if given."""
    from agents.evaluation import phase_spans

    spans = phase_spans(phases) if phases is not None else None
    if not runs:
        raise ValueError("no seed finished: nothing to score")
    facts = runs[0].env
    n_done = sum(run.steps_run for run in runs)
    if n_done:
        cost = ", ".join(
            f"{name} {1e3 * sum(r.cost_s[name] for r in runs) / n_done:.1f} "
            f"({1e3 * sum(r.cost_s[name] for r in runs) / n_done / facts['n_agents']:.2f})"
            for name in localizers
        )
        progress.note(f"swarm-phd evaluate: ms per env step (per observer): {cost}")
    scorers = {name: merge_tallies([r.scorers[name] for r in runs]) for name in localizers}
    camera_scorers = {
        name: merge_tallies([r.camera_scorers[name] for r in runs])
        for name in runs[0].camera_scorers
    }
    id_scorers = {
        name: merge_tallies([r.id_scorers[name] for r in runs]) for name in runs[0].id_scorers
    }
    finished = [run.seed for run in runs]
    task_metrics = [run.task_metrics for run in runs]
    results = {
        "config": {
            "preset": preset or _model_preset(policy),
            "duration_s": duration_s,
            "seeds": finished,
            **({"interrupted": True, "seeds_requested": list(seeds)} if interrupted else {}),
            "policy": policy,
            "task": facts["task"],
            "n_robots": facts["n_robots"],
            "localization_range_m": facts["localization_range_m"],
        },
        "localizers": {
            name: {
                **scorers[name].summary(),
                **(
                    {"at_camera_range": camera_scorers[name].summary()}
                    if name in camera_scorers
                    else {}
                ),
                "per_seed": [{"seed": run.seed, **run.figures[name]} for run in runs],
                **(
                    {"by_phase": phase_figures(sum(run.by_step[name] for run in runs), spans)}
                    if spans is not None
                    else {}
                ),
            }
            for name in localizers
        },
        **(
            {"identity": {name: sc.summary() for name, sc in id_scorers.items()}}
            if id_scorers
            else {}
        ),
        "task": _mean_dicts(task_metrics),
        "task_per_seed": [
            {"seed": seed, **m} for seed, m in zip(finished, task_metrics, strict=True)
        ],
        "wall_time_s": time.perf_counter() - start if start is not None else 0.0,
    }
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_json_atomically(out_dir / "metrics.json", results)
        from swarm_phd.figures import write_localization_figures

        traces = {name: scorers[name].trace for name in localizers}
        first = runs[0]
        write_localization_figures(
            out_dir, results, traces, np.array(first.paths), first.estimates
        )
    return results


def _pair_tallies(scorer: SeedScorer) -> np.ndarray:
    """The scorer's running (pair-steps above 0.30 m, in-range pair-steps) over all pairs, (2,)."""
    return np.array([scorer.large_steps.sum(), scorer.in_range_steps.sum()])


def phase_figures(counts: np.ndarray, spans: list[tuple[int, int | None]]) -> dict[str, float]:
    """``counts`` (T, 2): per step, the in-range pair-steps above 0.30 m and all of them; the
    share above, in %, over each span ``[lo, hi)`` of steps, keyed
    ``"pct_pair_steps_err_gt_30cm@<lo>-<hi>"`` (NaN: nothing in range there)."""
    from agents.evaluation import phase_key

    out = {}
    for lo, hi in spans:
        large, total = np.asarray(counts)[lo:hi].sum(axis=0)
        key = phase_key("pct_pair_steps_err_gt_30cm", lo, hi)
        out[key] = float(100.0 * large / total) if total else math.nan
    return out


def _model_preset(policy: str) -> str:
    """The preset a trained policy file's env used (seed-sim if it names none); sim-6m-20 for a
    policy by name."""
    from agents.policies import model_env_kwargs

    model = model_env_kwargs(policy)
    return "sim-6m-20" if model is None else model.get("preset", "seed-sim")


def comparison_rows(all_results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per policy: its task metrics and each localizer's headline metrics."""
    rows = []
    for res in all_results:
        row: dict[str, Any] = {"policy": res["config"]["policy"], **res.get("task", {})}
        for name, m in res["localizers"].items():
            one = m["seed_fig7"]["observer_ugv_0"]
            row[f"{name} ugv_0 teammates > 25 %"] = (
                f"{one['teammates_above_25pct']} of {one['tracked_teammates']}"
            )
            row[f"{name} ugv_0 median teammate % err>30cm"] = one["median"]
            row[f"{name} all observers median pair % err>30cm"] = m["seed_fig7"]["all_observers"][
                "median"
            ]
            row[f"{name} pooled per observer % err>30cm (median)"] = m["pooled_per_observer"][
                "median"
            ]
            row[f"{name} GOSPA"] = m["gospa"]["mean_m"]
            row[f"{name} card. MAE"] = m["cardinality"]["in_range_mae"]
        rows.append(row)
    return rows


def print_comparison(all_results: list[dict[str, Any]]) -> None:
    """Task and localization metrics of several policies, side by side (markdown)."""
    rows = comparison_rows(all_results)
    keys = list(dict.fromkeys(k for row in rows for k in row if k != "policy"))
    print("  | metric | " + " | ".join(str(r["policy"]) for r in rows) + " |")
    print("  |---|" + "---|" * len(rows))
    for key in keys:
        cells = [
            f"{r[key]:.3f}" if isinstance(r.get(key), float) else str(r.get(key, "-"))
            for r in rows
        ]
        print(f"  | {key} | " + " | ".join(cells) + " |")


#: The labels of :data:`PER_SEED_FIGURES` in the paired table (:func:`print_paired`): the
#: side-by-side row each one is the per-seed version of, where there is one.
PAIRED_FIGURE_LABELS = {
    "pct_pair_steps_err_gt_30cm": "% of pair-steps err>30cm",
    "pooled_per_observer_median_pct": "pooled per observer % err>30cm (median)",
    "gospa_mean_m": "GOSPA",
}


def paired_by_seed(all_results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each further policy of ``all_results`` against the first (``--policy``, the
    reference), paired by seed (:func:`agents.evaluation.paired_difference`): the task's
    metrics (``"task_per_seed"``; ``localizer`` None) and each localizer's per-seed figures
    (``"per_seed"``). One row per (policy, localizer, metric): the seeds paired, the
    per-seed differences ``policy - reference``, their mean, its standard error (None with
    one seed), the seeds on which the policy is better (``better_is`` lower or higher) and the
    verdict ("better by > 2 SE", "worse by > 2 SE", "within 2 SE", or that the SE needs 2
    seeds). A seed on which either has no value (NaN: nothing in range) is left out of that
    metric's pairs.

    A policy interrupted before its last seeds (or a reference that was) is paired on the
    seeds both finished. Raises ValueError, naming the policy, if it was asked for other seeds
    than the reference, or scored them in another order.
    """
    from agents.evaluation import higher_is_better, paired_difference

    reference, *others = all_results
    ref_policy = reference["config"]["policy"]
    ref_tables = _per_seed_tables(reference)
    rows: list[dict[str, Any]] = []
    for res in others:
        policy = res["config"]["policy"]
        tables = _per_seed_tables(res)
        requested, ref_requested = _requested_seeds(res), _requested_seeds(reference)
        if requested != ref_requested:
            raise ValueError(
                f"--compare {policy}: seeds {requested}, but the reference --policy "
                f"{ref_policy} has {ref_requested}: a paired comparison needs the same seeds in "
                "the same order"
            )
        for localizer, ref_table in ref_tables.items():
            # An interrupted run scored only its first seeds: pair on those both finished.
            finished = {d["seed"] for d in tables.get(localizer, [])}
            ref_finished = {d["seed"] for d in ref_table}
            table = [d for d in tables.get(localizer, []) if d["seed"] in ref_finished]
            ref_table = [d for d in ref_table if d["seed"] in finished]
            if [d["seed"] for d in table] != [d["seed"] for d in ref_table]:
                raise ValueError(
                    f"--compare {policy}: per-seed results in the order "
                    f"{[d['seed'] for d in table]}"
                    + (f" ({localizer})" if localizer else "")
                    + f", but the reference --policy {ref_policy} has "
                    f"{[d['seed'] for d in ref_table]}: a paired comparison needs the same "
                    "seeds in the same order"
                )
            keys = [k for k in dict.fromkeys(k for d in ref_table for k in d) if k != "seed"]
            for key in keys:
                if not all(key in d for d in (*ref_table, *table)):
                    continue  # a metric some seed has no value of (e.g. an empty episode)
                values, reference_values = [d[key] for d in table], [r[key] for r in ref_table]
                differences = [
                    (d["seed"], v - r)
                    for d, v, r in zip(table, values, reference_values, strict=True)
                    if math.isfinite(v - r)  # as paired_difference leaves them out
                ]
                row: dict[str, Any] = {
                    "policy": policy,
                    "reference": ref_policy,
                    "localizer": localizer,
                    "metric": key,
                    "better_is": "higher" if higher_is_better(key) else "lower",
                    "seeds": [seed for seed, _ in differences],
                    "differences": [x for _, x in differences],
                    **paired_difference(values, reference_values, key),
                }
                for field in ("mean_difference", "standard_error"):
                    if not math.isfinite(row[field]):
                        row[field] = None  # no pair, or one seed: JSON null, not NaN
                if row["verdict"] in ("better", "worse"):
                    row["verdict"] += " by > 2 SE"
                rows.append(row)
    return rows


def _requested_seeds(results: dict[str, Any]) -> list[int]:
    """The seeds an evaluation was asked for (an interrupted one finished fewer)."""
    config = results["config"]
    return list(config.get("seeds_requested", config["seeds"]))


def _per_seed_tables(results: dict[str, Any]) -> dict[str | None, list[dict[str, float]]]:
    """What :func:`paired_by_seed` pairs: the task metrics per seed (key None), then each
    localizer's per-seed figures."""
    tables: dict[str | None, list[dict[str, float]]] = {None: results.get("task_per_seed", [])}
    for name, m in results["localizers"].items():
        tables[name] = m["per_seed"]
    return tables


def print_paired(rows: list[dict[str, Any]]) -> None:
    """:func:`paired_by_seed` as a markdown table (nothing without rows)."""
    if not rows:
        return
    higher = sorted({r["metric"] for r in rows if r["better_is"] == "higher"})
    better = "lower" + (f"; higher for {', '.join(higher)}" if higher else "")
    print(
        f"  paired by seed, each policy − {rows[0]['reference']} (--policy): the mean "
        "difference over the seeds, its standard error (ddof=1), the seeds on which the policy "
        f"is better ({better}), and the verdict at 2 SE"
    )
    print("  | metric | policy − reference | mean difference | SE | seeds better | verdict |")
    print("  |---|---|---|---|---|---|")
    for r in rows:
        label = r["metric"]
        if r["localizer"] is not None:
            label = f"{r['localizer']} {PAIRED_FIGURE_LABELS.get(label, label)}"
        mean = "-" if r["mean_difference"] is None else f"{r['mean_difference']:+.3f}"
        se = "-" if r["standard_error"] is None else f"{r['standard_error']:.3f}"
        print(
            f"  | {label} | {r['policy']} − {r['reference']} | {mean} | {se} | "
            f"{r['seeds_better']} of {r['n_seeds']} | {r['verdict']} |"
        )


#: The Perera 2021 study's camera range (sec. 4: "2 meters was considered as the lidar sensor
#: range and 3m for the camera sensor"): the second scoring range of camera localizers (m).
CAMERA_SCORING_RANGE_M = 3.0


def _uses_camera(localizer: Any) -> bool:
    """Whether ``localizer`` runs camera updates (its PHD config's mode is lidar-camera; a
    PMB's config holds its PHD config as ``phd``)."""
    config = getattr(localizer, "config", None) or getattr(
        getattr(localizer, "bank", None), "config", None
    )
    config = getattr(config, "phd", config)
    return getattr(config, "mode", None) == "lidar-camera"


def _visible(truth: Any, camera: bool) -> np.ndarray | None:
    """Pairs the localizer's sensors could detect at their last reading (lidar, or lidar or
    camera), for the scorer's ``not_visible`` count; None without visibility truth."""
    vis = truth.visible
    if "lidar" not in vis:
        return None
    return vis["lidar"] | vis["camera"] if camera and "camera" in vis else vis["lidar"]


def _world_estimates(localizer, pose: np.ndarray) -> np.ndarray:
    est, _ = localizer.estimate(threshold=0.5)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return est @ np.array([[c, s], [-s, c]]) + pose[:2] if len(est) else np.zeros((0, 2))


def _mean_dicts(items: list[dict[str, float]]) -> dict[str, float]:
    keys = {k for d in items for k in d}
    return {k: float(np.mean([d[k] for d in items if k in d])) for k in sorted(keys)}


def print_table(results: dict[str, Any]) -> None:
    """Perera 2021's Fig. 7 statistic (per tracked teammate), then the other metrics (markdown)."""
    cfg = results["config"]
    print(
        f"  {cfg['preset']}, {cfg['n_robots']} robots, {cfg['duration_s']:.0f} s x "
        f"{len(cfg['seeds'])} seed(s), task {cfg.get('task', '-')}, policy {cfg['policy']}, "
        "in range = "
        f"{cfg['localization_range_m']:.1f} m"
    )
    print(
        "  | localizer | ugv_0: teammates > 25 % | ugv_0: median teammate % > 0.30 m | "
        "all observers: pairs > 25 % | median pair % | pooled per observer, median % |"
    )
    print("  |---|---|---|---|---|---|")
    for name, m in results["localizers"].items():
        for label, s in (("", m), (" at camera range", m.get("at_camera_range"))):
            if s is None:
                continue
            one = s["seed_fig7"]["observer_ugv_0"]
            every = s["seed_fig7"]["all_observers"]
            print(
                f"  | {name}{label} ({s['definition']['in_range_m']:g} m) | "
                f"{one['teammates_above_25pct']} of {one['tracked_teammates']} | "
                f"{one['median']:.1f} | {every['pairs_above_25pct']} of "
                f"{every['tracked_pairs']} | {every['median']:.1f} | "
                f"{s['pooled_per_observer']['median']:.1f} |"
            )
    print(
        "  | localizer | % < 0.1 m | % bearing < 7 deg | RMSE m | RMSE deg | GOSPA m "
        "(loc / missed / false m^2) | card. MAE in range (bias) | whole mixture (bias) |"
    )
    print("  |---|---|---|---|---|---|---|---|")
    for name, m in results["localizers"].items():
        s1, g, c = m["seed001"], m["gospa"], m["cardinality"]
        print(
            f"  | {name} | {s1['pct_time_position_err_lt_10cm']:.1f} | "
            f"{s1['pct_time_bearing_err_lt_7deg']:.1f} | {m['rmse_m']:.3f} | "
            f"{m['rmse_bearing_deg']:.2f} | {g['mean_m']:.3f} ({g['mean_localisation_m2']:.3f}"
            f" / {g['mean_missed_m2']:.3f} / {g['mean_false_m2']:.3f}) | "
            f"{c['in_range_mae']:.2f} ({c['in_range_bias']:+.2f}) | "
            f"{c['total_mae']:.2f} ({c['total_bias']:+.2f}) |"
        )
    for name, m in results["localizers"].items():
        causes = m["large_error_causes_pct_of_pair_steps"]
        by = m["by_range"]
        bins = ", ".join(
            f"{lo:g}-{hi:g} m {p:.1f}"
            for lo, hi, p, n in zip(
                by["edges_m"][:-1],
                by["edges_m"][1:],
                by["pct_err_gt_30cm"],
                by["pair_steps"],
                strict=True,
            )
            if n
        )
        print(
            f"  {name}: error > 0.30 m in {m['pct_pair_steps_err_gt_30cm']:.1f} % of pair-steps "
            + "("
            + ", ".join(f"{k} {v:.1f}" for k, v in causes.items())
            + f"); by range: {bins}"
        )
    print_identity_table(results)
    if results.get("task"):
        print("  task: " + ", ".join(f"{k} = {v:.3f}" for k, v in results["task"].items()))
    print(f"  wall time {results['wall_time_s']:.1f} s")


# ---------------------------------------------------------------------- identity scoring
class IdentityScorer:
    """Per observer: errors of each in-range neighbour's *own ID* estimate.

    For neighbour ``j`` of observer ``i`` the error is ``|est_i[j] - truth|`` (``inf`` if
    ``i`` holds no estimate for ``j``); with a heading estimate, also the wrapped heading error.
    """

    def __init__(self, n_observers: int, error_threshold_m: float = 0.30) -> None:
        self.n_observers = n_observers
        self.error_threshold_m = error_threshold_m
        self.pairs = np.zeros(n_observers)
        self.large = np.zeros(n_observers)
        self.accurate = np.zeros(n_observers)
        self.errors: list[float] = []
        self.heading_errors: list[float] = []
        # The Stegagno 2012 thesis's metrics (no estimate counts as an error): pair-steps with
        # bearing error < 7 deg; with a heading estimate, heading-estimating pair-steps < 7 deg.
        self.bearing_ok = 0
        self.heading_ok = 0
        self.heading_pairs = 0

    def add(self, observer: int, truth, mask: np.ndarray, identities: dict) -> None:
        for j in np.flatnonzero(mask).tolist():
            est = identities.get(j)
            rel = truth.relative_xy[observer, j]
            if est is None:
                err = math.inf
                self.heading_pairs += 1
            else:
                err = math.hypot(*(est[:2] - rel))
                b = math.atan2(est[1], est[0]) - math.atan2(rel[1], rel[0])
                self.bearing_ok += abs((b + math.pi) % (2 * math.pi) - math.pi) < math.radians(7)
                if len(est) > 2:
                    true_psi = truth.poses[j, 2] - truth.poses[observer, 2]
                    d = (est[2] - true_psi + math.pi) % (2 * math.pi) - math.pi
                    self.heading_errors.append(abs(math.degrees(d)))
                    self.heading_ok += abs(d) < math.radians(7)
                    self.heading_pairs += 1
            self.pairs[observer] += 1
            self.large[observer] += not err <= self.error_threshold_m
            self.accurate[observer] += err <= 0.10
            self.errors.append(err)

    def summary(self) -> dict[str, Any]:
        with np.errstate(invalid="ignore", divide="ignore"):
            pct = 100.0 * self.large / self.pairs
            acc = 100.0 * self.accurate / self.pairs
        finite = [e for e in self.errors if math.isfinite(e)]
        nan = float("nan")

        def dist(values: np.ndarray) -> dict[str, Any]:
            ok = values[np.isfinite(values)]
            return {
                "per_robot": [float(v) for v in values],
                "median": float(np.median(ok)) if ok.size else nan,
                "max": float(ok.max()) if ok.size else nan,
            }

        total = float(self.pairs.sum())
        return {
            "id_pct_time_err_gt_30cm": dist(pct),
            "id_pct_time_within_10cm": dist(acc),
            "id_percent_large_error": 100.0 * float(self.large.sum()) / total if total else nan,
            "id_percent_missing": 100.0 * (len(self.errors) - len(finite)) / total
            if total
            else nan,
            "id_median_error_m": float(np.median(finite)) if finite else nan,
            "id_median_heading_error_deg": float(np.median(self.heading_errors))
            if self.heading_errors
            else nan,
            "id_percent_within_10cm": 100.0 * float(self.accurate.sum()) / total if total else nan,
            "id_percent_bearing_within_7deg": 100.0 * self.bearing_ok / total if total else nan,
            "id_percent_heading_within_7deg": 100.0 * self.heading_ok / self.heading_pairs
            if self.heading_errors
            else nan,
        }


def print_identity_table(results: dict[str, Any]) -> None:
    """The ``identity`` block (ID-aware localizers), if any, as a markdown table."""
    ident = results.get("identity")
    if not ident:
        return
    print(
        "  | localizer (own-ID estimate) | % time err > 30 cm (median robot) | pooled | "
        "% time < 10 cm | no estimate % | median err m | median heading err deg | "
        "Stegagno 2012: % < 0.1 m / bearing < 7 deg / heading < 7 deg (pooled) |"
    )
    print("  |---|---|---|---|---|---|---|---|")
    for name, m in ident.items():
        print(
            f"  | {name} | {m['id_pct_time_err_gt_30cm']['median']:.1f} | "
            f"{m['id_percent_large_error']:.1f} | {m['id_pct_time_within_10cm']['median']:.1f} | "
            f"{m['id_percent_missing']:.1f} | {m['id_median_error_m']:.3f} | "
            f"{m['id_median_heading_error_deg']:.1f} | "
            f"{m['id_percent_within_10cm']:.1f} / {m['id_percent_bearing_within_7deg']:.1f} / "
            f"{m['id_percent_heading_within_7deg']:.1f} |"
        )
