"""``swarm-phd bridge``: drive robots through the bridge env with a policy (the scripted
wander by default, any scripted controller, or a trained ``.zip`` model or ``.pt`` student).

``--loopback`` is a dry run: it starts the loopback robot server (the simulator behind a
rosbridge-compatible websocket on 127.0.0.1) in this process and drives it exactly as it would
drive robots. Its robots carry the simulator's sensors, so the filter gets the preset's
simulator model (``make_config(preset).phd``); real robots get the Perera 2021 study's hardware
model (:func:`hardware_bridge.real_env`). ``--host H --robots ugv_0,ugv_1`` drives real robots (a
non-loopback host needs ``--allow-remote``). A trained policy runs in its own env's task,
observation and preset (``agents.policies.trained_policy_env``), on ``len(robots)`` robots.
Prints localization metrics and the task's metrics (when motion capture gives ground truth)
and the bridge's message counters.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from swarm_core import inputs


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
    parser.add_argument(
        "--preset", default=None, help="default: a trained policy's own preset, else lab-3m-4"
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="env steps (default: a trained policy's episode length, else 100 = 10 s)",
    )
    inputs.add_seed_argument(parser)
    parser.add_argument(
        "--policy",
        default="wander",
        help="'wander' (default); 'stop' sends zero velocity (a sensor check without motion); "
        "'random', 'scripted:NAME' (`swarm-phd list`), a trained model.zip / student.pt or "
        "an RLlib run directory (train --engine rllib --out), which runs in its own task and "
        "observation",
    )
    parser.add_argument(
        "--trust-policy",
        action="store_true",
        help="load an SB3 .zip from outside a swarm-phd train run, or an RLlib run, although "
        "loading it runs code stored in the file (both unpickle classes and spaces): only for "
        "a run you trained or verified yourself (a zip in its train --out directory and a "
        "student.pt load weights only and need no flag)",
    )
    parser.add_argument(
        "--task",
        default=None,
        help="the env's task, e.g. formation (default: a trained policy's own task, else wander)",
    )
    parser.add_argument("--task-params", default=None, help="task parameters as a JSON object")
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
        default=None,
        help="every robot's filter (`swarm-phd list`), e.g. phd-lc or pmb-lc (default: a "
        "trained policy's own, else phd)",
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
    parser.add_argument(
        "--onboard",
        action="store_true",
        help="the robots run their own filters: subscribe to /<robot>/swarm_phd/estimate "
        "instead of their scans and bearings (with --loopback the simulated robots run them)",
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


#: What a trained policy's own env settings carry to the robots: what it observes (the
#: observation's mode and layout), its localizer and its robot count. The rest of a model's
#: training overrides (speed limits, the filter's model, the arena, the control period...)
#: would change the robots' safety caps or the filter, so they are not applied, and listed.
MODEL_KEYS_ON_ROBOTS = (
    "observation",
    "top_k",
    "lidar_sectors",
    "lidar_sector_max_m",
    "localizer",
    "n_robots",
)


def bridge_env_kwargs(
    args: argparse.Namespace, robots: list[str] | None
) -> tuple[dict, list[str]]:
    """Preset, task, task parameters, localizer, observation settings and episode length
    (``max_steps``) of the bridge env for ``args.policy``, and the trained policy's env
    settings left out
    (:data:`MODEL_KEYS_ON_ROBOTS`), checked before anything connects: a trained policy's own
    env (not its episode length, nor its robot count when ``robots`` are named), a scripted
    controller's observation mode, else the simulator's defaults. The policy is built once on
    a simulator with these settings, so one that cannot act on them (another observation size,
    a controller without its task) is refused here too."""
    from agents.policies import SCRIPTED, policy_observation, rllib_checkpoint, trained_policy_env
    from agents.pretrained import resolve
    from swarm_core.inputs import parse_json_object

    spec = resolve(args.policy)  # pretrained:NAME: its file (an unknown name lists the known)
    if spec.startswith("privileged:"):
        raise ValueError(
            f"--policy {spec!r} is a training teacher that reads the simulator's truth; it "
            "cannot drive robots"
        )
    if spec.startswith("scripted:"):
        if spec.split(":", 1)[1] not in SCRIPTED:
            raise ValueError(
                f"--policy: unknown scripted policy {spec!r}; choose from {sorted(SCRIPTED)}"
            )
    elif spec.endswith((".zip", ".pt")):
        if not Path(spec).is_file():
            raise ValueError(f"--policy: policy file {spec!r} does not exist")
        from agents.sb3.safe_load import run_directory

        foreign_zip = spec.endswith(".zip") and run_directory(spec) is None
        if foreign_zip and not getattr(args, "trust_policy", False):
            raise ValueError(
                f"--policy {spec!r} is an SB3 model zip from outside a swarm-phd train run: "
                "loading one unpickles Python objects stored in it (its policy class, spaces, "
                "schedules), which can run any code, on the computer that drives the robots. "
                "Pass --trust-policy if you trained this file yourself or trust its source (a "
                "zip in its train --out directory and a student.pt load weights only)"
            )
    elif rllib_checkpoint(spec) is not None:
        if not getattr(args, "trust_policy", False):
            raise ValueError(
                f"--policy {spec!r} is an RLlib run: loading its module unpickles Python "
                "objects stored in the checkpoint, which can run any code, on the computer "
                "that drives the robots. Pass --trust-policy if you trained it yourself or "
                "trust its source"
            )
    elif spec not in ("wander", "stop", "random"):
        raise ValueError(
            "--policy must be 'wander', 'stop', 'random', 'scripted:NAME', 'pretrained:NAME', a "
            ".zip model, a .pt student or the --out directory of swarm-phd train --engine "
            f"rllib, got {spec!r}"
        )
    overrides: dict = {}
    if args.task_params is not None:
        overrides["task_params"] = parse_json_object(args.task_params, "--task-params")
    model = trained_policy_env(spec, args.preset, args.task, **overrides)
    dropped: list[str] = []
    if model is None:
        kwargs = {**overrides, "preset": args.preset or "lab-3m-4", "task": args.task or "wander"}
        observation = policy_observation(spec) if spec.startswith("scripted:") else None
        if observation is not None:  # e.g. scripted:formation acts on the robot's PHD estimate
            kwargs["observation"] = observation
    else:
        kept = ("preset", "task", "task_params", *MODEL_KEYS_ON_ROBOTS)
        kwargs = {k: v for k, v in model.items() if k in kept}
        # Its episode length is --steps; the bridge always localizes (it scores the filters).
        dropped = sorted(k for k in model if k not in kept and k not in ("max_steps", "localize"))
        if kwargs.get("observation") == "truth":
            raise ValueError(
                f"--policy {spec!r} was trained on the true neighbour table "
                "(observation='truth'); it cannot drive robots, which know only their estimate"
            )
    # --steps, else a trained policy's episode length (what it was trained to do), else 10 s.
    steps = args.steps if args.steps is not None else (model or {}).get("max_steps", 100)
    if steps < 1:
        raise ValueError(f"--steps must be >= 1, got {steps}")
    if robots is not None:
        kwargs.pop("n_robots", None)  # one agent per named robot
    kwargs["localizer"] = args.localizer or kwargs.get("localizer") or "phd"
    if spec not in ("wander", "stop"):
        _check_policy_acts(spec, kwargs, robots, steps, getattr(args, "trust_policy", False))
    return {**kwargs, "max_steps": steps}, dropped


def _check_policy_acts(
    spec: str, kwargs: dict, robots: list[str] | None, steps: int, trust: bool = False
) -> None:
    """Build ``spec`` on a simulator with the bridge env's settings (ValueError if it cannot
    act there), before anything connects."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    sized = {} if robots is None else {"n_robots": len(robots)}
    probe = parallel_env(**{**kwargs, **sized, "max_steps": steps})
    try:
        load_policy(spec, probe, trust=trust)
    finally:
        probe.close()


def run(args: argparse.Namespace) -> int:
    """SIGINT, SIGTERM and SIGHUP stop the robots at once, close the bag (readable up to the
    last complete step) and exit with status 128 + the signal number, without a traceback."""
    import sys

    from hardware_bridge.bag import bag_state
    from hardware_bridge.claim import RobotClaimedError
    from hardware_bridge.signals import (
        ExitSignals,
        Terminated,
        ignore_exit_signals,
        signal_exit,
    )

    signals = ExitSignals()
    try:
        return _run(args)
    except RobotClaimedError as exc:  # another bridge process drives these robots
        print(f"swarm-phd bridge: error: {exc}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, Terminated, SystemError) as exc:
        found = signal_exit(exc)
        if found is None:  # a SystemError of its own
            raise
        code, name = found
        ignore_exit_signals()  # leaving: the robots are stopped and the bag closed
    finally:
        signals.restore()
    where = f"; {bag_state(args.record)}" if args.record else ""
    print(f"swarm-phd bridge: {name}: robots stopped{where}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from agents.policies import load_policy
    from agents.scripted import WanderPolicy
    from hardware_bridge import real_env
    from swarm_env.config import make_config
    from swarm_phd.episode import format_metrics, run_episode

    inputs.seed("--seed", args.seed)
    if args.record:
        inputs.new_bag_dir("--record", args.record)
    robots = [r.strip() for r in args.robots.split(",") if r.strip()] if args.robots else None
    env_kwargs, not_applied = bridge_env_kwargs(args, robots)
    preset, steps = env_kwargs.pop("preset"), env_kwargs.pop("max_steps")
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
    server = None
    host, port = args.host, args.port
    if args.loopback:
        from hardware_bridge.loopback import LoopbackServer

        sized = {"n_robots": env_kwargs["n_robots"]} if "n_robots" in env_kwargs else {}
        server = LoopbackServer(
            preset,
            **sized,
            seed=args.seed,
            faults=_faults(args.faults),
            unstamped_bearings=unstamped,
            onboard=args.onboard,
            localizer=env_kwargs["localizer"],
        )
        port = server.start()
        host = "127.0.0.1"
        if not args.json:
            print(
                f"loopback robot server on ws://127.0.0.1:{port} ({len(server.robot_ids)} "
                f"simulated robots, preset {preset})"
            )
    elif args.faults:
        raise ValueError("--faults only applies to --loopback")
    # The filter's sensor model is the one of the robots' sensors: simulated ones on loopback.
    if args.loopback:
        env_kwargs["phd"] = make_config(preset).phd
    env = None
    try:
        env = real_env(
            robots=robots,
            host=host,
            port=port,
            preset=preset,
            allow_remote=args.allow_remote,
            record=args.record,
            bridge=bridge,
            max_steps=steps,
            onboard=args.onboard,
            **env_kwargs,
        )
        if args.policy == "stop":
            policy = None
        elif args.policy == "wander":
            policy = WanderPolicy.for_env(env, seed=args.seed)
            if args.max_speed is not None:  # wander at the capped speed, not into the cap
                policy = WanderPolicy(
                    max_speed_mps=min(args.max_speed, env.config.robot.max_speed_mps),
                    max_turn_rate_radps=env.config.robot.max_turn_rate_radps,
                    seed=args.seed,
                )
        else:  # the bridge's limits and geofence clip whatever it commands
            policy = load_policy(args.policy, env, trust=getattr(args, "trust_policy", False))
        if not args.json:
            print(
                f"bridge: {len(env.possible_agents)} robots {env.possible_agents} at "
                f"{host}:{port}, {steps} steps of {env.config.control_period_s} s, "
                f"{'the simulator' if args.loopback else 'Perera 2021 hardware'}'s sensor model; "
                f"preset {preset}; policy {args.policy}, task {env.task.name}, observation "
                f"{env.config.observation}, localizer {env.config.localizer}"
            )
            if not_applied:
                print(f"the policy's training settings not applied on robots: {not_applied}")
        start = time.monotonic()
        result = run_episode(env, policy, steps, seed=args.seed)
        wall = time.monotonic() - start
        task_metrics = env.task.metrics()
        world = env.world
        counters = world.counters_snapshot()
        timing = dict(world.timing)
    finally:
        try:
            if env is not None:
                env.close()  # stops the robots and closes the bag first, signals held
        finally:
            if server is not None:
                server_counters = server.counters.snapshot()
                server.close()
    summary = {
        "steps": result.steps,
        "wall_s": round(wall, 3),
        "metrics": result.metrics,
        "policy": args.policy,
        "preset": preset,
        "robots": list(env.possible_agents),
        "observation": env.config.observation,
        "localizer": env.config.localizer,
        "policy_settings_not_applied": not_applied,
        "task": {"name": env.task.name, **task_metrics},
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
    if task_metrics:
        print(
            f"task {env.task.name}: "
            + ", ".join(f"{k} = {v:.3f}" for k, v in task_metrics.items())
        )
    print("stale sensor-steps:", result.stale_steps or "none")
    print("message counters:")
    for key, value in counters.items():
        print(f"  {key}: {value}")
    if args.record:
        print(f"recorded to {args.record}")
    return 0
