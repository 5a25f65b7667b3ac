"""Our GM-PHD (``localization.RobotCentricPHD``) against Stone Soup's GM-PHD, side by side.

Both filters run in one process on identical data with matched models:

* a static sensor at the origin; 5 / 19 / 50 targets move in a 6 m x 6 m arena centred on it
  (random-walk velocity, |v| <= 0.3 m/s, bouncing off the walls);
* 300 scans at 7 Hz; every target within 2 m is detected with P_d = 0.9 and noise
  R = 0.0025 I; Poisson clutter, mean 2 per scan, uniform over the 2 m disc;
* both filters: random-walk motion (Q = 0.04^2 I per scan), constant P_s = 0.99, constant
  P_d = 0.9, one birth component per scan (mean 0, cov 1.5^2 I, weight 0.05), clutter
  intensity 2 / (pi 2^2), prune 1e-4, merge at squared Mahalanobis 4, cap 64, extraction of
  components with weight >= 0.5 (the same extraction rule is applied to both mixtures).

Reported per filter: median wall time per scan (predict + update + reduce), mean GOSPA
(c = 1, p = 2, alpha = 2) between the targets and the estimates inside the 2 m disc, its split
(mean localisation part, mean missed and false targets per scan), the cardinality error
(mean |number of estimates - number of targets| inside the disc) and the speed-up. Two extra
rows show our filter with its range-aware detection model (P_d = 0.9 inside 2 m, 0 outside)
and with measurement-driven births instead of the fixed birth.

The Poisson multi-Bernoulli filter (:mod:`localization.pmb`, issue 12) runs on the same data
with the same models (``PMBConfig(phd=<the matched PHDConfig>)``, PMB defaults for the rest):
its estimates are the tracks with existence ``r >= 0.5`` inside the disc (one target each).
Its cost is given for the numpy reference (``RobotCentricPMB``, against ``RobotCentricPHD``)
and for the compiled engines (``PMBBank`` against ``PHDBank``, one robot, one ``apply`` per
scan: what the env runs).

Known differences that remain (Stone Soup's design, not ours): its hypothesiser gates
pairs beyond Mahalanobis distance 5 (a pair at 5 sigma carries < 4e-6 of the weight; we set
the gate that wide so it changes nothing measurable), its birth component has no
missed-detection copy, its merge caps merged weights at 1 and its pruning/truncation
redistribute the removed weight over the survivors.

Usage::

    python benchmarks/bench_phd_vs_stonesoup.py [--quick] [--calls] [--env SECONDS] [--json PATH]

``--quick`` runs 60 scans and skips the 50-target case (a smoke test, ~10 s). ``--calls``
also times single calls of the Perera 2021-configured filter (``PHDConfig.perera2021()``,
all detection factors on) from recorded states with ~20 components and 5 measurements: the
env's hot path.
``--env SECONDS`` replays that many seconds of the env's own filter calls (seed-sim, 20 robots)
through ``PHDBank`` and ``PMBBank`` and reports the cost per env step.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from localization import PHDBank, PHDConfig, RobotCentricPHD  # noqa: E402
from localization.metrics import gospa  # noqa: E402
from localization.pmb import PMBBank, PMBConfig, RobotCentricPMB  # noqa: E402
from tests.localization.scenario import walk_start, walk_step  # noqa: E402

RATE_HZ = 7.0
ARENA_HALF_M = 3.0
SENSOR_RANGE_M = 2.0
PD = 0.9
NOISE_STD_M = 0.05
CLUTTER_MEAN = 2.0
CLUTTER_DENSITY = CLUTTER_MEAN / (math.pi * SENSOR_RANGE_M**2)
Q_STD_M = 0.04
PS = 0.99
BIRTH_WEIGHT = 0.05
BIRTH_STD_M = 1.5
PRUNE = 1e-4
MERGE = 4.0
CAP = 64
EXTRACT = 0.5
GATE_MAHALANOBIS = 5.0


@dataclass
class Scenario:
    truth: list[np.ndarray]  # per scan, (K, 2) targets inside the sensor disc
    scans: list[np.ndarray]  # per scan, (M, 2) detections (targets + clutter)


def make_scenario(n_targets: int, n_scans: int, seed: int) -> Scenario:
    """Deterministic targets and measurements (one generator per scenario)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / RATE_HZ
    pos, vel = walk_start(rng, n_targets, ARENA_HALF_M)
    truth, scans = [], []
    for _ in range(n_scans):
        walk_step(pos, vel, rng, dt, ARENA_HALF_M, accel_std_mps=0.1)
        inside = np.hypot(pos[:, 0], pos[:, 1]) <= SENSOR_RANGE_M
        detected = inside & (rng.random(n_targets) < PD)
        z = pos[detected] + rng.normal(0.0, NOISE_STD_M, size=(int(detected.sum()), 2))
        n_clutter = rng.poisson(CLUTTER_MEAN)
        r = SENSOR_RANGE_M * np.sqrt(rng.random(n_clutter))
        a = rng.uniform(-math.pi, math.pi, n_clutter)
        clutter = np.stack((r * np.cos(a), r * np.sin(a)), axis=1)
        scan = np.concatenate((z, clutter))
        scans.append(scan[rng.permutation(scan.shape[0])])
        truth.append(pos[inside].copy())
    return Scenario(truth, scans)


def extract(weights: np.ndarray, means: np.ndarray) -> np.ndarray:
    """Vo & Ma extraction (weight >= 0.5, round(w) copies), applied to both filters.

    Only estimates inside the sensor disc are kept: the truth is the set of targets inside
    it, and a filter that remembers a target which just left the disc is not wrong.
    """
    keep = (weights >= EXTRACT) & (np.hypot(means[:, 0], means[:, 1]) <= SENSOR_RANGE_M)
    counts = np.maximum(np.floor(weights[keep] + 0.5), 1).astype(int)
    return np.repeat(means[keep], counts, axis=0)


def our_config(pd_range_m: float = 1000.0, birth: str = "fixed") -> PHDConfig:
    """The matched model; ``pd_range_m`` (m) cuts P_d to 0 beyond it (default: the largest
    range the config accepts, far beyond every target: no cut)."""
    return PHDConfig.perera2021().replace(
        mode="lidar-only",
        prediction={
            "process_noise_std_m": Q_STD_M,
            "survival_model": "constant",
            "survival_probability": PS,
        },
        births={
            "model": birth,
            "weight": BIRTH_WEIGHT,
            "std_m": BIRTH_STD_M,
            "measurement_weight": BIRTH_WEIGHT,
        },
        lidar={
            "noise_std_m": NOISE_STD_M,
            "pd_model": "constant",
            "detection_probability": PD,
            "range_m": pd_range_m,
            "clutter_intensity": CLUTTER_DENSITY,
        },
        reduction={"prune_threshold": PRUNE, "merge_threshold": MERGE, "max_components": CAP},
    )


def extract_tracks(r: np.ndarray, means: np.ndarray) -> np.ndarray:
    """PMB extraction: tracks with ``r >= 0.5`` inside the sensor disc, one target each."""
    keep = (r >= EXTRACT) & (np.hypot(means[:, 0], means[:, 1]) <= SENSOR_RANGE_M)
    return means[keep]


def run_filter(scenario: Scenario, f, extractor) -> tuple[list[float], list]:
    """Wall time per scan (s) of ``f``'s predict + lidar update, and the scored error of the
    targets ``extractor(mixture.weights, mixture.means)`` extracts after each scan."""
    still = np.zeros(3)
    times, errors = [], []
    for scan, truth in zip(scenario.scans, scenario.truth, strict=True):
        t0 = time.perf_counter()
        f.predict(still)
        f.update_lidar(scan)
        times.append(time.perf_counter() - t0)
        mix = f.mixture
        errors.append(scored(truth, extractor(mix.weights, mix.means)))
    return times, errors


def run_ours(scenario: Scenario, config: PHDConfig) -> tuple[list[float], list]:
    return run_filter(scenario, RobotCentricPHD(config), extract)


def run_pmb(scenario: Scenario, config: PMBConfig) -> tuple[list[float], list]:
    return run_filter(scenario, RobotCentricPMB(config), extract_tracks)


def run_banks(scenario: Scenario, banks: list[PHDBank | PMBBank]) -> list[list[float]]:
    """Wall time per scan of compiled banks of one robot (one ``apply`` per scan each).

    The banks take turns on every scan, so a load change on the shared machine hits them alike.
    """
    still = np.zeros(3)
    for bank in banks:  # compile / load, then start from the empty prior
        bank.apply([[("predict", still), ("lidar", scenario.scans[0], None)]])
        bank.reset()
    times: list[list[float]] = [[] for _ in banks]
    for scan in scenario.scans:
        calls = [[("predict", still), ("lidar", scan, None)]]
        for bank, t in zip(banks, times, strict=True):
            t0 = time.perf_counter()
            bank.apply(calls)
            t.append(time.perf_counter() - t0)
    return times


def scored(truth: np.ndarray, estimates: np.ndarray) -> tuple[float, float, int, int, int]:
    """GOSPA (c = 1, p = 2, alpha = 2): distance, localisation part, missed, false, and the
    cardinality error ``|#estimates - #truth|``."""
    g = gospa(truth, estimates, c=1.0, p=2, alpha=2)
    return (
        g.distance,
        g.localisation,
        g.missed,
        g.false,
        abs(estimates.shape[0] - truth.shape[0]),
    )


def run_stonesoup(scenario: Scenario) -> tuple[list[float], list[float]]:
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        RandomWalk,
    )
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    dt = 1.0 / RATE_HZ
    q = Q_STD_M**2 / dt  # RandomWalk: Q = q * dt per axis
    transition = CombinedLinearGaussianTransitionModel([RandomWalk(q), RandomWalk(q)])
    measurement = LinearGaussian(
        ndim_state=2, mapping=(0, 1), noise_covar=np.eye(2) * NOISE_STD_M**2
    )
    kalman_updater = KalmanUpdater(measurement)
    hypothesiser = GaussianMixtureHypothesiser(
        DistanceHypothesiser(
            KalmanPredictor(transition),
            kalman_updater,
            Mahalanobis(),
            missed_distance=GATE_MAHALANOBIS,
        ),
        order_by_detection=True,
    )
    updater = PHDUpdater(
        kalman_updater,
        clutter_spatial_density=CLUTTER_DENSITY,
        prob_detection=PD,
        prob_survival=PS,
    )
    reducer = GaussianMixtureReducer(
        prune_threshold=PRUNE, merge_threshold=MERGE, max_number_components=CAP
    )
    start = datetime.datetime(2024, 1, 1)
    birth = TaggedWeightedGaussianState(
        state_vector=[[0.0], [0.0]],
        covar=np.eye(2) * BIRTH_STD_M**2,
        weight=BIRTH_WEIGHT,
        tag=TaggedWeightedGaussianState.BIRTH,
        timestamp=start,
    )
    components: list = []
    times, errors = [], []
    for k, (scan, truth) in enumerate(zip(scenario.scans, scenario.truth, strict=True)):
        stamp = start + datetime.timedelta(seconds=k * dt)
        detections = {
            Detection(z.reshape(2, 1), timestamp=stamp, measurement_model=measurement)
            for z in scan
        }
        t0 = time.perf_counter()
        birth.timestamp = stamp
        current = [*components, birth]
        hypotheses = hypothesiser.hypothesise(current, detections, stamp, order_by_detection=True)
        updated = updater.update(hypotheses)
        components = list(reducer.reduce(updated))
        times.append(time.perf_counter() - t0)
        if components:
            weights = np.array([float(c.weight) for c in components])
            means = np.array([np.asarray(c.state_vector, dtype=float).ravel() for c in components])
        else:
            weights, means = np.empty(0), np.empty((0, 2))
        errors.append(scored(truth, extract(weights, means)))
    return times, errors


def _recorded_states(n_states: int = 40, seed: int = 1) -> list[tuple]:
    """Seed-configured filters caught mid-run with ~20 components, plus 5 detections/bearings.

    A static observer among 24 teammates in a 6 m x 6 m square around it; the filter runs on
    model-consistent lidar and camera data, and states holding 17-23 components are recorded,
    each paired with 5 lidar detections and 5 bearings of the nearest teammates.
    """
    import copy

    rng = np.random.default_rng(seed)
    f = RobotCentricPHD(PHDConfig.perera2021())
    n_mates = 24
    pos = rng.uniform(-3.0, 3.0, size=(n_mates, 2))
    out = []
    for k in range(2000):
        pos += rng.normal(0.0, 0.02, size=pos.shape)
        r = np.hypot(pos[:, 0], pos[:, 1])
        f.predict(np.array([0.0, 0.0, 0.0]))
        det = rng.random(n_mates) < 1.0 / (1.02 + np.exp(8.0 * (r - 1.5)))
        f.update_lidar(pos[det] + rng.normal(0.0, 0.05, size=(int(det.sum()), 2)))
        cam = (rng.random(n_mates) < 0.9) & (r < 4.0)
        f.update_camera(np.arctan2(pos[cam, 1], pos[cam, 0]) + rng.normal(0, 0.08, cam.sum()))
        if k >= 50 and k % 5 == 0 and 17 <= len(f) <= 23:
            near = np.argsort(r)[:5]
            points = pos[near] + rng.normal(0.0, 0.05, size=(5, 2))
            bearings = np.arctan2(pos[near, 1], pos[near, 0]) + rng.normal(0, 0.08, 5)
            out.append((copy.deepcopy(f), points, bearings))
        if len(out) >= n_states:
            break
    return out


def per_call_timings(repeats: int = 30) -> dict:
    """Minimum-of-``repeats`` wall time (us) of single calls, median over recorded states."""
    import copy
    import timeit

    states = _recorded_states()
    ref = min(timeit.repeat(lambda: np.multiply(np.ones(20), 2.0), number=2000, repeat=5))
    result = {"reference_ufunc_us": ref / 2000 * 1e6, "states": len(states)}
    odo = np.array([0.02, 0.0, 0.01])
    calls = {
        "predict": lambda g, p, b: g.predict(odo),
        "update_lidar": lambda g, p, b: g.update_lidar(p),
        "update_camera": lambda g, p, b: g.update_camera(b),
    }
    for name, call in calls.items():
        per_state = []
        for f, points, bearings in states:
            best = math.inf
            for _ in range(repeats):
                g = copy.copy(f)
                t0 = time.perf_counter()
                call(g, points, bearings)
                best = min(best, time.perf_counter() - t0)
            per_state.append(best * 1e6)
        result[name + "_us"] = float(np.median(per_state))
    result["components"] = float(np.median([len(f) for f, _, _ in states]))
    return result


def row(name: str, n: int, times: list[float], errors: list) -> dict:
    # (scans, 5): see scored(); no errors (timing-only rows): NaN
    e = np.asarray(errors, dtype=float) if errors else np.full((1, 5), np.nan)
    return {
        "filter": name,
        "targets": n,
        "median_ms_per_scan": 1e3 * float(np.median(times)),
        "mean_gospa": float(e[:, 0].mean()),
        "mean_localisation": float(e[:, 1].mean()),
        "mean_missed": float(e[:, 2].mean()),
        "mean_false": float(e[:, 3].mean()),
        "cardinality_error": float(e[:, 4].mean()),
    }


def env_stream_costs(duration_s: float, seed: int = 0) -> dict:
    """Cost per env step of ``PHDBank`` and ``PMBBank`` (``SIMULATOR_PHD`` models, 20 robots)
    on the env's own call stream (``bench_bank.record_calls``: seed-sim, random actions), and
    the largest bank-vs-reference difference of the PMB over the first 20 steps."""
    from bench_bank import record_calls

    from swarm_env.config import SIMULATOR_PHD

    steps, _ = record_calls("seed-sim", duration_s, seed)
    n_robots = len(steps[0])
    pmb_cfg = PMBConfig(phd=SIMULATOR_PHD)
    banks = {"PHDBank": PHDBank(SIMULATOR_PHD, n_robots), "PMBBank": PMBBank(pmb_cfg, n_robots)}
    refs = [RobotCentricPMB(pmb_cfg) for _ in range(n_robots)]
    times: dict[str, list[float]] = {name: [] for name in banks}
    worst = 0.0
    for k, calls in enumerate(steps):
        for name, bank in banks.items():
            t0 = time.perf_counter()
            bank.apply(calls)
            times[name].append(time.perf_counter() - t0)
        if k < 20:
            for f, seq in zip(refs, calls, strict=True):
                for c in seq:
                    if c[0] == "predict":
                        f.predict(c[1])
                    elif c[0] == "lidar":
                        f.update_lidar(c[1], c[2], sensor_pose=c[3] if len(c) > 3 else None)
                    else:
                        f.update_camera(c[1], sensor_pose=c[2] if len(c) > 2 else None)
            for r, f in enumerate(refs):
                a, b = f.table, banks["PMBBank"].table(r)
                worst = max(
                    worst, math.inf if a.shape != b.shape else np.abs(a - b).max(initial=0)
                )
    out = {f"{name}_ms_per_step": 1e3 * float(np.median(t[5:])) for name, t in times.items()}
    out["steps"] = len(steps)
    out["calls_per_step"] = sum(len(c) for s in steps for c in s) / len(steps)
    out["pmb_bank_vs_reference_max_abs_diff"] = worst
    out["pmb_tracks_per_robot_final"] = banks["PMBBank"].counts.tolist()
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="60 scans, 5 and 19 targets")
    parser.add_argument("--json", type=Path, help="write the results as JSON to this path")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--calls", action="store_true", help="also time single filter calls (seed config)"
    )
    parser.add_argument(
        "--env",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="also time PHDBank and PMBBank on SECONDS of the env's own call stream",
    )
    args = parser.parse_args(argv)
    n_scans = 60 if args.quick else 300
    cases = (5, 19) if args.quick else (5, 19, 50)
    results = []
    print(
        "GOSPA: c = 1 m, p = 2, alpha = 2, inside the 2 m disc; missed / false: mean targets per "
        "scan; card. err: mean |#estimates - #targets|\n\n"
        "| targets | filter | median ms/scan | mean GOSPA | localisation | missed | false | "
        "card. err | speed-up |\n|---:|---|---:|---:|---:|---:|---:|---:|---:|"
    )
    for n in cases:
        scenario = make_scenario(n, n_scans, seed=args.seed + n)
        ss = row("stonesoup GM-PHD", n, *run_stonesoup(scenario))
        ours = row("ours (matched)", n, *run_ours(scenario, our_config()))
        ours_range = row("ours, P_d=0 beyond 2 m", n, *run_ours(scenario, our_config(2.0)))
        ours_meas = row(
            "ours, measurement births", n, *run_ours(scenario, our_config(2.0, "measurement"))
        )
        pmb = row("PMB (matched)", n, *run_pmb(scenario, PMBConfig(phd=our_config())))
        pmb_meas = row(
            "PMB, measurement births",
            n,
            *run_pmb(scenario, PMBConfig(phd=our_config(2.0, "measurement"))),
        )
        phd_times, pmb_times = run_banks(
            scenario, [PHDBank(our_config(), 1), PMBBank(PMBConfig(phd=our_config()), 1)]
        )
        phd_bank = row("ours (matched), PHDBank", n, phd_times, [])
        pmb_bank = row("PMB (matched), PMBBank", n, pmb_times, [])
        for r in (ss, ours, ours_range, ours_meas, pmb, pmb_meas, phd_bank, pmb_bank):
            r["speedup_vs_stonesoup"] = ss["median_ms_per_scan"] / r["median_ms_per_scan"]
            results.append(r)
            if math.isnan(r["mean_gospa"]):
                quality = "| (same as the reference) | | | | "
            else:
                quality = (
                    f"| {r['mean_gospa']:.3f} | {r['mean_localisation']:.3f} | "
                    f"{r['mean_missed']:.2f} | {r['mean_false']:.2f} | "
                    f"{r['cardinality_error']:.2f} "
                )
            print(
                f"| {n} | {r['filter']} | {r['median_ms_per_scan']:.3f} {quality}"
                f"| {r['speedup_vs_stonesoup']:.0f}x |"
            )
        print(
            f"| {n} | PMB vs Stone Soup GM-PHD: mean GOSPA "
            f"{100 * (pmb['mean_gospa'] / ss['mean_gospa'] - 1):+.1f} % | | | | | | | |"
        )
    calls = None
    if args.calls:
        calls = per_call_timings()
        print(
            f"\nPer call (seed config, ~{calls['components']:.0f} components, 5 measurements, "
            f"min of 30 single calls, median over {calls['states']} states; a 20-element "
            f"numpy multiply took {calls['reference_ufunc_us']:.2f} us on this run):\n"
            f"| call | us |\n|---|---:|\n"
            f"| predict | {calls['predict_us']:.1f} |\n"
            f"| update_lidar (+ reduce) | {calls['update_lidar_us']:.1f} |\n"
            f"| update_camera (+ reduce) | {calls['update_camera_us']:.1f} |"
        )
    env = None
    if args.env > 0:
        env = env_stream_costs(args.env, args.seed)
        print(
            f"\nEnv call stream (seed-sim, {env['steps']} steps, "
            f"{env['calls_per_step']:.0f} calls per step, 20 robots, SIMULATOR_PHD), median ms "
            f"per step: PHDBank {env['PHDBank_ms_per_step']:.2f}, "
            f"PMBBank {env['PMBBank_ms_per_step']:.2f}; PMB bank vs reference (first 20 "
            f"steps): max |diff| {env['pmb_bank_vs_reference_max_abs_diff']:.1e}"
        )
    if args.json:
        payload = {
            "scans": n_scans,
            "seed": args.seed,
            "python": platform.python_version(),
            "numpy": np.__version__,
            "machine": platform.machine(),
            "results": results,
            "per_call": calls,
            "env_stream": env,
        }
        args.json.write_text(json.dumps(payload, indent=2))
    return results


if __name__ == "__main__":
    main()
