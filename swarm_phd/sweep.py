"""``swarm-phd sweep``: the localization experiment over a grid of presets x localizers x seeds,
fanned out over Ray workers (a local Ray by default, a cluster with ``--address``).

One grid point is one ``(preset, seed)``: a single call of
:func:`swarm_phd.evaluate.evaluate_localization` with every requested localizer (they share the
motion and the measurements, so a point is one paired comparison). Each point runs as one Ray
task, in a worker process with one kernel thread (:func:`swarm_core.threads.set_kernel_threads`);
the driver compiles the numba kernels first, so workers load them from the cache (shared by
every process of a machine) instead of compiling.

A point's metrics are those of the serial call with the same arguments and seed, bit for bit:
the env and every filter are seeded from the point's seed alone, nothing crosses points
(``tests/test_sweep.py`` checks it). ``--serial`` runs the same points in this process, without
Ray: the reference, and the baseline of the wall-time figures in ``docs/scaling.md``.

Progress: one line per finished point (stderr). A failed point is reported with its preset and
seed and recorded as failed; the other points keep their results. The merged JSON (``--out``)
is rewritten after every finished point, atomically (a temporary file renamed over it), so an
interrupted sweep leaves a complete file of what finished::

    {"config": {...grid...}, "points": [{"preset", "seed", "status": "ok"|"failed",
     "results" | "error", "seconds"}...], "summary": {preset: {localizer: {metric: {"mean",
     "min", "max", "n"}}}}, "failed": [{"preset", "seed", "error"}...], "wall_time_s": ...}

``summary`` aggregates every scalar of each seed's localizer block over the seeds (keyed by
dotted path, e.g. ``headline.gospa_mean_m``). A mean over seeds is not the pooled number of
``swarm-phd evaluate --seeds 0,1``, which scores all seeds' pairs together; each point's own
block equals the serial run's.
"""

from __future__ import annotations

import argparse
import math
import numbers
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm_core import inputs, progress
from swarm_core.atomic_files import write_json_atomically
from swarm_core.inputs import parse_json_object, parse_seeds
from swarm_env.config import PRESETS
from swarm_phd import presets

#: Columns of the printed summary when the localizer blocks have no ``headline`` block.
FALLBACK_COLUMNS = (
    "pct_time_err_gt_30cm.median",
    "pct_time_within_10cm.median",
    "gospa_mean",
    "cardinality_mae",
)


@dataclass(frozen=True)
class GridPoint:
    """One Ray task: ``evaluate_localization(preset, duration_s, localizers, [seed], ...)``."""

    preset: str
    seed: int
    localizers: tuple[str, ...]
    duration_s: float
    policy: str = "scripted:wander"
    task: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)

    def label(self) -> str:
        return f"{self.preset} seed {self.seed}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--presets",
        default="sim-6m-20",
        help=f"comma-separated presets, of: {', '.join(PRESETS)}",
    )
    parser.add_argument(
        "--localizer", default="phd-lc,phd-lo", help="comma-separated localizers (all per point)"
    )
    parser.add_argument(
        "--seeds", default="0-3", help="comma-separated integers and ranges, e.g. '0-9' or '0,5'"
    )
    inputs.add_duration_argument(parser, 300.0)
    parser.add_argument(
        "--policy", default="scripted:wander", help="'scripted:NAME', 'random' or a model.zip"
    )
    parser.add_argument("--task", default=None, help="default: the model's, else 'wander'")
    parser.add_argument(
        "--env-overrides",
        default="{}",
        help='JSON dict of SwarmConfig overrides for every point, e.g. \'{"arena": '
        '{"n_boxes": 0}}\'',
    )
    add_ray_arguments(parser)
    parser.add_argument(
        "--serial", action="store_true", help="run the points in this process, without Ray"
    )
    parser.add_argument(
        "--out", default=None, help="merged results JSON (default: runs/sweep/sweep.json)"
    )


def add_ray_arguments(parser: argparse.ArgumentParser) -> None:
    """``--address`` and ``--ray-num-cpus`` (shared with ``evaluate --ray``)."""
    parser.add_argument(
        "--address",
        default=None,
        help="Ray cluster to join ('auto', 'ray://HEAD:10001'); default: a local Ray",
    )
    parser.add_argument(
        "--ray-num-cpus",
        type=int,
        default=None,
        help="CPUs (= parallel points) a local Ray may use (default: all of this machine's)",
    )


def _names(text: str, name: str) -> list[str]:
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:
        raise ValueError(f"{name} names nothing: {text!r}")
    return items


def grid(
    presets: list[str],
    localizers: list[str],
    seeds: list[int],
    duration_s: float,
    policy: str = "scripted:wander",
    task: str | None = None,
    overrides: dict[str, Any] | None = None,
) -> list[GridPoint]:
    """Every ``(preset, seed)`` point, presets outer. Checks the arguments every point shares
    (localizer names, duration) here, before any worker starts."""
    from localization.registry import LOCALIZERS

    unknown = [n for n in localizers if n not in LOCALIZERS]
    if unknown or not localizers:
        raise ValueError(f"--localizer must name some of {sorted(LOCALIZERS)}, got {localizers}")
    inputs.duration("--duration", duration_s)
    return [
        GridPoint(p, s, tuple(localizers), float(duration_s), policy, task, dict(overrides or {}))
        for p in presets
        for s in seeds
    ]


def evaluate_point(point: GridPoint, kernel_threads: int | None = 1) -> dict[str, Any]:
    """Run one point (in a Ray worker or in-process); the evaluation's results dict.

    ``kernel_threads``: threads of this process's numba kernels (1 in a worker: the cores are
    shared between worker processes; ``None`` leaves the process's setting).
    """
    from swarm_phd.evaluate import evaluate_localization

    if kernel_threads is not None:
        from swarm_core.threads import set_kernel_threads

        set_kernel_threads(kernel_threads)
    return evaluate_localization(
        point.preset,
        point.duration_s,
        list(point.localizers),
        [point.seed],
        policy=point.policy,
        task=point.task,
        **point.overrides,
    )


def _timed_point(point: GridPoint) -> tuple[dict[str, Any], float]:
    """The Ray task: results and the worker's own seconds (queueing excluded)."""
    from swarm_core import progress

    # Bars of many workers interleaved in the driver's log say nothing; the driver prints a
    # line per finished point instead.
    progress.set_quiet(True)
    start = time.perf_counter()
    results = evaluate_point(point, kernel_threads=1)
    return results, time.perf_counter() - start


def run_sweep(
    points: list[GridPoint],
    *,
    use_ray: bool = True,
    address: str | None = None,
    ray_num_cpus: int | None = None,
    out: Path | None = None,
    report=None,
) -> dict[str, Any]:
    """Run every point (Ray tasks, or in this process with ``use_ray=False``); return (and
    write to ``out``, atomically, after each finished point) the merged results.

    ``report(line)`` receives one line per finished point (default: stderr unless quiet).
    A point that raises is recorded as ``"failed"`` with its error; the others continue.
    """
    from swarm_core import progress

    if not points:
        raise ValueError("the sweep has no grid point")
    report = report or progress.note
    # wall_time_s: from the first point started to the last finished (Ray's start-up and a
    # kernel compile are not the sweep's work; the command's own wall time includes them).
    start = time.perf_counter()
    entries: list[dict[str, Any] | None] = [None] * len(points)
    merged = {"config": _grid_config(points, use_ray, address)}

    def finish(k: int, results: dict | None, error: str | None, seconds: float) -> None:
        p = points[k]
        entry: dict[str, Any] = {"preset": p.preset, "seed": p.seed, "seconds": seconds}
        if error is None:
            entry.update(status="ok", results=results)
            line = f"ok in {seconds:.1f} s"
        else:
            entry.update(status="failed", error=error)
            line = f"FAILED: {error.strip().splitlines()[-1]}"
        entries[k] = entry
        done = sum(e is not None for e in entries)
        report(f"sweep [{done}/{len(points)}] {p.label()}: {line}")
        merged.update(_merge(points, entries, time.perf_counter() - start))
        if out is not None:
            write_json_atomically(out, merged)

    if not use_ray:
        for k, point in enumerate(points):
            t0 = time.perf_counter()
            try:
                res = evaluate_point(point, kernel_threads=None)
                finish(k, res, None, time.perf_counter() - t0)
            except Exception:  # noqa: BLE001 - a failed point is reported, the sweep goes on
                finish(k, None, traceback.format_exc(limit=3), time.perf_counter() - t0)
        return merged

    import ray

    from swarm_env.warmup import warm_if_cold

    warm_if_cold()  # compile here once; the workers then load the kernels from the cache
    started = _start_ray(address, ray_num_cpus)
    start = time.perf_counter()
    try:
        task = ray.remote(num_cpus=1)(_timed_point)
        pending = {task.remote(p): k for k, p in enumerate(points)}
        submitted = {ref: time.perf_counter() for ref in pending}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            ref = ready[0]
            k = pending.pop(ref)
            try:
                res, seconds = ray.get(ref)
                finish(k, res, None, seconds)
            except Exception as exc:  # noqa: BLE001 - RayTaskError wraps the worker's error
                cause = getattr(exc, "cause", None) or exc
                finish(
                    k,
                    None,
                    f"{type(cause).__name__}: {cause}",
                    time.perf_counter() - submitted[ref],
                )
    finally:
        if started:
            ray.shutdown()
    return merged


def _start_ray(address: str | None, num_cpus: int | None) -> bool:
    """Join ``address`` or start a local Ray; returns whether this call started it. An
    already initialised Ray (a test fixture, a caller's cluster) is used as it is."""
    import ray

    import swarm_core.threads  # noqa: F401 - OMP_WAIT_POLICY set before workers copy the env

    if ray.is_initialized():
        return False
    if address:
        ray.init(address=address)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False)
    return True


def _grid_config(points: list[GridPoint], use_ray: bool, address: str | None) -> dict[str, Any]:
    first = points[0]
    return {
        "presets": list(dict.fromkeys(p.preset for p in points)),
        "seeds": list(dict.fromkeys(p.seed for p in points)),
        "localizers": list(first.localizers),
        "duration_s": first.duration_s,
        "policy": first.policy,
        "task": first.task,
        "overrides": first.overrides,
        "engine": "ray" if use_ray else "serial",
        "address": address,
    }


def _merge(
    points: list[GridPoint], entries: list[dict[str, Any] | None], wall_s: float
) -> dict[str, Any]:
    done = [e for e in entries if e is not None]
    summary: dict[str, Any] = {}
    for e in done:
        if e["status"] != "ok":
            continue
        for name, metrics in e["results"]["localizers"].items():
            slot = summary.setdefault(e["preset"], {}).setdefault(name, {})
            for key, value in numeric_leaves(metrics).items():
                slot.setdefault(key, []).append(value)
    for per_loc in summary.values():
        for slot in per_loc.values():
            for key, values in slot.items():
                ok = [v for v in values if math.isfinite(v)]
                slot[key] = {
                    "mean": sum(ok) / len(ok) if ok else float("nan"),
                    "min": min(ok) if ok else float("nan"),
                    "max": max(ok) if ok else float("nan"),
                    "n": len(values),
                }
    return {
        "points": done,
        "summary": summary,
        "failed": [
            {"preset": e["preset"], "seed": e["seed"], "error": e["error"]}
            for e in done
            if e["status"] == "failed"
        ],
        "complete": len(done) == len(points),
        "wall_time_s": wall_s,
    }


def numeric_leaves(block: dict[str, Any], prefix: str = "") -> dict[str, float]:
    """Every number of a nested results dict, keyed by dotted path (``headline.gospa_mean_m``).

    Lists (per-robot values) and booleans are left out: the summary is over seeds of scalars.
    Schema-agnostic on purpose: the evaluation's metric names are not this module's business.
    """
    out: dict[str, float] = {}
    for key, value in block.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(numeric_leaves(value, path + "."))
        elif isinstance(value, numbers.Real) and not isinstance(value, bool):
            out[path] = float(value)
    return out


def print_summary(merged: dict[str, Any]) -> None:
    """Per preset and localizer, mean [min, max] over seeds of the headline numbers (the
    ``headline`` block of the evaluation's results, else :data:`FALLBACK_COLUMNS`), then the
    failed points (markdown)."""
    for preset, per_loc in merged["summary"].items():
        keys = list(dict.fromkeys(k for m in per_loc.values() for k in m))
        columns = [k for k in keys if k.startswith("headline.")]
        columns = columns or [k for k in FALLBACK_COLUMNS if k in keys]
        names = [c.removeprefix("headline.") for c in columns]
        print(f"  {preset}: mean [min, max] over seeds")
        print("  | localizer | seeds | " + " | ".join(names) + " |")
        print("  |---|---|" + "---|" * len(columns))
        for name, m in per_loc.items():
            n = max((s["n"] for s in m.values()), default=0)
            cells = [
                "-" if c not in m else f"{m[c]['mean']:.3f} [{m[c]['min']:.3f}, {m[c]['max']:.3f}]"
                for c in columns
            ]
            print(f"  | {name} | {n} | " + " | ".join(cells) + " |")
    for f in merged["failed"]:
        last = f["error"].strip().splitlines()[-1]
        print(f"  FAILED {f['preset']} seed {f['seed']}: {last}")


def _command_grid(
    args: argparse.Namespace, preset_names: list[str], overrides: dict[str, Any]
) -> list[GridPoint]:
    """:func:`grid` of ``preset_names`` with the command's localizers, seeds, duration, policy
    and task."""
    return grid(
        preset_names,
        _names(args.localizer, "--localizer"),
        parse_seeds(args.seeds),
        args.duration,
        policy=args.policy,
        task=args.task,
        overrides=overrides,
    )


def run(args: argparse.Namespace) -> int:
    overrides = parse_json_object(args.env_overrides, "--env-overrides")
    names = presets.known("--presets", _names(args.presets, "--presets"))
    points = _command_grid(args, names, overrides)
    from agents.policies import is_trained_model

    if not is_trained_model(args.policy):  # a trained policy runs in its own env
        for preset in names:
            period = presets.control_period_s(preset, **overrides)
            inputs.duration("--duration", args.duration, period)
    out = inputs.output_file("--out", args.out or "runs/sweep/sweep.json")
    merged = run_sweep(
        points,
        use_ray=not args.serial,
        address=args.address,
        ray_num_cpus=args.ray_num_cpus,
        out=out,
    )
    print_summary(merged)
    print(
        f"{len(merged['points']) - len(merged['failed'])}/{len(points)} points ok in "
        f"{merged['wall_time_s']:.1f} s -> {out}"
    )
    return 1 if merged["failed"] else 0


def run_evaluate_ray(args: argparse.Namespace) -> int:
    """``swarm-phd evaluate --ray``: the serial command's evaluation with each seed in its own
    Ray task (:func:`swarm_phd.evaluate.score_seed`, one kernel thread per worker), the seeds'
    tallies added in the order of ``--seeds`` as the serial run adds them
    (:func:`swarm_phd.evaluate.assemble`): the same printed table, ``metrics.json`` and figures
    in ``--out``, the same numbers, in the wall time of the slowest seed per worker.

    A failed seed fails the command (exit 1, its error on stderr); Ctrl-C scores the seeds
    finished so far, as the serial run does.
    """
    import ray

    from swarm_env.warmup import warm_if_cold
    from swarm_phd.evaluate import assemble, print_table

    if getattr(args, "compare", None):
        raise ValueError("--compare is not supported with --ray: run the two policies apart")
    overrides: dict[str, Any] = {}
    if args.task_params is not None:
        overrides["task_params"] = parse_json_object(args.task_params, "--task-params")
    localizers = _names(args.localizer, "--localizer")
    seeds = parse_seeds(args.seeds)
    grid([args.preset or "lab-3m-4"], localizers, seeds, args.duration)  # checks, no run
    warm_if_cold()  # compile here once; the workers then load the kernels from the cache
    start = time.perf_counter()
    started = _start_ray(getattr(args, "address", None), getattr(args, "ray_num_cpus", None))
    runs: dict[int, Any] = {}
    durations: set[float] = set()
    interrupted = False
    try:
        task = ray.remote(num_cpus=1)(_score_one_seed)
        pending = {
            task.remote(
                args.preset,
                args.duration,
                localizers,
                args.policy,
                args.task,
                overrides,
                seed,
                seed == seeds[0],
            ): seed
            for seed in seeds
        }
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                seed = pending.pop(ready[0])
                try:
                    run, duration_s = ray.get(ready[0])
                except Exception as exc:  # noqa: BLE001 - RayTaskError wraps the worker's error
                    cause = getattr(exc, "cause", None) or exc
                    raise RuntimeError(
                        f"seed {seed} failed: {type(cause).__name__}: {cause}"
                    ) from exc
                runs[seed] = run
                durations.add(duration_s)
                progress.note(f"evaluate --ray: seed {seed} done [{len(runs)}/{len(seeds)}]")
        except KeyboardInterrupt:
            if not runs:
                raise
            interrupted = True
            for ref in pending:
                ray.cancel(ref, force=True)
            print(
                f"swarm-phd evaluate: interrupted; scoring the {len(runs)} finished seed(s) "
                f"{sorted(runs, key=seeds.index)}",
                file=sys.stderr,
            )
    except RuntimeError as exc:
        print(f"swarm-phd evaluate --ray: {exc}", file=sys.stderr)
        return 1
    finally:
        if started:
            ray.shutdown()
    (duration_s,) = durations
    if duration_s != args.duration:
        progress.note(
            f"swarm-phd evaluate: {args.policy}'s env ends each episode earlier: "
            f"{duration_s:g} s per seed, not --duration {args.duration:g} s"
        )
    results = assemble(
        [runs[s] for s in seeds if s in runs],  # the serial run's order
        preset=args.preset,
        duration_s=duration_s,
        localizers=localizers,
        seeds=seeds,
        policy=args.policy,
        interrupted=interrupted,
        out_dir=Path(args.out) if args.out else None,
        start=start,
    )
    print_table(results)
    return 0


def _score_one_seed(
    preset: str | None,
    duration_s: float,
    localizers: list[str],
    policy: str,
    task: str | None,
    overrides: dict[str, Any],
    seed: int,
    first: bool,
) -> tuple[Any, float]:
    """The Ray task of ``evaluate --ray``: one seed's :class:`swarm_phd.evaluate.SeedRun` and
    the seconds per seed that ran, as the serial command builds and scores it."""
    from swarm_core import progress
    from swarm_core.threads import set_kernel_threads
    from swarm_phd.evaluate import _episode_env, score_seed

    progress.set_quiet(True)  # the driver prints a line per finished seed
    set_kernel_threads(1)
    env, n_steps, duration_s, spans = _episode_env(
        preset, duration_s, localizers, policy, task, None, overrides
    )
    try:
        return score_seed(env, policy, localizers, seed, n_steps, spans, first=first), duration_s
    finally:
        env.close()


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm_phd.sweep`` (the same as ``swarm-phd sweep``)."""
    parser = argparse.ArgumentParser(prog="python -m swarm_phd.sweep", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
