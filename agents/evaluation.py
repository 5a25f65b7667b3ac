"""Scoring policies on a task's held-out seeds, and comparing them paired by seed.

One set of statistics for every comparison the project makes: ``swarm-phd evaluate
--compare``, the trainers' validation scores and the studies in ``experiments/`` all call
:func:`paired_difference` (the mean difference over seeds, its standard error and the verdict),
so a "better" means the same everywhere.

- :func:`score`: one policy's task metrics and per-agent episode return over seeds (mean, std,
  per seed; with ``phases``, each per-step task series over phases of the episode);
- :func:`paired_difference`: two policies' per-seed values of one metric, paired by seed;
- :func:`paired_differences`: every learned group and baseline against every reference;
- :func:`pooled`, :func:`markdown_table`, :func:`paired_table`: the tables.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: The phases (first steps) the studies and the recurrent student's scores split an episode
#: into by default.
DEFAULT_PHASES = (0, 25, 50, 100, 150)

#: Task metrics where more is better (the rest are errors and rates: less is better).
HIGHER_IS_BETTER = (
    "coverage",
    "episode_return",
    "enclosed_fraction",
    "final_enclosed_fraction",
    "ever_enclosed",
)


def higher_is_better(metric: str) -> bool:
    """Whether more of ``metric`` (or of its phase, ``NAME@LO-HI``) is better."""
    return metric.split("@", 1)[0] in HIGHER_IS_BETTER


def phase_key(name: str, lo: int, hi: int | None) -> str:
    """``formation_error_m@150-300``; the last, open-ended phase ``formation_error_m@150-``."""
    return f"{name}@{lo}-{'' if hi is None else hi}"


def phase_spans(phases: Any) -> list[tuple[int, int | None]]:
    """First steps ``[0, 150]`` -> spans ``[(0, 150), (150, None)]`` (the last open-ended);
    ValueError unless they are increasing integers >= 0."""
    bounds = [int(p) for p in phases]
    if not bounds or bounds != sorted(set(bounds)) or bounds[0] < 0:
        raise ValueError(f"phases must be increasing step numbers >= 0, got {list(phases)!r}")
    return list(zip(bounds, [*bounds[1:], None], strict=True))


def parse_phases(value: Any, flag: str = "--phases") -> list[int]:
    """Phases as first steps, from ``"0,25,50"`` or a sequence: ``[0, 25, 50]``;
    ``ValueError`` naming ``flag`` unless they are increasing integers >= 0."""
    try:
        phases = [int(p) for p in (value.split(",") if isinstance(value, str) else value)]
        phase_spans(phases)
    except (TypeError, ValueError):
        shown = value if isinstance(value, str) else list(value)
        raise ValueError(f"{flag} must be increasing integers >= 0, got {shown!r}") from None
    return phases


def phase_metrics(series: dict[str, np.ndarray], phases: list[int]) -> dict[str, float]:
    """Each per-step series (``Task.step_series``, index t: the step t + 1 ends) averaged over
    the phases ``[phases[i], phases[i + 1])`` (the last open-ended), keyed by
    :func:`phase_key`; NaN for a phase the episode did not reach."""
    spans = phase_spans(phases)
    out = {}
    for name, values in series.items():
        for lo, hi in spans:
            part = np.asarray(values, dtype=float)[lo:hi]
            out[phase_key(name, lo, hi)] = float(part.mean()) if part.size else float("nan")
    return out


def score(
    policy_spec: str,
    env_kwargs: dict[str, Any],
    seeds: list[int],
    n_steps: int | None = None,
    phases: list[int] | None = None,
) -> dict[str, Any]:
    """Mean/std over seeds of the task metrics and of the per-agent episode return; with
    ``phases`` (first steps), also of each per-step task series over each phase
    (:func:`phase_metrics`, e.g. ``formation_error_m@150-``)."""
    from agents.policies import load_policy
    from agents.pretrained import resolve
    from swarm_env import parallel_env
    from swarm_env.tasks import task_needs_estimates

    kwargs = dict(env_kwargs)
    spec = resolve(policy_spec)
    # A localization term on the estimate needs the filters whatever the policy reads.
    needs = task_needs_estimates(kwargs.get("task", "wander"), kwargs.get("task_params"))
    # scripted:NAME@truth runs in an env on the truth; privileged:NAME@truth reads the truth
    # from its infos, in an env on the estimate (the next branch).
    if spec.startswith("scripted:") and spec.endswith("@truth"):
        spec = spec[: -len("@truth")]
        kwargs.update(observation="truth", localize=needs)
    elif not spec.endswith(".zip"):
        from agents.policies import policy_observation

        mode = policy_observation(spec)
        kwargs.update(observation=mode or "measurements", localize=mode == "phd" or needs)
    env = parallel_env(**kwargs)
    policy = load_policy(spec, env)
    n_steps = n_steps or env.config.max_steps
    per_seed: list[dict[str, float]] = []
    curves: list[list[float]] = []  # per seed, the task's coverage after every step
    for seed in seeds:
        if hasattr(policy, "reset"):
            policy.reset(seed)
        obs, infos = env.reset(seed=seed)
        total = 0.0
        curve = []
        for _ in range(n_steps):
            if not env.agents:
                break
            obs, rewards, _, _, infos = env.step(policy(obs, infos))
            total += float(np.mean(list(rewards.values()))) if rewards else 0.0
            if hasattr(env.task, "coverage"):
                curve.append(float(env.task.coverage))
        by_phase = phase_metrics(env.task.step_series(), phases) if phases else {}
        per_seed.append({**env.task.metrics(), **by_phase, "episode_return": total})
        if curve:  # an episode ended early at the target: coverage stays where it was
            curves.append(curve + [curve[-1]] * (n_steps - len(curve)))
    env.close()
    keys = per_seed[0].keys()
    out = {
        "policy": policy_spec,
        "seeds": seeds,
        "mean": {k: float(np.mean([d[k] for d in per_seed])) for k in keys},
        "std": {k: float(np.std([d[k] for d in per_seed])) for k in keys},
        "per_seed": per_seed,
    }
    out["control_period_s"] = env.config.control_period_s
    if curves:
        out["coverage_curve_mean"] = np.mean(curves, axis=0).tolist()
    return out


def pooled(results: list[dict[str, Any]], metric: str) -> dict[str, float]:
    """Several runs (training seeds) scored on the same held-out seeds: the mean and std over
    all (run, seed) episodes, and the std of the runs' means (the training-seed spread)."""
    values = np.array([[d[metric] for d in r["per_seed"]] for r in results])
    return {
        "mean": float(values.mean()),
        "std": float(values.std()),
        "std_of_run_means": float(values.mean(axis=1).std()),
        "n_runs": len(results),
    }


def paired_differences(
    policies: dict[str, Any],
    groups: dict[str, list[str]],
    baselines: list[str],
    metric: str,
) -> list[dict[str, Any]]:
    """Every learned group (its runs' per-seed mean) and every later baseline against every
    baseline, and every learned group against every earlier one (a fine-tuned group against
    the group it started from: what the fine-tuning added), paired by held-out seed: the mean
    difference ``a - b`` in ``metric``, its
    standard error (``std(ddof=1) / sqrt(n)`` over the seeds), and on how many seeds ``a`` is
    better (lower, or higher for :data:`HIGHER_IS_BETTER`).

    Paired by seed, the spread that the layouts share cancels: on 20 formation seeds the
    per-policy std is ~0.06 m, the SE of a paired difference ~0.004 m. ``verdict`` is
    ``"better"`` / ``"worse"`` beyond 2 SE, else ``"within 2 SE"``, or
    :data:`NO_SE_VERDICT` / :data:`NO_PAIR_VERDICT` with under 2 / no seeds scored by both
    (each pair's statistic: :func:`paired_difference`). The SE is over the held-out
    seeds only: it judges these trained models, not the recipe (the runs' spread, the pooled
    row's "run means ±", is not in it). Every policy must have been scored on the same seeds.
    """

    seed_lists = {s: policies[s].get("seeds") for specs in groups.values() for s in specs}
    seed_lists.update({b: policies[b].get("seeds") for b in baselines})
    if len({tuple(v) for v in seed_lists.values() if v is not None}) > 1:
        raise ValueError(f"paired_differences needs the same seeds for every policy: {seed_lists}")

    def per_seed(specs: list[str]) -> np.ndarray:
        return np.mean([[d[metric] for d in policies[s]["per_seed"]] for s in specs], axis=0)

    # (contender, its specs, the references it is paired with, each with its specs): each
    # learned group against every baseline and every earlier group, and each pair of
    # baselines once (the later one against the earlier).
    learned = [(name, specs) for name, specs in groups.items() if specs]
    singles = [(b, [b]) for b in baselines]
    pairs = [(name, specs, singles + learned[:j]) for j, (name, specs) in enumerate(learned)]
    pairs += [(b, [b], singles[:j]) for j, b in enumerate(baselines)]
    return [
        {
            "policy": name,
            "baseline": base,
            **paired_difference(per_seed(specs), per_seed(base_specs), metric),
        }
        for name, specs, references in pairs
        for base, base_specs in references
    ]


#: :func:`paired_difference`'s verdict when there is no standard error (fewer than 2 seeds).
NO_SE_VERDICT = "SE needs at least 2 seeds"
#: ... and when no seed has a value on both sides.
NO_PAIR_VERDICT = "no seed scored by both"


def paired_difference(values: Any, reference: Any, metric: str) -> dict[str, Any]:
    """One policy's per-seed ``values`` of ``metric`` against a ``reference``'s on the same
    seeds, in the same order (a seed where either is not finite is left out, and not counted
    in ``n_seeds``): the mean of the differences ``values - reference``, its standard
    error (``std(ddof=1) / sqrt(n)``; NaN for one seed), on how many seeds the policy is better
    (lower, or higher for :data:`HIGHER_IS_BETTER`; a tie is not), and ``verdict``:
    ``"better"`` / ``"worse"`` beyond 2 SE, else ``"within 2 SE"`` (:data:`NO_SE_VERDICT`
    with one seed, :data:`NO_PAIR_VERDICT` with none). The one paired statistic of
    :func:`paired_differences`, ``experiments/localization_table.py`` and ``swarm-phd evaluate
    --compare``."""
    a = np.asarray(values, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(
            f"paired_difference needs one value per seed on the same seeds, got {a.shape} "
            f"values and {b.shape} reference values of {metric}"
        )
    diff = a - b
    diff = diff[np.isfinite(diff)]  # a seed either side has no value of (nothing in range)
    n = len(diff)
    if n == 0:
        return {
            "mean_difference": float("nan"),
            "standard_error": float("nan"),
            "seeds_better": 0,
            "n_seeds": 0,
            "verdict": NO_PAIR_VERDICT,
        }
    sign = 1.0 if higher_is_better(metric) else -1.0  # positive sign * diff = better
    se = float(diff.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    mean = float(diff.mean())
    if n < 2:
        verdict = NO_SE_VERDICT
    elif sign * mean > 2.0 * se:
        verdict = "better"
    elif -sign * mean > 2.0 * se:
        verdict = "worse"
    else:
        verdict = "within 2 SE"
    return {
        "mean_difference": mean,
        "standard_error": se,
        "seeds_better": int((sign * diff > 0).sum()),
        "n_seeds": n,
        "verdict": verdict,
    }


def paired_table(rows: list[dict[str, Any]], metric: str) -> str:
    """:func:`paired_differences` as markdown."""
    lines = [
        f"| policy − baseline, paired by seed | mean difference in {metric} | SE | "
        "seeds better | verdict |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['policy']} − {r['baseline']} | {r['mean_difference']:+.4f} | "
            f"{_se_cell(r['standard_error'], '.4f')} | {r['seeds_better']} of {r['n_seeds']} | "
            f"{r['verdict']} |"
        )
    return "\n".join(lines) + "\n"


def _se_cell(se: float, spec: str) -> str:
    """A standard error for a table: ``spec``-formatted, or "-" without one (one seed)."""
    return format(se, spec) if np.isfinite(se) else "-"


def markdown_table(results: dict[str, Any], metric: str, groups: dict[str, list[str]]) -> str:
    """Rows ``policy | metric mean +- std | return mean +- std`` plus one pooled row per group."""
    lines = [f"| policy | {metric} | episode return / agent |", "|---|---|---|"]
    for spec, r in results.items():
        m, s = r["mean"], r["std"]
        lines.append(
            f"| {spec} | {m[metric]:.3f} ± {s[metric]:.3f} | "
            f"{m['episode_return']:.1f} ± {s['episode_return']:.1f} |"
        )
    for name, specs in groups.items():
        if len(specs) < 2:
            continue
        p, ret = (
            pooled([results[s] for s in specs], metric),
            pooled([results[s] for s in specs], "episode_return"),
        )
        lines.append(
            f"| **{name}** ({p['n_runs']} training seeds, pooled) | "
            f"**{p['mean']:.3f} ± {p['std']:.3f}** (run means ± {p['std_of_run_means']:.3f}) | "
            f"{ret['mean']:.1f} ± {ret['std']:.1f} |"
        )
    return "\n".join(lines) + "\n"
