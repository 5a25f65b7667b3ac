"""The ``swarm-phd`` command line. Each subcommand lives in the module that does the work; this
file only parses arguments, applies the shared defaults and dispatches.

Shared by every command: defaults shown in ``--help``; ``--quiet`` (no progress bars or status
lines, results only); one default preset, :data:`DEFAULT_PRESET`, for every simulation command
(``bridge`` drives the lab robots and keeps ``lab-3m-4``; ``evaluate`` and ``bridge`` of a
trained policy keep the policy's); ``swarm-phd list`` names the presets, tasks and
localizers; ``--version``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

Command = Callable[[argparse.Namespace], int]
_REGISTRY: list[tuple[str, str, Callable[[argparse.ArgumentParser], None], str]] = []

#: The preset every simulation command defaults to (the source study's simulated experiment).
DEFAULT_PRESET = "sim-6m-20"
#: Commands whose ``--preset`` default is not :data:`DEFAULT_PRESET`, and why.
PRESET_EXCEPTIONS = {"bridge": "drives the lab robots", "warmup": "kernels do not depend on size"}
#: Commands that step an env: the first one on a fresh install compiles the kernels.
COMPILING_COMMANDS = (
    "demo",
    "bench",
    "evaluate",
    "sweep",
    "export-bag",
    "replay",
    "train",
    "bridge",
    "seed003",
    "mutual",
    "uav",
    "record",
)
#: What each preset models (``swarm_env.config.PRESETS`` holds the values).
PRESET_DESCRIPTIONS = {
    "sim-6m-20": "the source study's simulation: 20 UGVs, 6 m x 6 m walled arena, boxes, decoys",
    "perera2021": (
        "the source study's simulation with its own sensors and filter: 20 UGVs, 6 m x 6 m, "
        "lidar fading as its eq. 19, camera bearings with 5 deg noise fading as eq. 30, no decoys"
    ),
    "lab-3m-4": "the source study's lab test area: 4 UGVs, 3 m x 3 m, 2 decoy posts, 1 red decoy",
    "seed-uav": (
        "the Stegagno et al. ICRA 2013 setup: 3 UGVs, 2.5 m x 2.5 m, radio on, under a UAV "
        "(swarm-phd uav)"
    ),
}


def _no_default(value: object) -> bool:
    """None, a store_true flag's False, or suppressed (by identity: 0 and 0.0 are defaults)."""
    return value is None or value is False or value is argparse.SUPPRESS


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows ``(default: X)`` after every option that has a default, and keeps line breaks."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if _no_default(action.default) or "default" in text:
            return text
        return super()._get_help_string(action)


def _add(name: str, help_text: str, module: str):
    """Register a subcommand implemented by ``module.add_arguments`` and ``module.run``."""

    def configure(parser: argparse.ArgumentParser) -> None:
        import importlib

        importlib.import_module(module).add_arguments(parser)

    _REGISTRY.append((name, help_text, configure, module))


_add("demo", "run the source study's swarm and show sensors and localization", "swarm_phd.demo")
_add("bench", "measure env throughput (steps/s, real-time factor, lidar cost)", "swarm_phd.bench")
_add(
    "evaluate",
    "reproduce the source study's localization experiment / evaluate a policy",
    "swarm_phd.evaluate",
)
_add(
    "bridge",
    "drive robots (or --loopback simulated ones) over rosbridge",
    "swarm_phd.bridge",
)
_add(
    "replay",
    "rerun localization and metrics offline on a recorded bag",
    "swarm_phd.replay",
)
_add("export-bag", "write a simulated episode as a ROS 2 bag", "swarm_phd.export_bag")
_add(
    "record",
    "record a video (.mp4 or .gif) of any policy: scripted, random or trained",
    "swarm_phd.record",
)
_add(
    "train",
    "train a PPO policy shared by all agents on a task (stable-baselines3, or Ray RLlib with "
    "--engine rllib)",
    "agents.rllib.engine",
)
_add(
    "sweep",
    "localization sweeps over presets x localizers x seeds, on Ray workers (local or --address)",
    "swarm_phd.sweep",
)
_add(
    "seed003",
    "the low-cost IR swarm study: SLSQP direct estimation then a centralized UKF on IR "
    "range-bearing readings, 5 robots",
    "swarm_phd.seed003",
)
_add(
    "mutual",
    "the Stegagno 2012 thesis: mutual localization from anonymous detections and the radio "
    "(P-MultiReg, FastSLAM-MC), scored on the thesis's metrics",
    "swarm_phd.mutual",
)
_add(
    "uav",
    "the Stegagno et al. ICRA 2013 study: a UAV identifies wandering UGVs with ID-PHD on its "
    "downward camera",
    "swarm_phd.uav",
)
_add("warmup", "compile the numba kernels ahead of time (first run only)", "swarm_phd.warmup")
_add("list", "list the presets, tasks and localizers", "swarm_phd.cli")


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("swarm-phd")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown (not installed)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``swarm-phd list`` takes no options."""


def listing() -> str:
    """The presets, tasks and localizers, one per line with what they are."""
    from swarm_env.config import PRESET_ALIASES, PRESETS
    from swarm_env.tasks import TASKS

    lines = [f"presets (default {DEFAULT_PRESET}):"]
    for name, cfg in PRESETS.items():
        old = [k for k, v in PRESET_ALIASES.items() if v == name]
        desc = PRESET_DESCRIPTIONS.get(
            name, f"{cfg.n_robots} UGVs, {cfg.arena.width_m:g} m x {cfg.arena.height_m:g} m"
        )
        lines.append(f"  {name:<16} {desc}" + (f" (old name: {old[0]})" if old else ""))
    lines.append("tasks:")
    for name, cls in TASKS.items():
        doc = (cls.__doc__ or "").strip().splitlines()
        lines.append(f"  {name:<16} {doc[0] if doc else ''}")
    lines.append("localizers (evaluate --localizer):")
    for name, desc in _localizers().items():
        lines.append(f"  {name:<16} {desc}")
    lines.append("trained policies shipped (--policy pretrained:NAME; train --recipe NAME):")
    lines.extend(f"  {name:<16} {desc}" for name, desc in _pretrained().items())
    return "\n".join(lines)


def _pretrained() -> dict[str, str]:
    """Each shipped policy: its recipe and its held-out result against the task's best
    scripted controller (:mod:`agents.pretrained`)."""
    from agents.pretrained import card, names

    out = {}
    for name in names():
        c = card(name)
        g = c["goal"]
        out[name] = (
            f"{c['summary']}; {g['metric']} {g['policy_mean']:.3f} vs {g['baseline']} "
            f"{g['baseline_mean']:.3f} on {g['n_seeds']} held-out seeds ({g['verdict']})"
        )
    return out


def _localizers() -> dict[str, str]:
    try:
        from localization.registry import descriptions

        return descriptions()
    except ImportError:  # before the registry: the evaluation's own table
        from swarm_phd.evaluate import LOCALIZERS

        return {k: str(v) for k, v in LOCALIZERS.items()}


def run(args: argparse.Namespace) -> int:
    """``swarm-phd list``."""
    print(listing())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm-phd",
        description="UGV swarm simulator with embedded robot-centric GM-PHD localization. "
        "`swarm-phd COMMAND --help` shows each command's options and defaults.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"swarm-phd {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, help_text, configure, module in _REGISTRY:
        p = sub.add_parser(
            name, help=help_text, description=help_text, formatter_class=HelpFormatter
        )
        configure(p)
        p.add_argument(
            "-q",
            "--quiet",
            action="store_true",
            help="no progress bars or status lines (results only); for scripts",
        )
        _share_preset_default(name, p)
        _show_every_default(p)
        p.set_defaults(_module=module)
    return parser


def _share_preset_default(command: str, parser: argparse.ArgumentParser) -> None:
    """One default preset across commands; every ``--preset`` help lists the presets."""
    from swarm_env.config import PRESET_ALIASES, PRESETS

    for action in parser._actions:
        if action.dest != "preset":
            continue
        if action.default is not None and command not in PRESET_EXCEPTIONS:
            action.default = DEFAULT_PRESET
        elif action.default is not None:  # show the current name of an old-named default
            action.default = PRESET_ALIASES.get(action.default, action.default)
        names = ", ".join(PRESETS)
        action.help = f"{action.help + '; ' if action.help else ''}one of: {names}"


def _show_every_default(parser: argparse.ArgumentParser) -> None:
    """Options declared without help text still show their default and, for ``--task``, the
    task names."""
    from swarm_env.tasks import TASKS

    for action in parser._actions:
        if action.dest == "task" and action.option_strings:
            action.help = f"{action.help + '; ' if action.help else ''}one of: {', '.join(TASKS)}"
        if action.help is None and not _no_default(action.default):
            action.help = "default: %(default)s"


def main(argv: Sequence[str] | None = None) -> int:
    import importlib

    parser = build_parser()
    args = parser.parse_args(argv)
    from swarm_core import progress

    progress.set_quiet(args.quiet)
    from swarm_env import kernel_cache

    if args.command in COMPILING_COMMANDS:
        from swarm_env.warmup import warm_if_cold

        # At the command's first env, after it has checked its input (a bad flag is refused
        # at once), with the compile's own message and bar before the command's output.
        kernel_cache.set_first_use_action(warm_if_cold)
    elif args.quiet:
        kernel_cache.mark_noted()
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except ValueError as exc:  # bad input: a clear message, no traceback
        print(f"swarm-phd {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except SystemError as exc:
        # SIGTERM/SIGINT raised inside a C callback (numba loading a kernel) arrives wrapped:
        # exit as the signal asks (128 + signum), every finally having run on the way here.
        from swarm_core.signal_chain import unwrap_signal

        signal_exc = unwrap_signal(exc)
        if signal_exc is None:
            raise
        raise signal_exc from None
    finally:
        progress.set_quiet(False)
        kernel_cache.set_first_use_action(None)


if __name__ == "__main__":
    sys.exit(main())
