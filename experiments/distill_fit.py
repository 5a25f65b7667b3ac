"""How a distilled residual reproduces its teacher, phase by phase of the episode.

Question: what part of a teacher's correction does a feed-forward residual distilled from it
carry, and does it learn more than how the teacher's command depends on the base's? ::

    python -m experiments.distill_fit runs/formation_distill/warm_start.zip \
        --teacher privileged:formation-known-n-fast@truth --seeds 200-204 --out fit.json

Prints one table per phase (and writes it as JSON with ``--out``).

The model's scripted base (its zip's ``residual``) drives the robots for every seed, on the
model's own env, so every policy is asked about the same states: the ones the base reaches.
With ``--drive student`` the student drives instead: its fit on its own closed-loop states.
At every agent-step the teacher's label is the warm start's
(:func:`agents.sb3.warm_start.correction_labels`: ``clip((teacher - base) / high, -1, 1)``,
unit scale) and the student's answer is its correction (the policy's ``last_correction``).
Steps where the teacher random-walks are left out (their label is 0 by construction).

Printed per phase (``--phases``, step bounds): the labels' mean magnitude; ``R^2 = 1 -
student / zero``, the share of the labels' mean square the student's correction explains
(against answering 0, the base itself; a student carrying a fixed fraction ``c`` of every
label scores ``1 - (1 - c)^2``); the least-squares slopes of the teacher's and the student's
command on the base's (1: the command follows the base's; 0: unrelated to it; the teacher's
command is taken as base + label, which the label's clipping at full scale slightly biases);
and ``R^2`` *beyond the base*: the same share for the part of the label that a straight line
in the base's command does not explain (both the label and the student's correction with
their own regression on the base removed). A student with a high ``R^2``, a slope near the
teacher's and ``R^2`` beyond the base near 0 has learnt how the teacher's command depends on
the base's (for a teacher that ignores a noisy base: to cancel it), not what else the teacher
knows.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import DEFAULT_PHASES
from swarm_core.inputs import parse_seeds

__all__ = ["collect_fit", "phase_table", "main"]


def collect_fit(
    model: str | Path, teacher: str, seeds: list[int], drive: str = "base"
) -> dict[str, np.ndarray]:
    """Roll out ``model``'s base (``drive="base"``) or the model itself (``"student"``) on
    ``seeds`` and record, per agent-step (M rows):
    ``step`` (M,), ``label`` (M, 2) the teacher's correction, ``correction`` (M, 2) the
    student's, ``base`` (M, 2) the base's command, unit scale (``[v, omega] / high``, clipped),
    and ``wandering`` (M,) bool: the teacher random-walks."""
    from agents.policies import load_policy
    from agents.sb3.policy import load_sb3_policy, read_metadata
    from agents.sb3.residual import ResidualBase, base_in_unit_scale
    from agents.sb3.warm_start import correction_labels
    from swarm_env import parallel_env

    if drive not in ("base", "student"):
        raise ValueError(f"drive must be 'base' or 'student', got {drive!r}")
    meta = read_metadata(model)
    if not meta.get("residual"):
        raise ValueError(f"{str(model)!r} is not a residual model: it has no scripted base")
    mode = meta.get("residual_mode", "add")
    if mode != "add":
        # A gain residual's correction is an exponent, not comparable with additive labels.
        raise ValueError(
            f"{str(model)!r} has residual_mode {mode!r}; distill_fit compares additive "
            "corrections (residual_mode 'add')"
        )
    env = parallel_env(**meta["env_kwargs"])
    try:
        student = load_sb3_policy(model, env)
        base = ResidualBase(meta["residual"], env)
        tutor = load_policy(teacher, env)
        high = np.asarray(student.action_high, np.float64)
        out: dict[str, list] = {
            k: [] for k in ("step", "label", "correction", "base", "wandering")
        }
        for seed in seeds:
            for p in (student, base, tutor):
                p.reset(seed)
            obs, infos = env.reset(seed=seed)  # the simulator's infos carry the truth
            step = 0
            while env.agents:
                commands = base(obs, infos)
                acted = student(obs, infos)
                taught = tutor(obs, infos)
                agents = list(obs)
                out["label"].append(
                    correction_labels(taught, commands, tutor.wandering, agents, high)
                )
                out["correction"].append([student.last_correction[a] for a in agents])
                out["base"].append(base_in_unit_scale([commands[a] for a in agents], high))
                out["wandering"].append([a in tutor.wandering for a in agents])
                out["step"].append(np.full(len(agents), step))
                obs, _, _, _, infos = env.step(commands if drive == "base" else acted)
                step += 1
    finally:
        env.close()
    return {
        "step": np.concatenate(out["step"]),
        "label": np.concatenate(out["label"]).astype(np.float64),
        "correction": np.concatenate(out["correction"]).astype(np.float64),
        "base": np.concatenate(out["base"]).astype(np.float64),
        "wandering": np.concatenate(out["wandering"]).astype(bool),
    }


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of ``y`` on ``x`` with an intercept (NaN if ``x`` is constant)."""
    dx = x - x.mean()
    ss = float(dx @ dx)
    return float(dx @ (y - y.mean()) / ss) if ss > 0 else float("nan")


def _detrended(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y`` minus its least-squares line in ``x`` (``y`` minus its mean if ``x`` is constant)."""
    slope = _slope(x, y)
    if not np.isfinite(slope):
        return y - y.mean()
    return y - y.mean() - slope * (x - x.mean())


def phase_table(fit: dict[str, np.ndarray], phases=DEFAULT_PHASES) -> list[dict[str, Any]]:
    """Per phase ``[phases[i], phases[i + 1])`` (the last open-ended), over the rows where
    the teacher does not random-walk: ``n``, and per action dimension (``_v``, ``_omega``)
    ``label_abs`` mean |label|, ``mse_zero`` mean label^2, ``mse_student`` mean (label -
    correction)^2, ``r2 = 1 - mse_student / mse_zero``, ``r2_beyond_base`` the same for the
    label and correction each with its least-squares line in the base's command removed,
    ``sd_base`` the base command's standard deviation, and the slopes of the teacher's (base +
    label) and the student's (base + correction) command on the base's."""
    from agents.evaluation import phase_spans

    rows = []
    for lo, hi in phase_spans(phases):
        m = ~fit["wandering"] & (fit["step"] >= lo)
        if hi is not None:
            m &= fit["step"] < hi
        row: dict[str, Any] = {"from_step": lo, "to_step": hi, "n": int(m.sum())}
        if not m.any():
            rows.append(row)
            continue
        label, corr, base = fit["label"][m], fit["correction"][m], fit["base"][m]
        for j, name in enumerate(("v", "omega")):
            zero = float(np.mean(label[:, j] ** 2))
            student = float(np.mean((label[:, j] - corr[:, j]) ** 2))
            row[f"label_abs_{name}"] = float(np.mean(np.abs(label[:, j])))
            row[f"mse_zero_{name}"] = zero
            row[f"mse_student_{name}"] = student
            row[f"r2_{name}"] = 1.0 - student / zero if zero > 0 else float("nan")
            left = _detrended(base[:, j], label[:, j])
            left_student = _detrended(base[:, j], corr[:, j])
            spread = float(np.mean(left**2))
            missed = float(np.mean((left - left_student) ** 2))
            row[f"r2_beyond_base_{name}"] = 1.0 - missed / spread if spread > 0 else float("nan")
            row[f"sd_base_{name}"] = float(base[:, j].std())
            row[f"slope_teacher_{name}"] = _slope(base[:, j], base[:, j] + label[:, j])
            row[f"slope_student_{name}"] = _slope(base[:, j], base[:, j] + corr[:, j])
        rows.append(row)
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    head = (
        "| steps | n | abs label v / omega | R^2 v / omega | R^2 beyond the base v / omega "
        "| sd base v / omega | slope on base, teacher v / omega "
        "| slope on base, student v / omega |\n|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        span = f"{r['from_step']}-{'' if r['to_step'] is None else r['to_step']}"
        if r["n"] == 0:
            lines.append(f"| {span} | 0 | | | | | | |")
            continue
        lines.append(
            f"| {span} | {r['n']} | {r['label_abs_v']:.3f} / {r['label_abs_omega']:.3f} "
            f"| {r['r2_v']:.2f} / {r['r2_omega']:.2f} "
            f"| {r['r2_beyond_base_v']:.2f} / {r['r2_beyond_base_omega']:.2f} "
            f"| {r['sd_base_v']:.3f} / {r['sd_base_omega']:.3f} "
            f"| {r['slope_teacher_v']:.2f} / {r['slope_teacher_omega']:.2f} "
            f"| {r['slope_student_v']:.2f} / {r['slope_student_omega']:.2f} |"
        )
    return head + "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "models", nargs="+", help="residual model zips (warm_start.zip, model.zip)"
    )
    parser.add_argument(
        "--teacher", required=True, help="scripted:NAME, privileged:NAME or privileged:NAME@truth"
    )
    parser.add_argument("--seeds", default="200-204")
    parser.add_argument(
        "--phases",
        default=",".join(map(str, DEFAULT_PHASES)),
        help="comma-separated first steps of the phases",
    )
    parser.add_argument(
        "--drive",
        choices=("base", "student"),
        default="base",
        help="who drives the robots: the base (every model asked about the same states) or "
        "each student (its own closed-loop states)",
    )
    parser.add_argument("--out", default=None, help="also write the tables as JSON here")
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    try:
        phases = [int(p) for p in args.phases.split(",")]
    except ValueError:
        parser.error(f"--phases must be comma-separated integers, got {args.phases!r}")
    results = {}
    for model in args.models:
        if not Path(model).is_file():
            parser.error(f"model {model!r} does not exist")
        rows = phase_table(collect_fit(model, args.teacher, seeds, args.drive), phases)
        results[model] = rows
        print(f"{model} (teacher {args.teacher}, seeds {args.seeds}, {args.drive} driving)")
        print(markdown(rows))
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {"teacher": args.teacher, "seeds": seeds, "drive": args.drive, "models": results},
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
