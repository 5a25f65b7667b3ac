"""Package a recipe's run as a shipped policy: ``pretrained:NAME`` (:mod:`agents.pretrained`).

    python tools/ship_pretrained.py runs/recipe_formation formation

Copies the run's final policy (``ppo/student.pt``, or ``ppo/model.zip``'s weights and metadata
without its optimizer state or pickled objects, with the run's ``train_config.json`` and
``env_kwargs.json``, so it loads weights only) into
``agents/pretrained/NAME/`` and writes ``card.json`` from the run's ``recipe.json`` and
``final_evaluation.json``: the recipe and its command, the commit, the training and held-out
seeds, the held-out scores, the paired rows against the baselines and the goal (at least as
good as the task's best scripted controller, the first baseline, on the task metric: "met" when
the paired mean difference is not in the controller's favour, "tie" when it is but within 2
SE, "missed" beyond). ``--note`` adds what limits a policy that
misses it. The results page's table of shipped policies is generated from the cards
(``python experiments/results_page.py``).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def goal(paired: list[dict], metric: str, baseline: str) -> dict:
    """The paired row of ``metric`` against ``baseline`` and whether the goal is met."""
    row = next(r for r in paired if r["metric"] == metric and r["baseline"] == baseline)
    from agents.evaluation import higher_is_better

    # met: at least as good in the mean; tie: worse in the mean but within 2 SE; missed.
    better_sign = 1.0 if higher_is_better(metric) else -1.0
    if row["verdict"].startswith("worse"):
        status = "missed"
    elif better_sign * row["mean_difference"] >= 0:
        status = "met"
    else:
        status = "tie"
    return {
        "baseline": baseline,
        "metric": metric,
        "policy_mean": row["policy_mean"],
        "baseline_mean": row["baseline_mean"],
        "mean_difference": row["mean_difference"],
        "standard_error": row["standard_error"],
        "seeds_better": row["seeds_better"],
        "n_seeds": row["n_seeds"],
        "verdict": row["verdict"],
        "status": status,
        "met": status == "met",
    }


#: The members of an SB3 zip the weights-only loader reads (:mod:`agents.sb3.safe_load`); the
#: optimizer's state and the pickled ``data`` are left out of a shipped policy.
KEPT_MEMBERS = ("policy.pth", "swarm_phd.json", "_stable_baselines3_version", "system_info.txt")


def _weights_only_zip(src: Path, dest: Path) -> None:
    import zipfile

    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zout:
        for member in KEPT_MEMBERS:
            if member in zin.namelist():
                # a fixed date: the same weights make the same bytes (no churn in git)
                info = zipfile.ZipInfo(member, date_time=(1980, 1, 1, 0, 0, 0))
                zout.writestr(info, zin.read(member), zipfile.ZIP_DEFLATED)


def ship(run: Path, name: str, note: str | None = None) -> Path:
    recipe = json.loads((run / "recipe.json").read_text())
    report = json.loads((run / "final_evaluation.json").read_text())
    policy = run / recipe["policy"]
    dest = ROOT / "agents" / "pretrained" / name
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    if policy.suffix == ".zip":
        _weights_only_zip(policy, dest / policy.name)
    else:
        shutil.copyfile(policy, dest / policy.name)
    if policy.suffix == ".zip":
        for extra in ("train_config.json", "env_kwargs.json"):
            shutil.copyfile(policy.parent / extra, dest / extra)
    baselines = list(report["scores"])[1:]
    card = {
        "name": name,
        "task": recipe["task"],
        "recipe": recipe["recipe"],
        "summary": recipe["summary"],
        "command": f"swarm-phd train --recipe {recipe['recipe']} --seed {recipe['seed']} "
        f"--eval-seeds {len(report['seeds'])} --out runs/recipe_{recipe['recipe']}",
        "policy": policy.name,
        "commit": recipe["commit"],
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip()
        + f", Python {platform.python_version()}",
        "env_kwargs": recipe["env_kwargs"],
        "stages": recipe["stages"],
        "training_wall_s": recipe["wall_s"],
        "held_out_seeds": recipe["held_out_seeds"],
        "held_out": {spec: s["mean"] for spec, s in report["scores"].items()},
        "held_out_per_seed": report["scores"][next(iter(report["scores"]))]["per_seed"],
        "paired": report["paired"],
        "goal": goal(report["paired"], report["metric"], baselines[0]),
        "note": note,
    }
    (dest / "card.json").write_text(json.dumps(card, indent=1) + "\n")
    write_result_file()
    return dest


def _fmt(value: float) -> str:
    return f"{value:.3f}" if abs(value) < 10 else f"{value:.1f}"


def write_result_file() -> Path:
    """``experiments/results/pretrained.json``, the results page's row of the shipped
    policies, from every ``card.json``."""
    import datetime

    from agents.pretrained import card, names

    cards = [card(n) for n in names()]
    rows = []
    for c in cards:
        g = c["goal"]
        se = g["standard_error"]
        rows.append(
            [
                f"`pretrained:{c['name']}`",
                c["summary"].split(" (")[0],
                g["metric"],
                _fmt(g["policy_mean"]),
                f"{_fmt(g['baseline_mean'])} (`{g['baseline']}`)",
                _fmt(c["held_out"]["random"][g["metric"]]),
                f"{g['mean_difference']:+.4f} (SE {se:.4f}; {g['seeds_better']} of "
                f"{g['n_seeds']} seeds better)",
                f"{g['status']}: {g['verdict']}",
            ]
        )
    met = [c["name"] for c in cards if c["goal"]["status"] == "met"]
    tied = [c["name"] for c in cards if c["goal"]["status"] == "tie"]
    missed = [c["name"] for c in cards if c["goal"]["status"] == "missed"]
    notes = [
        "`lab-3m-4`, 4 robots, 300 steps (30 s), the default observation (each robot's own "
        "GM-PHD estimate); held-out seeds no stage trained or validated on, paired by seed; "
        "goal: at least as good as the task's best scripted controller (met: the paired mean "
        "difference is not in the controller's favour; tie: it is, within 2 SE; missed: "
        "beyond 2 SE).",
    ]
    notes += [f"`pretrained:{c['name']}`: {c['note']}" for c in cards if c.get("note")]
    result = {
        "section": "Learning",
        "order": 0,
        "question": "Do the shipped trained policies do their task at least as well as the "
        "best scripted controller, on held-out seeds?",
        "headline": ", ".join(
            f"{c['name']} {_fmt(c['goal']['policy_mean'])} vs {_fmt(c['goal']['baseline_mean'])}"
            for c in cards
        ),
        "verdict": (f"met by {', '.join(met)}" if met else "met by none")
        + (f"; tied within 2 SE (worse in the mean) by {', '.join(tied)}" if tied else "")
        + (f"; missed by {', '.join(missed)}" if missed else ""),
        "table": {
            "columns": [
                "policy",
                "recipe",
                "metric",
                "learned",
                "best scripted",
                "random",
                "learned - scripted",
                "goal",
            ],
            "rows": rows,
        },
        "notes": notes,
        "command": "swarm-phd train --recipe NAME --eval-seeds 50 --out runs/recipe_NAME; "
        "python tools/ship_pretrained.py runs/recipe_NAME NAME",
        "commit": sorted({c["commit"].split("+")[0] for c in cards})[0],
        "date": datetime.date.today().isoformat(),
        "machine": "the project's 2-core x86_64 VM (24 GiB, no GPU), one thread",
        "source": "agents/pretrained/*/card.json (the recipes' final_evaluation.json)",
    }
    path = ROOT / "experiments" / "results" / "pretrained.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a recipe's --out directory")
    parser.add_argument("name", help="the shipped name: pretrained:NAME")
    parser.add_argument("--note", default=None, help="what limits the policy, if it misses")
    args = parser.parse_args(argv)
    print(ship(args.run, args.name, args.note))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
