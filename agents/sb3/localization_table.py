"""One table of task and localization metrics for several policies, in one process.

    python -m agents.sb3.localization_table --policies runs/a/model.zip runs/b/model.zip \\
        scripted:formation --seeds 100-109 --out docs/results --name ablation

For every policy, on the same held-out seeds (one deterministic episode each, ``max_steps`` of
the first model's env): the per-agent episode return and the task metric, mean ± std over the
seeds (:func:`agents.sb3.report.score`), and the localization metrics of
:func:`swarm_phd.evaluate.evaluate_localization` on the same motion (every robot runs each of
``--localizers`` on the records of that motion): GOSPA (m) and the pooled per-observer share
of pair-steps with error above 0.30 m (median observer). Models run in the env they were
trained in; ``scripted:*`` and ``random`` in the first model's env (its task, task parameters
and overrides; observation as the policy needs). Writes ``results_<name>.json`` and
``results_<name>.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.sb3.report import score
from swarm_phd.sweep import parse_seeds


def policy_row(
    spec: str, base_kwargs: dict[str, Any], seeds: list[int], localizers: list[str], metric: str
) -> dict[str, Any]:
    """Return, task metric and localization metrics of one policy (see the module doc)."""
    from agents.sb3.policy import read_metadata
    from swarm_phd.evaluate import evaluate_localization

    if spec.endswith(".zip"):
        kwargs = dict(read_metadata(spec)["env_kwargs"])
    else:
        kwargs = {k: v for k, v in base_kwargs.items() if k not in ("observation", "localize")}
    scored = score(spec, kwargs, seeds)
    n_steps = int(kwargs.get("max_steps", 300))
    eval_kwargs = {k: v for k, v in kwargs.items() if k not in ("preset", "task")}
    if not spec.endswith(".zip"):
        eval_kwargs.pop("max_steps", None)
    loc = evaluate_localization(
        kwargs["preset"],
        n_steps * scored["control_period_s"],
        localizers,
        seeds,
        policy=spec,
        task=kwargs["task"],
        **({} if spec.endswith(".zip") else eval_kwargs),
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
        }
    return row


def markdown(rows: list[dict[str, Any]], metric: str, localizers: list[str]) -> str:
    head = ["policy", "return / agent", metric]
    for name in localizers:
        head += [f"{name} GOSPA (m)", f"{name} % > 0.30 m"]
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
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--policies", nargs="+", required=True, help="model.zip or scripted:*")
    parser.add_argument("--seeds", default="100-109")
    parser.add_argument("--localizers", default="phd-lc", help="comma-separated")
    parser.add_argument("--metric", default="formation_error_m")
    parser.add_argument("--out", default="docs/results")
    parser.add_argument("--name", default="ablation")
    args = parser.parse_args(argv)
    from agents.sb3.policy import read_metadata

    models = [p for p in args.policies if p.endswith(".zip")]
    if not models:
        raise ValueError("--policies needs at least one model.zip (its env is the table's env)")
    base = dict(read_metadata(models[0])["env_kwargs"])
    seeds = parse_seeds(args.seeds)
    localizers = [s.strip() for s in args.localizers.split(",") if s.strip()]
    rows = []
    for spec in args.policies:
        rows.append(policy_row(spec, base, seeds, localizers, args.metric))
        r = rows[-1]
        print(spec, r["episode_return"], r[args.metric], r["localizers"], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"results_{args.name}.json").write_text(
        json.dumps({"seeds": seeds, "env_kwargs": base, "rows": rows}, indent=2)
    )
    table = markdown(rows, args.metric, localizers)
    (out / f"results_{args.name}.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
