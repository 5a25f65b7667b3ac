"""Issue 13's throughput goal, measured side by side: the issue's code and command against HEAD.

Issue 13 measured PPO training at 440 agent transitions/s with the code of commit ``d6a6df1``
(``lab-3m-4`` formation on PHD observations, 4 copies through SuperSuit in 2 worker
processes) and asked for at least 3x. This machine's speed drifts by 10 % within hours, so
the old code runs here too, alternated with HEAD round by round, and each HEAD run is
compared with the old run just before it.

Every run is a real ``train`` command stopped by its wall-time budget
(``--max-wall-minutes``), and its rate is ``timesteps / wall_time_s`` from its
``train_summary.json`` (start-up and checkpoint writes included, for both). The old code runs
from a git worktree at ``--old-commit`` (created if missing) with this venv's Python; both
sides first run a few hundred steps untimed, so neither pays for compiling its numba kernels
inside its budget. Nothing else should run meanwhile: with the default 2 rounds of 3 runs it
takes about 20 minutes.

    .venv/bin/python benchmarks/bench_vs_issue13.py [--rounds 2] [--copies 32,64]
        [--minutes 2.5] [--out runs/bench/vs_issue13] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from swarm_core.atomic_files import write_json_atomically

ROOT = Path(__file__).resolve().parents[1]
TASK_PARAMS = '{"progress_weight": 10}'


def old_command(out: Path, timesteps: int, minutes: float | None) -> list[str]:
    """The issue's command, run from the old worktree (its CLI lived in ``swarm_env.cli``)."""
    cmd = [sys.executable, "-m", "swarm_env.cli", "train", "--task", "formation"]
    cmd += ["--task-params", TASK_PARAMS, "--observation", "phd", "--timesteps", str(timesteps)]
    cmd += ["--out", str(out), "--n-copies", "4", "--num-cpus", "2"]
    cmd += ["--checkpoint-every", "100000"]
    return cmd + (["--max-wall-minutes", str(minutes)] if minutes else [])


def head_command(out: Path, copies: int, timesteps: int, minutes: float | None) -> list[str]:
    """The same training at HEAD: ``copies`` batched copies in 2 worker processes."""
    cmd = [sys.executable, "-m", "swarm_phd.cli", "train", "--preset", "lab-3m-4"]
    cmd += ["--task", "formation", "--task-params", TASK_PARAMS, "--observation", "phd"]
    cmd += ["--timesteps", str(timesteps), "--out", str(out), "--n-copies", str(copies)]
    cmd += ["--num-cpus", "2", "--checkpoint-every", "100000", "--no-progress-bar"]
    return cmd + (["--max-wall-minutes", str(minutes)] if minutes else [])


def run(cmd: list[str], cwd: Path, out: Path) -> float:
    """Run one training (a fresh ``out``); its agent transitions/s."""
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f"{out.name}.log", "w") as log:
        subprocess.run(cmd, cwd=cwd, stdout=log, stderr=subprocess.STDOUT, check=True)
    summary = json.loads((out / "train_summary.json").read_text())
    return summary["timesteps"] / summary["wall_time_s"]


def ensure_worktree(path: Path, commit: str) -> None:
    if not (path / "swarm_env" / "cli.py").is_file():
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), commit], check=True
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--copies", default="32,64", help="HEAD's --n-copies, comma list")
    parser.add_argument("--minutes", type=float, default=2.5, help="each run's budget")
    parser.add_argument("--old-commit", default="d6a6df1")
    parser.add_argument(
        "--worktree",
        type=Path,
        default=Path(tempfile.gettempdir()) / "swarm-phd-d6a6df1",
        help="the old code's git worktree (outside this checkout: linters and pytest skip it)",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "bench" / "vs_issue13")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    copies = [int(c) for c in args.copies.split(",")]
    if args.rounds < 1 or not copies or min(copies) < 2:
        parser.error("--rounds must be >= 1 and every --copies >= 2 (2 workers)")
    out = args.out.resolve()
    worktree = args.worktree.resolve()
    ensure_worktree(worktree, args.old_commit)

    # Untimed: compile or load each side's kernels and start its workers once.
    run(old_command(out / "warm_old", 2048, None), worktree, out / "warm_old")
    run(head_command(out / "warm_head", 2, 2048, None), ROOT, out / "warm_head")

    rounds = []
    for r in range(1, args.rounds + 1):
        started = time.strftime("%H:%M UTC", time.gmtime())
        old_out = out / f"old_{r}"
        old = run(old_command(old_out, 3_000_000, args.minutes), worktree, old_out)
        row = {"round": r, "started": started, "old": old, "head": {}}
        for k in copies:
            run_out = out / f"head{k}_{r}"
            row["head"][k] = run(head_command(run_out, k, 3_000_000, args.minutes), ROOT, run_out)
        rounds.append(row)
        print(
            f"round {r} ({started}): old {old:.0f}/s; "
            + ", ".join(f"{k} copies {v:.0f}/s ({v / old:.2f}x)" for k, v in row["head"].items())
        )

    print("\n| run | " + " | ".join(f"round {row['round']}" for row in rounds) + " |")
    print("|---|" + "---:|" * len(rounds))
    print(f"| `{args.old_commit}`, 4 copies, SuperSuit, 2 workers | ", end="")
    print(" | ".join(f"{row['old']:.0f}" for row in rounds) + " |")
    for k in copies:
        cells = [f"{row['head'][k]:.0f} ({row['head'][k] / row['old']:.2f}x)" for row in rounds]
        print(f"| HEAD, {k} copies, 2 workers | " + " | ".join(cells) + " |")
    if args.json:
        write_json_atomically(args.json, {"old_commit": args.old_commit, "rounds": rounds})


if __name__ == "__main__":
    main()
