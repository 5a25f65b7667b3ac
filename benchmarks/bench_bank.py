"""PHD cost per env step: the compiled PHDBank against 20 pure-numpy RobotCentricPHD filters.

The workload is the env's own: the ``seed-sim`` preset (20 robots, odometry 10 Hz, lidar 7 Hz,
camera 30 Hz) is run with random actions and every step's per-robot filter calls are recorded
(``localization.feed.localizer_calls``, ~94 calls per 0.1 s step). The first ``--warmup`` seconds
bring the mixtures to their working size; the rest is replayed, step by step, through

* ``PHDBank.apply`` (one compiled call per step, what the env runs), and
* 20 independent ``RobotCentricPHD`` (the numpy reference), one method call per record,

and both end in the same state (checked: the same components, every entry to 1e-9). Reported:
median and mean wall time per env step and per filter call, and the share of real time (0.1 s
per step) the filters take.

    .venv/bin/python benchmarks/bench_bank.py [--duration 40] [--warmup 10] [--json PATH]
        [--phd FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from agents.policies import random_policy
from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.feed import localizer_calls
from localization.registry import run_calls
from swarm_env import parallel_env


def record_calls(preset: str, duration_s: float, seed: int) -> tuple[list, float]:
    """Every step's ``calls[r]`` lists, from a random-action rollout without localization."""
    env = parallel_env(preset, observation="measurements", localize=False)
    policy = random_policy(env, seed)
    obs, infos = env.reset(seed=seed)
    steps = []
    for _ in range(int(round(duration_s / env.config.control_period_s))):
        obs, _, _, _, infos = env.step(policy(obs, infos))
        world = env.last_world_step
        steps.append(
            [
                localizer_calls(world.measurements[a], world.stale.get(a, ()))
                for a in env.possible_agents
            ]
        )
    return steps, env.config.control_period_s


def run_filters(filters: list[RobotCentricPHD], calls: list) -> None:
    """Each robot's calls on its reference filter (:func:`localization.registry.run_calls`)."""
    for f, seq in zip(filters, calls, strict=True):
        run_calls(f, seq)


def _overrides(items: list[str]) -> dict:
    """``["births.camera=ray", "births.camera_weight=0.5"]`` -> the nested dict
    :meth:`PHDConfig.replace` takes (``{"births": {"camera": "ray", ...}}``)."""
    out: dict = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"--phd must be FIELD=VALUE, got {item!r}")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        *path, leaf = name.split(".")
        target = out
        for key in path:
            target = target.setdefault(key, {})
        target[leaf] = value
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="seed-sim")
    parser.add_argument("--duration", type=float, default=40.0, help="simulated seconds")
    parser.add_argument("--warmup", type=float, default=10.0, help="untimed seconds first")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mode", default="lidar-camera")
    parser.add_argument(
        "--config",
        choices=("simulator", "seed"),
        default="simulator",
        help="the simulator presets' PHDConfig() (default) or PHDConfig.perera2021()",
    )
    parser.add_argument(
        "--phd",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="PHDConfig field override, repeatable (e.g. --phd births.camera=ray); VALUE is "
        "parsed as JSON, else taken as a string",
    )
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    steps, period = record_calls(args.preset, args.duration, args.seed)
    n_warm = int(round(args.warmup / period))
    base = PHDConfig() if args.config == "simulator" else PHDConfig.perera2021()
    config = base.replace(mode=args.mode, **_overrides(args.phd))
    n_robots = len(steps[0])
    bank = PHDBank(config, n_robots)
    filters = [RobotCentricPHD(config) for _ in range(n_robots)]
    for calls in steps[:n_warm]:
        bank.apply(calls)
        run_filters(filters, calls)
    timed = steps[n_warm:]
    bank_s, filt_s = [], []
    for calls in timed:
        t0 = time.perf_counter()
        bank.apply(calls)
        t1 = time.perf_counter()
        run_filters(filters, calls)
        t2 = time.perf_counter()
        bank_s.append(t1 - t0)
        filt_s.append(t2 - t1)
    worst = 0.0
    for r, f in enumerate(filters):
        a, b = _canonical(bank.table(r)), _canonical(np.asarray(f.table))
        if a.shape != b.shape:
            raise SystemExit(
                f"robot {r}: {a.shape[1]} components in the bank, {b.shape[1]} in the reference"
            )
        worst = max(worst, float(np.abs(a - b).max(initial=0.0)))
    n_calls = sum(len(seq) for calls in timed for seq in calls) / len(timed)
    comps = float(np.mean(bank.counts))
    rows = {
        "bank": np.array(bank_s),
        "filters": np.array(filt_s),
    }
    print(
        f"bench_bank: {args.preset}, {args.config} config {_overrides(args.phd) or ''}, "
        f"mode {args.mode}, {len(timed)} steps "
        f"timed after "
        f"{n_warm} warm-up, {n_calls:.0f} filter calls/step, {comps:.1f} components/robot, "
        f"{platform.machine()}, {time.strftime('%Y-%m-%d')}"
    )
    print("| engine | ms/step median | ms/step mean | us/call | share of real time |")
    print("|---|---:|---:|---:|---:|")
    out = {"calls_per_step": n_calls, "components_per_robot": comps, "max_weight_diff": worst}
    for name, s in rows.items():
        print(
            f"| {name} | {np.median(s) * 1e3:.3f} | {s.mean() * 1e3:.3f} | "
            f"{s.mean() / n_calls * 1e6:.1f} | {s.mean() / period:.1%} |"
        )
        out[name] = {"ms_per_step_median": np.median(s) * 1e3, "ms_per_step_mean": s.mean() * 1e3}
    speedup = rows["filters"].mean() / rows["bank"].mean()
    print(f"speed-up {speedup:.1f}x; largest table difference between the two: {worst:.1e}")
    out["speedup"] = speedup
    if worst > 1e-9:
        raise SystemExit(f"bank and reference filters disagree by {worst:.2e}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2))


def _canonical(table: np.ndarray) -> np.ndarray:
    """Columns sorted by (w, x, y, ...): two tables holding the same components compare."""
    return table[:, np.lexsort(table[::-1])]


if __name__ == "__main__":
    main()
