"""One table of task and localization metrics for several policies, in one process.

    python -m experiments.localization_table --policies runs/a/model.zip runs/b/model.zip \\
        scripted:formation --seeds 100-109 --out runs/report --name ablation

Question: does a learned motion localize the teammates at least as well as scripted motion?
(``experiments/results/motion_localizes.json`` on the results page.)

For every policy, on the same held-out seeds (one deterministic episode each, ``max_steps`` of
the first model's env): the per-agent episode return and the task metric, mean ± std over the
seeds (:func:`agents.evaluation.score`), and the localization metrics of
:func:`swarm_phd.evaluate.evaluate_localization` on the same motion (every robot runs each of
``--localizers`` on the records of that motion): GOSPA (m) and the pooled per-observer share
of pair-steps with error above 0.30 m (median observer), and the same per seed, from which
every policy is compared with every earlier one paired by seed (mean difference, SE, seeds
better: :func:`paired_localization`). Models (``.zip``) and recurrent students (``.pt``) run
in the env they were trained in; ``scripted:*`` and ``random`` in the first model's env (its
task, task parameters and overrides; observation as the policy needs). Writes
``results_<name>.json`` and ``results_<name>.md``.

``--phases 0,20,100`` also splits the share of all pairs' in-range steps above 0.30 m by step
of the episode (``"by_phase"`` per localizer, with the whole episode's on the same statistic;
per seed; paired by seed like the other figures): the first steps' births are every motion's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import paired_differences, paired_table, score
from swarm_core.inputs import parse_seeds


def policy_row(
    spec: str,
    base_kwargs: dict[str, Any],
    seeds: list[int],
    localizers: list[str],
    metric: str,
    phases: list[int] | None = None,
) -> dict[str, Any]:
    """Return, task metric and localization metrics of one policy (see the module doc); with
    ``phases``, also each localizer's % of pair-steps above 0.30 m per phase of the episode
    (``"by_phase"``, and per seed)."""
    from agents.policies import model_env_kwargs
    from swarm_phd.evaluate import evaluate_localization

    model = model_env_kwargs(spec)  # a .zip model's or a .pt student's own env, else None
    if model is not None:
        kwargs = model
    else:
        kwargs = {k: v for k, v in base_kwargs.items() if k not in ("observation", "localize")}
    scored = score(spec, kwargs, seeds)
    n_steps = int(kwargs.get("max_steps", 300))
    eval_kwargs = {k: v for k, v in kwargs.items() if k not in ("preset", "task")}
    if model is None:
        eval_kwargs.pop("max_steps", None)
    loc = evaluate_localization(
        kwargs["preset"],
        n_steps * scored["control_period_s"],
        localizers,
        seeds,
        policy=spec,
        task=kwargs["task"],
        phases=phases,
        **({} if model is not None else eval_kwargs),
    )
    values = [d[metric] for d in scored["per_seed"]]
    returns = [d["episode_return"] for d in scored["per_seed"]]
    row = {
        "policy": spec,
        "episode_return": [float(np.mean(returns)), float(np.std(returns))],
        metric: [float(np.mean(values)), float(np.std(values))],
        # The same rollouts scored twice: the evaluator's task metric must agree.
        f"{metric}_evaluate": loc["task"].get(metric),
        "per_seed": scored["per_seed"],
        "localizers": {},
    }
    for name in localizers:
        m = loc["localizers"][name]
        row["localizers"][name] = {
            "gospa_m": m["gospa"]["mean_m"],
            "pct_above_0.30m": m["pooled_per_observer"]["median"],
            "per_seed": m["per_seed"],
            # With phases, the whole episode on their statistic: all pairs' steps pooled.
            **(
                {
                    "by_phase": {
                        "pct_pair_steps_err_gt_30cm": m["pct_pair_steps_err_gt_30cm"],
                        **m["by_phase"],
                    }
                }
                if "by_phase" in m
                else {}
            ),
        }
    return row


#: The per-seed localization figures that :func:`paired_localization` pairs, with the row
#: figure each one is the per-seed version of.
PAIRED_FIGURES = {
    "gospa_m": "gospa_mean_m",
    "pct_above_0.30m": "pooled_per_observer_median_pct",
}


def paired_localization(
    rows: list[dict[str, Any]], localizers: list[str], seeds: list[int], metric: str
) -> dict[str, list[dict[str, Any]]]:
    """Every policy against every earlier one, paired by held-out seed
    (:func:`agents.evaluation.paired_differences`): the task ``metric`` (key ``metric``) and
    each localizer's per-seed GOSPA and % of pair-steps above 0.30 m (the median observer's,
    per seed; keys ``"<localizer> <figure>"``), and with phases the % of all pairs' steps
    above 0.30 m per phase (``"<localizer> pct_pair_steps_err_gt_30cm@<lo>-<hi>"``)."""
    specs = [r["policy"] for r in rows]
    task = {r["policy"]: {"seeds": seeds, "per_seed": r["per_seed"]} for r in rows}
    out = {metric: paired_differences(task, {}, specs, metric)}
    for name in localizers:
        by_phase = rows[0]["localizers"][name].get("by_phase", {})
        figures = {**PAIRED_FIGURES, **{key: key for key in by_phase}}
        for figure, per_seed_key in figures.items():
            policies = {
                r["policy"]: {
                    "seeds": [d["seed"] for d in r["localizers"][name]["per_seed"]],
                    "per_seed": [
                        {figure: d[per_seed_key]} for d in r["localizers"][name]["per_seed"]
                    ],
                }
                for r in rows
            }
            for spec, p in policies.items():
                if p["seeds"] != seeds:
                    raise ValueError(
                        f"{spec}: localization scored on seeds {p['seeds']}, not {seeds}"
                    )
                missing = [
                    seed
                    for seed, d in zip(seeds, p["per_seed"], strict=True)
                    if not np.isfinite(d[figure])
                ]
                if missing:  # nothing in range on a seed: a mean over seeds would be NaN
                    raise ValueError(f"{spec}: no {name} {figure} on seeds {missing}")
            out[f"{name} {figure}"] = paired_differences(policies, {}, specs, figure)
    return out


def markdown(rows: list[dict[str, Any]], metric: str, localizers: list[str]) -> str:
    head = ["policy", "return / agent", metric]
    for name in localizers:
        head += [f"{name} GOSPA (m)", f"{name} % > 0.30 m"]
        head += [
            f"{name} % of pairs > 0.30 m, steps {key.split('@')[1] if '@' in key else 'all'}"
            for key in _phases(rows, name)
        ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            r["policy"],
            f"{r['episode_return'][0]:.1f} ± {r['episode_return'][1]:.1f}",
            f"{r[metric][0]:.3f} ± {r[metric][1]:.3f}",
        ]
        for name in localizers:
            m = r["localizers"][name]
            cells += [f"{m['gospa_m']:.3f}", f"{m['pct_above_0.30m']:.1f}"]
            cells += [f"{m['by_phase'][key]:.2f}" for key in _phases(rows, name)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _phases(rows: list[dict[str, Any]], name: str) -> list[str]:
    return list(rows[0]["localizers"][name].get("by_phase", {}))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--policies", nargs="+", required=True, help="model.zip, student.pt or scripted:*"
    )
    parser.add_argument("--seeds", default="100-109")
    parser.add_argument("--localizers", default="phd-lc", help="comma-separated")
    parser.add_argument("--metric", default="formation_error_m")
    parser.add_argument("--out", default="runs/report")
    parser.add_argument("--name", default="ablation")
    parser.add_argument(
        "--phases",
        default=None,
        help="comma-separated first steps (e.g. 0,20,100): also the %% of pair-steps above "
        "0.30 m per phase of the episode, paired by seed",
    )
    args = parser.parse_args(argv)
    phases = None
    if args.phases is not None:
        from experiments.recurrent_student import parse_phases

        phases = parse_phases(parser, args.phases)
    from agents.policies import model_env_kwargs

    models = [p for p in args.policies if p.endswith((".zip", ".pt"))]
    if not models:
        raise ValueError(
            "--policies needs at least one model.zip or student.pt (its env is the table's env)"
        )
    base = model_env_kwargs(models[0])
    episode_steps = base.get("max_steps", 300)
    if phases is not None and phases[-1] >= episode_steps:
        parser.error(
            f"--phases {args.phases}: the episodes of {models[0]!r} last {episode_steps} "
            "steps, so its last phase would be empty"
        )
    seeds = parse_seeds(args.seeds)
    localizers = [s.strip() for s in args.localizers.split(",") if s.strip()]
    rows = []
    for spec in args.policies:
        rows.append(policy_row(spec, base, seeds, localizers, args.metric, phases))
        r = rows[-1]
        for name in localizers:  # an interrupted evaluation scores fewer seeds: stop now
            scored = [d["seed"] for d in r["localizers"][name]["per_seed"]]
            if scored != seeds:
                raise ValueError(f"{spec}: {name} scored on seeds {scored}, not {seeds}")
        headline = {
            name: {k: v for k, v in m.items() if k != "per_seed"}
            for name, m in r["localizers"].items()
        }  # the per-seed figures go to the JSON only
        print(spec, r["episode_return"], r[args.metric], headline, flush=True)
    paired = paired_localization(rows, localizers, seeds, args.metric)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"results_{args.name}.json").write_text(
        json.dumps({"seeds": seeds, "env_kwargs": base, "rows": rows, "paired": paired}, indent=2)
    )
    table = markdown(rows, args.metric, localizers)
    for key, pairs in paired.items():
        table += f"\n{key}, paired by seed:\n\n" + paired_table(pairs, key.split()[-1])
    (out / f"results_{args.name}.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
