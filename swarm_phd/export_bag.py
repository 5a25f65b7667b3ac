"""``swarm-phd export-bag --out PATH --duration S``: write a simulated episode (scripted wander
policy) as a ROS 2 bag, laid out exactly as the bridge records robots, so ``swarm-phd replay``
is exercised on data the simulator wrote."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from hardware_bridge.bag import BagRecorder
from hardware_bridge.messages import topics
from swarm_env.config import make_config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="new bag directory (must not exist)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    parser.add_argument("--preset", default="seed-lab")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    if Path(args.out).exists():
        raise ValueError(f"--out {args.out} exists already; bags are never overwritten")
    summary = export_sim_episode(
        args.out, preset=args.preset, duration_s=args.duration, seed=args.seed
    )
    print(
        f"wrote {summary['path']}: {summary['steps']} steps, {summary['messages']} messages, "
        f"robots {summary['robots']}"
    )
    return 0


def export_sim_episode(
    path: str | Path,
    *,
    preset: str = "seed-lab",
    duration_s: float = 10.0,
    seed: int = 0,
    start_stamp_s: float = 1.7e9,
    **overrides: Any,
) -> dict[str, Any]:
    """Run the simulator with the scripted wander policy for ``duration_s`` and write the episode
    as a bag, exactly as the bridge would have recorded it from robots (odometry as integrated
    odom poses, scans as ``LaserScan``, bearings, mocap = the sim's truth, commands).

    Stamps are ``start_stamp_s`` + sim time (a fixed epoch keeps the file reproducible).
    Returns a summary with the number of steps and messages and, per step, each agent's PHD
    mixture in the simulator (``weights``, ``means``) for comparison with a replay.
    """
    from agents.scripted import WanderPolicy
    from hardware_bridge.messages import (
        bearings_msg,
        laser_scan_msg,
        odometry_msg,
        pose_stamped_msg,
    )
    from swarm_env.env import SwarmEnv

    if not duration_s > 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
    config = make_config(preset, **overrides)
    n_steps = max(1, int(round(duration_s / config.control_period_s)))
    config = dataclasses.replace(config, max_steps=max(config.max_steps, n_steps))
    env = SwarmEnv(config=config)
    agents = list(env.possible_agents)
    policy = WanderPolicy.for_env(env, seed=seed)
    recorder = BagRecorder(path, agents, config, source="sim")
    base_ns = int(round(start_stamp_s * 1e9))
    high = np.array([config.robot.max_speed_mps, config.robot.max_turn_rate_radps])
    odom = {a: np.zeros(3) for a in agents}
    trace: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []

    def stamp(t_s: float) -> int:
        return base_ns + int(round(t_s * 1e9))

    def snapshot() -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {
            a: (env.localizers[i].mixture.weights.copy(), env.localizers[i].mixture.means.copy())
            for i, a in enumerate(agents)
        }

    try:
        obs, infos = env.reset(seed=seed)
        for a in agents:
            names = topics(a)
            recorder.write(
                names["odometry"],
                "odometry",
                base_ns,
                odometry_msg(
                    base_ns,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    frame_id=f"{a}/odom",
                    child_frame_id=f"{a}/base_link",
                ),
            )
            pose = infos[a]["truth"]["pose"]
            recorder.write(names["mocap"], "mocap", base_ns, pose_stamped_msg(base_ns, *pose))
        recorder.write_marker("reset", 0, base_ns, {})
        trace.append(snapshot())
        scan_time = 1.0 / config.lidar.rate_hz
        for k in range(1, n_steps + 1):
            actions = policy(obs, infos)
            commands = np.array(
                [np.clip(np.asarray(actions[a], dtype=np.float64), -high, high) for a in agents]
            )
            recorder.write_commands(stamp(env.time_s) + 1, commands)
            obs, _, _, _, infos = env.step(actions)
            end_ns = stamp(env.time_s)
            for a in agents:
                names = topics(a)
                m = infos[a]["measurements"]
                for r in m["odometry"]:
                    x, y, yaw = odom[a]
                    dx, dy, dpsi = r["delta"]
                    c, s = np.cos(yaw), np.sin(yaw)
                    odom[a] = np.array(
                        [
                            x + c * dx - s * dy,
                            y + s * dx + c * dy,
                            np.remainder(yaw + dpsi + np.pi, 2 * np.pi) - np.pi,
                        ]
                    )
                    t = stamp(r["stamp_s"])
                    recorder.write(
                        names["odometry"],
                        "odometry",
                        t,
                        odometry_msg(
                            t,
                            *odom[a],
                            *r["velocity"],
                            frame_id=f"{a}/odom",
                            child_frame_id=f"{a}/base_link",
                        ),
                    )
                for r in m["lidar"]:
                    t = stamp(r["stamp_s"])
                    recorder.write(
                        names["lidar"],
                        "lidar",
                        t,
                        laser_scan_msg(
                            t,
                            r["angles_rad"],
                            r["ranges_m"],
                            r["intensities"],
                            range_min_m=config.lidar.range_min_m,
                            range_max_m=config.lidar.range_max_m,
                            scan_time_s=scan_time,
                            frame_id=f"{a}/laser",
                        ),
                    )
                for r in m["camera"]:
                    recorder.write(
                        names["camera"],
                        "camera",
                        stamp(r["stamp_s"]),
                        bearings_msg(r["bearings_rad"]),
                    )
                pose = infos[a]["truth"]["pose"]
                recorder.write(names["mocap"], "mocap", end_ns, pose_stamped_msg(end_ns, *pose))
            recorder.write_marker("step", k, end_ns, {})
            trace.append(snapshot())
    finally:
        recorder.close()
        env.close()
    return {
        "path": str(path),
        "robots": agents,
        "steps": n_steps,
        "messages": recorder.messages_written,
        "trace": trace,
    }
