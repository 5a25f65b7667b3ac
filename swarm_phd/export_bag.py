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
from swarm_core import inputs, progress
from swarm_env.config import make_config
from swarm_phd import presets


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="new bag directory (must not exist)")
    inputs.add_duration_argument(parser, 10.0)
    parser.add_argument("--preset", default="seed-lab")
    inputs.add_seed_argument(parser)


def run(args: argparse.Namespace) -> int:
    """SIGINT, SIGTERM and SIGHUP end the export with the bag closed (every step completed
    before the signal), a one-line message saying so, and status 128 + the signal number."""
    import sys

    from hardware_bridge.bag import bag_state
    from hardware_bridge.signals import (
        ExitSignals,
        Terminated,
        ignore_exit_signals,
        signal_exit,
    )

    period = presets.control_period_s(args.preset)  # an unknown preset is refused here too
    inputs.duration("--duration", args.duration, period)
    inputs.seed("--seed", args.seed)
    inputs.new_bag_dir("--out", args.out)
    signals = ExitSignals()
    try:
        summary = export_sim_episode(
            args.out, preset=args.preset, duration_s=args.duration, seed=args.seed
        )
    except (KeyboardInterrupt, Terminated, SystemError) as exc:
        found = signal_exit(exc)
        if found is None:  # a SystemError of its own
            raise
        code, name = found
        ignore_exit_signals()  # leaving: the bag is closed
    else:
        code = None
    finally:
        signals.restore()
    if code is not None:
        print(f"swarm-phd export-bag: {name}: {bag_state(args.out)}", file=sys.stderr)
        return code
    print(
        f"wrote {summary['path']}: {summary['steps']} steps, "
        f"{summary['messages'] + summary['markers']} messages ({summary['messages']} sensor, "
        f"mocap and command messages + {summary['markers']} step markers), "
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
    unstamped_bearings: tuple[str, ...] = (),
    **overrides: Any,
) -> dict[str, Any]:
    """Run the simulator with the scripted wander policy for ``duration_s`` and write the episode
    as a bag, exactly as the bridge would have recorded it from robots: the messages are built
    by the loopback robots' own :class:`~hardware_bridge.emit.RobotEmitter` (odometry as
    integrated odom poses, scans, stamped bearings, mocap = the sim's truth), plus commands.

    Stamps are ``start_stamp_s`` + sim time (a fixed epoch keeps the file reproducible).
    SIGINT, SIGTERM and SIGHUP end the export cleanly: the bag is closed, readable, and holds
    every step completed before the signal. Returns a summary with the number of steps and
    messages and, per step, each agent's PHD mixture in the simulator (``weights``, ``means``)
    for comparison with a replay.
    """
    from agents.scripted import WanderPolicy
    from hardware_bridge.emit import RobotEmitter
    from hardware_bridge.signals import ExitSignals, critical, shielded
    from swarm_env.env import SwarmEnv

    if not duration_s > 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
    config = make_config(preset, **overrides)
    n_steps = max(1, int(round(duration_s / config.control_period_s)))
    config = dataclasses.replace(config, max_steps=max(config.max_steps, n_steps))
    env = SwarmEnv(config=config)
    agents = list(env.possible_agents)
    policy = WanderPolicy.for_env(env, seed=seed)
    emitter = RobotEmitter(agents, config, unstamped_bearings=unstamped_bearings)
    signals = ExitSignals()
    recorder = None
    base_ns = int(round(start_stamp_s * 1e9))
    high = np.array([config.robot.max_speed_mps, config.robot.max_turn_rate_radps])
    trace: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []
    steps_done = 0

    def stamp(t_s: float) -> int:
        return base_ns + int(round(t_s * 1e9))

    def snapshot() -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {
            a: (env.localizers[i].mixture.weights.copy(), env.localizers[i].mixture.means.copy())
            for i, a in enumerate(agents)
        }

    def write(messages) -> None:
        for m in messages:
            recorder.write(m.topic, m.kind, m.stamp_ns, m.msg)

    try:
        recorder = BagRecorder(path, agents, config, source="sim")
        obs, infos = env.reset(seed=seed)
        emitter.reset()
        truth = env.last_world_step.truth
        with critical():
            for i, a in enumerate(agents):
                write([emitter.origin(a, base_ns)])
                pose = truth.poses[i]
                mocap = emitter.step(a, _no_records(), stamp, (0.0, pose))
                write(mocap)
            recorder.write_marker("reset", 0, base_ns, {})
        trace.append(snapshot())
        for index in progress.sim_steps(n_steps, config.control_period_s, "export-bag"):
            k = index + 1  # steps are numbered from 1 (0 is the reset)
            actions = policy(obs, infos)
            commands = np.array(
                [np.clip(np.asarray(actions[a], dtype=np.float64), -high, high) for a in agents]
            )
            t_cmd = stamp(env.time_s) + 1
            obs, _, _, _, infos = env.step(actions)
            step = env.last_world_step
            end_ns = stamp(step.time_s)
            with critical():  # one step's rows and marker, whole or not at all
                recorder.write_commands(t_cmd, commands)
                for i, a in enumerate(agents):
                    write(
                        emitter.step(
                            a, step.measurements[a], stamp, (step.time_s, step.truth.poses[i])
                        )
                    )
                recorder.write_marker("step", k, end_ns, {})
            steps_done = k
            trace.append(snapshot())
    finally:
        try:
            with shielded():  # the bag is closed whole, whatever signal follows
                try:
                    if recorder is not None:
                        recorder.close()
                finally:
                    env.close()
        finally:
            signals.restore()
    return {
        "path": str(path),
        "robots": agents,
        "steps": steps_done,
        "messages": recorder.messages_written,
        "markers": recorder.markers_written,
        "trace": trace,
    }


def _no_records():
    from swarm_core.records import RobotMeasurements

    return RobotMeasurements(odometry=[], lidar=[], camera=[])
