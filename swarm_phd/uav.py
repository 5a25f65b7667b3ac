"""``swarm-phd uav``: Stegagno 2013's experiment, a UAV identifying wandering UGVs with ID-PHD.

The env is :class:`swarm_env.uav.SupervisedSwarmEnv` on preset ``seed-uav`` (3 UGVs in a 2.5 m
square, a UAV at 2.8 m with a downward camera, the UGVs' odometry broadcast at 10 Hz). The UGVs
wander (:class:`agents.scripted.WanderPolicy`: the Stegagno 2013 study's "random motion with
obstacle avoidance"); the UAV hovers, as in that study's simulation (``--uav-control hover``),
or follows the centroid of its detections (``centroid``, the study's visual-servoing task T1).

Metrics, per identity ``i`` (UGV ``i``'s ID-PHD estimate: the mean of its heaviest component,
against its true pose in the UAV's level frame):

- **convergence time**: the first time from which the estimate stays within 0.12 m and 10 deg
  (the Stegagno 2013 study's figures) for ``--hold-s`` seconds; ``nan`` if never;
- after convergence: median / 95th percentile / max position error (m) and heading error
  (deg), and the fraction of time within both thresholds;
- **final error**: the mean position and heading error over the last 10 s (the
  Stegagno 2013 study's "final error").

The study's result (sec. V): convergence in less than one minute, final error under 12 cm and
10 deg. ``--json`` writes everything, with the measured camera statistics the filter used.

``--loopback`` runs the same experiment over the hardware bridge: a
:class:`~hardware_bridge.loopback.LoopbackServer` flies the simulated UGVs and the UAV in real
time behind a rosbridge websocket on 127.0.0.1, and the env is
:func:`hardware_bridge.real_supervised_env` (the UAV's pose and detections topics, its
``cmd_vel``); the truth for the metrics is read from the server. ``--record BAG`` records the
(first seed's) bridge episode to a ROS 2 bag.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm_core import inputs
from swarm_core.inputs import parse_seeds
from swarm_core.validation import check_number

#: The Stegagno 2013 study's figures (sec. V).
SEED_POSITION_M = 0.12
SEED_HEADING_DEG = 10.0
SEED_CONVERGENCE_S = 60.0
UAV_CONTROLS = ("hover", "centroid")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        default=None,
        help="UGV preset (default: seed-uav, the Stegagno 2013 study's setup)",
    )
    parser.add_argument(
        "--seeds", default="0,1,2", help="comma-separated integers or ranges (0-4)"
    )
    inputs.add_duration_argument(parser, 120.0)
    parser.add_argument("--uav-control", choices=UAV_CONTROLS, default="hover")
    parser.add_argument("--altitude", type=float, default=None, help="UAV altitude (m)")
    parser.add_argument("--loss", type=float, default=None, help="radio loss probability")
    parser.add_argument("--latency", type=float, default=None, help="radio latency (s)")
    parser.add_argument(
        "--filter-lag",
        type=float,
        default=None,
        help="fixed lag of the UAV's settled filter (s); default: the radio's latency + jitter; "
        "0 applies each increment when it arrives",
    )
    parser.add_argument(
        "--hold-s",
        type=float,
        default=5.0,
        help="convergence: within thresholds this long (s; >= 0, 0: from the first step within)",
    )
    parser.add_argument(
        "--loopback",
        action="store_true",
        help="run over the hardware bridge against a loopback robot server with a UAV "
        "(real time: --duration seconds of wall time per seed)",
    )
    parser.add_argument(
        "--record", default=None, help="with --loopback: record the first seed's episode here"
    )
    parser.add_argument("--json", default=None, help="write the metrics here")
    parser.add_argument(
        "--figure",
        default=None,
        help="write the first seed's x, y and heading errors per identity here (PNG; seed "
        "002's Fig. 5)",
    )


def run(args: argparse.Namespace) -> int:
    seeds = parse_seeds(str(args.seeds))
    comms: dict[str, Any] = {}
    if args.record and not args.loopback:
        raise ValueError("--record needs --loopback (a simulated episode has no bridge)")
    inputs.duration("--duration", args.duration)
    check_number("--hold-s", args.hold_s, low=0)
    check_number("--altitude", args.altitude, low=0, above=True, optional=True)
    check_number("--loss", args.loss, low=0, high=1, optional=True)
    check_number("--latency", args.latency, low=0, optional=True)
    check_number("--filter-lag", args.filter_lag, low=0, optional=True)
    for flag, path in (("--json", args.json), ("--figure", args.figure)):
        if path:
            inputs.output_file(flag, path)
    if args.record:
        inputs.new_bag_dir("--record", args.record)
    if args.loss is not None:
        comms["loss_probability"] = args.loss
    if args.latency is not None:
        comms["latency_s"] = args.latency
    result = run_seed002(
        seeds=seeds,
        duration_s=args.duration,
        preset=args.preset or "seed-uav",
        uav_control=args.uav_control,
        altitude_m=args.altitude,
        comms=comms,
        hold_s=args.hold_s,
        filter_lag_s=args.filter_lag,
        quiet=args.quiet,
        figure=Path(args.figure) if args.figure else None,
        loopback=args.loopback,
        record=args.record,
    )
    print(format_summary(result))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2, default=_jsonable))
        print(f"wrote {args.json}")
    return 0


def run_episode(
    seed: int,
    duration_s: float = 120.0,
    preset: str = "seed-uav",
    uav_control: str = "hover",
    altitude_m: float | None = None,
    comms: dict[str, Any] | None = None,
    filter_lag_s: float | None = None,
    loopback: bool = False,
    record: str | None = None,
) -> dict[str, Any]:
    """One episode; returns per-step error traces ``(T, n)`` and the camera statistics.
    ``loopback``: over the bridge against a loopback server (module docstring)."""
    from swarm_env.config import make_config
    from swarm_env.uav import SupervisedSwarmEnv, UAVConfig

    inputs.duration("--duration", duration_s, make_config(preset).control_period_s)
    if uav_control not in UAV_CONTROLS:
        raise ValueError(f"uav_control must be one of {UAV_CONTROLS}, got {uav_control!r}")
    uav = UAVConfig() if altitude_m is None else UAVConfig(start_altitude_m=altitude_m)
    n_steps = int(round(duration_s / make_config(preset).control_period_s))
    # The radio is what the UAV identifies the UGVs by: on for any preset.
    overrides: dict[str, Any] = {"comms": {"enabled": True, **(comms or {})}}
    server = None
    if loopback:
        from hardware_bridge import real_supervised_env
        from hardware_bridge.loopback import LoopbackServer

        server = LoopbackServer(preset, seed=seed, uav=uav)
        server.start()
        try:
            env = real_supervised_env(
                port=server.port,
                preset=preset,
                uav=uav,
                record=record,
                filter_lag_s=filter_lag_s,
                max_steps=n_steps + 1,
                **overrides,
            )
        except BaseException:
            server.close()
            raise
    else:
        env = SupervisedSwarmEnv(
            preset, uav=uav, max_steps=n_steps + 1, filter_lag_s=filter_lag_s, **overrides
        )
    try:
        return _episode(env, server, seed, n_steps, uav_control)
    finally:
        env.close()
        if server is not None:
            server.close()


def _level_truth(env: Any, server: Any) -> np.ndarray:
    """Over the bridge: the UGVs' true ``[x, y, psi]`` in the UAV's level frame at the step's
    end, from the loopback server's simulator (scoring only)."""
    from hardware_bridge.messages import s_to_ns
    from swarm_env.sensors.downward_camera import to_level_frame

    n = len(env.ugv_agents)
    poses, uav_pose, _ = server.truth_at(s_to_ns(env.ground.last_world_step.time_s))
    out = np.empty((n, 3))
    out[:, :2] = to_level_frame(uav_pose, poses[:n, :2])
    out[:, 2] = [_wrap(p - uav_pose[2]) for p in poses[:n, 2]]
    return out


def _ugv_truth(env: Any) -> np.ndarray | None:
    """The UGVs' true poses of the last step (simulator, or motion capture over the bridge:
    stamped with the step's records), ``None`` without."""
    truth = env.ground.last_world_step.truth
    return None if truth is None else truth.poses[: len(env.ugv_agents)].copy()


def _episode(env: Any, server: Any, seed: int, n_steps: int, uav_control: str) -> dict[str, Any]:
    from agents.scripted import WanderPolicy
    from swarm_env.uav import UAV_ID
    from swarm_env.uav.control import uav_action

    robot = env.config.robot
    policy = WanderPolicy(
        max_speed_mps=robot.max_speed_mps, max_turn_rate_radps=robot.max_turn_rate_radps, seed=seed
    )
    obs, infos = env.reset(seed=seed)
    n = len(env.ugv_agents)
    times, pos_err, head_err, in_view, slip, signed = [], [], [], [], [], []
    prev = _ugv_truth(env)
    t0 = infos[UAV_ID]["time_s"] if server is not None else 0.0
    for _ in range(n_steps):
        if not env.agents:
            break
        ugv = [a for a in env.agents if a != UAV_ID]
        actions = policy({a: obs[a] for a in ugv}, {a: infos[a] for a in ugv})
        actions[UAV_ID] = uav_action(env, uav_control)
        obs, _, _, _, infos = env.step(actions)
        info = infos[UAV_ID]
        truth = info["truth"]["ugv_level_poses"] if server is None else _level_truth(env, server)
        estimate = info["estimate"]
        pe, he = np.full(n, np.nan), np.full(n, np.nan)
        err = np.full((n, 3), np.nan)
        for i in range(n):
            if i in estimate:
                err[i, :2] = estimate[i][:2] - truth[i, :2]
                err[i, 2] = math.degrees(_wrap(estimate[i][2] - truth[i, 2]))
                pe[i] = math.hypot(*err[i, :2])
                he[i] = abs(err[i, 2])
        signed.append(err)
        half = env.uav_config.camera.half_extents_m(env.altitude_m)
        step = env.ground.last_world_step
        now = _ugv_truth(env)
        slip.append(
            np.zeros(n, dtype=bool)  # no truth (a bridge without motion capture): not known
            if prev is None or now is None
            else _odometry_slip(prev, now, [step.measurements[a] for a in env.ugv_agents])
        )
        prev = now
        times.append(info["time_s"] - t0)  # from the reset (ROS time over the bridge)
        pos_err.append(pe)
        head_err.append(he)
        in_view.append((np.abs(truth[:, :2]) <= half).all(axis=1))
    return {
        "seed": seed,
        "time_s": np.asarray(times),
        "position_error_m": np.asarray(pos_err),
        "heading_error_deg": np.asarray(head_err),
        "in_view": np.asarray(in_view),
        "slip": np.asarray(slip),
        "errors": np.asarray(signed),
        "camera_statistics": env.camera_statistics.as_dict(),
        "camera_model": {
            "detection_probability": env.camera_model.detection_probability,
            "noise_per_altitude": env.camera_model.noise_per_altitude,
            "clutter_per_frame": env.camera_model.clutter_per_frame,
        },
    }


def identity_metrics(
    time_s: np.ndarray,
    position_error_m: np.ndarray,
    heading_error_deg: np.ndarray,
    hold_s: float = 5.0,
    final_s: float = 10.0,
    slip: np.ndarray | None = None,
    slip_clear_s: float = 10.0,
) -> list[dict[str, float]]:
    """Per identity (columns of the ``(T, n)`` error arrays; ``nan`` = no estimate): see the
    module docstring. Convergence: the first step ``k`` such that every step in
    ``[t_k, t_k + hold_s]`` is within both thresholds."""
    ok = (position_error_m < SEED_POSITION_M) & (heading_error_deg < SEED_HEADING_DEG)
    out = []
    for i in range(position_error_m.shape[1]):
        conv = float("nan")
        k_conv = None
        for k in np.flatnonzero(ok[:, i]):
            window = (time_s >= time_s[k]) & (time_s <= time_s[k] + hold_s)
            if time_s[k] + hold_s <= time_s[-1] and ok[window, i].all():
                conv, k_conv = float(time_s[k]), int(k)
                break
        final = time_s >= time_s[-1] - final_s
        row = {
            "convergence_time_s": conv,
            "final_position_error_m": float(np.nanmean(position_error_m[final, i])),
            "final_heading_error_deg": float(np.nanmean(heading_error_deg[final, i])),
        }
        if k_conv is not None:
            pe, he = position_error_m[k_conv:, i], heading_error_deg[k_conv:, i]
            row.update(
                {
                    "position_error_median_m": float(np.nanmedian(pe)),
                    "position_error_p95_m": float(np.nanpercentile(pe, 95)),
                    "position_error_max_m": float(np.nanmax(pe)),
                    "heading_error_median_deg": float(np.nanmedian(he)),
                    "heading_error_p95_deg": float(np.nanpercentile(he, 95)),
                    "heading_error_max_deg": float(np.nanmax(he)),
                    "within_thresholds_fraction": float(ok[k_conv:, i].mean()),
                }
            )
            if slip is not None:
                # Steps with no wheel slip of this UGV in the last ``slip_clear_s`` seconds.
                slipped_at = time_s[slip[:, i]]
                last = np.searchsorted(slipped_at, time_s, side="right") - 1
                since = np.full(time_s.shape, np.inf)
                if slipped_at.size:  # a UGV that never slipped is clear everywhere
                    since = np.where(last >= 0, time_s - slipped_at[np.maximum(last, 0)], np.inf)
                clear = (since > slip_clear_s)[k_conv:]
                row["slip_fraction"] = float(slip[k_conv:, i].mean())
                row["heading_error_p95_no_slip_deg"] = (
                    float(np.nanpercentile(he[clear], 95)) if clear.any() else float("nan")
                )
                row["within_thresholds_no_slip_fraction"] = (
                    float(ok[k_conv:, i][clear].mean()) if clear.any() else float("nan")
                )
        out.append(row)
    return out


def run_seed002(
    seeds: list[int],
    duration_s: float = 120.0,
    preset: str = "seed-uav",
    uav_control: str = "hover",
    altitude_m: float | None = None,
    comms: dict[str, Any] | None = None,
    hold_s: float = 5.0,
    filter_lag_s: float | None = None,
    quiet: bool = True,
    figure: Path | None = None,
    loopback: bool = False,
    record: str | None = None,
) -> dict[str, Any]:
    """Every seed's episode and metrics, and the summary over seeds (``figure``: the first
    seed's error traces, see :func:`plot_errors`; ``loopback``: over the bridge, ``record``
    the first seed's bag)."""
    episodes = []
    for seed in seeds:
        start = time.perf_counter()
        ep = run_episode(
            seed,
            duration_s,
            preset,
            uav_control,
            altitude_m,
            comms,
            filter_lag_s,
            loopback=loopback,
            record=record if not episodes else None,
        )
        if figure is not None and not episodes:
            plot_errors(ep, figure)
            if not quiet:
                print(f"wrote {figure}", flush=True)
        metrics = identity_metrics(
            ep["time_s"],
            ep["position_error_m"],
            ep["heading_error_deg"],
            hold_s,
            slip=ep["slip"],
        )
        episodes.append(
            {
                "seed": seed,
                "wall_s": time.perf_counter() - start,
                "identities": metrics,
                "in_view_fraction": float(ep["in_view"].mean()),
                "camera_statistics": ep["camera_statistics"],
                "camera_model": ep["camera_model"],
            }
        )
        if not quiet:
            print(f"seed {seed}: {time.perf_counter() - start:.1f} s wall", flush=True)
    rows = [m for ep in episodes for m in ep["identities"]]
    conv = np.array([m["convergence_time_s"] for m in rows])
    final_p = np.array([m["final_position_error_m"] for m in rows])
    final_h = np.array([m["final_heading_error_deg"] for m in rows])
    summary = {
        "in_view_fraction_mean": float(np.mean([ep["in_view_fraction"] for ep in episodes])),
        "identities": len(rows),
        "converged": int(np.isfinite(conv).sum()),
        "converged_within_60s": int((conv <= SEED_CONVERGENCE_S).sum()),
        "convergence_time_s_max": float(np.nanmax(conv)) if np.isfinite(conv).any() else None,
        "convergence_time_s_median": float(np.nanmedian(conv))
        if np.isfinite(conv).any()
        else None,
        "final_position_error_m_max": float(np.nanmax(final_p)),
        "final_heading_error_deg_max": float(np.nanmax(final_h)),
        "final_within_seed": int(
            ((final_p < SEED_POSITION_M) & (final_h < SEED_HEADING_DEG)).sum()
        ),
        "within_thresholds_fraction_mean": float(
            np.mean([m.get("within_thresholds_fraction", 0.0) for m in rows])
        ),
        "within_thresholds_no_slip_fraction_mean": float(
            np.nanmean([m.get("within_thresholds_no_slip_fraction", np.nan) for m in rows])
        ),
    }
    return {
        "setup": {
            "preset": preset,
            "seeds": seeds,
            "duration_s": duration_s,
            "uav_control": uav_control,
            "altitude_m": altitude_m,
            "comms": comms or {},
            "hold_s": hold_s,
            "filter_lag_s": filter_lag_s,
            "loopback": loopback,
        },
        "seed_reference": {
            "convergence_s": SEED_CONVERGENCE_S,
            "position_m": SEED_POSITION_M,
            "heading_deg": SEED_HEADING_DEG,
        },
        "summary": summary,
        "episodes": episodes,
    }


def plot_errors(episode: dict[str, Any], path: Path) -> None:
    """Stegagno 2013's Fig. 5: x, y and heading errors of each identity's estimate over time,
    with Stegagno 2013's bounds (0.12 m, 10 deg) and the UGV's wheel-slip steps shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, err, slip = episode["time_s"], episode["errors"], episode["slip"]
    n = err.shape[1]
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    labels = ("x error (m)", "y error (m)", "heading error (deg)")
    bounds = (SEED_POSITION_M, SEED_POSITION_M, SEED_HEADING_DEG)
    for k, ax in enumerate(axes):
        for i in range(n):
            ax.plot(t, err[:, i, k], lw=0.8, label=f"UGV {i}")
            ax.fill_between(t, -bounds[k], bounds[k], where=slip[:, i], color=f"C{i}", alpha=0.15)
        ax.axhline(bounds[k], color="k", ls=":", lw=0.8)
        ax.axhline(-bounds[k], color="k", ls=":", lw=0.8)
        ax.set_ylabel(labels[k])
    axes[0].set_ylim(-0.3, 0.3)
    axes[1].set_ylim(-0.3, 0.3)
    axes[2].set_ylim(-60, 60)
    axes[0].legend(loc="upper right", ncol=n, fontsize=8)
    axes[0].set_title(
        f"ID-PHD on the UAV, seed {episode['seed']}: dotted = Stegagno 2013's bounds, "
        "shaded = wheel slip",
        fontsize=9,
    )
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def format_summary(result: dict[str, Any]) -> str:
    s = result["summary"]
    lines = [
        "Stegagno 2013 (ID-PHD on a UAV): per identity, the heaviest component vs the truth",
        f"{'seed':>4} {'id':>3} {'conv s':>7} {'pos med':>8} {'pos p95':>8} {'hdg med':>8} "
        f"{'hdg p95':>8} {'in thr':>7} {'final m':>8} {'final deg':>9} {'slip':>6} "
        f"{'p95 ns':>7} {'thr ns':>7}",
    ]
    for ep in result["episodes"]:
        for i, m in enumerate(ep["identities"]):
            lines.append(
                f"{ep['seed']:>4} {i:>3} {m['convergence_time_s']:>7.1f} "
                f"{m.get('position_error_median_m', math.nan):>8.3f} "
                f"{m.get('position_error_p95_m', math.nan):>8.3f} "
                f"{m.get('heading_error_median_deg', math.nan):>8.1f} "
                f"{m.get('heading_error_p95_deg', math.nan):>8.1f} "
                f"{m.get('within_thresholds_fraction', math.nan):>7.1%} "
                f"{m['final_position_error_m']:>8.3f} {m['final_heading_error_deg']:>9.1f} "
                f"{m.get('slip_fraction', math.nan):>6.1%} "
                f"{m.get('heading_error_p95_no_slip_deg', math.nan):>7.1f} "
                f"{m.get('within_thresholds_no_slip_fraction', math.nan):>7.1%}"
            )
    lines.append(
        f"converged {s['converged']}/{s['identities']} (within 60 s: "
        f"{s['converged_within_60s']}), convergence max {_fmt(s['convergence_time_s_max'])} s; "
        f"final error within 0.12 m and 10 deg: {s['final_within_seed']}/{s['identities']} "
        f"(max {s['final_position_error_m_max']:.3f} m, {s['final_heading_error_deg_max']:.1f} "
        f"deg); time within thresholds after convergence "
        f"{s['within_thresholds_fraction_mean']:.1%} "
        f"({s['within_thresholds_no_slip_fraction_mean']:.1%} > 10 s after any wheel slip)"
    )
    lines.append(
        "columns: slip = time the UGV's wheel odometry disagrees with its motion (> 1 cm or "
        "> 1 deg per step); ns = only steps > 10 s after its last slip"
    )
    lines.append(
        f"UGVs inside the camera footprint {s['in_view_fraction_mean']:.1%} of the time; "
        "Stegagno 2013 reports: convergence < 60 s, final error < 0.12 m and < 10 deg"
    )
    return "\n".join(lines)


def _odometry_slip(
    before: np.ndarray,
    after: np.ndarray,
    records: list[Any],
    tol_m: float = 0.01,
    tol_deg: float = 1.0,
) -> np.ndarray:
    """``(n,)`` bool: the UGV's wheel odometry of the step disagrees with its true motion by more
    than ``tol_m`` or ``tol_deg`` (wheel slip: a UGV pushing a wall or a teammate)."""
    from swarm_core.geometry import integrate_body_delta

    out = np.zeros(before.shape[0], dtype=bool)
    for i, rec in enumerate(records):
        pose = before[i].copy()
        for odo in rec.odometry:
            pose = integrate_body_delta(pose, odo.delta)
        dxy = math.hypot(*(pose[:2] - after[i, :2]))
        dpsi = abs(math.degrees(_wrap(pose[2] - after[i, 2])))
        out[i] = dxy > tol_m or dpsi > tol_deg
    return out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value)}")


def _fmt(value: float | None) -> str:
    return "never" if value is None else f"{value:.1f}"
