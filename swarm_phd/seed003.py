"""``swarm-phd seed003``: the IR-UKF study's 5-robot experiment: direct estimation, central UKF.

The simulated swarm (preset ``lab-3m-4`` with 5 robots, in a small obstacle-free arena like the
study's motion-capture floor) carries its IR sensor (:mod:`swarm_env.sensors.ir`:
~1 Hz, <= 1 m, identities, the study's range and bearing noise), simulated from the simulator's
ground truth. The robots stand still for ``--init-s`` seconds; the IR readings of that window
feed the direct estimation (:func:`localization.baselines.direct.direct_estimate`, SLSQP, no
initial state), which initialises the centralized UKF
(:class:`localization.baselines.centralized_ukf.CentralizedUKF`). Then the robots wander at the
study's speed (3 cm/s cruise) and the UKF runs on every robot's wheel odometry and the IR
readings. For comparison (as in the study), the direct estimation is also rerun on each second's
readings, warm-started from its previous solution.

Errors are reported as the study does: after the Kabsch fit (rotation + translation, det +1) of
the estimated positions onto the true ones, position RMSE (m) over the robots and heading RMSE
(deg, wrapped) at every step; ``metrics.json`` holds their time means per seed and overall.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from localization.baselines.centralized_ukf import CentralizedUKF, CentralizedUKFConfig
from localization.baselines.direct import align_poses, direct_estimate, pose_errors
from swarm_core import inputs
from swarm_core.atomic_files import atomic_write, write_json_atomically
from swarm_core.inputs import parse_json_object, parse_seeds
from swarm_core.validation import check_number
from swarm_env.sensors.ir import IRConfig, IRReadings, IRSensor

#: The IR-UKF study's reported accuracy: "about 10 cm, or on the order of the size of a robot".
SEED_ACCURACY_M = 0.10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        default=None,
        help="env preset for the robots and sensors (default: lab-3m-4, the lab-scale one)",
    )
    parser.add_argument("--n-robots", type=int, default=5, help="the IR-UKF study ran 5")
    parser.add_argument(
        "--arena-m", type=float, default=1.5, help="side of the square, obstacle-free arena (m)"
    )
    inputs.add_duration_argument(parser, 60.0)
    parser.add_argument(
        "--init-s",
        type=float,
        default=3.0,
        help="standstill at the start; its readings feed "
        "the direct estimation that initialises the UKF (s)",
    )
    parser.add_argument(
        "--speed", type=float, default=0.05, help="max speed (m/s); wander cruises at 0.6 of it"
    )
    parser.add_argument(
        "--seeds", default="0,1,2,3,4", help="comma-separated integers or ranges (0-4)"
    )
    parser.add_argument("--ir-params", default=None, help="JSON dict of IRConfig overrides")
    parser.add_argument(
        "--ukf-params", default=None, help="JSON dict of CentralizedUKFConfig overrides"
    )
    parser.add_argument(
        "--out", default=None, help="write metrics.json and seed003_error.png here"
    )


def run(args: argparse.Namespace) -> int:
    seeds = parse_seeds(str(args.seeds))
    inputs.duration("--duration", args.duration)
    inputs.integer("--n-robots", args.n_robots, minimum=2)
    check_number("--arena-m", args.arena_m, low=0, above=True)
    check_number("--init-s", args.init_s, low=0, high=args.duration, above=True)
    if args.init_s == args.duration:  # the run would end standing still: nothing to score
        raise ValueError(f"--init-s must be below --duration ({args.duration}), got {args.init_s}")
    check_number("--speed", args.speed, low=0, above=True)
    if args.out:
        inputs.output_dir("--out", args.out)
    ir_params = parse_json_object(args.ir_params, "--ir-params")
    if "outlier_offset_m" in ir_params:
        ir_params["outlier_offset_m"] = tuple(ir_params["outlier_offset_m"])
    try:
        ir = IRConfig(**ir_params)
        ukf = CentralizedUKFConfig(**parse_json_object(args.ukf_params, "--ukf-params"))
    except TypeError as exc:  # an unknown field name
        raise ValueError(f"--ir-params / --ukf-params: {exc}") from exc
    results = run_seed003(
        preset=args.preset or "lab-3m-4",
        n_robots=args.n_robots,
        arena_m=args.arena_m,
        duration_s=args.duration,
        init_s=args.init_s,
        speed_mps=args.speed,
        seeds=seeds,
        ir=ir,
        ukf=ukf,
        out_dir=Path(args.out) if args.out else None,
    )
    print_summary(results)
    return 0


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Odometry increments (N, 3) ``a`` then ``b`` (each in the body frame at its start)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    out = a.copy()
    out[:, 0] += c * b[:, 0] - s * b[:, 1]
    out[:, 1] += s * b[:, 0] + c * b[:, 1]
    out[:, 2] += b[:, 2]
    return out


def _step_odometry(step, robot_ids: tuple[str, ...]) -> np.ndarray:
    """Each robot's wheel-odometry increment over the step (N, 3), its records composed."""
    n = len(robot_ids)
    total = np.zeros((n, 3))
    depth = max(len(step.measurements[r].odometry) for r in robot_ids)
    for k in range(depth):  # records per step (1 at 10 Hz odometry, 0.1 s control)
        inc = np.zeros((n, 3))
        for i, rid in enumerate(robot_ids):
            recs = step.measurements[rid].odometry
            if k < len(recs):
                inc[i] = recs[k].delta
        total = _compose(total, inc)
    return total


def _errors(est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    pos, head = pose_errors(align_poses(est, truth), truth)
    return float(np.sqrt(np.mean(pos**2))), float(np.degrees(np.sqrt(np.mean(head**2))))


def run_episode(
    seed: int,
    preset: str = "lab-3m-4",
    n_robots: int = 5,
    arena_m: float = 1.5,
    duration_s: float = 60.0,
    init_s: float = 3.0,
    speed_mps: float = 0.05,
    ir: IRConfig | None = None,
    ukf: CentralizedUKFConfig | None = None,
) -> dict[str, Any]:
    """One episode; returns the error traces and their summaries (see module docstring)."""
    from agents.scripted import WanderPolicy
    from swarm_env import parallel_env

    if isinstance(n_robots, bool) or not isinstance(n_robots, int) or n_robots < 2:
        raise ValueError(f"n_robots must be an integer >= 2, got {n_robots!r}")
    inputs.duration("--duration", duration_s)
    if not (math.isfinite(init_s) and 0 < init_s < duration_s):
        raise ValueError(f"init_s must be in (0, duration), got {init_s!r}")
    if not (math.isfinite(speed_mps) and speed_mps > 0):
        raise ValueError(f"speed must be > 0 m/s, got {speed_mps!r}")
    env = parallel_env(
        preset,
        task="wander",
        n_robots=n_robots,
        arena={
            "width_m": arena_m,
            "height_m": arena_m,
            "n_decoy_posts": 0,
            "n_red_decoys": 0,
            "n_boxes": 0,
        },
        observation="truth",
        localize=False,
        max_steps=int(round(duration_s / 0.01)) + 10,  # any control period >= 10 ms
    )
    dt = env.config.control_period_s
    n_steps = inputs.steps_in(env, "--duration", duration_s)
    ids = tuple(env.possible_agents)
    # Turn rate capped at the IR-UKF study's "typical rotation" (0.02 rad per 1/30 s: 0.6 rad/s).
    policy = WanderPolicy(
        max_speed_mps=speed_mps, max_turn_rate_radps=0.6, avoid_distance_m=0.3, seed=seed
    )
    sensor = IRSensor(ir)
    filt = CentralizedUKF(ukf)
    obs, infos = env.reset(seed=seed)
    truth = env.last_world_step.truth.poses[:n_robots]
    # The sensor's own stream, derived from the episode seed (the env's stays untouched).
    sensor.reset(np.random.default_rng([seed, 3]), n_robots)
    pooled: list[IRReadings] = []
    window: list[IRReadings] = []
    trace: dict[str, list[float]] = {k: [] for k in ("time_s", "ukf_pos_m", "ukf_head_deg")}
    direct_trace: dict[str, list[float]] = {"time_s": [], "pos_m": [], "head_deg": []}
    init: dict[str, Any] = {}
    direct_prev: np.ndarray | None = None
    next_direct_s = init_s + sensor.config.period_s
    for k in range(n_steps):
        t_now = (k + 1) * dt
        moving = t_now > init_s
        actions = policy(obs, infos) if moving else {a: np.zeros(2, np.float32) for a in obs}
        obs, _, _, _, infos = env.step(actions)
        step = env.last_world_step
        truth = step.truth.poses[:n_robots]
        readings = sensor.step(step.time_s, truth)
        if not init:
            pooled.append(readings)
            if t_now + 1e-9 >= init_s:
                allr = IRReadings.concatenate(pooled)
                res = direct_estimate(
                    allr.observer,
                    allr.target,
                    allr.range_m,
                    allr.bearing_rad,
                    n_robots,
                    seed=seed,
                )
                pos, head = _errors(res.poses, truth)
                init = {
                    "time_s": step.time_s,
                    "n_readings": len(allr),
                    "enough_readings": res.enough_readings,
                    "all_linked": bool(res.observable.all()),
                    "rms_residual_m": res.rms_residual_m,
                    "pos_rmse_m": pos,
                    "head_rmse_deg": head,
                }
                filt.initialize(res.poses)
                direct_prev = res.poses
            continue
        filt.predict(_step_odometry(step, ids), dt)
        if len(readings):
            filt.update(readings.observer, readings.target, readings.range_m, readings.bearing_rad)
            window.append(readings)
        pos, head = _errors(filt.poses, truth)
        trace["time_s"].append(step.time_s)
        trace["ukf_pos_m"].append(pos)
        trace["ukf_head_deg"].append(head)
        if step.time_s + 1e-9 >= next_direct_s:
            # The study's comparison: direct estimation on the last second's sweeps.
            next_direct_s += sensor.config.period_s
            w = IRReadings.concatenate(window)
            window = []
            if len(w) and 2 * len(w) >= 3 * n_robots - 3:
                res = direct_estimate(
                    w.observer,
                    w.target,
                    w.range_m,
                    w.bearing_rad,
                    n_robots,
                    seed=seed,
                    x0=direct_prev,
                    n_starts=4,
                )
                direct_prev = res.poses
                pos, head = _errors(res.poses, truth)
                direct_trace["time_s"].append(step.time_s)
                direct_trace["pos_m"].append(pos)
                direct_trace["head_deg"].append(head)
    env.close()
    return {
        "seed": seed,
        "init": init,
        "ukf": {
            "pos_rmse_mean_m": float(np.mean(trace["ukf_pos_m"])),
            "head_rmse_mean_deg": float(np.mean(trace["ukf_head_deg"])),
            "pos_rmse_max_m": float(np.max(trace["ukf_pos_m"])),
            "pct_time_pos_rmse_le_10cm": float(
                100 * np.mean(np.array(trace["ukf_pos_m"]) <= 0.10)
            ),
        },
        "direct_per_second": {
            "n_solves": len(direct_trace["pos_m"]),
            "pos_rmse_median_m": float(np.median(direct_trace["pos_m"]))
            if direct_trace["pos_m"]
            else float("nan"),
            "head_rmse_median_deg": float(np.median(direct_trace["head_deg"]))
            if direct_trace["head_deg"]
            else float("nan"),
        },
        "trace": trace,
        "direct_trace": direct_trace,
    }


def run_seed003(
    preset: str,
    duration_s: float,
    seeds: list[int],
    n_robots: int = 5,
    arena_m: float = 1.5,
    init_s: float = 3.0,
    speed_mps: float = 0.05,
    ir: IRConfig | None = None,
    ukf: CentralizedUKFConfig | None = None,
    out_dir: Path | None = None,
) -> dict[str, Any]:
    """Run every seed; return (and with ``out_dir`` write) the metrics and the figure.

    The defaults are the IR-UKF study's setup (:func:`add_arguments`'): 5 robots, a 1.5 m square,
    3 s standstill, 5 cm/s, the study's IR figures (``IRConfig()``)."""
    if not seeds:
        raise ValueError("--seeds must name at least one integer")
    ir = IRConfig() if ir is None else ir
    ukf = CentralizedUKFConfig() if ukf is None else ukf
    start = time.perf_counter()
    episodes = [
        run_episode(s, preset, n_robots, arena_m, duration_s, init_s, speed_mps, ir, ukf)
        for s in seeds
    ]
    ukf_pos = [e["ukf"]["pos_rmse_mean_m"] for e in episodes]
    results = {
        "config": {
            "preset": preset,
            "n_robots": n_robots,
            "arena_m": arena_m,
            "duration_s": duration_s,
            "init_s": init_s,
            "speed_mps": speed_mps,
            "seeds": seeds,
            "ir": {f: getattr(ir, f) for f in ir.__slots__},
            "ir_effective_range_std_m": ir.effective_range_std_m,
            "ukf": {f: getattr(ukf, f) for f in ukf.__slots__},
            "error_definition": "after the Kabsch fit (rotation + translation, det +1) of the "
            "estimated positions onto the true ones, RMSE over the robots at each step; "
            "headings rotated by the fit, wrapped",
        },
        "summary": {
            "ukf_pos_rmse_mean_m": float(np.mean(ukf_pos)),
            "ukf_pos_rmse_worst_seed_m": float(np.max(ukf_pos)),
            "ukf_head_rmse_mean_deg": float(
                np.mean([e["ukf"]["head_rmse_mean_deg"] for e in episodes])
            ),
            "init_pos_rmse_mean_m": float(np.mean([e["init"]["pos_rmse_m"] for e in episodes])),
            "init_head_rmse_mean_deg": float(
                np.mean([e["init"]["head_rmse_deg"] for e in episodes])
            ),
            "direct_per_second_pos_rmse_median_m": float(
                np.nanmedian([e["direct_per_second"]["pos_rmse_median_m"] for e in episodes])
            ),
            "seed_accuracy_m": SEED_ACCURACY_M,
            "meets_seed_accuracy": bool(np.mean(ukf_pos) <= SEED_ACCURACY_M),
        },
        "episodes": [
            {**{k: v for k, v in e.items() if "trace" not in k}, **_traces(e)} for e in episodes
        ],
        "wall_time_s": time.perf_counter() - start,
    }
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        write_json_atomically(out_dir / "metrics.json", results)
        write_figure(out_dir / "seed003_error.png", episodes[0], results)
    return results


def _traces(episode: dict[str, Any]) -> dict[str, Any]:
    """The error traces for metrics.json: the UKF's every 1 s (every 10th step), the direct
    estimate's at each solve."""
    tr = episode["trace"]
    step = slice(None, None, 10)
    return {
        "ukf_trace_1hz": {
            "time_s": [round(t, 3) for t in tr["time_s"][step]],
            "pos_rmse_m": tr["ukf_pos_m"][step],
            "head_rmse_deg": tr["ukf_head_deg"][step],
        },
        "direct_trace": episode["direct_trace"],
    }


def write_figure(path: Path, episode: dict[str, Any], results: dict[str, Any]) -> None:
    """Position and heading RMSE over time (first seed): UKF every step, direct per second."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cfg = results["config"]
    tr, dtr = episode["trace"], episode["direct_trace"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax1.plot(tr["time_s"], tr["ukf_pos_m"], label="centralized UKF", color="tab:blue")
    ax1.plot(
        dtr["time_s"], dtr["pos_m"], ".", label="direct (SLSQP, last 1 s)", color="tab:orange"
    )
    ax1.axhline(SEED_ACCURACY_M, ls="--", color="grey", label="IR-UKF study: ~10 cm")
    ax1.set_ylabel("position RMSE (m)")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.plot(tr["time_s"], tr["ukf_head_deg"], color="tab:blue")
    ax2.plot(dtr["time_s"], dtr["head_deg"], ".", color="tab:orange")
    ax2.set_ylabel("heading RMSE (deg)")
    ax2.set_xlabel("time (s)")
    fig.suptitle(f"IR-UKF study reproduction: {cfg['n_robots']} robots, seed {episode['seed']}")
    ir = cfg["ir"]
    fig.text(
        0.01,
        0.005,
        f"Errors after Kabsch alignment to ground truth. IR {ir['rate_hz']:g} Hz, <= "
        f"{ir['max_range_m']:g} m, range sigma {ir['range_std_m'] * 100:.1f} cm core / "
        f"{cfg['ir_effective_range_std_m'] * 100:.1f} cm with outliers, bearing "
        f"{ir['bearing_std_deg']:g} deg; UKF initialised by direct estimation at "
        f"t = {episode['init']['time_s']:.1f} s.",
        fontsize=7,
        wrap=True,
    )
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110))
    plt.close(fig)


def print_summary(results: dict[str, Any]) -> None:
    cfg, s = results["config"], results["summary"]
    print(
        f"IR-UKF study: {cfg['n_robots']} robots, {cfg['duration_s']:.0f} s x {len(cfg['seeds'])} "
        f"seeds, arena {cfg['arena_m']:g} m ({results['wall_time_s']:.1f} s wall)"
    )
    for e in results["episodes"]:
        i, u, d = e["init"], e["ukf"], e["direct_per_second"]
        print(
            f"  seed {e['seed']}: init (direct, {i['n_readings']} readings) "
            f"{i['pos_rmse_m'] * 100:.1f} cm / {i['head_rmse_deg']:.1f} deg; UKF mean "
            f"{u['pos_rmse_mean_m'] * 100:.1f} cm / {u['head_rmse_mean_deg']:.1f} deg "
            f"(max {u['pos_rmse_max_m'] * 100:.1f} cm); direct per second median "
            f"{d['pos_rmse_median_m'] * 100:.1f} cm"
        )
    verdict = "meets" if s["meets_seed_accuracy"] else "MISSES"
    print(
        f"  UKF position RMSE {s['ukf_pos_rmse_mean_m'] * 100:.1f} cm (worst seed "
        f"{s['ukf_pos_rmse_worst_seed_m'] * 100:.1f} cm), heading "
        f"{s['ukf_head_rmse_mean_deg']:.1f} deg: {verdict} the study's ~10 cm"
    )
