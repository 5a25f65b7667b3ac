"""Issue 13's throughput goal, measured side by side: the issue's code and command against HEAD.

Issue 13 measured PPO training at 440 agent transitions/s with the code of commit ``d6a6df1``
(``lab-3m-4`` formation on PHD observations, 4 copies through SuperSuit in 2 worker
processes) and asked for at least 3x. This machine's speed drifts by 10 % within hours, so
the old code runs here too, alternated with HEAD: each round runs the old command, then
HEAD's once per ``--copies`` value, and every HEAD run is compared with its round's old run.

Every run is a real ``train`` command stopped by its wall-time budget
(``--max-wall-minutes``); both codes time from just before PPO's ``learn`` (the env and its
workers already built) to the end. Two rates per run, from its ``train_summary.json``:

- ``rate``: ``timesteps / wall_time_s``. The budget stops a run at the first env step past it,
  so the last rollout may be partial, counted but never paid for by its PPO update: this
  favours large rollouts (HEAD's 32 copies collect 16384 transitions per update, the old
  code 2048);
- ``whole_rollouts_rate``: only the whole rollouts counted, over the same wall time: a lower
  bound, since the partial rollout's env time stays in the wall. **The verdict uses it for
  HEAD and ``rate`` for the old code**, the conservative reading.

The old code runs from a git worktree at ``--old-commit`` (created, or pruned and recreated,
if missing) with this venv's Python and ``PYTHONPATH`` at the worktree; it keeps its default
progress bar (as the issue ran it), HEAD runs with ``--no-progress-bar``. Both sides first run
one short untimed training (the old code has no numba kernels to compile, but its imports and
files are then warm; HEAD loads or compiles its kernels). Nothing else should run meanwhile:
with the default 2 rounds of 3 runs it takes about 20 minutes.

    .venv/bin/python benchmarks/bench_vs_issue13.py [--rounds 2] [--copies 32,64]
        [--minutes 2.5] [--out runs/bench/vs_issue13] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from swarm_core.atomic_files import write_json_atomically

ROOT = Path(__file__).resolve().parents[1]
TASK_PARAMS = '{"progress_weight": 10}'
#: PPO's n_steps and the robots per copy (``lab-3m-4``), the same in both codes.
N_STEPS, ROBOTS = 128, 4
OLD_COPIES = 4


def old_command(out: Path, timesteps: int, minutes: float | None) -> list[str]:
    """The issue's command, run from the old worktree (its CLI lived in ``swarm_env.cli``)."""
    cmd = [sys.executable, "-m", "swarm_env.cli", "train", "--task", "formation"]
    cmd += ["--task-params", TASK_PARAMS, "--observation", "phd", "--timesteps", str(timesteps)]
    cmd += ["--out", str(out), "--n-copies", str(OLD_COPIES), "--num-cpus", "2"]
    cmd += ["--checkpoint-every", "100000"]
    return cmd + (["--max-wall-minutes", str(minutes)] if minutes is not None else [])


def head_command(out: Path, copies: int, timesteps: int, minutes: float | None) -> list[str]:
    """The same training at HEAD: ``copies`` batched copies in 2 worker processes."""
    cmd = [sys.executable, "-m", "swarm_phd.cli", "train", "--preset", "lab-3m-4"]
    cmd += ["--task", "formation", "--task-params", TASK_PARAMS, "--observation", "phd"]
    cmd += ["--timesteps", str(timesteps), "--out", str(out), "--n-copies", str(copies)]
    cmd += ["--num-cpus", "2", "--checkpoint-every", "100000", "--no-progress-bar"]
    return cmd + (["--max-wall-minutes", str(minutes)] if minutes is not None else [])


def run(cmd: list[str], cwd: Path, out: Path, copies: int) -> dict[str, float]:
    """Run one training into a fresh ``out``; its two rates (agent transitions/s)."""
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = out.parent / f"{out.name}.log"
    env = dict(os.environ)
    if cwd != ROOT:  # the old code: its packages, not this checkout's editable install
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(cwd), env.get("PYTHONPATH")]))
    with open(log_path, "w") as log:
        code = subprocess.run(
            cmd, cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT
        ).returncode
    if code != 0:
        tail = log_path.read_text().splitlines()[-15:]
        raise RuntimeError(
            f"exit code {code} from {' '.join(cmd)}; log {log_path}:\n" + "\n".join(tail)
        )
    summary = json.loads((out / "train_summary.json").read_text())
    timesteps, wall = summary["timesteps"], summary["wall_time_s"]
    rollout = N_STEPS * copies * ROBOTS
    return {
        "timesteps": timesteps,
        "wall_s": wall,
        "rate": timesteps / wall,
        "whole_rollouts_rate": timesteps // rollout * rollout / wall,
    }


def ensure_worktree(path: Path, commit: str) -> None:
    """A detached worktree of ``commit`` at ``path``: reused if it holds that commit."""
    git = ["git", "-C", str(ROOT)]
    wanted = subprocess.run(
        [*git, "rev-parse", f"{commit}^{{commit}}"], capture_output=True, text=True, check=True
    ).stdout.strip()
    if path.is_dir():
        head = subprocess.run(
            ["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        if head != wanted:
            raise SystemExit(f"--worktree {path} holds {head or 'no checkout'}, not {commit}")
        return
    subprocess.run([*git, "worktree", "prune"], check=True)  # a registered path /tmp lost
    subprocess.run([*git, "worktree", "add", "--detach", str(path), wanted], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--copies", default="32,64", help="HEAD's --n-copies, comma list")
    parser.add_argument("--minutes", type=float, default=2.5, help="each run's budget")
    parser.add_argument("--old-commit", default="d6a6df1")
    parser.add_argument(
        "--worktree",
        type=Path,
        default=None,
        help="the old code's git worktree (default: swarm-phd-<commit> in the temp directory, "
        "outside this checkout, so linters and pytest skip it)",
    )
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "bench" / "vs_issue13")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    try:
        copies = [int(c) for c in args.copies.split(",")]
    except ValueError:
        parser.error(f"--copies must be a comma list of integers, got {args.copies!r}")
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    if min(copies) < 2:
        parser.error(f"every --copies must be >= 2 (2 workers), got {args.copies!r}")
    if not args.minutes > 0:
        parser.error(f"--minutes must be > 0, got {args.minutes}")
    out = args.out.resolve()
    worktree = args.worktree or Path(tempfile.gettempdir()) / f"swarm-phd-{args.old_commit}"
    worktree = worktree.resolve()
    ensure_worktree(worktree, args.old_commit)

    # Untimed: each side's first training (kernels, imports, files), one rollout each.
    run(old_command(out / "warm_old", 2048, None), worktree, out / "warm_old", OLD_COPIES)
    run(head_command(out / "warm_head", 2, 1024, None), ROOT, out / "warm_head", 2)

    rounds = []
    for r in range(1, args.rounds + 1):
        started = time.strftime("%H:%M UTC", time.gmtime())
        old_out = out / f"old_{r}"
        old = run(old_command(old_out, 3_000_000, args.minutes), worktree, old_out, OLD_COPIES)
        row = {"round": r, "started": started, "old": old, "head": {}}
        for k in copies:
            run_out = out / f"head{k}_{r}"
            row["head"][k] = run(
                head_command(run_out, k, 3_000_000, args.minutes), ROOT, run_out, k
            )
        rounds.append(row)
        if args.json:  # after every round: a later failure keeps what ran
            write_json_atomically(args.json, {"old_commit": args.old_commit, "rounds": rounds})
        print(
            f"round {r} ({started}): old {old['rate']:.0f}/s; "
            + ", ".join(
                f"{k} copies {v['rate']:.0f}/s (whole rollouts {v['whole_rollouts_rate']:.0f}/s, "
                f"{v['whole_rollouts_rate'] / old['rate']:.2f}x)"
                for k, v in row["head"].items()
            )
        )

    print("\nagent transitions/s; HEAD: whole rollouts only (all counted), ratio to the old run")
    print("| run | " + " | ".join(f"round {row['round']}" for row in rounds) + " |")
    print("|---|" + "---:|" * len(rounds))
    cells = [f"{row['old']['rate']:.0f}" for row in rounds]
    print(f"| `{args.old_commit}`, {OLD_COPIES} copies, SuperSuit, 2 workers | ", end="")
    print(" | ".join(cells) + " |")
    for k in copies:
        cells = []
        for row in rounds:
            head, old = row["head"][k], row["old"]["rate"]
            lower = head["whole_rollouts_rate"]
            cells.append(f"{lower:.0f} ({head['rate']:.0f}): {lower / old:.2f}x")
        print(f"| HEAD, {k} copies, 2 workers | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
