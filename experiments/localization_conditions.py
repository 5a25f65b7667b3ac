"""Does the camera help, and does the PMB beat the GM-PHD, under the Perera 2021 study's
conditions and in the simulator's?

    python -m experiments.localization_conditions --presets perera2021,sim-6m-20,lab-3m-4 \\
        --decision-seeds 0 --report-seeds 1,2,3

For each preset, the four localizers ``phd-lc``, ``phd-lo``, ``pmb-lc``, ``pmb-lo`` run on the
same wander motion and the same measurements (every robot its own filter; one process, the
library's :func:`swarm_phd.evaluate.score_seed` per seed, added up by
:func:`swarm_phd.evaluate.assemble`), over the report seeds only. Per localizer: the study's
Fig. 7 statistic (per observer-teammate pair, the % of in-range time, 2 m, with the closest
component of weight > 0.1 farther than 0.30 m: the median over all pairs, the pairs above
25 %, and ``ugv_0``'s teammates above 25 %), mean GOSPA (c = 1 m, p = 2, within 2 m), the %
of pair-steps above 0.30 m by range band (0-1 and 1-2 m for every localizer; 2-3 m for the
camera ones, which the evaluator also scores to the study's 3 m camera range) and by cause
(:class:`localization.metrics.SeedScorer`: ``absent`` no component near, ``displaced`` the
nearest one too far, ``low_weight`` below 0.1, ``not_visible`` out of line of sight), and
the filter's cost per env step (ms, all robots).

On the simulator presets a fifth row, ``pmb-lc (camera rays)``, is the PMB with the teammates
only the camera sees held in its Poisson part (``PHDConfig.births.camera="ray"``:
:data:`CAMERA_FALSE_BLOBS_PER_RAD` and the other constants below, from the measured camera
statistics), on the same motion and measurements. On ``sim-6m-20`` the cost of ``phd-lc``,
``pmb-lc`` and that row is also measured alternated in one run (:func:`alternated_cost`, 30 s
of the first report seed): the cost ratio of the verdicts.

The study's own figures stand beside ours: in its simulation (``perera2021``, ``sim-6m-20``)
4 of ``ugv_0``'s 19 teammates above 25 % with lidar + camera and 9 with lidar only; on its four
real robots (``lab-3m-4``) the error time of the three teammates, lidar + camera / lidar
only, 12.7 / 20.7, 2.6 / 10.9 and 0.2 / 1.0 %.

Writes one results-page file per preset, ``experiments/results/localization_conditions_<preset>
.json`` (``experiments/results/README.md``), with the decision seeds (those looked at while
choosing anything) listed apart from the report seeds, then run ``python
experiments/results_page.py``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm_core.inputs import parse_seeds
from swarm_core.provenance import source_commit

ROOT = Path(__file__).resolve().parent.parent
LOCALIZERS = ("phd-lc", "phd-lo", "pmb-lc", "pmb-lo")
#: Each preset's episode length (s): the study's 300 s for its own conditions, 120 s for the
#: simulator presets.
DURATION_S = {"perera2021": 300.0, "sim-6m-20": 120.0, "lab-3m-4": 120.0}
#: The study's figures (its Fig. 7 for the simulation, its Fig. 24 for the real robots).
STUDY = {
    "perera2021": "ugv_0: 4 of 19 teammates > 25 % (LC), 9 (LO)",
    "sim-6m-20": "ugv_0: 4 of 19 teammates > 25 % (LC), 9 (LO)",
    "lab-3m-4": "teammates' error time 12.7, 2.6, 0.2 % (LC); 20.7, 10.9, 1.0 % (LO)",
}
BANDS_M = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0))

#: The PMB's camera-only teammates in its Poisson part (``PHDConfig.births.camera="ray"``,
#: :class:`localization.pmb.RobotCentricPMB`), every parameter from a measured statistic of
#: the simulated camera (``swarm_env.config``, the notes on ``SIM_CAMERA_CLUTTER_PER_RAD`` and
#: ``SIM_CAMERA_PD_*``, ``benchmarks/bench_detection_curves.py``):
#:
#: * clutter: only the false blobs, 1.29 red-decoy + 0.10 random blobs per frame = 0.22 /rad
#:   (the other 1.00 /rad of ``SIM_CAMERA_CLUTTER_PER_RAD`` are teammates beyond the lidar's
#:   reach, which the Poisson part now holds);
#: * each unexplained bearing's ray carries the measured share of such bearings that are
#:   teammates, 1.00 / 1.22 = 0.82, spread over the camera's reach, 0.3 m to 4.75 m (where the
#:   measured detection curve reaches 0), in proportion to ``r P_d(r)``.
CAMERA_FALSE_BLOBS_PER_RAD = 0.22
CAMERA_UNTRACKED_TEAMMATES_PER_RAD = 1.00
CAMERA_REACH_M = 4.75
CAMERA_RAYS = "pmb-lc (camera rays)"


def camera_rays_phd(phd: Any) -> Any:
    """``phd`` with the PMB's camera-only teammates in its Poisson part (:data:`CAMERA_RAYS`)."""

    return phd.replace(
        births={
            "camera": "ray",
            "camera_weight": CAMERA_UNTRACKED_TEAMMATES_PER_RAD
            / (CAMERA_UNTRACKED_TEAMMATES_PER_RAD + CAMERA_FALSE_BLOBS_PER_RAD),
            "camera_max_range_m": CAMERA_REACH_M,
        },
        camera={"clutter_intensity": CAMERA_FALSE_BLOBS_PER_RAD},
    )


CAUSES = ("absent", "displaced", "low_weight", "not_visible")


def band_pct(by_range: dict[str, Any], lo: float, hi: float) -> float:
    """% of pair-steps above 0.30 m over the scorer's range bins within ``[lo, hi)`` (m),
    from its ``by_range`` block (bins' counts recovered as pct x pair-steps); NaN if none."""
    edges = np.asarray(by_range["edges_m"])
    steps = np.asarray(by_range["pair_steps"], dtype=float)
    pct = np.nan_to_num(np.asarray(by_range["pct_err_gt_30cm"], dtype=float))
    inside = (edges[:-1] >= lo - 1e-9) & (edges[1:] <= hi + 1e-9)
    total = steps[inside].sum()
    return float((pct[inside] * steps[inside]).sum() / total) if total else math.nan


def summarize(name: str, block: dict[str, Any], cost_ms: float) -> dict[str, Any]:
    """The figures of one localizer's :func:`assemble` block that the table shows."""
    fig7 = block["seed_fig7"]
    pairs = np.asarray(fig7["all_observers"]["per_pair"], dtype=float)
    pairs = pairs[np.isfinite(pairs)]
    ugv0 = fig7["observer_ugv_0"]
    per_teammate = np.asarray(ugv0["per_teammate"], dtype=float)
    bands = {f"{lo:g}-{hi:g}": band_pct(block["by_range"], lo, hi) for lo, hi in BANDS_M[:2]}
    camera = block.get("at_camera_range")
    lo, hi = BANDS_M[2]
    bands[f"{lo:g}-{hi:g}"] = band_pct(camera["by_range"], lo, hi) if camera else math.nan
    return {
        "localizer": name,
        "pair_median_pct": float(np.median(pairs)) if pairs.size else math.nan,
        "pairs_above_25": int((pairs > 25.0).sum()),
        "pairs": int(pairs.size),
        "ugv0_above_25": int(ugv0["teammates_above_25pct"]),
        "ugv0_tracked": int(ugv0["tracked_teammates"]),
        "ugv0_per_teammate_pct": [float(v) for v in per_teammate[np.isfinite(per_teammate)]],
        "gospa_m": float(block["gospa"]["mean_m"]),
        "per_seed_gospa_m": [float(s["gospa_mean_m"]) for s in block["per_seed"]],
        "by_range_pct": bands,
        "causes_pct": {c: float(block["large_error_causes_pct_of_pair_steps"][c]) for c in CAUSES},
        "cost_ms_per_step": cost_ms,
    }


def _scored(
    preset: str, seeds: list[int], duration_s: float, names: list[str], **overrides: Any
) -> tuple[dict[str, Any], dict[str, float]]:
    """:func:`assemble`'s localizer blocks of ``names`` on ``seeds`` of ``preset`` (with
    ``overrides`` of its config), and each one's ms per env step."""
    from swarm_env import parallel_env
    from swarm_phd.evaluate import assemble, score_seed

    env = parallel_env(
        preset, task="wander", observation="measurements", localize=False, **overrides
    )
    try:
        n_steps = int(round(duration_s / env.config.control_period_s))
        runs = [
            score_seed(env, "scripted:wander", names, seed, n_steps, first=k == 0)
            for k, seed in enumerate(seeds)
        ]
    finally:
        env.close()
    results = assemble(
        runs,
        preset=preset,
        duration_s=duration_s,
        localizers=names,
        seeds=seeds,
        policy="scripted:wander",
    )
    steps = max(sum(r.steps_run for r in runs), 1)
    cost = {name: 1e3 * sum(r.cost_s[name] for r in runs) / steps for name in names}
    return results["localizers"], cost


def run_preset(
    preset: str, seeds: list[int], duration_s: float, camera_rays: bool = False
) -> dict[str, Any]:
    """The four localizers on ``seeds`` of ``preset`` (see the module doc): per localizer the
    figures of :func:`summarize`. ``camera_rays``: also :data:`CAMERA_RAYS`, the PMB with the
    camera-only teammates in its Poisson part, on the same motion and measurements (the
    filters do not act on the world: same seed, same records)."""
    blocks, cost = _scored(preset, seeds, duration_s, list(LOCALIZERS))
    rows = {name: summarize(name, blocks[name], cost[name]) for name in LOCALIZERS}
    if camera_rays:
        from swarm_env.config import make_config

        phd = camera_rays_phd(make_config(preset).phd)
        blocks, cost = _scored(preset, seeds, duration_s, ["pmb-lc"], phd=phd)
        rows[CAMERA_RAYS] = summarize(CAMERA_RAYS, blocks["pmb-lc"], cost["pmb-lc"])
    return rows


def alternated_cost(
    preset: str, seed: int, duration_s: float, camera_rays: bool = False
) -> dict[str, float]:
    """ms per env step of ``phd-lc`` and ``pmb-lc`` (and :data:`CAMERA_RAYS`) fed the same
    records of one episode, their order rotated every step (so load changes on a shared
    machine fall on each alike): the cost ratio of the issue's goal."""
    import itertools

    from agents.policies import load_policy
    from localization.feed import SwarmFeed
    from localization.registry import make_localizer
    from swarm_env import parallel_env

    env = parallel_env(preset, task="wander", observation="measurements", localize=False)
    try:
        n = len(env.possible_agents)
        phd = env.config.phd
        built = {
            "phd-lc": make_localizer("phd-lc", n, phd, seed),
            "pmb-lc": make_localizer("pmb-lc", n, phd, seed),
        }
        if camera_rays:
            built[CAMERA_RAYS] = make_localizer("pmb-lc", n, camera_rays_phd(phd), seed)
        names = list(built)
        spent = dict.fromkeys(names, 0.0)
        act = load_policy("scripted:wander", env)
        if hasattr(act, "reset"):
            act.reset(seed)
        obs, infos = env.reset(seed=seed)
        steps = int(round(duration_s / env.config.control_period_s))
        for t in range(steps):
            obs, _, _, _, infos = env.step(act(obs, infos))
            feed = SwarmFeed.from_world_step(env.last_world_step, env.possible_agents)
            order = names[t % len(names) :] + names[: t % len(names)]
            for name in itertools.islice(order, len(order)):
                t0 = time.perf_counter()
                built[name].step(feed)
                spent[name] += time.perf_counter() - t0
    finally:
        env.close()
    return {name: 1e3 * spent[name] / max(steps, 1) for name in names}


def _f(value: float, digits: int = 2) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}f}"


def goals(
    preset: str, rows: dict[str, dict[str, Any]], cost_ms: dict[str, float] | None = None
) -> list[str]:
    """The issue's goals for ``preset``, each as met / missed with its numbers; ``cost_ms``:
    :func:`alternated_cost`'s, for the cost ratio (else each row's own)."""
    out = []
    for fam in ("phd", "pmb"):
        lc, lo = rows[f"{fam}-lc"], rows[f"{fam}-lo"]
        if preset == "perera2021":
            ratio = (
                lo["pair_median_pct"] / lc["pair_median_pct"]
                if lc["pair_median_pct"]
                else math.inf
            )
            met = (
                ratio >= 2.0
                and lc["ugv0_above_25"] < 4
                and lo["ugv0_above_25"] > lc["ugv0_above_25"]
            )
            out.append(
                f"{fam}: LO/LC pair-median {_f(ratio)}x (goal >= 2x), ugv_0 above 25 %: LC "
                f"{lc['ugv0_above_25']}, LO {lo['ugv0_above_25']} (goal LC < 4 < LO): "
                f"{'met' if met else 'missed'}"
            )
        else:
            met = lc["gospa_m"] <= lo["gospa_m"] and lc["pair_median_pct"] <= lo["pair_median_pct"]
            out.append(
                f"{fam}: LC vs LO GOSPA {_f(lc['gospa_m'], 3)} vs {_f(lo['gospa_m'], 3)} m, "
                f"pair-median {_f(lc['pair_median_pct'])} vs {_f(lo['pair_median_pct'])} % "
                f"(goal: LC no worse on both): {'met' if met else 'missed'}"
            )
    if CAMERA_RAYS in rows and preset != "perera2021":
        rays, lo = rows[CAMERA_RAYS], rows["pmb-lo"]
        met = rays["gospa_m"] <= lo["gospa_m"] and rays["pair_median_pct"] <= lo["pair_median_pct"]
        out.append(
            f"{CAMERA_RAYS} vs pmb-lo: GOSPA {_f(rays['gospa_m'], 3)} vs "
            f"{_f(lo['gospa_m'], 3)} m, "
            f"pair-median {_f(rays['pair_median_pct'])} vs {_f(lo['pair_median_pct'])} % "
            f"(goal: LC no worse on both): {'met' if met else 'missed'}"
        )
    if preset == "sim-6m-20":
        phd = rows["phd-lc"]
        for name in ("pmb-lc", CAMERA_RAYS):
            if name not in rows:
                continue
            pmb = rows[name]
            gain = 1.0 - pmb["gospa_m"] / phd["gospa_m"]
            alternated = (cost_ms or {}).get(name)
            cost = (
                alternated / cost_ms["phd-lc"]
                if alternated is not None
                else pmb["cost_ms_per_step"] / phd["cost_ms_per_step"]
            )
            met = gain >= 0.15 and pmb["pair_median_pct"] < phd["pair_median_pct"] and cost <= 1.5
            out.append(
                f"{name} vs phd-lc: GOSPA {100 * gain:.1f} % lower (goal >= 15 %), pair-median "
                f"{_f(pmb['pair_median_pct'])} vs {_f(phd['pair_median_pct'])} % (goal: lower), "
                f"cost {_f(cost)}x (goal <= 1.5x): {'met' if met else 'missed'}"
            )
    return out


def result_file(
    preset: str,
    rows: dict[str, dict[str, Any]],
    decision: list[int],
    report: list[int],
    duration_s: float,
    command: str,
    cost_ms: dict[str, float] | None = None,
) -> dict[str, Any]:
    """The results-page file of one preset (``experiments/results/README.md``)."""
    lidar_camera = preset != "lab-3m-4"
    columns = [
        "localizer",
        "median pair % > 0.30 m",
        "pairs > 25 %",
        "ugv_0: teammates > 25 %" if lidar_camera else "ugv_0: teammates' %",
        "GOSPA (m)",
        "% > 0.30 m at 0-1 / 1-2 / 2-3 m",
        "causes: absent / displaced / low weight / not visible (% of pair-steps)",
        "ms per step",
    ]
    table_rows = []
    for name, r in rows.items():
        ugv0 = (
            f"{r['ugv0_above_25']} of {r['ugv0_tracked']}"
            if lidar_camera
            else ", ".join(_f(v, 1) for v in sorted(r["ugv0_per_teammate_pct"], reverse=True))
        )
        table_rows.append(
            [
                name,
                _f(r["pair_median_pct"]),
                f"{r['pairs_above_25']} of {r['pairs']}",
                ugv0,
                _f(r["gospa_m"], 3),
                " / ".join(_f(v, 1) for v in r["by_range_pct"].values()),
                " / ".join(_f(r["causes_pct"][c], 1) for c in CAUSES),
                _f(r["cost_ms_per_step"], 1),
            ]
        )
    verdicts = goals(preset, rows, cost_ms)
    lc, lo = rows["phd-lc"], rows["phd-lo"]
    return {
        "section": "Localization accuracy",
        "order": 1,
        "question": (
            f"`{preset}`: does lidar + camera localize better than lidar only, for the GM-PHD "
            "and the PMB (the Perera 2021 Fig. 7 statistic and GOSPA)?"
        ),
        "headline": (
            f"median pair % > 0.30 m: phd-lc {_f(lc['pair_median_pct'])} vs phd-lo "
            f"{_f(lo['pair_median_pct'])}, pmb-lc {_f(rows['pmb-lc']['pair_median_pct'])} vs "
            f"pmb-lo {_f(rows['pmb-lo']['pair_median_pct'])}; GOSPA phd-lc "
            f"{_f(lc['gospa_m'], 3)} vs phd-lo {_f(lo['gospa_m'], 3)} m; the study: "
            f"{STUDY[preset]}"
        ),
        "verdict": "; ".join(verdicts),
        "table": {"columns": columns, "rows": table_rows},
        "notes": [
            f"`{preset}`, {duration_s:g} s x report seeds {report}, 20 UGVs wandering"
            if lidar_camera
            else f"`{preset}`, {duration_s:g} s x report seeds {report}, 4 UGVs wandering",
            "Every robot its own filter, paired (same motion, same measurements); in range = "
            "2 m (the 2-3 m band: the camera localizers scored to the study's 3 m camera "
            "range; the lidar-only ones are not scored there). Seeds looked at while choosing "
            f"anything: {decision}, not reported.",
        ],
        "command": command,
        "commit": source_commit(mark_dirty=False) or "0000000",
        "date": datetime.date.today().isoformat(),
        "machine": _machine(),
        "source": "this command's output, the file itself (per-localizer figures under `rows`)",
        "seeds": {"decision": decision, "report": report},
        "rows": rows,
        **({"cost_alternated_ms_per_step": cost_ms} if cost_ms else {}),
    }


def _machine() -> str:
    import os

    return (
        f"{os.cpu_count()}-core {platform.machine()}, Python {platform.python_version()}, "
        f"load {os.getloadavg()[0]:.1f} at the end"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", default="perera2021,sim-6m-20,lab-3m-4")
    parser.add_argument(
        "--decision-seeds",
        default="0",
        help="seeds looked at while choosing anything: listed in the files, never reported",
    )
    parser.add_argument("--report-seeds", default="1,2,3", help="the seeds reported")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds per episode for every preset (default: 300 s perera2021, 120 s others)",
    )
    parser.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    args = parser.parse_args(argv)
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    from swarm_phd.presets import known

    known("--presets", presets)
    decision = parse_seeds(args.decision_seeds) if args.decision_seeds.strip() else []
    report = parse_seeds(args.report_seeds)
    overlap = sorted(set(decision) & set(report))
    if overlap:
        raise ValueError(f"--report-seeds {overlap} are also decision seeds: report others")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be > 0 s, got {args.duration!r}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # the code that runs: later commits during the run are not it
    commit = source_commit(mark_dirty=False) or "0000000"
    command = "python -m experiments.localization_conditions " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    for preset in presets:
        duration = args.duration or DURATION_S.get(preset, 120.0)
        t0 = time.perf_counter()
        rays = preset != "perera2021"  # the study's own filter there, as it describes it
        rows = run_preset(preset, report, duration, camera_rays=rays)
        cost = (
            alternated_cost(preset, report[0], min(duration, 30.0), camera_rays=True)
            if preset == "sim-6m-20"
            else None
        )
        data = result_file(preset, rows, decision, report, duration, command.strip(), cost)
        data["commit"] = commit
        path = out / f"localization_conditions_{preset.replace('-', '_')}.json"
        path.write_text(json.dumps(_finite(data), indent=1, allow_nan=False) + "\n")
        print(f"{preset}: {time.perf_counter() - t0:.0f} s -> {path}")
        for line in data["verdict"].split("; "):
            print("  " + line)
    return 0


def _finite(value: Any) -> Any:
    """``value`` with every NaN (nothing scored there) as ``None``: strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


if __name__ == "__main__":
    raise SystemExit(main())
