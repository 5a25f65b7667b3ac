"""The encirclement task (Lee 2012) under each intruder source, scripted and learned: enclosing
error, time enclosed and escape figures.

Question: does a learned policy encircle a moving intruder as well as the scripted controller,
and how much does each way of sensing the intruder cost? Its result is
``experiments/results/encirclement.json`` (the results page) and the figure
``docs/figures/encirclement_sources.png``.

Runs each policy (``--policies``: ``scripted:encirclement`` and/or trained SB3 ``model.zip``
files) on ``task="encirclement"`` (moving intruder, ``path="circle"``) under each intruder
setting (``--sources``), on the same seeds, and writes ``encirclement_sources.json`` and
``encirclement_sources.png`` to ``--out``::

    python -m experiments.encirclement_sources --preset lab-3m-4 --duration 120 \
        --seeds 0,1,2 --out docs/figures
    python -m experiments.encirclement_sources --duration 120 --seeds 100-109 \
        --policies scripted:encirclement,runs/encirclement/model.zip \
        --sources beacon,particle,particle+filter,estimate --out runs/encirclement/eval

Settings: ``beacon`` (ground-truth ablation, a reading every step), ``particle`` (the source
study's sparse range-bearing readings; the scripted controller runs its own particle filter on
them, a learned policy sees the raw readings), ``particle+filter`` (the same readings, filtered
by the task's particle filter: the features are its estimate, what a learned policy trained on
``intruder_features="filter"`` observes) and ``estimate`` (one reading at reset, then the
robot's own PHD estimate; a learned policy sees that one reading only); ``particle-range`` and
``particle-range+filter`` are the two particle settings with range-only readings
(``intruder_sensing="range"``: same rate, loss and range noise, no bearing).

``--particle-starts uniform,trilateration`` runs every setting once per particle-filter start
(``particle_start``: the Lee 2012 study's uniform cloud, or the triangulation / trilateration fix
of :mod:`localization.baselines.particle`); the results are then keyed ``SETTING/START``::

    python -m experiments.encirclement_sources --duration 120 --seeds 100-104 \
        --sources particle,particle-range --particle-starts uniform,trilateration

Per run the task's metrics (:meth:`swarm_env.tasks.encirclement.EncirclementTask.metrics`):
``radius_error_m`` (mean over steps of the agents' mean |d_i - r|, the enclosing error),
``enclosed_fraction`` (time enclosed), ``escape_fraction`` (share of the steps after the first
enclosure with the intruder outside the agents' hull) and ``escapes_per_min``; mean and std
over the seeds. Where a controller keeps an explicit intruder estimate (the scripted one under
``particle`` / ``estimate``, the task's filter under ``particle+filter``) also where it lay
(within 0.3 m of the intruder, of a teammate, elsewhere, or none), scored on the ground truth.
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

from swarm_core.atomic_files import write_json_atomically
from swarm_core.inputs import parse_seeds

SOURCES = (
    "beacon",
    "particle",
    "particle+filter",
    "estimate",
    "particle-range",
    "particle-range+filter",
)
KEYS = ("radius_error_m", "enclosed_fraction", "escape_fraction", "escapes_per_min")
TRACK_KEYS = ("track_on_intruder", "track_on_teammate", "track_elsewhere", "track_none")


def setting_params(setting: str) -> dict[str, Any]:
    """Task parameters of a ``--sources`` entry (``"particle+filter"``: the task's filter)."""
    if setting not in SOURCES:
        raise ValueError(f"unknown intruder setting {setting!r}; choose from {SOURCES}")
    params: dict[str, Any] = {"intruder_source": setting.split("-")[0].split("+")[0]}
    if setting.endswith("+filter"):
        params["intruder_features"] = "filter"
    if setting.startswith("particle-range"):
        params["intruder_sensing"] = "range"
    return params


def run_source(
    source: str,
    preset: str,
    duration_s: float,
    seed: int,
    task_params: dict[str, Any],
    policy: str = "scripted:encirclement",
) -> dict[str, float]:
    """One episode of ``policy`` under intruder setting ``source``; the task's metrics."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    env = parallel_env(
        preset, task="encirclement", task_params={**task_params, **setting_params(source)}
    )
    act = load_policy(policy, env)
    act.reset(seed)
    obs, infos = env.reset(seed=seed)
    counts = np.zeros(4)  # controller's intruder estimate: on it, on a teammate, elsewhere, none
    tracked = False
    for _ in range(int(round(duration_s / env.config.control_period_s))):
        if not env.agents:
            break
        obs, _, _, _, infos = env.step(act(obs, infos))
        estimates = intruder_estimates(act, env)
        if estimates is not None:
            tracked = True
            counts += track_outcomes(estimates, env)
    metrics = env.task.metrics()
    if tracked:
        share = counts / max(counts.sum(), 1.0)
        metrics.update(zip(TRACK_KEYS, (float(v) for v in share), strict=True))
    env.close()
    return metrics


def intruder_estimates(act: Any, env: Any) -> list[np.ndarray | None] | None:
    """Each agent's explicit intruder estimate (body frame) or ``None`` per agent; ``None``
    when the controller keeps none (the ground-truth beacon, a learned policy's raw readings)."""
    task = env.task
    if getattr(task, "intruder_features", "reading") == "filter":
        return task.intruder_estimates()
    if task.intruder_source == "beacon" or not hasattr(act, "intruder_estimate"):
        return None
    return [act.intruder_estimate(agent) for agent in env.possible_agents]


def track_outcomes(
    estimates: list[np.ndarray | None], env: Any, gate_m: float = 0.3
) -> np.ndarray:
    """Counts over the agents of where the intruder estimate lies in the world: within
    ``gate_m`` of the true intruder, else of a teammate, else elsewhere, or no estimate
    (ground truth used for scoring only)."""
    truth = env.last_world_step.truth
    out = np.zeros(4)
    for i in range(len(env.possible_agents)):
        q = estimates[i] if i < len(estimates) else None
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


def pm(m: dict[str, Any], key: str, scale: float = 1.0, fmt: str = ".1f") -> str:
    """``mean ± std`` of one summary entry, scaled."""
    return f"{scale * m[key]['mean']:{fmt}} ± {scale * m[key]['std']:{fmt}}"


def policy_label(policy: str) -> str:
    if policy.endswith(".zip"):
        return f"PPO {Path(policy).parent.name}/{Path(policy).stem}"
    return policy


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="lab-3m-4")
    parser.add_argument("--duration", type=float, default=120.0, help="simulated seconds")
    parser.add_argument("--seeds", default="0,1,2", help="e.g. 0,1,2 or 100-109")
    parser.add_argument("--sources", default="beacon,particle,estimate", help=f"of {SOURCES}")
    parser.add_argument(
        "--policies",
        default="scripted:encirclement",
        help="comma-separated: scripted:encirclement and/or trained model.zip paths",
    )
    parser.add_argument("--task-params", default="{}", help="JSON dict, e.g. reading_dropout")
    parser.add_argument(
        "--particle-starts",
        default=None,
        help="comma-separated particle_start values (uniform, trilateration; default: the "
        "--task-params one, else uniform); with more than one, results are keyed SETTING/START",
    )
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    sources = [s.strip() for s in args.sources.split(",") if s.strip()]
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    bad = [s for s in sources if s not in SOURCES]
    if bad or not seeds or not sources:
        raise ValueError(f"--sources must name some of {SOURCES} and --seeds some integers")
    for policy in policies:
        if not (policy.startswith("scripted:") or policy.endswith(".zip")):
            raise ValueError(f"--policies: {policy!r} is neither scripted:NAME nor a .zip model")
        if policy.endswith(".zip") and not Path(policy).is_file():
            raise ValueError(f"--policies: model {policy!r} does not exist")
    task_params = json.loads(args.task_params)
    starts_text = args.particle_starts or task_params.get("particle_start", "uniform")
    starts = [p.strip() for p in starts_text.split(",") if p.strip()]
    if not starts or any(p not in ("uniform", "trilateration") for p in starts):
        raise ValueError(f"--particle-starts must name uniform and/or trilateration, got {starts}")
    if len(starts) > 1:
        runs_of = [(f"{s}/{p}", s, {"particle_start": p}) for s in sources for p in starts]
    else:
        runs_of = [(s, s, {"particle_start": starts[0]}) for s in sources]
    start = time.perf_counter()
    results: dict[str, dict[str, Any]] = {}
    for policy in policies:
        results[policy] = {}
        for key, s, extra in runs_of:
            runs = [
                run_source(s, args.preset, args.duration, seed, {**task_params, **extra}, policy)
                for seed in seeds
            ]
            keys = KEYS + (TRACK_KEYS if all(TRACK_KEYS[0] in r for r in runs) else ())
            results[policy][key] = {
                k: {
                    "mean": float(np.mean([r[k] for r in runs])),
                    "std": float(np.std([r[k] for r in runs])),
                    "per_seed": [float(r[k]) for r in runs],
                }
                for k in keys
            }
    result = {
        "config": {
            "preset": args.preset,
            "duration_s": args.duration,
            "seeds": seeds,
            "task_params": task_params,
            "particle_starts": starts,
            "policies": policies,
        },
        "results": results,
        "wall_time_s": time.perf_counter() - start,
    }
    print(f"encirclement, {args.preset}, {args.duration:.0f} s x {len(seeds)} seeds (mean ± std)")
    print(
        "| policy | intruder setting | enclosing error (m) | time enclosed (%) | not enclosed "
        "after first enclosure (%) | escapes / min | intruder estimate on it / on a teammate "
        "/ none |"
    )
    print("|---|---|---|---|---|---|---|")
    for policy in policies:
        for s in results[policy]:
            m = results[policy][s]
            track = (
                " / ".join(
                    f"{100 * m[k]['mean']:.0f} %"
                    for k in ("track_on_intruder", "track_on_teammate", "track_none")
                )
                if "track_on_intruder" in m
                else "–"
            )

            print(
                f"| {policy_label(policy)} | {s} | {pm(m, 'radius_error_m', fmt='.3f')} | "
                f"{pm(m, 'enclosed_fraction', 100)} | {pm(m, 'escape_fraction', 100)} | "
                f"{pm(m, 'escapes_per_min', fmt='.2f')} | {track} |"
            )
    if args.out:
        out = Path(args.out)
        write_json_atomically(out / "encirclement_sources.json", result)
        write_figure(out / "encirclement_sources.png", result)
    return 0


def write_figure(path: Path, result: dict[str, Any]) -> None:
    """Three panels (enclosing error, time enclosed, not enclosed after the first enclosure):
    one bar group per intruder setting, one bar per policy (mean), dots for the seeds."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    policies = list(result["results"])
    sources = list(result["results"][policies[0]])
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
    panels = (
        ("radius_error_m", 1.0, "enclosing error (m)"),
        ("enclosed_fraction", 100.0, "time enclosed (%)"),
        ("escape_fraction", 100.0, "not enclosed after first\nenclosure (%)"),
    )
    width = 0.8 / len(policies)
    for ax, (key, scale, label) in zip(axes, panels, strict=True):
        for j, policy in enumerate(policies):
            for k, s in enumerate(sources):
                vals = scale * np.asarray(result["results"][policy][s][key]["per_seed"])
                x = k - 0.4 + width * (j + 0.5)
                ax.bar(
                    x,
                    vals.mean(),
                    width=width * 0.9,
                    color=f"C{j}",
                    alpha=0.7,
                    label=policy_label(policy) if k == 0 else None,
                )
                ax.plot(np.full(len(vals), x), vals, "k.", ms=3)
        ax.set_xticks(range(len(sources)), sources, fontsize=8)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    cfg = result["config"]
    seeds = cfg["seeds"]
    fig.suptitle(
        f"Encirclement by intruder source: {cfg['preset']}, {cfg['duration_s']:.0f} s, "
        f"seeds {seeds[0]}-{seeds[-1]} ({len(seeds)}) (bars: mean, dots: seeds)",
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
