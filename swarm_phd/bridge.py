"""``swarm-phd bridge``: run the scripted wander policy through the bridge env.

``--loopback`` is a dry run: it starts the loopback robot server (the simulator behind a
rosbridge-compatible websocket on 127.0.0.1) in this process and drives it exactly as it would
drive robots. Its robots carry the simulator's sensors, so the filter gets the preset's
simulator model (``make_config(preset).phd``); real robots get the seed's hardware model
(:func:`hardware_bridge.real_env`). ``--host H --robots ugv_0,ugv_1`` drives real robots (a
non-loopback host needs ``--allow-remote``). Prints localization metrics (when motion capture
gives ground truth) and the bridge's message counters.
"""

from __future__ import annotations

import argparse
import json
import time


def add_arguments(parser: argparse.ArgumentParser) -> None:
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument(
        "--loopback",
        action="store_true",
        help="dry run against an in-process loopback server (simulated robots)",
    )
    target.add_argument("--host", help="rosbridge server host (robots)")
    parser.add_argument("--port", type=int, default=9090, help="rosbridge port (default 9090)")
    parser.add_argument(
        "--robots",
        default=None,
        help="comma-separated robot namespaces (default: the preset's ugv_i)",
    )
    parser.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow a non-loopback --host (rosbridge has no authentication)",
    )
    parser.add_argument("--preset", default="seed-lab")
    parser.add_argument("--steps", type=int, default=100, help="env steps (default 100 = 10 s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--policy",
        choices=("wander", "stop"),
        default="wander",
        help="'stop' sends zero velocity (sensor check without motion)",
    )
    parser.add_argument(
        "--max-speed",
        type=float,
        default=None,
        help="cap the forward speed (m/s) below the preset's limit",
    )
    parser.add_argument(
        "--geofence", default=None, help="x_min,x_max,y_min,y_max in the mocap frame (m)"
    )
    parser.add_argument(
        "--localizer",
        default="phd",
        help="every robot's filter (`swarm-phd list`), e.g. phd-lc or pmb-lc",
    )
    parser.add_argument("--no-mocap", action="store_true", help="do not subscribe to mocap")
    parser.add_argument("--record", default=None, help="record the episode to this bag directory")
    parser.add_argument(
        "--faults",
        default=None,
        help="loopback only: fault probabilities, e.g. drop=0.05,malformed=0.02",
    )
    parser.add_argument(
        "--unstamped-bearings",
        default="",
        help="comma-separated robots that publish legacy header-less Float32MultiArray bearings",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def _faults(text: str | None):
    from hardware_bridge.loopback import FaultConfig

    if not text:
        return FaultConfig()
    values = {}
    for part in text.split(","):
        key, _, value = part.partition("=")
        key = key.strip()
        if key not in ("drop", "delay", "duplicate", "malformed", "delay_s"):
            raise ValueError(
                f"--faults: unknown fault {key!r} (drop, delay, duplicate, malformed, delay_s)"
            )
        try:
            values[key] = float(value)
        except ValueError as exc:
            raise ValueError(f"--faults: {key} needs a number, got {value!r}") from exc
    return FaultConfig(**values)


def run(args: argparse.Namespace) -> int:
    """SIGINT, SIGTERM and SIGHUP stop the robots at once, close the bag (readable up to the
    last complete step) and exit with status 128 + the signal number, without a traceback."""
    import signal
    import sys

    from hardware_bridge.signals import ExitSignals, Terminated

    signals = ExitSignals()
    try:
        return _run(args)
    except KeyboardInterrupt:
        code, name = 128 + signal.SIGINT, "SIGINT"
    except Terminated as exc:
        code, name = exc.code, signal.Signals(exc.signum).name
    finally:
        signals.restore()
    where = f"; bag {args.record} closed" if args.record else ""
    print(f"swarm-phd bridge: {name}: robots stopped{where}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from agents.scripted import WanderPolicy
    from hardware_bridge import real_env
    from swarm_env.config import make_config
    from swarm_phd.episode import format_metrics, run_episode

    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    bridge: dict = {"use_mocap": not args.no_mocap}
    if args.max_speed is not None:
        bridge["max_speed_mps"] = args.max_speed
    if args.geofence:
        try:
            bridge["geofence_m"] = tuple(float(v) for v in args.geofence.split(","))
        except ValueError as exc:
            raise ValueError(f"--geofence needs 4 numbers, got {args.geofence!r}") from exc
    unstamped = tuple(r.strip() for r in args.unstamped_bearings.split(",") if r.strip())
    if unstamped:
        bridge["unstamped_bearings"] = unstamped
    robots = [r.strip() for r in args.robots.split(",") if r.strip()] if args.robots else None
    server = None
    host, port = args.host, args.port
    if args.loopback:
        from hardware_bridge.loopback import LoopbackServer

        server = LoopbackServer(
            args.preset,
            seed=args.seed,
            faults=_faults(args.faults),
            unstamped_bearings=unstamped,
        )
        port = server.start()
        host = "127.0.0.1"
        if not args.json:
            print(
                f"loopback robot server on ws://127.0.0.1:{port} ({len(server.robot_ids)} "
                f"simulated robots, preset {args.preset})"
            )
    elif args.faults:
        raise ValueError("--faults only applies to --loopback")
    # The filter's sensor model is the one of the robots' sensors: simulated ones on loopback.
    model = {"phd": make_config(args.preset).phd} if args.loopback else {}
    env = None
    try:
        env = real_env(
            robots=robots,
            host=host,
            port=port,
            preset=args.preset,
            allow_remote=args.allow_remote,
            record=args.record,
            bridge=bridge,
            max_steps=args.steps,
            localizer=args.localizer,
            **model,
        )
        policy = WanderPolicy.for_env(env, seed=args.seed) if args.policy == "wander" else None
        if args.max_speed is not None and policy is not None:
            policy = WanderPolicy(
                max_speed_mps=min(args.max_speed, env.config.robot.max_speed_mps),
                max_turn_rate_radps=env.config.robot.max_turn_rate_radps,
                seed=args.seed,
            )
        if not args.json:
            print(
                f"bridge: {len(env.possible_agents)} robots {env.possible_agents} at "
                f"{host}:{port}, {args.steps} steps of {env.config.control_period_s} s, "
                f"{'the simulator' if args.loopback else 'the seed hardware'}'s sensor model"
            )
        start = time.monotonic()
        result = run_episode(env, policy, args.steps, seed=args.seed)
        wall = time.monotonic() - start
        world = env.world
        counters = world.counters_snapshot()
        timing = dict(world.timing)
    finally:
        if env is not None:
            env.close()
        if server is not None:
            server_counters = server.counters.snapshot()
            server.close()
    summary = {
        "steps": result.steps,
        "wall_s": round(wall, 3),
        "metrics": result.metrics,
        "stale_steps": result.stale_steps,
        "counters": counters,
        "timing": timing,
        "sensor_model": "simulator" if args.loopback else "seed-hardware",
        "rejected_messages": sum(
            v for k, v in counters.items() if k.endswith(".invalid") or k == "transport.malformed"
        ),
    }
    if server is not None:
        summary["server"] = {
            k: v
            for k, v in server_counters.items()
            if k.startswith(("injected", "server.twists", "published"))
        }
    if args.record:
        summary["bag"] = args.record
    if args.json:
        print(json.dumps(summary, indent=2, default=float))
        return 0
    print(
        f"ran {result.steps} steps in {wall:.2f} s "
        f"(max step overrun {timing['max_late_s'] * 1e3:.1f} ms)"
    )
    print("localization (each robot's own PHD vs ground truth):")
    print(format_metrics(result.metrics))
    print("stale sensor-steps:", result.stale_steps or "none")
    print("message counters:")
    for key, value in counters.items():
        print(f"  {key}: {value}")
    if args.record:
        print(f"recorded to {args.record}")
    return 0
