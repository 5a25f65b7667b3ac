"""``swarm-phd record``: a video (MP4 or GIF) of any policy the project runs.

``--policy`` takes what ``swarm-phd evaluate --policy`` takes (``scripted:NAME``, ``random``,
``privileged:NAME``, a trained ``model.zip`` or a recurrent student ``.pt``); the env is built
as ``swarm-phd evaluate`` builds it (:mod:`swarm_phd.evaluate`: a trained policy's own preset,
task and observation settings, a controller's observation mode; :mod:`agents.policies` builds
the policy), with the filters running so that the focus robot's estimate is drawn. Each frame
is the env's own ``render_mode="rgb_array"`` picture (:mod:`swarm_env.render`: the arena, every
robot, the focus robot's lidar scan, camera bearings and PHD estimate; one fixed size for a
whole episode).

Playback is real time: frame ``k`` shows the swarm at ``k / fps`` simulated seconds, for ``k``
from 0 (after the reset) to ``duration * fps``. The default ``--fps`` is one frame per control
step (10 for every preset); a lower one skips steps. The episode may end before
``--duration`` (a task that terminates, or the env's ``max_steps``): the video then ends
there. Encoding: ffmpeg from the ``imageio-ffmpeg`` wheel (``pip install "swarm-phd[render]"``),
H.264 for ``.mp4``, a per-frame palette for ``.gif``; the file appears complete or not at all
(written beside it, then renamed).

Bad input (an unknown policy, task or preset, an extension other than ``.mp4``/``.gif``, an
``--out`` whose directory cannot be written, an ``--fps`` above the control rate) is refused
before any step runs or any file is written.
"""

from __future__ import annotations

import argparse
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm_core import inputs, progress

#: What ``--out`` may end with, and what is written.
FORMATS = {".mp4": "H.264 MP4", ".gif": "animated GIF"}
#: ffmpeg's settings per format: H.264 at constant quality (CRF 23, yuv420p: every player
#: reads it); GIF with a palette made for each frame (streamed: nothing is buffered).
_FFMPEG = {
    ".mp4": {"codec": "libx264", "pix_fmt_out": "yuv420p", "output_params": ["-crf", "23"]},
    ".gif": {
        "codec": "gif",
        "pix_fmt_out": "pal8",
        "output_params": [
            "-vf",
            "split[a][b];[a]palettegen=stats_mode=single[p];[b][p]paletteuse=new=1:dither=none",
        ],
    },
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from agents.policies import add_trust_policy_argument
    from swarm_phd.evaluate import add_policy_arguments

    add_policy_arguments(parser)
    parser.add_argument(
        "--preset",
        default=None,
        help="default: a trained policy's (model.zip, student .pt) own preset, else sim-6m-20",
    )
    add_trust_policy_argument(parser)
    inputs.add_seed_argument(parser, "the episode's seed")
    inputs.add_duration_argument(parser, 30.0)
    parser.add_argument(
        "--fps",
        type=float,
        default=None,
        help="frames per second of video, played in real time (default: one frame per control "
        "step, 10; at most that)",
    )
    parser.add_argument(
        "--render-agent",
        default="ugv_0",
        help="the focus robot whose sensors and estimate are drawn",
    )
    parser.add_argument(
        "--out", default="runs/record/episode.mp4", help="the video file: .mp4 or .gif"
    )


@dataclass
class Recording:
    """What :func:`record` wrote."""

    path: Path
    frames: int
    fps: float
    size_px: tuple[int, int]  # (width, height)
    sim_time_s: float
    steps: int
    ended_early: bool  # the episode ended before the requested duration
    summary: dict[str, Any]  # the env it ran: robots, task, observation, localizer


def check_out(flag: str, path: str | os.PathLike) -> Path:
    """``path`` if it ends in a known extension (:data:`FORMATS`) and its directory can be
    written (made with its parents when the video is written); ValueError otherwise."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(
            f"{flag} {str(path)!r}: unknown video format {p.suffix or '(no extension)'!r}; "
            f"end the name with one of {', '.join(FORMATS)}"
        )
    return inputs.output_file(flag, p)


def check_policy_name(spec: str) -> None:
    """Refuse a ``--policy`` that names nothing the project can run, listing the known ones; a
    model file must exist. (Whether a known policy can act in the env is checked when it is
    built on it, still before any step.)"""
    from agents.policies import SCRIPTED
    from agents.pretrained import resolve

    spec = resolve(spec)  # pretrained:NAME: its file (an unknown name lists the known)
    if spec == "random" or spec.startswith("privileged:"):
        return
    if spec.startswith("scripted:"):
        if spec.split(":", 1)[1] in SCRIPTED:
            return
    elif spec.endswith((".zip", ".pt")):
        if not Path(spec).is_file():
            raise ValueError(f"--policy: policy file {spec!r} does not exist")
        return
    else:
        from agents.policies import rllib_checkpoint

        if rllib_checkpoint(spec) is not None:
            return
    from agents.pretrained import PREFIX, names

    known = ["random", *(f"scripted:{name}" for name in SCRIPTED), *(PREFIX + n for n in names())]
    raise ValueError(
        f"--policy: unknown policy {spec!r}; known: {', '.join(known)}, 'privileged:NAME' "
        "(a training teacher), a trained model.zip, a recurrent student .pt or the --out "
        "directory of swarm-phd train --engine rllib"
    )


def _require_encoder() -> Any:
    try:
        import imageio_ffmpeg
    except ImportError as exc:
        raise ValueError(
            'recording needs imageio-ffmpeg (it ships ffmpeg): pip install "swarm-phd[render]"'
        ) from exc
    return imageio_ffmpeg


def frame_steps(n_steps: int, control_period_s: float, fps: float) -> list[int]:
    """The env step each frame shows: frame ``k`` at ``k / fps`` s, the first step at or after
    that time (step ``j`` ends at ``j * control_period_s``), ``k`` up to ``n_steps`` steps."""
    per_frame = 1.0 / (fps * control_period_s)  # steps between frames (>= 1)
    n_frames = int(math.floor(n_steps / per_frame + 1e-9)) + 1
    return [int(math.ceil(k * per_frame - 1e-9)) for k in range(n_frames)]


def record(
    out: str | os.PathLike,
    policy: str = "scripted:wander",
    *,
    task: str | None = None,
    preset: str | None = None,
    seed: int = 0,
    duration_s: float = 30.0,
    fps: float | None = None,
    render_agent: str = "ugv_0",
    **overrides: Any,
) -> Recording:
    """Run one episode of ``policy`` and write it to ``out`` (``.mp4`` or ``.gif``).

    ``overrides`` go to the env (``task_params``, config fields such as ``n_robots``), over a
    trained policy's own settings. Returns what was written (:class:`Recording`). Raises
    ValueError, naming the argument, before anything runs or is written."""
    from agents.policies import load_policy, policy_env

    path = check_out("--out", out)
    inputs.seed("--seed", seed)
    inputs.duration("--duration", duration_s)
    if fps is not None:
        inputs.check_number("--fps", fps, low=0.0, above=True)
    check_policy_name(policy)
    ffmpeg = _require_encoder()
    env = policy_env(
        preset,
        task,
        policy,
        localize=True,  # the focus robot's estimate is drawn
        render_mode="rgb_array",
        render_agent=render_agent,
        **overrides,
    )
    try:
        period = env.config.control_period_s
        step_rate = 1.0 / period
        if fps is None:
            fps = step_rate
        elif fps > step_rate * (1 + 1e-9):
            raise ValueError(
                f"--fps must be at most the control rate, {step_rate:g} frames/s (one frame per "
                f"step of {period:g} s), got {fps!r}"
            )
        n_steps = inputs.steps_in(env, "--duration", duration_s)
        schedule = frame_steps(n_steps, period, fps)
        act = load_policy(policy, env)  # ValueError if it cannot act in this env
        kwargs = _env_summary(env)
        return _run(env, act, ffmpeg, path, seed, schedule, fps, n_steps, kwargs)
    finally:
        env.close()


def _env_summary(env: Any) -> dict[str, Any]:
    return {
        "n_robots": env.config.n_robots,
        "task": env.task.name,
        "observation": env.config.observation,
        "localizer": env.config.localizer,
    }


def _run(
    env: Any,
    act: Any,
    ffmpeg: Any,
    path: Path,
    seed: int,
    schedule: list[int],
    fps: float,
    n_steps: int,
    kwargs: dict[str, Any],
) -> Recording:
    if hasattr(act, "reset"):
        act.reset(seed)
    obs, infos = env.reset(seed=seed)
    first = env.render()
    height, width = first.shape[:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.partial{path.suffix.lower()}")
    writer = ffmpeg.write_frames(
        str(partial),
        (width, height),
        fps=fps,
        macro_block_size=1,  # the renderer's size is kept (no resize)
        ffmpeg_log_level="error",
        **_FFMPEG[path.suffix.lower()],
    )
    writer.send(None)  # start ffmpeg
    frames = steps = 0
    try:
        writer.send(np.ascontiguousarray(first))
        frames = 1
        for step in progress.sim_steps(n_steps, env.config.control_period_s, "record"):
            if not env.agents:
                break
            obs, _, _, _, infos = env.step(act(obs, infos))
            steps = step + 1
            if frames < len(schedule) and schedule[frames] == steps:
                frame = env.render()
                if frame.shape != first.shape:  # the renderer's contract: one size per episode
                    raise RuntimeError(
                        f"frame {frames} is {frame.shape}, the first was {first.shape}"
                    )
                writer.send(np.ascontiguousarray(frame))
                frames += 1
        writer.close()
        os.replace(partial, path)
    except BaseException:
        writer.close()
        partial.unlink(missing_ok=True)
        raise
    return Recording(
        path=path,
        frames=frames,
        fps=fps,
        size_px=(width, height),
        sim_time_s=env.time_s,
        steps=steps,
        ended_early=steps < n_steps,
        summary=kwargs,
    )


def run(args: argparse.Namespace) -> int:
    from swarm_core.inputs import parse_json_object

    if getattr(args, "trust_policy", False):
        from agents.policies import trust_policy_files

        trust_policy_files()

    overrides: dict[str, Any] = {}
    if args.task_params is not None:
        overrides["task_params"] = parse_json_object(args.task_params, "--task-params")
    rec = record(
        args.out,
        args.policy,
        task=args.task,
        preset=args.preset,
        seed=args.seed,
        duration_s=args.duration,
        fps=args.fps,
        render_agent=args.render_agent,
        **overrides,
    )
    ended = " (the episode ended there)" if rec.ended_early else ""
    print(
        f"swarm-phd record: {rec.path} ({FORMATS[rec.path.suffix.lower()]}): {rec.frames} "
        f"frames of {rec.size_px[0]}x{rec.size_px[1]} px at {rec.fps:g} fps, "
        f"{rec.sim_time_s:.1f} s simulated{ended}; policy {args.policy}, task "
        f"{rec.summary['task']}, {rec.summary['n_robots']} UGVs, seed {args.seed}, "
        f"focus {args.render_agent}"
    )
    return 0
