"""Seed 004's encirclement under each intruder source: enclosing error and escape figures.

Runs ``scripted:encirclement`` on ``task="encirclement"`` (moving intruder, ``path="circle"``)
with ``intruder_source`` = ``beacon`` (ground-truth ablation), ``particle`` (seed 004's particle
filter on sparse range-bearing readings) and ``estimate`` (the robot's own PHD estimate after one
cue at reset), on the same seeds, and writes ``encirclement_sources.json`` and
``encirclement_sources.png`` to ``--out``::

    python benchmarks/encirclement_sources.py --preset lab-3m-4 --duration 120 --seeds 0,1,2 \\
        --out docs/figures

Per run the task's metrics (:meth:`swarm_env.tasks.encirclement.EncirclementTask.metrics`):
``radius_error_m`` (mean over steps of the agents' mean |d_i - r|, the enclosing error),
``enclosed_fraction``, ``escape_fraction`` (share of the steps after the first enclosure with the
intruder outside the agents' hull) and ``escapes_per_min``; for ``particle`` and ``estimate``
also where the controller's intruder estimate lay (within 0.3 m of the intruder, of a teammate,
elsewhere, or none), scored against the ground truth.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

SOURCES = ("beacon", "particle", "estimate")
KEYS = ("radius_error_m", "enclosed_fraction", "escape_fraction", "escapes_per_min")


def run_source(
    source: str, preset: str, duration_s: float, seed: int, task_params: dict[str, Any]
) -> dict[str, float]:
    from agents.policies import load_policy
    from swarm_env import parallel_env

    env = parallel_env(
        preset, task="encirclement", task_params={**task_params, "intruder_source": source}
    )
    act = load_policy("scripted:encirclement", env)
    act.reset(seed)
    obs, infos = env.reset(seed=seed)
    counts = np.zeros(4)  # controller's intruder estimate: on it, on a teammate, elsewhere, none
    for _ in range(int(round(duration_s / env.config.control_period_s))):
        if not env.agents:
            break
        obs, _, _, _, infos = env.step(act(obs, infos))
        if source != "beacon":
            counts += track_outcomes(act, env)
    metrics = env.task.metrics()
    if source != "beacon":
        share = counts / max(counts.sum(), 1.0)
        metrics.update(
            track_on_intruder=share[0],
            track_on_teammate=share[1],
            track_elsewhere=share[2],
            track_none=share[3],
        )
    env.close()
    return metrics


def track_outcomes(act: Any, env: Any, gate_m: float = 0.3) -> np.ndarray:
    """Counts over the agents of where the controller's intruder estimate lies in the world:
    within ``gate_m`` of the true intruder, else of a teammate, else elsewhere, or no estimate
    (ground truth used for scoring only)."""
    truth = env.last_world_step.truth
    out = np.zeros(4)
    for i, agent in enumerate(env.possible_agents):
        q = act.intruder_estimate(agent)
        if q is None:
            out[3] += 1
            continue
        x, y, psi = truth.poses[i]
        c, s = np.cos(psi), np.sin(psi)
        w = np.array([x + c * q[0] - s * q[1], y + s * q[0] + c * q[1]])
        if np.hypot(*(w - truth.extra_xy[0])) < gate_m:
            out[0] += 1
        elif np.min(np.hypot(*(truth.poses[:, :2] - w).T)) < gate_m:
            out[1] += 1
        else:
            out[2] += 1
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="lab-3m-4")
    parser.add_argument("--duration", type=float, default=120.0, help="simulated seconds")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--sources", default=",".join(SOURCES))
    parser.add_argument("--task-params", default="{}", help="JSON dict, e.g. reading_dropout")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    sources = [s.strip() for s in args.sources.split(",") if s.strip()]
    bad = [s for s in sources if s not in SOURCES]
    if bad or not seeds:
        raise ValueError(f"--sources must name some of {SOURCES} and --seeds some integers")
    task_params = json.loads(args.task_params)
    start = time.perf_counter()
    runs = {
        s: [run_source(s, args.preset, args.duration, seed, task_params) for seed in seeds]
        for s in sources
    }
    track_keys = ("track_on_intruder", "track_on_teammate", "track_elsewhere", "track_none")
    summary = {
        s: {
            k: {"mean": float(np.mean([r[k] for r in rs])), "per_seed": [r[k] for r in rs]}
            for k in KEYS + (track_keys if s != "beacon" else ())
        }
        for s, rs in runs.items()
    }
    result = {
        "config": {
            "preset": args.preset,
            "duration_s": args.duration,
            "seeds": seeds,
            "task_params": task_params,
            "policy": "scripted:encirclement",
        },
        "sources": summary,
        "wall_time_s": time.perf_counter() - start,
    }
    print(f"encirclement, {args.preset}, {args.duration:.0f} s x {len(seeds)} seeds")
    print(
        "| source | enclosing error (m) | enclosed % | escape % after first enclosure "
        "| escapes / min | intruder estimate on it / on a teammate / none |"
    )
    print("|---|---|---|---|---|---|")
    for s in sources:
        m = summary[s]
        track = (
            "n/a (ground truth)"
            if s == "beacon"
            else " / ".join(
                f"{100 * m[k]['mean']:.0f} %"
                for k in ("track_on_intruder", "track_on_teammate", "track_none")
            )
        )
        print(
            f"| {s} | {m['radius_error_m']['mean']:.3f} | "
            f"{100 * m['enclosed_fraction']['mean']:.1f} | "
            f"{100 * m['escape_fraction']['mean']:.1f} | {m['escapes_per_min']['mean']:.2f} "
            f"| {track} |"
        )
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump(result, fh, indent=2)
        os.replace(tmp, out / "encirclement_sources.json")
        write_figure(out / "encirclement_sources.png", result)
    return 0


def write_figure(path: Path, result: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    sources = list(result["sources"])
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.4))
    panels = (
        ("radius_error_m", 1.0, "enclosing error (m)"),
        ("enclosed_fraction", 100.0, "time enclosed (%)"),
        ("escape_fraction", 100.0, "not enclosed after first\nenclosure (%)"),
    )
    for ax, (key, scale, label) in zip(axes, panels, strict=True):
        for k, s in enumerate(sources):
            vals = scale * np.asarray(result["sources"][s][key]["per_seed"])
            ax.bar(k, vals.mean(), color=f"C{k}", alpha=0.7)
            ax.plot(np.full(len(vals), k), vals, "k.", ms=4)
        ax.set_xticks(range(len(sources)), sources)
        ax.set_ylabel(label)
    cfg = result["config"]
    fig.suptitle(
        f"Encirclement by intruder source: {cfg['preset']}, {cfg['duration_s']:.0f} s, "
        f"seeds {cfg['seeds']} (bars: mean, dots: seeds)",
        fontsize=9,
    )
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp.png")
    os.close(fd)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


if __name__ == "__main__":
    raise SystemExit(main())
